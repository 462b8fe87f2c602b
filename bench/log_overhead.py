"""What ``vehicle experiment --log`` adds to a run: Search, Browse and Pathfind in castle.wrl from (-40, 0).

Each mission runs as the command line runs it, in a fresh process, without and with ``--log``: the
figures are the whole process's time (what one waits for) and the run's ``wall_time_s`` (in a fresh
process that includes loading the compiled loops, about 0.3 s, which the log starts before the run's
clock does). Then the same runs in this process after a warm-up, the run alone: the strictest figure.
Each figure is the best of --repeats, runs alternating with and without the log. Target: the log adds
at most 25%.
Run: python bench/log_overhead.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, castle_or_default, code_state, table

from vehicle.agent.settings import load_settings
from vehicle.lab.experiment import Experiment, run_experiment, warm_up
from vehicle.lab.log import ExperimentLog
from vehicle.world.scene import load_scene

MISSIONS = ["search", "browse", "pathfind"]
TARGET = 0.25


def command_line(scene: Path, start: list[str], mission: str, log: Path | None) -> tuple[float, float]:
    """(process seconds, wall_time_s) of one ``vehicle experiment`` process."""
    command = [sys.executable, "-m", "vehicle.cli", "experiment", "--scene", str(scene), *start,
               "--mission", mission, "--json"] + (["--log", str(log)] if log else [])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=True, cwd=ROOT)
    return time.perf_counter() - started, json.loads(done.stdout)["wall_time_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description="The cost of vehicle experiment --log.")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each, best counts (default %(default)s)")
    repeats = max(1, parser.parse_args().repeats)
    scene_path = castle_or_default()
    start = ["--start=-40,0"] if scene_path.name == "castle.wrl" else []
    load = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        log_path = Path(folder) / "run.tlog"
        best: dict[tuple[str, bool], list[float]] = {}
        for _ in range(repeats):
            for mission in MISSIONS:
                for logged in (False, True):
                    process, wall = command_line(scene_path, start, mission, log_path if logged else None)
                    old = best.get((mission, logged), [float("inf")] * 2)
                    best[mission, logged] = [min(old[0], process), min(old[1], wall)]
        warm_up()
        scene = load_scene(scene_path)
        settings = load_settings(scene_hints=scene.hints)
        runs: dict[tuple[str, bool], float] = {}
        for _ in range(repeats):
            for mission in MISSIONS:
                experiment = Experiment(str(scene_path), mission, "copter", (-40.0, 0.0) if start else None,
                                        None, settings)
                for logged in (False, True):
                    started = time.perf_counter()
                    log = ExperimentLog(log_path) if logged else None
                    run_experiment(experiment, scene=scene, on_step=log)
                    if log is not None:
                        log.close()
                    seconds = time.perf_counter() - started
                    runs[mission, logged] = min(runs.get((mission, logged), float("inf")), seconds)
        for mission in MISSIONS:
            plain, logged = best[mission, False], best[mission, True]
            warm_plain, warm_logged = runs[mission, False], runs[mission, True]
            rows.append([mission, f"{plain[0]:.2f} / {logged[0]:.2f} s", f"{logged[0] / plain[0] - 1:+.0%}",
                         f"{plain[1]:.3f} / {logged[1]:.3f} s", f"{logged[1] / plain[1] - 1:+.0%}",
                         f"{warm_plain * 1000:.0f} / {warm_logged * 1000:.0f} ms",
                         f"{warm_logged / warm_plain - 1:+.0%}"])
    print(table(["mission", "process, without / with --log", "added", "wall_time_s, without / with", "added",
                 "warmed run, without / with (log closed)", "added"], rows))
    print()
    print(f"Scene {scene_path.name}{' from (-40, 0)' if start else ''}; best of {repeats}; target: at most "
          f"{TARGET:.0%} added. Load average before/after: {load:.1f}/{os.getloadavg()[0]:.1f}. "
          f"Vehicle code: {code_state()}.")


if __name__ == "__main__":
    main()
