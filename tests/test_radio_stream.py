"""The radio link stream (vehicle.protocol.radiostream): loss, reordering, duplicates and hostile payloads, the
station's log of it (Fleet.radio, from real MAVLink bytes), and a recording's records exported as LINKS.csv."""

from __future__ import annotations

import csv
import math
import random
import threading

import numpy as np
import pytest
from harness import SPEEDUP, RunningStation, small_scene, start_sim, wait_wall
from mavlink_peer import Delivered

from groundstation.links_export import export_links
from groundstation.replay import Replay
from groundstation.state import Fleet
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.radiostream import (
    FORMAT_VERSION,
    HEADER,
    PAYLOAD,
    RADIO_LINKS,
    RECORD,
    LinkLog,
    LinkReceiver,
    LinkRecord,
    LinkSender,
)
from vehicle.sim.radios import Radios
from vehicle.tomography.links import records_of


def records(count: int, rx: int = 1, start: float = 10.0) -> list[LinkRecord]:
    rng = random.Random(count)
    senders = [tx for tx in (2, 4, 5, 200) if tx != rx]
    return [LinkRecord(round(start + 0.0125 * k, 4), rng.choice(senders), rx, rng.uniform(-50, 50),
                       rng.uniform(-50, 50), 1.5, -2.25, float(rng.randint(-90, -40)), 11) for k in range(count)]


def same(a: list[LinkRecord], b: list[LinkRecord]) -> bool:
    """Equal but for float32 positions and millisecond times."""
    key = lambda r: (round(r.t, 3), r.tx, r.rx)  # noqa: E731
    a, b = sorted(a, key=key), sorted(b, key=key)
    return len(a) == len(b) and all(
        (x.tx, x.rx, x.channel) == (y.tx, y.rx, y.channel) and abs(x.t - y.t) < 1e-3 and x.rssi == y.rssi
        and max(abs(x.tx_x - y.tx_x), abs(x.tx_y - y.tx_y), abs(x.rx_x - y.rx_x), abs(x.rx_y - y.rx_y)) < 1e-3
        for x, y in zip(a, b, strict=True))


def test_records_arrive_as_sent_in_payloads_a_tunnel_holds():
    sent = records(50)
    payloads = LinkSender().payloads(sent)
    assert all(len(p) <= PAYLOAD for p in payloads) and len(payloads) == math.ceil(50 / 4)
    receiver = LinkReceiver()
    got = [r for p in payloads for r in receiver.feed(p, 1)]
    assert same(got, sent) and receiver.records == 50


def test_loss_costs_only_the_lost_payloads_and_reordering_or_repeats_nothing():
    sent = records(200)
    payloads = LinkSender().payloads(sent)
    kept = [p for k, p in enumerate(payloads) if k % 3]  # a third lost
    shuffled = kept + kept[::2]  # and some twice
    random.Random(1).shuffle(shuffled)
    receiver = LinkReceiver()
    got = [r for p in shuffled for r in receiver.feed(p, 1)]
    expected = [r for k, p in enumerate(payloads) if k % 3 for r in LinkReceiver().feed(p, 1)]
    assert same(got, expected) and len(got) == len(expected) > 120
    assert receiver.duplicates == len(kept[::2])


def test_a_sender_that_starts_again_is_heard_again():
    receiver = LinkReceiver()
    first = LinkSender().payloads(records(400))
    for p in first:
        receiver.feed(p, 1)
    again = LinkSender().payloads(records(8, start=500.0))  # numbered from 1 again
    assert same([r for p in again for r in receiver.feed(p, 1)], records(8, start=500.0))


def _payload(*rows, seq=1, base=0.0, count=None, version=FORMAT_VERSION) -> bytes:
    return HEADER.pack(version, seq, base, len(rows) if count is None else count) + b"".join(
        RECORD.pack(*row) for row in rows)


def test_hostile_payloads_are_dropped_and_counted_never_raised():
    good = (2, 1, 5, 1.0, 2.0, 3.0, 4.0, -5500, 11)
    receiver = LinkReceiver()
    assert receiver.feed(_payload(good), 1) == [LinkRecord(0.005, 2, 1, 1.0, 2.0, 3.0, 4.0, -55.0, 11)]
    bad_records = [(2, 1, 5, math.nan, 2.0, 3.0, 4.0, -5500, 11), (2, 1, 5, 1e9, 2.0, 3.0, 4.0, -5500, 11),
                   (2, 1, 5, 1.0, 2.0, math.inf, 4.0, -5500, 11), (1, 1, 5, 1.0, 2.0, 3.0, 4.0, -5500, 11),
                   (2, 1, 5, 1.0, 2.0, 3.0, 4.0, 9000, 11), (2, 7, 5, 1.0, 2.0, 3.0, 4.0, -5500, 11)]
    for seq, row in enumerate(bad_records, start=2):  # NaN, far away, inf, heard by itself, +90 dBm, not its own
        assert receiver.feed(_payload(row, seq=seq), 1) == []
    assert receiver.dropped == len(bad_records)
    damaged = [b"", b"\x01", _payload(good, seq=20)[:-3], _payload(good, seq=21, count=3),
               _payload(good, seq=22, count=9), _payload(good, seq=23, version=9),
               _payload(good, seq=24, base=math.nan)]
    for payload in damaged:
        assert receiver.feed(payload, 1) == []
    assert receiver.damaged == len(damaged)
    rng = np.random.default_rng(0)
    for _ in range(5000):  # garbage: nothing raises, and what passes is plausible
        for r in receiver.feed(rng.integers(0, 256, rng.integers(0, 129), dtype=np.uint8).tobytes(), 0):
            assert all(math.isfinite(v) and abs(v) < 3000 for v in (r.t, r.tx_x, r.tx_y, r.rx_x, r.rx_y, r.rssi))
    assert receiver.payloads == 1 + len(bad_records) + len(damaged) + 5000


