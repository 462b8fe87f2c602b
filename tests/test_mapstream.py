"""The memory map and planned path over TUNNEL payloads (vehicle.mapstream).

A MapStreamer turns a changing MemoryMap into payloads; a MapReceiver rebuilds it.
The map changes through real sonar-like readings (add_readings), with simulated
time passed to ``tick`` by the test.
"""

import math
import struct
import zlib

import numpy as np
import pytest

from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.mapstream import MAP_DELTA, MAP_SNAPSHOT, PATH, PAYLOAD, MapReceiver, MapStreamer

HOME = (12.0, -7.0)  # not the origin, so offsets from home show
STEP = 0.25  # s between ticks


def scan(memory: MemoryMap, rng: np.random.Generator, n: int = 40) -> None:
    """A batch of horizontal readings from a random spot near home, some without echo."""
    origin = np.array([HOME[0] + rng.uniform(-8, 8), HOME[1] + rng.uniform(-8, 8), 4.0])
    angles = rng.uniform(0, 2 * math.pi, n)
    directions = np.column_stack([np.sin(angles), np.cos(angles), np.zeros(n)])
    distances = rng.uniform(1, 12, n)
    distances[rng.random(n) < 0.2] = np.nan
    memory.add_readings(
        np.repeat(origin[None], n, axis=0), directions, distances, np.full(n, 40.0), np.full(n, math.radians(7.5))
    )


class Stream:
    """A map, its streamer, and the payloads of every tick so far (each tagged with its tick)."""

    def __init__(self, seed=0, space_size=20.0, **streamer):
        self.rng = np.random.default_rng(seed)
        self.map = MemoryMap(HOME, space_size, 10)
        self.streamer = MapStreamer(self.map, HOME, **streamer)
        self.time = 0.0

    def tick(self, scans=1) -> list[tuple[int, bytes]]:
        for _ in range(scans):
            scan(self.map, self.rng)
        self.time += STEP
        return self.streamer.tick(self.time)

    def run(self, seconds) -> list[tuple[int, bytes]]:
        out = []
        for _ in range(round(seconds / STEP)):
            out += self.tick()
        return out


def feed(receiver, payloads):
    for kind, payload in payloads:
        assert receiver.feed(kind, payload)


def assert_equal_maps(receiver, memory):
    assert receiver.synced
    assert receiver.grid is not None
    assert receiver.grid.shape == memory.grid.shape
    assert np.array_equal(receiver.grid, memory.grid)


def synced_receiver(stream: Stream) -> MapReceiver:
    receiver = MapReceiver()
    feed(receiver, stream.run(1) + stream.streamer.snapshot())
    assert receiver.synced
    return receiver


def zlib_raw(data: bytes) -> bytes:
    import zlib

    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    return packer.compress(data) + packer.flush()


def _snapshot(size=4, resolution=1.0, origin=(0.0, 0.0), last=0, box=(0, 0, 1, 1), cells=b"\x05", ident=1):
    from vehicle.protocol.mapstream import _SNAPSHOT, snapshot_chunks

    head = _SNAPSHOT.pack(1, size, resolution, *origin, last, *box)
    return snapshot_chunks(ident, head + zlib.compress(cells, 6))


def _delta(seq, indices, values):
    from vehicle.protocol.mapstream import _DELTA, _deflate, _varints

    gaps = np.diff(np.asarray(indices, dtype=np.int64), prepend=0)
    return MAP_DELTA, _DELTA.pack(seq, len(indices)) + _deflate(_varints(gaps) + bytes(np.int8(values).tobytes()))


def _fed(*payloads) -> MapReceiver:
    receiver = MapReceiver()
    for kind, payload in payloads:
        assert receiver.feed(kind, payload)
    return receiver


# ---- snapshots and deltas: the copy equals the map -------------------------------------------
def test_a_receiver_fed_everything_equals_the_map_cell_for_cell():
    stream = Stream()
    receiver = MapReceiver()
    for k in range(60):
        feed(receiver, stream.tick())
        if k % 4 == 3:  # whenever every change has gone out, the copy is exact
            feed(receiver, stream.streamer.deltas())
            assert_equal_maps(receiver, stream.map)
    feed(receiver, stream.streamer.deltas())
    assert_equal_maps(receiver, stream.map)
    assert receiver.gaps == 0
    assert receiver.geometry.size == stream.map.size
    assert receiver.geometry.resolution == 10
    assert receiver.geometry.origin == pytest.approx((-20.0, -20.0))  # south-west corner, from home


