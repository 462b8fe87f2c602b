"""Planning on the memory map (vehicle.mapping.planner.MapPlanner) and the escape from inside the clearance
(planning._escape), each against a brute-force reference on random maps."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from vehicle.mapping import planning
from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.planner import MapPlanner

RADIUS = 0.3


def random_map(seed: int, fraction: float = 0.03) -> MemoryMap:
    """20 x 20 m at 5 cells/m, centred away from the origin, with scattered occupied and free cells."""
    m = MemoryMap((3.0, -2.0), space_size=10.0, resolution=5.0)
    rng = np.random.default_rng(seed)
    m.grid[rng.random(m.grid.shape) < fraction] = MemoryMap.OCCUPIED_AT
    m.grid[rng.random(m.grid.shape) < 0.3] = MemoryMap.FREE_AT
    return m


def test_a_spot_is_clear_exactly_when_no_obstacle_lies_within_the_body_and_padding():
    """Against every occupied cell: none within (radius + padding) of the spot's cell, in cells, counting one
    exactly that far; spots near the map's edges and outside it too."""
    checked = {True: 0, False: 0}
    for seed in range(4):
        m = random_map(seed)
        planner = MapPlanner(m, RADIUS)
        occupied = np.argwhere(m.occupied)
        rng = np.random.default_rng(100 + seed)
        for _ in range(150):
            x, y = rng.uniform(m.origin[0] - 0.5, m.origin[0] + 20.5), rng.uniform(m.origin[1] - 0.5,
                                                                                  m.origin[1] + 20.5)
            padding = float(rng.choice([0.0, 0.2, 0.5, 0.9]))
            cell = m.cell_of(x, y)
            if cell is None:
                assert not planner.is_clear((x, y), padding)
                continue
            reach = planner.margin_cells(padding)
            near = ((occupied - cell) ** 2).sum(axis=1) <= reach * reach + 1e-9
            assert planner.is_clear((x, y), padding) is (not near.any()), (x, y, padding)
            checked[not near.any()] += 1
    assert min(checked.values()) > 50


def test_a_spot_exactly_the_margin_away_from_an_obstacle_is_not_clear():
    m = MemoryMap((0.0, 0.0), space_size=5.0, resolution=10.0)
    planner = MapPlanner(m, 0.3)
    row, col = m.cell_of(0.05, 0.05)
    m.grid[row, col + 5] = MemoryMap.OCCUPIED_AT  # 5 cells east: the 0.3 m body and 0.2 m padding exactly
    m.grid[row + 6, col] = MemoryMap.OCCUPIED_AT  # 6 cells north: beyond it
    assert not planner.is_clear((0.05, 0.05), 0.2)
    assert planner.is_clear((0.05, 0.05), 0.1)
    corner = MapPlanner(m, 0.3)
    m.grid[0, 0] = MemoryMap.OCCUPIED_AT
    assert not corner.is_clear(m.center_of(0, 3), 0.0) and corner.is_clear(m.center_of(0, 4), 0.0)
    assert not corner.is_clear(m.center_of(3, 0), 0.0) and corner.is_clear(m.center_of(4, 0), 0.0)
    last = m.size - 1
    m.grid[last, last] = MemoryMap.OCCUPIED_AT
    assert not corner.is_clear(m.center_of(last, last - 3), 0.0) and corner.is_clear(m.center_of(last - 4, last), 0.0)


@pytest.fixture
def by_a_wall():
    """A wall along y = 2 (cells occupied from x = -3 to 3); a vehicle stopped 0.4 m south of it, inside the
    0.3 m body + 0.5 m padding."""
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=10.0)
    row = m.cell_of(0.0, 2.05)[0]
    m.grid[row, m.cell_of(-3.0, 0.0)[1]:m.cell_of(3.0, 0.0)[1] + 1] = MemoryMap.OCCUPIED_AT
    m.grid[m.free] = 0
    m.grid[:row - 1] = MemoryMap.FREE_AT  # the sonar saw the space south of it free
    return m, MapPlanner(m, RADIUS)


