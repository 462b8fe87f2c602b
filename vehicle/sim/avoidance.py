"""Stop before obstacles the sensors saw: the autopilot's last line of defence.

Like ArduPilot's simple avoidance with a proximity database (AP_OADatabase),
the autopilot remembers recent sonar hits near its operating height and caps
its speed towards any of them so that it can always brake to a stop ``margin``
short of the obstacle. Missions decide where to go; this only decides how fast
the body may go there. Each echo keeps its height, as the database's points
do: only those within ``BAND`` of the vehicle's height hold it back, so a
copter that climbed (RTL climbs to its return height) flies over the walls it
saw below.

An echo holds the vehicle back when the line it wants to move along would bring
the echo within the margin, and nearer than it is now, by more than ``GRAZE``.
A vehicle that already stands within the margin of an echo (a rover stopped
beside a kerb) may so move away from it or past it, as ArduPilot's avoidance
lets a vehicle slide along what it is too close to; only moving towards it is
held back. Without that, an echo right beside the body held back every
direction with a little of "ahead" in it, and the vehicle stood there for good.
"""

from __future__ import annotations

import math

import numba
import numpy as np

MARGIN = 0.1  # m kept between the body and any remembered echo (planning keeps at least twice that)
GRAZE = 0.05  # m: a move that brings an echo no nearer than this beyond the margin, or than it is now, is free
BAND = 1.0  # m: echoes further above or below the vehicle are no obstacle to it (the ground, a roof, a wall far below)


class ObstacleDatabase:
    def __init__(self, margin: float, accel: float, capacity: int = 512, lifetime: float = 60.0,
                 body_radius: float = 0.3):
        self.margin = margin
        self.accel = accel
        self.body_radius = body_radius
        self.lifetime = lifetime
        self._points = np.zeros((capacity, 3))
        self._times = np.full(capacity, -np.inf)
        self._next = 0
        self._clear_from: tuple[float, float] | None = None  # no echo at any height within _clear_radius of here
        self._clear_radius = 0.0

    def add(self, x: float, y: float, z: float, time: float) -> None:
        if self._clear_from is not None:
            self._clear_radius = min(self._clear_radius, math.dist(self._clear_from, (x, y)))
        self._points[self._next] = (x, y, z)
        self._times[self._next] = time
        self._next = (self._next + 1) % len(self._times)

    def clear(self) -> None:
        self._times[:] = -np.inf
        self._clear_from = None

    def speed_limit(self, x: float, y: float, z: float, vx: float, vy: float, now: float) -> float:
        """Highest speed along (vx, vy) from (x, y) at height z that can still stop short of every known
        obstacle."""
        speed = math.hypot(vx, vy)
        if speed < 1e-9:
            return 0.0
        reach = self.body_radius + self.margin + speed * speed / (2 * self.accel) + 1.0  # further cannot matter
        if self._clear_from is not None and math.dist(self._clear_from, (x, y)) + reach < self._clear_radius:
            return math.inf  # nothing known anywhere near: skip the search
        ux, uy = vx / speed, vy / speed
        nearest, gap = _nearest_and_ahead(self._points, self._times, now - self.lifetime, x, y, z, ux, uy,
                                          reach, self.body_radius + self.margin)
        self._clear_from, self._clear_radius = (x, y), nearest
        if gap == math.inf:
            return math.inf
        return math.sqrt(2 * self.accel * gap) if gap > 0 else 0.0


    def obstacle_ahead(self, x: float, y: float, z: float, vx: float, vy: float, now: float):
        """The nearest remembered obstacle in the corridor along (vx, vy): (distance, x, y), or None. Asked
        rarely (to say what holds the vehicle back), so plain numpy."""
        speed = math.hypot(vx, vy)
        if speed < 1e-9:
            return None
        ux, uy = vx / speed, vy / speed
        live = (self._times > now - self.lifetime) & (np.abs(self._points[:, 2] - z) <= BAND)
        dx, dy = self._points[live, 0] - x, self._points[live, 1] - y
        ahead = dx * ux + dy * uy
        corridor = self.body_radius + self.margin
        inside = (ahead > 0) & _in_the_way.py_func(np.abs(dx * uy - dy * ux), np.hypot(dx, dy), corridor)
        if not inside.any():
            return None
        k = np.flatnonzero(inside)[np.argmin(ahead[inside])]
        return float(np.hypot(dx[k], dy[k])), float(x + dx[k]), float(y + dy[k])


@numba.njit(cache=True)
def _nearest_and_ahead(points, times, oldest, x, y, z, ux, uy, reach, corridor):
    """Over the points remembered after ``oldest``: the distance to the nearest at any height, and how far
    (less the corridor's half-width) the nearest one within ``reach`` and ``BAND`` of height z lies ahead
    inside the corridor along (ux, uy), inf if none. A loop over a few hundred points, asked at every
    simulated step."""
    nearest = math.inf
    gap = math.inf
    for k in range(len(times)):
        if times[k] <= oldest:
            continue
        dx, dy = points[k, 0] - x, points[k, 1] - y
        distance = math.hypot(dx, dy)
        nearest = min(nearest, distance)
        if distance >= reach or abs(points[k, 2] - z) > BAND:
            continue
        ahead = dx * ux + dy * uy
        if ahead > 0 and _in_the_way(abs(dx * uy - dy * ux), distance, corridor):
            gap = min(gap, ahead - corridor)
    return nearest, gap


@numba.njit(cache=True)
def _in_the_way(passing, distance, corridor):
    """Whether an echo now ``distance`` away, which the line passes ``passing`` from, holds the vehicle back:
    the line brings it within the corridor (body radius plus margin) and nearer than it is now, each by more
    than ``GRAZE``. Arrays too, as ``_in_the_way.py_func``."""
    return passing < np.minimum(corridor, distance) - GRAZE
