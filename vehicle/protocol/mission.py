"""Mission items and the MAVLink mission protocol's wire side: items both ways, and the client's part.

A mission is a list of MissionItem, item 0 home, as ArduPilot stores it. On
the wire an item is a MISSION_ITEM_INT (latitude and longitude in 1e-7
degrees); legacy MISSION_ITEM (floats) is read too. ``download`` and
``upload`` are the ground station's (or a companion's) half of the protocol,
over any link that can send a message and wait for a reply: the ground
station and the onboard agent both use them. The vehicle's half lives with
the simulated autopilot (``vehicle.sim.mission_server``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink as mav

MISSION = mav.MAV_MISSION_TYPE_MISSION

# Mission commands the AUTO mode executes; anything else in a mission is skipped with a message.
NAV_WAYPOINT = mav.MAV_CMD_NAV_WAYPOINT
NAV_TAKEOFF = mav.MAV_CMD_NAV_TAKEOFF
NAV_LOITER_UNLIM = mav.MAV_CMD_NAV_LOITER_UNLIM
NAV_LOITER_TIME = mav.MAV_CMD_NAV_LOITER_TIME
NAV_LAND = mav.MAV_CMD_NAV_LAND
NAV_RETURN_TO_LAUNCH = mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
DO_CHANGE_SPEED = mav.MAV_CMD_DO_CHANGE_SPEED
SUPPORTED_ITEMS = {NAV_WAYPOINT, NAV_TAKEOFF, NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_LAND, NAV_RETURN_TO_LAUNCH,
                   DO_CHANGE_SPEED}
ALTITUDE_LIMIT = 1000.0  # m above home: the most a target may ask (the top of ArduPilot's FENCE_ALT_MAX range)


@dataclass
class MissionItem:
    """One MAVLink mission item in the global relative-altitude frame, as on the wire.

    ``lat``/``lon`` in degrees and ``alt`` in metres above home; ``param1..4`` as
    MAVLink defines them for ``command``. Item 0 is home, as ArduPilot stores it.
    """

    command: int
    lat: float = 0.0
    lon: float = 0.0
    alt: float = 0.0
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    frame: int = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT
    autocontinue: int = 1

    @property
    def is_nav(self) -> bool:
        return self.command < mav.MAV_CMD_NAV_LAST

    @property
    def has_position(self) -> bool:
        positioned = (NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_LAND)
        return self.command in positioned and bool(self.lat or self.lon)


@dataclass(slots=True)
class MissionProgress:
    """How far an autopilot is through its own AUTO mission (what MISSION_CURRENT reports)."""

    current: int  # sequence number of the item being flown
    count: int  # items, home included
    running: bool
    complete: bool  # flown to its end


def item_problem(item: MissionItem) -> int | None:
    """The MAV_MISSION_RESULT an autopilot refuses a navigation item with, or None if it can fly it: a
    position that is no number or not on Earth, an altitude beyond ``ALTITUDE_LIMIT``, a hold time that is
    no number (the item would never end)."""
    if not item.is_nav:
        return None
    if not (math.isfinite(item.lat) and abs(item.lat) <= 90):
        return mav.MAV_MISSION_INVALID_PARAM5_X
    if not (math.isfinite(item.lon) and abs(item.lon) <= 180):
        return mav.MAV_MISSION_INVALID_PARAM6_Y
    if not (math.isfinite(item.alt) and abs(item.alt) <= ALTITUDE_LIMIT):
        return mav.MAV_MISSION_INVALID_PARAM7
    if item.command in (NAV_WAYPOINT, NAV_LOITER_TIME) and not (math.isfinite(item.param1) and item.param1 >= 0):
        return mav.MAV_MISSION_INVALID_PARAM1
    return None


def home_item(datum: Datum, x: float, y: float) -> MissionItem:
    """Item 0 of a mission: home at scene position (x, y)."""
    lat, lon = datum.to_global(x, y)
    return MissionItem(NAV_WAYPOINT, lat, lon, 0.0)


def item_message(item: MissionItem, seq: int, target: tuple[int, int], current: bool):
    frame = item.frame
    if frame == mav.MAV_FRAME_GLOBAL_RELATIVE_ALT:
        frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    elif frame == mav.MAV_FRAME_GLOBAL:
        frame = mav.MAV_FRAME_GLOBAL_INT
    return mav.MAVLink_mission_item_int_message(
        target[0], target[1], seq, frame, item.command, int(current), item.autocontinue,
        item.param1, item.param2, item.param3, item.param4, int(round(item.lat * 1e7)),
        int(round(item.lon * 1e7)), item.alt, MISSION)


def item_from(message) -> MissionItem:
    """A MissionItem from a MISSION_ITEM_INT or a legacy float MISSION_ITEM."""
    scale = 1e-7 if message.get_type() == "MISSION_ITEM_INT" else 1.0
    frame = message.frame
    if frame == mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
        frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT
    elif frame == mav.MAV_FRAME_GLOBAL_INT:
        frame = mav.MAV_FRAME_GLOBAL
    return MissionItem(command=message.command, lat=message.x * scale, lon=message.y * scale, alt=message.z,
                       param1=message.param1, param2=message.param2, param3=message.param3,
                       param4=message.param4, frame=frame, autocontinue=message.autocontinue)


# ---- the client's half ---------------------------------------------------------------------------------
class Requester(Protocol):
    """A link that sends to a vehicle and waits for the first reply a predicate accepts (else raises)."""

    def request(self, sysid: int, message, accepts: Callable[[object], bool], timeout: float = 1.0): ...

    def send(self, message, sysid: int | None = None) -> None: ...


def download(link: Requester, sysid: int, component: int = 1, timeout: float = 1.0,
             progress: Callable[[int, int], None] | None = None) -> list[MissionItem]:
    """The vehicle's mission: MISSION_REQUEST_LIST, then each item in turn, then MISSION_ACK (``progress`` as
    ``upload``'s)."""
    count = link.request(sysid, mav.MAVLink_mission_request_list_message(sysid, component, MISSION),
                         lambda m: m.get_type() == "MISSION_COUNT", timeout).count
    items = []
    for seq in range(count):
        reply = link.request(sysid, mav.MAVLink_mission_request_int_message(sysid, component, seq, MISSION),
                             lambda m, s=seq: m.get_type() in ("MISSION_ITEM_INT", "MISSION_ITEM") and m.seq == s,
                             timeout)
        items.append(item_from(reply))
        if progress is not None:
            progress(seq + 1, count)
    link.send(mav.MAVLink_mission_ack_message(sysid, component, mav.MAV_MISSION_ACCEPTED, MISSION), sysid)
    return items


