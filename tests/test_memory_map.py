"""The memory map (vehicle.memory_map): a log-odds occupancy grid at the operating height."""

import math

import numpy as np
import pytest
from PIL import Image

from vehicle.mapping.memory_map import (
    FREE,
    FREE_SPREAD,
    NO_ECHO_CLEARS,
    OCCUPIED,
    SIDE_REACH,
    UNKNOWN,
    MemoryMap,
)
from vehicle.mapping.picture import draw_map

ORIGIN = np.array([0.5, 0.5, 4.0])  # the centre of cell (10, 10) in the maps below, at the operating height
EAST = np.array([1.0, 0.0, 0.0])
NORTH = np.array([0.0, 1.0, 0.0])


@pytest.fixture
def grid() -> MemoryMap:
    """20 x 20 cells of 1 m around the origin: cell (row, col) spans x = col - 10 .. col - 9, y likewise."""
    return MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)


# ---- size and cells --------------------------------------------------------------------------
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


def test_the_defaults_are_the_readmes_and_a_map_smaller_than_a_cell_has_one():
    m = MemoryMap((0.0, 0.0))
    assert (m.space_size, m.resolution, m.size) == (100.0, 10.0, 2000)
    assert MemoryMap((0.0, 0.0), space_size=0.5, resolution=1.0).size == 1  # half a cell across: one cell
    assert MemoryMap((0.0, 0.0), space_size=0.2, resolution=1.0).size == 1
    for size, resolution in [(0.0, 1.0), (-1.0, 1.0), (1.0, 0.0), (1.0, -2.0)]:
        with pytest.raises(ValueError, match="^space_size and resolution must be positive$"):
            MemoryMap((0.0, 0.0), space_size=size, resolution=resolution)


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


def test_a_map_centred_away_from_the_origin_at_ten_cells_a_metre_puts_echoes_where_they_are():
    """x and y, columns and rows, metres and cells are not interchangeable: a centre of (3, -2) and 10 cells
    a metre tell them apart."""
    m = MemoryMap((3.0, -2.0), space_size=5.0, resolution=10.0)
    assert m.origin == (-2.0, -7.0)
    assert m.cell_of(-1.95, -6.95) == (0, 0) and m.cell_of(0.05, -6.95) == (0, 20)
    assert m.cell_of(-1.95, -4.95) == (20, 0)
    assert m.center_of(20, 0) == pytest.approx((-1.95, -4.95))
    m.add_reading(np.array([3.05, -1.95, 4.0]), EAST, 2.0, 40.0)  # the echo at x = 5.05, y = -1.95
    np.testing.assert_allclose(m.occupied_points(), [[5.05, -1.95]])
    assert m.occupied[m.cell_of(5.05, -1.95)]


# ---- evidence: echoes, misses and their thresholds -------------------------------------------
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


def test_detections_count_a_cell_at_exactly_the_occupied_threshold(grid):
    from vehicle.mapping.memory_map import OCCUPIED_AT

    grid.grid[5, 5] = OCCUPIED_AT - 1
    assert grid.detections == 0
    grid.grid[5, 5] = OCCUPIED_AT
    assert grid.detections == 1 == int(grid.occupied.sum())


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


def test_cells_at_exactly_the_thresholds_are_occupied_or_free():
    grid = np.array([[MemoryMap.OCCUPIED_AT, MemoryMap.OCCUPIED_AT - 1, MemoryMap.FREE_AT, MemoryMap.FREE_AT + 1]],
                    dtype=np.int8)
    from vehicle.mapping.memory_map import states_of

    assert states_of(grid).tolist() == [[OCCUPIED, UNKNOWN, FREE, UNKNOWN]]
    m = MemoryMap((0.0, 0.0), space_size=1.0, resolution=2.0)
    m.grid[:] = np.resize(grid, (4, 4))
    assert np.array_equal(m.occupied_in(slice(1, 3), slice(0, 4)), m.occupied[1:3, :])
    assert np.array_equal(m.free_in(slice(0, 4), slice(2, 3)), m.free[:, 2:3])
    assert m.occupied_in(slice(0, 1), slice(0, 1))[0, 0] and m.free_in(slice(0, 1), slice(2, 3))[0, 0]


