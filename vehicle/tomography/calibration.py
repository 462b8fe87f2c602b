"""Empty-area levels per link and channel, fade levels, and which channels to trust.

The empty-area level of a link-channel is the mean of its RSS in a calibration capture (the area empty), or,
without one, the median of its RSS over the whole file: a robust estimate when each link is unobstructed more
than half the time, which moving people leave it (a person standing still for the whole file without a
calibration cannot be told from the room itself).

Channel diversity (Kaltiokallio, Bocca and Patwari 2012, 2014): the fade level of a link-channel is its
empty-area level minus what a log-distance path-loss model, fitted across all link-channels, predicts for its
length. A link-channel in an anti-fade (fade level above its link's median) reacts to a person on its line
strongly and consistently; one in a deep fade may even rise. Each link's measurement is the mean of its
anti-faded half of channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vehicle.tomography.links import LinkTable, Records, link_keys, match_keys


@dataclass
class Levels:
    """Per link-channel: the empty-area level (dBm), where it came from, and the fade level (dB)."""

    empty: np.ndarray
    calibrated: np.ndarray  # bool: from a calibration capture (else estimated from the file)
    fade: np.ndarray
    path_loss: tuple[float, float]  # (P0 at 1 m in dBm, exponent n) of the fitted log-distance model
    modelled: np.ndarray  # bool: the fitted model's level (heard too briefly, or not at all, for one of its own)


def group_mean(index: np.ndarray, values: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` per index (NaN where none) and the counts."""
    counts = np.bincount(index, minlength=size)
    sums = np.bincount(index, weights=values, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan), counts


def group_median(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Median of ``values`` per index (NaN where none)."""
    order = np.lexsort((values, index))
    index, values = index[order], values[order]
    starts = np.searchsorted(index, np.arange(size), side="left")
    ends = np.searchsorted(index, np.arange(size), side="right")
    out = np.full(size, np.nan)
    for i in np.nonzero(ends > starts)[0]:
        out[i] = np.median(values[starts[i]:ends[i]])
    return out


def file_levels(records: Records, table: LinkTable) -> np.ndarray:
    """The robust empty-area estimate: each link-channel's median RSS over the file."""
    return group_median(table.row_lc, records.rssi, len(table.lc_keys))


def empty_levels(records: Records, table: LinkTable, calibration: Records | None) -> Levels:
    """Levels for every link-channel of ``table``: from ``calibration`` where it has the link-channel, else
    from the file itself."""
    robust = file_levels(records, table)
    empty, calibrated = robust.copy(), np.zeros(len(robust), bool)
    if calibration is not None and len(calibration):
        where = match_keys(link_keys(calibration), table.lc_keys)
        known = where >= 0
        mean, counts = group_mean(where[known], calibration.rssi[known], len(robust))
        calibrated = counts > 0
        empty[calibrated] = mean[calibrated]
    fade, model = fade_levels(empty, table.lc_length)
    return Levels(empty, calibrated, fade, model, np.zeros(len(empty), bool))


def model_levels(records: Records, table: LinkTable) -> Levels:
    """Every link-channel's empty-area level as the log-distance model P0 - 10 n log10(d), fitted across all of
    them, predicts it: the reference for radios that measure a link only while it is obstructed or not at all
    (vehicles that stop at a pair of spots once, a person who stands still all along), which no level of the link's
    own can give. The fit is made robust by refitting without the link-channels more than 2.5 deviations off it
    (those a target shadows, or deep fades); what the model misses of each link (its static shadowing) is noise
    the image averages out over many links."""
    measured = file_levels(records, table)
    distance = np.maximum(table.lc_length, 0.1)
    A = np.column_stack([np.ones_like(distance), -10 * np.log10(distance)])
    keep = np.isfinite(measured)
    if len(np.unique(np.round(distance[keep], 2))) < 2:  # one length only: the exponent is not identifiable
        p0 = float(np.median(measured[keep])) if keep.any() else 0.0
        empty = np.full(len(measured), p0)
        return Levels(empty, np.zeros(len(empty), bool), measured - empty, (p0, 0.0), np.ones(len(empty), bool))
    for _ in range(2):
        (p0, n), *_ = np.linalg.lstsq(A[keep], measured[keep], rcond=None)
        residual = measured - A @ (p0, n)
        spread = 1.4826 * float(np.median(np.abs(residual[keep])))
        keep = np.isfinite(measured) & (np.abs(residual) <= 2.5 * max(spread, 1.0))
    empty = A @ (p0, n)
    return Levels(empty, np.zeros(len(empty), bool), measured - empty, (float(p0), float(n)),
                  np.ones(len(empty), bool))


def brief_or_model_levels(records: Records, table: LinkTable, calibration: Records | None) -> Levels:
    """The calibration's levels where it has a link-channel; else the link-channel's own robust level when it was
    heard over at least half the file's span (long enough for an obstruction to come and go, which that estimate
    assumes); else, for one heard only briefly (a pair of spots a team stood at once), the fitted path-loss
    model's (``model_levels``)."""
    data = empty_levels(records, table, calibration)
    model = model_levels(records, table)
    brief = heard_briefly(records, table) & ~data.calibrated
    empty = np.where(brief, model.empty, data.empty)
    fade, path_loss = fade_levels(empty, table.lc_length)
    return Levels(empty, data.calibrated, fade, path_loss, brief)


def heard_briefly(records: Records, table: LinkTable) -> np.ndarray:
    """Per link-channel: heard over less than half the records' span (a pair of spots a team stood at once), too
    briefly for a level of its own (``brief_or_model_levels``)."""
    first = np.full(len(table.lc_keys), np.inf)
    last = np.full(len(table.lc_keys), -np.inf)
    np.minimum.at(first, table.row_lc, records.t)
    np.maximum.at(last, table.row_lc, records.t)
    span = float(records.t.max() - records.t.min()) if len(records) else 0.0
    return last - first < 0.5 * span


def fade_levels(empty: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """Empty level minus the log-distance model P0 - 10 n log10(d) fitted (least squares) across links."""
    distance = np.maximum(length, 0.1)
    A = np.column_stack([np.ones_like(distance), -10 * np.log10(distance)])
    if len(np.unique(np.round(distance, 2))) < 2:  # one length only: the exponent is not identifiable
        p0 = float(np.mean(empty))
        return empty - p0, (p0, 0.0)
    (p0, n), *_ = np.linalg.lstsq(A, empty, rcond=None)
    return empty - A @ (p0, n), (float(p0), float(n))


def channel_weights(table: LinkTable, fade: np.ndarray) -> np.ndarray:
    """1 for the anti-faded half of each path's link-channels (fade level at or above the path's median),
    0 for the rest: a path measured on one channel keeps it."""
    weights = np.zeros(len(fade))
    median = group_median(table.lc_path, fade, int(table.lc_path.max()) + 1 if len(fade) else 0)
    weights[fade >= median[table.lc_path] - 1e-9] = 1.0
    return weights
