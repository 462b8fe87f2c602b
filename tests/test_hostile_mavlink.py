"""Hostile MAVLink peers against the ground station and the simulated vehicle: real UDP sockets, real bytes.

Each test plays an attacker (or a broken peer) on its own socket (``mavlink_peer.Peer``):
non-finite numbers, zlib bombs and absurd map sizes in the map stream, floods
of fake vehicles and of two-byte datagrams, commands from strangers, and
unsigned or wrongly signed messages; then checks that the station still
answers, shows only finite numbers and keeps tracking the real vehicle, and
that the vehicle obeys only its ground stations.
"""

from __future__ import annotations

import base64
import errno
import hashlib
import json
import math
import os
import re
import socket
import struct
import threading
import time
import tracemalloc
import zlib
from collections import Counter
from unittest import mock

import pytest
from harness import (
    HEARTBEAT_WAIT,
    SPEEDUP,
    RunningSim,
    RunningStation,
    command_ok,
    during,
    free_udp_port,
    launch_chromium,
    make_vehicle,
    needs_chromium,
    small_scene,
    start_sim,
    wait_mode,
    wait_wall,
)
from mavlink_peer import Gcs, Peer, acked, command, gcs_heartbeat, non_finite_messages, position, vehicle_heartbeat

from groundstation.link import Link
from groundstation.replay import Replay
from groundstation.state import FORGET_AFTER, LINK_LOST_AFTER, MAX_VEHICLES, Fleet
from vehicle.agent.companion import tunnel
from vehicle.agent.settings import Settings
from vehicle.cli import DEFAULT_SIM_LINK
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol import links, signing
from vehicle.protocol.map_bounds import MAX_SIDE, MAX_SPACE, MIN_RESOLUTION
from vehicle.protocol.mapstream import MAP_DELTA, MapReceiver, MapStreamer, snapshot_chunks
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.statustext import Reassembler, statustexts
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


# ---- 2. what a map stream claims ------------------------------------------------------------------------
def snapshot_blob(size: int, part: tuple[int, int, int, int], compressed: bytes, resolution: float = 10.0) -> bytes:
    """A map snapshot blob (see vehicle.protocol.mapstream) with any geometry it likes to claim."""
    return struct.pack("<BHfffIHHHH", 1, size, resolution, -20.0, -20.0, 0, *part) + compressed


def zlib_bomb(megabytes: int) -> bytes:
    """``megabytes`` MB of zeros, zlib-compressed about a thousand to one, made without holding them."""
    packer = zlib.compressobj(9)
    block = bytes(1 << 20)
    return b"".join(packer.compress(block) for _ in range(megabytes)) + packer.flush()


def peak_memory(run) -> int:
    """Bytes Python allocated at the peak while ``run()`` ran (numpy's arrays included)."""
    tracemalloc.start()
    try:
        run()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def feed_all(receiver: MapReceiver, payloads: list[tuple[int, bytes]]) -> None:
    for kind, payload in payloads:
        receiver.feed(kind, payload)


def test_a_zlib_bomb_in_a_map_snapshot_is_inflated_no_further_than_its_claim():
    bomb = snapshot_chunks(1, snapshot_blob(100, (0, 0, 10, 10), zlib_bomb(200)))  # 200 MB in ~1,700 chunks
    receiver = MapReceiver()
    assert peak_memory(lambda: feed_all(receiver, bomb)) < 20e6
    assert receiver.grid is None and receiver.snapshots == 0


@pytest.mark.parametrize("side", [MAX_SIDE + 1, 30_000, 65_535])
def test_a_snapshot_claiming_a_huge_map_in_one_packet_is_refused_before_any_grid_exists(side):
    claim = snapshot_chunks(1, snapshot_blob(side, (0, 0, 0, 0), zlib.compress(b"")))
    assert len(claim) == 1 and len(claim[0][1]) < 64  # one small TUNNEL message
    receiver = MapReceiver()
    assert peak_memory(lambda: feed_all(receiver, claim)) < 5e6
    assert receiver.grid is None and receiver.geometry is None


def test_a_snapshot_with_a_geometry_that_is_no_number_is_refused():
    for resolution in (math.nan, math.inf, 0.0, -1.0):
        receiver = MapReceiver()
        feed_all(receiver, snapshot_chunks(1, snapshot_blob(4, (0, 0, 0, 0), zlib.compress(b""), resolution)))
        assert receiver.grid is None


def test_the_widest_and_the_coarsest_maps_the_settings_allow_are_received():
    for space, resolution in ((MAX_SPACE, MAX_SIDE / (2 * MAX_SPACE)), (MAX_SPACE, MIN_RESOLUTION), (1.0, 50.0)):
        memory_map = MemoryMap((0.0, 0.0), Settings(space_size=space, resolution=resolution).space_size, resolution)
        receiver = MapReceiver()
        feed_all(receiver, MapStreamer(memory_map, (0.0, 0.0)).snapshot())
        assert receiver.grid is not None and receiver.grid.shape == memory_map.grid.shape, (space, resolution)


