"""A headless run recorded as a telemetry log: what ``vehicle sim`` would have sent, on simulated time.

The log carries the autopilot's messages (component 1) and the agent's
(component 191: its heartbeat, map, path, state and messages), stamped with
simulated time counted from ``LOG_EPOCH``, so the same run always writes the
same file and ``groundstation replay`` plays it like a live recording.

A run goes about a thousand times faster than real time and its log holds a
hundred messages a simulated second, so a log made message by message with
pymavlink would cost the run several times over. So the run only takes
note, and a writer process (forked, on the other core) makes the messages:

- the run keeps positions, attitude, VFR_HUD (20 and 4 Hz) and the readings
  as numbers, the rarer messages (heartbeats, status, events, the agent's;
  from the same ``Telemetry`` and ``Companion`` as a live vehicle's, asked
  only when something is due) as payloads, and the map cells that changed;
- the writer keeps a copy of the map from those changes and streams it with
  the same ``MapStreamer`` (deltas every 0.5 s as live; snapshots every
  ``SNAPSHOT_PERIOD`` of simulated time or less often for a big map, rather
  than 5 s, compressed with zlib's run-length strategy: a log is read from a
  disk, not joined late over a radio link, and that is a tenth of the
  default level's time for the same decoded map), makes the other payloads
  from the numbers with the encoders ``Telemetry`` itself uses (one row at
  a time live, thousands at once here: ``telemetry.poses``, ``telemetry.huds``,
  ``rangefinder.distance_sensors``), and
  frames every message (MAVLink 2 header, sequence number, CRC) in one
  compiled loop: no library frames many messages at once, and pymavlink's
  framing is most of its cost.

Where no process can be forked, the same writer works in the run's process.
A log that cannot be written (not opened, the disk full) does not stop the run:
its steps go nowhere from then on, and ``close`` raises ``LogError``.
The log names the run's scene as a station's recording does
(``vehicle.protocol.scene_note``), at its start and every simulated minute.
"""

from __future__ import annotations

import math
import multiprocessing
import queue
import signal
import struct
import threading
import zlib
from array import array
from pathlib import Path

import numba
import numpy as np

from vehicle.agent.companion import Companion
from vehicle.lab.stepper import Stepper
from vehicle.protocol import agent_status
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mapstream import MapStreamer, snapshot_chunks
from vehicle.protocol.mav import AUTOPILOT, COMPANION, mavlink
from vehicle.protocol.rangefinder import DISTANCE_SENSOR_WIRE, Reading, distance_sensors
from vehicle.protocol.scene_note import SceneNotes, note_text
from vehicle.protocol.tlog import LOG_EPOCH, TlogWriter
from vehicle.sim.telemetry import GLOBAL_POSITION_WIRE, LOCAL_POSITION_WIRE, VFR_HUD_WIRE, Telemetry, huds, poses

COMPONENTS = (AUTOPILOT, COMPANION)  # each has its own sequence numbers
SNAPSHOT_PERIOD = 10.0  # s of simulated time between map snapshots, at least
SNAPSHOT_BUDGET = 15000.0  # bytes of map part compressed per simulated second, at most (a bigger map: less often)
BATCH_STEPS = 100  # steps noted before they go to the writer
_STAMP = struct.Struct(">Q")  # a tlog record's timestamp

_GLOBAL_POSITION = mavlink.MAVLink_global_position_int_message
_LOCAL_POSITION = mavlink.MAVLink_local_position_ned_message
_ATTITUDE = mavlink.MAVLink_attitude_message
_DISTANCE_SENSOR = mavlink.MAVLink_distance_sensor_message
_TUNNEL = mavlink.MAVLink_tunnel_message
_VFR_HUD = mavlink.MAVLink_vfr_hud_message
POSES = (_GLOBAL_POSITION, _LOCAL_POSITION, _ATTITUDE)  # sent together, each with Telemetry's values
POSE_FIELDS = 12  # key, time, x, y, z, yaw, pitch, roll, vx, vy, vz, yaw rate
HUD_FIELDS = 7  # key, time, speed, yaw, z, vz, flying
RANGE_FIELDS = 9  # key, time, sensor, distance (NaN: none), yaw offset, pitch, max and min range, beam angle
# the encoders' payloads are framed here as they are: their layouts must be pymavlink's
assert _GLOBAL_POSITION.unpacker.format == "<IiiiihhhH" and GLOBAL_POSITION_WIRE.itemsize == 28
assert _LOCAL_POSITION.unpacker.format == _ATTITUDE.unpacker.format == "<Iffffff" and LOCAL_POSITION_WIRE.itemsize == 28
assert _VFR_HUD.unpacker.format == "<ffffhH" and VFR_HUD_WIRE.itemsize == 20
assert _DISTANCE_SENSOR.unpacker.format == "<IHHHBBBBff4fB" and DISTANCE_SENSOR_WIRE.itemsize == 39
_TUNNEL_HEAD = struct.Struct("<HBBB")  # payload_type, target system and component, payload_length
assert _TUNNEL.unpacker.format == "<HBBB128B"


