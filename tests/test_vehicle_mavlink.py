"""The simulated vehicle as a standard ground station sees it: real UDP sockets, real MAVLink bytes.

Each test starts ``vehicle sim``'s SimVehicle on a thread, sending to a port
the test's own pymavlink connection listens on, and talks to it as MAVProxy
or QGroundControl would. Waits are bounded in the vehicle's simulated time.
"""

from __future__ import annotations

import math
import random
import socket
from contextlib import contextmanager

import numpy as np
import pytest
from harness import RunningSim, free_tcp_port, free_udp_port, wait_wall
from mavlink_peer import Gcs

from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.protocol.mapstream import MAP_DELTA, MapReceiver
from vehicle.protocol.mav import COMPANION, mavlink, mavutil
from vehicle.protocol.modes import Kind
from vehicle.protocol.tlog import TlogWriter
from vehicle.sim.endpoint import Endpoint
from vehicle.sim.simulation import Simulation
from vehicle.sim.telemetry import Telemetry
from vehicle.world.scene import parse_scene

ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
WALL_Y = 8.0  # the south face of a wall north of the start

SCENE = f"""#VRML V2.0 utf8
Transform {{ translation 0 0 -0.5 children Shape {{ geometry Box {{ size 80 80 1 }} }} }}
Transform {{ translation 0 {WALL_Y + 0.25} 3 children Shape {{ geometry Box {{ size 20 0.5 6 }} }} }}
"""


@pytest.fixture(scope="module")
def scene():
    return parse_scene(SCENE)


def make_vehicle(scene, kind="copter", mission="browse", autostart=False, settings=None):
    return simulate(scene, mission, kind, settings or Settings(space_size=20), autostart=autostart)


@pytest.fixture
def fly(scene):
    """Start a vehicle and a GCS; yields (gcs, sim). Options: kind, mission, autostart, speedup, ..."""
    running = []

    def start(kind="copter", mission="browse", autostart=False, speedup=10.0, settings=None, **options):
        port = free_udp_port()
        gcs = Gcs(f"udpin:127.0.0.1:{port}", speedup=speedup)
        runner = RunningSim(
            make_vehicle(scene, kind, mission, autostart, settings),
            [f"udpout:127.0.0.1:{port}"],
            speedup=speedup,
            **options,
        )
        sim = runner.__enter__()
        running.append((runner, gcs))
        gcs.wait("HEARTBEAT")
        gcs.heartbeat()  # now that it knows where the vehicle is: the vehicle obeys ground stations it heard
        return gcs, sim

    yield start
    for runner, gcs in running:
        runner.__exit__(None, None, None)
        gcs.close()


def take_off(gcs, altitude=4.0):
    assert gcs.set_mode(4) == mavlink.MAV_RESULT_ACCEPTED  # copter GUIDED
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > (altitude - 0.2) * 1000, sim_timeout=20)


# ---- identity and telemetry ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kind", "mav_type", "mode"),
    [("copter", mavlink.MAV_TYPE_QUADROTOR, 4), ("rover", mavlink.MAV_TYPE_GROUND_ROVER, 4)],
)
def test_heartbeat_looks_like_ardupilot(fly, kind, mav_type, mode):
    gcs, _ = fly(kind)
    beat = gcs.wait("HEARTBEAT")
    assert beat.type == mav_type
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert beat.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not beat.base_mode & ARMED
    assert beat.custom_mode == mode  # copter spawns in GUIDED (4), rover in HOLD (4)


def test_pose_comes_twenty_times_per_heartbeat(fly):
    gcs, _ = fly()
    counts = {"HEARTBEAT": 0, "GLOBAL_POSITION_INT": 0, "ATTITUDE": 0, "LOCAL_POSITION_NED": 0}
    gcs.wait("HEARTBEAT")
    while counts["HEARTBEAT"] < 3:
        message = gcs.recv()
        if message is not None and message.get_type() in counts:
            counts[message.get_type()] += 1
    for kind in ("GLOBAL_POSITION_INT", "ATTITUDE", "LOCAL_POSITION_NED"):
        assert 45 <= counts[kind] <= 75, counts  # 20 Hz against 1 Hz heartbeats, both on the wall clock


