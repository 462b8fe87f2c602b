"""Benchmark of vehicle.planning: inflate, astar, smooth and plan on random grids.

Grids of N x N cells with scattered axis-aligned rectangles 2-30 cells wide
until about 2% of the cells are occupied (fixed seed), start and goal in
opposite corners (kept clear), clearance radius 3 cells. Each figure is the
median of several runs, in milliseconds. Prints a Markdown table.

    python bench/astar.py [--runs 7]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vehicle.mapping.planning import astar, inflate, plan, smooth  # noqa: E402

SIZES = (200, 1000, 2000)
TARGET_MS = {200: 2.0, 2000: 100.0}  # plan() targets
RADIUS = 3.0
OCCUPIED = 0.02


def random_grid(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    blocked = np.zeros((n, n), dtype=bool)
    while blocked.mean() < OCCUPIED:
        h, w = rng.integers(2, 31, size=2)
        r, c = rng.integers(0, n, size=2)
        blocked[r : r + h, c : c + w] = True
    corner = int(RADIUS) + 3
    blocked[:corner, :corner] = False
    blocked[-corner:, -corner:] = False
    return blocked


def median_ms(fn, runs: int) -> float:
    fn()  # warm up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    print(f"radius {RADIUS:g} cells, ~{OCCUPIED:.0%} occupied, median of {args.runs} runs, ms\n")
    print("| grid | occupied | inflate | astar | smooth | plan | plan target | waypoints (raw) |")
    print("|---|---|---|---|---|---|---|---|")
    for n in SIZES:
        blocked = random_grid(n)
        start, goal = (0, 0), (n - 1, n - 1)
        inflated = inflate(blocked, RADIUS)
        raw = astar(inflated, start, goal)
        waypoints = plan(blocked, start, goal, RADIUS)
        t_inflate = median_ms(lambda b=blocked: inflate(b, RADIUS), args.runs)
        t_astar = median_ms(lambda g=inflated, s=start, e=goal: astar(g, s, e), args.runs)
        t_smooth = median_ms(lambda p=raw, g=inflated: smooth(p, g), args.runs)
        t_plan = median_ms(lambda b=blocked, s=start, e=goal: plan(b, s, e, RADIUS), args.runs)
        target = f"<= {TARGET_MS[n]:g}" if n in TARGET_MS else "-"
        print(
            f"| {n}x{n} | {blocked.mean():.1%} | {t_inflate:.2f} | {t_astar:.2f} | {t_smooth:.2f} "
            f"| {t_plan:.2f} | {target} | {len(waypoints)} ({len(raw)}) |"
        )


if __name__ == "__main__":
    main()
