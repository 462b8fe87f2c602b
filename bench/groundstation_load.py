"""The ground station under load: pose-to-browser latency, and CPU and memory with ten vehicles and viewers.

Runs ``groundstation serve`` as its own process and feeds it ten synthetic
vehicles (HEARTBEAT at 1 Hz; GLOBAL_POSITION_INT and ATTITUDE at 20 Hz) over
loopback UDP. Nine viewers read the 3D view's websocket through the app's
proxy and one real browser (headless Chromium with Playwright) shows the page.
Vehicle 1 moves 10 cm east with every pose, so a viewer that decodes the
viser frames can tell which pose a frame shows and how long it took to get
there. The browser's view follows vehicle 1 (camera mode "follow"), and the
frames it draws a second are counted in its 3D view (animation frames in the
view's document, software WebGL as the harness's Chromium flags give it).
Targets: latency p50 < 10 ms and p99 < 30 ms at 20 Hz (viser alone takes
about 4 ms; the 3D view sends a pose as it comes); the server under one core
and 400 MB RSS. Run: python bench/groundstation_load.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time

import msgspec
import numpy as np
import websockets
import zstandard
from common import table

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink, pack

TICKS = os.sysconf("SC_CLK_TCK")
STEP = 0.1  # m east per pose of vehicle 1
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


# counts the frames the 3D view's document draws (requestAnimationFrame runs once per frame it paints)
COUNT_FRAMES = """() => { window.__frames = 0;
  const tick = () => { window.__frames += 1; requestAnimationFrame(tick); };
  requestAnimationFrame(tick); }"""


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def process_figures(pid: int) -> tuple[float, float]:
    """CPU seconds used so far, and resident memory in MB."""
    with open(f"/proc/{pid}/stat") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    with open(f"/proc/{pid}/status") as handle:
        rss = next(int(line.split()[1]) for line in handle if line.startswith("VmRSS"))
    return (int(fields[11]) + int(fields[12])) / TICKS, rss / 1024


class Vehicles(threading.Thread):
    """Ten synthetic vehicles at 20 Hz; remembers when each pose of vehicle 1 was sent."""

    def __init__(self, port: int, count: int = 10):
        super().__init__(daemon=True)
        self.address = ("127.0.0.1", port)
        self.count = count
        self.sent: dict[int, float] = {}  # pose number of vehicle 1 -> send time (perf_counter)
        self.stop = threading.Event()
        self.datum = Datum()

    def run(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        packers = [mavlink.MAVLink(None, srcSystem=i + 1, srcComponent=1) for i in range(self.count)]
        k = 0
        next_tick = time.perf_counter()
        while not self.stop.is_set():
            for index, packer in enumerate(packers):
                x = k * STEP if index == 0 else 5.0 * index
                lat, lon = self.datum.to_global(x, 10.0 * index)
                messages = [mavlink.MAVLink_global_position_int_message(k * 50, int(round(lat * 1e7)),
                                                                        int(round(lon * 1e7)), 588000, 4000,
                                                                        0, 200, 0, 9000),
                            mavlink.MAVLink_attitude_message(k * 50, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0)]
                if k % 20 == 0:
                    messages.insert(0, mavlink.MAVLink_heartbeat_message(2, 3, 217, 4, 4, 3))
                for message in messages:
                    sock.sendto(pack(message, packer), self.address)
            self.sent[k] = time.perf_counter()
            k += 1
            next_tick += 0.05
            time.sleep(max(0.0, next_tick - time.perf_counter()))


def decode_frame(frame: bytes) -> list[dict]:
    size = int.from_bytes(frame[:8], "little")
    compressed = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16:16 + compressed], max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


def body_x(messages: list[dict]) -> float | None:
    """The last x position of vehicle 1's body in a viser frame, if the frame moves it."""
    found = None
    for message in messages:
        if message.get("name") == "/vehicles/1/body":
            props = message.get("updates") or message.get("props") or message
            position = props.get("position") if isinstance(props, dict) else None
            if position is not None:
                found = float(position[0])
    return found


