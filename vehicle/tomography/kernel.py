"""Kernel distance measurements (KRTI: Zhao, Patwari, Phillips and Venkatasubramanian, "Radio tomographic imaging
and tracking of stationary and moving people via kernel distance", IPSN 2013).

Per link-channel and frame, the measurement is the kernel distance between the short-term histogram p of its
RSS (the readings of the frame's span of windows) and the long-term histogram q (the calibration capture's, or
without one the whole file's): D^2 = p'Kp + q'Kq - 2 p'Kq, K a Gaussian kernel on RSS values. It is zero when
the readings look like the empty room, grows with any change a person makes on the line (attenuation, or a
multipath rise), and is bounded (at most 2): a link that changes wildly far from the person counts no more
than one that the person blocks, where the mean attenuation counts it by its dB.

Histograms are over 1 dB bins (the step radios report). The kernel's width is the pooled spread of the
long-term readings about their link-channels' medians (their root-mean-square deviation, at least the 1 dB
step): readings within the room's own noise are alike, a person's shadow (several dB) is not.
"""

from __future__ import annotations

import numpy as np

from vehicle.tomography.links import LinkTable, Records, link_keys, match_keys

STEP_DB = 1.0  # the RSS step radios report, and the histograms' bin


def reference_rows(records: Records, table: LinkTable, calibration: Records | None,
                   recalibrate: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The long-term readings as (link-channel index, RSS): the calibration's where it has the link-channel
    (and it is not in ``recalibrate``, a bool per link-channel), else the file's own."""
    own = np.ones(len(table.lc_keys), bool)
    lc, rssi = np.zeros(0, np.int64), np.zeros(0)
    if calibration is not None and len(calibration):
        where = match_keys(link_keys(calibration), table.lc_keys)
        keep = where >= 0
        if recalibrate is not None:
            keep &= ~recalibrate[np.maximum(where, 0)]
        lc, rssi = where[keep], calibration.rssi[keep]
        own[np.unique(lc)] = False
    from_file = own[table.row_lc]
    return np.concatenate([lc, table.row_lc[from_file]]), np.concatenate([rssi, records.rssi[from_file]])


def kernel_width(lc: np.ndarray, rssi: np.ndarray) -> float:
    """The pooled root-mean-square deviation (dB) of the long-term readings from their link-channel's median,
    at least STEP_DB (readings one reporting step apart are alike: the step is the radio's rounding)."""
    if not len(lc):
        return STEP_DB
    order = np.lexsort((rssi, lc))
    lc, rssi = lc[order], rssi[order]
    starts = np.searchsorted(lc, lc, side="left")
    ends = np.searchsorted(lc, lc, side="right")
    median = 0.5 * (rssi[starts + (ends - starts - 1) // 2] + rssi[starts + (ends - starts) // 2])
    return max(STEP_DB, float(np.sqrt(np.mean((rssi - median) ** 2))))


def pool_span(frame: np.ndarray, frames: int, span: int, *columns: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each record once for every frame whose span (``span`` windows centred on it) covers its window: the
    frame indices and the columns repeated alike, within 0 .. frames - 1."""
    half = span // 2
    f = np.concatenate([frame + s for s in range(-half, span - half)])
    keep = (f >= 0) & (f < frames)
    return (f[keep], *(np.tile(column, span)[keep] for column in columns))


def kernel_distances(records: Records, table: LinkTable, reference: tuple[np.ndarray, np.ndarray],
                     use: np.ndarray, frame: np.ndarray, frames: int, span: int, width: float) -> np.ndarray:
    """(frames x link-channels) squared kernel distances, NaN where a link-channel was not heard in a frame's
    span. ``use`` selects the records that are imaged, ``frame`` their frame index; a frame's short-term
    histogram pools the ``span`` windows centred on it."""
    n_lc = len(table.lc_keys)
    ref_lc, ref_rssi = reference
    values = np.concatenate([np.round(ref_rssi), np.round(records.rssi[use])])
    low = float(values.min()) if len(values) else 0.0
    bins = int(values.max() - low) + 1 if len(values) else 1
    offsets = np.arange(-(bins - 1), bins)
    kernel = np.exp(-0.5 * (offsets / width) ** 2)  # K between two bins, by their difference
    # long-term histogram q per link-channel, (K q)(v) for every bin v, and q'Kq
    q = np.zeros((n_lc, bins))
    np.add.at(q, (ref_lc, (np.round(ref_rssi) - low).astype(np.int64)), 1.0)
    q /= np.maximum(q.sum(axis=1, keepdims=True), 1.0)
    square = kernel[(np.arange(bins)[:, None] - np.arange(bins)[None, :]) + bins - 1]
    Kq = q @ square
    qKq = (Kq * q).sum(axis=1)
    f, lc, value = pool_span(frame, frames, span, table.row_lc[use],
                             (np.round(records.rssi[use]) - low).astype(np.int64))
    group = f * n_lc + lc
    size = frames * n_lc
    counts = np.bincount(group, minlength=size).astype(float)
    pKq = np.bincount(group, weights=Kq[lc, value], minlength=size)
    # p'Kp over each group's distinct bins (sorted, so two bins of one group are entries i and i + k)
    cells, weight = np.unique(group * bins + value, return_counts=True)
    cell_group, cell_bin = cells // bins, cells % bins
    pKp = np.bincount(cell_group, weights=weight.astype(float) ** 2, minlength=size)
    for k in range(1, bins):
        same = cell_group[k:] == cell_group[:-k]
        if not same.any():
            break
        pair = weight[k:][same] * weight[:-k][same] * kernel[cell_bin[k:][same] - cell_bin[:-k][same] + bins - 1]
        pKp += 2 * np.bincount(cell_group[k:][same], weights=pair, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        distance = pKp / counts ** 2 + np.tile(qKq, frames) - 2 * pKq / counts
    distance = np.where(counts > 0, np.maximum(distance, 0.0), np.nan)
    return distance.reshape(frames, n_lc)
