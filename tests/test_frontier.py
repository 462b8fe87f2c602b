"""Frontier detection and the nearest reachable frontier (vehicle.mapping.frontier), on hand-made grids,
and Search exploring until no reachable frontier is left, in the real simulator."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_missions import Track, enclosure, fly, scene, wall
from vehicle.mapping import frontier


def grid(text: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Free, unknown and occupied masks of a picture: '.' (or 'S', the start) free, '?' unknown, '#' occupied
    (first line row 0)."""
    rows = np.array([list(line) for line in text.strip().splitlines()])
    return (rows == ".") | (rows == "S"), rows == "?", rows == "#"


def test_frontier_cells_are_free_cells_beside_unknown_ones_grouped_and_small_groups_dropped():
    free, unknown, _ = grid("""
......??
......??
####..??
?.##....
""")
    cells = frontier.frontier_cells(free, unknown)
    assert sorted(zip(*np.nonzero(cells), strict=True)) == [(0, 5), (1, 5), (2, 5), (3, 1), (3, 6), (3, 7)]
    groups = frontier.frontiers(free, unknown)
    assert sorted(len(g) for g in groups) == [1, 5]  # 8-connected: (2, 5) and (3, 6) touch
    assert [len(g) for g in frontier.frontiers(free, unknown, min_cells=2)] == [5]


def test_the_nearest_reachable_frontier_wins_over_a_nearer_one_behind_a_wall():
    free, unknown, occupied = grid("""
??????????????
..#...........
..#...........
..#.....S.....
..#...........
..#...........
..#..........?
""")
    start = (3, 8)
    passable = free & ~occupied
    found = list(frontier.reachable_frontiers(free, unknown, passable, start))
    left_of_wall = [f for f in found if f.goal[1] < 2]
    assert not left_of_wall  # the column left of the wall is 6 cells away, and unreachable
    assert found[0].distance == min(f.distance for f in found)
    lengths, _ = frontier.path_lengths(passable, start)
    assert np.isinf(lengths[3, 0]) and np.isfinite(lengths[3, 13])


def test_path_lengths_are_scipys_dijkstra_over_the_same_graph_and_each_predecessor_is_a_step_back():
    """Our compiled Dijkstra against scipy's over the grid built as a sparse graph (each step once, a diagonal
    only between two open cells), on random grids: the same lengths, and every predecessor one step back."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    generator = np.random.default_rng(7)
    for _ in range(20):
        passable = generator.random((23, 31)) < 0.7
        start = tuple(int(v) for v in np.argwhere(passable)[generator.integers(passable.sum())])
        rows, cols = passable.shape
        padded = np.pad(passable, 1)
        heads, tails, weights = [], [], []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            ok = passable & padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols]
            if dr and dc:
                ok &= padded[1 + dr:1 + dr + rows, 1:1 + cols] & padded[1:1 + rows, 1 + dc:1 + dc + cols]
            here = np.flatnonzero(ok)
            heads.append(here)
            tails.append(here + dr * cols + dc)
            weights.append(np.full(len(here), np.hypot(dr, dc)))
        graph = coo_matrix((np.concatenate(weights), (np.concatenate(heads), np.concatenate(tails))),
                           shape=(passable.size, passable.size)).tocsr()
        expected = dijkstra(graph, directed=False, indices=start[0] * cols + start[1]).reshape(passable.shape)
        lengths, parents = frontier.path_lengths(passable, start)
        np.testing.assert_allclose(lengths, expected, rtol=0, atol=1e-9)
        for cell in zip(*np.nonzero(np.isfinite(lengths) & (lengths > 0)), strict=True):
            back = np.unravel_index(parents[cell], passable.shape)
            assert max(abs(back[0] - cell[0]), abs(back[1] - cell[1])) == 1
            assert lengths[back] + np.hypot(back[0] - cell[0], back[1] - cell[1]) == pytest.approx(lengths[cell])
        assert parents[start] < 0 and lengths[start] == 0
        blocked = passable.copy()
        blocked[start] = False
        assert np.isinf(frontier.path_lengths(blocked, start)[0]).all()  # from a blocked cell: nowhere


def test_a_frontier_reached_only_through_a_gap_too_narrow_for_the_body_is_approached_but_not_entered():
    free, unknown, occupied = grid("""
