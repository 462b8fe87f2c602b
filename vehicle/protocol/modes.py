"""Vehicle kinds and flight modes with ArduPilot's numbers: the one table of mode names and numbers.

Standard ground stations read ``custom_mode`` as ArduPilot's mode number for the
vehicle's MAV_TYPE (pymavlink's tables, which MAVProxy uses), so every
conversion here goes through them: the simulated vehicle's (the modes it flies
are a subset), the ground station's commands and its timeline.
"""

from __future__ import annotations

import functools
import math
from enum import StrEnum

from vehicle.protocol import mav as _mav
from vehicle.protocol.mav import mavlink as mav


def modes_of(mav_type: int) -> dict[int, str]:
    """ArduPilot's modes for a MAV_TYPE, number -> name (empty for a type ArduPilot has no table for)."""
    return _mav.mavutil.mode_mapping_bynumber(mav_type) or {}  # mavutil loads here, on first use


def name_of(mav_type: int, number: int) -> str | None:
    """The name of mode ``number`` on a vehicle of ``mav_type``; None if it has none."""
    return modes_of(mav_type).get(number)


def number_of(mav_type: int, name: str) -> int | None:
    """The number of the mode called ``name`` (any case) on a vehicle of ``mav_type``; None if it has none."""
    wanted = name.upper()
    return next((number for number, mode in modes_of(mav_type).items() if mode == wanted), None)


def heartbeat_mode(message) -> str:
    """A HEARTBEAT's mode as people read it ("GUIDED"; PX4's names; "Mode(23)" for a number with no name)."""
    return _mav.mavutil.mode_string_v10(message)


def commanded_mode(param: float) -> int | None:
    """The custom mode a command's float parameter names; None for one no mode has (NaN, infinite, negative,
    beyond 32 bits), which anyone on a link, or a recording of it, may send: int() of it would raise."""
    return int(param) if math.isfinite(param) and 0 <= param < 2 ** 32 else None


class Kind(StrEnum):
    ROVER = "rover"
    COPTER = "copter"

    @property
    def mav_type(self) -> int:
        return mav.MAV_TYPE_GROUND_ROVER if self is Kind.ROVER else mav.MAV_TYPE_QUADROTOR


# The modes this simulated autopilot flies (their numbers are the table's: ``flown``).
FLOWN: dict[Kind, tuple[str, ...]] = {
    Kind.ROVER: ("MANUAL", "HOLD", "LOITER", "AUTO", "RTL", "GUIDED"),
    Kind.COPTER: ("AUTO", "GUIDED", "LOITER", "RTL", "LAND", "BRAKE"),
}


@functools.cache
def flown(kind: Kind) -> dict[str, int]:
    """The modes the simulated ``kind`` flies, name -> ArduPilot number."""
    return {name: number_of(kind.mav_type, name) for name in FLOWN[kind]}

# What "stop in place" means for each kind of vehicle (the ground station's abort).
STOP_MODE = {"rover": "HOLD", "boat": "HOLD", "copter": "BRAKE", "plane": "LOITER"}
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: disarm even in the air (ArduPilot's magic number)


def mode_number(kind: Kind, name: str) -> int:
    """The number of a mode the simulated ``kind`` flies; ValueError for one it does not."""
    try:
        return flown(kind)[name.upper()]
    except KeyError:
        raise ValueError(f"{kind.value} has no mode {name!r}; modes: {', '.join(FLOWN[kind])}") from None


def mode_name(kind: Kind, number: int) -> str | None:
    """The name of mode ``number`` if the simulated ``kind`` flies it, else None."""
    name = name_of(kind.mav_type, number)
    return name if name in FLOWN[kind] else None


# What a flight controller tells its agent when the vehicle was disarmed in GUIDED: the agent never disarms
# it there, so someone else did (an operator's kill), and the agent stops commanding.
DISARMED = "the vehicle was disarmed"
