"""Vehicle kinds, flight modes with ArduPilot's numbers, and mission items.

Standard ground stations read ``custom_mode`` as ArduPilot's mode number, so the
simulated vehicle uses the same numbers (Rover and Copter tables from pymavlink).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from vehicle.protocol.mav import mavlink as mav


class Kind(StrEnum):
    ROVER = "rover"
    COPTER = "copter"

    @property
    def mav_type(self) -> int:
        return mav.MAV_TYPE_GROUND_ROVER if self is Kind.ROVER else mav.MAV_TYPE_QUADROTOR


# The modes this simulated autopilot flies, by ArduPilot number.
MODES: dict[Kind, dict[str, int]] = {
    Kind.ROVER: {"MANUAL": 0, "HOLD": 4, "LOITER": 5, "AUTO": 10, "RTL": 11, "GUIDED": 15},
    Kind.COPTER: {"AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9, "BRAKE": 17},
}

# What "stop in place" means for each kind (the ground station's abort).
STOP_MODE = {Kind.ROVER: "HOLD", Kind.COPTER: "BRAKE"}


def mode_number(kind: Kind, name: str) -> int:
    try:
        return MODES[kind][name.upper()]
    except KeyError:
        raise ValueError(f"{kind.value} has no mode {name!r}; modes: {', '.join(MODES[kind])}") from None


def mode_name(kind: Kind, number: int) -> str | None:
    for name, value in MODES[kind].items():
        if value == number:
            return name
    return None


# Mission commands the AUTO mode executes; anything else in a mission is skipped with a message.
NAV_WAYPOINT = mav.MAV_CMD_NAV_WAYPOINT
NAV_TAKEOFF = mav.MAV_CMD_NAV_TAKEOFF
NAV_LOITER_UNLIM = mav.MAV_CMD_NAV_LOITER_UNLIM
NAV_LAND = mav.MAV_CMD_NAV_LAND
NAV_RETURN_TO_LAUNCH = mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
DO_CHANGE_SPEED = mav.MAV_CMD_DO_CHANGE_SPEED
SUPPORTED_ITEMS = {NAV_WAYPOINT, NAV_TAKEOFF, NAV_LOITER_UNLIM, NAV_LAND, NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED}


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
        return self.command in (NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LAND) and (self.lat or self.lon)
