"""Vehicles that hold the operator's exchanges: one that never answers, one that never stops asking for
mission items, and a second transfer to a vehicle already in one. Each is a fake vehicle on a real UDP
socket speaking real MAVLink to a real station; the station's retry clock is the test's (``StationClock``),
so a wait lasts exactly as long as the test says.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from harness import RunningStation, StationClock, small_scene, wait_wall
from mavlink_peer import FakeVehicle

from groundstation.api.common import EXCHANGES
from groundstation.link import REPLY_LOOK
from vehicle.protocol.mav import mavlink
from vehicle.protocol.mission import REQUESTS_PER_ITEM

SET_MODE = mavlink.MAV_CMD_DO_SET_MODE
MISSION = "QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.3632610\t149.1652300\t0.000000\t1\n" \
          "1\t0\t3\t16\t0\t0\t0\t0\t-35.3632000\t149.1653000\t5.000000\t1\n"


@pytest.fixture
def clock():
    return StationClock()


@pytest.fixture
def station(clock):
    with RunningStation(small_scene(), None) as running:
        running.station.link.retry_clock = clock
        try:
            yield running
        finally:  # a test that failed leaves tries waiting on its clock: the wall clock ends them
            running.station.link.retry_clock = time.monotonic


def heard(station: RunningStation, sysid: int, answer) -> FakeVehicle:
    """A fake vehicle ``sysid`` answering as ``answer(vehicle, message)`` says, once the station knows it."""
    vehicle = FakeVehicle(("127.0.0.1", station.mavlink_port), sysid, answer)
    wait_wall(lambda: station.http.get(f"/api/vehicles/{sysid}").status_code == 200, 10, f"vehicle {sysid}")
    return vehicle


def test_commands_waiting_on_a_silent_vehicle_never_hold_up_what_the_page_draws(station, clock):
    """More commands than asyncio has default threads, each waiting on a vehicle that never answers: the scene's
    picture (drawn on those threads) is still served at once, and every command ends in a 504 as its tries run
    out on the station's clock."""
    default_threads = min(32, (os.cpu_count() or 1) + 4)  # asyncio.to_thread's pool
    waiting = default_threads + 1
    silent = heard(station, 42, lambda vehicle, message: None)
    try:
        with ThreadPoolExecutor(waiting) as pool, station.api(timeout=60) as api:
            commands = [pool.submit(api.command, 42, action="rtl") for _ in range(waiting)]
            in_flight = min(waiting, EXCHANGES)
            wait_wall(lambda: len(silent.of_type("COMMAND_LONG", SET_MODE)) >= in_flight, 20,
                      f"{in_flight} commands sent")
            picture = station.http.get("/api/map2d/scene", timeout=10)
            assert picture.status_code == 200 and picture.json()["image"].startswith("data:image/png;base64,")
            while not all(command.done() for command in commands):
                clock.advance(1.0)
                time.sleep(REPLY_LOOK)  # the waits look at the clock this often
            answers = [command.result() for command in commands]
        assert {answer.status_code for answer in answers} == {504}
        assert all("did not answer COMMAND_LONG after 3 tries" in a.json()["detail"] for a in answers)
    finally:
        silent.close()


def keeps_asking(vehicle: FakeVehicle, message) -> None:
    """Asks for item 0 on the count, then for the other item of two after each, for ever."""
    kind = message.get_type()
    if kind == "MISSION_COUNT":
        vehicle.send(mavlink.MAVLink_mission_request_int_message(255, 190, 0, 0))
    elif kind == "MISSION_ITEM_INT":
        vehicle.send(mavlink.MAVLink_mission_request_int_message(255, 190, 1 - message.seq, 0))


def test_a_vehicle_that_keeps_asking_for_items_ends_the_upload_with_the_reason(station):
    vehicle = heard(station, 43, keeps_asking)
    try:
        answer = station.http.put("/api/vehicles/43/mission", content=MISSION, headers=station.http.operator)
        assert answer.status_code == 504
        assert answer.json()["detail"] == (f"vehicle 43 asked for {2 * REQUESTS_PER_ITEM} items of a 2-item mission "
                                           "and did not accept it")
        assert len(vehicle.of_type("MISSION_ITEM_INT")) == 2 * REQUESTS_PER_ITEM
    finally:
        vehicle.close()


def test_a_second_mission_transfer_to_a_vehicle_in_one_is_refused_and_the_first_completes(station):
    release = threading.Event()

    def accepts_when_released(vehicle: FakeVehicle, message) -> None:
        if message.get_type() == "MISSION_COUNT":
            threading.Thread(target=lambda: release.wait(20) and vehicle.send(
                mavlink.MAVLink_mission_ack_message(255, 190, mavlink.MAV_MISSION_ACCEPTED, 0)), daemon=True).start()

    vehicle = heard(station, 44, accepts_when_released)
    try:
        with ThreadPoolExecutor(1) as pool, station.api() as api:
            first = pool.submit(api.put, "/api/vehicles/44/mission", content=MISSION, headers=api.operator)
            wait_wall(lambda: vehicle.of_type("MISSION_COUNT"), 10, "the first upload under way")
            for second in (station.http.put("/api/vehicles/44/mission", content=MISSION,
                                            headers=station.http.operator),
                           station.http.get("/api/vehicles/44/mission")):
                assert second.status_code == 409
                assert second.json()["detail"] == ("a mission transfer with vehicle 44 is under way; try again when "
                                                   "it ends")
            release.set()
            assert first.result(timeout=20).json() == {"result": "accepted", "items": 2}
        assert len(vehicle.of_type("MISSION_COUNT")) == 1  # the refused ones never reached it
    finally:
        vehicle.close()
