"""The page's mission plan: its items to and from MAVLink mission items, QGC WPL and QGroundControl .plan files,
and each leg checked against the scene.

A plan item is what the plan view edits: an action (take-off, waypoint, loiter for a time, land, return to
launch) at scene x, y (metres, x east, y north) and an altitude above home, with an optional speed and hold
time. On the wire it is a MISSION_ITEM_INT (a speed is a DO_CHANGE_SPEED before its item), item 0 home.
Files are read here, not in the page, so that a hostile file meets the same checks as an upload
(``vehicle.protocol.waypoints``) and is refused with a reason a person can act on.
"""

from __future__ import annotations

import json
import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.mission import (
    DO_CHANGE_SPEED,
    NAV_LAND,
    NAV_LOITER_TIME,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    MissionItem,
    home_item,
)
from vehicle.protocol.waypoints import MAX_ALTITUDE, WaypointError, check_items, mission_text, parse_mission

Action = Literal["takeoff", "waypoint", "loiter", "land", "rtl"]
COMMANDS = {"takeoff": NAV_TAKEOFF, "waypoint": NAV_WAYPOINT, "loiter": NAV_LOITER_TIME, "land": NAV_LAND,
            "rtl": NAV_RETURN_TO_LAUNCH}
ACTIONS = {command: action for action, command in COMMANDS.items()}
RELATIVE = (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
MAX_PLAN_ITEMS = 700  # what our autopilot stores (ArduPilot's is about as many on a small board)
BODY_RADIUS = 0.3  # m: a leg is cast three times, along its middle and this far either side
QGC_ARDUPILOT, QGC_QUAD, QGC_ROVER = 3, 2, 10  # MAV_AUTOPILOT and MAV_TYPE numbers as a .plan stores them


class PlanError(ValueError):
    """A plan or a plan file that cannot be flown here, and why."""


Metres = Annotated[float, Field(allow_inf_nan=False, ge=-1e6, le=1e6)]


class PlanItem(BaseModel):
    action: Action
    x: Metres
    y: Metres
    alt: float = Field(0.0, allow_inf_nan=False, ge=-MAX_ALTITUDE, le=MAX_ALTITUDE, description="m above home")
    speed: float | None = Field(None, allow_inf_nan=False, gt=0, le=100, description="m/s from this item on")
    hold: float = Field(0.0, allow_inf_nan=False, ge=0, le=86400, description="s (a loiter's time, a waypoint's "
                                                                               "wait)")


class Plan(BaseModel):
    items: list[PlanItem] = Field(max_length=MAX_PLAN_ITEMS)
    home: tuple[Metres, Metres] | None = Field(None, description="scene x, y of home (default: the scene's origin)")


# ---- plan <-> mission items ------------------------------------------------------------------------------
def to_mission(plan: Plan, datum: Datum) -> list[MissionItem]:
    """The plan as mission items, item 0 home; a speed that changes is a DO_CHANGE_SPEED before its item."""
    items = [home_item(datum, *(plan.home or (0.0, 0.0)))]
    speed = None
    for p in plan.items:
        if p.speed is not None and p.speed != speed:
            items.append(MissionItem(DO_CHANGE_SPEED, param1=1.0, param2=p.speed, param3=-1.0,
                                     frame=mavlink.MAV_FRAME_MISSION))
            speed = p.speed
        lat, lon = datum.to_global(p.x, p.y)
        if p.action == "rtl":
            items.append(MissionItem(NAV_RETURN_TO_LAUNCH))
        else:
            items.append(MissionItem(COMMANDS[p.action], lat, lon, 0.0 if p.action == "land" else p.alt,
                                     param1=p.hold if p.action in ("waypoint", "loiter") else 0.0))
    return items


def from_mission(items: list[MissionItem], datum: Datum) -> Plan:
    """A plan from mission items (item 0 home); refuses what the plan view cannot show, naming the item."""
    if not items:
        raise PlanError("the mission has no items, not even home")
    home = datum.to_local(items[0].lat, items[0].lon) if items[0].lat or items[0].lon else (0.0, 0.0)
    plan, speed, where = [], None, home
    for seq, item in enumerate(items[1:], start=1):
        if item.command == DO_CHANGE_SPEED:
            if not (math.isfinite(item.param2) and 0 < item.param2 <= 100):
                raise PlanError(f"item {seq}: a speed of {item.param2} m/s (the plan view takes 0 to 100 m/s)")
            speed = item.param2
            continue
        action = ACTIONS.get(item.command)
        if action is None:
            raise PlanError(f"item {seq}: command {_command_name(item.command)} is not one the plan view edits "
                            "(take-off, waypoint, loiter time, land, return to launch, change speed)")
        if action != "rtl" and item.frame not in RELATIVE:
            raise PlanError(f"item {seq}: frame {item.frame} ({_frame_name(item.frame)}); the plan view plans "
                            "altitudes above home (frame 3, GLOBAL_RELATIVE_ALT)")
        if action == "rtl":
            x, y = home
        elif item.lat or item.lon:
            x, y = datum.to_local(item.lat, item.lon)
        else:
            x, y = where  # a take-off or land "here"
        hold = item.param1 if action in ("waypoint", "loiter") else 0.0
        if not (math.isfinite(hold) and 0 <= hold <= 86400):
            raise PlanError(f"item {seq}: a hold of {hold} s (the plan view takes 0 s to a day)")
        plan.append(PlanItem(action=action, x=round(x, 3), y=round(y, 3), alt=item.alt if action != "rtl" else 0.0,
                             speed=speed, hold=hold))
        speed, where = None, (x, y)
    if len(plan) > MAX_PLAN_ITEMS:
        raise PlanError(f"{len(plan)} items; the plan view takes at most {MAX_PLAN_ITEMS}")
    return Plan(items=plan, home=(round(home[0], 3), round(home[1], 3)))


def _command_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command)
    return f"{command} ({entry.name})" if entry else str(command)


