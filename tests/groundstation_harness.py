"""A real ground station for tests: GroundStation + its web app under uvicorn on loopback, simulated vehicles.

``RunningStation`` listens for MAVLink on a free UDP port (``udpin``), records
to a folder, and serves the app on a free TCP port in a background thread;
``Api`` is an httpx client with the operator token at hand. Vehicles are
``vehicle sim``'s SimVehicle on threads (``tests/mavlink_gcs.RunningSim``)
sending to the station's port. Waits on a vehicle are bounded in its
simulated time (the ``time_boot_s`` the API reports), with a wall-clock
backstop so a broken vehicle fails a test instead of hanging it.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import uvicorn
from mavlink_gcs import RunningSim, free_udp_port

from groundstation.app import create_app
from groundstation.server import GroundStation
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import Stepper, simulate
from vehicle.world.scene import Scene, parse_scene

TOKEN = "test-operator-token"
SPEEDUP = 10.0
# heartbeats (mode, armed) come once a wall second, that is every SPEEDUP simulated seconds: waits on them
# need that much simulated time and some
HEARTBEAT_WAIT = 2.5 * SPEEDUP
WALL_Y = 8.0  # the south face of a wall north of the origin

# flat ground, a wall north of the start and one east of it: something for the sonar to see
SCENE_TEXT = f"""#VRML V2.0 utf8
Transform {{ translation 0 0 -0.5 children Shape {{ geometry Box {{ size 80 80 1 }} }} }}
Transform {{ translation 0 {WALL_Y + 0.25} 3 children Shape {{ geometry Box {{ size 20 0.5 6 }} }} }}
Transform {{ translation 9.25 0 3 children Shape {{ geometry Box {{ size 0.5 12 6 }} }} }}
"""


class WaitTimeout(AssertionError):
    """A condition did not come true within its budget."""


def small_scene() -> Scene:
    return parse_scene(SCENE_TEXT)


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class RunningStation:
    """GroundStation on ``udpin:127.0.0.1:<free port>`` with its app served by uvicorn on a thread."""

    def __init__(self, scene: Scene | None, record_dir: str | Path | None, token: str = TOKEN):
        self.mavlink_port = free_udp_port()
        self.url = f"udpin:127.0.0.1:{self.mavlink_port}"
        self.station = GroundStation([self.url], scene, token, record_dir)
        self.token = token
        self.http_port = free_tcp_port()
        self.base = f"http://127.0.0.1:{self.http_port}"
        config = uvicorn.Config(create_app(self.station), host="127.0.0.1", port=self.http_port,
                                log_level="warning", ws_ping_interval=None)
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)

    def __enter__(self) -> RunningStation:
        self._thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.02)
        self.station.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)
        self.station.close()

    def vehicle_url(self) -> str:
        """The pymavlink URL a vehicle sends to."""
        return f"udpout:127.0.0.1:{self.mavlink_port}"

    def api(self, **kwargs) -> Api:
        return Api(self.base, self.token, **kwargs)


class Api(httpx.Client):
    """httpx client for the station; ``auth=True`` on a call adds the operator token."""

    def __init__(self, base: str, token: str, timeout: float = 30.0):
        super().__init__(base_url=base, timeout=timeout)
        self.token = token

    @property
    def operator(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}

    def command(self, sysid: int, **body) -> httpx.Response:
        return self.post(f"/api/vehicles/{sysid}/commands", json=body, headers=self.operator)

    def vehicle(self, sysid: int) -> dict | None:
        response = self.get(f"/api/vehicles/{sysid}")
        return response.json() if response.status_code == 200 else None

    def wait_vehicle(self, sysid: int, condition: Callable[[dict], bool], sim_timeout: float = 30.0,
                     wall_timeout: float | None = None, what: str = "condition") -> dict:
        """Poll GET /api/vehicles/{sysid} until ``condition(vehicle)``; bounded by the vehicle's simulated time
        (its time_boot_s), with a wall-clock backstop."""
        wall_timeout = wall_timeout if wall_timeout is not None else sim_timeout / SPEEDUP * 4 + 15
        deadline = time.monotonic() + wall_timeout
        start_sim = None
        last = None
        while time.monotonic() < deadline:
            last = self.vehicle(sysid)
            if last is not None:
                if last["time_boot_s"] is not None:
                    start_sim = last["time_boot_s"] if start_sim is None else start_sim
                    if last["time_boot_s"] - start_sim > sim_timeout:
                        break
                if condition(last):
                    return last
            time.sleep(0.05)
        raise WaitTimeout(f"vehicle {sysid}: {what} not met within {sim_timeout} s of simulated time; last: {last}")

    def wait_sim(self, sysid: int, seconds: float) -> dict:
        """Let ``seconds`` of the vehicle's simulated time pass."""
        start = self.wait_vehicle(sysid, lambda v: v["time_boot_s"] is not None, what="time_boot_s")["time_boot_s"]
        return self.wait_vehicle(sysid, lambda v: v["time_boot_s"] >= start + seconds, sim_timeout=seconds + 5,
                                 what=f"{seconds} s of simulated time")


def wait_wall(condition: Callable[[], object], timeout: float, what: str = "condition", period: float = 0.05,
              sleep: Callable[[], None] | None = None):
    """``condition()``'s first truthy value within ``timeout`` wall seconds (for wall-clock properties).

    ``sleep`` replaces ``time.sleep(period)``: with Playwright's sync API, events (websocket
    frames, requests) reach their handlers only while Playwright waits, so pass a page's wait."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise WaitTimeout(f"{what} not met within {timeout} s")
        if sleep is not None:
            sleep()
        else:
            time.sleep(period)


def make_vehicle(scene: Scene, kind: str = "copter", mission: str = "browse", autostart: bool = False,
                 settings: Settings | None = None, start: tuple[float, float] | None = None) -> Stepper:
    return simulate(scene, mission, kind, settings or Settings(space_size=20), start, autostart=autostart)


def start_sim(station: RunningStation, scene: Scene, sysid: int = 1, kind: str = "copter", mission: str = "browse",
              autostart: bool = False, start: tuple[float, float] | None = None, settings: Settings | None = None,
              **options) -> RunningSim:
    """A simulated vehicle sending to the station (not started: use it as a context manager or call
    ``__enter__``)."""
    stepper = make_vehicle(scene, kind, mission, autostart, settings, start)
    return RunningSim(stepper, [station.vehicle_url()], speedup=SPEEDUP, sysid=sysid, **options)


def command_ok(api: Api, sysid: int, **body) -> None:
    response = api.command(sysid, **body)
    assert response.status_code == 200, response.text
    assert response.json()["result"] == "accepted", (body, response.json())


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