@pytest.mark.parametrize(("goal", "clear"), [
    ((0.05, -5.0), True),  # straight away from the wall
    ((4.0, -3.0), True),  # away and to the side
    ((6.0, 1.65), True),  # along the wall, never closer, and out of the margin past its end
    ((0.05, 5.0), False),  # through it
    ((-2.0, 1.95), False),  # closer to it
    ((-1.0, 1.8), False),  # a little closer to it, sideways
])
def test_a_vehicle_stopped_near_a_wall_may_leave_it_only_by_getting_further_away(by_a_wall, goal, clear):
    m, planner = by_a_wall
    start = (0.05, 1.65)
    assert not planner.is_clear(start, 0.5)
    assert planner.path_clear(start, [goal], horizon=math.inf, padding=0.5) is clear


def test_leaving_the_margin_takes_the_first_cell_outside_it(by_a_wall):
    m, planner = by_a_wall
    from vehicle.mapping.planner import _leave_margin

    obstacles = planner.blocked_in(slice(0, m.size), slice(0, m.size))
    blocked = planning.inflate(obstacles, planner.margin_cells(0.5))
    a, b = m.cell_of(0.05, 1.65), m.cell_of(0.05, -5.0)
    exit_cell = _leave_margin(a, b, blocked, obstacles)
    assert exit_cell[1] == a[1] and not blocked[exit_cell] and blocked[exit_cell[0] + 1, exit_cell[1]]
    diagonal = m.cell_of(3.05, -1.35)  # away at 45 degrees
    exit_cell = _leave_margin(a, diagonal, blocked, obstacles)
    assert not blocked[exit_cell] and exit_cell[0] - a[0] == -(exit_cell[1] - a[1])
    inside = (a[0] - 1, a[1])  # a goal still inside the margin: the way ends there
    assert _leave_margin(a, inside, blocked, obstacles) == inside


def reference_escape_length(blocked: np.ndarray, inflated: np.ndarray, start: tuple[int, int]) -> int | None:
    """Steps of the shortest 8-connected walk over free cells (no squeezing between two blocked corners) from
    start to a cell outside the inflated obstacles."""
    seen = {start: 0}
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        if not inflated[r, c]:
            return seen[(r, c)]
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nr, nc = r + dr, c + dc
                if not (0 <= nr < blocked.shape[0] and 0 <= nc < blocked.shape[1]) or (nr, nc) in seen:
                    continue
                if blocked[nr, nc] or (dr and dc and blocked[r + dr, c] and blocked[r, c + dc]):
                    continue
                seen[(nr, nc)] = seen[(r, c)] + 1
                queue.append((nr, nc))
    return None


def test_the_escape_from_inside_the_clearance_is_a_shortest_walk_over_free_cells():
    """From random starts inside the inflated obstacles (near the grid's edges too): the walk steps to
    neighbouring free cells, never squeezes between corners, ends at the first cell outside the inflation,
    and is as short as any such walk; a start with no way out has no path."""
    found = boxed = 0
    for seed in range(30):
        rng = np.random.default_rng(seed)
        blocked = rng.random((14, 14)) < 0.3
        inflated = planning.inflate(blocked, 1.5)
        candidates = np.argwhere(inflated & ~blocked)
        start = tuple(int(v) for v in candidates[rng.integers(len(candidates))])
        expected = reference_escape_length(blocked, inflated, start)
        if expected is None:
            with pytest.raises(planning.NoPath, match="the start is boxed in by obstacles"):
                planning._escape(blocked, inflated, start)
            boxed += 1
            continue
        walk = planning._escape(blocked, inflated, start)
        assert walk.dtype == np.int64 and tuple(walk[0]) == start and len(walk) - 1 == expected
        assert not inflated[tuple(walk[-1])] and inflated[walk[:-1, 0], walk[:-1, 1]].all()
        assert not blocked[walk[:, 0], walk[:, 1]].any()
        steps = np.diff(walk, axis=0)
        assert (np.abs(steps).max(axis=1) == 1).all()
        for (r, c), (dr, dc) in zip(walk[:-1], steps, strict=True):
            assert not (dr and dc and blocked[r + dr, c] and blocked[r, c + dc])
        found += 1
    assert found >= 15 and boxed >= 1