def test_the_largest_map_a_vehicle_may_stream_is_received():
    receiver = MapReceiver()
    feed_all(receiver, snapshot_chunks(1, snapshot_blob(MAX_SIDE, (5, 5, 2, 2), zlib.compress(bytes([9] * 4)))))
    assert receiver.grid.shape == (MAX_SIDE, MAX_SIDE) and int(receiver.grid.sum()) == 36


def test_a_delta_naming_more_cells_than_its_map_or_a_cell_twice_is_dropped():
    receiver = MapReceiver()
    feed_all(receiver, snapshot_chunks(1, snapshot_blob(4, (0, 0, 0, 0), zlib.compress(b""))))
    assert receiver.synced and receiver.grid.shape == (4, 4)
    twice = _raw_deflate(bytes([0] * 100) + bytes([20] * 100))  # cell 0, a hundred times over
    receiver.feed(MAP_DELTA, struct.pack("<IH", 1, 100) + twice)
    assert receiver.applied == 0 and not receiver.grid.any()
    good = _raw_deflate(bytes([3, 1]) + bytes([20, 21]))  # cells 3 and 4
    receiver.feed(MAP_DELTA, struct.pack("<IH", 1, 2) + good)
    assert receiver.applied == 1 and receiver.grid.reshape(-1)[3:5].tolist() == [20, 21]


def _raw_deflate(data: bytes) -> bytes:
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    return packer.compress(data) + packer.flush()


def test_a_station_keeps_tracking_its_vehicle_through_map_bombs_and_huge_claims(scene, tmp_path):
    with RunningStation(scene, tmp_path) as station, start_sim(station, scene), \
            Peer(station_address(station), sysid=1, compid=191) as spoofer:
        api = station.http
        api.wait_vehicle(1, lambda v: v["map"]["source"] == "vehicle", what="the vehicle's own map")
        before = resident_bytes()
        for side in (30_000, 65_535):
            claim = snapshot_chunks(7, snapshot_blob(side, (0, 0, 0, 0), zlib.compress(b"")))
            spoofer.send(*(tunnel(kind, payload) for kind, payload in claim))
        spoofer.send(*(tunnel(kind, payload) for kind, payload in
                       snapshot_chunks(8, snapshot_blob(400, (0, 0, 10, 10), zlib_bomb(50)))))
        spoofer.send(tunnel(MAP_DELTA, struct.pack("<IH", 10**6, 65535) + zlib_bomb(1)[:120]))
        command_ok(api, 1, action="set_mode", mode="LOITER")
        shown = api.wait_vehicle(1, lambda v: v["mode"] == "LOITER", sim_timeout=HEARTBEAT_WAIT, what="LOITER")
        assert shown["link"]["heartbeat_age"] < 3 and shown["map"]["source"] == "vehicle"
        assert station.station.live.get(1).map_stream.grid.shape == (400, 400)  # the vehicle's map, still
        assert resident_bytes() - before < 100e6
        assert api.get("/api/health").json()["status"] == "ok"


def resident_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * 4096


# ---- 3. fake vehicles ------------------------------------------------------------------------------------
def test_a_flood_of_fake_vehicles_fills_the_fleet_only_to_its_limit_and_the_real_one_still_answers(scene, tmp_path):
    with RunningStation(scene, tmp_path) as station, start_sim(station, scene):
        api = station.http
        api.wait_vehicle(1, lambda v: v["link"]["state"] == "ok", what="the real vehicle")
        fakes = [Peer(station_address(station), sysid=2 + k % 254) for k in range(300)]  # each from its own port
        for fake in fakes:
            fake.send(vehicle_heartbeat(), position())
        health = wait_wall(lambda: (h := api.get("/api/health").json())["link"]["vehicles"]["refused"] > 0 and h,
                           10, "fake vehicles refused")
        held = health["link"]["vehicles"]
        assert held["held"] == held["limit"] == MAX_VEHICLES and len(api.vehicles()) == MAX_VEHICLES
        assert 1 in api.vehicles()  # heard first, kept
        command_ok(api, 1, action="set_mode", mode="LOITER")
        shown = api.wait_vehicle(1, lambda v: v["mode"] == "LOITER", sim_timeout=HEARTBEAT_WAIT, what="LOITER")
        assert shown["link"]["heartbeat_age"] < 3
        asked = {m.target_system for fake in fakes for m in fake.receive(0.005) if m.get_type() == "COMMAND_LONG"}
        assert 0 < len(asked) <= MAX_VEHICLES - 1  # only the vehicles the fleet holds are asked for telemetry
        for fake in fakes:
            fake.close()


