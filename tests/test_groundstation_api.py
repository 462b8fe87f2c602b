"""The ground station's REST API, status stream and page, against simulated vehicles over real UDP sockets.

One station (GroundStation + its app under uvicorn on loopback) serves the
whole module; simulated vehicles (``vehicle sim``'s SimVehicle on threads)
send to its MAVLink port. Vehicle 1 flies (a copter taken off through the
API), vehicle 2 waits on the ground, vehicle 3 stops answering, and hand-made
MAVLink 1 packets play an ArduPilot copter (7) and a plane (8) that stream no
map. Waits on a vehicle are bounded in its simulated time.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import socket
import ssl
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest
import websockets.sync.client
from harness import (
    TOKEN,
    WALL_Y,
    RunningStation,
    free_tcp_port,
    free_udp_port,
    idle_station,
    read_until,
    small_scene,
    start_sim,
    take_off,
    wait_armed,
    wait_mode,
    wait_wall,
)
from PIL import Image
from pymavlink.dialects.v10 import ardupilotmega as mavlink1

from groundstation.commands import PROBE_ABOVE, Command, execute, solid_at
from groundstation.security import is_loopback
from vehicle.mapping.picture import HOME
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.waypoints import parse_mission
from vehicle.world.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent
STOPPED_SYSID = 3


@pytest.fixture(scope="module")
def scene():
    return small_scene()


@pytest.fixture(scope="module")
def station(scene, tmp_path_factory):
    with RunningStation(scene, tmp_path_factory.mktemp("recordings")) as running:
        yield running


@pytest.fixture(scope="module")
def api(station):
    with station.api() as client:
        yield client


def seen(api, sysid: int) -> dict:
    return api.wait_vehicle(sysid, lambda v: v["link"]["state"] == "ok" and v["position"] is not None,
                            sim_timeout=10, what="first heartbeat and position")


@pytest.fixture(scope="module")
def flyer(station, api, scene):
    """Vehicle 1: a copter hovering at 4 m over its start in GUIDED (the onboard mission paused by the operator),
    taken there in simulated time: the map tests look at what it has seen from there."""
    with start_sim(station, scene, sysid=1, start=(0.0, 0.0), hovering=4.0) as sim:
        api.wait_vehicle(1, lambda v: v["mode"] == "GUIDED" and v["armed"] and (v["agent"] or {}).get("paused")
                         and v["position"] is not None and v["position"]["alt"] > 3.5, sim_timeout=10,
                         what="hovering, its mission paused")
        yield sim


@pytest.fixture(scope="module")
def grounded(station, api, scene):
    """Vehicle 2: a copter on the ground, disarmed, south-west of vehicle 1."""
    with start_sim(station, scene, sysid=2, start=(-4.0, -4.0)) as sim:
        seen(api, 2)
        yield sim


@dataclass
class Stopped:
    at: float  # wall time (monotonic) the vehicle stopped
    command: Future  # POST rtl to it, sent as it stopped: (response, seconds it took)


@pytest.fixture(scope="module")
def stopped(station, api, scene):
    """Vehicle 3: heard for a while, then its simulation stops. A command is sent to it at once, in the
    background, so its retries run while the link-loss test waits."""
    running = start_sim(station, scene, sysid=STOPPED_SYSID, start=(-4.0, 3.0))
    running.__enter__()
    try:
        seen(api, STOPPED_SYSID)
    finally:
        running.__exit__(None, None, None)
    at = time.monotonic()

    def rtl():
        with station.api() as client:
            started = time.monotonic()
            response = client.command(STOPPED_SYSID, action="rtl")
            return response, time.monotonic() - started

    with ThreadPoolExecutor(1) as pool:
        yield Stopped(at, pool.submit(rtl))


def airborne(api, sysid: int = 1) -> dict:
    """Make sure the vehicle flies, in GUIDED at about 4 m (after a test that changed its mode)."""
    vehicle = api.vehicle(sysid)
    if vehicle["position"]["alt"] < 3.0:
        return take_off(api, sysid)
    if vehicle["mode"] != "GUIDED":
        assert api.command(sysid, action="set_mode", mode="GUIDED").json()["result"] == "accepted"
        vehicle = wait_mode(api, sysid, "GUIDED")
    return vehicle


def goto_and_wait(api, sysid: int, x: float, y: float, tolerance: float = 0.3, sim_timeout: float = 40) -> dict:
    response = api.command(sysid, action="goto", x=x, y=y)
    assert response.status_code == 200 and response.json()["result"] == "accepted", response.text
    return api.wait_vehicle(
        sysid, lambda v: math.hypot(v["position"]["x"] - x, v["position"]["y"] - y) < tolerance,
        sim_timeout=sim_timeout, what=f"arrival at ({x}, {y})")


# ---- hand-made MAVLink 1 vehicles (ArduPilot-like, no map of their own) ----------------------------
class Mavlink1Vehicle:
    """Sends MAVLink 1 packets as ``sysid`` to the station's UDP port, as a plain ArduPilot would.

    Not ``mavlink_peer.FakeVehicle`` on purpose: that one speaks MAVLink 2, and these tests check that the
    station takes an older autopilot's MAVLink 1 (and builds its map from plain DISTANCE_SENSOR readings)."""

    def __init__(self, station: RunningStation, sysid: int):
        self.mav = mavlink1.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.address = ("127.0.0.1", station.mavlink_port)
        self.boot_ms = 0

    def send(self, message) -> None:
        self.socket.sendto(message.pack(self.mav), self.address)

    def heartbeat(self, mav_type: int, custom_mode: int, armed: bool = True) -> None:
        base = mavlink1.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink1.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        self.send(self.mav.heartbeat_encode(mav_type, mavlink1.MAV_AUTOPILOT_ARDUPILOTMEGA, base, custom_mode,
                                            mavlink1.MAV_STATE_ACTIVE, 3))

    def pose(self, datum: Datum, x: float, y: float, alt: float, yaw_deg: float) -> None:
        self.boot_ms += 100
        lat, lon = datum.to_global(x, y)
        self.send(self.mav.global_position_int_encode(self.boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)),
                                                      int((584 + alt) * 1000), int(alt * 1000), 0, 0, 0,
                                                      int(yaw_deg * 100)))
        self.send(self.mav.attitude_encode(self.boot_ms, 0.0, 0.0, math.radians(yaw_deg), 0.0, 0.0, 0.0))

    def distance(self, cm: int, orientation: int = 0, sensor: int = 0) -> None:
        self.send(self.mav.distance_sensor_encode(self.boot_ms, 2, 4000, cm,
                                                  mavlink1.MAV_DISTANCE_SENSOR_ULTRASOUND, sensor, orientation, 0))

    def close(self) -> None:
        self.socket.close()