class LogError(OSError):
    """A log not (wholly) written, said as a command line says it: "log run.tlog: No space left on device"."""

    def __str__(self) -> str:
        where = f"{self.filename2}: " if self.filename2 else ""  # a folder the log's could not be made in
        return f"log {self.filename}: {where}{self.strerror}"


class ExperimentLog:
    """Pass it as ``on_step`` to ``run_experiment``; ``close`` writes the final state."""

    def __init__(self, path: str | Path, sysid: int = 1, scene: str | Path | None = None):
        """``scene``: the scene file the run flies in, named in the log."""
        self.path = Path(path)
        self._lost = False  # the writer failed (or never opened): steps are noted no more
        self._writer: _Forked | _Writer | _Unopened | None = None
        try:
            self.file: TlogWriter | None = TlogWriter(path)
        except OSError as error:  # the run goes on all the same: its result matters more than its log
            self.file, self._writer, self._lost = None, _Unopened(error), True
        text = note_text(scene) if scene else None
        self._notes = SceneNotes(text) if text else None
        self.sysid = sysid
        self.telemetry: Telemetry | None = None
        self.companion: Companion | None = None
        self.time = 0.0
        self.messages = 0
        self._batch = _Batch()
        self._pose_due = self._hud_due = self._telemetry_due = self._agent_due = self._delta_due = 0.0
        self._pose_interval = self._hud_interval = self._delta_period = 0.0
        self._agent_status: agent_status.AgentStatus | None = None  # the last the companion was asked about
        self._steps = 0

    def _start(self, stepper: Stepper) -> None:
        simulation = self.simulation = stepper.simulation
        self.telemetry = Telemetry(simulation, start=0.0, sysid=self.sysid)
        intervals = self.telemetry.intervals
        self._pose_interval, self._hud_interval = intervals[_GLOBAL_POSITION.id], intervals[_VFR_HUD.id]
        for message in (*POSES, _VFR_HUD):  # on the same schedules, noted here as numbers
            assert intervals[message.id] == (self._hud_interval if message is _VFR_HUD else self._pose_interval)
            self.telemetry.set_interval(message.id, 0)
        geometry = None
        if stepper.agent is not None:
            companion = self.companion = _LogCompanion(stepper.agent, self.sysid, start=0.0)
            self._delta_period = companion.streamer.delta_period
            companion.streamer = _PathsOnly(companion.streamer)  # the writer streams the map
            memory = stepper.agent.map
            geometry = (memory.size, memory.resolution, memory.origin, companion.agent.ctx.home)
        _frame_nothing()  # loads the compiled framing once, not in every writer forked from here
        if self._writer is None:  # (else the log could not be opened)
            setup = (self.file, self.sysid, simulation.home, simulation.datum, geometry)
            self._writer = _Forked(setup) if "fork" in multiprocessing.get_all_start_methods() else _Writer(*setup)

    def __call__(self, stepper: Stepper, readings: list[Reading]) -> None:
        if self._lost:
            return  # the log could not be written: the rest of the run goes unnoted
        if self.telemetry is None:
            self._start(stepper)
        simulation = self.simulation
        now = self.time = simulation.time
        stamp = int((LOG_EPOCH + now) * 1e6)
        if self._notes is not None and now >= self._notes.due:
            self._note(now, stamp)
        batch = self._batch
        if now >= self._telemetry_due or simulation.autopilot.events:
            self._add(self.telemetry.tick(now), stamp, 0)
            self._telemetry_due = self.telemetry.next_due()
        if now >= self._pose_due:  # Telemetry's rule for a periodic message
            self._pose_due = max(self._pose_due + self._pose_interval, now)
            body = simulation.body
            pose = body.pose
            batch.poses.extend((batch.key, now, pose.x, pose.y, pose.z, pose.yaw, pose.pitch, pose.roll,
                                body.vx, body.vy, body.vz, body.yaw_rate))
            batch.key += len(POSES)
        if now >= self._hud_due:
            self._hud_due = max(self._hud_due + self._hud_interval, now)
            body = simulation.body
            batch.huds.extend((batch.key, now, math.hypot(body.vx, body.vy), body.pose.yaw, body.pose.z, body.vz,
                               simulation.autopilot.flying))
            batch.key += 1
        for reading in readings:
            batch.ranges.extend((batch.key, now, reading.sensor, math.nan if reading.distance is None else
                                 reading.distance, reading.yaw_offset, reading.pitch, reading.max_range,
                                 reading.min_range, reading.beam_angle))
            batch.key += 1
        companion = self.companion
        if companion is not None:
            if now >= self._agent_due or companion.agent.outbox or (  # only its clock and the agent's news
                    stepper.monitor_due and companion.status() != self._agent_status):
                self._add(companion.tick(now), stamp, 1)
                self._agent_due, self._agent_status = companion.next_due(), companion.status()
            if now >= self._delta_due:  # the map stream's schedule
                self._delta_due = now + self._delta_period
                self._map(stamp, now)
        self._steps += 1
        if self._steps % BATCH_STEPS == 0:
            self._send()

    def _add(self, messages: list, stamp: int, component: int) -> None:
        """Messages (pymavlink's, or the agent's TUNNEL payloads as they are) join the batch as payloads."""
        for message in messages:
            if isinstance(message, tuple):
                kind, payload = message
                self._batch.add(stamp, component, _TUNNEL, _TUNNEL_HEAD.pack(kind, 0, 0, len(payload)) + payload)
            else:
                self._batch.add(stamp, component, type(message), _payload(message))

    def _note(self, now: float, stamp: int) -> None:
        """The scene's note where it falls in the log: after all noted so far (sent on), before what follows."""
        self._send()
        self._batch.notes = [_STAMP.pack(stamp) + packet for packet in self._notes.take(now)]

    def _map(self, stamp: int, now: float, final: bool = False) -> None:
        """The cells changed since the last time and their values: the writer's copy of the map takes them and
        streams them (deltas, and a snapshot when one is due; ``final``: the last word, a snapshot)."""
        memory = self.companion.agent.map
        touched = memory.take_changes(in_order=False)  # the writer sorts them
        self._batch.map_updates.append((self._batch.key, stamp, now, touched, memory.grid.reshape(-1)[touched],
                                        final))
        self._batch.key += 1

    def _send(self) -> None:
        batch, self._batch = self._batch, _Batch(self._batch.key)
        if self._writer.error is None:  # a writer that failed takes no more: the run goes on, unlogged
            self._writer.write(batch)
        else:
            self._lost = True

    @property
    def error(self) -> LogError | None:
        """Why the log is not (wholly) written: it could not be opened, or a write failed (None: all is well)."""
        error = getattr(self._writer, "error", None)
        if error is None:
            return None
        elsewhere = error.filename if error.filename is not None and Path(error.filename) != self.path else None
        return LogError(error.errno, error.strerror or str(error), str(self.path), None, elsewhere)

    def close(self) -> None:
        """Finish with heartbeats and a full map snapshot, so the log ends on the final state. Raises
        ``LogError`` if the log could not be written (the run's result stands: the caller says both)."""
        if self._writer is None:  # the run ended before its first step: an empty log
            self.file.close()
            return
        if self.telemetry is not None:  # (else it ended before its first step, the log unopened)
            self._finish()
        self.messages = self._writer.close()
        if (error := self.error) is not None:
            raise error

    def _finish(self) -> None:
        telemetry, now = self.telemetry, self.time
        stamp = int((LOG_EPOCH + now) * 1e6)
        self._add([telemetry.heartbeat(now), telemetry.global_position(now)] + telemetry.events(now), stamp, 0)
        companion = self.companion
        if companion is not None:  # Companion.final, with the map from the writer
            status = companion.tunnel(agent_status.AGENT_STATUS, agent_status.encode(companion.status()))
            self._add([companion.heartbeat(), *companion.texts(), status], stamp, 1)
            self._map(stamp, now, final=True)
        self._send()


