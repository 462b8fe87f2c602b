"""The project's own scenes (scenes/*.wrl) load cleanly and are laid out as scenes/README.md says."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from vehicle.world.floor import reachable_floor
from vehicle.world.scene import Scene, load_scene

SCENES = Path(__file__).resolve().parent.parent / "scenes"

# name: expected Shape instances, triangle range, bounds (lo, hi) with tolerance, start, clear radius
EXPECTED = {
    "default": dict(
        objects=26,
        triangles=(300, 20_000),
        bounds=((-60, -60, 0), (60, 60, 12)),
        start=(0.0, 0.0),
        clear=3.0,
    ),
    "apartment": dict(
        objects=53,
        triangles=(200, 5_000),
        bounds=((-9, -6, 0), (9, 6, 2.6)),
        start=(-4.8, -3.0),
        clear=2.0,
    ),
    "house": dict(
        objects=32,
        triangles=(200, 5_000),
        bounds=((-8, -6, 0), (8, 6, 2.6)),
        start=(-3.0, -1.5),
        clear=1.5,
    ),
    "trees": dict(
        objects=65,  # the terrain and 32 trees of a trunk and a crown each
        triangles=(3_300, 200_000),
        bounds=None,  # checked in test_trees_*
        start=(0.0, 0.0),
        clear=3.0,
    ),
}
DEFAULT_COLOR = (204, 204, 204)  # VRML's diffuseColor when a Shape has no Material


_cache: dict[str, Scene] = {}


def _load(name: str) -> Scene:
    if name not in _cache:
        _cache[name] = load_scene(SCENES / f"{name}.wrl")
    return _cache[name]


@pytest.fixture(params=sorted(EXPECTED))
def scene(request) -> tuple[str, Scene]:
    return request.param, _load(request.param)


def _ground_z(mesh: trimesh.Trimesh, xy: np.ndarray) -> np.ndarray:
    """Height of the highest surface under each (x, y): a vertical ray from above; NaN where none."""
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    top = mesh.bounds[1, 2] + 10.0
    origins = np.column_stack((xy, np.full(len(xy), top)))
    directions = np.tile((0.0, 0.0, -1.0), (len(xy), 1))
    locations, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    z = np.full(len(xy), np.nan)
    z[rays] = locations[:, 2]
    return z


def _horizontal_distance(triangles: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Distance in the x-y plane from `point` to each triangle's projection (0 when it covers it)."""
    a, b, c = (triangles[:, k, :2] for k in range(3))
    p = np.asarray(point, dtype=float)[:2]

    def cross(u, v):
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

    def to_segment(s, e):
        se, sp = e - s, p - s
        t = np.clip(np.einsum("ij,ij->i", sp, se) / np.maximum(np.einsum("ij,ij->i", se, se), 1e-12), 0, 1)
        return np.linalg.norm(s + se * t[:, None] - p, axis=1)

    edges = np.minimum(np.minimum(to_segment(a, b), to_segment(b, c)), to_segment(c, a))
    s1, s2, s3 = cross(b - a, p - a), cross(c - b, p - b), cross(a - c, p - c)
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    inside &= np.abs(cross(b - a, c - a)) > 1e-12
    return np.where(inside, 0.0, edges)


def _reachable_labels(s: Scene, height: float, radius: float, res: float = 0.02):
    """label_at(x, y): the connected part of the floor where a body of ``radius`` fits at ``height``."""
    return reachable_floor(s, height, radius, res).label_at


# --- every scene -------------------------------------------------------------------------------------


def test_loads_without_warnings(scene):
    name, s = scene
    assert s.warnings == []
    assert s.objects == EXPECTED[name]["objects"]
    lo, hi = EXPECTED[name]["triangles"]
    assert lo <= len(s.mesh.faces) <= hi
    assert len(s.face_colors) == len(s.mesh.faces)
    assert np.isfinite(s.mesh.vertices).all()


def test_every_shape_has_its_own_colour(scene):
    name, s = scene
    rgb = s.face_colors[:, :3]
    assert not np.all(rgb == DEFAULT_COLOR, axis=1).any(), "a Shape without a Material diffuseColor"
    assert len(np.unique(rgb, axis=0)) >= 5


