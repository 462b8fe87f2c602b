"""The ground station's picture of a vehicle (groundstation.state.Fleet), message by message.

Messages are real pymavlink messages, packed and decoded as on a link; the
receiver's clock is given explicitly, so these tests need neither sockets nor sleeps.
"""

from __future__ import annotations

import math

import pytest
from mavlink_peer import Delivered

from groundstation.state import OWN_MAP_AFTER, Fleet
from vehicle.mapping.memory_map import HIT
from vehicle.protocol import agent_status
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.statustext import statustexts

SYSID = 3
DATUM = Datum()


autopilot, companion = Delivered(SYSID, 1), Delivered(SYSID, 191)


def heartbeat(kind=mavlink.MAV_TYPE_QUADROTOR, autopilot_type=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mode=4):
    return mavlink.MAVLink_heartbeat_message(kind, autopilot_type, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode,
                                             mavlink.MAV_STATE_ACTIVE, 3)


def position(x=0.0, y=0.0, alt=4.0):
    lat, lon = DATUM.to_global(x, y)
    return mavlink.MAVLink_global_position_int_message(1000, int(lat * 1e7), int(lon * 1e7), 0, int(alt * 1000),
                                                       0, 0, 0, 0)


def echo(distance_cm=500):
    return mavlink.MAVLink_distance_sensor_message(1000, 2, 4000, distance_cm, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND,
                                                   0, 0, 0, 0.26, 0.26, [0.0] * 4, 0)


@pytest.fixture
def fleet():
    return Fleet(DATUM)


def hear(fleet, now, *messages):
    for message in messages:
        fleet.apply(message, now)


def test_the_companions_heartbeat_neither_makes_a_vehicle_nor_changes_its_mode(fleet):
    hear(fleet, 0.0, companion(heartbeat(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0)))
    assert fleet.ids() == []  # a companion alone is no vehicle
    hear(fleet, 1.0, autopilot(heartbeat(mode=4)),
         companion(heartbeat(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0)))
    vehicle = fleet.get(SYSID)
    assert vehicle.mode == "GUIDED" and vehicle.kind == "copter"
    assert vehicle.has_companion(1.5) and not vehicle.has_companion(10.0)  # heard within the link timeout


def test_a_heartbeat_of_another_part_of_the_system_does_not_change_the_vehicles_mode(fleet):
    """A component that sends a vehicle's type with no autopilot (a companion program of another make, a
    gimbal driver) made no vehicle, yet its heartbeat set the vehicle's mode (to custom mode 0) and armed state."""
    other = Delivered(SYSID, 42)
    hear(fleet, 0.0, autopilot(heartbeat(mode=4)))
    hear(fleet, 1.0, other(heartbeat(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_INVALID, 0)))
    vehicle = fleet.get(SYSID)
    assert vehicle.mode == "GUIDED" and vehicle.custom_mode == 4
    hear(fleet, 2.0, autopilot(heartbeat(mode=6)))
    assert vehicle.mode == "RTL"  # the autopilot's own still does


def test_only_the_autopilot_makes_the_vehicle_and_sets_its_mode_position_and_battery(fleet):
    """Any other component (or a sender in its name: the link hears the autopilot only where its heartbeat
    comes from, so a spoofer takes a component id of its own) set the vehicle's mode with a heartbeat of an
    autopilot, and moved it with its positions; heard first, it made the vehicle, and the station then took
    the vehicle's own autopilot for another part of it. Its messages still show, its sensors' readings count."""
    other = Delivered(SYSID, 250)
    hear(fleet, 0.0, other(heartbeat(mode=9)), other(position(500.0, 500.0, 60.0)))
    assert fleet.ids() == []
    hear(fleet, 0.0, autopilot(heartbeat(mode=4)), autopilot(position(1.0, 2.0)),
         autopilot(mavlink.MAVLink_sys_status_message(0, 0, 0, 500, 16000, 1400, 90, 0, 0, 0, 0, 0, 0)))
    hear(fleet, 1.0, other(heartbeat(mode=9)), other(position(500.0, 500.0, 60.0)),
         other(mavlink.MAVLink_attitude_message(1000, 0.5, 0.5, 3.0, 0, 0, 0)),
         other(mavlink.MAVLink_sys_status_message(0, 0, 0, 500, 9000, 9000, 1, 0, 0, 0, 0, 0, 0)),
         other(mavlink.MAVLink_home_position_message(0, 0, 0, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)),
         other(mavlink.MAVLink_mission_current_message(7)),
         other(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING, b"gimbal hot", 0, 0)),
         other(echo(300)))
    vehicle = fleet.get(SYSID)
    assert vehicle.mode == "GUIDED" and vehicle.last_heartbeat == 0.0
    assert (vehicle.x, vehicle.y, vehicle.alt) == pytest.approx((1.0, 2.0, 4.0), abs=0.01)
    assert (vehicle.roll, vehicle.voltage, vehicle.remaining, vehicle.mission_current) == (0.0, 16.0, 90, None)
    assert vehicle.home == pytest.approx((1.0, 2.0), abs=0.01)  # its first fix, not the other's home
    assert vehicle.status == "gimbal hot" and vehicle.sonar[0].distance == 3.0
    assert vehicle.messages_received == 11  # all heard, as the vehicle's
    hear(fleet, 2.0, autopilot(heartbeat(mode=6)), autopilot(position(3.0, 4.0)))
    assert vehicle.mode == "RTL" and (vehicle.x, vehicle.y) == pytest.approx((3.0, 4.0), abs=0.01)