def test_every_payload_fits_a_tunnel_message():
    stream = Stream(seed=1)
    payloads = stream.run(12)
    assert {kind for kind, _ in payloads} == {MAP_SNAPSHOT, MAP_DELTA}
    assert all(0 < len(p) <= PAYLOAD for _, p in payloads)
    assert all(kind >= 32768 for kind in (MAP_SNAPSHOT, MAP_DELTA, PATH))


def test_snapshots_come_now_and_then_and_deltas_in_between():
    stream = Stream(seed=2, snapshot_period=5.0, delta_period=0.5)
    ticks = [stream.tick() for _ in range(round(12 / STEP))]
    snapshot_ticks = [i for i, out in enumerate(ticks) if any(k == MAP_SNAPSHOT for k, _ in out)]
    delta_ticks = [i for i, out in enumerate(ticks) if any(k == MAP_DELTA for k, _ in out)]
    assert len(snapshot_ticks) in (2, 3)  # at about 0, 5 and 10 s
    assert len(delta_ticks) >= 12 / 0.5 - 2


def test_deltas_go_out_every_delta_period_and_snapshots_keep_within_their_budget():
    """Deltas every half second (not at every tick); a big map's snapshots are spaced so that they use at most
    snapshot_budget bytes a second on average."""
    stream = Stream(seed=8, snapshot_period=1.0, snapshot_budget=2000.0)
    times = {MAP_DELTA: [], MAP_SNAPSHOT: []}
    sizes = []
    for _ in range(round(30 / STEP)):
        out = stream.tick(scans=3)
        snapshot = [p for k, p in out if k == MAP_SNAPSHOT]
        if snapshot:  # a snapshot sends the changes pending before it as deltas too
            times[MAP_SNAPSHOT].append(stream.time)
            sizes.append(len(snapshot) * PAYLOAD)
        elif any(k == MAP_DELTA for k, _ in out):
            times[MAP_DELTA].append(stream.time)
    assert len(times[MAP_DELTA]) > 30 and np.diff(times[MAP_DELTA]).min() == pytest.approx(0.5)
    gaps = np.diff(times[MAP_SNAPSHOT])
    assert len(gaps) >= 3 and max(sizes) > 2000  # bigger than a second of the budget: spaced further apart
    for gap, size in zip(gaps, sizes[:-1], strict=False):
        assert gap >= max(1.0, size / 2000.0) - 1e-9


def test_a_receiver_that_joins_late_catches_up_at_the_next_snapshot():
    stream = Stream(seed=3)
    stream.run(7)  # the first snapshot and many deltas go by before it listens
    receiver = MapReceiver()
    caught_up = False
    for _ in range(round(8 / STEP)):
        out = stream.tick()
        feed(receiver, out)
        caught_up |= any(k == MAP_SNAPSHOT for k, _ in out)
        if not caught_up:
            assert not receiver.synced
    assert caught_up
    feed(receiver, stream.streamer.deltas())
    assert_equal_maps(receiver, stream.map)


def test_a_receiver_that_loses_a_tenth_of_the_deltas_resyncs_at_the_next_snapshot():
    stream = Stream(seed=4)
    loss = np.random.default_rng(99)
    receiver = MapReceiver()
    for _ in range(round(14 / STEP)):
        feed(receiver, [(k, p) for k, p in stream.tick() if k != MAP_DELTA or loss.random() >= 0.1])
    assert receiver.gaps > 0  # it did notice losses
    # after the losses, one more snapshot and every delta after it
    while True:
        out = stream.tick()
        feed(receiver, out)
        if any(k == MAP_SNAPSHOT for k, _ in out):
            break
    feed(receiver, stream.run(2) + stream.streamer.deltas())
    assert_equal_maps(receiver, stream.map)


def test_snapshots_that_lost_a_chunk_are_dropped_once_a_newer_one_gets_further():
    """Parts of snapshots that will never complete are kept only until a newer snapshot gets further."""
    stream = Stream(seed=14, space_size=40.0)
    stream.run(10)
    receiver = MapReceiver()
    for _ in range(5):
        snapshot = [(k, p) for k, p in stream.streamer.snapshot() if k == MAP_SNAPSHOT]
        feed(receiver, snapshot[:-1])  # the last chunk of each is lost
    assert len(receiver._parts) == 5 and not receiver.synced
    feed(receiver, [(k, p) for k, p in stream.streamer.snapshot() if k == MAP_SNAPSHOT])
    assert receiver._parts == {} and receiver.synced