def test_bounds(scene):
    name, s = scene
    expected = EXPECTED[name]["bounds"]
    if expected is not None:
        np.testing.assert_allclose(s.bounds, np.array(expected, dtype=float), atol=0.01)


def test_start_and_heading(scene):
    name, s = scene
    assert s.start[:2] == pytest.approx(EXPECTED[name]["start"])
    assert s.start_heading == pytest.approx(0.0, abs=0.01)  # looking north


def test_start_ground_is_flat(scene):
    """The ground under the start and 2 m around it is level: nothing overhead, no slope."""
    name, s = scene
    x, y, _ = s.start
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.column_stack((x + 2 * np.cos(angles), y + 2 * np.sin(angles)))
    z = _ground_z(s.mesh, np.vstack(([x, y], ring)))
    assert np.isfinite(z).all()
    assert np.ptp(z) < 0.05
    if name in ("default", "house", "apartment"):
        assert abs(z[0]) < 0.01


def test_start_in_clear_space(scene):
    """No triangle between 0.2 m and 6 m above the start's ground within the clear radius."""
    name, s = scene
    x, y, _ = s.start
    g = _ground_z(s.mesh, [x, y])[0]
    tris = s.mesh.triangles
    zmin, zmax = tris[:, :, 2].min(axis=1), tris[:, :, 2].max(axis=1)
    band = (zmax > g + 0.2) & (zmin < g + 6.0)
    d = _horizontal_distance(tris[band], (x, y))
    assert d.min() >= EXPECTED[name]["clear"], f"an obstacle {d.min():.2f} m from the start"


# --- default ---------------------------------------------------------------------------------------


def test_default_objects_around_the_start():
    """Something stands 5-25 m from the start in most directions, and the ground covers 120 x 120 m."""
    s = _load("default")
    x, y, _ = s.start
    seen = 0
    for bearing in range(0, 360, 30):
        b = np.radians(bearing)
        d = np.array([np.sin(b), np.cos(b), 0.0])
        found = False
        for offset in (-1.0, 0.0, 1.0):  # three parallel rays: a poor man's beam
            o = np.array([x, y, 1.7]) + offset * np.array([d[1], -d[0], 0.0])
            hits, _, _ = s.mesh.ray.intersects_location([o], [d])
            dist = np.linalg.norm(hits[:, :2] - o[:2], axis=1) if len(hits) else np.array([])
            found |= bool(((dist > 5) & (dist < 25)).any())
        seen += found
    assert seen >= 8, f"only {seen} of 12 directions see an object within 25 m"
    assert _ground_z(s.mesh, [(-59, -59), (59, 59), (-59, 59), (59, -59)]) == pytest.approx(0.0, abs=0.01)


# --- house -----------------------------------------------------------------------------------------


def test_house_every_room_reachable_at_flight_height():
    """At 1.2 m a 0.3 m copter gets from the start through the doorways into all five rooms."""
    s = _load("house")
    label_at = _reachable_labels(s, 1.2, 0.3, res=0.05)

    start = label_at(*s.start[:2])
    assert start != 0
    assert label_at(-8.4, -6.4) != start, "the house is closed"
    rooms = {"kitchen": (5, -2), "bedroom 1": (-5.5, 3), "bedroom 2": (0, 3), "bathroom": (6, 3)}
    for room, (x, y) in rooms.items():
        assert label_at(x, y) == start, f"{room} not reachable from the start"


# --- apartment -------------------------------------------------------------------------------------

APARTMENT_ALTITUDE = 1.6  # the scene's WorldInfo suggests it
APARTMENT_ROOMS = {  # the spots in clear space its header names, one per room
    "living room": (-4.8, -3.0), "kitchen": (1.8, -2.6), "bedroom 1": (-5.8, 2.9), "bedroom 2": (-1.0, 2.9),
    "study": (3.2, 3.3), "corridor": (0.0, 0.25),
}
BATHROOM, STOREROOM = (7.0, -2.5), (7.5, 4.0)


