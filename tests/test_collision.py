"""Swept-sphere collision (vehicle.collision) and what a collision does to a Simulation run (vehicle.world)."""

import math
from collections import Counter

import numpy as np
import pytest

from vehicle.protocol.mav import mavlink as mav
from vehicle.protocol.modes import Kind
from vehicle.sim.simulation import PlacementError, Simulation
from vehicle.world.collision import Collider, point_triangle_distance, segment_triangle_distance
from vehicle.world.sonar import Sonar

RADIUS = 0.3
WALL_FACE_Y = 9.9  # south face of the wall in the wall_scene fixture
REAR_ONLY = [Sonar("rear", mount_yaw=180.0)]  # sees nothing ahead, so avoidance cannot brake


def test_a_body_flying_into_a_wall_touches_it_at_wall_minus_radius(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    contact = collider.sweep((0.0, 0.0, 4.0), (0.0, 12.0, 4.0))
    assert contact is not None
    assert contact.point[1] == pytest.approx(WALL_FACE_Y - RADIUS, abs=0.02)
    assert contact.point[0] == pytest.approx(0.0) and contact.point[2] == pytest.approx(4.0)
    assert contact.fraction == pytest.approx((WALL_FACE_Y - RADIUS) / 12.0, abs=0.002)
    assert wall_scene.mesh.face_normals[contact.face][1] == pytest.approx(-1.0, abs=1e-6)  # the south face
    assert "collision at" in contact.describe()


def test_a_body_passing_a_wall_further_than_its_radius_does_not_touch_it(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    assert collider.sweep((-15.0, WALL_FACE_Y - 1.0, 4.0), (15.0, WALL_FACE_Y - 1.0, 4.0)) is None


def test_grazing_a_wall_at_radius_plus_one_centimetre_does_not_touch_it(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    y = WALL_FACE_Y - RADIUS - 0.01
    assert collider.sweep((-15.0, y, 4.0), (15.0, y, 4.0)) is None
    # and past the wall's end, along its length
    assert collider.sweep((10.0 + RADIUS + 0.01, 0.0, 4.0), (10.0 + RADIUS + 0.01, 20.0, 4.0)) is None


def test_grazing_a_wall_one_centimetre_inside_the_radius_touches_it(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    y = WALL_FACE_Y - RADIUS + 0.01
    contact = collider.sweep((-15.0, y, 4.0), (15.0, y, 4.0))
    assert contact is not None
    assert contact.point[0] == pytest.approx(-10.0, abs=0.3)  # where the path meets the wall's west end


def test_a_fast_step_through_a_thin_wall_is_caught(wall_scene):
    """The whole swept path counts, not only where the step ends."""
    collider = Collider(wall_scene.mesh, RADIUS)
    assert collider.sweep((0.0, 8.0, 4.0), (0.0, 12.0, 4.0)) is not None


def test_contact_is_found_to_a_millionth_of_the_step(wall_scene):
    """Bisection over the step, from its start to its end, 20 times: the contact lies at most 2**-20 of the
    step before the fraction reported (here just past a half, where 19 halvings would be twice as coarse)."""
    collider = Collider(wall_scene.mesh, RADIUS)
    touch_y = WALL_FACE_Y - RADIUS
    exact = 0.5 + 1e-7
    start = touch_y - 0.5
    contact = collider.sweep((0.0, start, 4.0), (0.0, start + 0.5 / exact, 4.0))
    assert contact is not None
    assert 0.0 <= contact.fraction - exact <= 2.0**-20


def test_contact_is_found_within_a_millionth_of_the_step_past_the_first_touch(wall_scene):
    """20 halvings of the step: the contact returned touches, and lies at most 2**-20 of the step past the
    exact first touching position (here 9.6 m along a 12 m step, a fraction of 0.8)."""
    collider = Collider(wall_scene.mesh, RADIUS)
    contact = collider.sweep((0.0, 0.0, 4.0), (0.0, 12.0, 4.0))
    exact = (WALL_FACE_Y - RADIUS) / 12.0
    assert 0.0 <= contact.fraction - exact <= 2**-20 + 1e-12


def test_clearance_is_the_distance_to_the_nearest_surface(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    assert collider.clearance(np.array([0.0, 8.0, 4.0])) == pytest.approx(1.9, abs=1e-6)
    assert collider.clearance(np.array([0.0, 0.0, 50.0])) == collider.search  # nothing near


@pytest.mark.parametrize(("radius", "search"), [(0.5, 4.0), (3.0, 6.0)])
def test_clearance_looks_as_far_as_search_and_at_least_twice_the_radius(flat_scene, radius, search):
    collider = Collider(flat_scene.mesh, radius, ignore_walkable=True)  # a rover: the ground is nothing to hit
    assert collider.search == search
    assert collider.clearance((0.0, 0.0, 50.0)) == search  # nothing within reach


@pytest.mark.parametrize(("point", "expected"), [
    ((0.5, -1.0, 0.0), 1.0),  # off the edge ab
    ((0.25, 0.25, 2.0), 2.0),  # above it
    ((-3.0, -4.0, 0.0), 5.0),  # off vertex a
    ((3.0, 3.0, 0.0), 2.0 * math.sqrt(2.0)),  # off the long edge bc
])
def test_point_triangle_distance_in_each_region(point, expected):
    triangle = np.array([[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]])
    assert point_triangle_distance(np.array(point), triangle)[0] == pytest.approx(expected)


def voronoi_region(closest: np.ndarray, triangle: np.ndarray) -> str:
    """Which feature of the triangle abc the closest point lies on: a vertex, an edge or the face."""
    a, b, c = triangle
    v0, v1, v2 = b - a, c - a, closest - a
    d00, d01, d11, d20, d21 = v0 @ v0, v0 @ v1, v1 @ v1, v2 @ v0, v2 @ v1
    denom = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    on = {name for name, weight in (("a", 1 - v - w), ("b", v), ("c", w)) if weight > 1e-6}
    return "face" if len(on) == 3 else "".join(sorted(on))


def test_point_triangle_distance_agrees_with_trimesh_in_all_seven_voronoi_regions():
    """Random triangles and points (seeded) against trimesh's closest points, so every region is checked:
    the three vertices, the three edges and the face (a slip between edges ab and ac was once wrong in
    a sixth of random cases while hand-picked cases passed)."""
    from trimesh.triangles import closest_point

    rng = np.random.default_rng(14)
    triangles = rng.normal(size=(3000, 3, 3)) * rng.uniform(0.1, 10, size=(3000, 1, 1))
    points = rng.normal(size=(3000, 3)) * 6
    expected = closest_point(triangles, points)
    regions = Counter()
    for triangle, point, closest in zip(triangles, points, expected, strict=True):
        distance = point_triangle_distance(point, triangle[None])[0]
        assert distance == pytest.approx(np.linalg.norm(point - closest), rel=1e-9, abs=1e-9)
        regions[voronoi_region(closest, triangle)] += 1
    assert set(regions) == {"a", "b", "c", "ab", "bc", "ac", "face"}
    assert min(regions.values()) >= 100, regions


def test_a_point_beyond_b_whose_closest_point_is_on_edge_bc_not_on_the_line_through_ab():
    """c lies beyond b along ab (an obtuse corner at b): a point just past b below ab is nearest to edge bc,
    where the line through ab, extended past b, would be nearer."""
    triangle = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0]]])
    assert point_triangle_distance(np.array([1.5, -0.25, 0.0]), triangle)[0] == pytest.approx(0.375 * math.sqrt(2))


def test_a_point_past_b_of_a_triangle_leaning_past_b_is_nearest_to_edge_bc():
    """Ericson's edge-ab region needs the point on a's side of b (d3 <= 0). Where c leans past b along ab (an
    obtuse angle at b), a point just past b lies in edge bc's region, and its true distance is larger than
    its distance to the line through a and b: taking edge ab there would report the body too close."""
    from trimesh.triangles import closest_point

    triangle = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 1.0, 0.0]])
    points = np.array([[1.5, -0.5, 0.0], [1.2, -0.1, 0.3], [1.9, -0.2, -0.4], [1.05, -0.9, 0.0]])
    for point in points:
        expected = np.linalg.norm(point - closest_point(triangle[None], point[None])[0])
        assert point_triangle_distance(point, triangle[None])[0] == pytest.approx(expected, rel=1e-12)
    assert point_triangle_distance(points[0], triangle[None])[0] == pytest.approx(math.sqrt(0.45))