def test_deltas_that_arrive_before_the_snapshot_they_follow_are_applied():
    stream = Stream(seed=5)
    stream.run(2)
    snapshot = stream.streamer.snapshot()
    later = stream.run(1) + stream.streamer.deltas()
    receiver = MapReceiver()
    feed(receiver, later)  # out of order: the deltas first
    assert not receiver.synced
    feed(receiver, snapshot)
    assert_equal_maps(receiver, stream.map)


def test_a_delta_applied_twice_does_no_harm():
    stream = Stream(seed=6)
    receiver = MapReceiver()
    payloads = stream.run(3) + stream.streamer.deltas()
    feed(receiver, payloads)
    feed(receiver, [(k, p) for k, p in payloads if k == MAP_DELTA][-3:])
    assert_equal_maps(receiver, stream.map)


# ---- sequence numbers, gaps and versions -----------------------------------------------------
def test_an_empty_delta_advances_the_sequence():
    """A delta of no cells is still a step in the sequence: the one after it is no gap."""
    stream = Stream(seed=10)
    receiver = synced_receiver(stream)
    first = receiver.applied + 1
    feed(receiver, [(MAP_DELTA, struct.pack("<IH", first, 0) + zlib_raw(b""))])
    assert receiver.synced and receiver.applied == first and receiver.gaps == 0
    stream.streamer.delta_seq = first
    feed(receiver, stream.run(2) + stream.streamer.deltas())
    assert_equal_maps(receiver, stream.map)
    assert receiver.gaps == 0


def test_the_receiver_counts_payloads_snapshots_gaps_and_versions():
    stream = Stream(seed=12)
    receiver = MapReceiver()
    payloads = stream.run(6)
    feed(receiver, payloads)
    assert receiver.payloads == len(payloads)
    assert receiver.snapshots == sum(struct.unpack_from("<HHH", p)[1] == 0 for k, p in payloads if k == MAP_SNAPSHOT)
    assert receiver.snapshots >= 2
    version = receiver.version
    deltas = [(k, p) for k, p in stream.run(2) if k == MAP_DELTA]
    assert len(deltas) >= 3
    feed(receiver, deltas[:1])
    assert receiver.version == version + 1  # each change shows as a new version (the views redraw on it)
    feed(receiver, deltas[2:])  # the second one lost
    assert receiver.gaps == 1 and not receiver.synced  # a gap: no longer in sync
    assert receiver.version == version + 1  # nothing applied after the gap
    feed(receiver, stream.streamer.snapshot())
    assert receiver.synced and receiver.version > version + 1 and receiver.gaps == 1


def test_versions_and_gaps_count_one_by_one_and_an_empty_delta_is_applied():
    receiver = _fed(*_snapshot(last=10))
    assert (receiver.version, receiver.applied) == (1, 10)
    receiver.feed(*_delta(11, [], []))  # nothing changed in that period: still the next number
    assert (receiver.applied, receiver.synced) == (11, True)
    receiver.feed(*_delta(12, [1, 2], [3, 4]))
    assert receiver.version == 3 and receiver.grid[0, 1:3].tolist() == [3, 4]
    receiver.feed(*_delta(14, [1], [1]))  # 13 lost
    for chunk in _snapshot(last=20, ident=2):
        receiver.feed(*chunk)
    receiver.feed(*_delta(22, [1], [1]))  # 21 lost
    assert receiver.gaps == 2 and receiver.version == 4 and not receiver.synced


def _stream():
    rng = np.random.default_rng(1)
    memory = MemoryMap((0.0, 0.0), 20, 10)
    streamer = MapStreamer(memory, (0.0, 0.0))
    clock = [0.0]

    def run(seconds):
        out = []
        for _ in range(round(seconds / 0.25)):
            origin = np.array([rng.uniform(-8, 8), rng.uniform(-8, 8), 4.0])
            a = rng.uniform(0, 2 * math.pi, 40)
            memory.add_readings(np.repeat(origin[None], 40, axis=0), np.column_stack([np.sin(a), np.cos(a),
                                np.zeros(40)]), rng.uniform(1, 12, 40), np.full(40, 40.0), np.full(40, 0.13))
            clock[0] += 0.25
            out += streamer.tick(clock[0])
        return out

    return memory, streamer, run


