"""Every mission in every scene, with default settings (plus the scene's suggestions), beside the thesis.

Scenes: castle.wrl from start (-40, 0) (the project's default scene when ../shared is
absent), then the project's default, trees, house and apartment scenes from their own starts. Each
mission prints its outcome, detections (occupied cells at the end), cells ever hit,
simulated and wall time and the speed-up, beside the thesis's Table 1 count for that
mission and scene where there is one. Runs are deterministic, so all of them run
--repeats times, in rounds, and each one's fastest wall time counts: on a shared
machine the same run can take twice as long during a spell of a few seconds when
other work competes for the cores. They run one after another in this process.
Target: a whole mission at least 1000x faster than real time. Scene loading and
preparation (once per scene) and the process warm-up are timed apart.
Run: python bench/missions.py [--sensors single|triple|servo] [--repeats 7]
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

from common import CASTLE, ROOT, castle_or_default, code_state, table

from vehicle.agent.settings import load_settings
from vehicle.lab.experiment import Experiment, run_experiment, warm_up
from vehicle.lab.presets import THESIS_TABLE
from vehicle.sim.simulation import Simulation
from vehicle.world.scene import load_scene
from vehicle.world.suites import DEFAULT_SUITE, SENSOR_SUITES

MISSIONS = ["square", "browse", "search", "pathfind"]
TARGET = 1000.0


def scenes() -> list[tuple[Path, tuple[float, float] | None]]:
    first = castle_or_default()
    out = [(first, (-40.0, 0.0) if first == CASTLE else None)]
    out += [(ROOT / "scenes" / name, None) for name in ("default.wrl", "trees.wrl", "house.wrl", "apartment.wrl")]
    return list(dict.fromkeys(out))  # the default scene once when castle is absent


def main() -> None:
    parser = argparse.ArgumentParser(description="Every mission in every scene, timed.")
    parser.add_argument("--sensors", default=DEFAULT_SUITE, choices=list(SENSOR_SUITES),
                        help="sensor suite (default %(default)s; the thesis's vehicle had a single sonar)")
    parser.add_argument("--repeats", type=int, default=7,
                        help="rounds over all missions; each one's fastest run counts (default %(default)s)")
    args = parser.parse_args()
    suite, repeats = args.sensors, max(1, args.repeats)
    load = os.getloadavg()[0]
    warmed = warm_up()  # loads the compiled loops (compiles them on a fresh install)
    runs = []  # (where, prepared s, experiment, scene)
    for path, start in scenes():
        scene = load_scene(path)
        settings = load_settings(scene_hints=scene.hints)
        started = time.perf_counter()
        Simulation(scene, "copter", start)  # builds the scene's ray-casting BVH and collision grid
        prepared = time.perf_counter() - started
        where = f"{path.name}" + (f" @{start[0]:g},{start[1]:g}" if start else "")
        runs += [(where, prepared, Experiment(str(path), mission, "copter", start, None, settings, sensors=suite),
                  scene) for mission in MISSIONS]
    walls = [math.inf] * len(runs)
    results: list[dict] = [{}] * len(runs)
    for _ in range(repeats):  # rounds over all runs, so a slow spell of the machine spoils one round, not a mission
        for index, (_where, _prepared, experiment, scene) in enumerate(runs):
            started = time.perf_counter()
            results[index] = run_experiment(experiment, scene=scene)
            walls[index] = min(walls[index], time.perf_counter() - started)
    rows = []
    total_sim = total_wall = 0.0
    slowest = None
    for (where, prepared, experiment, _scene), result, wall in zip(runs, results, walls, strict=True):
        mission, stem = experiment.mission, Path(experiment.scene).stem
        sim = result.get("sim_time_s", 0.0)
        total_sim += sim
        total_wall += wall
        speedup = sim / wall if wall > 0 else float("inf")
        if slowest is None or speedup < slowest[0]:
            slowest = (speedup, f"{mission} in {Path(experiment.scene).name}")
        thesis = THESIS_TABLE[mission].get(stem)
        rows.append([where, f"{prepared * 1000:.0f}", mission, result["outcome"], result["reason"],
                     result["detections"], result["cells_ever_hit"], "-" if thesis is None else thesis,
                     f"{sim:.1f}", f"{wall:.2f}", f"{speedup:,.0f}x"])
    print(table(["scene", "prepare ms", "mission", "outcome", "reason", "detections", "cells ever hit",
                 "thesis (Table 1)", "simulated s", "wall s", "speed-up"], rows))
    overall = total_sim / total_wall if total_wall > 0 else float("inf")
    print()
    print(table(["simulated s", "wall s", "overall speed-up", "slowest mission", "target"],
                [[f"{total_sim:.0f}", f"{total_wall:.1f}", f"{overall:,.0f}x",
                  f"{slowest[1]}: {slowest[0]:,.0f}x" if slowest else "-", f">= {TARGET:.0f}x per mission"]]))
    print()
    print(f"Every mission ran {repeats} times, in rounds over all of them (runs are deterministic); its wall time "
          "is its fastest run's.")
    print(f"Not counted in the missions' times: loading each scene and preparing it once (the ray-casting BVH and "
          f"collision grid every run in it shares, 'prepare ms'), and the process's warm-up ({warmed:.2f} s: "
          "a short flight in a built-in scene that loads the compiled loops).")
    print(f"Copter with the {suite} sensor suite, default settings plus each scene's suggestions (house: "
          "altitude 1.6, padding 0.1, closeness 0.8, "
          "space_size 10, its waypoints; apartment: the same but space_size 15). The thesis's figures are its best "
          "over a 48-setting sweep (its Square "
          f"runs all collided); these are single runs. Load average before/after: {load:.1f}/{os.getloadavg()[0]:.1f} "
          f"(other processes on the machine slow the wall times). Vehicle code: {code_state()}.")


if __name__ == "__main__":
    main()