????????????
............
####.#######
............
............
............
""")
    start = (5, 5)
    passable = free & (np.arange(6) >= 4)[:, None]  # the body fits only a row clear of the wall
    assert not list(frontier.reachable_frontiers(free, unknown, passable, start))
    found = list(frontier.reachable_frontiers(free, unknown, passable, start, narrow=free))
    assert len(found) == 1 and found[0].narrow
    assert found[0].goal[0] == 4 and abs(found[0].goal[1] - 4) <= 1  # short of the gap, where the body fits


def test_a_frontier_looked_at_from_its_roomy_goal_is_approached_closer():
    """A doorway (column 4) into a corridor whose sides stay unknown from the room: the goal with known-free
    space all round (clearance 1.5 cells) is in the room; once the room is looked from, the frontier's goal is
    the reachable cell nearest it, through the doorway, from where the corridor is seen. Before,
    a frontier whose roomy goal was looked from was dropped, and Search in three of the apartment's rooms
    ended in under a minute with 13 % of the floor known."""
    free, unknown, occupied = grid("""
???.???
###.###
.......
.......
.......
...S...
""")
    start = (5, 3)
    passable = free
    roomy_goal = next(frontier.reachable_frontiers(free, unknown, passable, start, clearance=1.5)).goal
    assert roomy_goal[0] >= 2
    looked = np.zeros_like(free)
    looked[2:, :] = True  # the whole room looked from
    found = list(frontier.reachable_frontiers(free, unknown, passable, start, clearance=1.5, looked=looked))
    assert [f.goal for f in found] == [(0, 3)]  # the frontier's own cell, at the corridor, reachable


def test_search_in_a_closed_room_ends_only_when_no_reachable_frontier_is_left():
    """A room 8 m across with a side room through a 1.9 m doorway: Search sees both and ends saying why."""
    walls = [*enclosure(0, 0, 8), wall(2.5, -1, 0.2, 6.2)]  # a wall across, its doorway at the north end
    track = Track()
    result = fly(scene(*walls), "search", track=track, time_limit=400, space_size=10)
    assert result["outcome"] == "finished", result["reason"]
    assert track.world.collision is None
    m = track.agent.map
    (r0, c0), (r1, c1) = m.cell_of(2.7, -3.9), m.cell_of(3.8, 3.9)  # the side room, behind the wall across
    known = float(np.mean(m.grid[r0:r1, c0:c1] != 0))
    assert known > 0.5, known
    assert "no reachable frontier left" in result["reason"], result["reason"]


def test_the_nearest_frontier_looked_for_near_the_vehicle_first_is_the_one_the_whole_map_gives(monkeypatch):
    """Search looks for the nearest frontier around the vehicle before the whole map (half a team's time went
    to the whole shared map): from every spot of a map that Search made, the answer must be the same."""
    from vehicle.agent.missions import search
    from vehicle.agent.settings import Settings
    from vehicle.lab.stepper import simulate
    from vehicle.world.bundled import default_scene
    from vehicle.world.scene import load_scene

    stepper = simulate(load_scene(str(default_scene())), "search", settings=Settings(time_limit=600))
    stepper.run(240)
    mission, ctx = stepper.agent.mission, stepper.agent.ctx
    spots = [(float(x), float(y)) for x in np.arange(-18, 19, 6.0) for y in np.arange(-18, 19, 6.0)
             if ctx.is_clear((float(x), float(y)))]
    assert len(spots) > 20

    def goals(near: float) -> list:
        monkeypatch.setattr(search, "NEAR_FRONTIER", near)
        found = []
        for spot in spots:
            monkeypatch.setattr(type(ctx), "position", property(lambda self, spot=spot: spot))
            found.append(mission.nearest_frontier())
        return found

    whole = goals(1e6)
    assert sum(goal is not None for goal in whole) > 10
    for near in (search.NEAR_FRONTIER, 4.0, 2.0):  # the nearer, the more often the whole map decides
        assert goals(near) == whole, near
