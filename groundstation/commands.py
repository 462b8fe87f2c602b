"""Operator actions, as the REST API and the page name them, turned into MAVLink for one vehicle.

Each returns the vehicle's COMMAND_ACK result as a word ("accepted",
"denied", ...) or raises ``LinkError`` when the vehicle never answered. What
"stop" means depends on the vehicle: a rover holds, a copter brakes, a plane
loiters.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, model_validator

from groundstation.link import Link
from groundstation.state import VehicleState
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink, mavutil
from vehicle.protocol.modes import FORCE_DISARM, STOP_MODE

COMPANION = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
Action = Literal["abort", "kill", "rtl", "set_mode", "arm", "disarm", "takeoff", "land", "resume", "goto", "speed"]


class Command(BaseModel):
    """A command from the operator (JSON body of POST /api/vehicles/{sysid}/commands)."""

    action: Action
    mode: str | None = Field(None, description="flight mode name for set_mode, e.g. GUIDED")
    altitude: float | None = Field(None, gt=0, le=1000, description="take-off altitude, m above home")
    x: float | None = Field(None, description="goto target, scene metres east")
    y: float | None = Field(None, description="goto target, scene metres north")
    speed: float | None = Field(None, gt=0, le=50, description="m/s, for speed")
    confirm: bool = Field(False, description="kill needs this true: it force-disarms, even in the air")

    @model_validator(mode="after")
    def _complete(self) -> Command:
        needs = {"set_mode": ("mode",), "takeoff": ("altitude",), "goto": ("x", "y"), "speed": ("speed",)}
        missing = [name for name in needs.get(self.action, ()) if getattr(self, name) is None]
        if missing:
            raise ValueError(f"{self.action} needs {', '.join(missing)}")
        if self.action == "kill" and not self.confirm:
            raise ValueError("kill force-disarms the vehicle, even in the air: send confirm: true")
        return self


def mode_number(vehicle: VehicleState, name: str) -> int | None:
    mapping = mavutil.mode_mapping_bynumber(vehicle.mav_type) or {}
    for number, mode in mapping.items():
        if mode == name.upper():
            return number
    return None


def execute(link: Link, vehicle: VehicleState, command: Command, datum: Datum | None, now: float) -> str:
    """``now``: the receiver's clock, to tell whether the vehicle's companion is still heard."""
    sysid = vehicle.sysid
    action = command.action

    def set_mode(name: str) -> str:
        number = mode_number(vehicle, name)
        if number is None:
            return "unsupported"
        return link.command(sysid, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)

    if action == "abort":
        return set_mode(STOP_MODE.get(vehicle.kind, "LOITER"))
    if action == "rtl":
        return set_mode("RTL")
    if action == "set_mode":
        return set_mode(command.mode)
    if action == "land":
        return link.command(sysid, mavlink.MAV_CMD_NAV_LAND)
    if action in ("arm", "disarm"):
        return link.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if action == "arm" else 0.0)
    if action == "kill":
        return link.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_DISARM)
    if action == "takeoff":
        return link.command(sysid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, command.altitude)
    if action == "resume":
        if vehicle.has_companion(now):  # its agent on a companion computer: to the autopilot this would start AUTO
            return link.command(sysid, mavlink.MAV_CMD_MISSION_START, component=COMPANION)
        result = set_mode("AUTO")
        return result if result != "accepted" else link.command(sysid, mavlink.MAV_CMD_MISSION_START)
    if action == "speed":
        return link.command(sysid, mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, command.speed, -1)
    if action == "goto":
        if datum is None:
            return "denied"
        lat, lon = datum.to_global(command.x, command.y)
        return link.command_int(sysid, mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                [-1, mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, float("nan")],
                                int(round(lat * 1e7)), int(round(lon * 1e7)), float("nan"))
    raise ValueError(f"unknown action {action}")