ARDU_XY = (25.0, -30.0)  # where the hand-made copter hovers
ARDU_ECHO = 5.1  # m, straight ahead (north)


@pytest.fixture(scope="module")
def ardupilot_copter(station, api):
    """System 7: an ArduPilot copter (MAVLink 1) hovering north-up, its forward sonar seeing something 5.1 m ahead."""
    vehicle = Mavlink1Vehicle(station, 7)
    datum = station.station.live.datum
    try:
        vehicle.heartbeat(mavlink1.MAV_TYPE_QUADROTOR, 5)  # LOITER
        wait_wall(lambda: api.vehicle(7), 5, "the station hears system 7")

        def send() -> bool:  # as a vehicle does, all along: the station builds a map once it sees no stream
            vehicle.pose(datum, *ARDU_XY, 4.0, 0.0)
            vehicle.heartbeat(mavlink1.MAV_TYPE_QUADROTOR, 5)
            vehicle.distance(int(ARDU_ECHO * 100))
            return (api.vehicle(7) or {}).get("map", {}).get("occupied")

        wait_wall(send, 10, "a map for system 7", period=0.1)
        yield vehicle
    finally:
        vehicle.close()


@pytest.fixture(scope="module")
def plane(station, api):
    """System 8: an ArduPilot plane (MAVLink 1) in RTL, with a position and no sonar."""
    vehicle = Mavlink1Vehicle(station, 8)
    try:
        vehicle.heartbeat(mavlink1.MAV_TYPE_FIXED_WING, 11)
        vehicle.pose(station.station.live.datum, 40.0, 40.0, 60.0, 90.0)
        wait_wall(lambda: (api.vehicle(8) or {}).get("position"), 5, "the plane's position")
        yield vehicle
    finally:
        vehicle.close()


# ---- status ----------------------------------------------------------------------------------------
def test_health(station, api, flyer):
    response = api.get("/api/health")
    assert response.status_code == 200
    health = response.json()
    assert health["status"] == "ok" and health["mode"] == "live"
    assert health["vehicles"] >= 1
    assert health["links"] == [station.url]
    assert health["version"]
    head = api.head("/api/health")  # as uptime monitors ask
    assert head.status_code == 200 and head.content == b""


def test_vehicles_lists_a_flying_vehicle(api, flyer):
    vehicle = airborne(api)
    vehicles = api.get("/api/vehicles").json()
    assert isinstance(vehicles, list)
    one = next(v for v in vehicles if v["sysid"] == 1)
    assert one["type"] == "copter" and one["mode"] == "GUIDED" and one["armed"] is True
    position = one["position"]
    assert {"x", "y", "z", "lat", "lon", "alt"} <= set(position)
    assert position["z"] == pytest.approx(vehicle["position"]["z"], abs=0.5)
    assert 3.0 < position["alt"] < 5.0 and position["z"] > 3.0
    assert abs(position["x"]) < 3 and abs(position["y"]) < 3
    assert set(one["attitude"]) == {"roll", "pitch", "yaw"}
    assert isinstance(one["speed"], float)
    assert one["link"]["state"] == "ok"
    assert 0 <= one["link"]["heartbeat_age"] < 3.0
    assert one["link"]["mavlink"] == 2 and one["link"]["messages"] > 0
    assert set(one["mission"]) == {"current", "total", "reached", "left"}
    texts = [m["text"] for m in one["messages"]]
    assert "Arming motors" in texts and any(t.startswith("Takeoff") for t in texts)
    assert one["battery"]["voltage"] > 10
    assert one["home"] == {"x": pytest.approx(0, abs=0.05), "y": pytest.approx(0, abs=0.05)}
    assert one["time_boot_s"] > 0


def test_one_vehicle_and_unknown_ids(api, flyer):
    one = api.get("/api/vehicles/1")
    assert one.status_code == 200
    assert one.json()["sysid"] == 1 and one.json()["type"] == "copter"
    missing = api.get("/api/vehicles/99")
    assert missing.status_code == 404
    assert "99" in missing.json()["detail"]
    assert api.get("/api/vehicles/not-a-number").status_code == 422


def test_map_as_png(api, flyer):
    api.wait_vehicle(1, lambda v: (v["map"]["occupied"] or 0) > 0, sim_timeout=30, what="an occupied cell")
    response = api.get("/api/vehicles/1/map")
    assert response.status_code == 200
    assert response.headers["content-type"] == "image/png"
    picture = Image.open(io.BytesIO(response.content))
    picture.load()
    assert picture.format == "PNG"
    assert max(picture.size) <= 900  # the explored part of a 400 x 400 map, with a title, a scale and a legend
    pixels = np.asarray(picture.convert("RGB")).astype(int)
    home_rows, _ = np.nonzero(np.all(pixels == HOME, axis=-1))  # the picture's home marker (and its swatch)
    occupied = (pixels[..., 0] > 150) & (pixels[..., 1] < 80) & (pixels[..., 2] < 90)
    assert occupied[:home_rows.min()].sum() >= 9  # the wall north of the start, above home: north is up


