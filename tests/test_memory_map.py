"""The memory map (vehicle.memory_map): a log-odds occupancy grid at the operating height."""

import math

import numpy as np
import pytest
from PIL import Image

from vehicle.mapping.memory_map import FREE, OCCUPIED, UNKNOWN, MemoryMap
from vehicle.mapping.picture import draw_map

ORIGIN = np.array([0.5, 0.5, 4.0])  # the centre of cell (10, 10) in the maps below, at the operating height
EAST = np.array([1.0, 0.0, 0.0])
NORTH = np.array([0.0, 1.0, 0.0])


@pytest.fixture
def grid() -> MemoryMap:
    """20 x 20 cells of 1 m around the origin: cell (row, col) spans x = col - 10 .. col - 9, y likewise."""
    return MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)


def test_the_map_covers_space_size_around_home_at_the_resolution():
    m = MemoryMap((3.0, -2.0), space_size=100.0, resolution=10.0)
    assert m.grid.shape == (2000, 2000) and m.grid.dtype == np.int8
    assert m.origin == (-97.0, -102.0)
    assert not m.grid.any() and m.detections == 0 and m.cells_ever_hit == 0


def test_a_bad_size_is_refused():
    with pytest.raises(ValueError):
        MemoryMap((0.0, 0.0), space_size=0.0)
    with pytest.raises(ValueError):
        MemoryMap((0.0, 0.0), resolution=-1.0)


def test_an_echo_marks_its_end_occupied_the_cells_before_it_free_and_the_rest_unknown(grid):
    assert grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    states = grid.states()
    assert states[10, 15] == OCCUPIED
    assert np.all(states[10, 10:15] == FREE)
    expected = np.full(states.shape, UNKNOWN)
    expected[10, 10:15] = FREE
    expected[10, 15] = OCCUPIED
    np.testing.assert_array_equal(states, expected)
    assert grid.occupied.sum() == 1 and grid.free.sum() == 5


def test_detections_count_occupied_cells_and_cells_ever_hit_remembers(grid):
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    grid.add_reading(ORIGIN, NORTH, 3.0, 40.0)
    assert grid.detections == 2 and grid.cells_ever_hit == 2
    assert sorted(map(tuple, grid.occupied_points())) == [(0.5, 3.5), (5.5, 0.5)]
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)  # the same cell again
    assert grid.detections == 2 and grid.cells_ever_hit == 2


def test_repeated_free_passes_fade_an_occupied_cell(grid):
    """A moving object: seen once at 5 m, then the beam passes where it was."""
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    assert grid.occupied[10, 15]
    passes = 0
    while grid.occupied[10, 15]:
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)
        passes += 1
        assert passes < 5
    assert passes >= 1
    assert grid.detections == 1  # only the new end cell at 8 m
    assert grid.cells_ever_hit == 2
    for _ in range(3):
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)
    assert grid.states()[10, 15] == FREE


def test_a_long_seen_wall_still_fades_within_a_bounded_number_of_passes(grid):
    for _ in range(50):  # saturates
        grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    passes = 0
    while grid.occupied[10, 15]:
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)
        passes += 1
        assert passes <= 10


def test_a_reading_without_echo_clears_free_space_only(grid):
    assert not grid.add_reading(ORIGIN, NORTH, None, 40.0)
    assert grid.detections == 0
    assert np.all(grid.free[10:20, 10])  # up to the map edge (nothing echoed for 9.5 m)


def test_a_ray_that_leaves_the_band_marks_no_obstacle(grid):
    """A sonar tilted 45 degrees down hits the ground 4 m below: no obstacle, only free space up to the band."""
    down = np.array([1.0, 0.0, -1.0]) / math.sqrt(2)
    assert not grid.add_reading(ORIGIN, down, 4.0 * math.sqrt(2), 40.0)
    assert grid.detections == 0 and grid.cells_ever_hit == 0
    assert grid.states()[10, 14] == UNKNOWN  # where the ground was hit
    assert np.flatnonzero(grid.free[10]).max() <= 11  # free only while within 1 m of the sensor's height


def test_a_hit_inside_the_band_is_an_obstacle_even_if_slightly_tilted(grid):
    tilted = np.array([1.0, 0.0, 0.1]) / math.hypot(1.0, 0.1)
    assert grid.add_reading(ORIGIN, tilted, 5.0, 40.0)  # 0.5 m above the sensor: inside the 1 m band
    assert grid.occupied[10, 15]  # 4.98 m east of x = 0.5


