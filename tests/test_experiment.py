"""One headless run (vehicle.experiment) and ``vehicle experiment`` (vehicle.cli).

Scenes are small VRML files written by the tests (a ground slab and a wall north of
home) and every run uses a 20 m map, so a run takes well under a second.
"""

import gc
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vehicle import __version__
from vehicle.agent.settings import Settings
from vehicle.cli import main
from vehicle.lab.experiment import OUTCOMES, Experiment, run_experiment
from vehicle.mapping.memory_map import MemoryMap
from vehicle.world.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
HEADER = "#VRML V2.0 utf8\n"
README_KEYS = {"mission", "scene", "outcome", "reason", "detections", "cells_ever_hit", "resolution", "sim_time_s",
               "wall_time_s", "distance_m", "seed", "version"}
SMALL = Settings(space_size=20, time_limit=150)


def box(x, y, z, sx, sy, sz):
    return f"Transform {{ translation {x} {y} {z} children Shape {{ geometry Box {{ size {sx} {sy} {sz} }} }} }}\n"


GROUND = box(0, 0, -0.05, 80, 80, 0.1)
WALL = box(0, 4, 2, 8, 0.2, 6)  # south face at y = 3.9
LEG_WALL = box(5, 0, 2, 4, 0.2, 6)  # across the east leg of the square (corners at +-5 m)


@pytest.fixture
def scene_file(tmp_path) -> Path:
    path = tmp_path / "yard.wrl"
    path.write_text(HEADER + GROUND + WALL)
    return path


def run(scene_file, mission="browse", settings=SMALL, **kwargs):
    return run_experiment(Experiment(str(scene_file), mission, settings=settings, **kwargs))


def test_the_result_has_every_key_the_readme_lists(scene_file):
    result = run(scene_file)
    assert README_KEYS <= set(result)
    assert result["outcome"] == "finished"
    assert result["mission"] == "browse" and result["scene"] == "yard.wrl"
    assert result["version"] == __version__ and result["seed"] == 0
    assert result["resolution"] == SMALL.resolution
    assert result["detections"] > 0 and result["cells_ever_hit"] >= result["detections"]
    assert 0 < result["sim_time_s"] < SMALL.time_limit
    assert result["wall_time_s"] >= 0
    assert result["settings"] == SMALL.model_dump()
    json.dumps(result)  # plain JSON


def test_the_same_arguments_and_seed_give_the_same_json_but_for_wall_time(scene_file):
    def stripped():
        result = run(scene_file, "search", seed=7)
        del result["wall_time_s"]
        return json.dumps(result, sort_keys=True)

    first = stripped()
    assert first == stripped()
    assert json.loads(first)["seed"] == 7


def test_a_ctrl_c_while_a_compiled_loop_runs_ends_the_run_as_a_ctrl_c(scene_file):
    """Ctrl-C inside a numba loop surfaces as a SystemError ("returned a result with an exception set") caused by
    the KeyboardInterrupt. The run reported it as its error, with exit code 1 and no log's closing line, where a
    Ctrl-C anywhere else ends it with 130."""
    def interrupted(stepper, readings):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ctrl_c:
            raise SystemError("CPUDispatcher(<function project>) returned a result with an exception set") from ctrl_c

    with pytest.raises(KeyboardInterrupt):
        run_experiment(Experiment(str(scene_file), "browse", settings=SMALL), on_step=interrupted)


def test_a_start_inside_an_obstacle_is_an_error_with_a_reason(scene_file):
    result = run(scene_file, start=(0.0, 3.75))  # the body (0.3 m) would poke into the wall face at y = 3.9
    assert result["outcome"] == "error"
    assert "inside an obstacle" in result["reason"]
    assert result["detections"] == 0
    assert README_KEYS - {"sim_time_s", "distance_m"} <= set(result)


def test_a_run_that_ends_in_a_collision_exits_1_saying_so(tmp_path, capsys):
    """A script running experiments must not take a crash for a flight that went well (it exited 0)."""
    path = tmp_path / "roof.wrl"
    path.write_text(HEADER + GROUND + box(0, 0, 2.6, 12, 12, 0.2))  # a roof 2.5 m over the start
    assert main(["experiment", "--scene", str(path), "--start", "0,0,0.5", "--mission", "square"]) == 1
    assert "square in roof.wrl (copter): collision - collision at x=0.00 y=0.00" in capsys.readouterr().out


def test_an_unreadable_scene_is_an_error(tmp_path):
    result = run(tmp_path / "missing.wrl")
    assert result["outcome"] == "error"
    assert result["reason"]


