"""The onboard agent: gets the vehicle ready, runs the monitor and the mission, and brings it home.

Stepped once per ``monitor_period`` of the flight controller's time, it reads
the monitor's observation and commands the vehicle through its flight
controller (``vehicle.agent.controller``), never anything else. Its phases run
one way: preflight -> take-off -> mission -> homing -> landing -> done. A
mission that completes or gives up, a vehicle that leaves the allowed space,
or a time budget that runs low all lead home. Someone else taking over (a
mode change the agent did not make, another ground station's target) pauses
the agent; ``resume`` hands control back to it. A pause for a cause that ends
by itself (a gap in the autopilot's heartbeat) lifts itself once it is over,
unless someone took over meanwhile. The operator's "Go here"
(``go_to``) pauses the mission too, and the agent flies there along a path
planned on its map, refusing a target it knows to be inside an obstacle.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from enum import StrEnum

from vehicle.agent.controller import FlightController
from vehicle.agent.missions import mission_class
from vehicle.agent.missions.base import Context, Status
from vehicle.agent.missions.routines import Travel
from vehicle.agent.monitor import RIDE_HEIGHT, Monitor
from vehicle.agent.settings import Settings
from vehicle.agent.traffic import CLEAR_FOR, GiveWay, column
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.mav import ACCEPTED, mavlink, refusal
from vehicle.protocol.modes import Kind

HOME_TOLERANCE = 0.5  # m
NEAR_SIDE = 0.5  # m: how far towards the vehicle Go here looks for a spot the body fits at, when not at the target
NEAR_SIDE_STEP = 0.1  # m between the distances tried, nearest first, ...
NEAR_SIDE_BEARINGS = 5  # ... each on this many bearings within NEAR_SIDE_ARC of the way to the vehicle
NEAR_SIDE_ARC = math.radians(60.0)
SETTLED = 0.1  # m/s: slower than this counts as at rest
SETTLE_OVER_HOME = 10.0  # s a copter waits at most to come to rest over home before it lands (a gusty day)
OVER_HOME = 0.15  # m from home within which a copter at rest counts as over it
BLOCKED_FOR = 1.0  # s held back by avoidance before the monitor treats it as an obstacle too close
RESERVE = 60.0  # s kept for scans, detours and landing on the way home (at most a sixth of the time limit)
MESSAGES_KEPT = 200
# An arming or a take-off the autopilot refuses is asked for again, PREFLIGHT_RETRY s (its clock) later, up to
# PREFLIGHT_TRIES times before the agent pauses: one refusal is not an autopilot's last word (a loaded ArduCopter's
# pre-arm checks flicker, and it disarms a copter left idle on the ground, after which it fails the take-off)
PREFLIGHT_TRIES = 3
PREFLIGHT_RETRY = 2.0


class Phase(StrEnum):
    WAITING = "waiting"  # on the ground, for a start from the operator
    PREFLIGHT = "preflight"
    TAKEOFF = "takeoff"
    MISSION = "mission"
    HOMING = "homing"
    LANDING = "landing"
    DONE = "done"


class Agent:
    def __init__(self, fc: FlightController, mission: str, settings: Settings,
                 waypoints: list[tuple[float, float]] | None = None, autostart: bool = True,
                 log: Callable[[str], None] | None = None, scene=None):
        """``log``: where the agent's messages are also written (a companion's standard error); ``scene``: the
        world it was given, if any (a MAVLink agent's ``--scene``)."""
        self.fc = fc
        self.log = log
        self.settings = settings
        home = (fc.home[0], fc.home[1])
        self.map = MemoryMap(home, settings.space_size, settings.resolution)
        height = fc.radius + RIDE_HEIGHT if fc.kind is Kind.ROVER else None  # a copter's ground is unknown
        self.monitor = Monitor(settings, self.map, home, fc.radius, brake=fc.brake, height=height, say=self.say)
        self.messages: deque[str] = deque(maxlen=MESSAGES_KEPT)
        self.outbox: deque[tuple[int, str]] = deque(maxlen=MESSAGES_KEPT)  # (severity, text) for the wire
        self.ctx = Context(fc, self.map, self.monitor, settings, waypoints, say=self.say, scene=scene)
        self.mission_name = mission
        self.mission = mission_class(mission)(self.ctx)
        self.phase = Phase.PREFLIGHT if autostart else Phase.WAITING
        self.outcome: str | None = None  # "finished" | "stopped" once the mission ends
        self.reason = ""
        self.paused = False
        self.pause_reason = ""
        self.operator = ""  # "pause" (the operator's Pause) or "control" (the operator took control) while paused
        self._hold_due = False  # the operator's Pause or Take control: hold at the next step
        self.mission_began = False  # the mission itself started (after the take-off), once at least
        self._until: Callable[[], str | None] | None = None  # a passing pause's end, in words once it is over
        self._paused_since: float | None = None  # when the mission's clock stopped for a pause
        self._travel: Travel | None = None
        self._errand: Travel | None = None  # the operator's "Go here", flown while the mission is paused
        self._over_home: float | None = None  # since when a copter back home has been coming to rest to land
        self._settling = False
        self._blocked_since: float | None = None
        self._clear_below: float | None = None  # since when no team-mate is below a landing held for one
        self._relaunch: Phase | None = None  # the phase to go back to after taking off again on a resume
        self.give_way = GiveWay(self.ctx, self._after_giving_way)  # to team-mates (none alone)
        self._speed_sent = settings.speed  # the autopilot's speed as last set (``Context.speed``)
        self._refusals = 0  # of the arming or the take-off, since the preflight began
        self.refused = ""  # the last of them, in words, while the agent asks again
        self._ask_again_at = -math.inf  # when to ask for them again after a refusal

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.messages.append(text)
        self.outbox.append((severity, text))
        if self.log is not None:
            self.log(text)

    # ---- starting, pausing, resuming ----------------------------------------------------------
    def start(self) -> bool:
        """Start the mission (the operator's start, or again after one ended). False if one is running."""
        if self.phase not in (Phase.WAITING, Phase.DONE):
            return False
        if self.phase is Phase.DONE:
            self.mission = mission_class(self.mission_name)(self.ctx)
            self.outcome, self.reason, self._travel = None, "", None
        self.paused = False
        self.pause_reason = ""
        self.operator = ""
        self._hold_due = False
        self._until = None
        self._errand = None
        self._paused_since = None
        self.ctx.started = self.ctx.time = self.fc.time
        self.phase = Phase.PREFLIGHT
        self._ask_afresh()
        self.fc.took_over()  # what the operator did to get here (GUIDED, arm) is no takeover
        return True

    def hold_for_operator(self, control: bool) -> str | None:
        """The operator's Pause (``control`` False: hold where it is, Continue resumes) or Take control (the agent
        holds the vehicle once, then commands nothing until handed back). Why not, or None."""
        wanted = "control" if control else "pause"
        if self.phase in (Phase.WAITING, Phase.DONE):
            state = "waiting for a start" if self.phase is Phase.WAITING else f"{self.outcome or 'ended'}"
            return f"the agent's mission is not running ({state}): nothing to {'take over' if control else 'pause'}"
        if self.paused and self.operator == wanted:
            return "the operator has control already" if control else "the mission is paused already"
        if self._errand is not None:
            self._errand = None
            self.ctx.planned_path = []
        self._stop_clock()
        self.paused = True
        self.operator = wanted
        self._until = None
        self._hold_due = True
        self.pause_reason = ("the operator has control: the agent commands nothing until handed back" if control
                             else "paused by the operator: holding here until Continue")
        self.say(f"Agent: {self.pause_reason}", mavlink.MAV_SEVERITY_NOTICE)
        return None

    def _hold_here(self) -> None:
        """The operator's Pause or Take control: stop where it is (an AUTO mission: in GUIDED)."""
        self._hold_due = False
        if self.fc.mode == "AUTO":
            self._set_mode("GUIDED")
        self.fc.hold()
        self.fc.took_over()  # its own mode change is no takeover

    def resume(self) -> bool:
        """Hand control back to the agent (the operator's resume). False if not paused."""
        if not self.paused:
            return False
        self.operator = ""
        self._hold_due = False
        if self._errand is not None:  # resumed on the way to the operator's target: the mission goes first
            self._errand = None
            self.ctx.planned_path = []
        self.fc.took_over()  # the operator's own switch back is the hand-back, not a takeover
        self._carry_on_after_pause("Agent: resuming mission", own_mode=True)
        return True

    def _carry_on_after_pause(self, said: str, own_mode: bool) -> None:
        """Take up again whatever the pause interrupted; with ``own_mode`` in the agent's own mode (after an
        operator's resume; after a passing pause the mode is still the agent's, or someone took over)."""
        self.paused = False
        self.operator = ""
        self.pause_reason = ""
        self._until = None
        self._restart_clock()
        self._ask_afresh()
        self.say(said)
        if self._down_meanwhile():  # an operator's RTL, LAND or kill brought it down or disarmed it: up again first
            self._relaunch = self.phase
            self.phase = Phase.PREFLIGHT
            return
        if self.phase is Phase.TAKEOFF:  # the take-off was cut short: from the start (GUIDED, arm, climb)
            self.phase = Phase.PREFLIGHT
            return
        if own_mode and (self.phase is Phase.HOMING
                         or (self.phase is Phase.MISSION and self.mission.mode == "GUIDED")):
            self._set_mode("GUIDED")
        if self.phase is Phase.MISSION:
            self.mission.resume()
        if self._travel is not None:
            self._travel.resume()

    def _stop_clock(self) -> None:
        """A pause stops the mission's clock: the time limit is for flying the mission, and an operator who
        held the vehicle for twenty minutes, then resumed, saw it give up at once, its time used."""
        if not self.paused:
            self._paused_since = self.ctx.time

    def _restart_clock(self) -> None:
        if self._paused_since is not None:
            self.ctx.started += self.ctx.time - self._paused_since
            self._paused_since = None

    def _down_meanwhile(self) -> bool:
        return (self.phase in (Phase.MISSION, Phase.HOMING)
                and not (self.fc.armed and (self.fc.kind is Kind.ROVER or self.fc.flying)))

    def pause(self, reason: str, until: Callable[[], str | None] | None = None) -> None:
        """Stop commanding until resumed: someone took over, or the flight controller refused a command.
        Said once: several requests sent before the pause may be refused for the same reason.

        ``until``: the pause passes by itself (the flight controller went silent, on a busy machine):
        ``until()`` says in words that its cause is over (None while it lasts), and the agent carries on by
        itself. A pause for good (an operator's takeover) meanwhile stays one."""
        if self.paused and reason == self.pause_reason:
            return
        self._stop_clock()
        self.paused = True
        self.pause_reason = reason
        self._until = until
        self.say(f"Agent: paused, {reason}", mavlink.MAV_SEVERITY_WARNING)

    def _passed(self) -> bool:
        """A passing pause whose cause is over is lifted (and said); True then."""
        over = self._until() if self._until is not None else None
        if over is None:
            return False
        self._carry_on_after_pause(f"Agent: {over}; resuming mission", own_mode=False)
        return True

    def go_to(self, point: tuple[float, float]) -> str | None:
        """The operator's "Go here": pause the mission and fly to ``point`` around what the map knows (where the
        body does not fit beside a known obstacle, to the nearest spot towards the vehicle where it does).
        Returns why it is refused, or None when the vehicle is on its way."""
        fc, ctx = self.fc, self.ctx
        where = place(point)
        if not ctx.inside(point, margin=0.5):
            return f"{where} is outside the allowed space around home"
        target = point if ctx.is_clear(point, padding=0.0) else self._near_side(point)
        if target is None:
            return f"{where} is inside a known obstacle"
        if not fc.armed or (fc.kind is Kind.COPTER and not fc.flying):
            return "not flying: arm and take off first"
        if self.operator == "control":
            return "the operator has control: hand back to the agent first"
        self.operator = ""
        self._errand = Travel(ctx, target, HOME_TOLERANCE)
        ctx.planned_path = []  # the way to where it was going is not the way there
        self._stop_clock()
        self.paused = True
        self.pause_reason = f"going to {where} for the operator"
        self._until = None
        if fc.mode != "GUIDED":
            self._set_mode("GUIDED")
        fc.took_over()  # the operator's own command is no takeover
        if target == point:
            self.say(f"Go here: on the way to {where}")
        else:
            self.say(f"Go here: the body does not fit at {where} beside a known obstacle; on the way to "
                     f"{place(target)}, {math.dist(point, target):.1f} m towards here")
        return None

    def _near_side(self, point: tuple[float, float]) -> tuple[float, float] | None:
        """The nearest spot within NEAR_SIDE of ``point`` and NEAR_SIDE_ARC of the way to the vehicle where the body
        fits; None if there is none. A target beside what the map holds (a cell a far echo marked at its cone's
        edge, a wall's face) is reached as near as the body goes, from the vehicle's side; one just behind a
        wall's face has no such spot (they all lie as near the face), and is refused."""
        x, y = self.ctx.position
        towards = math.atan2(y - point[1], x - point[0])
        turns = sorted((NEAR_SIDE_ARC * (2 * b / (NEAR_SIDE_BEARINGS - 1) - 1) for b in range(NEAR_SIDE_BEARINGS)),
                       key=abs)
        distances = [k * NEAR_SIDE_STEP for k in range(1, round(NEAR_SIDE / NEAR_SIDE_STEP) + 1)]
        found = self.ctx.nearest_clear(point, distances, [towards + turn for turn in turns], padding=0.0)
        return None if found is None else found[0]

    def _run_errand(self) -> None:
        travel = self._errand
        status = travel.too_close() if self.ctx.observation.too_close else travel.step()
        if status is Status.RUNNING:
            return
        self._errand = None
        self.ctx.planned_path = []
        where = place(travel.goal)
        if status is Status.DONE:  # the autopilot's last target is the goal itself: it settles there
            self.pause_reason = f"holding at {where}, where the operator sent it"
            self.say(f"Go here: arrived at {where}; holding")
        else:
            self.pause_reason = f"holding: could not reach {where} ({travel.reason})"
            self.say(f"Go here: {travel.reason}; holding", mavlink.MAV_SEVERITY_WARNING)
            self.fc.hold()

    def _set_mode(self, mode: str) -> None:
        self.fc.set_mode(mode)

    def set_speed(self) -> int:
        """Travel at ``Context.speed``: the operator's speed setting just changed, or the ground's sight limits it."""
        self._speed_sent = self.ctx.speed
        return self.fc.set_speed(self._speed_sent)

    def _limit_speed(self) -> None:
        """Once the sensors looking down have reported, slow down to what lets the vehicle stop short of an edge
        they see (a rover's 10 degree sonar sees one about 1.6 m ahead: from 2.5 m/s it needs 2 m), and creep
        while the near one looks at what may be an edge; speed up again once it has."""
        speed, monitor = self.ctx.speed, self.monitor
        if speed < self._speed_sent and monitor.creeping:
            self.say(f"Speed limited to {speed:.1f} m/s: the ground may drop away ahead; looking closer "
                     f"({monitor.near_sight:.1f} m ahead)")
        elif speed < self._speed_sent:
            self.say(f"Speed limited to {speed:.1f} m/s: the ground is seen {monitor.ground_sight:.1f} m ahead")
        elif speed > self._speed_sent:
            self.say(f"Speed back to {speed:.1f} m/s: the ground ahead is driven")
        else:
            return
        self.set_speed()

    # ---- the step -----------------------------------------------------------------------------
    def step(self) -> None:
        fc, ctx = self.fc, self.ctx
        now = ctx.time = fc.time
        self.monitor.collect(fc.readings())
        pose = fc.pose
        navigation = fc.navigation
        clearance = ctx.path_clearance if ctx.planned_path else math.inf  # less than the padding in a doorway
        observation = self.monitor.observe(now, pose.x, pose.y, navigation.heading, fc.speed, navigation.reach,
                                           clearance, ctx.planned_path)
        ctx.observation = observation
        if self.monitor.ground_sight is not None:
            self._limit_speed()
        taken = fc.took_over()
        if self._errand is not None:
            if taken is not None:  # someone else took over on the way
                self._errand = None
                ctx.planned_path = []
                self.pause(taken)
                return
            self._note_blocked(now, observation)
            self._run_errand()
            return
        if self.phase in (Phase.WAITING, Phase.DONE):
            if fc.taking_off and fc.mode == "GUIDED":
                self.start()  # the operator's GUIDED take-off starts the mission
            return
        if self._hold_due:
            self._hold_here()
        if self.operator:  # the operator's Pause or control: whatever the operator does next is theirs
            return
        if taken is not None:
            self.pause(taken)
        if self.paused and (taken is not None or not self._passed()):
            return
        self._note_blocked(now, observation)
        if self._level_flight() and self.give_way.step():
            return
        getattr(self, f"_{self.phase.value}")(now)

    def _level_flight(self) -> bool:
        """On the mission (GUIDED or AUTO) or on the way home, off the ground: it may give way to a team-mate."""
        return (self.phase in (Phase.MISSION, Phase.HOMING)
                and (self.fc.kind is Kind.ROVER or self.fc.flying) and not self.fc.taking_off)

    def _after_giving_way(self) -> None:
        """The way is clear again: send again whatever the mission or the way home was doing (an AUTO mission:
        back to AUTO, which flies on to the waypoint it was flying to)."""
        if self.phase is Phase.MISSION and self.mission.mode == "AUTO":
            self._set_mode("AUTO")
            self.say("Traffic: back to AUTO")
        elif self.phase is Phase.MISSION:
            self.mission.resume()
        if self._travel is not None:
            self._travel.resume()
        if self.phase is Phase.HOMING:
            self._over_home = None  # it may have given way while coming to rest over home: over home again

    def _note_blocked(self, now: float, observation) -> None:
        """Held back by the autopilot's avoidance for BLOCKED_FOR counts as an obstacle too close."""
        if self.fc.blocked:
            self._blocked_since = now if self._blocked_since is None else self._blocked_since
        else:
            self._blocked_since = None
        if self._blocked_since is not None and now - self._blocked_since >= BLOCKED_FOR:
            observation.too_close = True
            self._blocked_since = None

    def _preflight(self, now: float) -> None:
        fc = self.fc
        if self.mission.mode == "AUTO" and self._relaunch is not Phase.HOMING:  # the autopilot takes off itself
            self._relaunch = None
            self.mission.begin()
            self._set_mode("AUTO")
            fc.arm()
            if fc.mission.running or fc.start_mission() == 0:
                self.phase = Phase.MISSION
                self.mission_began = True
            return
        if now < self._ask_again_at:
            return
        self._set_mode("GUIDED")
        if not self._granted(now, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, fc.arm(report=False)):
            return
        if fc.kind is Kind.ROVER or (fc.flying and not fc.taking_off):
            self._ask_afresh()
            self._carry_on()
            return
        if not fc.taking_off:
            above = column(self.ctx, fc.home[2] + self.settings.altitude, fc.pose.z)
            if above is not None:  # it would climb into a team-mate: wait on the ground
                self._say_once(f"Traffic: waiting to take off: vehicle {above.vehicle} is above")
                return
            if not self._granted(now, mavlink.MAV_CMD_NAV_TAKEOFF, fc.takeoff(self.settings.altitude, report=False)):
                return
        self._ask_afresh()
        self.phase = Phase.TAKEOFF

    def _granted(self, now: float, command: int, result: int) -> bool:
        """The autopilot accepted a preflight command (or does not know it, which is no refusal either). A
        refusal is said and asked again (``PREFLIGHT_TRIES`` in all, the arming's and the take-off's together);
        the last one pauses the agent, saying why, as any refused command does."""
        if result in (ACCEPTED, mavlink.MAV_RESULT_UNSUPPORTED):
            return True
        self._refusals += 1
        why = self.refused = refusal(command, result)
        if self._refusals < PREFLIGHT_TRIES:
            self.say(f"Preflight: {why}; asking again in {PREFLIGHT_RETRY:g} s", mavlink.MAV_SEVERITY_WARNING)
            self._ask_again_at = now + PREFLIGHT_RETRY
        else:
            self._ask_afresh()
            self.pause(why)
        return False

    def _ask_afresh(self) -> None:
        """The preflight's refusals counted from none, and nothing to wait for: a start, a resume (an
        autopilot rebooted meanwhile counts its time from zero again), or the last refusal."""
        self._refusals, self.refused, self._ask_again_at = 0, "", -math.inf

    def _takeoff(self, now: float) -> None:
        if self.fc.flying and not self.fc.taking_off:
            self._carry_on()

    def _carry_on(self) -> None:
        """Ready to go (armed, and a copter in the air): start the mission, or go back to where an operator
        interrupted it."""
        relaunched, self._relaunch = self._relaunch, None
        if relaunched is None:
            self._start_mission()
            return
        self.phase = relaunched  # back to where the operator interrupted it
        if relaunched is Phase.MISSION:
            self.mission.resume()
        if self._travel is not None:
            self._travel.resume()

    def _start_mission(self) -> None:
        self.phase = Phase.MISSION
        self.mission_began = True
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
        speed = min(self.settings.speed, self.monitor.cruise_limit)  # not a creep towards a rim (``Context.speed``)
        return 2.0 * self.ctx.distance_to(self.ctx.home) / speed + reserve

    def _end_mission(self, status: Status, reason: str) -> None:
        self.outcome = "finished" if status is Status.DONE else "stopped"
        self.reason = reason or ("mission complete" if status is Status.DONE else "stopped")
        self.say(f"Mission {self.mission.name}: {self.outcome} ({self.reason}); going home")
        if self.fc.mode != "GUIDED":
            self._set_mode("GUIDED")
        self.mission.stop()
        self._travel = Travel(self.ctx, self.ctx.home, HOME_TOLERANCE, relax=True)
        self._settling = True
        self._over_home = None
        self.phase = Phase.HOMING

    def _homing(self, now: float) -> None:
        if self._settling:  # come to rest where the mission ended before setting off home
            if self.fc.speed > SETTLED:
                return
            self._settling = False
        travel = self._travel
        status = travel.too_close() if self.ctx.observation.too_close else travel.step()
        if status is Status.RUNNING:
            return
        if status is Status.STOPPED:  # the operator must bring it home now: a warning, not news
            self.say(f"Homing: {travel.reason}; holding position", mavlink.MAV_SEVERITY_WARNING)
            self.outcome = "stopped"
            self.reason = f"{self.reason}; could not get home: {travel.reason}"
            self.mission.stop()
            self.phase = Phase.DONE
            return
        if self.fc.kind is Kind.COPTER:
            # come to rest over home first: LAND descends where it begins, and one begun at speed drifts (in the
            # house, onto the bed beside a home 0.4 m from it)
            if self._over_home is None:
                self._over_home = now
                self.ctx.goto(self.ctx.home)
            # at rest is not enough: one that gave way to a team-mate near home rests off it (a copter landed
            # 0.3 m from home, on a bed's edge)
            away = self.ctx.distance_to(self.ctx.home) > OVER_HOME
            if (self.fc.speed > SETTLED or away) and now - self._over_home < SETTLE_OVER_HOME:
                return
            self._set_mode("LAND")
            self.phase = Phase.LANDING
        else:
            self._set_mode("HOLD")
            self.phase = Phase.DONE

    def _landing(self, now: float) -> None:
        """Land, but never onto a team-mate: hold the height (GUIDED) while one is below, within the margin."""
        fc = self.fc
        if not fc.armed:
            self.phase = Phase.DONE
            return
        below = column(self.ctx, fc.pose.z, fc.home[2]) if fc.flying else None
        if below is not None:
            self._clear_below = None
            if fc.mode == "LAND":
                self._set_mode("GUIDED")
                fc.goto(fc.pose.x, fc.pose.y)  # at the height it has reached
                self.say(f"Traffic: holding the landing: vehicle {below.vehicle} is below")
        elif fc.mode != "LAND":
            self._clear_below = now if self._clear_below is None else self._clear_below
            if now - self._clear_below >= CLEAR_FOR:
                self.say("Traffic: clear below; landing")
                self._set_mode("LAND")

    def _say_once(self, text: str) -> None:
        if not self.messages or self.messages[-1] != text:
            self.say(text)


def place(point: tuple[float, float]) -> str:
    """A point as messages name it, "(x, y)" to the decimetre (never "-0.0")."""
    return f"({round(point[0], 1) + 0.0:.1f}, {round(point[1], 1) + 0.0:.1f})"
