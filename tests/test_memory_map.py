"""The memory map (vehicle.memory_map): a log-odds occupancy grid at the operating height."""

import math

import numpy as np
import pytest
from PIL import Image

from vehicle.mapping.memory_map import FREE, FREE_SPREAD, NO_ECHO_CLEARS, OCCUPIED, SIDE_REACH, UNKNOWN, MemoryMap

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


def test_a_cell_hit_many_times_stays_occupied_at_the_saturation_limit(grid):
    """Evidence saturates: an int8 cell that kept adding HIT would wrap past 127 to a negative value, and a
    long-seen wall would vanish (after 15 hits it read -121)."""
    for hits in range(1, 101):
        grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
        assert grid.occupied[10, 15], f"the wall vanished after {hits} hits"
        assert 0 < grid.grid[10, 15] <= MemoryMap.LIMIT
    assert grid.grid[10, 15] == MemoryMap.LIMIT
    assert grid.detections == 1


def test_a_long_seen_wall_still_fades_within_a_bounded_number_of_passes(grid):
    """Saturation is what keeps fading bounded: from LIMIT, ceil((LIMIT - OCCUPIED_AT + 1) / MISS) passes."""
    for _ in range(50):  # saturates
        grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    assert grid.occupied[10, 15] and grid.grid[10, 15] == MemoryMap.LIMIT
    passes = 0
    while grid.occupied[10, 15]:
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)
        passes += 1
        assert passes <= 10
    assert passes == math.ceil((MemoryMap.LIMIT - MemoryMap.OCCUPIED_AT + 1) / MemoryMap.MISS)


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
    grid.add_reading(ORIGIN, NORTH, 8.0, 40.0)  # occupied cell (18, 10): near the top of a north-up picture
    grid.save_png(tmp_path / "map.png")
    with Image.open(tmp_path / "map.png") as image:
        assert image.format == "PNG" and image.size == (20, 20)
        pixels = np.asarray(image.convert("RGB")).astype(int)
    occupied = pixels[20 - 1 - 18, 10]
    unknown = pixels[0, 0]
    assert occupied[0] > 150 and occupied[0] > occupied[1] + 100  # dark red
    assert tuple(unknown) == (60, 60, 66)  # the background shows through unknown cells
    assert tuple(pixels[20 - 1 - 12, 10]) not in (tuple(unknown), tuple(occupied))  # free: pale


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
    assert grid.occupied[10, 15]
    passes = 0
    while grid.occupied[10, 15]:
        grid.add_reading(ORIGIN, EAST, 8.0, 40.0)  # fades (and marks the cell at 8 m)
        passes += 1
        assert passes <= 10
    assert passes >= 1 and grid.occupied_version > version
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


# ---- cones, batches and long lines -----------------------------------------------------------------------
@pytest.fixture
def fine() -> MemoryMap:
    """20 m across at 10 cells/m around the origin: cell (row, col) spans x = col/10 - 10 .. (col + 1)/10 - 10."""
    return MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)


def along(m: MemoryMap, angle: float, distance: float, origin=(0.05, 0.05)) -> tuple[int, int]:
    """The cell ``distance`` metres from ``origin`` at ``angle`` radians left of east."""
    return m.cell_of(origin[0] + distance * math.cos(angle), origin[1] + distance * math.sin(angle))


def test_a_cone_marks_its_sides_free_up_to_the_echo_and_at_most_side_reach(fine):
    """A sonar hears the nearest echo in its cone, so the cone is free up to it: lines at FREE_SPREAD of the
    half-angle either side, as far as the centre line and SIDE_REACH at most; the echo on the centre line."""
    origin = np.array([[0.05, 0.05, 4.0]])
    half = 0.3
    side = FREE_SPREAD * half
    fine.add_readings(origin, np.array([EAST]), np.array([6.0]), np.array([40.0]), beams=np.array([half]))
    assert fine.occupied[along(fine, 0.0, 6.0)] and fine.detections == 1
    for angle in (side, -side):
        assert fine.free[along(fine, angle, 3.0)] and fine.free[along(fine, angle, 5.9)]
        assert not fine.free[along(fine, angle, 6.3)]  # not past the echo
    long = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    long.add_readings(origin, np.array([EAST]), np.array([9.5]), np.array([40.0]), beams=np.array([half]))
    for angle in (side, -side):
        assert long.free[along(long, angle, SIDE_REACH - 0.2)]
        assert not long.free[along(long, angle, SIDE_REACH + 0.3)]  # the sides stop at SIDE_REACH
    bare = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    bare.add_readings(origin, np.array([EAST]), np.array([6.0]), np.array([40.0]))  # no beam: the centre only
    assert not bare.free[along(bare, side, 3.0)] and bare.free[along(bare, 0.0, 3.0)]


