"""The memory map and the planned path over MAVLink TUNNEL messages.

TUNNEL (385) carries at most 128 bytes of payload, tagged with a payload type;
types from 32768 up are free for private use. Three are ours (all integers
little-endian):

* ``MAP_SNAPSHOT`` (32800): one chunk of a full map. Chunk header
  ``<HHH`` = snapshot id, chunk index, chunk count, then up to 122 bytes of
  the snapshot blob. The blob, once its chunks are joined, is ``<BHfffIHHHH``
  (format version 1, cells per side, resolution in cells/m, south-west corner
  x and y in metres east and north of home, the number of the last delta
  already in it, then the first row, first column, rows and columns of the
  part of the grid that is not all zero) followed by that part
  zlib-compressed: int8 log-odds, rows south to north, columns west to east.
* ``MAP_DELTA`` (32801): ``<IH`` = delta number, cell count n, then a raw
  deflate stream (zlib, wbits -15) of: n cell indices in increasing order, each
  as the LEB128 varint of its difference from the previous one (the first from
  0; a flat index is row * size + column), then the n new values as int8.
  Values are absolute, so applying a delta twice does no harm. Changed cells
  lie along sonar beams, so this packs some 60-100 cells into one payload.
* ``PATH`` (32802): ``<HBB`` = path id, chunk index, chunk count, then up to
  15 points ``<ff`` (metres east and north of home). An empty path is one
  chunk with no points.

A receiver that joins late, or misses a delta (a gap in the numbers), waits for
the next snapshot and then applies the deltas numbered after it, so its copy
equals the onboard map cell for cell. Snapshots go out every few seconds, less
often when they are big, so that they use at most a set share of the link.

A receiver believes nothing a stream claims beyond what a vehicle can send
(``map_bounds``): a map is at most ``MAX_SIDE`` cells a side, at a resolution and over an extent
the mission settings allow (they refuse others, so both ends agree), a
snapshot's part is inflated no further than the claimed geometry holds (a zlib
bomb stops there), and a delta that names more cells than its map has, or a
cell twice, is dropped. Non-finite numbers (geometry, path points) are no map
and no path.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from vehicle.protocol.map_bounds import MAX_REACH, MAX_RESOLUTION, MAX_SIDE, MIN_RESOLUTION

MAP_SNAPSHOT = 32800
MAP_DELTA = 32801
PATH = 32802
PAYLOAD = 128

SNAPSHOT_CHUNK = struct.Struct("<HHH")
_SNAPSHOT = struct.Struct("<BHfffIHHHH")
_DELTA = struct.Struct("<IH")
PATH_CHUNK = struct.Struct("<HBB")
_POINT = struct.Struct("<ff")
DELTA_ROOM = PAYLOAD - _DELTA.size
POINTS_PER_CHUNK = (PAYLOAD - PATH_CHUNK.size) // _POINT.size
FORMAT_VERSION = 1
VARINT_MAX = 5  # bytes of one LEB128 gap (gaps stay below 2**35)


@dataclass
class MapGeometry:
    size: int
    resolution: float
    origin: tuple[float, float]  # south-west corner, metres east and north of home


# ---- sending -------------------------------------------------------------------------------------
class MapStreamer:
    """Turns the onboard map into TUNNEL payloads: deltas as cells change, a snapshot now and then."""

    def __init__(self, memory_map, home: tuple[float, float], snapshot_period: float = 5.0,
                 delta_period: float = 0.5, snapshot_budget: float = 8000.0):
        self.map = memory_map
        self.home = home
        self.snapshot_period = snapshot_period  # at least this long between snapshots
        self.snapshot_budget = snapshot_budget  # bytes/s that snapshots may use on average
        self.delta_period = delta_period
        self.delta_seq = 0
        self.snapshot_id = 0
        self.path_id = 0
        self._next_snapshot = 0.0
        self._next_delta = 0.0
        self._last_path: list[tuple[float, float]] | None = None
        grid = memory_map.grid.reshape(-1)  # the values receivers have been told: a new map's zeros
        self._sent = grid.copy() if grid.any() else np.zeros_like(grid)  # (zeros cost no copy)

    def tick(self, now: float) -> list[tuple[int, bytes]]:
        """Payloads (type, bytes) due at ``now``."""
        out: list[tuple[int, bytes]] = []
        if now >= self._next_delta:
            self._next_delta = now + self.delta_period
            out += self.deltas()
        if now >= self._next_snapshot:
            chunks = self.snapshot()
            size = len(chunks) * PAYLOAD
            self._next_snapshot = now + max(self.snapshot_period, size / self.snapshot_budget)
            out += chunks
        return out

    def next_due(self) -> float:
        """When ``tick`` next has something to send (a delta or a snapshot)."""
        return min(self._next_delta, self._next_snapshot)

    def deltas(self) -> list[tuple[int, bytes]]:
        """Cells whose value differs from what was last sent, in as few payloads as fit."""
        touched = self.map.take_changes()
        grid = self.map.grid.reshape(-1)
        changed = touched[grid[touched] != self._sent[touched]]
        self._sent[changed] = grid[changed]
        values = grid[changed]
        codes, ends = _varint_codes(np.diff(changed, prepend=0))  # a payload's first gap is from 0: see below
        ends = ends.tolist()
        out = []
        start, guess = 0, 64
        while start < len(changed):
            count = min(guess, len(changed) - start)
            first = _varint(int(changed[start]))  # its index itself, not its gap to the one before
            while True:  # as many cells as fit, shrinking the guess until the packed form does
                body = _deflate(first + codes[ends[start]:ends[start + count - 1]]
                                + values[start:start + count].tobytes())
                if len(body) <= DELTA_ROOM or count == 1:
                    break
                count = max(1, int(count * DELTA_ROOM / len(body) * 0.95))
            self.delta_seq += 1
            out.append((MAP_DELTA, _DELTA.pack(self.delta_seq, count) + body))
            guess = count + count // 4 + 1 if len(body) < DELTA_ROOM * 0.85 else count
            start += count
        return out

    def snapshot(self) -> list[tuple[int, bytes]]:
        """The whole map, chunked. Pending changes go out as deltas first, so the snapshot covers them."""
        out = self.deltas()
        ident, head, part = self.snapshot_parts()
        return out + snapshot_chunks(ident, head + zlib.compress(part, 6))

    def snapshot_parts(self) -> tuple[int, bytes, bytes]:
        """A new snapshot's id, its header, and the raw bytes of the map's non-zero part; the blob is the header
        and that part zlib-compressed (any level or strategy). ``snapshot`` without the compression, which a
        log may do elsewhere; take ``deltas`` first."""
        m = self.map
        origin = (m.origin[0] - self.home[0], m.origin[1] - self.home[1])
        r0, c0, nr, nc = _nonzero_box(m.grid)
        head = _SNAPSHOT.pack(FORMAT_VERSION, m.size, m.resolution, *origin, self.delta_seq, r0, c0, nr, nc)
        self.snapshot_id = (self.snapshot_id + 1) % 65536
        return self.snapshot_id, head, m.grid[r0:r0 + nr, c0:c0 + nc].tobytes()

    def path(self, points: list[tuple[float, float]], force: bool = False) -> list[tuple[int, bytes]]:
        """The planned path (scene metres) if it changed since the last call (or ``force``)."""
        rounded = [(round(x - self.home[0], 2), round(y - self.home[1], 2)) for x, y in points]
        if rounded == self._last_path and not force:
            return []
        self._last_path = rounded
        self.path_id = (self.path_id + 1) % 65536
        groups = [rounded[i:i + POINTS_PER_CHUNK] for i in range(0, len(rounded), POINTS_PER_CHUNK)] or [[]]
        return [(PATH, PATH_CHUNK.pack(self.path_id, index, len(groups)) + b"".join(_POINT.pack(*p) for p in group))
                for index, group in enumerate(groups)]


def _unpack_cells(body: bytes, count: int) -> tuple[np.ndarray, np.ndarray]:
    raw = _inflate(zlib.decompressobj(-15), body, count * (VARINT_MAX + 1))
    gaps, offset = _read_varints(raw, count)
    if count > 1 and int(gaps[1:].min()) < 1:
        raise ValueError("cell indices that do not increase")
    values = np.frombuffer(raw, dtype=np.int8, count=count, offset=offset)
    return np.cumsum(gaps), values


def _inflate(inflater, data: bytes, most: int) -> bytes:
    """``data`` decompressed, refused (ValueError) if it holds more than ``most`` bytes: inflation stops there, so
    a few bytes that claim gigabytes cost nothing."""
    raw = inflater.decompress(data, max(most, 1))  # (0 would mean no limit)
    if inflater.unconsumed_tail or not inflater.eof or len(raw) > most:
        raise ValueError("compressed data that holds more than its header claims, or is cut short")
    return raw


def _deflate(data: bytes) -> bytes:
    return zlib.compress(data, 9, -15)  # raw deflate (no zlib header)


def _varints(numbers: np.ndarray) -> bytes:
    """LEB128 encoding of non-negative integers below 2**35."""
    return _varint_codes(numbers)[0]


def _varint(number: int) -> bytes:
    """``_varints`` of one number."""
    out = bytearray()
    while number >= 0x80:
        out.append(number & 0x7F | 0x80)
        number >>= 7
    out.append(number)
    return bytes(out)


def _varint_codes(numbers: np.ndarray) -> tuple[bytes, np.ndarray]:
    """The LEB128 encodings of non-negative integers below 2**35, end to end, and where each one ends."""
    numbers = numbers.astype(np.int64)
    lengths = np.ones(len(numbers), dtype=np.int64)
    for k in range(1, 5):
        lengths += numbers >= (1 << (7 * k))
    ends = np.cumsum(lengths)
    owner = np.repeat(np.arange(len(numbers)), lengths)
    k = np.arange(int(ends[-1]) if len(ends) else 0) - np.repeat(ends - lengths, lengths)
    more = k < lengths[owner] - 1
    return (((numbers[owner] >> (7 * k)) & 0x7F) | (more << 7)).astype(np.uint8).tobytes(), ends


def _read_varints(raw: bytes, count: int) -> tuple[np.ndarray, int]:
    """The first ``count`` LEB128 integers of ``raw`` and the offset after them."""
    data = np.frombuffer(raw, dtype=np.uint8)
    ends = np.flatnonzero(data < 0x80)[:count]
    if len(ends) < count:
        raise ValueError("truncated varints")
    used = int(ends[-1]) + 1 if count else 0
    starts = np.concatenate(([0], ends[:-1] + 1)) if count else np.zeros(0, dtype=np.int64)
    if count and int((ends - starts).max()) > 4:
        raise ValueError("varint too long")
    k = np.arange(used) - np.repeat(starts, ends - starts + 1)
    parts = (data[:used].astype(np.int64) & 0x7F) << (7 * k)
    return (np.add.reduceat(parts, starts) if count else np.zeros(0, dtype=np.int64)), used


def _nonzero_box(grid: np.ndarray) -> tuple[int, int, int, int]:
    """First row, first column, rows and columns of the smallest box holding every non-zero cell. Rows of
    cells are read 8 to a machine word where they fit (a 2000 x 2000 map in a tenth of the time)."""
    words = grid.view(np.uint64) if grid.shape[1] % 8 == 0 and grid.flags.c_contiguous else grid
    rows = np.flatnonzero(words.any(axis=1))
    if not len(rows):
        return 0, 0, 0, 0
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    used = np.bitwise_or.reduce(words[r0:r1], axis=0)  # per column (or word of 8 columns): any cell set
    cols = np.flatnonzero(used.view(np.uint8) if words is not grid else used)
    return r0, int(cols[0]), r1 - r0, int(cols[-1]) + 1 - int(cols[0])


def snapshot_chunks(ident: int, blob: bytes) -> list[tuple[int, bytes]]:
    """The MAP_SNAPSHOT payloads of snapshot ``ident`` (see ``MapStreamer.snapshot_parts``)."""
    return _chunks(MAP_SNAPSHOT, ident, blob)


def _chunks(kind: int, ident: int, blob: bytes) -> list[tuple[int, bytes]]:
    room = PAYLOAD - SNAPSHOT_CHUNK.size
    parts = [blob[i:i + room] for i in range(0, len(blob), room)]
    if len(parts) > 65535:
        raise ValueError("map snapshot too large to chunk")
    return [(kind, SNAPSHOT_CHUNK.pack(ident, index, len(parts)) + part) for index, part in enumerate(parts)]


# ---- receiving -----------------------------------------------------------------------------------
@dataclass
class MapReceiver:
    """Rebuilds a vehicle's map (and planned path) from TUNNEL payloads, tolerating loss and late joining."""

    geometry: MapGeometry | None = None
    grid: np.ndarray | None = None
    applied: int = 0  # number of the last delta applied
    synced: bool = False  # the copy equals the onboard map as of delta ``applied``
    path: list[tuple[float, float]] = field(default_factory=list)  # metres east, north of home
    snapshots: int = 0
    gaps: int = 0
    version: int = 0  # increments whenever the grid changes (for redraws)
    payloads: int = 0  # of ours received, whole or damaged: the sender streams a map
    _parts: dict[int, dict[int, bytes]] = field(default_factory=dict)
    _pending: dict[int, bytes] = field(default_factory=dict)  # deltas waiting for a snapshot
    _path_parts: dict[int, dict[int, list]] = field(default_factory=dict)

    def feed(self, payload_type: int, payload: bytes) -> bool:
        """Take one TUNNEL payload; True if it was ours. Malformed payloads are dropped."""
        try:
            if payload_type == MAP_DELTA:
                self._delta(payload)
            elif payload_type == MAP_SNAPSHOT:
                self._snapshot_chunk(payload)
            elif payload_type == PATH:
                self._path_chunk(payload)
            else:
                return False
        except (struct.error, zlib.error, ValueError, IndexError, KeyError):
            pass  # ours but damaged: ignore, the next snapshot repairs
        self.payloads += 1
        return True

    def _delta(self, payload: bytes) -> None:
        seq, count = _DELTA.unpack_from(payload)
        if not self.synced:
            self._pending[seq] = payload
            if len(self._pending) > 4096:  # never got a snapshot: keep only the recent ones
                self._pending.pop(min(self._pending))
            return
        if seq <= self.applied:
            return
        if seq != self.applied + 1:
            self.gaps += 1
            self.synced = False
            self._pending = {seq: payload}
            return
        self._apply(payload)

    def _apply(self, payload: bytes) -> None:
        seq, count = _DELTA.unpack_from(payload)
        if count > self.grid.size:
            raise ValueError("a delta with more cells than its map")
        indices, values = _unpack_cells(payload[_DELTA.size:], count)
        flat = self.grid.reshape(-1)
        if count and int(indices.max()) >= flat.size:
            raise ValueError("cell index outside the map")
        flat[indices] = values
        self.applied = seq
        self.version += 1

    def _snapshot_chunk(self, payload: bytes) -> None:
        ident, index, count = SNAPSHOT_CHUNK.unpack_from(payload)
        if index >= count:
            raise ValueError("chunk index past the chunk count")
        parts = self._parts.setdefault(ident, {})
        parts[index] = payload[SNAPSHOT_CHUNK.size:]
        for other in [k for k in self._parts if k != ident]:  # an older snapshot will not complete now
            if len(self._parts[other]) < len(parts):
                del self._parts[other]
        if len(parts) < count:
            return
        del self._parts[ident]
        blob = b"".join(parts[i] for i in range(count))
        version, size, resolution, ox, oy, last_delta, r0, c0, nr, nc = _SNAPSHOT.unpack_from(blob)
        if version != FORMAT_VERSION:
            raise ValueError(f"unknown map format {version}")
        if not 0 < size <= MAX_SIDE or r0 + nr > size or c0 + nc > size:
            raise ValueError(f"a map of {size} cells a side (at most {MAX_SIDE}), or a part outside it")
        if not (math.isfinite(resolution) and resolution > 0 and math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError("a map geometry that is not a number")
        if not (MIN_RESOLUTION * 0.999 <= resolution <= MAX_RESOLUTION * 1.001  # as float32 carries them
                and size / resolution <= MAX_REACH and abs(ox) <= MAX_REACH and abs(oy) <= MAX_REACH):
            raise ValueError("a map geometry no vehicle makes (resolution or extent beyond the settings' bounds)")
        part = np.frombuffer(_inflate(zlib.decompressobj(), blob[_SNAPSHOT.size:], nr * nc), dtype=np.int8)
        if part.size != nr * nc:
            raise ValueError("snapshot size mismatch")
        grid = np.zeros((size, size), dtype=np.int8)
        grid[r0:r0 + nr, c0:c0 + nc] = part.reshape(nr, nc)
        self.geometry = MapGeometry(size, resolution, (ox, oy))
        self.grid = grid
        self.applied = last_delta
        self.synced = True
        self.snapshots += 1
        self.version += 1
        pending, self._pending = self._pending, {}
        for seq in sorted(s for s in pending if s > last_delta):
            if seq != self.applied + 1:
                break  # not a continuation of this snapshot (a stray or a gap): wait for the next one
            self._apply(pending[seq])

    def _path_chunk(self, payload: bytes) -> None:
        ident, index, count = PATH_CHUNK.unpack_from(payload)
        if index >= count:
            raise ValueError("chunk index past the chunk count")
        body = payload[PATH_CHUNK.size:]
        points = [_POINT.unpack_from(body, i * _POINT.size) for i in range(len(body) // _POINT.size)]
        points = [p for p in points if math.isfinite(p[0]) and math.isfinite(p[1])]
        parts = self._path_parts.setdefault(ident, {})
        parts[index] = points
        for other in [k for k in self._path_parts if k != ident]:
            del self._path_parts[other]
        if len(parts) == count:
            self.path = [p for i in range(count) for p in parts[i]]
            del self._path_parts[ident]