class _LogCompanion(Companion):
    """The agent's messages with its TUNNEL payloads left as (type, payload): the log frames them itself."""

    def tunnel(self, kind: int, payload: bytes) -> tuple[int, bytes]:
        return kind, payload


class _PathsOnly:
    """Stands in for the companion's map streamer in a log: its paths as before, no map (the writer streams it)."""

    def __init__(self, streamer: MapStreamer):
        self.path = streamer.path

    def tick(self, now: float) -> list:
        return []

    def next_due(self) -> float:
        return math.inf


class _Batch:
    """What a few steps noted, each with its place in the log (``key``): messages as payloads, the poses as
    numbers, the map as the cells that changed."""

    def __init__(self, key: int = 0):
        self.key = key  # the next message's place in the log
        self.rows: list[tuple] = []  # (key, stamp, component, message id, CRC extra, payload)
        self.poses = array("d")  # POSE_FIELDS a pose (its key the first of POSES'), end to end
        self.huds = array("d")  # HUD_FIELDS a VFR_HUD
        self.ranges = array("d")  # RANGE_FIELDS a DISTANCE_SENSOR
        self.map_updates: list[tuple] = []  # (key, stamp, time, cells, their values, final or not)
        self.notes: list[bytes] = []  # log records made already (the scene's note), written before the rest

    def add(self, stamp: int, component: int, message, payload: bytes) -> None:
        self.rows.append((self.key, stamp, component, message.id, message.crc_extra, payload))
        self.key += 1


