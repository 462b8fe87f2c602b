"""The orbit camera keeps a vehicle in sight that flies out of it (off the edge, under the page's 2D map) while
the viewer leaves the camera alone, sliding across the ground with its angle kept; a viewer who turned the
camera away is not followed back (groundstation/camera.py, groundstation/viewport.py)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from groundstation import camera
from groundstation.viewport import PAN_SECONDS, Vehicle, Viewport
from groundstation.views import ViewSettings

FOV, ASPECT = math.radians(50), 1.6
SCENE = (np.array([-20.0, -20.0, 0.0]), np.array([20.0, 20.0, 8.0]))


class Camera:
    """viser's camera as the viewport uses it: setting the eye slides the look-at with it, the orientation
    follows (OpenCV's axes: +x right, +y down, +z ahead)."""

    def __init__(self, eye, look):
        self.fov, self.aspect, self.up_direction = FOV, ASPECT, (0.0, 0.0, 1.0)
        self._eye, self._look = np.asarray(eye, float), np.asarray(look, float)

    @property
    def position(self):
        return self._eye

    @position.setter
    def position(self, eye):
        eye = np.asarray(eye, float)
        self._look, self._eye = self._look + (eye - self._eye), eye

    @property
    def look_at(self):
        return self._look

    @look_at.setter
    def look_at(self, look):
        self._look = np.asarray(look, float)

    @property
    def wxyz(self):
        ahead = (self._look - self._eye) / np.linalg.norm(self._look - self._eye)
        right = np.cross(ahead, (0.0, 0.0, 1.0))
        right /= np.linalg.norm(right)
        x, y, z, w = Rotation.from_matrix(np.column_stack([right, np.cross(ahead, right), ahead])).as_quat()
        return np.array([w, x, y, z])


def viewport(covered=None) -> tuple[Viewport, Camera]:
    cam = Camera(*camera.fit(*SCENE, fov=FOV, aspect=ASPECT))
    frame = SimpleNamespace(visible=True)
    client = SimpleNamespace(camera=cam, scene=SimpleNamespace(add_frame=lambda *a, **k: frame))
    port = Viewport(client)
    port.apply(ViewSettings(covered=covered, version=1), lambda x, y: 0.0)
    return port, cam


def spot(cam: Camera, at) -> tuple[float, float] | None:
    return camera.project(cam.wxyz, cam.position, FOV, ASPECT, at)


def fly(port: Viewport, at, seconds: float) -> None:
    for _ in range(round(seconds / 0.05)):
        port.move_camera([Vehicle(1, np.asarray(at, float), 0.0, 0.0, (255, 255, 255))], None, [], 0.05, SCENE,
                         lambda origin, direction: None)


def test_project_is_the_inverse_of_ray():
    cam = Camera((-10.0, -12.0, 9.0), (2.0, 1.0, 0.0))
    for x, y in ((0.0, 0.0), (0.5, -0.3), (-0.8, 0.7)):
        direction = camera.ray(cam.wxyz, FOV, ASPECT, x, y)
        assert np.allclose(spot(cam, cam.position + direction * 7.0), (x, y), atol=1e-9)
    assert spot(cam, cam.position - (cam.look_at - cam.position)) is None  # behind the camera


def test_a_vehicle_that_flies_off_the_edge_is_slid_back_into_the_middle():
    port, cam = viewport()
    fly(port, (0.0, 0.0, 4.0), 0.5)
    angle = cam.wxyz.copy()
    away = (100.0, -80.0, 4.0)
    assert not camera.in_sight(spot(cam, away), None)  # off the right edge
    fly(port, away, 0.05)
    assert port.pan is not None  # the slide begins
    fly(port, away, PAN_SECONDS + 0.2)
    assert np.allclose(spot(cam, away), (0.0, 0.0), atol=0.02)
    assert np.allclose(cam.wxyz, angle) or np.allclose(cam.wxyz, -angle)  # slid, not turned


def test_a_vehicle_under_the_2d_map_is_slid_out_from_under_it():
    covered = (-1.0, -1.0, -0.2, 0.1)  # the map over the lower left of the view
    port, cam = viewport(covered)
    fly(port, (0.0, 0.0, 4.0), 0.5)
    under = cam.position + camera.ray(cam.wxyz, FOV, ASPECT, -0.6, -0.5) * 20.0
    under[2] = 4.0
    assert not camera.in_sight(spot(cam, under), covered)
    fly(port, under, PAN_SECONDS + 0.3)
    seen = spot(cam, under)
    assert camera.in_sight(seen, covered) and np.allclose(seen, camera.open_middle(covered), atol=0.02), seen
    assert camera.open_middle(covered)[0] > -0.2 and camera.open_middle(covered)[1] > 0.1


@pytest.mark.parametrize("moved_by_viewer", [True, False])
def test_a_viewer_who_turned_away_is_not_followed_back(moved_by_viewer):
    port, cam = viewport()
    fly(port, (0.0, 0.0, 4.0), 0.5)
    if moved_by_viewer:  # the viewer drags the view east: the vehicle leaves it on the left
        cam.position = cam.position + np.array([80.0, 0.0, 0.0])
        fly(port, (0.0, 0.0, 4.0), 2.0)
        assert not camera.in_sight(spot(cam, (0.0, 0.0, 4.0)), None)  # left where the viewer looks
    else:  # the same change of view made by the vehicle flying west: the camera goes after it
        fly(port, (-80.0, 0.0, 4.0), 2.0)
        assert camera.in_sight(spot(cam, (-80.0, 0.0, 4.0)), None)