def segment_triangle_reference(p0: np.ndarray, p1: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Segment-to-triangle distance from trimesh's closest points alone: the distance of p0 + t (p1 - p0) to a
    triangle is convex in t, so a ternary search on t finds its minimum."""
    from trimesh.triangles import closest_point

    def at(t):
        points = p0 + t[:, None] * (p1 - p0)
        return np.linalg.norm(points - closest_point(triangles, points), axis=1)

    lo, hi = np.zeros(len(triangles)), np.ones(len(triangles))
    for _ in range(60):
        a, b = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        nearer_a = at(a) < at(b)
        hi = np.where(nearer_a, b, hi)
        lo = np.where(nearer_a, lo, a)
    return np.minimum.reduce([at(lo), at(np.zeros(len(triangles))), at(np.ones(len(triangles)))])


def test_segment_triangle_distance_agrees_with_trimesh_on_random_segments():
    """The swept body's distance to each triangle: the segment's ends, its closest approach to the triangle's
    edges, and zero where it passes through the face, all against an independent reference."""
    rng = np.random.default_rng(7)
    triangles = rng.normal(size=(150, 3, 3)) * 3
    crossings = 0
    for k in range(30):
        p0, p1 = rng.normal(size=3) * 4, rng.normal(size=3) * 4
        if k % 4 == 0:
            p1 = p0 + rng.normal(size=3) * 0.05  # short steps, as a simulation takes
        got = segment_triangle_distance(p0, p1, triangles)
        expected = segment_triangle_reference(p0, p1, triangles)
        np.testing.assert_allclose(got, expected, atol=1e-7)
        crossings += int(np.count_nonzero(expected < 1e-9))
    assert crossings > 10  # segments through faces were among them (distance zero)


@pytest.mark.parametrize("axes", [(0, 1, 2), (1, 2, 0), (2, 0, 1)])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_point_over_the_face_is_as_far_as_its_height_whichever_plane_the_triangle_lies_in(axes, sign):
    """Triangles in the coordinate planes with edges (1, 1) and (1, -1): every part of the face normal counts
    (a slip in one component of the cross product makes such a triangle look like one without area)."""
    a, b, c = np.zeros(3), np.array([2.0, 2.0 * sign, 0.0]), np.array([2.0, -2.0 * sign, 0.0])
    triangle = np.array([a, b, c])[:, axes]
    above = np.array([1.2, 0.3, 0.7])[list(axes)]
    assert point_triangle_distance(above, triangle[None])[0] == pytest.approx(0.7)


def test_a_point_over_a_triangle_whose_edges_mix_x_and_y_is_as_far_as_its_height():
    """The face's normal has all three parts of the cross product: with one wrong, this triangle in the ground
    plane (edges (1, 1, 0) and (1, 0, 0)) would look like one without area and be measured by its edges."""
    triangle = np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]])
    assert point_triangle_distance(np.array([0.7, 0.3, 0.5]), triangle)[0] == pytest.approx(0.5)


@pytest.fixture
def clutter():
    """A field of 300 small triangles (foliage), a few big ones across it (ground, a slanted roof) and a wall
    of 20 m along y = 5: small ones are binned by grid cell, big ones checked everywhere."""
    import trimesh

    rng = np.random.default_rng(11)
    small = rng.uniform(-20, 20, size=(300, 1, 3)) + rng.normal(size=(300, 3, 3)) * 0.8
    big = np.array([[[-30, -30, 0], [30, -30, 0], [30, 30, 0]], [[-30, -30, 0], [30, 30, 0], [-30, 30, 0]],
                    [[-25, -25, 9], [25, -25, 14], [0, 25, 11]],
                    [[-10, 5, 0], [10, 5, 0], [10, 5, 8]], [[-10, 5, 0], [10, 5, 8], [-10, 5, 8]]],
                   dtype=float)
    triangles = np.concatenate([small, big])
    return trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(len(triangles) * 3).reshape(-1, 3), process=False)


def test_the_grid_finds_every_triangle_near_a_point_or_a_step(clutter):
    """Clearance and contact through the grid equal a brute-force check of every triangle: binning must never
    lose a triangle that is near (it may hand over ones that are not)."""
    triangles = np.asarray(clutter.triangles)
    collider = Collider(clutter, RADIUS)
    rng = np.random.default_rng(12)
    contacts = 0
    for _ in range(60):
        point = rng.uniform([-24, -24, -1], [24, 24, 15])
        nearest = point_triangle_distance(point, triangles).min()
        assert collider.clearance(point) == pytest.approx(min(collider.search, nearest), abs=1e-12)
        end = point + rng.normal(size=3) * 1.5
        touching = segment_triangle_distance(point, end, triangles).min() < RADIUS
        fresh = Collider(collider.grid, RADIUS)  # no clear ball from an earlier step
        contact = fresh.sweep(point, end)
        assert (contact is not None) == touching, (point, end)
        if contact is not None:
            contacts += 1
            assert point_triangle_distance(contact.point, triangles[[contact.face]])[0] <= RADIUS + 1e-4
            if nearest >= RADIUS:  # first touch on the way: clear until there
                before = point + (contact.point - point) * (1 - 1e-4)
                assert segment_triangle_distance(point, before, triangles).min() >= RADIUS - 1e-4
            else:  # it started touching
                assert contact.fraction < 1e-5
    assert 8 < contacts < 52  # both outcomes, many times


def test_a_rover_ignores_only_the_faces_it_can_drive_on(clutter):
    """ignore_walkable keeps the faces steeper than about 45 degrees and maps contacts back to the mesh's face
    numbers."""
    collider = Collider(clutter, RADIUS, ignore_walkable=True)
    normals = np.asarray(clutter.face_normals)
    kept = np.flatnonzero(normals[:, 2] <= 0.7)
    assert np.array_equal(collider.grid.face_ids, kept)
    assert 0 < len(kept) < len(normals)
    contact = collider.sweep((0.0, 0.0, 4.0), (0.0, 10.0, 4.0))  # into the wall at y = 5, not the ground
    assert contact is not None and contact.face in (len(normals) - 2, len(normals) - 1)
    assert contact.point[1] == pytest.approx(5.0 - RADIUS, abs=1e-3)


def test_colliders_share_the_grid_they_are_given_and_a_grid_keeps_walkable_faces_by_default(flat_scene):
    from vehicle.world.collision import TriangleGrid

    grid = TriangleGrid(flat_scene.mesh)
    assert len(grid.triangles) == len(flat_scene.mesh.faces)  # the ground too, unless told to leave it out
    assert Collider(grid, RADIUS).grid is grid
    assert len(TriangleGrid(flat_scene.mesh, ignore_walkable=True).triangles) < len(grid.triangles)


def test_the_distance_between_two_segments_is_exact_on_its_own():
    """The segment-to-segment helper against a reference (the distance of a point moving along one segment to
    the other is convex), on its own: inside the segment-to-triangle distance each corner of a triangle is
    reached through two edges, which hides an error in one of them, but not from a step along an edge."""
    from vehicle.world.collision import _segment_segment_distance

    def point_to_segment(points, a, b):
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(ab @ ab, 1e-300), 0, 1)
        return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)

    rng = np.random.default_rng(21)
    checked = 0
    for k in range(300):
        p1, q1, p2, q2 = rng.normal(size=(4, 3)) * rng.choice([0.05, 1.0, 5.0], size=(4, 1))
        if k % 10 == 0:
            q2 = p2 + (q1 - p1) * rng.uniform(-2, 2)  # parallel
        if k % 10 == 1:
            q1 = p1.copy()  # a point, not a segment
        if k % 10 == 2:
            q2 = p2.copy()
        s = np.linspace(0, 1, 2001)
        expected = point_to_segment(p1 + s[:, None] * (q1 - p1), p2, q2).min()
        got = _segment_segment_distance(p1, q1, p2[None], q2[None])[0]
        assert got <= expected + 1e-9 and got == pytest.approx(expected, abs=2e-3 * np.linalg.norm(q1 - p1) + 1e-9)
        checked += 1
    assert checked == 300


def test_a_step_past_a_triangle_shrunk_to_a_point_is_as_near_as_its_closest_approach():
    """A triangle whose corners are all in one place is that point, for a step as for a body at rest: a step
    passing it mid-way was measured from its ends only (the edges, of no length, came out too far)."""
    point_like = np.full((1, 3, 3), 2.0)
    assert segment_triangle_distance(np.array([0.0, 2.1, 2.0]), np.array([4.0, 2.1, 2.0]), point_like)[0] == \
        pytest.approx(0.1)


def test_a_short_step_through_a_small_triangle_touches_it():
    """A 5 cm step through the middle of a 10 cm triangle: the crossing test alone finds it (both ends and
    every edge are further away than zero)."""
    triangle = np.array([[[0.0, -0.05, -0.05], [0.0, 0.05, -0.05], [0.0, 0.0, 0.05]]])
    assert segment_triangle_distance(np.array([-0.025, 0.0, 0.0]), np.array([0.025, 0.0, 0.0]), triangle)[0] == 0.0


def test_touching_at_exactly_the_radius_is_no_contact(make_scene, box):
    """Contact means closer than the radius: a body whose path keeps exactly the radius away does not touch."""
    scene = make_scene(box(0, 10.25, 2, 20, 0.5, 4))  # south face at y = 10 exactly
    collider = Collider(scene.mesh, 0.5)
    assert collider.sweep((-5.0, 9.5, 2.0), (5.0, 9.5, 2.0)) is None
    assert collider.sweep((-5.0, 9.5, 2.0), (5.0, 9.5 + 2**-10, 2.0)) is not None


def test_a_rover_on_flat_ground_has_nothing_to_hit():
    """Every face is walkable: the rover's collider holds no triangle at all, and answers anywhere."""
    import trimesh

    ground = trimesh.Trimesh([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], [[0, 1, 2], [0, 2, 3]],
                             process=False)
    collider = Collider(ground, RADIUS, ignore_walkable=True)
    assert len(collider.grid.triangles) == 0
    for start, end in [((0.0, 0.0, 0.3), (1.0, 0.0, 0.3)), ((-5.0, -5.0, 0.0), (5.0, 5.0, 0.0))]:
        assert collider.sweep(start, end) is None
    assert collider.clearance(np.zeros(3)) == collider.search


def test_a_lone_triangle_in_the_first_cell_of_the_grid_is_found():
    """The grid files triangles by cell, the first cell too (the south-west-most), even with one triangle."""
    import trimesh

    triangles = np.array([[[-9.9, -9.9, 0.0], [-9.5, -9.9, 0.0], [-9.9, -9.5, 0.0]],
                          [[9.5, 9.5, 0.0], [9.9, 9.5, 0.0], [9.5, 9.9, 0.0]],
                          [[9.5, -9.5, 0.0], [9.9, -9.5, 0.0], [9.5, -9.1, 0.0]]])
    mesh = trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(9).reshape(-1, 3), process=False)
    collider = Collider(mesh, RADIUS)
    assert collider.clearance(np.array([-9.8, -9.8, 0.2])) == pytest.approx(0.2)
    assert collider.clearance(np.array([9.6, 9.6, 0.2])) == pytest.approx(0.2)
    assert collider.touches(np.array([-9.8, -9.8, 0.2]))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_triangle_with_a_repeated_corner_is_the_segment_between_its_corners(axis):
    """Two corners in one place (a degenerate face some exporters write): the segment between the corners, along
    any axis, with the edge of no length handled."""
    def along(*values):
        point = np.zeros(3)
        point[axis] = values[0]
        point[(axis + 1) % 3] = values[1]
        return point

    for corners in ([along(0, 0), along(1, 0), along(0, 0)], [along(0, 0), along(0, 0), along(3, 0)],
                    [along(3, 0), along(0, 0), along(0, 0)]):
        triangle = np.array([corners])
        assert point_triangle_distance(along(0.5, 1.0), triangle)[0] == pytest.approx(1.0)
        assert point_triangle_distance(along(-3.0, 4.0), triangle)[0] == pytest.approx(5.0)
    spread = np.array([[along(0, 0), along(3, 0), along(6, 0)]])  # three corners 3 m apart on a line
    assert point_triangle_distance(along(1.5, 1.0), spread)[0] == pytest.approx(1.0)
    assert point_triangle_distance(along(7.0, 0.0), spread)[0] == pytest.approx(1.0)


