import hashlib
from collections import Counter

import numpy as np
import pytest
import scipy.ndimage as ndi

from vehicle.mapping.planning import (
    GOAL_BLOCKED,
    START_BLOCKED,
    UNREACHABLE,
    NoPath,
    _astar_cells,
    _search,
    astar,
    corner_cuts,
    inflate,
    line_is_clear,
    plan,
    smooth,
)


def crossed_cells(path, grid):
    """Cells met by dense samples along every segment (2**12 per segment: never exactly on a cell edge)."""
    path = np.asarray(path, dtype=float)
    t = (np.arange(2**12) + 0.5) / 2**12
    cells = []
    for p, q in zip(path[:-1], path[1:], strict=True):
        pts = np.rint(p + t[:, None] * (q - p)).astype(int)
        cells.append(pts)
    return np.concatenate(cells) if cells else np.zeros((0, 2), int)


def assert_clear(path, grid):
    cells = crossed_cells(path, grid)
    assert not grid[cells[:, 0], cells[:, 1]].any()


def length(path):
    return float(np.linalg.norm(np.diff(np.asarray(path, float), axis=0), axis=1).sum())


def random_grid(n, seed, fraction=0.05):
    rng = np.random.default_rng(seed)
    g = np.zeros((n, n), bool)
    while g.mean() < fraction:
        h, w = rng.integers(2, 12, size=2)
        r, c = rng.integers(0, n, size=2)
        g[r : r + h, c : c + w] = True
    g[:6, :6] = g[-6:, -6:] = False
    return g


@pytest.mark.parametrize("radius", [0, 0.5, 1, 1.5, 2, 3, 3.6, 7])
def test_inflate_is_a_disc_dilation(radius):
    g = np.random.default_rng(3).random((40, 57)) < 0.03
    R = int(radius)
    yy, xx = np.mgrid[-R : R + 1, -R : R + 1]
    expected = ndi.binary_dilation(g, yy**2 + xx**2 <= radius**2)
    assert (inflate(g, radius) == expected).all()


@pytest.mark.parametrize("radius", [63.0, 64.0, 64.7, 130.2])
def test_inflate_is_a_disc_dilation_across_whole_words(radius):
    """Radii of 64 cells and more shift rows by whole 64-cell words and more."""
    g = np.zeros((300, 333), bool)
    g[[5, 150, 290], [7, 200, 330]] = True
    g[100, 60:70] = True
    rows, cols = np.mgrid[:300, :333]
    expected = np.zeros_like(g)
    for r, c in zip(*np.nonzero(g), strict=True):  # a few cells: each one's disc directly
        expected |= (rows - r) ** 2 + (cols - c) ** 2 <= radius**2
    assert (inflate(g, radius) == expected).all()


def test_path_around_a_wall():
    g = np.zeros((40, 40), bool)
    g[0:30, 20] = True  # wall from the south edge, open to the north
    path = plan(g, (5, 5), (5, 35), radius_cells=2)
    assert tuple(path[0]) == (5, 5) and tuple(path[-1]) == (5, 35)
    assert path[:, 0].max() >= 30 + 2  # went round the end of the wall with clearance
    assert_clear(path, inflate(g, 2))


@pytest.mark.parametrize("gap, passes", [(4, False), (5, True), (7, True)])
def test_gap_only_when_wider_than_the_clearance(gap, passes):
    g = np.zeros((41, 40), bool)
    g[:, 20] = True
    g[18 : 18 + gap, 20] = False
    if passes:
        path = plan(g, (20, 5), (20, 35), radius_cells=2)
        assert_clear(path, inflate(g, 2))
    else:
        with pytest.raises(NoPath) as err:
            plan(g, (20, 5), (20, 35), radius_cells=2)
        assert err.value.reason == UNREACHABLE


@pytest.mark.parametrize("doubtful", [False, True])
def test_enclosed_goal_has_no_path(doubtful):
    g = np.zeros((40, 40), bool)
    g[25:36, 25] = g[25:36, 35] = g[25, 25:36] = g[35, 25:36] = True
    with pytest.raises(NoPath) as err:
        plan(g, (2, 2), (30, 30), radius_cells=1, doubtful=doubtful)
    assert err.value.reason == UNREACHABLE and str(err.value) == "no path"


def test_a_doubtful_search_that_has_a_path_finds_the_same_one():
    g = np.zeros((40, 40), bool)
    g[0:30, 20] = True
    assert np.array_equal(plan(g, (5, 5), (5, 35), 2, doubtful=True), plan(g, (5, 5), (5, 35), 2))


