"""Operator actions, as the REST API and the page name them, turned into MAVLink for one vehicle.

Each returns the vehicle's COMMAND_ACK result as a word ("accepted",
"denied", ...) or raises ``LinkError`` when the vehicle never answered. What
"stop" means depends on the vehicle: a rover holds, a copter brakes, a plane
loiters. With an onboard agent, Pause, Take control and Continue go to the
agent (DO_PAUSE_CONTINUE to component 191): it holds the vehicle and waits,
or commands nothing more until handed back (then a goto goes to the
autopilot). ``refusal`` refuses before sending what cannot mean what its
name says (a resume of a mission that runs), and ``explain`` puts every
answer but "accepted" into words a person can act on.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, model_validator

from groundstation.link import Link
from groundstation.state import Fleet, VehicleState
from vehicle.mapping.memory_map import OCCUPIED_AT
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import AUTOPILOT, COMPANION, mavlink
from vehicle.protocol.modes import FORCE_DISARM, STOP_MODE, number_of
from vehicle.world.solids import solid_at

Action = Literal["abort", "kill", "rtl", "set_mode", "arm", "disarm", "takeoff", "land", "resume", "goto", "speed",
                 "auto", "pause", "continue", "take_control"]
WHY = {  # what a refusal means, when the vehicle said nothing more
    "denied": "the vehicle refused it in its present state",
    "temporarily rejected": "the vehicle cannot do it just now (busy, or not ready): try again in a moment",
    "unsupported": "this vehicle does not know this command",
    "failed": "the vehicle tried and failed",
    "cancelled": "the vehicle cancelled it",
}
GOTO_REACH = 1000.0  # m from home a goto may go when neither the vehicle's map nor a scene bounds its space
SCENE_MARGIN = 20.0  # m beyond the scene's bounds a goto may go
PROBE_ABOVE = 0.5  # m above the vehicle's height (a rover's: its ground) where a goto's target is looked at


class Command(BaseModel):
    """A command from the operator (JSON body of POST /api/vehicles/{sysid}/commands). Strict: a number
    given as a string, or as true, is refused rather than read as one."""

    model_config = ConfigDict(allow_inf_nan=False, strict=True)

    action: Action
    mode: str | None = Field(None, max_length=32, description="flight mode name for set_mode, e.g. GUIDED")
    altitude: float | None = Field(None, gt=0, le=1000, description="take-off altitude, m above home")
    x: float | None = Field(None, ge=-1e6, le=1e6, description="goto target, scene metres east")
    y: float | None = Field(None, ge=-1e6, le=1e6, description="goto target, scene metres north")
    speed: float | None = Field(None, gt=0, le=50, description="m/s, for speed")
    confirm: StrictBool = Field(False, description="kill needs this JSON true: it force-disarms, even in the air")

    @model_validator(mode="after")
    def _complete(self) -> Command:
        needs = {"set_mode": ("mode",), "takeoff": ("altitude",), "goto": ("x", "y"), "speed": ("speed",)}
        missing = [name for name in needs.get(self.action, ()) if getattr(self, name) is None]
        if missing:
            raise ValueError(f"{self.action} needs {', '.join(missing)}")
        if self.action == "kill" and not self.confirm:
            raise ValueError("kill force-disarms the vehicle, even in the air: send confirm: true")
        return self


def outside_space(fleet: Fleet, vehicle: VehicleState, x: float, y: float, scene=None) -> str | None:
    """Why a goto to (x, y) is refused before it is sent, or None. It must lie in the vehicle's own space (the
    square its agent maps), else in the scene give or take ``SCENE_MARGIN``, else within ``GOTO_REACH`` of
    its home."""
    geometry, home = vehicle.map_stream.geometry, vehicle.home
    if geometry is not None and home is not None:
        west, south = home[0] + geometry.origin[0], home[1] + geometry.origin[1]
        side = geometry.size / geometry.resolution
        if not (west <= x <= west + side and south <= y <= south + side):
            return (f"({x:.1f}, {y:.1f}) is outside vehicle {vehicle.sysid}'s space, "
                    f"x {west:.1f} to {west + side:.1f} and y {south:.1f} to {south + side:.1f}")
        return None
    if scene is not None and len(scene.faces):
        low, high = scene.bounds
        if not (low[0] - SCENE_MARGIN <= x <= high[0] + SCENE_MARGIN and
                low[1] - SCENE_MARGIN <= y <= high[1] + SCENE_MARGIN):
            return f"({x:.1f}, {y:.1f}) is more than {SCENE_MARGIN:.0f} m outside the scene"
        return None
    centre = home or (vehicle.x, vehicle.y)
    if centre[0] is not None and (x - centre[0]) ** 2 + (y - centre[1]) ** 2 > GOTO_REACH ** 2:
        return f"({x:.1f}, {y:.1f}) is more than {GOTO_REACH:.0f} m from vehicle {vehicle.sysid}'s home"
    if fleet.datum is None:
        return "no position is known yet to go from"
    return None


def blocked(fleet: Fleet, vehicle: VehicleState, x: float, y: float, scene=None) -> str | None:
    """Why a goto to (x, y) is refused before it is sent because nothing can stand there, or None: inside a
    closed solid of the scene at the vehicle's height, or on a cell its memory map holds occupied. Sent, such a
    target was accepted and then failed with "no known path"."""
    with fleet.lock:
        height = fleet.height(vehicle)
        grid = vehicle.map_grid()
        cell = None if grid is None else _cell_value(grid, x, y)
    if scene is not None and len(scene.faces):
        solid = solid_at(scene, x, y, height + PROBE_ABOVE)
        if solid is not None:
            return f"the target ({x:.1f}, {y:.1f}) is inside a building ({solid}): pick a point outside it"
    if cell is not None and cell >= OCCUPIED_AT:
        return (f"the target ({x:.1f}, {y:.1f}) is on an occupied cell of vehicle {vehicle.sysid}'s map: "
                "pick a point its map shows free or unknown")
    return None


def _cell_value(grid: tuple, x: float, y: float) -> int | None:
    """The map's value at (x, y) (``grid``: values, cells per metre, south-west corner), None off the map."""
    values, resolution, origin = grid
    row, col = math.floor((y - origin[1]) * resolution), math.floor((x - origin[0]) * resolution)
    inside = 0 <= row < values.shape[0] and 0 <= col < values.shape[1]
    return int(values[row, col]) if inside else None


