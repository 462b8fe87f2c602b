"""The simulated flight controller as an onboard computer in the same process sees it.

``SimController`` implements the agent's flight-controller interface
(``vehicle.agent.controller``) over a ``Simulation``, with calls instead of
MAVLink, so experiments and sweeps run at full speed. It behaves as the MAVLink
implementation does: requests answer with the autopilot's MAV_RESULT, and
someone else's mode change or GUIDED target, or a request the autopilot
refused, is reported by ``took_over``.
The readings the simulation takes reach it through ``collect``.
"""

from __future__ import annotations

import math

from vehicle.protocol.frames import Navigation, Pose
from vehicle.protocol.geodesy import heading_of
from vehicle.protocol.mav import mavlink, refusal
from vehicle.protocol.mission import MissionItem, MissionProgress
from vehicle.protocol.modes import DISARMED
from vehicle.protocol.rangefinder import Reading
from vehicle.protocol.traffic import Traffic
from vehicle.sim.avoidance import MARGIN as AVOID_MARGIN
from vehicle.sim.simulation import Simulation
from vehicle.sim.team import Team

SOURCE = "companion"  # what the autopilot records as the source of the requests made here
MOVING = 0.05  # m/s: navigation asking for less is not moving anywhere


class SimController:
    def __init__(self, simulation: Simulation, team: Team | None = None, system_id: int = 1):
        """``team``: the team the simulation flies in, whose other vehicles ``traffic`` reports."""
        self.simulation = simulation
        self.team = team
        self.system_id = team.ids[team.simulations.index(simulation)] if team is not None else system_id
        self.autopilot = pilot = simulation.autopilot
        self.kind = simulation.kind
        self.datum = simulation.datum
        self.home = pilot.home
        self.radius = simulation.limits.radius
        self.brake = simulation.limits.accel
        self.avoid_margin = AVOID_MARGIN
        self.servo = simulation.servo
        self._readings: list[Reading] = []
        self._mode_changes = pilot.mode_changes
        self._overrides = pilot.overrides
        self._refused: str | None = None  # the latest request the autopilot refused, in words
        self._armed = pilot.armed  # as last looked at: a disarm in GUIDED is someone else's (a kill)

    def collect(self, readings: list[Reading]) -> None:
        """Readings the simulation took this step (the stepper hands them over)."""
        self._readings.extend(readings)

    # ---- observe ----------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return self.simulation.time

    @property
    def pose(self) -> Pose:
        return self.simulation.body.pose

    @property
    def speed(self) -> float:
        return self.simulation.body.speed

    @property
    def mode(self) -> str:
        return self.autopilot.mode

    @property
    def armed(self) -> bool:
        return self.autopilot.armed

    @property
    def flying(self) -> bool:
        return self.autopilot.flying

    @property
    def taking_off(self) -> bool:
        return self.autopilot.taking_off

    @property
    def navigation(self) -> Navigation:
        pilot = self.autopilot
        vx, vy = pilot.wanted
        heading = heading_of(vx, vy) if math.hypot(vx, vy) > MOVING else None
        destination = pilot.destination
        pose = self.simulation.body.pose
        reach = math.inf if destination is None else math.dist((pose.x, pose.y), destination)
        return Navigation(heading, reach)

    @property
    def blocked(self) -> bool:
        return self.autopilot.blocked

    @property
    def mission(self) -> MissionProgress:
        pilot = self.autopilot
        count = len(pilot.mission)
        return MissionProgress(pilot.current, count, pilot.mission_running, pilot.current >= count)

    def readings(self) -> list[Reading]:
        readings, self._readings = self._readings, []
        return readings

    def traffic(self) -> list[Traffic]:
        if self.team is None or len(self.team) == 1:
            return []
        return [other for other in self.team.traffic() if other.vehicle != self.system_id]

    def took_over(self) -> str | None:
        pilot = self.autopilot
        what = None
        if pilot.mode_changes != self._mode_changes:
            self._mode_changes = pilot.mode_changes
            if pilot.mode_source == "failsafe":
                what = f"failsafe switched to {pilot.mode}"
            elif pilot.mode_source != SOURCE:
                what = f"operator switched to {pilot.mode}"
        if pilot.overrides != self._overrides:
            self._overrides = pilot.overrides
            what = what or f"operator {pilot.override}"
        if self._armed and not pilot.armed and pilot.mode == "GUIDED":
            what = what or DISARMED
        self._armed = pilot.armed
        what, self._refused = what or self._refused, None
        return what

    def _answer(self, command: int, result: int, report: bool = True) -> int:
        """Pass the autopilot's answer on; a refusal is news (``report``), as over MAVLink (where unsupported is
        not)."""
        if report and result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_UNSUPPORTED):
            self._refused = refusal(command, result)
        return result

    # ---- act --------------------------------------------------------------------------------------
    def arm(self, report: bool = True) -> int:
        return self._answer(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, self.autopilot.arm(), report)

    def takeoff(self, altitude: float, report: bool = True) -> int:
        return self._answer(mavlink.MAV_CMD_NAV_TAKEOFF, self.autopilot.takeoff(altitude), report)

    def set_mode(self, name: str) -> int:
        result = self.autopilot.set_mode(name, source=SOURCE)
        self._mode_changes = self.autopilot.mode_changes
        return self._answer(mavlink.MAV_CMD_DO_SET_MODE, result)

    def goto(self, x: float, y: float, altitude: float | None = None) -> int:
        return self._answer(mavlink.MAV_CMD_DO_REPOSITION, self.autopilot.goto(x, y, altitude))

    def set_yaw(self, heading: float, relative: bool = False) -> int:
        return self._answer(mavlink.MAV_CMD_CONDITION_YAW, self.autopilot.set_yaw(heading, relative))

    def set_speed(self, speed: float) -> int:
        return self._answer(mavlink.MAV_CMD_DO_CHANGE_SPEED, self.autopilot.set_speed(speed))

    def set_servo(self, channel: int, pwm: int) -> int:
        return self._answer(mavlink.MAV_CMD_DO_SET_SERVO, self.autopilot.set_servo(channel, pwm))

    def hold(self) -> int:
        if self.autopilot.mode != "GUIDED" or not self.autopilot.armed:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        self.autopilot.hold_here()
        self.autopilot.clear_targets()
        return mavlink.MAV_RESULT_ACCEPTED

    def return_home(self) -> int:
        return self.set_mode("RTL")

    def land(self) -> int:
        return self.set_mode("LAND") if self.kind == "copter" else mavlink.MAV_RESULT_UNSUPPORTED

    def upload_mission(self, items: list[MissionItem]) -> int:
        self.autopilot.set_mission(items)
        return mavlink.MAV_RESULT_ACCEPTED

    def download_mission(self) -> list[MissionItem]:
        return list(self.autopilot.mission)

    def start_mission(self) -> int:
        return self._answer(mavlink.MAV_CMD_MISSION_START, self.autopilot.start_mission())
