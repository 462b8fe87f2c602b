"""Radio tomographic imaging: accuracy on the two basement walks, and speed.

Both walks with the command's defaults and each truth.json's cli options, scored by ../shared/rti/score.py
(RMSE, median and 90th percentile of the strongest peak's error), beside the comparison figures, and the same
with the empty room's long-term histogram, with the RSS variance (VRTI) or the mean attenuation instead of the
kernel distance, and without the calibration; the time to
build the weights of 1,000 links on a 100 x 100 grid; the time per frame once a set of links' map is built
(goal: under 5 ms, for live imaging at 10 Hz on one core); peak memory.
Run: python bench/rti.py   (BLAS on one thread, as the station would run it beside its other work)
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from common import ROOT, code_state, table  # noqa: E402

from vehicle.tomography.imaging import Imager, reconstruct  # noqa: E402
from vehicle.tomography.links import read_links  # noqa: E402
from vehicle.tomography.weights import Grid, weight_rows  # noqa: E402

SHARED = ROOT.parent / "shared" / "rti"
COMPARISON = {"basement_walk1": (1.655, 1.424, 1.845), "basement_walk2": (1.627, 1.379, 1.968)}


def walks() -> list[list[object]]:
    sys.path.insert(0, str(SHARED))
    from score import score_walk

    rows = []
    for case, (author, vrti, tikhonov) in COMPARISON.items():
        truth = json.loads((SHARED / case / "truth.json").read_text())
        cli = truth["cli"]
        records = read_links(SHARED / case / "links.csv.gz")
        calibration = read_links(SHARED / case / cli["calibration"])
        variants = (("defaults (--measure kernel, reference the file's)", calibration, {}),
                    ("--reference empty (the defaults before)", calibration, {"reference": "empty"}),
                    ("--measure variance (sub-mean)", calibration, {"measure": "variance"}),
                    ("--measure variance --variance plain", calibration, {"measure": "variance", "variance": "plain"}),
                    ("--measure variance --prior difference", calibration,
                     {"measure": "variance", "prior": "difference"}),
                    ("--measure mean", calibration, {"measure": "mean"}),
                    ("--measure mean --smooth 1", calibration, {"measure": "mean", "span": 1}),
                    ("no --calibration", None, {}), ("no --calibration, --measure mean", None, {"measure": "mean"}),
                    ("no --calibration, --measure variance", None, {"measure": "variance"}))
        for name, empty, options in variants:
            started = time.perf_counter()
            result = reconstruct(records, empty, bounds=cli["bounds"], cell=cli["cell"], window=cli["window"],
                                 peaks=cli["peaks"], **options)
            took = time.perf_counter() - started
            score = score_walk(truth, result.to_json())
            rows.append([case, name, score["rmse_m"], score["median_m"], score["p90_m"], f"{took:.1f} s", author,
                         vrti, tikhonov])
    return rows


def speed() -> list[list[object]]:
    rng = np.random.default_rng(1)
    grid = Grid((0.0, 0.0, 20.0, 20.0), 0.2)  # 100 x 100
    ends = rng.uniform(0, 20, (1000, 4))
    started = time.perf_counter()
    W = weight_rows(grid, ends)
    build = time.perf_counter() - started
    rows = [["weights, 1,000 links on 100 x 100", f"{build * 1000:.0f} ms", f"{W.nnz:,} non-zeros"]]
    # a live frame: 45 paths (the walks' 10 radios) on the walks' 41 x 40 grid, and 378 (28 radios) on 50 x 50
    for radios, grid in ((10, Grid((0.0, 0.0, 8.128, 7.8232), 0.2)), (28, Grid((0.0, 0.0, 10.0, 10.0), 0.2))):
        spots = rng.uniform(0, grid.bounds[2], (radios, 2))
        i, j = np.triu_indices(radios, 1)
        paths = np.column_stack([spots[i], spots[j]])
        imager = Imager(grid)
        y = rng.normal(0, 1, len(paths))
        started = time.perf_counter()
        imager.image(paths, y, alpha=1.0)
        first = time.perf_counter() - started
        frames = 200
        started = time.perf_counter()
        for _ in range(frames):
            imager.image(paths, rng.normal(0, 1, len(paths)), alpha=1.0)
        per = (time.perf_counter() - started) / frames
        rows.append([f"frame, {len(paths)} links on {grid.nx} x {grid.ny}", f"{per * 1000:.2f} ms (goal < 5)",
                     f"first (builds the map) {first * 1000:.0f} ms"])
        started = time.perf_counter()
        for _ in range(frames):
            imager.image(paths, rng.normal(0, 1, len(paths)))
        per = (time.perf_counter() - started) / frames
        rows.append([f"frame with its own GCV alpha, {len(paths)} links", f"{per * 1000:.2f} ms", ""])
    return rows


def main() -> None:
    print(code_state())
    if SHARED.exists():
        print(table(["walk", "options", "RMSE m", "median m", "p90 m", "time", "author's RTI", "VRTI",
                     "ellipse-Tikhonov"], walks()))
    else:
        print("(../shared/rti is absent: no walk figures)")
    print()
    print(table(["what", "time", "note"], speed()))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak memory (max RSS of this process): {peak:.0f} MB")


if __name__ == "__main__":
    main()