def _frame_name(frame: int) -> str:
    entry = mavlink.enums["MAV_FRAME"].get(frame)
    return entry.name if entry else "unknown"


# ---- files ----------------------------------------------------------------------------------------------
def read_file(text: str, datum: Datum) -> Plan:
    """A plan from QGC WPL 110 text or a QGroundControl .plan (JSON), told apart by their first character."""
    if text.lstrip().startswith("{"):
        return from_mission(read_qgc_plan(text), datum)
    if not text.lstrip().startswith("QGC WPL"):
        raise PlanError("neither a QGC WPL mission (first line 'QGC WPL 110') nor a QGroundControl .plan (JSON)")
    try:
        return from_mission(parse_mission(text), datum)
    except WaypointError as error:
        raise PlanError(str(error)) from None


def write_file(plan: Plan, datum: Datum, kind: Literal["wpl", "plan"], vehicle: str = "copter") -> str:
    items = to_mission(plan, datum)
    return mission_text(items) if kind == "wpl" else json.dumps(qgc_plan(items, datum, vehicle), indent=2) + "\n"


def qgc_plan(items: list[MissionItem], datum: Datum, vehicle: str = "copter") -> dict:
    """A QGroundControl .plan document (its version 1, mission version 2) of mission items, item 0 home."""
    home = items[0]
    simple = [{"type": "SimpleItem", "autoContinue": bool(item.autocontinue), "command": item.command,
               "doJumpId": seq, "frame": item.frame,
               "params": [item.param1, item.param2, item.param3, item.param4, item.lat, item.lon, item.alt]}
              for seq, item in enumerate(items[1:], start=1)]
    return {"fileType": "Plan", "groundStation": "scanstation", "version": 1,
            "geoFence": {"circles": [], "polygons": [], "version": 2}, "rallyPoints": {"points": [], "version": 2},
            "mission": {"version": 2, "firmwareType": QGC_ARDUPILOT,
                        "vehicleType": QGC_ROVER if vehicle == "rover" else QGC_QUAD,
                        "cruiseSpeed": 2.5, "hoverSpeed": 2.5,
                        "plannedHomePosition": [home.lat, home.lon, datum.alt], "items": simple}}