class _Writer:
    """Turns batches into log records: the map stream from its own copy of the map, then every message framed
    in the order the run sent them."""

    def __init__(self, file: TlogWriter, sysid: int, home: tuple[float, float, float], datum: Datum,
                 geometry: tuple | None):
        self.file = file
        self.sysid = sysid
        self.home = home
        self.datum = datum
        self.seqs = np.zeros(len(COMPONENTS), dtype=np.int64)  # the next sequence number of each component
        self.messages = 0
        self.error: OSError | None = None  # the first write that failed: nothing is written after it
        self.map = _MapCopy(*geometry[:3]) if geometry else None
        self.streamer = MapStreamer(self.map, geometry[3]) if geometry else None
        self.next_snapshot = 0.0  # one at the start, as a live vehicle's

    def write(self, batch: _Batch) -> None:
        if batch.notes:
            self._put(b"".join(batch.notes), len(batch.notes))
        rows = batch.rows
        for key, stamp, now, cells, values, final in batch.map_updates:
            payloads = self._map(now, cells, values, final or now >= self.next_snapshot)
            step = 1.0 / max(len(payloads), 1)  # they share the update's place, in their order
            rows += [(key + i * step, stamp, 1, _TUNNEL.id, _TUNNEL.crc_extra,
                      _TUNNEL_HEAD.pack(kind, 0, 0, len(payload)) + payload)
                     for i, (kind, payload) in enumerate(payloads)]
        keys, stamps, components, ids, extras, payloads = zip(*rows, strict=True) if rows else ((),) * 6
        columns = [[keys], [stamps], [components], [ids], [extras]]
        lengths = [np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))]
        data = [np.frombuffer(b"".join(payloads), dtype=np.uint8)]
        poses = np.frombuffer(batch.poses).reshape(-1, POSE_FIELDS)
        huds = np.frombuffer(batch.huds).reshape(-1, HUD_FIELDS)
        ranges = np.frombuffer(batch.ranges).reshape(-1, RANGE_FIELDS)
        for numbers, messages, payloads_of in ((poses, POSES, self._poses), (huds, (_VFR_HUD,), self._huds),
                                               (ranges, (_DISTANCE_SENSOR,), self._ranges)):
            count = len(numbers)
            if not count:  # a batch cut short (before a scene note) may have none
                continue
            blocks = payloads_of(numbers)
            stamps_us = ((LOG_EPOCH + numbers[:, 1]) * 1e6).astype(np.int64)  # int(), as for every record
            for index, (message, block) in enumerate(zip(messages, blocks, strict=True)):
                for column, values in zip(columns, (numbers[:, 0] + index, stamps_us, 0, message.id,
                                                    message.crc_extra), strict=True):
                    column.append(np.full(count, values) if np.isscalar(values) else values)
                lengths.append(np.full(count, block.shape[1]))
                data.append(block.reshape(-1))
        keys = np.concatenate(columns[0]).astype(np.float64)  # a map update's payloads: fractions of its key
        stamps, components, ids, extras = (np.concatenate(column).astype(np.int64) for column in columns[1:])
        if len(keys):
            lengths = np.concatenate(lengths)
            self._put(_frame(np.concatenate(data), np.cumsum(lengths) - lengths, lengths,
                             np.argsort(keys, kind="stable"), stamps, ids, extras, components, self.seqs,
                             self.sysid, np.array(COMPONENTS)).tobytes(), len(keys))

    def _put(self, records: bytes, count: int) -> None:
        """Records into the file; a failed write is the log's error, not the run's (it goes on without)."""
        if self.error is not None:  # (the rest of a batch after the failure)
            return
        try:
            self.file.write_records(records)
        except OSError as error:
            self.error = error
        else:
            self.messages += count

    def _map(self, now: float, cells: np.ndarray, values: np.ndarray, snapshot: bool) -> list[tuple[int, bytes]]:
        self.map.update(cells, values)
        out = self.streamer.deltas()
        if snapshot:
            ident, head, part = self.streamer.snapshot_parts()
            self.next_snapshot = now + max(SNAPSHOT_PERIOD, len(part) / SNAPSHOT_BUDGET)
            packer = zlib.compressobj(6, zlib.DEFLATED, 15, 8, zlib.Z_RLE)
            out += snapshot_chunks(ident, head + packer.compress(part) + packer.flush())
        return out

    def _poses(self, rows: np.ndarray) -> list[np.ndarray]:
        """GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE payloads (rows of bytes), by Telemetry's encoder."""
        return [_bytes(block) for block in poses(self.datum, self.home, rows[:, 1:])]

    def _huds(self, rows: np.ndarray) -> list[np.ndarray]:
        """VFR_HUD payloads, by Telemetry's encoder."""
        return [_bytes(huds(self.datum, self.home, rows[:, 2:]))]

    def _ranges(self, rows: np.ndarray) -> list[np.ndarray]:
        """DISTANCE_SENSOR payloads, by the rangefinder's encoder (time in ms, as the live vehicle's)."""
        readings = rows[:, 1:].copy()
        readings[:, 0] = np.trunc(readings[:, 0] * 1000)
        return [_bytes(distance_sensors(readings))]

    def close(self) -> int:
        try:
            self.file.close()  # flushes what is buffered: that can fail too
        except OSError as error:
            self.error = self.error or error
        return self.messages


