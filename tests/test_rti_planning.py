"""The tomography planner: the greedy step goes where the image is least sure, every agent plans alike from
the same history, spots keep clear of the scene and of each other, and the perimeter plan looks across."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import GROUND

from vehicle.agent.missions.rti import clear_spots
from vehicle.tomography.planning import ALONG, Planner, nearest_object, ring

REGION = (0.0, 0.0, 6.0, 6.0)
BOX = """Transform { translation 8.5 3 2 children Shape { geometry Box { size 1 1 4 } } }"""


def planner(kind="uncertainty", **options) -> Planner:
    return Planner(REGION, ring(REGION, 1.0, 1.0), kind, **{"dwell": 1e6, **options})  # travel costs nothing


def weight_in(p: Planner, a, b, columns: slice) -> float:
    """The share of the link a-b's weight on the image's given columns."""
    w = p.weights.matrix(np.array([[*a, *b]], float)).toarray().reshape(p.grid.shape)
    return w[:, columns].sum() / w.sum()


def test_the_greedy_step_picks_a_link_through_the_pixels_no_link_has_crossed():
    p = planner()
    half = p.grid.nx // 2
    for x in np.arange(0.25, 3.0, 0.25):  # the west half crossed north-south many times over
        for _ in range(3):
            p.measured((x, -1.0), (x, 7.0))
    a, b = p.next_spots([(0.0, -1.0), (0.0, 7.0)])
    assert weight_in(p, a, b, slice(half, None)) > 0.9, (a, b)  # through the east half
    # the same step without that history goes anywhere but is not drawn to the east: the test can fail
    fresh = planner()
    a, b = fresh.next_spots([(0.0, -1.0), (0.0, 7.0)])
    assert weight_in(fresh, a, b, slice(half, None)) < 0.9


def test_each_step_lowers_the_uncertainty_most_where_it_was_highest():
    p = planner()
    before = p.uncertainty()
    p.next_spots([(0.0, -1.0), (6.0, 7.0)])
    assert p.uncertainty() < before
    assert p.links == 1


def test_the_greedy_step_measures_along_the_perimeter_plans_four_directions():
    """Lines in a few directions leave a target crossed from two or three, and the image splits it between
    their crossings: each link runs within ``ALONG`` degrees of 0, 45, 90 or 135."""
    p = planner(dwell=3.0)
    here = [(0.0, -1.0), (6.0, 7.0)]
    off = []
    for _ in range(16):
        a, b = here = p.next_spots(here)
        angle = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0])) % 45.0
        off.append(min(angle, 45.0 - angle))
    assert max(off) <= ALONG + 1e-6, off


def test_two_agents_with_the_same_history_make_the_same_plan():
    first, second = planner(dwell=3.0), planner(dwell=3.0)
    here_1 = here_2 = [(0.0, 0.0), (-4.0, -4.0)]
    plan_1, plan_2 = [], []
    for _ in range(10):
        here_1, here_2 = first.next_spots(here_1), second.next_spots(here_2)
        plan_1.append(here_1)
        plan_2.append(here_2)
    assert plan_1 == plan_2
    assert len({tuple(step) for step in plan_1}) == 10  # it moves on: ten different pairs
    # another history (one link more) gives another plan
    other = planner(dwell=3.0)
    other.measured(*plan_1[0])  # the first step's link, already measured
    here = [(0.0, 0.0), (-4.0, -4.0)]
    assert [here := other.next_spots(here) for _ in range(10)] != plan_1


def test_each_vehicle_goes_to_the_spot_nearest_where_it_was():
    p = planner()
    a, b = p.next_spots([(-1.0, -1.0), (7.0, 7.0)])
    swapped = planner()
    c, d = swapped.next_spots([(7.0, 7.0), (-1.0, -1.0)])
    assert (a, b) == (d, c)
    assert math.dist(a, (-1, -1)) + math.dist(b, (7, 7)) <= math.dist(a, (7, 7)) + math.dist(b, (-1, -1))


def test_spots_keep_clear_of_the_scene_and_of_each_other(make_scene):
    scene = make_scene(GROUND, BOX)
    spots = ring(REGION, 2.0, 0.5)
    clear = clear_spots(spots, scene, radius=0.3, altitude=2.0, padding=0.5)
    assert 0 < len(clear) < len(spots)
    box = np.array([8.5, 3.0])
    assert np.abs(clear - box).max(axis=1).min() > 0.5 + 0.3 + 0.5  # half the box, the body and the padding
    removed = [s for s in spots.tolist() if s not in clear.tolist()]
    assert all(np.abs(np.array(s) - box).max() < 1.4 for s in removed)
    p = Planner(REGION, clear, apart=3.0)
    here = [(0.0, 0.0), (6.0, 6.0)]
    for _ in range(20):
        here = p.next_spots(here)
        assert math.dist(*here) >= 3.0
        assert all(s in clear.tolist() for s in map(list, here))


def test_the_perimeter_plan_measures_straight_across_then_steps_along():
    p = planner("perimeter")
    steps = [p.next_spots([(0.0, -2.0), (0.0, 8.0)]) for _ in range(3)]
    for a, b in steps:
        assert a[0] == b[0] and abs(a[1] - b[1]) == 8.0  # straight across, north-south
    assert steps[1][0][0] - steps[0][0][0] == 1.0  # a spot further along


def test_a_third_vehicle_and_fixed_nodes_are_planned_for():
    p = planner()
    spots = p.next_spots([(0.0, 0.0), (6.0, 6.0), (0.0, 6.0)])
    assert len(set(spots)) == 3 and p.links >= 2  # a link that misses the region is no measurement
    alone = planner(fixed=[(-1.0, 3.0), (7.0, 3.0)])
    (spot,) = alone.next_spots([(3.0, -1.0)])
    assert alone.links == 2 and spot in [tuple(s) for s in alone.spots.tolist()]


def test_the_region_is_the_object_nearest_the_start(make_scene):
    far = "Transform { translation 30 0 2 children Shape { geometry Box { size 2 2 4 } } }"
    scene = make_scene(GROUND, BOX, far)
    assert nearest_object(scene, (0.0, 0.0), margin=1.0) == (7.0, 1.5, 10.0, 4.5)
    with pytest.raises(ValueError, match="no object"):
        nearest_object(make_scene(GROUND), (0.0, 0.0))


def test_a_ring_with_no_room_is_refused():
    with pytest.raises(ValueError, match="fewer than two clear spots"):
        Planner(REGION, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="unknown planner"):
        Planner(REGION, ring(REGION, 1.0, 1.0), "spiral")


def line_distance(point, a, b) -> float:
    """Distance from ``point`` to the straight line through a and b."""
    (px, py), (ax, ay), (bx, by) = point, a, b
    return abs((bx - ax) * (py - ay) - (by - ay) * (px - ax)) / math.dist(a, b)


def test_the_perimeter_plan_lays_lines_in_four_directions_evenly_spaced():
    p = planner("perimeter", rounds=20)
    here = [(0.0, -1.0), (0.0, 7.0)]
    steps = [here := p.next_spots(here) for _ in range(20)]
    angles = [round(math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))) % 180 for a, b in steps]
    assert sorted(set(angles)) == [0, 45, 90, 135] and all(angles.count(a) == 5 for a in (0, 45, 90, 135)), angles
    north_south = sorted(a[0] for a, b in steps if a[0] == b[0])
    assert np.allclose(np.diff(north_south), 1.0)  # five strips of 1.2 m, snapped to the ring's 1 m spots
    assert p.next_spots(here) == steps[0] or set(p.next_spots(steps[0])) == set(steps[1])  # then again


def test_the_perimeter_plan_tells_two_targets_from_their_ghosts():
    """Two targets 1.5 m apart on a diagonal: in a grid of north-south and east-west lines their ghosts (the
    other two corners of the rectangle they span) lie on exactly the lines the targets do, so no measurement
    tells them apart; lines in further directions pass a ghost and miss both targets."""
    targets = [(2.5, 2.5), (3.56, 3.56)]
    ghosts = [(2.5, 3.56), (3.56, 2.5)]
    p = planner("perimeter", rounds=24)
    here = [(0.0, -1.0), (0.0, 7.0)]
    lines = [here := p.next_spots(here) for _ in range(24)]
    telling = [line for line in lines if min(line_distance(g, *line) for g in ghosts) < 0.3
               and min(line_distance(t, *line) for t in targets) > 0.6]
    assert len(telling) >= 2, lines
