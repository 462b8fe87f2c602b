"""Where a body fits at a height in a scene, and how much of that floor a memory map has seen.

Indoors, how well a mission explored is the share of the floor it could reach that its map knows
(free or occupied): issue 32's "share of the reachable floor". The scene's cross-section at the
height is drawn on a fine grid, cells at least the body's radius from it are where the body fits,
and their connected parts are the rooms it can get between (a doorway narrower than the body splits them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from vehicle.mapping.memory_map import MemoryMap
from vehicle.world.scene import Scene


@dataclass(frozen=True)
class Floor:
    labels: np.ndarray  # [i, j] along x, y: the connected part a cell is in, 0 where the body does not fit
    origin: tuple[float, float]  # scene x, y of cell (0, 0)'s corner
    res: float  # m per cell

    def label_at(self, x: float, y: float) -> int:
        """The connected part (x, y) is in; 0 where the body does not fit there or off the scene."""
        i, j = int((x - self.origin[0]) / self.res), int((y - self.origin[1]) / self.res)
        inside = 0 <= i < self.labels.shape[0] and 0 <= j < self.labels.shape[1]
        return int(self.labels[i, j]) if inside else 0

    def known_share(self, memory: MemoryMap, start: tuple[float, float]) -> float:
        """The share of the floor reachable from ``start`` and inside the map whose map cell is known (free or
        occupied)."""
        part = self.label_at(*start)
        if part == 0:
            return 0.0
        rows, cols = np.indices(memory.grid.shape)
        x = memory.origin[0] + (cols + 0.5) / memory.resolution
        y = memory.origin[1] + (rows + 0.5) / memory.resolution
        i = np.floor((x - self.origin[0]) / self.res).astype(int)
        j = np.floor((y - self.origin[1]) / self.res).astype(int)
        inside = (i >= 0) & (i < self.labels.shape[0]) & (j >= 0) & (j < self.labels.shape[1])
        reachable = np.zeros(memory.grid.shape, dtype=bool)
        reachable[inside] = self.labels[i[inside], j[inside]] == part
        total = int(reachable.sum())
        return float((reachable & (memory.grid != 0)).sum()) / total if total else 0.0


def reachable_floor(scene: Scene, height: float, radius: float, res: float = 0.02) -> Floor:
    """Where a body of ``radius`` fits at ``height`` above z = 0, in connected parts, on a grid of ``res`` m."""
    sections = trimesh.intersections.mesh_plane(scene.mesh, (0, 0, 1), (0, 0, height))
    lo = scene.bounds[0, :2] - 0.5
    drawn = np.zeros(tuple(np.ceil((scene.bounds[1, :2] + 0.5 - lo) / res).astype(int)), dtype=bool)
    for a, b in sections[:, :, :2]:  # each segment drawn at half-cell steps, so no cell it crosses is missed
        n = int(np.linalg.norm(b - a) / (res / 2)) + 2
        ij = ((a + np.linspace(0, 1, n)[:, None] * (b - a) - lo) / res).astype(int)
        drawn[ij[:, 0], ij[:, 1]] = True
    labels, _ = ndimage.label(ndimage.distance_transform_edt(~drawn) * res > radius)
    return Floor(labels, (float(lo[0]), float(lo[1])), res)
