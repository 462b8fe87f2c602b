"""Vehicle kinds and flight modes with ArduPilot's numbers.

Standard ground stations read ``custom_mode`` as ArduPilot's mode number, so the
simulated vehicle uses the same numbers (Rover and Copter tables from pymavlink).
"""

from __future__ import annotations

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

# What "stop in place" means for each kind of vehicle (the ground station's abort).
STOP_MODE = {"rover": "HOLD", "boat": "HOLD", "copter": "BRAKE", "plane": "LOITER"}
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: disarm even in the air (ArduPilot's magic number)


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

# What a flight controller tells its agent when the vehicle was disarmed in GUIDED: the agent never disarms
# it there, so someone else did (an operator's kill), and the agent stops commanding.
DISARMED = "the vehicle was disarmed"
