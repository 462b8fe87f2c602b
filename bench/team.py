"""A team in one world: its speed, its safety over many runs, and what it finds together.

1. Simulated seconds per wall second of teams of 1, 2, 4 and 8 copters flying
   Search in the default scene in this one process, beside a lone vehicle
   (``simulate``, as before teams) in the same run. Goals: a team of 1 within
   5 % of the lone vehicle; a team of N at least 1/N of it (a vehicle in a team
   costs no more than a lone one).
2. Many team runs (2 to 8 copters, the project's scenes, random starts around
   the scene's start, Search and Pathfind): collisions between vehicles or with
   the scene (goal: none) and the closest approach between vehicles; each
   collision with the ``vehicle experiment`` command that flies that run again
   (its starts to the last digit: a team's flight changes with a start's last
   digits).
3. Occupied cells found by a team of 4 and by one vehicle in the same simulated
   time in the default scene (goal: 2.5 times).

Run: python bench/team.py [--runs 40] [--seconds 120] [--seed 1] [--only speed|safety|coverage] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import os
import random
import time

from common import DEFAULT_SCENE, ROOT, table

from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, run_team, warm_up
from vehicle.lab.stepper import TEAM_SPOTS, simulate, simulate_team
from vehicle.sim.simulation import PlacementError
from vehicle.world.scene import load_scene

SCENES = [DEFAULT_SCENE, ROOT / "scenes" / "trees.wrl", ROOT / "scenes" / "house.wrl"]


def speed(scene, seconds: float, repeats: int = 3) -> list[list[object]]:
    """Simulated seconds per wall second of a lone vehicle and of teams, each flying Search for ``seconds``;
    also per CPU second of this process, which others' load on a shared machine sways less. Each the best of
    ``repeats`` fresh runs (the same flight each time), taken in turns (the lone vehicle, then each team, then
    again): a lone run takes a fraction of a second, which a busy machine's hiccup can halve, and a shared
    machine's speed drifts over a minute, so each is timed in every stretch of it."""
    settings = Settings().updated({"time_limit": seconds + 60})

    def fly_lone():
        lone = simulate(scene, "search", "copter", settings)
        return lambda: lone.run(seconds)

    def fly_team(count):
        def ready():
            stepper = simulate_team(scene, "search", count, settings=settings)

            def fly():
                while stepper.team.time < seconds - 1e-9:
                    stepper.step()
            return fly
        return ready

    who = {"lone vehicle": fly_lone, **{f"team of {count}": fly_team(count) for count in (1, 2, 4, 8)}}
    wall = dict.fromkeys(who, math.inf)
    cpu = dict.fromkeys(who, math.inf)
    for _ in range(repeats):
        for name, ready in who.items():
            fly = ready()  # set up, not timed
            started, used = time.perf_counter(), time.process_time()
            fly()
            wall[name] = min(wall[name], time.perf_counter() - started)
            cpu[name] = min(cpu[name], time.process_time() - used)
    lone_rate, lone_cpu = seconds / wall["lone vehicle"], seconds / cpu["lone vehicle"]
    rows = [["lone vehicle", f"{lone_rate:.0f}x", "1.00", f"{lone_cpu:.0f}x", "1.00", "-"]]
    for count in (1, 2, 4, 8):
        name = f"team of {count}"
        rate, per_cpu = seconds / wall[name], seconds / cpu[name]
        goal = 0.95 if count == 1 else 1 / count
        rows.append([name, f"{rate:.0f}x", f"{rate / lone_rate:.2f}", f"{per_cpu:.0f}x", f"{per_cpu / lone_cpu:.2f}",
                     f">= {goal:.2f} {'met' if rate / lone_rate >= goal else 'MISSED'}"])
    return rows


