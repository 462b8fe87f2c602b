"""A team's memory maps share what they learn: one map's changed cells taken into another's.

What one vehicle found is evidence for all: a cell another map holds occupied
becomes at least as occupied in this one, a cell it holds free becomes free
here if this map knew nothing of it. Both maps have the same resolution; their
origins (each centred on its vehicle's home) may differ by whole cells or less
(then the nearest cell). Taken-in cells are not noted as this map's own
changes, so they do not travel back again.

A source's changes are read once (``Changes.of``: only the cells it holds
occupied or free, the rest can change nothing) and then applied to every
team-mate's map (``apply``), so a team of N reads N sets, not N x (N - 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vehicle.mapping.memory_map import MemoryMap


@dataclass(frozen=True)
class Changes:
    """A map's changed cells that say something: where (rows, columns of its grid) and what it holds."""

    source: MemoryMap
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray

    @classmethod
    def of(cls, source: MemoryMap, cells: np.ndarray) -> Changes:
        """``cells``: flat indices of ``source`` (e.g. its ``take_changes()``)."""
        values = source.grid.reshape(-1)[cells]
        telling = (values >= source.OCCUPIED_AT) | (values <= source.FREE_AT)
        rows, cols = np.divmod(cells[telling], source.size)
        return cls(source, rows, cols, values[telling])


def take_in(target: MemoryMap, source: MemoryMap, cells: np.ndarray) -> int:
    """Take ``source``'s values of ``cells`` (flat indices of it, e.g. its ``take_changes()``) into ``target``;
    returns how many of its cells changed."""
    return apply(target, Changes.of(source, cells))


def apply(target: MemoryMap, changes: Changes) -> int:
    """Take a team-mate's ``changes`` into ``target``; returns how many of its cells changed."""
    source = changes.source
    if not len(changes.values) or target.resolution != source.resolution:
        return 0
    rows = changes.rows + round((source.origin[1] - target.origin[1]) * target.resolution)
    cols = changes.cols + round((source.origin[0] - target.origin[0]) * target.resolution)
    inside = (rows >= 0) & (rows < target.size) & (cols >= 0) & (cols < target.size)
    values = changes.values[inside]
    where = rows[inside] * target.size + cols[inside]
    flat = target.grid.reshape(-1)
    old = flat[where]
    occupied = values >= target.OCCUPIED_AT
    unknown = (old > target.FREE_AT) & (old < target.OCCUPIED_AT)
    new = np.where(occupied, np.maximum(old, values), np.where(unknown, values, old))  # the rest hold free
    changed = new != old
    if not changed.any():
        return 0
    flat[where[changed]] = new[changed]
    target.ever_hit.reshape(-1)[where[changed & occupied]] = True
    target.version += 1
    target.occupied_version += int(np.count_nonzero((old >= target.OCCUPIED_AT) != (new >= target.OCCUPIED_AT)))
    return int(np.count_nonzero(changed))
