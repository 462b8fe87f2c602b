"""Ground that drops away or rises too steeply (issue 32): a rover with the "ground" suite's sonar looking
down and ahead stops before an edge it could have seen and goes no further, takes a step down shallower
than ``drop_depth`` (the monitor alone: the simulated body cannot roll down a step), and refuses a ramp
steeper than ``max_slope`` while it takes a gentle one, drives down a slope it can drive and onto the level
top of a climb.

Each scene is a plateau (top at z = 0) south of y = 8 with the rover at its middle facing north, and a
Pathfind waypoint at (0, 16) past whatever lies at y = 8; simulated time throughout.
"""

import math

import numpy as np
import pytest
from conftest import vrml_box

from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.rangefinder import Reading
from vehicle.world.suites import sensor_suite

EDGE = 8.0  # m north of the start, where the plateau ends
GOAL = (0.0, 16.0)
PLATEAU = vrml_box(0, -20, -1.0, 60, 56, 2.0)  # top at z = 0 up to y = 8
HEIGHT = 0.35  # m: the simulated rover's sensors above its ground
SETTINGS = dict(speed=1.5, space_size=30, time_limit=120)


def lower_ground(depth: float) -> str:
    """Ground north of the edge, ``depth`` below the plateau."""
    return vrml_box(0, 30, -depth - 1.0, 60, 44, 2.0)


def ramp(degrees: float) -> str:
    """A ramp rising north from the plateau's edge at ``degrees``, on flat ground level with the plateau."""
    length = 12.0
    tilt = math.radians(degrees)
    # a slab 1 m thick whose top face starts at (y = EDGE, z = 0) and rises northwards
    cy = EDGE + length / 2 * math.cos(tilt) + 0.5 * math.sin(tilt)
    cz = length / 2 * math.sin(tilt) - 0.5 * math.cos(tilt)
    return vrml_box(0, 30, -1.0, 60, 44, 2.0) + vrml_box(0, cy, cz, 60, length, 1.0, f"1 0 0 {tilt}")


def drive(scene, suite: str = "ground", **settings):
    """Pathfind to GOAL; the lowest and the northmost the rover's centre came, whether it arrived, the stepper."""
    stepper = simulate(scene, "pathfind", "rover", Settings(**SETTINGS | settings), start=(0.0, 0.0), heading=0.0,
                       waypoints=[GOAL], sensors=sensor_suite(suite, "rover"))
    start_z = stepper.simulation.pose.z
    lowest, northmost, arrived = start_z, 0.0, False
    for _ in range(int(90 / stepper.simulation.dt)):
        stepper.step()
        pose = stepper.simulation.pose
        lowest, northmost = min(lowest, pose.z), max(northmost, pose.y)
        arrived = arrived or math.hypot(pose.x - GOAL[0], pose.y - GOAL[1]) < 2.0
        if stepper.simulation.collision is not None or arrived or stepper.agent.outcome is not None:
            break
    return start_z - lowest, northmost, arrived, stepper


@pytest.mark.parametrize("suite", ["ground", "triple", "single", "servo"])
def test_a_rover_stops_before_a_2_m_bank_and_never_falls(make_scene, suite):
    """Whatever its level sonars, a rover carries the ground sonar (with the level ones alone it drove over)."""
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, lower_ground(2.0)), suite)
    assert stepper.simulation.collision is None
    assert fall < 0.05, f"the rover fell {fall:.2f} m"
    assert northmost < EDGE - 0.3, f"its centre came to y = {northmost:.2f}, over the edge at {EDGE}"
    assert not arrived
    said = " ".join(stepper.agent.messages)
    assert "ground drops away" in said, said
    memory = stepper.agent.map  # the edge is in the map, so the planner goes round it
    assert memory.occupied[memory.cell_of(0.0, EDGE + 0.1)] or memory.occupied[memory.cell_of(0.0, EDGE)] \
        or memory.occupied_in(*_around(memory, 0.0, EDGE)).any()


