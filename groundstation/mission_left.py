"""What is left of a mission the autopilot flies (AUTO): the distance along its remaining legs and the time at its
speed, so the card can say when it will be done (QGroundControl's "time remaining").

The route is the mission the station uploaded or downloaded: its items with a position, each with its item number.
What is left runs from the vehicle to the item it flies to (MISSION_CURRENT) and on through the rest, plus the time
of each loiter item on the way. A leg's speed is the mission's own (the last DO_CHANGE_SPEED before the leg's end),
else the vehicle's ground speed while it moves; with neither, only the distance is known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import DO_CHANGE_SPEED, NAV_LOITER_TIME, MissionItem

MOVING = 0.5  # m/s: a ground speed below this says nothing of the mission's pace (turning, braking, loitering)


@dataclass(frozen=True)
class Stop:
    seq: int  # the item's number in the mission (0 is home)
    x: float
    y: float
    loiter_s: float = 0.0  # a NAV_LOITER_TIME's time there


@dataclass(frozen=True)
class Route:
    stops: tuple[Stop, ...]
    speeds: tuple[tuple[int, float], ...]  # (item number, m/s) of each DO_CHANGE_SPEED that sets one


def route_of(items: list[MissionItem], datum: Datum) -> Route:
    """The route of a mission as the station holds it (item 0, home, is no stop)."""
    stops, speeds = [], []
    for seq, item in enumerate(items):
        if seq > 0 and item.has_position:
            x, y = datum.to_local(item.lat, item.lon)
            loiter = item.param1 if item.command == NAV_LOITER_TIME and math.isfinite(item.param1) else 0.0
            stops.append(Stop(seq, x, y, max(0.0, loiter)))
        elif item.command == DO_CHANGE_SPEED and math.isfinite(item.param2) and item.param2 > 0:
            speeds.append((seq, float(item.param2)))
    return Route(tuple(stops), tuple(speeds))


def left(route: Route | None, current: int | None, position: tuple[float, float] | None,
         ground_speed: float | None) -> dict | None:
    """``{"m": distance left, "s": time left or None, "speed": the speed it assumes now or None}``, or None when the
    route, the current item or the position is unknown, or the route has no stop from the current item on."""
    if route is None or current is None or position is None or None in position:
        return None
    ahead = [stop for stop in route.stops if stop.seq >= current]
    if not ahead:
        return None
    metres, seconds, here, speed_now = 0.0, 0.0, position, None
    for k, stop in enumerate(ahead):
        leg = math.dist(here, (stop.x, stop.y))
        planned = [speed for seq, speed in route.speeds if seq < stop.seq]  # set before this leg's stop
        speed = planned[-1] if planned else ground_speed if ground_speed is not None and ground_speed >= MOVING \
            else None
        speed_now = speed if k == 0 else speed_now
        metres += leg
        seconds = None if seconds is None or speed is None else seconds + leg / speed + stop.loiter_s
        here = (stop.x, stop.y)
    return {"m": round(metres, 1), "s": None if seconds is None else round(seconds), "speed": speed_now}
