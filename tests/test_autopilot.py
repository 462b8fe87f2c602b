"""The simulated flight controller in its Simulation (vehicle.autopilot, vehicle.physics, vehicle.world).

Everything runs on simulated time: the tests step the Simulation and look at the pose.
"""

import math
import re

import numpy as np
import pytest

from vehicle.protocol.frames import Pose
from vehicle.protocol.geodesy import Datum, heading_of, wrap_pi
from vehicle.protocol.mav import ACCEPTED, DENIED, FAILED, TEMPORARILY_REJECTED, UNSUPPORTED, mavlink
from vehicle.protocol.mission import (
    DO_CHANGE_SPEED,
    NAV_LAND,
    NAV_LOITER_UNLIM,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    MissionItem,
)
from vehicle.protocol.modes import STOP_MODE, Kind, commanded_mode, flown, mode_name, mode_number, name_of, number_of
from vehicle.sim.autopilot import VELOCITY_TIMEOUT, Autopilot
from vehicle.sim.avoidance import GRAZE, MARGIN, ObstacleDatabase
from vehicle.sim.physics import Body, Limits
from vehicle.sim.simulation import Simulation
from vehicle.world.sonar import Sonar

ALTITUDE = 4.0
REST_Z = 0.35  # body centre of a landed vehicle on ground at z = 0 (radius 0.3 + clearance 0.05)


def armed_copter(scene, start=(0.0, 0.0), altitude=ALTITUDE, **kwargs) -> Simulation:
    """A copter that took off in GUIDED and hovers at ``altitude`` above its start."""
    world = Simulation(scene, Kind.COPTER, start=start, **kwargs)
    assert world.autopilot.arm() == ACCEPTED
    assert world.autopilot.takeoff(altitude) == ACCEPTED
    world.run_for(altitude / world.limits.climb_rate + 3.0)
    return world


def armed_rover(scene, start=(0.0, 0.0), **kwargs) -> Simulation:
    world = Simulation(scene, Kind.ROVER, start=start, **kwargs)
    assert world.autopilot.arm() == ACCEPTED
    assert world.autopilot.set_mode("GUIDED") == ACCEPTED
    return world


def vehicle(kind: Kind, scene, **kwargs) -> Simulation:
    return armed_copter(scene, **kwargs) if kind is Kind.COPTER else armed_rover(scene, **kwargs)


def taking_off(scene) -> Simulation:
    world = Simulation(scene, Kind.COPTER)
    world.autopilot.arm()
    world.autopilot.takeoff(10.0)
    world.run_for(1.0)  # climbing, at about 1.85 m
    return world


def bare_autopilot(kind: Kind, ground: float = 0.0) -> Autopilot:
    """An Autopilot on its own (no Simulation, no obstacle database), its body resting at the origin on flat
    ground at height ``ground``, which is also home's; step it with ``autopilot.step(dt, ground)``."""
    body = Body(kind, pose=Pose(0.0, 0.0, 0.0))
    body.pose.z = body.rest_height(ground)
    return Autopilot(kind, body, (0.0, 0.0, ground), Datum())


def step_until(world: Simulation, condition, limit: float) -> float:
    """Step until ``condition()`` holds; returns the simulated time it took (fails past ``limit`` seconds)."""
    start = world.time
    while not condition():
        assert world.time - start < limit, f"not reached within {limit} s of simulated time"
        world.step()
    return world.time - start


def position_item(world: Simulation, command: int, x: float, y: float, alt: float = ALTITUDE, **params) -> MissionItem:
    lat, lon = world.datum.to_global(x, y)
    return MissionItem(command, lat, lon, alt, **params)


def reached(world: Simulation) -> list[int]:
    return [event.seq for event in world.autopilot.events if event.kind == "reached"]


def texts(world: Simulation) -> list[str]:
    return [event.text for event in world.autopilot.events if event.kind == "text"]


def said(world: Simulation) -> list[tuple[str, int]]:
    return [(event.text, event.severity) for event in world.autopilot.events if event.kind == "text"]


# ---- arming and take-off ----------------------------------------------------------------------


def test_copter_boots_disarmed_on_the_ground_in_guided(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, start=(2.0, 3.0), heading=90.0)
    assert not world.autopilot.armed and world.autopilot.mode == "GUIDED"
    assert world.pose.xyz() == pytest.approx((2.0, 3.0, REST_Z))
    assert world.pose.yaw == pytest.approx(math.pi / 2)
    assert world.home == pytest.approx((2.0, 3.0, 0.0))
    world.run_for(2.0)
    assert world.pose.xyz() == pytest.approx((2.0, 3.0, REST_Z))  # disarmed: nothing moves


def test_rover_boots_disarmed_in_hold(flat_scene):
    world = Simulation(flat_scene, Kind.ROVER)
    assert not world.autopilot.armed and world.autopilot.mode == "HOLD"


def test_copter_takes_off_to_altitude_in_guided(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, start=(0.0, 0.0))
    world.autopilot.arm()
    assert world.autopilot.takeoff(ALTITUDE) == ACCEPTED
    took = step_until(world, lambda: abs(world.pose.z - ALTITUDE) < 0.2 and abs(world.body.vz) < 0.05, limit=8.0)
    assert took <= ALTITUDE / world.limits.climb_rate + 3.0
    assert world.autopilot.flying
    assert world.autopilot.altitude == pytest.approx(ALTITUDE, abs=0.2)
    world.run_for(10.0)
    assert world.pose.xyz() == pytest.approx((0.0, 0.0, ALTITUDE), abs=0.2)  # and holds there


def test_takeoff_to_one_metre_is_accepted_and_flown(flat_scene):
    """A low take-off to 1 m is flown."""
    world = Simulation(flat_scene, Kind.COPTER)
    world.autopilot.arm()
    assert world.autopilot.takeoff(1.0) == ACCEPTED
    world.run_for(5.0)
    assert world.autopilot.altitude == pytest.approx(1.0, abs=0.1) and world.autopilot.flying


def test_takeoff_altitude_is_above_the_start_ground(make_scene, box):
    scene = make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(0, 0, 1, 6, 6, 2))  # start on a 2 m plinth
    world = armed_copter(scene)
    assert world.pose.z == pytest.approx(2.0 + ALTITUDE, abs=0.2)
    assert world.autopilot.altitude == pytest.approx(ALTITUDE, abs=0.2)