REQUESTS_PER_ITEM = 3  # an upload answers at most this many requests per item: a vehicle that lost some asks
# again, one that keeps asking and never accepts would hold the uploader for ever


class MissionError(Exception):
    """The vehicle asked for an item the upload does not have, or kept asking without accepting the mission."""


def upload(link: Requester, sysid: int, items: list[MissionItem], component: int = 1, timeout: float = 1.0,
           progress: Callable[[int, int], None] | None = None) -> str:
    """Upload items (item 0 is home); returns the vehicle's MISSION_ACK result as a word ("accepted", ...).
    ``progress(sent, count)`` is told each item as it goes, for a page to show."""
    def wanted(m) -> bool:
        return m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")

    reply = link.request(sysid, mav.MAVLink_mission_count_message(sysid, component, len(items), MISSION), wanted,
                         timeout)
    most = REQUESTS_PER_ITEM * len(items)
    for answered in range(most + 1):
        if reply.get_type() == "MISSION_ACK":
            return mission_result(reply.type)
        if answered == most:
            break
        seq = reply.seq
        if not 0 <= seq < len(items):
            raise MissionError(f"vehicle {sysid} asked for mission item {seq} of {len(items)}")
        if progress is not None:
            progress(seq + 1, len(items))
        reply = link.request(sysid, item_message(items[seq], seq, (sysid, component), False),
                             lambda m, s=seq: wanted(m) and (m.get_type() == "MISSION_ACK" or m.seq != s), timeout)
    raise MissionError(f"vehicle {sysid} asked for {most} items of a {len(items)}-item mission and did not accept it")


def mission_result(code: int) -> str:
    return "accepted" if code == mav.MAV_MISSION_ACCEPTED else \
        mav.enums["MAV_MISSION_RESULT"][code].name.removeprefix("MAV_MISSION_").lower()