def test_a_rover_at_the_default_speed_slows_to_stop_short_of_an_edge_it_sees_late(make_scene):
    """The down sonar sees an edge about 1.6 m ahead; from the default 2.5 m/s a rover needs more than that to
    stop (two monitor periods and the braking), and in the castle one drove down a bank so. It now drives no
    faster than it can stop within that sight, and says so."""
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, lower_ground(2.0)), speed=Settings().speed)
    assert stepper.simulation.collision is None and fall < 0.05, f"fell {fall:.2f} m"
    assert northmost < EDGE - 0.3, f"its centre came to y = {northmost:.2f}, over the edge at {EDGE}"
    limit = stepper.agent.monitor.speed_limit
    assert limit < Settings().speed and stepper.simulation.autopilot.speed == limit
    assert any(text.startswith(f"Speed limited to {limit:.1f} m/s") for text in stepper.agent.messages)


def test_the_speed_limit_stops_the_body_within_the_ground_sonars_sight():
    mon, _ = ground_monitor()
    assert mon.speed_limit == math.inf  # nothing seen of the ground yet
    mon.collect([ground_echo(0.0)])
    mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.0)
    sight = HEIGHT / math.tan(math.radians(12.0))  # where the cone's lower edge meets level ground
    assert mon.ground_sight == pytest.approx(sight)
    v, period = mon.speed_limit, mon.settings.monitor_period
    stop = 2 * period * v + v * v / (2 * mon.brake)
    assert stop <= sight - mon.radius < stop + 2 * period * 0.1 + 0.1 * v / mon.brake + 0.01  # to 0.1 m/s below


def _around(memory, x, y, half=0.6):
    (r0, c0), (r1, c1) = memory.cell_of(x - half, y - half), memory.cell_of(x + half, y + half)
    return slice(r0, r1 + 1), slice(c0, c1 + 1)


def ground_echo(depth: float, pitch: float = -10.0, beam: float = 2.0) -> Reading:
    """The down sonar of a rover at the origin facing north, 0.35 m above its ground, echoing off ground
    ``depth`` below that (None: no echo within its 6 m) along the cone's lower edge."""
    lower = math.radians(-pitch + beam)
    distance = None if depth is None else (HEIGHT + depth) / math.sin(lower)
    axis = np.array([0.0, math.cos(math.radians(pitch)), math.sin(math.radians(pitch))])
    return Reading(0.0, 3, np.array([0.0, 0.0, HEIGHT]), axis, distance, 6.0, 0.0, beam, 0.02, pitch)


def ground_monitor():
    settings = Settings(space_size=20)
    memory = MemoryMap((0.0, 0.0), settings.space_size, settings.resolution)
    return Monitor(settings, memory, (0.0, 0.0), 0.3, height=HEIGHT), memory


@pytest.mark.parametrize("depth, obstacle", [(0.0, False), (0.2, False), (0.5, True), (None, True)])
def test_a_drop_deeper_than_drop_depth_is_an_obstacle_ahead_and_in_the_map(depth, obstacle):
    """A step down of 0.2 m is driven over (the simulated rover's sphere cannot roll down a step, so this is
    the monitor's word alone); 0.5 m and no echo at all are edges: ahead, too close, and marked in the map."""
    mon, memory = ground_monitor()
    mon.collect([ground_echo(depth)])
    observation = mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.5)
    assert observation.too_close is obstacle
    assert (observation.ground is not None) is obstacle
    edge = HEIGHT / math.tan(math.radians(12.0))  # where the cone's lower edge met level ground
    assert (memory.detections > 0) is obstacle
    if obstacle:
        assert memory.occupied_in(*_around(memory, 0.0, edge, 0.15)).any()


