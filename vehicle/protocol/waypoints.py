"""AUTO missions as QGC WPL 110 text: read with pymavlink's mavwp, written here.

QGC WPL is what QGroundControl, Mission Planner and MAVProxy save, so a mission
planned in any of them flies here, and ours open there. Item 0 is home. Writing
is done here because mavwp saves coordinates with 6 decimals (11 cm); 8 keep
a waypoint where it was put.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import MissionItem


class WaypointError(ValueError):
    pass


def load_mission(path: str | Path, source: str | None = None) -> list[MissionItem]:
    """Mission items from a QGC WPL file (item 0 is home); ``source`` names it in errors (default: the path)."""
    from pymavlink import mavwp  # loaded when a mission file is read (mavutil comes with it)

    source = source or str(path)
    loader = mavwp.MAVWPLoader()
    try:
        loader.load(str(path))
    except (OSError, UnicodeDecodeError) as error:
        raise WaypointError(f"{source}: {error.strerror if isinstance(error, OSError) else error}") from None
    except Exception as error:  # mavwp raises MAVWPError and bare ValueErrors/IndexErrors on bad lines
        raise WaypointError(f"{source}: not a QGC WPL 110 mission ({error})") from None
    items = [MissionItem(command=w.command, lat=w.x, lon=w.y, alt=w.z, param1=w.param1, param2=w.param2,
                         param3=w.param3, param4=w.param4, frame=w.frame, autocontinue=w.autocontinue)
             for w in (loader.wp(i) for i in range(loader.count()))]
    _check(items, source)
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


MAX_ITEMS = 65535  # MAVLink numbers mission items with 16 bits


def _check(items: list[MissionItem], source: str) -> None:
    """What MAVLink can carry: a bounded count, finite coordinates on Earth, fields that fit their types."""
    if len(items) > MAX_ITEMS:
        raise WaypointError(f"{source}: {len(items)} items; MAVLink carries at most {MAX_ITEMS}")
    for seq, item in enumerate(items):
        where = f"{source}: item {seq}"
        if not all(math.isfinite(v) for v in (item.lat, item.lon, item.alt)):
            raise WaypointError(f"{where}: its position is not a number")
        if abs(item.lat) > 90 or abs(item.lon) > 180:
            raise WaypointError(f"{where}: latitude {item.lat} or longitude {item.lon} is not on Earth")
        if not (0 <= item.command <= 65535 and 0 <= item.frame <= 255 and item.autocontinue in (0, 1)):
            raise WaypointError(f"{where}: command {item.command}, frame {item.frame} or autocontinue "
                                f"{item.autocontinue} out of range")
        if any(math.isinf(p) for p in (item.param1, item.param2, item.param3, item.param4)):
            raise WaypointError(f"{where}: a parameter is infinite")


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
