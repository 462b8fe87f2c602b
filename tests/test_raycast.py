"""First-hit ray casting (vehicle.raycast): the Embree and numpy backends agree; misses; ground height."""

import math

import numpy as np
import pytest

from vehicle.world.collision import point_triangle_distance
from vehicle.world.raycast import RayCaster, embree_available
from vehicle.world.scene import load_scene

needs_embree = pytest.mark.skipif(not embree_available(), reason="needs embreex (x86_64 wheels only)")


def random_rays(bounds: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins spread over the scene's bounding box, directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    lo, hi = bounds
    origins = rng.uniform(lo, hi, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    return origins, directions


def assert_backends_agree(mesh, origins, directions) -> int:
    embree = RayCaster(mesh, "embree")
    numpy_ = RayCaster(mesh, "numpy")
    d_e, f_e = embree.cast(origins, directions)
    d_n, f_n = numpy_.cast(origins, directions)
    np.testing.assert_array_equal(np.isfinite(d_e), np.isfinite(d_n))
    hit = np.isfinite(d_e)
    np.testing.assert_allclose(d_e[hit], d_n[hit], atol=1e-3, rtol=0)
    # a ray through an edge shared by two triangles may name either: both must hold the hit point
    for i in np.flatnonzero(f_e != f_n):
        point = origins[i] + directions[i] * d_n[i]
        both = mesh.triangles[[f_e[i], f_n[i]]]
        assert point_triangle_distance(point, both).max() < 1e-4, f"ray {i}: faces {f_e[i]} != {f_n[i]}"
    assert np.mean(f_e == f_n) > 0.99
    return int(hit.sum())


@pytest.fixture
def yard(make_scene, box):
    """Ground, a 2 m cube, a thin wall and a roof on four posts."""
    return make_scene(
        box(0, 0, -0.05, 40, 40, 0.1),
        box(5, 5, 1, 2, 2, 2),
        box(-6, 0, 1.5, 0.2, 8, 3),
        box(0, -8, 3, 4, 4, 0.2),  # roof: top at z = 3.1 over -2..2 x -10..-6
        *(box(x, y, 1.45, 0.2, 0.2, 2.9) for x in (-1.9, 1.9) for y in (-9.9, -6.1)),
    )


@needs_embree
def test_backends_agree_on_a_small_parsed_scene(yard):
    origins, directions = random_rays(yard.mesh.bounds + [[-2, -2, 0], [2, 2, 3]], 2000, seed=1)
    assert assert_backends_agree(yard.mesh, origins, directions) > 500


@needs_embree
def test_backends_agree_on_the_castle(castle_path):
    mesh = load_scene(castle_path).mesh
    origins, directions = random_rays(mesh.bounds, 3000, seed=2)
    assert assert_backends_agree(mesh, origins, directions) > 500


@needs_embree
def test_cast_from_one_origin_matches_cast_on_both_backends(yard):
    _, directions = random_rays(yard.mesh.bounds, 500, seed=3)
    origin = np.array([0.5, 0.5, 1.5])
    reference = RayCaster(yard.mesh, "numpy").cast(np.tile(origin, (500, 1)), directions)
    for backend in ("embree", "numpy"):
        distance, face = RayCaster(yard.mesh, backend).cast_from(origin, directions)
        np.testing.assert_allclose(distance, reference[0], atol=1e-3, rtol=0)
        np.testing.assert_array_equal(face, reference[1])


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_known_wall_distance_and_face(backend, yard):
    if backend == "embree" and not embree_available():
        pytest.skip("needs embreex")
    caster = RayCaster(yard.mesh, backend)
    distance, face = caster.cast(np.array([[0.0, 0.0, 1.0]]), np.array([[-1.0, 0.0, 0.0]]))
    assert distance[0] == pytest.approx(5.9, abs=1e-4)  # east face of the wall at x = -5.9
    assert caster.face_normals[face[0]] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_misses_are_inf_and_minus_one(backend, yard):
    if backend == "embree" and not embree_available():
        pytest.skip("needs embreex")
    caster = RayCaster(yard.mesh, backend)
    origins = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [100.0, 100.0, 1.0]])
    directions = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    distance, face = caster.cast(origins, directions)
    assert math.isinf(distance[0]) and face[0] == -1  # up into the open sky
    assert np.isfinite(distance[1]) and face[1] >= 0
    assert math.isinf(distance[2]) and face[2] == -1  # outside the ground's extent
    assert face.dtype.kind == "i"


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_an_empty_scene_misses_everything(backend, make_scene):
    if backend == "embree" and not embree_available():
        pytest.skip("needs embreex")
    caster = RayCaster(make_scene().mesh, backend)
    distance, face = caster.cast(np.zeros((3, 3)), np.tile([0.0, 0.0, -1.0], (3, 1)))
    assert np.all(np.isinf(distance)) and np.all(face == -1)
    assert caster.ground_height(1.0, 2.0, default=-7.0) == -7.0


def test_no_rays_give_empty_results(yard):
    distance, face = RayCaster(yard.mesh).cast(np.zeros((0, 3)), np.zeros((0, 3)))
    assert distance.shape == (0,) and face.shape == (0,)


def test_unknown_backend_is_refused(yard):
    with pytest.raises(ValueError, match="backend"):
        RayCaster(yard.mesh, "optix")


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_ground_height_is_the_roof_under_a_roof_and_the_ground_in_the_open(backend, yard):
    if backend == "embree" and not embree_available():
        pytest.skip("needs embreex")
    caster = RayCaster(yard.mesh, backend)
    assert caster.ground_height(0.0, -8.0) == pytest.approx(3.1, abs=1e-4)
    assert caster.ground_height(0.0, 3.0) == pytest.approx(0.0, abs=1e-4)
    assert caster.ground_height(5.0, 5.0) == pytest.approx(2.0, abs=1e-4)  # on top of the cube
    assert caster.ground_height(500.0, 0.0, default=-1.5) == -1.5  # beyond the scene
