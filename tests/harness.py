"""The one test harness: real ground stations, simulated vehicles on real sockets, Chromium, and the waits.

- ``RunningStation``: a ``GroundStation`` and its web app under uvicorn on a
  thread, listening for MAVLink on a free UDP port (``udpin``), recording to a
  folder; ``station.api()`` gives an httpx client that knows the operator token.
- ``RunningSim``: a simulated vehicle (``vehicle sim``'s SimVehicle) on a
  thread; ``start_sim`` makes one that sends to a station.
- Waits: ``wait_sim`` bounds a wait in the vehicle's simulated time (as
  ArduPilot's autotest waits on SITL time), with a wall-clock backstop so a
  vehicle that stops talking fails a test instead of hanging it; ``wait_wall``
  bounds a wait on what runs on the wall clock (the status stream, link loss).
  Both raise ``WaitTimeout`` saying "waited N s for X; last seen: Y" (as
  ArduPilot's autotest does). ``during`` paces what a test keeps doing for a
  while (a flood, collecting frames); ``read_until`` watches a process's output.
  No test writes a ``while time.monotonic() < deadline`` loop of its own.
- ``launch_chromium``: Debian's Chromium with the flags that give WebGL
  through SwiftShader (software WebGL); a browser is never downloaded.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import os
import re
import selectors
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.security import Access
from groundstation.server import GroundStation, app_config
from vehicle.agent.settings import Settings
from vehicle.lab.live import SimOptions, SimVehicle
from vehicle.lab.stepper import Stepper, simulate
from vehicle.sim.battery import Battery
from vehicle.world.bundled import default_scene
from vehicle.world.scene import Scene, load_scene, parse_scene

TOKEN = "test-operator-token"
SPEEDUP = 10.0
# heartbeats (mode, armed) come once a wall second, that is every SPEEDUP simulated seconds: waits on them
# need that much simulated time and some
HEARTBEAT_WAIT = 2.5 * SPEEDUP
WALL_Y = 8.0  # the south face of a wall north of the origin in ``small_scene``
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
NO_CHROMIUM = "needs Debian's chromium at /usr/bin/chromium (./scripts/test.sh installs it)"
needs_chromium = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=NO_CHROMIUM)


def skip_module_without_chromium() -> None:
    """Called at the top of a browser test module: skips the whole module on a machine without Chromium, before
    it imports Playwright."""
    if not Path(CHROMIUM).exists():
        pytest.skip(NO_CHROMIUM, allow_module_level=True)

# flat ground, a wall north of the start and one east of it: something for the sonar to see
SCENE_TEXT = f"""#VRML V2.0 utf8
Transform {{ translation 0 0 -0.5 children Shape {{ geometry Box {{ size 80 80 1 }} }} }}
Transform {{ translation 0 {WALL_Y + 0.25} 3 children Shape {{ geometry Box {{ size 20 0.5 6 }} }} }}
Transform {{ translation 9.25 0 3 children Shape {{ geometry Box {{ size 0.5 12 6 }} }} }}
"""


class WaitTimeout(AssertionError):
    """A condition did not come true within its budget."""


class StationClock:
    """The station's retry clock in a test (``Link.retry_clock``): it stands still until the test moves it, so
    however slow the machine, a try waits exactly as long as the test says (it starts at 1024 s and moves by
    1/1024ths: sums are exact)."""

    def __init__(self):
        self.now = 1024.0

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def small_scene() -> Scene:
    return parse_scene(SCENE_TEXT)


def load_default_scene() -> Scene:
    return load_scene(default_scene())


# ---- ports ----------------------------------------------------------------------------------------------
PORT_BLOCK = 1500  # ports a test worker hands out, at most, before it uses them again


def _ports_to_hand_out() -> Iterator[int]:
    """Ports for what a test starts (a station's web or MAVLink port), in a block below the kernel's range for
    sockets bound to port 0: every client socket takes one of those, and with a port from there another test
    could take it between the probe and its use. Each pytest-xdist worker has a block of its own."""
    try:
        ephemeral = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        ephemeral = 32768  # Linux's default
    worker = os.environ.get("PYTEST_XDIST_WORKER", "").removeprefix("gw")
    first = ephemeral - PORT_BLOCK * (int(worker) + 1) if worker.isdigit() else 0
    if first < 1024:  # not a worker (other runs of the tests may be beside it), or no room below the range:
        return itertools.repeat(0)  # the kernel's choice, as a probe on port 0 gets it
    return itertools.cycle(range(first, first + PORT_BLOCK))


_ports = _ports_to_hand_out()
_ports_lock = threading.Lock()


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port on 127.0.0.1 nothing holds now, of this kind (``socket.SOCK_DGRAM`` or ``SOCK_STREAM``)."""
    with _ports_lock:
        for _ in range(PORT_BLOCK):
            with socket.socket(socket.AF_INET, kind) as probe:
                try:
                    probe.bind(("127.0.0.1", next(_ports)))
                except OSError:  # held by something else on the machine, or a closed TCP port's TIME_WAIT
                    continue
                return probe.getsockname()[1]
    raise OSError(f"no free port among the {PORT_BLOCK} this test worker hands out")


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def free_tcp_port() -> int:
    return free_port(socket.SOCK_STREAM)


# ---- waits ----------------------------------------------------------------------------------------------
def wait_sim(read: Callable[[], tuple[object, float | None]], condition: Callable[[object], object],
             sim_timeout: float, speedup: float = SPEEDUP, what: str = "condition"):
    """The first value ``read()`` gives that ``condition`` holds for, within ``sim_timeout`` seconds of the
    vehicle's simulated time. ``read`` returns (value or None, the vehicle's latest simulated time or None);
    the wall clock only backs the wait up (four times the budget at ``speedup``, and 15 s)."""
    start = last = None
    for _ in during(sim_timeout / speedup * 4 + 15, period=0):
        value, sim = read()
        if value is not None:
            last = value
            if condition(value):
                return value
        if sim is not None:
            start = sim if start is None else start
            if sim - start > sim_timeout:
                break
    raise WaitTimeout(f"waited {sim_timeout:g} s of simulated time for {what}; last seen: {last}")


def wait_wall(condition: Callable[[], object], timeout: float, what: str = "condition", period: float = 0.05,
              sleep: Callable[[], None] | None = None, done: Callable[[object], object] = bool):
    """``condition()``'s first value that ``done`` holds for (truthy, unless told) within ``timeout`` wall
    seconds (for wall-clock properties).

    ``sleep`` replaces ``time.sleep(period)``: with Playwright's sync API, events (websocket
    frames, requests) reach their handlers only while Playwright waits, so pass a page's wait."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if done(value):
            return value
        if time.monotonic() > deadline:
            raise WaitTimeout(f"waited {timeout:g} s for {what}; last seen: {value!r}")
        if sleep is not None:
            sleep()
        else:
            time.sleep(period)


def during(seconds: float, period: float = 0.0) -> Iterator[float]:
    """Yields the seconds left, until ``seconds`` wall seconds have passed, sleeping ``period`` between turns:
    for what a test keeps doing for a while (commands under a flood, frames a stream brings), not a wait."""
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        yield left
        if period:
            time.sleep(period)


def read_until(process: subprocess.Popen, pattern: str, timeout: float) -> tuple[str, str]:
    """A process's stdout and stderr (``""`` for one not piped) read until the regular expression ``pattern``
    matches its stdout, it exits, or ``timeout`` wall seconds pass (the caller asserts on what it read)."""
    streams = {stream: [] for stream in (process.stdout, process.stderr) if stream is not None}
    chooser = selectors.DefaultSelector()
    for stream in streams:
        chooser.register(stream, selectors.EVENT_READ)
    for _ in during(timeout):
        if re.search(pattern, b"".join(streams[process.stdout]).decode(errors="replace")):
            break
        for key, _ in chooser.select(timeout=0.2):
            data = os.read(key.fileobj.fileno(), 65536)
            if data:
                streams[key.fileobj].append(data)
            else:
                chooser.unregister(key.fileobj)
        if process.poll() is not None and not chooser.get_map():
            break
    chooser.close()
    return tuple(b"".join(streams.get(s, [])).decode(errors="replace") for s in (process.stdout, process.stderr))


# ---- vehicles ---------------------------------------------------------------------------------------------
class RunningSim:
    """A SimVehicle on its own thread, talking over real UDP sockets (a context manager, or start/stop)."""

    def __init__(self, stepper: Stepper, urls: list[str], speedup: float = SPEEDUP, **options):
        self.sim = SimVehicle(stepper, SimOptions(urls, speedup=speedup, **options))
        self.world = stepper.simulation
        self.speedup = speedup
        self.thread = threading.Thread(target=self.sim.run, daemon=True)

    def __enter__(self) -> SimVehicle:
        self.thread.start()
        return self.sim

    def __exit__(self, *exc) -> None:
        self.sim.stop()
        self.thread.join(timeout=5)

    def start(self) -> RunningSim:
        self.__enter__()
        return self

    def stop(self) -> None:
        if self.thread.is_alive():
            self.__exit__(None, None, None)


def make_vehicle(scene: Scene, kind: str = "copter", mission: str = "browse", autostart: bool = False,
                 settings: Settings | None = None, start: tuple[float, ...] | None = None) -> Stepper:
    """A test's vehicle, with ten times the battery: at SPEEDUP a copter hovering through a module that a slow
    machine takes minutes over would reach the battery failsafe and land under the tests."""
    return simulate(scene, mission, kind, settings or Settings(space_size=20), start, autostart=autostart,
                    battery=Battery(capacity_mah=50_000.0, charge_mah=50_000.0))


def start_sim(station: RunningStation, scene: Scene, sysid: int = 1, kind: str = "copter", mission: str = "browse",
              autostart: bool = False, start: tuple[float, ...] | None = None, settings: Settings | None = None,
              speedup: float = SPEEDUP, hovering: float | None = None, **options) -> RunningSim:
    """A simulated vehicle sending to the station (not started: use it as a context manager or ``start()``);
    ``hovering``: already up at that altitude, its mission paused (``hover``)."""
    stepper = make_vehicle(scene, kind, mission, autostart, settings, start)
    if hovering is not None:
        hover(stepper, hovering)
    return RunningSim(stepper, [station.vehicle_url()], speedup=speedup, sysid=sysid, **options)


def hover(stepper: Stepper, altitude: float, sim_timeout: float = 30.0) -> None:
    """Take a copter up and have the operator take over, in simulated time before it goes live: what
    ``take_off`` does over the API, where a test machine slow to answer would let the mission that a take-off
    starts fly the vehicle elsewhere (or finish, and land it) before the operator's BRAKE. Then the vehicle
    hovers in GUIDED over its start, its agent paused, whatever the machine's load."""
    pilot, agent = stepper.simulation.autopilot, stepper.agent
    for request in (lambda: pilot.set_mode("GUIDED"), pilot.arm, lambda: pilot.takeoff(altitude)):
        assert request() == mavlink.MAV_RESULT_ACCEPTED
    reached = stepper.run(sim_timeout, until=lambda: pilot.altitude > altitude - 0.3 and not pilot.taking_off)
    assert reached, f"take-off to {altitude} m: not reached within {sim_timeout:g} s of simulated time"
    pilot.set_mode("BRAKE")
    stepper.run(1.0)
    pilot.set_mode("GUIDED")
    paused = stepper.run(sim_timeout, until=lambda: agent is None or agent.paused)
    assert paused, "the agent did not notice the operator's take-over"


# ---- the ground station ------------------------------------------------------------------------------------
class RunningStation:
    """GroundStation on ``udpin:127.0.0.1:<free port>`` with its app served by uvicorn on a thread."""

    def __init__(self, scene: Scene | None, record_dir: str | Path | None, token: str = TOKEN,
                 urls: list[str] | None = None, access: Access | None = None, http_port: int | None = None,
                 **station):
        """``urls``: the MAVLink links (default: ``udpin`` on a free port, which ``vehicle_url`` sends to);
        ``access``: who may reach the app (default: as when served on loopback); ``http_port``: the web port
        (default: a free one; a restarted station takes its predecessor's)."""
        self.mavlink_port = free_udp_port()
        self.url = f"udpin:127.0.0.1:{self.mavlink_port}"
        self.station = GroundStation(urls or [self.url], scene, token, record_dir, **station)
        self.token = token
        self.http_port = http_port or free_tcp_port()
        self.base = f"http://127.0.0.1:{self.http_port}"
        config = app_config(self.station, "127.0.0.1", self.http_port, access=access)
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)

    def __enter__(self) -> RunningStation:
        self._thread.start()
        wait_wall(lambda: self.server.started or not self._thread.is_alive(), 20, "uvicorn started")
        assert self.server.started, "uvicorn did not start"
        self.station.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)
        if "http" in self.__dict__:
            self.http.close()
        self.station.close()

    def vehicle_url(self) -> str:
        """The pymavlink URL a vehicle sends to."""
        return f"udpout:127.0.0.1:{self.mavlink_port}"

    def api(self, **kwargs) -> Api:
        """A new httpx client for the station (close it, or use it as a context manager)."""
        return Api(self.base, self.token, **kwargs)

    @functools.cached_property
    def http(self) -> Api:
        """The station's own client, closed with it."""
        return self.api()