# ---- readings: the band, the map's edges, bad input ------------------------------------------
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


def test_a_narrower_band_cuts_a_tilted_beam_where_it_leaves_it():
    """A beam tilted up leaves a 0.5 m band after band / its vertical share of the distance."""
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0, band=0.5)
    up = np.array([math.cos(0.2), 0.0, math.sin(0.2)])  # leaves the band at 0.5 / sin(0.2) = 2.52 m
    assert not m.add_reading(np.array([0.05, 0.05, 4.0]), up, 3.0, 40.0)  # the echo is above the band
    free_x = (np.flatnonzero(m.free[m.cell_of(0.05, 0.05)[0]]).max() + 0.5) / 10 - 10
    assert free_x == pytest.approx(0.05 + 0.5 / math.tan(0.2), abs=0.1)


def test_a_reading_beyond_the_map_edge_does_not_crash(grid):
    assert not grid.add_reading(ORIGIN, NORTH, 50.0, 100.0)
    assert grid.detections == 0
    assert np.all(grid.free[10:, 10])
    assert not grid.add_reading(np.array([-30.0, -30.0, 4.0]), EAST, 5.0, 40.0)  # entirely outside
    assert grid.detections == 0


def test_echoes_and_lines_in_the_first_cells_and_on_the_map_edge(grid):
    """Cell 0 is a cell like any other; a point exactly on the west or south edge is inside the map."""
    assert not grid.add_reading(np.array([-9.5, -5.5, 4.0]), -NORTH, 5.0, 40.0)  # echo at y = -10.5: off the map
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
    assert m.add_reading(np.array([-9.5, -5.5, 4.0]), -NORTH, 4.0, 40.0) and m.occupied[0, 0]  # cell 0
    edge = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
    edge.add_reading(np.array([-10.0, -10.0, 4.0]), EAST, 2.5, 40.0)  # from the south-west corner exactly
    assert edge.free[0, 0] and edge.free[0, 1] and edge.occupied[0, 2]
    start2 = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
    start2.add_reading(np.array([-7.5, -9.5, 4.0]), EAST, 3.0, 40.0)  # starts in cell 2
    assert start2.free[0, 2] and start2.free[0, 4] and start2.occupied[0, 5]


def test_an_echo_exactly_on_the_maps_west_edge_is_in_its_first_column(grid):
    assert grid.add_reading(np.array([-5.0, 0.5, 4.0]), -EAST, 5.0, 40.0)  # the echo at x = -10, the edge
    assert grid.ever_hit[10, 0] and grid.cells_ever_hit == 1


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
    with pytest.raises(ValueError, match=r"^distances: expected one per reading, \(3,\), not shape \(2,\)$"):
        grid.add_readings(origins, directions, np.array([5.0, 6.0]), np.full(3, 40.0))
    with pytest.raises(ValueError, match=r"^free: expected one per reading, \(3,\), not shape \(2,\)$"):
        grid.add_readings(origins, directions, np.full(3, 5.0), np.full(3, 40.0), free=np.array([True, False]))
    with pytest.raises(ValueError, match=r"^directions: expected one per reading, \(3, 3\), not shape \(2, 3\)$"):
        grid.add_readings(origins, directions[:2], np.full(3, 5.0), np.full(3, 40.0))
    with pytest.raises(ValueError, match=r"^max_ranges: expected one per reading"):
        grid.add_readings(origins, directions, np.full(3, 5.0), np.full(2, 40.0))
    with pytest.raises(ValueError, match=r"^beams: expected one per reading"):
        grid.add_readings(origins, directions, np.full(3, 5.0), 40.0, beams=np.full(2, 0.1))
    assert grid.version == 0 and not grid.grid.any()  # nothing was marked
    assert grid.add_readings(origins, directions, np.full(3, 5.0), 40.0) == 3  # one max range for all


def test_a_direction_that_is_no_unit_vector_is_taken_as_one(grid):
    assert grid.add_readings(ORIGIN[None], np.array([[1e9, 0.0, 0.0]]), np.array([5.0]), np.array([40.0])) == 1
    assert grid.occupied[10, 15] and grid.detections == 1