def test_message_interval_and_request_message(fly):
    gcs, _ = fly()
    ok = mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 500_000) == ok
    gcs.wait("HEARTBEAT")
    attitudes = beats = 0
    while beats < 3:
        message = gcs.recv()
        kind = message.get_type() if message is not None else None
        beats += kind == "HEARTBEAT"
        attitudes += kind == "ATTITUDE"
    assert 4 <= attitudes <= 8  # 2 Hz
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == ok
    version = gcs.wait("AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert gcs.command(mavlink.MAV_CMD_GET_HOME_POSITION) == ok
    home = gcs.wait("HOME_POSITION")
    assert home.latitude == pytest.approx(-353632610, abs=2)
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 9999) == mavlink.MAV_RESULT_UNSUPPORTED


def test_sys_status_reports_health_and_a_battery_that_drains(fly):
    gcs, _ = fly()
    first = gcs.wait("SYS_STATUS")
    assert first.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_GEOFENCE
    assert first.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
    take_off(gcs)
    later = gcs.wait("SYS_STATUS", lambda m: m.voltage_battery < first.voltage_battery, sim_timeout=120)
    assert later.current_battery > 500  # > 5 A in the air


def test_distance_sensor_matches_the_geometry(fly):
    gcs, sim = fly()
    take_off(gcs)
    # face north and stay (an operator's yaw also pauses the onboard mission, which would turn it)
    assert gcs.command(mavlink.MAV_CMD_CONDITION_YAW, 0, 90, 1, 0) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait("ATTITUDE", lambda m: abs(m.yaw) < 0.005 and abs(m.yawspeed) < 1e-3, sim_timeout=20)
    sensor = gcs.wait("DISTANCE_SENSOR", lambda m: m.id == 0 and m.orientation == 0)
    position = gcs.wait("LOCAL_POSITION_NED")
    assert sensor.type == mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND
    assert sensor.current_distance / 100 == pytest.approx(WALL_Y - position.x, abs=0.1)
    side = gcs.wait("DISTANCE_SENSOR", lambda m: m.id == 1)
    assert side.orientation == 7  # 45 degrees left: MAV_SENSOR_ROTATION_YAW_315
    # the nearest echo in a 7.5-degree cone turned 45 degrees from the wall's normal
    gap = WALL_Y - position.x
    assert gap / math.cos(math.radians(37.5)) - 0.1 <= side.current_distance / 100 <= gap * math.sqrt(2) + 0.1


# ---- commands -------------------------------------------------------------------------------------
def test_mode_changes_are_acknowledged_and_reported(fly):
    gcs, _ = fly()
    for number in (5, 17, 4):  # LOITER, BRAKE, GUIDED
        assert gcs.set_mode(number) == mavlink.MAV_RESULT_ACCEPTED
        gcs.wait_mode(number)
    assert gcs.set_mode(99) == mavlink.MAV_RESULT_UNSUPPORTED
    gcs.mav.set_mode_send(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)  # legacy SET_MODE
    gcs.wait_mode(5)


def test_unknown_command_is_unsupported_not_silent(fly):
    gcs, _ = fly()
    assert gcs.command(31010) == mavlink.MAV_RESULT_UNSUPPORTED


def test_a_command_the_onboard_agent_does_not_take_is_unsupported_not_silent(fly):
    gcs, _ = fly()
    for command in (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 31010):
        gcs.heartbeat()
        gcs.mav.command_long_send(1, 191, command, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = gcs.wait("COMMAND_ACK", lambda m, c=command: m.command == c, component=191)
        assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED


def test_take_off_then_rtl_lands_at_home_and_disarms(fly):
    gcs, _ = fly()
    take_off(gcs)
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0b110111111000, 4.0, -5.0, -4.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    gcs.wait("LOCAL_POSITION_NED", lambda m: abs(m.x - 4) < 0.3 and abs(m.y + 5) < 0.3, sim_timeout=30)
    assert gcs.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait_mode(6)
    gcs.wait("HEARTBEAT", lambda m: not m.base_mode & ARMED, sim_timeout=60)
    home = gcs.wait("LOCAL_POSITION_NED")
    assert math.hypot(home.x, home.y) < 0.5


def test_force_disarm_in_the_air(fly):
    gcs, _ = fly()
    take_off(gcs)
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mavlink.MAV_RESULT_FAILED  # flying
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait("HEARTBEAT", lambda m: not m.base_mode & ARMED)
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt < 500, sim_timeout=10)  # it falls


