"""``vehicle experiment --vehicles N``: a team headless on simulated time, its JSON, and what it refuses."""

from __future__ import annotations

import json

import pytest

from vehicle.agent.settings import Settings
from vehicle.cli import main
from vehicle.lab.experiment import Experiment, run_team
from vehicle.lab.stepper import simulate_team
from vehicle.world.collision import Contact


def experiment(capsys, *args: str) -> tuple[int, dict | str]:
    code = main(["experiment", *args])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 and "--json" in args else err)


def test_a_team_reports_every_vehicle_and_the_closest_approaches(capsys, flat_scene, tmp_path):
    args = ["--mission", "pathfind", "--vehicles", "2", "--time-limit", "150", "--json"]
    code, result = experiment(capsys, *args)
    assert code == 0
    assert result["team"] == 2 and result["share_maps"] is True
    assert [v["sysid"] for v in result["vehicles"]] == [1, 2]
    assert [v["start"] for v in result["vehicles"]] == [[0.0, 0.0], [-4.0, -4.0]]  # the demo's spots
    for v in result["vehicles"]:
        assert {"outcome", "reason", "detections", "cells_ever_hit", "distance_m", "closest_scene_m"} <= set(v)
        assert v["closest_scene_m"] is not None and v["closest_scene_m"] > 0
    assert result["closest_vehicles_m"] >= 2.0 and result["closest_pair"] == [1, 2]
    assert result["outcome"] != "collision" and all(v["outcome"] != "collision" for v in result["vehicles"])
    # the same command line gives the same JSON (but the wall time)
    code, again = experiment(capsys, *args)
    for run in (result, again):
        run.pop("wall_time_s")
    assert again == result


def test_share_maps_off_is_said_and_each_map_is_its_own(capsys):
    code, result = experiment(capsys, "--mission", "browse", "--vehicles", "2", "--set", "share_maps=0", "--json")
    assert code == 0 and result["share_maps"] is False and result["cells_shared"] == 0
    code, shared = experiment(capsys, "--mission", "browse", "--vehicles", "2", "--json")
    assert shared["cells_shared"] > 0
    # sharing, each vehicle's map holds what the other found too
    assert min(v["detections"] for v in shared["vehicles"]) > max(v["detections"] for v in result["vehicles"])


@pytest.mark.parametrize("args, words", [
    (["--vehicles", "0"], "1 to 8"),
    (["--vehicles", "2", "--start", "0,0", "--start", "0.3,0"], "start inside each other"),
    (["--vehicles", "2", "--sysids", "4,4"], "system id 4"),
    (["--vehicles", "2", "--sysids", "1,2,3"], "--sysids names 3"),
    (["--vehicles", "2", "--start", "0,0"], "once per vehicle"),
])
def test_a_team_that_cannot_be_is_a_usage_error_before_anything_flies(capsys, args, words):
    with pytest.raises(SystemExit) if args[1] == "0" else _returns(2):
        code, err = experiment(capsys, "--mission", "browse", *args)
        assert code == 2 and words in err and "Traceback" not in err
    if args[1] == "0":
        assert words in capsys.readouterr().err


class _returns:
    """A context that expects no exception (the code is checked inside)."""

    def __init__(self, code):
        self.code = code

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_a_vehicle_that_crashes_mid_run_is_reported_and_the_rest_fly_on(flat_scene):
    settings = Settings().updated({"time_limit": 150})
    stepper = simulate_team(flat_scene, "pathfind", 3, settings=settings)
    for _ in range(400):  # 20 s in
        stepper.step()
    wreck = stepper.team.simulations[1]
    wreck.crash(Contact(point=wreck.pose.xyz(), fraction=0.0, face=0))
    result = run_team(Experiment("flat.wrl", "pathfind", settings=settings), stepper)
    first, wreck, third = result["vehicles"]
    assert wreck["outcome"] == "collision"
    assert result["outcome"] == "collision" and "vehicle 2: collision" in result["reason"]
    for flew_on in (first, third):  # the rest flew their squares on, to the end of the mission
        assert flew_on["outcome"] in ("finished", "stopped")
        assert any("reached waypoint 3" in m for m in flew_on["messages"])
