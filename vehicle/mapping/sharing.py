"""A team's memory maps share what they learn: one map's changed cells taken into another's.

What one vehicle found is evidence for all: a cell another map holds occupied
becomes at least as occupied in this one, a cell it holds free becomes free
here if this map knew nothing of it. Both maps have the same resolution; their
origins (each centred on its vehicle's home) may differ by whole cells or less
(then the nearest cell). Taken-in cells are not noted as this map's own
changes, so they do not travel back again.
"""

from __future__ import annotations

import numpy as np

from vehicle.mapping.memory_map import MemoryMap


def take_in(target: MemoryMap, source: MemoryMap, cells: np.ndarray) -> int:
    """Take ``source``'s values of ``cells`` (flat indices of it, e.g. its ``take_changes()``) into ``target``;
    returns how many of its cells changed."""
    if not len(cells) or target.resolution != source.resolution:
        return 0
    rows, cols = np.divmod(cells, source.size)
    shift_row = round((source.origin[1] - target.origin[1]) * target.resolution)
    shift_col = round((source.origin[0] - target.origin[0]) * target.resolution)
    rows, cols = rows + shift_row, cols + shift_col
    inside = (rows >= 0) & (rows < target.size) & (cols >= 0) & (cols < target.size)
    values = source.grid.reshape(-1)[cells[inside]]
    where = rows[inside] * target.size + cols[inside]
    flat = target.grid.reshape(-1)
    old = flat[where]
    occupied = values >= target.OCCUPIED_AT
    unknown = (old > target.FREE_AT) & (old < target.OCCUPIED_AT)
    new = np.where(occupied, np.maximum(old, values), np.where((values <= target.FREE_AT) & unknown, values, old))
    changed = new != old
    if not changed.any():
        return 0
    flat[where[changed]] = new[changed]
    target.ever_hit.reshape(-1)[where[changed & occupied]] = True
    target.version += 1
    target.occupied_version += int(np.count_nonzero((old >= target.OCCUPIED_AT) != (new >= target.OCCUPIED_AT)))
    return int(np.count_nonzero(changed))
