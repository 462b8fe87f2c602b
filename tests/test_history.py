"""A vehicle's history: bounded samples (oldest dropped), thinned answers, no NaN out, bounded events; and the
fleet's events for mode changes, arming and the station's own commands and the vehicle's ACKs."""

from __future__ import annotations

import json
import math

import pytest

from groundstation.history import EVENTS_KEPT, History
from groundstation.state import Fleet
from vehicle.protocol.mav import COMPANION, mavlink


def test_samples_are_bounded_thinned_and_never_nan():
    history = History(every=1.0, capacity=5)
    for t in range(8):
        assert history.due(1, float(t))
        history.sample(1, float(t), {"altitude": float(t), "speed": math.nan if t == 6 else 1.0, "sonar 0": None})
        assert not history.due(1, t + 0.5)
    answer = history.of(1).as_json()
    assert answer["t"] == [3.0, 4.0, 5.0, 6.0, 7.0]  # the last five, oldest first
    assert answer["series"]["altitude"] == [3.0, 4.0, 5.0, 6.0, 7.0]
    assert answer["series"]["speed"] == [1.0, 1.0, 1.0, None, 1.0]
    assert "sonar 0" not in answer["series"]  # never had a value
    assert answer["units"] == {"altitude": "m", "speed": "m/s"}
    json.dumps(answer, allow_nan=False)
    assert history.of(1).as_json(since=5.0)["t"] == [6.0, 7.0]
    assert history.of(1).as_json(limit=2)["t"] == [3.0, 7.0]  # evenly thinned, the ends kept
    assert history.due(1, 2.0)  # a replay that seeks back samples again


def test_events_are_bounded_and_cut():
    history = History()
    for i in range(EVENTS_KEPT + 10):
        history.event(1, float(i), "message", "x" * 1000, 6, routine=True)
    events = history.of(1).as_json()["events"]
    assert len(events) == EVENTS_KEPT and events[0]["t"] == 10.0 and len(events[0]["text"]) == 300
    for i in range(3):  # a warning is kept however routine its kind
        history.event(1, 2000.0 + i, "message", "warning", 4, routine=True)
    assert len(history.of(1).as_json()["events"]) == EVENTS_KEPT + 3


def message(cls, *args, src=1, comp=1):
    m = cls(*args)
    m.pack(mavlink.MAVLink(None, srcSystem=src, srcComponent=comp))
    return m


def heartbeat(mode: int, armed: bool):
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return message(mavlink.MAVLink_heartbeat_message, mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                   base, mode, 4, 3)


def test_the_fleet_marks_modes_arming_commands_and_acks():
    fleet = Fleet()
    fleet.apply(heartbeat(4, False), 100.0)  # GUIDED
    fleet.apply(heartbeat(4, True), 101.0)
    command = message(mavlink.MAVLink_command_long_message, 1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                      mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0, 0, 0, 0, 0, src=255, comp=190)
    fleet.apply(command, 102.0)  # this station's order: RTL
    fleet.apply(message(mavlink.MAVLink_command_ack_message, mavlink.MAV_CMD_DO_SET_MODE, 0, 0, 0, 255, 190), 102.1)
    fleet.apply(heartbeat(6, True), 103.0)
    quiet = message(mavlink.MAVLink_command_long_message, 1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                    33, 1e5, 0, 0, 0, 0, 0, src=255, comp=190)
    fleet.apply(quiet, 104.0)  # telemetry requests are not worth a marker
    events = [(e["t"], e["kind"], e["text"]) for e in fleet.history.of(1).as_json()["events"]]
    assert events == [(100.0, "mode", "first heard: GUIDED"), (101.0, "armed", "armed"),
                      (102.0, "command", "sent DO_SET_MODE RTL"), (102.1, "ack", "DO_SET_MODE: accepted"),
                      (103.0, "mode", "mode GUIDED → RTL")]
    assert fleet.vehicles[1].other_gcs is None  # our own order, not another station's


