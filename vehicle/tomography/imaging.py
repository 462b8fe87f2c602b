"""From link records to images, one per time window: attenuations, drift, solving, peaks and the track.

Per window, a link-channel's measurement is the kernel distance of its RSS histogram from a long-term one
(vehicle.tomography.kernel; the default: the file's when windows are imaged, as KRTI's long-term window, since
against a quiet empty capture every link the walker's multipath stirs looks changed; the capture's for one
image of the whole file), its RSS variance (vehicle.tomography.variance, VRTI: motion only), or its
attenuation, the empty-area level minus the mean of its RSS in the window; a path's measurement (the
unordered pair of positions: both directions see the same obstacles) is the mean over its anti-faded channels
that were heard. A path not heard at all in a window is left out of that window's solve (it is not assumed
unchanged: a missing packet says nothing about the path); the linear map is cached per
set of present paths, so the usual full set costs one matrix-vector product per frame.

Drift: a path whose median attenuation over the file is not predicted by the other paths (its leave-one-out
residual more than DRIFT_SIGMAS robust standard deviations off) has changed since calibration: a person
standing still is seen by every path through them, a drifted radio by its own links only. Its channels are
recalibrated on the file's own median, and it no longer paints a blob beside its radios.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

from vehicle.tomography.calibration import (
    Levels,
    brief_or_model_levels,
    channel_weights,
    empty_levels,
    file_levels,
    group_mean,
    model_levels,
)
from vehicle.tomography.kernel import kernel_distances, kernel_width, reference_rows
from vehicle.tomography.links import LinkTable, Records, link_table
from vehicle.tomography.solvers import RegularisedLS, difference_prior_times, sparse_nonnegative, tv_discrepancy
from vehicle.tomography.tracking import Tracker
from vehicle.tomography.variance import variance_measurements
from vehicle.tomography.weights import LAMBDA, Grid, WeightCache, default_cell

CORRELATION = 0.5  # m: the prior's correlation distance, about a person's width, the size of what we image
NEAR_RADIO = 0.5  # m (a person's width) round a radio whose links' levels come from the path-loss model: no peak
DRIFT_SIGMAS = 3.0
DRIFT_ROUNDS = 4
WORST_SHARE = 2 / 3  # a round takes out the paths within this share of the worst deviation
DRIFT_MIN_DB = 5.0  # what a person near a link's line does to it in a room: 1 dB typically, 7 dB at the 90th percentile
SOLVERS = ("ls", "tv", "sparse")
MEASURES = ("mean", "kernel", "variance")
PRIORS = ("exponential", "difference")
REFERENCES = ("auto", "file", "empty")
EMPTY_SOURCES = ("data", "model", "brief")
FLOOR_FRAMES = 10  # frames: fewer, and a path's median could be the person's own (see above_floor)
SMOOTH = 3  # windows: the centred moving average of each path's measurement (see smooth)
STANDING = {"measure": "mean", "solver": "sparse", "model": "line"}  # the method for people standing still, as a
# team's missions image them: the attenuation in dB (a target that stood still through the history is no change
# to the kernel distance or the variance, and attenuations add up where links cross two people), the sparse
# non-negative solve and the line model (each is needed: of 20 simulated missions with two people 1.5 m apart,
# 18 imaged both apart with the three, 7 with least squares, 6 with the ellipse, 3 with the defaults)


def smooth(Y: np.ndarray, span: int) -> np.ndarray:
    """Each window's path measurements averaged with the windows around it (``span`` in all, centred), over the
    readings that were heard: a person moves little in a few seconds while the noise of a one-second window
    (one or two readings per channel) falls by sqrt(span). Paths heard in none of them stay NaN."""
    if span <= 1 or len(Y) < 2:
        return Y
    present = np.isfinite(Y)
    kernel = np.ones(span)
    num = np.apply_along_axis(np.convolve, 0, np.where(present, Y, 0.0), kernel, mode="same")
    den = np.apply_along_axis(np.convolve, 0, present.astype(float), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0.5, num / np.maximum(den, 1e-12), np.nan)


class Imager:
    """Images of one grid from path measurements: the library's live face (the station calls it per window)."""

    def __init__(self, grid: Grid, model: str = "ellipse", lam: float = LAMBDA, delta: float = CORRELATION,
                 maps: int = 32, prior: str = "exponential"):
        if prior not in PRIORS:
            raise ValueError(f"unknown prior {prior!r} (one of {', '.join(PRIORS)})")
        self.grid, self.delta, self.prior = grid, delta, prior
        self.weights = WeightCache(grid, model, lam)
        self._centres = grid.centres()
        self._maps: OrderedDict[bytes, tuple[RegularisedLS, object]] = OrderedDict()
        self._size = maps

    def linear_map(self, paths: np.ndarray, sigma: np.ndarray) -> tuple[RegularisedLS, object]:
        """The regularised least-squares map of a set of paths, its rows divided by each path's noise standard
        deviation ``sigma`` (so that the noise is white), and that weight matrix; cached."""
        key = np.round(paths, 3).tobytes() + np.round(sigma, 3).tobytes()
        if key not in self._maps:
            W = (sp.diags(1.0 / sigma) @ self.weights.matrix(paths)).tocsr()
            B = None  # the exponential covariance: RegularisedLS builds C W^T itself
            if self.prior == "difference":
                B = difference_prior_times(self.grid.shape, W, self.delta / self.grid.cell)
            self._maps[key] = (RegularisedLS(W, self._centres, self.delta, B), W)
            while len(self._maps) > self._size:
                self._maps.popitem(last=False)
        self._maps.move_to_end(key)
        return self._maps[key]

    def image(self, paths: np.ndarray, y: np.ndarray, sigma: np.ndarray | None = None, alpha: float | None = None,
              solver: str = "ls"):
        """(image (ny, nx), alpha, residual rms in noise standard deviations) for measurements ``y`` (dB) of
        ``paths`` with noise ``sigma`` (dB); alpha by GCV on this frame alone when not given."""
        sigma = np.ones(len(y)) if sigma is None else sigma
        y = y / sigma
        if solver == "sparse":  # no prior, no alpha: the least-squares map is not needed
            W = sp.diags(1.0 / sigma) @ self.weights.matrix(paths)
            x = sparse_nonnegative(W, y)
            rms = float(np.sqrt(np.mean((y - W @ x) ** 2))) if len(y) else 0.0
            return x.reshape(self.grid.shape), alpha, rms
        lmap, W = self.linear_map(paths, sigma)
        if alpha is None:
            alpha, _ = lmap.gcv(lmap.project(y))
        if solver == "tv":
            target = float(np.sum((y - lmap.fitted(y, alpha)) ** 2))
            x, _, _ = tv_discrepancy(W, y, self.grid.shape, target, x0=np.clip(lmap.solve(y, alpha), 0, None))
            fit = W @ x
        else:
            x = lmap.solve(y, alpha)
            fit = lmap.fitted(y, alpha)
        rms = float(np.sqrt(np.mean((y - fit) ** 2))) if len(y) else 0.0
        return x.reshape(self.grid.shape), alpha, rms