def read_qgc_plan(text: str) -> list[MissionItem]:
    """Mission items (item 0 home) from a QGroundControl .plan; every error names the item and what is wrong."""
    try:
        document = json.loads(text)
    except (ValueError, RecursionError) as error:
        where = f" (line {error.lineno}, column {error.colno})" if isinstance(error, json.JSONDecodeError) else ""
        raise PlanError(f"the .plan file is not valid JSON{where}") from None
    if not isinstance(document, dict) or document.get("fileType") != "Plan":
        raise PlanError("not a QGroundControl .plan: its fileType is not \"Plan\"")
    mission = document.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise PlanError("the .plan file has no mission with a list of items")
    raw = mission["items"]
    if len(raw) > MAX_PLAN_ITEMS:
        raise PlanError(f"the .plan file has {len(raw)} items; at most {MAX_PLAN_ITEMS} are flown here")
    home = mission.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) == 3 and all(_number(v) for v in home)):
        raise PlanError("the .plan file's plannedHomePosition is not [latitude, longitude, altitude]")
    items = [MissionItem(NAV_WAYPOINT, float(home[0]), float(home[1]), 0.0)]
    for seq, entry in enumerate(raw, start=1):
        items.append(_simple_item(entry, seq))
    try:
        check_items(items, "the .plan file")
    except WaypointError as error:
        raise PlanError(str(error)) from None
    return items


def _simple_item(entry, seq: int) -> MissionItem:
    where = f"the .plan file: item {seq}"
    if not isinstance(entry, dict):
        raise PlanError(f"{where} is not an object")
    if entry.get("type") == "ComplexItem":
        raise PlanError(f"{where} is a {entry.get('complexItemType', 'complex')} pattern; turn it into waypoints in "
                        "QGroundControl first (the plan view flies simple items)")
    if entry.get("type") != "SimpleItem":
        raise PlanError(f"{where}: its type is not \"SimpleItem\"")
    command, frame, params = entry.get("command"), entry.get("frame"), entry.get("params")
    if not (_whole(command) and _whole(frame)):
        raise PlanError(f"{where}: command and frame must be whole numbers")
    if not (isinstance(params, list) and len(params) == 7):
        raise PlanError(f"{where}: params must be a list of 7 numbers")
    if not all(p is None or _number(p) for p in params) or any(p is None for p in params[4:]):
        raise PlanError(f"{where}: params must be numbers (null only for the first four)")
    p = [math.nan if v is None else float(v) for v in params]  # QGroundControl writes NaN (a default) as null
    return MissionItem(command, p[4], p[5], p[6], *p[:4], frame=frame,
                       autocontinue=0 if entry.get("autoContinue") is False else 1)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _whole(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 65535


# ---- legs against the scene -----------------------------------------------------------------------------
def legs(plan: Plan) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    """The flown path as 3D legs (z above home), from home: a take-off climbs where it is, a land descends."""
    home = plan.home or (0.0, 0.0)
    here = (home[0], home[1], 0.0)
    path = []
    for p in plan.items:
        if p.action == "takeoff":
            there = (here[0], here[1], p.alt)
        elif p.action == "rtl":
            there = (home[0], home[1], here[2])
        elif p.action == "land":
            there = (p.x, p.y, here[2])
        else:
            there = (p.x, p.y, p.alt)
        path.append((here, there))
        here = there
    return path


def check_legs(plan: Plan, scene, caster, ground: float) -> list[dict]:
    """Each leg of the plan, and whether the scene stands in its way (``ground``: the scene's height at home).
    A leg is cast along its middle and a body's radius to either side, from at least 0.5 m above home's ground
    (a rover's, or a take-off's start, would graze the ground it stands on)."""
    out = []
    for index, (a, b) in enumerate(legs(plan)):
        start = np.array([a[0], a[1], ground + max(a[2], 0.5)])
        end = np.array([b[0], b[1], ground + max(b[2], 0.5)])
        span = end - start
        length = float(np.linalg.norm(span))
        leg = {"index": index, "length": round(math.dist(a, b), 2), "blocked": False, "hit": None, "object": None}
        if length > 1e-6 and caster is not None:
            direction = span / length
            side = np.cross(direction, [0.0, 0.0, 1.0])
            side = side / np.linalg.norm(side) * BODY_RADIUS if np.linalg.norm(side) > 1e-9 else np.zeros(3)
            origins = np.array([start, start + side, start - side])
            distances, faces = caster.cast(origins, np.broadcast_to(direction, origins.shape))
            nearest = int(np.argmin(distances))
            if distances[nearest] < length:
                hit = origins[nearest] + direction * distances[nearest]
                leg.update(blocked=True, hit=[round(float(v), 2) for v in hit],
                           object=_object(scene, int(faces[nearest])))
        out.append(leg)
    return out


def _object(scene, face: int) -> str:
    index = int(scene.face_object[face]) if 0 <= face < len(scene.face_object) else -1
    names = scene.object_names
    return names[index] if 0 <= index < len(names) and names[index] else f"shape {index}"