def test_a_millimetre_triangle_is_measured_as_a_face_not_as_its_edges():
    """A tiny triangle still has area: a point just over its middle is as far as its height."""
    triangle = np.array([[[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0]]])
    assert point_triangle_distance(np.array([2.5e-4, 2.5e-4, 0.01]), triangle)[0] == pytest.approx(0.01, rel=1e-9)


def test_triangles_in_single_precision_are_measured_in_double():
    rng = np.random.default_rng(5)
    triangles = rng.normal(size=(50, 3, 3)).astype(np.float32)
    point = rng.normal(size=3).astype(np.float32)
    np.testing.assert_array_equal(point_triangle_distance(point, triangles),
                                  point_triangle_distance(point.astype(np.float64), triangles.astype(np.float64)))


def test_a_triangle_without_area_is_as_near_as_its_edges():
    collinear = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]])  # a 2 m segment along x
    assert point_triangle_distance(np.array([1.5, 1.0, 0.0]), collinear)[0] == pytest.approx(1.0)
    assert point_triangle_distance(np.array([3.0, 0.0, 0.0]), collinear)[0] == pytest.approx(1.0)
    point_like = np.zeros((1, 3, 3))
    assert point_triangle_distance(np.array([0.0, 3.0, 4.0]), point_like)[0] == pytest.approx(5.0)