def subpixel_offset(before: np.ndarray, at: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Where the parabola through three neighbouring pixels' values peaks, in pixels from the middle one (the
    three-point estimator of a sampled maximum), within half a pixel; 0 where the values do not bend down or a
    neighbour is NaN (outside the image)."""
    bend = before - 2 * at + after
    down = bend < 0  # False where a neighbour is NaN (outside the image): no shift
    offset = np.where(down, 0.5 * (before - after) / np.where(down, bend, -1.0), 0.0)
    return np.clip(offset, -0.5, 0.5)


def near_radios(grid: Grid, paths: np.ndarray) -> np.ndarray:
    """(ny, nx) bool: the pixels within ``NEAR_RADIO`` of an end of the given paths (x0, y0, x1, y1 rows), where
    no peak is looked for. Those are paths whose empty level came from the path-loss model: a radio's own offset
    from the model (its antenna, its body, the ground it stood on) lowers every link it measured there alike,
    and the sparse solve puts it on the pixels that only those links cross, beside the radio. Nothing tells
    that from a person standing there, and a team's ring of spots then held the strongest peak (a small region's
    image over the ring: the person found in 12 of 16 missions, in 16 without peaks beside the spots)."""
    if not len(paths):
        return np.zeros(grid.shape, bool)
    ends = cKDTree(np.unique(np.vstack([paths[:, :2], paths[:, 2:]]), axis=0))  # moving radios: many ends
    gap, _ = ends.query(grid.centres(), distance_upper_bound=NEAR_RADIO)
    return (gap < NEAR_RADIO).reshape(grid.shape)


def find_peaks(image: np.ndarray, grid: Grid, count: int, separation: float) -> list[dict]:
    """The image's own local maxima above zero, at least ``separation`` apart, strongest first, at most
    ``count``; each placed where the parabola through its pixel and the two neighbours along each axis peaks
    (a pixel centre would be up to half a cell off), within the bounds; ``value`` is the pixel's own."""
    if count <= 0:
        return []
    radius = max(1, int(round(separation / grid.cell)))
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    footprint = xx ** 2 + yy ** 2 <= radius ** 2
    local = (image == maximum_filter(image, footprint=footprint, mode="constant", cval=-np.inf)) & (image > 0)
    iy, ix = np.nonzero(local)
    order = np.argsort(-image[iy, ix], kind="stable")[:count]
    iy, ix = iy[order], ix[order]
    padded = np.pad(image.astype(float), 1, constant_values=np.nan)
    py, px = iy + 1, ix + 1
    dx = subpixel_offset(padded[py, px - 1], padded[py, px], padded[py, px + 1])
    dy = subpixel_offset(padded[py - 1, px], padded[py, px], padded[py + 1, px])
    x0, y0, x1, y1 = grid.bounds
    xs = np.clip(x0 + (ix + 0.5 + dx) * grid.cell, x0, x1)
    ys = np.clip(y0 + (iy + 0.5 + dy) * grid.cell, y0, y1)
    return [{"x": round(float(x), 3), "y": round(float(y), 3), "value": round(float(image[j, i]), 4)}
            for x, y, j, i in zip(xs, ys, iy, ix, strict=True)]


