"""The station's live radio tomography: frames from link records find the target, a slow solve skips windows
instead of queueing them and never blocks a reader, and a replay's rebuilt log gives the frame the live station
showed."""

import math
import threading

import numpy as np
import pytest

from groundstation.rti_live import LiveImager, boundary, frame_at, picture
from vehicle.protocol.radiostream import LinkLog, LinkRecord
from vehicle.tomography import synthetic
from vehicle.tomography.links import records_of

TARGET = (2.0, 4.0)


def sweep_rows(start: float, stop: float, seed: int = 3, person_from: float = 20.0) -> list[LinkRecord]:
    """A 16-radio square of 6.4 m measuring every 0.5 s; a person stands at TARGET from ``person_from``. Every
    record is vehicle 1 hearing radio 2 (a vehicle reports what its own radio heard)."""
    net = synthetic.Network(synthetic.square(16, 6.4), channels=1, seed=seed)
    recs = net.sweeps(np.arange(start, stop, 0.5), people=lambda t: [TARGET] if t >= person_from else [])
    return [LinkRecord(float(recs.t[i]), 2, 1, *recs.tx[i], *recs.rx[i], float(recs.rssi[i]), int(recs.channel[i]))
            for i in range(len(recs))]


@pytest.fixture(scope="module")
def rows():
    return sweep_rows(0.0, 30.0)


def test_a_frame_from_synthetic_records_finds_the_target(rows):
    log = LinkLog()
    log.append(rows)
    frame = frame_at(records_of(log.snapshot()), 30.0, window=1.0, history=60.0)
    best = frame.peaks[0]
    assert math.dist((best["x"], best["y"]), TARGET) < 0.5, frame.peaks
    assert frame.t == 30.0 and frame.bounds == (0.0, 0.0, 6.4, 6.4)
    assert frame.links_per_s == pytest.approx(sum(r.t >= 29.0 for r in rows), rel=0.01)
    assert 0.9 < frame.coverage <= 1.0  # 16 radios round the square cross nearly every pixel
    assert len(frame.links) == 120  # the last window's distinct paths: 16 * 15 / 2
    drawn = picture(frame)
    assert drawn["image"].startswith("data:image/png;base64,") and drawn["scale"]["max"] > 0


def test_frames_are_the_window_boundaries_of_the_records_clock(rows):
    assert boundary(29.99, 1.0) == 29.0 and boundary(30.0, 1.0) == 30.0
    log = LinkLog()
    imager = LiveImager(lambda: log, window=1.0)
    assert not imager.step() and imager.latest() is None  # nothing heard: no frame, no error
    log.append([r for r in rows if r.t < 25.2])
    assert imager.step()
    assert imager.latest().t == 25.0 and imager.latest().records == sum(r.t < 25.0 for r in rows)
    log.append([r for r in rows if 25.2 <= r.t < 25.7])  # still inside the window 25..26: nothing new to image
    assert not imager.step() and imager.latest().t == 25.0


def test_a_slow_solve_skips_windows_and_blocks_no_reader(rows):
    log = LinkLog()
    log.append([r for r in rows if r.t < 10.2])
    entered, release, seen = threading.Event(), threading.Event(), []

    def slow(records, end, **options):
        seen.append(end)
        entered.set()
        assert release.wait(30)
        return frame_at(records, end, **options)

    imager = LiveImager(lambda: log, window=1.0, solve=slow)
    imager.start()
    try:
        assert entered.wait(30)
        log.append([r for r in rows if 10.2 <= r.t < 15.2])  # five windows close while the first solve runs
        assert imager.latest() is None  # a reader is answered at once, mid-solve
        entered.clear()
        release.set()
        assert entered.wait(30)
        for _ in range(1500):
            if imager.latest() is not None and imager.latest().t == 15.0:
                break
            threading.Event().wait(0.02)
    finally:
        imager.stop()
    assert seen == [10.0, 15.0]  # 11 .. 14 were never queued
    assert imager.skipped == 4 and imager.latest().t == 15.0


def test_replay_seek_gives_the_frame_the_live_station_showed(rows):
    live_log, shown = LinkLog(), {}
    live = LiveImager(lambda: live_log, window=1.0)
    for start in np.arange(0.0, 30.0, 0.5):  # records arrive in batches, a frame per window
        live_log.append([r for r in rows if start <= r.t < start + 0.5])
        if live.step() and live.latest() is not None:
            shown[live.latest().t] = live.latest()
    replay_log = LinkLog()
    replay = LiveImager(lambda: replay_log, window=1.0)
    for seek in (27.3, 21.6, 29.9):  # a seek rebuilds the log from the records up to then
        replay_log.clear()
        replay_log.append([r for r in rows if r.t <= seek])
        replay.step()
        frame, then = replay.latest(), shown[boundary(seek, 1.0)]
        assert frame.t == then.t
        np.testing.assert_array_equal(frame.image, then.image)
        assert frame.peaks == then.peaks and frame.links == then.links