def test_point_triangle_distance_refuses_wrong_shapes():
    with pytest.raises(ValueError, match="triangles"):
        point_triangle_distance(np.zeros(3), np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="point"):
        point_triangle_distance(np.zeros(2), np.zeros((1, 3, 3)))


def test_touches_a_point_within_radius_of_the_wall(wall_scene):
    collider = Collider(wall_scene.mesh, RADIUS)
    assert collider.touches(np.array([0.0, WALL_FACE_Y - 0.2, 2.0]))
    assert not collider.touches(np.array([0.0, WALL_FACE_Y - 0.4, 2.0]))


def test_the_ground_is_an_obstacle_for_a_copter_but_not_for_a_rover(flat_scene):
    resting_low = np.array([0.0, 0.0, 0.2])  # sphere bottom 0.1 m below the ground's top
    assert Collider(flat_scene.mesh, RADIUS).touches(resting_low)
    assert not Collider(flat_scene.mesh, RADIUS, ignore_walkable=True).touches(resting_low)


@pytest.fixture
def ramp_scene(make_scene, box):
    """Ground and a 10 degree ramp (a tilted box) rising eastwards from x = 0; a wall across it at x = 12."""
    slope = math.radians(10)
    centre_x = 8.0
    centre_z = centre_x * math.tan(slope) - 0.5 / math.cos(slope)  # top surface at z = 0 at x = 0
    return make_scene(
        box(0, 0, -0.05, 100, 100, 0.1),
        box(centre_x, 0, centre_z, 20, 6, 1, rotation=f"0 1 0 {-slope}"),
        box(12, 0, 4, 0.3, 6, 6),
    )


