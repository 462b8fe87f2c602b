"""Overhangs (issue 29's team runs under pines): a copter carries a sonar pitched up, so it sees the underside of
a tree's crown or a roof a little above its flight level, where the level cones pass under it; the monitor takes
its echoes within the map's band for obstacles, and its silence for nothing.

The scene: flat ground (top at z = 0) and a tree's crown, a cone 3 m in radius and 6 m tall without its bottom
(as the pines of scenes/trees.wrl), centred at (0, 12) with its rim 0.25 m above the copter's centre (altitude
4 m); the copter starts at the origin facing north with a Pathfind waypoint at (0, 20) beyond it; simulated
time throughout.
"""

import math

import numpy as np
import pytest
from conftest import GROUND

from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.rangefinder import Reading
from vehicle.world.suites import LOOKS_UP, SENSOR_SUITES, sensor_suite

ALTITUDE = 4.0
UNDERSIDE = 0.25  # m above the copter's centre: less than the body's radius (0.3), so flying under is a crash
CROWN = (f"Transform {{ translation 0 12 {ALTITUDE + UNDERSIDE + 3.0} children Shape {{ geometry Cone {{ "
         f"bottomRadius 3 height 6 bottom FALSE }} }} }}\n")


def fly(scene, sensors):
    """Pathfind north past the slab; the stepper once it ends, crashes or 60 simulated seconds pass."""
    stepper = simulate(scene, "pathfind", "copter", Settings(speed=2.5, space_size=30, time_limit=120,
                                                             altitude=ALTITUDE),
                       start=(0.0, 0.0), heading=0.0, waypoints=[(0.0, 20.0)], sensors=sensors)
    for _ in range(int(60 / stepper.simulation.dt)):
        stepper.step()
        if stepper.simulation.collision is not None or stepper.agent.outcome is not None:
            break
    return stepper


def test_a_copter_sees_an_overhang_it_would_hit_and_flies_round_it(make_scene):
    """With the level sonars alone it flies under the crown's rim and hits it (their cones reach it 1.9 m ahead,
    too late at 2.5 m/s); the overhead sonar sees it further out, so the copter goes round and arrives."""
    scene = make_scene(GROUND, CROWN)
    level_only = fly(scene, [s for s in sensor_suite("triple", "copter") if s.mount_pitch < LOOKS_UP])
    assert level_only.simulation.collision is not None  # the scene is a trap for level sonars
    stepper = fly(scene, sensor_suite("triple", "copter"))
    assert stepper.simulation.collision is None, stepper.simulation.collision.describe()
    assert stepper.agent.outcome == "finished", (stepper.agent.outcome, stepper.agent.reason)


def test_every_copter_suite_carries_the_overhead_sonar_and_no_rover_suite_does():
    for suite in SENSOR_SUITES:
        assert [s.name for s in sensor_suite(suite, "copter") if s.mount_pitch >= LOOKS_UP] == ["up"], suite
        assert not [s for s in sensor_suite(suite, "rover") if s.mount_pitch >= LOOKS_UP], suite


def overhead_echo(distance: float | None, pitch: float = 8.0, beam: float = 6.0) -> Reading:
    """The overhead sonar of a copter at (0, 0, 4) facing north, its echo ``distance`` away (None: none)."""
    axis = np.array([0.0, math.cos(math.radians(pitch)), math.sin(math.radians(pitch))])
    return Reading(0.0, 3, np.array([0.0, 0.0, 4.0]), axis, distance, 12.0, 0.0, beam, 0.02, pitch)


def monitor():
    settings = Settings(space_size=20, padding=0.5)
    memory = MemoryMap((0.0, 0.0), settings.space_size, settings.resolution)
    return Monitor(settings, memory, (0.0, 0.0), 0.3), memory


@pytest.mark.parametrize("range_m, obstacle", [(2.0, True), (6.0, True), (9.0, False)])
def test_an_overhead_echo_is_an_obstacle_while_the_beams_centre_meets_it_within_the_band(range_m, obstacle):
    """The beam's centre, 8 degrees up, is 0.28 m above the sensor 2 m out and 0.84 m 6 m out: within the
    map's band (1 m), so the echo is in the way, in the map and ahead; 9 m out, 1.25 m: room overhead."""
    mon, memory = monitor()
    mon.collect([overhead_echo(range_m)])
    observation = mon.observe(1.0, 0.0, 0.0, 0.0, speed=2.0, reach=30.0)
    assert (memory.detections > 0) is obstacle
    assert (observation.nearest_ahead is not None) is obstacle
    if obstacle:
        assert observation.nearest_ahead == pytest.approx(range_m * math.cos(math.radians(8.0)), abs=0.01)


@pytest.mark.parametrize("distance", [None, 5.0])
def test_the_overhead_beam_marks_no_free_space(distance):
    """It rises over what the level sonars see: a low wall under it, not yet seen, must stay unknown (a level
    sonar's silence marks the cells along its beam free)."""
    mon, memory = monitor()
    mon.collect([overhead_echo(distance)])
    mon.observe(1.0, 0.0, 0.0, 0.0, speed=2.0)
    ahead = [memory.cell_of(0.0, y) for y in np.arange(1.0, 4.5, 0.5)]
    assert all(memory.grid[cell] == 0 for cell in ahead), [int(memory.grid[cell]) for cell in ahead]
    level = overhead_echo(None, pitch=0.0, beam=7.5)  # the same silence from a level sonar frees them
    mon.collect([level])
    mon.observe(2.0, 0.0, 0.0, 0.0, speed=2.0)
    assert all(memory.grid[cell] < 0 for cell in ahead)