def test_a_collision_ends_the_run(tmp_path):
    path = tmp_path / "leg.wrl"
    path.write_text(HEADER + GROUND + LEG_WALL)

    def blind(stepper, readings):  # no sonar: neither avoidance nor the monitor can see the wall
        stepper.simulation.sonars.sensors = []

    result = run_experiment(Experiment(str(path), "square", settings=SMALL), on_step=blind)
    assert result["outcome"] == "collision"
    assert "collision" in result["reason"]
    x, y, _ = result["final_position"]
    assert 3 <= x <= 7 and abs(y) < 0.5  # on the wall
    assert result["sim_time_s"] < 60  # the run ended there


def test_the_time_limit_ends_a_run_as_timeout(scene_file):
    result = run(scene_file, "square", settings=SMALL.updated({"time_limit": 10}))
    assert result["outcome"] == "timeout"
    assert "time limit" in result["reason"]
    assert result["sim_time_s"] == pytest.approx(10, abs=0.1)


def test_outcomes_are_the_five_of_the_design():
    assert set(OUTCOMES) == {"finished", "stopped", "collision", "timeout", "error"}


def test_the_scene_default_start_and_given_start_are_used(tmp_path):
    path = tmp_path / "start.wrl"
    path.write_text(HEADER + GROUND + WALL + 'DEF Start Viewpoint { position 3 -2 10 }\n')
    assert run(path)["start"] == [3.0, -2.0]
    assert run(path, start=(-6.0, 1.0))["start"] == [-6.0, 1.0]


def test_waypoints_from_the_scene_hints_are_flown(tmp_path):
    path = tmp_path / "hinted.wrl"
    path.write_text(HEADER + GROUND + 'WorldInfo { info ["waypoints=-3,-3; 3,-3"] }\n')
    result = run(path, "pathfind")
    assert result["outcome"] == "finished", result["reason"]
    assert sum("reached waypoint" in m for m in result["messages"]) == 2


def test_map_out_writes_the_final_map_as_npy_and_png(scene_file, tmp_path):
    out = tmp_path / "maps"
    result = run_experiment(Experiment(str(scene_file), "browse", settings=SMALL, seed=3), map_out=out)
    grid = np.load(out / "yard-browse-3.npy")
    size = round(2 * SMALL.space_size * SMALL.resolution)
    assert grid.shape == (size, size) and grid.dtype == np.int8
    assert int(np.count_nonzero(grid >= MemoryMap.OCCUPIED_AT)) == result["detections"]
    with Image.open(out / "yard-browse-3.png") as picture:
        assert picture.format == "PNG" and max(picture.size) <= 1500  # a picture for people (test_map_picture)


def test_a_loaded_scene_can_be_passed_in(scene_file):
    scene = load_scene(scene_file)
    a = run_experiment(Experiment(str(scene_file), "browse", settings=SMALL), scene=scene)
    b = run(scene_file)
    assert a["detections"] == b["detections"] and a["sim_time_s"] == b["sim_time_s"]


def test_runs_in_one_process_leave_no_map_behind(scene_file):
    """A sweep worker runs hundreds of experiments: each map (megabytes) must go with its run."""
    scene = load_scene(scene_file)
    gc.collect()
    before = {id(o) for o in gc.get_objects() if isinstance(o, MemoryMap)}  # other tests' (a station's) live on
    for _ in range(3):
        run_experiment(Experiment(str(scene_file), "browse", settings=SMALL), scene=scene)
    gc.collect()
    assert not [o for o in gc.get_objects() if isinstance(o, MemoryMap) and id(o) not in before]


