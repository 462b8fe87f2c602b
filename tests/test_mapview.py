"""The 2D map's pictures: the merged map sums the vehicles' log-odds cell by cell, on one grid covering all."""

from __future__ import annotations

import numpy as np

from groundstation.mapview import merge, overlay


def test_merged_map_sums_log_odds_cell_by_cell_over_every_explored_part():
    a = np.zeros((10, 10), dtype=np.int8)
    b = np.zeros((10, 10), dtype=np.int8)
    a[5, 5] = 40  # the cell from (5, 5) to (6, 6) m, seen occupied by one vehicle
    b[5, 3] = 30  # the same place in b's grid, whose origin is 2 m further east
    b[0, 0] = -20  # a cell only b saw free, from (2, 0) to (3, 1) m
    merged, resolution, origin = merge([(a, 1.0, (0.0, 0.0)), (b, 1.0, (2.0, 0.0))])
    assert resolution == 1.0 and origin == (2.0, 0.0)  # the south-west of what either explored
    assert merged.shape == (6, 4)
    assert merged[5, 3] == 70  # independent evidence adds up
    assert merged[0, 0] == -20
    assert np.count_nonzero(merged) == 2
    a[5, 5] = b[5, 3] = 120
    merged, _, _ = merge([(a, 1.0, (0.0, 0.0)), (b, 1.0, (2.0, 0.0))])
    assert merged[5, 3] == 127  # clipped to the map's range


def test_nothing_explored_makes_no_picture():
    empty = np.zeros((5, 5), dtype=np.int8)
    assert merge([(empty, 1.0, (0.0, 0.0))]) is None
    assert overlay((empty, 1.0, (0.0, 0.0))) is None
    empty[2, 2] = 50
    found = overlay((empty, 2.0, (10.0, 20.0)))
    assert found["image"].startswith("data:image/png;base64,")
    west, south, east, north = found["bounds"]
    assert west <= 11.0 < east and south <= 21.0 < north