def test_reposition_in_guided(fly):
    gcs, sim = fly()
    take_off(gcs)
    lat, lon = sim.world.datum.to_global(-6.0, 3.0)
    gcs.mav.command_int_send(
        1,
        1,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_CMD_DO_REPOSITION,
        0,
        0,
        -1,
        0,
        0,
        0,
        int(lat * 1e7),
        int(lon * 1e7),
        5.0,
    )
    ack = gcs.wait("COMMAND_ACK", lambda m: m.command == mavlink.MAV_CMD_DO_REPOSITION)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait(
        "LOCAL_POSITION_NED", lambda m: abs(m.x - 3) < 0.3 and abs(m.y + 6) < 0.3 and abs(m.z + 5) < 0.3, sim_timeout=30
    )


def test_rover_abort_is_hold(fly):
    gcs, _ = fly("rover")
    assert gcs.set_mode(15) == mavlink.MAV_RESULT_ACCEPTED  # GUIDED
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0b110111111000, -10.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    gcs.wait("VFR_HUD", lambda m: m.groundspeed > 1.0, sim_timeout=20)
    assert gcs.set_mode(4) == mavlink.MAV_RESULT_ACCEPTED  # HOLD
    gcs.wait("VFR_HUD", lambda m: m.groundspeed < 0.05, sim_timeout=10)


# ---- the onboard mission and the operator --------------------------------------------------------
def test_arm_auto_and_mission_start_start_the_onboard_mission(fly):
    gcs, _ = fly(mission="browse")
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.set_mode(3) == mavlink.MAV_RESULT_ACCEPTED  # AUTO
    assert gcs.command(mavlink.MAV_CMD_MISSION_START) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait_text("browse: start", sim_timeout=20)
    gcs.wait_text("browse: finished", sim_timeout=120)


def test_a_plain_autopilot_refuses_auto_without_a_mission_as_ardupilot_does(fly):
    """With no agent on board, AUTO needs items to fly (the all-in-one vehicle's agent takes AUTO as its start)."""
    gcs, _ = fly("rover", mission=None)
    assert gcs.set_mode(10) == mavlink.MAV_RESULT_FAILED  # AUTO
    gcs.wait_text("No Mission. Can't set AUTO.")
    gcs.wait_text("Flight mode change failed")
    assert gcs.wait("HEARTBEAT").custom_mode == 4  # still HOLD


def test_operator_takeover_pauses_and_resume_continues(fly):
    gcs, sim = fly(mission="browse", autostart=True)
    gcs.wait_text("browse: start", sim_timeout=20)
    assert gcs.set_mode(17) == mavlink.MAV_RESULT_ACCEPTED  # BRAKE
    gcs.wait_text("paused")
    heading = gcs.wait("ATTITUDE").yaw
    sim_then = gcs.sim_time
    still = gcs.wait("ATTITUDE", lambda m: gcs.sim_time > sim_then + 5, sim_timeout=10)
    assert still.yaw == pytest.approx(heading, abs=0.05)  # the scan stopped while paused
    assert gcs.set_mode(3) == mavlink.MAV_RESULT_ACCEPTED  # AUTO
    assert gcs.command(mavlink.MAV_CMD_MISSION_START) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait_text("resuming")
    gcs.wait_text("browse: finished", sim_timeout=120)


def test_gcs_failsafe_returns_a_copter_home_and_obeys_again(fly):
    gcs, _ = fly(failsafe_timeout=2.0)
    take_off(gcs)
    assert gcs.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED  # LOITER: the operator holds it, the agent pauses
    gcs.wait_mode(5)
    mark = len(gcs.texts)
    gcs.wait_text("GCS failsafe", since=mark, heartbeats=False, sim_timeout=60)
    gcs.wait_mode(6)  # RTL
    gcs.wait_text("cleared", since=mark)
    assert gcs.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED


def test_the_agent_says_a_failsafe_not_an_operator_took_over(fly):
    gcs, _ = fly(mission="search", autostart=True, failsafe_timeout=2.0)  # minutes of searching
    gcs.wait_text("search: start", sim_timeout=20)
    mark = len(gcs.texts)
    gcs.wait_text("GCS failsafe", since=mark, heartbeats=False, sim_timeout=60)  # the station falls silent
    paused = gcs.wait_text("Agent: paused", since=mark, heartbeats=False)
    assert paused == "Agent: paused, failsafe switched to RTL"


def test_gcs_failsafe_holds_a_rover(fly):
    gcs, _ = fly("rover", failsafe_timeout=2.0)
    assert gcs.set_mode(15) == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait_text("GCS failsafe", heartbeats=False, sim_timeout=60)
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 4, heartbeats=False, sim_timeout=60)  # HOLD


# ---- parameters and missions ---------------------------------------------------------------------
def test_parameters_list_read_and_set(fly):
    gcs, sim = fly()
    gcs.mav.param_request_list_send(1, 1)
    names = set()
    while len(names) < 10:
        names.add(gcs.wait("PARAM_VALUE").param_id)
    assert {"SCN_SPEED", "SCN_ALTITUDE", "SCN_RESOLUTION", "SCN_MON_PERIOD"} <= names
    gcs.mav.param_set_send(1, 1, b"SCN_SPEED", 3.5, mavlink.MAV_PARAM_TYPE_REAL32)
    assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "SCN_SPEED").param_value == pytest.approx(3.5)
    assert sim.agent.settings.speed == 3.5
    gcs.mav.param_set_send(1, 1, b"SCN_SPEED", -1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "SCN_SPEED").param_value == pytest.approx(3.5)
    gcs.wait_text("SCN_SPEED")
    gcs.mav.param_request_read_send(1, 1, b"SCN_ALTITUDE", -1)
    assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "SCN_ALTITUDE").param_value == pytest.approx(4.0)