@pytest.mark.parametrize(("dr", "dc"), [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])
def test_the_escape_goes_whichever_way_the_only_gap_is(dr, dc):
    """A start in a ring of obstacles with one gap, in each of the eight directions, at the grid's edge too."""
    for centre in ((3, 3), (1, 1), (5, 5)):
        blocked = np.zeros((7, 7), bool)
        r, c = centre
        for er in (-1, 0, 1):
            for ec in (-1, 0, 1):
                if (er or ec) and (er, ec) != (dr, dc) and 0 <= r + er < 7 and 0 <= c + ec < 7:
                    blocked[r + er, c + ec] = True
        if dr and dc:  # a diagonal gap needs one side open, or it is a squeeze between corners
            blocked[r + dr, c] = False
        inflated = np.ones((7, 7), bool)
        target = (r + 2 * dr, c + 2 * dc)
        if not (0 <= target[0] < 7 and 0 <= target[1] < 7):
            continue
        inflated[target] = False
        walk = planning._escape(blocked, inflated, centre)
        assert tuple(walk[-1]) == target and not blocked[walk[:, 0], walk[:, 1]].any()


@pytest.mark.parametrize("outside", [(14.0, 5.0), (-9.0, -2.0), (3.0, -14.0), (15.0, 11.0), (-30.0, 30.0)])
def test_from_off_the_map_the_path_comes_straight_back_onto_it_first(outside):
    """A vehicle that just left its space stands off its own map: it had "no known path" home, and hovered there
    for good. The path now starts where the straight line to the goal comes onto the map, then goes round."""
    m = MemoryMap((3.0, -2.0), space_size=10.0, resolution=5.0)  # x -7 to 13, y -12 to 8
    m.grid[35:65, 60:62] = MemoryMap.OCCUPIED_AT  # a wall 6 m long at x = 5, between the edge and home
    planner = MapPlanner(m, RADIUS)
    path, _ = planner.plan(outside, (3.0, -2.0), padding=0.2)
    assert path is not None and path[-1] == (3.0, -2.0)
    entry = path[0]
    assert m.cell_of(*entry) is not None and m.cell_of(*outside) is None
    on_edge = [abs(entry[0] - (-7.0)), abs(entry[0] - 13.0), abs(entry[1] - (-12.0)), abs(entry[1] - 8.0)]
    assert min(on_edge) <= 0.1 / 5.0 + 1e-9  # a tenth of a cell in from an edge
    across = (entry[0] - outside[0]) * (-2.0 - outside[1]) - (entry[1] - outside[1]) * (3.0 - outside[0])
    assert abs(across) < 1e-6  # on the straight line from where it stands to the goal
    for a, b in zip(path, path[1:], strict=False):  # and round the wall (x 5 to 5.4, y -5 to 1) from there
        for t in np.linspace(0.0, 1.0, 200):
            x, y = a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
            assert math.hypot(max(5.0 - x, 0.0, x - 5.4), max(-5.0 - y, 0.0, y - 1.0)) > RADIUS


def test_a_goal_off_the_map_has_no_path():
    m = MemoryMap((0.0, 0.0), space_size=10.0, resolution=5.0)
    assert MapPlanner(m, RADIUS).plan((0.0, 0.0), (30.0, 0.0), padding=0.2) == (None, 0)


# ---- reachable targets are found, unreachable ones refused with the reason ---------------------------------
def known_map() -> MemoryMap:
    """The default map (+-100 m at 10 cells/m around the origin), every cell seen free."""
    m = MemoryMap((0.0, 0.0))
    m.grid[:] = MemoryMap.FREE_AT
    return m