@contextlib.contextmanager
def idle_station(scene: Scene | None = None, record_dir: str | Path | None = None, urls: list[str] | None = None,
                 token: str = TOKEN, **station) -> Iterator[GroundStation]:
    """A ``GroundStation`` neither started nor served (no MAVLink link unless ``urls``), closed on the way out:
    for what the station object itself does (replays, its datum, the 3D view's drawing) without a web server.
    A test of ``serve`` builds its own: ``serve`` closes the station it is given."""
    ground = GroundStation(urls or [], scene, token, record_dir, **station)
    try:
        yield ground
    finally:
        ground.close()


class Api(httpx.Client):
    """httpx client for the station that knows the operator token."""

    def __init__(self, base: str, token: str, timeout: float = 30.0):
        super().__init__(base_url=base, timeout=timeout)
        self.token = token

    @property
    def operator(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}

    def command(self, sysid: int, **body) -> httpx.Response:
        return self.post(f"/api/vehicles/{sysid}/commands", json=body, headers=self.operator)

    def result(self, sysid: int, **body) -> str:
        """POST a command with the token; the vehicle's ACK result ("accepted", ...)."""
        response = self.command(sysid, **body)
        assert response.status_code == 200, (response.status_code, response.text)
        return response.json()["result"]

    def vehicles(self) -> dict[int, dict]:
        return {v["sysid"]: v for v in self.get("/api/vehicles").json()}

    def vehicle(self, sysid: int) -> dict | None:
        response = self.get(f"/api/vehicles/{sysid}")
        return response.json() if response.status_code == 200 else None

    def wait_vehicle(self, sysid: int, condition: Callable[[dict], object], sim_timeout: float = 30.0,
                     speedup: float = SPEEDUP, what: str = "condition") -> dict:
        """GET /api/vehicles/{sysid} until ``condition(vehicle)``, within ``sim_timeout`` of its simulated time."""
        def read():
            vehicle = self.vehicle(sysid)
            if vehicle is None:
                time.sleep(0.05)
                return None, None
            time.sleep(0.05)
            return vehicle, vehicle["time_boot_s"]

        return wait_sim(read, condition, sim_timeout, speedup, f"vehicle {sysid}: {what}")

    def wait_sim_time(self, sysid: int, seconds: float, speedup: float = SPEEDUP) -> dict:
        """Let ``seconds`` of the vehicle's simulated time pass."""
        start = self.wait_vehicle(sysid, lambda v: v["time_boot_s"] is not None, speedup=speedup,
                                  what="time_boot_s")["time_boot_s"]
        return self.wait_vehicle(sysid, lambda v: v["time_boot_s"] >= start + seconds, seconds + 5, speedup,
                                 f"{seconds} s of simulated time")


