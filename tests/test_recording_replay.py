"""Session recordings and replay: the .tlog a live ground station writes, the recordings API, and replaying
recordings (ours, `vehicle experiment --log`'s, and logs of vehicles that are not ours) in the ground station.

One station records a simulated copter flying the ``search`` mission for the
whole module; while it flies, the test notes what the live station shows
(pose and map copy, with the log time of the last message it applied), so a
replay of the recording can be held against it.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import random
import shutil
import struct
import subprocess
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, unquote

import numpy as np
import pytest
from harness import (
    SCENE_TEXT,
    Api,
    RunningStation,
    command_ok,
    idle_station,
    small_scene,
    start_sim,
    wait_wall,
)
from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from websockets.sync.client import connect as ws_connect

from groundstation.replay import Player, Replay, ReplayError, index_tlog
from groundstation.state import HITS_KEPT, Fleet
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol import agent_status
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mapstream import MAP_SNAPSHOT, PATH, MapReceiver, MapStreamer
from vehicle.protocol.mav import mavlink, mavutil

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
TLOG_STAMP = struct.Struct(">Q")


# ---- the recorded flight ------------------------------------------------------------------------
@dataclass
class Moment:
    """What the live ground station showed for vehicle 1 at one moment."""

    time: float  # receiver time of the last message it applied (= that record's tlog timestamp)
    x: float
    y: float
    mode: str
    armed: bool
    grid: np.ndarray | None
    synced: bool
    applied: int


@dataclass
class Flight:
    running: RunningStation
    api: Api
    moments: list[Moment]
    sizes: list[int]  # the session file's size, sampled while the vehicle flew

    @property
    def station(self):
        return self.running.station

    @property
    def session(self) -> Path:
        return self.station.recorder.path

    @property
    def record_dir(self) -> Path:
        return self.station.record_dir


def note(station) -> Moment | None:
    live = station.live
    with live.lock:
        vehicle = live.get(1)
        if vehicle is None or vehicle.x is None:
            return None
        stream = vehicle.map_stream
        return Moment(vehicle.last_message, vehicle.x, vehicle.y, vehicle.mode, vehicle.armed,
                      None if stream.grid is None else stream.grid.copy(), stream.synced, stream.applied)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A station recording a copter that flies `search` (map snapshots every second) for about 6 wall seconds;
    the vehicle keeps running (landed once done) until the module ends."""
    scene = small_scene()
    record_dir = tmp_path_factory.mktemp("recordings")
    with RunningStation(scene, record_dir) as running, running.api() as api:
        vehicle = start_sim(running, scene, sysid=1, mission="search", autostart=True)
        vehicle.sim.companion.streamer.snapshot_period = 1.0
        with vehicle:
            api.wait_vehicle(1, lambda v: v["link"]["state"] == "ok" and v["map"]["source"] == "vehicle",
                             sim_timeout=20, what="heartbeat and map")
            command_ok(api, 1, action="speed", speed=2.5)  # a COMMAND_LONG from the ground station, in the log
            moments, sizes = [], []
            for _ in range(6):
                time.sleep(0.7)
                moment = note(running.station)
                if moment is not None and moment.grid is not None:
                    moments.append(moment)
                sizes.append(running.station.recorder.path.stat().st_size)
            yield Flight(running, api, moments, sizes)


def records(path: Path) -> list[tuple[float, bytes]]:
    """(timestamp, packet) of every whole record of a tlog, by its framing (for checks and for cutting logs)."""
    index = index_tlog(path)
    data = path.read_bytes()
    return [(float(t), data[int(o):int(o) + int(n)]) for t, o, n in
            zip(index.times, index.offsets, index.lengths, strict=True)]


def decoded(path: Path) -> list:
    """Every message of a tlog as pymavlink decodes it sequentially (``_timestamp`` is the record's time)."""
    reader = mavutil.mavlink_connection(str(path))
    messages = []
    try:
        while (message := reader.recv_msg()) is not None:
            if message.get_type() != "BAD_DATA":
                messages.append(message)
    finally:
        reader.close()
    return messages


