"""The same Search in castle, flown by the agent in-process, over MAVLink against our simulator as a plain
autopilot, and over MAVLink against ArduCopter SITL: outcome, detections, distance, the autopilot's time, and
the agent's CPU time per second of the autopilot's clock.

castle.wrl from (-40, 0) (the project's default scene when ../shared is absent); our autopilot and SITL run
at --speedup 10; SITL gets the scene's sonar fed back as a proximity sensor (--sensors scene) and its home at
the datum's position of the start. The simulated time over MAVLink includes the wait for the autopilot to be
ready (ArduPilot's EKF takes about 45 s). Each flight runs once.
Run: python bench/companion.py [--mission search] [--speedup 10]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import CASTLE, ROOT, castle_or_default, code_state, table

from vehicle.lab.experiment import Experiment, run_experiment, warm_up
from vehicle.protocol.geodesy import Datum

SITL = ROOT.parent / "shared" / "sitl"
VEHICLE = [sys.executable, "-m", "vehicle.cli"]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def agent(url: str, mission: str, scene: Path, sensors: str) -> tuple[dict, float]:
    """Run ``vehicle agent``; its result and the CPU seconds it used."""
    process = subprocess.Popen([*VEHICLE, "agent", "--connect", url, "--mission", mission, "--scene", str(scene),
                                "--sensors", sensors, "--json"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               text=True)
    out = process.stdout.read()
    _, _, usage = os.wait4(process.pid, 0)
    return json.loads(out.strip().splitlines()[-1]), usage.ru_utime + usage.ru_stime


def in_process(scene: Path, start, mission: str) -> tuple[dict, float]:
    warm_up()
    cpu = time.process_time()
    result = run_experiment(Experiment(str(scene), mission, start=start))
    return result, time.process_time() - cpu


def against_our_autopilot(scene: Path, start, mission: str, speedup: float) -> tuple[dict, float]:
    port = free_udp_port()
    where = [f"--start={start[0]},{start[1]}"] if start else []
    sim = subprocess.Popen([*VEHICLE, "sim", "--role", "autopilot", "--scene", str(scene), *where, "--speedup",
                            str(speedup), "--mavlink", f"udpout:127.0.0.1:{port}"], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    try:
        return agent(f"udpin:127.0.0.1:{port}", mission, scene, "fc")
    finally:
        sim.terminate()
        sim.wait()


def against_sitl(scene: Path, start, mission: str, speedup: float) -> tuple[dict, float] | None:
    if not (SITL / "arducopter").exists():
        return None
    lat, lon = Datum().to_global(*(start or (0.0, 0.0)))
    folder = tempfile.mkdtemp(prefix="sitl-")
    sitl = subprocess.Popen([str(SITL / "arducopter"), "--model", "+", "--speedup", str(speedup), "-I", "2", "-w",
                             "--defaults", f"{SITL / 'copter.parm'},{SITL / 'proximity.parm'}", "--home",
                             f"{lat},{lon},{Datum().alt},0"], cwd=folder, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        time.sleep(0.5)
        return agent("tcp:127.0.0.1:5780", mission, scene, "scene")
    finally:
        sitl.terminate()
        sitl.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission", default="search")
    parser.add_argument("--speedup", type=float, default=10.0)
    args = parser.parse_args()
    scene = castle_or_default()
    start = (-40.0, 0.0) if scene == CASTLE else None
    flights = [("in-process (experiment)", in_process(scene, start, args.mission)),
               (f"MAVLink, vehicle sim --role autopilot x{args.speedup:g}",
                against_our_autopilot(scene, start, args.mission, args.speedup)),
               (f"MAVLink, ArduCopter SITL x{args.speedup:g}, --sensors scene",
                against_sitl(scene, start, args.mission, args.speedup))]
    rows = []
    for name, flown in flights:
        if flown is None:
            rows.append([name, "skipped (no ../shared/sitl)", "", "", "", ""])
            continue
        result, cpu = flown
        simulated = result.get("sim_time_s") or 0.0
        rows.append([name, f"{result['outcome']} ({result['reason']})", result.get("detections", 0),
                     f"{result.get('distance_m', 0):.0f} m", f"{simulated:.0f} s",
                     f"{1000 * cpu / simulated:.1f} ms" if simulated else "-"])
    print(f"{code_state()}; {args.mission} in {scene.name}; load average {os.getloadavg()[0]:.2f}\n")
    print(table(["flown", "outcome", "detections", "distance", "autopilot time", "agent CPU per autopilot s"],
                rows))


if __name__ == "__main__":
    main()