def test_routine_acks_are_counted_and_what_matters_outlives_a_flood():
    """An agent's search acknowledged 961 of the last 1,000 events as "DO_REPOSITION: accepted" and pushed the
    operator's commands out: now they are counted, and commands, modes and warnings stay for the flight."""
    fleet = Fleet()
    fleet.apply(heartbeat(4, True), 100.0)
    command = message(mavlink.MAVLink_command_long_message, 1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                      mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0, 0, 0, 0, 0, src=255, comp=190)
    fleet.apply(command, 101.0)
    for i in range(3000):  # the autopilot answers the agent (system 1, component 191)
        fleet.apply(message(mavlink.MAVLink_command_ack_message, mavlink.MAV_CMD_DO_REPOSITION, 0, 0, 0, 1,
                            COMPANION), 102.0 + i * 0.01)
    for i in range(EVENTS_KEPT + 5):  # chatter, then one warning among it
        fleet.apply(message(mavlink.MAVLink_statustext_message, 6, f"info {i}".encode()), 140.0 + i * 0.01)
    fleet.apply(message(mavlink.MAVLink_statustext_message, 4, b"Battery low", comp=COMPANION), 200.0)
    answer = fleet.history.of(1).as_json()
    texts = [(e["source"], e["text"]) for e in answer["events"]]
    assert ("operator", "sent DO_SET_MODE RTL") in texts and ("autopilot", "first heard: GUIDED, armed") in texts
    assert ("agent", "Battery low") in texts
    assert not any("DO_REPOSITION" in text for _, text in texts)
    assert answer["counted"] == [{"source": "agent", "text": "DO_REPOSITION: accepted", "count": 3000,
                                  "last": 131.99}]
    assert len([t for s, t in texts if t.startswith("info")]) == EVENTS_KEPT  # routine ones stay bounded
    assert [e["t"] for e in answer["events"]] == sorted(e["t"] for e in answer["events"])


def test_a_fall_after_a_kill_in_the_air_is_a_crash():
    fleet = Fleet()
    fleet.apply(heartbeat(4, True), 100.0)

    def position(alt: float, vz: float, t: float):
        fleet.apply(message(mavlink.MAVLink_global_position_int_message, 0, -353632620, 1491652370, 0,
                            int(alt * 1000), 0, 0, int(vz * 100), 0), t)

    position(4.0, 0.0, 100.5)
    fleet.apply(heartbeat(4, True), 101.0)
    position(3.5, 3.0, 101.2)  # killed at 4 m: the heartbeat that says so comes a second later
    position(2.0, 6.0, 101.4)
    fleet.apply(heartbeat(4, False), 101.5)
    position(0.4, 9.0, 101.6)
    assert fleet.vehicles[1].falling is not None
    position(0.35, 0.0, 101.8)  # at rest, on something a little higher than home
    crashes = [(e["text"], e["severity"]) for e in fleet.history.of(1).as_json()["events"] if e["kind"] == "crash"]
    assert crashes == [("disarmed in the air at 4.0 m above home: falling", 2),
                       ("crashed: fell 3.6 m, hitting the ground at 9.0 m/s", 2)]
    assert fleet.describe(fleet.vehicles[1], 102.0)["crash"]["text"].startswith("crashed: fell 3.6 m")
    fleet.apply(heartbeat(4, True), 110.0)  # armed on the ground and disarmed there: no crash
    fleet.apply(heartbeat(4, False), 111.0)
    assert len([e for e in fleet.history.of(1).as_json()["events"] if e["kind"] == "crash"]) == 2


def test_the_battery_s_flight_time_left_comes_from_its_drain():
    fleet = Fleet()
    for t in range(0, 200, 1):  # 1 % every 10 s: from 80 % at t = 80 s on, 8 % more an 80 s
        fleet.apply(heartbeat(4, True), float(t))
        fleet.apply(message(mavlink.MAVLink_sys_status_message, 0, 0, 0, 500, 16000, 1000, 100 - t // 10,
                            0, 0, 0, 0, 0, 0), float(t) + 0.5)
    battery = fleet.describe(fleet.vehicles[1], 200.0)["battery"]
    assert battery["remaining"] == 81 and battery["flight_left_s"] == pytest.approx(810, rel=0.05)
    idle = Fleet()  # no drain seen yet: no guess
    idle.apply(heartbeat(4, True), 0.0)
    idle.apply(message(mavlink.MAVLink_sys_status_message, 0, 0, 0, 500, 16000, 1000, 90, 0, 0, 0, 0, 0, 0), 1.0)
    assert idle.describe(idle.vehicles[1], 2.0)["battery"]["flight_left_s"] is None
