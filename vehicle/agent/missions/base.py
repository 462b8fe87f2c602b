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
from scipy import ndimage

from vehicle.agent.monitor import Monitor, Observation
from vehicle.agent.settings import Settings
from vehicle.mapping import planning
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.modes import Kind
from vehicle.sim.autopilot import Autopilot
from vehicle.sim.avoidance import MARGIN as AVOID_MARGIN
from vehicle.sim.sensors import Servo

PLAN_MARGINS = (15.0, 40.0)  # m around start and goal that planning searches, the small window first
UNSEEN_EXTENT = 1.0  # m: unknown cells this close to an obstacle are presumed to be more of it


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
    started: float = 0.0  # when the mission was started (simulated time)
    observation: Observation | None = None
    say: Callable[[str], None] = print
    planned_path: list[tuple[float, float]] = field(default_factory=list)  # for display
    servo: Servo | None = None  # a servo turning the sonar, if the vehicle has one

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

    def inside(self, point: tuple[float, float], margin: float = 1.0) -> bool:
        """Whether the point lies in the allowed space around home (with a margin)."""
        half = self.settings.space_size - margin
        return abs(point[0] - self.home[0]) <= half and abs(point[1] - self.home[1]) <= half

    @property
    def time_left(self) -> float:
        return self.settings.time_limit - (self.time - self.started)

    # ---- planning on the memory map ------------------------------------------------------------
    def plan(self, goal: tuple[float, float], relax: bool = False,
             level: int = 0) -> tuple[list[tuple[float, float]] | None, int]:
        """A path (scene metres, excluding the current position) to ``goal`` around known obstacles.

        Searches a window around start and goal first (fast), then a wider one.
        Obstacles are grown by the body radius plus the padding (at least twice the
        margin the autopilot's avoidance keeps, so the two never disagree); a
        vehicle that is already closer first escapes the shortest way out. If the
        goal sits inside that margin, it retries with the avoidance margin only.
        With ``relax`` (going home), an unreachable goal is tried again without
        presuming unseen obstacles: getting home along a tight path beats not
        getting home. Returns the path (None if there is none) and the level of
        relaxation that found it, to start from next time.
        """
        start_cell = self.map.cell_of(*self.position)
        goal_cell = self.map.cell_of(*goal)
        if start_cell is None or goal_cell is None:
            return None, level
        if level == 0 and self.path_clear([goal], horizon=math.inf, padding=self.settings.padding):
            return [goal], level  # in the open: no search needed
        attempts = [(self.settings.padding, True), (0.0, True)] + ([(0.0, False)] if relax else [])
        for index, (padding, presume) in enumerate(attempts[level:], start=level):
            for wider, margin in enumerate(PLAN_MARGINS):
                window = self._window(start_cell, goal_cell, margin)
                try:  # a wider window is tried when a smaller one had no path: there may be none
                    cells = self._plan_in(start_cell, goal_cell, padding, window, presume, doubtful=wider > 0)
                except planning.NoPath as failure:
                    if failure.reason == planning.UNREACHABLE:
                        continue  # a wider window may find a way round
                    break  # start or goal inside the padding: try with less
                points = [self.map.center_of(r, c) for r, c in cells[1:]]
                if points:
                    points[-1] = goal
                return points or [goal], index
            else:
                if not relax:
                    return None, level  # less padding would only squeeze through gaps never seen
        return None, level

    def margin_cells(self, padding: float) -> float:
        """How far paths keep from obstacles, in cells: the body radius plus padding, and at least twice the
        margin of the autopilot's avoidance, so that a planned path never runs into the avoidance's stop."""
        return (self.radius + max(padding, 2 * AVOID_MARGIN)) * self.map.resolution

    def _window(self, a: tuple[int, int], b: tuple[int, int], margin_m: float) -> tuple[slice, slice]:
        """The rows and columns within ``margin_m`` of the box around cells a and b."""
        margin = int(margin_m * self.map.resolution)
        r0, r1 = max(0, min(a[0], b[0]) - margin), min(self.map.size, max(a[0], b[0]) + margin + 1)
        c0, c1 = max(0, min(a[1], b[1]) - margin), min(self.map.size, max(a[1], b[1]) + margin + 1)
        return slice(r0, r1), slice(c0, c1)

    def blocked_in(self, rows: slice, cols: slice, presume: bool = True) -> np.ndarray:
        """Cells to plan around in a window: obstacles, and unknown cells right next to them.

        A sonar sees a wall only where it faces the beam; the part of a wall that
        runs along the path stays unknown until the vehicle is beside it. So the
        unknown surroundings of what was seen are presumed to be more of it, and
        paths keep that much further away until the sonar shows them free.
        """
        occupied = self.map.occupied_in(rows, cols)
        if not presume:
            return occupied
        presumed = planning.inflate(occupied, UNSEEN_EXTENT * self.map.resolution)
        return occupied | (presumed & ~self.map.free_in(rows, cols))

    def _plan_in(self, start, goal, padding: float, window, presume: bool, doubtful: bool = False) -> np.ndarray:
        obstacles, offset = self.blocked_in(*window, presume), (window[0].start, window[1].start)
        local_start = (start[0] - offset[0], start[1] - offset[1])
        if presume:  # where the body is now is no presumed obstacle, whatever the sonar has not seen
            reach = int(math.ceil(self.radius * self.map.resolution))
            rows = slice(max(0, local_start[0] - reach), local_start[0] + reach + 1)
            cols = slice(max(0, local_start[1] - reach), local_start[1] + reach + 1)
            obstacles[rows, cols] &= self.map.occupied_in(slice(rows.start + offset[0], rows.stop + offset[0]),
                                                          slice(cols.start + offset[1], cols.stop + offset[1]))
        local_goal = (goal[0] - offset[0], goal[1] - offset[1])
        local = planning.plan(obstacles, local_start, local_goal, self.margin_cells(padding), doubtful)
        return local + np.array(offset)

    def path_clear(self, points: list[tuple[float, float]], horizon: float = 15.0, padding: float = 0.0) -> bool:
        """Whether the polyline from here through ``points`` keeps clear of known obstacles (by ``padding``).

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
        pad = int(math.ceil(self.margin_cells(padding))) + 1
        r0, r1 = max(0, min(rows) - pad), min(self.map.size, max(rows) + pad + 1)
        c0, c1 = max(0, min(cols) - pad), min(self.map.size, max(cols) + pad + 1)
        obstacles = self.blocked_in(slice(r0, r1), slice(c0, c1))
        blocked = planning.inflate(obstacles, self.margin_cells(padding))
        local = [(r - r0, c - c0) for r, c in cells]
        if blocked[local[0]]:
            # the vehicle is already within the margin of an obstacle (it stopped near a wall):
            # the first leg may cross the margin to get out, as long as it never gets any closer
            exit_cell = self._leave_margin(local[0], local[1], blocked, obstacles)
            if exit_cell is None:
                return False
            local[0] = exit_cell
        return all(planning.line_is_clear(blocked, a, b) for a, b in zip(local, local[1:], strict=False))

    @staticmethod
    def _leave_margin(a: tuple[int, int], b: tuple[int, int], blocked: np.ndarray,
                      obstacles: np.ndarray) -> tuple[int, int] | None:
        """The first cell on the way from a to b out of the margin; None if on the way there the
        distance to the nearest obstacle ever shrinks below where it started."""
        distance = ndimage.distance_transform_edt(~obstacles)
        start = distance[a]
        steps = max(abs(b[0] - a[0]), abs(b[1] - a[1]))
        for k in range(1, steps + 1):
            cell = (a[0] + round((b[0] - a[0]) * k / steps), a[1] + round((b[1] - a[1]) * k / steps))
            if distance[cell] < start - 0.5:
                return None
            if not blocked[cell]:
                return cell
        return b

    def is_clear(self, point: tuple[float, float], padding: float | None = None) -> bool:
        """Whether the body (plus padding) would fit at ``point`` without touching a known obstacle."""
        cell = self.map.cell_of(*point)
        if cell is None:
            return False
        radius = self.margin_cells(self.settings.padding if padding is None else padding)
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

    def resume(self) -> None:
        """The operator handed control back: send again whatever the mission was doing."""
        for routine in (getattr(self, "scan", None), getattr(self, "travel", None)):
            if routine is not None:
                routine.resume()

    def stop(self) -> None:
        """Halt in place (GUIDED: hold the current position)."""
        x, y = self.ctx.position
        self.ctx.vehicle.goto(x, y, self.ctx.settings.altitude if self.ctx.kind is Kind.COPTER else None)
