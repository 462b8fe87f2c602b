"""The image grid and the weight models: how much each pixel's attenuation counts in each link's measurement.

Ellipse (Wilson and Patwari 2010): a pixel counts for a link when the excess path length through its centre
(distance to one end plus distance to the other, minus the link's length) is below ``lam``; weight
1/sqrt(link length), so that long links, which pass many pixels, do not dominate. Exponential (the smooth
alternative, after Kaltiokallio, Bocca and Patwari 2014): the weight fades as exp(-excess / lam), cut at
``EXP_CUT`` * lam. Line (a person's shadow): the weight fades as a Gaussian of the pixel's distance from the
link's segment, standard deviation ``LINE_WIDTH``, cut at ``LINE_CUT`` of it, whatever the link's length: a person
shadows a link he stands near, by about as much on a long link as on a short one, so a pixel's attenuation
counts whole (no 1/sqrt(length)), and the band is as wide in the middle as near the radios, where the ellipse
narrows to nothing and a person beside a radio is seen by none of its links. Rows are sparse and cached per path
(the rounded positions of its two ends), so moving radios that revisit spots cost nothing new.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

LAMBDA = 0.1  # m: excess path length of the ellipse (Patwari's released RTI code and Kaltiokallio et al. use 0.1 m)
EXP_CUT = 4.0
LINE_WIDTH = 0.4  # m: about a person's half-width (0.2 to 0.25 m) and the fringe past it where the body still
# shadows part of the first Fresnel zone (a few tenths of a metre at 2.4 GHz); 0.3 m imaged two people 1.5 m apart
# apart in 15 of 20 simulated missions, 0.4 m in 19
LINE_CUT = 3.0
MODELS = ("ellipse", "exponential", "line")


@dataclass(frozen=True)
class Grid:
    """Pixels of side ``cell`` covering ``bounds`` (x0, y0, x1, y1); pixel (row iy, column ix) is index
    iy * nx + ix, centred at (x0 + (ix + 0.5) cell, y0 + (iy + 0.5) cell)."""

    bounds: tuple[float, float, float, float]
    cell: float

    def __post_init__(self) -> None:
        x0, y0, x1, y1 = self.bounds
        if not all(math.isfinite(v) for v in (*self.bounds, self.cell)):
            raise ValueError("bounds and cell must be finite numbers")
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"bounds {x0:g},{y0:g},{x1:g},{y1:g} have zero area (need x0 < x1 and y0 < y1)")
        if self.cell <= 0:
            raise ValueError(f"cell {self.cell:g} must be positive")
        if self.nx * self.ny > 250_000:
            raise ValueError(f"cell {self.cell:g} m makes {self.nx} x {self.ny} pixels (at most 250,000)")

    @property
    def nx(self) -> int:
        return max(1, math.ceil((self.bounds[2] - self.bounds[0]) / self.cell - 1e-9))

    @property
    def ny(self) -> int:
        return max(1, math.ceil((self.bounds[3] - self.bounds[1]) / self.cell - 1e-9))

    @property
    def shape(self) -> tuple[int, int]:
        return self.ny, self.nx

    def centres(self) -> np.ndarray:
        """(ny * nx, 2) pixel centres."""
        xs = self.bounds[0] + (np.arange(self.nx) + 0.5) * self.cell
        ys = self.bounds[1] + (np.arange(self.ny) + 0.5) * self.cell
        gx, gy = np.meshgrid(xs, ys)
        return np.column_stack([gx.ravel(), gy.ravel()])


def default_cell(bounds: tuple[float, float, float, float]) -> float:
    """About 50 pixels along the longer side, at least 0.1 m (finer than a person is wide, coarse enough that
    the prior's covariance stays small), rounded to a tidy 0.05 m step (0.15, not 0.15000000000000002).
    Up to a 10 m area that is at most 0.2 m: at least two pixel centres across the ellipse of any link over 1 m
    (its half-width at the middle is sqrt(d lam / 2 + lam^2 / 4), 0.23 m for d = 1 m at lam = 0.1 m) and
    across a person (0.3 to 0.5 m)."""
    side = max(bounds[2] - bounds[0], bounds[3] - bounds[1])
    return max(0.1, round(round(side / 50 / 0.05) * 0.05, 2))


def weight_rows(grid: Grid, paths: np.ndarray, model: str = "ellipse", lam: float = LAMBDA) -> sp.csr_matrix:
    """The weight matrix (paths x pixels) of ``paths`` ((P, 4): x0, y0, x1, y1), computed afresh."""
    if model not in MODELS:
        raise ValueError(f"unknown weight model {model!r} (one of {', '.join(MODELS)})")
    centres = grid.centres()
    rows, cols, vals = [], [], []
    for start in range(0, len(paths), 64):  # a few MB at a time
        block = paths[start:start + 64]
        r, c, v = _block_weights(centres, block[:, None, :2], block[:, None, 2:], model, lam)
        rows.append(r + start)
        cols.append(c)
        vals.append(v)
    n = grid.nx * grid.ny
    if not rows:
        return sp.csr_matrix((0, n))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(paths), n))


def _block_weights(centres: np.ndarray, a: np.ndarray, b: np.ndarray, model: str, lam: float):
    """(path, pixel, weight) of the nonzero weights of a block of paths from ``a`` to ``b`` ((P, 1, 2) each)."""
    if model == "line":
        ab = b - a
        along = np.clip(((centres[None] - a) * ab).sum(axis=2) / np.maximum((ab ** 2).sum(axis=2), 1e-12), 0.0, 1.0)
        distance = np.linalg.norm(centres[None] - (a + along[..., None] * ab), axis=2)
        r, c = np.nonzero(distance < LINE_CUT * LINE_WIDTH)
        return r, c, np.exp(-0.5 * (distance[r, c] / LINE_WIDTH) ** 2)
    length = np.hypot(*(b - a)[:, 0].T)
    excess = np.linalg.norm(centres[None] - a, axis=2) + np.linalg.norm(centres[None] - b, axis=2) - length[:, None]
    r, c = np.nonzero(excess < (lam if model == "ellipse" else EXP_CUT * lam))
    if model == "ellipse":
        return r, c, 1.0 / np.sqrt(length[r])
    return r, c, np.exp(-excess[r, c] / lam) / np.sqrt(length[r])


class WeightCache:
    """Weight rows per path, kept for the last ``size`` distinct paths (least recently used go first)."""

    def __init__(self, grid: Grid, model: str = "ellipse", lam: float = LAMBDA, size: int = 100_000):
        self.grid, self.model, self.lam, self.size = grid, model, lam, size
        self._rows: OrderedDict[tuple, sp.csr_matrix] = OrderedDict()
        self.built = 0

    def matrix(self, paths: np.ndarray) -> sp.csr_matrix:
        keys = [tuple(np.round(p, 3)) for p in paths.tolist()]
        new = [i for i, key in enumerate(keys) if key not in self._rows]
        if new:
            fresh = weight_rows(self.grid, paths[new], self.model, self.lam)
            for j, i in enumerate(new):
                self._rows[keys[i]] = fresh[j]
            self.built += len(new)
        if not keys:
            return sp.csr_matrix((0, self.grid.nx * self.grid.ny))
        matrix = sp.vstack([self._rows[key] for key in keys], format="csr")
        for key in keys:
            self._rows.move_to_end(key)
        while len(self._rows) > self.size:
            self._rows.popitem(last=False)
        return matrix