async def viewer(url: str, vehicles: Vehicles, latencies: list[float] | None, until: float) -> int:
    frames = 0
    async with websockets.connect(url, subprotocols=["viser-v1.1.1"], max_size=None) as socket_:
        while time.perf_counter() < until:
            try:
                frame = await asyncio.wait_for(socket_.recv(), timeout=1.0)
            except TimeoutError:
                continue
            arrived = time.perf_counter()
            frames += 1
            if latencies is None or not isinstance(frame, bytes):
                continue
            x = body_x(decode_frame(frame))
            if x is not None:
                sent = vehicles.sent.get(round(x / STEP))
                if sent is not None:
                    latencies.append(arrived - sent)
    return frames


async def viewers(url: str, vehicles: Vehicles, count: int, seconds: float) -> tuple[list[float], int]:
    latencies: list[float] = []
    until = time.perf_counter() + seconds
    frames = await asyncio.gather(*(viewer(url, vehicles, latencies if i == 0 else None, until)
                                    for i in range(count)))
    return latencies, sum(frames)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    web, udp = free_port(), free_port(socket.SOCK_DGRAM)
    with tempfile.TemporaryDirectory() as records:
        server = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "serve", "--mavlink",
                                   f"udpin:127.0.0.1:{udp}", "--port", str(web), "--token", "bench",
                                   "--record-dir", records], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  text=True)
        vehicles = Vehicles(udp)
        try:
            for line in server.stdout:
                if "ground station:" in line:
                    break
            vehicles.start()
            time.sleep(2.0)
            from playwright.sync_api import sync_playwright

            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1200, "height": 760})
                page.goto(f"http://127.0.0.1:{web}/#token=bench")
                page.frame_locator("#view").locator("canvas").first.wait_for(timeout=120_000)
                # the camera chases vehicle 1 (the view's frame may be loading: no wait for its navigation)
                page.click('#view3d [data-camera-mode="follow"]', no_wait_after=True)
                time.sleep(3.0)
                view = page.frame_locator("#view").locator("body")
                view.evaluate(COUNT_FRAMES, timeout=120_000)
                browser_frames0 = view.evaluate("() => [window.__frames, performance.now()]")
                cpu0, _ = process_figures(server.pid)
                started = time.perf_counter()
                outcome: dict = {}  # the viewers get their own thread: Playwright's sync API holds this one's loop
                worker = threading.Thread(target=lambda: outcome.update(result=asyncio.run(
                    viewers(f"ws://127.0.0.1:{web}/viz", vehicles, 9, args.seconds))))
                worker.start()
                while worker.is_alive():
                    page.wait_for_timeout(500)  # keep the browser's page alive and drawing
                latencies, frames = outcome["result"]
                wall = time.perf_counter() - started
                browser_frames1 = view.evaluate("() => [window.__frames, performance.now()]")
                browser_fps = (browser_frames1[0] - browser_frames0[0]) / (browser_frames1[1] - browser_frames0[1]) \
                    * 1000
                cpu1, rss = process_figures(server.pid)
                load = os.getloadavg()[0]  # other work on the machine shows in the latency's tail
                browser.close()
        finally:
            vehicles.stop.set()
            server.terminate()
            server.wait(timeout=10)
    ms = np.array(latencies) * 1000
    print(f"10 vehicles at 20 Hz, 9 websocket viewers + 1 browser, {wall:.0f} s; {frames} frames to the "
          f"viewers; {len(ms)} poses of vehicle 1 timed")
    print(table(["what", "figure", "target"], [
        ["pose -> viewer frame, p50", f"{np.percentile(ms, 50):.1f} ms" if len(ms) else "-", "< 10 ms"],
        ["pose -> viewer frame, p99", f"{np.percentile(ms, 99):.1f} ms" if len(ms) else "-", "< 30 ms"],
        ["browser, follow mode (software WebGL)", f"{browser_fps:.1f} frames/s", "-"],
        ["server CPU", f"{(cpu1 - cpu0) / wall:.2f} core", "< 1 core"],
        ["server RSS", f"{rss:.0f} MB", "< 400 MB"],
        ["machine load at the end (1 min average)", f"{load:.1f} on {os.cpu_count()} cores", "-"],
    ]))


if __name__ == "__main__":
    main()
