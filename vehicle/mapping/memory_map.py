"""The memory map: a 2D occupancy grid at the operating height, centred on home.

Cells hold log-odds in small integers (int8): a hit adds evidence of an
obstacle, a ray passing through a cell adds evidence of free space, so every
cell is unknown, free or occupied and objects that move away fade. Integers
keep the map exact when it is streamed: a ground station applying the same
cell values holds the same map, cell for cell. Rows run along +y (north),
columns along +x (east), as an image of the map seen from above with row 0 south.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numba
import numpy as np

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
FREE_SPREAD = 0.7  # share of a beam's half-angle at which its sides are marked free
SIDE_REACH = 8.0  # m: further out the sides add little beyond the centre line, and cost as much


# Log-odds evidence, in int8 cells
HIT = 9  # evidence added to the cell a reading ends in
MISS = 3  # evidence removed from each cell a reading passes through
LIMIT = 30  # saturation, so a long-seen wall can still fade within a few passes
FLOOR = -3  # free evidence saturates at once: a newcomer shows up at its first echo, and
# free cells change only once, which keeps the streamed map small
OCCUPIED_AT = 6  # at or above: occupied
FREE_AT = -3  # at or below: free
NO_ECHO_CLEARS = 15.0  # m: a reading without echo is evidence of free space only this far
# (a surface met at a grazing angle returns no echo either, so "nothing" is weak evidence)


class MemoryMap:
    HIT, MISS, LIMIT, FLOOR, OCCUPIED_AT, FREE_AT, NO_ECHO_CLEARS = (
        HIT, MISS, LIMIT, FLOOR, OCCUPIED_AT, FREE_AT, NO_ECHO_CLEARS)

    def __init__(self, center: tuple[float, float], space_size: float = 100.0, resolution: float = 10.0,
                 band: float = 1.0):
        if space_size <= 0 or resolution <= 0:
            raise ValueError("space_size and resolution must be positive")
        self.center = (float(center[0]), float(center[1]))
        self.space_size = float(space_size)
        self.resolution = float(resolution)
        self.band = band  # hits further than this above or below the sensor are ground or ceiling
        self.size = max(1, int(round(2 * space_size * resolution)))
        self.origin = (self.center[0] - space_size, self.center[1] - space_size)  # south-west corner
        self.grid = np.zeros((self.size, self.size), dtype=np.int8)
        self.ever_hit = np.zeros((self.size, self.size), dtype=bool)
        self.occupied_version = 0  # counts cells becoming or ceasing to be occupied, so users can skip rechecks
        self.version = 0  # counts updates of any kind, for views that redraw
        self._changed: list[np.ndarray] = []
        self._folded: np.ndarray | None = None  # changes folded into a mask when nobody took them

    # ---- geometry ----------------------------------------------------------------------------
    def cell_of(self, x: float, y: float) -> tuple[int, int] | None:
        """(row, col) of the cell containing the point, or None outside the map."""
        col = math.floor((x - self.origin[0]) * self.resolution)
        row = math.floor((y - self.origin[1]) * self.resolution)
        if 0 <= row < self.size and 0 <= col < self.size:
            return row, col
        return None

    def center_of(self, row: float, col: float) -> tuple[float, float]:
        return (self.origin[0] + (col + 0.5) / self.resolution, self.origin[1] + (row + 0.5) / self.resolution)

    def contains(self, x: float, y: float) -> bool:
        return self.cell_of(x, y) is not None

    # ---- evidence ----------------------------------------------------------------------------
    def add_readings(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
                     max_ranges: np.ndarray, beams: np.ndarray | None = None,
                     free: np.ndarray | None = None) -> int:
        """Project a batch of readings into the map; returns how many marked an obstacle.

        ``distances`` holds NaN where a reading had no echo (then the ray is free up to
        its max range, at most ``NO_ECHO_CLEARS``). A sonar hears the nearest echo in
        its cone, so the whole cone is free up to the distance measured (the classic
        sonar model): besides the centre line, two lines at ``FREE_SPREAD`` of the
        half-angle ``beams`` (radians) either side are marked free, up to ``SIDE_REACH``
        where the cone is narrow enough to matter (doorways). The echo itself is
        placed on the centre line. A batch is one monitor period: each cell that any
        line passes loses ``MISS`` once, each cell an echo ends in gains ``HIT`` once
        (readings of one period see the same thing, so they are one piece of
        evidence); misses are applied before hits. A beam that leaves the band around
        the sensor's height counts only up to where it leaves it, and its echo (ground
        or ceiling) is no obstacle. ``free`` (a mask) picks the readings whose beams
        mark free space, when several of a batch would only repeat each other.
        """
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        count = len(origins)
        if not count:
            return 0
        directions = _per_reading(directions, (count, 3), "directions")
        distances = _per_reading(distances, (count,), "distances")
        clears = np.minimum(_per_reading(max_ranges, (count,), "max_ranges"), self.NO_ECHO_CLEARS)
        spreads = np.zeros(count) if beams is None else FREE_SPREAD * _per_reading(beams, (count,), "beams")
        marks = np.ones(count, dtype=np.bool_) if free is None else _per_reading(free, (count,), "free", np.bool_)
        self.version += 1
        passed, hits, crossed = _project(
            self.grid.reshape(-1), self.ever_hit.reshape(-1), self.size, self.origin[0], self.origin[1],
            self.resolution, self.band, np.ascontiguousarray(origins), directions, distances, clears, spreads,
            beams is not None, marks)
        self.occupied_version += crossed
        if len(passed):
            self._note_changes(passed)
        if len(hits):
            self._note_changes(hits)
        return len(hits)

    def add_reading(self, origin: np.ndarray, direction: np.ndarray, distance: float | None,
                    max_range: float) -> bool:
        """Project one reading (see ``add_readings``); True when it marked an obstacle."""
        return self.add_readings(np.asarray(origin)[None], np.asarray(direction)[None],
                                 np.array([np.nan if distance is None else distance]), np.array([max_range])) > 0

    def mark_body(self, x: float, y: float, radius: float) -> None:
        """The vehicle's body is here, so these cells are free, whatever the sonar said."""
        centre = self.cell_of(x, y)
        if centre is None:
            return
        cells, crossed = _free_cells(self.grid.reshape(-1), self.size, *centre, *_disc(radius, self.resolution))
        self.occupied_version += crossed
        if len(cells):
            self._note_changes(cells)

    def _note_changes(self, cells: np.ndarray) -> None:
        self._changed.append(cells)
        if len(self._changed) > 512:  # nobody is taking them (a batch run): fold them into a mask of the map
            if self._folded is None:
                self._folded = np.zeros(self.grid.size, dtype=bool)
            self._folded[np.concatenate(self._changed)] = True
            self._changed.clear()

    def take_changes(self) -> np.ndarray:
        """Flat indices of cells changed since the last call (for streaming deltas)."""
        if self._folded is not None:
            self._changed.append(np.flatnonzero(self._folded))
            self._folded = None
        if not self._changed:
            return np.zeros(0, dtype=np.int64)
        changed = np.unique(np.concatenate(self._changed))
        self._changed.clear()
        return changed

    # ---- views -------------------------------------------------------------------------------
    @property
    def occupied(self) -> np.ndarray:
        return self.grid >= self.OCCUPIED_AT

    def occupied_in(self, rows: slice, cols: slice) -> np.ndarray:
        """The occupied mask of a window only (cheaper than slicing the whole mask)."""
        return self.grid[rows, cols] >= self.OCCUPIED_AT

    def free_in(self, rows: slice, cols: slice) -> np.ndarray:
        return self.grid[rows, cols] <= self.FREE_AT

    @property
    def free(self) -> np.ndarray:
        return self.grid <= self.FREE_AT

    def states(self) -> np.ndarray:
        """Per cell UNKNOWN (0), FREE (1) or OCCUPIED (2)."""
        out = np.zeros(self.grid.shape, dtype=np.uint8)
        out[self.free] = FREE
        out[self.occupied] = OCCUPIED
        return out

    @property
    def detections(self) -> int:
        """Cells occupied now (the thesis's memory-map count)."""
        return int(np.count_nonzero(self.occupied))

    @property
    def cells_ever_hit(self) -> int:
        return int(np.count_nonzero(self.ever_hit))

    def occupied_points(self) -> np.ndarray:
        """(n, 2) scene x, y of the centres of occupied cells."""
        rows, cols = np.nonzero(self.occupied)
        return np.column_stack([self.origin[0] + (cols + 0.5) / self.resolution,
                                self.origin[1] + (rows + 0.5) / self.resolution])

    def image(self) -> np.ndarray:
        """RGBA picture, north up: unknown transparent, free pale, occupied dark red."""
        return state_image(self.states())

    def save_npy(self, path: str | Path) -> None:
        np.save(path, self.grid)

    def save_png(self, path: str | Path) -> None:
        from PIL import Image

        rgba = self.image()
        background = np.full(rgba.shape, (60, 60, 66, 255), dtype=np.uint8)
        alpha = rgba[..., 3:4].astype(np.float32) / 255
        blended = (rgba * alpha + background * (1 - alpha)).astype(np.uint8)
        blended[..., 3] = 255
        Image.fromarray(blended).save(path)