def test_an_edge_seen_ahead_is_marked_either_side_of_the_beam_too():
    """The 2 degree beam meets an edge at one point, but an edge is a line: marked 20 degrees either side too, a
    rover's way planned along the rim keeps off it (in the castle one ran along a bank's rim and touched the
    slope as it turned towards it)."""
    mon, memory = ground_monitor()
    mon.collect([ground_echo(None)])
    mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.0)
    edge = HEIGHT / math.tan(math.radians(12.0))
    for side in (-1, 1):
        angle = math.radians(20.0) * side
        assert memory.occupied_in(*_around(memory, edge * math.sin(angle), edge * math.cos(angle), 0.1)).any()


def test_ground_echoes_are_never_walls():
    """The old monitor took the down sonar's echo off level ground 1.6 m ahead for a wall."""
    mon, memory = ground_monitor()
    mon.collect([ground_echo(0.0)])
    observation = mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.5)
    assert observation.nearest_ahead is None and memory.detections == 0


def downhill(degrees: float, length: float = 30.0, behind: float = 3.0) -> str:
    """A slab whose top falls northwards at ``degrees``, through (y = 0, z = 0), ``behind`` m of it south of there."""
    tilt = math.radians(degrees)
    along = behind - length / 2  # where the origin lies along the slab, from its middle
    cy, cz = -along * math.cos(tilt) - 0.5 * math.sin(tilt), along * math.sin(tilt) - 0.5 * math.cos(tilt)
    return vrml_box(0, cy, cz, 60, length, 1.0, f"1 0 0 {-tilt}")


@pytest.mark.parametrize("slope", [15.0, -15.0])
def test_on_a_slope_it_can_drive_the_ground_ahead_is_no_drop(slope):
    """A rover on a slope of 15 degrees (under its ``max_slope``), facing down it (or up it): its down sonar
    meets the slope where it would meet level ground under a level rover. The ground ahead lies on in the plane
    the rover stands on, so nothing drops away (measured from the level, the slope down was 0.41 m deep there,
    and a rover stopped at every downhill)."""
    mon, memory = ground_monitor()
    pitch = math.radians(-10.0 - slope)  # the beam's centre, the mount's 10 degrees and the rover's own tilt
    reading = ground_echo(0.0)
    reading.direction = np.array([0.0, math.cos(pitch), math.sin(pitch)])
    mon.collect([reading])
    observation = mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.5)
    assert observation.ground is None and not observation.too_close
    assert memory.detections == 0


def test_at_the_top_of_a_climb_level_ground_ahead_is_no_drop():
    """A rover pitched 8 degrees up a climb: its down sonar's lower edge meets the level top 5 m ahead, 0.69 m
    below the plane the rover stands on but level with its own ground."""
    mon, memory = ground_monitor()
    pitch, lower = math.radians(-10.0 + 8.0), math.radians(-10.0 + 8.0 - 2.0)
    reading = ground_echo(0.0)
    reading.direction = np.array([0.0, math.cos(pitch), math.sin(pitch)])
    reading.distance = HEIGHT / math.sin(-lower)
    mon.collect([reading])
    observation = mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.5)
    assert observation.ground is None and not observation.too_close
    assert memory.detections == 0


def test_a_rover_drives_down_a_long_slope_it_can_drive(make_scene):
    stepper = simulate(make_scene(downhill(15.0)), "pathfind", "rover", Settings(**SETTINGS), start=(0.0, 0.0),
                       heading=0.0, waypoints=[(0.0, 12.0)], sensors=sensor_suite("ground", "rover"))
    assert stepper.run(60, until=lambda: stepper.agent.outcome is not None)
    assert stepper.simulation.collision is None
    assert stepper.agent.outcome == "finished", stepper.agent.messages
    assert "drops away" not in " ".join(stepper.agent.messages)


