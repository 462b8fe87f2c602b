"""The monitor (vehicle.monitor): vetting readings, feeding the memory map, and "too close" ahead.

Readings are made by hand (a vehicle at the origin, 4 m up, travelling north unless
said otherwise); the last test flies a vehicle at a wall with the autopilot's own
avoidance switched off, so only the monitor can stop it.
"""

import math

import numpy as np
import pytest

from vehicle.agent.monitor import Monitor, sweep_profile
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.rangefinder import Reading

RADIUS = 0.3
NORTH, EAST, SOUTH = 0.0, math.pi / 2, math.pi
ALTITUDE = 4.0


def reading(dx, dy, distance, dz=0.0, origin=(0.0, 0.0, ALTITUDE), max_range=40.0):
    """A reading from ``origin`` along (dx, dy, dz) (normalised); ``distance`` None for no echo."""
    direction = np.array([dx, dy, dz], dtype=float)
    direction /= np.linalg.norm(direction)
    return Reading(0.0, 0, np.array(origin, dtype=float), direction, distance, max_range, 0.0, 7.5)


def monitor(**settings):
    s = Settings(space_size=20, **settings)
    memory = MemoryMap((0.0, 0.0), s.space_size, s.resolution)
    return Monitor(s, memory, (0.0, 0.0), RADIUS), memory


def observe(mon, readings, travel=NORTH, x=0.0, y=0.0, time=1.0, speed=0.0):
    mon.collect(readings)
    return mon.observe(time, x, y, travel, speed)


def occupied_at(memory, x, y):
    return bool(memory.occupied[memory.cell_of(x, y)])


# ---- vetting and mapping ----------------------------------------------------------------------
def test_readings_past_farness_are_dropped_and_not_mapped():
    mon, memory = monitor(farness=10)
    far = reading(1, 0, 15.0)  # an echo 15 m east: past farness
    near = reading(-1, 0, 5.0)  # an echo 5 m west
    observation = observe(mon, [far, near])
    assert mon.readings_dropped == 1
    assert not occupied_at(memory, 15.0, 0.0)
    assert not memory.ever_hit[memory.cell_of(15.05, 0.0)]
    assert occupied_at(memory, -5.0, 0.0)
    assert memory.detections == memory.cells_ever_hit == 1
    kept = {r.distance for r in observation.readings}
    assert kept == {None, 5.0}  # the far one is kept as "no echo", the near one as it is


def test_a_reading_at_farness_is_kept():
    mon, memory = monitor(farness=10)
    observe(mon, [reading(1, 0, 10.0)])
    assert mon.readings_dropped == 0
    assert occupied_at(memory, 10.0, 0.0)


def test_dropped_readings_are_counted_over_periods():
    mon, _ = monitor(farness=10)
    for k in range(3):
        observe(mon, [reading(1, 0, 12.0 + k), reading(0, 1, 3.0), reading(0, -1, None)], time=k + 1.0)
    assert mon.readings_dropped == 3
    assert mon.readings_used == 9


def test_readings_fill_the_map_with_free_space_and_obstacles():
    mon, memory = monitor()
    observe(mon, [reading(1, 0, 6.0)])
    assert occupied_at(memory, 6.0, 0.0)
    assert memory.free[memory.cell_of(3.0, 0.0)]  # the beam passed through here


def test_an_echo_from_the_ground_is_not_an_obstacle():
    mon, memory = monitor()
    # pointing 45 degrees down from 4 m: the ground is met 4 m ahead, far below the band
    observation = observe(mon, [reading(0, 1, math.sqrt(32), dz=-1)])
    assert memory.detections == 0
    assert observation.nearest_ahead is None and not observation.too_close


# ---- too close ahead --------------------------------------------------------------------------
def test_an_echo_ahead_closer_than_closeness_is_too_close():
    mon, _ = monitor(closeness=2.0)
    observation = observe(mon, [reading(0, 1, 1.5)], travel=NORTH)
    assert observation.nearest_ahead == pytest.approx(1.5)
    assert observation.too_close


def test_a_vehicle_speeding_up_is_too_close_for_the_speed_it_reaches_by_the_next_period():
    """Up from 1.27 to 1.87 m/s in a period, on its way to 2.5 m/s, with an echo 2.08 m ahead: by the next
    period it goes 2.47 m/s, from which it needs 1.84 m to stand, so it must stop now (stopped a period
    later, it struck a wall met obliquely in the apartment). Holding 1.87 m/s, the same echo is no reason
    to stop yet."""
    echo = [reading(0, 1, 2.08)]
    speeding, _ = monitor(closeness=0.8, speed=2.5)
    assert not observe(speeding, [], travel=NORTH, speed=1.27).too_close
    assert observe(speeding, echo, travel=NORTH, speed=1.87, time=2.0).too_close
    steady, _ = monitor(closeness=0.8, speed=2.5)
    assert not observe(steady, [], travel=NORTH, speed=1.87).too_close
    assert not observe(steady, echo, travel=NORTH, speed=1.87, time=2.0).too_close