def test_a_reading_beyond_the_map_edge_does_not_crash(grid):
    assert not grid.add_reading(ORIGIN, NORTH, 50.0, 100.0)
    assert grid.detections == 0
    assert np.all(grid.free[10:, 10])
    assert not grid.add_reading(np.array([-30.0, -30.0, 4.0]), EAST, 5.0, 40.0)  # entirely outside
    assert grid.detections == 0


def test_nonsense_readings_mark_nothing_and_break_nothing(grid):
    """An infinite or NaN distance is no echo; a NaN origin or a zero direction is no reading."""
    origins = np.array([ORIGIN, ORIGIN, [np.nan, 0.0, 4.0], ORIGIN])
    directions = np.array([EAST, NORTH, EAST, [0.0, 0.0, 0.0]])
    marked = grid.add_readings(origins, directions, np.array([np.inf, np.nan, 3.0, 2.0]), np.full(4, 40.0))
    assert marked == 0 and grid.detections == 0
    assert np.all(grid.free[10, 10:20]) and np.all(grid.free[10:20, 10])  # no echo: free up to the edge


def test_absurdly_long_readings_are_cut_at_the_map_edge(grid):
    """Lines far longer than the map are traced over the map only (and their sum never overflows)."""
    origins = np.array([ORIGIN, ORIGIN, [-1e12, 0.5, 4.0], ORIGIN])
    directions = np.array([EAST, EAST, EAST, NORTH])
    grid.add_readings(origins, directions, np.full(4, 2.0**62 / 10), np.full(4, 2.0**62))
    assert grid.detections == 0  # every echo lies far beyond the map
    assert np.all(grid.free[10, :]) and np.all(grid.free[10:, 10])  # the lines across the map are free


def test_readings_whose_arrays_disagree_in_length_are_refused(grid):
    origins = np.tile(ORIGIN, (3, 1))
    directions = np.array([EAST, NORTH, -EAST])
    with pytest.raises(ValueError, match="distances"):
        grid.add_readings(origins, directions, np.array([5.0, 6.0]), np.full(3, 40.0))
    with pytest.raises(ValueError, match="free"):
        grid.add_readings(origins, directions, np.full(3, 5.0), np.full(3, 40.0), free=np.array([True, False]))
    with pytest.raises(ValueError, match="directions"):
        grid.add_readings(origins, directions[:2], np.full(3, 5.0), np.full(3, 40.0))
    assert grid.version == 0 and not grid.grid.any()  # nothing was marked
    assert grid.add_readings(origins, directions, np.full(3, 5.0), 40.0) == 3  # one max range for all


def test_a_direction_that_is_no_unit_vector_is_taken_as_one(grid):
    assert grid.add_readings(ORIGIN[None], np.array([[1e9, 0.0, 0.0]]), np.array([5.0]), np.array([40.0])) == 1
    assert grid.occupied[10, 15] and grid.detections == 1


def test_a_batch_of_readings_counts_its_obstacles(grid):
    origins = np.tile(ORIGIN, (3, 1))
    directions = np.array([EAST, NORTH, -EAST])
    marked = grid.add_readings(origins, directions, np.array([5.0, np.nan, 4.0]), np.full(3, 40.0))
    assert marked == 2
    assert grid.occupied[10, 15] and grid.occupied[10, 6]
    assert grid.add_readings(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0)) == 0


def test_cell_of_and_center_of_round_trip(grid):
    for row, col in [(0, 0), (19, 19), (3, 17), (12, 5)]:
        x, y = grid.center_of(row, col)
        assert grid.cell_of(x, y) == (row, col)
    assert grid.center_of(10, 10) == (0.5, 0.5)


def test_rows_run_north_and_columns_east(grid):
    assert grid.cell_of(0.5, 5.5) == (15, 10)  # north: a higher row
    assert grid.cell_of(0.5, -5.5) == (4, 10)
    assert grid.cell_of(5.5, 0.5) == (10, 15)  # east: a higher column
    assert grid.cell_of(-10.0, -10.0) == (0, 0)  # the south-west corner


def test_points_outside_the_map_have_no_cell(grid):
    for x, y in [(10.0, 0.0), (0.0, 10.0), (-10.01, 0.0), (0.0, -10.01), (100.0, 100.0)]:
        assert grid.cell_of(x, y) is None
        assert not grid.contains(x, y)
    assert grid.contains(9.99, -9.99)


def test_cells_of_a_fine_map():
    m = MemoryMap((0.0, 0.0), space_size=5.0, resolution=10.0)
    assert m.cell_of(0.0, 0.0) == (50, 50)
    assert m.cell_of(0.05, -0.01) == (49, 50)
    assert m.center_of(49, 50) == pytest.approx((0.05, -0.05))