def _per_reading(values, shape: tuple[int, ...], what: str, dtype=np.float64) -> np.ndarray:
    """``values`` as a C array of ``shape`` (a scalar, or one row, applies to every reading)."""
    array = np.asarray(values, dtype=dtype)
    if array.shape == shape:
        return np.ascontiguousarray(array)
    try:
        return np.array(np.broadcast_to(array, shape))
    except ValueError:
        raise ValueError(f"{what}: expected one per reading, {shape}, not shape {np.shape(values)}") from None


@functools.cache
def _disc(radius: float, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column offsets of the cells whose centres lie within ``radius`` metres of a cell's centre."""
    reach = int(math.ceil(radius * resolution))
    rows, cols = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    inside = (rows**2 + cols**2) * (1.0 / resolution**2) <= radius * radius
    return rows[inside], cols[inside]


STATE_COLOURS = np.array([[0, 0, 0, 0], [235, 240, 245, 110], [200, 30, 40, 255]], dtype=np.uint8)


def state_image(states: np.ndarray) -> np.ndarray:
    """RGBA image (north up) of a grid of UNKNOWN/FREE/OCCUPIED states (row 0 south)."""
    return STATE_COLOURS[states[::-1]]


# ---- compiled loops --------------------------------------------------------------------------
# Tracing a dozen lines through the grid is a few microseconds of arithmetic, but written
# with numpy it took about a hundred calls on small arrays, whose overheads made it the
# largest share of a simulated mission's time. No maintained library traces a batch of
# sonar cones into an occupancy grid, so the loops are written out and compiled with numba
# (cached on disk). NUMBA_DISABLE_JIT=1 runs the same code as plain Python.


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
def _project(grid, ever_hit, size, x0, y0, resolution, band, origins, directions, distances, clears, spreads,
             sides, marks):
    """``MemoryMap.add_readings`` on flat views of the grid: returns the cells passed (each listed once
    per line), the cells hit, and 1 if some cell became or ceased to be occupied, else 0."""
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
    for k in range(used):
        grid[passed[k]] = after[k]
    hits = echo_cell[echo_cell >= 0]
    gained = np.empty(len(hits), dtype=np.int8)
    for k in range(len(hits)):  # misses first, then hits, each once
        before = grid[hits[k]]
        gained[k] = min(before + HIT, LIMIT)
        if before < OCCUPIED_AT and gained[k] >= OCCUPIED_AT:
            crossed = 1
    for k in range(len(hits)):
        grid[hits[k]] = gained[k]
        ever_hit[hits[k]] = True
    return passed, hits, crossed


@numba.njit(cache=True)
def _free_cells(grid, size, row, col, rows, cols):
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
