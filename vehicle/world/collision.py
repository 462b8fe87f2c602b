"""Swept-sphere collision of the vehicle body against the scene mesh.

trimesh answers point-to-mesh distance through an R-tree at about a millisecond a
query, too slow for every simulation step (and too slow to import for a run); embreex offers no distance queries. So
this module keeps a coarse grid of triangles over the ground plane and measures
exact segment-to-triangle distances on the few triangles near the vehicle. Most
steps cost nothing: after each exact check the body is known to be clear of
everything within some radius, and until it leaves that ball no test is needed
(conservative advancement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

LARGE_SPAN = 64  # grid cells: triangles covering more are checked by their bounding box alone
WALKABLE_NORMAL_Z = 0.7  # faces flatter than ~45 degrees are ground a rover may drive on


@dataclass(frozen=True)
class Contact:
    point: np.ndarray  # body centre at first contact
    fraction: float  # how far along the step (0..1) the contact happened
    face: int  # index of the face touched (-1: another vehicle's body)
    vehicles: tuple[int, ...] = ()  # the system ids of both vehicles, when two bodies met

    def describe(self) -> str:
        x, y, z = self.point
        if self.vehicles:
            return f"collision of vehicles {self.vehicles[0]} and {self.vehicles[1]} at x={x:.2f} y={y:.2f} z={z:.2f}"
        return f"collision at x={x:.2f} y={y:.2f} z={z:.2f} (face {self.face})"


class TriangleGrid:
    """The scene's triangles binned by the ground-plane grid cells their bounding boxes overlap.

    Built once per scene and vehicle kind (a few milliseconds for ten thousand
    triangles) and shared by every collider in it: it never changes.
    """

    def __init__(self, geometry, ignore_walkable: bool = False, cell_size: float = 2.0):
        """``geometry``: a Scene or a trimesh (anything with ``triangles`` and ``face_normals``)."""
        self.cell_size = float(cell_size)
        triangles = np.asarray(geometry.triangles, dtype=np.float64).reshape(-1, 3, 3)
        face_ids = np.arange(len(triangles))
        if ignore_walkable and len(triangles):
            keep = np.asarray(geometry.face_normals)[:, 2] <= WALKABLE_NORMAL_Z
            triangles, face_ids = triangles[keep], face_ids[keep]
        self.triangles = triangles
        self.face_ids = face_ids
        self._lo = triangles.min(axis=1) if len(triangles) else np.zeros((0, 3))
        self._hi = triangles.max(axis=1) if len(triangles) else np.zeros((0, 3))
        self._grid = self._build_grid()
        self._blocks: dict[tuple[int, int, int, int], np.ndarray] = {}  # candidates by block of cells

    def _build_grid(self) -> dict[tuple[int, int], np.ndarray]:
        """Triangles by cell; big ones (ground planes) go in ``_large``, checked everywhere."""
        lo = np.floor(self._lo[:, :2] / self.cell_size).astype(np.int64)
        hi = np.floor(self._hi[:, :2] / self.cell_size).astype(np.int64)
        spans = hi - lo + 1
        count = spans.prod(axis=1)
        self._large = np.flatnonzero(count > LARGE_SPAN)
        small = np.flatnonzero(count <= LARGE_SPAN)
        # one (triangle, cell) pair per cell each small triangle overlaps, made without a Python loop
        triangle = np.repeat(small, count[small])
        k = np.arange(len(triangle)) - np.repeat(np.cumsum(count[small]) - count[small], count[small])
        i = lo[triangle, 0] + k // spans[triangle, 1]
        j = lo[triangle, 1] + k % spans[triangle, 1]
        if not len(triangle):
            return {}
        order = np.lexsort((triangle, j, i))
        i, j, triangle = i[order], j[order], triangle[order]
        breaks = np.flatnonzero((np.diff(i) != 0) | (np.diff(j) != 0)) + 1
        groups = np.split(triangle, breaks)
        firsts = np.concatenate(([0], breaks))
        return {(int(i[f]), int(j[f])): group for f, group in zip(firsts, groups, strict=True)}

    def candidates(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices of triangles whose bounding box overlaps the box [lo, hi]."""
        ids = self.near(lo, hi)
        overlap = np.all((self._lo[ids] <= hi) & (self._hi[ids] >= lo), axis=1)
        return ids[overlap]

    def near(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices of the triangles binned in the grid cells the box [lo, hi] covers on the ground plane (and
        the large ones): every triangle whose bounding box overlaps the box, and some more."""
        size = self.cell_size
        block = (math.floor(lo[0] / size), math.floor(lo[1] / size), math.floor(hi[0] / size),
                 math.floor(hi[1] / size))
        ids = self._blocks.get(block)
        if ids is None:  # the grid never changes: each block of cells is gathered once
            i0, j0, i1, j1 = block
            found = [self._grid[key] for i in range(i0, i1 + 1) for j in range(j0, j1 + 1)
                     if (key := (i, j)) in self._grid]
            found.append(self._large)
            ids = np.unique(np.concatenate(found))
            if len(self._blocks) >= 4096:
                self._blocks.clear()
            self._blocks[block] = ids
        return ids


class Collider:
    """Answers whether a sphere of ``radius`` moving from p0 to p1 touches the scene's triangles.

    Takes the scene (or a trimesh), or its ``TriangleGrid`` when several colliders share one.
    """

    def __init__(self, geometry, radius: float, ignore_walkable: bool = False, search: float = 4.0):
        self.grid = geometry if isinstance(geometry, TriangleGrid) else TriangleGrid(geometry, ignore_walkable)
        self.radius = float(radius)
        self.search = max(float(search), 2 * self.radius)
        self._triangles = self.grid.triangles
        self._anchor: np.ndarray | None = None
        self._safe = 0.0

    def clearance(self, point: np.ndarray) -> float:
        """Distance from ``point`` to the nearest triangle, or ``search`` if none is that close."""
        point = np.asarray(point, dtype=np.float64)
        # a triangle binned near but not overlapping the box lies further than ``search``: the cap hides it
        return _nearest(point, self._triangles, self.grid.near(point - self.search, point + self.search),
                        self.search)

    def sweep(self, p0, p1) -> Contact | None:
        """First contact of the body moving in a straight line from p0 to p1 (x, y, z), or None."""
        if self._anchor is not None and max(math.dist(p0, self._anchor), math.dist(p1, self._anchor)) <= self._safe:
            return None  # still inside the ball known to be clear
        step = math.dist(p0, p1)
        p0 = np.asarray(p0, dtype=np.float64)
        p1 = np.asarray(p1, dtype=np.float64)
        clear = self.clearance(p0)
        if clear - self.radius > step:
            self._anchor, self._safe = tuple(p0), clear - self.radius
            return None
        self._anchor = None
        ids = self.grid.candidates(np.minimum(p0, p1) - self.radius, np.maximum(p0, p1) + self.radius)
        if len(ids) == 0:
            return None
        triangles = self._triangles[ids]
        distance = segment_triangle_distance(p0, p1, triangles)
        if distance.min() >= self.radius:
            return None
        lo, hi = 0.0, 1.0  # bisect for the first touching position along the step
        for _ in range(20):
            mid = (lo + hi) / 2
            if segment_triangle_distance(p0, p0 + mid * (p1 - p0), triangles).min() < self.radius:
                hi = mid
            else:
                lo = mid
        end = p0 + hi * (p1 - p0)
        touching = int(np.argmin(segment_triangle_distance(p0, end, triangles)))
        return Contact(point=end, fraction=hi, face=int(self.grid.face_ids[ids[touching]]))

    def touches(self, point: np.ndarray) -> bool:
        return self.sweep(point, point) is not None


def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance from the point p (3,) to each triangle (n, 3, 3)."""
    p, tri = np.asarray(p, dtype=np.float64), np.ascontiguousarray(tri, dtype=np.float64)
    if p.shape != (3,) or tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ValueError(f"expected a point (3,) and triangles (n, 3, 3), not {p.shape} and {tri.shape}")
    return _point_triangle_distance(p, tri)


@numba.njit(cache=True)
def _point_triangle_distance(p, tri):
    """A loop over the triangles: the clearance check measures hundreds of them near the body (foliage),
    which took a few dozen numpy calls on arrays of that size."""
    out = np.empty(len(tri))
    point = (p[0], p[1], p[2])
    for k in range(len(tri)):
        a = (tri[k, 0, 0], tri[k, 0, 1], tri[k, 0, 2])
        b = (tri[k, 1, 0], tri[k, 1, 1], tri[k, 1, 2])
        c = (tri[k, 2, 0], tri[k, 2, 1], tri[k, 2, 2])
        out[k] = math.sqrt(_squared_distance(point, a, b, c))
    return out


@numba.njit(cache=True)
def _nearest(p, tri, ids, cap):
    """min(cap, the distance from p to the nearest of the triangles ``ids``), in one compiled call: the
    clearance is measured every few steps of every vehicle, and numpy's gathering of the triangles cost more
    than measuring them."""
    point = (p[0], p[1], p[2])
    best = cap * cap
    for k in ids:
        a = (tri[k, 0, 0], tri[k, 0, 1], tri[k, 0, 2])
        b = (tri[k, 1, 0], tri[k, 1, 1], tri[k, 1, 2])
        c = (tri[k, 2, 0], tri[k, 2, 1], tri[k, 2, 2])
        best = min(best, _squared_distance(point, a, b, c))
    return math.sqrt(best)


@numba.njit(cache=True)
def _squared_distance(p, a, b, c):
    """Squared distance from p to the triangle abc: Ericson, Real-Time Collision Detection, 5.1.5
    (the closest point by the Voronoi region p lies in); a triangle without area is its edges."""
    ab, ac, ap = _sub(b, a), _sub(c, a), _sub(p, a)
    normal = _cross(ab, ac)
    if _dot(normal, normal) <= 1e-12 * _dot(ab, ab) * _dot(ac, ac):
        return min(_to_segment(p, a, b), _to_segment(p, b, c), _to_segment(p, c, a))
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    if d1 <= 0 and d2 <= 0:
        return _dot(ap, ap)  # vertex a
    bp = _sub(p, b)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    if d3 >= 0 and d4 <= d3:
        return _dot(bp, bp)  # vertex b
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return _to_point(p, _along(a, ab, d1 / (d1 - d3)))  # edge ab
    cp = _sub(p, c)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    if d6 >= 0 and d5 <= d6:
        return _dot(cp, cp)  # vertex c
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return _to_point(p, _along(a, ac, d2 / (d2 - d6)))  # edge ac
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        return _to_point(p, _along(b, _sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))))  # edge bc
    denom = va + vb + vc
    return _to_point(p, _along(_along(a, ab, vb / denom), ac, vc / denom))  # the face itself


