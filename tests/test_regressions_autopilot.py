"""Regression tests for autopilot bugs found while writing the vehicle tests (each failed before its fix)."""

import math

import pytest

from vehicle.protocol.modes import Kind
from vehicle.sim.simulation import Simulation
from vehicle.world.scene import parse_scene
from vehicle.world.sonar import Sonar

GROUND = "#VRML V2.0 utf8\nTransform { translation 0 0 -0.05 children Shape { geometry Box { size 200 200 0.1 } } }\n"


@pytest.fixture
def flat_scene():
    return parse_scene(GROUND)


def taking_off(scene) -> Simulation:
    world = Simulation(scene, Kind.COPTER)
    world.autopilot.arm()
    world.autopilot.takeoff(10.0)
    world.run_for(1.0)  # climbing, at about 1.85 m
    return world


# ---- bugs: the GUIDED take-off goal (_altitude_goal) outlives mode changes and disarming ----------

def test_land_during_takeoff_descends_at_once(flat_scene):
    world = taking_off(flat_scene)
    z = world.pose.z
    world.autopilot.set_mode("LAND")
    world.run_for(1.0)
    assert world.pose.z < z  # it used to climb on to 10 m first


def test_brake_during_takeoff_stops_the_climb(flat_scene):
    world = taking_off(flat_scene)
    z = world.pose.z
    world.autopilot.set_mode("BRAKE")
    world.run_for(5.0)
    assert world.pose.z < z + 1.0  # it used to climb on to the take-off altitude


def test_rearming_after_a_forced_disarm_during_takeoff_stays_on_the_ground(flat_scene):
    world = taking_off(flat_scene)
    world.autopilot.disarm(force=True)
    world.run_for(3.0)  # falls back to the ground
    world.autopilot.arm()  # no take-off command
    world.run_for(5.0)
    assert world.pose.z == pytest.approx(0.35, abs=0.01)  # it used to take off by itself


# ---- bug: a Simulation without sensors cannot step ----------------------------------------------------

def test_a_world_without_sensors_steps(flat_scene):
    world = Simulation(flat_scene, Kind.COPTER, sensors=[])
    assert world.step() == []  # ValueError: need at least one array to concatenate (vehicle/sensors.py:124)


# ---- questionable: stopping modes and the velocity timeout drive back to where they were engaged ------

def test_rover_hold_stops_without_turning_around(flat_scene):
    world = Simulation(flat_scene, Kind.ROVER)
    world.autopilot.arm()
    world.autopilot.set_mode("GUIDED")
    world.autopilot.goto(0.0, 60.0)
    world.run_for(10.0)
    world.autopilot.set_mode("HOLD")
    world.run_for(10.0)
    assert abs(math.degrees(world.pose.yaw) % 360 - 0.0) < 10  # it used to U-turn back to the hold point


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
