"""What is left of an AUTO mission (groundstation.mission_left): legs, loiter time, and which speed."""

import math

import pytest

from groundstation.mission_left import left, route_of
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import DO_CHANGE_SPEED, NAV_LOITER_TIME, NAV_WAYPOINT, MissionItem

DATUM = Datum()


def at(command: int, x: float, y: float, **params) -> MissionItem:
    lat, lon = DATUM.to_global(x, y)
    return MissionItem(command, lat, lon, 4.0, **params)


MISSION = [at(NAV_WAYPOINT, 0, 0), at(NAV_WAYPOINT, 0, 10), MissionItem(DO_CHANGE_SPEED, param2=5.0),
           at(NAV_LOITER_TIME, 10, 10, param1=30.0), at(NAV_WAYPOINT, 10, 0)]


def test_the_legs_left_from_the_vehicle_at_each_legs_speed_with_the_loiter_time():
    route = route_of(MISSION, DATUM)
    assert [s.seq for s in route.stops] == [1, 3, 4] and route.speeds == ((2, 5.0),)
    # flying to item 1 at 2 m/s (the vehicle's own pace until the mission sets one), 4 m short of it
    rest = left(route, 1, (0.0, 6.0), 2.0)
    assert rest["m"] == pytest.approx(4 + 10 + 10, abs=0.01) and rest["speed"] == 2.0
    assert rest["s"] == pytest.approx(4 / 2 + 10 / 5 + 30 + 10 / 5, abs=1)
    assert left(route, 4, (10.0, 5.0), 0.0) == {"m": pytest.approx(5.0, abs=0.01), "s": 1, "speed": 5.0}


def test_without_a_pace_only_the_distance_is_known_and_nothing_past_the_end():
    route = route_of(MISSION, DATUM)
    assert left(route, 1, (0.0, 0.0), 0.2)["s"] is None  # hovering: no pace to go by
    assert left(route, 1, (0.0, 0.0), None)["m"] == pytest.approx(30.0, abs=0.01)
    assert left(route, 5, (0.0, 0.0), 3.0) is None
    assert left(None, 1, (0.0, 0.0), 3.0) is None and left(route, None, (0.0, 0.0), 3.0) is None
    assert left(route, 1, (None, None), 3.0) is None


def test_a_loiter_time_or_speed_that_is_not_a_number_counts_for_nothing():
    route = route_of([at(NAV_WAYPOINT, 0, 0), MissionItem(DO_CHANGE_SPEED, param2=math.nan),
                      at(NAV_LOITER_TIME, 0, 10, param1=math.nan)], DATUM)
    assert route.speeds == () and route.stops[0].loiter_s == 0.0
    assert left(route, 1, (0.0, 0.0), 2.0)["s"] == 5