def test_a_rover_driving_up_a_tilted_box_is_not_colliding(ramp_scene):
    world = Simulation(ramp_scene, Kind.ROVER, start=(-5.0, 0.0), heading=90.0)
    world.autopilot.arm()
    world.autopilot.set_mode("GUIDED")
    world.autopilot.goto(9.0, 0.0)
    world.run_for(20.0)
    assert world.collision is None
    assert world.pose.x == pytest.approx(9.0, abs=0.2)
    assert world.pose.z > 1.5  # up on the ramp, 9 m * tan(10 deg) = 1.59 m
    assert world.pose.pitch == pytest.approx(math.radians(10), abs=0.01)


def test_a_rover_on_a_slope_collides_with_a_wall(ramp_scene):
    world = Simulation(ramp_scene, Kind.ROVER, start=(-5.0, 0.0), heading=90.0, sensors=REAR_ONLY)
    world.autopilot.arm()
    world.autopilot.set_mode("GUIDED")
    world.autopilot.goto(20.0, 0.0)
    world.run_for(30.0)
    assert world.collision is not None
    assert world.collision.point[0] == pytest.approx(12 - 0.15 - RADIUS, abs=0.05)


def test_world_refuses_a_start_overlapping_a_wall(wall_scene):
    with pytest.raises(PlacementError, match="inside an obstacle"):
        Simulation(wall_scene, Kind.COPTER, start=(0.0, WALL_FACE_Y - 0.1))