def test_a_direction_that_is_no_unit_vector_is_scaled_in_every_component(grid):
    """Directions of length 2 (close to unit length, and exactly 2) are normalised, x, y and z alike."""
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0, band=1.0)
    d = np.array([1.6, 1.2, 0.0])  # length 2, north-east
    assert m.add_reading(np.array([0.05, 0.05, 4.0]), d, 5.0, 40.0)
    assert m.occupied[m.cell_of(0.05 + 4.0, 0.05 + 3.0)]
    tilted = np.array([2.0 * math.sqrt(1 - 0.15**2), 0.0, 2.0 * 0.15])  # length 2, 0.15 up: 0.75 m at 5 m
    assert m.add_reading(np.array([0.05, 0.05, 4.0]), tilted, 5.0, 40.0)  # within the 1 m band
    assert grid.add_reading(ORIGIN, np.array([0.0, 2.0, 0.0]), 5.0, 40.0) and grid.occupied[15, 10]


def test_a_batch_of_readings_counts_its_obstacles(grid):
    origins = np.tile(ORIGIN, (3, 1))
    directions = np.array([EAST, NORTH, -EAST])
    marked = grid.add_readings(origins, directions, np.array([5.0, np.nan, 4.0]), np.full(3, 40.0))
    assert marked == 2
    assert grid.occupied[10, 15] and grid.occupied[10, 6]
    assert grid.add_readings(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0)) == 0


def test_a_reading_without_direction_or_left_out_of_the_free_mask_stops_nothing_after_it(grid):
    origins = np.tile(ORIGIN, (3, 1))
    directions = np.array([[0.0, 0.0, 0.0], EAST, NORTH])
    assert grid.add_readings(origins, directions, np.array([2.0, 5.0, 3.0]), 40.0) == 2
    assert grid.occupied[10, 15] and grid.occupied[13, 10]
    other = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
    assert other.add_readings(origins[:2], directions[1:], np.array([5.0, 3.0]), 40.0,
                              free=np.array([False, True])) == 2
    assert not other.free[10, 12] and other.free[12, 10]  # the second reading marked its free cells


def test_readings_as_lists_or_in_single_precision_mark_the_map_as_float64_arrays_do():
    def batch(kind):
        origins = [[0.5, 0.5, 4.0], [-3.0, 2.0, 4.0]]
        directions = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
        distances, ranges, beams, free = [3.0, float("nan")], [40.0, 6.0], [0.2, 0.3], [True, True]
        made = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
        if kind == "arrays":
            made.add_readings(
                np.array(origins),
                np.array(directions),
                np.array(distances),
                np.array(ranges),
                np.array(beams),
                np.array(free),
            )
        elif kind == "float32":
            f = np.float32
            made.add_readings(
                np.array(origins, f),
                np.array(directions, f),
                np.array(distances, f),
                np.array(ranges, f),
                np.array(beams, f),
                np.array(free, np.uint8),
            )
        else:
            made.add_readings(origins, directions, distances, ranges, beams, free)
        return made.grid

    expected = batch("arrays")
    assert (expected != 0).sum() > 5
    assert np.array_equal(batch("lists"), expected) and np.array_equal(batch("float32"), expected)


# ---- the vehicle's body ----------------------------------------------------------------------
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


def test_the_body_frees_cells_up_to_the_map_edges_and_never_wraps_round(grid):
    """At the west edge no cell of the row below (at the east edge) is touched, and the edge rows and columns
    themselves are freed."""
    grid.mark_body(-9.5, 0.5, radius=1.0)  # cell (10, 0)
    freed = {tuple(c) for c in np.argwhere(grid.free)}
    assert freed == {(10, 0), (9, 0), (11, 0), (10, 1)}
    assert np.array_equal(np.sort(grid.take_changes()), [9 * 20, 10 * 20, 10 * 20 + 1, 11 * 20])
    other = MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0)
    other.mark_body(9.5, -9.5, radius=1.0)  # cell (0, 19): the south-east corner
    assert {tuple(c) for c in np.argwhere(other.free)} == {(0, 19), (1, 19), (0, 18)}
    assert np.array_equal(np.sort(other.take_changes()), [18, 19, 20 + 19])
    assert other.take_changes().dtype.kind == "i" and grid.take_changes().dtype.kind == "i"


