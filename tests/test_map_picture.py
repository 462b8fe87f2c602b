"""Pictures of memory maps (vehicle.mapping.picture): cropped to what was explored, cells big enough to see,
a legend, a scale bar and north; the same renderer for `vehicle experiment --map-out` and the API."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, run_experiment
from vehicle.mapping.memory_map import FREE_AT, OCCUPIED_AT, MemoryMap
from vehicle.mapping.picture import (
    HOME,
    MAX_SIDE,
    MIN_CELL,
    PATH,
    TEXT,
    TRAIL,
    UNKNOWN_GROUND,
    draw_map,
    nice_length,
)
from vehicle.world.scene import parse_scene

FULL = 2000  # cells a side of a default map (100 m either way at 10 cells/m)
OCCUPIED_RGB = (200, 30, 40)


def full_map() -> MemoryMap:
    return MemoryMap((0.0, 0.0), space_size=100.0, resolution=10.0)


def patch(memory: MemoryMap, west: float, south: float, east: float, north: float, value: int = FREE_AT) -> None:
    """Set the cells of a rectangle (scene metres) to ``value``."""
    r0, c0 = memory.cell_of(west, south)
    r1, c1 = memory.cell_of(east, north)
    memory.grid[r0:r1 + 1, c0:c1 + 1] = value


def rgb(picture) -> np.ndarray:
    return np.asarray(picture.image.convert("RGB")).astype(int)


def red(pixels: np.ndarray) -> np.ndarray:
    return (pixels[..., 0] > 150) & (pixels[..., 1] < 80) & (pixels[..., 2] < 90)


def test_a_small_explored_patch_gives_a_small_picture_of_that_patch():
    memory = full_map()
    patch(memory, 10.0, 20.0, 18.0, 26.0)
    picture = draw_map(memory.grid, memory.resolution, memory.origin)
    west, south, east, north = picture.window
    assert west <= 10.0 and east >= 18.1 and south <= 20.0 and north >= 26.1  # the patch is in it
    assert east - west <= 12.5 and north - south <= 10.5  # and not much more: a margin around it
    width, height = picture.image.size
    assert width * height <= FULL * FULL / 6  # the old picture was 2,000 x 2,000 pixels, whatever was explored
    pixels = rgb(picture)
    left, top, right, bottom = picture.map_box
    share_unknown = np.mean(np.all(pixels[top:bottom, left:right] == UNKNOWN_GROUND, axis=-1))
    assert share_unknown < 0.65  # not three quarters unexplored, and more, as the whole map was


def test_a_whole_explored_map_stays_within_bounds_and_keeps_every_obstacle():
    memory = full_map()
    memory.grid[:] = FREE_AT
    memory.grid[1234, 567] = OCCUPIED_AT  # one occupied cell among four million
    picture = draw_map(memory.grid, memory.resolution, memory.origin)
    left, top, right, bottom = picture.map_box
    assert right - left <= MAX_SIDE and bottom - top <= MAX_SIDE
    assert picture.block > 1  # cells drawn in blocks
    rows, cols = np.nonzero(red(rgb(picture)[top:bottom, left:right]))
    assert len(rows)  # the lone obstacle is still there
    assert rows.max() - rows.min() + 1 >= MIN_CELL and cols.max() - cols.min() + 1 >= MIN_CELL
    x, y = memory.center_of(1234, 567)
    column, row = picture.pixel(x, y)
    assert abs(column - left - cols.mean()) <= picture.cell_pixels and abs(row - top - rows.mean()) <= \
        picture.cell_pixels  # where it is


@pytest.mark.parametrize("resolution", [1.0, 10.0, 20.0])
def test_an_occupied_cell_is_at_least_min_cell_pixels_wide(resolution):
    memory = MemoryMap((0.0, 0.0), space_size=50.0, resolution=resolution)
    patch(memory, -15.0, -15.0, 15.0, 15.0)
    row, col = memory.cell_of(3.0, 4.0)
    memory.grid[row, col] = OCCUPIED_AT
    picture = draw_map(memory.grid, memory.resolution, memory.origin)
    rows, cols = np.nonzero(red(rgb(picture)))
    assert rows.max() - rows.min() + 1 >= MIN_CELL and cols.max() - cols.min() + 1 >= MIN_CELL


def test_the_legend_swatches_show_the_maps_colours():
    memory = full_map()
    patch(memory, -5.0, -5.0, 5.0, 5.0)
    picture = draw_map(memory.grid, memory.resolution, memory.origin, home=(0.0, 0.0),
                       trail=[(0, 0), (3, 0), (3, 3)], planned_path=[(3, 3), (-3, 3)])
    pixels = rgb(picture)

    def centre(name: str) -> tuple[int, ...]:
        x0, y0, x1, y1 = picture.swatches[name]
        return tuple(pixels[(y0 + y1) // 2, (x0 + x1) // 2])

    free_in_map = pixels[(picture.map_box[1] + picture.map_box[3]) // 2 + 20, (picture.map_box[0] +
                                                                               picture.map_box[2]) // 2 - 20]
    assert centre("unknown") == UNKNOWN_GROUND
    assert centre("free") == tuple(free_in_map)  # the colour free cells have on the map
    assert centre("occupied") == OCCUPIED_RGB  # state_image's occupied, opaque
    assert centre("trail") == TRAIL and centre("planned path") == PATH and centre("home") == HOME
    for name in picture.swatches:  # under the map, in the legend
        assert picture.swatches[name][1] > picture.map_box[3]


def test_the_scale_bar_is_as_long_as_it_says():
    memory = full_map()
    patch(memory, -20.0, -10.0, 17.0, 10.0)
    picture = draw_map(memory.grid, memory.resolution, memory.origin)
    west, _, east, _ = picture.window
    metres = nice_length((east - west) / 4)
    assert metres == 10.0  # 1, 2 or 5 times a power of ten, near a quarter of the width
    per_metre = (picture.map_box[2] - picture.map_box[0]) / (east - west)
    row = rgb(picture)[picture.map_box[3] + 14 + 8]  # the bar's middle, under the map
    white = np.flatnonzero(np.all(row == TEXT, axis=-1))
    bar = white[:np.argmax(np.diff(white) > 1) + 1]  # the first run (the label "10 m" follows)
    assert bar[0] == 14  # from the left edge's padding
    assert abs((bar[-1] - bar[0]) - metres * per_metre) <= 2


def test_north_is_up_and_overlays_are_where_their_points_are():
    memory = full_map()
    patch(memory, -8.0, -8.0, 8.0, 8.0)
    memory.grid[memory.cell_of(0.0, 6.0)] = OCCUPIED_AT  # north of home
    trail = [(0.0, 0.0), (0.0, -5.0), (5.0, -5.0)]
    picture = draw_map(memory.grid, memory.resolution, memory.origin, home=(0.0, 0.0), trail=trail)
    pixels = rgb(picture)
    left, top, right, bottom = picture.map_box
    rows, _ = np.nonzero(red(pixels[top:bottom, left:right]))
    rows += top
    home_column, home_row = picture.pixel(0.0, 0.0)
    assert rows.max() < home_row  # the obstacle north of home is above it
    assert tuple(pixels[int(home_row), int(home_column)]) == HOME
    column, row = picture.pixel(2.5, -5.0)  # on the trail's second leg
    assert tuple(pixels[int(row), int(column)]) == TRAIL


def test_experiment_map_out_writes_the_picture_with_the_runs_trail(tmp_path):
    scene = parse_scene("""#VRML V2.0 utf8
Transform { translation 0 0 -0.05 children Shape { geometry Box { size 60 60 0.1 } } }
Transform { translation 0 6 2 children Shape { geometry Box { size 8 0.3 6 } } }
""", "walls.wrl")
    settings = Settings(space_size=20, time_limit=60)
    result = run_experiment(Experiment("walls.wrl", "pathfind", settings=settings, waypoints=[(-5.0, 3.0)]),
                            scene=scene, map_out=tmp_path)
    assert result["outcome"] == "finished"
    with Image.open(tmp_path / "walls-pathfind-0.png") as image:
        pixels = np.asarray(image.convert("RGB")).astype(int)
    assert max(image.size) <= MAX_SIDE + 300
    assert np.any(np.all(pixels == TRAIL, axis=-1))  # where it flew
    assert np.count_nonzero(red(pixels)) >= MIN_CELL * MIN_CELL  # the wall it saw
    assert np.load(tmp_path / "walls-pathfind-0.npy").shape == (400, 400)  # the raw map as it was
