"""``vehicle agent``: the onboard agent as a process of its own, on a companion computer beside an autopilot.

It connects to the flight controller (serial, TCP or UDP), identifies itself
as component 191 of the autopilot's system, waits until the autopilot is
ready, and flies the mission through ``MavlinkController`` on the autopilot's
clock: every ``monitor_period`` of ``time_boot_ms`` the agent steps. Its own
messages (``Companion``: heartbeat, map, path, state, texts) go to the
autopilot, which routes them to every ground station, and straight to the
``--gcs`` links. A ground station's MISSION_START addressed to component 191
resumes it. A message the agent drops (in the autopilot's name from elsewhere,
one request too many, one it fails on) is said, and the flight goes on.

A companion computer is a slow machine, and so may be the autopilot's: a gap
in the autopilot's heartbeat pauses the agent (it stops commanding), and once
the heartbeat is back the agent carries on by itself; both are said, to the
ground stations and on standard error (``--stay`` or not, nobody need press
Resume). An operator's takeover meanwhile still pauses it for good. A mission
that does not start within START_TIMEOUT of the agent's start (pre-arm checks
that never pass, an arm or take-off refused, an autopilot gone silent), or a
run that ends before it started, ends as ``error``, saying what held it up.

Readings come from the autopilot's DISTANCE_SENSOR / OBSTACLE_DISTANCE
(``--sensors fc``, sonars wired to a real vehicle), or (``--sensors scene``)
from the sonar cast into a VRML scene at the pose the autopilot reports, ten
times a second of its clock: then the agent also checks that trajectory
against the scene's triangles (a collision ends the run) and feeds the
readings to the autopilot as DISTANCE_SENSOR, as a sensor on the companion
would (ArduPilot's PRX1_TYPE 2 proximity).
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from vehicle import __version__
from vehicle.agent.agent import Agent, Phase
from vehicle.agent.companion import COMPONENT, Companion
from vehicle.agent.mavlink_controller import HEARTBEAT_LOST, FlightControllerError, MavlinkController
from vehicle.agent.settings import Settings
from vehicle.ctrl_c import reraise_ctrl_c
from vehicle.protocol import links
from vehicle.protocol.frames import Pose
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.rangefinder import distance_sensor
from vehicle.protocol.tlog import TlogWriter
from vehicle.world.scene import Scene

SONAR_RATE = 10.0  # Hz of the autopilot's clock
START_TIMEOUT = 180.0  # wall s from the agent's start to the mission's (ArduPilot's EKF alone takes ~45 s)
IDLE = 0.002  # wall s to wait when nothing came in
STEADY = 1.5  # wall s the autopilot's heartbeat is back before the agent carries on: the first after a stall may
# predate what the autopilot then took from its input (an operator's mode change sent meanwhile)
RADIUS = 0.3  # m, the vehicle body the agent plans around
CLEARANCE = 0.05  # m between the ground and the body when the vehicle stands


@dataclass
class AgentOptions:
    connect: str
    mission: str
    kind: str = "copter"
    settings: Settings = field(default_factory=Settings)
    waypoints: list[tuple[float, float]] | None = None
    scene: Scene | None = None
    sensors: str = "fc"  # "fc" | "scene"
    suite: str = "triple"
    gcs: list[str] = field(default_factory=list)
    datum: Datum = field(default_factory=Datum)
    log: str | None = None
    wait: bool = False  # wait for a ground station's MISSION_START before starting
    stay: bool = False  # after the mission, stay (a ground station's MISSION_START flies it again)
    connect_timeout: float = 60.0
    signing_key: bytes | None = None  # MAVLink 2 signing on every link: sign everything, refuse what is not signed
    start_timeout: float | None = None  # wall s from its start (with ``wait``, the operator's) to the mission's;
    # None: START_TIMEOUT
    radio_nodes: list[tuple[float, ...]] = field(default_factory=list)  # fixed radio nodes, scene metres (rti)


class OnboardAgent:
    def __init__(self, options: AgentOptions):
        self.options = options
        self.log = TlogWriter(options.log) if options.log else None
        key = options.signing_key
        self.conn = links.connect(options.connect, 1, COMPONENT, key)  # the system id is the autopilot's, once heard
        self.gcs = [links.connect(url, 1, COMPONENT, key) for url in options.gcs]
        self.sonars = self.collider = None
        ground = None
        servo = None
        if options.sensors == "scene":
            if options.scene is None:
                raise ValueError("--sensors scene needs --scene")
            from vehicle.world.collision import Collider
            from vehicle.world.raycast import RayCaster
            from vehicle.world.sonar import SonarArray
            from vehicle.world.suites import sensor_suite

            caster = RayCaster(options.scene)
            ground = self.ground = caster.ground_height
            self.sonars = SonarArray(sensor_suite(options.suite, options.kind), caster)
            servo = next((s.servo for s in self.sonars.sensors if s.servo is not None), None)
            self.collider = Collider(options.scene, RADIUS, ignore_walkable=options.kind == "rover")
        self.fc = MavlinkController(self.conn, options.kind, options.datum, ground, radius=RADIUS, servo=servo,
                                    use_fc_sensors=options.sensors == "fc", extra_links=tuple(self.gcs))
        self.fc.radio_nodes = [tuple(p[:2]) for p in options.radio_nodes]
        self.agent: Agent | None = None
        self.companion: Companion | None = None
        self.collision = None
        self.distance = 0.0
        self._last_xyz: tuple[float, float, float] | None = None

    # ---- the run ------------------------------------------------------------------------------------
    def run(self, duration: float | None = None, say=print) -> dict:
        """Connect, wait for the autopilot, fly; returns the result (as ``vehicle experiment`` does)."""
        options, fc = self.options, self.fc
        started = time.monotonic()
        fc.connect(options.connect_timeout)
        say(f"agent: {options.kind} {fc.sysid} at home {fc.home[0]:.1f}, {fc.home[1]:.1f}; mission "
            f"{options.mission}; readings from {'the scene' if self.sonars else 'the flight controller'}")
        self.agent = Agent(fc, options.mission, options.settings, options.waypoints, autostart=False,
                           log=lambda text: say(f"agent: {text.removeprefix('Agent: ')}"), scene=options.scene)
        self.companion = Companion(self.agent, fc.sysid, start=time.time())
        fc.handler = self.companion.handle
        fc.avoid_margin = self._avoid_margin()
        fc.prefer_speed(options.settings.speed)
        begun = fc.time
        next_step = next_reading = fc.time
        trying_since = None if options.wait else time.monotonic()  # the start deadline runs from here
        allowed = options.start_timeout or START_TIMEOUT
        watch = links.LinkWatch([fc.conn, *fc.extra_links])
        outcome = reason = None
        period = options.settings.monitor_period
        while outcome is None:
            now = time.time()
            came = fc.pump()
            self.companion.hear(fc.take_radio())
            for line in watch.changes():
                say(f"agent: {line}")
            self._record(came, now)
            if (news := fc.news()) is not None:  # spoofed, flooded or failing messages: the agent flies on
                self.agent.say(f"Agent: {news}", mavlink.MAV_SEVERITY_WARNING)
            if self.sonars is not None and fc.time >= next_reading:
                next_reading = fc.time + 1.0 / SONAR_RATE
                self._sense(now)
            if self.collision is not None:
                outcome, reason = "collision", self.collision.describe()
                break
            agent = self.agent
            self._mind_the_gap()  # right after the pump: a step that kept the loop busy is no gap
            if agent.phase is Phase.WAITING and not options.wait and not fc.lost:
                if fc.mode != "GUIDED":
                    fc.set_mode("GUIDED")
                if fc.ready() and fc.mode == "GUIDED":
                    agent.start()
            if trying_since is None and agent.phase is not Phase.WAITING:  # with --wait: the operator's start
                trying_since = time.monotonic()
            if not agent.mission_began and trying_since is not None and time.monotonic() - trying_since > allowed:
                fc.hold()
                outcome, reason = "error", self._not_started(f"the mission did not start within {allowed:g} s: "
                                                             f"{self._holdup()}")
                break
            try:
                if fc.time >= next_step:
                    next_step = max(next_step + period, fc.time)
                    agent.step()
                    if agent.done and not options.stay:
                        outcome, reason = agent.outcome, agent.reason
            except Exception as error:  # noqa: BLE001 - a bug in the agent: the vehicle must not fly on unwatched
                reraise_ctrl_c(error)
                outcome, reason = "error", self._failed(error, say)
                break
            self._broadcast(self.companion.tick(now), now)
            if fc.time - begun > options.settings.time_limit + 120 and not options.stay:
                outcome, reason = "timeout", f"time limit of {options.settings.time_limit:g} s reached"
            if duration is not None and time.monotonic() - started > duration:
                outcome, reason = outcome or "stopped", reason or "stopped after the given duration"
            if not came:
                time.sleep(IDLE)
        if outcome not in ("error", "collision") and not self.agent.mission_began:  # a timeout, or --duration
            outcome, reason = "error", self._not_started(f"the mission never started ({self._holdup()}); {reason}")
        self._broadcast(self.companion.final(), time.time())
        result = self.result(outcome, reason, begun, time.monotonic() - started)
        self.close()
        return result

    def _mind_the_gap(self) -> None:
        """A gap in the autopilot's heartbeat (a busy machine, here or there) pauses the agent; once the heartbeat
        is back, the agent carries on by itself (``Agent.pause``'s ``until``). Said both times."""
        fc, agent = self.fc, self.agent
        if not fc.lost or agent.paused or agent.phase in (Phase.WAITING, Phase.DONE):
            return
        since = fc.last_heard

        def back() -> str | None:
            if fc.lost or time.monotonic() - fc.back_since < STEADY:
                return None
            return f"the flight controller's heartbeat is back after {fc.back_since - since:.1f} s"

        agent.pause(f"lost the flight controller's heartbeat for {HEARTBEAT_LOST:g} s; not commanding until it is back",
                    until=back)

    def _not_started(self, reason: str) -> str:
        """The run ends before the mission started: an error, said to the operator too."""
        self.agent.say(f"Agent: {reason}", mavlink.MAV_SEVERITY_ERROR)
        return reason

    def _holdup(self) -> str:
        """What kept the mission from starting, in words."""
        fc, agent = self.fc, self.agent
        if agent.paused:
            return f"paused, {agent.pause_reason}"
        if fc.lost:
            return f"no heartbeat from the flight controller for {time.monotonic() - fc.last_heard:.0f} s"
        if agent.phase is Phase.WAITING:
            if self.options.wait:
                return "it waited for a ground station's start (--wait)"
            if fc.mode != "GUIDED":
                return f"the flight controller stayed in {fc.mode}, not GUIDED"
            return "the flight controller's pre-arm checks never passed"
        if agent.phase is Phase.PREFLIGHT and agent.refused:
            return f"{agent.refused}, asking again"
        if agent.phase is Phase.TAKEOFF:
            return f"the take-off did not reach {self.options.settings.altitude:g} m"
        return f"still in {agent.phase.value}"

    def _failed(self, error: Exception, say) -> str:
        """The agent failed (a bug): the vehicle is told to hold, the operator why (and standard error the
        traceback); the run ends with this reason. Its last target would otherwise run on with nobody watching."""
        reason = f"the agent failed ({type(error).__name__}: {error}); the vehicle holds"
        say("agent: " + "".join(traceback.format_exception(error)).rstrip())
        self.fc.hold()
        self.agent.say(f"Agent: failed ({type(error).__name__}: {error}); holding", mavlink.MAV_SEVERITY_CRITICAL)
        return reason

    def _avoid_margin(self) -> float:
        """How far the autopilot's own obstacle avoidance keeps from echoes (AVOID_MARGIN when AVOID_ENABLE)."""
        values = {}
        for name in ("AVOID_ENABLE", "AVOID_MARGIN"):
            self.fc.send(mavlink.MAVLink_param_request_read_message(self.fc.sysid, 1, name.encode(), -1))
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and len(values) < 2:
            for message in self.fc.pump():
                if message.get_type() == "PARAM_VALUE":
                    values[message.param_id.rstrip("\0")] = message.param_value
            time.sleep(IDLE)
        return float(values.get("AVOID_MARGIN", 0.0)) if values.get("AVOID_ENABLE", 0) else 0.0

    def _sense(self, now: float) -> None:
        """Cast the sonar at the pose the autopilot reports; check the way there against the scene."""
        fc = self.fc
        pose = self._body(fc.pose)
        here = pose.xyz()
        if self._last_xyz is not None:
            self.distance += math.dist(self._last_xyz, here)
            contact = self.collider.sweep(np.array(self._last_xyz), np.array(here))
            if contact is not None:
                self.collision = contact
                fc.hold()
                self.agent.say(f"Crash: {contact.describe()}", mavlink.MAV_SEVERITY_CRITICAL)
        self._last_xyz = here
        readings = self.sonars.read(pose, fc.time)
        fc.collect(readings)
        ms = int(fc.time * 1000)
        self._broadcast([distance_sensor(r, ms) for r in readings], now, to_ground=False)

    def _body(self, reported: Pose) -> Pose:
        """Where the body is in the scene: the autopilot's height is that of the vehicle resting on its feet (0
        on the ground at home), so the body's centre sits a radius and a clearance higher; a rover rides on the
        scene's ground, of which the autopilot knows nothing."""
        z = reported.z if self.options.kind == "copter" else self.ground(reported.x, reported.y)
        return Pose(reported.x, reported.y, z + RADIUS + CLEARANCE, reported.yaw, reported.pitch, reported.roll)

    def _broadcast(self, messages: list, now: float, to_ground: bool = True) -> None:
        links = [self.conn, *self.gcs] if to_ground else [self.conn]
        for message in messages:
            packet = pack(message, self.conn.mav)
            for link in links:
                try:
                    link.write(packet)
                except OSError:
                    continue
            if self.log is not None:
                self.log.write(packet, now)

    def _record(self, messages: list, now: float) -> None:
        if self.log is not None:
            for message in messages:
                self.log.write(message.get_msgbuf(), now)

    def result(self, outcome: str, reason: str, begun: float, wall: float) -> dict:
        agent = self.agent
        return {"mission": self.options.mission, "vehicle": self.options.kind, "sensors": self.options.sensors,
                "outcome": outcome, "reason": reason, "version": __version__,
                "detections": agent.map.detections if agent else 0,
                "cells_ever_hit": agent.map.cells_ever_hit if agent else 0,
                "resolution": self.options.settings.resolution, "sim_time_s": round(self.fc.time - begun, 3),
                "distance_m": round(self.distance or (agent.monitor.distance_travelled if agent else 0.0), 2),
                "flight_controller_problems": self.fc.problems, "wall_time_s": round(wall, 3),
                "messages": list(agent.messages)[-20:] if agent else []}

    def close(self) -> None:
        for link in (self.conn, *self.gcs):
            link.close()
        if self.log is not None:
            self.log.close()


def run_agent(options: AgentOptions, duration: float | None = None, say=print) -> dict:
    """One flight of the onboard agent; a flight controller that cannot be flown is an ``error`` outcome."""
    try:
        agent = OnboardAgent(options)
    except (OSError, ValueError) as error:
        return {"mission": options.mission, "outcome": "error", "reason": str(error)}
    try:
        return agent.run(duration, say)
    except FlightControllerError as error:
        agent.close()
        return {"mission": options.mission, "outcome": "error", "reason": str(error)}
