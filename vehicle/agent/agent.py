"""The onboard agent: gets the vehicle ready, runs the monitor and the mission, and brings it home.

Stepped once per ``monitor_period`` of simulated time, it reads the monitor's
observation and commands the autopilot. Its phases run one way: preflight ->
take-off -> mission -> homing -> landing -> done. A mission that completes or
gives up, a vehicle that leaves the allowed space, or a time budget that
runs low all lead home. An operator's mode change pauses the agent; AUTO with
MISSION_START hands control back to it (see ``resume``).
"""

from __future__ import annotations

import math
from enum import StrEnum

from vehicle.agent.missions import mission_class
from vehicle.agent.missions.base import Context, Status
from vehicle.agent.missions.routines import Travel
from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.geodesy import heading_of
from vehicle.protocol.modes import Kind
from vehicle.sim.autopilot import Autopilot
from vehicle.sim.sensors import Reading, Servo

HOME_TOLERANCE = 0.5  # m
SETTLED = 0.1  # m/s: slower than this counts as at rest
BLOCKED_FOR = 1.0  # s held back by avoidance before the monitor treats it as an obstacle too close
RESERVE = 60.0  # s kept for scans, detours and landing on the way home (at most a sixth of the time limit)


class Phase(StrEnum):
    WAITING = "waiting"  # on the ground, for a start from the operator
    PREFLIGHT = "preflight"
    TAKEOFF = "takeoff"
    MISSION = "mission"
    HOMING = "homing"
    LANDING = "landing"
    DONE = "done"


