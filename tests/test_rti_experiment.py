"""Tomography experiments: vehicle experiment --mission rti reports what the image found and when, and vehicle
sweep sweeps the team size, the targets and the planner."""

from __future__ import annotations

import csv

import pytest

from vehicle.lab.sweep import Job, SweepSpec, run_local, run_sweep

YARD = """#VRML V2.0 utf8
WorldInfo { info ["space_size=30" "time_limit=150" "waypoints=-3,-3; 3,-3"] }
Transform { translation 0 0 -0.05 children Shape { geometry Box { size 80 80 0.1 } } }
"""


def test_the_sweep_sweeps_the_team_size(tmp_path):
    scene = tmp_path / "yard.wrl"
    scene.write_text(YARD)
    spec = SweepSpec(["pathfind"], [str(scene)], {}, teams=[1, 2])
    jobs = spec.jobs()
    assert [j.vehicles for j in jobs] == [1, 2]
    results = {r["team"] if "team" in r else 1: r for r in run_local(jobs, workers=1)}
    assert results[1]["outcome"] == results[2]["outcome"] == "finished"
    assert "vehicles" not in results[1] and len(results[2]["vehicles"]) == 2
    run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    with open(tmp_path / "out" / "results.csv", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["team"] or "1" for row in rows] == ["1", "2"]
    assert Job(str(scene), "pathfind", (), 0, "copter", 2, "") in jobs


REGION = {"rti_x0": 4.0, "rti_y0": 4.0, "rti_x1": 10.0, "rti_y1": 10.0, "rti_dwell": 2.0, "time_limit": 300}


def rti_run(scene, targets, planner="perimeter", rounds=16, calibrated=True, **settings):
    from vehicle.agent.settings import Settings
    from vehicle.lab.experiment import Experiment
    from vehicle.lab.tomograph import run_team_experiment

    values = {**REGION, "rti_planner": planner, "rti_rounds": rounds, **settings}
    experiment = Experiment("flat.wrl", "rti", settings=Settings().updated(values), seed=3)
    return run_team_experiment(experiment, scene, 2, targets, calibrated=calibrated)


def test_a_team_finds_a_target_and_says_when_and_from_how_many_links(flat_scene):
    result = rti_run(flat_scene, [(7.3, 6.4)])
    rti = result["rti"]
    assert result["outcome"] == "finished", result["reason"]
    assert rti["found"] and rti["distances_m"][0] <= 0.5
    assert rti["found_s"] is not None and rti["found_s"] <= result["sim_time_s"]
    # distance over time: one row per image, the last one the final distance; the early images are worse
    assert rti["over_time"][-1][1:] == rti["distances_m"]
    assert rti["over_time"][0][1] is None or rti["over_time"][0][1] > rti["distances_m"][0]
    # only the links measured while both held their spots are imaged: one path a round
    assert 0 < rti["links_imaged"] < rti["links_heard"]
    assert rti["paths"] == 16


def test_without_the_empty_area_capture_the_levels_come_from_a_path_loss_model(flat_scene, monkeypatch):
    """As the station's live image: the empty twin is not read at all, and in the open the model's levels find
    the target as well."""
    from vehicle.lab import tomograph

    seen = []
    real = tomograph.reconstruct
    monkeypatch.setattr(tomograph, "reconstruct", lambda *a, **k: seen.append(k) or real(*a, **k))
    rti = rti_run(flat_scene, [(7.3, 6.4)], calibrated=False)["rti"]
    assert rti["found"] and rti["distances_m"][0] <= 0.5
    assert seen and all("calibration" not in k and k["empty_from"] == "brief" for k in seen)


def test_without_a_target_no_peak_is_called_found(flat_scene):
    rti = rti_run(flat_scene, [], rounds=6)["rti"]
    assert rti["targets"] == [] and rti["distances_m"] == [] and rti["peaks"] == []
    assert rti["links_imaged"] > 0


def test_the_sweep_sweeps_targets_and_the_planner(tmp_path):
    scene = tmp_path / "yard.wrl"
    scene.write_text(YARD)
    grid = {**{k: [v] for k, v in REGION.items()}, "rti_rounds": [6], "rti_planner": [0, 1]}
    spec = SweepSpec(["rti"], [str(scene)], grid, teams=[2], targets=["7,7", "5,5;9,9"])
    assert len(spec.jobs()) == 4
    run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    with open(tmp_path / "out" / "results.csv", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["rti_planner"], r["targets_spec"]) for r in rows] == [
        ("0.0", "7,7"), ("0.0", "5,5;9,9"), ("1.0", "7,7"), ("1.0", "5,5;9,9")]
    assert all(r["team"] == "2" and int(r["rti_links_imaged"]) > 0 and r["rti_found"] in ("True", "False")
               for r in rows)


def test_bad_targets_are_refused_before_any_run():
    with pytest.raises(ValueError, match="target 'x,1' is not X,Y"):
        SweepSpec(["rti"], ["a.wrl"], {}, targets=["x,1"])


def test_a_run_may_end_with_the_missions(flat_scene):
    from vehicle.agent.settings import Settings
    from vehicle.lab.experiment import Experiment
    from vehicle.lab.tomograph import run_team_experiment

    settings = Settings().updated({**REGION, "rti_rounds": 3})
    whole = run_team_experiment(Experiment("flat.wrl", "rti", settings=settings), flat_scene, 2, [(7.0, 7.0)])
    short = run_team_experiment(Experiment("flat.wrl", "rti", settings=settings), flat_scene, 2, [(7.0, 7.0)],
                                until_mission_end=True)
    assert whole["outcome"] == "finished" and short["outcome"] == "timeout"
    assert all("Mission rti: finished" in v["messages"][-1] for v in short["vehicles"])
    assert short["sim_time_s"] < whole["sim_time_s"]
    assert short["rti"]["links_imaged"] == whole["rti"]["links_imaged"] > 0