def test_takeoff_refused_when_disarmed(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    assert world.autopilot.takeoff(ALTITUDE) == TEMPORARILY_REJECTED
    world.run_for(2.0)
    assert world.pose.z == pytest.approx(REST_Z)


def test_takeoff_refused_outside_guided(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    world.autopilot.arm()
    assert world.autopilot.set_mode("LOITER") == ACCEPTED
    assert world.autopilot.takeoff(ALTITUDE) == TEMPORARILY_REJECTED
    world.run_for(2.0)
    assert world.pose.z == pytest.approx(REST_Z)


def test_takeoff_to_zero_altitude_denied_and_again_in_the_air_failed(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    world.autopilot.arm()
    assert world.autopilot.takeoff(0.0) == DENIED
    world = armed_copter(flat_scene)
    assert world.autopilot.takeoff(ALTITUDE) == FAILED


def test_a_takeoff_that_would_not_leave_the_ground_fails_and_says_why(flat_scene):
    """A copter resting with its centre 0.35 m up counts as flying 5 cm above that, and its take-off is done within
    0.1 m of its height: a take-off to 0.2 m was accepted and never ended, on the ground (the agent waited in
    silence for ever). As ArduPilot refuses a take-off downwards, it now fails; 0.5 m is the lowest that flies."""
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.arm()
    for low in (0.2, 0.4, 0.49):
        assert autopilot.takeoff(low) == FAILED
        assert not autopilot.taking_off
    assert texts(world)[-1] == "Takeoff: 0.49 m would not leave the ground; at least 0.50 m"
    assert autopilot.takeoff(0.5) == ACCEPTED
    step_until(world, lambda: not autopilot.taking_off, limit=5.0)
    assert autopilot.flying and world.pose.z == pytest.approx(0.5, abs=0.1)


def test_a_mission_takeoff_too_low_to_leave_the_ground_climbs_to_the_lowest_that_does(flat_scene):
    """An AUTO take-off item to 0.1 m held the copter on the ground for ever, the mission stuck on it."""
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.set_mission([MissionItem(NAV_WAYPOINT), MissionItem(NAV_TAKEOFF, alt=0.1),
                           position_item(world, NAV_WAYPOINT, 3.0, 0.0, alt=2.0)])
    autopilot.arm()
    autopilot.set_mode("AUTO")
    autopilot.start_mission()
    step_until(world, lambda: reached(world) == [1], limit=5.0)
    assert autopilot.flying and world.pose.z == pytest.approx(0.5, abs=0.1)
    step_until(world, lambda: reached(world) == [1, 2], limit=20.0)


def test_rover_takeoff_unsupported(flat_scene):
    world = armed_rover(flat_scene)
    assert world.autopilot.takeoff(ALTITUDE) == UNSUPPORTED


def test_guided_commands_refused_when_disarmed(flat_scene):
    autopilot = Simulation(flat_scene, Kind.COPTER).autopilot
    assert autopilot.goto(5.0, 5.0) == TEMPORARILY_REJECTED
    assert autopilot.set_velocity(1.0, 0.0) == TEMPORARILY_REJECTED
    assert autopilot.set_yaw(1.0) == TEMPORARILY_REJECTED


def test_arming_refused_in_land_unless_forced(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    world.autopilot.set_mode("LAND")
    assert world.autopilot.arm() == FAILED
    assert not world.autopilot.armed
    assert world.autopilot.arm(force=True) == ACCEPTED


@pytest.mark.parametrize("mode", ["RTL", "LAND"])
def test_arming_a_copter_in_rtl_or_land_is_refused_with_a_critical_message_naming_the_mode(flat_scene, mode):
    """A copter cannot be armed in RTL or LAND; the operator is told which mode, as a critical message."""
    world = Simulation(flat_scene, Kind.COPTER)
    assert world.autopilot.set_mode(mode) == ACCEPTED
    assert world.autopilot.arm() == FAILED
    assert world.autopilot.armed is False
    assert said(world) == [(f"Arm: mode {mode} not armable", 2)]  # MAV_SEVERITY_CRITICAL


def test_the_operator_hears_what_arming_disarming_and_missions_do_with_their_severity(flat_scene):
    """The texts a ground station shows (STATUSTEXT) are part of the behaviour: wording and severity."""
    info, notice, warning, critical = 6, 5, 4, 2
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    assert autopilot.disarm() == FAILED
    assert autopilot.start_mission() == DENIED  # not in AUTO: refused quietly
    assert autopilot.set_mode("AUTO") == FAILED  # no items
    autopilot.set_mission([autopilot.home_item(), position_item(world, NAV_WAYPOINT, 3.0, 0.0)])
    assert autopilot.set_mode("AUTO") == ACCEPTED
    assert autopilot.start_mission() == ACCEPTED
    assert autopilot.disarm(force=True) == ACCEPTED
    ground = Simulation(flat_scene, Kind.ROVER)
    ground.autopilot.arm()
    assert ground.autopilot.disarm() == ACCEPTED
    assert said(world) == [
        ("Arming motors", info),
        ("Takeoff to 4.0 m", info),
        ("Disarm: vehicle is flying", critical),
        ("No Mission. Can't set AUTO.", notice),
        ("Flight mode change failed", warning),
        ("Mission: 1 started", info),
        ("Disarming motors (forced)", info),
    ]
    assert said(ground)[-1] == ("Disarming motors", info)


# ---- modes ------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_unknown_mode_name_is_unsupported(kind, flat_scene):
    autopilot = Simulation(flat_scene, kind).autopilot
    before = autopilot.mode
    assert autopilot.set_mode("FLIP") == UNSUPPORTED
    assert autopilot.mode == before


def test_copter_has_no_hold_and_rover_has_no_brake(flat_scene):
    assert Simulation(flat_scene, Kind.COPTER).autopilot.set_mode("HOLD") == UNSUPPORTED
    assert Simulation(flat_scene, Kind.ROVER).autopilot.set_mode("BRAKE") == UNSUPPORTED


def test_mode_names_are_case_insensitive(flat_scene):
    autopilot = Simulation(flat_scene, Kind.COPTER).autopilot
    assert autopilot.set_mode("brake") == ACCEPTED
    assert autopilot.mode == "BRAKE"


def test_mode_changes_are_counted_and_the_source_of_each_request_is_kept(flat_scene):
    """Each change of mode counts once; a request for the mode it is already in only records its source;
    a request without a source comes from the ground station ("gcs")."""
    autopilot = Simulation(flat_scene, Kind.COPTER).autopilot
    assert (autopilot.mode_changes, autopilot.mode_source) == (0, "boot")
    assert autopilot.set_mode("LOITER") == ACCEPTED
    assert (autopilot.mode_changes, autopilot.mode_source) == (1, "gcs")
    assert autopilot.set_mode("LOITER", source="failsafe") == ACCEPTED  # no change of mode
    assert (autopilot.mode_changes, autopilot.mode_source) == (1, "failsafe")
    assert autopilot.set_mode("BRAKE", source="agent") == ACCEPTED
    assert (autopilot.mode_changes, autopilot.mode_source) == (2, "agent")
    assert autopilot.set_mode("GUIDED") == ACCEPTED
    assert (autopilot.mode, autopilot.mode_changes, autopilot.mode_source) == ("GUIDED", 3, "gcs")


def test_mode_numbers_are_ardupilots():
    assert {name: mode_number(Kind.ROVER, name) for name in ("HOLD", "LOITER", "AUTO", "RTL", "GUIDED")} == {
        "HOLD": 4,
        "LOITER": 5,
        "AUTO": 10,
        "RTL": 11,
        "GUIDED": 15,
    }
    assert {name: mode_number(Kind.COPTER, name) for name in ("AUTO", "GUIDED", "LOITER", "RTL", "LAND", "BRAKE")} == {
        "AUTO": 3,
        "GUIDED": 4,
        "LOITER": 5,
        "RTL": 6,
        "LAND": 9,
        "BRAKE": 17,
    }
    assert all(mode_name(kind, number) == name for kind in Kind for name, number in flown(kind).items())
    assert mode_name(Kind.COPTER, 99) is None
    with pytest.raises(ValueError, match="no mode"):
        mode_number(Kind.COPTER, "HOLD")
    assert STOP_MODE == {"rover": "HOLD", "boat": "HOLD", "copter": "BRAKE", "plane": "LOITER"}


def test_one_table_names_the_modes_of_every_vehicle_type():
    """The simulator's modes, the station's commands and its timeline read the same table (ArduPilot's)."""
    plane, copter = mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_TYPE_QUADROTOR
    assert (number_of(plane, "rtl"), name_of(plane, 11)) == (11, "RTL")
    assert (number_of(copter, "HOLD"), name_of(copter, 99), number_of(0, "RTL")) == (None, None, None)
    assert all(name_of(kind.mav_type, number) == name for kind in Kind for name, number in flown(kind).items())
    assert [commanded_mode(v) for v in (4.0, float("nan"), float("inf"), -1.0, 2.0 ** 32)] == [4, None, None, None,
                                                                                                None]


# ---- GUIDED: goto, velocity, yaw, speed ---------------------------------------------------------


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_goto_turns_first_then_moves(kind, flat_scene):
    world = vehicle(kind, flat_scene)  # facing north
    target = (20.0, -20.0)  # south-east: 135 degrees to turn
    assert world.autopilot.goto(*target) == ACCEPTED
    turned_at = None
    for _ in range(200):
        world.step()
        error = abs(wrap_pi(heading_of(target[0] - world.pose.x, target[1] - world.pose.y) - world.pose.yaw))
        if error > math.radians(15):
            assert world.body.speed < 0.05, f"moving at {world.body.speed:.2f} m/s with {math.degrees(error):.0f} deg"
        elif turned_at is None:
            turned_at = world.time
    assert turned_at is not None
    assert world.body.speed > 1.0  # moving once it faces the target


def test_the_nose_turns_the_way_short_hops_go_so_the_sonars_look_there(flat_scene):
    """A copter facing north sent east in hops of 0.14 m, each once the last is reached (a path cell by cell
    past a door frame): it turns as it goes, as ArduCopter's yaw follows its velocity; before, within 0.5 m of
    a target it kept its heading, and flew sideways into a wall its sonars, looking north, never saw."""
    world = vehicle(Kind.COPTER, flat_scene)
    for hop in range(1, 11):
        assert world.autopilot.goto(0.14 * hop, 0.0) == ACCEPTED
        step_until(world, lambda: world.autopilot._target is None, limit=5.0)
    assert world.pose.x == pytest.approx(1.4, abs=0.15)
    assert abs(wrap_pi(world.pose.yaw - math.pi / 2)) < math.radians(20), math.degrees(world.pose.yaw)


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_goto_reaches_the_target_and_holds(kind, flat_scene):
    world = vehicle(kind, flat_scene)
    world.autopilot.goto(20.0, -20.0)
    step_until(
        world, lambda: math.hypot(world.pose.x - 20, world.pose.y + 20) < 0.15 and world.body.speed < 0.01, limit=40.0
    )
    world.run_for(10.0)
    assert (world.pose.x, world.pose.y) == pytest.approx((20.0, -20.0), abs=0.15)
    assert world.body.speed < 0.01
    if kind is Kind.COPTER:
        assert world.pose.z == pytest.approx(ALTITUDE, abs=0.2)


def test_a_copter_holding_its_height_low_over_a_box_top_still_flies_on(make_scene, box):
    """The box top is 0.38 m below the body's centre: where it rests there lies 3 cm below it, closer than
    the 5 cm a take-off must climb to count as flying. Passing over it is no landing (it once stopped there
    for good, deaf to its GUIDED targets)."""
    top = ALTITUDE - REST_Z - 0.03
    scene = make_scene(box(0, 0, -0.05, 80, 80, 0.1), box(5, 0, top / 2, 4, 4, top))
    world = armed_copter(scene)
    world.autopilot.avoidance = None  # its edge would hold it back: it came over one its sonars never saw
    world.autopilot.goto(10.0, 0.0)
    step_until(world, lambda: world.pose.x > 5.0, limit=20.0)
    assert world.autopilot.flying  # over the box
    step_until(world, lambda: math.hypot(world.pose.x - 10, world.pose.y) < 0.15, limit=20.0)
    assert world.collision is None and world.autopilot.flying


def test_goto_with_altitude_changes_height(flat_scene):
    world = armed_copter(flat_scene)
    world.autopilot.goto(0.0, 10.0, altitude=7.0)
    world.run_for(20.0)
    assert world.pose.xyz() == pytest.approx((0.0, 10.0, 7.0), abs=0.2)


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_speed_acceleration_turn_and_climb_limits_hold_at_every_step(kind, flat_scene):
    limits = Limits()
    world = vehicle(kind, flat_scene, limits=limits)
    autopilot = world.autopilot
    assert autopilot.set_speed(limits.max_speed) == ACCEPTED
    commands = [(25.0, 0.0, 0.0, 9.0), (-20.0, 15.0, 0.0, 2.0), (0.0, 0.0, 0.0, 8.0)]  # goto x, y, alt; hurry
    prev = (world.body.vx, world.body.vy, world.pose.yaw, world.pose.z)
    max_speed = 0.0
    for x, y, _, altitude in commands:
        autopilot.goto(x, y, altitude=altitude)
        for _ in range(400):
            world.step()
            vx, vy, yaw, z = world.body.vx, world.body.vy, world.pose.yaw, world.pose.z
            speed = math.hypot(vx, vy)
            max_speed = max(max_speed, speed)
            assert speed <= limits.max_speed + 1e-9
            assert math.hypot(vx - prev[0], vy - prev[1]) <= limits.accel * world.dt + 1e-9
            assert abs(wrap_pi(yaw - prev[2])) <= limits.turn_rate * world.dt + 1e-9
            assert abs(z - prev[3]) <= limits.climb_rate * world.dt + 1e-6
            prev = (vx, vy, yaw, z)
    assert max_speed == pytest.approx(limits.max_speed, abs=0.01)  # the limit was actually reached


def test_velocity_beyond_max_speed_is_capped(flat_scene):
    world = armed_copter(flat_scene)
    world.autopilot.set_velocity(0.0, 50.0)
    world.run_for(2.9)
    assert world.body.speed == pytest.approx(world.limits.max_speed)


def test_velocity_command_moves_the_vehicle_until_it_expires_after_3_s(flat_scene):
    world = armed_copter(flat_scene)  # facing north: no turn needed
    assert world.autopilot.set_velocity(0.0, 2.0) == ACCEPTED
    world.run_for(VELOCITY_TIMEOUT - 0.1)
    assert world.body.vy == pytest.approx(2.0)
    world.run_for(0.15)
    expired_at = world.pose.y
    speeds = []
    for _ in range(round(8.0 / world.dt)):
        world.step()
        speeds.append(world.body.speed)
        assert abs(world.pose.y - expired_at) < 2.0  # braking distance at 2 m/s is 0.8 m
    assert speeds[0] < 2.0  # braking right after expiry
    assert max(speeds[-40:]) < 0.01  # and at rest for good


def test_copter_stops_where_a_velocity_command_expires_without_flying_back(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    world.autopilot.arm()
    world.autopilot.takeoff(4.0)
    world.run_for(6.0)
    world.autopilot.set_velocity(0.0, 2.0)
    furthest = 0.0
    for _ in range(200):
        world.step()
        furthest = max(furthest, world.pose.y)
    assert world.pose.y == pytest.approx(furthest, abs=0.05)  # it used to fly back to the expiry point


def test_velocity_command_turns_first_towards_its_direction(flat_scene):
    world = armed_copter(flat_scene)  # facing north
    world.autopilot.set_velocity(2.0, 0.0)  # east
    world.run_for(0.5)  # 45 degrees turned at 90 deg/s
    assert world.body.speed < 0.05
    world.run_for(1.5)
    assert world.pose.yaw == pytest.approx(math.pi / 2, abs=1e-6)
    assert world.body.vx > 1.0


def test_a_velocity_without_a_vertical_part_keeps_the_height(flat_scene):
    world = armed_copter(flat_scene)
    assert world.autopilot.set_velocity(1.0, 0.0) == ACCEPTED
    world.run_for(2.0)
    assert world.pose.x > 0.5 and world.autopilot.altitude == pytest.approx(ALTITUDE, abs=0.1)


def test_a_vehicle_steered_by_velocity_has_no_destination_and_on_open_ground_is_not_held_back(flat_scene):
    """Under a velocity command there is no place the vehicle is going to (unlike a goto); nothing holds it back."""
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    autopilot.goto(0.0, 10.0)
    world.step()
    assert autopilot.destination == (0.0, 10.0) and autopilot.blocked is False
    autopilot.set_velocity(0.0, 2.0)
    world.run_for(1.0)
    assert world.body.vy > 1.0
    assert autopilot.destination is None and autopilot.blocked is False


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_set_yaw_turns_in_place(kind, flat_scene):
    world = vehicle(kind, flat_scene)
    start = world.pose.xyz()
    assert world.autopilot.set_yaw(math.radians(270)) == ACCEPTED  # west: a quarter turn left
    for _ in range(round(2.0 / world.dt)):
        world.step()
        assert world.body.speed < 1e-9
    assert world.pose.yaw == pytest.approx(math.radians(270), abs=1e-6)
    assert world.pose.xyz() == pytest.approx(start, abs=1e-6)


def test_set_yaw_relative_turns_by_that_angle(flat_scene):
    world = armed_copter(flat_scene)
    world.autopilot.set_yaw(math.radians(90))
    world.run_for(2.0)
    world.autopilot.set_yaw(math.radians(-30), relative=True)
    world.run_for(1.0)
    assert math.degrees(world.pose.yaw) == pytest.approx(60.0, abs=1e-4)


def test_a_yaw_is_a_compass_heading_unless_relative_and_never_cancels_a_target(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    assert autopilot.set_yaw(math.radians(90)) == ACCEPTED  # absolute by default
    world.run_for(5.0)
    assert world.pose.yaw == pytest.approx(math.radians(90), abs=0.02)
    assert autopilot.set_yaw(math.radians(300), relative=True) == ACCEPTED  # 90 + 300 = 390: 30 degrees
    world.run_for(6.0)
    assert world.pose.yaw == pytest.approx(math.radians(30), abs=0.02)
    assert autopilot.goto(8.0, 0.0) == ACCEPTED
    world.run_for(0.2)
    assert autopilot.set_yaw(math.radians(90)) == ACCEPTED  # while going there
    world.run_for(15.0)
    assert (world.pose.x, world.pose.y) == pytest.approx((8.0, 0.0), abs=0.15)


def test_set_speed_changes_cruise_and_refuses_out_of_range(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    assert autopilot.set_speed(0.0) == DENIED
    assert autopilot.set_speed(world.limits.max_speed + 1) == DENIED
    assert autopilot.set_speed(1.0) == ACCEPTED
    autopilot.goto(0.0, 30.0)
    world.run_for(10.0)
    assert world.body.speed == pytest.approx(1.0)


# ---- AUTO missions ----------------------------------------------------------------------------


def test_auto_mission_visits_waypoints_in_order_with_speed_changes(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),  # home, replaced
            MissionItem(NAV_TAKEOFF, alt=ALTITUDE),  # 1
            position_item(world, NAV_WAYPOINT, 20.0, 0.0),  # 2
            MissionItem(DO_CHANGE_SPEED, param1=1, param2=4.0),  # 3
            position_item(world, NAV_WAYPOINT, 20.0, 25.0),  # 4
            position_item(world, NAV_WAYPOINT, 0.0, 25.0, param2=0.5),  # 5: tighter acceptance radius
            position_item(world, NAV_LOITER_UNLIM, 0.0, 10.0),  # 6
        ]
    )
    autopilot.arm()
    assert autopilot.set_mode("AUTO") == ACCEPTED
    assert not autopilot.mission_running  # a copter on the ground waits for MISSION_START
    assert autopilot.start_mission() == ACCEPTED
    leg_speeds: dict[int, float] = {}
    nearest: dict[int, float] = {}
    targets = {2: (20.0, 0.0), 4: (20.0, 25.0), 5: (0.0, 25.0)}
    while autopilot.current < 6:
        assert world.time < 120
        current = autopilot.current
        world.step()
        leg_speeds[current] = max(leg_speeds.get(current, 0.0), world.body.speed)
        if current in targets:
            distance = math.dist((world.pose.x, world.pose.y), targets[current])
            nearest[current] = min(nearest.get(current, math.inf), distance)
    assert reached(world) == [1, 2, 3, 4, 5]
    assert leg_speeds[2] == pytest.approx(2.5, abs=0.01)  # the cruise speed until DO_CHANGE_SPEED
    assert leg_speeds[4] == pytest.approx(4.0, abs=0.01)
    assert autopilot.speed == 4.0
    assert nearest[2] <= world.autopilot.wp_radius and nearest[4] <= world.autopilot.wp_radius
    assert nearest[5] <= 0.5
    assert world.pose.z == pytest.approx(ALTITUDE, abs=0.2)


def test_auto_nav_land_lands_at_its_position_and_disarms(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),
            MissionItem(NAV_TAKEOFF, alt=3.0),
            position_item(world, NAV_LAND, 8.0, 6.0, alt=0.0),
        ]
    )
    autopilot.arm()
    autopilot.set_mode("AUTO")
    autopilot.start_mission()
    step_until(world, lambda: not autopilot.armed, limit=40.0)
    world.run_for(1.0)  # disarmed at touchdown, within 5 cm of resting: it settles
    assert world.pose.xyz() == pytest.approx((8.0, 6.0, REST_Z), abs=0.15)
    assert reached(world) == [1, 2]
    assert "Landed; disarming" in texts(world)
    assert world.collision is None


def test_a_copter_landing_at_the_end_of_its_mission_disarms_with_the_mission_over(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            autopilot.home_item(),
            position_item(world, NAV_WAYPOINT, 4.0, 0.0),
            position_item(world, NAV_LAND, 4.0, 0.0, alt=0.0),
        ]
    )
    autopilot.set_mode("AUTO")
    assert autopilot.start_mission() == ACCEPTED
    step_until(world, lambda: not autopilot.armed, 60.0)
    assert autopilot.mission_running is False and reached(world) == [1, 2]
    assert autopilot.current == len(autopilot.mission)
    assert texts(world)[-2:] == ["Mission complete", "Landed; disarming"]


def test_auto_return_to_launch_brings_a_copter_home_and_lands(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, start=(3.0, 4.0))
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),
            MissionItem(NAV_TAKEOFF, alt=ALTITUDE),
            position_item(world, NAV_WAYPOINT, 15.0, 4.0),
            MissionItem(NAV_RETURN_TO_LAUNCH),
        ]
    )
    autopilot.arm()
    autopilot.set_mode("AUTO")
    autopilot.start_mission()
    step_until(world, lambda: not autopilot.armed, limit=60.0)
    world.run_for(1.0)
    assert math.hypot(world.pose.x - 3.0, world.pose.y - 4.0) < 0.3
    assert world.pose.z == pytest.approx(REST_Z, abs=0.01)
    assert reached(world) == [1, 2, 3]