def test_start_inside_inflated_obstacle_escapes():
    g = np.zeros((30, 30), bool)
    g[0:20, 10] = True
    start = (5, 11)  # right next to the wall, well inside the 3-cell clearance
    inflated = inflate(g, 3)
    assert inflated[start] and not g[start]
    path = plan(g, start, (5, 25), radius_cells=3)
    assert tuple(path[0]) == start and tuple(path[-1]) == (5, 25)
    assert not inflated[tuple(path[1])]
    assert_clear(path[:2], g)  # the escape leg never crosses a real obstacle
    assert_clear(path[1:], inflated)
    assert path[1][1] >= 14  # stepped away from the wall, not through it


def test_start_boxed_in_by_obstacles_has_no_path():
    g = np.zeros((20, 20), bool)
    g[8:13, 8] = g[8:13, 12] = g[8, 8:13] = g[12, 8:13] = True
    with pytest.raises(NoPath) as err:
        plan(g, (10, 10), (2, 2), radius_cells=3)
    assert err.value.reason == UNREACHABLE


def test_start_or_goal_in_an_obstacle():
    g = np.zeros((20, 20), bool)
    g[10, 10] = True
    with pytest.raises(NoPath) as err:
        plan(g, (10, 10), (2, 2), radius_cells=1)
    assert err.value.reason == START_BLOCKED
    with pytest.raises(NoPath) as err:
        plan(g, (2, 2), (10, 10), radius_cells=1)
    assert err.value.reason == GOAL_BLOCKED
    with pytest.raises(NoPath) as err:  # too close to an obstacle counts as inside
        plan(g, (2, 2), (10, 11), radius_cells=1.5)
    assert err.value.reason == GOAL_BLOCKED
    with pytest.raises(NoPath) as err:
        astar(g, (2, 2), (10, 10))
    assert err.value.reason == GOAL_BLOCKED


@pytest.mark.parametrize("seed", range(6))
def test_smoothed_path_is_clear_and_no_longer(seed):
    g = random_grid(80, seed)
    inflated = inflate(g, 1.5)
    raw = astar(inflated, (0, 0), (79, 79))
    assert_clear(raw, inflated)
    smoothed = smooth(raw, inflated)
    assert (smoothed[0] == raw[0]).all() and (smoothed[-1] == raw[-1]).all()
    assert len(smoothed) < len(raw)
    assert_clear(smoothed, inflated)
    assert length(smoothed) <= length(raw) + 1e-9
    assert_clear(plan(g, (0, 0), (79, 79), 1.5), inflated)


def test_shortcut_never_grazes_a_blocked_corner():
    g = np.zeros((5, 5), bool)
    g[0, 1] = True
    assert not line_is_clear(g, (0, 0), (1, 1))  # passes exactly through the corner of (0, 1)
    assert not line_is_clear(g, (0, 0), (2, 2))
    assert line_is_clear(g, (1, 0), (2, 2))
    path = np.array([(0, 0), (1, 0), (1, 1), (2, 2)])
    assert smooth(path, g).tolist() == [[0, 0], [1, 0], [2, 2]]


def test_line_test_matches_exact_geometry():
    def touches(p, q, cell):  # closed segment vs closed unit square (Liang-Barsky)
        p, q = np.array(p, float), np.array(q, float)
        t0, t1 = 0.0, 1.0
        for ax in (0, 1):
            lo, hi, d = cell[ax] - 0.5, cell[ax] + 0.5, q[ax] - p[ax]
            if d == 0:
                if not lo <= p[ax] <= hi:
                    return False
            else:
                a, b = sorted(((lo - p[ax]) / d, (hi - p[ax]) / d))
                t0, t1 = max(t0, a), min(t1, b)
        return t0 <= t1

    rng = np.random.default_rng(5)
    for _ in range(300):
        g = rng.random((9, 9)) < 0.15
        p, q = tuple(rng.integers(0, 9, 2)), tuple(rng.integers(0, 9, 2))
        expected = not any(touches(p, q, c) for c in zip(*np.nonzero(g), strict=True))
        assert line_is_clear(g, p, q) == expected, (p, q)


def test_diagonal_corner_cutting_is_refused():
    g = np.zeros((12, 12), bool)
    for i in range(12):
        g[i, 11 - i] = True  # a wall of cells touching only at their corners
    raw = _search(g, (0, 0), (11, 11))
    assert len(raw) and len(corner_cuts(raw, g))  # the search itself slips through, as pyastar2d's does
    with pytest.raises(NoPath):
        astar(g, (0, 0), (11, 11))
    g[11, 0] = False  # an opening at one end: the path must use it
    path = astar(g, (0, 0), (11, 11))
    assert not len(corner_cuts(path, g))
    assert ((path[:, 0] >= 10) & (path[:, 1] <= 1)).any()  # crossed at the opening
    assert_clear(plan(g, (0, 0), (11, 11), 0), g)


