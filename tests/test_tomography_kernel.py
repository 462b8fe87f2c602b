"""Kernel distance measurements (vehicle.tomography.kernel): the squared kernel distance between a frame's
short-term RSS histogram and the long-term one, against its definition computed pair by pair."""

import numpy as np
import pytest

from vehicle.tomography.imaging import reconstruct
from vehicle.tomography.kernel import kernel_distances, kernel_width, reference_rows
from vehicle.tomography.links import Records, link_table
from vehicle.tomography.synthetic import Network, square


def records_of(t, rssi, channel):
    n = len(t)
    return Records("test", np.asarray(t, float), np.tile([0.0, 0.0], (n, 1)), np.tile([3.0, 0.0], (n, 1)),
                   np.asarray(rssi, float), np.asarray(channel, np.int64))


def definition(p, q, width):
    k = lambda a, b: np.exp(-0.5 * ((np.asarray(a)[:, None] - np.asarray(b)[None, :]) / width) ** 2).mean()  # noqa: E731
    return k(p, p) + k(q, q) - 2 * k(p, q)


def test_kernel_distance_matches_its_definition_per_frame_and_channel():
    rng = np.random.default_rng(4)
    calibration = records_of(np.zeros(40), np.round(rng.normal(-60, 1.0, 40)), np.repeat([1, 2], 20))
    t = np.repeat(np.arange(6.0), 4)
    rssi = np.round(rng.normal(-63, 3.0, len(t)))
    channel = np.tile([1, 1, 2, 2], 6)
    records = records_of(t, rssi, channel)
    table = link_table(records)
    reference = reference_rows(records, table, calibration)
    width = kernel_width(*reference)
    assert width >= 1.0
    frame = t.astype(np.int64)
    for span in (1, 3):
        got = kernel_distances(records, table, reference, np.ones(len(t), bool), frame, 6, span, width)
        for f in range(6):
            for lc in range(len(table.lc_keys)):
                ch = table.lc_keys[lc, 4]
                window = (np.abs(frame - f) <= span // 2) & (channel == ch)
                expected = definition(rssi[window], calibration.rssi[calibration.channel == ch], width)
                assert got[f, lc] == pytest.approx(expected, abs=1e-9), (span, f, lc)


def test_the_file_is_the_long_term_histogram_where_there_is_no_calibration():
    records = records_of([0.0, 1.0, 2.0], [-60, -61, -60], [1, 1, 1])
    table = link_table(records)
    lc, rssi = reference_rows(records, table, None)
    assert sorted(rssi) == [-61, -60, -60] and (lc == 0).all()
    calibration = records_of([0.0], [-50], [1])
    lc, rssi = reference_rows(records, table, calibration)
    assert list(rssi) == [-50]
    lc, rssi = reference_rows(records, table, calibration, recalibrate=np.array([True]))  # a drifted link
    assert sorted(rssi) == [-61, -60, -60]


def test_a_person_standing_still_is_found_with_the_first_seconds_as_calibration():
    """No empty capture file: the first 4 s are empty, then a person stands still for the rest."""
    net = Network(square(), channels=2, seed=5)
    person = np.array([2.9, 4.4])
    times = np.arange(24) * 0.5
    records = net.sweeps(times, lambda t: [person] if t >= 4 else [])
    for measure in ("kernel", "mean"):
        result = reconstruct(records, calibration_seconds=4, bounds=(0, 0, 6.4, 6.4), cell=0.2, measure=measure)
        peak = result.frames[0]["peaks"][0]
        assert np.hypot(peak["x"] - person[0], peak["y"] - person[1]) < 0.3, (measure, peak)
        assert result.info["measure"] == measure