def test_world_refuses_a_rover_start_overlapping_a_box(make_scene, box):
    scene = make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(0.2, 0, 1, 0.2, 4, 2))
    with pytest.raises(PlacementError):
        Simulation(scene, Kind.ROVER, start=(0.0, 0.0))


@pytest.mark.parametrize("start", [(1e9, 0.0), (0.0, -100_001.0), (0.0, 0.0, 1e6), (math.nan, 0.0)])
def test_world_refuses_a_start_far_from_the_scene(wall_scene, start):
    """A scene is local metres: a start a million kilometres out made a vehicle whose telemetry overflowed
    MAVLink's integer positions (a struct.error traceback from ``vehicle sim --start 1e9,0``)."""
    with pytest.raises(PlacementError, match="more than 100 km from the scene's origin"):
        Simulation(wall_scene, Kind.COPTER, start=start)
    Simulation(wall_scene, Kind.COPTER, start=(-99_000.0, 99_000.0))  # far, and still a place


def test_world_accepts_a_start_just_clear_of_a_wall(wall_scene):
    Simulation(wall_scene, Kind.COPTER, start=(0.0, WALL_FACE_Y - RADIUS - 0.05))


@pytest.fixture
def roofed_room(make_scene, box):
    """Ground, and a 6 x 6 m room around the origin: walls 3 m high, a floor slab 0.2 m thick and a roof on top."""
    return make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(0, 0, 0.1, 6, 6, 0.2), box(0, 0, 3.05, 6.4, 6.4, 0.1),
                      box(3.1, 0, 1.5, 0.2, 6, 3), box(-3.1, 0, 1.5, 0.2, 6, 3), box(0, 3.1, 1.5, 6, 0.2, 3),
                      box(0, -3.1, 1.5, 6, 0.2, 3))