def test_a_rover_climbs_onto_the_level_top_of_a_ramp_it_can_drive(make_scene):
    """At the top of a 10 degree climb the ground bends away from the plane the rover stands on, but no deeper
    than the level: that is no drop (measured from the plane alone, it stopped there for good)."""
    tilt, length = math.radians(10.0), 5.0
    cy = EDGE + length / 2 * math.cos(tilt) + 0.5 * math.sin(tilt)
    cz = length / 2 * math.sin(tilt) - 0.5 * math.cos(tilt)
    top, end = length * math.sin(tilt), EDGE + length * math.cos(tilt)
    climb = vrml_box(0, cy, cz, 60, length, 1.0, f"1 0 0 {tilt}")
    mesa = vrml_box(0, end + 10, top - 1.0, 60, 20, 2.0)
    scene = make_scene(PLATEAU, vrml_box(0, 30, -1.0, 60, 44, 2.0), climb, mesa)
    stepper = simulate(scene, "pathfind", "rover", Settings(**SETTINGS), start=(0.0, 0.0), heading=0.0,
                       waypoints=[(0.0, end + 4.0)], sensors=sensor_suite("ground", "rover"))
    assert stepper.run(90, until=lambda: stepper.agent.outcome is not None)
    assert stepper.simulation.collision is None
    assert stepper.agent.outcome == "finished", stepper.agent.messages
    assert "drops away" not in " ".join(stepper.agent.messages)


def test_a_steep_ramp_is_refused(make_scene):
    """24 degrees up the ramp; the rover meets it on a slant, where it climbs about 20 degrees: over 15."""
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, ramp(24.0)), max_slope=15)
    assert not arrived
    assert northmost < EDGE, f"it drove onto the ramp, to y = {northmost:.2f}"
    assert "ground rises too steeply" in " ".join(stepper.agent.messages)


def test_a_gentle_ramp_is_taken(make_scene):
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, ramp(8.0)), max_slope=15)
    assert stepper.simulation.collision is None
    assert arrived, f"stopped at y = {northmost:.2f}: {stepper.agent.messages}"


def slope_down_ahead(degrees: float, length: float = 10.0) -> str:
    """From the plateau's edge a slab falls north at ``degrees`` for ``length`` m onto level ground below."""
    tilt = math.radians(degrees)
    cy = EDGE + length / 2 * math.cos(tilt) - 0.5 * math.sin(tilt)
    cz = -length / 2 * math.sin(tilt) - 0.5 * math.cos(tilt)
    low, end = -length * math.sin(tilt), EDGE + length * math.cos(tilt)
    return vrml_box(0, cy, cz, 60, length, 1.0, f"1 0 0 {-tilt}") + vrml_box(0, end + 15, low - 1.0, 60, 30, 2.0)


def test_a_rover_drives_down_a_slope_that_starts_ahead_of_it(make_scene):
    """Level ground, then 15 degrees down for 2.6 m. The 10 degree sonar passes over the slope as over a bank
    (the rover stopped there for good); the 30 degree one meets it and tells a slope it can drive: the rover
    stops at the far sonar's first word, creeps while the near one looks, and drives down to its waypoint."""
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, slope_down_ahead(15.0)))
    assert stepper.simulation.collision is None
    assert arrived, f"it stopped at y = {northmost:.2f}: {stepper.agent.messages}"
    said = list(stepper.agent.messages)
    assert any(m.startswith("Speed limited to 0.4 m/s: the ground may drop away ahead; looking closer") for m in said)
    assert any(m.startswith("Speed back to 1.5 m/s") for m in said), said


@pytest.mark.parametrize("degrees", [25.0, 90.0])
def test_a_slope_down_steeper_than_max_slope_or_a_bank_that_starts_ahead_is_refused(make_scene, degrees):
    """25 degrees down (over ``max_slope``, 20) or a 2.6 m bank: the near sonar sees the ground fall more
    steeply than 20 degrees by more than ``drop_depth``: an edge, marked, and the rover's centre stays behind
    the rim (0.4 m behind a bank's; 0.2 m behind the 25 degree slope's, which it sees only once the slope has
    fallen ``drop_depth``)."""
    down = slope_down_ahead(degrees) if degrees < 90 else lower_ground(2.6)
    fall, northmost, arrived, stepper = drive(make_scene(PLATEAU, down))
    assert stepper.simulation.collision is None
    assert fall < 0.05 and northmost < (EDGE - 0.1 if degrees < 90 else EDGE - 0.3), (fall, northmost)
    assert not arrived
    memory = stepper.agent.map
    assert memory.occupied_in(*_around(memory, 0.0, EDGE, 0.3)).any()