class _Unopened:
    """Stands in for the writer of a log that could not be opened: it takes nothing, and says why."""

    messages = 0

    def __init__(self, error: OSError):
        self.error = error

    def close(self) -> int:
        return 0


class _MapCopy:
    """The writer's copy of the agent's map, as much of a ``MemoryMap`` as ``MapStreamer`` reads."""

    def __init__(self, size: int, resolution: float, origin: tuple[float, float]):
        self.size, self.resolution, self.origin = size, resolution, origin
        self.grid = np.zeros((size, size), dtype=np.int8)
        self._changed = np.zeros(0, dtype=np.int64)

    def update(self, cells: np.ndarray, values: np.ndarray) -> None:
        """Cells as the agent's map noted them (in no order, perhaps repeated) and their values now."""
        self.grid.reshape(-1)[cells] = values
        cells = np.sort(cells)
        first = np.ones(len(cells), dtype=bool)
        first[1:] = cells[1:] != cells[:-1]
        self._changed = cells[first]

    def take_changes(self) -> np.ndarray:
        changed, self._changed = self._changed, np.zeros(0, dtype=np.int64)
        return changed


class _Forked:
    """A writer in a forked process: batches go to it through a pipe (sent by a thread, so that the run goes on
    while the writer catches up), and at the end it says how many messages it wrote, and the error that stopped
    it if a write failed (it says so and ends at once, so that the run stops sending)."""

    def __init__(self, setup: tuple):
        """``setup``: the arguments of the ``_Writer``, made in the child (its copy of the map is the child's)."""
        context = multiprocessing.get_context("fork")
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_serve, args=(setup, child), daemon=True, name="log-writer")
        self.process.start()
        child.close()
        setup[0].close()  # this process's copy of the file: the child writes it
        self.messages = 0
        self.error: OSError | None = None  # set by the sender, when the writer has ended
        self.batches: queue.SimpleQueue[_Batch | None] = queue.SimpleQueue()
        self.sender = threading.Thread(target=self._send, daemon=True, name="log-sender")
        self.sender.start()

    def _send(self) -> None:
        """The batches in order, then the writer's last word: at the end, or as soon as a batch finds it gone."""
        try:
            while (batch := self.batches.get()) is not None:
                self.connection.send(batch)
            self.connection.send(None)
        except OSError:  # a broken pipe: the writer ended, its last word waiting
            pass
        try:
            self.messages, error = self.connection.recv()
        except (EOFError, OSError):  # it ended without a word (killed)
            error = OSError("its writer process ended")
        self.error = error

    def write(self, batch: _Batch) -> None:
        self.batches.put(batch)

    def close(self) -> int:
        self.batches.put(None)
        self.sender.join()
        self.process.join()
        return self.messages