@dataclass
class Result:
    grid: Grid
    window: float | None
    frames: list[dict]
    mean_image: np.ndarray
    radios: np.ndarray
    info: dict = field(default_factory=dict)

    def to_json(self, images: bool = False) -> dict:
        """The contract's JSON; with ``images``, each frame's image as rows of values (y up, 4 decimals)."""
        frames = [{k: v for k, v in f.items() if k != "image"} for f in self.frames]
        if images:
            for frame, full in zip(frames, self.frames, strict=True):
                if "image" in full:
                    frame["image"] = np.round(full["image"], 4).tolist()
        return {"bounds": [round(v, 4) for v in self.grid.bounds], "cell": self.grid.cell, "window": self.window,
                "grid": [self.grid.nx, self.grid.ny], **self.info, "frames": frames}


def frame_index(t: np.ndarray, start: float, window: float | None) -> tuple[np.ndarray, int]:
    """Each record's frame (window) index and how many frames there are."""
    if not window:
        return np.zeros(len(t), np.int64), 1
    frame = np.floor((t - start) / window + 1e-9).astype(np.int64)
    return frame, int(frame.max()) + 1 if len(frame) else 0


def path_means(per_lc: np.ndarray, table: LinkTable, weights: np.ndarray) -> np.ndarray:
    """(frames x paths): each path's weighted mean over its link-channels heard in the frame (NaN where none)."""
    frames, n_path = len(per_lc), len(table.paths)
    heard = np.isfinite(per_lc)
    w = np.where(heard, weights[None, :], 0.0)
    sums = np.zeros((frames, n_path))
    norms = np.zeros((frames, n_path))
    np.add.at(sums.T, table.lc_path, (np.where(heard, per_lc, 0.0) * w).T)
    np.add.at(norms.T, table.lc_path, w.T)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norms > 0, sums / np.maximum(norms, 1e-12), np.nan)


def window_measurements(records: Records, table: LinkTable, levels: Levels, weights: np.ndarray,
                        start: float, window: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Frame start times and the (frames x paths) mean attenuations, NaN where a path was not heard."""
    use = (records.t >= start) & (weights[table.row_lc] > 0)
    frame, frames = frame_index(records.t[use], start, window)
    lc = table.row_lc[use]
    n_lc = len(table.lc_keys)
    mean_lc, _ = group_mean(frame * n_lc + lc, levels.empty[lc] - records.rssi[use], frames * n_lc)
    times = start + np.arange(frames) * (window or 0.0)
    return times, path_means(mean_lc.reshape(frames, n_lc), table, weights)


def kernel_measurements(records: Records, table: LinkTable, calibration: Records | None, drifted: np.ndarray,
                        weights: np.ndarray, start: float, window: float | None, span: int,
                        reference: str) -> tuple[np.ndarray, dict]:
    """The (frames x paths) kernel distances (vehicle.tomography.kernel), the short-term histogram of a frame
    pooling ``span`` windows, the long-term one the file's own (``reference`` "file", KRTI's) or the empty
    area's ("empty"; drifted paths then the file's)."""
    use = (records.t >= start) & (weights[table.row_lc] > 0)
    frame, frames = frame_index(records.t[use], start, window)
    empty = calibration if reference == "empty" else None
    reference = reference_rows(records, table, empty, drifted[table.lc_path])
    width = kernel_width(*reference)
    per_lc = kernel_distances(records, table, reference, use, frame, frames, span, width)
    Y, extra = path_means(per_lc, table, weights), {"kernel_db": round(width, 3)}
    if empty is None and frames >= FLOOR_FRAMES:
        Y, floor = above_floor(Y)
        extra["kernel_floor"] = round(float(np.median(floor)), 4)
    return Y, extra


def above_floor(Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each path's kernel distances less its floor, its median over the frames. A short-term histogram of a
    few readings never matches the long-term one, so an unchanged path reads above zero, by how widely its
    RSS spreads and how many packets it heard: on the basement walks the floor differs 30-fold between paths,
    up to a quarter of what a person does to a path. Against the file's own histogram each path is unchanged
    most of the time (KRTI's premise), so its median is that floor; a path's change is what rises above it."""
    with np.errstate(all="ignore"):
        floor = np.nanmedian(Y, axis=0)
    floor = np.where(np.isfinite(floor), floor, 0.0)
    return Y - floor[None, :], floor