def agent_of(vehicle: VehicleState, now: float):
    """The onboard agent's status when one speaks for the vehicle (on a companion, heard lately), else None."""
    return vehicle.agent if vehicle.agent is not None and vehicle.has_companion(now) else None


def refusal(vehicle: VehicleState, command: Command, now: float) -> str | None:
    """Why the command is refused before anything is sent because it cannot do what its name says, or None."""
    agent = agent_of(vehicle, now)
    action = command.action
    if action == "resume" and agent is not None and agent.state == "running":
        return ("the agent's mission is already running: there is nothing to resume. Pause holds it where it is; "
                "Take control hands it to you")
    if action == "take_control" and agent is None:
        return "no onboard agent commands this vehicle: you have control already"
    if action == "continue" and agent is not None and not agent.paused:
        return f"the agent's mission is {agent.state}, not paused: there is nothing to continue"
    return None


def note(vehicle: VehicleState, command: Command, now: float) -> str | None:
    """What an accepted command did that its answer alone does not say, in words."""
    agent = agent_of(vehicle, now)
    if _takes_control(vehicle, command, now):
        return ("the agent stopped and handed you control: the vehicle holds in GUIDED until you send it "
                "somewhere (Go here) or hand back (Continue)")
    if command.action == "take_control":
        return "the agent holds the vehicle and commands nothing more until you hand back (Continue)"
    if command.action == "pause":
        return "the vehicle holds where it is; Continue resumes the mission" if agent is not None else None
    return None


