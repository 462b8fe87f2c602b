"""A team's maps share what they learn (vehicle.mapping.sharing): all team-mates' changes at once give what
taking them one team-mate after another gives."""

import numpy as np

from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.sharing import Changes, apply


def _one_after_another(target: MemoryMap, sources: list[MemoryMap], grids: list[np.ndarray],
                        cells: list[np.ndarray]) -> int:
    """The rule, cell by cell, with each source's values as they were (``grids``) when its changes were read:
    an occupied value raises the cell to it, a free one fills an unknown cell. Returns the changes made."""
    made = 0
    for source, grid, changed in zip(sources, grids, cells, strict=True):
        if source is target:
            continue
        shift_rows = round((source.origin[1] - target.origin[1]) * target.resolution)
        shift_cols = round((source.origin[0] - target.origin[0]) * target.resolution)
        for cell in changed:
            row, col = divmod(int(cell), source.size)
            value = int(grid[row, col])
            row, col = row + shift_rows, col + shift_cols
            if not (0 <= row < target.size and 0 <= col < target.size):
                continue
            old = int(target.grid[row, col])
            if value >= target.OCCUPIED_AT and value > old:
                target.grid[row, col] = value
                target.ever_hit[row, col] = True
                made += 1
            elif value <= target.FREE_AT and target.FREE_AT < old < target.OCCUPIED_AT:
                target.grid[row, col] = value
                made += 1
    return made


def test_all_team_mates_changes_at_once_are_those_taken_one_after_another():
    rng = np.random.default_rng(4)
    for trial in range(20):
        homes = [(0.0, 0.0), (1.0, -0.5), (-2.3, 0.7), (0.05, 0.0)]  # origins apart by cells and by less
        maps = [MemoryMap(home, space_size=3.0, resolution=10.0) for home in homes]
        for m in maps:
            m.grid[:] = rng.integers(-8, 12, m.grid.shape)
        cells = [rng.choice(m.grid.size, size=rng.integers(0, 300), replace=True) for m in maps]  # repeats too
        read = [m.grid.copy() for m in maps]
        changes = [Changes.of(m, c) for m, c in zip(maps, cells, strict=True)]
        reference = [MemoryMap(home, space_size=3.0, resolution=10.0) for home in homes]
        for copy, m in zip(reference, maps, strict=True):
            copy.grid[:] = m.grid
        for k, m in enumerate(maps):
            occupied, version = np.count_nonzero(m.grid >= m.OCCUPIED_AT), m.occupied_version
            changed = apply(m, changes)
            assert changed == _one_after_another(reference[k], maps, read, cells) > 0
            became = np.count_nonzero(m.grid >= m.OCCUPIED_AT) - occupied  # cells never cease to be occupied
            assert m.occupied_version - version == became
            assert np.array_equal(m.grid, reference[k].grid), trial
            assert np.array_equal(m.ever_hit, reference[k].ever_hit), trial
