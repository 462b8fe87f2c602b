"""What a recording keeps, and how far it may grow: a night of flooding must not fill the disk.

The station records everything from its vehicles and everything it sends; of a sender that is not one of its
vehicles, only the first few messages a minute (counted in /api/health). A recording that reaches its size or
duration limit is closed and the next begun, a new .tlog in the same list that replays like any other. No
recording is begun on a nearly full disk, and the health banner's field says so.
"""

from __future__ import annotations

import shutil
import time
from collections import Counter
from pathlib import Path

from harness import RunningStation, wait_wall
from mavlink_peer import Peer, position, vehicle_heartbeat
from pymavlink import mavutil

import groundstation.recorder as recorder_module
from groundstation.recorder import Limits
from vehicle.protocol.mav import mavlink, pack

STRANGER = 77


def senders(path: Path) -> Counter:
    """Messages in a .tlog by system id, as pymavlink reads it."""
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    counted = Counter()
    while (message := log.recv_match()) is not None:
        if message.get_type() != "BAD_DATA":
            counted[message.get_srcSystem()] += 1
    log.close()
    return counted


def send_and_wait(running: RunningStation, peer: Peer, messages: list, batch: int = 50) -> None:
    """Send in batches the station's socket holds, each heard before the next goes."""
    link = running.station.link
    for start in range(0, len(messages), batch):
        expected = link.stats["received"] + len(messages[start:start + batch])
        peer.send(*messages[start:start + batch])
        wait_wall(lambda expected=expected: link.stats["received"] >= expected, 20, "the batch heard")


def test_a_flood_from_a_stranger_is_capped_and_a_vehicle_is_recorded_whole(tmp_path):
    quota = 20
    with RunningStation(None, tmp_path, record_limits=Limits(stranger_messages=quota)) as running, \
            running.api() as api, Peer(("127.0.0.1", running.mavlink_port), sysid=1) as peer:
        send_and_wait(running, peer, [vehicle_heartbeat()] + [position(time_ms=1000 + k) for k in range(100)])
        wait_wall(lambda: 1 in api.vehicles(), 10, "vehicle 1 shown")
        peer.as_system(STRANGER)  # no heartbeat of a vehicle: never one the station holds
        flood = [position(time_ms=k) for k in range(400)]
        send_and_wait(running, peer, flood)
        recorder = running.station.recorder
        recorder._writer.flush()
        counted = senders(recorder.path)
        health = api.get("/api/health").json()["recording"]
    assert counted[1] == 101  # the vehicle: all of it
    # the stranger: its quota (twice at most, if the flood straddled a minute), the rest counted
    assert quota <= counted[STRANGER] <= 2 * quota
    assert health["strangers_dropped"] == len(flood) - counted[STRANGER]


def test_a_recording_at_its_size_limit_goes_on_in_a_second_file_that_replays(tmp_path):
    limit = 20_000
    with RunningStation(None, tmp_path, record_limits=Limits(max_bytes=limit)) as running, running.api() as api, \
            Peer(("127.0.0.1", running.mavlink_port), sysid=1) as peer:
        send_and_wait(running, peer, [vehicle_heartbeat()])  # vehicle 1 known: all of it is kept
        recorder, first = running.station.recorder, running.station.recorder.path
        packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        beat = pack(vehicle_heartbeat(), packer)
        stamp = time.time()
        for k in range(800):  # some 30 kB from vehicle 1, 10 ms apart
            recorder.write(beat if k % 10 == 0 else pack(position(time_ms=k * 10), packer), stamp + k / 100, 1)
        recorder._writer.flush()
        second = recorder.path
        listed = {r["name"]: r for r in api.get("/api/recordings").json()}
        assert second != first and {first.name, second.name} <= set(listed)
        assert listed[second.name]["recording"] and not listed[first.name]["recording"]
        assert limit * 0.9 < first.stat().st_size <= limit  # closed at the limit, not past it
        started = api.post("/api/replay", json={"name": first.name}, headers=api.operator)
        assert started.status_code == 200, started.text
        wait_wall(lambda: 1 in api.vehicles(), 10, "vehicle 1 replayed")
        assert senders(first)[1] + senders(second)[1] == 801  # nothing lost between the two


def test_a_recording_at_its_duration_limit_goes_on_in_a_second_file(tmp_path):
    with RunningStation(None, tmp_path, record_limits=Limits(max_seconds=60.0)) as running:
        recorder = running.station.recorder
        first = recorder.path
        packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        stamp = recorder._first
        recorder.write(pack(position(), packer), stamp + 59.0)
        assert recorder.path == first
        recorder.write(pack(position(), packer), stamp + 61.0)
        assert recorder.path != first and recorder.path.parent == first.parent


def test_a_nearly_full_disk_begins_no_recording_and_the_health_banner_says_so(tmp_path, monkeypatch):
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(recorder_module.shutil, "disk_usage",
                        lambda path: usage._replace(free=500 * 10**6))  # 500 MB free, under the default 1 GB
    with RunningStation(None, tmp_path) as running, running.api() as api, \
            Peer(("127.0.0.1", running.mavlink_port), sysid=1) as peer:
        send_and_wait(running, peer, [vehicle_heartbeat(), position()])
        health = api.get("/api/health").json()
        assert health["status"] == "degraded"
        said = health["link"]["recording_error"]  # the field the page's health banner shows
        assert said.startswith("not recording") and "500 MB free" in said and "1,000 MB" in said
        assert health["recording"]["file"] is None and health["recording"]["not_kept"] >= 2
        assert list(tmp_path.glob("*.tlog")) == [] and api.get("/api/recordings").json() == []
        # room again: the next look at the disk begins a recording
        monkeypatch.setattr(recorder_module.shutil, "disk_usage", lambda path: usage._replace(free=10**12))
        monkeypatch.setattr(recorder_module, "LOOK_AGAIN_EVERY", 0.0)
        wait_wall(lambda: running.station.recorder.path is not None, 10, "a recording begun")
        health = api.get("/api/health").json()
        assert health["link"]["recording_error"] is None and health["recording"]["refused"] is None
