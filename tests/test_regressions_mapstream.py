"""Regression tests for MapReceiver bugs (each failed before its fix)."""

import math
import struct

import numpy as np

from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.mapstream import MAP_DELTA, MAP_SNAPSHOT, PATH, MapReceiver, MapStreamer


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
