"""The memory map: a 2D occupancy grid at the operating height, centred on home.

Cells hold log-odds in small integers (int8): a hit adds evidence of an
obstacle, a ray passing through a cell adds evidence of free space, so every
cell is unknown, free or occupied and objects that move away fade. Integers
keep the map exact when it is streamed: a ground station applying the same
cell values holds the same map, cell for cell. Rows run along +y (north),
columns along +x (east), as an image of the map seen from above with row 0 south.

Doorways. A sonar's echo at range r comes from somewhere on the arc of its
cone at r (at 3 m the arc of a 7.5 degree half-angle is 0.8 m wide, nearly a
doorway). Putting the echo on the centre line, or marking the whole arc
occupied, closes a doorway whenever a cone's edge touches its frame. Of the
three ways out (a finer grid near the vehicle, sub-cell ray ends, or hits
that mark only the cells that can explain them), the last is chosen: it keeps
one grid at one resolution (so the streamed map, its pictures and the
planner's windows are unchanged) and it fixes the cause, not the scale. An
echo's arc is sampled every half cell; cells known free cannot explain it, an
occupied cell on it (a door frame seen face on) explains it alone, and
otherwise the unknown cell nearest the centre line takes it, which the free
lines through the doorway from nearer poses clear if it was wrong. (Sharing
the evidence among all unknown cells of the arc was tried: it blurred an
oblique wall up to a metre in front of itself.)
The free part of a cone is filled with lines at most a cell apart (up to
``FREE_SPREAD`` of its half-angle and ``SIDE_REACH``), so that a doorway
seen through is free cell for cell, as planning through it needs.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

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
        sonar model): lines across the cone, at most a cell apart, up to ``FREE_SPREAD``
        of the half-angle ``beams`` (radians) either side, are marked free up to a cell
        short of the echo (the sides up to ``SIDE_REACH`` at most). The echo marks the
        cells of its arc that can explain it (see the module docstring); without
        ``beams`` a reading is one line, free up to the cell its echo ends in, which
        gains ``HIT``. A batch is one monitor period: each cell that any line passes
        loses ``MISS`` once, each cell an echo marks gains once, the most any echo of
        the batch gives it (readings of one period see the same thing, so they are
        one piece of evidence); misses are applied before hits. A beam that leaves the band around
        the sensor's height counts only up to where it leaves it, and its echo (ground
        or ceiling) is no obstacle. ``free`` (a mask) picks the readings whose beams
        mark free space, when several of a batch would only repeat each other.
        """
        if not (type(origins) is np.ndarray and origins.dtype == np.float64 and origins.shape[1:] == (3,)):
            origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        count = len(origins)
        if not count:
            return 0
        directions = _per_reading(directions, (count, 3), "directions")
        distances = _per_reading(distances, (count,), "distances")
        clears = np.minimum(_per_reading(max_ranges, (count,), "max_ranges"), self.NO_ECHO_CLEARS)
        halves = np.zeros(count) if beams is None else _per_reading(beams, (count,), "beams")
        marks = np.ones(count, dtype=np.bool_) if free is None else _per_reading(free, (count,), "free", np.bool_)
        self.version += 1
        changed, hits, crossed = _loops().project(
            self.grid.reshape(-1), self.ever_hit.reshape(-1), self.size, self.origin[0], self.origin[1],
            self.resolution, self.band, np.ascontiguousarray(origins), directions, distances, clears, halves,
            beams is not None, marks)
        self.occupied_version += crossed
        if len(changed):
            self._note_changes(changed)
        return hits

    def add_reading(self, origin: np.ndarray, direction: np.ndarray, distance: float | None,
                    max_range: float, free: bool = True) -> bool:
        """Project one reading (see ``add_readings``; ``free`` False: its echo marks, its beam frees nothing);
        True when it marked an obstacle."""
        return self.add_readings(np.asarray(origin)[None], np.asarray(direction)[None],
                                 np.array([np.nan if distance is None else distance]), np.array([max_range]),
                                 free=np.array([free])) > 0

    def mark_body(self, x: float, y: float, radius: float) -> None:
        """The vehicle's body is here, so these cells are free, whatever the sonar said."""
        centre = self.cell_of(x, y)
        if centre is None:
            return
        cells, crossed = _loops().free_cells(self.grid.reshape(-1), self.size, *centre,
                                             *_disc(radius, self.resolution))
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

    def take_changes(self, in_order: bool = True) -> np.ndarray:
        """Flat indices of cells changed since the last call (for streaming deltas), in increasing order and
        each once; ``in_order=False``: as they were noted (a caller that sorts them elsewhere)."""
        if self._folded is not None:
            self._changed.append(np.flatnonzero(self._folded))
            self._folded = None
        if not self._changed:
            return np.zeros(0, dtype=np.int64)
        changed = np.concatenate(self._changed)
        self._changed.clear()
        if not in_order:
            return changed
        changed.sort()  # then without repeats (np.unique, several times slower)
        first = np.ones(len(changed), dtype=bool)
        first[1:] = changed[1:] != changed[:-1]
        return changed[first]

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
        return states_of(self.grid)

    @property
    def detections(self) -> int:
        """Cells occupied now (the thesis's memory-map count)."""
        return int(_loops().count_occupied(self.grid.reshape(-1)))

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

    def save_png(self, path: str | Path, **decorations) -> None:
        """A picture of the map for people (``picture.draw_map``: cropped to what was explored, with a legend,
        scale and north; ``decorations`` are its title, home, trail, path, waypoints and position)."""
        from vehicle.mapping.picture import save_map_picture

        save_map_picture(path, self.grid, self.resolution, self.origin, **decorations)


def _loops():
    """The compiled loops (``vehicle.mapping.tracing``), loaded when a map first takes evidence: a ground
    station that only shows streamed maps never loads numba."""
    from vehicle.mapping import tracing

    return tracing


def _per_reading(values, shape: tuple[int, ...], what: str, dtype=np.float64) -> np.ndarray:
    """``values`` as a C array of ``shape`` (a scalar, or one row, applies to every reading)."""
    if type(values) is np.ndarray and values.shape == shape and values.dtype == dtype and values.flags.c_contiguous:
        return values  # as the monitor builds them: nothing to convert
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


def states_of(grid: np.ndarray) -> np.ndarray:
    """Per cell of a log-odds grid (a map here, or one streamed from a vehicle): UNKNOWN, FREE or OCCUPIED."""
    out = np.zeros(grid.shape, dtype=np.uint8)
    out[grid <= FREE_AT] = FREE
    out[grid >= OCCUPIED_AT] = OCCUPIED
    return out


STATE_COLOURS = np.array([[0, 0, 0, 0], [235, 240, 245, 110], [200, 30, 40, 255]], dtype=np.uint8)


def state_image(states: np.ndarray) -> np.ndarray:
    """RGBA image (north up) of a grid of UNKNOWN/FREE/OCCUPIED states (row 0 south)."""
    return STATE_COLOURS[states[::-1]]
