"""The battery's failsafe levels: the station reads each autopilot's BATT_* parameters (groundstation.params) and
our simulated autopilot answers them with the levels it acts on.

A fake ArduPilot on real UDP (pymavlink) answers the station's PARAM_REQUEST_READs as a test scripts it; the
station's rounds of requests are paced on its retry clock, which the test moves (StationClock), so a round comes
only when the test says, however slow the machine. The simulator is asked as any ground station asks it.
"""

from __future__ import annotations

import math
import time

import pytest
from harness import RunningSim, StationClock, free_udp_port, wait_wall
from mavlink_peer import FakeVehicle, Gcs

from groundstation import params
from groundstation.link import Link
from groundstation.state import LINK_LOST_AFTER, Fleet
from vehicle.lab.stepper import simulate
from vehicle.protocol.mav import mavlink
from vehicle.sim.battery import Battery
from vehicle.world.scene import parse_scene

ARDUCOPTER = {"BATT_CAPACITY": 5200.0, "BATT_LOW_VOLT": 10.5, "BATT_CRT_VOLT": 10.0, "BATT_LOW_MAH": 1040.0,
              "BATT_CRT_MAH": 520.0, "BATT_FS_LOW_ACT": 2.0, "BATT_FS_CRT_ACT": 1.0}
SCENE = "#VRML V2.0 utf8\nTransform { translation 0 0 -0.5 children Shape { geometry Box { size 80 80 1 } } }\n"


def requests(vehicle: FakeVehicle, name: str | None = None) -> list:
    return [m for m in vehicle.of_type("PARAM_REQUEST_READ") if name is None or m.param_id == name]


def param_value(name: str, value: float):
    return mavlink.MAVLink_param_value_message(name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32, 900, 0)


def battery_status():
    return mavlink.MAVLink_sys_status_message(0, 0, 0, 500, 15800, 1200, 80, 0, 0, 0, 0, 0, 0)


class ArduCopter(FakeVehicle):
    """Answers each PARAM_REQUEST_READ with its value in ``answers`` (none for a name left out) from the
    ``answer_from``-th request of that name on; before the good value of BATT_LOW_MAH it sends a NaN, after the
    good BATT_CAPACITY an absurd one (a broken or hostile autopilot)."""

    def __init__(self, port: int, answers: dict[str, float], answer_from: dict[str, int] | None = None):
        self.answers, self.answer_from = answers, answer_from or {}
        super().__init__(("127.0.0.1", port), 1, answer=ArduCopter._answer, beat=0.2)

    def _answer(self, message) -> None:
        if message.get_type() == "PARAM_REQUEST_READ":
            self.send(battery_status())
            name = message.param_id
            if name not in self.answers or len(requests(self, name)) < self.answer_from.get(name, 1):
                return
            if name == "BATT_LOW_MAH":
                self.send(param_value(name, math.nan))
            self.send(param_value(name, self.answers[name]))
            if name == "BATT_CAPACITY":
                self.send(param_value(name, 1e12))


def start_link(clock: StationClock) -> tuple[Link, int]:
    port = free_udp_port()
    return Link([f"udpin:127.0.0.1:{port}"], Fleet(), retry_clock=clock).start(), port


def failsafe_of(link: Link) -> dict | None:
    vehicle = link.fleet.get(1)
    battery = link.fleet.describe(vehicle, time.time())["battery"] if vehicle is not None else None
    return battery and battery["failsafe"]


def test_the_station_reads_an_autopilots_failsafe_levels_asking_again_for_what_did_not_come():
    clock = StationClock()
    link, port = start_link(clock)
    answers = {name: value for name, value in ARDUCOPTER.items() if name != "BATT_CRT_MAH"}  # never answered
    try:
        with ArduCopter(port, answers, answer_from={"BATT_CRT_VOLT": 2}) as vehicle:
            wait_wall(lambda: len(requests(vehicle)) == len(params.WANTED), 5, "the first round of requests")
            assert {m.param_id for m in requests(vehicle)} == set(params.WANTED)
            assert all(m.target_component == 1 and m.param_index == -1 for m in requests(vehicle))
            wait_wall(lambda: (failsafe_of(link) or {}).get("capacity_mah") == 5200.0, 5, "the capacity kept")
            wait_wall(lambda: failsafe_of(link)["low"]["mah"] == 1040.0, 5, "the low level")
            assert failsafe_of(link)["critical"]["volt"] is None  # not answered the first time

            clock.advance(params.RETRY_AFTER)  # the second round: only what is missing
            wait_wall(lambda: failsafe_of(link)["critical"]["volt"] == 10.0, 5, "the critical voltage, asked again")
            assert len(requests(vehicle)) == len(params.WANTED) + 2
            assert {m.param_id for m in requests(vehicle)[len(params.WANTED):]} == {"BATT_CRT_VOLT", "BATT_CRT_MAH"}

            clock.advance(params.RETRY_AFTER)
            wait_wall(lambda: len(requests(vehicle, "BATT_CRT_MAH")) == params.TRIES, 5, "the last round")
            clock.advance(10 * params.RETRY_AFTER)
            wait_wall(lambda: 1 not in link.params, 5, "the station done asking")
            assert len(requests(vehicle, "BATT_CRT_MAH")) == params.TRIES

            failsafe = failsafe_of(link)
            assert failsafe["low"] == {"volt": 10.5, "mah": 1040.0, "percent": 20.0, "action": "RTL"}
            assert failsafe["critical"] == {"volt": 10.0, "mah": None, "percent": None, "action": "Land"}
            assert link.fleet.get(1).params_ignored == 2  # the NaN and the 1e12 mAh, counted, not kept
    finally:
        link.close()