def _corridor_hit(s: Scene, origin: tuple[float, float], direction: tuple[float, float]) -> float:
    """How far a horizontal ray at flight height from ``origin`` goes before it meets the scene."""
    o = np.array([[*origin, APARTMENT_ALTITUDE]])
    hits, _, _ = s.mesh.ray.intersects_location(o, np.array([[*direction, 0.0]]))
    return float(np.linalg.norm(hits[:, :2] - o[0, :2], axis=1).min())


def test_apartment_corridor_runs_the_whole_width_between_its_walls():
    """Along its middle the corridor is clear from the west wall to the east wall; across it, 1.38 m between
    the walls, except at a doorway, where the ray goes on into the room."""
    s = _load("apartment")
    assert _corridor_hit(s, (-8.7, 0.25), (1, 0)) == pytest.approx(17.5, abs=0.01)  # inner faces at x = +-8.8
    for x in (-8.0, -3.0, 0.5, 4.5, 8.0):  # on wall between the doorways
        assert _corridor_hit(s, (x, 0.25), (0, 1)) + _corridor_hit(s, (x, 0.25), (0, -1)) == pytest.approx(1.38)
    doorways = {(-6.0, 1): 4.8, (-1.5, 1): 4.8, (3.25, 1): 0.5, (-4.0, -1): 5.0, (2.5, -1): 5.0, (7.0, -1): 3.0}
    for (x, north_or_south), beyond in doorways.items():  # a ray through the doorway reaches well into the room
        assert _corridor_hit(s, (x, 0.25), (0, north_or_south)) > beyond, f"doorway at x = {x} closed"


def test_apartment_rooms_are_reached_through_doorways_of_0_9_to_1_2_m():
    """A body 0.84 m across (radius 0.42) gets from the start into every room but two: the bathroom, whose
    doorway is 0.8 m, and the storeroom, which has none. The default copter's body with its doorway clearance
    (radius 0.35) fits the bathroom's doorway too."""
    s = _load("apartment")
    wide = _reachable_labels(s, APARTMENT_ALTITUDE, 0.42)
    start = wide(*s.start[:2])
    assert start != 0
    for room, spot in APARTMENT_ROOMS.items():
        assert wide(*spot) == start, f"{room} not reachable through a 0.9 m doorway"
    assert wide(*BATHROOM) not in (0, start), "the bathroom's doorway is wider than 0.84 m"
    narrow = _reachable_labels(s, APARTMENT_ALTITUDE, 0.35)
    assert narrow(*BATHROOM) == narrow(*s.start[:2]) != 0, "the bathroom's doorway is narrower than 0.7 m"


def test_apartment_storeroom_is_closed_and_the_flat_too():
    """Not even a point gets into the storeroom from the start, nor out of the flat: no gap at flight height."""
    s = _load("apartment")
    point = _reachable_labels(s, APARTMENT_ALTITUDE, 0.0)
    start = point(*s.start[:2])
    assert point(*STOREROOM) not in (0, start), "the storeroom has a way in"
    assert point(-9.4, -6.4) != start, "the flat is open to the outside"


def test_apartment_waypoints_are_in_reachable_rooms():
    """The WorldInfo's Pathfind route (kitchen, bathroom, study, bedroom 2, bedroom 1, living room) is all on
    floor the default copter reaches, each point 1 m or more from anything at flight height."""
    s = _load("apartment")
    route = [tuple(float(v) for v in p.split(",")) for p in s.hints["waypoints"].split(";")]
    assert len(route) == 6 and route[1] == BATHROOM
    clear = _reachable_labels(s, APARTMENT_ALTITUDE, 1.0)
    narrow = _reachable_labels(s, APARTMENT_ALTITUDE, 0.35)
    for x, y in route:
        assert clear(x, y) != 0 and narrow(x, y) == narrow(*s.start[:2])
    assert s.hints["altitude"] == str(APARTMENT_ALTITUDE)


