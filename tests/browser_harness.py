"""A real ground station, simulated copters and a headless Chromium, for the browser tests.

``Station`` runs ``groundstation.server.GroundStation`` with its web app under
uvicorn on a thread (a free port on 127.0.0.1, a known operator token, a
recording folder) listening for MAVLink on a free UDP port. ``Copter`` runs a
simulated copter in the same scene on a thread (``mavlink_gcs.RunningSim``),
sending to that port over real UDP. ``launch_chromium`` starts Debian's
Chromium with the flags that give WebGL through SwiftShader (see
FIELD-NOTES.md); a browser is never downloaded.

Every wait here is bounded: on the wall clock for what the ground station
does on the wall clock (the stream, link loss), and on the vehicle's simulated
time (``time_boot_s`` as the ground station reports it) for what the vehicle
does on its own clock, with a wall-clock backstop.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import uvicorn
from groundstation_harness import free_tcp_port, wait_wall
from mavlink_gcs import RunningSim, free_udp_port

from groundstation.app import create_app
from groundstation.server import GroundStation
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.world.scene import Scene, load_scene

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENE = ROOT / "scenes" / "default.wrl"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def poll(condition: Callable[[], object], timeout: float, interval: float = 0.1, what: str = "condition",
         sleep: Callable[[], None] | None = None):
    """The first truthy value of ``condition()`` within ``timeout`` wall seconds, else WaitTimeout."""
    return wait_wall(condition, timeout, what, interval, sleep)


class Station:
    """A GroundStation and its web app, served by uvicorn on a thread."""

    def __init__(self, scene: Scene, token: str, record_dir: Path):
        self.mavlink_port = free_udp_port()
        self.http_port = free_tcp_port()
        self.token = token
        self.station = GroundStation([f"udpin:127.0.0.1:{self.mavlink_port}"], scene, token, record_dir)
        config = uvicorn.Config(create_app(self.station), host="127.0.0.1", port=self.http_port,
                                log_level="warning", ws_ping_interval=None)
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)
        self.url = f"http://127.0.0.1:{self.http_port}"
        self.http = httpx.Client(base_url=self.url, timeout=30.0)

    def start(self) -> Station:
        self._thread.start()
        poll(lambda: self.server.started or not self._thread.is_alive(), 20, 0.05, "uvicorn started")
        assert self.server.started, "uvicorn did not start"
        self.station.start()
        return self

    def close(self) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)
        self.http.close()
        self.station.close()

    # ---- the REST API ---------------------------------------------------------------------------------
    def post(self, path: str, body: dict, token: bool = True) -> httpx.Response:
        headers = {"Authorization": f"Bearer {self.token}"} if token else {}
        return self.http.post(path, json=body, headers=headers)

    def command(self, sysid: int, **body) -> str:
        """POST a command with the token; the vehicle's ACK result ("accepted", ...)."""
        response = self.post(f"/api/vehicles/{sysid}/commands", body)
        assert response.status_code == 200, (response.status_code, response.text)
        return response.json()["result"]

    def vehicles(self) -> dict[int, dict]:
        return {v["sysid"]: v for v in self.http.get("/api/vehicles").json()}

    def vehicle(self, sysid: int) -> dict | None:
        return self.vehicles().get(sysid)

    def wait_vehicle(self, sysid: int, condition: Callable[[dict], object], sim_timeout: float,
                     speedup: float, what: str = "vehicle condition") -> dict:
        """The vehicle's description once ``condition`` holds, within ``sim_timeout`` s of its own clock
        (``time_boot_s``), with a wall-clock backstop for a vehicle that stops talking."""
        start_sim = v = None
        deadline = time.monotonic() + sim_timeout / speedup * 4 + 15
        while time.monotonic() < deadline:
            v = self.vehicle(sysid)
            if v is not None:
                if condition(v):
                    return v
                sim = v.get("time_boot_s")
                if sim is not None:
                    start_sim = sim if start_sim is None else start_sim
                    if sim - start_sim > sim_timeout:
                        break
            time.sleep(0.1)
        raise AssertionError(f"{what}: not within {sim_timeout:g} s of simulated time; last {v}")


class Copter:
    """A simulated copter in the scene, on a thread, sending MAVLink to the station's UDP port."""

    def __init__(self, scene: Scene, port: int, sysid: int, mission: str = "browse", autostart: bool = False,
                 speedup: float = 5.0, start: tuple[float, float] | None = None, settings: Settings | None = None):
        self.sysid = sysid
        self.speedup = speedup
        stepper = simulate(scene, mission, "copter", settings, start, autostart=autostart)
        self.world = stepper.simulation
        self.runner = RunningSim(stepper, [f"udpout:127.0.0.1:{port}"], speedup=speedup, sysid=sysid)
        self.running = False

    def start(self) -> Copter:
        self.runner.__enter__()
        self.running = True
        return self

    def stop(self) -> None:
        if self.running:
            self.runner.__exit__(None, None, None)
            self.running = False


def load_default_scene() -> Scene:
    return load_scene(DEFAULT_SCENE)


def launch_chromium(playwright):
    return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