# ---- recording ---------------------------------------------------------------------------------------
def test_the_session_log_appears_and_grows_while_recording(flight):
    assert flight.session.parent == flight.record_dir
    assert flight.session.name.startswith("session-") and flight.session.suffix == ".tlog"
    assert flight.sizes[0] > 0
    assert all(b >= a for a, b in zip(flight.sizes, flight.sizes[1:], strict=False)), flight.sizes
    assert flight.sizes[-1] > flight.sizes[len(flight.sizes) // 2] > flight.sizes[0], flight.sizes
    # flushed within about a second: a record stamped in the last 1.5 s is already on disk
    started = time.time()
    fresh = wait_wall(lambda: (tail := records(flight.session)[-1][0]) > started - 1.5 and tail, 3,
                      "a fresh record on disk")
    assert fresh > started - 1.5
    size = flight.session.stat().st_size
    wait_wall(lambda: flight.session.stat().st_size > size, 2.5, "the log grows")


def test_the_session_log_holds_both_directions(flight):
    messages = decoded(flight.session)
    kinds = Counter((m.get_type(), m.get_srcSystem()) for m in messages)
    for kind in ("HEARTBEAT", "GLOBAL_POSITION_INT", "ATTITUDE", "DISTANCE_SENSOR", "TUNNEL", "COMMAND_ACK",
                 "STATUSTEXT"):
        assert kinds[(kind, 1)] > 0, kind
    assert kinds[("HEARTBEAT", 255)] >= 2  # the ground station's own heartbeats, once a second
    assert kinds[("COMMAND_LONG", 255)] >= 1
    gcs_beat = next(m for m in messages if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 255)
    assert gcs_beat.type == mavlink.MAV_TYPE_GCS
    commands = [m for m in messages if m.get_type() == "COMMAND_LONG"]
    assert {m.command for m in commands} >= {mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,  # asking for telemetry
                                             mavlink.MAV_CMD_DO_CHANGE_SPEED}  # the test's command
    assert all(m.target_system == 1 for m in commands)
    stamps = np.array([m._timestamp for m in messages])
    assert stamps[0] == pytest.approx(time.time(), abs=120)  # wall-clock stamps of this session
    assert np.diff(stamps).min() > -0.01  # in time order (but for a packet sent while one was received)


def test_mavlogdump_reads_the_session_log(flight):
    result = subprocess.run([sys.executable, str(BIN / "mavlogdump.py"), "--types", "HEARTBEAT,COMMAND_LONG",
                             str(flight.session)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert any("HEARTBEAT" in line for line in lines)
    assert any("COMMAND_LONG" in line for line in lines)
    assert sum("HEARTBEAT" in line for line in lines) >= 4


# ---- the recordings API ---------------------------------------------------------------------------------
def test_recordings_are_listed(flight):
    listed = flight.api.get("/api/recordings")
    assert listed.status_code == 200
    session = next(r for r in listed.json() if r["name"] == flight.session.name)
    assert session["recording"] is True
    assert session["size"] > 0 and session["modified"] == pytest.approx(time.time(), abs=60)


def test_listing_recordings_reads_none_of_them_and_lists_only_files(flight, monkeypatch):
    """A recording is indexed (its duration read) in the background: while that is held back, the list and
    the status stream answer at once, the duration coming later. A pipe named like a recording, which
    would block whoever reads it, and a folder are not recordings."""
    held, released = threading.Event(), threading.Event()
    real = index_tlog

    def slow_index(path, columns=True):
        held.set()
        released.wait(30)
        return real(path, columns)

    monkeypatch.setattr("groundstation.recordings.index_tlog", slow_index)
    copy, pipe, folder = (flight.record_dir / name for name in ("held-copy.tlog", "pipe.tlog", "folder.tlog"))
    shutil.copyfile(flight.session, copy)
    os.mkfifo(pipe)
    folder.mkdir()
    try:
        listed = {r["name"]: r for r in flight.api.get("/api/recordings").json()}
        assert "pipe.tlog" not in listed and "folder.tlog" not in listed
        assert listed["held-copy.tlog"]["duration_s"] is None  # not read yet
        assert held.wait(10)  # the indexer is reading it now, and stays there until released
        stream_url = flight.running.base.replace("http://", "ws://") + "/ws"
        with ws_connect(stream_url) as stream:  # the stream's first status lists recordings, read or not
            frame = json.loads(stream.recv(timeout=5))
        assert "held-copy.tlog" in [r["name"] for r in frame["recordings"]]
        assert flight.api.get("/api/recordings/pipe.tlog").status_code == 404
        released.set()
        wait_wall(lambda: {r["name"]: r for r in flight.api.get("/api/recordings").json()}["held-copy.tlog"]
                  ["duration_s"] == round(real(copy).duration, 1), 10, "the duration, once read")
    finally:
        released.set()
        copy.unlink(missing_ok=True)
        pipe.unlink(missing_ok=True)
        folder.rmdir()


def test_a_recording_whose_name_is_no_text_is_left_out_and_said_once(flight, caplog):
    """A file named with bytes no encoding decodes (copied from another system, say) made the list a 500, and
    the page's recordings list with it: JSON cannot carry such a name, and no request could name it."""
    caplog.set_level(logging.WARNING, logger="groundstation")
    odd = flight.record_dir / os.fsdecode(b"odd\xff.tlog")
    shutil.copyfile(flight.session, odd)
    try:
        for _ in range(2):
            listed = flight.api.get("/api/recordings")
            assert listed.status_code == 200 and flight.session.name in [r["name"] for r in listed.json()]
        assert caplog.text.count("its name is no UTF-8 text (rename it)") == 1
    finally:
        odd.unlink()


def test_a_recording_the_indexer_fails_on_has_no_duration_and_is_indexed_again_once_it_changes(flight, monkeypatch,
                                                                                               caplog):
    """Not a bad file (that is a ReplayError) but a failure nobody foresaw: said in the log, and the file is
    not left marked as being indexed, where it would never be indexed again."""
    real = index_tlog

    def failing(path, columns=True):
        raise ValueError("mmap length is greater than file size")

    monkeypatch.setattr("groundstation.recordings.index_tlog", failing)
    copy = flight.record_dir / "failing-copy.tlog"
    shutil.copyfile(flight.session, copy)

    def duration():
        return {r["name"]: r for r in flight.api.get("/api/recordings").json()}["failing-copy.tlog"]["duration_s"]

    try:
        wait_wall(lambda: copy not in flight.running.station.recordings._indexing and duration() is None
                  and "could not index the recording failing-copy.tlog" in caplog.text, 10, "the failure said")
        monkeypatch.setattr("groundstation.recordings.index_tlog", real)
        os.utime(copy, (time.time() + 5, time.time() + 5))  # changed: indexed again
        wait_wall(lambda: duration() == round(real(copy).duration, 1), 10, "the duration, once read again")
    finally:
        copy.unlink(missing_ok=True)


def test_a_finished_recording_downloads_byte_for_byte(flight):
    finished = flight.record_dir / "finished-copy.tlog"
    shutil.copyfile(flight.session, finished)
    try:
        listed = {r["name"]: r for r in flight.api.get("/api/recordings").json()}
        assert listed["finished-copy.tlog"]["recording"] is False
        response = flight.api.get("/api/recordings/finished-copy.tlog")
        assert response.status_code == 200
        assert response.content == finished.read_bytes()
        assert response.headers["content-type"] == "application/octet-stream"
        assert "finished-copy.tlog" in response.headers["content-disposition"]
    finally:
        finished.unlink(missing_ok=True)


@pytest.mark.parametrize("name", ["飞行.tlog", "cr\r\nX-Evil: 1.tlog", 'quote".tlog', "back\\slash ñ.tlog"])
def test_a_recording_called_anything_downloads_under_its_own_name(flight, name):
    """Its name went into the header as it was: a non-ASCII one was a 500, a line break ended the response
    unanswered, a quote made a header that says another name."""
    copy = flight.record_dir / name
    shutil.copyfile(flight.session, copy)
    try:
        assert name in [r["name"] for r in flight.api.get("/api/recordings").json()]
        response = flight.api.get(f"/api/recordings/{quote(name, safe='')}")
        assert response.status_code == 200 and response.content == copy.read_bytes()
        disposition = response.headers["content-disposition"]
        assert "x-evil" not in response.headers
        assert unquote(disposition.split("filename*=UTF-8''")[1]) == name  # what a browser saves it as
        plain = disposition.split('filename="')[1].split('";')[0]
        assert plain.isascii() and '"' not in plain and "\\" not in plain and plain.isprintable()
    finally:
        copy.unlink()


def test_a_name_that_is_no_text_is_named_by_its_bytes():
    """A replay started from any path (``groundstation replay FILE``) exports under that file's name: one that
    is no UTF-8 made quote() raise, and the export a 500."""
    from groundstation.api.common import attachment

    header = attachment(os.fsdecode(b"odd\xff.html"))
    assert header == "attachment; filename=\"odd_.html\"; filename*=UTF-8''odd%FF.html"


def test_the_session_being_recorded_downloads_as_a_consistent_prefix(tmp_path):
    """The session goes on growing while it downloads (a long one over a slow link): the download is the file
    as it was when asked for, whole, not a broken transfer."""
    with RunningStation(None, tmp_path) as running, running.api() as api:
        recorder = running.station.recorder
        packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        packet = mavlink.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0, 0, 0).pack(packer)
        stamp = time.time()
        for _ in range(1_000_000):  # some 20 MB: more than the sockets between the two ends hold
            recorder.write(packet, stamp)
        recorder._writer.flush()
        received = bytearray()
        with api.stream("GET", f"/api/recordings/{recorder.path.name}") as response:
            assert response.status_code == 200
            declared = int(response.headers["content-length"])
            for i, chunk in enumerate(response.iter_bytes(65536)):
                received += chunk
                if i == 2:  # the recorder writes on while the download runs
                    for _ in range(200_000):
                        recorder.write(packet, stamp)
                    recorder._writer.flush()
                if i < 5:
                    time.sleep(0.05)
        assert len(received) == declared
        assert bytes(received) == recorder.path.read_bytes()[:declared]
        assert recorder.path.stat().st_size > declared


def test_deleting_recordings(flight):
    api = flight.api
    doomed = flight.record_dir / "old-session.tlog"
    shutil.copyfile(flight.session, doomed)
    assert api.delete("/api/recordings/old-session.tlog").status_code == 401
    assert api.delete("/api/recordings/old-session.tlog", headers={"Authorization": "Bearer no"}).status_code == 401
    assert doomed.exists()
    busy = api.delete(f"/api/recordings/{flight.session.name}", headers=api.operator)
    assert busy.status_code == 409
    assert flight.session.exists()
    gone = api.delete("/api/recordings/old-session.tlog", headers=api.operator)
    assert gone.status_code == 200 and gone.json() == {"deleted": "old-session.tlog"}
    assert not doomed.exists()
    assert api.delete("/api/recordings/old-session.tlog", headers=api.operator).status_code == 404
    assert "old-session.tlog" not in [r["name"] for r in api.get("/api/recordings").json()]


def test_recording_names_cannot_leave_the_folder(flight, tmp_path):
    api = flight.api
    outside = flight.record_dir.parent / "outside.tlog"
    outside.write_bytes(flight.session.read_bytes()[:4096])
    try:
        for name in ("../outside.tlog", "..%2Foutside.tlog", "%2E%2E%2Foutside.tlog", "..\\outside.tlog",
                     "%2E%2E%5Coutside.tlog", "missing.tlog", "README.md", "..%2F..%2Fetc%2Fpasswd"):
            assert api.get(f"/api/recordings/{name}").status_code == 404, name
            assert api.delete(f"/api/recordings/{name}", headers=api.operator).status_code == 404, name
        for name in ("../outside.tlog", "/etc/passwd", "sub/x.tlog", "x.txt", "..", ""):
            assert flight.station.recordings.path(name) is None, name
        replay = api.post("/api/replay", json={"name": "../outside.tlog"}, headers=api.operator)
        assert replay.status_code == 404
        long = api.get(f"/api/recordings/{'x' * 5000}.tlog")
        assert long.status_code == 404 and len(long.text) < 200  # the name is not echoed back whole
    finally:
        outside.unlink()
    assert outside.parent.exists()


# ---- replay equals live -------------------------------------------------------------------------------
def sequential_maps(path: Path, stamps: list[float]) -> dict[float, tuple[np.ndarray | None, bool, int]]:
    """Vehicle 1's map as a MapReceiver fed every TUNNEL of the log in order, up to and including each stamp."""
    receiver = MapReceiver()
    wanted = sorted(stamps)
    maps = {}
    for message in decoded(path):
        while wanted and message._timestamp > wanted[0]:
            stamp = wanted.pop(0)
            maps[stamp] = (None if receiver.grid is None else receiver.grid.copy(), receiver.synced, receiver.applied)
        if not wanted:
            break
        if message.get_type() == "TUNNEL" and message.get_srcSystem() == 1:
            receiver.feed(message.payload_type, bytes(message.payload[:message.payload_length]))
    for stamp in wanted:
        maps[stamp] = (None if receiver.grid is None else receiver.grid.copy(), receiver.synced, receiver.applied)
    return maps


def tlog_time(t: float) -> float:
    """A receiver time as its tlog record stores it (whole microseconds)."""
    return int(t * 1e6) / 1e6


def map_losses(path: Path) -> tuple[int, int]:
    """(missing map deltas, incomplete map snapshots) of vehicle 1 in a log: what UDP loss took from its map."""
    deltas, chunks = [], {}
    for message in decoded(path):
        if message.get_type() != "TUNNEL" or message.get_srcSystem() != 1:
            continue
        payload = bytes(message.payload[:message.payload_length])
        if message.payload_type == 32801:
            deltas.append(struct.unpack_from("<I", payload)[0])
        elif message.payload_type == MAP_SNAPSHOT:
            ident, index, count = struct.unpack_from("<HHH", payload)
            chunks.setdefault(ident, [count, set()])[1].add(index)
    missing = (max(deltas) - min(deltas) + 1 - len(set(deltas))) if deltas else 0
    incomplete = sum(len(got) < count for count, got in list(chunks.values())[:-1])  # the last may be cut off
    return missing, incomplete


def finished_copy(flight: Flight, path: Path) -> Path:
    """Every whole record of the session on disk, once the last moment noted has been flushed."""
    wait_wall(lambda: records(flight.session)[-1][0] > flight.moments[-1].time, 5, "the recorder's flush")
    path.write_bytes(b"".join(TLOG_STAMP.pack(round(t * 1e6)) + p for t, p in records(flight.session)))
    return path


def test_replay_equals_live(flight, tmp_path):
    assert len(flight.moments) >= 4
    assert len({(round(m.x, 1), round(m.y, 1)) for m in flight.moments}) >= 3  # it went places
    path = finished_copy(flight, tmp_path / "flight.tlog")
    lossless = map_losses(path) == (0, 0)  # on a loaded machine UDP may drop some of the map stream
    live = flight.station.live
    replay = Replay.open(path, Fleet(live.datum, live.ground_height))
    assert replay.index.warning == ""
    assert replay.index.start + replay.duration > flight.moments[-1].time
    stamps = [tlog_time(m.time) for m in flight.moments]
    sequential = sequential_maps(path, stamps)
    compared_live = compared_sequential = 0
    for moment, stamp in zip(flight.moments, stamps, strict=True):
        replay.seek(stamp - replay.index.start + 5e-7)  # up to and including the record at ``stamp``
        vehicle = replay.fleet.get(1)
        assert vehicle is not None
        assert vehicle.last_message == pytest.approx(stamp, abs=1e-6)
        assert math.hypot(vehicle.x - moment.x, vehicle.y - moment.y) < 0.03, (moment.time, vehicle.x, moment.x)
        assert (vehicle.mode, vehicle.armed) == (moment.mode, moment.armed)
        stream = vehicle.map_stream
        # decoding the log from its start up to the same record gives what the live station held then
        grid, synced, applied = sequential[stamp]
        assert (synced, applied) == (moment.synced, moment.applied)
        assert np.array_equal(grid, moment.grid)
        if lossless:
            assert stream.synced and synced
        if synced:  # a synced live copy: the replay has the map too (from the last complete snapshot on)
            assert stream.synced and stream.applied == applied
            assert np.array_equal(grid, stream.grid)
            compared_sequential += 1
        if stream.synced and moment.synced and moment.applied == stream.applied:  # what the live station showed
            assert np.array_equal(moment.grid, stream.grid)
            compared_live += 1
    if lossless:
        assert compared_live == compared_sequential == len(flight.moments)
    else:
        assert compared_live >= 1 and compared_sequential >= 1
    assert np.count_nonzero(flight.moments[-1].grid >= 6) > 10  # the walls are in the map


def test_playing_forward_equals_seeking(flight, tmp_path):
    path = finished_copy(flight, tmp_path / "flight.tlog")
    lossless = map_losses(path) == (0, 0)
    live = flight.station.live
    played = Replay.open(path, Fleet(live.datum, live.ground_height))
    sought = Replay.open(path, Fleet(live.datum, live.ground_height))
    assert played.duration > 3.0
    played.seek(1.0)
    targets = (2.0, played.duration / 2 + 0.5, played.duration - 0.3)
    maps_compared = 0
    for target in targets:
        while played.clock < target - 1e-9:
            played.advance(min(0.25, target - played.clock))
        assert played.clock == pytest.approx(target)
        sought.seek(target)
        a, b = played.fleet.get(1), sought.fleet.get(1)
        assert (a.x, a.y, a.mode, a.armed) == (b.x, b.y, b.mode, b.armed)
        if lossless:
            assert a.map_stream.synced and b.map_stream.synced
        if a.map_stream.synced and b.map_stream.synced:
            assert a.map_stream.applied == b.map_stream.applied
            assert np.array_equal(a.map_stream.grid, b.map_stream.grid)
            assert b.own_map is None  # the vehicle's map applied before the readings: no map of the station's own
            maps_compared += 1
    # UDP may drop part of the map stream on a loaded machine, but never so much that no map is compared
    assert maps_compared == len(targets) if lossless else maps_compared >= 1


# ---- replay through the API -------------------------------------------------------------------------------
PLANE_SYSID = 9
CIRCLE_RADIUS = 80.0  # m
CIRCLE_PERIOD = 30.0  # s
PLANE_CENTRE = (-35.3600000, 149.1700000)
PLANE_START = 1714564800.0  # 2024-05-01T12:00:00Z


def plane_log(path: Path, duration: float = 30.0) -> list[tuple[float, float, float]]:
    """A tlog as an ArduPlane (MAVLink 1) flying a circle would give a ground station: dozens of message types
    we do not use, GLOBAL_POSITION_INT at 10 Hz, and the station's own traffic. Returns (time, lat, lon) of each
    GLOBAL_POSITION_INT."""
    centre = Datum(*PLANE_CENTRE, 0.0)
    plane = mavlink1.MAVLink(None, srcSystem=PLANE_SYSID, srcComponent=1)
    gcs = mavlink1.MAVLink(None, srcSystem=255, srcComponent=190)
    rng = random.Random(5)
    out = []
    fixes = []
    clock = [0]  # microseconds of the last record: each record a little after the one before, as received

    def write(t: float, message, packer=plane) -> float:
        stamp = max(int(round((PLANE_START + t) * 1e6)), clock[0] + 20)
        clock[0] = stamp
        out.append(TLOG_STAMP.pack(stamp) + message.pack(packer))
        return stamp / 1e6

    armed = mavlink1.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink1.MAV_MODE_FLAG_SAFETY_ARMED
    steps = int(duration * 10)
    for step in range(steps + 1):
        t = step * 0.1
        ms = int(t * 1000) + 60_000
        angle = 2 * math.pi * t / CIRCLE_PERIOD
        x, y = CIRCLE_RADIUS * math.sin(angle), CIRCLE_RADIUS * math.cos(angle)
        lat, lon = centre.to_global(x, y)
        lat_i, lon_i = int(round(lat * 1e7)), int(round(lon * 1e7))
        heading = (math.degrees(angle) + 90) % 360
        speed = 2 * math.pi * CIRCLE_RADIUS / CIRCLE_PERIOD
        vx, vy = speed * math.cos(math.radians(heading)), speed * math.sin(math.radians(heading))  # north, east
        if step % 10 == 0:
            write(t, plane.heartbeat_encode(mavlink1.MAV_TYPE_FIXED_WING, mavlink1.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                            armed, 10, mavlink1.MAV_STATE_ACTIVE, 3))
            write(t, gcs.heartbeat_encode(mavlink1.MAV_TYPE_GCS, mavlink1.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3), gcs)
            write(t, plane.home_position_encode(int(PLANE_CENTRE[0] * 1e7), int(PLANE_CENTRE[1] * 1e7), 584000,
                                                0, 0, 0, [1, 0, 0, 0], 0, 0, 0))
            write(t, plane.sys_status_encode(0x3FFFFF, 0x3FFFFF, 0x3FFFFF, 300, 12400, 1500, 80 - step // 50,
                                             0, 0, 0, 0, 0, 0))
            write(t, plane.system_time_encode(int((PLANE_START + t) * 1e6), ms))
            write(t, plane.meminfo_encode(0, 65535))
            write(t, plane.power_status_encode(5000, 5100, 3))
            write(t, plane.ekf_status_report_encode(0x1FF, 0.1, 0.1, 0.1, 0.05, 0.0))
            write(t, plane.vibration_encode(ms * 1000, 2.0, 2.1, 2.3, 0, 0, 0))
            write(t, plane.terrain_report_encode(lat_i, lon_i, 100, 12.5, 87.5, 0, 56))
            write(t, plane.hwstatus_encode(5000, 0))
            write(t, plane.wind_encode(270.0, 3.5, 0.0))
            write(t, plane.battery_status_encode(0, 0, 1, 2500, [4100] * 10, 1500, 1200, -1, 80))
            write(t, plane.mission_current_encode(2))
            write(t, plane.gps_global_origin_encode(int(PLANE_CENTRE[0] * 1e7), int(PLANE_CENTRE[1] * 1e7),
                                                    584000))
            write(t, plane.sensor_offsets_encode(10, -20, 30, 0.2, 100000, 2500, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            write(t, plane.fence_status_encode(0, 0, 0, 0))
            write(t, plane.radio_status_encode(200, 190, 90, 40, 35, 0, 0))
            write(t, gcs.request_data_stream_encode(PLANE_SYSID, 1, 0, 4, 1), gcs)
        if step % 50 == 0:
            write(t, plane.param_value_encode(b"WP_RADIUS", 90.0, mavlink1.MAV_PARAM_TYPE_REAL32, 1200, step // 50))
            write(t, plane.statustext_encode(mavlink1.MAV_SEVERITY_INFO, f"Reached waypoint #{step // 50}".encode()))
        if step % 2 == 0:
            write(t, plane.raw_imu_encode(ms * 1000, 1, -2, -1000, 3, 4, 5, 200, -100, 400))
            write(t, plane.scaled_imu2_encode(ms, 1, -2, -1000, 3, 4, 5, 200, -100, 400))
            write(t, plane.scaled_pressure_encode(ms, 945.5, 0.3, 2650))
            write(t, plane.gps_raw_int_encode(ms * 1000, 3, lat_i, lon_i, 684000, 90, 120, int(speed * 100),
                                              int(heading * 100), 14))
            write(t, plane.rc_channels_encode(ms, 16, *([1500] * 18), 255))
            write(t, plane.rc_channels_raw_encode(ms, 0, *([1500] * 8), 255))
            write(t, plane.servo_output_raw_encode(ms * 1000, 0, *([1500] * 8)))
            write(t, plane.nav_controller_output_encode(-25.0, 2.0, int(heading), int(heading), 150, 0.5, 0.2, 1.1))
            write(t, plane.vfr_hud_encode(speed + 1, speed, int(heading), 55, 684.0, 0.1))
            write(t, plane.ahrs_encode(0.0, 0.0, 0.0, 0.9, 1.0, 0.01, 0.02))
            write(t, plane.ahrs2_encode(-0.4, 0.03, math.radians(heading), 684.0, lat_i, lon_i))
            write(t, plane.simstate_encode(-0.4, 0.03, math.radians(heading), 0, 0, -9.8, 0, 0, 0.2, lat_i, lon_i))
            write(t, plane.rangefinder_encode(rng.uniform(0, 40), 1.2))
        stamp = write(t, plane.global_position_int_encode(ms, lat_i, lon_i, 684000, 100000, int(vx * 100),
                                                          int(vy * 100), 0, int(heading * 100)))
        write(t, plane.attitude_encode(ms, -0.4, 0.03, math.radians(heading), 0.0, 0.0, 0.2))
        write(t, plane.local_position_ned_encode(ms, y, x, -100.0, vx, vy, 0.0))
        fixes.append((stamp, lat_i * 1e-7, lon_i * 1e-7))
    path.write_bytes(b"".join(out))
    return fixes


@dataclass
class PlaneLog:
    path: Path
    fixes: list[tuple[float, float, float]]

    @property
    def name(self) -> str:
        return self.path.name


@pytest.fixture(scope="module")
def plane_in_record_dir(flight):
    path = flight.record_dir / "ardupilot-plane.tlog"
    return PlaneLog(path, plane_log(path))


def fix_at(fixes, when: float) -> tuple[float, float, float]:
    """The last GLOBAL_POSITION_INT at or before ``when`` (Unix seconds)."""
    return [f for f in fixes if f[0] <= when + 1e-7][-1]


def test_a_foreign_plane_log_indexes_and_replays(tmp_path):
    path = tmp_path / "plane.tlog"
    fixes = plane_log(path)
    index = index_tlog(path)
    kinds = Counter(m.get_type() for m in decoded(path))
    assert len(kinds) >= 35  # dozens of message types
    assert len(index) == sum(kinds.values()) and index.warning == ""
    assert index.duration == pytest.approx(30.0, abs=0.01)
    replay = Replay.open(path, Fleet())  # no scene: the first home heard is the origin
    for seconds in (0.5, 3.33, 7.5, 15.0, 22.25, 30.0):
        replay.seek(seconds)
        plane = replay.fleet.get(PLANE_SYSID)
        assert plane is not None and replay.fleet.ids() == [PLANE_SYSID]  # the GCS is no vehicle
        assert plane.kind == "plane" and plane.mode == "AUTO" and plane.armed
        assert plane.mavlink_version == 1
        when, lat, lon = fix_at(fixes, replay.index.start + seconds)
        assert (plane.lat, plane.lon) == (pytest.approx(lat, abs=1e-9), pytest.approx(lon, abs=1e-9))
        x, y = Datum(*PLANE_CENTRE, 0.0).to_local(lat, lon)
        assert math.hypot(plane.x - x, plane.y - y) < 0.05
        assert math.hypot(plane.x, plane.y) == pytest.approx(CIRCLE_RADIUS, abs=0.5)
        assert plane.alt == pytest.approx(100.0)
        assert plane.map_grid() is None and not plane.sonar  # no scene, no sonar, no map
        assert plane.voltage == pytest.approx(12.4)
        assert plane.time_boot_s == pytest.approx(60.0 + round(seconds * 10) / 10, abs=0.11)
        assert plane.last_message <= replay.index.start + seconds + 1e-6
        assert plane.status.startswith("Reached waypoint")
        assert len(plane.trail) >= 1
    replay.seek(15.0)
    replay.advance(7.25)  # playing forward lands in the same place as seeking
    when, lat, lon = fix_at(fixes, replay.index.start + 22.25)
    assert replay.fleet.get(PLANE_SYSID).lat == pytest.approx(lat, abs=1e-9)


def test_replay_through_the_api(flight, plane_in_record_dir):
    api = flight.api
    name = plane_in_record_dir.name
    assert api.get("/api/replay").json() == {"mode": "live", "replay": None}
    assert api.post("/api/replay/control", json={"play": True}, headers=api.operator).status_code == 409
    assert api.get("/api/replay/export").status_code == 409
    assert api.post("/api/replay", json={"name": name}).status_code == 401
    assert api.post("/api/replay", json={"name": "nope.tlog"}, headers=api.operator).status_code == 404
    assert api.post("/api/replay", json={}, headers=api.operator).status_code == 422
    started = api.post("/api/replay", json={"name": name}, headers=api.operator)
    assert started.status_code == 200, started.text
    status = started.json()
    assert status["name"] == name and status["duration"] == pytest.approx(30.0, abs=0.01)
    try:
        assert api.get("/api/health").json()["mode"] == "replay"
        assert [v["sysid"] for v in api.get("/api/vehicles").json()] == [PLANE_SYSID]
        assert api.get("/api/vehicles/1").status_code == 404  # the live vehicle is not shown
        plane = api.vehicle(PLANE_SYSID)
        assert plane["type"] == "plane" and plane["mode"] == "AUTO" and plane["link"]["mavlink"] == 1
        control = "/api/replay/control"

        # pause: the time stays
        paused = api.post(control, json={"play": False}, headers=api.operator).json()
        assert paused["playing"] is False
        # the player ticks on the wall clock: look at every tick for six of them, the time stays put at each
        looks = 0
        started = time.monotonic()
        while time.monotonic() - started < 6 * Player.TICK:
            assert api.get("/api/replay").json()["replay"]["time"] == paused["time"]
            looks += 1
            time.sleep(Player.TICK)
        assert looks >= 3
        # seek
        sought = api.post(control, json={"seek": 10.0}, headers=api.operator).json()
        assert sought["time"] == pytest.approx(10.0) and sought["playing"] is False
        position = api.vehicle(PLANE_SYSID)["position"]
        _, lat, lon = fix_at(plane_in_record_dir.fixes, PLANE_START + 10.0)
        x, y = flight.station.live.datum.to_local(lat, lon)  # the scene's datum places the log
        assert (position["lat"], position["lon"]) == (pytest.approx(lat, abs=1e-9), pytest.approx(lon, abs=1e-9))
        assert (position["x"], position["y"]) == (pytest.approx(x, abs=0.01), pytest.approx(y, abs=0.01))
        centre = flight.station.live.datum.to_local(*PLANE_CENTRE)
        assert math.dist((x, y), centre) == pytest.approx(CIRCLE_RADIUS, abs=0.5)
        # the link age is on the log's clock
        assert api.vehicle(PLANE_SYSID)["link"]["state"] == "ok"
        # step forward and back, a tenth of a second each, and pause
        stepped = api.post(control, json={"step": 1}, headers=api.operator).json()
        assert stepped["time"] == pytest.approx(10.1) and stepped["playing"] is False
        back = api.post(control, json={"step": -1}, headers=api.operator).json()
        assert back["time"] == pytest.approx(10.0)
        # play at 20x: the time moves
        playing = api.post(control, json={"play": True, "speed": 20}, headers=api.operator).json()
        assert playing["playing"] is True and playing["speed"] == 20
        moved = wait_wall(lambda: (t := api.get("/api/replay").json()["replay"]["time"]) > 12.0 and t, 5,
                          "replay time moves")
        assert moved > 12.0
        later = api.vehicle(PLANE_SYSID)["position"]
        assert math.dist((later["x"], later["y"]), (position["x"], position["y"])) > 5.0
        # bad controls
        for body in ({"speed": 25}, {"speed": 0.05}, {"seek": -1}, {"step": 2}):
            assert api.post(control, json=body, headers=api.operator).status_code == 422, body
        assert api.post(control, json={"play": False}).status_code == 401
        # commands and missions are refused in replay
        refused = api.command(PLANE_SYSID, action="rtl")
        assert refused.status_code == 409
        assert api.command(1, action="rtl").status_code == 409
        assert api.get(f"/api/vehicles/{PLANE_SYSID}/mission").status_code == 409
        assert api.put(f"/api/vehicles/{PLANE_SYSID}/mission", content="QGC WPL 110\n",
                       headers=api.operator).status_code == 409
        # the file being replayed cannot be deleted
        assert api.delete(f"/api/recordings/{name}", headers=api.operator).status_code == 409
        # at the end it stops, and playing again starts over
        api.post(control, json={"seek": 29.9, "play": True}, headers=api.operator)
        ended = wait_wall(lambda: (r := api.get("/api/replay").json()["replay"])["playing"] is False and r, 5,
                          "the end")
        assert ended["time"] == ended["duration"] == pytest.approx(30.0, abs=0.01)
        again = api.post(control, json={"play": True}, headers=api.operator).json()
        assert again["playing"] is True and again["time"] < 1.0
        api.post(control, json={"play": False}, headers=api.operator)
    finally:
        stopped = api.post("/api/replay/stop", headers=api.operator)
    assert stopped.status_code == 200 and stopped.json() == {"mode": "live"}
    assert api.get("/api/health").json()["mode"] == "live"
    assert 1 in [v["sysid"] for v in api.get("/api/vehicles").json()]
    assert PLANE_SYSID not in [v["sysid"] for v in api.get("/api/vehicles").json()]
    assert api.post("/api/replay/stop").status_code == 401


def test_replaying_a_file_that_is_no_log_is_422(flight):
    api = flight.api
    fake = flight.record_dir / "not-a-log.tlog"
    fake.write_bytes((ROOT / "README.md").read_bytes())
    try:
        response = api.post("/api/replay", json={"name": fake.name}, headers=api.operator)
        assert response.status_code == 422
        assert "not a telemetry log" in response.json()["detail"]
        assert api.get("/api/health").json()["mode"] == "live"
    finally:
        fake.unlink()


def test_the_stream_follows_the_replay(flight, plane_in_record_dir):
    import json

    import websockets.sync.client

    api = flight.api
    assert api.post("/api/replay", json={"name": plane_in_record_dir.name}, headers=api.operator).status_code == 200
    try:
        api.post("/api/replay/control", json={"seek": 5.0, "play": False}, headers=api.operator)
        url = f"ws://127.0.0.1:{flight.running.http_port}/ws"
        with websockets.sync.client.connect(url, open_timeout=5) as socket_:
            frame = json.loads(socket_.recv(timeout=5))
        assert frame["type"] == "vehicles" and frame["mode"] == "replay"
        assert frame["replay"]["name"] == plane_in_record_dir.name and frame["replay"]["time"] == pytest.approx(5.0)
        assert [v["sysid"] for v in frame["vehicles"]] == [PLANE_SYSID]
        assert frame["time"] == pytest.approx(PLANE_START + 5.0)
    finally:
        api.post("/api/replay/stop", headers=api.operator)


def test_a_pause_and_seek_while_playing_stays_where_it_landed(flight, plane_in_record_dir):
    """The player must not move on from a seek that also paused (it used to, when it woke during the seek)."""
    api = flight.api
    assert api.post("/api/replay", json={"name": plane_in_record_dir.name}, headers=api.operator).status_code == 200
    try:
        for attempt in range(15):
            control = {"seek": 0.0, "play": True, "speed": 20.0}
            assert api.post("/api/replay/control", json=control, headers=api.operator).json()["playing"]
            time.sleep(0.12)  # a few of the player's ticks: it is playing, and wakes at any moment
            paused = api.post("/api/replay/control", json={"seek": 5.0, "play": False}, headers=api.operator).json()
            assert not paused["playing"] and paused["time"] == 5.0, attempt
            time.sleep(0.12)
            status = api.get("/api/replay").json()["replay"]
            assert not status["playing"] and status["time"] == 5.0, (attempt, status)
    finally:
        api.post("/api/replay/stop", headers=api.operator)


def test_export_is_one_html_file(flight, plane_in_record_dir):
    api = flight.api
    assert api.post("/api/replay", json={"name": plane_in_record_dir.name}, headers=api.operator).status_code == 200
    try:
        exported = api.get("/api/replay/export", timeout=120)
    finally:
        api.post("/api/replay/stop", headers=api.operator)
    assert exported.status_code == 200
    assert exported.headers["content-type"].startswith("text/html")
    assert 'filename="ardupilot-plane.html"' in exported.headers["content-disposition"]
    assert "__VISER_EMBED_DATA__" in exported.text
    assert exported.text.lstrip().lower().startswith("<!doctype html") or "<html" in exported.text[:2000].lower()


# ---- logs from elsewhere -----------------------------------------------------------------------------------
@dataclass
class ExperimentRun:
    log: Path
    final_map: np.ndarray


@pytest.fixture(scope="module")
def experiment_run(tmp_path_factory) -> ExperimentRun:
    """`vehicle experiment --log` of a copter scanning once round in the walls scene, and its final map."""
    folder = tmp_path_factory.mktemp("experiment")
    scene = folder / "walls.wrl"
    scene.write_text(SCENE_TEXT)
    log = folder / "run.tlog"
    result = subprocess.run(
        [str(BIN / "vehicle"), "experiment", "--scene", str(scene), "--mission", "browse", "--set", "space_size=20",
         "--time-limit", "60", "--map-out", str(folder / "map"), "--log", str(log)],
        capture_output=True, text=True, timeout=120, cwd=folder)
    assert result.returncode == 0, result.stderr
    return ExperimentRun(log, np.load(next((folder / "map").glob("*.npy"))))


def test_an_experiment_log_replays(experiment_run):
    log = experiment_run.log
    index = index_tlog(log)
    assert index.warning == "" and len(index) > 1000
    assert index.start == pytest.approx(1767225600.0, abs=1)  # simulated time from 2026-01-01
    replay = Replay.open(log, Fleet(Datum()))
    replay.seek(replay.duration)
    vehicle = replay.fleet.get(1)
    assert vehicle is not None and vehicle.kind == "copter"
    assert vehicle.map_stream.synced
    assert np.array_equal(vehicle.map_stream.grid, experiment_run.final_map)  # the run's final map
    assert math.hypot(vehicle.x, vehicle.y) < 0.5  # it went home
    replay.seek(replay.duration / 2)
    middle = replay.fleet.get(1)
    assert middle.alt > 3.0 and middle.armed  # mid-scan, in the air


def assert_same_state(got, expected, where: str = "vehicle") -> int:
    """Field by field (dataclasses, deques, dicts, maps cell by cell); returns how many leaves were compared."""
    if dataclasses.is_dataclass(got) and not isinstance(got, type):
        assert type(got) is type(expected), where
        return sum(assert_same_state(getattr(got, f.name), getattr(expected, f.name), f"{where}.{f.name}")
                   for f in dataclasses.fields(got))
    if isinstance(got, np.ndarray) or isinstance(expected, np.ndarray):
        assert np.array_equal(got, expected), f"{where}: {np.count_nonzero(got != expected)} cells differ"
        return 1
    if isinstance(got, (deque, list, tuple)) and not isinstance(got, str):
        assert len(got) == len(expected), f"{where}: {len(got)} items, not {len(expected)}"
        return sum(assert_same_state(a, b, f"{where}[{i}]") for i, (a, b) in enumerate(zip(got, expected,
                                                                                          strict=True))) or 1
    if isinstance(got, dict):
        assert got.keys() == expected.keys(), where
        return sum(assert_same_state(got[k], expected[k], f"{where}[{k!r}]") for k in got) or 1
    if isinstance(got, MemoryMap):
        assert np.array_equal(got.grid, expected.grid), where
        return 1
    assert got == expected, f"{where}: {got!r} != {expected!r}"
    return 1


def test_seeking_backwards_gives_the_state_a_direct_seek_gives(experiment_run):
    """A seek rebuilds the fleet from nothing: going back from late in the log leaves nothing of the later
    state (a seek that kept the fleet left 350 trail points where a direct seek gives 50)."""
    log = experiment_run.log
    back = Replay.open(log, Fleet(Datum()))
    late, early = back.duration * 0.9, back.duration * 0.2
    back.seek(late)
    later = back.fleet.get(1)
    trail_late, hits_late, map_late = len(later.trail), len(later.hits), later.map_stream.grid.copy()
    back.seek(early)
    direct = Replay.open(log, Fleet(Datum()))
    direct.seek(early)
    assert back.fleet.ids() == direct.fleet.ids() == [1]
    got, expected = back.fleet.get(1), direct.fleet.get(1)
    assert expected.map_stream.synced and expected.map_stream.grid.any()  # there is a map to compare
    # what a seek that kept the later state would show differs from the state early on
    assert len(expected.trail) < trail_late and len(expected.hits) < hits_late
    assert not np.array_equal(expected.map_stream.grid, map_late)
    compared = assert_same_state(got, expected)
    assert compared > 100  # the trail, the hits and the map were compared, not just a few fields
    assert (back.position, back.clock) == (direct.position, direct.clock)


def test_a_replayed_old_log_draws_its_sonar_beams(experiment_run, monkeypatch):
    """The 3D view takes its clock from the station: a log flown months ago draws its beams as live does."""
    with idle_station() as station:
        scene = station.view.server.scene
        drawn, add = [], scene.add_line_segments
        monkeypatch.setattr(scene, "add_line_segments", lambda name, *a, **k: drawn.append(name) or add(name, *a, **k))
        replay = station.replays.start(experiment_run.log)
        replay.playing = False
        replay.seek(replay.duration / 2)  # mid-scan
        station.view.draw()
        assert "/layers/beams/1" in drawn


def test_after_a_seek_a_vehicle_was_last_heard_at_its_last_record(tmp_path):
    """A seek applies only the records that rebuild the state, maps before poses; the vehicle was still
    last heard at its very last record before the seek time, often a map message."""
    log = tmp_path / "mixed.tlog"
    synthetic_log(log, 3000)
    index = index_tlog(log)
    replay = Replay.open(log, Fleet(Datum()))
    mine = np.flatnonzero(index.sysids == 1)
    tunnels = mine[index.msgids[mine] == mavlink.MAVLINK_MSG_ID_TUNNEL]
    assert len(tunnels) > 20
    for i in tunnels[len(tunnels) // 2::len(tunnels) // 20]:
        replay.seek(float(index.times[i]) - index.start + 5e-7)  # up to and including the map record
        vehicle = replay.fleet.get(1)
        assert vehicle is not None and vehicle.last_message == pytest.approx(index.times[i], abs=1e-6)


def test_seeking_in_a_log_that_lost_snapshot_chunks_still_shows_the_map(experiment_run, tmp_path):
    """A live station that lost a chunk of each of the last two map snapshots (UDP loss hits the snapshot
    bursts first) stays synced from an earlier snapshot plus the deltas; seeking in its recording does too,
    from the last complete snapshot."""
    log = experiment_run.log
    index = index_tlog(log)
    data = log.read_bytes()

    def header(i: int) -> tuple[int, int, int]:  # snapshot id, chunk index, chunk count of a TUNNEL record
        body = int(index.offsets[i]) + 10  # MAVLink 2; the payload starts 5 bytes into the TUNNEL fields
        return struct.unpack_from("<HHH", data[body + 5:body + 11].ljust(6, b"\0"))

    chunks = [int(i) for i in np.flatnonzero(index.tunnel_types == MAP_SNAPSHOT)]
    starts = [i for i in chunks if header(i)[1] == 0]
    assert len(starts) >= 3 and all(header(i)[2] >= 2 for i in starts[-2:])
    lost = {next(i for i in chunks if i > start and header(i)[1] == 1) for start in starts[-2:]}
    lossy = tmp_path / "lossy.tlog"
    lossy.write_bytes(b"".join(data[int(o) - 8:int(o) + int(n)] for k, (o, n) in
                               enumerate(zip(index.offsets, index.lengths, strict=True)) if k not in lost))
    live = MapReceiver()  # what a live station that heard exactly this held at the end
    for message in decoded(lossy):
        if message.get_type() == "TUNNEL":
            live.feed(message.payload_type, bytes(message.payload[:message.payload_length]))
    assert live.synced and np.array_equal(live.grid, experiment_run.final_map)
    replay = Replay.open(lossy, Fleet(Datum()))
    for seconds in (replay.duration, float(index.times[starts[-1]] - index.start) + 0.01):
        replay.seek(seconds)
        stream = replay.fleet.get(1).map_stream
        assert stream.synced, f"no map at {seconds:.2f} s where the live station had one"
    replay.seek(replay.duration)
    assert np.array_equal(replay.fleet.get(1).map_stream.grid, live.grid)


@pytest.mark.parametrize("where", ["after the header", "half way", "one byte short"])
def test_a_truncated_log_replays_up_to_the_cut(tmp_path, where):
    whole = tmp_path / "whole.tlog"
    fixes = plane_log(whole)
    full = index_tlog(whole)
    keep = len(full) // 2
    length = int(full.lengths[keep])
    into = {"after the header": 6 + 1, "half way": length // 2, "one byte short": length - 1}[where]
    cut_at = int(full.offsets[keep]) + into  # into the packet of record ``keep``
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(whole.read_bytes()[:cut_at])
    index = index_tlog(cut)
    assert "truncated" in index.warning and "cut.tlog" in index.warning
    assert len(index) == keep
    span = index_tlog(cut, columns=False)  # as the recordings list reads it
    assert (span.start, span.duration, span.warning) == (index.start, index.duration, index.warning)
    assert np.array_equal(index.offsets, full.offsets[:keep])
    replay = Replay.open(cut, Fleet())
    assert replay.status()["warning"] == index.warning
    assert replay.duration == pytest.approx(float(full.times[keep - 1] - full.times[0]))
    replay.seek(replay.duration)
    plane = replay.fleet.get(PLANE_SYSID)
    when, lat, lon = fix_at(fixes, float(index.times[-1]))
    assert plane.lat == pytest.approx(lat, abs=1e-9) and plane.lon == pytest.approx(lon, abs=1e-9)


@pytest.mark.parametrize("into", [1, 4, 7, 8, 9, 11])  # bytes into the record: its timestamp, its header
def test_a_log_cut_in_a_record_header_replays_with_a_warning(tmp_path, into):
    whole = tmp_path / "whole.tlog"
    plane_log(whole)
    full = index_tlog(whole)
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(whole.read_bytes()[:int(full.offsets[500]) - 8 + into])
    index = index_tlog(cut)
    assert index.warning and "cut.tlog" in index.warning  # never silently
    assert len(index) == 500
    replay = Replay.open(cut, Fleet())
    replay.seek(replay.duration)
    assert replay.fleet.get(PLANE_SYSID) is not None


def test_a_partly_corrupt_log_replays_up_to_the_damage(tmp_path):
    whole = tmp_path / "whole.tlog"
    plane_log(whole)
    full = index_tlog(whole)
    damage_at = int(full.offsets[3000]) - 8  # the start of record 3000 (its timestamp)
    data = whole.read_bytes()
    garbage = random.Random(11).randbytes(500)
    corrupt = tmp_path / "corrupt.tlog"
    corrupt.write_bytes(data[:damage_at] + garbage + data[damage_at:])
    index = index_tlog(corrupt)
    assert "damaged" in index.warning and str(damage_at) in index.warning
    assert len(index) == 3000
    span = index_tlog(corrupt, columns=False)  # as the recordings list reads it
    assert (span.start, span.duration, span.warning) == (index.start, index.duration, index.warning)
    assert np.array_equal(index.offsets, full.offsets[:3000])
    replay = Replay.open(corrupt, Fleet())
    assert replay.duration == pytest.approx(float(full.times[2999] - full.times[0]))
    replay.seek(replay.duration)
    plane = replay.fleet.get(PLANE_SYSID)
    assert plane is not None and plane.kind == "plane"
    # a damaged packet inside a record (a flipped payload byte: bad CRC) is skipped, not fatal
    flipped = bytearray(data)
    flipped[int(full.offsets[100]) + 8] ^= 0xFF
    broken = tmp_path / "flipped.tlog"
    broken.write_bytes(bytes(flipped))
    replay = Replay.open(broken, Fleet())
    replay.seek(replay.duration)
    assert replay.fleet.get(PLANE_SYSID) is not None


@pytest.mark.parametrize("kind", ["readme", "png", "empty", "tiny", "zeros"])
def test_a_file_that_is_no_log_is_refused_clearly(tmp_path, kind):
    if kind == "readme":
        path = ROOT / "README.md"
    else:
        path = tmp_path / f"{kind}.tlog"
        if kind == "png":
            from PIL import Image

            Image.new("RGB", (8, 8), (10, 200, 30)).save(path, "PNG")
        else:
            path.write_bytes({"empty": b"", "tiny": b"\xfe\x09\x00", "zeros": bytes(4096)}[kind])
    with pytest.raises(ReplayError, match="not a telemetry log") as caught:
        index_tlog(path)
    assert path.name in str(caught.value)
    with pytest.raises(ReplayError):
        Replay.open(path, Fleet())


def test_groundstation_replay_refuses_a_file_that_is_no_log():
    result = subprocess.run([str(BIN / "groundstation"), "replay", "README.md", "--port", "1"], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "README.md is not a telemetry log" in result.stderr
    assert result.stderr.startswith("groundstation replay:")
    assert "Traceback" not in result.stderr


def test_groundstation_replay_refuses_a_missing_file(tmp_path, capsys):
    from groundstation.cli import main

    assert main(["replay", str(tmp_path / "no-such.tlog"), "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("groundstation replay:") and "no-such.tlog" in err


# ---- the index is exact ---------------------------------------------------------------------------------
def synthetic_log(path: Path, count: int = 20_000) -> None:
    """``count`` records: MAVLink 2 (trimmed payloads, TUNNEL with our payload types, ids above 255, a few
    signed) and MAVLink 1, from three systems."""
    rng = random.Random(42)
    v2 = {sysid: mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1) for sysid in (1, 2)}
    v1 = mavlink1.MAVLink(None, srcSystem=3, srcComponent=1)
    signed = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    signed.signing.secret_key = bytes(range(32))
    signed.signing.link_id = 1
    signed.signing.sign_outgoing = True
    signed.signing.timestamp = 1
    chunks = []
    stamp = PLANE_START
    for i in range(count):
        stamp += rng.uniform(0.0001, 0.01)
        choice = rng.random()
        if choice < 0.1:
            packer, message = v1, mavlink1.MAVLink_heartbeat_message(1, 3, 0, rng.randrange(20), 4, 3)
        elif choice < 0.2:
            packer, message = v1, mavlink1.MAVLink_attitude_message(i, rng.random(), 0.0, 0.0, 0.0, 0.0, 0.0)
        elif choice < 0.22:
            packer, message = signed, mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)
        else:
            packer = v2[1 if choice < 0.6 else 2]
            pick = rng.randrange(7)
            if pick == 0:
                size = rng.randrange(0, 129)
                payload = bytes(rng.randrange(256) for _ in range(size))
                message = mavlink.MAVLink_tunnel_message(255, 190, rng.choice((MAP_SNAPSHOT, 32801, 32802, 7)),
                                                         size, list(payload.ljust(128, b"\0")))
            elif pick == 1:
                message = mavlink.MAVLink_global_position_int_message(i, rng.randrange(-900000000, 900000000),
                                                                      rng.randrange(-1800000000, 1800000000),
                                                                      0, 0, 0, 0, 0, 0)  # trailing zeros trimmed
            elif pick == 2:
                message = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 0)  # almost all zeros
            elif pick == 3:
                message = mavlink.MAVLink_distance_sensor_message(i, 2, 4000, rng.randrange(4000), 1, 0, 0, 0,
                                                                  0, 0, [1, 0, 0, 0], 0)
            elif pick == 4:
                text = "x" * rng.randrange(1, 50)
                message = mavlink.MAVLink_statustext_message(6, text.encode(), 0, 0)
            elif pick == 5:
                message = mavlink.MAVLink_autopilot_version_message(0xFFFF, 1, 2, 3, 4, bytes(8), bytes(8),
                                                                    bytes(8), 5, 6, 7, bytes(18))
            else:
                message = mavlink.MAVLink_command_ack_message(rng.randrange(600), 0, 0, 0, 255, 190)
        chunks.append(TLOG_STAMP.pack(int(stamp * 1e6)) + message.pack(packer))
    path.write_bytes(b"".join(chunks))


def test_the_index_is_exact_on_20000_messages(tmp_path):
    path = tmp_path / "synthetic.tlog"
    synthetic_log(path)
    index = index_tlog(path)
    assert len(index) == 20_000 and index.warning == ""
    messages = decoded(path)
    assert len(messages) == 20_000
    assert Counter(int(i) for i in index.msgids) == Counter(m.get_msgId() for m in messages)
    assert [int(s) for s in index.sysids] == [m.get_srcSystem() for m in messages]
    assert np.allclose(index.times, [m._timestamp for m in messages], atol=1e-6)
    tunnels = [m.payload_type for m in messages if m.get_type() == "TUNNEL"]
    assert [int(t) for t in index.tunnel_types[index.msgids == mavlink.MAVLINK_MSG_ID_TUNNEL]] == tunnels
    assert set(index.tunnel_types[index.msgids != mavlink.MAVLINK_MSG_ID_TUNNEL]) == {-1}
    data = path.read_bytes()
    for i in range(0, 20_000, 997):  # each record's bytes are its packet, as pymavlink packed it
        assert bytes(data[index.offsets[i]:index.offsets[i] + index.lengths[i]]) == bytes(messages[i].get_msgbuf())
    assert sum(bool(m.get_msgbuf()[2] & 0x01) for m in messages if m.get_msgbuf()[0] == 0xFD) >= 100  # signed


def test_the_index_is_exact_on_map_snapshot_chunk_headers(tmp_path):
    """The chunk header read from the raw packet (snapshot id, chunk index, chunk count: three unsigned 16-bit
    numbers) is the one pymavlink decodes, in every snapshot chunk: also where MAVLink 2 dropped trailing zero
    bytes of the payload into the header (its missing bytes are zeros, not the checksum after the payload)."""
    path = tmp_path / "synthetic.tlog"
    synthetic_log(path, 6000)
    index = index_tlog(path)
    replay = Replay.open(path, Fleet(Datum()))
    messages = decoded(path)
    chunks = [int(i) for i in np.flatnonzero(index.tunnel_types == MAP_SNAPSHOT)]
    for i in chunks:
        assert replay.chunk_header(i) == struct.unpack_from("<HHH", bytes(messages[i].payload)), i
    cut = [i for i in chunks if bytes(messages[i].get_msgbuf())[1] < 5 + 6]  # the header cut short on the wire
    assert len(chunks) > 100 and sum(max(replay.chunk_header(i)) >= 32768 for i in chunks) >= 10
    assert len(cut) >= 5 and sum(replay.chunk_header(i) == (0, 0, 0) for i in cut) >= 1



def test_raw_reads_of_heartbeats_and_sensor_ids_are_pymavlinks_in_mavlink_1_and_2(tmp_path):
    """A heartbeat's type and autopilot and a distance sensor's id, read from the raw packet, are the ones
    pymavlink decodes: from MAVLink 1 packets (a 6-byte header) and MAVLink 2 ones (10 bytes, trailing zero
    bytes of the payload dropped, so a zero id or autopilot may not be on the wire at all)."""
    rng = random.Random(7)
    senders = [mavlink1.MAVLink(None, srcSystem=3, srcComponent=1), mavlink.MAVLink(None, srcSystem=1, srcComponent=1)]
    records = []
    for k in range(400):
        sender = senders[k % 2]
        if k % 4 < 2:
            message = sender.heartbeat_encode(rng.choice((0, 1, 2, 10, 255)), rng.choice((0, 3, 8)), 0, 0, 0, 3)
        else:
            message = sender.distance_sensor_encode(k, 2, 4000, rng.randrange(4000), 1, rng.choice((0, 1, 7, 255)),
                                                    0, 0)
        records.append(TLOG_STAMP.pack(int((PLANE_START + k / 10) * 1e6)) + message.pack(sender))
    path = tmp_path / "both.tlog"
    path.write_bytes(b"".join(records))
    replay = Replay.open(path, Fleet(Datum()))
    messages = decoded(path)
    assert len(messages) == len(replay.index) == 400
    seen = Counter()
    for i, message in enumerate(messages):
        version = message.get_msgbuf()[0]
        if message.get_type() == "HEARTBEAT":
            assert replay._heartbeat_kind(i) == (message.type, message.autopilot), i
            seen[version, "heartbeat", message.autopilot == 0] += 1
        else:
            assert replay.sensor_id(i) == message.id, i
            seen[version, "sensor", message.id == 0] += 1
    assert len(seen) == 8  # each kind from each version, with a zero and a non-zero field

# ---- seeking and playing a log of two mapping vehicles --------------------------------------------------
TICK = 1 / 64  # s between records of the logs below: exact in binary, so a seek can land exactly on a record


class TlogWriter:
    """A tlog written record by record, each TICK after the one before."""

    def __init__(self):
        self.records: list[bytes] = []

    @property
    def next_time(self) -> float:
        return PLANE_START + len(self.records) * TICK

    def write(self, message, packer) -> float:
        stamp = self.next_time
        self.records.append(TLOG_STAMP.pack(round(stamp * 1e6)) + message.pack(packer))
        return stamp

    def save(self, path: Path) -> Path:
        path.write_bytes(b"".join(self.records))
        return path


def tunnel_of(kind: int, payload: bytes):
    return mavlink.MAVLink_tunnel_message(0, 0, kind, len(payload), list(payload.ljust(128, b"\0")))


def packers(sysid: int):
    """The autopilot's and the companion computer's packers of a vehicle."""
    return (
        mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1),
        mavlink.MAVLink(None, srcSystem=sysid, srcComponent=mavlink.MAV_COMP_ID_ONBOARD_COMPUTER),
    )


def copter_beat(custom_mode: int = 3):
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR,
        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
        custom_mode,
        mavlink.MAV_STATE_ACTIVE,
        3,
    )


def companion_beat():
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
    )


def fix(x: float, y: float, ms: int):
    """A GLOBAL_POSITION_INT at scene x, y, 10 m up, heading north."""
    lat, lon = Datum(*PLANE_CENTRE, 0.0).to_global(x, y)
    return mavlink.MAVLink_global_position_int_message(
        ms, int(round(lat * 1e7)), int(round(lon * 1e7)), 0, 10_000, 50, -20, 0, 0
    )


SURVEY_PATHS = {3: 40, 500: 35, 800: 7}  # copter 1's planned paths: step sent, points (15 to a chunk)
SURVEY_LOST = 500  # the path whose middle chunk was lost on the way


def survey_path(step: int, points: int) -> list[tuple[float, float]]:
    return [(round(step / 100 + k * 0.5, 2), round(-k * 0.25, 2)) for k in range(points)]


def corrupt_last(log: TlogWriter, into: int) -> None:
    """Flip a byte ``into`` the packet of the last record written: its checksum no longer matches."""
    record = bytearray(log.records[-1])
    record[TLOG_STAMP.size + into] ^= 0x55
    log.records[-1] = bytes(record)


def survey_log(path: Path, steps: int = 1200) -> Path:
    """Copters 1 and 2 with companion computers, recorded from the vehicles' first words on: both stream their
    maps (deltas, a snapshot every 4 s), 1 takes a sonar reading every 4th step while it pitches and turns, both
    send a text now and then. Copter 1's agent sends its status every 10 steps, copter 2's once, at the start
    (it idles throughout). Their agents send planned paths: copter 2's one, early;
    copter 1's at the steps of SURVEY_PATHS, all but one whole. Copter 1's last two agent statuses are damaged:
    one that does not decode as a status, one whose packet fails its checksum. The log opens with a text of
    copter 1, before its first heartbeat (playing drops it: no vehicle yet), and a heartbeat of copter 2."""
    log = TlogWriter()
    (one, one_companion), (two, two_companion) = packers(1), packers(2)
    onboard = MemoryMap((0.0, 0.0), 10.0, 5.0)
    streamer = MapStreamer(onboard, (0.0, 0.0), snapshot_period=4.0)
    streamer_two = MapStreamer(MemoryMap((0.0, 0.0), 10.0, 5.0), (0.0, 0.0), snapshot_period=4.0)  # an empty map
    rng = random.Random(3)
    log.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"recording", 0, 0), one)
    log.write(copter_beat(), two)
    for step in range(steps):
        ms = step * 100
        t = log.next_time - PLANE_START
        angle = step / 50
        x, y = 5 * math.cos(angle), 5 * math.sin(angle)
        if step % 10 == 0:
            log.write(copter_beat(3 if step < steps // 2 else 4), one)
            log.write(companion_beat(), one_companion)
            log.write(copter_beat(), two)
            log.write(companion_beat(), two_companion)
            log.write(
                mavlink.MAVLink_sys_status_message(
                    0, 0, 0, 300, 12_600 - step, 1500, 90 - step // 20, 0, 0, 0, 0, 0, 0
                ),
                one,
            )
            log.write(mavlink.MAVLink_mission_current_message(step // 100, 12, 0, 0), one)
            phase = ("takeoff", "mission", "homing")[3 * step // steps]
            status = agent_status.encode(agent_status.AgentStatus(phase, False, "", "survey", f"step {step}"))
            if step == steps - 20:
                status = bytes([len(agent_status.PHASES)]) + status[1:]  # a phase no agent has
            log.write(tunnel_of(agent_status.AGENT_STATUS, status), one_companion)
            if step == steps - 10:
                corrupt_last(log, 10 + 5 + 6)  # a byte of the mission's name
            if step == 0:  # copter 2's agent says its state only when it changes, and it idles throughout
                idle = agent_status.AgentStatus("waiting", False, "", "survey", "idle")
                log.write(tunnel_of(agent_status.AGENT_STATUS, agent_status.encode(idle)), two_companion)
        if step in SURVEY_PATHS:
            chunks = streamer.path(survey_path(step, SURVEY_PATHS[step]))
            for number, (kind, payload) in enumerate(chunks):
                if step != SURVEY_LOST or number != 1:
                    log.write(tunnel_of(kind, payload), one_companion)
        if step == 2:
            for kind, payload in streamer_two.path([(-1.0, 2.0), (-3.5, 4.25)]):
                log.write(tunnel_of(kind, payload), two_companion)
        log.write(fix(x, y, ms), one)
        pitch, yaw = 0.2 + 0.15 * math.sin(step / 7), (angle + math.pi / 2 + 0.3 * math.sin(step / 5)) % (2 * math.pi)
        log.write(mavlink.MAVLink_attitude_message(ms, 0.05, pitch, yaw, 0, 0, 0), one)  # (the fix says north)
        log.write(fix(-x, -y, ms), two)
        log.write(mavlink.MAVLink_attitude_message(ms, 0.0, 0.0, 1.0, 0, 0, 0), two)
        if step % 4 == 0:
            distance = rng.uniform(1.5, 4.0)
            log.write(
                mavlink.MAVLink_distance_sensor_message(
                    ms, 20, 1000, int(distance * 100), 1, 0, 0, 0, 0, 0, [1, 0, 0, 0], 0
                ),
                one,
            )
            onboard.add_reading(
                np.array([x, y, 2.0]), np.array([math.cos(angle), math.sin(angle), 0.0]), distance, 10.0
            )
        for kind, payload in streamer.tick(t):
            log.write(tunnel_of(kind, payload), one_companion)
        for kind, payload in streamer_two.tick(t):
            log.write(tunnel_of(kind, payload), two_companion)
        if step % 60 == 30:
            for packer, who in ((one, "one"), (two, "two")):
                text = f"{who} passed step {step}".encode()
                log.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, text, 0, 0), packer)
    return log.save(path)


def played(path: Path, until: float, datum: Datum) -> Fleet:
    """A Fleet fed every message of the log up to ``until`` (Unix seconds) in order, as a live link would."""
    fleet = Fleet(datum, forget_after=None)
    for message in decoded(path):
        if message._timestamp > until:
            break
        fleet.apply(message, message._timestamp)
    return fleet


def shown(vehicle) -> dict:
    """What a seek rebuilds of a vehicle: its latest status messages, trail, sonar, hits and agent."""
    return {
        "mode": vehicle.mode,
        "armed": vehicle.armed,
        "kind": vehicle.kind,
        "position": (vehicle.lat, vehicle.lon, vehicle.alt, vehicle.x, vehicle.y),
        "attitude": (vehicle.roll, vehicle.pitch, vehicle.yaw),
        "motion": (vehicle.speed, vehicle.climb),
        "battery": (vehicle.voltage, vehicle.remaining),
        "home": vehicle.home,
        "heard": (vehicle.last_heartbeat, vehicle.last_message, vehicle.companion_heartbeat),
        "status": vehicle.status,
        "boot": vehicle.time_boot_s,
        "mission": (vehicle.mission_current, vehicle.mission_total),
        "trail": list(vehicle.trail),
        "sonar": vehicle.sonar,
        "hits": list(vehicle.hits),
        "agent": vehicle.agent,
        "path": vehicle.planned_path(),
    }


def test_after_a_seek_two_mapping_vehicles_show_what_the_log_played_up_to_there_shows(tmp_path, monkeypatch):
    """A seek applies only some records (the first heartbeats, the map from its last whole snapshot, the path from
    its last whole sending, the latest of each status message per component, the recent texts and readings) and
    still shows each vehicle as playing the log from its start up to the seek time does: the planned path sent
    before the last snapshot, each sonar hit where the vehicle's attitude then put it, the agent's last status that
    decodes; its messages are the last of those playing shows, each once (not the text copter 1 sent before its
    first heartbeat, which playing drops). It decodes each record it applies once, and of the planned path's
    records only those from the last whole path on."""
    path = survey_log(tmp_path / "survey.tlog")
    index = index_tlog(path)
    datum = Datum(*PLANE_CENTRE, 0.0)
    replay = Replay.open(path, Fleet(datum))
    decoding: list[int] = []  # the records the replay decodes, in order
    decode = replay.decode
    monkeypatch.setattr(replay, "decode", lambda i, decoder=None: decoding.append(i) or decode(i, decoder))
    path_ids = {i: struct.unpack_from("<H", packet, 10 + 5)[0] for i, (_, packet) in enumerate(records(path))
                if index.tunnel_types[i] == PATH and index.sysids[i] == 1}  # copter 1's path records: their path id
    first_status = np.flatnonzero((index.tunnel_types == agent_status.AGENT_STATUS) & (index.sysids == 1))[0]
    at = [
        float(index.times[first_status] - index.start),  # copter 1's agent has sent one status so far
        replay.duration * 0.45,
        replay.duration * 0.8,
        replay.duration,
    ]
    maps = sequential_maps(path, [index.start + seconds for seconds in at])
    paths = []  # the step of copter 1's path shown at each seek
    for seconds in at:
        decoding.clear()
        replay.seek(seconds)
        assert len(decoding) == len(set(decoding)) > 0
        until = index.start + seconds
        fleet = played(path, until, datum)
        assert replay.fleet.ids() == fleet.ids() == [1, 2]
        for sysid in (1, 2):
            got, expected = replay.fleet.get(sysid), fleet.get(sysid)
            assert shown(got) == shown(expected), (seconds, sysid)
            assert [m["text"] for m in got.messages] == [m["text"] for m in expected.messages][-20:]
            assert got.status == (got.messages[-1]["text"] if got.messages else "")
        copter = replay.fleet.get(1)
        grid, synced, applied = maps[until]
        assert (copter.map_stream.synced, copter.map_stream.applied) == (synced, applied)
        assert synced == (seconds > 1)  # the first snapshot comes after the first status
        assert np.array_equal(copter.map_stream.grid, grid)
        assert len(copter.hits) == len(fleet.get(1).hits) >= (100 if seconds > 10 else 0)
        # the step of copter 1's latest fix (none yet: -1); the paths of its step came before it
        step = -1 if copter.time_boot_s is None else round(copter.time_boot_s * 10)
        sent = [s for s in SURVEY_PATHS if s <= step and s != SURVEY_LOST]
        paths.append(sent[-1] if sent else None)
        assert copter.map_stream.path == [tuple(float(np.float32(v)) for v in point)
                                          for point in (survey_path(sent[-1], SURVEY_PATHS[sent[-1]]) if sent else [])]
        assert replay.fleet.get(2).map_stream.path == ([(-1.0, 2.0), (-3.5, 4.25)] if step >= 2 else [])
        shown_id = list(SURVEY_PATHS).index(sent[-1]) + 1 if sent else 0  # the paths' ids count from 1
        assert [path_ids[i] for i in decoding if i in path_ids] == [
            ident for i, ident in path_ids.items() if i < replay.position and ident >= shown_id
        ]
    assert paths == [None, 3, 800, 800]  # the second seek comes after the path that lost a chunk
    assert copter.mode != replay.fleet.get(2).mode and len(copter.messages) == 20  # the late mode; 21 texts said
    assert copter.agent.reason == "step 1170"  # the last two do not decode
    assert replay.fleet.get(2).agent.reason == "idle"


def mapping_log(path: Path) -> tuple[Path, list[np.ndarray]]:
    """Copter 1's companion streams a noisy map: snapshot 1 (three chunks or more), deltas, snapshot 2 with a delta
    sent between its first and second chunk (as a sender that spreads a big snapshot's chunks over several ticks
    would), and more deltas. Returns the log and the onboard map after snapshot 1 and at the end."""
    log = TlogWriter()
    autopilot, companion = packers(1)
    onboard = MemoryMap((0.0, 0.0), 10.0, 5.0)
    rng = np.random.default_rng(8)
    onboard.grid[20:60, 20:60] = rng.integers(-20, 20, (40, 40), dtype=np.int8)
    streamer = MapStreamer(onboard, (0.0, 0.0))  # (a map that had something in it when streaming began)
    log.write(copter_beat(), autopilot)
    log.write(companion_beat(), companion)
    log.write(fix(0.0, 0.0, 0), autopilot)

    def readings(count: int) -> None:
        for _ in range(count):
            angle = rng.uniform(0, 2 * math.pi)
            onboard.add_reading(
                np.array([0.0, 0.0, 2.0]),
                np.array([math.cos(angle), math.sin(angle), 0.0]),
                rng.uniform(2.0, 8.0),
                10.0,
            )

    def send(payloads) -> None:
        for kind, payload in payloads:
            log.write(tunnel_of(kind, payload), companion)

    first = streamer.snapshot()
    assert sum(kind == MAP_SNAPSHOT for kind, _ in first) >= 3
    send(first)
    maps = [onboard.grid.copy()]
    for _ in range(3):
        readings(2)
        send(streamer.deltas())
        log.write(copter_beat(), autopilot)
    readings(2)
    second = streamer.snapshot()
    chunks = [i for i, (kind, _) in enumerate(second) if kind == MAP_SNAPSHOT]
    send(second[: chunks[0] + 1])
    readings(2)
    between = streamer.deltas()
    assert between
    send(between)
    send(second[chunks[0] + 1 :])
    for _ in range(3):
        readings(2)
        send(streamer.deltas())
        log.write(copter_beat(), autopilot)
    maps.append(onboard.grid.copy())
    return log.save(path), maps


def test_after_a_seek_the_map_is_the_vehicles_also_when_a_delta_came_between_snapshot_chunks(tmp_path):
    """The map is rebuilt from the last whole snapshot on, with the deltas after it: a delta newer than that
    snapshot that came between its chunks is applied once the snapshot is whole, so the map is the vehicle's. A
    seek into the first snapshot, before its last chunk, shows no map yet."""
    path, (after_first, final) = mapping_log(tmp_path / "mapping.tlog")
    index = index_tlog(path)
    replay = Replay.open(path, Fleet(Datum()))
    replay.seek(replay.duration)
    stream = replay.fleet.get(1).map_stream
    assert stream.synced and np.array_equal(stream.grid, final)
    chunks = np.flatnonzero(index.tunnel_types == MAP_SNAPSHOT)
    replay.seek(float(index.times[chunks[0]] - index.start))  # up to and including its first chunk
    vehicle = replay.fleet.get(1)
    assert vehicle is not None and vehicle.map_source is None and not vehicle.map_stream.synced
    whole = next(i for i in chunks if replay.chunk_header(int(i))[1] == replay.chunk_header(int(i))[2] - 1)
    replay.seek(float(index.times[whole] - index.start))
    stream = replay.fleet.get(1).map_stream
    assert stream.synced and np.array_equal(stream.grid, after_first)


def long_flight_log(path: Path, poses: int = 5997, readings: int = 0, fix_from: int | None = None) -> Path:
    """A rover driving east 1 m per LOCAL_POSITION_NED (its pose number is its x), a heartbeat every 10 poses and
    a text every 500; with ``readings`` N, a reading of its forward sonar after every N-th pose; with ``fix_from``,
    from that pose on a GLOBAL_POSITION_INT after each local one, that puts it 50 m north of where the local one
    does (the station takes the global one once it has one)."""
    log = TlogWriter()
    rover = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    for k in range(poses):
        if k % 10 == 0:
            log.write(
                mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_GROUND_ROVER,
                    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                    0,
                    10,
                    mavlink.MAV_STATE_ACTIVE,
                    3,
                ),
                rover,
            )
        if k % 500 == 250:
            log.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, f"pose {k}".encode(), 0, 0), rover)
        log.write(mavlink.MAVLink_local_position_ned_message(k * 100, 0.0, float(k), 0.0, 0.0, 1.0, 0.0), rover)
        if fix_from is not None and k >= fix_from:
            lat, lon = Datum().to_global(float(k), 50.0)
            log.write(mavlink.MAVLink_global_position_int_message(k * 100, round(lat * 1e7), round(lon * 1e7), 0, 0,
                                                                  100, 0, 0, 9000), rover)
        if readings and k % readings == readings - 1:
            log.write(mavlink.MAVLink_distance_sensor_message(k * 100, 20, 1000, 300 + k % 7, 1, 0, 0, 0), rover)
    return log.save(path)


def test_after_a_seek_a_long_flights_trail_is_thinned_evenly_from_the_first_fix_to_the_last(tmp_path):
    """A seek draws the trail from a sample of the poses: it starts at the first pose and ends at the latest, and
    the samples are evenly spread (pose numbers between neighbours differ by at most one)."""
    replay = Replay.open(long_flight_log(tmp_path / "long.tlog"), Fleet(Datum()))
    for seconds in (60.0, replay.duration):  # some 3500 poses, then all 5997
        replay.seek(seconds)
        rover = replay.fleet.get(1)
        numbers = [round(x) for x, y, z in rover.trail]
        assert numbers[0] == 0 and numbers[-1] == round(rover.x)
        gaps = np.diff(numbers)
        assert 1000 < len(numbers) <= 1500 and gaps.min() >= gaps.max() - 1 >= 1, sorted(Counter(gaps).items())
    assert rover.x == 5996.0


def test_after_a_seek_in_a_long_flight_each_sonar_hit_is_where_the_latest_pose_before_its_reading_put_it(tmp_path):
    """A seek draws a long flight's trail from a sample of its poses, yet places each sonar reading with the latest
    pose before it, as playing the log does (with the sample's poses, hits landed up to 3 m behind here), and adds
    no point to the trail for it: the trail stays the even sample. Two poses come to a reading, so the pose before
    the latest is not the one it needs."""
    path = long_flight_log(tmp_path / "long.tlog", readings=2)
    replay = Replay.open(path, Fleet(Datum()))
    for seconds in (60.0, replay.duration):  # some 1800 poses, then all 5997
        replay.seek(seconds)
        rover, expected = replay.fleet.get(1), played(path, replay.now, Datum()).get(1)
        assert len(rover.hits) == HITS_KEPT and list(rover.hits) == list(expected.hits)
        assert rover.sonar == expected.sonar and (rover.x, rover.y) == (expected.x, expected.y)
        numbers = [round(x) for x, y, z in rover.trail]
        gaps = np.diff(numbers)
        assert numbers[0] == 0 and numbers[-1] == round(rover.x)
        assert 1000 < len(numbers) <= 1500 and gaps.min() >= gaps.max() - 1 >= 1, sorted(Counter(gaps).items())


def test_after_a_seek_the_reading_after_the_first_fix_is_placed_by_that_fix(tmp_path):
    """A rover placed by its local position until its first GPS fix: after a seek the reading right after the fix is
    placed by the fix, as playing places it, though the trail's sample of poses (here) left that fix out."""
    path = long_flight_log(tmp_path / "fix.tlog", 2100, readings=1, fix_from=2000)
    replay = Replay.open(path, Fleet(Datum()))
    index = replay.index
    first_fix = np.flatnonzero(index.msgids == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)[0]
    replay.seek(float(index.times[first_fix] - index.start) + 0.3)  # a few readings after it
    rover, expected = replay.fleet.get(1), played(path, replay.now, Datum()).get(1)
    assert (2000, 50) not in [(round(x), round(y)) for x, y, z in rover.trail]
    assert list(rover.hits) == list(expected.hits)
    # facing north on its local position, east once the fix gives a heading: the fix's reading hits 3 m east
    hits = [(round(x), round(y)) for x, y, z in expected.hits]
    fixed = hits.index((2003, 50))
    assert hits[fixed - 1] == (1999, 3) and all(y == 50 for x, y in hits[fixed:])


def test_stepping_forward_and_backwards_after_a_seek_moves_a_tenth_of_a_second(tmp_path):
    """A step forward plays on by 0.1 s of log time, a step back seeks 0.1 s back: each shows what a seek to its
    time shows."""
    path = long_flight_log(tmp_path / "long.tlog", 2000)
    replay = Replay.open(path, Fleet(Datum()))
    sought = Replay.open(path, Fleet(Datum()))
    replay.seek(10.0)
    places = []
    for direction, seconds in ((1, 10.1), (1, 10.2), (-1, 10.1), (-1, 10.0), (-1, 9.9)):
        replay.step(direction)
        assert replay.clock == pytest.approx(seconds)
        sought.seek(seconds)
        assert replay.fleet.get(1).x == sought.fleet.get(1).x
        places.append(replay.fleet.get(1).x)
    assert places[0] < places[1] and places[2] == places[0] and places[2] > places[3] > places[4]  # some 6 poses a step


def test_playing_on_after_a_seek_applies_each_record_once_up_to_its_exact_time_and_stops_at_the_end(tmp_path):
    """Playing forward applies every record up to and including the new time, once, and at the end of the log
    stops playing there."""
    path = long_flight_log(tmp_path / "long.tlog", 2000)
    index = index_tlog(path)
    replay = Replay.open(path, Fleet(Datum()))
    texts = np.flatnonzero(index.msgids == mavlink.MAVLINK_MSG_ID_STATUSTEXT)
    replay.advance(float(index.times[texts[1]] - index.start))  # exactly to the second text
    assert replay.fleet.get(1).status == "pose 750"
    replay.advance(10.0)
    replay.advance(5.0)
    sought = Replay.open(path, Fleet(Datum()))
    sought.seek(replay.clock)
    got, expected = replay.fleet.get(1), sought.fleet.get(1)
    assert (
        [m["text"] for m in got.messages]
        == [m["text"] for m in expected.messages]
        == ["pose 250", "pose 750", "pose 1250"]
    )
    assert got.x == expected.x and got.status == "pose 1250"
    replay.playing = True
    replay.advance(replay.duration)
    assert replay.clock == replay.duration and replay.playing is False
    assert replay.fleet.get(1).x == 1999.0 and [m["text"] for m in replay.fleet.get(1).messages][-1] == "pose 1750"


def playing_at_10x(tmp_path) -> tuple[Replay, Player, list[float]]:
    """A long flight's replay playing at 10x, its player (not started: a test ticks it) and the player's clock,
    which stands still until the test moves ``wall[0]``."""
    replay = Replay.open(long_flight_log(tmp_path / "long.tlog", 2000), Fleet(Datum()))
    wall = [100.0]
    player = Player(replay, clock=lambda: wall[0])
    replay.speed, replay.playing = 10.0, True
    return replay, player, wall


def test_the_player_plays_wall_time_times_speed_and_not_the_time_a_seek_took(tmp_path):
    """At 10x, a tenth of a second of wall time plays a second of the log; a seek that took 0.3 s (a long
    log's seek does) is not played on by the next tick, and a paused replay stays put."""
    replay, player, wall = playing_at_10x(tmp_path)
    wall[0] += 0.1
    player.tick()
    assert replay.clock == pytest.approx(1.0)
    replay.seek(20.0)
    wall[0] += 0.3  # the seek's own time
    player.tick()
    assert replay.clock == 20.0
    wall[0] += 0.05
    player.tick()
    assert replay.clock == pytest.approx(20.5)
    replay.playing = False
    wall[0] += 0.05
    player.tick()
    assert replay.clock == pytest.approx(20.5)
    replay.playing = True  # the time paused is not played either
    wall[0] += 0.05
    player.tick()
    assert replay.clock == pytest.approx(21.0)


def test_a_pause_that_comes_during_a_players_tick_answers_the_time_the_replay_stays_at(tmp_path):
    """An operator's pause waits for a tick in progress and answers the time that tick left: it used to answer the
    time before the tick, and the replay then stood a tick further on (CI saw 0.052 s after a pause at 0.0)."""
    replay, player, wall = playing_at_10x(tmp_path)
    wall[0] += 0.1
    in_tick, go_on = threading.Event(), threading.Event()
    advance = replay.advance

    def slow_advance(seconds):  # the tick holds the lock while it plays on
        in_tick.set()
        go_on.wait(5)
        advance(seconds)

    replay.advance = slow_advance
    ticking = threading.Thread(target=player.tick)
    ticking.start()
    assert in_tick.wait(5)
    answered = []
    pausing = threading.Thread(target=lambda: answered.append(replay.control(play=False)))
    pausing.start()
    pausing.join(0.2)
    assert pausing.is_alive() and not answered  # it waits for the tick
    go_on.set()
    ticking.join(5)
    pausing.join(5)
    assert answered[0]["playing"] is False and answered[0]["time"] == pytest.approx(1.0) == replay.clock
    wall[0] += 0.1
    player.tick()
    assert replay.status()["time"] == answered[0]["time"]


def test_replay_controls_apply_in_order_pause_seek_step_play(tmp_path):
    """One control may carry several changes: speed, then a pause, a seek, a step, then play (from the start once
    the end was reached)."""
    path = long_flight_log(tmp_path / "long.tlog", 2000)
    replay = Replay.open(path, Fleet(Datum()))
    replay.playing = True
    status = replay.control(speed=5.0, seek=10.0, step=1)
    assert status["speed"] == 5.0 and status["time"] == pytest.approx(10.1) and status["playing"] is False
    status = replay.control(seek=12.0, play=True)
    assert status["time"] == 12.0 and status["playing"] is True
    replay.advance(replay.duration)
    assert replay.playing is False
    status = replay.control(play=True)
    assert status["time"] == 0.0 and status["playing"] is True
    status = replay.control(play=False)
    assert status["time"] == 0.0 and status["playing"] is False


def test_a_replay_opens_at_its_first_vehicle_so_a_page_asking_after_it_finds_it(tmp_path):
    """A station's recording starts with its own records (a text, its heartbeat) before any vehicle's heartbeat:
    a replay opened at 0 held no vehicle for a moment, and a page still showing that vehicle live asked for its map
    and history and got 404s. It opens at the first vehicle's heartbeat; a log with no vehicle opens at 0."""
    log = TlogWriter()
    station = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rover = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    for k in range(5):
        log.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, f"station {k}".encode(), 0, 0),
                  station)
    beat = log.write(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GROUND_ROVER,
                                                       mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 10, 4, 3), rover)
    for k in range(20):
        log.write(mavlink.MAVLink_local_position_ned_message(k * 100, float(k), 0.0, 0.0, 0.0, 0.0, 0.0), rover)
    replay = Replay.open(log.save(tmp_path / "station_first.tlog"), Fleet(Datum()))
    assert replay.clock > 0 and replay.clock == pytest.approx(beat - PLANE_START)
    assert replay.fleet.get(1) is not None

    empty = TlogWriter()
    for _ in range(5):
        empty.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"alone", 0, 0), station)
    lonely = Replay.open(empty.save(tmp_path / "no_vehicle.tlog"), Fleet(Datum()))
    assert lonely.clock == 0.0 and not lonely.fleet.vehicles