class Agent:
    def __init__(self, vehicle: Autopilot, mission: str, settings: Settings, radius: float,
                 waypoints: list[tuple[float, float]] | None = None, autostart: bool = True,
                 servo: Servo | None = None):
        self.vehicle = vehicle
        self.settings = settings
        home = (vehicle.home[0], vehicle.home[1])
        self.map = MemoryMap(home, settings.space_size, settings.resolution)
        self.monitor = Monitor(settings, self.map, home, radius, brake=vehicle.body.limits.accel)
        self.messages: list[str] = []
        self.ctx = Context(vehicle, self.map, self.monitor, settings, home, radius, waypoints, say=self.say,
                           servo=servo)
        self.mission_name = mission
        self.mission = mission_class(mission)(self.ctx)
        self.phase = Phase.PREFLIGHT if autostart else Phase.WAITING
        self.outcome: str | None = None  # "finished" | "stopped" once the mission ends
        self.reason = ""
        self.paused = False
        self._travel: Travel | None = None
        self._settling = False
        self._blocked_since: float | None = None
        self._mode_changes = vehicle.mode_changes

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    def say(self, text: str) -> None:
        self.messages.append(text)
        self.vehicle._say(text)

    def collect(self, readings: list[Reading]) -> None:
        self.monitor.collect(readings)

    # ---- operator takeover --------------------------------------------------------------------
    def _operator_took_over(self) -> bool:
        changed = self.vehicle.mode_changes != self._mode_changes and self.vehicle.mode_source != "agent"
        self._mode_changes = self.vehicle.mode_changes
        return changed

    def start(self) -> bool:
        """Start the mission (the operator's start, or again after one ended). False if one is running."""
        if self.phase not in (Phase.WAITING, Phase.DONE):
            return False
        if self.phase is Phase.DONE:
            self.mission = mission_class(self.mission_name)(self.ctx)
            self.outcome, self.reason, self._travel = None, "", None
        self.paused = False
        self.ctx.started = self.ctx.time
        self.phase = Phase.PREFLIGHT
        self._mode_changes = self.vehicle.mode_changes
        return True

    def take_over(self, what: str) -> None:
        """An operator steered the vehicle directly (a GUIDED target, a yaw): pause the mission."""
        if self.phase not in (Phase.WAITING, Phase.DONE) and not self.paused:
            self.paused = True
            self.say(f"Agent: paused, operator {what}")

    def resume(self) -> bool:
        """Hand control back to the agent (the operator's AUTO + MISSION_START). False if not paused."""
        if not self.paused:
            return False
        self.paused = False
        self._mode_changes = self.vehicle.mode_changes  # the operator's AUTO is the hand-back, not a takeover
        self.say("Agent: resuming mission")
        if self.phase is Phase.HOMING or (self.phase is Phase.MISSION and self.mission.mode == "GUIDED"):
            self._set_mode("GUIDED")
        if self.phase is Phase.MISSION:
            self.mission.resume()
        if self._travel is not None:
            self._travel.resume()
        return True

    def _set_mode(self, mode: str) -> None:
        self.vehicle.set_mode(mode, source="agent")
        self._mode_changes = self.vehicle.mode_changes

    # ---- the step -----------------------------------------------------------------------------
    def step(self, now: float) -> None:
        ctx = self.ctx
        ctx.time = now
        x, y = ctx.position
        wanted = self.vehicle.wanted
        travel = heading_of(*wanted) if math.hypot(*wanted) > 0.05 else None
        destination = self.vehicle.destination
        reach = math.inf if destination is None else math.dist((x, y), destination)
        observation = self.monitor.observe(now, x, y, travel, self.vehicle.body.speed, reach)
        ctx.observation = observation
        if self._operator_took_over() and self.phase not in (Phase.DONE, Phase.WAITING):
            self.paused = True
            self.say(f"Agent: paused, operator switched to {self.vehicle.mode}")
        if self.paused or self.phase in (Phase.DONE, Phase.WAITING):
            return
        if self.vehicle.blocked:
            self._blocked_since = now if self._blocked_since is None else self._blocked_since
        else:
            self._blocked_since = None
        if self._blocked_since is not None and now - self._blocked_since >= BLOCKED_FOR:
            observation.too_close = True
            self._blocked_since = None
        getattr(self, f"_{self.phase.value}")(now)

    def _preflight(self, now: float) -> None:
        vehicle = self.vehicle
        if self.mission.mode == "AUTO":
            self.mission.begin()
            self._set_mode("AUTO")
            vehicle.arm()
            if vehicle.mission_running:
                self.phase = Phase.MISSION
                return
            if vehicle.start_mission() == 0:
                self.phase = Phase.MISSION
            return
        self._set_mode("GUIDED")
        vehicle.arm()
        if self.vehicle.kind is Kind.ROVER or (vehicle.flying and not vehicle.taking_off):
            self._start_mission()
            return
        if not vehicle.taking_off:
            vehicle.takeoff(self.settings.altitude)
        self.phase = Phase.TAKEOFF

    def _takeoff(self, now: float) -> None:
        if self.vehicle.flying and not self.vehicle.taking_off:
            self._start_mission()

    def _start_mission(self) -> None:
        self.phase = Phase.MISSION
        self.say(f"Mission {self.mission.name}: start")
        self.mission.begin()

    def _mission(self, now: float) -> None:
        observation = self.ctx.observation
        if observation.outside:
            self._end_mission(Status.STOPPED, "left the allowed space around home")
            return
        if observation.too_close:
            status = self.mission.too_close()
        elif self.ctx.time_left < self._time_home() and self.mission.mode == "GUIDED":
            status = self.mission.out_of_time()
        else:
            status = self.mission.step()
        if status is not Status.RUNNING:
            self._end_mission(status, self.mission.reason)

    def _time_home(self) -> float:
        reserve = min(RESERVE, self.settings.time_limit / 6)
        return 2.0 * self.ctx.distance_to(self.ctx.home) / self.settings.speed + reserve

    def _end_mission(self, status: Status, reason: str) -> None:
        self.outcome = "finished" if status is Status.DONE else "stopped"
        self.reason = reason or ("mission complete" if status is Status.DONE else "stopped")
        self.say(f"Mission {self.mission.name}: {self.outcome} ({self.reason}); going home")
        if self.vehicle.mode != "GUIDED":
            self._set_mode("GUIDED")
        self.mission.stop()
        self._travel = Travel(self.ctx, self.ctx.home, HOME_TOLERANCE, relax=True)
        self._settling = True
        self.phase = Phase.HOMING

    def _homing(self, now: float) -> None:
        if self._settling:  # come to rest where the mission ended before setting off home
            if self.vehicle.body.speed > SETTLED:
                return
            self._settling = False
        travel = self._travel
        status = travel.too_close() if self.ctx.observation.too_close else travel.step()
        if status is Status.RUNNING:
            return
        if status is Status.STOPPED:
            self.say(f"Homing: {travel.reason}; holding position")
            self.outcome = "stopped"
            self.reason = f"{self.reason}; could not get home: {travel.reason}"
            self.mission.stop()
            self.phase = Phase.DONE
            return
        if self.vehicle.kind is Kind.COPTER:
            self._set_mode("LAND")
            self.phase = Phase.LANDING
        else:
            self._set_mode("HOLD")
            self.phase = Phase.DONE

    def _landing(self, now: float) -> None:
        if not self.vehicle.armed:
            self.phase = Phase.DONE
