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

from vehicle.mapping.memory_map import FLOOR, FREE_AT, FREE_SPREAD, HIT, LIMIT, MISS, OCCUPIED_AT, SIDE_REACH


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
def _add_line(lines, used, x, y, dx, dy, skip, strong, x0, y0, resolution, size):
    """Append the segment (x, y) + t (dx, dy), t in [0, 1], to ``lines`` (``strong``: it takes evidence from
    occupied cells too); returns the new count. One longer
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
    lines[used, 5] = 1.0 if strong else 0.0
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
def project(grid, ever_hit, size, x0, y0, resolution, band, origins, directions, distances, clears, beams,
            sides, marks):
    """``MemoryMap.add_readings`` on flat views of the grid: returns the cells whose value changed (most cells
    a beam passes are free already), how many readings ended in an echo on the map, and 1 if some cell
    became or ceased to be occupied, else 0."""
    count = len(origins)
    lengths = np.zeros(count)
    units = np.zeros((count, 2))
    echoes = np.zeros(count, dtype=np.bool_)
    fans = np.zeros(count, dtype=np.int64)  # free lines either side of the centre line
    arcs = np.zeros(count + 1, dtype=np.int64)  # where each reading's arc samples start
    total_lines = 0
    for i in range(count):
        arcs[i + 1] = arcs[i]
        echo = math.isfinite(distances[i])
        length = distances[i] if echo else clears[i]
        ux, uy, uz = directions[i, 0], directions[i, 1], directions[i, 2]
        norm = math.sqrt(ux * ux + uy * uy + uz * uz)
        if not norm > 0 or not math.isfinite(norm) or not length >= 0:
            continue  # no direction (or no length): no reading
        if abs(norm - 1.0) > 1e-9:  # directions should be unit vectors; a sloppy caller's still are
            ux, uy, uz = ux / norm, uy / norm, uz / norm
        vertical = abs(uz * length)
        if vertical > band:  # the beam leaves the band: it counts up to there, and its echo (ground or ceiling)
            length = length * band / max(vertical, 1e-12)  # is no obstacle
            echo = False
        lengths[i], units[i, 0], units[i, 1], echoes[i] = length, ux, uy, echo
        if echo:  # the arc the echo lies on, sampled every half cell (the centre only for a bare line)
            across = 2.0 * beams[i] * length * math.hypot(ux, uy) * resolution
            arcs[i + 1] += 1 + 2 * int(min(across, 4.0 * size) + 0.5) if sides else 1
        if marks[i]:
            if sides:  # lines across the cone at most a cell apart where they end
                reach = min(length, SIDE_REACH)
                fans[i] = int(math.ceil(FREE_SPREAD * beams[i] * reach * resolution))
            total_lines += 1 + 2 * fans[i]
    lines = np.empty((max(total_lines, 1), 6))  # x, y, dx, dy, a cell the line does not mark, strong
    used_lines = np.int64(0)  # not the literal 0: that would compile the callees once more for it
    arc_cells = np.full(arcs[count], -1, dtype=np.int64)
    for i in range(count):
        x, y, ux, uy, length = origins[i, 0], origins[i, 1], units[i, 0], units[i, 1], lengths[i]
        echo_cell = -1
        if echoes[i]:
            echo_cell = _cell(x + ux * length, y + uy * length, x0, y0, resolution, size)
            samples = arcs[i + 1] - arcs[i]
            for k in range(samples):
                angle = beams[i] * (2.0 * k / (samples - 1.0) - 1.0) if samples > 1 else 0.0
                c, s = math.cos(angle), math.sin(angle)
                arc_cells[arcs[i] + k] = _cell(x + (ux * c - uy * s) * length, y + (uy * c + ux * s) * length,
                                               x0, y0, resolution, size)
        if not marks[i] or not (length >= 0):
            continue
        if not sides:  # a bare line: free up to the cell its echo ends in
            used_lines = _add_line(lines, used_lines, x, y, ux * length, uy * length, echo_cell, True, x0, y0,
                                   resolution, size)
            continue
        free = max(length - 1.0 / resolution, 0.0) if echoes[i] else length  # a cell short of the echo's arc
        heard = echoes[i]  # silence says nothing of a wall met too obliquely to echo: it clears unknown cells only
        used_lines = _add_line(lines, used_lines, x, y, ux * free, uy * free, -1, heard, x0, y0, resolution, size)
        reach = min(free, SIDE_REACH)
        for k in range(1, fans[i] + 1):
            spread = FREE_SPREAD * beams[i] * k / fans[i]
            c, s = math.cos(spread), math.sin(spread)
            used_lines = _add_line(lines, used_lines, x, y, (ux * c + uy * s) * reach, (uy * c - ux * s) * reach,
                                   -1, heard, x0, y0, resolution, size)
            used_lines = _add_line(lines, used_lines, x, y, (ux * c - uy * s) * reach, (uy * c + ux * s) * reach,
                                   -1, heard, x0, y0, resolution, size)
    room = 0
    for k in range(used_lines):
        room += _samples(lines[k, 2], lines[k, 3], resolution)
    passed = np.empty(room, dtype=np.int64)
    strong = np.empty(room, dtype=np.bool_)
    used = np.int64(0)
    for k in range(used_lines):
        first = used
        used = _trace(passed, used, lines[k, 0], lines[k, 1], lines[k, 2], lines[k, 3], int(lines[k, 4]), x0, y0,
                      resolution, size)
        strong[first:used] = lines[k, 5] > 0
    passed = passed[:used]
    crossed = 0
    # each cell loses MISS once however many lines pass it: all new values come from the old ones; a line
    # that is not strong leaves occupied cells alone
    after = np.empty(used, dtype=np.int8)
    for k in range(used):
        before = grid[passed[k]]
        after[k] = max(before - MISS, FLOOR) if strong[k] or before < OCCUPIED_AT else before
        if before >= OCCUPIED_AT and after[k] < OCCUPIED_AT:
            crossed = 1
    changed = np.empty(used + arcs[count], dtype=np.int64)
    changes = 0
    for k in range(used):
        if not strong[k] and after[k] == grid[passed[k]]:
            continue  # a weak line that left an occupied cell alone does not undo a strong one's miss
        if grid[passed[k]] != after[k]:
            changed[changes] = passed[k]
            changes += 1
        grid[passed[k]] = after[k]
    # then the echoes, each on the cells of its arc that can explain it (misses first, then hits)
    targets, gains, hits = _explain(grid, arcs, arc_cells, echoes)
    order = np.argsort(targets, kind="mergesort")
    k = 0
    while k < len(order):  # each cell gains once, the most any echo of the batch gives it
        cell, gain = targets[order[k]], gains[order[k]]
        k += 1
        while k < len(order) and targets[order[k]] == cell:
            gain = max(gain, gains[order[k]])
            k += 1
        before = grid[cell]
        value = min(before + gain, LIMIT)
        if before < OCCUPIED_AT <= value:
            crossed = 1
        if value != before:
            changed[changes] = cell
            changes += 1
        grid[cell] = value
        ever_hit[cell] = True
    return changed[:changes], hits, crossed


@numba.njit(cache=True)
def _explain(grid, arcs, arc_cells, echoes):
    """The cells each echo adds evidence to (HIT each): an echo at range r comes from somewhere on the arc of
    its cone at r. Cells known free cannot explain it; occupied cells on the arc (a door frame seen face on)
    explain it alone; else the unknown cell nearest the centre line takes it; an arc whose every cell is
    known free marks its centre cell (something new). So a cone that spans a doorway beside a frame already
    seen marks nothing in the doorway, and one marked wrongly is cleared by the free lines through it."""
    targets = np.empty(len(arc_cells), dtype=np.int64)
    gains = np.empty(len(arc_cells), dtype=np.int64)
    used = 0
    hits = 0
    for i in range(len(arcs) - 1):
        if not echoes[i]:
            continue
        first, last = arcs[i], arcs[i + 1]
        occupied = 0
        unknown = 0
        previous = -2
        for k in range(first, last):
            cell = arc_cells[k]
            if cell < 0 or cell == previous:
                previous = cell
                continue
            previous = cell
            if grid[cell] >= OCCUPIED_AT:
                occupied += 1
            elif grid[cell] > FREE_AT:
                unknown += 1
        if occupied + unknown == 0:
            middle = arc_cells[(first + last - 1) // 2]
            if middle >= 0:
                targets[used], gains[used] = middle, HIT
                used += 1
                hits += 1
            continue
        hits += 1
        if not occupied:  # the unknown cell nearest the centre line (where the beam is strongest) takes it
            middle = (first + last - 1) / 2.0
            best = -1
            for k in range(first, last):
                cell = arc_cells[k]
                if cell >= 0 and grid[cell] > FREE_AT and (best < 0 or abs(k - middle) < abs(best - middle)):
                    best = k
            targets[used], gains[used] = arc_cells[best], HIT
            used += 1
            continue
        previous = -2
        for k in range(first, last):
            cell = arc_cells[k]
            if cell >= 0 and cell != previous and grid[cell] >= OCCUPIED_AT:
                targets[used], gains[used] = cell, HIT
                used += 1
            previous = cell
    return targets[:used], gains[:used], hits


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
