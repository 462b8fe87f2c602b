"""The memory map's compiled loops: sonar cones traced into the grid, the body's cells marked free.

Tracing a dozen lines through the grid is a few microseconds of arithmetic, but
written with numpy it took about a hundred calls on small arrays, whose
overheads made it the largest share of a simulated mission's time. No
maintained library traces a batch of sonar cones into an occupancy grid, so
the loops are written out and compiled with numba (cached on disk).
``NUMBA_DISABLE_JIT=1`` runs the same code as plain Python. ``MemoryMap``
loads this module on its first update, not on import.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vehicle.mapping.memory_map import FLOOR, FREE_AT, HIT, LIMIT, MISS, OCCUPIED_AT, SIDE_REACH


@numba.njit(cache=True)
def _cell(x, y, x0, y0, resolution, size):
    """Flat index of the cell of a point, -1 outside the map (or for NaN, compared before any rounding)."""
    col = (x - x0) * resolution
    row = (y - y0) * resolution
    if 0.0 <= col < size and 0.0 <= row < size:
        return int(row) * size + int(col)
    return -1


@numba.njit(cache=True)
def _samples(dx, dy, resolution):
    """Points sampled along a segment: one per cell length, both ends included; none if it is not finite."""
    cells = math.hypot(dx, dy) * resolution
    return int(cells) + 2 if math.isfinite(cells) else 0


@numba.njit(cache=True)
def _trace(out, used, x, y, dx, dy, skip, x0, y0, resolution, size):
    """Append to ``out`` (from ``used`` on) the cells the segment (x, y) + t (dx, dy), t in [0, 1], passes,
    except ``skip``; returns the new count.

    Samples once per cell length (a cell the line only clips near a corner may be missed,
    which costs nothing here); a straight line never comes back to a cell it left, so
    dropping repeats of the previous sample lists each cell once.
    """
    samples = _samples(dx, dy, resolution)
    previous = -2
    for k in range(samples):
        t = k / (samples - 1.0)
        cell = _cell(x + dx * t, y + dy * t, x0, y0, resolution, size)
        if cell >= 0 and cell != previous and cell != skip:
            out[used] = cell
            used += 1
        previous = cell
    return used


@numba.njit(cache=True)
def _add_line(lines, used, x, y, dx, dy, skip, x0, y0, resolution, size):
    """Append the segment (x, y) + t (dx, dy), t in [0, 1], to ``lines``; returns the new count. One longer
    than the map is wide is cut to its part over the map first, so no line takes more samples than the map
    has cells across, whatever it is given."""
    if _samples(dx, dy, resolution) > 2 * size + 2:
        side = size / resolution  # Liang-Barsky: the span of t over the map's square, one edge at a time
        start, end = _clip(-dx, x - x0, 0.0, 1.0)
        start, end = _clip(dx, x0 + side - x, start, end)
        start, end = _clip(-dy, y - y0, start, end)
        start, end = _clip(dy, y0 + side - y, start, end)
        if not start < end:
            return used
        x, y, dx, dy = x + dx * start, y + dy * start, dx * (end - start), dy * (end - start)
    lines[used, 0], lines[used, 1], lines[used, 2], lines[used, 3], lines[used, 4] = x, y, dx, dy, skip
    return used + 1


@numba.njit(cache=True)
def _clip(step, gap, start, end):
    """Narrow the span [start, end] of t to where the segment is inside one edge of a square: ``gap`` is
    how far inside the edge it starts, ``step`` how fast it moves away from it per unit of t."""
    if step == 0.0:
        return (start, end) if gap >= 0.0 else (1.0, 0.0)
    if step < 0.0:
        return max(start, gap / step), end
    return start, min(end, gap / step)


@numba.njit(cache=True)
def project(grid, ever_hit, size, x0, y0, resolution, band, origins, directions, distances, clears, spreads,
             sides, marks):
    """``MemoryMap.add_readings`` on flat views of the grid: returns the cells whose value changed (most cells
    a beam passes are free already), how many cells were hit, and 1 if some cell became or ceased to be
    occupied, else 0."""
    count = len(origins)
    echo_cell = np.full(count, -1)
    lines = np.empty((3 * count, 5))  # x, y, dx, dy and the echo cell of each line marked free
    used_lines = np.int64(0)  # not the literal 0: that would compile the callees once more for it
    for i in range(count):
        echo = math.isfinite(distances[i])
        length = distances[i] if echo else clears[i]
        x, y, ux, uy, uz = origins[i, 0], origins[i, 1], directions[i, 0], directions[i, 1], directions[i, 2]
        norm = math.sqrt(ux * ux + uy * uy + uz * uz)
        if not norm > 0 or not math.isfinite(norm):
            continue  # no direction: no reading
        if abs(norm - 1.0) > 1e-9:  # directions should be unit vectors; a sloppy caller's still are
            ux, uy, uz = ux / norm, uy / norm, uz / norm
        vertical = abs(uz * length)
        if vertical > band:  # the beam leaves the band: it counts up to there, and its echo is ground or ceiling
            length = length * band / max(vertical, 1e-12)
            echo = False
        if echo:
            echo_cell[i] = _cell(x + ux * length, y + uy * length, x0, y0, resolution, size)
        if not marks[i]:
            continue
        used_lines = _add_line(lines, used_lines, x, y, ux * length, uy * length, echo_cell[i], x0, y0,
                               resolution, size)
        if sides:  # the cone's sides, as far as the centre line reaches and SIDE_REACH at most
            c, s = math.cos(spreads[i]), math.sin(spreads[i])
            reach = min(length, SIDE_REACH)
            used_lines = _add_line(lines, used_lines, x, y, (ux * c + uy * s) * reach, (uy * c - ux * s) * reach,
                                   echo_cell[i], x0, y0, resolution, size)
            used_lines = _add_line(lines, used_lines, x, y, (ux * c - uy * s) * reach, (uy * c + ux * s) * reach,
                                   echo_cell[i], x0, y0, resolution, size)
    room = 0
    for k in range(used_lines):
        room += _samples(lines[k, 2], lines[k, 3], resolution)
    passed = np.empty(room, dtype=np.int64)
    used = np.int64(0)
    for k in range(used_lines):
        used = _trace(passed, used, lines[k, 0], lines[k, 1], lines[k, 2], lines[k, 3], int(lines[k, 4]), x0, y0,
                      resolution, size)
    passed = passed[:used]
    crossed = 0
    # each cell loses MISS once however many lines pass it: all new values come from the old ones
    after = np.empty(used, dtype=np.int8)
    for k in range(used):
        before = grid[passed[k]]
        after[k] = max(before - MISS, FLOOR)
        if before >= OCCUPIED_AT and after[k] < OCCUPIED_AT:
            crossed = 1
    hits = echo_cell[echo_cell >= 0]
    changed = np.empty(used + len(hits), dtype=np.int64)
    count = 0
    for k in range(used):
        if grid[passed[k]] != after[k]:
            changed[count] = passed[k]
            count += 1
        grid[passed[k]] = after[k]
    gained = np.empty(len(hits), dtype=np.int8)
    for k in range(len(hits)):  # misses first, then hits, each once
        before = grid[hits[k]]
        gained[k] = min(before + HIT, LIMIT)
        if before < OCCUPIED_AT and gained[k] >= OCCUPIED_AT:
            crossed = 1
    for k in range(len(hits)):
        if grid[hits[k]] != gained[k]:
            changed[count] = hits[k]
            count += 1
        grid[hits[k]] = gained[k]
        ever_hit[hits[k]] = True
    return changed[:count], len(hits), crossed


@numba.njit(cache=True)
def free_cells(grid, size, row, col, rows, cols):
    """Mark free the cells at the offsets (rows, cols) from (row, col) that are inside the map and not
    free yet; returns them, and 1 if one of them was occupied, else 0."""
    changed = np.empty(len(rows), dtype=np.int64)
    used = 0
    crossed = 0
    for k in range(len(rows)):
        r, c = row + rows[k], col + cols[k]
        if 0 <= r < size and 0 <= c < size and grid[r * size + c] > FREE_AT:
            if grid[r * size + c] >= OCCUPIED_AT:
                crossed = 1
            grid[r * size + c] = FREE_AT
            changed[used] = r * size + c
            used += 1
    return changed[:used], crossed


@numba.njit(cache=True)
def count_occupied(grid):
    """How many cells are occupied: ``np.count_nonzero(grid >= OCCUPIED_AT)`` without its 4 MB temporary (at
    the end of every run, a tenth of a short one's time)."""
    count = 0
    for value in grid:
        if value >= OCCUPIED_AT:
            count += 1
    return count
