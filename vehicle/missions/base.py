"""What every mission sees and does: the context, the status, and the Mission interface.

A mission is a small class that is stepped by the agent once per monitor period
and steers the vehicle through the autopilot's commands (the same requests a
companion computer sends over MAVLink). It never touches the simulation: it
sees the pose, the monitor's observation and the memory map, like a real
onboard agent would.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar

import numpy as np

from vehicle import planning
from vehicle.autopilot import Autopilot
from vehicle.memory_map import MemoryMap
from vehicle.modes import Kind
from vehicle.monitor import Monitor, Observation
from vehicle.settings import Settings

PLAN_MARGIN = 15.0  # m around start and goal that a first planning attempt searches


class Status(StrEnum):
    RUNNING = "running"
    DONE = "done"  # the mission's plan is complete
    STOPPED = "stopped"  # the mission gave up safely (reason in Mission.reason)


@dataclass
class Context:
    vehicle: Autopilot
    map: MemoryMap
    monitor: Monitor
    settings: Settings
    home: tuple[float, float]
    radius: float  # of the vehicle body, m
    waypoints: list[tuple[float, float]] | None = None  # given by the operator, scene metres
    time: float = 0.0
    observation: Observation | None = None
    say: Callable[[str], None] = print
    planned_path: list[tuple[float, float]] = field(default_factory=list)  # for display

    @property
    def kind(self) -> Kind:
        return self.vehicle.kind

    @property
    def position(self) -> tuple[float, float]:
        pose = self.vehicle.body.pose
        return pose.x, pose.y

    def distance_to(self, point: tuple[float, float]) -> float:
        x, y = self.position
        return math.hypot(point[0] - x, point[1] - y)

    @property
    def time_left(self) -> float:
        return self.settings.time_limit - self.time

    def clearance_cells(self, padding: float | None = None) -> float:
        pad = self.settings.padding if padding is None else padding
        return (self.radius + pad) * self.map.resolution

    # ---- planning on the memory map ------------------------------------------------------------
    def plan(self, goal: tuple[float, float]) -> list[tuple[float, float]] | None:
        """A path (scene metres, excluding the current position) to ``goal`` around known obstacles.

        Searches a window around start and goal first (fast), then the whole map.
        If the goal or start sits inside the padded obstacles, retries with less
        padding: getting home along a tight path beats not getting home.
        """
        start_cell = self.map.cell_of(*self.position)
        goal_cell = self.map.cell_of(*goal)
        if start_cell is None or goal_cell is None:
            return None
        for padding in dict.fromkeys((self.settings.padding, 0.0)):
            for window in (self._window(start_cell, goal_cell), None):
                try:
                    cells = self._plan_in(start_cell, goal_cell, self.clearance_cells(padding), window)
                except planning.NoPath as failure:
                    if failure.reason == planning.UNREACHABLE and window is not None:
                        continue
                    break
                points = [self.map.center_of(r, c) for r, c in cells[1:]]
                if points:
                    points[-1] = goal
                return points or [goal]
        return None

    def _window(self, a: tuple[int, int], b: tuple[int, int]) -> tuple[slice, slice] | None:
        margin = int(PLAN_MARGIN * self.map.resolution)
        r0, r1 = max(0, min(a[0], b[0]) - margin), min(self.map.size, max(a[0], b[0]) + margin + 1)
        c0, c1 = max(0, min(a[1], b[1]) - margin), min(self.map.size, max(a[1], b[1]) + margin + 1)
        if r0 == 0 and c0 == 0 and r1 == self.map.size and c1 == self.map.size:
            return None
        return slice(r0, r1), slice(c0, c1)

    def _plan_in(self, start, goal, radius_cells, window) -> np.ndarray:
        if window is None:
            blocked, offset = self.map.occupied, (0, 0)
        else:
            blocked, offset = self.map.occupied_in(*window), (window[0].start, window[1].start)
        local = planning.plan(blocked, (start[0] - offset[0], start[1] - offset[1]),
                              (goal[0] - offset[0], goal[1] - offset[1]), radius_cells)
        return local + np.array(offset)

    def path_clear(self, points: list[tuple[float, float]], horizon: float = 15.0) -> bool:
        """Whether the polyline from here through ``points`` keeps clear of known (unpadded) obstacles.

        Only the first ``horizon`` metres are checked: that is where new obstacles
        matter now, and the rest is checked again as the vehicle gets there.
        """
        chain = [self.position]
        length = 0.0
        for point in points:
            length += math.dist(chain[-1], point)
            chain.append(point)
            if length > horizon:
                break
        if len(chain) < 2:
            return True
        cells = [self.map.cell_of(*p) for p in chain]
        if any(c is None for c in cells):
            return False
        rows = [c[0] for c in cells]
        cols = [c[1] for c in cells]
        pad = int(math.ceil(self.clearance_cells(0.0))) + 1
        r0, r1 = max(0, min(rows) - pad), min(self.map.size, max(rows) + pad + 1)
        c0, c1 = max(0, min(cols) - pad), min(self.map.size, max(cols) + pad + 1)
        blocked = planning.inflate(self.map.occupied_in(slice(r0, r1), slice(c0, c1)), self.clearance_cells(0.0))
        local = [(r - r0, c - c0) for r, c in cells]
        # the first leg starts where the vehicle is, possibly already within the clearance of a wall
        return all(planning.line_is_clear(blocked, a, b) or (i == 0 and not blocked[b])
                   for i, (a, b) in enumerate(zip(local, local[1:], strict=False)))

    def is_clear(self, point: tuple[float, float], padding: float | None = None) -> bool:
        """Whether the body (plus padding) would fit at ``point`` without touching a known obstacle."""
        cell = self.map.cell_of(*point)
        if cell is None:
            return False
        radius = self.clearance_cells(padding)
        reach = int(math.ceil(radius))
        r0, c0 = max(0, cell[0] - reach), max(0, cell[1] - reach)
        window = self.map.occupied_in(slice(r0, cell[0] + reach + 1), slice(c0, cell[1] + reach + 1))
        rows, cols = np.nonzero(window)
        return not np.any((rows + r0 - cell[0]) ** 2 + (cols + c0 - cell[1]) ** 2 <= radius * radius)


class Mission:
    """Base class: subclasses set ``name`` and ``help`` and implement ``step``.

    ``mode`` is the flight mode the mission flies in: GUIDED missions get the
    vehicle airborne (or armed) from the agent before ``begin``; AUTO missions
    upload their items in ``begin`` and are started by the agent.
    """

    name: ClassVar[str]
    help: ClassVar[str]
    mode: ClassVar[str] = "GUIDED"

    def __init__(self, ctx: Context):
        self.ctx = ctx
        self.reason = ""

    def begin(self) -> None:
        """Called once when the vehicle is ready (armed, airborne for a copter)."""

    def step(self) -> Status:
        raise NotImplementedError

    def too_close(self) -> Status:
        """The monitor stopped the vehicle: an obstacle is closer than ``closeness`` ahead.

        The default gives up safely; missions that can find another way override it.
        """
        self.reason = "obstacle closer than the safety distance"
        return Status.STOPPED

    def out_of_time(self) -> Status:
        """Time to head home to make it within the limit: DONE if the plan is complete enough."""
        self.reason = "time budget spent before the plan was complete"
        return Status.STOPPED

    def stop(self) -> None:
        """Halt in place (GUIDED: hold the current position)."""
        x, y = self.ctx.position
        self.ctx.vehicle.goto(x, y, self.ctx.settings.altitude if self.ctx.kind is Kind.COPTER else None)