def test_the_sender_leaves_out_what_no_receiver_would_keep_and_splits_long_spans():
    sender = LinkSender()
    odd = [LinkRecord(0.0, 2, 1, math.nan, 0, 1, 1, -50, 11), LinkRecord(0.0, 1, 1, 0, 0, 1, 1, -50, 11)]
    assert sender.payloads(odd) == []
    spread = [LinkRecord(t, 2, 1, 0, 0, 1, 1, -50, 11) for t in (0.0, 30.0, 70.0, 69.0)]  # 70 s: past the ms field
    payloads = sender.payloads(spread)
    assert len(payloads) == 3 and same([r for p in payloads for r in LinkReceiver().feed(p, 1)], spread)


def test_the_link_log_is_bounded_answers_by_time_and_takes_appends_from_threads():
    log = LinkLog(capacity=3000)

    def append(k):
        for i in range(100):
            log.append([LinkRecord(k * 1000 + i, 2, 1, float(i), 0.0, 5.0, 0.0, -50.0, 11)] * 5)

    threads = [threading.Thread(target=append, args=(k,)) for k in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(log) == 3000  # 4000 appended, the oldest gone
    columns = records_of(log.snapshot(since=5000, until=5050))
    assert len(columns) == 250 and np.all(np.diff(columns.t) >= 0) and columns.tx.shape == (250, 2)
    assert columns.rssi[0] == -50.0 and columns.channel.dtype == np.int64
    assert len(records_of(log.snapshot(since=1e9))) == 0


def tunnel(payload: bytes):
    return mavlink.MAVLink_tunnel_message(0, 0, RADIO_LINKS, len(payload), list(payload.ljust(PAYLOAD, b"\0")))


def test_the_fleet_takes_the_agents_records_in_the_scene_frame_from_mavlink_bytes():
    datum = Datum()
    autopilot, agent = Delivered(3, 1), Delivered(3, 191)
    fleet = Fleet(datum)
    beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4,
                                             mavlink.MAV_STATE_ACTIVE, 3)
    fleet.apply(autopilot(beat), 0.0)
    sent = records(12, rx=3)
    payloads = LinkSender().payloads(sent)
    fleet.apply(agent(tunnel(payloads[0])), 0.5)  # before the vehicle's home is known: held
    assert len(fleet.radio) == 0
    lat, lon = datum.to_global(10.0, -4.0)
    fleet.apply(autopilot(mavlink.MAVLink_global_position_int_message(1000, int(lat * 1e7), int(lon * 1e7), 0, 0,
                                                                      0, 0, 0, 0)), 1.0)
    for payload in payloads[1:]:
        fleet.apply(agent(tunnel(payload)), 1.5)
    fleet.apply(autopilot(tunnel(LinkSender().payloads(records(4, rx=3, start=99.0))[0])), 2.0)  # not the agent's
    hx, hy = fleet.get(3).home
    assert (hx, hy) == pytest.approx((10.0, -4.0), abs=0.02)
    moved = [LinkRecord(r.t, r.tx, r.rx, r.tx_x + hx, r.tx_y + hy, r.rx_x + hx, r.rx_y + hy, r.rssi, r.channel)
             for r in sent]
    assert same(fleet.radio.snapshot(), moved)
    fleet.apply(agent(tunnel(payloads[1])), 3.0)  # a repeat
    assert len(fleet.radio) == 12 and fleet.get(3).radio_stream.duplicates == 1


def test_a_recording_exports_the_records_the_station_got_and_a_replay_seek_rebuilds_them(tmp_path):
    scene = small_scene()
    with RunningStation(scene, tmp_path) as running:
        sim = start_sim(running, scene, mission="browse", autostart=True)
        world = sim.world
        sim.sim.radios = Radios(scene, [1], [(-5.0, 0.0, 1.0), (5.0, 3.0, 2.0)], [(0.0, 1.0)], seed=2,
                                home={1: (world.home[0], world.home[1])})
        with sim:
            fleet = running.station.live
            wait_wall(lambda: len(fleet.radio) >= 120, 60 / SPEEDUP * 10, "120 link records at the station")
        got = fleet.radio.snapshot()
        recording = running.station.recorder.path
    assert {(r.tx, r.rx) for r in got} == {(200, 1), (201, 1)}  # the nodes' packets, heard by the vehicle
    assert {(round(r.tx_x, 3), round(r.tx_y, 3)) for r in got} == {(-5.0, 0.0), (5.0, 3.0)}  # scene frame
    out = tmp_path / "links.csv"
    count, frame = export_links(recording, out, scene)
    with open(out, encoding="utf-8") as file:
        rows = list(csv.DictReader(file))
    exported = [LinkRecord(float(r["t"]), int(r["tx"]), int(r["rx"]), float(r["tx_x"]), float(r["tx_y"]),
                           float(r["rx_x"]), float(r["rx_y"]), float(r["rssi"]), int(r["channel"])) for r in rows]
    assert count == len(rows) and same(exported, got)
    assert [float(r["t"]) for r in rows] == sorted(float(r["t"]) for r in rows)

    replay = Replay.open(recording, Fleet(Datum(), forget_after=None))
    replay.seek(replay.duration)
    assert same(replay.fleet.radio.snapshot(), got)
    replay.seek(replay.duration / 2)
    half = replay.fleet.radio.snapshot()
    assert 0 < len(half) < len(got) and same(half, [r for r in got if r.t <= max(h.t for h in half)])
    replay.seek(replay.duration)
    assert len(replay.fleet.radio) == len(got)  # a seek back and forth counts each record once
