"""Doorways: a map built by the real sonar and monitor from poses in a room lets the planner through a doorway
the body fits through, and refuses one it does not fit, with the reason."""

from __future__ import annotations

import math

import pytest
from conftest import GROUND, vrml_box

from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.planner import MapPlanner
from vehicle.protocol.frames import Pose
from vehicle.world.raycast import RayCaster
from vehicle.world.sonar import SonarArray
from vehicle.world.suites import DEFAULT_SUITE, sensor_suite

RADIUS = 0.3  # the default copter's body
DOOR_X = 0.3  # the doorway's middle; the wall's south face is at y = 3
SURVEY = [(-1.5, -1.5), (1.5, -1.5), (-1.5, 1.5), (1.5, 1.5), (DOOR_X, 1.2)]  # where the vehicle scans around
START, GOAL = (DOOR_X, -1.0), (DOOR_X, 6.0)  # in the room, and in the room beyond the doorway


def two_rooms(make_scene, door: float):
    """Two 6 x 6 m rooms (x -3..3; y -3..3 and 3.1..9), 2.6 m high, joined by a doorway ``door`` m wide in
    the wall between them (0.1 m thick)."""
    walls = [vrml_box(0, -3.1, 1.3, 6.4, 0.2, 2.6), vrml_box(-3.1, 3, 1.3, 0.2, 12.4, 2.6),
             vrml_box(3.1, 3, 1.3, 0.2, 12.4, 2.6), vrml_box(0, 9.1, 1.3, 6.4, 0.2, 2.6)]
    west, east = DOOR_X - door / 2 + 3.0, 3.0 - DOOR_X - door / 2  # lengths of the wall either side
    walls += [vrml_box(-3 + west / 2, 3.05, 1.3, west, 0.1, 2.6), vrml_box(3 - east / 2, 3.05, 1.3, east, 0.1, 2.6)]
    return make_scene(GROUND, *walls)


def surveyed(scene) -> MemoryMap:
    """The memory map after a full turn at each survey pose, 1 m up, with the default sensors, as the monitor
    keeps it (a reading every 0.1 s, a monitor period every two, 10 degrees a period)."""
    settings = Settings()
    sonars = SonarArray(sensor_suite(DEFAULT_SUITE), RayCaster(scene))
    memory = MemoryMap((0.0, 0.0), space_size=10.0, resolution=settings.resolution)
    monitor = Monitor(settings, memory, (0.0, 0.0), RADIUS)
    time = 0.0
    for x, y in SURVEY:
        for step in range(37):
            for _ in range(2):
                time += 0.1
                monitor.collect(sonars.read(Pose(x, y, 1.0, math.radians(10.0 * step)), time))
            monitor.observe(time, x, y, None)
    return memory


def crosses_the_doorway(path: list[tuple[float, float]], door: float) -> bool:
    """Whether the polyline from START crosses the wall's line (y = 3.05) inside the doorway."""
    for (x0, y0), (x1, y1) in zip([START, *path], path, strict=False):
        if (y0 - 3.05) * (y1 - 3.05) <= 0 and y0 != y1:
            x = x0 + (x1 - x0) * (3.05 - y0) / (y1 - y0)
            return abs(x - DOOR_X) < door / 2
    return False


@pytest.mark.parametrize("door", [1.0, 0.9])
def test_a_doorway_the_body_fits_through_is_passed(make_scene, door):
    memory = surveyed(two_rooms(make_scene, door))
    planner = MapPlanner(memory, RADIUS, avoid_margin=0.1)
    path, _ = planner.plan(START, GOAL, padding=Settings().padding)
    assert path is not None, planner.reason
    assert crosses_the_doorway(path, door) and path[-1] == GOAL
    assert all(planner.is_clear(point, 0.0) for point in path[:-1])  # the body and the doorway clearance fit


@pytest.mark.parametrize("door", [0.5, 0.7])
def test_a_doorway_the_body_does_not_fit_through_is_refused_with_the_reason(make_scene, door):
    memory = surveyed(two_rooms(make_scene, door))
    planner = MapPlanner(memory, RADIUS, avoid_margin=0.1)
    path, _ = planner.plan(START, GOAL, padding=Settings().padding)
    assert path is None
    assert planner.reason == "the vehicle is enclosed by known obstacles"


def test_the_sonar_does_not_close_the_doorway_it_saw_from_afar(make_scene):
    """The same rooms, the doorway 1.0 m wide: no cell of the doorway itself is occupied after the survey,
    though every pose but the last sees it from 2.5 m or further, where the cone is wider than 0.6 m."""
    memory = surveyed(two_rooms(make_scene, 1.0))
    inside = [memory.cell_of(DOOR_X + dx / 10, 3.05) for dx in range(-3, 4)]
    assert not any(memory.occupied[cell] for cell in inside)
    assert memory.occupied[memory.cell_of(-1.5, 2.95)] or memory.occupied[memory.cell_of(-1.5, 3.05)]  # the wall