def test_map_as_json(api, flyer):
    api.wait_vehicle(1, lambda v: (v["map"]["occupied"] or 0) > 0, sim_timeout=30, what="an occupied cell")
    response = api.get("/api/vehicles/1/map", params={"format": "json"})
    assert response.status_code == 200
    body = response.json()
    assert body["source"] == "vehicle"
    assert body["resolution"] == 10.0
    assert body["origin"] == [pytest.approx(-20.0, abs=0.05), pytest.approx(-20.0, abs=0.05)]
    assert body["size"] == 400
    window, values = body["window"], np.array(body["values"])
    assert values.shape == (window["rows"], window["cols"])
    assert 0 <= window["row"] and window["row"] + window["rows"] <= 400
    assert 0 <= window["col"] and window["col"] + window["cols"] <= 400
    assert body["occupied"] == int((values >= body["occupied_at"]).sum()) > 0
    # the wall north of the start (south face at y = 8) is where the occupied cells are
    rows, cols = np.nonzero(values >= body["occupied_at"])
    ys = body["origin"][1] + (window["row"] + rows + 0.5) / body["resolution"]
    assert np.median(ys) == pytest.approx(8.0, abs=1.0)


def test_map_errors(api, flyer, plane):
    assert api.get("/api/vehicles/8/map").status_code == 404  # a plane with no sonar has no map yet
    assert "no map" in api.get("/api/vehicles/8/map", params={"format": "json"}).json()["detail"]
    assert api.get("/api/vehicles/99/map").status_code == 404
    assert api.get("/api/vehicles/1/map", params={"format": "jpeg"}).status_code == 422


# ---- commands: authentication and validation ---------------------------------------------------------
def test_commands_need_the_operator_token(api, flyer, caplog, monkeypatch):
    # every refusal reported: else an earlier test's refusal on this station, under LOG_EVERY ago, hides these
    monkeypatch.setattr("groundstation.security.LOG_EVERY", 0.0)
    caplog.set_level(logging.WARNING, logger="groundstation")
    body = {"action": "rtl"}
    missing = api.post("/api/vehicles/1/commands", json=body)
    assert missing.status_code == 401
    assert missing.headers["www-authenticate"] == "Bearer"
    assert missing.json()["detail"] == "the operator token is missing or wrong"
    wrong = api.post("/api/vehicles/1/commands", json=body, headers={"Authorization": "Bearer not-the-token"})
    assert wrong.status_code == 401
    assert wrong.headers["www-authenticate"] == "Bearer"
    basic = api.post("/api/vehicles/1/commands", json=body, headers={"Authorization": f"Basic {TOKEN}"})
    assert basic.status_code == 401
    assert any("token" in record.getMessage() for record in caplog.records)  # refusals are logged
    assert api.vehicle(1)["mode"] != "RTL"  # nothing was sent


@pytest.mark.parametrize("body", [
    {"action": "explode"},
    {"action": "takeoff"},
    {"action": "kill"},
    {"action": "kill", "confirm": False},
    {"action": "set_mode"},
    {"action": "goto", "x": 1.0},
    {"action": "speed", "speed": -1},
    {"action": "takeoff", "altitude": 0},
    {},
])
def test_bad_command_payloads_are_422(api, flyer, body):
    response = api.command(1, **body)
    assert response.status_code == 422, response.text


def test_command_to_an_unknown_vehicle_is_404(api, flyer):
    response = api.command(99, action="rtl")
    assert response.status_code == 404


# ---- commands that fly ---------------------------------------------------------------------------
def test_rtl(api, flyer):
    airborne(api)
    goto_and_wait(api, 1, 3.0, 3.0)
    response = api.command(1, action="rtl")
    assert response.status_code == 200
    assert response.json() == {"action": "rtl", "result": "accepted"}
    wait_mode(api, 1, "RTL")
    # home, landed, disarmed, as ArduPilot's RTL does
    landed = api.wait_vehicle(1, lambda v: not v["armed"] and v["position"]["alt"] < 0.5, sim_timeout=60,
                              what="landed at home")
    assert math.hypot(landed["position"]["x"], landed["position"]["y"]) < 0.5
    airborne(api)


def test_abort_brakes_a_copter(api, flyer):
    airborne(api)
    goto = api.command(1, action="goto", x=-3.0, y=-3.0)
    assert goto.json()["result"] == "accepted"
    api.wait_vehicle(1, lambda v: v["speed"] > 0.5, sim_timeout=10, what="moving")
    assert api.command(1, action="abort").json()["result"] == "accepted"
    wait_mode(api, 1, "BRAKE")
    stopped = api.wait_vehicle(1, lambda v: v["speed"] < 0.05, sim_timeout=10, what="standstill")
    later = api.wait_sim_time(1, 3.0)
    assert later["mode"] == "BRAKE"
    assert math.dist((later["position"]["x"], later["position"]["y"]),
                     (stopped["position"]["x"], stopped["position"]["y"])) < 0.1
    airborne(api)


def test_set_mode(api, flyer):
    airborne(api)
    assert api.command(1, action="set_mode", mode="LOITER").json()["result"] == "accepted"
    wait_mode(api, 1, "LOITER")
    assert api.command(1, action="set_mode", mode="guided").json()["result"] == "accepted"  # any case
    wait_mode(api, 1, "GUIDED")
    assert api.command(1, action="set_mode", mode="NO_SUCH_MODE").json()["result"] == "unsupported"
    assert api.vehicle(1)["mode"] == "GUIDED"


