"""Frontiers: where known-free space meets unknown space, and which of them the body can get to.

Frontier-based exploration (Yamauchi 1997, "A frontier-based approach for
autonomous exploration"): a frontier cell is a free cell next to an unknown
one; connected frontier cells form a frontier; the explorer goes to the
nearest frontier it can reach, looks around, and repeats until no reachable
frontier is left, which is the one honest "explored everything" there is.

Reachability and distance come from one Dijkstra over the cells the body fits
in (free, and further than the clearance from every occupied cell), run from
the vehicle's cell: it gives the path length to every frontier cell at once,
and a frontier behind a wall is simply never reached. Steps are 8-connected
(1 or sqrt 2 cells long) and a diagonal step needs both cells beside it open,
as the planner's A* does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.planning import inflate

EIGHT = np.ones((3, 3), dtype=bool)
NARROW = 0.5  # share of the clearance a way through a gap the body does not fit must keep, to be worth a look
REACH = 4.0  # times the clearance: how far from its frontier a goal may lie
FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class Frontier:
    cells: np.ndarray  # (n, 2) rows and columns of its cells
    goal: tuple[int, int]  # its cell nearest the vehicle by path
    distance: float  # path length to ``goal``, in cells
    narrow: bool = False  # reached only through a gap the body does not fit (``goal`` is short of it)


def frontier_cells(free: np.ndarray, unknown: np.ndarray) -> np.ndarray:
    """Free cells with an unknown cell among their four side neighbours."""
    return free & ndimage.binary_dilation(unknown, structure=FOUR)


def frontiers(free: np.ndarray, unknown: np.ndarray, min_cells: int = 1) -> list[np.ndarray]:
    """The frontier cells grouped into 8-connected frontiers of at least ``min_cells`` cells, each (n, 2)."""
    labels, count = ndimage.label(frontier_cells(free, unknown), structure=EIGHT)
    if not count:
        return []
    order = np.argsort(labels, axis=None, kind="stable")
    flat = labels.ravel()[order]
    starts = np.searchsorted(flat, np.arange(1, count + 2))
    groups = [order[a:b] for a, b in zip(starts[:-1], starts[1:], strict=True)]
    return [np.column_stack(np.unravel_index(g, labels.shape)) for g in groups if len(g) >= min_cells]


def path_lengths(passable: np.ndarray, start: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Length in cells of the shortest 8-connected path from ``start`` to every cell over passable cells
    (inf where there is none, and everywhere if ``start`` itself is not passable), and each cell's
    predecessor on it (a flat index, negative where there is none)."""
    rows, cols = passable.shape
    if not passable[start]:
        return np.full(passable.shape, np.inf), np.full(passable.shape, -1)
    padded = np.pad(passable, 1)

    def beside(dr: int, dc: int) -> np.ndarray:  # whether the cell (dr, dc) away is on the grid and passable
        return padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols]

    heads, tails, weights = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):  # each undirected step once
        ok = passable & beside(dr, dc)
        if dr and dc:  # no squeezing between two blocked cells touching at a corner
            ok &= beside(dr, 0) & beside(0, dc)
        here = np.flatnonzero(ok)
        heads.append(here)
        tails.append(here + dr * cols + dc)
        weights.append(np.full(len(here), np.hypot(dr, dc)))
    graph = coo_matrix((np.concatenate(weights), (np.concatenate(heads), np.concatenate(tails))),
                       shape=(passable.size, passable.size)).tocsr()
    lengths, parents = dijkstra(graph, directed=False, indices=start[0] * cols + start[1], return_predecessors=True)
    return lengths.reshape(passable.shape), parents.reshape(passable.shape)


def reachable_frontiers(free: np.ndarray, unknown: np.ndarray, passable: np.ndarray, start: tuple[int, int],
                        min_cells: int = 1, narrow: np.ndarray | None = None, clearance: float = 0.0,
                        looked: np.ndarray | None = None) -> list[Frontier]:
    """The frontiers (of at least ``min_cells`` cells) the vehicle can get to from ``start`` over passable
    cells, nearest first by path length.

    Each one's goal is the reachable cell nearest by path that lies more than ``clearance`` cells from every
    unknown cell and within ``REACH`` times that (and a cell) of the frontier: a frontier along a wall the sonar has
    not seen yet lies right on the wall, so the goal is where the body has known-free space all round. Cells
    ``looked`` (around spots already looked from) are no goal: a frontier whose every such goal was looked
    from comes after those, its goal the reachable cell nearest the frontier itself (the corridor's sides
    beyond a doorway stay unknown from the room; from the doorway they are seen).
    ``narrow`` (cells a thinner body would fit in): a frontier reached only through those (a doorway the map
    draws narrower than it is, as a sonar's first look at its frame does) comes after the others, its goal
    the last such cell on the way to it, from where a closer look may open the way."""
    lengths, _ = path_lengths(passable, start)
    groups = frontiers(free, unknown, min_cells)
    if not groups:
        return []
    labels = np.zeros(free.shape, dtype=np.int64)
    for k, cells in enumerate(groups, 1):
        labels[cells[:, 0], cells[:, 1]] = k
    gap, (rows, cols) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    nearest = labels[rows, cols]  # the frontier each cell is nearest to
    roomy = ndimage.distance_transform_edt(~unknown) > clearance
    fresh = np.isfinite(lengths) if looked is None else np.isfinite(lengths) & ~looked
    within = gap <= REACH * clearance + 1
    goal_of = _goals(fresh & roomy & within, nearest, lengths, len(groups))
    near = [Frontier(groups[k - 1], goal, float(lengths[goal])) for k, goal in goal_of.items()]
    closer = _goals(fresh & within, nearest, gap, len(groups))  # the rest: as near the frontier as the body gets
    again = [Frontier(groups[k - 1], goal, float(lengths[goal])) for k, goal in closer.items() if k not in goal_of]
    with_goal = goal_of.keys() | closer.keys()
    far = []
    if narrow is not None:
        loose, parents = path_lengths(narrow | passable, start)
        for k, cells in enumerate(groups, 1):
            along = loose[cells[:, 0], cells[:, 1]]
            first = int(np.argmin(along))
            if k in with_goal or not np.isfinite(along[first]):
                continue
            cell = int(np.ravel_multi_index(cells[first], free.shape))
            while not (np.isfinite(lengths.flat[cell]) and roomy.flat[cell]) and parents.flat[cell] >= 0:
                cell = int(parents.flat[cell])  # back along the way to where the body fits in known-free space
            goal = tuple(int(v) for v in np.unravel_index(cell, free.shape))
            far.append(Frontier(cells, goal, float(lengths[goal]), narrow=True))
    return sorted(near, key=lambda f: f.distance) + sorted(again, key=lambda f: f.distance) + \
        sorted(far, key=lambda f: f.distance)


