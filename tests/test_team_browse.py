"""A team browsing splits the area: each vehicle browses from a spot in its own share, out from the team's centre,
instead of all turning at their homes a few metres apart."""

from __future__ import annotations

from pathlib import Path

from vehicle.agent.settings import load_settings
from vehicle.lab.experiment import Experiment, run_team
from vehicle.lab.stepper import simulate_team
from vehicle.world.scene import load_scene

DEFAULT = Path(__file__).resolve().parent.parent / "scenes" / "default.wrl"


def browse(count: int) -> tuple[dict, list]:
    scene = load_scene(DEFAULT)
    settings = load_settings(scene_hints=scene.hints).updated({"time_limit": 120})
    stepper = simulate_team(scene, "browse", count, settings=settings)
    return run_team(Experiment("default.wrl", "browse", settings=settings), stepper), stepper.agents


def test_a_team_of_two_browsing_knows_far_more_than_one():
    """In the default scene one vehicle's turn finds 94 occupied cells; two turning at their homes 5 m apart found
    160, and now, each from its own spot 10 m out, 342: over three times one's."""
    (one, alone), (two, agents) = browse(1), browse(2)
    assert [v["outcome"] for v in two["vehicles"]] == ["finished", "finished"]
    assert two["detections"] >= 3 * one["detections"], (one["detections"], two["detections"])
    assert all(any(m.startswith("Browse: browsing from") for m in a.messages) for a in agents)
    assert not any(m.startswith("Browse: browsing from") for m in alone[0].messages)  # alone: at home


def test_each_vehicle_browses_in_its_own_share():
    """The spots are each nearer to their own vehicle's start than to any other's (the Voronoi split), and the
    team's vehicles turn far apart."""
    result, agents = browse(3)
    assert [v["outcome"] for v in result["vehicles"]] == ["finished"] * 3
    assert result["closest_vehicles_m"] >= 2.0
    starts = [a.ctx.home for a in agents]
    for k, agent in enumerate(agents):
        said = next(m for m in agent.messages if m.startswith("Browse: browsing from"))
        spot = tuple(float(v) for v in said.split("(")[1].split(")")[0].split(","))
        mine = _dist(spot, starts[k])
        assert all(mine < _dist(spot, s) for j, s in enumerate(starts) if j != k)


def _dist(a, b) -> float:
    return ((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2) ** 0.5