def test_a_vehicle_that_never_answers_costs_a_bounded_number_of_requests_and_is_asked_again_when_back():
    clock = StationClock()
    link, port = start_link(clock)
    bound = params.TRIES * len(params.WANTED)
    try:
        with ArduCopter(port, {}) as vehicle:
            for rounds in range(1, params.TRIES + 1):
                wait_wall(lambda rounds=rounds: len(requests(vehicle)) == rounds * len(params.WANTED), 5,
                          f"round {rounds} of requests")
                clock.advance(params.RETRY_AFTER)
            clock.advance(100 * params.RETRY_AFTER)
            wait_wall(lambda: 1 not in link.params, 5, "the station done asking")
            time.sleep(0.2)  # the link's loop goes round many times: it sends no more
            assert len(requests(vehicle)) == bound
            assert failsafe_of(link) is None
        time.sleep(LINK_LOST_AFTER + 0.5)  # its link is lost ...
        with ArduCopter(port, ARDUCOPTER) as back:  # ... and comes back (a reboot, say): it is asked again
            wait_wall(lambda: failsafe_of(link) is not None and failsafe_of(link)["critical"]["mah"] == 520.0, 5,
                      "the levels of the vehicle back")
            assert len(requests(back)) == len(params.WANTED)
    finally:
        link.close()


def test_only_the_autopilots_wanted_finite_values_are_kept():
    fleet = Fleet()
    parser = mavlink.MAVLink(None)

    def deliver(message, component=1):
        packer = mavlink.MAVLink(None, srcSystem=7, srcComponent=component)
        fleet.apply(parser.decode(bytearray(message.pack(packer))), 1.0)

    deliver(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                              0, 0, 0, 3))
    deliver(param_value("BATT_FS_CRT_ACT", 2.0))
    deliver(param_value("BATT_FS_LOW_ACT", 1.0), component=191)  # the companion's word is not the autopilot's
    deliver(param_value("SCN_SPEED", 3.0))
    for absurd in (math.inf, -1.0, 500.0):
        deliver(param_value("BATT_FS_LOW_ACT", absurd))
    rover = fleet.get(7)
    assert rover.params == {"BATT_FS_CRT_ACT": 2.0}
    assert rover.params_ignored == 3
    assert params.failsafe(rover.params, rover.kind)["critical"]["action"] == "Hold"


@pytest.mark.parametrize("kind, critical_action", [("copter", 1.0), ("rover", 2.0)])
def test_our_simulator_answers_with_the_levels_it_acts_on(kind, critical_action):
    port = free_udp_port()
    gcs = Gcs(f"udpin:127.0.0.1:{port}", speedup=10.0)
    stepper = simulate(parse_scene(SCENE), "browse", kind, autostart=False,
                       battery=Battery(capacity_mah=4000.0, charge_mah=4000.0))
    with RunningSim(stepper, [f"udpout:127.0.0.1:{port}"], speedup=10.0):
        gcs.wait("HEARTBEAT")
        got = {}
        for name in params.WANTED:
            gcs.mav.param_request_read_send(1, 1, name.encode(), -1)
            got[name] = gcs.wait("PARAM_VALUE", lambda m, name=name: m.param_id == name).param_value
        gcs.mav.param_request_read_send(1, 1, b"SCN_SPEED", -1)  # the agent's own still come from the agent
        assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "SCN_SPEED").param_value > 0
    gcs.close()
    assert got == {"BATT_CAPACITY": 4000.0, "BATT_LOW_VOLT": 0.0, "BATT_CRT_VOLT": 0.0, "BATT_LOW_MAH": 800.0,
                   "BATT_CRT_MAH": 400.0, "BATT_FS_LOW_ACT": 0.0, "BATT_FS_CRT_ACT": critical_action}
    levels = params.failsafe(got, kind)
    assert (levels["low"]["percent"], levels["critical"]["percent"]) == (20.0, 10.0)
    assert levels["critical"]["action"] == ("Land" if kind == "copter" else "Hold")