def upload(gcs, items):
    """Upload (lat, lon, alt) waypoints with the mission protocol; returns the final MISSION_ACK type."""
    gcs.heartbeat()
    gcs.mav.mission_count_send(1, 1, len(items) + 1, 0)
    while True:
        message = gcs.wait(None, lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"))
        if message.get_type() == "MISSION_ACK":
            return message.type
        seq = message.seq
        lat, lon, alt = items[seq - 1] if seq else items[0]
        command = mavlink.MAV_CMD_NAV_WAYPOINT
        gcs.mav.mission_item_int_send(
            1,
            1,
            seq,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            command,
            0,
            1,
            0,
            0,
            0,
            0,
            int(lat * 1e7),
            int(lon * 1e7),
            alt,
            0,
        )


def download(gcs):
    gcs.mav.mission_request_list_send(1, 1)
    count = gcs.wait("MISSION_COUNT").count
    items = []
    for seq in range(count):
        gcs.mav.mission_request_int_send(1, 1, seq, 0)
        items.append(gcs.wait("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s))
    gcs.mav.mission_ack_send(1, 1, mavlink.MAV_MISSION_ACCEPTED, 0)
    return items


NAN, INF = math.nan, math.inf


def test_commands_with_numbers_no_vehicle_can_use_are_denied_and_leave_it_flying(fly):
    """Each of these was ACCEPTED: a NaN speed and then any goto killed the process, a NaN yaw spun the copter
    for good, a NaN arm disarmed it, a NaN interval stopped its heartbeat, a take-off to inf climbed for ever,
    a goto to latitude 135 flew off."""
    gcs, sim = fly()
    take_off(gcs)  # the agent starts its mission; a turn the operator orders pauses it, once
    assert gcs.command(mavlink.MAV_CMD_CONDITION_YAW, 90) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait_text("Agent: paused, operator turned the vehicle")
    lat, lon = sim.world.datum.to_global(3.0, 2.0)
    hostile = [
        (mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, NAN, -1),
        (mavlink.MAV_CMD_CONDITION_YAW, NAN),
        (mavlink.MAV_CMD_CONDITION_YAW, INF, 0, 0, 1),
        (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, NAN),
        (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HEARTBEAT, NAN),
        (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HEARTBEAT, -5),
        (mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, INF),
        (mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 1e38),
        (mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, NAN, NAN, 5),
        (mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 135.0, lon, 5),
        (mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, lat, lon, INF),
        (mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, lat, lon, 5000),
    ]
    for command, *params in hostile:
        assert gcs.command(command, *params) == mavlink.MAV_RESULT_DENIED, (command, params)
    assert sim.world.autopilot.armed and sim.world.autopilot.speed == 2.5 and sim.world.autopilot.mode == "GUIDED"
    gcs.wait("HEARTBEAT")  # still beating
    assert len([t for t in gcs.texts if "Agent: paused" in t]) == 1  # a refused command took nothing over
    assert gcs.command(mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, lat, lon, 5) == mavlink.MAV_RESULT_ACCEPTED
    # the process lives on and flies there (the agent took off with it and may hold it short: close is enough)
    gcs.wait("LOCAL_POSITION_NED", lambda m: math.hypot(m.x - 2, m.y - 3) < 1.0 and abs(m.z + 5) < 0.3, sim_timeout=30)


def test_a_global_position_target_is_flown_in_its_frame(fly):
    """Above sea level in MAV_FRAME_GLOBAL_INT, above home in the relative frames; a frame that is none is no
    target (590 m above sea level was flown as 590 m above home, frame 99 as relative)."""
    gcs, sim = fly()
    take_off(gcs)
    lat, lon = sim.world.datum.to_global(2.0, 1.0)
    sea_level = sim.world.datum.alt + sim.world.home[2]

    def target(frame, alt):
        gcs.heartbeat()
        gcs.mav.set_position_target_global_int_send(0, 1, 1, frame, 0x0DF8, int(lat * 1e7), int(lon * 1e7), alt,
                                                         0, 0, 0, 0, 0, 0, 0, 0)

    target(99, 30.0)
    target(mavlink.MAV_FRAME_GLOBAL_INT, sea_level + 6.0)
    gcs.wait("LOCAL_POSITION_NED", lambda m: math.hypot(m.x - 1, m.y - 2) < 1.0 and abs(m.z + 6) < 0.3,
             sim_timeout=30)  # 6 m up, not 30 (frame 99) nor 590 (sea level read as home)
    target(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 3.0)
    gcs.wait("LOCAL_POSITION_NED", lambda m: abs(m.z + 3) < 0.3, sim_timeout=30)


def test_a_mission_item_the_autopilot_cannot_fly_ends_the_upload_and_keeps_the_mission(fly):
    gcs, sim = fly()
    lat, lon = sim.world.datum.to_global(3.0, 2.0)
    assert upload(gcs, [(lat, lon, 5.0)]) == mavlink.MAV_MISSION_ACCEPTED
    for bad, result in (((135.0, lon, 5.0), mavlink.MAV_MISSION_INVALID_PARAM5_X),
                        ((lat, lon, NAN), mavlink.MAV_MISSION_INVALID_PARAM7),
                        ((lat, lon, 2e4), mavlink.MAV_MISSION_INVALID_PARAM7)):
        assert upload(gcs, [(lat, lon, 5.0), bad]) == result, bad
    kept = download(gcs)
    assert len(kept) == 2 and kept[1].z == pytest.approx(5.0)


def test_mission_upload_download_round_trip_and_auto_flies_it(fly):
    gcs, sim = fly(mission="square")
    points = [sim.world.datum.to_global(x, y) + (4.0,) for x, y in ((0, 5), (5, 5), (5, 0))]
    assert upload(gcs, points) == mavlink.MAV_MISSION_ACCEPTED
    items = download(gcs)
    assert len(items) == 4  # home + 3
    for item, (lat, lon, alt) in zip(items[1:], points, strict=True):
        assert (item.x, item.y) == (int(lat * 1e7), int(lon * 1e7))
        assert item.z == pytest.approx(alt)
        assert item.command == mavlink.MAV_CMD_NAV_WAYPOINT
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.set_mode(3) == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_MISSION_START) == mavlink.MAV_RESULT_ACCEPTED
    reached = {gcs.wait("MISSION_ITEM_REACHED", sim_timeout=60).seq for _ in range(3)}
    assert reached == {1, 2, 3}


def test_mission_clear_all(fly):
    gcs, _ = fly()
    point = [(-35.3632, 149.1652, 4.0)]
    assert upload(gcs, point) == mavlink.MAV_MISSION_ACCEPTED
    gcs.mav.mission_clear_all_send(1, 1, 0)
    assert gcs.wait("MISSION_ACK").type == mavlink.MAV_MISSION_ACCEPTED
    assert len(download(gcs)) == 1  # home only


# ---- the map over TUNNEL ----------------------------------------------------------------------------
def collect_map(gcs, receiver, until, drop=None, rng=None, sim_timeout=120):
    """Feed TUNNEL payloads to the receiver until ``until()``; ``drop`` maps payload type -> loss rate."""

    def feed(message):
        if message.get_type() == "TUNNEL":
            lost = drop is not None and rng.random() < drop.get(message.payload_type, 0.0)
            if not lost:
                receiver.feed(message.payload_type, bytes(message.payload[: message.payload_length]))
        return until()

    gcs.wait(None, feed, sim_timeout=sim_timeout, component=COMPANION)  # the map is the onboard agent's


def test_map_copy_equals_the_onboard_map(fly):
    gcs, sim = fly(mission="browse", autostart=True)
    streamer = sim.companion.streamer
    streamer.snapshot_period, streamer.snapshot_budget = 1.0, 1e9
    receiver = MapReceiver()
    collect_map(gcs, receiver, lambda: sim.agent.done and receiver.synced and receiver.snapshots >= 2)
    sim.stop()
    while True:  # drain what was sent before it stopped
        message = gcs.recv(timeout=0.5, component=COMPANION)
        if message is None:
            break
        if message.get_type() == "TUNNEL":
            receiver.feed(message.payload_type, bytes(message.payload[: message.payload_length]))
    assert receiver.applied == streamer.delta_seq
    assert np.array_equal(receiver.grid.reshape(-1), streamer._sent)
    assert (receiver.grid >= 6).sum() > 10  # it saw the wall


def test_a_late_and_lossy_ground_station_resynchronises(fly):
    gcs, sim = fly(mission="search", autostart=True)
    streamer = sim.companion.streamer
    streamer.snapshot_period, streamer.snapshot_budget = 1.0, 1e9
    gcs.wait("ATTITUDE", lambda m: gcs.sim_time > 10, sim_timeout=30)  # join late
    receiver = MapReceiver()
    # lose a fifth of the map deltas, until a gap was noticed and a later
    # snapshot repaired it
    collect_map(
        gcs,
        receiver,
        lambda: receiver.gaps > 0 and receiver.synced and receiver.snapshots >= 2,
        drop={MAP_DELTA: 0.2},
        rng=random.Random(3),
        sim_timeout=300,
    )
    sim.stop()
    while (message := gcs.recv(timeout=0.5, component=COMPANION)) is not None:
        if message.get_type() == "TUNNEL":
            receiver.feed(message.payload_type, bytes(message.payload[: message.payload_length]))
    assert receiver.synced and receiver.applied == streamer.delta_seq
    assert np.array_equal(receiver.grid.reshape(-1), streamer._sent)


# ---- robustness -------------------------------------------------------------------------------------
def test_garbage_and_foreign_messages_are_ignored_and_counted(fly):
    gcs, sim = fly()
    gcs.heartbeat()
    gcs.wait("HEARTBEAT")
    address = sim.endpoint.links[0].port.getsockname()
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rng = random.Random(1)
    stranger = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    good = mavlink.MAVLink_command_long_message(7, 1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
    packet = good.pack(stranger)
    for _ in range(20):
        raw.sendto(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))), address)
        raw.sendto(packet[: rng.randrange(1, len(packet))], address)  # truncated
    for _ in range(3):  # a whole packet for system 7, not us (the first may land in a half-parsed one)
        raw.sendto(packet, address)
    raw.close()
    assert gcs.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED  # still obeys
    gcs.wait_mode(5)
    assert sim.endpoint.stats["bad packets"] > 0
    assert sim.endpoint.stats["for other systems"] >= 1
    assert sim.world.autopilot.mode == "LOITER"


