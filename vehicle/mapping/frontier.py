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
as the planner's A* does. The Dijkstra is our own, over the grid's neighbours
and compiled with numba: scipy's (``csgraph.dijkstra``) gives the same lengths
but needs the grid rebuilt as a sparse graph at every call, which cost more
than the search, and a team's vehicles, each turned away from its team-mates'
shares, look for frontiers several times a minute (a third of a team's time).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.planning import inflate

EIGHT = np.ones((3, 3), dtype=bool)
NARROW = 0.5  # share of the clearance a way through a gap the body does not fit must keep, to be worth a look
REACH = 4.0  # times the clearance: how far from its frontier a goal may lie
FOUR = ndimage.generate_binary_structure(2, 1)
SQRT2 = math.sqrt(2.0)


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


def path_lengths(passable: np.ndarray, start: tuple[int, int],
                 limit: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """Length in cells of the shortest 8-connected path from ``start`` to every cell over passable cells
    (inf where there is none or it is longer than ``limit``, and everywhere if ``start`` itself is not
    passable), and each cell's predecessor on it (a flat index, negative where there is none)."""
    if not passable[start]:
        return np.full(passable.shape, np.inf), np.full(passable.shape, -1)
    lengths, parents = _dijkstra(np.ascontiguousarray(passable, dtype=np.bool_), int(start[0]), int(start[1]),
                                 float(limit))
    return lengths.reshape(passable.shape), parents.reshape(passable.shape)


@numba.njit(cache=True)
def _dijkstra(passable, start_row, start_col, limit):
    """Dijkstra from one cell over the passable cells of a grid, 8-connected, a diagonal step only between
    two open cells beside it, no further than ``limit``; flat lengths and predecessors (-1: none). Its queue
    is a binary heap in two arrays (a length, a cell), a cell pushed again whenever a shorter way to it is
    found. Equal lengths go in the cells' order, which a window cut from a bigger grid keeps: sums of 1 and
    sqrt 2 taken in another order can differ in the last bit, and the near and the whole map must give the
    same goals. It runs on a copy of the grid with a closed border, so a step needs no bounds check (a
    cell's row-major order is the same in both)."""
    rows, cols = passable.shape
    width = cols + 2
    cells_in = (rows + 2) * width
    open_ = np.zeros(cells_in, dtype=np.bool_)
    for r in range(rows):
        for c in range(cols):
            open_[(r + 1) * width + c + 1] = passable[r, c]
    lengths = np.full(cells_in, np.inf)
    parents = np.full(cells_in, -1, dtype=np.int64)
    settled = np.zeros(cells_in, dtype=np.bool_)
    steps = np.array([-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1], dtype=np.int64)
    sides = np.array([-width, -width, -width, 0, 0, width, width, width], dtype=np.int64)  # the step's row part
    room = 4 * (rows + cols) + 64  # about a wavefront's cells; doubled when full (a cell may be in it 8 times)
    keys, cells = np.empty(room), np.empty(room, dtype=np.int64)
    first = (start_row + 1) * width + start_col + 1
    lengths[first] = 0.0
    keys[0], cells[0], size = 0.0, first, 1
    while size > 0:
        length, cell = keys[0], cells[0]
        size -= 1
        _sift_down(keys, cells, size)
        if settled[cell]:
            continue
        settled[cell] = True
        for k in range(8):
            there = cell + steps[k]
            if not open_[there] or settled[there]:
                continue
            if k == 1 or k == 3 or k == 4 or k == 6:
                step = 1.0
            elif open_[cell + sides[k]] and open_[cell + steps[k] - sides[k]]:
                step = SQRT2
            else:
                continue
            if length + step < lengths[there] and length + step <= limit:
                lengths[there] = length + step
                parents[there] = cell
                if size == len(keys):
                    keys, cells = np.concatenate((keys, np.empty(size))), np.concatenate((cells, cells))
                _push(keys, cells, size, length + step, there)
                size += 1
    out_lengths = np.empty(rows * cols)
    out_parents = np.empty(rows * cols, dtype=np.int64)
    for r in range(rows):
        for c in range(cols):
            padded = (r + 1) * width + c + 1
            out_lengths[r * cols + c] = lengths[padded]
            parent = parents[padded]
            out_parents[r * cols + c] = -1 if parent < 0 else (parent // width - 1) * cols + parent % width - 1
    return out_lengths, out_parents


@numba.njit(cache=True)
def _push(keys, cells, size, key, cell):
    """Put (key, cell) into the heap of ``size`` entries."""
    i = size
    while i > 0:
        parent = (i - 1) // 2
        if keys[parent] < key or (keys[parent] == key and cells[parent] < cell):
            break
        keys[i], cells[i] = keys[parent], cells[parent]
        i = parent
    keys[i], cells[i] = key, cell


@numba.njit(cache=True)
def _sift_down(keys, cells, size):
    """After the root was taken: move the last entry (at ``size``) down from the root to its place."""
    if size == 0:
        return
    key, cell = keys[size], cells[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and (keys[child + 1] < keys[child] or
                                 (keys[child + 1] == keys[child] and cells[child + 1] < cells[child])):
            child += 1
        if keys[child] > key or (keys[child] == key and cells[child] > cell):
            break
        keys[i], cells[i] = keys[child], cells[child]
        i = child
    keys[i], cells[i] = key, cell


def reachable_frontiers(free: np.ndarray, unknown: np.ndarray, passable: np.ndarray, start: tuple[int, int],
                        min_cells: int = 1, narrow: np.ndarray | None = None, clearance: float = 0.0,
                        looked: np.ndarray | None = None, limit: float = math.inf) -> Iterator[Frontier]:
    """The frontiers (of at least ``min_cells`` cells) the vehicle can get to from ``start`` over passable
    cells, nearest first by path length, as the caller takes them.

    Each one's goal is the reachable cell nearest by path that lies more than ``clearance`` cells from every
    unknown cell and within ``REACH`` times that (and a cell) of the frontier: a frontier along a wall the sonar has
    not seen yet lies right on the wall, so the goal is where the body has known-free space all round. Cells
    ``looked`` (around spots already looked from) are no goal: a frontier whose every such goal was looked
    from comes after those, its goal the reachable cell nearest the frontier itself (the corridor's sides
    beyond a doorway stay unknown from the room; from the doorway they are seen).
    ``narrow`` (cells a thinner body would fit in): a frontier reached only through those (a doorway the map
    draws narrower than it is, as a sonar's first look at its frame does) comes after the others, its goal
    the last such cell on the way to it, from where a closer look may open the way. Those are looked for only
    once the caller has turned the others down (a second Dijkstra, half the time).
    ``limit`` (cells): only the frontiers whose goal with known-free space all round lies within it by path,
    in the same order; whether any other comes before the rest takes every length, which the caller then
    looks for without a limit. The search stops there: a fraction of the time near the vehicle."""
    lengths, _ = path_lengths(passable, start, limit)
    groups = frontiers(free, unknown, min_cells)
    if not groups:
        return
    labels = np.zeros(free.shape, dtype=np.int64)
    for k, cells in enumerate(groups, 1):
        labels[cells[:, 0], cells[:, 1]] = k
    # goals lie on reached cells within ``reach`` of a frontier: the rest is measured only around those
    # (a near search reaches a fraction of its window), which gives the same gaps and nearest frontiers there
    reach = REACH * clearance + 1
    rows, cols, (r0, c0) = _around(np.isfinite(lengths), math.ceil(reach) + 1)
    box_labels = labels[rows, cols]
    roomy = ~inflate(unknown, clearance)  # further than the clearance from every unknown cell
    goal_of, closer = {}, {}
    if box_labels.any():
        gap, (nearest_rows, nearest_cols) = ndimage.distance_transform_edt(box_labels == 0, return_indices=True)
        nearest = box_labels[nearest_rows, nearest_cols]  # the frontier each cell is nearest to
        box_lengths = lengths[rows, cols]
        fresh = np.isfinite(box_lengths) if looked is None else np.isfinite(box_lengths) & ~looked[rows, cols]
        within = gap <= reach
        goal_of = _goals(fresh & roomy[rows, cols] & within, nearest, box_lengths, len(groups), (r0, c0))
        closer = _goals(fresh & within, nearest, gap, len(groups), (r0, c0))  # the rest: as near the frontier
        # as the body gets
    near = [Frontier(groups[k - 1], goal, float(lengths[goal])) for k, goal in goal_of.items()]
    again = [Frontier(groups[k - 1], goal, float(lengths[goal])) for k, goal in closer.items() if k not in goal_of]
    yield from sorted(near, key=lambda f: f.distance)
    if math.isfinite(limit):
        return
    yield from sorted(again, key=lambda f: f.distance)
    with_goal = goal_of.keys() | closer.keys()
    if narrow is None or len(with_goal) == len(groups):
        return
    far = []
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
    yield from sorted(far, key=lambda f: f.distance)


def _goals(candidates: np.ndarray, nearest: np.ndarray, cost: np.ndarray, count: int,
           offset: tuple[int, int] = (0, 0)) -> dict[int, tuple[int, int]]:
    """For each frontier (1 ... count) with candidate cells nearest it, its candidate of least ``cost``
    (its cell, ``offset`` added)."""
    best = np.full(count + 1, np.inf)
    np.minimum.at(best, nearest[candidates], cost[candidates])
    rows, cols = np.nonzero(candidates & (cost == best[nearest]))
    _, first = np.unique(nearest[rows, cols], return_index=True)  # each frontier's first cell in row order
    first.sort()  # the frontiers in that order too: equally near ones keep it when sorted by distance
    return {int(nearest[rows[i], cols[i]]): (int(rows[i]) + offset[0], int(cols[i]) + offset[1]) for i in first}


def _around(mask: np.ndarray, pad: int) -> tuple[slice, slice, tuple[int, int]]:
    """The rows and columns of the smallest box holding every true cell of ``mask``, widened by ``pad`` cells
    (within the grid; empty when none is true), and its first cell."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return slice(0, 0), slice(0, 0), (0, 0)
    r0, c0 = max(0, rows[0] - pad), max(0, cols[0] - pad)
    return slice(r0, rows[-1] + pad + 1), slice(c0, cols[-1] + pad + 1), (int(r0), int(c0))


def on_map(memory_map: MemoryMap, position: tuple[float, float], clearance: float, min_cells: int,
           box: tuple[float, float, float, float], done: list[tuple[float, float]] = (),
           done_radius: float = 0.0, limit: float = math.inf) -> Iterator[Frontier]:
    """The reachable frontiers of a memory map from ``position``, nearest first, in map cells, as the caller
    takes them.

    The body fits in free cells further than ``clearance`` cells from every occupied one (and where it is
    now). Only cells inside ``box`` (x0, y0, x1, y1: the allowed space) count, so exploration stops at its
    edge. Frontier cells within ``done_radius`` m of a point of ``done`` (spots already looked around from,
    goals given up on) no longer count: what stays unknown from right beside it, the sonar cannot see.
    ``limit``: as for ``reachable_frontiers``."""
    m = memory_map
    here = m.cell_of(*position)
    if here is None:
        return
    low, high = m.cell_of(*np.maximum(box[:2], m.origin)), m.cell_of(*np.minimum(box[2:], _far_corner(m)))
    known = m.grid[low[0]:high[0] + 1, low[1]:high[1] + 1] != 0
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if not len(rows):
        return
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
    found = reachable_frontiers(free & ~looked, unknown, passable, start, min_cells, narrow, clearance, looked, limit)
    for f in found:
        if not looked[f.goal]:
            yield Frontier(f.cells + (r0, c0), (f.goal[0] + r0, f.goal[1] + c0), f.distance, f.narrow)


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