@numba.njit(cache=True)
def _to_segment(p, a, b):
    ab = _sub(b, a)
    length = _dot(ab, ab)
    t = 0.0 if length == 0 else min(1.0, max(0.0, _dot(_sub(p, a), ab) / length))
    return _to_point(p, _along(a, ab, t))


@numba.njit(cache=True)
def _to_point(p, q):
    d = _sub(p, q)
    return _dot(d, d)


@numba.njit(cache=True)
def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


@numba.njit(cache=True)
def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@numba.njit(cache=True)
def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


@numba.njit(cache=True)
def _along(u, d, t):
    """u + t d"""
    return (u[0] + d[0] * t, u[1] + d[1] * t, u[2] + d[2] * t)


def _segment_segment_distance(p1, q1, p2, q2):
    """Distance between segments p1q1 (broadcast) and p2q2 (n, 3); Ericson 5.1.9."""
    d1 = np.broadcast_to(q1 - p1, p2.shape)
    d2 = q2 - p2
    r = p1 - p2
    a = _rowdot(d1, d1)
    e = _rowdot(d2, d2)
    f = _rowdot(d2, r)
    c = _rowdot(d1, r)
    b = _rowdot(d1, d2)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12, np.clip((b * f - c * e) / denom, 0, 1), 0.0)
        s = np.where(a > 1e-12, s, 0.0)
        # a second segment without length is a point: t < 0 takes the point of the first nearest to it
        t = np.where(e > 1e-12, (b * s + f) / e, -1.0)
        s_low = np.where(a > 1e-12, np.clip(-c / a, 0, 1), 0.0)
        s_high = np.where(a > 1e-12, np.clip((b - c) / a, 0, 1), 0.0)
    s = np.where(t < 0, s_low, np.where(t > 1, s_high, s))
    t = np.clip(t, 0, 1)
    closest1 = p1 + d1 * s[:, None]
    closest2 = p2 + d2 * t[:, None]
    return np.linalg.norm(closest1 - closest2, axis=1)


def _segment_crosses_triangle(p0, p1, tri):
    """Whether the segment p0p1 passes through each triangle (Moller-Trumbore)."""
    direction = p1 - p0
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a
    h = np.cross(direction, e2)
    det = _rowdot(e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = p0 - a
        u = inv * _rowdot(s, h)
        q = np.cross(s, e1)
        v = inv * _rowdot(direction, q)
        t = inv * _rowdot(e2, q)
        return (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def segment_triangle_distance(p0: np.ndarray, p1: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Exact distance from the segment p0p1 to each triangle (n, 3, 3)."""
    best = np.minimum(point_triangle_distance(p0, tri), point_triangle_distance(p1, tri))
    if (p1 != p0).any():
        for i, j in ((0, 1), (1, 2), (2, 0)):
            best = np.minimum(best, _segment_segment_distance(p0, p1, tri[:, i], tri[:, j]))
        best = np.where(_segment_crosses_triangle(p0, p1, tri), 0.0, best)
    return best
