"""Kinematics of the simulated body: limited acceleration, turn rate and climb rate.

The autopilot decides what velocity and heading it wants; this module decides
what the body can do in one fixed step. It is a point mass with a heading, not
a dynamics model: enough to reproduce how ArduPilot vehicles move at mission
speeds, deterministic, and cheap enough to run thousands of steps per second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vehicle.protocol.frames import Pose
from vehicle.protocol.geodesy import heading_vector, wrap_pi
from vehicle.protocol.modes import Kind

GRAVITY = 9.81
MAX_TILT = math.radians(30)


@dataclass
class Limits:
    """What the body can do; defaults are gentle values for a small rover or quadcopter."""

    max_speed: float = 5.0  # m/s horizontal
    accel: float = 2.5  # m/s^2 horizontal
    turn_rate: float = math.radians(90)  # rad/s
    climb_rate: float = 1.5  # m/s
    radius: float = 0.3  # m, the collision sphere
    ground_clearance: float = 0.05  # m between the ground and the bottom of the sphere when landed


@dataclass
class Body:
    kind: Kind
    limits: Limits = field(default_factory=Limits)
    pose: Pose = field(default_factory=Pose)
    vx: float = 0.0  # m/s east
    vy: float = 0.0  # m/s north
    vz: float = 0.0  # m/s up
    yaw_rate: float = 0.0

    @property
    def speed(self) -> float:
        return math.hypot(self.vx, self.vy)

    def rest_height(self, ground: float) -> float:
        """Height of the body centre when resting on ground at the given height."""
        return ground + self.limits.radius + self.limits.ground_clearance

    def step(self, dt: float, vx: float, vy: float, vz: float, yaw: float | None,
             ground: float, ground_normal: tuple[float, float, float] = (0.0, 0.0, 1.0),
             falling: bool = False) -> None:
        """Move one step towards the wanted velocity (m/s, ENU) and heading (rad or None).

        ``falling`` is a copter without thrust (disarmed in the air): it drops freely.
        """
        lim = self.limits
        if yaw is not None:
            turn = max(-lim.turn_rate * dt, min(lim.turn_rate * dt, wrap_pi(yaw - self.pose.yaw)))
        else:
            turn = 0.0
        self.pose.yaw = (self.pose.yaw + turn) % (2 * math.pi)
        self.yaw_rate = turn / dt

        wanted = math.hypot(vx, vy)
        if wanted > lim.max_speed:
            vx, vy = vx * lim.max_speed / wanted, vy * lim.max_speed / wanted
        if self.kind is Kind.ROVER:  # wheels: no sideways motion, no reversing
            hx, hy = heading_vector(self.pose.yaw)
            along = max(0.0, vx * hx + vy * hy)
            vx, vy = along * hx, along * hy
        dvx, dvy = vx - self.vx, vy - self.vy
        change = math.hypot(dvx, dvy)
        max_change = lim.accel * dt
        if change > max_change:
            dvx, dvy = dvx * max_change / change, dvy * max_change / change
        ax, ay = dvx / dt, dvy / dt
        self.vx += dvx
        self.vy += dvy
        self.pose.x += self.vx * dt
        self.pose.y += self.vy * dt

        if self.kind is Kind.ROVER:
            self.vz = 0.0
            self._settle_on_ground(ground, ground_normal)
        else:
            if falling:
                self.vz -= GRAVITY * dt
            else:
                self.vz = max(-lim.climb_rate, min(lim.climb_rate, vz))
            self.pose.z = self.pose.z + self.vz * dt
            if self.pose.z <= self.rest_height(ground):
                self.pose.z, self.vz = self.rest_height(ground), 0.0
            self._tilt_with_acceleration(ax, ay)

    def _settle_on_ground(self, ground: float, normal: tuple[float, float, float]) -> None:
        nx, ny, nz = normal
        hx, hy = heading_vector(self.pose.yaw)
        rx, ry = hy, -hx  # right-hand side
        nz = max(nz, 1e-6)
        self.pose.z = self.rest_height(ground)
        self.pose.pitch = math.atan(-(nx * hx + ny * hy) / nz)
        self.pose.roll = math.atan((nx * rx + ny * ry) / nz)

    def _tilt_with_acceleration(self, ax: float, ay: float) -> None:
        """A multirotor leans into its acceleration: nose down to speed up, right down to go right."""
        hx, hy = heading_vector(self.pose.yaw)
        forward = ax * hx + ay * hy
        right = ax * hy - ay * hx
        self.pose.pitch = max(-MAX_TILT, min(MAX_TILT, -math.atan2(forward, GRAVITY)))
        self.pose.roll = max(-MAX_TILT, min(MAX_TILT, math.atan2(right, GRAVITY)))

    def stop(self) -> None:
        self.vx = self.vy = self.vz = self.yaw_rate = 0.0