def test_system_0_is_no_vehicle(fleet):
    """0 is MAVLink's broadcast address: a "vehicle" there would have every command to it go to all of them."""
    broadcast = mavlink.MAVLink(None, srcSystem=0, srcComponent=1)
    hear(fleet, 0.0, mavlink.MAVLink(None).decode(bytearray(heartbeat().pack(broadcast))))
    assert fleet.ids() == []
    hear(fleet, 1.0, autopilot(heartbeat()))
    assert fleet.ids() == [SYSID]


def test_the_agents_status_shows_on_its_vehicle(fleet):
    status = agent_status.AgentStatus("mission", True, "", "search", "operator switched to BRAKE")
    payload = agent_status.encode(status)
    tunnel = mavlink.MAVLink_tunnel_message(0, 0, agent_status.AGENT_STATUS, len(payload),
                                            list(payload.ljust(128, b"\0")))
    hear(fleet, 0.0, autopilot(heartbeat()), companion(tunnel))
    shown = fleet.describe(fleet.get(SYSID), 0.0)["agent"]
    assert shown["state"] == "paused" and shown["reason"] == "operator switched to BRAKE"
    assert shown["mission"] == "search" and shown["phase"] == "mission"


def test_a_long_message_in_chunks_is_shown_whole(fleet):
    text = "Mission search: finished (search time used (12 legs)); going home now, at cruise speed"
    hear(fleet, 0.0, autopilot(heartbeat()), *[companion(m) for m in statustexts(text, 6, 7)])
    assert [m["text"] for m in fleet.get(SYSID).messages] == [text]


def test_the_station_builds_no_map_of_its_own_for_a_vehicle_whose_agent_streams_one(fleet):
    hear(fleet, 0.0, autopilot(heartbeat()), autopilot(position()), autopilot(echo()))
    hear(fleet, 0.5, companion(heartbeat(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0)))
    for k in range(20):
        hear(fleet, 1.0 + k * 0.5, autopilot(echo()))
    assert fleet.get(SYSID).own_map is None and fleet.get(SYSID).map_source is None


def test_the_station_builds_a_map_for_a_vehicle_without_a_stream_from_all_its_readings(fleet):
    hear(fleet, 0.0, autopilot(heartbeat()), autopilot(position()), autopilot(echo()))
    assert fleet.get(SYSID).own_map is None  # not yet: its agent may still speak up
    hear(fleet, OWN_MAP_AFTER + 0.1, autopilot(echo()))
    vehicle = fleet.get(SYSID)
    assert vehicle.map_source == "groundstation"
    assert fleet.describe(vehicle, OWN_MAP_AFTER)["map"]["occupied"] == 1  # both readings, the same cell
    assert vehicle.own_map.grid.max() == 2 * HIT  # the reading from before the decision counts too
    assert vehicle.own_map.cells_ever_hit == 1 and not vehicle.unmapped


def station(sysid: int):
    """A ground station's component (``sysid`` 255 is this station's own)."""
    packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
    return lambda message: mavlink.MAVLink(None).decode(bytearray(message.pack(packer)))