@pytest.mark.parametrize(("x", "y"), [(9.5, 9.5), (-9.5, 9.5), (9.5, -9.5), (-9.5, -9.5)])
def test_the_body_at_a_corner_frees_only_the_cells_inside_the_map(grid, x, y):
    grid.mark_body(x, y, 2.0)
    freed = np.argwhere(grid.states() == FREE)
    assert len(freed) and (np.abs(freed + 0.5 - (np.array([y, x]) + 10)).max(axis=1) <= 2.5).all()


# ---- changes and versions --------------------------------------------------------------------
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


def test_changes_nobody_takes_stay_bounded_and_complete(grid):
    for step in range(2000):
        grid.add_reading(np.array([0.5, 0.5, 0.0]), np.array([1.0, 0.0, 0.0]), 0.5 + (step % 9) * 0.1, 40.0)
    assert len(grid._changed) <= 513
    changed = grid.take_changes()
    assert len(changed) == len(np.unique(changed)) > 0


def test_changes_folded_while_nobody_takes_them_are_all_returned():
    """Over 512 updates nobody took, the changes fold into a mask: taking them then gives every cell that
    changed, the same cells a taker after every update saw."""
    eager, lazy = (MemoryMap((0.0, 0.0), space_size=10.0, resolution=1.0) for _ in range(2))
    seen = set()
    rng = np.random.default_rng(3)
    for _ in range(700):
        origin = np.array([rng.uniform(-9, 9), rng.uniform(-9, 9), 4.0])
        angle = rng.uniform(0, 2 * math.pi)
        direction = np.array([math.cos(angle), math.sin(angle), 0.0])
        distance = rng.uniform(0.5, 6)
        for m in (eager, lazy):
            m.add_reading(origin, direction, distance, 40.0)
        seen.update(eager.take_changes().tolist())
        if rng.random() < 0.05:
            for m in (eager, lazy):
                m.mark_body(*origin[:2], 0.6)
    assert len(lazy._changed) <= 513
    got = lazy.take_changes()
    assert got.dtype.kind == "i" and sorted(got.tolist()) == sorted(seen)
    assert lazy.take_changes().size == 0
    for m in (eager, lazy):  # after a take, changes are listed again, not folded
        m.add_reading(ORIGIN, EAST, 3.0, 40.0)
    assert lazy._folded is None and len(lazy._changed) == 1
    expected = eager.take_changes()
    assert expected.size and np.array_equal(lazy.take_changes(), expected)


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


def test_version_counts_every_update_and_occupied_version_every_change_of_the_occupied_set(grid):
    """A cell at exactly OCCUPIED_AT is occupied: reaching it, or leaving it, changes the occupied set; going
    from above it to it, or from it upwards, does not."""
    assert grid.version == 0
    for expected in (1, 2, 3):
        grid.add_reading(ORIGIN, NORTH, None, 40.0)
        assert grid.version == expected
    grid.mark_body(-5.0, -5.0, 1.0)
    assert grid.version == 3  # marking the body is no update of the evidence

    def step(reading, changes: bool, value: int):
        before = grid.occupied_version
        reading()
        assert grid.grid[10, 15] == value
        assert (grid.occupied_version != before) is changes, (value, grid.occupied_version, before)

    hit = lambda: grid.add_reading(ORIGIN, EAST, 5.0, 40.0)  # noqa: E731
    passed = lambda: grid.add_reading(ORIGIN, EAST, None, 40.0)  # noqa: E731 - free up to the map's edge
    step(hit, True, 9)  # unknown to occupied
    step(passed, False, 6)  # still occupied, at the threshold
    step(hit, False, 15)  # from the threshold upwards
    step(passed, False, 12)
    step(passed, False, 9)
    step(passed, False, 6)
    step(passed, True, 3)  # from the threshold down: no longer occupied
    step(passed, False, 0)
    step(passed, False, -3)  # free
    step(hit, True, 6)  # from free straight to the threshold
    step(lambda: grid.mark_body(5.5, 0.5, 0.3), True, MemoryMap.FREE_AT)  # the body frees a cell at the threshold