def _goals(candidates: np.ndarray, nearest: np.ndarray, cost: np.ndarray, count: int) -> dict[int, tuple[int, int]]:
    """For each frontier (1 ... count) with candidate cells nearest it, its candidate of least ``cost``."""
    best = np.full(count + 1, np.inf)
    np.minimum.at(best, nearest[candidates], cost[candidates])
    goal_of = {}
    for r, c in zip(*np.nonzero(candidates & (cost == best[nearest])), strict=True):
        goal_of.setdefault(int(nearest[r, c]), (int(r), int(c)))
    return goal_of


def on_map(memory_map: MemoryMap, position: tuple[float, float], clearance: float, min_cells: int,
           box: tuple[float, float, float, float], done: list[tuple[float, float]] = (),
           done_radius: float = 0.0) -> list[Frontier]:
    """The reachable frontiers of a memory map from ``position``, nearest first, in map cells.

    The body fits in free cells further than ``clearance`` cells from every occupied one (and where it is
    now). Only cells inside ``box`` (x0, y0, x1, y1: the allowed space) count, so exploration stops at its
    edge. Frontier cells within ``done_radius`` m of a point of ``done`` (spots already looked around from,
    goals given up on) no longer count: what stays unknown from right beside it, the sonar cannot see."""
    m = memory_map
    here = m.cell_of(*position)
    if here is None:
        return []
    low, high = m.cell_of(*np.maximum(box[:2], m.origin)), m.cell_of(*np.minimum(box[2:], _far_corner(m)))
    known = m.grid[low[0]:high[0] + 1, low[1]:high[1] + 1] != 0
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if not len(rows):
        return []
    pad = int(np.ceil(clearance)) + 2  # the known part, and room for the unknown beside it and the inflation
    r0, r1 = max(low[0], low[0] + rows[0] - pad, 0), min(high[0] + 1, low[0] + rows[-1] + pad + 1)
    c0, c1 = max(low[1], low[1] + cols[0] - pad, 0), min(high[1] + 1, low[1] + cols[-1] + pad + 1)
    r0, r1 = min(r0, here[0]), max(r1, here[0] + 1)
    c0, c1 = min(c0, here[1]), max(c1, here[1] + 1)
    window = m.grid[r0:r1, c0:c1]
    free, occupied = window <= m.FREE_AT, window >= m.OCCUPIED_AT
    start = (here[0] - r0, here[1] - c0)
    body = _disc_mask(free.shape, [start], clearance)
    passable = (free & ~inflate(occupied, clearance)) | (body & ~occupied)
    narrow = free & ~inflate(occupied, NARROW * clearance)
    unknown = ~free & ~occupied
    looked = np.zeros(free.shape, dtype=bool)
    if done:
        cells = [(int((y - m.origin[1]) * m.resolution) - r0, int((x - m.origin[0]) * m.resolution) - c0)
                 for x, y in done]
        looked = _disc_mask(free.shape, cells, done_radius * m.resolution)
    found = reachable_frontiers(free & ~looked, unknown, passable, start, min_cells, narrow, clearance, looked)
    return [Frontier(f.cells + (r0, c0), (f.goal[0] + r0, f.goal[1] + c0), f.distance, f.narrow)
            for f in found if not looked[f.goal]]


def _far_corner(m: MemoryMap) -> np.ndarray:
    """Scene x, y just inside the map's north-east corner."""
    return np.array(m.origin) + (m.size - 0.5) / m.resolution


def _disc_mask(shape: tuple[int, int], centres: list[tuple[int, int]], radius: float) -> np.ndarray:
    """Cells within ``radius`` cells of any of the centres (which may lie off the grid)."""
    out = np.zeros(shape, dtype=bool)
    reach = int(np.ceil(radius))
    for r, c in centres:
        rows = slice(min(max(0, r - reach), shape[0]), max(0, min(shape[0], r + reach + 1)))
        cols = slice(min(max(0, c - reach), shape[1]), max(0, min(shape[1], c + reach + 1)))
        dr, dc = np.ogrid[rows, cols]
        out[rows, cols] |= (dr - r) ** 2 + (dc - c) ** 2 <= radius * radius
    return out