def test_a_reading_without_echo_clears_only_no_echo_clears_metres():
    """No echo is weak evidence (a surface at a grazing angle returns none either): free up to
    NO_ECHO_CLEARS, however far the sonar reaches."""
    m = MemoryMap((0.0, 0.0), space_size=20.0, resolution=10.0)
    m.add_reading(np.array([-9.95, 0.05, 4.0]), EAST, None, 40.0)
    assert m.free[along(m, 0.0, NO_ECHO_CLEARS - 0.2, (-9.95, 0.05))]
    assert not m.free[along(m, 0.0, NO_ECHO_CLEARS + 0.2, (-9.95, 0.05))]
    short = MemoryMap((0.0, 0.0), space_size=20.0, resolution=10.0)
    short.add_reading(np.array([-9.95, 0.05, 4.0]), EAST, None, 4.0)  # a shorter sonar clears its own range
    assert short.free[along(short, 0.0, 3.8, (-9.95, 0.05))] and not short.free[along(short, 0.0, 4.3, (-9.95, 0.05))]


def test_readings_left_out_of_the_free_mask_mark_their_echo_only(fine):
    origins = np.tile([0.05, 0.05, 4.0], (2, 1))
    marked = fine.add_readings(origins, np.array([EAST, NORTH]), np.array([5.0, 5.0]), np.full(2, 40.0),
                               free=np.array([True, False]))
    assert marked == 2 and fine.occupied[along(fine, 0.0, 5.0)] and fine.occupied[along(fine, math.pi / 2, 5.0)]
    assert fine.free[along(fine, 0.0, 2.5)] and not fine.free[along(fine, math.pi / 2, 2.5)]


def test_one_batch_is_one_piece_of_evidence_per_cell(grid):
    """Readings of one monitor period see the same thing: a cell that several lines pass loses MISS once."""
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    assert grid.grid[10, 15] == MemoryMap.HIT
    three = np.tile(ORIGIN, (3, 1))
    grid.add_readings(three, np.tile(EAST, (3, 1)), np.full(3, 8.0), np.full(3, 40.0))  # all three pass it
    assert grid.grid[10, 15] == MemoryMap.HIT - MemoryMap.MISS and grid.occupied[10, 15]
    assert grid.grid[10, 18] == MemoryMap.HIT  # one hit, however many echoes ended there


def test_misses_come_before_hits_in_a_batch(grid):
    """A saturated wall that one reading of a batch ends in and another passes stays saturated (misses first,
    then hits; the other order would leave it at LIMIT - MISS)."""
    for _ in range(10):
        grid.add_reading(ORIGIN, EAST, 5.0, 40.0)
    assert grid.grid[10, 15] == MemoryMap.LIMIT
    grid.add_readings(np.tile(ORIGIN, (2, 1)), np.tile(EAST, (2, 1)), np.array([5.0, 8.0]), np.full(2, 40.0))
    assert grid.grid[10, 15] == MemoryMap.LIMIT


@pytest.mark.parametrize(("start", "direction"), [
    ((1e9, 0.55), (-1.0, 0.0)),  # from far east, going west
    ((0.55, 1e9), (0.0, -1.0)),  # from far north, going south
    ((0.55, -1e9), (0.0, 1.0)),  # from far south
    ((-1e9, -1e9 + 0.05), (1.0, 1.0)),  # from far south-west, diagonally
    ((1e9, 1e9), (1.0, 1.0)),  # beyond the north-east corner, going away: never over the map
])
def test_an_absurdly_long_line_from_any_side_is_traced_over_the_map_only(grid, start, direction):
    d = np.array([*direction, 0.0]) / math.hypot(*direction)
    crossing = grid.add_readings(np.array([[*start, 4.0]]), d[None], np.array([4e9]), np.array([8e9]),
                                 free=np.array([True]))
    assert crossing == 0 and grid.detections == 0  # the echo lies far off the map
    free = np.argwhere(grid.free)
    if start == (1e9, 1e9):
        assert len(free) == 0
    elif direction[0] == 0 or direction[1] == 0:  # a whole row or column of the map
        assert len(free) == 20 and len({tuple(c) for c in free[:, [0 if direction[0] else 1]]}) == 1
    else:  # the diagonal, corner to corner
        assert len(free) >= 20 and {(0, 0), (19, 19)} <= {tuple(c) for c in free}