@pytest.mark.parametrize("sender", [77, 255], ids=["another station", "this station"])
@pytest.mark.parametrize("value, shown", [(float("nan"), "nan"), (float("inf"), "inf"), (float("-inf"), "-inf"),
                                          (-1.0, "-1.0"), (2.0 ** 32, "4294967296.0")])
def test_a_command_with_a_number_no_mode_has_is_shown_as_sent_and_raises_nothing(fleet, sender, value, shown):
    """A DO_SET_MODE whose mode (param2) was NaN raised in Fleet.apply (int() of it): live the link counted it,
    but a recording holds it, and its replay stopped there. Every parameter of either command message, from any
    station, to a known vehicle: no number raises; the mode shows as it was sent."""
    send = station(sender)
    custom = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    hear(fleet, 0.0, autopilot(heartbeat(mode=4)))
    for k, command in enumerate((mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                 mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_DO_REPOSITION)):
        hear(fleet, 1.0 + k,
             send(mavlink.MAVLink_command_long_message(SYSID, 1, command, 0, custom, value, *[value] * 5)),
             send(mavlink.MAVLink_command_long_message(SYSID, 1, command, 0, *[value] * 7)),
             send(mavlink.MAVLink_command_int_message(SYSID, 1, 0, command, 0, 0, custom, value, value, value,
                                                      0, 0, value)),
             send(mavlink.MAVLink_command_int_message(SYSID, 1, 0, command, 0, 0, *[value] * 4, 0, 0, value)))
    texts = [e["text"] for e in fleet.history.of(SYSID).as_json()["events"] if e["kind"] == "command"]
    assert texts[:2] == [f"sent DO_SET_MODE {shown}", "sent DO_SET_MODE"]
    assert texts.count(f"sent DO_SET_MODE {shown}") == 2  # by COMMAND_LONG and by COMMAND_INT
    hear(fleet, 9.0, send(mavlink.MAVLink_command_long_message(SYSID, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, custom,
                                                               value, 0, 0, 0, 0, 0)))
    # this station's order: a mode change may follow, but the order named no mode (another's is not ours)
    assert fleet.get(SYSID).ordered == ((9.0, None) if sender == 255 else (-math.inf, None))


def test_a_command_naming_a_mode_still_shows_and_orders_it(fleet):
    hear(fleet, 0.0, autopilot(heartbeat(mode=4)))
    hear(fleet, 1.0, station(255)(mavlink.MAVLink_command_long_message(
        SYSID, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6.0, 0, 0, 0, 0, 0)))
    events = fleet.history.of(SYSID).as_json()["events"]
    assert [e["text"] for e in events if e["kind"] == "command"] == ["sent DO_SET_MODE RTL"]
    assert fleet.get(SYSID).ordered == (1.0, 6)


def test_an_overhead_sonar_is_shown_with_its_pitch_and_its_silence_clears_nothing_in_the_stations_map(fleet):
    """A copter's overhead sonar (8 degrees up, a custom orientation with its mount in ``quaternion``): the API
    gives its pitch (the page names it "0° up 8°"), and in a map the station builds itself its beam, which
    rises over the walls, frees no cell; a level sonar's silence along the same bearing does."""
    from vehicle.protocol.rangefinder import orientation_of

    orientation, quaternion = orientation_of(0.0, 8.0)
    overhead = mavlink.MAVLink_distance_sensor_message(1000, 2, 1200, 1201, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND,
                                                       3, orientation, 0, 0.1, 0.1, quaternion, 0)
    hear(fleet, 0.0, autopilot(heartbeat()), autopilot(position()))
    hear(fleet, OWN_MAP_AFTER + 0.1, autopilot(overhead))
    vehicle = fleet.get(SYSID)
    described = fleet.describe(vehicle, OWN_MAP_AFTER + 0.1)["sonar"]
    assert [(s["id"], s["bearing"], s["pitch"]) for s in described] == [(3, 0.0, 8.0)]
    ahead = [vehicle.own_map.cell_of(0.0, y) for y in (2.0, 4.0, 6.0)]
    assert all(vehicle.own_map.grid[cell] == 0 for cell in ahead)
    level = mavlink.MAVLink_distance_sensor_message(1000, 2, 1200, 1201, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND,
                                                    4, 0, 0, 0.1, 0.1, [0.0] * 4, 0)
    hear(fleet, OWN_MAP_AFTER + 0.2, autopilot(level))
    assert all(vehicle.own_map.grid[cell] < 0 for cell in ahead)
