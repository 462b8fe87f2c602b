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
from vehicle.protocol.geodesy import heading_vector
from vehicle.protocol.modes import Kind

GRAVITY = 9.81
MAX_TILT = math.radians(30)
_PI, _TWO_PI = math.pi, 2 * math.pi
_hypot, _sin, _cos, _atan2 = math.hypot, math.sin, math.cos, math.atan2


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
        # Run every simulated step, so written with locals and with the small helpers it uses inlined
        # (wrap_pi, heading_vector, rest_height, _tilt_with_acceleration): the same operations in the same order.
        lim = self.limits
        pose = self.pose
        if yaw is not None:
            most = lim.turn_rate * dt
            turn = max(-most, min(most, (yaw - pose.yaw + _PI) % _TWO_PI - _PI))
        else:
            turn = 0.0
        heading = (pose.yaw + turn) % _TWO_PI
        pose.yaw = heading
        self.yaw_rate = turn / dt

        wanted = _hypot(vx, vy)
        if wanted > lim.max_speed:
            vx, vy = vx * lim.max_speed / wanted, vy * lim.max_speed / wanted
        rover = self.kind is Kind.ROVER
        if rover:  # wheels: no sideways motion, no reversing
            hx, hy = _sin(heading), _cos(heading)
            along = max(0.0, vx * hx + vy * hy)
            vx, vy = along * hx, along * hy
        dvx, dvy = vx - self.vx, vy - self.vy
        change = _hypot(dvx, dvy)
        max_change = lim.accel * dt
        if change > max_change:
            dvx, dvy = dvx * max_change / change, dvy * max_change / change
        ax, ay = dvx / dt, dvy / dt
        self.vx += dvx
        self.vy += dvy
        pose.x += self.vx * dt
        pose.y += self.vy * dt

        if rover:
            self.vz = 0.0
            self._settle_on_ground(ground, ground_normal)
        else:
            if falling:
                self.vz -= GRAVITY * dt
            else:
                self.vz = max(-lim.climb_rate, min(lim.climb_rate, vz))
            pose.z = pose.z + self.vz * dt
            rest = ground + lim.radius + lim.ground_clearance
            if pose.z <= rest:
                pose.z, self.vz = rest, 0.0
            # a multirotor leans into its acceleration: nose down to speed up, right down to go right
            hx, hy = _sin(heading), _cos(heading)
            forward = ax * hx + ay * hy
            right = ax * hy - ay * hx
            pose.pitch = max(-MAX_TILT, min(MAX_TILT, -_atan2(forward, GRAVITY)))
            pose.roll = max(-MAX_TILT, min(MAX_TILT, _atan2(right, GRAVITY)))

    def _settle_on_ground(self, ground: float, normal: tuple[float, float, float]) -> None:
        nx, ny, nz = normal
        hx, hy = heading_vector(self.pose.yaw)
        rx, ry = hy, -hx  # right-hand side
        nz = max(nz, 1e-6)
        self.pose.z = self.rest_height(ground)
        self.pose.pitch = math.atan(-(nx * hx + ny * hy) / nz)
        self.pose.roll = math.atan((nx * rx + ny * ry) / nz)

    def stop(self) -> None:
        self.vx = self.vy = self.vz = self.yaw_rate = 0.0