def test_apartment_known_share_of_the_reachable_floor():
    """The coverage measure: nothing known is 0, everything known is 1, the living room alone about a quarter
    (its floor where the body fits, less its tall furniture, of the whole flat's but the storeroom), and
    knowing the storeroom or the outside adds nothing."""
    from vehicle.mapping.memory_map import MemoryMap

    s = _load("apartment")
    floor = reachable_floor(s, APARTMENT_ALTITUDE, 0.35)
    start = tuple(s.start[:2])
    memory = MemoryMap(start, space_size=15, resolution=10)
    assert floor.known_share(memory, start) == 0.0

    def mark(x0, x1, y0, y1):
        (r0, c0), (r1, c1) = memory.cell_of(x0, y0), memory.cell_of(x1, y1)
        memory.grid[r0:r1 + 1, c0:c1 + 1] = -3

    mark(5.5, 9.0, 1.0, 6.0)  # the storeroom
    mark(-19.0, -9.0, -15.0, 10.0)  # outside, west of the flat
    assert floor.known_share(memory, start) == 0.0
    mark(-9.0, -1.0, -6.0, -0.5)  # the living room
    assert 0.2 < floor.known_share(memory, start) < 0.3
    memory.grid[:] = 5
    assert floor.known_share(memory, start) == 1.0
    assert floor.known_share(memory, STOREROOM) == 1.0  # from inside the storeroom, its own floor
    assert floor.known_share(memory, (-8.7, -5.7)) == 0.0  # where the body does not fit


# --- trees -----------------------------------------------------------------------------------------


def _trees_parts(s: Scene):
    """The terrain (the Shape spanning the scene) and, per other Shape, its faces."""
    objects = [np.flatnonzero(s.face_object == k) for k in range(s.objects)]
    spans = [np.ptp(s.mesh.vertices[s.mesh.faces[f]].reshape(-1, 3)[:, :2], axis=0).min() for f in objects]
    terrain = int(np.argmax(spans))
    ground = trimesh.Trimesh(s.mesh.vertices, s.mesh.faces[objects[terrain]], process=False)
    others = [f for k, f in enumerate(objects) if k != terrain]
    return ground, others


def test_trees_uneven_ground():
    s = _load("trees")
    ground, _ = _trees_parts(s)
    lo, hi = ground.bounds
    assert lo[:2] == pytest.approx((-40, -40)) and hi[:2] == pytest.approx((40, 40))
    xs = np.linspace(-39, 39, 40)
    grid = np.array(np.meshgrid(xs, xs)).reshape(2, -1).T
    z = _ground_z(ground, grid)
    assert np.isfinite(z).all()
    assert np.ptp(z) >= 1.5
    assert 0.0 <= z.min() and z.max() <= 3.0
    assert 9.0 <= s.bounds[1, 2] <= 14.0


def test_trees_trunks_stand_on_the_ground_and_crowns_clear_it():
    s = _load("trees")
    ground, parts = _trees_parts(s)
    trunks = crowns = 0
    for faces in parts:
        v = s.mesh.vertices[np.unique(s.mesh.faces[faces])]
        width = np.ptp(v[:, :2], axis=0).max()
        height = np.ptp(v[:, 2])
        if width < 1.0:  # a trunk: thin and tall, its foot just below the ground
            trunks += 1
            assert 3.0 <= height <= 6.5
            assert 0.4 <= width <= 0.8
            g = _ground_z(ground, v[:, :2].mean(axis=0))[0]
            assert g - 0.5 < v[:, 2].min() < g, "trunk foot not just below the ground"
        else:  # a crown: its every point at least 2.5 m above the ground below it
            crowns += 1
            assert 3.0 <= width <= 6.0
            clearance = v[:, 2] - _ground_z(ground, v[:, :2])
            assert clearance.min() >= 2.5
    assert trunks == crowns == 32


def test_a_scene_built_for_a_run_still_pickles_and_shares_its_preparation():
    """A scene's BVH and collision grid are built once for every run in it, and left behind when the
    scene goes to a worker process (an Embree scene does not pickle)."""
    import pickle

    from vehicle.sim.simulation import Simulation

    s = _load("house")
    first, second = Simulation(s), Simulation(s)
    assert first.caster is second.caster and first.collider.grid is second.collider.grid
    copy = pickle.loads(pickle.dumps(s))
    assert len(copy.mesh.faces) == len(s.mesh.faces)
    assert Simulation(copy).caster is not first.caster
