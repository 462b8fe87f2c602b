"""A team searching splits the area by where each vehicle is, and a vehicle whose share is searched helps in a
team-mate's instead of ending while frontiers are left."""

from __future__ import annotations

import math
from pathlib import Path

from vehicle.agent.agent import Phase
from vehicle.agent.settings import load_settings
from vehicle.lab.stepper import simulate_team
from vehicle.world.scene import load_scene

DEFAULT = Path(__file__).resolve().parent.parent / "scenes" / "default.wrl"


def test_the_vehicle_in_the_middle_of_a_team_of_eight_searches_on_past_its_own_share():
    """Vehicle 1 starts in the middle of the team's spots, its share a few metres across: after its first scan
    every goal and frontier lay in a team-mate's share, and it ended its Search ("no reachable frontier left")
    a quarter of a minute after take-off while the team's area was still mostly unknown. Now it flies to the
    nearest frontier, says so, and is still searching a minute and a half later, far from home."""
    scene = load_scene(DEFAULT)
    settings = load_settings(scene_hints=scene.hints).updated({"time_limit": 300})
    stepper = simulate_team(scene, "search", 8, settings=settings)
    middle = stepper.agents[0]
    while stepper.team.time < 90:
        stepper.step()
    assert stepper.team.simulations[0].collision is None
    assert middle.phase is Phase.MISSION, list(middle.messages)
    assert any(m.startswith("Search: nothing left to search in this vehicle's share; helping at")
               for m in middle.messages), list(middle.messages)
    x, y = middle.ctx.position
    assert math.hypot(x - middle.ctx.home[0], y - middle.ctx.home[1]) > 5.0, (x, y)