def test_several_ground_stations_at_once(scene):
    ports = [free_udp_port(), free_udp_port()]
    first, second = (Gcs(f"udpin:127.0.0.1:{p}", sysid=s, speedup=10) for p, s in zip(ports, (255, 245), strict=True))
    with RunningSim(make_vehicle(scene), [f"udpout:127.0.0.1:{p}" for p in ports], speedup=10):
        first.wait("HEARTBEAT")
        second.wait("HEARTBEAT")
        assert second.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED
        first.wait_mode(5)
    first.close()
    second.close()


def test_vehicle_log_records_both_directions(fly, tmp_path):
    log = tmp_path / "vehicle.tlog"
    gcs, sim = fly(log=str(log))
    assert gcs.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED
    sim.stop()
    wait_wall(lambda: sim.log._file.closed, 5, "the vehicle's log closed")  # the loop closes it on its way out
    reader = mavutil.mavlink_connection(str(log))
    kinds = set()
    while (message := reader.recv_match()) is not None:
        kinds.add((message.get_type(), message.get_srcSystem()))
    assert ("HEARTBEAT", 1) in kinds and ("COMMAND_ACK", 1) in kinds
    assert ("COMMAND_LONG", 255) in kinds  # what the ground station sent


@contextmanager
def endpoint_alone(scene, log: TlogWriter | None = None):
    """The copter's endpoint on a UDP port without the loop that drives it: the test calls ``poll(now)`` with
    the wall times it chooses; yields (endpoint, its autopilot, a ground station talking to it)."""
    port = free_udp_port()
    world = Simulation(scene, Kind.COPTER)
    endpoint = Endpoint([f"udpin:127.0.0.1:{port}"], world, Telemetry(world), failsafe_timeout=5.0, log=log)
    gcs = Gcs(f"udpout:127.0.0.1:{port}")
    try:
        yield endpoint, world.autopilot, gcs
    finally:
        gcs.close()
        endpoint.close()