def test_goto_moves_the_vehicle_there(api, flyer):
    airborne(api)
    arrived = goto_and_wait(api, 1, 3.0, -4.0)
    assert arrived["mode"] == "GUIDED"
    assert arrived["position"]["alt"] == pytest.approx(4.0, abs=0.5)  # keeps its height
    back = goto_and_wait(api, 1, 0.0, 0.0)
    assert abs(back["position"]["x"]) < 0.3 and abs(back["position"]["y"]) < 0.3


def test_goto_with_an_agent_is_planned_round_what_its_map_knows(api, flyer):
    airborne(api)
    goto_and_wait(api, 1, 0.0, 4.0)  # facing the wall north of the start: its sonars map it
    wide = 0.0

    def there(v):
        nonlocal wide
        wide = max([wide, *(abs(x) for x, _ in v["path"])])
        return math.hypot(v["position"]["x"], v["position"]["y"] - 12.0) < 0.5

    assert api.command(1, action="goto", x=0.0, y=12.0).json()["result"] == "accepted"  # behind the wall
    arrived = api.wait_vehicle(1, there, sim_timeout=120, what="arrival behind the wall")
    assert wide > 10.0  # the planned path went round the wall's end (it spans x -10 to 10)
    assert arrived["armed"] and arrived["position"]["alt"] > 3.0
    told = api.wait_vehicle(1, lambda v: any(m["text"] == "Go here: arrived at (0.0, 12.0); holding"
                                             for m in v["messages"]), sim_timeout=10, what="the agent says so")
    assert told["agent"]["paused"] and "where the operator sent it" in told["agent"]["reason"]
    goto_and_wait(api, 1, 0.0, 0.0, tolerance=0.5, sim_timeout=120)


@pytest.fixture
def sent_gotos(station, monkeypatch):
    """The Go here targets the station sends (``Link.command_int``, spied on and called through)."""
    link, sent = station.station.link, []
    send = link.command_int
    monkeypatch.setattr(link, "command_int", lambda *args, **kwargs: sent.append(args) or send(*args, **kwargs))
    return sent


def test_goto_inside_a_building_or_on_an_occupied_cell_is_refused_before_it_is_sent(station, api, flyer, scene,
                                                                                    sent_gotos):
    """A target inside a closed solid of the scene, or on a cell the vehicle's map holds occupied, is a 422 that
    says why; it used to be sent, accepted, and then fail on the vehicle with "no known path"."""
    airborne(api)
    goto_and_wait(api, 1, 0.0, 4.0)  # facing the wall north of the start: its sonars map the south face
    sent_gotos.clear()
    inside = api.command(1, action="goto", x=0.0, y=WALL_Y + 0.25)
    assert inside.status_code == 422
    assert inside.json()["detail"] == ("the target (0.0, 8.2) is inside a building (shape 1): pick a point "
                                       "outside it")
    cells = api.get("/api/vehicles/1/map", params={"format": "json"}).json()
    window, resolution, (west, south) = cells["window"], cells["resolution"], cells["origin"]
    occupied = [(west + (window["col"] + c + 0.5) / resolution, south + (window["row"] + r + 0.5) / resolution)
                for r, row in enumerate(cells["values"]) for c, value in enumerate(row)
                if value >= cells["occupied_at"]]
    height = station.station.live.height(station.station.live.get(1))
    outside = [(x, y) for x, y in occupied if solid_at(scene, x, y, height + PROBE_ABOVE) is None]
    assert outside, "the sonars marked no occupied cell outside the wall"
    x, y = outside[0]
    on_cell = api.command(1, action="goto", x=x, y=y)
    assert on_cell.status_code == 422
    assert on_cell.json()["detail"] == (f"the target ({x:.1f}, {y:.1f}) is on an occupied cell of vehicle 1's map: "
                                        "pick a point its map shows free or unknown")
    assert sent_gotos == []  # neither reached the vehicle
    goto_and_wait(api, 1, 0.0, 0.0)  # a free target is sent, and flown to
    assert len(sent_gotos) == 1


def test_goto_into_a_known_obstacle_sent_by_another_station_is_refused_by_the_agent(station, api, flyer):
    """Past this station's check (as another ground station would send it), the agent refuses it and says why."""
    airborne(api)
    goto_and_wait(api, 1, 0.0, 4.0)
    running = station.station
    goto = Command(action="goto", x=0.0, y=WALL_Y + 0.25)
    assert execute(running.link, running.live.get(1), goto, running.live.datum, time.time()) == "denied"
    told = api.wait_vehicle(1, lambda v: any("Go here refused" in m["text"] for m in v["messages"]),
                            sim_timeout=10, what="the reason")
    refusal = next(m for m in told["messages"] if "Go here refused" in m["text"])
    assert refusal["text"] == "Go here refused: (0.0, 8.2) is inside a known obstacle"
    goto_and_wait(api, 1, 0.0, 0.0)


def test_speed_limits_the_cruise_speed(api, flyer):
    airborne(api)
    response = api.command(1, action="speed", speed=1.0)
    assert response.status_code == 200 and response.json()["result"] == "accepted"
    try:
        fastest = 0.0

        def there(v):
            nonlocal fastest
            fastest = max(fastest, v["speed"])
            return math.hypot(v["position"]["x"] + 5, v["position"]["y"]) < 0.3

        assert api.command(1, action="goto", x=-5.0, y=0.0).json()["result"] == "accepted"
        api.wait_vehicle(1, there, sim_timeout=30, what="arrival at (-5, 0)")
        assert 0.5 < fastest <= 1.15
    finally:
        assert api.command(1, action="speed", speed=2.5).json()["result"] == "accepted"
    goto_and_wait(api, 1, 0.0, 0.0)


def test_arm_and_disarm_answer_with_result_words(api, grounded, flyer):
    assert api.command(2, action="arm").json()["result"] == "accepted"
    wait_armed(api, 2)
    assert api.command(2, action="disarm").json()["result"] == "accepted"
    wait_armed(api, 2, False)
    airborne(api)
    assert api.command(1, action="disarm").json()["result"] == "failed"  # flying: ArduPilot refuses
    after = api.wait_sim_time(1, 1.0)
    assert after["armed"] and after["position"]["alt"] > 3.0