def test_a_start_height_stands_the_vehicle_on_the_floor_below_it_not_on_the_roof(roofed_room):
    inside = Simulation(roofed_room, Kind.COPTER, start=(0.0, 0.0, 1.7))
    assert inside.home[2] == pytest.approx(0.2)  # the floor's top
    assert inside.pose.z == pytest.approx(0.2 + RADIUS + inside.limits.ground_clearance)
    above = Simulation(roofed_room, Kind.COPTER, start=(0.0, 0.0))  # without a height: the highest surface
    assert above.home[2] == pytest.approx(3.1)


def test_the_start_viewpoints_height_counts_as_the_start_height(make_scene, box):
    room = make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(0, 0, 3.05, 6.4, 6.4, 0.1),
                      'DEF Start Viewpoint { position 1 1 1.7 orientation 1 0 0 1.5708 }\n')
    world = Simulation(room, Kind.ROVER)
    assert (world.home[0], world.home[1]) == pytest.approx((1.0, 1.0))
    assert world.home[2] == pytest.approx(0.0, abs=1e-4)  # under the roof, on the ground


def test_a_start_on_the_top_of_a_wall_is_refused_and_one_beside_it_on_the_roof_is_not(roofed_room, make_scene, box):
    """A random team start once stood a copter on a house's wall, 0.2 m thick: it flew, and landed back
    onto the wall's edge. The roof is wide enough to stand on."""
    with pytest.raises(PlacementError, match=r"stands on an edge: the ground 0.3 m from it lies at 0.00 m"):
        Simulation(make_scene(box(0, 0, -0.05, 100, 100, 0.1), box(3.1, 0, 1.5, 0.2, 6, 3)), Kind.COPTER,
                   start=(3.1, 0.0))
    assert Simulation(roofed_room, Kind.COPTER, start=(0.0, 0.0)).home[2] == pytest.approx(3.1)