def test_a_vehicle_not_heard_for_ten_minutes_is_forgotten_and_makes_room():
    fleet = Fleet(max_vehicles=2)
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=3), 0.0)
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=4), 0.0)
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=5), 1.0)
    assert fleet.ids() == [3, 4] and fleet.refused == 1  # full: the newcomer is refused
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=4), FORGET_AFTER - 10)
    fleet.apply(_decoded(vehicle_heartbeat(), sysid=5), FORGET_AFTER + 1)
    assert fleet.ids() == [4, 5] and fleet.forgotten == 1  # 3 was silent for ten minutes: forgotten


def test_a_replayed_log_forgets_no_vehicle_however_long_it_was_silent(tmp_path):
    path = tmp_path / "quiet.tlog"
    log = TlogWriter(path)
    first, second = (mavlink.MAVLink(None, srcSystem=s, srcComponent=1) for s in (9, 10))
    log.write(pack(vehicle_heartbeat(), first), 1_700_000_000.0)
    log.write(pack(vehicle_heartbeat(), second), 1_700_000_000.0 + 2 * FORGET_AFTER)
    log.close()
    replay = Replay.open(path, Fleet())
    replay.advance(replay.duration)
    assert replay.fleet.ids() == [9, 10]
    replay.seek(replay.duration)
    assert replay.fleet.ids() == [9, 10]


def assert_orders_reach_only(link: Link, vehicle: Peer, attacker: Peer) -> None:
    """A mode change the station sends to vehicle 1 reaches the vehicle, and none of it the attacker."""
    vehicle.receive(0.3), attacker.receive(0.3)  # what the station said before: its telemetry requests

    def orders(peer):
        return [m for m in peer.receive()
                if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE]

    link.send(command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4), 1)
    assert len(orders(vehicle)) == 1 and orders(attacker) == []


@pytest.mark.parametrize("attack", [
    pytest.param([tunnel(32801, b"\0" * 100), position()] * 50, id="a map snapshot flood"),
    pytest.param([vehicle_heartbeat()] * 5, id="spoofed heartbeats"),
    pytest.param([position(), position(alt=80.0)], id="spoofed positions"),
])
def test_what_comes_in_a_vehicles_name_from_elsewhere_neither_moves_it_nor_takes_its_orders(attack):
    """A map snapshot in vehicle 1's name, 8,555 chunks from an attacker's address, took vehicle 1's route, as
    did (without signing) a single heartbeat in its name: the operator's commands went to the attacker for as
    long as the attack lasted, and came back unanswered. Positions in its name from anywhere moved it on the
    page."""
    port = free_udp_port()
    fleet = Fleet()
    link = Link([f"udpin:127.0.0.1:{port}"], fleet).start()
    try:
        with Peer(("127.0.0.1", port), sysid=1) as vehicle, Peer(("127.0.0.1", port), sysid=1) as attacker:
            vehicle.send(vehicle_heartbeat(), position(alt=4.0))
            wait_wall(lambda: 1 in link.route and fleet.vehicles[1].alt == 4.0, 5, "the vehicle heard")
            attacker.send(*attack)
            wait_wall(lambda: link.from_elsewhere[1] == len(attack), 5, "the attack heard")
            assert fleet.vehicles[1].alt == 4.0 and fleet.vehicles[1].map_stream.payloads == 0
            assert link.health()["from_elsewhere"] == [{"sysid": 1, "messages": len(attack)}]
            assert_orders_reach_only(link, vehicle, attacker)
    finally:
        link.close()


class KeptPort:
    """A link's stand-in that keeps who was written to (the station answers a heartbeat with requests)."""

    def __init__(self):
        self.refused: Counter = Counter()
        self.written: list = []

    def write(self, packet: bytes, peer=None) -> None:
        self.written.append(peer)