def test_kill_force_disarms_in_the_air(api, grounded):
    take_off(api, 2, altitude=3.0)
    refused = api.command(2, action="kill")
    assert refused.status_code == 422
    assert "confirm" in refused.text
    response = api.command(2, action="kill", confirm=True)
    assert response.status_code == 200 and response.json()["result"] == "accepted"
    wait_armed(api, 2, False)
    api.wait_vehicle(2, lambda v: v["position"]["alt"] < 0.6, sim_timeout=10, what="fell")


# ---- missions ------------------------------------------------------------------------------------------
def waypoints(text: str) -> list[tuple[int, float, float, float]]:
    return [(item.command, item.lat, item.lon, item.alt) for item in parse_mission(text)]


def test_mission_download_is_qgc_wpl(api, grounded):
    response = api.get("/api/vehicles/2/mission")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    lines = response.text.splitlines()
    assert lines[0] == "QGC WPL 110"
    assert len(lines) >= 2  # item 0 is home
    home = waypoints(response.text)[0]
    lat, lon = Datum().to_global(-4.0, -4.0)
    assert home[1] == pytest.approx(lat, abs=1e-6) and home[2] == pytest.approx(lon, abs=1e-6)
    assert api.get("/api/vehicles/99/mission").status_code == 404


def test_mission_upload_round_trips(api, grounded):
    datum = Datum()
    points = [datum.to_global(x, y) for x, y in ((-4.0, 0.0), (0.0, -6.0), (-7.5, -7.5))]
    home = datum.to_global(-4.0, -4.0)
    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{home[0]:.8f}\t{home[1]:.8f}\t0.000000\t1"]
    lines += [f"{i}\t0\t3\t16\t0\t0\t0\t0\t{lat:.8f}\t{lon:.8f}\t4.000000\t1" for i, (lat, lon) in
              enumerate(points, start=1)]
    text = "\n".join(lines) + "\n"
    response = api.put("/api/vehicles/2/mission", content=text, headers=api.operator)
    assert response.status_code == 200, response.text
    assert response.json() == {"result": "accepted", "items": 4}
    back = api.get("/api/vehicles/2/mission")
    assert back.status_code == 200
    got = waypoints(back.text)
    assert len(got) == 4
    for (command, lat, lon, alt), (want_lat, want_lon) in zip(got[1:], points, strict=True):
        assert command == 16
        assert lat == pytest.approx(want_lat, abs=1e-6) and lon == pytest.approx(want_lon, abs=1e-6)
        assert alt == pytest.approx(4.0)