def test_switching_logs_forgets_the_other_frame(rows):
    logs = {"which": LinkLog()}
    logs["which"].append(rows)
    imager = LiveImager(lambda: logs["which"], window=1.0)
    assert imager.step() and imager.latest() is not None
    logs["which"] = LinkLog()  # a replay with no radio records
    imager.step()
    assert imager.latest() is None


def test_a_team_that_hears_each_pair_once_is_imaged_over_its_whole_mission():
    """A mission's pairs of spots are each heard once, one after another (here 120 pairs in 240 s): the frame
    images them all, where the last minute's 30 pairs put the peak metres off the standing person."""
    from test_tomography_reference import TARGET as STANDING
    from test_tomography_reference import one_turn_each

    misses = []
    for seed in (1, 2, 3, 4):
        best = frame_at(one_turn_each(seed), 240.0).peaks[0]
        misses.append(math.dist((best["x"], best["y"]), STANDING))
    assert sum(m < 0.5 for m in misses) >= 3, misses


def test_a_link_heard_all_along_is_imaged_from_records_spread_over_the_history():
    """A fixed network heard for 300 s costs a frame no more records per link than PER_LINK, taken evenly from
    the whole history (its first minute included), and still finds the person who walked in."""
    from groundstation.rti_live import PER_LINK, evenly

    assert evenly(np.array([0, 0, 0, 0, 0, 1, 1, 0, 0, 0]), 3).tolist() == [True, False, False, True, False,
                                                                            True, True, False, True, False]
    records = records_of(sweep_rows(0.0, 300.0, person_from=200.0))
    frame = frame_at(records, 300.0)
    assert frame.records <= 120 * PER_LINK < len(records) / 2
    best = frame.peaks[0]
    assert math.dist((best["x"], best["y"]), TARGET) < 0.5, frame.peaks


def test_a_missions_image_outlives_the_mission():
    """Landed at home, a team's radios go on measuring the one link between their homes: the paths the mission
    measured stay in the image (for FORGET s), where a sliding history forgot them and showed that one link."""
    from test_tomography_reference import TARGET as STANDING
    from test_tomography_reference import one_turn_each

    from groundstation.rti_live import FORGET
    from vehicle.tomography.links import Records

    mission = one_turn_each(2)
    home = np.arange(240.0, 640.0, 0.5)  # a pair of spots heard on after the mission, as two homes are
    rows = np.flatnonzero(mission.t < 2.0)[:1]  # the first pair's path
    after = Records("after", home, np.repeat(mission.tx[rows], len(home), 0), np.repeat(mission.rx[rows], len(home), 0),
                    np.full(len(home), mission.rssi[rows][0]), np.repeat(mission.channel[rows], len(home)))
    records = Records("all", *(np.concatenate([a, b]) for a, b in zip(
        (mission.t, mission.tx, mission.rx, mission.rssi, mission.channel),
        (after.t, after.tx, after.rx, after.rssi, after.channel), strict=True)))
    frame = frame_at(records, 640.0)
    assert 640.0 - 240.0 < FORGET and frame.paths > 100
    best = frame.peaks[0]
    assert math.dist((best["x"], best["y"]), STANDING) < 0.5, frame.peaks


def test_the_command_line_gives_the_live_image_from_the_same_records(rows, tmp_path, capsys):
    """docs/rti.md: ``rti reconstruct`` with the station's options on a recording's exported links images what
    the page showed (here every path has at most PER_LINK records, which the station would thin)."""
    import json

    from groundstation.cli import main

    rows = [r for r in rows if r.t < 25.0]  # 50 sweeps, both ways: 100 records a path
    log = LinkLog()
    log.append(rows)
    frame = frame_at(records_of(log.snapshot()), 25.0, window=1.0, history=60.0)
    links = tmp_path / "links.csv"
    links.write_text("t,tx,rx,tx_x,tx_y,rx_x,rx_y,rssi,channel\n" + "".join(
        ",".join(str(float(v)) for v in (r.t, r.tx, r.rx, r.tx_x, r.tx_y, r.rx_x, r.rx_y, r.rssi, r.channel)) + "\n"
        for r in rows))
    out = tmp_path / "out.json"
    assert main(["rti", "reconstruct", str(links), "--cell", "0.25", "--measure", "mean", "--solver", "sparse",
                 "--model", "line", "--empty-from", "brief", "--images", "--json", str(out)]) == 0, capsys.readouterr()
    imaged = json.loads(out.read_text())["frames"][0]
    np.testing.assert_allclose(imaged["image"], np.round(frame.image, 4), atol=1e-4)
    assert imaged["peaks"] == frame.peaks