def test_a_vehicle_is_heard_where_its_heartbeat_comes_from_and_followed_once_silent_there():
    """Its link died and it came back on another (a radio after Wi-Fi, a restarted process on a new port): its
    heartbeat there is heard once none came from the old place for LINK_LOST_AFTER, and only then is what comes
    from there. Another part of the system (its onboard agent, on a link of its own) is heard from anywhere."""
    fleet = Fleet()
    link = Link([], fleet)
    wifi, radio = KeptPort(), KeptPort()
    start = time.time()

    def hear(port: KeptPort, message, after: float, compid: int = 1) -> None:
        packet = pack(message, mavlink.MAVLink(None, srcSystem=1, srcComponent=compid))
        parsed = mavlink.MAVLink(None).parse_buffer(packet)[0]
        parsed._peer = ("127.0.0.1", 5000) if port is wifi else None
        link._receive(port, parsed, start + after)

    hear(wifi, vehicle_heartbeat(), 0.0)
    hear(wifi, position(alt=4.0), 0.1)
    hear(radio, vehicle_heartbeat(), 0.2)  # a second link to it, or another sender: not heard while wifi beats
    hear(radio, position(alt=50.0), 0.3)
    assert fleet.vehicles[1].alt == 4.0 and link.from_elsewhere[1] == 2 and link.route[1][0] is wifi
    hear(wifi, position(alt=5.0), 1.0)  # telemetry from wifi does not count as its heartbeat
    hear(radio, vehicle_heartbeat(), LINK_LOST_AFTER - 0.1)
    assert link.from_elsewhere[1] == 3 and link.route[1][0] is wifi
    hear(radio, vehicle_heartbeat(), LINK_LOST_AFTER + 0.1)
    hear(radio, position(alt=6.0), LINK_LOST_AFTER + 0.2)
    hear(wifi, position(alt=60.0), LINK_LOST_AFTER + 0.3)  # now wifi is elsewhere
    assert fleet.vehicles[1].alt == 6.0 and link.from_elsewhere[1] == 4 and link.route[1][0] is radio
    hear(wifi, vehicle_heartbeat(mav_type=mavlink.MAV_TYPE_ONBOARD_CONTROLLER), LINK_LOST_AFTER + 0.4, compid=191)
    hear(wifi, mavlink.MAVLink_statustext_message(6, b"agent here"), LINK_LOST_AFTER + 0.5, compid=191)
    assert fleet.vehicles[1].status == "agent here" and link.route[1][0] is radio
    assert link.from_elsewhere[1] == 4
    link._prune(start + LINK_LOST_AFTER + FORGET_AFTER + 1)  # forgotten: whoever is heard next is heard
    assert 1 not in link.route
    hear(wifi, position(alt=7.0), LINK_LOST_AFTER + FORGET_AFTER + 2)
    assert link.route[1][0] is wifi and link.from_elsewhere[1] == 4


def test_a_reply_is_taken_only_from_the_component_asked_and_a_boot_time_only_from_the_autopilot():
    """A COMMAND_ACK in vehicle 1's name from another component (a sender that took a component id of its own)
    answered the station's order to the autopilot: a LAND the vehicle never saw came back "denied". A small
    boot time from such a component made the station ask again for all its telemetry at every heartbeat."""
    port = free_udp_port()
    link = Link([f"udpin:127.0.0.1:{port}"], Fleet()).start()
    try:
        with Peer(("127.0.0.1", port), sysid=1) as vehicle, Peer(("127.0.0.1", port), sysid=1, compid=250) as other:
            vehicle.send(vehicle_heartbeat(), mavlink.MAVLink_attitude_message(600_000, 0, 0, 0, 0, 0, 0))
            wait_wall(lambda: link._asked.get(1, (0, 0))[1] == 600.0, 5, "the vehicle heard, ten minutes up")
            asked = link._asked[1]

            def answer():
                time.sleep(0.2)  # the station waits for a reply by now
                other.send(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_RESULT_DENIED))
                time.sleep(0.3)
                vehicle.send(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_NAV_LAND,
                                                                 mavlink.MAV_RESULT_ACCEPTED))

            threading.Thread(target=answer, daemon=True).start()
            reply = link.request(1, command(mavlink.MAV_CMD_NAV_LAND), lambda m: m.get_type() == "COMMAND_ACK",
                                 timeout=3.0, retries=1)
            assert (reply.result, reply.get_srcComponent()) == (mavlink.MAV_RESULT_ACCEPTED, 1)
            received = link.stats["received"]
            other.send(mavlink.MAVLink_attitude_message(1000, 0, 0, 0, 0, 0, 0))  # "rebooted a second ago"
            vehicle.send(vehicle_heartbeat())
            wait_wall(lambda: link.stats["received"] >= received + 2, 5, "both heard")
            assert link._asked[1][1] == asked[1]  # not taken for a reboot: not asked again
    finally:
        link.close()


def test_a_vehicle_heard_signed_keeps_its_orders_from_an_unsigned_heartbeat_in_its_name():
    """A station with a key that does not require signing let an unsigned heartbeat in a signed vehicle's name, from
    anywhere, take its route: the operator's orders went to the sender of the heartbeat."""
    port = free_udp_port()
    fleet = Fleet()
    link = Link([f"udpin:127.0.0.1:{port}"], fleet, signing_key=KEY).start()
    try:
        with Peer(("127.0.0.1", port), sysid=1, key=KEY) as vehicle, \
                Peer(("127.0.0.1", port), sysid=1) as attacker, Peer(("127.0.0.1", port), sysid=2) as stranger:
            vehicle.send(vehicle_heartbeat())
            wait_wall(lambda: 1 in link.route and fleet.vehicles.get(1) is not None, 5, "the vehicle heard")
            attacker.send(vehicle_heartbeat(), vehicle_heartbeat(), position())
            received = link.stats["received"]
            radio = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)  # on the vehicle's link; radios never sign
            vehicle.raw(pack(mavlink.MAVLink_radio_status_message(200, 190, 90, 80, 70, 0, 0), radio))
            attacker.as_system(1, 100).send(vehicle_heartbeat(mav_type=mavlink.MAV_TYPE_CAMERA))  # a part never signed
            stranger.send(vehicle_heartbeat())  # a vehicle never heard signed is still shown, as unsigned
            wait_wall(lambda: 2 in link.route and link.stats["received"] >= received + 3, 5, "the unsigned heard")
            assert link.health()["signing"]["refused"] == [{"sysid": 1, "messages": 3}]
            assert fleet.vehicles[1].signed is True and fleet.vehicles[2].signed is False
            assert_orders_reach_only(link, vehicle, attacker.as_system(1, 1))
            link._prune(time.time() + FORGET_AFTER + 1)  # vehicle 1 silent for ten minutes: forgotten, with its key
            attacker.send(vehicle_heartbeat())
            wait_wall(lambda: 1 in link.route, 5, "a new vehicle 1 heard")
            assert link.health()["signing"]["refused"] == [{"sysid": 1, "messages": 3}]
    finally:
        link.close()