def command_ok(api: Api, sysid: int, **body) -> None:
    assert api.result(sysid, **body) == "accepted", body


def wait_mode(api: Api, sysid: int, mode: str) -> dict:
    return api.wait_vehicle(sysid, lambda v: v["mode"] == mode, sim_timeout=HEARTBEAT_WAIT, what=f"mode {mode}")


def wait_armed(api: Api, sysid: int, armed: bool = True) -> dict:
    return api.wait_vehicle(sysid, lambda v: v["armed"] is armed, sim_timeout=HEARTBEAT_WAIT,
                            what="armed" if armed else "disarmed")


def take_off(api: Api, sysid: int, altitude: float = 4.0, hover: bool = True) -> dict:
    """GUIDED, arm, take off; returns the vehicle once at altitude and armed. A take-off starts the onboard
    mission if it waits: with ``hover`` the operator takes over (BRAKE, then GUIDED), so the vehicle hovers."""
    for body in ({"action": "set_mode", "mode": "GUIDED"}, {"action": "arm"},
                 {"action": "takeoff", "altitude": altitude}):
        command_ok(api, sysid, **body)
    api.wait_vehicle(sysid, lambda v: v["position"] is not None and v["position"]["alt"] > altitude - 0.3,
                     sim_timeout=30, what="take-off altitude")
    if hover:
        command_ok(api, sysid, action="set_mode", mode="BRAKE")
        command_ok(api, sysid, action="set_mode", mode="GUIDED")
        wait_mode(api, sysid, "GUIDED")
    return wait_armed(api, sysid)


