"""Start-up: what a command costs before it does anything, and the ground station's memory with a vehicle.

Each command runs in a process of its own, several times; the fastest wall time
and the peak resident memory of that run count (os.wait4's rusage). One
``vehicle experiment`` (Browse in castle from -40, 0; the default scene when
../shared is absent) is timed from process start to its JSON, and its process
overhead is that minus the ``wall_time_s`` it reports. The station serves the
default scene on loopback ports with one simulated copter flying Search; its
resident memory is read from /proc once the vehicle's map has arrived.
Targets: help under 0.3 s; an experiment's process overhead under 0.8 s; the
station under 200 MB with one vehicle.
Run: python bench/startup.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
from common import CASTLE, DEFAULT_SCENE, castle_or_default, code_state, table

BIN = Path(sys.executable).parent


PEAK = ("import runpy, sys\nsys.argv = sys.argv[1:]\ntry:\n    runpy.run_module(sys.argv[0], run_name='__main__')\n"
        "except SystemExit:\n    pass\nfinally:\n    print(next(line.split()[1] for line in open('/proc/self/status')\n"
        "               if line.startswith('VmHWM')), file=sys.stderr)")


def run(module: str, *args: str) -> tuple[float, float, str]:
    """Wall seconds, peak resident MB (VmHWM, read by the process itself as it ends) and standard output of
    one run of ``python -m module args``."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", PEAK, module, *args], capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{module} {' '.join(args)} failed: {done.stderr}")
    return wall, int(done.stderr.split()[-1]) / 1024, done.stdout


def best(module: str, args: list[str], repeats: int) -> tuple[float, float, str]:
    return min((run(module, *args) for _ in range(repeats)), key=lambda r: r[0])


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def resident_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def station_memory() -> float:
    port, mavlink = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    station = subprocess.Popen([str(BIN / "groundstation"), "serve", "--scene", str(DEFAULT_SCENE), "--port", str(port),
                                "--mavlink", f"udpin:127.0.0.1:{mavlink}", "--record-dir", "", "--token", "bench"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    vehicle = subprocess.Popen([str(BIN / "vehicle"), "sim", "--mission", "search", "--autostart", "--speedup", "2",
                                "--mavlink", f"udpout:127.0.0.1:{mavlink}"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as http:
            while time.monotonic() < deadline:
                try:
                    vehicles = http.get("/api/vehicles").json()
                except httpx.HTTPError:
                    vehicles = []
                if vehicles and vehicles[0]["map"]["source"] == "vehicle" and vehicles[0]["position"]:
                    break
                time.sleep(0.5)
            else:
                raise SystemExit("the vehicle's map never reached the station")
            time.sleep(10)  # a few more snapshots, trails and page frames
            return resident_mb(station.pid)
    finally:
        vehicle.terminate()
        station.terminate()
        vehicle.wait(10)
        station.wait(10)


def main() -> None:
    parser = argparse.ArgumentParser(description="Start-up time and memory of the commands.")
    parser.add_argument("--repeats", type=int, default=5, help="runs per command; the fastest counts")
    args = parser.parse_args()
    rows = []
    for name in ("vehicle --help", "vehicle scene --help", "groundstation --help"):
        program, *rest = name.split()
        wall, peak, _ = best(f"{program}.cli", rest, args.repeats)
        rows.append([f"`{name}`", f"{wall:.2f} s", f"{peak:.0f} MB", "< 0.3 s"])
    scene = castle_or_default()
    start = ["--start=-40,0"] if scene == CASTLE else []
    command = ["experiment", "--scene", str(scene), "--mission", "browse", *start, "--json"]
    run("vehicle.cli", *command)  # the first run may compile the simulation's loops (once after an install)
    wall, peak, out = best("vehicle.cli", command, args.repeats)
    inside = json.loads(out)["wall_time_s"]
    rows.append([f"`vehicle experiment` (browse in {scene.name}), process overhead",
                 f"{wall - inside:.2f} s (of {wall:.2f} s)", f"{peak:.0f} MB", "< 0.8 s"])
    rows.append(["ground station, default scene, one simulated copter", "-", f"{station_memory():.0f} MB resident",
                 "< 200 MB"])
    print(f"{code_state()}; load average {os.getloadavg()[0]:.2f}\n")
    print(table(["what", "wall time", "memory", "target"], rows))


if __name__ == "__main__":
    main()
