"""The simulated flight controller: arming, modes and the AUTO mission, as ArduPilot behaves.

It turns mode and command requests into a wanted velocity and heading for the
body each step. Requests answer with a MAVLink result code (MAV_RESULT_*), so
the MAVLink endpoint can pass them straight into COMMAND_ACK. Positions are
scene metres; mission items carry latitude/longitude, converted with the datum.
A copter's RTL climbs to ``rtl_altitude`` first (ArduPilot's RTL_ALT), flies
home and lands. It never stops in silence: held back by an obstacle for a
moment, it says where and what it is doing, once per stop.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from vehicle.protocol.geodesy import Datum, heading_of, wrap_pi
from vehicle.protocol.mav import ACCEPTED, DENIED, FAILED, TEMPORARILY_REJECTED, UNSUPPORTED
from vehicle.protocol.mav import mavlink as mav
from vehicle.protocol.mission import (
    ALTITUDE_LIMIT,
    DO_CHANGE_SPEED,
    NAV_LAND,
    NAV_LOITER_TIME,
    NAV_LOITER_UNLIM,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    MissionItem,
    home_item,
)
from vehicle.protocol.modes import FLOWN, Kind
from vehicle.sim.avoidance import ObstacleDatabase
from vehicle.sim.physics import Body

_PI, _TWO_PI = math.pi, 2 * math.pi
TURN_FIRST = math.radians(12)  # heading error above which the vehicle turns in place before moving
ARRIVED = 0.15  # m: a position target closer than this is reached
VELOCITY_TIMEOUT = 3.0  # s: GUIDED velocity commands expire, as in ArduPilot
LANDING_SPEED = 0.7  # m/s
RTL_ALTITUDE = 15.0  # m above home a copter climbs to before flying home (ArduPilot's RTL_ALT default, 1500 cm)
AIRBORNE = 0.05  # m above its resting height from which a copter counts as flying
TOUCHED = 0.005  # m above its resting height within which a flying copter counts as down again: as
# ArduPilot's land detector, a copter holding its height a few centimetres over a box top still flies
TAKEOFF_REACHED = 0.1  # m: a GUIDED take-off this close to its height is done
STOPPED_FOR = 1.0  # s held back by an obstacle before the autopilot says so
SAME_STOP = 0.5  # m: held back again this close to a stop already told, on the way to the same place, is that stop


@dataclass
class Event:
    """Something a ground station should hear about: a message, a reached item, a new current item."""

    kind: str  # "text" | "reached" | "current"
    text: str = ""
    severity: int = mav.MAV_SEVERITY_INFO
    seq: int = -1


class Autopilot:
    def __init__(self, kind: Kind, body: Body, home: tuple[float, float, float], datum: Datum,
                 cruise_speed: float = 2.5, wp_radius: float = 1.0, avoidance: ObstacleDatabase | None = None,
                 rtl_altitude: float = RTL_ALTITUDE):
        self.kind = kind
        self.body = body
        self.home = home  # x, y and ground height of the start
        self.datum = datum
        self.cruise_speed = cruise_speed
        self.wp_radius = wp_radius
        self.avoidance = avoidance
        self.rtl_altitude = rtl_altitude
        self.armed = False
        self.wrecked = False  # a body that crashed never flies again (see ``crashed``)
        self.mode = "GUIDED" if kind is Kind.COPTER else "HOLD"
        self.mode_source = "boot"
        self.mode_changes = 0
        self.overrides = 0  # times a ground station steered it directly (see ``overridden``)
        self.override = ""
        self.speed = cruise_speed
        self.mission: list[MissionItem] = [self.home_item()]
        self.current = 1
        self.mission_running = False
        self.servos: dict[int, int] = {}  # output channel -> PWM, as MAV_CMD_DO_SET_SERVO sets them
        self.events: deque[Event] = deque(maxlen=256)  # drained by telemetry; bounded when nobody listens
        self.time = 0.0
        self._target: tuple[float, float, float] | None = None  # GUIDED position
        self._velocity: tuple[float, float, float, float] | None = None  # vx, vy, vz, expiry
        self._yaw: float | None = None
        self._hold: tuple[float, float, float] | None = None
        self._altitude_goal: float | None = None  # copter take-off
        self._braking = False
        self._item_timer: float | None = None
        self._rtl_done = False
        self._rtl_height: float | None = None  # the height RTL climbs to, set as RTL begins
        self._descending = False
        self._blocked_since: float | None = None
        self._told_stop: tuple[float, float, tuple[float, float]] | None = None  # the last stop told: x, y, its goal
        self.wanted = (0.0, 0.0)  # horizontal velocity navigation asked for, before avoidance
        self.destination: tuple[float, float] | None = None  # where navigation is taking the vehicle now
        self.blocked = False  # avoidance holds the vehicle back from an obstacle
        self._airborne = False  # flying as of the last step (``flying``'s hysteresis)
        self.battery_critical = False  # the battery failsafe has acted: no arming again (as ArduPilot's)
        self.ground_now = home[2]  # ground height under the vehicle, set each step
        self.hold_here()

    # ---- state -------------------------------------------------------------------------------
    @property
    def flying(self) -> bool:
        """A copter leaves the ground AIRBORNE above where it rests, and is down again only once it rests on
        something (within TOUCHED): passing low over a box top whose rest height is within AIRBORNE of its
        own is no landing (it stopped obeying GUIDED targets there, for good)."""
        if self.kind is not Kind.COPTER:
            return False
        return self.body.pose.z > self.body.rest_height(self.ground_now) + (TOUCHED if self._airborne else AIRBORNE)

    @property
    def taking_off(self) -> bool:
        """A GUIDED take-off is still climbing."""
        return self._altitude_goal is not None

    @property
    def altitude(self) -> float:
        """Height of the body above the start's ground (what GLOBAL_POSITION_INT calls relative_alt)."""
        return self.body.pose.z - self.home[2]

    def home_item(self) -> MissionItem:
        return home_item(self.datum, self.home[0], self.home[1])

    def say(self, text: str, severity: int = mav.MAV_SEVERITY_INFO) -> None:
        self.events.append(Event("text", text, severity))

    def overridden(self, what: str) -> None:
        """A ground station steered the vehicle directly (a GUIDED target, a yaw), not through a mode change."""
        self.overrides += 1
        self.override = what

    def clear_targets(self) -> None:
        """Drop any GUIDED position, velocity or yaw target."""
        self._target = self._velocity = self._yaw = None

    def hold_here(self) -> None:
        """Hold where the vehicle comes to rest (braking first if it is moving), at its current height."""
        pose = self.body.pose
        self._hold = (pose.x, pose.y, pose.z)
        self._braking = True

    def battery_failsafe(self, critical: bool, voltage: float, remaining: float) -> None:
        """ArduPilot's battery monitor: at the low level a warning; at the critical one, flying, a copter lands
        and a rover holds (BATT_FS_CRT_ACT Land; a rover's Hold), as the failsafe's mode change. Without it a
        copter hovered on at 0 %, and nobody was told."""
        text = f"Battery 1 is {'critical' if critical else 'low'}: {voltage:.1f} V, {remaining:.0%} left"
        self.battery_critical = critical
        if not (critical and self.armed):
            self.say(text, mav.MAV_SEVERITY_CRITICAL)
            return
        action = "LAND" if self.kind is Kind.COPTER else "HOLD"
        self.say(f"{text}; battery failsafe: {action}", mav.MAV_SEVERITY_CRITICAL)
        self.set_mode(action, source="failsafe")

    # ---- requests (each returns a MAV_RESULT) ------------------------------------------------
    def crashed(self) -> None:
        """The body hit something: the motors stop, and no arming, forced or not, brings a wreck back (a real
        autopilot's crash check disarms too; the simulated wreck lies still, so arming it would only feign a
        vehicle ready to fly)."""
        self.armed = False
        self.mission_running = False
        self._altitude_goal = None
        self.wrecked = True

    def arm(self, force: bool = False) -> int:
        if self.wrecked:
            self.say("Arm: vehicle crashed", mav.MAV_SEVERITY_CRITICAL)
            return FAILED
        if self.armed:
            return ACCEPTED
        if not force and self.kind is Kind.COPTER and self.mode in ("RTL", "LAND"):
            self.say(f"Arm: mode {self.mode} not armable", mav.MAV_SEVERITY_CRITICAL)
            return FAILED
        if not force and self.battery_critical:
            self.say("Arm: Battery 1 critical", mav.MAV_SEVERITY_CRITICAL)
            return FAILED
        self.armed = True
        self._altitude_goal = None
        self.clear_targets()  # a target from before a disarm (a kill in the air) is no order to fly now
        self.hold_here()
        self.say("Arming motors")
        return ACCEPTED

    def disarm(self, force: bool = False) -> int:
        if not self.armed:
            return ACCEPTED
        if self.flying and not force:
            self.say("Disarm: vehicle is flying", mav.MAV_SEVERITY_CRITICAL)
            return FAILED
        self.armed = False
        self.mission_running = False
        self._altitude_goal = None
        self.say("Disarming motors" + (" (forced)" if force else ""))
        return ACCEPTED

    def set_mode(self, name: str, source: str = "gcs", agent_on_board: bool = False) -> int:
        """As ArduPilot: AUTO with nothing to fly but home is refused (but for a disarmed copter), unless
        ``agent_on_board``: then AUTO is the signal that starts or resumes an onboard agent's mission."""
        name = name.upper()
        if name not in FLOWN[self.kind]:
            return UNSUPPORTED
        if name == self.mode:
            self.mode_source = source
            return ACCEPTED
        nothing_to_fly = len(self.mission) <= 1 and (self.armed or self.kind is Kind.ROVER)
        if name == "AUTO" and nothing_to_fly and not agent_on_board:
            self.say("No Mission. Can't set AUTO.", mav.MAV_SEVERITY_NOTICE)
            self.say("Flight mode change failed", mav.MAV_SEVERITY_WARNING)
            return FAILED
        self.mode = name
        self.mode_source = source
        self.mode_changes += 1
        self._target = self._velocity = self._yaw = self._altitude_goal = None
        self._rtl_done = False
        self._rtl_height = None
        self._item_timer = None
        self.hold_here()
        if name == "RTL" and self.kind is Kind.COPTER and self.armed:
            height = max(self.body.pose.z, self.home[2] + self.rtl_altitude)
            self._rtl_height = height
            if height > self.body.pose.z + 0.5:
                self.say(f"RTL: climbing to {height - self.home[2]:.0f} m, then home")
        if name == "AUTO":
            # a rover starts its mission on entering AUTO; a copter on the ground waits for MISSION_START
            self.mission_running = self.armed and (self.kind is Kind.ROVER or self.flying)
        else:
            self.mission_running = False
        return ACCEPTED

    def takeoff(self, altitude: float) -> int:
        if self.kind is not Kind.COPTER or self.mode != "GUIDED" or not self.armed:
            return TEMPORARILY_REJECTED if self.kind is Kind.COPTER else UNSUPPORTED
        if not 0 < altitude <= ALTITUDE_LIMIT:  # NaN too
            return DENIED
        if self.flying:
            return FAILED
        lowest = self._lowest_takeoff()
        if altitude < lowest:  # it would be done before it left the ground (ArduPilot: no take-off downwards)
            self.say(f"Takeoff: {altitude:.2f} m would not leave the ground; at least {lowest:.2f} m")
            return FAILED
        self._altitude_goal = self.home[2] + altitude
        pose = self.body.pose
        self._hold = (pose.x, pose.y, self._altitude_goal)
        self.say(f"Takeoff to {altitude:.1f} m")
        return ACCEPTED

    def _lowest_takeoff(self) -> float:
        """The lowest take-off height above home that ends in the air: the climb is done within TAKEOFF_REACHED
        of its height, and a copter counts as flying only AIRBORNE above where it rests."""
        return self.body.rest_height(self.ground_now) + AIRBORNE + TAKEOFF_REACHED - self.home[2]

    def _guided_ready(self) -> int | None:
        if self.mode != "GUIDED":
            return TEMPORARILY_REJECTED
        if not self.armed:
            return TEMPORARILY_REJECTED
        return None

    def goto(self, x: float, y: float, altitude: float | None = None) -> int:
        """GUIDED position target in scene metres; altitude above the start's ground (None keeps the current)."""
        if not (math.isfinite(x) and math.isfinite(y)) or (altitude is not None
                                                           and not abs(altitude) <= ALTITUDE_LIMIT):  # NaN too
            return DENIED
        if (refused := self._guided_ready()) is not None:
            return refused
        z = self.body.pose.z if altitude is None or self.kind is Kind.ROVER else self.home[2] + altitude
        self._target = (x, y, z)
        self._velocity = None
        self._yaw = None
        return ACCEPTED

    def set_velocity(self, vx: float, vy: float, vz: float = 0.0) -> int:
        if (refused := self._guided_ready()) is not None:
            return refused
        self._velocity = (vx, vy, vz, self.time + VELOCITY_TIMEOUT)
        self._target = None
        return ACCEPTED

    def set_yaw(self, heading: float, relative: bool = False) -> int:
        """Turn to a compass heading (radians); with ``relative``, by that angle (clockwise positive)."""
        if not math.isfinite(heading):  # a NaN heading would turn it for ever
            return DENIED
        if (refused := self._guided_ready()) is not None:
            return refused
        base = self.body.pose.yaw if relative else 0.0
        self._yaw = (base + heading) % (2 * math.pi)
        if self._target is None and self._velocity is None:
            self.hold_here()
        return ACCEPTED

    def set_speed(self, speed: float) -> int:
        if not 0 < speed <= self.body.limits.max_speed:  # NaN too
            return DENIED
        self.speed = speed
        return ACCEPTED

    def set_servo(self, channel: int, pwm: int) -> int:
        """MAV_CMD_DO_SET_SERVO: drive an output (a servo that turns a sonar, say)."""
        if not 1 <= channel <= 32 or not 500 <= pwm <= 2500:
            return DENIED
        self.servos[channel] = int(pwm)
        return ACCEPTED

    def set_mission(self, items: list[MissionItem]) -> None:
        """Replace the AUTO mission (item 0 is home and is kept)."""
        self.mission = [self.home_item(), *items[1:]] if items else [self.home_item()]
        self.current = min(1, len(self.mission) - 1) or 1
        self.mission_running = False

    def start_mission(self, first: int = 0) -> int:
        """MAV_CMD_MISSION_START: run the AUTO mission from ``first`` (0 = resume at the current item)."""
        if self.mode != "AUTO" or not self.armed:
            return DENIED
        if len(self.mission) <= 1:
            self.say("Mission: no items", mav.MAV_SEVERITY_WARNING)
            return FAILED
        if first > 0:
            self.set_current(first)
        if self.current >= len(self.mission):
            self.set_current(1)
        self.mission_running = True
        self._item_timer = None
        self.say(f"Mission: {self.current} started")
        return ACCEPTED

    def set_current(self, seq: int) -> bool:
        if not 1 <= seq < len(self.mission):
            return False
        self.current = seq
        self._item_timer = None
        self.events.append(Event("current", seq=seq))
        return True

    # ---- the step ---------------------------------------------------------------------------
    def step(self, dt: float, ground: float, ground_normal=(0.0, 0.0, 1.0)) -> None:
        self.time += dt
        self.ground_now = ground
        if not self.armed:
            falling = self.kind is Kind.COPTER and self.body.pose.z > self.body.rest_height(ground) + 1e-6
            self.body.step(dt, 0.0, 0.0, 0.0, None, ground, ground_normal, falling=falling)
            self._airborne = self.flying
            return
        self._descending = False
        self.destination = None
        vx, vy, vz, yaw = self._navigate(dt)
        self.wanted = (vx, vy)
        self.blocked = False
        if self.avoidance is not None and (vx or vy):
            body = self.body
            pose = body.pose
            limit = self.avoidance.speed_limit(pose.x, pose.y, pose.z, vx, vy, self.time)
            limit = max(0.0, limit - math.hypot(body.vx, body.vy) * dt)  # one step of reaction time
            wanted = math.hypot(vx, vy)
            if wanted > limit:
                vx, vy = vx * limit / wanted, vy * limit / wanted
                self.blocked = limit < 0.05
        self._tell_if_stopped()
        self.body.step(dt, vx, vy, vz, yaw, ground, ground_normal)
        if self._descending and not self.flying:
            self._touchdown()
        self._airborne = self.flying

    def _tell_if_stopped(self) -> None:
        """Say once, after STOPPED_FOR, that an obstacle holds the vehicle back from where it is going. A vehicle
        that creeps a few millimetres on and stops again (a remembered echo overwritten by a newer one a hair
        further) is still at the stop it told."""
        pose = self.body.pose
        told = self._told_stop
        if told is not None and (told[2] != self.destination or math.dist(told[:2], (pose.x, pose.y)) >= SAME_STOP):
            self._told_stop = told = None  # it left that stop, or is going elsewhere
        if not self.blocked or self.destination is None:
            self._blocked_since = None
            return
        if self._blocked_since is None:
            self._blocked_since = self.time
        if told is not None or self.time - self._blocked_since < STOPPED_FOR:
            return
        self._told_stop = (pose.x, pose.y, self.destination)
        wanted_x, wanted_y = self.wanted
        found = self.avoidance.obstacle_ahead(pose.x, pose.y, pose.z, wanted_x, wanted_y, self.time)
        where = "" if found is None else f"obstacle {found[0]:.1f} m ahead at ({found[1]:.1f}, {found[2]:.1f}); "
        tx, ty = self.destination
        if self.mode == "RTL":
            doing = "holding; climb higher or steer it round" if self.kind is Kind.COPTER else "holding"
            self.say(f"RTL: {where}cannot reach home, {doing}", mav.MAV_SEVERITY_WARNING)
        else:  # a GUIDED target may be the operator's or an onboard agent's: the autopilot cannot tell whose
            self.say(f"{self.mode}: {where}stopped short of ({tx:.1f}, {ty:.1f})", mav.MAV_SEVERITY_WARNING)

    def _touchdown(self) -> None:
        """A copter that was landing is on the ground: finish the item and disarm, as ArduPilot does."""
        if self.mode == "AUTO" and self.mission_running:
            self._advance()
        self.armed = False
        self.mission_running = False
        self.say("Landed; disarming")

    def _navigate(self, dt: float) -> tuple[float, float, float, float | None]:
        if self._altitude_goal is not None:  # GUIDED take-off: climb straight up first
            if abs(self.body.pose.z - self._altitude_goal) < TAKEOFF_REACHED and self.flying:
                self._altitude_goal = None
            else:
                return self._fly_to(self._hold[0], self._hold[1], self._altitude_goal, dt)[:4]
        mode = self.mode
        if mode == "GUIDED":
            return self._guided(dt)
        if mode == "AUTO":
            if self.mission_running:
                return self._auto(dt)
            return self._hold_position(dt)
        if mode == "RTL":
            return self._return_home(dt)
        if mode == "LAND":
            return self._land_here(dt)
        return self._hold_position(dt)  # HOLD, LOITER, BRAKE, MANUAL without a pilot

    def _hold_position(self, dt):
        if self._braking:  # stop first, then hold the spot where it stopped, as ArduPilot's BRAKE does
            if self.body.speed > 0.05:
                pose = self.body.pose
                self._hold = (pose.x, pose.y, self._hold[2])
                return 0.0, 0.0, self._climb_towards(self._hold[2]), None
            self._braking = False
            self._hold = (self.body.pose.x, self.body.pose.y, self._hold[2])
        x, y, z = self._hold
        return self._fly_to(x, y, z, dt, turn_first=False)[:4]

    def _climb_towards(self, z: float) -> float:
        if self.kind is not Kind.COPTER:
            return 0.0
        climb = self.body.limits.climb_rate
        return max(-climb, min(climb, 2.0 * (z - self.body.pose.z)))

    def _guided(self, dt):
        if self.kind is Kind.COPTER and not self.flying:  # as ArduCopter: on the ground only a take-off lifts it
            return 0.0, 0.0, 0.0, None
        if self._velocity is not None:
            vx, vy, vz, expiry = self._velocity
            if self.time > expiry:
                self._velocity = None
                self.hold_here()
                return self._hold_position(dt)
            heading = heading_of(vx, vy) if math.hypot(vx, vy) > 0.05 else None
            if heading is not None and abs(wrap_pi(heading - self.body.pose.yaw)) > TURN_FIRST:
                return 0.0, 0.0, vz, heading
            return vx, vy, vz, heading
        if self._target is not None:
            x, y, z = self._target
            vx, vy, vz, yaw, arrived = self._fly_to(x, y, z, dt)
            if arrived:
                self._target = None
                self._hold = (x, y, z)
            return vx, vy, vz, yaw
        vx, vy, vz, _ = self._hold_position(dt)
        return vx, vy, vz, self._yaw

    def _fly_to(self, x: float, y: float, z: float, dt: float, speed: float | None = None,
                turn_first: bool = True):
        """Velocity and heading that bring the body to (x, y, z): turn first, then move, braking to arrive."""
        # run every step: _climb_towards, heading_of and wrap_pi inlined (the same operations)
        body = self.body
        pose = body.pose
        self.destination = (x, y)
        dx, dy = x - pose.x, y - pose.y
        distance = math.hypot(dx, dy)
        copter = self.kind is Kind.COPTER
        if copter:
            climb = body.limits.climb_rate
            vz = max(-climb, min(climb, 2.0 * (z - pose.z)))
        else:
            vz = 0.0
        arrived = distance < ARRIVED and abs(z - pose.z) < 0.2 if copter else distance < ARRIVED
        if distance < ARRIVED:
            return 0.0, 0.0, vz, None, arrived
        heading = math.atan2(dx, dy) % _TWO_PI
        if turn_first and distance > 0.5 and abs((heading - pose.yaw + _PI) % _TWO_PI - _PI) > TURN_FIRST:
            return 0.0, 0.0, vz, heading, False
        cruise = self.speed if speed is None else speed
        wanted = min(cruise, math.sqrt(2 * self.body.limits.accel * distance) * 0.9, distance / dt)
        if self.kind is Kind.ROVER and distance <= 0.5 and abs(wrap_pi(heading - pose.yaw)) > math.pi / 2:
            return 0.0, 0.0, 0.0, None, True  # close enough: a rover cannot back up onto the point
        # a copter's nose follows the way it goes, however short the hop, as ArduCopter's yaw follows its velocity
        # (it holds its heading once within ARRIVED, above, where the way flips as it arrives)
        yaw = heading if copter or distance > 0.5 else None
        return wanted * dx / distance, wanted * dy / distance, vz, yaw, False

    def _return_home(self, dt):
        hx, hy, _ = self.home
        z = self.body.pose.z
        if self._rtl_height is not None and not self._rtl_done:  # a copter climbs where it is first, as ArduPilot's
            if self._rtl_height - z > 0.2:
                vx, vy, _, yaw = self._hold_position(dt)
                return vx, vy, self._climb_towards(self._rtl_height), yaw
            z = self._rtl_height
        if self._rtl_done:
            return self._land_here(dt) if self.kind is Kind.COPTER else self._hold_position(dt)
        vx, vy, vz, yaw, arrived = self._fly_to(hx, hy, z, dt)
        if arrived or math.hypot(self.body.pose.x - hx, self.body.pose.y - hy) < 0.3:
            self._rtl_done = True
            self.say("Reached home")
            self.hold_here()
        return vx, vy, vz, yaw

    def _land_here(self, dt):
        x, y, _ = self._hold
        vx, vy, _, _ = self._fly_to(x, y, self.body.pose.z, dt, turn_first=False)[:4]
        self._descending = True
        return vx, vy, -LANDING_SPEED, None

    # ---- AUTO --------------------------------------------------------------------------------
    def _advance(self) -> None:
        self.events.append(Event("reached", seq=self.current))
        self._item_timer = None
        self._rtl_done = False
        if self.current + 1 < len(self.mission):
            self.set_current(self.current + 1)
        else:
            self.current = len(self.mission)
            self.mission_running = False
            self.hold_here()
            self.say("Mission complete")

    def _auto(self, dt):
        for _ in range(len(self.mission)):  # do-commands complete at once; stop at the first nav item
            if self.current >= len(self.mission):
                return self._hold_position(dt)
            item = self.mission[self.current]
            if item.command == DO_CHANGE_SPEED:
                if item.param2 > 0:
                    self.set_speed(item.param2)
                self._advance()
                continue
            if item.command == NAV_TAKEOFF and (self.kind is Kind.ROVER or self.flying and
                                                self.body.pose.z >= self.home[2] + item.alt - 0.1):
                self._advance()
                continue
            if item.command not in (NAV_TAKEOFF, NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_LAND,
                                    NAV_RETURN_TO_LAUNCH):
                self.say(f"Mission: skipping unsupported command {item.command}", mav.MAV_SEVERITY_WARNING)
                self._advance()
                continue
            break
        if not self.mission_running:
            return self._hold_position(dt)
        item = self.mission[self.current]
        pose = self.body.pose
        if item.command == NAV_TAKEOFF:  # at least off the ground, or the item would never end
            return self._fly_to(pose.x, pose.y, self.home[2] + max(item.alt, self._lowest_takeoff()), dt)[:4]
        if item.command == NAV_RETURN_TO_LAUNCH:
            result = self._return_home(dt)
            if self._rtl_done and self.kind is Kind.ROVER:
                self._advance()
            return result
        x, y = self.datum.to_local(item.lat, item.lon) if item.has_position else (pose.x, pose.y)
        z = self.home[2] + item.alt if self.kind is Kind.COPTER and item.command != NAV_LAND else pose.z
        if self.kind is Kind.COPTER and not self.flying and item.command != NAV_LAND:
            return self._fly_to(pose.x, pose.y, max(z, self.home[2] + 1.0), dt)[:4]  # take off first
        if item.command == NAV_LAND:
            if math.hypot(x - pose.x, y - pose.y) > ARRIVED:
                return self._fly_to(x, y, pose.z, dt)[:4]
            if self.kind is Kind.ROVER:
                self._advance()
                return self._hold_position(dt)
            self._hold = (x, y, pose.z)
            return self._land_here(dt)
        radius = item.param2 if item.param2 > 0 else self.wp_radius
        vx, vy, vz, yaw, arrived = self._fly_to(x, y, z, dt)
        if math.hypot(x - pose.x, y - pose.y) <= radius or arrived:
            if item.command == NAV_LOITER_UNLIM:
                return self._fly_to(x, y, z, dt, turn_first=False)[:4]
            if self._item_timer is None:
                self._item_timer = self.time
            if self.time - self._item_timer >= item.param1:
                self._advance()
        return vx, vy, vz, yaw