def test_occupied_version_moves_by_one_when_the_occupied_set_changes(grid):
    steps = []
    for _ in range(12):
        before = grid.occupied_version
        grid.add_reading(ORIGIN, EAST, 3.0, 40.0)
        steps.append(grid.occupied_version - before)
    assert sorted(set(steps)) == [0, 1] and sum(steps) == 1  # once, when the echo's cell became occupied
    before = grid.occupied_version
    grid.mark_body(3.5, 0.5, 0.6)  # over the echo's cell
    assert grid.occupied_version == before + 1 and grid.detections == 0


def test_occupied_version_moves_by_one_when_a_cell_fades_out_of_the_occupied_set(grid):
    """Ceasing to be occupied changes the occupied set once, like becoming occupied: one step of the version
    on the pass that takes the cell below OCCUPIED_AT, none on the others; one step, too, for an update in
    which one cell fades out and another becomes occupied."""
    grid.add_reading(ORIGIN, EAST, 3.0, 40.0)  # (10, 13) occupied, at HIT
    steps, values = [], []
    for _ in range(4):
        before = grid.occupied_version
        grid.add_reading(ORIGIN, EAST, None, 40.0)  # passes it, no echo
        steps.append(grid.occupied_version - before)
        values.append(int(grid.grid[10, 13]))
    assert values == [6, 3, 0, -3] and steps == [0, 1, 0, 0]
    grid.add_reading(ORIGIN, EAST, 3.0, 40.0)  # (10, 13) occupied again, at 6
    before = grid.occupied_version
    grid.add_reading(ORIGIN, EAST, 5.0, 40.0)  # (10, 13) fades to 3, (10, 15) becomes occupied
    assert grid.occupied_version == before + 1
    assert grid.grid[10, 13] == 3 and grid.occupied[10, 15] and grid.detections == 1


# ---- files and pictures ----------------------------------------------------------------------
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


def test_the_picture_of_the_map_is_drawn_from_its_own_cells_size_and_place(grid, tmp_path):
    """save_png hands the renderer (vehicle/mapping/picture.py, tested in test_map_picture.py) this map's
    grid, resolution and origin: the file is the very picture drawn from them."""
    from vehicle.mapping.picture import save_map_picture

    grid.add_reading(ORIGIN, NORTH, 8.0, 40.0)
    grid.save_png(tmp_path / "map.png", title="t")
    save_map_picture(tmp_path / "direct.png", grid.grid.copy(), grid.resolution, grid.origin, title="t")
    other = MemoryMap((3.0, -2.0), space_size=10.0, resolution=1.0)
    other.grid[:] = grid.grid
    other.save_png(tmp_path / "moved.png", title="t")
    with Image.open(tmp_path / "map.png") as a, Image.open(tmp_path / "direct.png") as b:
        assert a.size == b.size and np.array_equal(np.asarray(a), np.asarray(b))
    assert (tmp_path / "map.png").read_bytes() != (tmp_path / "moved.png").read_bytes()  # the origin is drawn


def test_the_image_is_the_picture_of_the_states(grid):
    from vehicle.mapping.memory_map import state_image

    grid.add_reading(ORIGIN, EAST, 3.0, 40.0)
    assert np.array_equal(grid.image(), state_image(grid.states()))


# ---- cones, batches and long lines -----------------------------------------------------------------------
@pytest.fixture
def fine() -> MemoryMap:
    """20 m across at 10 cells/m around the origin: cell (row, col) spans x = col/10 - 10 .. (col + 1)/10 - 10."""
    return MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)


def along(m: MemoryMap, angle: float, distance: float, origin=(0.05, 0.05)) -> tuple[int, int]:
    """The cell ``distance`` metres from ``origin`` at ``angle`` radians left of east."""
    return m.cell_of(origin[0] + distance * math.cos(angle), origin[1] + distance * math.sin(angle))


