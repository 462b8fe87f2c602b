"""Wall time of the thesis's sweep (``vehicle sweep --preset thesis``): 576 runs, target under 6 minutes on 2 cores.

Runs the preset exactly as ``vehicle sweep`` does (``vehicle.cli.cmd_sweep``), into a
temporary folder, and prints the wall time against the target, the outcome counts (in
all and per mission and scene) and the ``best.md`` table beside the thesis's Table 1.
The wall time includes flying the best runs again to draw their maps, as the command does.
``--preset indoor`` runs the same grid in the project's indoor scenes (house, apartment: 384 runs)
instead; its wall time is reported but has no target.
Run: python bench/thesis_sweep.py [--preset thesis|indoor] [--workers N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from common import code_state, table

from vehicle.lab.experiment import OUTCOMES
from vehicle.lab.presets import PRESETS
from vehicle.lab.sweep import SweepSpec, run_sweep

TARGET_S = 6 * 60
TARGET_RUNS = 576


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="local worker processes (default: one per core)")
    parser.add_argument("--keep", metavar="DIR", help="write the results here instead of a temporary folder")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--preset", choices=["thesis", "indoor"], default="thesis",
                        help="the sweep to run (default %(default)s; only the thesis's has a time target)")
    args = parser.parse_args()

    load = os.getloadavg()[0]
    preset = PRESETS[args.preset]
    spec = SweepSpec(preset["missions"], preset["scenes"](), preset["grid"], 1, "copter")
    runs = len(spec.jobs())
    print(f"{runs} runs over {', '.join(Path(s).name for s in spec.scenes)} on {args.workers} workers",
          file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="thesis-sweep-") as temp:
        out = Path(args.keep or temp)
        started = time.perf_counter()
        results = run_sweep(spec, out, workers=args.workers, progress=not args.no_progress)
        wall = time.perf_counter() - started
        best = (out / "best.md").read_text(encoding="utf-8")

    cores = os.cpu_count() or 1
    sim = sum(r.get("sim_time_s", 0) for r in results)
    verdict = "met" if wall < TARGET_S and runs >= TARGET_RUNS else "NOT met"
    target = f"{TARGET_RUNS} runs < {TARGET_S // 60} min on 2 cores"
    if args.preset != "thesis":
        verdict, target = "-", "none"
    print(table(["runs", "workers", "cores", "wall", "simulated", "sim/wall", "target", "verdict"],
                [[runs, args.workers, cores, f"{wall:.0f} s ({wall / 60:.1f} min)", f"{sim / 3600:.1f} h",
                  f"{sim / wall:,.0f}x", target, verdict]]))
    print()
    counts = Counter(r["outcome"] for r in results)
    print("outcomes: " + ", ".join(f"{o} {counts[o]}" for o in OUTCOMES))
    print()
    groups = sorted({(r["mission"], Path(r["scene"]).stem) for r in results},
                    key=lambda k: (preset["missions"].index(k[0]), k[1]))
    rows = []
    for mission, scene in groups:
        mine = [r for r in results if r["mission"] == mission and Path(r["scene"]).stem == scene]
        c = Counter(r["outcome"] for r in mine)
        rows.append([mission, scene, len(mine), *(c[o] for o in OUTCOMES),
                     sum(r["detections"] == 0 for r in mine), max(r["detections"] for r in mine)])
    print(table(["mission", "scene", "runs", *OUTCOMES, "zero detections", "max detections"], rows))
    print()
    print(best)
    for r in results:
        if r["outcome"] in ("collision", "error"):
            print(f"- {r['outcome']}: {r['mission']} in {r['scene_spec']} with {r['swept']}: {r['reason']}")
    print(f"Load average before/after: {load:.1f}/{os.getloadavg()[0]:.1f}. Vehicle code: {code_state()}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