def _serve(setup: tuple, connection) -> None:
    """The writer's loop. A terminal's Ctrl-C reaches the whole process group: the writer leaves it to the run,
    which closes the log, so that what was sent is written and the log ends whole (interrupted, the writer
    printed a traceback and the run a 'connection reset')."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    writer = _Writer(*setup)
    while writer.error is None and (batch := connection.recv()) is not None:
        writer.write(batch)
    connection.send((writer.close(), writer.error))


def _bytes(payloads: np.ndarray) -> np.ndarray:
    """Payloads of a wire layout as rows of bytes."""
    return payloads.view(np.uint8).reshape(len(payloads), -1)


def _payload(message) -> bytes:
    """A pymavlink message's payload, as its ``pack`` makes it before framing it (the writer frames them all at
    once): framing one costs ten times as much, most of it the CRC in Python."""
    message._pack = _payload_only  # pack() hands the payload to _pack, which frames it; here it is given back
    try:
        return message.pack(None)
    finally:
        del message._pack  # the message packs as before


def _payload_only(mav, crc_extra: int, payload: bytes, force_mavlink1: bool = False) -> bytes:
    return payload


def _frame_nothing() -> None:
    empty = np.zeros(0, dtype=np.int64)
    _frame(np.zeros(0, dtype=np.uint8), empty, empty, empty, empty, empty, empty, empty, np.zeros(2, np.int64), 1,
           np.array(COMPONENTS))


@numba.njit(cache=True)
def _frame(payloads, starts, lengths, order, stamps, ids, extras, components, seqs, sysid, compids):
    """The log records of the messages, in ``order``: each the 8-byte big-endian microsecond stamp and the
    MAVLink 2 packet pymavlink would make (trailing zero bytes of the payload dropped, at least one kept;
    the component's next sequence number, advanced in ``seqs``; the CRC-16/MCRF4XX of header and payload
    and the message's CRC extra)."""
    out = np.empty(len(order) * 20 + lengths.sum(), dtype=np.uint8)
    at = 0
    for k in order:
        start, length = starts[k], lengths[k]
        while length > 1 and payloads[start + length - 1] == 0:
            length -= 1
        for i in range(8):
            out[at + i] = (stamps[k] >> (56 - 8 * i)) & 0xFF
        head = at + 8
        component = components[k]
        out[head], out[head + 1], out[head + 2], out[head + 3] = 253, length, 0, 0
        out[head + 4], out[head + 5], out[head + 6] = seqs[component], sysid, compids[component]
        out[head + 7], out[head + 8], out[head + 9] = ids[k] & 0xFF, (ids[k] >> 8) & 0xFF, ids[k] >> 16
        out[head + 10:head + 10 + length] = payloads[start:start + length]
        crc = 0xFFFF
        for i in range(head + 1, head + 10 + length):
            crc = _crc_add(crc, out[i])
        crc = _crc_add(crc, extras[k])
        out[head + 10 + length], out[head + 11 + length] = crc & 0xFF, crc >> 8
        at = head + 12 + length
        seqs[component] = (seqs[component] + 1) & 0xFF
    return out[:at]


@numba.njit(cache=True)
def _crc_add(crc, byte):
    """One byte into the X.25 CRC that MAVLink uses (CRC-16/MCRF4XX)."""
    tmp = (byte ^ crc) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
