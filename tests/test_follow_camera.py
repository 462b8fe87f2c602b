"""The follow camera keeps the vehicle in sight: a wall between it and the vehicle pulls it in front of the wall."""

from types import SimpleNamespace

import numpy as np
import trimesh

from groundstation import camera
from groundstation.viewport import WALL_MARGIN, clear_eye
from groundstation.viz import SceneView
from vehicle.world.raycast import RayCaster


def ground_point_over(mesh):
    """The 3D view's own ray cast (scene first, then the plane z = 0) over ``mesh``."""
    view = SimpleNamespace(caster=RayCaster(mesh) if mesh is not None else None)
    return lambda origin, direction: SceneView.ground_point(view, origin, direction)


def test_a_wall_between_vehicle_and_eye_pulls_the_eye_in_front_of_it():
    vehicle = np.array([0.0, 0.0, 1.0])
    eye, _ = camera.follow(vehicle, 0.0, 8.0)
    middle = (vehicle + eye) / 2
    back = (eye - vehicle)[:2] / np.linalg.norm((eye - vehicle)[:2])  # behind the vehicle, across the ground
    wall = trimesh.creation.box(extents=(0.4, 20.0, 20.0))  # 0.4 m thick across x, turned to face the vehicle
    wall.apply_transform(trimesh.transformations.rotation_matrix(np.arctan2(back[1], back[0]), (0, 0, 1)))
    wall.apply_translation((middle[0], middle[1], 5.0))
    pulled = clear_eye(vehicle, eye, ground_point_over(wall))
    wall_near = float(np.dot((middle - vehicle)[:2], back)) - 0.2  # the wall's face towards the vehicle
    along = np.linalg.norm(pulled - vehicle)
    assert along < np.linalg.norm(eye - vehicle) / 2  # in front of the wall, not behind it
    assert float(np.dot((pulled - vehicle)[:2], back)) <= wall_near - WALL_MARGIN * 0.5
    # on the same line from the vehicle to the wanted eye: the same view, only nearer
    direction = (eye - vehicle) / np.linalg.norm(eye - vehicle)
    assert np.allclose((pulled - vehicle) / along, direction)
    assert pulled[2] > 0.0


def test_an_open_view_keeps_the_wanted_eye_and_the_ground_is_never_crossed():
    vehicle = np.array([0.0, 0.0, 1.0])
    eye, _ = camera.follow(vehicle, 0.0, 8.0)
    assert np.allclose(clear_eye(vehicle, eye, ground_point_over(None)), eye)
    below = vehicle + np.array([-6.0, 0.0, -3.0])  # a wanted eye under the ground
    pulled = clear_eye(vehicle, below, ground_point_over(None))
    assert 0.0 <= pulled[2] < vehicle[2]