def test_mission_upload_errors(api, grounded):
    text = "QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36326100\t149.16523000\t0.000000\t1\n"
    assert api.put("/api/vehicles/2/mission", content=text).status_code == 401
    wrong = api.put("/api/vehicles/2/mission", content=text, headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401
    garbage = api.put("/api/vehicles/2/mission", content=b"this is not a mission\n\x00\xff", headers=api.operator)
    assert garbage.status_code == 422
    bad_line = api.put("/api/vehicles/2/mission", content="QGC WPL 110\n0\t1\tnot numbers\n", headers=api.operator)
    assert bad_line.status_code == 422
    empty = api.put("/api/vehicles/2/mission", content="QGC WPL 110\n", headers=api.operator)
    assert empty.status_code == 422
    assert api.put("/api/vehicles/99/mission", content=text, headers=api.operator).status_code == 404


# ---- sign-in -------------------------------------------------------------------------------------------
def test_auth(api):
    assert api.get("/api/auth", headers=api.operator).status_code == 200
    assert api.get("/api/auth", headers=api.operator).json() == {"ok": True}
    missing = api.get("/api/auth")
    assert missing.status_code == 401 and missing.headers["www-authenticate"] == "Bearer"
    assert api.get("/api/auth", headers={"Authorization": "Bearer wrong"}).status_code == 401
    assert api.get("/api/auth", headers={"Authorization": "Bearer"}).status_code == 401


def test_the_token_may_follow_the_scheme_after_several_spaces(api):
    """``Bearer`` and the token may stand any number of spaces apart (RFC 7235 allows one or more)."""
    spaced = {"Authorization": f"Bearer   {TOKEN}"}
    assert api.get("/api/auth", headers=spaced).status_code == 200
    assert api.post("/api/vehicles/99/commands", json={"action": "rtl"}, headers=spaced).status_code == 404


@pytest.mark.parametrize("near_miss", [
    TOKEN[:-1] + chr(ord(TOKEN[-1]) ^ 1),  # only the last character differs
    TOKEN[:-1],  # one character short
    TOKEN + "x",  # one character long
    TOKEN[:6],  # a prefix
    TOKEN.upper(),
])
def test_a_token_that_differs_only_in_its_last_character_is_refused(api, near_miss):
    """The whole token counts: a check of a prefix, or of a length, lets a near miss command the vehicles."""
    assert near_miss != TOKEN
    bearer = {"Authorization": f"Bearer {near_miss}"}
    assert api.get("/api/auth", headers=bearer).status_code == 401
    refused = api.post("/api/vehicles/99/commands", json={"action": "rtl"}, headers=bearer)
    assert refused.status_code == 401  # before the vehicle is even looked up (404 with the token)
    assert api.post("/api/vehicles/99/commands", json={"action": "rtl"}, headers=api.operator).status_code == 404


# ---- the status stream -------------------------------------------------------------------------------
def test_websocket_streams_the_vehicles_while_they_fly(station, api, flyer):
    airborne(api)
    assert api.command(1, action="speed", speed=1.5).json()["result"] == "accepted"
    assert api.command(1, action="goto", x=-10.0, y=-12.0).json()["result"] == "accepted"  # 15 m: 10 s simulated
    frames = []
    try:
        with websockets.sync.client.connect(f"ws://127.0.0.1:{station.http_port}/ws", open_timeout=5) as socket_:
            def frame():
                got = json.loads(socket_.recv(timeout=5))
                if got.get("type") == "vehicles":
                    frames.append(got)
                return len(frames)

            wait_wall(frame, 10, "four frames of the vehicles", period=0, done=lambda count: count >= 4)
    finally:
        assert api.command(1, action="speed", speed=2.5).json()["result"] == "accepted"
    assert len(frames) == 4
    assert all(frame["mode"] == "live" and isinstance(frame["vehicles"], list) for frame in frames)
    assert all(frame["replay"] is None and frame["time"] > 0 for frame in frames)
    positions = [next(v for v in frame["vehicles"] if v["sysid"] == 1)["position"] for frame in frames]
    moves = [math.dist((a["x"], a["y"]), (b["x"], b["y"])) for a, b in zip(positions, positions[1:], strict=False)]
    assert sum(m > 0.05 for m in moves) >= 2, positions  # it moves between frames
    goto_and_wait(api, 1, 0.0, 0.0)



def test_a_new_stream_gets_the_status_at_once_not_a_period_later(station, monkeypatch):
    """The first frame is the status, sent as the stream opens: with a period of an hour between status frames,
    one still comes (a page used to show nothing for its first quarter of a second)."""
    import groundstation.api.streams as app

    monkeypatch.setattr(app, "STREAM_PERIOD", 3600.0)
    with websockets.sync.client.connect(f"ws://127.0.0.1:{station.http_port}/ws", open_timeout=5) as socket_:
        frame = json.loads(socket_.recv(timeout=5))
    assert frame["type"] == "vehicles" and frame["mode"] == "live" and isinstance(frame["vehicles"], list)

# ---- the page, the docs, the 3D view -----------------------------------------------------------------
def test_the_page_docs_and_3d_view(api):
    page = api.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'id="view"' in page.text and "<iframe" in page.text
    assert api.get("/static/app.js").status_code == 200
    assert '<link rel="icon" href="/static/favicon.svg"' in page.text
    for icon in (api.get("/static/favicon.svg"), api.get("/favicon.ico")):  # the page's, and where browsers look
        assert icon.status_code == 200 and icon.headers["content-type"].startswith("image/svg+xml")
        assert icon.text.startswith("<svg")
    docs = api.get("/docs")
    assert docs.status_code == 200 and "swagger" in docs.text.lower()
    schema = api.get("/openapi.json")
    assert schema.status_code == 200
    paths = schema.json()["paths"]
    for path in ("/api/health", "/api/vehicles", "/api/vehicles/{sysid}/commands", "/api/vehicles/{sysid}/map",
                 "/api/vehicles/{sysid}/mission", "/api/recordings", "/api/replay"):
        assert path in paths
    viz = api.get("/viz/")
    assert viz.status_code == 200
    assert viz.headers["content-type"].startswith("text/html")
    assert "<html" in viz.text.lower()
    redirect = api.get("/viz", follow_redirects=False)
    assert redirect.status_code in (301, 302, 307, 308) and redirect.headers["location"].endswith("/viz/")


# ---- a vehicle that stops answering ------------------------------------------------------------------
def test_link_loss_is_reported_within_seconds(api, stopped, flyer):
    """The link shows lost exactly when the last heartbeat is over 3 s old (wall clock), at every look, however
    long after the vehicle stopped this test runs."""
    looks = []

    def lost():
        vehicle = api.vehicle(STOPPED_SYSID)
        link = vehicle["link"]
        assert link["heartbeat_age"] >= 3.0 if link["state"] == "lost" else link["heartbeat_age"] <= 3.0, link
        looks.append(link["state"])
        return link["state"] == "lost" and vehicle

    wait_wall(lost, 10, "link lost")
    assert looks[-1] == "lost"
    assert api.vehicle(1)["link"]["state"] == "ok"  # the others are unaffected


def test_command_to_a_silent_vehicle_is_504_after_retries(stopped):
    response, elapsed = stopped.command.result(timeout=30)
    assert response.status_code == 504
    assert "did not answer" in response.json()["detail"]
    assert elapsed >= 2.5  # three tries of a second each, not one


# ---- vehicles that are not ours ---------------------------------------------------------------------
def test_an_ardupilot_copter_gets_a_map_built_here(api, ardupilot_copter):
    vehicle = api.vehicle(7)
    assert vehicle["type"] == "copter" and vehicle["mode"] == "LOITER" and vehicle["armed"]
    assert vehicle["link"]["mavlink"] == 1
    assert vehicle["position"]["x"] == pytest.approx(ARDU_XY[0], abs=0.05)
    assert vehicle["position"]["y"] == pytest.approx(ARDU_XY[1], abs=0.05)
    assert vehicle["map"]["source"] == "groundstation" and vehicle["map"]["occupied"] >= 1
    body = api.get("/api/vehicles/7/map", params={"format": "json"}).json()
    assert body["source"] == "groundstation"
    values = np.array(body["values"])
    rows, cols = np.nonzero(values >= body["occupied_at"])
    assert len(rows) >= 1
    xs = body["origin"][0] + (body["window"]["col"] + cols + 0.5) / body["resolution"]
    ys = body["origin"][1] + (body["window"]["row"] + rows + 0.5) / body["resolution"]
    nearest = np.min(np.hypot(xs - ARDU_XY[0], ys - (ARDU_XY[1] + ARDU_ECHO)))
    assert nearest < 0.3  # the echo 5.1 m north of it
    free = np.count_nonzero(values <= body["free_at"])
    assert free >= 10  # the beam before the echo is free space
    png = api.get("/api/vehicles/7/map")
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"


def test_a_plane_heartbeat_shows_a_plane(api, plane):
    vehicle = api.vehicle(8)
    assert vehicle["type"] == "plane"
    assert vehicle["mode"] == "RTL"
    assert vehicle["link"]["mavlink"] == 1
    assert vehicle["position"]["x"] == pytest.approx(40.0, abs=0.05)
    assert vehicle["position"]["alt"] == pytest.approx(60.0, abs=0.01)
    assert vehicle["heading"] == pytest.approx(90.0, abs=0.5)
    assert vehicle["map"]["source"] is None


def test_a_gcs_heartbeat_makes_no_vehicle(station, api):
    """Another ground station's heartbeat is no vehicle. A vehicle's heartbeat sent right after it, from the same
    socket, marks when the station has handled both (one socket's datagrams are handled in order)."""
    other = Mavlink1Vehicle(station, 42)
    marker = Mavlink1Vehicle(station, 43)
    marker.socket.close()
    marker.socket = other.socket
    try:
        other.send(other.mav.heartbeat_encode(mavlink1.MAV_TYPE_GCS, mavlink1.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        marker.heartbeat(mavlink1.MAV_TYPE_QUADROTOR, 5)
        wait_wall(lambda: api.vehicle(43), 10, "the marker vehicle")
    finally:
        other.close()
    assert api.vehicle(42) is None
    assert api.get("/api/vehicles/42").status_code == 404


# ---- binding --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("host", "loopback"), [
    ("127.0.0.1", True), ("127.1.2.3", True), ("localhost", True), ("::1", True),
    ("0.0.0.0", False), ("::", False), ("192.168.1.10", False), ("example.org", False),
])
def test_is_loopback(host, loopback):
    assert is_loopback(host) is loopback


def test_serving_beyond_loopback_without_tls_warns(tmp_path):
    port = free_tcp_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "serve", "--host", "0.0.0.0", "--port", str(port),
         "--token", TOKEN, "--record-dir", "", "--mavlink", f"udpin:127.0.0.1:{free_udp_port()}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"})
    try:
        out, err = read_until(process, "ground station:", timeout=30)
        assert process.poll() is None, (out, err)
        health = wait_wall(lambda: _health(port, TOKEN), 10, "the served app answers")
        assert health["status"] == "ok"
        assert httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5).status_code == 401  # watching needs it
    finally:
        process.terminate()
        try:
            rest = process.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            rest = process.communicate()
    err += rest[1].decode(errors="replace")
    assert "WARNING: serving on 0.0.0.0 without TLS" in err
    assert "--tls-cert" in err or "127.0.0.1" in err  # it says what to do about it
    assert "watching needs the operator token" in err and "--viewer-token" in err
    assert f"#token={TOKEN}" in out
    assert not list(tmp_path.iterdir())  # --record-dir '' records nothing


