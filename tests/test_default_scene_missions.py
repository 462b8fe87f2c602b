"""Every default waypoint of every mission in the demo scene is reachable: Square and Pathfind fly the corners
of a square round home, a corner inside a building pulled towards home until it is clear (the simulator knows
the scene, the agent does not), each clear of every building at the flight altitude, and Pathfind visits them
all. Before, the south-west corner lay inside the Office and Pathfind always ended "stopped, waypoints 4
unreachable"."""

from __future__ import annotations

import math

import pytest

from groundstation.commands import solid_at
from vehicle.agent.missions import mission_class
from vehicle.agent.missions.square import square_corners
from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, run_experiment
from vehicle.lab.stepper import simulate
from vehicle.world.bundled import default_scene

CLEAR = 2.0  # m round a waypoint that must be free of every building
WAYPOINT_MISSIONS = ("pathfind", "square")  # the missions that fly to waypoints


def defaults(scene, mission: str) -> list[tuple[float, float]]:
    """The waypoints a mission flies in the scene from its start when given none."""
    agent = simulate(scene, mission).agent
    return list(agent.ctx.waypoints or square_corners(agent.ctx.home, agent.settings.space_size))


def test_the_missions_that_fly_waypoints_are_these():
    for name in WAYPOINT_MISSIONS:
        assert mission_class(name)  # a renamed mission fails here rather than being left out below


@pytest.mark.parametrize("mission", WAYPOINT_MISSIONS)
def test_every_default_waypoint_is_clear_of_the_buildings(scene, mission):
    altitude = Settings().altitude
    points = defaults(scene, mission)
    assert len(points) == 4 and points[:3] == square_corners((0.0, 0.0), Settings().space_size)[:3]  # moved: one
    for x, y in points:
        for r in (0.0, CLEAR):
            for k in range(12):
                a = k * math.pi / 6
                inside = solid_at(scene, x + r * math.cos(a), y + r * math.sin(a), altitude)
                assert inside is None, f"waypoint ({x:g}, {y:g}) is within {CLEAR:g} m of {inside}"


def test_pathfind_reaches_every_default_waypoint(scene):
    """(Square flies its legs straight, in AUTO, and stops at an obstacle on the way: which its waypoints are
    does not change that.)"""
    result = run_experiment(Experiment(str(default_scene()), "pathfind"), scene=scene)
    assert (result["outcome"], result["reason"]) == ("finished", "mission complete")
