"""Swept-sphere collision of the vehicle body against the scene mesh.

trimesh answers point-to-mesh distance through an R-tree at about a millisecond a
query, too slow for every simulation step; embreex offers no distance queries. So
this module keeps a coarse grid of triangles over the ground plane and measures
exact segment-to-triangle distances on the few triangles near the vehicle. Most
steps cost nothing: after each exact check the body is known to be clear of
everything within some radius, and until it leaves that ball no test is needed
(conservative advancement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

LARGE_SPAN = 64  # grid cells: triangles covering more are checked by their bounding box alone
WALKABLE_NORMAL_Z = 0.7  # faces flatter than ~45 degrees are ground a rover may drive on


@dataclass(frozen=True)
class Contact:
    point: np.ndarray  # body centre at first contact
    fraction: float  # how far along the step (0..1) the contact happened
    face: int  # index of the face touched

    def describe(self) -> str:
        x, y, z = self.point
        return f"collision at x={x:.2f} y={y:.2f} z={z:.2f} (face {self.face})"


class TriangleGrid:
    """The scene's triangles binned by the ground-plane grid cells their bounding boxes overlap.

    Built once per scene and vehicle kind (a few milliseconds for ten thousand
    triangles) and shared by every collider in it: it never changes.
    """

    def __init__(self, mesh: trimesh.Trimesh, ignore_walkable: bool = False, cell_size: float = 2.0):
        self.cell_size = float(cell_size)
        triangles = np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3, 3)
        face_ids = np.arange(len(triangles))
        if ignore_walkable and len(triangles):
            keep = np.asarray(mesh.face_normals)[:, 2] <= WALKABLE_NORMAL_Z
            triangles, face_ids = triangles[keep], face_ids[keep]
        self.triangles = triangles
        self.face_ids = face_ids
        self._lo = triangles.min(axis=1) if len(triangles) else np.zeros((0, 3))
        self._hi = triangles.max(axis=1) if len(triangles) else np.zeros((0, 3))
        self._grid = self._build_grid()

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
        i0, j0 = np.floor(lo[:2] / self.cell_size).astype(int)
        i1, j1 = np.floor(hi[:2] / self.cell_size).astype(int)
        found = [self._grid[key] for i in range(i0, i1 + 1) for j in range(j0, j1 + 1)
                 if (key := (i, j)) in self._grid]
        found.append(self._large)
        ids = np.unique(np.concatenate(found))
        overlap = np.all((self._lo[ids] <= hi) & (self._hi[ids] >= lo), axis=1)
        return ids[overlap]


class Collider:
    """Answers whether a sphere of ``radius`` moving from p0 to p1 touches the mesh.

    Takes the mesh, or its ``TriangleGrid`` when several colliders share one.
    """

    def __init__(self, mesh: trimesh.Trimesh | TriangleGrid, radius: float, ignore_walkable: bool = False,
                 search: float = 4.0):
        self.grid = mesh if isinstance(mesh, TriangleGrid) else TriangleGrid(mesh, ignore_walkable)
        self.radius = float(radius)
        self.search = max(float(search), 2 * self.radius)
        self._triangles = self.grid.triangles
        self._anchor: np.ndarray | None = None
        self._safe = 0.0

    def clearance(self, point: np.ndarray) -> float:
        """Distance from ``point`` to the nearest triangle, or ``search`` if none is that close."""
        point = np.asarray(point, dtype=np.float64)
        ids = self.grid.candidates(point - self.search, point + self.search)
        if len(ids) == 0:
            return self.search
        return min(self.search, float(point_triangle_distance(point, self._triangles[ids]).min()))

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


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def closest_points_on_triangles(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Closest point on each triangle (n, 3, 3) to the point p (3,) or points (n, 3).

    Ericson, Real-Time Collision Detection, 5.1.5, vectorised over triangles.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    p = np.broadcast_to(p, a.shape)
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        result = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    result = np.where(on_bc[:, None], b + (c - b) * t_bc[:, None], result)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    result = np.where(on_ac[:, None], a + ac * t_ac[:, None], result)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    result = np.where(on_ab[:, None], a + ab * t_ab[:, None], result)
    result = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, result)
    result = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, result)
    result = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, result)
    # degenerate triangles (zero area) fall back to their first vertex
    return np.where(np.isfinite(result), result, a)


def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    return np.linalg.norm(closest_points_on_triangles(p, tri) - p, axis=1)


def _segment_segment_distance(p1, q1, p2, q2):
    """Distance between segments p1q1 (broadcast) and p2q2 (n, 3); Ericson 5.1.9."""
    d1 = np.broadcast_to(q1 - p1, p2.shape)
    d2 = q2 - p2
    r = p1 - p2
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    c = _dot(d1, r)
    b = _dot(d1, d2)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12, np.clip((b * f - c * e) / denom, 0, 1), 0.0)
        s = np.where(a > 1e-12, s, 0.0)
        t = np.where(e > 1e-12, (b * s + f) / e, 0.0)
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
    det = _dot(e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = p0 - a
        u = inv * _dot(s, h)
        q = np.cross(s, e1)
        v = inv * _dot(direction, q)
        t = inv * _dot(e2, q)
        return (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def segment_triangle_distance(p0: np.ndarray, p1: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Exact distance from the segment p0p1 to each triangle (n, 3, 3)."""
    best = np.minimum(point_triangle_distance(p0, tri), point_triangle_distance(p1, tri))
    if (p1 != p0).any():
        for i, j in ((0, 1), (1, 2), (2, 0)):
            best = np.minimum(best, _segment_segment_distance(p0, p1, tri[:, i], tri[:, j]))
        best = np.where(_segment_crosses_triangle(p0, p1, tri), 0.0, best)
    return best