def wall(m: MemoryMap, y: float, x0: float | None, x1: float | None, value: int = MemoryMap.OCCUPIED_AT) -> None:
    """Cells along y from x0 to x1 (None: the map's edge) set to ``value``."""
    row = m.cell_of(0.0, y)[0]
    m.grid[row, 0 if x0 is None else m.cell_of(x0, 0.0)[1]:m.size if x1 is None else m.cell_of(x1, 0.0)[1] + 1] = value


def test_a_way_round_a_wall_that_leaves_every_window_is_found():
    """A wall 5 m north from the map's west edge to x = 55 m: the only way round passes its east end, beyond
    the 40 m window around start and goal; the whole map is searched before giving up."""
    m = known_map()
    wall(m, 5.0, None, 55.0)
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    path, _ = planner.plan((0.0, 0.0), (0.0, 10.0), padding=0.5)
    assert path is not None, planner.reason
    assert max(x for x, _ in path) > 55.0 and path[-1] == (0.0, 10.0)
    assert all(planner.is_clear(point, 0.5) for point in path)  # with the padding: the way round is wide open


def test_a_gap_between_seen_walls_that_the_sonar_has_not_looked_into_is_planned_through():
    """Two walls 5 m north with a 1.6 m gap whose cells are unknown: presuming the unseen to be more wall
    closes it, so it is planned through without that presumption (the sonar checks it on the way) rather
    than refused with "no known path" (a Go here to an open spot beyond was refused so)."""
    m = known_map()
    wall(m, 5.0, None, -0.8)
    wall(m, 5.0, 0.8, None)
    wall(m, 5.0, -0.7, 0.7, value=0)
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    path, level = planner.plan((0.0, 0.0), (0.0, 10.0), padding=0.5)
    assert path is not None and level == 2, planner.reason
    assert all(abs(x) < 0.8 for x, y in path if 4.5 < y < 5.5) or len(path) == 1


def ring(m: MemoryMap, centre: tuple[float, float], radius: float) -> None:
    for angle in np.linspace(0, 2 * math.pi, 2000):
        m.grid[m.cell_of(centre[0] + radius * math.cos(angle), centre[1] + radius * math.sin(angle))] = 20


@pytest.mark.parametrize(("start", "goal", "reason"), [
    ((0.0, 0.0), (20.0, 0.0), "the target is enclosed by known obstacles"),
    ((20.0, 0.0), (0.0, 0.0), "the vehicle is enclosed by known obstacles"),
    ((0.0, 0.0), (23.0, 0.0), "the target is on an occupied cell"),
    ((0.0, 0.0), (22.8, 0.0), "the target is within 0.35 m of a known obstacle"),
])
def test_an_unreachable_target_is_refused_with_the_reason(start, goal, reason):
    """A closed ring 3 m in radius around (20, 0): nothing crosses it, whatever the padding."""
    m = known_map()
    ring(m, (20.0, 0.0), 3.0)
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    path, _ = planner.plan(start, goal, padding=0.5, relax=True)
    assert path is None and planner.reason == reason
    m.grid[m.cell_of(17.0, 0.0)[0] - 6:m.cell_of(17.0, 0.0)[0] + 7, m.cell_of(17.0, 0.0)[1]] = MemoryMap.FREE_AT
    if "occupied" not in reason and "within" not in reason:  # a doorway 1.3 m wide in the ring: now it is found
        path, _ = planner.plan(start, goal, padding=0.5)
        assert path is not None and path[-1] == goal, planner.reason


def clearance_along(path: list[tuple[float, float]], start: tuple[float, float], m: MemoryMap):
    """(point, distance to the nearest occupied cell's centre) every 5 cm along a path from ``start``."""
    occupied = np.array([m.center_of(r, c) for r, c in np.argwhere(m.occupied)])
    for a, b in zip([start, *path[:-1]], path, strict=True):
        for t in np.linspace(0.0, 1.0, max(2, int(math.dist(a, b) / 0.05))):
            point = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
            yield point, float(np.min(np.hypot(*(occupied - point).T)))