def near_echo(depth: float | None, y: float = 0.0) -> Reading:
    """The near sonar (30 degrees down) of a level rover at (0, y) facing north, its echo off ground ``depth``
    below its own along the cone's lower edge (None: no echo within its 3 m)."""
    reading = ground_echo(depth, pitch=-30.0)
    reading.sensor, reading.max_range = 4, 3.0
    reading.origin = np.array([0.0, y, HEIGHT])
    return reading


def test_the_far_sonars_edge_stops_a_rover_once_then_it_creeps_while_the_near_one_looks():
    mon, memory = ground_monitor()
    mon.collect([ground_echo(None), near_echo(0.0)])
    first = mon.observe(1.0, 0.0, 0.0, 0.0, speed=1.5)
    assert first.too_close and first.ground.startswith("ground drops away")  # coming at 1.5 m/s: stop first
    assert mon.creeping and mon.speed_limit == pytest.approx(0.4)
    assert memory.detections == 0  # the near sonar decides what is an edge
    mon.collect([ground_echo(None), near_echo(0.0, 0.1)])
    creeping = mon.observe(1.25, 0.0, 0.1, 0.0, speed=0.4)
    assert not creeping.too_close and creeping.ground is None and memory.detections == 0
    mon.collect([ground_echo(None), near_echo(2.0, 0.2)])  # the near one meets the bank's foot: an edge
    edge = mon.observe(1.5, 0.0, 0.2, 0.0, speed=0.4)
    assert edge.too_close and edge.ground.startswith("ground drops away")
    assert memory.occupied_in(*_around(memory, 0.0, 0.2 + HEIGHT / math.tan(math.radians(32.0)), 0.15)).any()
    mon.collect([ground_echo(0.0), near_echo(0.0, 0.2)])  # turned away: level ground again
    mon.observe(3.0, 0.0, 0.2, 0.0, speed=0.0)
    assert not mon.creeping and mon.speed_limit > 1.5


def test_without_a_recent_word_from_the_near_sonar_the_far_ones_edge_is_an_edge():
    """A near sonar that fell silent vouches for nothing: the far one's edges stop the rover and are marked, as
    for a vehicle without one."""
    mon, memory = ground_monitor()
    mon.collect([ground_echo(0.0), near_echo(0.0)])
    mon.observe(1.0, 0.0, 0.0, 0.0, speed=0.4)
    mon.collect([ground_echo(None)])
    observation = mon.observe(2.5, 0.0, 0.0, 0.0, speed=0.4)
    assert observation.too_close and not mon.creeping
    assert memory.detections > 0


def test_the_way_home_is_timed_at_the_cruise_speed_not_at_the_creep_towards_a_rim(make_scene):
    """Timed at the 0.4 m/s creep, the way home looked four times as long, and a rover's Search in the castle ended
    a third early whenever it crept towards a rim."""
    stepper = simulate(make_scene(PLATEAU, lower_ground(2.0)), "pathfind", "rover", Settings(**SETTINGS),
                       start=(0.0, 0.0), heading=0.0, waypoints=[GOAL], sensors=sensor_suite("ground", "rover"))
    agent = stepper.agent
    assert stepper.run(30, until=lambda: agent.monitor.creeping)
    assert agent.ctx.speed == pytest.approx(0.4)
    home = agent.ctx.distance_to(agent.ctx.home)
    assert home > 3.0
    cruise = min(agent.settings.speed, agent.monitor.cruise_limit)
    assert cruise == pytest.approx(1.5)  # the setting; the far sonar's sight would allow 1.6 m/s
    assert agent._time_home() == pytest.approx(2.0 * home / cruise + min(60.0, agent.settings.time_limit / 6))