def test_a_cone_marks_its_sides_free_up_to_the_echo_and_at_most_side_reach(fine):
    """A sonar hears the nearest echo in its cone, so the cone is free up to it: lines at most a cell apart up
    to FREE_SPREAD of the half-angle either side, to a cell short of the echo and SIDE_REACH at most; the echo
    is on the arc of its cone, and when nothing on it is known, its centre cell takes it."""
    origin = np.array([[0.05, 0.05, 4.0]])
    half = 0.3
    side = FREE_SPREAD * half
    fine.add_readings(origin, np.array([EAST]), np.array([6.0]), np.array([40.0]), beams=np.array([half]))
    assert fine.occupied[along(fine, 0.0, 6.0)] and fine.detections == 1
    for angle in np.linspace(-side, side, 7):
        assert fine.free[along(fine, angle, 3.0)] and fine.free[along(fine, angle, 5.8)]
        assert not fine.free[along(fine, angle, 6.3)]  # not past the echo
    assert not fine.free[along(fine, 1.3 * side, 3.0)]  # nor beyond FREE_SPREAD
    long = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    long.add_readings(origin, np.array([EAST]), np.array([9.5]), np.array([40.0]), beams=np.array([half]))
    for angle in (side, -side):
        assert long.free[along(long, angle, SIDE_REACH - 0.2)]
        assert not long.free[along(long, angle, SIDE_REACH + 0.3)]  # the sides stop at SIDE_REACH
    bare = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    bare.add_readings(origin, np.array([EAST]), np.array([6.0]), np.array([40.0]))  # no beam: the centre only
    assert not bare.free[along(bare, side, 3.0)] and bare.free[along(bare, 0.0, 3.0)]
    assert bare.occupied[along(bare, 0.0, 6.0)] and bare.detections == 1


def test_an_occupied_cell_on_the_arc_explains_the_echo_alone(fine):
    """A door frame seen face on (occupied) explains an echo whose cone spans the doorway beside it: only it
    gains, the doorway's cells stay as they were; cells known free never explain an echo."""
    origin = np.array([[0.05, 0.05, 1.0]])
    half = math.radians(7.5)
    frame = along(fine, half * 0.9, 4.0)
    fine.grid[frame] = MemoryMap.OCCUPIED_AT
    doorway = along(fine, 0.0, 4.0)
    fine.add_readings(origin, np.array([EAST]), np.array([4.0]), np.array([40.0]), beams=np.array([half]))
    assert fine.grid[frame] == MemoryMap.OCCUPIED_AT + MemoryMap.HIT and fine.grid[doorway] == 0
    fine.grid[frame] = MemoryMap.FREE_AT  # seen free since: the centre of the arc takes the echo
    fine.add_readings(origin, np.array([EAST]), np.array([4.0]), np.array([40.0]), beams=np.array([half]))
    assert fine.grid[frame] == MemoryMap.FREE_AT and fine.grid[doorway] == MemoryMap.HIT
    fine.grid[doorway] = MemoryMap.FREE_AT  # the centre known free too: the nearest unknown cell to it
    fine.add_readings(origin, np.array([EAST]), np.array([4.0]), np.array([40.0]), beams=np.array([half]))
    assert fine.grid[doorway] == MemoryMap.FREE_AT and fine.detections == 1


def test_a_cone_without_echo_clears_unknown_cells_but_leaves_walls_alone(fine):
    """Silence says nothing of a wall met too obliquely to echo: a cone without echo marks unknown cells free
    and leaves occupied ones; a cone with an echo beyond takes evidence from them."""
    origin = np.array([[0.05, 0.05, 1.0]])
    wall = along(fine, 0.0, 3.0)
    fine.grid[wall] = MemoryMap.OCCUPIED_AT
    fine.add_readings(origin, np.array([EAST]), np.array([np.nan]), np.array([40.0]), beams=np.array([0.13]))
    assert fine.grid[wall] == MemoryMap.OCCUPIED_AT and fine.free[along(fine, 0.0, 5.0)]
    fine.add_readings(origin, np.array([EAST]), np.array([6.0]), np.array([40.0]), beams=np.array([0.13]))
    assert fine.grid[wall] == MemoryMap.OCCUPIED_AT - MemoryMap.MISS


def test_a_cone_pointing_north_east_marks_both_sides(fine):
    """The sides of a cone pointing anywhere but along an axis (rotations mixing x and y)."""
    origin = np.array([[0.05, 0.05, 4.0]])
    half = 0.4
    side = FREE_SPREAD * half
    heading = math.radians(40)
    d = np.array([[math.cos(heading), math.sin(heading), 0.0]])
    fine.add_readings(origin, d, np.array([6.0]), np.array([40.0]), beams=np.array([half]))
    for angle in (heading + side, heading - side):
        assert fine.free[along(fine, angle, 4.0)] and fine.free[along(fine, angle, 5.5)]
    assert not fine.free[along(fine, heading + 2 * side, 4.0)] and not fine.free[along(fine, heading - 2 * side, 4.0)]