def reconstruct(records: Records, calibration: Records | None = None, calibration_seconds: float | None = None,
                bounds: tuple[float, float, float, float] | None = None, cell: float | None = None,
                window: float | None = None, peaks: int = 3, solver: str = "ls", model: str = "ellipse",
                drift: bool = True, span: int = SMOOTH, measure: str = "kernel", variance: str = "sub-mean",
                reference: str = "auto", prior: str = "exponential", empty_from: str = "data") -> Result:
    """The whole method on one file (see the module's docstring and docs/rti.md). ``empty_from``: each link's
    empty-area level from the calibration, else the file's own robust level ("data"), or from a path-loss
    model fitted across the links ("model", ``calibration.model_levels``), or the model's only for links heard
    briefly ("brief": radios that stop at spots once, ``calibration.brief_or_model_levels``)."""
    if empty_from not in EMPTY_SOURCES:
        raise ValueError(f"unknown empty-area source {empty_from!r} (one of {', '.join(EMPTY_SOURCES)})")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r} (one of {', '.join(SOLVERS)})")
    if measure not in MEASURES:
        raise ValueError(f"unknown measure {measure!r} (one of {', '.join(MEASURES)})")
    if reference not in REFERENCES:
        raise ValueError(f"unknown reference {reference!r} (one of {', '.join(REFERENCES)})")
    if window is not None and not (window > 0 and math.isfinite(window)):
        raise ValueError(f"window {window:g} must be a positive number of seconds")
    start = float(records.t.min())
    if calibration_seconds is not None:
        if not calibration_seconds > 0:
            raise ValueError(f"calibration seconds {calibration_seconds:g} must be positive")
        early = records.t < start + calibration_seconds
        if early.all():
            raise ValueError(f"{records.path}: --calibration-seconds {calibration_seconds:g} takes the whole file "
                             f"({records.t.max() - start:.1f} s), leaving nothing to image")
        calibration = records.select(early)
        start += calibration_seconds
    if bounds is None:
        ends = np.vstack([records.tx, records.rx])
        bounds = (*ends.min(axis=0).tolist(), *ends.max(axis=0).tolist())
    grid = Grid(tuple(float(v) for v in bounds), float(cell) if cell else default_cell(bounds))
    table = link_table(records)
    levels = (model_levels(records, table) if empty_from == "model" else
              brief_or_model_levels(records, table, calibration) if empty_from == "brief" else
              empty_levels(records, table, calibration))
    weights = channel_weights(table, levels.fade)
    times, Y = window_measurements(records, table, levels, weights, start, window)
    sigma = np.ones(len(table.paths))  # paths weigh alike: see docs/rti.md on weighting by the empty-area noise
    imager = Imager(grid, model, prior=prior)
    alpha = choose_alpha(imager, table.paths, Y, sigma)
    drifted = np.zeros(len(table.paths), bool)
    if drift and levels.calibrated.any():
        drifted = drifted_paths(imager, table.paths, Y, sigma, alpha)
        if drifted.any():
            redo = drifted[table.lc_path]
            levels.empty[redo] = file_levels(records, table)[redo]
            levels.modelled[redo] = False
            times, Y = window_measurements(records, table, levels, weights, start, window)
    no_peak = near_radios(grid, table.paths[np.unique(table.lc_path[levels.modelled])])
    span = span if window else 1
    extra = {}
    if measure == "kernel":
        reference = ("file" if window else "empty") if reference == "auto" else reference
        Y, extra = kernel_measurements(records, table, calibration, drifted, weights, start, window, span, reference)
        extra["reference"] = reference
    elif measure == "variance":
        use = (records.t >= start) & (weights[table.row_lc] > 0)
        frame, frames = frame_index(records.t[use], start, window)
        per_lc = variance_measurements(records, table, calibration, use, frame, frames, window, span, variance)
        Y, extra = path_means(per_lc, table, weights), {"variance": variance}
    else:
        Y = smooth(Y, span)
    alpha = None if solver == "sparse" else choose_alpha(imager, table.paths, Y, sigma)  # on what is imaged:
    # smoothing lowered the noise (the sparse solve has no alpha)
    frames, tracker = [], Tracker()
    total = np.zeros(grid.shape)
    for time, y in zip(times, Y, strict=True):
        present = np.isfinite(y)
        frame = {"t": round(float(time), 3), "paths": int(present.sum())}
        if present.any():
            image, _, rms = imager.image(table.paths[present], y[present], sigma[present], alpha, solver)
            total += image
            frame["peaks"] = find_peaks(np.where(no_peak, 0.0, image), grid, peaks, CORRELATION)
            frame["max"] = round(float(image.max()), 4)
            frame["residual_db"] = round(rms, 3)
            frame["image"] = image
        else:
            frame["peaks"] = []
        if window:
            best = frame["peaks"][0] if frame["peaks"] else None
            frame["track"] = tracker.step(window, (best["x"], best["y"]) if best else None)
        frames.append(frame)
    info = {
        "measure": measure, **extra, "solver": solver, "model": model, "prior": prior,
        "smooth_windows": span if window else None,
        "alpha": alpha,
        "correlation_m": CORRELATION, "lambda_m": LAMBDA,
        "links": {"link_channels": len(table.lc_keys), "paths": len(table.paths),
                  "calibrated": int(levels.calibrated.sum()), "channels_used": int((weights > 0).sum()),
                  "drifted_paths": int(drifted.sum())},
        "path_loss": {"p0_dbm": round(levels.path_loss[0], 2), "exponent": round(levels.path_loss[1], 3)},
        "skipped": dict(records.skipped),
    }
    return Result(grid, window, frames, total / max(1, len(frames)), records.radios(), info)


