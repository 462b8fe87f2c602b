"""Replay of a recorded .tlog: an index of its raw framing, seeking, and playback into a Fleet.

pymavlink decodes some 16,000 messages a second, so an hour at 20 Hz (about
300,000 messages) would take twenty seconds to open that way. Opening reads
only the framing instead: the timestamp, system and component ids, message
id and offset of every record (and, for TUNNEL, the payload type in its first
two bytes).
Seeking to a time then decodes only what rebuilds the state there: the
latest of each status message (of the onboard agent's, the last few: a damaged
one leaves the one before), a thinned-out trail, the recent messages and sonar
hits (each reading after the attitude and pose the vehicle had then), the map
from its last complete snapshot on and the planned path from its last complete
sending on (both found from the chunk headers in the raw TUNNEL payloads). Playing forward
feeds the Fleet message by message, as a live link does: a log is just another
MAVLink source, and the views cannot tell the difference. What a system sent
before its first vehicle heartbeat (a text at boot, say) playing drops, as a
live station does, and so does a seek. A record that decodes but makes the
Fleet raise is counted (``errors`` and ``last_error`` in the status) and
passed over, as the live link does: one bad message in a recording must not
stop its replay.
"""

from __future__ import annotations

import logging
import mmap
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.state import Fleet, makes_a_vehicle
from vehicle.protocol.agent_status import AGENT_STATUS
from vehicle.protocol.mapstream import MAP_SNAPSHOT, PATH, PATH_CHUNK, SNAPSHOT_CHUNK
from vehicle.protocol.mav import AUTOPILOT, mavlink
from vehicle.protocol.radiostream import RADIO_LINKS

log = logging.getLogger("groundstation.replay")