def _health(port: int, token: str | None = None) -> dict | None:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        response = httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=2, headers=headers)
    except httpx.HTTPError:
        return None
    return response.json() if response.status_code == 200 else None


@pytest.mark.parametrize(("host", "tls", "warned", "url"), [
    ("127.0.0.1", False, False, "http://127.0.0.1:8123/"), ("localhost", False, False, "http://localhost:8123/"),
    ("0.0.0.0", False, True, "http://127.0.0.1:8123/"), ("192.0.2.7", False, True, "http://192.0.2.7:8123/"),
    ("0.0.0.0", True, False, "https://127.0.0.1:8123/"), ("::1", False, False, "http://[::1]:8123/"),
    ("::", False, True, "http://127.0.0.1:8123/"), ("2001:db8::7", True, False, "https://[2001:db8::7]:8123/"),
])
def test_serve_warns_only_when_exposed_without_tls(monkeypatch, capsys, tmp_path, host, tls, warned, url):
    """serve() itself, with its binding and uvicorn's run replaced: the warning depends on the host and TLS alone."""
    import uvicorn

    from groundstation import server

    ran = []
    monkeypatch.setattr(server, "_listening_socket", lambda host, port: None)
    monkeypatch.setattr(uvicorn.Server, "run", lambda self, *a, **k: ran.append(self.config))
    station = server.GroundStation([], None, TOKEN, record_dir=None)
    lines = []
    cert = (certificate(tmp_path),) * 2 if tls else (None, None)
    server.serve(station, host, 8123, *cert, announce=lines.append)
    err = capsys.readouterr().err
    assert ("without TLS" in err) is warned
    assert len(ran) == 1 and ran[0].host == host
    assert lines and f"{url}" in lines[0] and f"#token={TOKEN}" in lines[0], lines


def certificate(folder: Path) -> str:
    """A PEM file holding a key and a certificate for 127.0.0.1 (trustme's test CA); the CA's is ca.pem beside it."""
    import trustme

    authority = trustme.CA()
    authority.cert_pem.write_to_path(str(folder / "ca.pem"))
    path = folder / "server.pem"
    authority.issue_cert("127.0.0.1", "localhost").private_key_and_cert_chain_pem.write_to_path(str(path))
    return str(path)


def test_a_web_port_in_use_is_an_error_before_the_address_is_announced(tmp_path):
    """uvicorn binds after the station announced its address (another server's) and only logged the failure;
    and the session's recording, empty but for the note naming its scene, stayed in the list."""
    from groundstation import server

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    scene = load_scene(ROOT / "scenes" / "default.wrl")  # a file: the recording names it in a note
    station = server.GroundStation([f"udpin:127.0.0.1:{free_udp_port()}"], scene, TOKEN, record_dir=tmp_path)
    lines = []
    try:
        assert len(list(tmp_path.glob("session-*.tlog"))) == 1  # its note written (not flushed yet)
        with pytest.raises(OSError, match=f"cannot serve on 127.0.0.1:{taken.getsockname()[1]}"):
            server.serve(station, "127.0.0.1", taken.getsockname()[1], announce=lines.append)
        assert lines == []
        assert list(tmp_path.glob("session-*.tlog")) == []  # and took it away, empty, with itself
    finally:
        taken.close()


