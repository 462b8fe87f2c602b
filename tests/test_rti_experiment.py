"""Tomography experiments: vehicle experiment --mission rti reports what the image found and when, and vehicle
sweep sweeps the team size, the targets and the planner."""

from __future__ import annotations

import csv

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
