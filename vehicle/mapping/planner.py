"""Planning on the memory map: paths that keep clear of what the sonar saw, and checks of lines and spots.

``MapPlanner`` answers the questions a mission asks of its map: a path from
here to there around known obstacles (A* in a window around both, see
``planning``), whether a polyline or a spot is clear, and with how much
margin. Obstacles are grown by the body radius plus a padding, and by at
least twice the margin the autopilot's own obstacle avoidance keeps, so a
planned path never runs into the autopilot's stop.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from vehicle.mapping import planning
from vehicle.mapping.memory_map import MemoryMap

PLAN_MARGINS = (15.0, 40.0)  # m around start and goal that planning searches, the small window first
UNSEEN_EXTENT = 1.0  # m: unknown cells this close to an obstacle are presumed to be more of it
DOORWAY_CLEARANCE = 0.05  # m between the body and an obstacle's cell when nothing wider gets through
SQUEEZE_REACH = 1.0  # m around a doorway within which a path keeps only that clearance
SQUEEZE_STEP = 0.5  # cells: the clearances tried through a doorway, widest first, step by step

Point = tuple[float, float]


class MapPlanner:
    def __init__(self, memory_map: MemoryMap, radius: float, avoid_margin: float = 0.0):
        self.map = memory_map
        self.radius = radius  # of the vehicle body, m
        self.avoid_margin = avoid_margin  # m the autopilot's avoidance keeps from echoes
        self.reason = ""  # why the last plan found no path
        self.clearance = 0.0  # m beyond the body the last path keeps where it passes closest (a doorway)

    def plan(self, start: Point, goal: Point, padding: float, relax: bool = False,
             level: int = 0) -> tuple[list[Point] | None, int]:
        """A path (scene metres, excluding ``start``) to ``goal`` around known obstacles, ``padding`` m clear.

        Tries, from ``level`` on: obstacles grown by the body radius plus the padding, with unseen
        obstacles presumed beside the seen ones; then the body plus ``DOORWAY_CLEARANCE`` only (a
        doorway the body fits through); then that without presuming unseen obstacles. Each in a
        window around start and goal (fast), a wider one, and the whole map, so a way round that
        leaves the windows is still found. A vehicle that is already too close first escapes the
        shortest way out. ``relax`` is kept for callers going home (every goal now gets every level).
        Returns the path (None if there is none, and then ``reason`` says why) and the level that found
        it, to start from next time.
        """
        self.reason = ""
        self.clearance = max(padding, 2 * self.avoid_margin)
        start_cell = self.map.cell_of(*start)
        goal_cell = self.map.cell_of(*goal)
        if goal_cell is None:
            self.reason = "the target is outside the map"
            return None, level
        if start_cell is None:  # off the map (a vehicle that just left its space): straight back onto it first
            entry = self._entry(start, goal)
            path, level = self.plan(entry, goal, padding, relax, level)
            return (None if path is None else [entry, *path]), level
        if level == 0 and self.path_clear(start, [goal], horizon=math.inf, padding=padding):
            return [goal], level  # in the open: no search needed
        attempts = [(self.margin_cells(padding), True), (self.margin_cells(0.0), True), (self.margin_cells(0.0), False)]
        if 1.0 / self.map.resolution > self.radius:  # cells wider than the body resolve no doorway, and on a map
            attempts = attempts[:1]  # this coarse a gap between the walls seen is a wall missed as often as not
        for index, (margin, presume) in enumerate(attempts[level:], start=level):
            for wider, window in enumerate(self._windows(start_cell, goal_cell)):
                try:  # a wider window is tried when a smaller one had no path: there may be none
                    cells = self._plan_in(start_cell, goal_cell, margin, window, presume, doubtful=wider > 0)
                except planning.NoPath as failure:
                    if failure.reason == planning.UNREACHABLE:
                        continue  # a wider window may find a way round
                    break  # start or goal inside the margin: try with less
                if index > 0:  # squeezed through somewhere: keep the wide clearance everywhere else
                    cells, margin = self._widen(cells, start_cell, goal_cell, window, presume, attempts[0][0], margin)
                self.clearance = margin / self.map.resolution - self.radius
                points = [self.map.center_of(r, c) for r, c in cells[1:]]
                if points:
                    points[-1] = goal
                return points or [goal], index
        self.reason = self._why_not(start_cell, goal_cell, attempts[-1][0])
        return None, level

    def _widen(self, cells: np.ndarray, start, goal, window, presume: bool, wide: float,
               tight: float) -> tuple[np.ndarray, float]:
        """The path planned again with less than the wide clearance allowed only within ``SQUEEZE_REACH`` of
        where the tight path had to pass closer than the wide clearance (a doorway), and the wide one
        everywhere else: a path squeezed through one doorway must not hug every wall on its way. There it keeps
        the widest clearance that gets through, tried from the wide one down in steps of ``SQUEEZE_STEP``: the
        middle of the doorway, not along its frame. Returns the path and that clearance (cells); the tight
        path and clearance if none.

        Had to: no cell with the wide clearance lies within the difference of the two clearances (the wide
        one and the one tried) of it (beside a wall, one step aside gives the wide clearance; in a doorway
        none does); and at its start and end. The wide clearance presumes the unseen surroundings of seen walls
        to be more wall, as the first attempt does: a sonar sees no wall it meets at a glancing angle, so a
        path must not graze one."""
        obstacles, offset = self.blocked_in(*window, presume), np.array((window[0].start, window[1].start))
        wide_zone = planning.inflate(self.blocked_in(*window, True), wide)  # unseen walls presumed, as at first
        local = cells - offset
        legs = [np.rint(np.linspace(a, b, int(np.abs(b - a).max()) + 1)).astype(int)
                for a, b in zip(local[:-1], local[1:], strict=True)]
        walk = np.concatenate(legs) if legs else local
        local_start, local_goal = tuple(int(v) for v in start - offset), tuple(int(v) for v in goal - offset)
        for margin in np.arange(wide - SQUEEZE_STEP, tight, -SQUEEZE_STEP).tolist() + [tight]:
            # the widest clearance that still gets through: the middle of the doorway, not along one frame
            bottleneck = wide_zone & ~planning.inflate(~wide_zone, wide - margin + 1.0)
            squeezed = np.zeros_like(obstacles)
            on_walk = bottleneck[walk[:, 0], walk[:, 1]]
            squeezed[walk[on_walk, 0], walk[on_walk, 1]] = True
            squeezed[tuple(local[0])] = squeezed[tuple(local[-1])] = True  # leaving a wall, reaching a goal by one
            allowed = planning.inflate(squeezed, SQUEEZE_REACH * self.map.resolution) | squeezed
            grid = (wide_zone & ~allowed) | planning.inflate(obstacles, margin)
            if grid[local_start] or grid[local_goal]:
                continue
            try:
                return planning.smooth(planning.astar(grid, local_start, local_goal), grid) + offset, margin
            except planning.NoPath:
                continue
        return cells, tight

    def _windows(self, a: tuple[int, int], b: tuple[int, int]):
        """The windows planning searches, smallest first, the whole map last (each once)."""
        seen = set()
        for margin in PLAN_MARGINS:
            window = self._window(a, b, margin)
            key = (window[0].start, window[0].stop, window[1].start, window[1].stop)
            if key not in seen:
                seen.add(key)
                yield window
        if (0, self.map.size, 0, self.map.size) not in seen:
            yield slice(0, self.map.size), slice(0, self.map.size)

    def _why_not(self, start: tuple[int, int], goal: tuple[int, int], margin: float) -> str:
        """Why no path joins start and goal at the smallest clearance, with no unseen obstacles presumed."""
        occupied = self.map.occupied
        if occupied[goal]:
            return "the target is on an occupied cell"
        inflated = planning.inflate(occupied, margin)
        if inflated[goal]:
            return f"the target is within {margin / self.map.resolution:.2f} m of a known obstacle"
        labels, _ = ndimage.label(~inflated, structure=np.ones((3, 3)))
        if labels[start] == 0:  # the body is within the clearance: where it can escape to
            if occupied[start]:
                return "the vehicle is inside a known obstacle"
            try:
                escape = planning._escape(occupied, inflated, start)[-1]
            except planning.NoPath:
                return "the vehicle is boxed in by known obstacles, too close to them to move"
            start = (int(escape[0]), int(escape[1]))
        if labels[start] == labels[goal]:
            return "no path (only through a gap where a corner is cut)"
        sizes = np.bincount(labels.ravel())
        edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
        if labels[goal] not in edge and sizes[labels[goal]] <= sizes[labels[start]]:
            return "the target is enclosed by known obstacles"
        return "the vehicle is enclosed by known obstacles"

    def _entry(self, outside: Point, inside: Point) -> Point:
        """Where the line from a point off the map to one on it comes onto the map, a tenth of a cell in."""
        inset, extent = 0.1 / self.map.resolution, self.map.size / self.map.resolution
        t = 0.0  # how far along the line it comes in: past the last edge it crosses inwards
        for axis in (0, 1):
            low, high = self.map.origin[axis] + inset, self.map.origin[axis] + extent - inset
            step = inside[axis] - outside[axis]
            if outside[axis] < low < inside[axis] or outside[axis] > high > inside[axis]:
                edge = low if outside[axis] < low else high
                t = max(t, (edge - outside[axis]) / step)
        return outside[0] + t * (inside[0] - outside[0]), outside[1] + t * (inside[1] - outside[1])

    def margin_cells(self, padding: float) -> float:
        """How far paths keep from obstacles, in cells: the body radius plus padding, and at least twice the
        margin of the autopilot's avoidance, so that a planned path never runs into the avoidance's stop.
        Padding 0 is the least clearance planning accepts: the body plus ``DOORWAY_CLEARANCE`` (a doorway
        0.8 m wide or more at 10 cells/m for a 0.3 m body; the autopilot's avoidance holds back only an
        echo the line passes within its margin less its graze, 0.35 m, so it lets the body through)."""
        if padding <= 0:
            return (self.radius + DOORWAY_CLEARANCE) * self.map.resolution
        return (self.radius + max(padding, 2 * self.avoid_margin)) * self.map.resolution

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

    def _plan_in(self, start, goal, margin: float, window, presume: bool, doubtful: bool = False) -> np.ndarray:
        obstacles, offset = self.blocked_in(*window, presume), (window[0].start, window[1].start)
        local_start = (start[0] - offset[0], start[1] - offset[1])
        if presume:  # where the body is now is no presumed obstacle, whatever the sonar has not seen
            reach = int(math.ceil(self.radius * self.map.resolution))
            rows = slice(max(0, local_start[0] - reach), local_start[0] + reach + 1)
            cols = slice(max(0, local_start[1] - reach), local_start[1] + reach + 1)
            obstacles[rows, cols] &= self.map.occupied_in(slice(rows.start + offset[0], rows.stop + offset[0]),
                                                          slice(cols.start + offset[1], cols.stop + offset[1]))
        local_goal = (goal[0] - offset[0], goal[1] - offset[1])
        local = planning.plan(obstacles, local_start, local_goal, margin, doubtful)
        return local + np.array(offset)

    def path_clear(self, start: Point, points: list[Point], horizon: float = 15.0, padding: float = 0.0) -> bool:
        """Whether the polyline from ``start`` through ``points`` keeps clear of known obstacles (by ``padding``).

        Only the first ``horizon`` metres are checked: that is where new obstacles
        matter now, and the rest is checked again as the vehicle gets there.
        """
        margin = self.margin_cells(padding)
        chain = [start]
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
        pad = int(math.ceil(margin)) + 1
        r0, r1 = max(0, min(rows) - pad), min(self.map.size, max(rows) + pad + 1)
        c0, c1 = max(0, min(cols) - pad), min(self.map.size, max(cols) + pad + 1)
        obstacles = self.blocked_in(slice(r0, r1), slice(c0, c1))
        blocked = planning.inflate(obstacles, margin)
        local = [(r - r0, c - c0) for r, c in cells]
        if blocked[local[0]]:
            # the vehicle is already within the margin of an obstacle (it stopped near a wall):
            # the first leg may cross the margin to get out, as long as it never gets any closer
            exit_cell = _leave_margin(local[0], local[1], blocked, obstacles)
            if exit_cell is None:
                return False
            local[0] = exit_cell
        return all(planning.line_is_clear(blocked, a, b) for a, b in zip(local, local[1:], strict=False))

    def is_clear(self, point: Point, padding: float) -> bool:
        """Whether the body (plus padding) would fit at ``point`` without touching a known obstacle."""
        cell = self.map.cell_of(*point)
        if cell is None:
            return False
        radius = self.margin_cells(padding)
        reach = int(math.ceil(radius))
        r0, c0 = max(0, cell[0] - reach), max(0, cell[1] - reach)
        window = self.map.occupied_in(slice(r0, cell[0] + reach + 1), slice(c0, cell[1] + reach + 1))
        rows, cols = np.nonzero(window)
        return not np.any((rows + r0 - cell[0]) ** 2 + (cols + c0 - cell[1]) ** 2 <= radius * radius)


def _leave_margin(a: tuple[int, int], b: tuple[int, int], blocked: np.ndarray,
                  obstacles: np.ndarray) -> tuple[int, int] | None:
    """The first cell on the way from a to b out of the margin; None if on the way there the distance to the
    nearest obstacle ever shrinks below where it started."""
    from scipy import ndimage

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