def test_bug5_one_stray_delta_with_a_far_sequence_number_desyncs_the_receiver_for_good():
    # The stray delta is kept in _pending; at every later snapshot the pending deltas are replayed,
    # the stray one is a "gap" again (synced = False, _pending = {stray}), so the receiver never
    # stays in sync: after 24 s and 5 snapshots its copy still differs from the map.
    memory, streamer, run = _stream()
    receiver = MapReceiver()
    for kind, payload in run(3):
        receiver.feed(kind, payload)
    assert receiver.synced
    receiver.feed(MAP_DELTA, struct.pack("<IH", 10**6, 3) + b"\x01\x02\x03")  # one corrupted/stray packet
    for kind, payload in run(24) + streamer.deltas():
        receiver.feed(kind, payload)
    assert receiver.synced
    assert np.array_equal(receiver.grid, memory.grid)


# ---- damaged and hostile payloads ------------------------------------------------------------
def test_garbage_payloads_are_ignored_without_exceptions():
    stream = Stream(seed=7)
    receiver = MapReceiver()
    feed(receiver, stream.run(3) + stream.streamer.deltas())
    rng = np.random.default_rng(0)
    garbage = [b"", b"\x00", b"\xff" * 3, b"\xff" * PAYLOAD, struct.pack("<IH", 1, 65535) + b"\x01" * 20]
    garbage += [rng.bytes(int(rng.integers(1, PAYLOAD + 1))) for _ in range(300)]
    for kind in (MAP_SNAPSHOT, MAP_DELTA):
        for payload in garbage:
            receiver.feed(kind, payload)  # must not raise
    for payload in (b"", b"\x01", b"\x01\x00\x00", struct.pack("<HBB", 7, 0, 1) + b"\x00" * 5):
        receiver.feed(PATH, payload)  # too short for a header, or a point cut short
    assert receiver.feed(32900, b"not ours") is False
    assert receiver.feed(0, b"") is False