def many_runs(runs: int, seconds: float, seed: int = 1) -> tuple[list[list[object]], dict]:
    """``runs`` team runs of random size, scene, mission and starts; returns rows per scene and the totals."""
    chooser = random.Random(seed)
    scenes = {path: load_scene(path) for path in SCENES}
    totals = {"runs": 0, "vehicle collisions": 0, "scene collisions": 0, "closest": math.inf, "refused starts": 0}
    per_scene: dict[str, list] = {}
    while totals["runs"] < runs:
        path = chooser.choice(SCENES)
        scene = scenes[path]
        count = chooser.randint(2, 8)
        mission = chooser.choice(["search", "pathfind"])
        x0, y0 = (scene.start or (0.0, 0.0))[:2]
        dx, dy = chooser.uniform(-3, 3), chooser.uniform(-3, 3)
        spots = chooser.sample(TEAM_SPOTS, count)
        starts = [(x0 + dx + sx, y0 + dy + sy) for sx, sy in spots]
        settings = load_settings_of(scene).updated({"time_limit": seconds})
        try:
            stepper = simulate_team(scene, mission, count, settings=settings, starts=starts, seed=totals["runs"])
        except PlacementError:  # a start inside an obstacle: drawn again
            totals["refused starts"] += 1
            continue
        result = run_team(Experiment(str(path), mission, settings=settings, seed=totals["runs"]), stepper)
        crashes = [v for v in result["vehicles"] if v["outcome"] == "collision"]
        by_vehicle = sum("vehicles" in v["reason"] for v in crashes)
        at = " ".join(f"--start={float(x)!r},{float(y)!r}" for x, y in starts)  # every digit: a flight turns on them
        totals.setdefault("crashes", []).extend(
            f"vehicle {v['sysid']}: {v['reason']}; reproduce: `vehicle experiment --scene {path} --mission {mission} "
            f"--vehicles {count} {at} --seed {totals['runs']} --time-limit {seconds:g}`" for v in crashes)
        totals["runs"] += 1
        totals["vehicle collisions"] += by_vehicle
        totals["scene collisions"] += len(crashes) - by_vehicle
        totals["closest"] = min(totals["closest"], result["closest_vehicles_m"])
        row = per_scene.setdefault(path.name, [0, 0, 0, math.inf])
        row[0] += 1
        row[1] += by_vehicle
        row[2] += len(crashes) - by_vehicle
        row[3] = min(row[3], result["closest_vehicles_m"])
    rows = [[name, n, v, s, f"{closest:.2f} m"] for name, (n, v, s, closest) in sorted(per_scene.items())]
    return rows, totals


def load_settings_of(scene) -> Settings:
    from vehicle.agent.settings import load_settings

    return load_settings(scene_hints=scene.hints)


def coverage(scene, seconds: float) -> list[list[object]]:
    """Occupied cells of one vehicle and of a team of 4, flying Search for the same simulated time."""
    settings = Settings().updated({"time_limit": seconds})
    rows = []
    for count in (1, 4):
        stepper = simulate_team(scene, "search", count, settings=settings)
        result = run_team(Experiment(str(DEFAULT_SCENE), "search", settings=settings), stepper)
        rows.append([count, result["detections"], result["sim_time_s"]])
    ratio = rows[1][1] / max(rows[0][1], 1)
    rows.append(["ratio", f"{ratio:.2f}", f"goal >= 2.5 {'met' if ratio >= 2.5 else 'MISSED'}"])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=40, help="team runs for the safety figures (the issue asks 200)")
    parser.add_argument("--seconds", type=float, default=120.0, help="simulated seconds of each safety run")
    parser.add_argument("--seed", type=int, default=1, help="draws the safety runs (scene, team, mission, starts)")
    parser.add_argument("--speed-seconds", type=float, default=120.0, help="simulated seconds of each speed run")
    parser.add_argument("--coverage-seconds", type=float, default=300.0, help="simulated seconds of the coverage runs")
    parser.add_argument("--repeats", type=int, default=3, help="speed runs of each, the best kept")
    parser.add_argument("--only", choices=["speed", "safety", "coverage"], help="print only these figures")
    args = parser.parse_args()
    warm_up()
    scene = load_scene(DEFAULT_SCENE)
    if args.only in (None, "speed"):
        print(f"Speed: Search in {DEFAULT_SCENE.name}, {args.speed_seconds:g} s simulated each, one process "
              f"(load average {os.getloadavg()[0]:.1f})")
        print(table(["who", "sim s / wall s", "of the lone vehicle", "sim s / CPU s", "of the lone vehicle",
                     "goal (wall)"], speed(scene, args.speed_seconds, args.repeats)))
        print()
    if args.only in (None, "safety"):
        safety(args.runs, args.seconds, args.seed)
        print()
    if args.only in (None, "coverage"):
        print(f"Coverage: Search in {DEFAULT_SCENE.name}, {args.coverage_seconds:g} s simulated")
        print(table(["vehicles", "occupied cells", "simulated s"], coverage(scene, args.coverage_seconds)))


def safety(runs: int, seconds: float, seed: int = 1) -> None:
    started = time.perf_counter()
    rows, totals = many_runs(runs, seconds, seed)
    print(f"Safety: {totals['runs']} team runs of 2 to 8 copters, Search or Pathfind, {seconds:g} s each, random "
          f"starts drawn with seed {seed} ({totals['refused starts']} inside obstacles and drawn again), "
          f"{time.perf_counter() - started:.0f} s wall")
    print(table(["scene", "runs", "vehicle collisions", "scene collisions", "closest approach"], rows))
    print(f"total: {totals['vehicle collisions']} collisions between vehicles, {totals['scene collisions']} with the "
          f"scene (goal 0); closest approach between two bodies {totals['closest']:.2f} m")
    for crash in totals.get("crashes", []):
        print(f"- {crash}")


if __name__ == "__main__":
    main()