def test_auto_rover_starts_on_entering_auto_and_returns_home_to_hold(flat_scene):
    world = Simulation(flat_scene, Kind.ROVER, start=(3.0, 4.0))
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),
            position_item(world, NAV_WAYPOINT, 12.0, 4.0),
            position_item(world, NAV_WAYPOINT, 12.0, 12.0),
            MissionItem(NAV_RETURN_TO_LAUNCH),
        ]
    )
    autopilot.arm()
    autopilot.set_mode("AUTO")
    assert autopilot.mission_running
    step_until(world, lambda: not autopilot.mission_running, limit=60.0)
    assert reached(world) == [1, 2, 3]
    assert "Mission complete" in texts(world)
    world.run_for(5.0)
    assert math.hypot(world.pose.x - 3.0, world.pose.y - 4.0) < 0.3
    assert world.body.speed < 0.01
    assert autopilot.armed  # a rover holds at home


def test_a_finished_mission_is_no_longer_running(flat_scene):
    """After its last item the mission is over: not running, current past the end, and it says so."""
    world = Simulation(flat_scene, Kind.ROVER)
    autopilot = world.autopilot
    autopilot.set_mission([autopilot.home_item(), position_item(world, NAV_WAYPOINT, 0.0, 4.0)])
    autopilot.arm()
    autopilot.set_mode("AUTO")
    step_until(world, lambda: autopilot.current == len(autopilot.mission), limit=20.0)
    assert autopilot.mission_running is False
    assert texts(world)[-1] == "Mission complete"


