"""Parameter sweeps (vehicle.sweep, ``vehicle sweep``): jobs, local workers, Dask, and the files written.

The sweep runs in a small scene written by the test, whose WorldInfo suggests a
20 m map, a short time limit and two pathfind waypoints, so each run takes a
fraction of a second of CPU.
"""

import csv

import pytest

from vehicle import __version__
from vehicle.agent.settings import Settings
from vehicle.cli import main
from vehicle.lab.sweep import Job, SweepSpec, best_runs, markdown_table, parse_grid, run_local, run_sweep

SCENE = """#VRML V2.0 utf8
WorldInfo { info ["space_size=20" "time_limit=120" "waypoints=-3,-3; 3,-3"] }
Transform { translation 0 0 -0.05 children Shape { geometry Box { size 80 80 0.1 } } }
Transform { translation 0 4 2 children Shape { geometry Box { size 8 0.2 6 } } }
"""
MISSIONS = ["browse", "pathfind"]
GRID = {"padding": [0.1, 0.5]}


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "yard.wrl"
    path.write_text(SCENE)
    return str(path)


@pytest.fixture(scope="module")
def spec(scene_path):
    return SweepSpec(MISSIONS, [scene_path], GRID)


@pytest.fixture(scope="module")
def local(spec, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    return out, run_sweep(spec, out, workers=2, progress=False)


def per_run(results):
    return {(r["mission"], r["swept"]["padding"]): r["detections"] for r in results}


# ---- jobs and the grid --------------------------------------------------------------------------
def test_jobs_are_the_product_of_missions_scenes_settings_and_seeds():
    spec = SweepSpec(["browse", "search"], ["a.wrl", "b.wrl@-40,0"], {"padding": [0.1, 2, 4], "resolution": [1, 10]},
                     seeds=2)
    jobs = spec.jobs()
    assert len(jobs) == 2 * 2 * 6 * 2
    assert len(set(jobs)) == len(jobs)
    assert {j.seed for j in jobs} == {0, 1}
    assert jobs[0] == Job("a.wrl", "browse", (("padding", 0.1), ("resolution", 1)), 0, "copter")


def test_a_job_scene_may_carry_a_start():
    job = Job("scenes/castle.wrl@-40,0.5", "browse", ())
    assert job.scene_path == "scenes/castle.wrl"
    assert job.start == (-40.0, 0.5)
    assert Job("x.wrl", "browse", ()).start is None


def test_an_empty_grid_is_one_combination():
    assert len(SweepSpec(["browse"], ["a.wrl"]).jobs()) == 1


def test_parse_grid_reads_known_settings():
    assert parse_grid(["padding=0.1,2,4", "closeness = 0.1, 2"]) == {"padding": [0.1, 2.0, 4.0],
                                                                     "closeness": [0.1, 2.0]}
    assert parse_grid([]) == {}


@pytest.mark.parametrize("item", ["bogus=1,2", "padding", "Padding=1", "=1,2"])
def test_parse_grid_rejects_unknown_names_and_malformed_items(item):
    with pytest.raises(ValueError, match="--grid"):
        parse_grid([item])


@pytest.mark.parametrize("item", ["padding=a,b", "padding=1,x", "padding=", "padding=,"])
def test_parse_grid_rejects_values_that_are_not_numbers_or_none(item):
    """``padding=`` was an internal error (zip() argument 2 is shorter than argument 1), ``1,x`` a bare
    'could not convert string to float'."""
    with pytest.raises(ValueError, match=f"--grid wants SETTING=V1,V2,... with numbers, not '{item}'"):
        parse_grid([item])


# ---- a tiny sweep on local workers ----------------------------------------------------------------
def test_a_local_sweep_writes_one_csv_row_per_run_with_seed_and_version(local):
    out, results = local
    with open(out / "results.csv", newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(results) == 4
    assert {"scene_spec", "mission", "seed", "version", "outcome", "detections", "sim_time_s",
            *Settings.model_fields} <= set(rows[0])
    assert [(r["mission"], float(r["padding"])) for r in rows] == [
        ("browse", 0.1), ("browse", 0.5), ("pathfind", 0.1), ("pathfind", 0.5)]  # in the order of the spec
    assert {r["seed"] for r in rows} == {"0"}
    assert {r["version"] for r in rows} == {__version__}
    assert {float(r["space_size"]) for r in rows} == {20.0}  # the scene's suggestion
    assert [int(r["detections"]) for r in rows] == [r["detections"] for r in results]


def test_the_local_runs_finish_in_the_small_scene(local):
    _, results = local
    assert all(r["outcome"] == "finished" for r in results), [(r["mission"], r["reason"]) for r in results]
    assert all(r["detections"] > 0 for r in results)


def test_a_local_sweep_writes_best_md_in_the_form_of_table_1(local):
    out, results = local
    text = (out / "best.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert lines[0] == "| mission | yard |"
    best = {m: max(r["detections"] for r in results if r["mission"] == m) for m in MISSIONS}
    for mission in MISSIONS:
        row = next(line for line in lines if line.startswith(f"| {mission} |"))
        assert f"| {best[mission]}, " in row


def test_a_local_sweep_draws_the_best_maps(local):
    out, _ = local
    pictures = sorted(p.name for p in (out / "maps").glob("*.png"))
    assert pictures == ["yard-browse-0.png", "yard-pathfind-0.png"]


def test_one_worker_gives_the_same_results(spec, local):
    _, results = local
    assert per_run(run_local(spec.jobs(), workers=1)) == per_run(results)


def test_a_dask_cluster_gives_the_same_detections_per_run(spec, local, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    _, results = local
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) \
            as cluster:
        on_dask = run_sweep(spec, tmp_path, dask=cluster, progress=False)
    assert per_run(on_dask) == per_run(results)
    assert (tmp_path / "results.csv").exists() and (tmp_path / "best.md").exists()


# ---- ranking and the table ----------------------------------------------------------------------
def run_result(mission, scene, outcome, detections):
    return {"mission": mission, "scene": f"{scene}.wrl", "outcome": outcome, "detections": detections,
            "sim_time_s": 61}


def test_best_runs_rank_safe_endings_first_then_timeouts_then_collisions_and_errors():
    results = [run_result("square", "castle", "collision", 50), run_result("square", "castle", "stopped", 8),
               run_result("square", "castle", "error", 99), run_result("browse", "castle", "finished", 20),
               run_result("browse", "castle", "timeout", 25), run_result("search", "castle", "timeout", 5),
               run_result("search", "castle", "collision", 90)]
    best = best_runs(results)
    assert best[("square", "castle")]["detections"] == 8
    assert best[("browse", "castle")]["detections"] == 20
    assert best[("search", "castle")]["outcome"] == "timeout"


def test_the_table_shows_outcome_time_and_the_thesis_figure():
    best = best_runs([run_result("search", "castle", "finished", 150), run_result("square", "castle", "stopped", 9),
                      run_result("search", "mine", "finished", 30)])
    table = markdown_table(best)
    assert "| search | 150, 00:01:01 vs 140 | 30, 00:01:01 |" in table
    assert "| square | 9 (stopped), 00:01:01 vs 6 | - |" in table


# ---- the command line -----------------------------------------------------------------------------
def test_cli_sweep_prints_the_table_and_writes_the_results(scene_path, tmp_path, capsys):
    out = tmp_path / "cli"
    code = main(["sweep", "--missions", "browse", "--scene", scene_path, "--grid", "padding=0.1,0.5",
                 "--workers", "1", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0
    assert "| browse |" in captured.out and "outcomes: finished 2" in captured.out
    assert "2 runs" in captured.err
    assert (out / "results.csv").exists()


@pytest.mark.parametrize("args, message", [
    (["--missions", "hover"], "unknown mission 'hover'"),
    (["--grid", "bogus=1"], "--grid"),
    # found only once the runs had started, in a worker (the others' results were lost)
    (["--grid", "speed=2,0.01"], "--grid: speed: Input should be greater than or equal to 0.1 (got 0.01)"),
    (["--grid", "space_size=1000", "--grid", "resolution=5"], "--grid: space_size 1000 m at resolution 5"),
])
def test_cli_sweep_refuses_unknown_names_and_bad_values_before_any_run(scene_path, tmp_path, capsys, args,
                                                                        message):
    code = main(["sweep", "--scene", scene_path, "--workers", "1", "--out", str(tmp_path), *args])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())  # nothing ran


@pytest.mark.parametrize("spec", ["x.wrl@a,b", "x.wrl@1", "x.wrl@1,nan", "x.wrl@"])
def test_a_scene_start_that_is_no_point_is_refused_before_any_run(spec):
    with pytest.raises(ValueError, match="--scene wants FILE or FILE@X,Y"):
        SweepSpec(["browse"], [spec])


def test_a_scene_start_far_from_the_scene_is_refused_before_any_run():
    with pytest.raises(ValueError, match="more than 100 km from the scene's origin"):
        SweepSpec(["browse"], ["x.wrl@1e9,0"])
    SweepSpec(["browse"], ["x.wrl@-99000,99000"])  # far, and still a place