def test_search_returns_pyastar2d_paths():
    """The very paths pyastar2d 1.1 returned (``astar_path`` on weights 1 / inf, diagonals allowed) for 200
    seeded grids, hashed: among equally short paths the search picks the same one, so missions fly as before."""
    rng = np.random.default_rng(2024)
    digest = hashlib.sha256()
    for _ in range(200):
        shape = (int(rng.integers(2, 60)), int(rng.integers(2, 60)))
        g = rng.random(shape) < rng.choice([0.0, 0.1, 0.3, 0.4])
        s, t = tuple(int(v) for v in rng.integers(0, shape, 2)), tuple(int(v) for v in rng.integers(0, shape, 2))
        g[s] = g[t] = False
        path = _search(g, s, t)
        digest.update(path.astype(np.int64).tobytes() if len(path) else b"none")
    assert digest.hexdigest() == "064dcde82d03278ab4c8e7e269b8ad138fe69e80901561f7b707974e3216d944"


def test_search_reports_a_heap_too_small():
    g = np.zeros((20, 20), bool)
    path, complete = _astar_cells(g, 0, 399, np.empty(4, dtype=np.int64))
    assert not complete and not len(path)
    assert np.array_equal(_search(g, (0, 0), (19, 19)), np.column_stack([np.arange(20), np.arange(20)]))


def test_noisy_grids_get_a_path_without_corner_cuts_exactly_when_one_exists():
    """A path that never squeezes between two cells touching at a corner exists exactly when start and goal
    are 4-connected (each diagonal step that cuts no corner has a free cell beside it): A* finds one then,
    and says no path otherwise (it once gave up on 3 of these 10 grids that had one)."""
    outcomes = Counter()
    for seed in range(10):
        g = np.random.default_rng(seed).random((30, 30)) < 0.3
        g[0, 0] = g[29, 29] = False
        labels, _ = ndi.label(~g)  # 4-connected regions of free cells
        if labels[0, 0] == labels[29, 29]:
            path = astar(g, (0, 0), (29, 29))
            assert not len(corner_cuts(path, g)), seed
            assert not g[path[:, 0], path[:, 1]].any()
            assert (np.abs(np.diff(path, axis=0)).max(axis=1) == 1).all()  # steps to neighbouring cells
            outcomes["path"] += 1
        else:
            with pytest.raises(NoPath) as err:
                astar(g, (0, 0), (29, 29))
            assert err.value.reason == UNREACHABLE
            outcomes["no path"] += 1
    assert outcomes == {"path": 7, "no path": 3}  # both kinds of grid were checked


def test_start_and_goal_across_a_pinch_go_round_it():
    """Start and goal are the free pair of a 2x2 pinch: the diagonal between them cuts a corner, and the way
    round takes 6 steps."""
    g = np.zeros((4, 4), bool)
    g[1, 1] = g[2, 2] = True
    path = astar(g, (1, 2), (2, 1))
    assert tuple(path[0]) == (1, 2) and tuple(path[-1]) == (2, 1)
    assert not len(corner_cuts(path, g))
    assert not g[path[:, 0], path[:, 1]].any()
    assert len(path) - 1 >= 6


def test_start_equals_goal():
    g = np.zeros((10, 10), bool)
    g[5, 6] = True
    assert plan(g, (5, 5), (5, 5), 3).tolist() == [[5, 5]]
    assert astar(g, (2, 2), (2, 2)).tolist() == [[2, 2]]


def test_out_of_grid_is_a_value_error():
    g = np.zeros((10, 10), bool)
    for start, goal in [((-1, 0), (5, 5)), ((0, 0), (10, 5)), ((0, 0), (5, 10))]:
        with pytest.raises(ValueError):
            plan(g, start, goal, 1)
        with pytest.raises(ValueError):
            astar(g, start, goal)


def test_a_cell_outside_the_grid_is_refused_with_its_name_the_cell_and_the_grid_size():
    """Rows and columns are checked against their own bounds (the grid need not be square), and the error says
    which end is outside, where, and how big the grid is."""
    wide, tall = np.zeros((10, 20), bool), np.zeros((20, 10), bool)
    for find in (astar, lambda g, s, t: plan(g, s, t, 1)):
        with pytest.raises(ValueError, match=r"^start \(12, 0\) is outside the 10x20 grid$"):
            find(wide, (12, 0), (1, 1))
        with pytest.raises(ValueError, match=r"^goal \(3, 25\) is outside the 10x20 grid$"):
            find(wide, (1, 1), (3, 25))
        with pytest.raises(ValueError, match=r"^goal \(2, 12\) is outside the 20x10 grid$"):
            find(tall, (1, 1), (2, 12))
        path = find(tall, (15, 2), (1, 8))  # row 15 is inside a grid of 20 rows, though it has only 10 columns
        assert tuple(path[0]) == (15, 2) and tuple(path[-1]) == (1, 8)


