"""Search: scan, then head for a far detection with open space beside it, and scan again there.

As in the thesis, the next goal comes from the latest sweep: the echo that is
far away and has the most open space beside it wins (a weighted score), and
the vehicle aims beside it and short of it by a stand-off distance rather than
onto it, which keeps it around the outside of objects. We add two things: goals
near places already visited are not considered, and goals among unknown cells
score higher, so it keeps finding new ground (the next room, the far side of a
building). It ends when no goal is left, or when its time budget is spent.
In a team each vehicle keeps to the goals nearer to it than to any team-mate
(a Voronoi split on where they are now), so the team spreads out.

Which sweep headings lie in the arcs beside each echo is one loop over all
pairs of a sweep (a few hundred readings): numpy built it from a dozen n x n
temporaries, a tenth of a Search's time, so the loop is compiled with numba.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vehicle.agent.missions.base import Mission, Status
from vehicle.agent.missions.routines import Scan, ServoScan, Travel, scan
from vehicle.agent.monitor import sweep_profile
from vehicle.agent.traffic import someone_elses
from vehicle.mapping import frontier

OPEN_ARC = (math.radians(10), math.radians(40))  # where "beside" an echo is, either side
OPEN_WEIGHT = 0.5
UNKNOWN_WEIGHT = 20.0  # m of score for a goal surrounded by nothing but unknown cells
UNKNOWN_RADIUS = 3.0  # m around a goal looked at for unknown cells
VISITED_FRACTION = 0.2  # goals closer to an earlier goal or scan spot than this share of space_size are skipped
VISITED_MAX = 6.0  # m, whatever the space size
MIN_LEG = 1.0  # m: goals closer than this are not worth a trip
LOOKED_RADIUS = 1.0  # m: frontier cells this near a spot scanned from (or a goal given up on) stay unknown to the sonar
NEAR_FRONTIER = 10.0  # m: the nearest frontier is first looked for this far around the vehicle (by path) ...
NEAR_MARGIN = 5.0  # m: ... in a square this much wider
TIE = 1e-9  # m: arcs whose mean free distances differ by less are equally open (whatever the rounding)


class Search(Mission):
    name = "search"

    def begin(self) -> None:
        self.scan: Scan | ServoScan | None = scan(self.ctx)
        self.travel: Travel | None = None
        self.visited: list[tuple[float, float]] = [self.ctx.position]
        self.visited_radius = min(VISITED_MAX, VISITED_FRACTION * self.ctx.settings.space_size)
        self.legs = 0
        self.looked: list[tuple[float, float]] = []  # spots scanned from and frontier goals given up on

    def step(self) -> Status:
        if self.scan is not None:
            if not self.scan.step():
                return Status.RUNNING
            return self._after_scan(self.scan.readings)
        status = self.travel.step()
        if status is Status.RUNNING:
            return status
        if status is Status.STOPPED:
            self.looked.append(self.travel.goal)  # no way there: not a frontier to try again
        self.scan = scan(self.ctx)  # arrived, or no way there: look around again
        self.visited.append(self.ctx.position)
        return Status.RUNNING

    def _after_scan(self, readings) -> Status:
        self.scan = None
        self.looked.append(self.ctx.position)
        goal = self.choose_goal(readings) or self.nearest_frontier()
        if goal is None:
            self.reason = "no open direction left to search: no reachable frontier left"
            return Status.DONE
        self.legs += 1
        self.visited.append(goal)
        self.travel = Travel(self.ctx, goal, self.ctx.settings.closeness)
        return Status.RUNNING

    def choose_goal(self, readings) -> tuple[float, float] | None:
        """The stand-off point beside the best-scoring echo of the sweep, or None.

        An echo scores its distance, plus OPEN_WEIGHT times the mean free distance
        of the more open arc beside it, plus UNKNOWN_WEIGHT times the share of
        unknown cells around its goal. Echoes are tried best first by the most
        they could score, so the map is consulted only for the few that can win.
        """
        ctx = self.ctx
        band = ctx.map.band
        readings = [r for r in readings if r.distance is None or abs(r.hit[2] - r.origin[2]) <= band]
        headings, distances = sweep_profile(readings)
        if not len(headings):
            return None
        reach = min(ctx.settings.farness, max(r.max_range for r in readings))
        free = np.minimum(distances, reach)
        standoff = ctx.settings.closeness + ctx.radius + ctx.settings.padding
        left = _means_in_arcs(headings, free, -OPEN_ARC[1], -OPEN_ARC[0])
        right = _means_in_arcs(headings, free, OPEN_ARC[0], OPEN_ARC[1])
        promise = distances + OPEN_WEIGHT * np.maximum(left, right)  # the score without the unknown share
        x, y = ctx.position
        best, best_score, best_index = None, -math.inf, len(headings)
        for i in np.argsort(-(promise + UNKNOWN_WEIGHT), kind="stable"):  # best possible first, ties in order
            heading, distance = headings[i], distances[i]
            if promise[i] + UNKNOWN_WEIGHT < best_score:
                break  # no later echo can beat the best one
            if not np.isfinite(distance) or distance - standoff < MIN_LEG:
                continue
            side = 1.0 if right[i] >= left[i] - TIE else -1.0  # +1: clockwise of the echo (also on a tie)
            ux, uy = math.sin(heading), math.cos(heading)
            sx, sy = side * uy, -side * ux  # perpendicular towards the open side
            goal = (x + ux * (distance - standoff) + sx * standoff, y + uy * (distance - standoff) + sy * standoff)
            if any(math.hypot(goal[0] - vx, goal[1] - vy) < self.visited_radius for vx, vy in self.visited):
                continue
            if not ctx.is_clear(goal) or not ctx.inside(goal) or someone_elses(ctx, goal):
                continue
            score = promise[i] + UNKNOWN_WEIGHT * self._unknown_around(goal)
            if score > best_score or (score == best_score and i < best_index):
                best, best_score, best_index = goal, score, i
        return best

    def nearest_frontier(self) -> tuple[float, float] | None:
        """The nearest point by path where known-free space meets unknown space (``vehicle.mapping.frontier``)
        inside the allowed space and not in a team-mate's share; when every one left is in a team-mate's
        share, the nearest of those (a share is where each is now, and shares change as the team moves: a
        vehicle that ended here would leave its team-mates the rest, as the one in the middle of a team of
        eight did a quarter of a minute after take-off); None when no frontier is left at all."""
        ctx = self.ctx
        m = ctx.map
        half = ctx.settings.space_size - 1.0  # as ``ctx.inside``
        box = (ctx.home[0] - half, ctx.home[1] - half, ctx.home[0] + half, ctx.home[1] + half)
        done = max(ctx.settings.closeness, LOOKED_RADIUS) + 1.0 / m.resolution  # a goal counts as reached that far
        min_cells = max(1, math.ceil(2 * ctx.radius * m.resolution))  # a frontier narrower than the body
        x, y = ctx.position
        side = NEAR_FRONTIER + NEAR_MARGIN
        near = (max(box[0], x - side), max(box[1], y - side), min(box[2], x + side), min(box[3], y + side))
        # first around the vehicle (a path no longer than NEAR_FRONTIER stays within it, and the margin holds
        # what decides a frontier's goal there: the walls a body keeps clear of, the unknown beside it, the rest
        # of the frontier), then the whole map: a team's shared map is the team's whole area, and the search
        # over it was half of a team's time. Near, only the frontiers whose roomy goal lies within that reach
        # are looked at; for any other (goals looked from, gaps) the whole map decides
        nearest = None
        for area, within in ((near, NEAR_FRONTIER * m.resolution), (box, math.inf)):
            for found in frontier.on_map(m, ctx.position, ctx.planner.margin_cells(0.0), min_cells, area,
                                         self.looked, done, limit=within):
                goal = m.center_of(*found.goal)
                if not someone_elses(ctx, goal):
                    return goal
                nearest = nearest or goal
        if nearest is not None:
            self.ctx.say(f"Search: nothing left to search in this vehicle's share; helping at ({nearest[0]:.1f}, "
                         f"{nearest[1]:.1f})")
        return nearest

    def _unknown_around(self, point: tuple[float, float]) -> float:
        """Share of the cells within UNKNOWN_RADIUS of the point that are neither free nor occupied."""
        m = self.ctx.map
        cell = m.cell_of(*point)
        reach = int(UNKNOWN_RADIUS * m.resolution)
        rows = slice(max(0, cell[0] - reach), cell[0] + reach + 1)
        cols = slice(max(0, cell[1] - reach), cell[1] + reach + 1)
        window = m.grid[rows, cols]
        return float(np.count_nonzero((window > m.FREE_AT) & (window < m.OCCUPIED_AT))) / max(window.size, 1)

    def too_close(self) -> Status:
        """Close to a new object: stop and scan again from here (a frontier goal is not tried again)."""
        self.stop()
        if self.travel is not None:
            self.looked.append(self.travel.goal)
        self.travel = None
        self.scan = scan(self.ctx)
        self.visited.append(self.ctx.position)
        return Status.RUNNING

    def out_of_time(self) -> Status:
        self.reason = f"search time used ({self.legs} legs)"
        return Status.DONE


def _means_in_arcs(headings: np.ndarray, values: np.ndarray, start: float, end: float) -> np.ndarray:
    """For each heading h, the mean of the values whose heading lies in the arc [h + start, h + end]
    (radians, any period), 0 where none does."""
    inside, count = _arc_mask(np.ascontiguousarray(headings, dtype=np.float64), float(start), float(end))
    return np.where(count > 0, (inside @ values) / np.maximum(count, 1), 0.0)


@numba.njit(cache=True)
def _arc_mask(headings, start, end):
    """inside[i, j] = 1.0 where heading j lies in the arc of heading i, that is where
    ``(h[j] - (h[i] + start)) % 2pi <= (h[i] + end) - (h[i] + start)``, and the count of each row. As float64,
    so that ``inside @ values`` multiplies the same matrix numpy made of a boolean mask."""
    n = len(headings)
    inside = np.zeros((n, n))
    count = np.zeros(n, dtype=np.int64)
    turn = 2 * math.pi
    for i in range(n):
        low = headings[i] + start
        width = (headings[i] + end) - low
        for j in range(n):
            if _wrap(headings[j] - low, turn) <= width:
                inside[i, j] = 1.0
                count[i] += 1
    return inside, count


@numba.njit(cache=True)
def _wrap(x, turn):
    """Python's ``x % turn`` (turn > 0) without a call to fmod where |x| < 2 turn: fmod is then x, x - turn
    or x + turn, each exact (Sterbenz), and Python adds turn to a negative remainder."""
    if 0.0 < x < turn:
        return x
    if x == 0.0:
        return 0.0  # +0.0, as Python gives for -0.0 too
    if turn <= x < 2.0 * turn:
        return x - turn
    if -turn <= x < 0.0:
        return x + turn
    if -2.0 * turn < x < -turn:
        return (x + turn) + turn
    return x % turn