def _takes_control(vehicle: VehicleState, command: Command, now: float) -> bool:
    """GUIDED while the agent flies its mission (in GUIDED already: the mode alone would change nothing) takes
    control from the agent first."""
    agent = agent_of(vehicle, now)
    return (command.action == "set_mode" and command.mode.upper() == "GUIDED" and agent is not None
            and agent.state == "running")


def explain(result: str, said: list[str]) -> str | None:
    """Why a command was not accepted, in words: what the vehicle said about it (``said``: its warnings since
    the command went), else what its answer means. None when accepted."""
    if result == "accepted":
        return None
    if said:
        return "; ".join(said[-2:])
    word = result.split(" (")[0]
    return WHY.get(word, f"the vehicle answered {result}")


def fly_mission(link: Link, vehicle: VehicleState, set_mode) -> str:
    """The autopilot's own mission, in AUTO: armed first if it is not (a copter in GUIDED, as ArduPilot arms in
    no AUTO), then AUTO and MISSION_START to the autopilot, never to an agent. The first answer that is not
    "accepted" is the result, named by its step."""
    steps = []
    if not vehicle.armed:
        if vehicle.kind == "copter":
            steps.append(("GUIDED", lambda: set_mode("GUIDED")))
        steps.append(("arm", lambda: link.command(vehicle.sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)))
    steps += [("AUTO", lambda: set_mode("AUTO")),
              ("mission start", lambda: link.command(vehicle.sysid, mavlink.MAV_CMD_MISSION_START))]
    for name, step in steps:
        result = step()
        if result != "accepted":
            return f"{result} ({name})"
    return "accepted"


def _agent_flies(vehicle: VehicleState, now: float) -> bool:
    """An onboard agent flies a goto (planned round what its map knows) unless the operator took control."""
    return vehicle.has_companion(now) and not (vehicle.agent is not None and vehicle.agent.operator == "control")


def execute(link: Link, vehicle: VehicleState, command: Command, datum: Datum | None, now: float) -> str:
    """``now``: the receiver's clock, to tell whether the vehicle's companion is still heard."""
    sysid = vehicle.sysid
    action = command.action

    def set_mode(name: str) -> str:
        number = number_of(vehicle.mav_type, name)
        if number is None:
            return "unsupported"
        return link.command(sysid, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)

    if action == "abort":
        return set_mode(STOP_MODE.get(vehicle.kind, "LOITER"))
    if action == "rtl":
        return set_mode("RTL")
    if action == "set_mode" and _takes_control(vehicle, command, now):
        taken = link.command(sysid, mavlink.MAV_CMD_DO_PAUSE_CONTINUE, 0.0, 1.0, component=COMPANION)
        if taken != "accepted":
            return f"{taken} (take control)"
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
    if action in ("pause", "continue", "take_control"):  # to the agent if one flies, else to the autopilot
        to_agent = action == "take_control" or (vehicle.has_companion(now) and vehicle.agent is not None)
        params = {"pause": (0.0, 0.0), "take_control": (0.0, 1.0), "continue": (1.0, 0.0)}[action]
        return link.command(sysid, mavlink.MAV_CMD_DO_PAUSE_CONTINUE, *params,
                            component=COMPANION if to_agent else AUTOPILOT)
    if action == "resume":
        if vehicle.has_companion(now):  # its agent on a companion computer: to the autopilot this would start AUTO
            return link.command(sysid, mavlink.MAV_CMD_MISSION_START, component=COMPANION)
        result = set_mode("AUTO")
        return result if result != "accepted" else link.command(sysid, mavlink.MAV_CMD_MISSION_START)
    if action == "auto":
        return fly_mission(link, vehicle, set_mode)
    if action == "speed":
        return link.command(sysid, mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, command.speed, -1)
    if action == "goto":  # to its agent when it has one (which plans round what its map knows), else the autopilot
        if datum is None:
            return "denied"
        lat, lon = datum.to_global(command.x, command.y)
        return link.command_int(sysid, mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                [-1, mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, float("nan")],
                                int(round(lat * 1e7)), int(round(lon * 1e7)), float("nan"),
                                component=COMPANION if _agent_flies(vehicle, now) else AUTOPILOT)
    raise ValueError(f"unknown action {action}")