# ---- the command line -------------------------------------------------------------------------
def cli(*args, capsys):
    code = main(["experiment", *map(str, args)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_json_prints_one_json_object(scene_file):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = subprocess.run([sys.executable, "-m", "vehicle.cli", "experiment", "--scene", str(scene_file),
                              "--mission", "Browse", "--json", "--set", "space_size=20", "--time-limit", "150"],
                             cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert process.returncode == 0, process.stderr
    lines = process.stdout.strip().splitlines()
    assert len(lines) == 1
    result = json.loads(lines[0])
    assert README_KEYS <= set(result)
    assert result["mission"] == "browse" and result["outcome"] == "finished"
    assert result["settings"]["space_size"] == 20 and result["settings"]["time_limit"] == 150


def test_cli_without_json_prints_a_summary(scene_file, capsys):
    code, out, _ = cli("--scene", scene_file, "--mission", "browse", "--set", "space_size=20",
                       "--time-limit", "150", capsys=capsys)
    assert code == 0
    assert "browse in yard.wrl (copter): finished" in out
    assert "detections" in out


def test_cli_set_of_an_unknown_name_exits_2_with_a_clear_message(scene_file, capsys):
    code, out, err = cli("--scene", scene_file, "--mission", "browse", "--set", "bogus=1", capsys=capsys)
    assert code == 2
    assert out == ""
    assert "unknown setting bogus" in err
    assert "space_size" in err  # the known names are listed


@pytest.mark.parametrize("assignment, words", [("speed=fast", "speed"), ("speed", "name=value"),
                                               ("closeness=-1", "closeness")])
def test_cli_bad_set_values_exit_2(scene_file, capsys, assignment, words):
    code, _, err = cli("--scene", scene_file, "--mission", "browse", "--set", assignment, capsys=capsys)
    assert code == 2
    assert words in err and err.startswith("vehicle experiment:")


def test_cli_config_toml_sets_the_mission_parameters(scene_file, tmp_path, capsys):
    config = tmp_path / "mission.toml"
    config.write_text("space_size = 20\nyaw_step = 30\ntime_limit = 150\n")
    code, out, _ = cli("--scene", scene_file, "--mission", "browse", "--config", config, "--set", "yaw_step=45",
                       "--json", capsys=capsys)
    assert code == 0
    result = json.loads(out)
    assert result["settings"]["space_size"] == 20
    assert result["settings"]["yaw_step"] == 45  # --set wins over the file
    assert result["outcome"] == "finished"


def test_cli_a_start_inside_an_obstacle_exits_1_with_the_error_in_the_json(scene_file, capsys):
    code, out, _ = cli("--scene", scene_file, "--mission", "browse", "--start=0,3.75", "--set", "space_size=20",
                         "--json", capsys=capsys)
    assert code == 1
    result = json.loads(out)
    assert result["outcome"] == "error" and "inside an obstacle" in result["reason"]


def test_cli_negative_start_with_equals(scene_file, capsys):
    code, out, _ = cli("--scene", scene_file, "--mission", "browse", "--start=-6,-2", "--set", "space_size=20",
                       "--time-limit", "150", "--json", capsys=capsys)
    assert code == 0
    result = json.loads(out)
    assert result["start"] == [-6.0, -2.0]
    x, y, _ = result["final_position"]
    assert math.hypot(x + 6, y + 2) < 0.5


def test_cli_scene_hints_apply_below_set(tmp_path, capsys):
    path = tmp_path / "low.wrl"
    path.write_text(HEADER + GROUND + WALL + 'WorldInfo { info ["altitude=1.5" "space_size=20" "yaw_step=20"] }\n')
    code, out, _ = cli("--scene", path, "--mission", "browse", "--set", "yaw_step=30", "--time-limit", "150",
                       "--json", capsys=capsys)
    assert code == 0
    settings = json.loads(out)["settings"]
    assert settings["altitude"] == 1.5 and settings["space_size"] == 20 and settings["yaw_step"] == 30


def test_the_warm_up_flight_reaches_every_compiled_loop():
    """``vehicle sim`` flies it before its link opens: a loop first compiled mid-flight would freeze the
    vehicle for seconds on a fresh install. In a process of its own, so no other test has called them;
    the loops these call are compiled into them."""
    script = """
from vehicle.mapping import planning, tracing
from vehicle.sim import avoidance
from vehicle.world import sonar as sensors
from vehicle.world import collision
from vehicle.lab.experiment import warm_up
from vehicle.agent import traffic
from vehicle.mapping import sharing
warm_up()
loops = [tracing.project, tracing.free_cells, sensors._nearest_echoes, avoidance._nearest_and_ahead,
         planning._supercover_is_clear, collision._nearest, collision._point_triangle_distance, traffic._meet,
         sharing._take]
print([loop.__name__ for loop in loops if not loop.signatures])
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_only_a_ctrl_c_behind_an_error_is_raised_again_and_a_looping_chain_ends():
    """``reraise_ctrl_c`` (used by runs and by the agent's loop): the KeyboardInterrupt two causes deep is raised;
    an error with none behind it, even in a chain that loops, is left to the caller."""
    from vehicle.ctrl_c import reraise_ctrl_c

    inner = KeyboardInterrupt()
    middle = RuntimeError("middle")
    middle.__cause__ = inner
    outer = SystemError("returned a result with an exception set")
    outer.__cause__ = middle
    with pytest.raises(KeyboardInterrupt) as raised:
        reraise_ctrl_c(outer)
    assert raised.value is inner
    first, second = ValueError("a"), ValueError("b")
    first.__context__, second.__context__ = second, first
    assert reraise_ctrl_c(first) is None
