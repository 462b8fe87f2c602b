"""Grid path planning on the memory map: inflate, A*, smooth.

The memory map is a 2D occupancy grid, rows along +y (north) and columns along
+x (east). Planning works on a boolean obstacle mask ``blocked`` of shape
(rows, cols) and on cells given as ``(row, col)``:

1. :func:`inflate` grows every obstacle by a disc of the vehicle radius plus
   padding (in cells), so the vehicle can then be planned as a point.
2. :func:`astar` finds an 8-connected path on the inflated mask.
3. :func:`smooth` replaces runs of grid steps by straight segments wherever
   the straight line stays clear (line-of-sight shortcutting).

:func:`plan` chains the three and handles the awkward cases.

Why an A* of our own: the search is the one pyastar2d (A* in C++) does, step
for step, written out in :func:`_astar_cells` and compiled with numba. Among
the many equally short 8-connected paths, which one A* returns depends on the
order its priority queue breaks ties in, so the loop keeps pyastar2d's order
exactly (libstdc++'s binary heap) and returns the very same paths; missions
planned before fly the same routes. pyastar2d was chosen over python-tcod,
scikit-image's MCP and a pure-Python heapq A* for speed (on random grids of
200x200 / 1000x1000 / 2000x2000 cells: 1.1 / 27 / 79 ms, against 1.8 / 123 /
831 ms for tcod); the replica searches as fast, and saves what each call cost
around the search (a float32 weight grid, its minimum, a flattened copy, the
ctypes call), about a fifth of a typical replan's A* time.

What the search does, and what we add:

* A move costs the weight of the cell it enters (1 free, inf blocked), a
  diagonal move as much as a straight one, so its raw paths are shortest in
  steps, not in metres; smoothing removes the resulting detours.
* It does not look at the two cells beside a diagonal move, so it happily
  squeezes diagonally between two blocked cells that touch at a corner (a
  vehicle would hit both). :func:`astar` checks the path it gets for such a
  cut (cheap, vectorised); only if there is one, it closes every such pinch in
  the grid by blocking the two free cells of the 2x2 block and searches again.
  That is conservative: it can only remove free cells, so a path through a
  one-cell pinch may be lost, never a blocked cell gained; if it lost every
  path, a four-connected search (which never cuts a corner) finds one.
* It can start from a blocked cell (the start is never entered), but every
  free neighbour must be reachable. A vehicle that stopped within the
  inflation radius of a wall is in that situation: :func:`plan` then first
  escapes to the nearest cell that is free in the inflated map (breadth-first
  over cells free in the *real* map, so the escape never crosses an obstacle)
  and plans from there. The nearest free cell is not always the best exit
  (e.g. in a corridor narrower than the clearance), which is accepted.

Run ``python bench/astar.py`` for the current timings.
"""

from __future__ import annotations

import functools
import math
import operator
from collections import deque

import numba
import numpy as np

START_BLOCKED = "start is inside an obstacle"
GOAL_BLOCKED = "goal is inside an obstacle"
UNREACHABLE = "no path"


