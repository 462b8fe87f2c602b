"""The monitor: every period, vet the sensor readings, keep the memory map, and raise the alarm.

It drops readings past ``farness`` (a glitching sonar reports nonsense far
away), takes an echo off a team-mate for free space up to it (not a wall: the
agent keeps apart from team-mates through ``vehicle.agent.traffic``), projects
the rest into the memory map, and reports an obstacle closer
than ``closeness`` in the direction the vehicle is moving, so the agent can
stop before it gets any closer. It also keeps the mission's progress figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from vehicle.agent.settings import Settings
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.geodesy import heading_of
from vehicle.protocol.rangefinder import Reading


@dataclass
class Observation:
    """What the monitor saw in one period."""

    time: float
    readings: list[Reading] = field(default_factory=list)  # readings kept this period
    nearest_ahead: float | None = None  # closest echo in the direction of travel, metres
    too_close: bool = False
    outside: bool = False  # the vehicle left the allowed space around home


class Monitor:
    def __init__(self, settings: Settings, memory_map: MemoryMap, home: tuple[float, float], radius: float,
                 brake: float = 2.5):
        self.settings = settings
        self.map = memory_map
        self.home = home
        self.radius = radius
        self.brake = brake  # m/s^2 the vehicle can decelerate at
        self.readings_dropped = 0
        self.readings_used = 0
        self.distance_travelled = 0.0
        self._last_xy: tuple[float, float] | None = None
        self._pending: list[Reading] = []

    def _nearest_ahead(self, x: float, y: float, travel: float, readings: list[Reading],
                       reach: float) -> float | None:
        """Distance ahead of the nearest echo inside the corridor the body sweeps along ``travel``,
        as far as ``reach`` metres."""
        ux, uy = math.sin(travel), math.cos(travel)
        corridor = self.radius + self.settings.padding
        nearest = None
        for reading in readings:  # a handful per period: plain floats beat a dozen numpy calls
            if reading.distance is None:
                continue
            ox, oy, oz = reading.origin.tolist()
            rx, ry, rz = reading.direction.tolist()
            hx, hy, hz = ox + rx * reading.distance, oy + ry * reading.distance, oz + rz * reading.distance
            if abs(hz - oz) > self.map.band:
                continue  # ground or ceiling
            dx, dy = hx - x, hy - y
            ahead = dx * ux + dy * uy
            if 0 < ahead < reach + corridor and abs(dx * uy - dy * ux) < corridor:
                nearest = ahead if nearest is None else min(nearest, ahead)
        return nearest

    def collect(self, readings: list[Reading]) -> None:
        """Buffer readings taken between two monitor periods."""
        self._pending.extend(readings)

    def observe(self, time: float, x: float, y: float, travel: float | None, speed: float = 0.0,
                reach: float = math.inf) -> Observation:
        """Run one monitor period on the readings collected since the last one.

        ``travel`` is the compass heading (rad) the vehicle wants to move in, None when it
        wants to stay put. An echo is "ahead" when its point lies in the corridor the
        body sweeps along that heading (body radius plus padding either side). It is
        too close when the vehicle, moving at ``speed``, could not stop within
        ``closeness`` of it: one more period of travel plus the braking distance.
        Echoes beyond ``reach`` (where the vehicle will stop or turn) are not in the way.
        """
        observation = Observation(time)
        if self._last_xy is not None:
            self.distance_travelled += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)
        self.map.mark_body(x, y, self.radius)
        farness = self.settings.farness
        pending = self._pending
        readings = [r if r.distance is None or r.distance <= farness else replace(r, distance=None)
                    for r in pending]  # past farness: a glitch, or too far to trust
        count = len(readings)
        self.readings_used += count
        self.readings_dropped += sum(r is not kept for r, kept in zip(pending, readings, strict=True))
        # an echo off a team-mate is no wall: free space up to it, nothing known beyond (it moves on)
        readings = [r if r.vehicle is None or r.distance is None else replace(r, distance=None, max_range=r.distance)
                    for r in readings]
        observation.readings = readings
        if readings:
            # one pass into arrays (np.array of a list of small arrays is slow)
            origins, directions = np.empty((count, 3)), np.empty((count, 3))
            distances, max_ranges, beams = np.empty(count), np.empty(count), np.empty(count)
            latest = {}
            for i, r in enumerate(readings):
                origins[i] = r.origin
                directions[i] = r.direction
                distances[i] = np.nan if r.distance is None else r.distance
                max_ranges[i] = min(r.max_range, farness)
                beams[i] = math.radians(r.beam_angle)
                latest[r.sensor] = i
            # free space from each sensor's latest reading of the period: the earlier ones only repeat it
            free = np.zeros(count, dtype=bool)
            free[list(latest.values())] = True
            self.map.add_readings(origins, directions, distances, max_ranges, beams, free)
            if travel is not None:
                observation.nearest_ahead = self._nearest_ahead(x, y, travel, readings, reach)
        self._pending = []
        stopping = speed * self.settings.monitor_period + speed * speed / (2 * self.brake)
        observation.too_close = (observation.nearest_ahead is not None
                                 and observation.nearest_ahead < self.settings.closeness + stopping)
        half = self.settings.space_size
        observation.outside = abs(x - self.home[0]) > half or abs(y - self.home[1]) > half
        return observation


def sweep_profile(readings: list[Reading]) -> tuple[np.ndarray, np.ndarray]:
    """Headings (rad) and distances (inf for no echo) of a set of readings, sorted by heading."""
    if not readings:
        return np.zeros(0), np.zeros(0)
    headings = np.array([heading_of(r.direction[0], r.direction[1]) for r in readings])
    distances = np.array([np.inf if r.distance is None else r.distance for r in readings])
    order = np.argsort(headings)
    return headings[order], distances[order]
