"""A team on the wire: ``vehicle sim --role autopilot --vehicles N`` serves N autopilots in one world, and each
agent learns where the others are from the ADSB_VEHICLE its autopilot forwards.

Real processes and real sockets: the team runs as the command a user types, the agents' flight controllers
(``MavlinkController``) listen on the ports the command's port rule gives (vehicle k: the --mavlink port + 10 k).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import pytest
from harness import SCENE_TEXT, during, free_port, free_udp_port, wait_sim, wait_wall
from test_demo import WAIT, processes_mentioning, vehicles

from vehicle.agent.mavlink_controller import MavlinkController
from vehicle.protocol import links
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink

SPEEDUP = 4.0
RADIUS = 0.3  # m: the simulated copter's body, and what the agent assumes a team-mate's is


def free_pair() -> int:
    """A UDP port P with P + 10 free too (vehicle 2's, by the team's port rule)."""
    for _ in range(50):
        port = free_udp_port()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("127.0.0.1", port + 10))
            except OSError:
                continue
        return port
    raise OSError("no free pair of UDP ports ten apart")


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "walls.wrl"
    path.write_text(SCENE_TEXT)
    return path


def start_team(scene_file, port: int, *extra: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "vehicle.cli", "sim", "--role", "autopilot", "--vehicles", "2", "--scene",
               str(scene_file), "--mavlink", f"udpout:127.0.0.1:{port}", "--speedup", str(SPEEDUP), *extra]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def agents(port: int) -> list[MavlinkController]:
    return [MavlinkController(links.connect(f"udpin:127.0.0.1:{p}", 1, 191), "copter", Datum(), radius=RADIUS)
            for p in (port, port + 10)]


def heard(fc: MavlinkController):
    """What the controller knows of its team-mates now, and its autopilot's clock (for ``wait_sim``)."""
    fc.pump()
    return fc.traffic(), fc.time


def test_two_autopilots_in_one_world_each_agent_hears_the_other_as_adsb_and_sees_its_body(scene_file):
    port = free_pair()
    controllers = agents(port)
    # vehicle 2 stands 3 m north of vehicle 1, both facing north: 1's forward sonar looks at 2's body
    team = start_team(scene_file, port, "--start=0,0", "--start=0,3", "--heading", "0")
    try:
        for fc in controllers:
            fc.connect(60)
        one, two = controllers
        assert (one.system_id, two.system_id) == (1, 2)
        others = wait_sim(lambda: heard(one), lambda t: len(t) == 1, 10, SPEEDUP, "vehicle 1 hears vehicle 2")
        assert others[0].vehicle == 2
        assert abs(others[0].x) < 0.05 and abs(others[0].y - 3.0) < 0.05 and others[0].radius == RADIUS
        mates = wait_sim(lambda: heard(two), lambda t: len(t) == 1, 10, SPEEDUP, "vehicle 2 hears vehicle 1")
        assert mates[0].vehicle == 1 and abs(mates[0].x) < 0.05 and abs(mates[0].y) < 0.05

        def forward_echo():
            echoes = [m.current_distance / 100.0 for m in one.pump()
                      if m.get_type() == "DISTANCE_SENSOR" and m.orientation == mavlink.MAV_SENSOR_ROTATION_NONE]
            return (echoes[-1] if echoes else None), one.time

        # the wall behind vehicle 2 is 8 m away: an echo at 3 m less its radius is vehicle 2's body
        echo = wait_sim(forward_echo, lambda d: d is not None, 10, SPEEDUP, "vehicle 1's forward sonar")
        assert abs(echo - (3.0 - RADIUS)) < 0.15, echo

        # vehicle 2 climbs: vehicle 1 hears it rise, moving, not only where it stood
        assert two.set_mode("GUIDED") == 0 and two.arm() == 0 and two.takeoff(3.0) == 0
        risen = wait_sim(lambda: heard(one), lambda t: t and t[0].z > 2.0, 30, SPEEDUP, "vehicle 2 seen climbing")
        assert risen[0].vehicle == 2
        assert heard(two)[0][0].z < 0.5, "vehicle 1 stayed on the ground"
    finally:
        team.terminate()
        output = team.communicate(timeout=10)[0]
        for fc in controllers:
            fc.conn.close()
    # told before its silent seconds (some 15 once after an install), where a new user took them for a hang
    assert output.startswith("vehicle team: loading the simulation's compiled loops"), output
    assert f"vehicle 1: copter at 0.0, 0.0 on udpout:127.0.0.1:{port}" in output, output
    assert f"vehicle 2: copter at 0.0, 3.0 on udpout:127.0.0.1:{port + 10}" in output, output


