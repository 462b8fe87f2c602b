"""Ten simulated vehicles streaming at once over loopback UDP: message rates, loss, and their CPU.

Starts ten ``vehicle sim`` processes flying Search in the default scene at
real time, all sending to one UDP port where this script listens with
pymavlink like a ground station (and sends GCS heartbeats back). Loss is
counted from the MAVLink sequence numbers of each vehicle. Targets: 20 Hz
pose, every sonar reading and the map deltas with no loss, the ten vehicles
together under one core. Run: python bench/mavlink_load.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time
from collections import Counter, defaultdict

from common import DEFAULT_SCENE, table

from vehicle.protocol.mav import mavlink, mavutil

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--vehicles", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    port = free_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    gcs.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    starts = [(0, 0), (-4, -4), (4, -3), (-3, 4), (6, 6), (-7, 1), (1, -7), (8, -1), (-8, -6), (3, 9)]
    sims = []
    for index in range(args.vehicles):
        x, y = starts[index % len(starts)]
        sims.append(subprocess.Popen(
            [sys.executable, "-m", "vehicle.cli", "sim", "--scene", str(DEFAULT_SCENE), "--mission", "search",
             f"--start={x},{y}", "--sysid", str(index + 1), "--autostart", "--mavlink",
             f"udpout:127.0.0.1:{port}"], stdout=subprocess.DEVNULL))
    counts: dict[int, Counter] = defaultdict(Counter)
    last_seq: dict[tuple[int, int], int] = {}
    lost = Counter()
    warmup = time.monotonic() + 5.0  # let them start, load the scene and take off
    started = None
    cpu_start: dict[int, float] = {}
    next_beat = 0.0
    try:
        while True:
            now = time.monotonic()
            if now >= next_beat:
                gcs.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                next_beat = now + 1.0
            if started is None and now >= warmup:
                started = now
                cpu_start = {p.pid: cpu_seconds(p.pid) for p in sims}
                counts.clear()
                lost.clear()
                last_seq.clear()
            if started is not None and now - started >= args.seconds:
                break
            message = gcs.recv_match(blocking=True, timeout=0.1)
            if message is None or message.get_type() == "BAD_DATA" or started is None:
                continue
            sysid = message.get_srcSystem()
            key = (sysid, message.get_srcComponent())
            seq = message.get_seq()
            if key in last_seq:
                lost[sysid] += (seq - last_seq[key] - 1) % 256
            last_seq[key] = seq
            counts[sysid][message.get_type()] += 1
        wall = time.monotonic() - started
        cpu = sum(cpu_seconds(p.pid) - cpu_start[p.pid] for p in sims)
    finally:
        for process in sims:
            process.terminate()
        for process in sims:
            process.wait(timeout=10)
    rows = []
    for sysid in sorted(counts):
        c = counts[sysid]
        rows.append([sysid, f"{c['GLOBAL_POSITION_INT'] / wall:.1f}", f"{c['ATTITUDE'] / wall:.1f}",
                     f"{c['DISTANCE_SENSOR'] / wall:.1f}", f"{c['TUNNEL'] / wall:.1f}",
                     f"{sum(c.values()) / wall:.0f}", lost[sysid]])
    print(f"{args.vehicles} vehicles for {wall:.0f} s over loopback UDP")
    print(table(["sysid", "GLOBAL_POSITION_INT/s", "ATTITUDE/s", "DISTANCE_SENSOR/s", "TUNNEL/s", "messages/s",
                 "lost"], rows))
    total = sum(sum(c.values()) for c in counts.values())
    print(table(["vehicles", "messages/s in all", "lost in all", "CPU of all vehicles", "target"],
                [[len(counts), f"{total / wall:,.0f}", sum(lost.values()), f"{cpu / wall:.2f} core",
                  "no loss, < 1 core"]]))


if __name__ == "__main__":
    main()