def test_mark_body_frees_the_cells_under_the_vehicle(grid):
    grid.add_reading(ORIGIN, NORTH, 3.0, 40.0)
    grid.add_reading(ORIGIN, EAST, 6.0, 40.0)
    assert grid.occupied[13, 10]
    grid.mark_body(0.5, 3.5, radius=1.0)
    assert not grid.occupied[13, 10]
    assert grid.states()[13, 10] == FREE
    assert grid.free[12, 10] and grid.free[14, 10] and grid.free[13, 9] and grid.free[13, 11]
    assert grid.occupied[10, 16]  # far away: untouched
    grid.mark_body(500.0, 500.0, radius=1.0)  # outside the map: nothing happens


def test_take_changes_returns_changed_flat_indices_then_empties(grid):
    assert grid.take_changes().size == 0
    grid.add_reading(ORIGIN, EAST, 3.0, 40.0)
    changed = grid.take_changes()
    np.testing.assert_array_equal(changed, [10 * 20 + c for c in range(10, 14)])
    assert np.all(grid.grid.reshape(-1)[changed] != 0)
    assert grid.take_changes().size == 0
    grid.mark_body(0.5, 0.5, radius=0.2)  # already free: no change
    assert grid.take_changes().size == 0
    grid.mark_body(-5.5, -5.5, radius=0.2)  # unknown -> free
    np.testing.assert_array_equal(grid.take_changes(), [4 * 20 + 4])


def test_save_npy_round_trips(grid, tmp_path):
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    grid.add_reading(ORIGIN, NORTH, 7.0, 40.0)
    grid.save_npy(tmp_path / "map.npy")
    loaded = np.load(tmp_path / "map.npy")
    assert loaded.dtype == np.int8
    np.testing.assert_array_equal(loaded, grid.grid)


def test_save_png_writes_a_picture_north_up(grid, tmp_path):
    grid.add_reading(ORIGIN, NORTH, 8.0, 40.0)  # occupied cell (18, 10): north of the start
    grid.save_png(tmp_path / "map.png", home=(0.5, 0.5))
    picture = draw_map(grid.grid, grid.resolution, grid.origin, home=(0.5, 0.5))  # the same picture, and its layout
    with Image.open(tmp_path / "map.png") as image:
        assert image.format == "PNG"
        pixels = np.asarray(image.convert("RGB")).astype(int)
    assert np.array_equal(pixels, np.asarray(picture.image))

    def at(x: float, y: float) -> np.ndarray:
        column, row = picture.pixel(x, y)
        return pixels[int(row), int(column)]

    occupied, free, unknown = at(*grid.center_of(18, 10)), at(*grid.center_of(14, 10)), at(*grid.center_of(14, 8))
    assert picture.pixel(*grid.center_of(18, 10))[1] < picture.pixel(0.5, 0.5)[1]  # north is up
    assert occupied[0] > 150 and occupied[0] > occupied[1] + 100  # dark red
    assert tuple(unknown) == (60, 60, 66)  # the background shows through unknown cells
    assert tuple(free) not in (tuple(unknown), tuple(occupied)) and free.min() > unknown.max()  # free: pale


def test_occupied_version_changes_only_when_the_occupied_set_changes(grid):
    version = grid.occupied_version
    grid.add_reading(ORIGIN, NORTH, None, 40.0)  # free space only
    assert grid.occupied_version == version
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)  # a new occupied cell
    assert grid.occupied_version > version
    version = grid.occupied_version
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)  # more evidence for the same cell
    assert grid.occupied_version == version
    grid.add_reading(ORIGIN, NORTH, None, 40.0)
    assert grid.occupied_version == version
    while grid.occupied[10, 15]:
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)  # fades (and marks the cell at 8 m)
    assert grid.occupied_version > version
    version = grid.occupied_version
    grid.mark_body(-5.0, -5.0, radius=1.0)  # frees unknown cells only
    assert grid.occupied_version == version
    grid.mark_body(8.5, 0.5, radius=0.4)  # frees the occupied cell at 8 m
    assert grid.occupied_version > version
    assert grid.detections == 0


def test_changes_nobody_takes_stay_bounded_and_complete(grid):
    for step in range(2000):
        grid.add_reading(np.array([0.5, 0.5, 0.0]), np.array([1.0, 0.0, 0.0]), 0.5 + (step % 9) * 0.1, 40.0)
    assert len(grid._changed) <= 513
    changed = grid.take_changes()
    assert len(changed) == len(np.unique(changed)) > 0