def test_a_vehicle_boxed_in_closer_than_the_clearance_is_refused_with_the_reason_not_an_exception():
    """Its own cell free, every cell round it occupied (a coarse map with a large padding, as a thesis sweep's
    house runs made): no way out, and planning says so; before, the escape's NoPath escaped the planner."""
    m = known_map()
    r, c = m.cell_of(0.0, 0.0)
    m.grid[r - 1:r + 2, c - 1:c + 2] = MemoryMap.OCCUPIED_AT
    m.grid[r, c] = MemoryMap.FREE_AT
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    path, _ = planner.plan((0.0, 0.0), (5.0, 0.0), padding=0.5)
    assert path is None and planner.reason == "the vehicle is boxed in by known obstacles, too close to them to move"


def test_a_path_squeezed_through_a_doorway_keeps_the_wide_clearance_away_from_it():
    """A wall 5 m north with a 1.0 m doorway at x = 0, the vehicle 1 m from the wall 8 m west of it: the way
    through needs the doorway's tight clearance, but only near the doorway; the straight line to it would
    graze the wall for 7 m (a wall met at a glancing angle gives the sonar no echo: a copter hit one so)."""
    m = known_map()
    wall(m, 5.0, None, -0.5)
    wall(m, 5.0, 0.5, None)
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    start = (-8.0, 4.0)
    path, level = planner.plan(start, (6.0, 7.0), padding=0.5)
    assert path is not None and level > 0, planner.reason
    wide = planner.margin_cells(0.5) / m.resolution
    near_doorway = far = 0
    for point, clearance in clearance_along(path, start, m):
        if math.dist(point, (0.0, 5.0)) > 2.0:
            assert clearance >= wide - 0.15, point  # a cell's worth of the smoothing's tolerance
            far += 1
        else:
            assert clearance >= planner.margin_cells(0.0) / m.resolution - 0.05, point
            near_doorway += 1
    assert far > 100 and near_doorway > 10


@pytest.mark.parametrize("start", [(-8.0, 4.0), (-3.0, 3.0), (0.5, 3.0)])
def test_a_path_squeezed_through_a_doorway_passes_its_middle(start):
    """The 1.0 m doorway of the test above, the padding 0.1 m (the wide clearance is 0.5 m, twice the
    avoidance's margin, more than the doorway's half): the path keeps the most clearance the doorway has (its
    middle, 0.5 m from both frames), not the least that fits (0.35 m, along one frame, where a door frame at a
    sonar cone's edge stopped the vehicle), and the planner reports the clearance it kept."""
    m = known_map()
    wall(m, 5.0, None, -0.5)
    wall(m, 5.0, 0.5, None)
    planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
    path, level = planner.plan(start, (3.0, 7.0), padding=0.1)
    assert path is not None and level > 0, planner.reason
    near = [clearance for point, clearance in clearance_along(path, start, m) if math.dist(point, (0.0, 5.0)) < 1.5]
    assert min(near) >= 0.45
    assert planner.clearance == pytest.approx(0.45 - RADIUS)


def test_a_map_coarser_than_the_body_plans_through_no_gap_it_has_not_seen():
    """At 1 cell/m a cell is wider than the body: a 2 m stretch of unknown cells between two seen walls is as
    likely a wall the sonar missed as a doorway, so no path goes through it (the house's coarse-map Search
    grazed an unseen wall so); at 10 cells/m the same gap is planned through."""
    for resolution, found in ((1.0, False), (10.0, True)):
        m = MemoryMap((0.0, 0.0), space_size=30.0, resolution=resolution)
        m.grid[:] = MemoryMap.FREE_AT
        wall(m, 5.0, None, -1.0)
        wall(m, 5.0, 1.0, None)
        wall(m, 5.0, -0.9, 0.9, value=0)
        planner = MapPlanner(m, RADIUS, avoid_margin=0.1)
        path, _ = planner.plan((0.0, 0.0), (0.0, 10.0), padding=0.5)
        assert (path is not None) is found, (resolution, planner.reason)