@pytest.mark.parametrize("content", [None, b"not a certificate\n"])
def test_a_certificate_that_will_not_load_is_an_error_naming_it_before_the_address_is_announced(tmp_path, content):
    """uvicorn loaded the certificate only once it ran: the address was announced, then '[Errno 2] No such file
    or directory' named no file, and an empty recording stayed."""
    from groundstation import server

    pem = tmp_path / "server.pem"
    if content is not None:
        pem.write_bytes(content)
    station = server.GroundStation([f"udpin:127.0.0.1:{free_udp_port()}"], None, TOKEN, record_dir=tmp_path)
    lines = []
    with pytest.raises(ValueError, match=f"cannot serve HTTPS with --tls-cert {pem} and --tls-key {pem}: "):
        server.serve(station, "127.0.0.1", free_tcp_port(), str(pem), str(pem), announce=lines.append)
    assert lines == [] and list(tmp_path.glob("session-*.tlog")) == []


def test_a_link_that_cannot_open_leaves_no_recording(tmp_path):
    from groundstation import server

    with pytest.raises(OSError, match="cannot listen on udpin:999.1.1.1:14550"):
        server.GroundStation(["udpin:999.1.1.1:14550"], None, TOKEN, record_dir=tmp_path)
    assert list(tmp_path.glob("session-*.tlog")) == []


def test_the_station_serves_https_with_its_certificate(tmp_path):
    pem, port = certificate(tmp_path), free_tcp_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "serve", "--port", str(port), "--token", TOKEN,
         "--record-dir", "", "--mavlink", f"udpin:127.0.0.1:{free_udp_port()}", "--tls-cert", pem, "--tls-key", pem],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"})
    try:
        out, err = read_until(process, "ground station:", timeout=30)
        assert f"https://127.0.0.1:{port}/#token={TOKEN}" in out, (out, err)

        trusted = ssl.create_default_context(cafile=str(tmp_path / "ca.pem"))

        def health():
            try:
                return httpx.get(f"https://127.0.0.1:{port}/api/health", verify=trusted, timeout=2)
            except httpx.HTTPError:
                return None

        assert wait_wall(health, 10, "the station answers over HTTPS").json()["status"] == "ok"
    finally:
        process.terminate()
        process.communicate(timeout=10)


def test_the_web_port_listens_before_the_address_is_announced():
    """A page opened the moment the address showed was refused: uvicorn listened only once it had started."""
    from groundstation import server

    listening = server._listening_socket("127.0.0.1", 0)
    try:
        with socket.create_connection(listening.getsockname(), timeout=2):
            pass  # queued until the server takes it
    finally:
        listening.close()


def test_serve_refuses_half_a_tls_setup():
    from groundstation import server

    with idle_station() as station:
        with pytest.raises(ValueError, match="tls"):
            server.serve(station, "127.0.0.1", 8123, tls_cert="cert.pem", tls_key=None)


@pytest.mark.parametrize(("given", "expected"), [(None, (47.3769, 8.5417, 408.0)),
                                                 ("51.5,-0.12", (51.5, -0.12, 584.0))])
def test_the_station_takes_its_datum_from_the_option_else_the_scene(given, expected):
    """Vehicles report latitude and longitude; the station must place them with the datum they use."""
    from vehicle.protocol.geodesy import Datum
    from vehicle.world.scene import parse_scene

    scene = parse_scene('#VRML V2.0 utf8\nWorldInfo { info ["datum=47.3769,8.5417,408"] }\n'
                        "Shape { geometry Box { size 10 10 0.1 } }\n")
    with idle_station(scene, datum=Datum.parse(given) if given else None) as station:
        datum = station.live.datum
        assert (datum.lat, datum.lon, datum.alt) == expected


def test_without_a_scene_the_given_datum_places_live_and_replayed_vehicles():
    from vehicle.protocol.geodesy import Datum

    for given in (Datum(51.5, -0.12, 11.0), None):  # None: the first home heard becomes the origin
        with idle_station(datum=given) as station:
            assert station.datum == given and station.live.datum == given


def test_an_uploaded_mission_says_what_is_left_of_it(api, grounded):
    """QGroundControl's "time remaining": the legs from the vehicle through the items left, at the speed the
    mission sets, plus its loiter time."""
    datum = Datum()
    home = datum.to_global(-4.0, -4.0)
    (a_lat, a_lon), (b_lat, b_lon) = datum.to_global(-4.0, 0.0), datum.to_global(-1.0, 4.0)
    text = "\n".join(["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{home[0]:.8f}\t{home[1]:.8f}\t0.000000\t1",
                      "1\t0\t3\t178\t1\t2.0\t-1\t0\t0\t0\t0\t1",  # DO_CHANGE_SPEED: 2 m/s
                      f"2\t0\t3\t16\t0\t0\t0\t0\t{a_lat:.8f}\t{a_lon:.8f}\t4.000000\t1",
                      f"3\t0\t3\t19\t10\t0\t0\t0\t{b_lat:.8f}\t{b_lon:.8f}\t4.000000\t1"]) + "\n"  # loiter 10 s
    assert api.put("/api/vehicles/2/mission", content=text, headers=api.operator).status_code == 200

    def left():
        return api.get("/api/vehicles/2").json()["mission"]["left"]

    wait_wall(lambda: left() is not None, 30.0, "the mission's remaining legs")
    assert left()["m"] == pytest.approx(4.0 + 5.0, abs=0.05)  # from home (-4, -4) to (-4, 0), then (-1, 4)
    assert left()["s"] == pytest.approx(9.0 / 2.0 + 10.0, abs=1.0) and left()["speed"] == 2.0