def test_a_cone_wider_than_a_small_map_is_cut_to_it():
    """Side lines longer than the map is wide are clipped to it like the centre line."""
    m = MemoryMap((0.0, 0.0), space_size=1.0, resolution=1.0)  # 2 x 2 cells
    m.add_readings(np.array([[-0.5, -0.5, 4.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([np.nan]),
                   np.array([40.0]), beams=np.array([1.0]))
    assert m.free[0, 0] and m.free[0, 1] and m.free[1, 1]  # the left side crosses into the row above


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


@pytest.mark.parametrize(("start", "direction", "cells"), [
    ((-1e6, 5.05), (1.0, 0.0), "row"),  # a long line at 10 cells a metre
    ((-1e6, 5.05), (1.0, 1e-7), "row"),  # nearly parallel to x: it climbs 0.1 m over its million metres
    ((-1e6, 50.0), (1.0, 0.0), "none"),  # parallel to the map's north edge, beyond it
    ((50.0, -1e6), (0.0, 1.0), "none"),  # parallel to its east edge, beyond it
])
def test_long_lines_at_ten_cells_a_metre_are_cut_to_the_map(start, direction, cells):
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    d = np.array([*direction, 0.0]) / math.hypot(*direction)
    m.add_readings(np.array([[*start, 4.0]]), d[None], np.array([np.nan]), np.array([4e6]),
                   free=np.array([True]))
    m.NO_ECHO_CLEARS = math.inf
    m.add_readings(np.array([[*start, 4.0]]), d[None], np.array([np.nan]), np.array([4e6]))
    free = np.argwhere(m.free)
    if cells == "none":
        assert len(free) == 0
    else:
        assert set(free[:, 0].tolist()) <= {150, 151} and len(set(free[:, 1].tolist())) == 200


def test_a_long_line_that_ends_inside_the_map_stops_at_its_end():
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    m.NO_ECHO_CLEARS = math.inf
    m.add_readings(np.array([[-1e6, 5.05, 4.0]]), np.array([EAST]), np.array([1e6]), np.array([2e6]))
    assert m.occupied[m.cell_of(0.0, 5.05)] and m.detections == 1
    row = m.cell_of(0.0, 5.05)[0]
    assert np.flatnonzero(m.free[row]).max() == m.cell_of(0.0, 5.05)[1] - 1  # free up to the echo, not past


@pytest.mark.parametrize("x", [-20.0, -19.0, -10.0])
def test_an_absurdly_long_beam_along_or_near_an_edge_marks_what_a_shorter_one_across_the_map_does(x):
    """A line longer than the map is cut to the map's square first (Liang-Barsky), exactly: along the west
    edge itself, 1 m inside it, or through the middle, at 2 m per cell."""

    def beam(distance):
        made = MemoryMap((0.0, 0.0), space_size=20.0, resolution=0.5)  # 20 x 20 cells of 2 m
        made.add_reading(np.array([x, -15.0, 4.0]), NORTH, distance, 2e6)
        return made.states()

    short = beam(50.0)  # ends beyond the north edge; short enough not to be cut
    assert (short == FREE).sum() >= 17
    assert np.array_equal(beam(1e6), short)


def test_single_precision_origins_far_off_the_map_are_cut_to_it_as_double_ones_are():
    """An origin in single precision is the float64 value it holds: a line from 10 000 km west is cut to the
    map's square in double precision and marks the whole row, edge to edge (cut in float32, where one unit
    in the last place is 1 m there, it would stop 0.35 m short of the east edge)."""
    for dtype in (np.float64, np.float32):
        m = MemoryMap((0.35, 0.0), space_size=10.0, resolution=10.0)  # x from -9.65 to 10.35
        assert m.add_readings(np.array([[-1e7, 0.05, 4.0]], dtype), np.array([EAST]), np.array([2e7]),
                              np.array([4e7])) == 0  # the echo lies 10 000 km east, off the map
        row = m.cell_of(0.0, 0.05)[0]
        assert np.array_equal(np.argwhere(m.free), [(row, col) for col in range(200)]), dtype
        assert m.detections == 0