def choose_alpha(imager: Imager, paths: np.ndarray, Y: np.ndarray, sigma: np.ndarray) -> float:
    """alpha by GCV pooled over the frames that heard the most common set of paths (the noise-to-prior ratio
    is the data's, not the frame's: one value serves every set)."""
    present = np.isfinite(Y)
    if not present.any():
        return 1.0
    sets, counts = np.unique(present, axis=0, return_counts=True)
    usual = sets[int(np.argmax(np.where(sets.any(axis=1), counts, 0)))]
    rows = Y[(present == usual).all(axis=1)][:, usual]
    lmap, _ = imager.linear_map(paths[usual], sigma[usual])
    alpha, _ = lmap.gcv(lmap.project((rows / sigma[usual]).T))
    return alpha


def drifted_paths(imager: Imager, paths: np.ndarray, Y: np.ndarray, sigma: np.ndarray, alpha: float) -> np.ndarray:
    """Paths whose median attenuation over the file the other paths do not predict (see the module's docstring).
    Worst first, a few rounds: a drifted path also spoils the prediction of the paths beside it, so those are
    judged again once it is out."""
    with np.errstate(all="ignore"):
        median = np.nanmedian(np.where(np.isfinite(Y), Y, np.nan), axis=0) if len(Y) else np.zeros(len(paths))
    active = np.isfinite(median)
    out = np.zeros(len(paths), bool)
    for _ in range(DRIFT_ROUNDS):
        index = np.nonzero(active)[0]
        if len(index) < 4:
            break
        lmap, _ = imager.linear_map(paths[index], sigma[index])
        loo = lmap.loo_residuals(median[index] / sigma[index], alpha) * sigma[index]
        deviation = np.abs(loo - np.median(loo))
        spread = 1.4826 * float(np.median(deviation))
        worst = ((deviation > DRIFT_SIGMAS * spread) & (deviation > DRIFT_MIN_DB)
                 & (deviation >= WORST_SHARE * deviation.max()))
        if not worst.any():
            break
        out[index[worst]] = True
        active[index[worst]] = False
    return out
