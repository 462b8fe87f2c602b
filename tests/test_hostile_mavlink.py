"""Hostile MAVLink peers against the ground station and the simulated vehicle: real UDP sockets, real bytes.

Each test plays an attacker (or a broken peer) on its own socket (``mavlink_peer.Peer``):
non-finite numbers, zlib bombs and absurd map sizes in the map stream, floods
of fake vehicles and of two-byte datagrams, commands from strangers, and
unsigned or wrongly signed messages; then checks that the station still
answers, shows only finite numbers and keeps tracking the real vehicle, and
that the vehicle obeys only its ground stations.
"""

from __future__ import annotations

import json
import math

import pytest
from harness import RunningStation, small_scene, wait_wall
from mavlink_peer import Peer, non_finite_messages, position, vehicle_heartbeat

from groundstation.replay import Replay
from groundstation.state import Fleet
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.tlog import TlogWriter


@pytest.fixture(scope="module")
def scene():
    return small_scene()


def strict_json(text: str):
    """JSON as a browser's JSON.parse reads it: NaN and Infinity are no JSON."""
    def refuse(constant):
        raise ValueError(f"{constant} in JSON")
    return json.loads(text, parse_constant=refuse)


def station_address(station: RunningStation) -> tuple[str, int]:
    return "127.0.0.1", station.mavlink_port


def ws_frame(station: RunningStation) -> str:
    import websockets.sync.client

    with websockets.sync.client.connect(f"ws://127.0.0.1:{station.http_port}/ws", open_timeout=5) as socket_:
        while True:
            frame = socket_.recv(timeout=5)
            if '"vehicles"' in frame:
                return frame


# ---- 1. non-finite numbers ------------------------------------------------------------------------------
def test_non_finite_numbers_from_a_fake_vehicle_reach_neither_the_api_nor_the_status_stream(tmp_path):
    with RunningStation(None, tmp_path) as station, Peer(station_address(station), sysid=7) as peer:
        peer.send(vehicle_heartbeat(), position(alt=3.0))
        wait_wall(lambda: (station.http.vehicle(7) or {}).get("position"), 10, "the fake vehicle tracked")
        peer.send(*non_finite_messages())
        wait_wall(lambda: station.station.live.get(7).messages_received >= 9, 10, "the broken messages applied")
        response = station.http.get("/api/vehicles")
        assert response.status_code == 200
        shown = strict_json(response.text)[0]
        assert shown["attitude"] == {"roll": 0.0, "pitch": 0.0, "yaw": 0.0}  # the last good values
        assert shown["speed"] == 0.0 and shown["position"]["alt"] == 3.0
        assert shown["position"]["lat"] == pytest.approx(-35.363261)
        strict_json(ws_frame(station))


def test_describe_gives_none_for_any_number_that_is_not_finite():
    fleet = Fleet()
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=3), 0.0)
    vehicle = fleet.get(3)
    vehicle.x, vehicle.y, vehicle.alt, vehicle.roll, vehicle.speed = math.nan, math.inf, -math.inf, math.nan, math.nan
    vehicle.voltage, vehicle.current, vehicle.home = math.nan, math.inf, (math.nan, 0.0)
    shown = fleet.describe(vehicle, 1.0)
    strict_json(json.dumps(shown))
    assert shown["position"]["x"] is None and shown["attitude"]["roll"] is None and shown["speed"] is None


def test_a_crafted_tlog_with_non_finite_numbers_replays_to_finite_json(tmp_path):
    path = tmp_path / "crafted.tlog"
    log = TlogWriter(path)
    packer = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
    for k, message in enumerate([vehicle_heartbeat(), position(), *non_finite_messages(), vehicle_heartbeat()]):
        log.write(pack(message, packer), 1_700_000_000.0 + k * 0.1)
    log.close()
    replay = Replay.open(path, Fleet())
    replay.seek(replay.duration)
    for at in (0.0, 0.35, replay.duration):
        replay.seek(at)
        shown = [replay.fleet.describe(v, replay.now) for v in replay.fleet.vehicles.values()]
        strict_json(json.dumps(shown))
    replay.seek(0.0)
    replay.advance(replay.duration)  # played forward message by message, as a live link feeds it
    assert replay.fleet.get(9).roll == 0.0
    strict_json(json.dumps([replay.fleet.describe(v, replay.now) for v in replay.fleet.vehicles.values()]))


def _decoded(message, sysid: int, compid: int = 1):
    packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    return mavlink.MAVLink(None).decode(bytearray(message.pack(packer)))