def test_messages_made_while_the_only_link_is_down_count_as_unsent(scene):
    """A vehicle whose one link (a TCP station not listening) is down said at the end that it had sent
    everything it made."""
    world = Simulation(scene, Kind.COPTER)
    endpoint = Endpoint([f"tcp:127.0.0.1:{free_tcp_port()}"], world, Telemetry(world))
    try:
        endpoint.send([endpoint.telemetry.heartbeat(0.0)] * 3, now=0.0)
        assert endpoint.stats == {"unsent (no link up)": 3}
    finally:
        endpoint.close()
    with endpoint_alone(scene) as (endpoint, _, _gcs):  # a UDP listener is up from the start
        endpoint.send([endpoint.telemetry.heartbeat(0.0)] * 2, now=0.0)
        assert endpoint.stats == {"sent": 2}


def gcs_heard(endpoint, gcs, now: float) -> None:
    """A ground station's heartbeat, taken in at wall time ``now``."""
    gcs.heartbeat()
    wait_wall(lambda: endpoint.poll(now) or endpoint.gcs_seen == now, 5, "the ground station's heartbeat")


def next_text(gcs):
    """The next STATUSTEXT the vehicle sends."""
    return wait_wall(lambda: (m := gcs.recv(0.1)) is not None and m.get_type() == "STATUSTEXT" and m, 5, "a STATUSTEXT")