def test_an_obstacle_mask_that_is_not_2d_is_refused_with_its_shape():
    with pytest.raises(ValueError, match=r"^expected a 2D obstacle mask, got shape \(10,\)$"):
        astar(np.zeros(10, bool), (0, 0), (0, 5))
    with pytest.raises(ValueError, match=r"^expected a 2D obstacle mask, got shape \(2, 3, 4\)$"):
        plan(np.zeros((2, 3, 4), bool), (0, 0), (1, 1), 1)


def test_an_obstacle_mask_of_numbers_plans_like_the_boolean_one():
    """Any non-zero cell is an obstacle: a mask given as 0.0 / 1.0 gets the very paths its boolean twin gets."""
    g = np.zeros((30, 30), bool)
    g[0:20, 10] = True
    g[24, 4] = g[25, 5] = True  # a pinch across the diagonal from (29, 0), which A* alone squeezes through
    numbers = g.astype(float)
    assert np.array_equal(plan(numbers, (5, 5), (5, 25), 2), plan(g, (5, 5), (5, 25), 2))
    assert np.array_equal(plan(numbers, (5, 11), (5, 25), 3), plan(g, (5, 11), (5, 25), 3))  # with an escape
    assert np.array_equal(astar(numbers, (29, 0), (20, 9), doubtful=True), astar(g, (29, 0), (20, 9)))


def test_a_blocked_start_is_refused_by_the_search_itself():
    g = np.zeros((10, 10), bool)
    g[4, 4] = True
    with pytest.raises(NoPath) as err:
        astar(g, (4, 4), (8, 8))
    assert err.value.reason == START_BLOCKED and str(err.value) == "start is inside an obstacle"


def test_corner_cuts_are_only_diagonal_steps_between_two_blocked_cells():
    """A diagonal step beside one blocked cell, or a straight step between two, is no cut; only the diagonal
    squeezing between both cells of a checkerboard is, and it is reported by its index in the path."""
    g = np.zeros((3, 3), bool)
    step = np.array([(0, 0), (1, 1)])
    assert not len(corner_cuts(step, g))
    g[1, 0] = True
    assert not len(corner_cuts(step, g))
    g[1, 0], g[0, 1] = False, True
    assert not len(corner_cuts(step, g))
    g[1, 0] = True
    assert corner_cuts(step, g).tolist() == [0]
    assert corner_cuts(np.array([(2, 0), (2, 1), (1, 2), (0, 1), (1, 1), (0, 0)]), g).tolist() == [4]
    g[:] = False
    g[0, 1] = g[2, 1] = True
    assert not len(corner_cuts(np.array([(1, 0), (1, 1), (1, 2)]), g))  # straight between two blocked cells


@pytest.mark.parametrize("path", [[(2, 2)], np.zeros((0, 2), np.int64)])
def test_a_path_without_a_step_has_no_corner_cut_and_its_cuts_index_it(path):
    """Too short to have a step: no cuts, as an empty array of indices (usable to index the path)."""
    g = np.ones((3, 3), bool)
    cuts = corner_cuts(path, g)
    assert len(cuts) == 0
    assert len(np.asarray(path)[cuts]) == 0


def test_on_an_open_grid_the_path_is_the_straight_diagonal():
    """Diagonal steps past no obstacle are no corner cuts: 19 diagonal steps, not a staircase of 38."""
    path = astar(np.zeros((20, 20), bool), (0, 0), (19, 19))
    assert path.tolist() == [[i, i] for i in range(20)]


@pytest.mark.parametrize(
    "pinch, start, goal",
    [([(5, 6), (6, 5)], (0, 0), (19, 19)), ([(9, 9), (10, 10)], (0, 19), (19, 0))],
    ids=["pinch-across-the-diagonal", "pinch-along-the-diagonal"],
)
def test_a_pinch_on_the_straight_way_costs_a_detour_of_two_steps(pinch, start, goal):
    """The only shortest path squeezes through a pinch (of either orientation): it is closed, and the search
    goes round it on the 8-connected grid (21 steps) instead of falling back to four-connected steps (38)."""
    g = np.zeros((20, 20), bool)
    for cell in pinch:
        g[cell] = True
    path = astar(g, start, goal)
    assert tuple(path[0]) == start and tuple(path[-1]) == goal
    assert not len(corner_cuts(path, g))
    assert not g[path[:, 0], path[:, 1]].any()
    assert (np.abs(np.diff(path, axis=0)).max(axis=1) == 1).all()
    assert len(path) - 1 == 21