@pytest.mark.parametrize("arguments, says", [
    (["--vehicles", "0"], "0"),
    (["--vehicles", "9"], "9"),
    (["--vehicles", "2", "--sysids", "3,3"], "two vehicles have the system id 3"),
    (["--vehicles", "2", "--start=0,0", "--start=0.2,0"], "start inside each other"),
    (["--vehicles", "2", "--mavlink", "udpin:127.0.0.1:14999", "--port-step", "0"], "listen on one port"),
    (["--vehicles", "2", "--mavlink", "/dev/ttyUSB0,57600"], "names no port"),
    (["--sysids", "1,2"], "give --vehicles N"),
])
def test_a_bad_team_is_a_usage_error_before_anything_starts(scene_file, arguments, says):
    run = subprocess.run([sys.executable, "-m", "vehicle.cli", "sim", "--role", "autopilot", "--scene",
                          str(scene_file), *arguments], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stdout + run.stderr
    assert says in run.stderr and "Traceback" not in run.stderr, run.stderr


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc to find the vehicle processes")
def test_the_demo_flies_a_mixed_team_in_one_world_with_an_agent_each(tmp_path):
    port, mavlink_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    process = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "demo", "--port", str(port),
                                "--mavlink-port", str(mavlink_port), "--record-dir", "", "--speedup", "4",
                                "--vehicles", "2", "--vehicle", "mixed", "--quiet"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        def listed() -> list[dict]:
            assert process.poll() is None, f"the demo exited: {process.stdout.read()}"
            try:
                return vehicles(port)
            except OSError:  # not serving yet
                return []

        seen = wait_wall(listed, WAIT, "two vehicles placed, each with its onboard agent", period=0.5,
                         done=lambda seen: len(seen) == 2 and all(v["agent"] and v["position"] for v in seen))
        assert sorted((v["sysid"], v["type"]) for v in seen) == [(1, "copter"), (2, "rover")], seen
        assert all(v["agent"]["companion"] for v in seen), "each vehicle has its onboard agent"
        worlds = processes_mentioning(f"--team-link udpout:127.0.0.1:{mavlink_port}")
        assert len(worlds) == 1, "one world process serves both flight controllers"
        assert len(processes_mentioning(" agent --connect udpin:127.0.0.1:")) >= 2
    finally:
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=30)
        for pid in processes_mentioning(f"udpout:127.0.0.1:{mavlink_port}"):
            os.kill(pid, signal.SIGKILL)


def test_a_near_miss_is_one_event_on_each_vehicles_timeline_naming_both_and_counted():
    """Two vehicles' own MAVLink bytes to a real station: they close in to 1.5 m (inside 2 m + both radii), stay
    there for many poses, part, and close in again."""
    from harness import RunningStation
    from mavlink_peer import Peer, fly_pair

    with RunningStation(None, None) as station, Peer(("127.0.0.1", station.mavlink_port), 1) as one, \
            Peer(("127.0.0.1", station.mavlink_port), 2) as two:
        api = station.api()

        def fly(north_of_one: list[float]) -> None:
            fly_pair(one, two, north_of_one)

        def near_misses(sysid: int) -> list[str]:
            events = api.get(f"/api/vehicles/{sysid}/history").json()["events"]
            return [e["text"] for e in events if e["kind"] == "near miss"]

        def settled(sysid: int, north: float) -> bool:  # the station took in the last pose sent
            found = api.vehicle(sysid)
            return found is not None and found["position"] is not None and \
                abs(found["position"]["y"] - (north if sysid == 2 else 0.0)) < 0.05

        fly([10.0] * 5)
        wait_wall(lambda: settled(1, 0) and settled(2, 10.0), 10, "both vehicles placed")
        assert near_misses(1) == []
        fly([6.0, 4.0, 2.0, 1.5, 1.5, 1.5, 1.6, 1.4])
        wait_wall(lambda: settled(2, 1.4), 10, "vehicle 2 close")
        for sysid in (1, 2):
            texts = near_misses(sysid)
            assert len(texts) == 1 and "vehicles 1 and 2" in texts[0], texts
            assert api.vehicle(sysid)["near_misses"] == 1
        fly([3.0, 10.0, 1.5, 1.3])  # 3 m is still close (within the margin and a metre more): no new event
        wait_wall(lambda: settled(2, 1.3), 10, "vehicle 2 close again")
        assert len(near_misses(1)) == 2 and api.vehicle(2)["near_misses"] == 2


