"""Variance measurements (VRTI: Wilson and Patwari, "See-through walls: motion tracking using variance-based radio
tomographic imaging networks", IEEE TMC 2011).

A person moving near a link's line changes which multipath components add up at the receiver, so the link's RSS
varies from reading to reading; a still room, or a still person, leaves only the receiver's noise. Per
link-channel and frame the measurement is the sample variance (dB^2, unbiased) of its readings in the frame's
span of windows (the paper's window of the last few readings: three one-second windows hold about five sweeps of
the walks, the data set author's code keeps four). The model is s = W x + n with x a *motion* image.

``sub-mean`` takes off each link-channel's empty-room variance, the noise part of s: its mean windowed variance in
the calibration capture, or without one its median over the file's frames (most windows of a link have nobody
moving near it). ``plain`` images the variance as it is, as the paper does; a link whose receiver is noisier
than the others then paints a streak along it. A level drift moves the mean, not the spread: a drifted link
changes only the one window in which it steps.
"""

from __future__ import annotations

import warnings

import numpy as np

from vehicle.tomography.kernel import pool_span
from vehicle.tomography.links import LinkTable, Records, link_keys, match_keys

BASELINES = ("sub-mean", "plain")


def windowed_variances(lc: np.ndarray, rssi: np.ndarray, n_lc: int, frame: np.ndarray, frames: int,
                       span: int) -> np.ndarray:
    """(frames x link-channels) unbiased sample variance of the readings (link-channel ``lc``, value ``rssi``,
    window ``frame``) that fall in each frame's span of windows; NaN where fewer than two."""
    f, lc, value = pool_span(frame, frames, span, lc, rssi)
    centre = np.zeros(n_lc)  # readings about their link-channel's first value: no cancellation in s2 - s1^2 / n
    first = np.unique(lc, return_index=True)
    centre[first[0]] = value[first[1]]
    value = value - centre[lc]
    group, size = f * n_lc + lc, frames * n_lc
    n = np.bincount(group, minlength=size).astype(float)
    s1 = np.bincount(group, weights=value, minlength=size)
    s2 = np.bincount(group, weights=value ** 2, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        variance = np.where(n >= 2, np.maximum(s2 - s1 ** 2 / np.maximum(n, 1), 0.0) / np.maximum(n - 1, 1), np.nan)
    return variance.reshape(frames, n_lc)


def empty_variance(table: LinkTable, calibration: Records | None, window: float | None, span: int,
                   fallback: np.ndarray) -> np.ndarray:
    """Each link-channel's empty-room variance: the mean windowed variance of the calibration capture (the same
    windows and span as the images), else the median over frames of ``fallback`` (the file's own)."""
    n_lc = len(table.lc_keys)
    with warnings.catch_warnings():  # a link-channel never heard twice in a frame has no variance: NaN, said here
        warnings.simplefilter("ignore", RuntimeWarning)
        own = np.nanmedian(fallback, axis=0) if len(fallback) else np.full(n_lc, np.nan)
    if calibration is None or not len(calibration):
        return own
    where = match_keys(link_keys(calibration), table.lc_keys)
    known = where >= 0
    t = calibration.t[known]
    if window:
        frame = np.floor((t - t.min()) / window + 1e-9).astype(np.int64) if len(t) else np.zeros(0, np.int64)
    else:
        frame, span = np.zeros(len(t), np.int64), 1
    frames = int(frame.max()) + 1 if len(frame) else 0
    calibrated = windowed_variances(where[known], calibration.rssi[known], n_lc, frame, frames, span)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(calibrated, axis=0) if frames else np.full(n_lc, np.nan)
    return np.where(np.isfinite(mean), mean, own)


def variance_measurements(records: Records, table: LinkTable, calibration: Records | None, use: np.ndarray,
                          frame: np.ndarray, frames: int, window: float | None, span: int,
                          baseline: str) -> np.ndarray:
    """(frames x link-channels) windowed variances of the imaged records, less the empty-room variance with
    ``sub-mean``."""
    if baseline not in BASELINES:
        raise ValueError(f"unknown variance baseline {baseline!r} (one of {', '.join(BASELINES)})")
    n_lc = len(table.lc_keys)
    variance = windowed_variances(table.row_lc[use], records.rssi[use], n_lc, frame, frames, span)
    if baseline == "plain":
        return variance
    empty = empty_variance(table, calibration, window, span, variance)
    return variance - np.where(np.isfinite(empty), empty, 0.0)[None, :]