# ---- the browser -------------------------------------------------------------------------------------------
def launch_chromium(playwright):
    return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)


@contextlib.contextmanager
def operator_page(browser, base: str, token: str, width: int = 1400, height: int = 900, timeout_ms: int = 20_000):
    """The page signed in with ``token``, its 3D view's frame an empty page (the panel and the 2D map are what
    such a test is about); fails on the way out if the page had JavaScript errors or policy violations."""
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": width, "height": height})
    context.set_default_timeout(timeout_ms)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.on("console", lambda m: errors.append(m.text) if "Content Security Policy" in m.text else None)
    page.route("**/viz/**", lambda route: route.fulfill(body="<!doctype html><title>3D view left out</title>",
                                                        content_type="text/html"))
    try:
        page.goto(f"{base}/#token={token}")
        expect(page.locator("#auth-status")).to_have_text("Signed in", timeout=timeout_ms)
        yield page
    finally:
        context.close()
    assert not errors, f"JavaScript errors or policy violations on the page: {errors}"


def canvas_colours(page, selector: str) -> set[tuple[int, int, int]]:
    """The distinct colours (4 bits a channel) a canvas shows."""
    import base64
    import io

    import numpy as np
    from PIL import Image

    url = page.eval_on_selector(selector, "c => c.toDataURL('image/png')")
    image = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB")) >> 4
    return {tuple(int(c) for c in row) for row in np.unique(image.reshape(-1, 3), axis=0)}