def test_an_echo_ahead_beyond_closeness_is_not_too_close():
    mon, _ = monitor(closeness=2.0)
    observation = observe(mon, [reading(0, 1, 3.0)], travel=NORTH)
    assert observation.nearest_ahead == pytest.approx(3.0)
    assert not observation.too_close


def test_an_echo_in_the_corridor_but_off_the_heading_is_too_close():
    mon, _ = monitor(closeness=2.0, padding=0.5)
    # hit at (0.6, 1.2): 0.6 m to the side of the track, inside radius + padding = 0.8 m
    observation = observe(mon, [reading(0.6, 1.2, math.hypot(0.6, 1.2))], travel=NORTH)
    assert observation.nearest_ahead == pytest.approx(1.2)
    assert observation.too_close


def test_an_echo_beside_the_corridor_is_not_too_close():
    mon, _ = monitor(closeness=2.0, padding=0.5)
    # hit at (1.0, 1.0): 1.0 m to the side, outside radius + padding = 0.8 m
    observation = observe(mon, [reading(1.0, 1.0, math.hypot(1.0, 1.0))], travel=NORTH)
    assert observation.nearest_ahead is None
    assert not observation.too_close


def test_an_echo_behind_or_when_standing_still_is_not_too_close():
    mon, _ = monitor(closeness=2.0)
    assert not observe(mon, [reading(0, 1, 1.0)], travel=SOUTH).too_close
    assert not observe(mon, [reading(0, 1, 1.0)], travel=None, time=2.0).too_close


def test_the_corridor_follows_the_direction_of_travel():
    mon, _ = monitor(closeness=2.0)
    east = [reading(1, 0, 1.0, origin=(3.0, 2.0, ALTITUDE))]
    assert observe(mon, east, travel=EAST, x=3.0, y=2.0).too_close
    assert not observe(mon, east, travel=NORTH, x=3.0, y=2.0, time=2.0).too_close


def test_the_nearest_echo_in_the_corridor_counts():
    mon, _ = monitor(closeness=2.0)
    observation = observe(mon, [reading(0, 1, 5.0), reading(0.3, 1, math.hypot(0.3, 1) * 2.5),
                                reading(1, 0.2, 1.0)], travel=NORTH)
    assert observation.nearest_ahead == pytest.approx(2.5)
    assert not observation.too_close


@pytest.mark.parametrize(("known", "too_close"), [(None, True), ((0.55, 3.95), False), ((0.05, 3.95), True)])
def test_an_echo_a_known_obstacle_beside_the_corridor_explains_is_not_ahead(known, too_close):
    """An echo 4 m north comes from somewhere on its cone's arc, 0.52 m either side of the centre line: with a
    door frame already in the map at the arc's edge, beside the 0.4 m corridor, the frame explains it (as the
    map takes it to); with nothing known there, or the known obstacle in the corridor, it is ahead."""
    mon, memory = monitor(closeness=5.0, padding=0.1)
    if known is not None:
        memory.grid[memory.cell_of(*known)] = MemoryMap.OCCUPIED_AT
    observation = observe(mon, [reading(0, 1, 4.0)], travel=NORTH)
    assert observation.too_close is too_close
    assert (observation.nearest_ahead is not None) is too_close


@pytest.mark.parametrize(("clearance", "too_close"), [(float("inf"), True), (0.05, False)])
def test_the_corridor_is_as_narrow_as_the_clearance_the_path_was_planned_with(clearance, too_close):
    """A path squeezed through a doorway keeps 0.05 m beyond the body: the frame it passes 0.38 m from the
    centre line is no obstacle ahead on it, though it is within the padding's 0.4 m corridor."""
    mon, _ = monitor(closeness=2.0, padding=0.1)
    mon.collect([reading(0.38, 1.0, math.hypot(0.38, 1.0))])
    assert mon.observe(1.0, 0.0, 0.0, NORTH, clearance=clearance).too_close is too_close