def test_damaged_copies_of_real_payloads_do_not_spoil_the_copy():
    stream = Stream(seed=7)
    receiver = MapReceiver()
    good = stream.run(3) + stream.streamer.deltas()
    feed(receiver, good)
    for kind, payload in good:  # truncated and bit-flipped copies of everything already sent
        receiver.feed(kind, payload[: len(payload) // 2])
        flipped = bytearray(payload)
        flipped[-1] ^= 0xFF
        receiver.feed(kind, bytes(flipped))
    feed(receiver, stream.run(1) + stream.streamer.snapshot() + stream.run(1) + stream.streamer.deltas())
    assert_equal_maps(receiver, stream.map)


def test_a_snapshot_chunk_from_an_unknown_format_version_is_ignored():
    stream = Stream(seed=8)
    stream.run(1)
    chunks = stream.streamer.snapshot()
    snap = [(k, p) for k, p in chunks if k == MAP_SNAPSHOT]
    assert len(snap) >= 1
    kind, first = snap[0]
    broken = bytearray(first)
    broken[6] = 99  # the blob's format version (after the <HHH chunk header)
    receiver = MapReceiver()
    receiver.feed(kind, bytes(broken))
    for kind, payload in snap[1:]:
        receiver.feed(kind, payload)
    assert not receiver.synced


def test_a_delta_with_bytes_after_its_values_applies_its_count_of_cells():
    stream = Stream(seed=11)
    receiver = synced_receiver(stream)
    seq = receiver.applied + 1
    body = bytes([5, 1]) + bytes([7, 8]) + b"\x09\x09\x09"  # cells 5 and 6 get 7 and 8; three bytes too many
    feed(receiver, [(MAP_DELTA, struct.pack("<IH", seq, 2) + zlib_raw(body))])
    assert receiver.applied == seq and receiver.grid.reshape(-1)[5:7].tolist() == [7, 8]


def test_a_receiver_without_a_snapshot_keeps_only_the_latest_4096_deltas():
    receiver = MapReceiver()
    for seq in range(1, 5001):
        receiver.feed(MAP_DELTA, struct.pack("<IH", seq, 0) + zlib_raw(b""))
    assert len(receiver._pending) == 4096 and min(receiver._pending) == 5001 - 4096


def test_a_stray_chunk_numbered_past_its_count_spoils_no_snapshot_or_path():
    """A chunk whose index equals its count is refused, so the snapshot or path it claims to belong to still
    completes from its real chunks."""
    stream = Stream(seed=13, space_size=40.0)
    stream.run(10)
    chunks = stream.streamer.snapshot()
    snapshot = [(k, p) for k, p in chunks if k == MAP_SNAPSHOT]
    ident, _, count = struct.unpack_from("<HHH", snapshot[0][1])
    assert count >= 2
    receiver = MapReceiver()
    stray = (MAP_SNAPSHOT, struct.pack("<HHH", ident, count, count) + b"\x00" * 20)
    feed(receiver, [(k, p) for k, p in chunks if k == MAP_DELTA] + snapshot[:1] + [stray] + snapshot[1:])
    assert receiver.synced and receiver.snapshots == 1 and np.array_equal(receiver.grid, stream.map.grid)
    path = stream.streamer.path([(float(i), 0.0) for i in range(20)])  # two chunks
    assert len(path) == 2
    path_id = struct.unpack_from("<HBB", path[0][1])[0]
    feed(receiver, path[:1] + [(PATH, struct.pack("<HBB", path_id, 2, 2) + b"\x00" * 8)] + path[1:])
    assert len(receiver.path) == 20


def test_bug4_a_path_chunk_with_an_index_past_its_count_is_dropped_and_the_next_path_still_arrives():
    """MapReceiver._path_chunk once stored {5: []}, saw len(parts) == count == 1 and read parts[0]: a KeyError
    that feed() did not catch, so one hostile packet ended the link thread."""
    receiver = MapReceiver()
    assert receiver.feed(PATH, struct.pack("<HBB", 1, 5, 1))  # ours, but damaged: dropped
    assert receiver.path == [] and receiver.payloads == 1
    assert receiver.feed(PATH, struct.pack("<HBBff", 2, 0, 1, 1.5, -2.0))
    assert receiver.path == [(1.5, -2.0)]


def test_bug4_a_snapshot_chunk_with_an_index_past_its_count_is_dropped_and_the_next_snapshot_still_applies():
    """MapReceiver._snapshot_chunk: the same pattern, b"".join(parts[i] for i in range(count)) -> KeyError."""
    receiver = MapReceiver()
    assert receiver.feed(MAP_SNAPSHOT, struct.pack("<HHH", 1, 3, 1) + b"x")
    assert receiver.grid is None and not receiver.synced and receiver.snapshots == 0 and receiver.payloads == 1
    memory = MemoryMap((0.0, 0.0), 5, 2)
    memory.add_reading(np.array([0.0, 0.0, 4.0]), np.array([1.0, 0.0, 0.0]), 3.0, 40.0)
    for kind, payload in MapStreamer(memory, (0.0, 0.0)).snapshot():
        receiver.feed(kind, payload)
    assert receiver.synced and receiver.snapshots == 1 and np.array_equal(receiver.grid, memory.grid)


@pytest.mark.parametrize(
    ("size", "resolution", "accepted"),
    [
        (1, 1.0, True),
        (4000, 2.0, True),  # 2 km a side: the widest space the settings allow
        (2, 0.01, True),  # the coarsest
        (4, 50.0, True),  # the finest
        (4000, 0.5, False),  # 8 km a side
        (4, 1e-30, False),  # a space of 1e31 m would let every goto pass the station's check
        (4, 0.005, False),
        (4, 60.0, False),
        (0, 1.0, False),
        (4001, 1.0, False),
        (4, 0.0, False),
        (4, float("nan"), False),
        (4, float("inf"), False),
    ],
)
def test_a_snapshot_is_taken_at_the_sizes_and_resolutions_the_settings_allow(size, resolution, accepted):
    box = (0, 0, 1, 1) if size else (0, 0, 0, 0)
    receiver = _fed(*_snapshot(size=size, resolution=resolution, box=box, cells=b"\x05" if size else b""))
    assert receiver.synced is accepted and receiver.snapshots == int(accepted)
    if accepted:
        assert receiver.grid.shape == (size, size) and receiver.grid[0, 0] == 5
        assert receiver.geometry.resolution == pytest.approx(resolution)  # float32 on the wire


@pytest.mark.parametrize(
    "origin", [(float("nan"), 0.0), (0.0, float("nan")), (float("inf"), 0.0), (0.0, -float("inf")), (3e38, 0.0),
               (0.0, -2200.0)]
)
def test_a_snapshot_placed_nowhere_is_refused(origin):
    assert not _fed(*_snapshot(origin=origin)).synced


@pytest.mark.parametrize("box", [(3, 0, 2, 1), (0, 3, 1, 2)])
def test_a_snapshot_part_reaching_past_the_map_is_refused(box):
    assert not _fed(*_snapshot(box=box, cells=b"\x05\x05")).synced


def test_a_delta_may_change_every_cell_but_not_one_more_nor_go_back():
    whole = _fed(*_snapshot(size=2, box=(0, 0, 2, 2), cells=b"\x00" * 4))
    whole.feed(*_delta(1, [0, 1, 2, 3], [1, 2, 3, 4]))
    assert whole.grid.tolist() == [[1, 2], [3, 4]] and whole.applied == 1
    back = _fed(*_snapshot(size=2, box=(0, 0, 2, 2), cells=b"\x00" * 4))
    from vehicle.protocol.mapstream import _DELTA, _deflate, _varints

    back.feed(MAP_DELTA, _DELTA.pack(1, 2) + _deflate(_varints(np.array([3, 0])) + b"\x01\x02"))  # 3, then 3 again
    assert back.applied == 0 and not back.grid.any()


def test_a_snapshot_that_inflates_past_its_box_is_refused_without_inflating_it():
    """A few kilobytes of deflate that claim one cell and hold 40 MB: refused, and inflation stops at the cell."""
    import tracemalloc

    chunks = _snapshot(cells=bytes(40_000_000))
    tracemalloc.start()
    try:
        receiver = _fed(*chunks)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert not receiver.synced and peak < 5_000_000


def test_a_snapshot_whose_compressed_part_lacks_its_checksum_is_refused():
    """A zlib stream ends with the Adler-32 of what it holds: a snapshot part without it is cut short, and is
    refused even though every cell it claims inflates (nothing vouches for them); whole, it is taken."""
    cells = bytes(range(1, 17))
    from vehicle.protocol.mapstream import _SNAPSHOT, snapshot_chunks

    head = _SNAPSHOT.pack(1, 4, 1.0, 0.0, 0.0, 0, 0, 0, 4, 4)
    whole = zlib.compress(cells, 6)
    cut = _fed(*snapshot_chunks(1, head + whole[:-4]))
    assert (cut.synced, cut.snapshots, cut.grid) == (False, 0, None)
    taken = _fed(*snapshot_chunks(2, head + whole))
    assert taken.synced and taken.grid.tobytes() == cells


def test_a_delta_whose_deflate_stream_never_ends_is_dropped():
    """A delta's raw deflate stream must reach its end: one flushed but never finished (as if cut after the
    cells) is dropped like any damaged delta, so the receiver waits for the next snapshot, even though its
    cells and values inflate whole."""
    from vehicle.protocol.mapstream import _DELTA, _varints

    data = _varints(np.array([1, 1])) + np.int8([3, 4]).tobytes()  # cells 1 and 2 get 3 and 4
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    unfinished = packer.compress(data) + packer.flush(zlib.Z_SYNC_FLUSH)
    receiver = _fed(*_snapshot(last=10))
    receiver.feed(MAP_DELTA, _DELTA.pack(11, 2) + unfinished)
    assert (receiver.applied, receiver.version) == (10, 1) and receiver.grid[0, 1:3].tolist() == [0, 0]
    receiver.feed(MAP_DELTA, _DELTA.pack(11, 2) + unfinished + packer.flush())  # the same, finished
    assert (receiver.applied, receiver.version) == (11, 2) and receiver.grid[0, 1:3].tolist() == [3, 4]


# ---- the planned path ------------------------------------------------------------------------
@pytest.mark.parametrize("count", [0, 1, 15, 16, 40])
def test_a_path_round_trips_relative_to_home(count):
    memory = MemoryMap(HOME, 20, 10)
    streamer = MapStreamer(memory, HOME)
    points = [(HOME[0] + 0.37 * k, HOME[1] - 1.29 * k + 0.004) for k in range(count)]
    payloads = streamer.path(points)
    assert all(kind == PATH and len(p) <= PAYLOAD for kind, p in payloads)
    receiver = MapReceiver()
    receiver.path = [(99.0, 99.0)]
    feed(receiver, payloads)
    assert len(receiver.path) == count
    for (x, y), (east, north) in zip(points, receiver.path, strict=True):
        assert east == pytest.approx(x - HOME[0], abs=0.006)
        assert north == pytest.approx(y - HOME[1], abs=0.006)


def test_an_unchanged_path_is_not_sent_again_unless_forced():
    streamer = MapStreamer(MemoryMap(HOME, 20, 10), HOME)
    points = [(13.0, -6.0), (15.0, -2.0)]
    assert streamer.path(points)
    assert streamer.path(points) == []
    assert streamer.path(points, force=True)
    assert streamer.path([*points, (16.0, 0.0)])


def test_a_newer_path_replaces_one_half_received():
    streamer = MapStreamer(MemoryMap(HOME, 20, 10), HOME)
    old = streamer.path([(HOME[0] + k, HOME[1]) for k in range(30)])
    new = streamer.path([(HOME[0], HOME[1] + 1.0)])
    receiver = MapReceiver()
    feed(receiver, old[:1] + new + old[1:])
    assert receiver.path == [(0.0, 1.0)]


def test_the_path_goes_out_to_the_centimetre_and_its_id_wraps_round():
    streamer = MapStreamer(MemoryMap((0.0, 0.0), 10.0, 1.0), (1.0, 2.0))
    streamer.path_id = 65535
    ((kind, payload),) = streamer.path([(4.123456, 5.987654)])
    ident, index, count = struct.unpack_from("<HBB", payload)
    assert (kind, ident, index, count) == (PATH, 0, 0, 1)
    x, y = struct.unpack_from("<ff", payload, 4)
    assert (x, y) == (pytest.approx(3.12, abs=1e-6), pytest.approx(3.99, abs=1e-6))


def test_a_path_point_with_either_coordinate_not_finite_is_dropped():
    from vehicle.protocol.mapstream import _POINT, PATH_CHUNK

    points = [(1.0, 2.0), (float("nan"), 3.0), (4.0, float("inf")), (5.0, 6.0)]
    receiver = _fed((PATH, PATH_CHUNK.pack(1, 0, 1) + b"".join(_POINT.pack(*p) for p in points)))
    assert receiver.path == [(1.0, 2.0), (5.0, 6.0)]


# ---- the wire format -------------------------------------------------------------------------
@pytest.mark.parametrize("number", [0, 1, 127, 128, 129, 255, 16383, 16384, 2**28 - 1, 2**28, 2**35 - 1])
def test_one_varint_reads_back_as_its_number_at_every_length_boundary(number):
    from vehicle.protocol.mapstream import _read_varints, _varint, _varints

    assert _varint(number) == _varints(np.array([number]))
    assert _read_varints(_varint(number) + b"\x07", 1) == (np.array([number]), len(_varint(number)))


@pytest.mark.parametrize("space_size", [4.5, 8.5])
def test_a_map_whose_side_is_no_multiple_of_8_cells_is_snapshot_cell_for_cell(space_size):
    """Rows are read 8 cells to a machine word only where they hold whole words: a map 9 or 17 cells a side is
    read cell by cell, and its snapshot carries the box of its non-zero cells exactly."""
    memory = MemoryMap((0.0, 0.0), space_size, 1.0)
    side = memory.size
    assert side in (9, 17)
    memory.grid[2, 3] = 7
    memory.grid[side - 2, side - 1] = -4
    ident, head, part = MapStreamer(memory, (0.0, 0.0)).snapshot_parts()
    from vehicle.protocol.mapstream import _SNAPSHOT

    assert _SNAPSHOT.unpack(head)[-4:] == (2, 3, side - 3, side - 3)
    receiver = MapReceiver()
    feed(receiver, MapStreamer(memory, (0.0, 0.0)).snapshot())
    assert_equal_maps(receiver, memory)


@pytest.mark.parametrize("space_size", [0.5, 20.0])
def test_the_snapshot_of_an_empty_map_names_an_empty_part_at_the_first_cell(space_size):
    """With no non-zero cell the part is no rows and no columns, at row 0 and column 0 (inside even a map of
    one cell, for a receiver that checks where the part starts), and holds no bytes."""
    from vehicle.protocol.mapstream import _SNAPSHOT

    memory = MemoryMap((0.0, 0.0), space_size, 1.0)
    ident, head, part = MapStreamer(memory, (0.0, 0.0)).snapshot_parts()
    assert _SNAPSHOT.unpack(head)[-4:] == (0, 0, 0, 0) and part == b""


# ---- size ---------------------------------------------------------------------------------------
def test_a_full_2000_by_2000_map_snapshot_chunks_into_128_byte_payloads():
    memory = MemoryMap((0.0, 0.0), 100, 10)
    assert memory.grid.shape == (2000, 2000)
    rng = np.random.default_rng(11)
    memory.grid[:] = rng.integers(-3, 31, memory.grid.shape, dtype=np.int8)  # nothing compresses well
    memory.grid[0, 0] = memory.grid[-1, -1] = 30  # the whole extent is in use
    chunks = MapStreamer(memory, (0.0, 0.0)).snapshot()
    assert all(kind == MAP_SNAPSHOT and len(payload) <= PAYLOAD for kind, payload in chunks)
    receiver = MapReceiver()
    feed(receiver, chunks)
    assert_equal_maps(receiver, memory)


def test_an_empty_map_streams_and_is_received_as_empty():
    memory = MemoryMap(HOME, 20, 10)
    receiver = MapReceiver()
    feed(receiver, MapStreamer(memory, HOME).tick(0.0))
    assert_equal_maps(receiver, memory)
    assert not receiver.grid.any()


def test_deltas_pack_dozens_of_cells_into_each_payload():
    """Changed cells lie along beams: a payload carries some 60 to 100 of them (at least 40 here), which keeps
    the stream small."""
    stream = Stream(seed=9)
    deltas = [p for k, p in stream.run(10) if k == MAP_DELTA]
    cells = [struct.unpack_from("<IH", p)[1] for p in deltas]
    assert sum(cells) / len(deltas) >= 40, cells
    assert all(len(p) <= PAYLOAD for p in deltas)


def test_cells_far_apart_on_a_full_size_map_travel_in_one_delta():
    """Index gaps of millions of cells (a 2000 x 2000 map) take 4-byte varints, which the receiver reads."""
    memory = MemoryMap((0.0, 0.0), 100.0, 10.0)
    streamer = MapStreamer(memory, (0.0, 0.0))
    receiver = MapReceiver()
    feed(receiver, streamer.snapshot())
    memory.grid[0, 0] = 9
    memory.grid[1999, 1999] = -3
    memory._note_changes(np.array([0, 1999 * 2000 + 1999]))
    payloads = streamer.deltas()
    assert len(payloads) == 1
    feed(receiver, payloads)
    assert receiver.synced and receiver.applied == 1 and np.array_equal(receiver.grid, memory.grid)
    assert receiver.grid.dtype == np.int8  # the copy holds int8 log-odds like the onboard map


def test_delta_payloads_are_filled_before_another_is_started():
    from vehicle.protocol.mapstream import DELTA_ROOM

    grid = MemoryMap((0.0, 0.0), space_size=50.0, resolution=1.0)
    streamer = MapStreamer(grid, (0.0, 0.0))
    rng = np.random.default_rng(4)
    cells = np.sort(rng.choice(grid.grid.size, 3000, replace=False))
    grid.grid.reshape(-1)[cells] = rng.integers(-8, 8, 3000)
    grid._note_changes(cells)
    payloads = streamer.deltas()
    sizes = [len(p) - 6 for _, p in payloads]
    assert len(payloads) > 5 and max(sizes) <= DELTA_ROOM
    assert min(sizes[1:-1]) >= 0.8 * DELTA_ROOM  # from a first guess on, all but the last nearly full


def test_a_snapshot_is_cut_into_at_most_65535_chunks():
    from vehicle.protocol.mapstream import SNAPSHOT_CHUNK, snapshot_chunks

    room = PAYLOAD - SNAPSHOT_CHUNK.size
    assert len(snapshot_chunks(1, bytes(65535 * room))) == 65535
    with pytest.raises(ValueError, match="^map snapshot too large to chunk$"):
        snapshot_chunks(1, bytes(65535 * room + 1))