class NoPath(Exception):
    """No path exists. ``reason`` is START_BLOCKED, GOAL_BLOCKED or UNREACHABLE."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason} ({detail})" if detail else reason)
        self.reason = reason


def _cell(grid: np.ndarray, cell, what: str) -> tuple[int, int]:
    """(row, col) as Python ints; ValueError outside the grid."""
    r, c = (operator.index(v) for v in cell)
    if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]):
        raise ValueError(f"{what} {(r, c)} is outside the {grid.shape[0]}x{grid.shape[1]} grid")
    return r, c


def _mask(grid: np.ndarray) -> np.ndarray:
    grid = np.asarray(grid, dtype=bool)
    if grid.ndim != 2:
        raise ValueError(f"expected a 2D obstacle mask, got shape {grid.shape}")
    return grid


def inflate(blocked: np.ndarray, radius_cells: float) -> np.ndarray:
    """Obstacles grown by a disc of the given radius (vehicle radius + padding, in cells).

    A cell is blocked if its centre lies within ``radius_cells`` of the centre
    of a blocked cell (the same as ``scipy.ndimage.binary_dilation`` with a
    disc). The disc is done row by row: for each row offset ``dy`` the
    obstacles are dilated horizontally by ``floor(sqrt(r^2 - dy^2))`` (grown
    one column at a time, as widths only grow while ``|dy|`` shrinks) and ORed
    in shifted by ``dy``. Rows are packed 64 cells to a machine word, so a
    window of a few hundred cells a side is a few words a row and each of the
    about 4r passes a few thousand word operations: several times faster than
    the same passes on a boolean array, or scipy's generic dilation.
    """
    b = _mask(blocked)
    if radius_cells < 1:
        return b.copy()
    rows, cols = b.shape
    reach, half = _half_widths(float(radius_cells))
    packed = np.zeros((rows, (cols + 63) // 64 * 8), dtype=np.uint8)
    packed[:, :(cols + 7) // 8] = np.packbits(b, axis=1, bitorder="little")  # bit k of word j: column 64 j + k
    out = _dilate_rows(packed.view(np.uint64), reach, half)
    return np.unpackbits(out.view(np.uint8), axis=1, count=cols, bitorder="little").view(bool)


@functools.cache
def _half_widths(radius_cells: float) -> tuple[int, np.ndarray]:
    """floor(radius) and, for each row offset dy up to it, the half-width of the disc on that row."""
    reach = int(math.floor(radius_cells))
    half = [int(math.floor(math.sqrt(radius_cells**2 - dy * dy) + 1e-9)) for dy in range(reach + 1)]
    return reach, np.array(half, dtype=np.int64)


@numba.njit(cache=True)
def _dilate_rows(words, reach, half):
    """``inflate`` on rows of bits: each row dilated horizontally by half[dy], ORed into the rows dy above
    and below. Shifting a row by w columns moves every word's bits by w % 64 and the words by w // 64,
    carrying the bits that fall off a word into its neighbour."""
    rows, count = words.shape
    wide = words.copy()  # the rows dilated horizontally by w
    out = np.zeros((rows, count), dtype=np.uint64)
    w = 0
    for dy in range(reach, -1, -1):
        while w < half[dy]:
            w += 1
            skip, bits = w // 64, np.uint64(w % 64)
            carry = np.uint64(64) - bits  # used only when bits > 0: a shift by 64 is undefined
            for r in range(rows):
                for j in range(count):
                    moved = np.uint64(0)
                    if j - skip >= 0:  # towards higher columns
                        moved |= words[r, j - skip] << bits
                        if bits and j - skip - 1 >= 0:
                            moved |= words[r, j - skip - 1] >> carry
                    if j + skip < count:  # towards lower columns
                        moved |= words[r, j + skip] >> bits
                        if bits and j + skip + 1 < count:
                            moved |= words[r, j + skip + 1] << carry
                    wide[r, j] |= moved
        for r in range(rows):
            if r - dy >= 0:
                for j in range(count):
                    out[r - dy, j] |= wide[r, j]
            if dy and r + dy < rows:
                for j in range(count):
                    out[r + dy, j] |= wide[r, j]
    return out


def corner_cuts(path: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """Indices i where the diagonal step path[i] -> path[i+1] squeezes between two blocked cells."""
    path = np.asarray(path)
    if len(path) < 2:
        return np.zeros(0, dtype=np.intp)
    p, q = path[:-1], path[1:]
    diagonal = np.abs(q - p).min(axis=1) == 1
    cut = diagonal & blocked[p[:, 0], q[:, 1]] & blocked[q[:, 0], p[:, 1]]
    return np.flatnonzero(cut)


def _close_pinches(blocked: np.ndarray, keep: tuple[int, int]) -> np.ndarray:
    """Block the free pair of every 2x2 checkerboard (X. / .X), repeatedly, except ``keep``."""
    b = blocked.copy()
    while True:
        a, bb, c, d = b[:-1, :-1], b[:-1, 1:], b[1:, :-1], b[1:, 1:]
        p1 = a & d & ~(bb | c)
        p2 = bb & c & ~(a | d)
        if not (p1.any() or p2.any()):
            return b
        b[:-1, 1:] |= p1
        b[1:, :-1] |= p1
        b[:-1, :-1] |= p2
        b[1:, 1:] |= p2
        b[keep] = False  # its partner in the pinch is blocked, which closes it


def astar(blocked_inflated: np.ndarray, start, goal, doubtful: bool = False) -> np.ndarray:
    """8-connected A* path, (n, 2) int cells (row, col) from start to goal inclusive.

    Diagonal moves never pass between two blocked cells touching at a corner
    (see the module docstring). Raises NoPath if start or goal is blocked or
    the goal cannot be reached, ValueError if either is outside the grid.
    ``doubtful`` (a smaller search already failed): first see whether the goal
    is reachable at all, as A* that finds no path has explored every cell it
    could reach (70 ms on 800x800 cells), while labelling the free regions
    takes a few (but as long as a successful search on an open grid).
    """
    grid = _mask(blocked_inflated)
    start, goal = _cell(grid, start, "start"), _cell(grid, goal, "goal")
    if grid[start]:
        raise NoPath(START_BLOCKED)
    if grid[goal]:
        raise NoPath(GOAL_BLOCKED)
    if start == goal:
        return np.array([start], dtype=np.int64)
    if doubtful and not _connected(grid, start, goal):
        raise NoPath(UNREACHABLE)
    path = _search(grid, start, goal)
    if not len(path):
        raise NoPath(UNREACHABLE)
    if not len(corner_cuts(path, grid)):
        return path
    path = _search(_close_pinches(grid, keep=goal), start, goal)
    if len(path) and not len(corner_cuts(path, grid)):
        return path
    # Closing the pinches closed every way (a corridor turning at a pinch, or start and goal the
    # free pair of one): four-connected steps never cut a corner and find a way whenever one exists.
    path = _search(grid, start, goal, diagonal=False)
    if not len(path):
        raise NoPath(UNREACHABLE, "start and goal are only connected through a corner")
    return path


def _search(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int], diagonal: bool = True) -> np.ndarray:
    """``_astar_cells`` (8-connected, or 4-connected if not ``diagonal``) with room in its heap for as many
    entries as cells, or, in the rare search that needs more, for the most it can ever hold: a cell is pushed
    only when its cost drops, which happens only when a neighbour is expanded for the first time (the
    heuristic is consistent), so at most 8 times."""
    blocked = np.ascontiguousarray(blocked)
    width = blocked.shape[1]
    for room in (blocked.size + 16, 8 * blocked.size + 1):
        path, complete = _astar_cells(blocked, start[0] * width + start[1], goal[0] * width + goal[1],
                                      np.empty(room, dtype=np.int64), diagonal)
        if complete:
            break
    return path


_ROW_STEPS = np.array([-1, -1, -1, 0, 0, 1, 1, 1])  # the neighbours in pyastar2d's order
_COL_STEPS = np.array([-1, 0, 1, -1, 1, -1, 0, 1])
_UNSEEN = 1 << 30  # the cost of a free cell not reached yet


@numba.njit(cache=True)
def _astar_cells(blocked, start, goal, heap, diagonal=True):
    """pyastar2d's A*, step for step: 8-connected, each free cell entered costs 1 (blocked ones are never
    entered), priority = cost + the L-inf distance to the goal, neighbours in pyastar2d's order, and a
    binary heap that breaks ties as libstdc++'s std::priority_queue (``_push``, ``_pop``), so the path is
    the very one pyastar2d returns. Costs are whole numbers, as pyastar2d's float32 sums of ones are.
    Flat cell indices in; out an (n, 2) array of (row, col), empty when the goal is unreachable, and
    False if ``heap`` was too small to finish. Not ``diagonal``: 4-connected, with the L1 distance to the
    goal as the heuristic (pyastar2d's ``allow_diagonal=False``).

    The costs live on the grid with a border of one cell, and a blocked or border cell costs 0: as every
    step costs at least 1, "no cheaper than what the cell has" then also rejects blocked cells and cells
    off the grid, one test where there were three. The heap orders by priority alone, so its items
    carry the bordered cell indices without changing the order."""
    h, w = blocked.shape
    width = w + 2
    costs = np.zeros((h + 2) * width, dtype=np.int32)  # 32 bits: less memory to fill and to read
    for r in range(h):
        for c in range(w):
            if not blocked[r, c]:
                costs[(r + 1) * width + c + 1] = _UNSEEN
    parents = np.empty((h + 2) * width, dtype=np.int32)
    steps = _ROW_STEPS * width + _COL_STEPS
    start = (start // w + 1) * width + start % w + 1
    goal = (goal // w + 1) * width + goal % w + 1
    costs[start] = 0
    heap[0] = start  # priority << 32 | cell: the heap compares priorities only
    size = 1
    goal_row, goal_col = goal // width, goal % width
    while size > 0:
        cell = heap[0] & 0xFFFFFFFF
        if cell == goal:
            return _walk_back(parents, start, goal, width), True
        size = _pop(heap, size)
        row, col = cell // width, cell % width
        cost = costs[cell] + 1
        for k in range(8):
            if not diagonal and _ROW_STEPS[k] != 0 and _COL_STEPS[k] != 0:
                continue
            nb = cell + steps[k]
            if cost >= costs[nb]:
                continue
            if size == len(heap):
                return np.empty((0, 2), dtype=np.int64), False
            costs[nb] = cost
            parents[nb] = cell
            r, c = row + _ROW_STEPS[k], col + _COL_STEPS[k]
            if diagonal:
                priority = np.int64(cost + max(abs(r - goal_row), abs(c - goal_col)))
            else:
                priority = np.int64(cost + abs(r - goal_row) + abs(c - goal_col))
            size = _push(heap, size, (priority << 32) | nb)
    return np.empty((0, 2), dtype=np.int64), True


@numba.njit(cache=True)
def _push(heap, size, item):
    """libstdc++'s push_heap for a min-heap on priority (``item >> 32``); returns the new size."""
    hole = size
    parent = (hole - 1) // 2
    while hole > 0 and (heap[parent] >> 32) > (item >> 32):
        heap[hole] = heap[parent]
        hole = parent
        parent = (hole - 1) // 2
    heap[hole] = item
    return size + 1


@numba.njit(cache=True)
def _pop(heap, size):
    """libstdc++'s pop_heap (its __adjust_heap: the hole goes down to a leaf, then the last item is pushed
    back up from there); returns the new size."""
    size -= 1
    last = heap[size]
    hole = 0
    child = 0
    while child < (size - 1) // 2:
        child = 2 * (child + 1)
        if (heap[child] >> 32) > (heap[child - 1] >> 32):
            child -= 1
        heap[hole] = heap[child]
        hole = child
    if size % 2 == 0 and child == (size - 2) // 2:
        child = 2 * (child + 1)
        heap[hole] = heap[child - 1]
        hole = child - 1
    _push(heap, hole, last)
    return size


@numba.njit(cache=True)
def _walk_back(parents, start, goal, width):
    """The cells from start to goal, following parents back from the goal (bordered cell indices in, cells
    of the grid out)."""
    count = 1
    cell = goal
    while cell != start:
        cell = parents[cell]
        count += 1
    path = np.empty((count, 2), dtype=np.int64)
    cell = goal
    for i in range(count - 1, -1, -1):
        path[i, 0], path[i, 1] = cell // width - 1, cell % width - 1
        if i:
            cell = parents[cell]
    return path


def _connected(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> bool:
    """Whether start and goal lie in one 8-connected region of free cells."""
    from scipy import ndimage  # loaded by the first plan that needs it, not by every run

    labels, _ = ndimage.label(~blocked, structure=np.ones((3, 3), dtype=bool))
    return labels[start] == labels[goal]


def line_is_clear(blocked: np.ndarray, p, q) -> bool:
    """True if the segment between the centres of cells p and q touches no blocked cell.

    Exact supercover: every cell the segment passes through, including cells
    it only touches at a corner, so a shortcut never clips a blocked corner.
    Cell (r, c) is the square [r - 1/2, r + 1/2] x [c - 1/2, c + 1/2]. Along
    the major axis, each column (or row) strip is crossed over a range of
    the minor coordinate, computed in integer half-cell units; the cells
    whose range meets it (at most three) are tested. Cells beyond the grid's
    edge (a line along it may touch them at a corner) count as clear.
    """
    return _supercover_is_clear(blocked, int(p[0]), int(p[1]), int(q[0]), int(q[1]))


@numba.njit(cache=True)
def _supercover_is_clear(grid, r0, c0, r1, c1):
    """``line_is_clear`` as a loop: smoothing and path checks test thousands of short lines, each a
    dozen numpy calls on a handful of cells when vectorised."""
    steep = abs(c1 - c0) < abs(r1 - r0)
    if steep:  # make columns the major axis (grid indices are swapped back below)
        r0, c0, r1, c1 = c0, r0, c1, r1
    if c1 < c0:
        r0, c0, r1, c1 = r1, c1, r0, c0
    D, dr = c1 - c0, r1 - r0
    rows, cols = (grid.shape[1], grid.shape[0]) if steep else (grid.shape[0], grid.shape[1])
    for k in range(D + 1):
        # minor coordinate times 2D at the strip's edges (clipped to the segment's ends)
        ya = 2 * D * r0 + dr * max(2 * k - 1, 0)
        yb = 2 * D * r0 + dr * min(2 * k + 1, 2 * D)
        ylo, yhi = min(ya, yb), max(ya, yb)
        if D == 0:
            low = high = r0
        else:
            low = -((D - ylo) // (2 * D))  # ceil((ylo - D) / 2D): lowest row touched
            high = min((yhi + D) // (2 * D), low + 2)  # highest row touched
        col = c0 + k
        if not 0 <= col < cols:
            continue
        for row in range(max(low, 0), min(high, rows - 1) + 1):
            if grid[col, row] if steep else grid[row, col]:
                return False
    return True


def smooth(path: np.ndarray, blocked_inflated: np.ndarray) -> np.ndarray:
    """Line-of-sight shortcutting: from each waypoint jump to the farthest visible later one.

    Greedy; "farthest" is found by probing 1, 2, 4, ... steps ahead until a
    line is blocked, then bisecting, so each waypoint costs O(log n) exact line
    tests (:func:`line_is_clear`) instead of O(n). Visibility along a path is
    not monotone, so this may stop short of the truly farthest visible point;
    every kept segment is still verified. The next path point is always
    accepted, so the result is never longer than the input and keeps its first
    and last points.
    """
    path = np.asarray(path)
    grid = _mask(blocked_inflated)
    n = len(path)
    if n <= 2:
        return path.copy()
    keep = [0]
    i = 0
    while i < n - 1:
        lo, hi, step = i + 1, None, 2
        while lo < n - 1:
            j = min(i + step, n - 1)
            if line_is_clear(grid, path[i], path[j]):
                lo = j
                step *= 2
            else:
                hi = j
                break
        if hi is not None:
            while hi - lo > 1:
                m = (lo + hi) // 2
                if line_is_clear(grid, path[i], path[m]):
                    lo = m
                else:
                    hi = m
        keep.append(lo)
        i = lo
    return path[keep]


def _escape(blocked: np.ndarray, inflated: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Shortest 8-connected walk over really free cells from start to the nearest inflated-free cell."""
    rows, cols = blocked.shape
    parent = {start: start}
    queue = deque([start])
    while queue:
        r, c = cell = queue.popleft()
        if not inflated[cell]:
            walk = [cell]
            while walk[-1] != start:
                walk.append(parent[walk[-1]])
            return np.array(walk[::-1], dtype=np.int64)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nb = (r + dr, c + dc)
                if not (0 <= nb[0] < rows and 0 <= nb[1] < cols) or nb in parent or blocked[nb]:
                    continue
                if dr and dc and blocked[r + dr, c] and blocked[r, c + dc]:
                    continue  # no squeezing between corners
                parent[nb] = cell
                queue.append(nb)
    raise NoPath(UNREACHABLE, "the start is boxed in by obstacles")


def plan(blocked: np.ndarray, start, goal, radius_cells: float, doubtful: bool = False) -> np.ndarray:
    """Waypoint cells (n, 2) from start to goal, both included, keeping radius_cells of clearance.

    inflate + astar + smooth. A start inside the inflated zone (but not in an
    obstacle) first escapes to the nearest free cell; a goal inside the
    inflated zone raises NoPath(GOAL_BLOCKED). start == goal gives one point.
    ``doubtful``: see :func:`astar`.
    """
    blocked = _mask(blocked)
    start, goal = _cell(blocked, start, "start"), _cell(blocked, goal, "goal")
    if blocked[start]:
        raise NoPath(START_BLOCKED)
    if start == goal:
        return np.array([start], dtype=np.int64)
    if blocked[goal]:
        raise NoPath(GOAL_BLOCKED)
    inflated = inflate(blocked, radius_cells)
    if inflated[goal]:
        raise NoPath(GOAL_BLOCKED, f"within {radius_cells:g} cells of one")
    head = np.zeros((0, 2), dtype=np.int64)
    if inflated[start]:
        escape = _escape(blocked, inflated, start)
        head = smooth(escape, blocked)[:-1]
        start = tuple(int(v) for v in escape[-1])
    return np.concatenate([head, smooth(astar(inflated, start, goal, doubtful), inflated)])