@pytest.mark.parametrize("doubtful", [False, True])
def test_start_and_goal_connected_only_through_corners_are_told_apart_from_unconnected_ones(doubtful):
    """Joined only diagonally through pinches (8-connected, never 4-connected): the error says so, also when
    the search was doubtful and checked first whether the goal can be reached at all."""
    g = np.zeros((12, 12), bool)
    for i in range(12):
        g[i, 11 - i] = True  # a wall of cells touching only at their corners
    with pytest.raises(NoPath) as err:
        astar(g, (0, 0), (11, 11), doubtful=doubtful)
    assert err.value.reason == UNREACHABLE
    assert str(err.value) == "no path (start and goal are only connected through a corner)"


def test_a_search_that_runs_out_of_heap_room_is_run_again_with_enough(monkeypatch):
    """The first heap has room for about one entry a cell; a search that needs more is repeated with room for
    the most entries any search can hold, and finds the same path."""
    import vehicle.mapping.planning as planning

    real, rooms = planning._astar_cells, []

    def first_one_too_small(blocked, start, goal, heap, diagonal):
        rooms.append(len(heap))
        return real(blocked, start, goal, heap[:4] if len(rooms) == 1 else heap, diagonal)

    g = np.zeros((20, 20), bool)
    monkeypatch.setattr(planning, "_astar_cells", first_one_too_small)
    assert np.array_equal(_search(g, (0, 0), (19, 19)), np.column_stack([np.arange(20), np.arange(20)]))
    assert len(rooms) == 2 and rooms[1] >= 3 * g.size + 1  # a cell's cost drops at most twice after its first push


def test_the_escape_never_squeezes_between_two_obstacles_touching_at_a_corner():
    """A pocket of real free cells whose only way out is diagonally between two blocked cells: the escape does
    not take it, and says the start is boxed in."""
    g = np.zeros((20, 20), bool)
    g[8:12, 8:12] = True
    g[9:11, 9:11] = False  # the pocket: rows and columns 9 and 10
    g[11, 11] = False  # touches the pocket's corner (10, 10) between the blocked (10, 11) and (11, 10)
    for start in [(9, 9), (9, 10), (10, 9), (10, 10)]:
        with pytest.raises(NoPath) as err:
            plan(g, start, (2, 2), radius_cells=3)
        assert err.value.reason == UNREACHABLE
        assert str(err.value) == "no path (the start is boxed in by obstacles)"


def test_the_escape_steps_diagonally_beside_an_obstacle_but_not_through_a_squeeze():
    """At the grid's bottom edge, between two obstacles touching at a corner (to its upper left) and one two
    cells to the right: the nearest clear cell is two steps away, the first one diagonally past the corner of
    the obstacle above, after the squeeze to the upper left has been refused."""
    g = np.zeros((9, 9), bool)
    g[7, 3] = g[8, 2] = g[8, 5] = True
    inflated = inflate(g, 1)
    for goal in [(0, 0), (2, 6)]:
        path = plan(g, (8, 3), goal, radius_cells=1)
        assert path.tolist() == [[8, 3], [7, 4], [6, 4], list(goal)]
        assert inflated[7, 4] and not inflated[6, 4]


@pytest.mark.parametrize("turns", range(4))
def test_the_escape_runs_along_a_corridor_on_any_edge_of_the_grid(turns):
    """A start at the dead end of a corridor one cell wide, between a wall and the grid's edge: it escapes
    along the corridor to its mouth, whichever edge (the same layout turned by quarter turns) it runs along,
    never stepping off the grid."""
    base = np.zeros((9, 30), bool)
    base[1, 6:] = True  # the wall; row 0 beside it is the corridor

    def turned(cell):
        mark = np.zeros(base.shape, bool)
        mark[cell] = True
        return tuple(int(v) for v in np.argwhere(np.rot90(mark, turns))[0])

    g = np.rot90(base, turns).copy()
    start, mouth, goal = turned((0, 29)), turned((0, 5)), turned((6, 2))
    inflated = inflate(g, 1)
    assert inflated[start] and not inflated[mouth]
    path = plan(g, start, goal, radius_cells=1)
    assert tuple(path[0]) == start and tuple(path[1]) == mouth and tuple(path[-1]) == goal
    assert_clear(path[:2], g)
    assert_clear(path[1:], inflated)