V1, V2 = 0xFE, 0xFD
SIGNED = 0x01
EARLIEST, LATEST = 946684800, 4102444800  # plausible timestamps: 2000..2100
TUNNEL = mavlink.MAVLINK_MSG_ID_TUNNEL
HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
POSES = (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
LATEST_ONLY = (HEARTBEAT, mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_VFR_HUD,
               mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
               mavlink.MAVLINK_MSG_ID_MISSION_CURRENT, mavlink.MAVLINK_MSG_ID_MISSION_ITEM_REACHED, *POSES)
STATUSTEXT = mavlink.MAVLINK_MSG_ID_STATUSTEXT
DISTANCE_SENSOR = mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR
ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
TRAIL_SAMPLES = 1500
RECENT_TEXTS = 20
RECENT_READINGS = 600
RECENT_STATUSES = 10  # the onboard agent's, per component: the latest that decodes among them is shown


RELEASE_EVERY = 16 << 20  # bytes of a log scanned before they are unmapped: a gigabyte is not a gigabyte resident
DONTNEED = getattr(mmap, "MADV_DONTNEED", None)  # not on Windows: there the pages stay mapped until the scan ends


class ReplayError(ValueError):
    """The file is not a telemetry log."""


@dataclass
class TlogIndex:
    """Where every record of a tlog is, without decoding it."""

    path: Path
    offsets: np.ndarray  # of each packet (after its timestamp)
    lengths: np.ndarray
    times: np.ndarray  # seconds since the Unix epoch
    sysids: np.ndarray
    compids: np.ndarray
    msgids: np.ndarray
    tunnel_types: np.ndarray  # TUNNEL payload type, -1 for other messages
    warning: str = ""

    @property
    def start(self) -> float:
        return float(self.times[0])

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    def __len__(self) -> int:
        return len(self.offsets)


def index_tlog(path: str | Path, columns: bool = True) -> TlogIndex:
    """Index a .tlog; a damaged or truncated tail is left out with a warning, a non-log is a ReplayError.
    ``columns=False``: the span only (``times`` holds the first and the last record's), read the same way in
    a few megabytes; the whole index of a big log takes some 2.5 times its size."""
    path = Path(path)
    with open(path, "rb") as handle:
        size = handle.seek(0, 2)
        if size < 8 + 8:
            raise ReplayError(f"{path.name} is not a telemetry log (too short)")
        data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _scan(path, data, size, columns)
    finally:
        data.close()


def _scan(path: Path, data, size: int, columns: bool) -> TlogIndex:
    offsets, lengths, times, sysids, compids, msgids, tunnels = [], [], [], [], [], [], []
    position = count = released = 0
    first = last = 0.0
    warning = ""
    unpack_time = struct.Struct(">Q").unpack_from
    while position + 8 < size:
        if position - released > RELEASE_EVERY and DONTNEED is not None:  # pages read leave the process
            data.madvise(DONTNEED, released, RELEASE_EVERY)  # (the page cache keeps them)
            released += RELEASE_EVERY
        stamp = unpack_time(data, position)[0] / 1e6
        start = position + 8
        magic = data[start]
        if magic == V2 and start + 10 <= size:
            length = 12 + data[start + 1] + (13 if data[start + 2] & SIGNED else 0)
            msgid = data[start + 7] | data[start + 8] << 8 | data[start + 9] << 16
            sysid, compid = data[start + 5], data[start + 6]
            body = start + 10
        elif magic == V1 and start + 6 <= size:
            length = 8 + data[start + 1]
            msgid = data[start + 5]
            sysid, compid = data[start + 3], data[start + 4]
            body = start + 6
        else:
            warning = _damage(path, position, count)
            break
        if not EARLIEST < stamp < LATEST or (count and stamp + 3600 < last):
            warning = _damage(path, position, count)
            break
        if start + length > size:
            warning = f"{path.name} is truncated: the last record is cut off at byte {position}; replaying up to it"
            break
        if not count:
            first = stamp
        count += 1
        last = stamp
        if columns:
            offsets.append(start)
            lengths.append(length)
            times.append(stamp)
            sysids.append(sysid)
            compids.append(compid)
            msgids.append(msgid)
            tunnels.append(data[body] | data[body + 1] << 8 if msgid == TUNNEL and length >= 14 else -1)
        position = start + length
    if not warning and position < size and count:
        warning = f"{path.name} is truncated: the last record is cut off at byte {position}; replaying up to it"
    if not count:
        raise ReplayError(f"{path.name} is not a telemetry log (no MAVLink record at its start)")
    return TlogIndex(path, np.array(offsets, dtype=np.int64), np.array(lengths, dtype=np.int32),
                     np.array(times if columns else [first, last]), np.array(sysids, dtype=np.int32),
                     np.array(compids, dtype=np.int32), np.array(msgids, dtype=np.int32),
                     np.array(tunnels, dtype=np.int32), warning)


def _damage(path: Path, position: int, records: int) -> str:
    if records == 0:
        raise ReplayError(f"{path.name} is not a telemetry log (no MAVLink record at its start)")
    return f"{path.name} is damaged at byte {position}; replaying the {records} records before it"


@dataclass
class Replay:
    """Plays a recording into its own Fleet: seek, play, pause, step, speed."""

    index: TlogIndex
    fleet: Fleet
    name: str = ""
    speed: float = 1.0
    playing: bool = False
    scene: dict | None = None  # the scene it is shown in and how it was found (``replay_scene``)
    position: int = 0  # index of the next record to apply
    clock: float = 0.0  # seconds from the start of the log
    seeks: int = 0  # seeks so far: the player does not count a seek's own time as played
    errors: int = 0  # records that raised when applied (each time one was), passed over
    last_error: str = ""
    _data: bytes = field(default=b"", repr=False)
    _vehicles_made_at: dict[int, int] | None = field(default=None, repr=False)  # sysid -> its first vehicle beat
    lock: threading.RLock = field(default_factory=threading.RLock, repr=False)

    @classmethod
    def open(cls, path: str | Path, fleet: Fleet) -> Replay:
        index = index_tlog(path)
        fleet.forget_after = None  # a vehicle silent for a while in the log is still the log's
        replay = cls(index, fleet, Path(path).name)
        replay._data = Path(path).read_bytes()
        replay._decoder = mavlink.MAVLink(None)
        replay._decoder.robust_parsing = True
        replay.seek(replay.first_vehicle_at())
        return replay

    def first_vehicle_at(self) -> float:
        """Seconds into the log of the first heartbeat that makes a vehicle (0 if none does): a replay opens
        there, so a page that asks after the vehicle it saw live finds it at once, not a 404 while the log's
        first records (the station's own, a text) play."""
        made = self._vehicles_made()
        if not made:
            return 0.0
        return max(float(self.index.times[min(made.values())]) - self.index.start, 0.0)

    @property
    def duration(self) -> float:
        return self.index.duration

    def status(self) -> dict:
        """Read without the lock, which a seek holds for a while: the event loop asks for it."""
        return {"name": self.name, "time": round(self.clock, 3), "duration": round(self.duration, 3),
                "playing": self.playing, "speed": self.speed, "warning": self.index.warning or None,
                "scene": self.scene, "errors": self.errors, "last_error": self.last_error or None}

    @property
    def now(self) -> float:
        """The log's own clock (Unix seconds) at the current replay time, for link ages and the like."""
        return self.index.start + self.clock

    # ---- decoding ---------------------------------------------------------------------------------
    def decode(self, i: int, decoder=None):
        """The message of record ``i`` (None if it does not decode), by the replay's decoder or ``decoder``."""
        start = int(self.index.offsets[i])
        packet = self._data[start:start + int(self.index.lengths[i])]
        try:
            message = (decoder or self._decoder).decode(bytearray(packet))
        except Exception:  # noqa: BLE001 - pymavlink raises many kinds on a damaged packet
            return None
        return message

    def message(self, i: int, decoder):
        """Record ``i`` decoded by ``decoder`` (another thread's: a pymavlink decoder keeps state, so the
        player's is not shared), None if it is damaged."""
        return self.decode(i, decoder)

    @staticmethod
    def decoder():
        """A decoder of its own for a thread that reads the log besides the player."""
        decoder = mavlink.MAVLink(None)
        decoder.robust_parsing = True
        return decoder

    def chunk_header(self, i: int) -> tuple[int, int, int]:
        """Snapshot id, chunk index and chunk count of a map snapshot chunk (record ``i``), undecoded."""
        return self._chunk_header(i)

    def sensor_id(self, i: int) -> int:
        """The sensor id of a DISTANCE_SENSOR record, undecoded (its 12th payload byte)."""
        return self._payload(i, 12)[11]

    def _payload(self, i: int, size: int) -> bytes:
        """The first ``size`` bytes of record ``i``'s payload, undecoded. MAVLink 2 drops a payload's trailing
        zero bytes (the packet's length byte says how many are left): the missing ones are zeros, not the
        checksum after the payload."""
        start = int(self.index.offsets[i])
        body = start + (10 if self._data[start] == V2 else 6)
        return self._data[body:body + min(self._data[start + 1], size)].ljust(size, b"\0")

    def _apply(self, indices, off_trail: set[int] | frozenset = frozenset()) -> None:
        for i in indices:
            message = self.decode(int(i))
            if message is None:
                continue
            try:
                if i in off_trail:
                    self._apply_off_trail(message, float(self.index.times[i]))
                else:
                    self.fleet.apply(message, float(self.index.times[i]))
            except Exception as error:  # noqa: BLE001 - one bad record must not stop the replay; counted, shown
                self.failed(error, f"{message.get_type()} at {self.index.times[i] - self.index.start:.3f} s")

    def failed(self, error: BaseException, where: str) -> None:
        """Count a failure and keep it for the status, as the live link does for /api/health."""
        self.errors += 1
        self.last_error = f"{type(error).__name__}: {error} ({where})"[:200]
        log.warning("replay: %s", self.last_error)

    def _apply_off_trail(self, message, now: float) -> None:
        """A pose applied only to place the sonar readings after it: its point is left off the trail, which a
        seek draws from an even sample of the poses."""
        vehicle = self.fleet.get(message.get_srcSystem())
        points = len(vehicle.trail) if vehicle is not None else 0
        self.fleet.apply(message, now)
        if vehicle is not None and len(vehicle.trail) > points:
            vehicle.trail.pop()

    # ---- seeking ----------------------------------------------------------------------------------
    def seek(self, seconds: float) -> None:
        """Rebuild the fleet as it was ``seconds`` into the log."""
        with self.lock:
            seconds = min(max(seconds, 0.0), self.duration)
            end = int(np.searchsorted(self.index.times, self.index.start + seconds, side="right"))
            with self.fleet.lock:
                self.fleet.clear()
                needed, latest, off_trail = self._needed(end)
                self._apply(needed, set(off_trail.tolist()))
                for sysid, i in latest.items():  # the records applied end with a pose or a text, not the last
                    vehicle = self.fleet.get(sysid)
                    if vehicle is not None:
                        vehicle.last_message = float(self.index.times[i])
            self.position = end
            self.clock = seconds
            self.seeks += 1

    def _needed(self, end: int) -> tuple[np.ndarray, dict[int, int], np.ndarray]:
        """Indices of the records before ``end`` that rebuild the state at ``end``, each vehicle's last
        record before ``end`` (when it was last heard), and the poses among them to keep off the trail.

        The first heartbeat of each component comes first (the autopilot's creates
        the vehicle), then its map from the last whole snapshot on (so the
        readings that follow draw hits, not a map of the ground station's own)
        and its planned path from the last whole one on, then the rest in time
        order: each sonar reading after the latest attitude and the latest pose
        (of each kind) before it, so that its hit lands where it did (a pose
        there only for that stays off the trail, which is an even sample), and
        last every batch of the agent's radio link records (``fleet.radio``
        holds them all, as when playing; by then the vehicle's home is known).
        Status messages count per component: a vehicle's autopilot and its
        companion computer each have a latest one; of the agent's statuses the
        last few are applied, so that a damaged latest one leaves the one before
        it, as when playing. What a system sent before the heartbeat that made
        it a vehicle is left out: playing drops it.
        """
        index = self.index
        msgids, sysids, compids = index.msgids[:end], index.sysids[:end], index.compids[:end]
        firsts: list[np.ndarray] = []
        maps: list[np.ndarray] = []
        rest: list[np.ndarray] = []
        latest: dict[int, int] = {}
        placing: list[np.ndarray] = []
        radio: list[np.ndarray] = []  # every link record batch, applied last (its vehicle's home known by then)
        made = self._vehicles_made()
        for sysid in np.unique(sysids):
            mine = sysids == sysid
            latest[int(sysid)] = int(np.flatnonzero(mine)[-1])
            if (made_at := made.get(int(sysid))) is not None:
                mine[:made_at] = False  # not yet a vehicle: the fleet drops what it sent
            for compid in np.unique(compids[mine]):
                theirs = mine & (compids == compid)
                firsts.append(np.flatnonzero(theirs & (msgids == HEARTBEAT))[:1])
                for msgid in LATEST_ONLY:
                    rest.append(np.flatnonzero(theirs & (msgids == msgid))[-1:])
                statuses = np.flatnonzero(theirs & (msgids == TUNNEL))
                rest.append(statuses[index.tunnel_types[statuses] == AGENT_STATUS][-RECENT_STATUSES:])
            autopilot = mine & (compids == AUTOPILOT)  # its pose is its autopilot's (the fleet takes no other)
            poses = np.flatnonzero(autopilot & np.isin(msgids, POSES))
            if len(poses):
                rest.append(poses[np.linspace(0, len(poses) - 1, min(len(poses), TRAIL_SAMPLES)).astype(int)])
            rest.append(np.flatnonzero(mine & (msgids == STATUSTEXT))[-RECENT_TEXTS:])
            tunnels = np.flatnonzero(mine & (msgids == TUNNEL) & (index.tunnel_types[:end] != AGENT_STATUS)
                                     & (index.tunnel_types[:end] != RADIO_LINKS))
            radio.append(np.flatnonzero(mine & (msgids == TUNNEL) & (index.tunnel_types[:end] == RADIO_LINKS)))
            snapshot_chunks = tunnels[index.tunnel_types[tunnels] == MAP_SNAPSHOT]
            path_chunks = tunnels[index.tunnel_types[tunnels] == PATH]
            readings = np.flatnonzero(mine & (msgids == DISTANCE_SENSOR))
            if len(path_chunks):
                maps.append(path_chunks[path_chunks >= self._whole_start(path_chunks, PATH_CHUNK)])
            if len(snapshot_chunks):
                maps.append(tunnels[tunnels >= self._whole_start(snapshot_chunks, SNAPSHOT_CHUNK)])
                readings = readings[-RECENT_READINGS:]  # (with none, the station maps every reading)
            attitudes = np.flatnonzero(autopilot & (msgids == ATTITUDE))
            before = np.searchsorted(attitudes, readings) - 1  # the latest attitude before each reading
            rest.append(attitudes[before[before >= 0]])
            for msgid in POSES:  # and the latest pose of each kind, which the trail's sample may have left out
                of_kind = poses[msgids[poses] == msgid]
                before = np.searchsorted(of_kind, readings) - 1
                placing.append(of_kind[before[before >= 0]])
            rest.append(readings)
        none = np.zeros(0, dtype=np.int64)
        if not firsts:
            return none, latest, none
        first = np.unique(np.concatenate(firsts))
        off_trail = np.setdiff1d(np.concatenate(placing + [none]), np.concatenate(rest))
        return np.concatenate([first, np.unique(np.concatenate(maps + [none])),
                               np.setdiff1d(np.concatenate(rest + [off_trail]), first),
                               np.sort(np.concatenate(radio + [none]))]), latest, off_trail

    def _vehicles_made(self) -> dict[int, int]:
        """Per system id, the record of the heartbeat that makes it a vehicle in the fleet (the first that says
        a vehicle, by its raw type and autopilot bytes, and decodes); found once for the whole log."""
        if self._vehicles_made_at is None:
            index = self.index
            heartbeats = np.flatnonzero(index.msgids == HEARTBEAT)
            made: dict[int, int] = {}
            for i in heartbeats.tolist():
                sysid = int(index.sysids[i])
                if sysid not in made and makes_a_vehicle(*self._heartbeat_kind(i), int(index.compids[i])):
                    message = self.decode(i)
                    if message is not None and message.get_type() == "HEARTBEAT":
                        made[sysid] = i
            self._vehicles_made_at = made
        return self._vehicles_made_at

    def _heartbeat_kind(self, i: int) -> tuple[int, int]:
        """The type and autopilot of a HEARTBEAT record, undecoded (its 5th and 6th payload bytes)."""
        payload = self._payload(i, 6)
        return payload[4], payload[5]

    def _whole_start(self, chunks: np.ndarray, header: struct.Struct) -> int:
        """Record index where the last complete one among ``chunks`` (of map snapshots, or of paths, as
        ``header`` says) began (its first chunk); the first chunk's if none is complete.

        A snapshot cut off by the seek time, or one that lost a chunk on the way,
        cannot be applied; the deltas after an earlier whole one bring the map up
        to date just the same. A path that lost a chunk leaves the one before.
        """
        seen: dict[int, set[int]] = {}
        for i in chunks[::-1]:  # from the latest back: the first whole one found is the one
            ident, number, count = self._chunk_header(int(i), header)
            numbers = seen.setdefault(ident, set())
            numbers.add(number)
            if number == 0:
                if len(numbers) == count:
                    return int(i)
                del seen[ident]  # an incomplete one: its id may come round again earlier
        return int(chunks[0])

    def _chunk_header(self, i: int, header: struct.Struct = SNAPSHOT_CHUNK) -> tuple[int, int, int]:
        """Id, chunk index and chunk count inside a MAP_SNAPSHOT (or, by ``header``, PATH) TUNNEL record, from
        the raw packet."""
        # TUNNEL on the wire: payload_type u16, target system, target component, payload length, payload; the
        # chunk header opens the payload
        return header.unpack_from(self._payload(i, 5 + header.size), 5)

    # ---- playing ----------------------------------------------------------------------------------
    def advance(self, seconds: float) -> None:
        """Play forward by ``seconds`` of log time, message by message."""
        with self.lock:
            target = min(self.clock + seconds, self.duration)
            end = int(np.searchsorted(self.index.times, self.index.start + target, side="right"))
            with self.fleet.lock:
                self._apply(range(self.position, end))
            self.position = end
            self.clock = target
            if self.clock >= self.duration:
                self.playing = False

    def control(self, play: bool | None = None, speed: float | None = None, seek: float | None = None,
                step: int | None = None) -> dict:
        """Apply an operator's control at once, under the lock, and answer the status it left: a player's tick
        comes wholly before or wholly after it, so a pause answers the time it stays at."""
        with self.lock:
            if speed is not None:
                self.speed = speed
            if play is False or step is not None:  # before a seek or step: no tick moves on from where it lands
                self.playing = False
            if seek is not None:
                self.seek(seek)
            if step is not None:
                self.step(step)
            if play:
                if self.clock >= self.duration:
                    self.seek(0.0)
                self.playing = True
            return self.status()

    def step(self, direction: int) -> None:
        """One step of 1/10 s of log time forward (or back)."""
        if direction >= 0:
            self.advance(0.1)
        else:
            self.seek(self.clock - 0.1)


class Player:
    """Runs a Replay in real time times its speed, on its own thread.

    Only time the replay spends playing counts: the tick after a seek starts
    from the seek's end, so a seek that took a while does not jump on by it.
    ``clock`` is the wall clock (``time.monotonic``); a test steps its own.
    """

    TICK = 0.05

    def __init__(self, replay: Replay, clock: Callable[[], float] = time.monotonic):
        self.replay = replay
        self._clock = clock
        self._last = clock()
        self._seeks = replay.seeks
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)

    def start(self) -> Player:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)

    def _run(self) -> None:
        while not self._stop.wait(self.TICK):
            try:
                self.tick()
            except Exception as error:  # noqa: BLE001 - the thread must not die while the status says playing
                self.replay.playing = False  # (a tick that failed would fail again): paused, and the status says why
                self.replay.failed(error, "playing")

    def tick(self) -> None:
        """Play on by the time since the last tick (or since the last seek, if one came between)."""
        replay = self.replay
        with replay.lock:  # read under the lock: a pause and seek leaves nothing to come, a seek's time is its own
            now = self._clock()
            if replay.playing and replay.seeks == self._seeks:
                replay.advance((now - self._last) * replay.speed)
            self._last, self._seeks = now, replay.seeks
