"""Where a team's radios stop next to image a region: the uncertainty-driven plan, or the perimeter plan.

Uncertainty-driven (a greedy D-optimal design): the reconstruction is linear-Gaussian (vehicle.tomography.solvers:
a prior covariance C over the pixels, measurements y = W x + noise), so the posterior covariance
P = (C^-1 + W^T W / noise)^-1 depends only on WHICH links were measured, never on what they read. Every agent of
a team can therefore compute the same plan from the same history of positions, exchanging no measurements. The
next step is the pair of candidate spots whose link w has the largest posterior variance w^T P w (the information
it brings, log(1 + w^T P w / noise), is largest), per square root of the seconds of flying there and dwelling;
P then takes the rank-one update of that link, and the next step looks where the image is least sure of now.
Why the square root: a greedy step by information alone flies across the ring for every link, and one by
information per second (the cost-benefit greedy of budgeted design) hops between neighbouring spots and piles
its links into the few directions near the vehicles; either alone is known to do badly on some designs, and the
square root weighs the two. Over the bench's 50 one-target runs it found 48 (46 per second), sooner (median 113 s,
128 s per second) and closer (median error 0.21 m, 0.24 m). Why D-optimal: the A-optimal step (the link that most
lowers the sum of the pixels' variances) found 50 single targets of 50, but two people 1.5 m apart in 15 runs of
20 (18), and people with a narrow shadow on the synthetic model in 24 of 40 (33); a step restricted to the links
through the pixel least sure found 49 and 13 of 20 (7 December).
Why its links run in the perimeter plan's four directions only (within ``ALONG`` degrees of 0, 45, 90 or 135): the
image finds a person where the attenuated links cross, and the sparse solve splits a person between the crossings
of links that come from a few close directions (the greedy step's two misses of 50 single targets had two peaks
0.47 and 0.6 m either side of the person). Four directions 45 degrees apart, as computed tomography's parallel
projections, cross every spot from angles that tell it from those crossings; the greedy step still chooses which
lines and where. On the bench: 50 single targets of 50 (48 with links in any direction, the same median time,
108 s), two people 1.5 m apart in 35 runs of 40 (32); within 10 degrees, 50 and 15 of 20 (7 December). A third
vehicle's spot, and a spot against fixed nodes, are chosen from all directions.

Perimeter (the obvious plan, laid as in computed tomography): parallel lines across the region in ``FAMILIES``
directions (north-south, east-west and the two diagonals), each family's lines evenly spaced across the region,
the mission's rounds shared evenly among them; each line's two spots are the ring's spots nearest its ends. With
two directions only (the plan before), two targets make four crossings that the lines cannot tell apart (the
ghosts of a two-angle grid); every further direction sees the pair from a side where the ghosts lie off its lines.

Candidate spots lie on a ring around the region (its bounds grown by ``offset``), every ``spacing`` metres, kept
where the scene leaves room for a body; the two spots of a pair are at least ``apart`` metres from each other.
With more than two vehicles, each further spot is chosen the same greedy way against the spots already chosen;
with fixed radio nodes, every chosen spot's links to them count too.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.linalg import blas
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from vehicle.tomography.weights import Grid, WeightCache

CORRELATION = 0.5  # m: the prior's correlation distance (as the imaging's)
NOISE = 0.5  # a link's noise variance, in units of a pixel's prior variance
CELL = 0.3  # m: the planner's pixel (coarser than an image's: the plan needs where, not detail) ...
MAX_SIDE_PIXELS = 36  # ... and at most this many along the longer side: P holds pixels^2 numbers
PLANNERS = ("uncertainty", "perimeter")
FAMILIES = 4  # directions of the perimeter plan's lines: 0, 45, 90 and 135 degrees
ALONG = 5.0  # degrees: the uncertainty-driven step's links run this near one of the FAMILIES directions

Point = tuple[float, float]


def ring(bounds: tuple[float, float, float, float], offset: float, spacing: float) -> np.ndarray:
    """(n, 2) spots every ``spacing`` m (at most) round the rectangle ``bounds`` grown by ``offset``,
    anticlockwise from its south-west corner."""
    x0, y0, x1, y1 = bounds[0] - offset, bounds[1] - offset, bounds[2] + offset, bounds[3] + offset
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    spots = []
    for a, b in itertools.pairwise(corners):
        n = max(1, math.ceil(np.linalg.norm(b - a) / spacing))
        spots.extend(a + (b - a) * k / n for k in range(n))
    return np.array(spots)


def nearest_object(scene, start: Point, margin: float = 0.5) -> tuple[float, float, float, float]:
    """The ground footprint (bounds, grown by ``margin``) of the scene's object nearest ``start``; the ground
    itself (an object less than 0.2 m tall) is none."""
    triangles = np.asarray(scene.triangles).reshape(-1, 3, 3)
    owner = np.asarray(scene.face_object)
    best, footprint = math.inf, None
    for index in np.unique(owner):
        corners = triangles[owner == index].reshape(-1, 3)
        low, high = corners.min(axis=0), corners.max(axis=0)
        if high[2] - low[2] < 0.2:
            continue
        gap = math.hypot(max(low[0] - start[0], 0.0, start[0] - high[0]),
                         max(low[1] - start[1], 0.0, start[1] - high[1]))
        if gap < best:
            best, footprint = gap, (low[0] - margin, low[1] - margin, high[0] + margin, high[1] + margin)
    if footprint is None:
        raise ValueError("the scene has no object to image: give the region's bounds")
    return tuple(round(float(v), 3) for v in footprint)


class Planner:
    """The plan of one team round a region; every agent holds its own and, given the same history, computes
    the same next spots (see the module's docstring)."""

    def __init__(self, bounds: tuple[float, float, float, float], spots: np.ndarray, kind: str = "uncertainty",
                 fixed: list[Point] | None = None, apart: float = 2.6, dwell: float = 5.0, speed: float = 2.5,
                 rounds: int = 40):
        if kind not in PLANNERS:
            raise ValueError(f"unknown planner {kind!r} (one of {', '.join(PLANNERS)})")
        if len(spots) < 2:
            raise ValueError("fewer than two clear spots round the region: the scene leaves no room to fly round it")
        self.kind, self.bounds, self.spots = kind, bounds, np.asarray(spots, float)
        self.fixed = [tuple(map(float, p)) for p in (fixed or [])]
        self.apart, self.dwell, self.speed = apart, dwell, speed
        self.lines = perimeter_lines(bounds, self.spots, max(1, int(rounds)), apart) if kind == "perimeter" else []
        side = max(bounds[2] - bounds[0], bounds[3] - bounds[1])
        self.grid = Grid(bounds, max(CELL, side / MAX_SIDE_PIXELS))
        self.weights = WeightCache(self.grid)
        centres = self.grid.centres()
        self.P = np.exp(-cdist(centres, centres) / CORRELATION)  # the posterior covariance, the prior before any link
        self.steps = 0
        self.links = 0
        pairs = np.array([(i, j) for i, j in itertools.combinations(range(len(self.spots)), 2)
                          if np.linalg.norm(self.spots[i] - self.spots[j]) >= apart])
        self.pairs = pairs = along_families(self.spots, pairs)
        self._pair_rows = self.weights.matrix(np.hstack([self.spots[pairs[:, 0]], self.spots[pairs[:, 1]]]))
        self._pair_variance = self.variance_along(self._pair_rows)  # kept up to date by each rank-one update

    # ---- the posterior ----------------------------------------------------------------------
    def variance_along(self, rows) -> np.ndarray:
        """w^T P w for each row w (a sparse matrix of links x pixels)."""
        if not rows.shape[0]:
            return np.zeros(0)
        return np.asarray(rows.multiply(rows @ self.P).sum(axis=1)).ravel()

    def measured(self, a: Point, b: Point) -> None:
        """Take the link between ``a`` and ``b`` as measured: P's rank-one update."""
        w = self.weights.matrix(np.array([[*a, *b]], float)).toarray().ravel()
        if not w.any():
            return
        Pw = self.P @ w
        c = NOISE + w @ Pw
        blas.dger(-1.0 / c, Pw, Pw, a=self.P.T, overwrite_a=True)  # P -= Pw Pw^T / c, in place (P is symmetric)
        self._pair_variance -= (self._pair_rows @ Pw) ** 2 / c
        self.links += 1

    def uncertainty(self) -> float:
        """The mean posterior variance of the region's pixels (1 before any link)."""
        return float(np.mean(np.diag(self.P)))

    # ---- the next spots ---------------------------------------------------------------------
    def next_spots(self, previous: list[Point], known: bool = True) -> list[Point]:
        """Where the ``len(previous)`` vehicles stop next, in their order; the links among them and to the fixed
        nodes are then taken as measured. ``previous``: where each was, its spot of the last step, which every
        agent knows alike (``known``): the spots go to the vehicles with the least travel in all, and travel
        time counts in the choice. Not ``known`` (the first step, from where each agent sees the others now):
        travel does not count, and in their order each vehicle takes the spot nearest to it, so that one already
        on its way there keeps it whoever plans."""
        count = len(previous)
        if self.kind == "perimeter":
            chosen = self._perimeter(count)
        else:
            chosen = self._greedy(count, previous if known else None)
        spots = [tuple(float(v) for v in self.spots[i]) for i in chosen]
        if known:
            cost = np.array([[math.dist(p, s) for s in spots] for p in previous])
            spots = [spots[k] for k in linear_sum_assignment(cost)[1]]
        else:
            free, spots = spots, []
            for p in previous:
                spots.append(free.pop(min(range(len(free)), key=lambda k: (math.dist(p, free[k]), k))))
        for a, b in itertools.combinations(spots, 2):
            self.measured(a, b)
        for a in spots:
            for node in self.fixed:
                self.measured(a, node)
        self.steps += 1
        return spots

    def _greedy(self, count: int, previous: list[Point] | None) -> list[int]:
        """The pair (or, with fixed nodes, the spot) of most information per square root of the seconds it
        takes, then further spots the same way against those chosen."""
        travel = np.zeros(len(self.spots))
        if previous is not None:
            here = np.asarray(previous, float)
            travel = np.linalg.norm(self.spots[:, None, :] - here[None, :, :], axis=2).min(axis=1) / self.speed
        if self.fixed:
            chosen = [self._best_spot([], travel)]
        else:
            gain = np.log1p(np.maximum(self._pair_variance, 0.0) / NOISE)
            seconds = self.dwell + np.maximum(travel[self.pairs[:, 0]], travel[self.pairs[:, 1]])
            chosen = list(self.pairs[int(np.argmax(gain / np.sqrt(seconds)))])
        while len(chosen) < count:
            chosen.append(self._best_spot(chosen, travel))
        return chosen

    def _best_spot(self, chosen: list[int], travel: np.ndarray) -> int:
        """The spot, apart from those chosen, whose links to them and to the fixed nodes bring the most."""
        others = [tuple(self.spots[i]) for i in chosen] + self.fixed
        far = np.array([all(math.dist(s, self.spots[i]) >= self.apart for i in chosen) for s in self.spots])
        gain = np.zeros(len(self.spots))
        for other in others:
            rows = self.weights.matrix(np.array([[*s, *other] for s in self.spots], float))
            gain += np.log1p(self.variance_along(rows) / NOISE)
        return int(np.argmax(np.where(far, gain / np.sqrt(self.dwell + travel), -np.inf)))

    def _perimeter(self, count: int) -> list[int]:
        """Step k: the k-th line of the plan (again from the first when the mission goes on); further vehicles
        spread evenly round the ring from its first spot."""
        first, partner = self.lines[self.steps % len(self.lines)]
        n = len(self.spots)
        return [first, partner, *((first + k * n // count) % n for k in range(2, count))]


def along_families(spots: np.ndarray, pairs: np.ndarray, tolerance: float = ALONG) -> np.ndarray:
    """The pairs (rows of spot indices) whose line runs within ``tolerance`` degrees of one of the ``FAMILIES``
    directions; all of them if none does (a ring too small to hold such a pair)."""
    if not len(pairs):
        return pairs
    step = np.diff(spots[pairs], axis=1)[:, 0]
    family = math.pi / FAMILIES
    off = np.mod(np.arctan2(step[:, 1], step[:, 0]), family)
    keep = np.minimum(off, family - off) <= math.radians(tolerance) + 1e-9
    return pairs[keep] if keep.any() else pairs


def perimeter_lines(bounds, spots: np.ndarray, rounds: int, apart: float) -> list[tuple[int, int]]:
    """The perimeter plan: ``rounds`` lines (pairs of spot indices), shared evenly among ``FAMILIES`` directions,
    each family's lines evenly spaced across the region (the middles of equal strips), one family swept after
    the other, each from the end nearer where the last one ended."""
    x0, y0, x1, y1 = bounds
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
    centre = corners.mean(axis=0)
    lines: list[tuple[int, int]] = []
    for family in range(FAMILIES):
        count = rounds // FAMILIES + (family < rounds % FAMILIES)
        if not count:
            continue
        angle = math.pi * (0, 2, 1, 3)[family % 4] / 4 if FAMILIES == 4 else math.pi * family / FAMILIES
        normal = np.array([math.cos(angle), math.sin(angle)])  # across the lines; 0: north-south lines
        along = np.array([-normal[1], normal[0]])
        across = (corners - centre) @ normal
        low, high = across.min(), across.max()
        family_lines = []
        for k in range(count):
            middle = centre + normal * (low + (k + 0.5) * (high - low) / count)
            ends = [_nearest_on_ring(spots, middle, sign * along, normal) for sign in (-1, 1)]
            family_lines.append(_apart(spots, *ends, apart))
        if lines and _gap(spots, lines[-1], family_lines[-1]) < _gap(spots, lines[-1], family_lines[0]):
            family_lines.reverse()
        lines.extend(family_lines)
    return lines


def _nearest_on_ring(spots: np.ndarray, start: np.ndarray, direction: np.ndarray, normal: np.ndarray) -> int:
    """The spot nearest where the ray from ``start`` (inside the ring) along ``direction`` leaves the ring: of the
    spots ahead, the one nearest the line (the ring is convex, so the ray meets it once); of two as near, the one
    on the ``-normal`` side, for both ends of a line alike, so that the line keeps its direction."""
    offset = spots - start
    side = offset @ normal
    distance = np.where(offset @ direction > 0, np.round(np.abs(side), 6), np.inf)
    return int(np.lexsort((side, distance))[0])


def _apart(spots: np.ndarray, first: int, partner: int, apart: float) -> tuple[int, int]:
    """The pair, its partner moved along the ring until the two are ``apart``."""
    for _ in range(len(spots)):
        if np.linalg.norm(spots[partner] - spots[first]) >= apart:
            break
        partner = (partner + 1) % len(spots)
    return first, partner


def _gap(spots: np.ndarray, a: tuple[int, int], b: tuple[int, int]) -> float:
    """How far the two radios fly from line a to line b (each to the nearer end)."""
    pa, pb = spots[list(a)], spots[list(b)]
    return min(np.linalg.norm(pa - pb, axis=1).sum(), np.linalg.norm(pa - pb[::-1], axis=1).sum())
