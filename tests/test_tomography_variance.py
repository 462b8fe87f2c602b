"""Variance-based radio tomography (VRTI, vehicle.tomography.variance) on a simulated network: 28 radios around a
6.4 m square, a person walking a circle at 0.8 m/s, 0.7 dB noise per reading, 6 % of readings missing; and the
Tikhonov gradient prior (--prior difference) against its closed form."""

import numpy as np
import pytest
import scipy.sparse as sp

from vehicle.tomography.imaging import above_floor, reconstruct
from vehicle.tomography.links import link_table
from vehicle.tomography.solvers import RegularisedLS, difference_prior_times, gradient_operators
from vehicle.tomography.synthetic import Network, line_distance, square
from vehicle.tomography.variance import windowed_variances

BOUNDS = (0.0, 0.0, 6.4, 6.4)
NOISY = [(0, 14), (3, 9), (20, 5)]  # radio pairs whose receivers are noisier (3 dB) than the rest (0.7 dB)
TIMES = 100 + np.arange(80) * 0.25  # 20 s, four sweeps a second


def walker(t: float) -> list[tuple[float, float]]:
    """A 1.6 m circle round the middle at 0.8 m/s."""
    a = (t - 100) * 0.8 / 1.6
    return [(3.2 + 1.6 * np.cos(a), 3.2 + 1.6 * np.sin(a))]


@pytest.fixture
def net():
    """A fresh network per test: its draws do not depend on which tests ran before."""
    return Network(square(), channels=2, seed=3)


def noise_of(net: Network, noisy: list[tuple[int, int]]) -> np.ndarray:
    noise = np.full(len(net.tx), 0.7)
    for a, b in noisy:
        noise[((net.tx == a) & (net.rx == b)) | ((net.tx == b) & (net.rx == a))] = 3.0
    return noise


def errors(result) -> np.ndarray:
    """Strongest peak to the walker at each window's middle (the first and last windows hold half a span)."""
    out = []
    for frame in result.frames[1:-1]:
        truth = np.array(walker(frame["t"] + 0.5)[0])
        peak = frame["peaks"][0] if frame["peaks"] else None
        out.append(np.hypot(peak["x"] - truth[0], peak["y"] - truth[1]) if peak else np.inf)
    return np.array(out)


def test_the_windowed_variance_is_the_sample_variance_of_each_span():
    rng = np.random.default_rng(7)
    lc = rng.integers(0, 3, 200)
    rssi = np.round(rng.normal(-60, 2, 200))
    frame = np.sort(rng.integers(0, 6, 200))
    for span in (1, 3):
        got = windowed_variances(lc, rssi, 3, frame, 6, span)
        for f in range(6):
            for link in range(3):
                mine = rssi[(lc == link) & (np.abs(frame - f) <= span // 2)]
                expected = np.var(mine, ddof=1) if len(mine) >= 2 else np.nan
                assert got[f, link] == pytest.approx(expected, abs=1e-9, nan_ok=True), (span, f, link)


def test_a_moving_target_raises_the_variance_of_the_links_it_crosses(net):
    records = net.sweeps(TIMES, walker)
    table = link_table(records)
    frame = np.floor(records.t - 100).astype(np.int64)
    variance = windowed_variances(table.row_lc, records.rssi, len(table.lc_keys), frame, 20, 3)
    ends = table.paths[table.lc_path]  # each link-channel's two ends in metres
    crossed, quiet = [], []
    for f in range(1, 19):
        track = [walker(t)[0] for t in np.linspace(99 + f, 102 + f, 13)]  # the span: windows f - 1 .. f + 1
        near = np.min([line_distance(np.asarray(p), ends[:, :2], ends[:, 2:]) for p in track], axis=0)
        crossed.append(variance[f][near < 0.2])
        quiet.append(variance[f][near > 1.0])
    crossed, quiet = np.concatenate(crossed), np.concatenate(quiet)
    assert np.nanmean(crossed) > 5 * np.nanmean(quiet), (np.nanmean(crossed), np.nanmean(quiet))


def test_the_walker_is_tracked_and_noisy_links_paint_no_streak_with_sub_mean(net):
    """Three radio pairs are 3 dB noisy in the empty room too. Less each link-channel's empty-room variance
    (sub-mean), the strongest peak follows the walker (it is smeared along his last 2.4 m: the span is 3 s);
    imaged plain, as the paper does, the noisy links' variance outweighs him."""
    noise = noise_of(net, NOISY)
    calibration = net.sweeps(np.arange(40) * 0.25, noise=noise)
    records = net.sweeps(TIMES, walker, noise=noise)
    result = reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0, peaks=1, measure="variance")
    assert result.info["measure"] == "variance" and result.info["variance"] == "sub-mean"
    sub_mean = errors(result)
    assert np.median(sub_mean) < 1.0 and np.percentile(sub_mean, 90) < 1.5, sub_mean
    plain = errors(reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0, peaks=1,
                               measure="variance", variance="plain"))
    far = 2.5  # m: more than the span's smear (2.4 m) away: the peak is on something else
    assert np.mean(plain > far) > 0.25 and not (sub_mean > far).any(), (plain, sub_mean)