def test_auto_loiter_unlimited_holds_forever(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),
            MissionItem(NAV_TAKEOFF, alt=ALTITUDE),
            position_item(world, NAV_LOITER_UNLIM, -6.0, 5.0),
            position_item(world, NAV_WAYPOINT, 10.0, 10.0),
        ]
    )
    autopilot.arm()
    autopilot.set_mode("AUTO")
    autopilot.start_mission()
    world.run_for(600.0)
    assert autopilot.current == 2 and autopilot.mission_running
    assert reached(world) == [1]
    assert world.pose.xyz() == pytest.approx((-6.0, 5.0, ALTITUDE), abs=0.2)


def test_auto_and_start_mission_are_refused_without_items(flat_scene):
    """As ArduPilot: with only home, an armed copter and any rover are refused AUTO, saying why; a disarmed copter
    may wait in AUTO for a mission, but starting one fails."""
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    assert autopilot.set_mode("AUTO") == ACCEPTED
    autopilot.arm()
    assert autopilot.start_mission() == FAILED  # only home
    assert autopilot.set_mode("GUIDED") == ACCEPTED
    assert autopilot.start_mission() == DENIED  # not in AUTO
    assert autopilot.set_mode("AUTO") == FAILED and autopilot.mode == "GUIDED"
    assert texts(world)[-3:] == ["Mission: no items", "No Mission. Can't set AUTO.", "Flight mode change failed"]
    rover = Simulation(flat_scene, Kind.ROVER)
    mode = rover.autopilot.mode
    assert rover.autopilot.set_mode("AUTO") == FAILED and rover.autopilot.mode == mode  # disarmed too
    rover.autopilot.set_mission([MissionItem(NAV_WAYPOINT), position_item(rover, NAV_WAYPOINT, 0.0, 8.0)])
    assert rover.autopilot.set_mode("AUTO") == ACCEPTED