@pytest.mark.parametrize(("path", "too_close"), [
    (None, False),  # the target 0.5 m ahead is all it knows: the vehicle stops there
    ([(0.0, 0.0), (0.0, 0.5), (0.1, 1.0), (0.1, 3.0)], True),  # the path runs on straight ahead
    ([(0.0, 0.0), (0.0, 0.5), (2.0, 0.6)], False),  # it turns east at the target
])
def test_the_reach_runs_on_as_far_as_the_path_goes_straight_ahead(path, too_close):
    """A path walked target by target (each half a metre ahead) runs on past each of them: an echo 1.5 m
    ahead is in the way when the path goes on that way (a vehicle flew into a wall 1.2 m ahead that way, its
    target 0.3 m ahead), and not when the path turns off before it."""
    mon, _ = monitor(closeness=2.0, padding=0.5)
    mon.collect([reading(0, 1, 1.5)])
    assert mon.observe(1.0, 0.0, 0.0, NORTH, reach=0.5, path=path).too_close is too_close


@pytest.mark.parametrize(("wall", "too_close"), [(None, True), (0.0, False), (0.25, True)])
def test_beyond_the_target_a_wall_the_map_knows_a_cell_off_the_echo_was_planned_round(wall, too_close):
    """The path runs on north past the target 0.5 m ahead, and an echo comes from 1.5 m ahead: a wall the
    map holds a cell beyond the echo's arc is the one the path on was planned round (a wall along a corridor
    whose cells the arc misses by one stopped a copter at every doorway), so only a new one is in the way;
    a known cell further off (a frame beside a gap the path goes through) explains nothing."""
    mon, memory = monitor(closeness=2.0, padding=0.5)
    if wall is not None:
        row, col = memory.cell_of(wall, 1.5)
        memory.grid[row + 1, col] = MemoryMap.OCCUPIED_AT
    mon.collect([reading(0, 1, 1.5)])
    path = [(0.0, 0.0), (0.0, 0.5), (0.0, 3.0)]
    assert mon.observe(1.0, 0.0, 0.0, NORTH, reach=0.5, path=path).too_close is too_close


def test_leaving_the_allowed_space_is_reported():
    mon, _ = monitor()
    assert not observe(mon, [], x=19.0, y=-19.0).outside
    assert observe(mon, [], x=20.5, y=0.0, time=2.0).outside


def test_the_monitor_tracks_the_distance_travelled():
    mon, _ = monitor()
    for k, (x, y) in enumerate([(0, 0), (3, 4), (3, 0)]):
        observe(mon, [], x=x, y=y, time=float(k))
    assert mon.distance_travelled == pytest.approx(9.0)


def test_sweep_profile_sorts_readings_by_heading():
    headings, distances = sweep_profile([reading(-1, 0, 2.0), reading(1, 0, None), reading(0, 1, 3.0)])
    assert headings == pytest.approx([0.0, math.pi / 2, 3 * math.pi / 2])
    assert list(distances) == [3.0, math.inf, 2.0]


# ---- the agent stops the vehicle ------------------------------------------------------------
@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_the_agent_stops_the_vehicle_short_of_a_wall_when_the_monitor_says_too_close(make_scene, box, vehicle):
    # Square flies AUTO (no planning, no avoidance of its own): its east leg from (5, 5) to (5, -5)
    # meets a wall whose north face is at y = 0.1. Only the monitor can stop it.
    scene = make_scene(box(0, 0, -0.05, 80, 80, 0.1), box(5, 0, 2, 4, 0.2, 6))
    settings = Settings(space_size=20, time_limit=200)
    stepper = simulate(scene, "square", vehicle, settings)
    world, agent = stepper.simulation, stepper.agent
    world.autopilot.avoidance = None
    alarm = rest = None
    closest = math.inf
    while world.time < 60 and (alarm is None or world.time < alarm + 3.0):
        stepper.step()
        assert world.collision is None, world.collision.describe()
        closest = min(closest, abs(world.pose.y - 0.1) if 3 < world.pose.x < 7 else math.inf)
        if alarm is not None and rest is None and world.body.speed < 0.05:
            rest = world.time
        if stepper.monitor_due:
            if alarm is None and agent.ctx.observation.too_close:
                alarm = world.time
                # on the east leg, which it turns onto within closeness (2 m) of the corner (5, 5): a rover
                # slowed to what its ground sonar's sight allows turns early, at x = 3.8
                assert 3.0 < world.pose.x < 7.0 and 0.1 < world.pose.y < 5.0
    assert alarm is not None, "the monitor never found the wall too close"
    assert rest is not None and rest - alarm < 2.0  # brought to rest at once
    assert closest > world.limits.radius  # short of the wall
    assert agent.outcome == "stopped"
    assert "closer than the safety distance" in agent.reason
