"""Building blocks that several missions share: scanning in place and travelling with replanning."""

from __future__ import annotations

import math

import numpy as np

from vehicle.agent.missions.base import Context, Status
from vehicle.protocol.geodesy import wrap_pi
from vehicle.protocol.rangefinder import Reading

YAW_REACHED = math.radians(2)
PATH_POINT_REACHED = 0.5  # m: intermediate path points count as passed this close
GOAL_HELD = 0.3  # m: an autopilot at rest this near its goal holds it as reached (ArduPilot: its arrival radius)
GOAL_SETTLED = 0.1  # m/s: slower than this counts as at rest
PATH_CHECK_PERIOD = 1.0  # s between checks of the path ahead against new obstacles
STUCK_RADIUS = 1.0  # m: stopped again this close to the last stop counts as no progress
STUCK_TRIES = 3  # stops without progress before giving up
SCANNED_NEAR = 1.0  # m: a scan this close counts as having looked around here


class Scan:
    """Turn in place through ``turn`` degrees in ``yaw_step`` increments, collecting every reading.

    Turning the whole vehicle is what the thesis's Browse does; the sonar reads
    all the while, so each step adds a fan of readings to the map.
    """

    def __init__(self, ctx: Context, turn: float = 360.0):
        self.ctx = ctx
        self.step_rad = math.radians(ctx.settings.yaw_step)
        self.steps = max(1, math.ceil(turn / ctx.settings.yaw_step))
        self.start = ctx.yaw
        self.done_steps = -1
        self.readings: list[Reading] = []
        ctx.hold_here()

    def resume(self) -> None:
        """Turn again towards the heading of the current step (an operator's mode change dropped it)."""
        if self.done_steps >= 0:
            self.ctx.hold_here()
            self.ctx.fc.set_yaw((self.start + self.done_steps * self.step_rad) % (2 * math.pi))

    def step(self) -> bool:
        """True once the full turn is done."""
        if self.ctx.observation is not None:
            self.readings.extend(self.ctx.observation.readings)
        target = self.start + max(self.done_steps, 0) * self.step_rad
        if self.done_steps >= 0 and abs(wrap_pi(self.ctx.yaw - target)) > YAW_REACHED:
            return False
        self.done_steps += 1
        if self.done_steps > self.steps:
            return True
        self.ctx.fc.set_yaw((self.start + self.done_steps * self.step_rad) % (2 * math.pi))
        return False


class ServoScan:
    """Sweep a servo-mounted sonar across its range in ``yaw_step`` increments, turn the vehicle by that
    range, sweep back, and so on until the sweeps have covered a full circle.

    The thesis's other way to browse: only the sensor turns, so the vehicle turns
    far less (by the servo's range between sweeps, not in every step).
    """

    def __init__(self, ctx: Context):
        self.ctx = ctx
        servo = ctx.servo
        step = ctx.settings.yaw_step
        angles = list(np.arange(servo.angle_min, servo.angle_max + 1e-9, step))
        coverage = servo.angle_max - servo.angle_min + step
        sweeps = max(1, math.ceil(360.0 / coverage))
        start = ctx.yaw
        self.plan = [((start + math.radians(k * coverage)) % (2 * math.pi), angle)
                     for k in range(sweeps) for angle in (angles if k % 2 == 0 else angles[::-1])]
        self.index = -1
        self.readings: list[Reading] = []
        ctx.hold_here()

    def resume(self) -> None:
        if self.index >= 0:
            self.ctx.hold_here()
            self.ctx.fc.set_yaw(self.plan[self.index][0])

    def step(self) -> bool:
        """True once the sweeps are done (the servo is then centred again)."""
        ctx = self.ctx
        if ctx.observation is not None:
            self.readings.extend(ctx.observation.readings)
        if self.index >= 0 and abs(wrap_pi(ctx.yaw - self.plan[self.index][0])) > YAW_REACHED:
            return False  # still turning to this sweep's heading
        self.index += 1
        servo = ctx.servo
        if self.index >= len(self.plan):
            ctx.fc.set_servo(servo.channel, servo.pwm_for(0.0))
            return True
        heading, angle = self.plan[self.index]
        if self.index == 0 or heading != self.plan[self.index - 1][0]:
            ctx.fc.set_yaw(heading)
        ctx.fc.set_servo(servo.channel, servo.pwm_for(angle))
        return False


def scan(ctx: Context) -> Scan | ServoScan:
    """Look around from here: with the servo if the sonar has one, else by turning the vehicle."""
    return ServoScan(ctx) if ctx.servo is not None else Scan(ctx)