def test_a_new_mission_waits_to_be_started_at_its_first_item(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    autopilot.set_mode("AUTO")
    autopilot.set_mission([autopilot.home_item(), position_item(world, NAV_WAYPOINT, 3.0, 0.0)])
    assert autopilot.mission_running is False and autopilot.current == 1
    autopilot.set_mission([])  # cleared: home only
    assert len(autopilot.mission) == 1 and autopilot.current == 1 and autopilot.mission_running is False


def test_mission_start_resumes_restarts_or_jumps_to_an_item(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    items = [position_item(world, NAV_WAYPOINT, 2.0 * k, 0.0) for k in range(1, 5)]
    autopilot.set_mission([autopilot.home_item(), *items])
    autopilot.set_mode("AUTO")
    assert autopilot.set_current(3) is True
    assert autopilot.start_mission() == ACCEPTED and autopilot.current == 3  # 0: resume at the current item
    assert autopilot.start_mission(1) == ACCEPTED and autopilot.current == 1  # from the first
    assert autopilot.start_mission(2) == ACCEPTED and autopilot.current == 2
    autopilot.current = len(autopilot.mission)  # finished
    assert autopilot.start_mission() == ACCEPTED and autopilot.current == 1  # starts over
    one = Simulation(flat_scene, Kind.ROVER).autopilot
    one.arm()
    one.set_mission([one.home_item(), MissionItem(NAV_WAYPOINT, *one.datum.to_global(3.0, 0.0), 0.0)])
    assert one.set_mode("AUTO") == ACCEPTED
    assert one.start_mission() == ACCEPTED  # a mission of one item


def test_set_current_takes_only_the_items_after_home_and_says_so(flat_scene):
    world = armed_copter(flat_scene)
    autopilot = world.autopilot
    autopilot.set_mission([autopilot.home_item(), *[position_item(world, NAV_WAYPOINT, k, 0.0) for k in (2, 4)]])
    before = list(autopilot.events)
    assert autopilot.set_current(0) is False and autopilot.set_current(3) is False
    assert list(autopilot.events) == before and autopilot.current == 1
    assert autopilot.set_current(2) is True and autopilot.current == 2
    assert autopilot.set_current(1) is True and autopilot.current == 1
    assert [(e.kind, e.seq) for e in list(autopilot.events)[len(before) :]] == [("current", 2), ("current", 1)]


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_leaving_auto_stops_the_mission(flat_scene, kind):
    """A running mission stops when the vehicle is switched out of AUTO."""
    world = vehicle(kind, flat_scene)
    autopilot = world.autopilot
    autopilot.set_mission([autopilot.home_item(), position_item(world, NAV_WAYPOINT, 0.0, 30.0)])
    autopilot.set_mode("AUTO")
    assert autopilot.start_mission() == ACCEPTED and autopilot.mission_running is True
    world.run_for(1.0)
    assert autopilot.set_mode("GUIDED") == ACCEPTED
    assert autopilot.mission_running is False


def test_unsupported_mission_items_are_skipped_with_a_warning(flat_scene):
    world = Simulation(flat_scene, Kind.ROVER)
    autopilot = world.autopilot
    autopilot.set_mission(
        [
            MissionItem(NAV_WAYPOINT),
            MissionItem(183),  # DO_SET_SERVO
            position_item(world, NAV_WAYPOINT, 0.0, 8.0),
        ]
    )
    autopilot.arm()
    autopilot.set_mode("AUTO")
    world.run_for(15.0)
    assert reached(world) == [1, 2]
    assert any("unsupported command 183" in text for text in texts(world))


# ---- RTL, LAND, stopping ------------------------------------------------------------------------


def test_rtl_copter_returns_home_lands_and_disarms(flat_scene):
    world = armed_copter(flat_scene, start=(2.0, -3.0))
    world.autopilot.goto(15.0, 5.0)
    world.run_for(15.0)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    step_until(world, lambda: not world.autopilot.armed, limit=70.0)  # up to 15 m, home, down
    world.run_for(1.0)
    assert math.hypot(world.pose.x - 2.0, world.pose.y + 3.0) < 0.3
    assert world.pose.z == pytest.approx(REST_Z, abs=0.01)
    assert "Reached home" in texts(world)
    assert world.collision is None


def test_rtl_copter_climbs_to_rtl_altitude_where_it_is_before_flying_home(flat_scene):
    world = armed_copter(flat_scene, start=(2.0, -3.0))
    world.autopilot.goto(15.0, 5.0)
    world.run_for(15.0)
    x, y = world.pose.x, world.pose.y
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    highest = world.pose.z

    def climbed() -> bool:
        nonlocal highest
        highest = max(highest, world.pose.z)
        if world.pose.z < 14.8:
            assert math.hypot(world.pose.x - x, world.pose.y - y) < 0.5  # straight up first
        return math.hypot(world.pose.x - x, world.pose.y - y) > 1.0

    step_until(world, climbed, limit=30.0)
    assert world.pose.z == pytest.approx(15.0, abs=0.3)
    assert "RTL: climbing to 15 m, then home" in texts(world)
    step_until(world, lambda: not world.autopilot.armed, limit=60.0)
    assert math.hypot(world.pose.x - 2.0, world.pose.y + 3.0) < 0.3
    assert highest < 15.5


def test_rtl_climbs_straight_up_to_within_0_2_m_of_its_height_even_when_facing_home(flat_scene):
    """RTL's climb goes on (straight up) until within 0.2 m of the RTL height, even when the copter already
    faces home and need not turn: only then does it fly home."""
    world = armed_copter(flat_scene)
    world.autopilot.goto(0.0, -10.0)
    world.run_for(10.0)
    assert world.autopilot.set_yaw(0.0) == ACCEPTED  # face north, towards home
    world.run_for(3.0)
    spot = (world.pose.x, world.pose.y)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    while world.pose.z < 14.79:
        assert world.time < 60.0
        world.step()
        assert math.dist((world.pose.x, world.pose.y), spot) < 0.01, f"moving off at {world.pose.z:.2f} m"
    step_until(world, lambda: not world.autopilot.armed, limit=40.0)
    assert math.hypot(world.pose.x, world.pose.y) < 0.3


def test_rtl_ends_its_climb_at_exactly_0_2_m_below_the_rtl_height():
    """The climb ends once the copter is no more than 0.2 m below the RTL height: from exactly 0.2 m below,
    RTL goes straight on to home (here right where the copter stands: it is reached at the first step)."""
    autopilot = bare_autopilot(Kind.COPTER, ground=-0.05)  # resting at z = 0.3
    autopilot.rtl_altitude = 0.55  # the RTL height: z = 0.5, exactly 0.2 m above the copter
    autopilot.arm()
    assert autopilot.set_mode("RTL") == ACCEPTED
    assert autopilot.home[2] + autopilot.rtl_altitude - autopilot.body.pose.z == 0.2
    autopilot.step(0.05, -0.05)
    assert [event.text for event in autopilot.events][-1] == "Reached home"


def test_a_copter_knocked_off_its_spot_during_the_rtl_climb_goes_back_to_it(flat_scene):
    """While RTL climbs, the copter holds its spot: pushed off it by a gust it flies back, then goes home."""
    world = armed_copter(flat_scene, start=(2.0, -3.0))
    world.autopilot.goto(12.0, -3.0)
    world.run_for(10.0)
    spot = (world.pose.x, world.pose.y)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    world.run_for(1.0)
    world.body.vx = 3.0  # a gust
    world.run_for(1.0)
    assert math.dist((world.pose.x, world.pose.y), spot) > 1.0
    step_until(world, lambda: math.dist((world.pose.x, world.pose.y), spot) < 0.1, limit=5.0)
    assert world.pose.z < 14.0  # still climbing
    step_until(world, lambda: not world.autopilot.armed, limit=60.0)
    assert math.hypot(world.pose.x - 2.0, world.pose.y + 3.0) < 0.3


def test_rtl_above_rtl_altitude_keeps_its_height_and_rtl_alt_can_be_set(flat_scene):
    world = armed_copter(flat_scene, altitude=6.0)
    world.autopilot.rtl_altitude = 3.0
    world.autopilot.goto(10.0, 0.0)
    world.run_for(10.0)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    world.run_for(2.0)
    assert world.pose.z == pytest.approx(6.0, abs=0.3)  # no climb (nor a descent before home)
    assert not any(text.startswith("RTL: climbing") for text in texts(world))


def test_rtl_announces_its_climb_only_when_more_than_half_a_metre_below_the_rtl_height(make_scene, box):
    """Entering RTL, a copter says it climbs only when the RTL height is more than 0.5 m above it."""
    world = armed_copter(make_scene(box(0, 0, -0.5, 200, 200, 1)))  # its top exactly at 0
    autopilot = world.autopilot
    assert autopilot.home[2] == 0.0
    autopilot.rtl_altitude = world.pose.z + 0.5
    assert autopilot.set_mode("RTL") == ACCEPTED
    assert not any(text.startswith("RTL: climbing") for text in texts(world))
    autopilot.set_mode("GUIDED")
    autopilot.rtl_altitude = world.pose.z + 1.0
    assert autopilot.set_mode("RTL") == ACCEPTED
    assert texts(world)[-1] == f"RTL: climbing to {world.pose.z + 1.0:.0f} m, then home"


def test_rtl_tells_the_height_it_climbs_to_above_the_start_ground(make_scene, box):
    """The climb RTL announces is to RTL_ALT above the start's ground, here on top of a 2 m plinth."""
    scene = make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(0, 0, 1, 6, 6, 2))
    world = armed_copter(scene)
    assert world.home[2] == pytest.approx(2.0)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    assert texts(world)[-1] == "RTL: climbing to 15 m, then home"
    highest = world.pose.z
    for _ in range(round(12.0 / world.dt)):
        world.step()
        highest = max(highest, world.pose.z)
    assert highest == pytest.approx(17.0, abs=0.3)


@pytest.mark.parametrize("kind", [Kind.COPTER, Kind.ROVER])
def test_rtl_goes_home_when_home_is_not_the_scene_origin(flat_scene, kind):
    """Home at (-6, 5): RTL flies there, says so once, and (copter) lands or (rover) holds there."""
    world = vehicle(kind, flat_scene, start=(-6.0, 5.0))
    autopilot = world.autopilot
    assert autopilot.goto(4.0, -3.0) == ACCEPTED
    world.run_for(20.0)
    assert autopilot.set_mode("RTL") == ACCEPTED
    world.run_for(40.0)
    assert (world.pose.x, world.pose.y) == pytest.approx((-6.0, 5.0), abs=0.3)
    assert texts(world).count("Reached home") == 1
    if kind is Kind.COPTER:
        assert not autopilot.armed and texts(world)[-1] == "Landed; disarming"
    else:
        assert autopilot.armed and world.body.speed < 0.01


@pytest.mark.parametrize(
    ("start", "home", "reached_at_once"),
    [
        ((0.0, 0.0), (0.2, 0.0), True),  # within 0.3 m: home
        ((0.0, 0.0), (0.3, 0.0), False),  # exactly 0.3 m: not yet
        ((6.0, 5.0), (-6.0, 5.0), False),  # 12 m west of home
        ((-6.0, -5.0), (-6.0, 5.0), False),  # 10 m south of home
    ],
)
def test_rtl_counts_home_as_reached_within_less_than_0_3_m_of_it(flat_scene, start, home, reached_at_once):
    """RTL takes home as reached as soon as the vehicle is less than 0.3 m from it (x and y), and not before."""
    world = armed_copter(flat_scene, start=start)
    autopilot = world.autopilot
    autopilot.rtl_altitude = 3.0  # below the copter: no climb first
    autopilot.home = (*home, 0.0)
    assert autopilot.set_mode("RTL") == ACCEPTED
    world.step()
    assert ("Reached home" in texts(world)) is reached_at_once
    if not reached_at_once:
        step_until(world, lambda: "Reached home" in texts(world), limit=20.0)
        assert math.dist((world.pose.x, world.pose.y), home) < 0.3


def test_a_stop_before_an_obstacle_is_told_once_with_where(wall_scene):
    world = armed_copter(wall_scene)
    world.autopilot.goto(0.0, 20.0)  # behind the wall
    world.run_for(30.0)
    assert world.autopilot.blocked
    told = [text for text in texts(world) if text.startswith("GUIDED:")]  # not "Go here": an agent's may be held
    assert len(told) == 1, told
    assert "stopped short of (0.0, 20.0)" in told[0]
    distance, x, y = (
        float(v) for v in re.search(r"obstacle ([\d.]+) m ahead at \(([-\d.]+), ([-\d.]+)\)", told[0]).groups()
    )
    assert 0.3 < distance < 2.5 and abs(y - 9.9) < 0.3 and abs(x) < 1.0


def test_a_stop_is_told_again_for_a_new_goal_or_after_leaving_it(wall_scene):
    """Told once per stop: creeping on a few millimetres is the same stop (see above), but held back on the way
    somewhere else, or again after going away, is a new one."""
    world = armed_copter(wall_scene)
    world.autopilot.goto(0.0, 20.0)
    world.run_for(30.0)
    world.autopilot.goto(0.5, 20.0)  # behind the same wall, from the same spot
    world.run_for(5.0)
    world.body.pose.y -= 1.0  # a gust pushes it a metre back; it flies up to the wall again
    world.run_for(10.0)
    told = [text.split("stopped short of ")[-1] for text in texts(world) if text.startswith("GUIDED:")]
    assert told == ["(0.0, 20.0)", "(0.5, 20.0)", "(0.5, 20.0)"], texts(world)


def test_rtl_held_back_by_a_tall_wall_says_so(make_scene, box):
    ground = box(0, 0, -0.5, 200, 200, 1)
    tower = box(0, 10.5, 15, 20, 1, 30)  # 30 m high: above RTL_ALT
    world = armed_copter(make_scene(ground, tower), start=(0.0, 0.0))
    world.autopilot.goto(0.0, 20.0)
    world.run_for(20.0)  # stopped south of the wall
    world.autopilot.home = (0.0, 25.0, 0.0)  # home lies behind it
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    world.run_for(40.0)
    told = [text for text in texts(world) if text.startswith("RTL:") and "cannot reach home" in text]
    assert len(told) == 1 and "obstacle" in told[0], texts(world)
    assert world.collision is None


def test_rtl_flies_home_over_a_wall_it_was_held_back_by_below(wall_scene):
    """Avoidance keeps each echo's height: the 5 m wall that stopped the copter at 4 m does not hold it back
    at RTL's 15 m, so it flies over it home (it used to hover there, saying it could not reach home)."""
    world = armed_copter(wall_scene)
    world.autopilot.goto(0.0, 20.0)
    world.run_for(20.0)
    assert world.autopilot.blocked and world.pose.y < 9.9  # stopped south of the wall, which it saw
    world.autopilot.home = (0.0, 25.0, 0.0)  # home lies behind it
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    step_until(world, lambda: not world.autopilot.armed, limit=90.0)
    assert math.hypot(world.pose.x - 0.0, world.pose.y - 25.0) < 0.3, texts(world)
    assert not [text for text in texts(world) if "cannot reach home" in text]
    assert world.collision is None


def test_remembered_echoes_hold_back_only_within_a_metre_of_the_vehicles_height():
    """An echo 1 m above or below the vehicle still caps its speed towards it; one further away does not."""
    database = ObstacleDatabase(margin=MARGIN, accel=2.5)
    database.add(0.0, 1.5, 4.0, time=0.0)
    capped = math.sqrt(2 * 2.5 * (1.5 - database.body_radius - MARGIN))
    for height in (3.0, 4.0, 5.0):
        assert database.speed_limit(0.0, 0.0, height, 0.0, 2.0, now=1.0) == pytest.approx(capped), height
        assert database.obstacle_ahead(0.0, 0.0, height, 0.0, 2.0, now=1.0)[0] == pytest.approx(1.5), height
    for height in (2.99, 5.01, 15.0):
        assert database.speed_limit(0.0, 0.0, height, 0.0, 2.0, now=1.0) == math.inf, height
        assert database.obstacle_ahead(0.0, 0.0, height, 0.0, 2.0, now=1.0) is None, height


def test_an_echo_within_the_margin_beside_the_vehicle_holds_back_only_moving_towards_it():
    """A vehicle stopped with an echo right beside it, inside its margin (a rover by a kerb), may move past it
    or away; only moving towards it is held back. It used to be held back in every direction with the least
    bit of "ahead" in it, and stood there for good."""
    database = ObstacleDatabase(margin=MARGIN, accel=2.5)
    database.add(0.35, 0.02, 0.0, time=0.0)  # 0.35 m east, inside body radius + margin (0.4 m), a little north
    for vx, vy in ((0.0, 2.0), (-2.0, 0.0), (-1.0, 1.0), (0.0, -2.0)):  # past it to the north or south, away
        assert database.speed_limit(0.0, 0.0, 0.0, vx, vy, now=1.0) == math.inf, (vx, vy)
        assert database.obstacle_ahead(0.0, 0.0, 0.0, vx, vy, now=1.0) is None, (vx, vy)
    for vx, vy in ((2.0, 0.0), (1.0, 1.0), (1.0, -1.0)):  # towards it
        assert database.speed_limit(0.0, 0.0, 0.0, vx, vy, now=1.0) == 0.0, (vx, vy)
        assert database.obstacle_ahead(0.0, 0.0, 0.0, vx, vy, now=1.0)[1:] == (0.35, 0.02), (vx, vy)


def test_an_echo_the_corridor_only_grazes_holds_nothing_back():
    """Passing an echo that comes no more than GRAZE inside the margin is free; one further inside caps the
    speed so the vehicle stops a margin short of it."""
    corridor = 0.3 + MARGIN
    database = ObstacleDatabase(margin=MARGIN, accel=2.5, body_radius=0.3)
    database.add(corridor - GRAZE + 0.005, 1.5, 0.0, time=0.0)
    assert database.speed_limit(0.0, 0.0, 0.0, 0.0, 2.0, now=1.0) == math.inf
    database.add(corridor - GRAZE - 0.005, 1.5, 0.0, time=0.0)
    capped = math.sqrt(2 * 2.5 * (1.5 - corridor))
    assert database.speed_limit(0.0, 0.0, 0.0, 0.0, 2.0, now=1.0) == pytest.approx(capped)
    assert database.obstacle_ahead(0.0, 0.0, 0.0, 0.0, 2.0, now=1.0)[1] == corridor - GRAZE - 0.005


def test_rtl_rover_returns_home_and_holds(flat_scene):
    world = armed_rover(flat_scene, start=(2.0, -3.0))
    world.autopilot.goto(15.0, 5.0)
    world.run_for(15.0)
    assert world.autopilot.set_mode("RTL") == ACCEPTED
    world.run_for(30.0)
    assert math.hypot(world.pose.x - 2.0, world.pose.y + 3.0) < 0.3
    assert world.body.speed < 0.01
    assert world.autopilot.armed


def test_a_rover_knocked_off_home_after_rtl_stops_near_it_and_stays_armed(flat_scene):
    """A rover that reached home holds there: pushed on past it, it stops (it cannot back up) and stays armed."""
    world = armed_rover(flat_scene, start=(2.0, -3.0))
    world.autopilot.goto(2.0, 10.0)
    world.run_for(10.0)
    world.autopilot.set_mode("RTL")
    step_until(world, lambda: "Reached home" in texts(world), limit=30.0)
    world.run_for(3.0)
    heading = world.pose.yaw
    world.body.vx, world.body.vy = 2.0 * math.sin(heading), 2.0 * math.cos(heading)  # a shove forwards
    world.run_for(5.0)
    assert world.body.speed < 0.01 and world.autopilot.armed
    assert 0.15 < math.hypot(world.pose.x - 2.0, world.pose.y + 3.0) < 1.0


def test_land_mode_lands_in_place_and_disarms(flat_scene):
    world = armed_copter(flat_scene)
    world.autopilot.goto(5.0, 5.0)
    world.run_for(10.0)
    here = (world.pose.x, world.pose.y)
    assert world.autopilot.set_mode("LAND") == ACCEPTED
    took = step_until(world, lambda: not world.autopilot.armed, limit=15.0)
    world.run_for(1.0)
    assert took == pytest.approx((ALTITUDE - REST_Z) / 0.7, abs=0.5)  # at the landing speed
    assert (world.pose.x, world.pose.y) == pytest.approx(here, abs=0.05)
    assert world.pose.z == pytest.approx(REST_Z, abs=0.01)


def test_land_during_takeoff_descends_at_once(flat_scene):
    world = taking_off(flat_scene)
    z = world.pose.z
    world.autopilot.set_mode("LAND")
    world.run_for(1.0)
    assert world.pose.z < z  # it used to climb on to 10 m first


def test_land_engaged_at_speed_comes_back_to_where_it_was_engaged_and_lands_there(flat_scene):
    """LAND holds the spot where it was engaged: a copter still braking from cruise speed flies back to it
    (without turning round first) while it descends, and is disarmed on touching down."""
    world = armed_copter(flat_scene)
    world.autopilot.goto(0.0, 60.0)
    world.run_for(10.0)
    assert world.body.speed == pytest.approx(2.5)
    here = (world.pose.x, world.pose.y)
    assert world.autopilot.set_mode("LAND") == ACCEPTED
    step_until(world, lambda: not world.autopilot.armed, limit=15.0)
    assert math.dist((world.pose.x, world.pose.y), here) < 0.1  # braking had carried it 1.2 m on
    assert world.autopilot.armed is False and texts(world)[-1] == "Landed; disarming"


@pytest.mark.parametrize(
    ("kind", "mode"), [(Kind.COPTER, "BRAKE"), (Kind.COPTER, "LOITER"), (Kind.ROVER, "HOLD"), (Kind.ROVER, "LOITER")]
)
def test_stop_modes_stop_in_place(kind, mode, flat_scene):
    world = vehicle(kind, flat_scene)
    world.autopilot.goto(0.0, 60.0)
    world.run_for(10.0)
    speed = world.body.speed
    assert speed == pytest.approx(2.5)
    stopped_at = world.pose.xyz()
    assert world.autopilot.set_mode(mode) == ACCEPTED
    braking = speed * speed / (2 * world.limits.accel)
    for _ in range(round(10.0 / world.dt)):
        world.step()
        assert math.dist(world.pose.xyz(), stopped_at) < braking + 0.2
    resting = world.pose.xyz()
    world.run_for(10.0)
    assert world.pose.xyz() == pytest.approx(resting, abs=1e-3)
    assert world.body.speed < 1e-3
    assert world.autopilot.armed


def test_brake_during_takeoff_stops_the_climb(flat_scene):
    world = taking_off(flat_scene)
    z = world.pose.z
    world.autopilot.set_mode("BRAKE")
    world.run_for(5.0)
    assert world.pose.z < z + 1.0  # it used to climb on to the take-off altitude


def test_rover_hold_stops_without_turning_around(flat_scene):
    world = Simulation(flat_scene, Kind.ROVER)
    world.autopilot.arm()
    world.autopilot.set_mode("GUIDED")
    world.autopilot.goto(0.0, 60.0)
    world.run_for(10.0)
    world.autopilot.set_mode("HOLD")
    world.run_for(10.0)
    assert abs(math.degrees(world.pose.yaw) % 360 - 0.0) < 10  # it used to U-turn back to the hold point


def test_copter_brake_holds_where_it_came_to_rest(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, sensors=[Sonar(mount_yaw=180)])
    world.autopilot.arm()
    world.autopilot.takeoff(4.0)
    world.run_for(6.0)
    world.autopilot.goto(0.0, 60.0)
    world.run_for(10.0)
    world.autopilot.set_mode("BRAKE")
    furthest = 0.0
    for _ in range(200):
        world.step()
        furthest = max(furthest, world.pose.y)
    assert world.pose.y == pytest.approx(furthest, abs=0.05)  # it used to fly back to where BRAKE was engaged


def test_disarm_refused_in_the_air_unless_forced(flat_scene):
    world = armed_copter(flat_scene)
    assert world.autopilot.disarm() == FAILED
    assert world.autopilot.armed
    assert world.autopilot.disarm(force=True) == ACCEPTED
    assert not world.autopilot.armed


def test_disarm_on_the_ground_is_accepted(flat_scene):
    world = armed_rover(flat_scene)
    assert world.autopilot.disarm() == ACCEPTED
    assert not world.autopilot.armed


def test_disarming_ends_the_mission_and_the_take_off_it_was_in(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.arm()
    autopilot.takeoff(4.0)
    world.run_for(0.5)  # climbing
    autopilot.set_mode("AUTO")
    autopilot.set_mission([autopilot.home_item(), position_item(world, NAV_WAYPOINT, 3.0, 0.0)])
    autopilot.start_mission()
    assert autopilot.disarm(force=True) == ACCEPTED
    assert autopilot.armed is False and autopilot.mission_running is False
    world.run_for(3.0)  # falls to the ground
    autopilot.set_mode("GUIDED")
    assert autopilot.arm() == ACCEPTED
    world.run_for(5.0)
    assert world.pose.z == pytest.approx(REST_Z, abs=0.01)  # armed again, it does not resume the old take-off


def test_a_forced_disarm_ends_the_take_off(flat_scene):
    """Disarmed during a GUIDED take-off, a copter no longer counts as taking off."""
    world = Simulation(flat_scene, Kind.COPTER)
    autopilot = world.autopilot
    autopilot.arm()
    autopilot.takeoff(4.0)
    world.run_for(0.5)
    assert autopilot.taking_off is True
    assert autopilot.disarm(force=True) == ACCEPTED
    assert autopilot.taking_off is False


def test_forced_disarm_in_the_air_makes_a_copter_fall_to_the_ground(flat_scene):
    world = armed_copter(flat_scene)
    world.autopilot.disarm(force=True)
    heights = []
    for _ in range(round(2.0 / world.dt)):
        world.step()
        heights.append(world.pose.z)
    assert all(b <= a for a, b in zip(heights, heights[1:], strict=False))
    fall_time = math.sqrt(2 * (ALTITUDE - REST_Z) / 9.81)  # free fall: 0.86 s
    landed = next(i for i, z in enumerate(heights) if z <= REST_Z + 1e-6) * world.dt
    assert landed == pytest.approx(fall_time, abs=0.1)
    assert heights[-1] == pytest.approx(REST_Z)
    assert not world.autopilot.flying


def test_a_disarmed_copter_within_a_micrometre_of_its_resting_height_is_left_resting():
    """A disarmed copter falls only when more than 1 micrometre above its resting height (that tolerance
    absorbs rounding); at exactly 1 micrometre it is not dropped, at 2 it falls onto the ground."""
    autopilot = bare_autopilot(Kind.COPTER)
    body = autopilot.body
    rest = body.rest_height(0.0)
    body.pose.z = rest + 1e-6
    for _ in range(20):
        autopilot.step(0.05, 0.0)
    assert body.pose.z == rest + 1e-6 and body.vz == 0.0
    body.pose.z = rest + 2e-6
    autopilot.step(0.05, 0.0)
    assert body.pose.z == rest


def test_a_copter_killed_on_its_way_and_armed_again_stays_on_the_ground_until_a_take_off(flat_scene):
    """Armed again after a kill, the copter took off by itself and flew on to the target it had been given
    before (the operator pressed Arm, and it left). Arming drops old targets, and as in ArduCopter's GUIDED a
    copter on the ground leaves it only by a take-off."""
    world = armed_copter(flat_scene)
    assert world.autopilot.goto(20.0, 0.0, ALTITUDE) == ACCEPTED
    world.run_for(2.0)
    world.autopilot.disarm(force=True)
    world.run_for(3.0)  # it fell
    fallen = world.pose.xyz()
    assert world.autopilot.arm() == ACCEPTED
    world.run_for(5.0)
    assert world.pose.xyz() == pytest.approx(fallen, abs=1e-3) and not world.autopilot.flying
    assert world.autopilot.takeoff(ALTITUDE) == ACCEPTED
    world.run_for(ALTITUDE / world.limits.climb_rate + 3.0)
    assert world.pose.z == pytest.approx(ALTITUDE, abs=0.15) and world.pose.x == pytest.approx(fallen[0])


def test_rearming_after_a_forced_disarm_during_takeoff_stays_on_the_ground(flat_scene):
    world = taking_off(flat_scene)
    world.autopilot.disarm(force=True)
    world.run_for(3.0)  # falls back to the ground
    world.autopilot.arm()  # no take-off command
    world.run_for(5.0)
    assert world.pose.z == pytest.approx(0.35, abs=0.01)  # it used to take off by itself


def test_a_guided_target_does_not_lift_a_copter_off_the_ground(flat_scene):
    """As in ArduCopter: a position or velocity target given on the ground waits for a take-off."""
    world = Simulation(flat_scene, Kind.COPTER)
    assert world.autopilot.arm() == ACCEPTED
    assert world.autopilot.goto(5.0, 5.0, ALTITUDE) == ACCEPTED
    world.run_for(5.0)
    assert world.autopilot.set_velocity(1.0, 0.0, 1.0) == ACCEPTED
    world.run_for(1.0)
    assert world.pose.xyz() == pytest.approx((0.0, 0.0, REST_Z), abs=1e-3) and not world.autopilot.flying


# ---- the battery ----------------------------------------------------------------------------------------
def test_a_low_battery_is_said_and_a_critical_one_lands_a_copter_as_the_failsafe(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, start=(0.0, 0.0))
    world.autopilot.arm()
    world.autopilot.takeoff(ALTITUDE)
    world.run_for(10.0)
    battery = world.battery
    battery.charge_mah = 0.2 * battery.capacity_mah + 1.0  # just above the low level
    world.run_for(1.0)
    assert texts(world)[-1] == "Battery 1 is low: 14.8 V, 20% left" and world.autopilot.mode == "GUIDED"
    said = len(texts(world))
    battery.charge_mah = 0.1 * battery.capacity_mah + 1.0
    world.run_for(1.0)
    assert texts(world)[said:] == ["Battery 1 is critical: 14.4 V, 10% left; battery failsafe: LAND"]  # once each
    assert (world.autopilot.mode, world.autopilot.mode_source) == ("LAND", "failsafe")
    step_until(world, lambda: not world.autopilot.armed, limit=30.0)  # landed, and disarmed
    assert world.pose.z == pytest.approx(REST_Z, abs=0.05)
    world.autopilot.set_mode("GUIDED")
    assert world.autopilot.arm() == FAILED and texts(world)[-1] == "Arm: Battery 1 critical"  # not up again
    assert world.autopilot.arm(force=True) == ACCEPTED  # but for a forced arm, as on ArduPilot


def test_a_rover_holds_at_a_critical_battery_and_one_on_the_ground_is_only_warned(flat_scene):
    rover = Simulation(flat_scene, Kind.ROVER)
    rover.autopilot.arm()
    rover.autopilot.set_mode("GUIDED")
    rover.battery.charge_mah = 0.1 * rover.battery.capacity_mah  # past both levels at once: one alarm, critical
    rover.step()
    assert texts(rover)[-1].endswith("; battery failsafe: HOLD") and rover.autopilot.mode == "HOLD"
    parked = Simulation(flat_scene, Kind.COPTER)
    parked.battery.charge_mah = 0.05 * parked.battery.capacity_mah
    parked.step()
    assert texts(parked)[-1] == "Battery 1 is critical: 14.0 V, 5% left" and parked.autopilot.mode == "GUIDED"


# ---- servos and a ground station's direct steering ---------------------------------------------


@pytest.mark.parametrize(
    ("channel", "pwm", "result"),
    [
        (1, 500, ACCEPTED),
        (32, 2500, ACCEPTED),
        (9, 1500, ACCEPTED),
        (0, 1500, DENIED),
        (33, 1500, DENIED),
        (1, 499, DENIED),
        (1, 2501, DENIED),
    ],
)
def test_a_servo_takes_channels_1_to_32_and_pulses_of_500_to_2500_microseconds(flat_scene, channel, pwm, result):
    autopilot = Simulation(flat_scene, Kind.ROVER).autopilot
    assert autopilot.set_servo(channel, pwm) == result
    assert autopilot.servos.get(channel) == (pwm if result == ACCEPTED else None)
    assert type(autopilot.servos.get(channel)) is (int if result == ACCEPTED else type(None))


def test_direct_steering_by_a_ground_station_is_counted(flat_scene):
    autopilot = Simulation(flat_scene, Kind.ROVER).autopilot
    assert (autopilot.overrides, autopilot.override) == (0, "")
    autopilot.overridden("goto")
    autopilot.overridden("yaw")
    assert (autopilot.overrides, autopilot.override) == (2, "yaw")
    autopilot.clear_targets()
    assert (autopilot._target, autopilot._velocity, autopilot._yaw) == (None, None, None)


# ---- ground following, determinism, avoidance ----------------------------------------------------


@pytest.fixture
def hill_scene(make_scene):
    """An ElevationGrid: flat at z = 0 for x < 0, rising 0.2 m per m eastwards to z = 2 at x = 10, then flat."""
    xs = np.arange(-20, 21)
    heights = np.clip(xs * 0.2, 0.0, 2.0)
    values = " ".join(f"{h:g}" for h in np.tile(heights, 5))
    return make_scene(
        "Transform { translation -20 10 0 rotation 1 0 0 1.5708 children Shape { geometry ElevationGrid {"
        f" xDimension 41 zDimension 5 xSpacing 1 zSpacing 5 height [ {values} ] }} }} }}\n"
    )


def test_rover_follows_uneven_ground(hill_scene):
    world = armed_rover(hill_scene, start=(-8.0, 0.0))
    caster = world.caster
    world.autopilot.goto(16.0, 0.0)
    samples = []
    for _ in range(round(20.0 / world.dt)):
        world.step()
        ground = caster.ground_height(world.pose.x, world.pose.y)
        assert world.pose.z - ground == pytest.approx(REST_Z, abs=0.05)
        samples.append((world.pose.x, world.pose.pitch))
    assert world.collision is None
    assert world.pose.x == pytest.approx(16.0, abs=0.2)
    assert world.pose.z == pytest.approx(2.0 + REST_Z, abs=0.01)
    climbing = [pitch for x, pitch in samples if 1.0 < x < 9.0]
    assert climbing and all(p == pytest.approx(math.atan(0.2), abs=1e-3) for p in climbing)  # nose up
    world.autopilot.goto(-8.0, 0.0)
    descending = []
    for _ in range(round(25.0 / world.dt)):
        world.step()
        if 1.0 < world.pose.x < 9.0:
            descending.append(world.pose.pitch)
    assert descending and all(p == pytest.approx(-math.atan(0.2), abs=1e-3) for p in descending)  # nose down
    assert world.pose.z == pytest.approx(REST_Z, abs=0.01)


def test_a_disarmed_rover_rests_tilted_with_the_slope_it_stands_on(hill_scene):
    """Disarmed, a rover still settles on the ground under it: on a 0.2 slope it is pitched nose up."""
    world = Simulation(hill_scene, Kind.ROVER, start=(5.0, 0.0), heading=90.0)  # facing up the slope
    world.step()
    assert not world.autopilot.armed
    assert world.pose.pitch == pytest.approx(math.atan(0.2), abs=1e-3)
    assert world.pose.roll == pytest.approx(0.0, abs=1e-3)


def test_copter_holds_height_above_the_start_ground_over_a_hill(hill_scene):
    world = armed_copter(hill_scene, start=(-8.0, 0.0))
    world.autopilot.goto(16.0, 0.0)
    world.run_for(20.0)
    assert world.pose.x == pytest.approx(16.0, abs=0.2)
    assert world.pose.z == pytest.approx(ALTITUDE, abs=0.2)  # does not follow the terrain


def trajectory(scene) -> list[tuple]:
    sensors = [Sonar("front", noise=0.05), Sonar("right", mount_yaw=60.0, noise=0.05)]
    world = Simulation(scene, Kind.COPTER, seed=7, sensors=sensors)
    world.autopilot.arm()
    world.autopilot.takeoff(3.0)
    out = []
    for target in ((6.0, 8.0), (-7.0, 2.0)):
        world.run_for(4.0)
        world.autopilot.goto(*target)
        for _ in range(200):
            readings = world.step()
            out.append(
                (
                    *world.pose.xyz(),
                    world.pose.yaw,
                    world.pose.pitch,
                    world.pose.roll,
                    tuple(r.distance for r in readings),
                )
            )
    return out


def test_two_identical_runs_give_identical_trajectories(wall_scene):
    first, second = trajectory(wall_scene), trajectory(wall_scene)
    assert first == second
    assert any(d is not None for *_, distances in first for d in distances)  # the sonars saw the wall


def test_a_world_without_sensors_steps(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, sensors=[])
    assert world.step() == []  # ValueError: need at least one array to concatenate (vehicle/sensors.py:124)


def test_a_copter_flown_at_a_wall_stops_short_of_it_with_the_default_sensors(wall_scene):
    world = armed_copter(wall_scene)
    world.autopilot.goto(0.0, 20.0)  # behind the wall
    world.run_for(30.0)
    assert world.collision is None
    assert world.autopilot.blocked
    assert world.body.speed < 0.01
    assert 8.0 < world.pose.y < 9.9 - world.limits.radius


def test_a_copter_flown_at_a_wall_keeps_cruise_speed_until_it_must_brake_and_is_blocked_only_once_stopped(
    wall_scene,
):
    """Avoidance caps the speed so the copter can still stop short, allowing one step of reaction time only:
    it flies on at cruise speed until about 2 m from the wall, and counts as blocked only when (nearly) stopped."""
    world = armed_copter(wall_scene)
    world.autopilot.goto(0.0, 20.0)
    speed_at_8 = None
    for _ in range(round(30.0 / world.dt)):
        world.step()
        if speed_at_8 is None and world.pose.y >= 8.0:
            speed_at_8 = world.body.speed
        if world.autopilot.blocked:
            assert world.body.speed < 0.3, f"blocked at {world.body.speed:.2f} m/s, y = {world.pose.y:.2f}"
    assert speed_at_8 == pytest.approx(2.5)  # 1.9 m before the wall
    assert world.autopilot.blocked and world.body.speed < 0.01
    assert world.pose.y > 9.3


def test_a_copter_flown_diagonally_at_a_wall_stops_short_of_it(wall_scene):
    world = armed_copter(wall_scene, start=(-6.0, 0.0))
    world.autopilot.set_speed(4.0)
    world.autopilot.goto(6.0, 16.0)
    world.run_for(30.0)
    assert world.collision is None
    assert world.pose.y < 9.9 - world.limits.radius


@pytest.mark.parametrize(
    ("wall", "target"), [((0, 10, 2, 20, 0.2, 6), (0.0, 20.0)), ((10, 0, 2, 0.2, 20, 6), (20.0, 0.0))]
)
def test_a_fast_head_on_approach_stops_the_avoidance_margin_short_of_the_wall(make_scene, box, wall, target):
    """At 4 m/s straight at a wall to the north or to the east, the speed cap (with its reaction time for the
    speed in either direction) stops the copter at least the avoidance margin short of the wall."""
    world = armed_copter(make_scene(box(0, 0, -0.05, 200, 200, 0.1), box(*wall)))
    world.autopilot.set_speed(4.0)
    world.autopilot.goto(*target)
    nearest = math.inf
    for _ in range(round(20.0 / world.dt)):
        world.step()
        nearest = min(nearest, 9.9 - max(world.pose.x, world.pose.y) - world.limits.radius)
    assert world.collision is None
    assert MARGIN <= nearest < MARGIN + 0.1


def test_an_autopilot_without_an_obstacle_database_drives_unhindered():
    """An Autopilot built without ``avoidance`` (its default) steers without any speed limit from obstacles."""
    autopilot = bare_autopilot(Kind.ROVER)
    assert autopilot.avoidance is None
    autopilot.arm()
    autopilot.set_mode("GUIDED")
    assert autopilot.goto(0.0, 10.0) == ACCEPTED
    for _ in range(400):  # 20 s
        autopilot.step(0.05, 0.0)
    assert (autopilot.body.pose.x, autopilot.body.pose.y) == pytest.approx((0.0, 10.0), abs=0.15)
    assert autopilot.blocked is False


def creeping_rover(flat_scene, speed: float) -> Simulation:
    """A rover at rest at the origin facing north, with one remembered echo ahead placed so that avoidance
    caps its speed northwards at exactly ``speed`` (its acceleration is chosen to make that exact)."""
    gap = 2.0**-10  # m between the body (radius and margin) and the echo
    limits = Limits(accel=speed * speed / (2 * gap))  # sqrt(2 * accel * gap) == speed
    world = armed_rover(flat_scene, limits=limits)
    avoidance = world.avoidance
    corridor = avoidance.body_radius + avoidance.margin
    assert (corridor + gap) - corridor == gap and math.sqrt(2 * avoidance.accel * gap) == speed
    avoidance.add(0.0, corridor + gap, world.pose.z, world.time)
    assert world.body.speed == 0.0 and world.pose.yaw == 0.0
    return world


def test_asking_for_exactly_the_speed_that_still_stops_short_is_not_held_back(flat_scene):
    """Avoidance slows a vehicle only when it asks for more than it can still stop at: asking for exactly
    that speed (here 0.04 m/s) it is not held back."""
    world = creeping_rover(flat_scene, 0.04)
    assert world.autopilot.set_velocity(0.0, 0.04) == ACCEPTED
    world.step()
    assert world.autopilot.blocked is False
    assert world.body.vy == pytest.approx(0.04)


def test_a_vehicle_held_back_to_0_05_m_s_is_not_yet_blocked(flat_scene):
    """A vehicle counts as blocked only when avoidance lets it move at less than 0.05 m/s: at exactly
    0.05 m/s it still moves and is not blocked."""
    world = creeping_rover(flat_scene, 0.05)
    assert world.autopilot.set_velocity(0.0, 1.0) == ACCEPTED
    world.step()
    assert world.autopilot.blocked is False
    assert world.body.vy == pytest.approx(0.05)
