"""AUTO missions as QGC WPL 110 text: read with pymavlink's mavwp, written here.

QGC WPL is what QGroundControl, Mission Planner and MAVProxy save, so a mission
planned in any of them flies here, and ours open there. Item 0 is home. Writing
is done here because mavwp saves coordinates with 6 decimals (11 cm); 8 keep
a waypoint where it was put.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from pathlib import Path

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.mission import MissionItem


class WaypointError(ValueError):
    pass


def load_mission(path: str | Path, source: str | None = None) -> list[MissionItem]:
    """Mission items from a QGC WPL file (item 0 is home); ``source`` names it in errors (default: the path)."""
    from pymavlink import mavwp  # loaded when a mission file is read (mavutil comes with it)

    source = source or str(path)
    try:
        _check_fields(Path(path).read_text(encoding="utf-8"), source)  # before mavwp, whose errors quote fields
        loader = mavwp.MAVWPLoader()
        loader.load(str(path))
    except (OSError, UnicodeDecodeError) as error:
        raise WaypointError(f"{source}: {error.strerror if isinstance(error, OSError) else error}") from None
    except WaypointError:
        raise
    except Exception as error:  # mavwp raises MAVWPError and bare ValueErrors/IndexErrors on bad lines
        why = str(error)
        if why.startswith("Unsupported waypoint format"):  # it quotes the whole first line, which may be megabytes
            why = "its first line names no waypoint format mavwp reads"
        raise WaypointError(f"{source}: not a QGC WPL 110 mission ({_shortened(why)})") from None
    items = [MissionItem(command=w.command, lat=w.x, lon=w.y, alt=w.z, param1=w.param1, param2=w.param2,
                         param3=w.param3, param4=w.param4, frame=w.frame, autocontinue=w.autocontinue)
             for w in (loader.wp(i) for i in range(loader.count()))]
    check_items(items, source)
    return items


def parse_mission(text: str) -> list[MissionItem]:
    """Mission items from QGC WPL text (an upload over HTTP); errors call it "the mission", never by the
    temporary file mavwp reads it from."""
    with tempfile.NamedTemporaryFile("w", suffix=".waypoints", delete=False, encoding="utf-8") as handle:
        handle.write(text)
    try:
        return load_mission(handle.name, "the mission")
    finally:
        os.unlink(handle.name)


def _shortened(text: str, most: int = 120) -> str:
    return text if len(text) <= most else text[:most] + "..."


MAX_ITEMS = 65535  # MAVLink numbers mission items with 16 bits
FLOAT32_MAX = 3.4028234663852886e38  # MAVLink carries params and altitudes as float32
MAX_ALTITUDE = 2**31 / 100  # m: ArduPilot keeps altitudes as 32-bit centimetres
FRAMES = frozenset(mavlink.enums["MAV_FRAME"]) - {mavlink.MAV_FRAME_ENUM_END}
_INTEGER = re.compile(r"[+-]?\d+")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(nan|inf|infinity)", re.IGNORECASE)
_INTEGER_FIELDS = {0: "seq", 1: "current", 2: "frame", 3: "command", 11: "autocontinue"}


def _check_fields(text: str, source: str) -> None:
    """What mavwp leaves unchecked in QGC WPL 110 text: each field a plain decimal number (Python's int and
    float also take "1_0", which would put a mistyped waypoint in another country), whole numbers where
    MAVLink has integers, items numbered 0, 1, 2, ... and "current" 0 or 1. Errors name the line and the
    field, never the text (it may be anyone's)."""
    lines = text.splitlines()
    if not lines or lines[0].strip() != "QGC WPL 110":
        return  # the older formats mavwp reads have other columns
    seq = 0
    for number, line in enumerate(lines[1:], start=2):
        if line.startswith("#") or not line.strip():
            continue  # as mavwp skips them
        where = f"{source}: line {number}"
        fields = line.split()
        if len(fields) != 12:
            raise WaypointError(f"{source}: not a QGC WPL 110 mission (line {number} has {len(fields)} fields, "
                                "not 12)")
        for column, field in enumerate(fields):
            name = _INTEGER_FIELDS.get(column)
            if not (_INTEGER if name else _NUMBER).fullmatch(field):
                raise WaypointError(f"{where}: field {column + 1} is not " +
                                    (f"a whole number ({name})" if name else "a decimal number"))
        if int(fields[0]) != seq:
            raise WaypointError(f"{where}: items must be numbered 0, 1, 2, ... in order (this one should be {seq})")
        if int(fields[1]) not in (0, 1):
            raise WaypointError(f"{where}: 'current' is 0 or 1")
        seq += 1


def check_items(items: list[MissionItem], source: str) -> None:
    """What MAVLink can carry: a bounded count, finite coordinates on Earth, fields that fit their types."""
    if len(items) > MAX_ITEMS:
        raise WaypointError(f"{source}: {len(items)} items; MAVLink carries at most {MAX_ITEMS}")
    for seq, item in enumerate(items):
        where = f"{source}: item {seq}"
        if not all(math.isfinite(v) for v in (item.lat, item.lon, item.alt)):
            raise WaypointError(f"{where}: its position is not a number")
        if abs(item.lat) > 90 or abs(item.lon) > 180:
            raise WaypointError(f"{where}: latitude {item.lat} or longitude {item.lon} is not on Earth")
        if abs(item.alt) > MAX_ALTITUDE:
            raise WaypointError(f"{where}: altitude beyond {MAX_ALTITUDE / 1000:,.0f} km, more than an autopilot "
                                "can hold")
        if not (0 <= item.command <= 65535 and item.frame in FRAMES and item.autocontinue in (0, 1)):
            raise WaypointError(f"{where}: command {item.command}, frame {item.frame} or autocontinue "
                                f"{item.autocontinue} out of range")
        if any(math.isinf(p) or abs(p) > FLOAT32_MAX for p in (item.param1, item.param2, item.param3, item.param4)):
            raise WaypointError(f"{where}: a parameter is infinite or beyond what MAVLink's float32 carries")


def mission_text(items: list[MissionItem]) -> str:
    """QGC WPL 110 text of mission items, the first being home."""
    lines = ["QGC WPL 110"]
    for seq, item in enumerate(items):
        lines.append("\t".join([
            str(seq), "1" if seq == 0 else "0", str(item.frame), str(item.command),
            *(f"{p:.8f}" for p in (item.param1, item.param2, item.param3, item.param4)),
            f"{item.lat:.8f}", f"{item.lon:.8f}", f"{item.alt:.6f}", str(item.autocontinue),
        ]))
    return "\n".join(lines) + "\n"


def save_mission(items: list[MissionItem], path: str | Path) -> None:
    Path(path).write_text(mission_text(items), encoding="utf-8")


def positions(items: list[MissionItem], datum: Datum) -> list[tuple[float, float]]:
    """Scene x, y of the items that have a position, skipping home (item 0)."""
    return [datum.to_local(item.lat, item.lon) for item in items[1:] if item.has_position]


def load_positions(path: str | Path, datum: Datum) -> list[tuple[float, float]]:
    points = positions(load_mission(path), datum)
    if not points:
        raise WaypointError(f"{path}: no waypoints with a position")
    return points



def parse_points(text: str) -> list[tuple[float, float]]:
    """``"x,y; x,y; ..."`` (scene metres), as a scene's ``waypoints=`` hint gives them."""
    points = []
    for part in filter(None, (p.strip() for p in text.split(";"))):
        try:
            x, y = (float(v) for v in part.split(","))
        except ValueError:
            raise WaypointError(f"waypoints are 'x,y; x,y; ...', not {text!r}") from None
        points.append((x, y))
    return points