def test_a_start_height_with_nothing_below_it_is_refused(roofed_room):
    with pytest.raises(PlacementError, match="nothing to stand on below the start"):
        Simulation(roofed_room, Kind.COPTER, start=(20.0, 20.0, -5.0))


def fly_into_the_wall(wall_scene) -> Simulation:
    world = Simulation(wall_scene, Kind.COPTER, start=(0.0, 0.0), sensors=REAR_ONLY)
    world.autopilot.arm()
    world.autopilot.takeoff(4.0)
    world.run_for(8.0)
    world.autopilot.goto(0.0, 20.0)
    world.run_for(30.0)
    return world


def test_a_collision_ends_the_run(wall_scene):
    world = fly_into_the_wall(wall_scene)
    assert world.collision is not None
    assert world.pose.y == pytest.approx(WALL_FACE_Y - RADIUS, abs=0.02)
    assert world.body.speed == 0.0
    assert not world.autopilot.armed


def test_nothing_moves_after_a_collision(wall_scene):
    world = fly_into_the_wall(wall_scene)
    pose, steps, contact = world.pose.xyz(), world.steps, world.collision
    assert world.autopilot.goto(0.0, -20.0) != 0  # disarmed: GUIDED commands are refused
    for _ in range(50):
        assert world.step() == []
    assert world.pose.xyz() == pose
    assert world.steps == steps + 50  # the wreck lies still while the clock goes on
    assert world.collision is contact


@pytest.mark.parametrize("force", [False, True])
def test_a_wreck_refuses_to_arm_and_says_why(wall_scene, force):
    """An operator's Continue after a crash armed the wreck, and the agent flew its mission on in a body that
    lay still."""
    world = fly_into_the_wall(wall_scene)
    assert world.autopilot.arm(force=force) != 0
    assert not world.autopilot.armed
    told = [(event.text, event.severity) for event in world.autopilot.events if event.kind == "text"]
    assert ("Arm: vehicle crashed", mav.MAV_SEVERITY_CRITICAL) in told


def test_stepping_towards_a_wall_finds_contact_at_wall_minus_radius_despite_the_clear_zone_shortcut(wall_scene):
    """Steps of a simulation: after an exact check the body skips checks inside the ball known to be clear.
    That ball must leave room for the body's radius, or contact is found late (at 9.85 m, not 9.60 m)."""
    collider = Collider(wall_scene.mesh, RADIUS)
    step = 0.05
    contact, y, skipped = None, 0.0, 0
    while contact is None:
        assert y < WALL_FACE_Y, "walked through the wall"
        skipped += collider._anchor is not None  # the next step may be answered from the clear ball
        contact = collider.sweep((0.0, y, 4.0), (0.0, y + step, 4.0))
        y += step
    assert skipped > 100  # the shortcut was in use all along the way
    assert contact.point[1] == pytest.approx(WALL_FACE_Y - RADIUS, abs=1e-3)
