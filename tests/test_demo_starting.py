"""The demo's vehicles starting are told, not discovered: the status frames say since when the station started
them until the first is heard, then how long it took (the first start after an install compiles the
simulator's loops for some 15 s, and the page said only "No vehicles yet"); a station that started none says
nothing."""

from __future__ import annotations

from harness import idle_station

from vehicle.protocol.mav import mavlink


def heartbeat():
    m = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                          mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4, 3)
    m.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    return m


def test_the_status_says_the_vehicles_are_starting_and_how_long_they_took():
    with idle_station() as station:
        assert station.status()["starting"] is None  # it started no vehicles
        station.expect_vehicles()
        station.vehicles_started -= 12.0  # as if the station had started them 12 s ago
        starting = station.status()["starting"]
        assert starting["took"] is None and 12.0 <= starting["since"] < 30.0
        station.live.apply(heartbeat(), station.now())
        took = station.status()["starting"]["took"]
        assert 12.0 <= took < 30.0
        station.vehicles_started -= 100.0
        assert station.status()["starting"]["took"] == took  # the time to the first one heard, kept