def test_the_links_routes_and_unfinished_texts_stay_bounded():
    link = Link([], Fleet())
    for sysid in range(1, 256):
        link.route[sysid] = (None, None, 0.0 if sysid > 1 else FORGET_AFTER, 0.0)
        link._asked[sysid] = (0.0, 0.0)
    link._prune(FORGET_AFTER + 1)
    assert list(link.route) == [1] and list(link._asked) == [1]  # only the one heard within ten minutes
    texts = Reassembler()
    for k in range(300):  # chunk 0 of a long text each, never finished, from many senders
        texts.feed(_decoded(statustexts("x" * 120, 6, k + 1)[0], sysid=1 + k % 255, compid=1 + k // 255), 0.0)
    assert len(texts._partial) <= texts.limit


# ---- 4. who the simulated vehicle obeys --------------------------------------------------------------------
ARM, TAKEOFF, SET_MODE = (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_NAV_TAKEOFF,
                          mavlink.MAV_CMD_DO_SET_MODE)


def sim_for(peer: Peer, scene, **options) -> RunningSim:
    """A simulated copter sending to ``peer``, which sends back to it once started."""
    runner = RunningSim(make_vehicle(scene), [peer.url], **options)
    peer.address = runner.sim.endpoint.links[0].port.getsockname()
    return runner


def test_the_sim_denies_a_sender_that_is_no_ground_station_and_obeys_one_that_is(scene):
    with Peer(None, sysid=66) as stranger, sim_for(stranger, scene) as sim:
        pilot = sim.world.autopilot
        for number, params in ((SET_MODE, (1, 5)), (ARM, (1,)), (TAKEOFF, (0, 0, 0, 0, 0, 0, 4))):
            stranger.send(command(number, *params))
            ack = acked(stranger, number)
            assert ack.result == mavlink.MAV_RESULT_DENIED and ack.target_system == 66  # told, not ignored
        stranger.send(mavlink.MAVLink_set_mode_message(1, 1, 5),
                      mavlink.MAVLink_mission_count_message(1, 1, 3, 0))
        assert stranger.wait(lambda m: m.get_type() == "MISSION_REQUEST_INT", 1.0) is None
        assert not pilot.armed and pilot.mode == "GUIDED"  # as it booted
        assert [t for t in stranger.texts if "Not obeying 66/1" in t] == ["Not obeying 66/1: no GCS heartbeat from it"]
        stranger.send(gcs_heartbeat())  # now it is a ground station
        for number, params in ((ARM, (1,)), (TAKEOFF, (0, 0, 0, 0, 0, 0, 4))):
            stranger.send(command(number, *params))
            assert acked(stranger, number).result == mavlink.MAV_RESULT_ACCEPTED
        assert pilot.armed and pilot.mode == "GUIDED"


def test_the_sim_obeys_its_own_companion_without_a_gcs_heartbeat(scene):
    with Peer(None, sysid=1, compid=191) as companion, sim_for(companion, scene) as sim:
        companion.send(command(SET_MODE, 1, 5))
        assert acked(companion, SET_MODE).result == mavlink.MAV_RESULT_ACCEPTED
        assert sim.world.autopilot.mode == "LOITER"
        companion.as_system(1, 190).send(command(SET_MODE, 1, 4))  # the same system, another component
        assert acked(companion, SET_MODE).result == mavlink.MAV_RESULT_DENIED


def test_a_strangers_orders_are_not_routed_on_to_the_companion(scene):
    with Peer(None, sysid=66) as stranger, Peer(None, sysid=1, compid=191) as agent:
        runner = RunningSim(make_vehicle(scene, mission=None), [stranger.url, agent.url], sim_clock=True)
        stranger.address = runner.sim.endpoint.links[0].port.getsockname()
        agent.address = runner.sim.endpoint.links[1].port.getsockname()
        with runner:
            agent.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                         mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
            stranger.send(command(mavlink.MAV_CMD_MISSION_START, component=191))
            assert acked(stranger, mavlink.MAV_CMD_MISSION_START).result == mavlink.MAV_RESULT_DENIED
            assert agent.wait(lambda m: m.get_type() == "COMMAND_LONG", 1.0) is None
            stranger.send(gcs_heartbeat(), command(mavlink.MAV_CMD_MISSION_START, component=191))
            assert agent.wait(lambda m: m.get_type() == "COMMAND_LONG", 2.0) is not None  # a ground station's is


def test_vehicle_sim_answers_on_loopback_only_unless_told_otherwise():
    link = links.connect(DEFAULT_SIM_LINK)  # what ``vehicle sim`` talks on without --mavlink
    try:
        assert link.port.getsockname()[0] == "127.0.0.1"
    finally:
        link.close()


# ---- 5. a flood of two-byte datagrams ------------------------------------------------------------------------
class Flooder:
    """Sends ``\\xfd\\xff`` (the start of a MAVLink 2 packet of 255 bytes that never comes) to some addresses, at
    ``rate`` datagrams a second each, from its own socket, until stopped."""

    def __init__(self, addresses: list[tuple[str, int]], rate: float = 150.0):
        self.addresses, self.rate, self.sent = addresses, rate, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Flooder:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _run(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as flood:
            while not self._stop.wait(1.0 / self.rate):
                for address in self.addresses:
                    flood.sendto(b"\xfd\xff", address)
                    self.sent += 1


@pytest.mark.parametrize("target", ["station", "vehicle"])
def test_a_two_byte_datagram_flood_neither_hides_the_vehicle_nor_trips_its_failsafe(scene, tmp_path, target):
    """Against the station's port, or the vehicle's: with one parser for all senders the flood swallowed the
    real packets that followed it (commands went unanswered, the vehicle's GCS failsafe tripped)."""
    with RunningStation(scene, tmp_path) as station, start_sim(station, scene, failsafe_timeout=2.0) as sim:
        api = station.http
        api.wait_vehicle(1, lambda v: v["link"]["state"] == "ok" and v["position"], what="the vehicle")
        port = station_address(station) if target == "station" else sim.endpoint.links[0].port.getsockname()
        with Flooder([port]) as flood:
            results = []
            for _ in during(3.0, period=0.2):  # longer than the vehicle's failsafe timeout
                mode = "LOITER" if len(results) % 2 == 0 else "GUIDED"
                results.append(api.result(1, action="set_mode", mode=mode))
                assert api.vehicle(1)["link"]["heartbeat_age"] < 3
        assert flood.sent > 300 and len(results) >= 5 and set(results) == {"accepted"}
        assert not sim.endpoint.in_failsafe
        assert not [m for m in api.vehicle(1)["messages"] if "failsafe" in m["text"]]


# ---- 6. signing ----------------------------------------------------------------------------------------------
KEY = signing.load_key("correct horse battery staple")
WRONG_KEY = signing.load_key("not the key")


def test_a_signing_key_is_a_file_of_32_bytes_or_of_hex_or_base64_or_a_passphrase(tmp_path):
    raw = bytes(range(32))
    for name, content in (("raw", raw), ("hex", raw.hex().encode() + b"\n"), ("b64", base64.b64encode(raw))):
        (tmp_path / name).write_bytes(content)
        assert signing.load_key(str(tmp_path / name)) == raw
    assert KEY == hashlib.sha256(b"correct horse battery staple").digest()  # as MAVProxy's signing setup
    (tmp_path / "short").write_bytes(b"0123")
    for bad in (str(tmp_path / "short"), str(tmp_path / "missing.key"), ""):
        with pytest.raises(signing.SigningKeyError):
            signing.load_key(bad)


def _signed(message, key: bytes, sysid: int = 1, compid: int = 1, packer=None):
    packer = packer or mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if key is not None and not packer.signing.sign_outgoing:
        signing.sign_outgoing(packer, key)
    return mavlink.MAVLink(None).decode(bytearray(pack(message, packer)))


def test_the_verifier_takes_each_signed_message_once_and_nothing_else():
    verifier = signing.Verifier(KEY)
    beat = _signed(vehicle_heartbeat(), KEY)
    assert verifier.check(beat) == signing.SIGNED
    assert verifier.check(beat) == signing.REPLAYED  # the same packet again (from anyone): a replay
    assert verifier.check(_signed(vehicle_heartbeat(), WRONG_KEY)) == signing.BAD
    assert verifier.check(_decoded(vehicle_heartbeat(), 1)) == signing.UNSIGNED
    radio = _decoded(mavlink.MAVLink_radio_status_message(200, 190, 90, 80, 70, 0, 0), 51, 68)
    assert verifier.admits(radio, verifier.check(radio))  # radios do not sign
    assert not verifier.admits(beat, signing.UNSIGNED) and not verifier.admits(beat, signing.BAD)
    assert signing.Verifier(KEY, require=False).admits(beat, signing.UNSIGNED)


def test_a_forged_packet_with_a_future_timestamp_does_not_silence_the_genuine_stream():
    """pymavlink's own check records the timestamp before it checks the signature."""
    verifier = signing.Verifier(KEY)
    genuine = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    signing.sign_outgoing(genuine, KEY)
    forger = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    signing.sign_outgoing(forger, WRONG_KEY)
    forger.signing.link_id = genuine.signing.link_id
    forger.signing.timestamp = genuine.signing.timestamp + 10**9
    assert verifier.check(_signed(vehicle_heartbeat(), KEY, packer=forger)) == signing.BAD
    assert verifier.check(_signed(vehicle_heartbeat(), KEY, packer=genuine)) == signing.SIGNED


def test_a_signed_sim_obeys_only_signed_commands_and_signs_what_it_sends(scene):
    with Peer(None, sysid=66) as unsigned, Peer(None, sysid=67, key=WRONG_KEY) as forger, \
            Peer(None, sysid=68, key=KEY) as operator:
        runner = RunningSim(make_vehicle(scene), [unsigned.url, forger.url, operator.url], signing_key=KEY)
        for k, peer in enumerate((unsigned, forger, operator)):
            peer.address = runner.sim.endpoint.links[k].port.getsockname()
        with runner as sim:
            for peer in (unsigned, forger):
                peer.send(gcs_heartbeat(), command(ARM, 1))
                assert acked(peer, ARM, timeout=1.5) is None  # dropped unheard: not even denied
            assert not sim.world.autopilot.armed
            answer = None
            for _ in range(5):  # as a ground station does: the command again until it is answered
                operator.send(gcs_heartbeat(), command(ARM, 1))
                if (answer := acked(operator, ARM)) is not None:
                    break
            assert answer is not None, "the signed operator's ARM was never answered"
            assert answer.result == mavlink.MAV_RESULT_ACCEPTED and sim.world.autopilot.armed
            unsigned.as_system(51, 68).send(mavlink.MAVLink_radio_status_message(200, 190, 90, 80, 70, 0, 0))
            beat = unsigned.wait(lambda m: m.get_type() == "HEARTBEAT")
            assert signing.Verifier(KEY).check(beat) == signing.SIGNED
            refused = sum((link.refused for link in sim.endpoint.links), Counter())
            assert refused[66] >= 2 and refused[67] >= 2 and 51 not in refused and 68 not in refused


@pytest.mark.parametrize(("vehicle_key", "signed"), [(KEY, True), (None, False)])
def test_a_station_with_a_key_shows_whether_each_vehicle_signs(scene, tmp_path, vehicle_key, signed):
    with RunningStation(scene, tmp_path, signing_key=KEY) as station, \
            start_sim(station, scene, signing_key=vehicle_key):
        shown = station.http.wait_vehicle(1, lambda v: v["link"]["signed"] is not None, what="its link")
        assert shown["link"]["signed"] is signed
        command_ok(station.http, 1, action="set_mode", mode="LOITER")  # what the station sends is signed


def test_a_station_that_requires_signing_shows_no_unsigned_vehicle(scene, tmp_path):
    with RunningStation(scene, tmp_path, signing_key=KEY, require_signing=True) as station, \
            start_sim(station, scene), start_sim(station, scene, sysid=2, signing_key=KEY):
        station.http.wait_vehicle(2, lambda v: v["link"]["signed"], what="the signed vehicle")
        health = wait_wall(lambda: (h := station.http.get("/api/health").json())["link"]["signing"]["refused"] and h,
                           10, "the unsigned vehicle refused")
        assert 1 not in station.http.vehicles()
        assert health["link"]["signing"] == {"key": True, "required": True,
                                             "refused": [{"sysid": 1, "messages": mock.ANY}]}


# ---- 7. another ground station in command ------------------------------------------------------------------
def test_the_station_shows_when_another_ground_station_commands_its_vehicle(scene, tmp_path):
    other_port = free_udp_port()
    other = Gcs(f"udpin:127.0.0.1:{other_port}", sysid=254, speedup=SPEEDUP)
    with RunningStation(scene, tmp_path) as station, \
            RunningSim(make_vehicle(scene), [station.vehicle_url(), f"udpout:127.0.0.1:{other_port}"]):
        api = station.http
        api.wait_vehicle(1, lambda v: v["link"]["state"] == "ok", what="the vehicle")
        assert api.vehicle(1)["other_gcs"] is None
        other.wait("HEARTBEAT")  # and its own heartbeats reach the vehicle, which routes them to the station
        assert other.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED  # LOITER, by station 254
        shown = api.wait_vehicle(1, lambda v: v["other_gcs"] is not None, what="the other station")
        assert shown["other_gcs"]["sysid"] == 254
        assert shown["other_gcs"]["last"] == "COMMAND_ACK MAV_CMD_DO_SET_MODE accepted"
        assert 0 <= shown["other_gcs"]["age"] < 3
        health = api.get("/api/health").json()["link"]
        assert [s["sysid"] for s in health["other_stations"]] == [254]

        command_ok(api, 1, action="set_mode", mode="GUIDED")  # this station's own order: not another's doing
        wait_mode(api, 1, "GUIDED")
        assert api.vehicle(1)["other_gcs"]["last"] == "COMMAND_ACK MAV_CMD_DO_SET_MODE accepted"

        other.heartbeat()
        other.mav.set_mode_send(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 17)  # BRAKE, unacknowledged
        other.wait_mode(17)
        shown = api.wait_vehicle(1, lambda v: v["mode"] == "BRAKE", sim_timeout=HEARTBEAT_WAIT, what="BRAKE")
        assert shown["other_gcs"] == {"sysid": 254, "last": "mode BRAKE, not ordered by this station",
                                      "age": mock.ANY}
    other.close()


@needs_chromium
@pytest.mark.browser
def test_the_page_shows_another_ground_station_and_a_signed_link(scene, tmp_path):
    from playwright.sync_api import expect, sync_playwright

    other_port = free_udp_port()
    other = Gcs(f"udpin:127.0.0.1:{other_port}", sysid=254, speedup=SPEEDUP, key=KEY)  # it has the key too
    with RunningStation(scene, tmp_path, signing_key=KEY) as station, \
            RunningSim(make_vehicle(scene), [station.vehicle_url(), f"udpout:127.0.0.1:{other_port}"],
                       signing_key=KEY), sync_playwright() as playwright:
        station.http.wait_vehicle(1, lambda v: v["link"]["signed"], what="the signed vehicle")
        browser = launch_chromium(playwright)
        try:
            page = browser.new_page()
            page.goto(station.base + "/")
            card = page.locator(".vehicle-card[data-sysid='1']")
            expect(card.locator(".link")).to_have_text(re.compile(r"^link ok · .* · signed$"))
            banner = card.locator(".other-gcs-banner")
            expect(banner).to_be_hidden()
            other.wait("HEARTBEAT")
            assert other.set_mode(5) == mavlink.MAV_RESULT_ACCEPTED  # LOITER, by station 254
            expect(banner).to_have_text(re.compile(
                r"^Another ground station \(system 254\) is commanding this vehicle: "
                # the ACK or the heartbeat in the new mode, whichever the station hears first
                r"(COMMAND_ACK MAV_CMD_DO_SET_MODE accepted|mode LOITER, not ordered by this station), "
                r"[\d.]+ s ago$"), timeout=15_000)
            expect(banner).to_be_visible()
        finally:
            browser.close()
    other.close()


# ---- 8. a full disk, and a message that breaks the fleet ----------------------------------------------------
class FullDisk:
    """A file on a disk with no room left: every write and flush fails as a full disk does."""

    def write(self, data) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def flush(self) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self) -> None:
        pass


def test_a_full_disk_degrades_the_health_report_but_the_vehicle_stays_tracked(scene, tmp_path):
    with RunningStation(scene, tmp_path) as station, start_sim(station, scene):
        api = station.http
        api.wait_vehicle(1, lambda v: v["link"]["state"] == "ok", what="the vehicle")
        assert api.get("/api/health").json()["status"] == "ok"
        station.station.recorder._writer._file = FullDisk()
        health = wait_wall(lambda: (h := api.get("/api/health").json())["status"] == "degraded" and h, 10,
                           "the health report degraded")
        assert "No space left on device" in health["recording"]["error"] == health["link"]["recording_error"]
        assert health["link"]["thread"] == "ok"
        command_ok(api, 1, action="set_mode", mode="LOITER")
        shown = api.wait_vehicle(1, lambda v: v["mode"] == "LOITER", sim_timeout=HEARTBEAT_WAIT, what="LOITER")
        assert shown["link"]["heartbeat_age"] < 3


def test_a_message_that_breaks_the_fleet_is_counted_and_the_link_thread_goes_on(tmp_path, monkeypatch):
    def exhausted(*args):
        raise MemoryError("a VFR_HUD too many")

    with RunningStation(None, tmp_path) as station, Peer(station_address(station), sysid=7) as peer:
        monkeypatch.setattr(station.station.live, "_vfr_hud", exhausted)
        peer.send(vehicle_heartbeat(), mavlink.MAVLink_vfr_hud_message(1.0, 1.0, 0, 0, 0, 0), position(alt=2.0))
        link = wait_wall(lambda: (h := station.http.get("/api/health").json()["link"])["errors"] and h, 10,
                         "the error counted")
        assert link["errors"] == 1 and link["last_error"] == "MemoryError: a VFR_HUD too many"
        assert link["thread"] == "ok" and station.station.link._thread.is_alive()
        shown = wait_wall(lambda: station.http.vehicle(7)["position"], 10, "the next message applied")
        assert shown["alt"] == 2.0