def test_the_station_relays_each_vehicle_to_the_others_unless_their_team_reports_it():
    """Two vehicles that do not share a world (two ArduPilots) hear of each other only through the station: it
    sends ADSB_VEHICLE for each (its place, altitude above sea level and velocity) to every link, and stops
    relaying one that a vehicle reports itself (our world's autopilots do). An agent takes the relay on its
    direct link to the station, as a team-mate."""
    from harness import RunningStation
    from mavlink_peer import Peer, vehicle_heartbeat

    metre = 1 / 111_320
    with RunningStation(None, None) as station, Peer(("127.0.0.1", station.mavlink_port), 1) as one, \
            Peer(("127.0.0.1", station.mavlink_port), 2) as two:
        def placed(step: int) -> None:
            one.send(vehicle_heartbeat(), mavlink.MAVLink_global_position_int_message(
                1000 + step, -353632610, 1491652300, 590_000, 4000, 0, 0, 0, 65535))
            two.send(vehicle_heartbeat(), mavlink.MAVLink_global_position_int_message(
                1000 + step, int((-35.363261 + 8 * metre) * 1e7), 1491652300, 588_000, 2000, -150, 0, 0, 9000))

        def relayed(peer: Peer, icao: int):
            for step in range(40):
                placed(step)
                for m in peer.receive(0.05):
                    if m.get_type() == "ADSB_VEHICLE" and m.ICAO_address == icao:
                        return m
            return None

        report = relayed(one, 2)
        assert report is not None, "vehicle 1 hears of vehicle 2"
        assert report.get_srcSystem() == 255
        assert abs(report.lat - int((-35.363261 + 8 * metre) * 1e7)) <= 1 and report.altitude == 588_000
        assert report.hor_velocity == 150 and report.heading == 18000  # 1.5 m/s south
        assert relayed(two, 1) is not None, "vehicle 2 hears of vehicle 1"

        # vehicle 1's autopilot reports vehicle 2 itself: the station relays 2 no more, 1 still
        own = mavlink.MAVLink_adsb_vehicle_message(2, report.lat, report.lon, 0, 588_000, 18000, 150, 0, b"VEH2",
                                                   14, 0, report.flags, 0)
        for _ in range(5):
            one.send(own)
        time.sleep(0.3)
        for peer in (one, two):
            peer.receive(0.2)  # what was on the way
        heard = []
        for step in range(20):
            placed(step)
            heard += [m.ICAO_address for m in two.receive(0.05) if m.get_type() == "ADSB_VEHICLE"]
        assert 1 in heard and 2 not in heard, heard

    # an agent takes a relay from its direct link to a station (--gcs), never a station's through the autopilot's
    autopilot, gcs = free_udp_port(), free_udp_port()
    pilot = MavlinkController(links.connect(f"udpin:127.0.0.1:{autopilot}", 1, 191), "copter", Datum(),
                              extra_links=(links.connect(f"udpin:127.0.0.1:{gcs}", 1, 191),))
    try:
        with Peer(("127.0.0.1", autopilot), 1) as fc, Peer(("127.0.0.1", gcs), 255, 190) as station_side:
            fc.send(vehicle_heartbeat())
            relay = mavlink.MAVLink_adsb_vehicle_message(2, -353632610, 1491652300, 0, 588_000, 0, 0, 0, b"VEH2", 14,
                                                         0, report.flags, 0)
            fc.as_system(255, 190).send(relay)  # a station's, through the autopilot's link: not taken
            def taken() -> list:
                pilot.pump()
                return pilot.traffic()

            for _ in during(0.5):
                assert taken() == []
            station_side.send(relay)
            found = wait_wall(taken, 5, "the relay taken as a team-mate")
            assert [t.vehicle for t in found] == [2]
    finally:
        pilot.conn.close()
        for link in pilot.extra_links:
            link.close()
