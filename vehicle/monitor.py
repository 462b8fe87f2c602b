"""The monitor: every period, vet the sensor readings, keep the memory map, and raise the alarm.

It drops readings past ``farness`` (a glitching sonar reports nonsense far
away), projects the rest into the memory map, and reports an obstacle closer
than ``closeness`` in the direction the vehicle is moving, so the agent can
stop before it gets any closer. It also keeps the mission's progress figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vehicle.geodesy import heading_of
from vehicle.memory_map import MemoryMap
from vehicle.sensors import Reading
from vehicle.settings import Settings


@dataclass
class Observation:
    """What the monitor saw in one period."""

    time: float
    readings: list[Reading] = field(default_factory=list)  # readings kept this period
    nearest_ahead: float | None = None  # closest echo in the direction of travel, metres
    too_close: bool = False
    outside: bool = False  # the vehicle left the allowed space around home


class Monitor:
    def __init__(self, settings: Settings, memory_map: MemoryMap, home: tuple[float, float], radius: float):
        self.settings = settings
        self.map = memory_map
        self.home = home
        self.radius = radius
        self.readings_dropped = 0
        self.readings_used = 0
        self.distance_travelled = 0.0
        self._last_xy: tuple[float, float] | None = None
        self._pending: list[Reading] = []

    def collect(self, readings: list[Reading]) -> None:
        """Buffer readings taken between two monitor periods."""
        self._pending.extend(readings)

    def observe(self, time: float, x: float, y: float, travel: float | None) -> Observation:
        """Run one monitor period on the readings collected since the last one.

        ``travel`` is the compass heading (rad) the vehicle wants to move in, None when it
        wants to stay put. An echo is "ahead" when its point lies in the corridor the
        body sweeps along that heading (body radius plus padding either side).
        """
        observation = Observation(time)
        if self._last_xy is not None:
            self.distance_travelled += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)
        self.map.mark_body(x, y, self.radius)
        farness = self.settings.farness
        corridor = self.radius + self.settings.padding
        ux, uy = (math.sin(travel), math.cos(travel)) if travel is not None else (0.0, 0.0)
        for reading in self._pending:
            if reading.distance is not None and reading.distance > farness:
                self.readings_dropped += 1
                reading = Reading(reading.time, reading.sensor, reading.origin, reading.direction, None,
                                  min(reading.max_range, farness), reading.yaw_offset)
            self.readings_used += 1
            self.map.add_reading(reading.origin, reading.direction, reading.distance,
                                 min(reading.max_range, farness))
            observation.readings.append(reading)
            if reading.distance is None or travel is None:
                continue
            hit = reading.hit
            if abs(hit[2] - reading.origin[2]) > self.map.band:
                continue  # ground or ceiling
            dx, dy = hit[0] - x, hit[1] - y
            ahead = dx * ux + dy * uy
            if ahead > 0 and abs(dx * uy - dy * ux) < corridor:
                nearest = observation.nearest_ahead
                observation.nearest_ahead = ahead if nearest is None else min(nearest, ahead)
        self._pending.clear()
        observation.too_close = (observation.nearest_ahead is not None
                                 and observation.nearest_ahead < self.settings.closeness)
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
