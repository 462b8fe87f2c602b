"""The map's pictures for the page and the 3D view: one crop and shrink for both (the far edges' obstacles kept,
the picture's bounds true to its cells); the merged map sums the vehicles' log-odds cell by cell, on one grid
covering all."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.mapview import MAX_PIXELS, merge, overlay
from groundstation.state import Fleet, VehicleState
from groundstation.viz import MAP_PIXELS, SceneView
from vehicle.mapping import picture
from vehicle.mapping.memory_map import STATE_COLOURS, MemoryMap

OCCUPIED, FREE = STATE_COLOURS[2], STATE_COLOURS[1]


def edged_map() -> MemoryMap:
    """A 2,000-cell map whose explored part (1,103 x 1,031 cells from the south-west corner) is no whole number of
    blocks in either direction, with an obstacle in its north-east corner cell and free space in its south-west."""
    memory = MemoryMap((0.0, 0.0), space_size=100.0, resolution=10.0)
    memory.grid[0, 0] = -20
    memory.grid[1102, 1030] = 40
    return memory


@pytest.mark.parametrize("max_pixels", [MAX_PIXELS, MAP_PIXELS])
def test_a_shrunk_map_keeps_the_obstacle_in_its_far_corner_and_its_bounds_match_its_cells(max_pixels):
    memory = edged_map()
    found = picture.overlay(memory.grid, memory.resolution, memory.origin, max_pixels)
    block = -(-1103 // max_pixels)
    assert found.block == block > 1
    assert found.image.shape[:2] == (-(-1103 // block), -(-1031 // block))
    assert (found.image[0, -1] == OCCUPIED).all()  # north-east: the partly filled last block is padded, not cut
    assert (found.image[-1, 0] == FREE).all()
    west, south, east, north = found.window
    assert (west, south) == (-100.0, -100.0)
    assert east - west == pytest.approx(found.image.shape[1] * block / 10)  # a pixel is a block, everywhere
    assert north - south == pytest.approx(found.image.shape[0] * block / 10)
    assert east >= -100.0 + 103.1 and north >= -100.0 + 110.3  # the obstacle's cell lies inside


def test_the_page_and_the_3d_view_draw_the_same_picture_of_a_map():
    memory = edged_map()
    page = overlay((memory.grid, memory.resolution, memory.origin))
    expected = picture.overlay(memory.grid, memory.resolution, memory.origin, MAX_PIXELS)
    assert page["bounds"] == [round(v, 3) for v in expected.window]
    fleet = Fleet()
    fleet.vehicles[1] = VehicleState(1, x=0.0, y=0.0, own_map=memory)
    drawn = []
    view = SceneView(fleet, None)
    try:
        view.server.scene.add_image = lambda name, image, **where: drawn.append((image, where))
        view.draw(slow=True)
    finally:
        view.close()
    (image, where), = drawn
    expected = picture.overlay(memory.grid, memory.resolution, memory.origin, MAP_PIXELS)
    assert (image == expected.image).all()  # at full opacity, the overlay's own pixels
    west, south, east, north = expected.window
    assert where["render_width"] == pytest.approx(east - west)
    assert where["render_height"] == pytest.approx(north - south)
    assert where["position"][:2] == pytest.approx(((west + east) / 2, (south + north) / 2))


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
