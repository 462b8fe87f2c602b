"""Open a one-hour recording and seek in it: the replay targets.

Synthesises a .tlog of one vehicle flying for an hour at 20 Hz (heartbeat and
status at 1 Hz, GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE at 20 Hz,
three DISTANCE_SENSOR readings at 10 Hz, the memory map in TUNNEL snapshots
and deltas: about 330,000 messages), then times opening it (index + the first
seek) and seeking to random times. Targets: open under 5 s, seek under 300 ms.
Run: python bench/replay_open.py
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np
from common import table

from groundstation.replay import Replay
from groundstation.state import Fleet
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mapstream import PAYLOAD, MapStreamer
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.tlog import TlogWriter

HOUR = 3600.0


def synthesise(path: Path, seconds: float = HOUR) -> int:
    """Write the recording; returns the number of messages."""
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    writer = TlogWriter(path)
    datum = Datum()
    memory = MemoryMap((0.0, 0.0), 100, 10)
    streamer = MapStreamer(memory, (0.0, 0.0))
    start = 1767225600.0
    count = 0
    rng = np.random.default_rng(1)
    for step in range(int(seconds * 20)):
        t = step / 20
        angle = t / 60.0
        x, y = 30 * math.cos(angle), 30 * math.sin(angle)
        lat, lon = datum.to_global(x, y)
        heading = (math.degrees(angle) + 180) % 360
        messages = [
            mavlink.MAVLink_global_position_int_message(int(t * 1000), int(lat * 1e7), int(lon * 1e7), 588000,
                                                        4000, 0, 0, 0, int(heading * 100)),
            mavlink.MAVLink_local_position_ned_message(int(t * 1000), y, x, -4.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_attitude_message(int(t * 1000), 0.0, 0.0, math.radians(heading), 0.0, 0.0, 0.0),
        ]
        if step % 20 == 0:
            messages += [mavlink.MAVLink_heartbeat_message(2, 3, 217, 4, 4, 3),
                         mavlink.MAVLink_sys_status_message(0, 0, 0, 250, 16000, 1400, 80, 0, 0, 0, 0, 0, 0)]
        if step % 2 == 0:
            origins, directions, distances = [], [], []
            for sensor in range(3):
                yaw = math.radians(heading + (sensor - 1) * 45)
                distance = float(rng.uniform(5, 35))
                messages.append(mavlink.MAVLink_distance_sensor_message(
                    int(t * 1000), 2, 4000, int(distance * 100), 1, sensor, (7 + sensor * 1) % 8, 0))
                origins.append((x, y, 4.0))
                directions.append((math.sin(yaw), math.cos(yaw), 0.0))
                distances.append(distance)
            memory.add_readings(np.array(origins), np.array(directions), np.array(distances), np.full(3, 40.0))
        for kind, payload in streamer.tick(t):
            messages.append(mavlink.MAVLink_tunnel_message(0, 0, kind, len(payload),
                                                           list(payload.ljust(PAYLOAD, b"\0"))))
        for message in messages:
            writer.write(pack(message, packer), start + t)
        count += len(messages)
    writer.close()
    return count


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "hour.tlog"
        started = time.perf_counter()
        count = synthesise(path)
        made = time.perf_counter() - started
        started = time.perf_counter()
        replay = Replay.open(path, Fleet(Datum()))
        opened = time.perf_counter() - started
        rng = np.random.default_rng(2)
        seeks = []
        for target in rng.uniform(0, replay.duration, 20):
            started = time.perf_counter()
            replay.seek(float(target))
            seeks.append(time.perf_counter() - started)
        occupied = replay.fleet.occupied(replay.fleet.get(1))
        print(f"recording: {count:,} messages, {path.stat().st_size / 1e6:.1f} MB, {replay.duration:.0f} s "
              f"(made in {made:.0f} s); after the last seek the map has {occupied} occupied cells")
        print(table(["what", "figure", "target"], [
            ["open (index + first seek)", f"{opened:.2f} s", "< 5 s"],
            ["seek, median of 20", f"{np.median(seeks) * 1000:.0f} ms", "< 300 ms"],
            ["seek, slowest of 20", f"{max(seeks) * 1000:.0f} ms", "< 300 ms"],
        ]))


if __name__ == "__main__":
    main()