class Travel:
    """Get to ``goal`` along a path planned on the memory map, replanning when it turns out blocked.

    When the monitor reports an obstacle too close ahead, stop, scan around to
    learn the surroundings, then plan again: the thesis's Pathfind behaviour.
    When no path is known, look around once from here before giving up: the
    way may lie through a doorway the sonar has not looked through yet.
    """

    def __init__(self, ctx: Context, goal: tuple[float, float], tolerance: float, relax: bool = False):
        self.ctx = ctx
        self.relax = relax  # plan with less margin if that is the only way (going home)
        self.level = 0  # how much planning had to relax so far; later plans start there
        self.goal = goal
        self.tolerance = tolerance
        self.path: list[tuple[float, float]] | None = None
        self.scan: Scan | ServoScan | None = None
        self.reason = ""
        self.replans = 0
        self._sent: tuple[float, float] | None = None
        self._checked: tuple[int, int] | None = None
        self._scanned_at: tuple[float, float] | None = None
        self._next_check = 0.0
        self._stuck_at: tuple[float, float] | None = None
        self._stuck = 0

    def step(self) -> Status:
        ctx = self.ctx
        if self.scan is not None:
            if not self.scan.step():
                return Status.RUNNING
            self.scan = None
            self.path = None
        if ctx.distance_to(self.goal) <= self.tolerance or self._held_at_goal():
            ctx.planned_path = []
            return Status.DONE
        if self.path is None or not self._still_clear():
            self.path, self.level = ctx.plan(self.goal, self.relax, self.level)
            ctx.path_clearance = ctx.planner.clearance
            self.replans += 1
            self._sent = None
            self._checked = (ctx.map.occupied_version, len(self.path or ()))
            if self.path is None and not self._scanned_near():
                return self.too_close()  # scan, then plan again
            if self.path is None:
                why = ctx.planner.reason
                self.reason = f"no known path to ({self.goal[0]:.1f}, {self.goal[1]:.1f})" + (f": {why}" if why else "")
                ctx.planned_path = []
                return Status.STOPPED
        while len(self.path) > 1 and ctx.distance_to(self.path[0]) < PATH_POINT_REACHED:
            self.path.pop(0)
        ctx.planned_path = [ctx.position, *self.path]
        target = self.path[0]
        if target != self._sent:
            ctx.goto(target)
            self._sent = target
        return Status.RUNNING

    def _held_at_goal(self) -> bool:
        """The goal sent, and the vehicle at rest within ``GOAL_HELD`` of it: an autopilot stops short of a
        target by as much as its own arrival radius, so a tolerance below that (``closeness`` 0.1 m) would
        wait for ever (it hovered 121 s 0.12 m from its goal)."""
        ctx = self.ctx
        return (self._sent == self.goal and ctx.fc.speed < GOAL_SETTLED
                and ctx.distance_to(self.goal) <= GOAL_HELD)

    def resume(self) -> None:
        """Plan afresh and send the target again (an operator's mode change dropped it)."""
        self.path = None
        self._sent = None
        if self.scan is not None:
            self.scan.resume()

    def _still_clear(self) -> bool:
        """Check the path against the map again, at most once a second and only if obstacles changed.

        Between checks the monitor and the autopilot's avoidance keep the vehicle safe;
        the check only decides when a better path is worth planning.
        """
        state = (self.ctx.map.occupied_version, len(self.path))
        if state == self._checked or self.ctx.time < self._next_check:
            return True
        self._checked = state
        self._next_check = self.ctx.time + PATH_CHECK_PERIOD
        return self.ctx.path_clear(self.path)

    def too_close(self) -> Status:
        """Stop, look around, and plan again once the scan is done; give up if that keeps happening here."""
        if self.scan is None:
            here = self.ctx.position
            if self._stuck_at is not None and math.dist(here, self._stuck_at) < STUCK_RADIUS:
                self._stuck += 1
            else:
                self._stuck_at, self._stuck = here, 1
            if self._stuck > STUCK_TRIES:
                self.reason = f"blocked at ({here[0]:.1f}, {here[1]:.1f}) on the way to " \
                              f"({self.goal[0]:.1f}, {self.goal[1]:.1f})"
                self.ctx.planned_path = []
                return Status.STOPPED
            self.scan = scan(self.ctx)
            self._scanned_at = here
            self._sent = None
        return Status.RUNNING

    def _scanned_near(self) -> bool:
        return self._scanned_at is not None and self.ctx.distance_to(self._scanned_at) < SCANNED_NEAR