def test_a_person_standing_still_is_not_motion(net):
    """The variance images motion: a person who stands still changes a link's mean, not its spread."""
    calibration = net.sweeps(np.arange(40) * 0.25)
    peak = {}
    for name, people in (("still", lambda t: [(3.1, 2.9)]), ("moving", walker)):
        result = reconstruct(net.sweeps(TIMES, people), calibration, bounds=BOUNDS, cell=0.2, window=1.0,
                             peaks=1, measure="variance")
        peak[name] = np.median([frame["max"] for frame in result.frames])
    assert peak["still"] < 0.05 * peak["moving"], peak


def test_the_kernel_reference_is_the_file_when_windows_are_imaged(net):
    """--reference auto: KRTI's long-term histogram (the file's) for tracking in windows, the empty room's for
    one image of the whole file (against the file's own, a single frame would be its own reference)."""
    calibration = net.sweeps(np.arange(8) * 0.5)
    records = net.sweeps(TIMES, walker)
    assert reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0).info["reference"] == "file"
    assert reconstruct(records, calibration, bounds=BOUNDS, cell=0.2).info["reference"] == "empty"
    assert reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0,
                       reference="empty").info["reference"] == "empty"


def test_the_difference_prior_is_tikhonov_with_a_gradient_penalty():
    """x = argmin |W x - y|^2 + alpha x'Qx, Q = Dx'Dx + Dy'Dy + I / reach^2, solved in the paths' space."""
    rng = np.random.default_rng(2)
    shape, reach, alpha = (6, 7), 2.5, 0.3
    W = sp.random(9, 42, density=0.3, random_state=3, format="csr")
    y = rng.normal(size=9)
    B = difference_prior_times(shape, W, reach)
    x = RegularisedLS(W, np.zeros((42, 2)), 1.0, B).solve(y, alpha)
    Dx, Dy = gradient_operators(shape)
    Q = (Dx.T @ Dx + Dy.T @ Dy).toarray() + np.eye(42) / reach ** 2
    expected = np.linalg.solve(W.T @ W + alpha * Q, W.T @ y)
    assert np.allclose(x, expected, atol=1e-8)



def test_each_path_is_measured_above_its_own_kernel_floor():
    """An unchanged path reads above zero by its own floor (a quiet path 0.02, a noisy one 0.3); a person's
    rise on a path is measured from that path's floor, so the quiet and the noisy path read the same rise."""
    rng = np.random.default_rng(4)
    Y = np.column_stack([0.02 + rng.normal(0, 0.005, 40), 0.3 + rng.normal(0, 0.05, 40)])
    Y[30:34] += 0.5  # someone crosses both paths in four of the forty frames
    Y[5, 1] = np.nan  # a frame that did not hear the noisy path
    above, floor = above_floor(Y)
    assert floor == pytest.approx([0.02, 0.3], abs=0.03)
    assert np.nanmedian(above, axis=0) == pytest.approx([0.0, 0.0], abs=1e-12)
    assert above[30:34].mean(axis=0) == pytest.approx([0.5, 0.5], abs=0.06)
    assert np.isnan(above[5, 1])


def test_the_floor_is_taken_only_against_the_files_own_histogram_over_enough_frames(net):
    """KRTI's premise (each path unchanged most of the time) holds for the file's own long-term histogram over
    many windows; against an empty capture, or over a few windows, a person standing still would be the floor."""
    calibration = net.sweeps(np.arange(8) * 0.5)
    records = net.sweeps(TIMES, walker)
    assert reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0).info["kernel_floor"] > 0
    assert "kernel_floor" not in reconstruct(records, calibration, bounds=BOUNDS, cell=0.2, window=1.0,
                                             reference="empty").info
    short = net.sweeps(100 + np.arange(20) * 0.25, walker)  # 5 windows
    assert "kernel_floor" not in reconstruct(short, calibration, bounds=BOUNDS, cell=0.2, window=1.0).info
