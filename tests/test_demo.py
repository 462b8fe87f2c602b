"""The README's first command: ``groundstation demo`` serves the page and flies a simulated vehicle.

Runs the real command as a user would (a subprocess on free ports) and stops it
the way a service manager does, with SIGTERM: the vehicles must go down with it,
or the next demo would meet an orphan flying on its port. The station's terminal
stays quiet while it runs.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from harness import free_port, wait_wall

WAIT = 120.0  # s: generous, the demo's vehicles start as separate processes on a busy machine


def processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def vehicles(port: int) -> list[dict]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/vehicles", timeout=5) as response:
        return json.load(response)


def demo_vehicles(process: subprocess.Popen, port: int) -> list[dict]:
    """The demo's vehicles as its station lists them (none while it starts up); fails at once if it exited."""
    assert process.poll() is None, f"the demo exited: {process.stdout.read()}"
    try:
        return vehicles(port)
    except OSError:
        return []


def wait_vehicles_gone(mavlink_port: int) -> None:
    wait_wall(lambda: processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}"), 10,
              "every vehicle process of the demo gone (a vehicle outlived the demo)", period=0.2,
              done=lambda pids: not pids)


@pytest.fixture
def demo(tmp_path):
    port, mavlink_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    command = [sys.executable, "-m", "groundstation.cli", "demo", "--port", str(port), "--mavlink-port",
               str(mavlink_port), "--token", "demo-token", "--record-dir", str(tmp_path), "--speedup", "4",
               "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    yield process, port, mavlink_port, tmp_path
    if process.poll() is None:
        process.kill()
    for pid in processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}"):
        os.kill(pid, signal.SIGKILL)


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc to find the vehicle processes")
def test_the_demo_flies_a_vehicle_and_stops_with_it_on_sigterm(demo):
    process, port, mavlink_port, record_dir = demo
    def airborne(vehicle: dict) -> bool:
        return vehicle["armed"] and vehicle["position"] and vehicle["position"]["z"] > 1.0

    seen = wait_wall(lambda: demo_vehicles(process, port), WAIT, "a vehicle of the demo's in the air", period=0.5,
                     done=lambda listed: any(airborne(v) for v in listed))
    flying = next(v for v in seen if airborne(v))
    assert flying["type"] == "copter" and flying["mode"] == "GUIDED"
    assert processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}"), "the vehicle runs as its own process"
    assert list(record_dir.glob("session-*.tlog")), "the demo records its session"

    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0
    output = process.stdout.read()
    assert "ground station: http://127.0.0.1:" in output and "#token=demo-token" in output
    assert "viser" not in output.lower(), "no banner naming the 3D view's internal port"
    wait_vehicles_gone(mavlink_port)


def test_the_demo_sends_to_a_free_port_when_another_ground_station_holds_14550(capsys):
    """QGroundControl listens on 14550: the demo's station cannot (it no longer shares a UDP port), and only it
    listens to the demo's vehicles, so any free port will do, and it says which."""
    from groundstation.cli import _demo_port

    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        holder.bind(("127.0.0.1", 14550))
    except OSError:
        pass  # another program holds it already: the very case
    try:
        port = _demo_port()
        assert port != 14550
        assert f"UDP port 14550 is taken (another ground station?); the vehicles send to {port}" in \
            capsys.readouterr().out
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", port))  # free
    finally:
        holder.close()


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc to find the vehicle processes")
def test_a_vehicle_process_that_exits_stops_the_demo_saying_which(tmp_path):
    """A bad --mission is the agent's usage error: the demo went on serving a vehicle without its agent."""
    port, mavlink_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    done = subprocess.run([sys.executable, "-m", "groundstation.cli", "demo", "--port", str(port), "--mavlink-port",
                           str(mavlink_port), "--record-dir", "", "--mission", "hover", "--quiet"],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 1
    assert "demo: vehicle 1's onboard agent exited with code 2; stopping" in done.stderr
    assert "invalid choice: 'hover'" in done.stderr
    assert processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}") == []  # its flight controller went too


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc to find the vehicle processes")
def test_ctrl_c_stops_the_demo_and_its_vehicles_quietly(tmp_path):
    """A terminal's Ctrl-C goes to the whole foreground group: the vehicles died beside the station, the
    onboard agent with a KeyboardInterrupt traceback. They now run in their own sessions; the station stops
    them, and no vehicle counts as having failed."""
    port, mavlink_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    process = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "demo", "--port", str(port),
                                "--mavlink-port", str(mavlink_port), "--record-dir", "", "--speedup", "4"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        wait_wall(lambda: demo_vehicles(process, port), WAIT, "a vehicle's onboard agent heard", period=0.5,
                  done=lambda listed: any(v["agent"] for v in listed))
        assert processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}")
        os.killpg(process.pid, signal.SIGINT)
        assert process.wait(timeout=30) == 0
        output = process.stdout.read()
        assert "Traceback" not in output and "exited with code" not in output, output
        wait_vehicles_gone(mavlink_port)
    finally:
        if process.poll() is None:
            process.kill()


DRAWN_FOR_A_VIEWER_GONE = """
import sys
import viser
if sys.argv[1] == "station":
    import groundstation.viz
server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
server.stop()  # its connections closed, as a viewer's when it closes its page
server.scene.add_frame("/x", show_axes=False)  # a frame drawn meanwhile: never delivered
"""


@pytest.mark.parametrize(("importer", "warned"), [("viser alone", True), ("station", False)])
def test_a_frame_drawn_for_a_viewer_that_just_left_warns_nobody_on_the_stations_terminal(importer, warned):
    """viser warns when a frame is queued for a closed connection: the station draws every viewer's frame, so a
    viewer closing its page between two frames put a warning on the operator's terminal."""
    done = subprocess.run([sys.executable, "-c", DRAWN_FOR_A_VIEWER_GONE, importer], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parent.parent)
    assert done.returncode == 0, done.stderr
    assert ("on a closed connection" in done.stderr) is warned, done.stderr
