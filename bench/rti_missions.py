"""Radio tomography missions: a team of two copters images targets in the default scene (vehicle.lab.tomograph).

1. One target at a random spot of an open 10 x 10 m area (x 25..35, y -35..-25, south-east of the start):
   over --runs runs per planner, the share found within 0.5 m (the image's strongest peak), and the median
   simulated time until found (from the start of the run: take-off and the flight there count), for the
   uncertainty-driven planner and the perimeter plan.
2. Two targets 1.5 m apart at random in the same area: both found as two peaks, in how many of 10 runs.
3. Through a building: two targets inside the Garage (x -18..-10, y -5..3, 5 m high), the radios on a ring
   outside it at 4 m: what is found, beside the same targets with the scene's walls taken out of the radio model;
   each with the empty-area capture and without it (each link's empty level from a path-loss model fitted
   across the links, as the station's live image has it).

Every run flies the whole mission (``rti_rounds`` pairs), headless, faster than real time, and ends there (the
way home and the landing are not flown).
Run: python bench/rti_missions.py [--runs 50] [--pairs 10] [--building 5] [--rounds 40]
                                  [--planners uncertainty,perimeter] [--parts one,two,building]
(parts and planners split over processes run side by side on a loaded machine; each prints its own tables)
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import sys
import time

from common import DEFAULT_SCENE, code_state, table

from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, warm_up
from vehicle.lab.tomograph import run_team_experiment
from vehicle.tomography.planning import PLANNERS
from vehicle.world.scene import load_scene

OPEN = (25.0, -35.0, 35.0, -25.0)
GARAGE = (-18.0, -5.0, -10.0, 3.0)


def run(scene, planner: str, bounds, targets, seed: int, rounds: int, model=None, calibrated: bool = True) -> dict:
    settings = Settings().updated({"rti_planner": planner, "rti_x0": bounds[0], "rti_y0": bounds[1],
                                   "rti_x1": bounds[2], "rti_y1": bounds[3], "rti_rounds": rounds,
                                   "time_limit": 400})
    experiment = Experiment(str(DEFAULT_SCENE), "rti", "copter", settings=settings, seed=seed)
    return run_team_experiment(experiment, scene, 2, targets, model=model, until_mission_end=True,
                               calibrated=calibrated)


def inside(rng: random.Random, bounds, margin: float = 1.0) -> tuple[float, float]:
    return (round(rng.uniform(bounds[0] + margin, bounds[2] - margin), 2),
            round(rng.uniform(bounds[1] + margin, bounds[3] - margin), 2))


def pair(rng: random.Random, bounds, apart: float = 1.5) -> list[tuple[float, float]]:
    cx, cy = inside(rng, bounds, 1.0 + apart / 2)
    angle = rng.uniform(0, math.pi)
    dx, dy = apart / 2 * math.cos(angle), apart / 2 * math.sin(angle)
    return [(round(cx - dx, 2), round(cy - dy, 2)), (round(cx + dx, 2), round(cy + dy, 2))]


def one_target(scene, runs: int, rounds: int, planners, first: int = 0) -> list[list[object]]:
    rows = []
    for planner in planners:
        rng = random.Random(1)
        for _ in range(first):  # the targets of the runs before (another process's share)
            inside(rng, OPEN)
        found, times, errors, links = 0, [], [], []
        for k in range(first, first + runs):
            result = run(scene, planner, OPEN, [inside(rng, OPEN)], k, rounds)
            rti = result["rti"]
            ended = ", ".join(sorted({v["messages"][-1] for v in result["vehicles"] if v["messages"]}))
            found += rti["found"]
            if rti["found_s"] is not None:
                times.append(rti["found_s"])
            if rti["distances_m"][0] is not None:
                errors.append(rti["distances_m"][0])
            links.append(rti["links_imaged"])
            print(f"{planner} run {k + 1}: {rti['distances_m']} found at {rti['found_s']} s, {rti['links_imaged']} "
                  f"links; {ended}", file=sys.stderr, flush=True)
        rows.append([planner, runs, f"{found} ({100 * found / runs:.0f} %)",
                     f"{statistics.median(times):.0f} s" if times else "-",
                     f"{statistics.median(errors):.2f} m" if errors else "-",
                     f"{statistics.median(links):.0f}"])
    return rows


def two_targets(scene, runs: int, rounds: int, planners) -> list[list[object]]:
    rows = []
    for planner in planners:
        rng = random.Random(2)
        both, times = 0, []
        for k in range(runs):
            targets = pair(rng, OPEN)
            rti = run(scene, planner, OPEN, targets, 1000 + k, rounds)["rti"]
            both += rti["found"]
            print(f"{planner} two-target run {k + 1}: {targets} -> {rti['distances_m']} found at {rti['found_s']} s",
                  file=sys.stderr, flush=True)
            if rti["found_s"] is not None:
                times.append(rti["found_s"])
        rows.append([planner, f"{both} of {runs}", f"{statistics.median(times):.0f} s" if times else "-"])
    return rows


def building(scene, runs: int, rounds: int) -> list[list[object]]:
    from vehicle.world.radio import RadioModel

    rows = []
    targets = [(-15.5, -2.0), (-12.5, 1.0)]
    for label, model, calibrated in (("walls as the model says", None, True),
                                     ("no wall loss", RadioModel(wall_loss_db=0.0), True),
                                     ("walls, no empty-area capture (the live image's levels)", None, False),
                                     ("no wall loss, no capture", RadioModel(wall_loss_db=0.0), False)):
        found, distances = 0, []
        for k in range(runs):
            rti = run(scene, "uncertainty", GARAGE, targets, 2000 + k, rounds, model, calibrated)["rti"]
            found += rti["found"]
            distances.extend(d for d in rti["distances_m"] if d is not None)
        rows.append([label, f"{found} of {runs}", f"{statistics.median(distances):.2f} m" if distances else "-"])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50, help="one-target runs per planner (default 50)")
    parser.add_argument("--pairs", type=int, default=10, help="two-target runs per planner (default 10)")
    parser.add_argument("--building", type=int, default=5, help="runs through the building per case (default 5)")
    parser.add_argument("--rounds", type=int, default=round(Settings().rti_rounds),
                        help="pairs of spots per mission (default: rti_rounds' default, 40)")
    parser.add_argument("--planners", default=",".join(PLANNERS), help="comma-separated (default: both)")
    parser.add_argument("--parts", default="one,two,building", help="comma-separated (default: all three)")
    parser.add_argument("--first", type=int, default=0, help="the first one-target run (to split runs over processes)")
    args = parser.parse_args()
    planners, parts = args.planners.split(","), args.parts.split(",")
    warm_up()
    scene = load_scene(DEFAULT_SCENE)
    started = time.perf_counter()
    print(f"## Radio tomography missions ({code_state()}; {args.rounds} pairs of spots, dwell "
          f"{Settings().rti_dwell:g} s)\n")
    if "one" in parts:
        print("One target at random in the open 10 x 10 m area (x 25..35, y -35..-25), a team of two copters:\n")
        print(table(["planner", "runs", "found within 0.5 m at the end", "median time to found",
                     "median final error", "median links imaged"],
                    one_target(scene, args.runs, args.rounds, planners, args.first)))
    if "two" in parts:
        print(f"\nTwo targets 1.5 m apart, at random in the same area ({args.pairs} runs per planner):\n")
        print(table(["planner", "both found as two peaks", "median time to both found"],
                    two_targets(scene, args.pairs, args.rounds, planners)))
    if "building" in parts:
        print("\nThrough a building: targets at (-15.5, -2) and (-12.5, 1) inside the Garage, the radios outside "
              f"at 4 m ({args.building} runs each):\n")
        print(table(["radio model", "both found within 0.5 m", "median target-to-peak distance"],
                    building(scene, args.building, args.rounds)))
    print(f"\n{time.perf_counter() - started:.0f} s wall")


if __name__ == "__main__":
    main()