def test_the_gcs_failsafe_comes_after_exactly_its_timeout_and_again_each_time_the_station_falls_silent(scene, tmp_path):
    """Silent for the whole timeout (5 s), a ground station it has heard makes an armed copter return home,
    as the failsafe (the autopilot keeps who changed its mode); a CRITICAL text says why, another that it is
    cleared when the station is back, and the next silence starts it again. The vehicle log has each text at
    the time it was sent."""
    log = TlogWriter(tmp_path / "vehicle.tlog")
    failsafe = "GCS failsafe: no ground station for 5 s, RTL"
    with endpoint_alone(scene, log) as (endpoint, autopilot, gcs):
        assert autopilot.arm() == mavlink.MAV_RESULT_ACCEPTED
        gcs_heard(endpoint, gcs, 100.0)
        endpoint.poll(104.999)
        assert autopilot.mode == "GUIDED"
        endpoint.poll(105.0)
        assert (autopilot.mode, autopilot.mode_source) == ("RTL", "failsafe")
        text = next_text(gcs)
        assert (text.text, text.severity) == (failsafe, mavlink.MAV_SEVERITY_CRITICAL)

        gcs_heard(endpoint, gcs, 107.0)
        text = next_text(gcs)
        assert (text.text, text.severity) == ("GCS failsafe cleared: ground station back", mavlink.MAV_SEVERITY_INFO)
        assert autopilot.set_mode("LOITER") == mavlink.MAV_RESULT_ACCEPTED  # the operator takes it back
        endpoint.poll(111.9)
        assert autopilot.mode == "LOITER"
        endpoint.poll(112.0)
        assert (autopilot.mode, autopilot.mode_source) == ("RTL", "failsafe")
        assert next_text(gcs).text == failsafe
    log.close()
    reader = mavutil.mavlink_connection(str(tmp_path / "vehicle.tlog"))
    texts = []
    while (message := reader.recv_match(type="STATUSTEXT")) is not None:
        texts.append((message._timestamp, message.text))
    assert texts == [(105.0, failsafe), (107.0, "GCS failsafe cleared: ground station back"), (112.0, failsafe)]


def test_the_gcs_failsafe_needs_a_station_once_heard_and_fires_once_per_silence(scene, tmp_path):
    """A vehicle that never heard a ground station has none to lose (ArduPilot waits for the first), and one
    silence is one failsafe: polls through it neither say it again nor take back a mode set since."""
    log = TlogWriter(tmp_path / "vehicle.tlog")
    with endpoint_alone(scene, log) as (endpoint, autopilot, gcs):
        assert autopilot.arm() == mavlink.MAV_RESULT_ACCEPTED
        for now in (100.0, 1000.0):
            endpoint.poll(now)
        assert autopilot.mode == "GUIDED" and not endpoint.in_failsafe
        gcs_heard(endpoint, gcs, 1000.0)
        endpoint.poll(1005.0)
        assert (autopilot.mode, autopilot.mode_source) == ("RTL", "failsafe")
        assert autopilot.set_mode("LOITER") == mavlink.MAV_RESULT_ACCEPTED  # a pilot's switch, on the vehicle
        for now in (1005.05, 1010.0, 1100.0):
            endpoint.poll(now)
        assert autopilot.mode == "LOITER" and endpoint.in_failsafe
    log.close()
    reader = mavutil.mavlink_connection(str(tmp_path / "vehicle.tlog"))
    texts = []
    while (message := reader.recv_match(type="STATUSTEXT")) is not None:
        texts.append((message._timestamp, message.text))
    assert texts == [(1005.0, "GCS failsafe: no ground station for 5 s, RTL")]


def command_acked_at(endpoint, gcs, now: float, command: int, *params: float) -> int:
    """A ground station's COMMAND_LONG, without a heartbeat before it, taken in at wall time ``now``: its ACK's
    result."""
    gcs.mav.command_long_send(1, 1, command, 0, *(list(params) + [0.0] * 7)[:7])
    return wait_wall(lambda: endpoint.poll(now) or (m := gcs.recv(0.05)) is not None and m.get_type() ==
                     "COMMAND_ACK" and m.command == command and m, 5, "the COMMAND_ACK").result


def test_a_ground_station_silent_for_exactly_the_failsafe_timeout_is_no_longer_obeyed_as_the_failsafe_fires(scene):
    """One rule for the failsafe and for whom the vehicle obeys: a silence that reaches the timeout (5 s) is a
    lost ground station. Just short of it the station's command is obeyed; at exactly the timeout it is denied,
    in the same poll in which the failsafe fires (it used to be obeyed by a vehicle that had given it up)."""
    set_mode = mavlink.MAV_CMD_DO_SET_MODE
    with endpoint_alone(scene) as (endpoint, autopilot, gcs):
        gcs_heard(endpoint, gcs, 100.0)
        assert command_acked_at(endpoint, gcs, 104.999, set_mode, 1, 5) == mavlink.MAV_RESULT_ACCEPTED
        assert autopilot.mode == "LOITER" and not endpoint.in_failsafe
        assert command_acked_at(endpoint, gcs, 105.0, set_mode, 1, 4) == mavlink.MAV_RESULT_DENIED
        assert autopilot.mode == "LOITER" and endpoint.in_failsafe
