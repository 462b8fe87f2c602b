"""The camera geometry of each 3D-view mode (groundstation/camera.py), without viser or a browser."""

from __future__ import annotations

import math

import numpy as np
import pytest
from viser import transforms

from groundstation import camera


def look(eye, target) -> np.ndarray:
    """wxyz of a camera at ``eye`` looking at ``target`` with +z up, built as viser builds it (OpenCV axes:
    +z ahead, +x right, -y up)."""
    ahead = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    ahead /= np.linalg.norm(ahead)
    right = np.cross(ahead, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(ahead, right)
    return transforms.SO3.from_matrix(np.stack([right, down, ahead], axis=1)).wxyz


@pytest.mark.parametrize("heading", [0.0, math.pi / 2, 2.5, -1.0])
def test_follow_is_behind_and_above_looking_past_the_vehicle(heading):
    vehicle = np.array([3.0, -2.0, 4.0])
    eye, target = camera.follow(vehicle, heading, 10.0)
    ahead = camera.forward(heading)
    assert np.dot(vehicle - eye, ahead) == pytest.approx(10.0)  # 10 m behind along the heading
    assert eye[2] > vehicle[2] + 2  # above it, so it does not hide what is ahead
    assert np.dot(target - vehicle, ahead) > 0  # looking past it
    assert np.linalg.norm(np.cross(target - vehicle, ahead)) == pytest.approx(0, abs=1e-9)  # straight ahead


def test_compass_heading_is_clockwise_from_north():
    assert camera.forward(0.0) == pytest.approx([0, 1, 0], abs=1e-12)  # north is +y
    assert camera.forward(math.pi / 2) == pytest.approx([1, 0, 0], abs=1e-12)  # east is +x
    assert camera.forward(0.0, math.pi / 2) == pytest.approx([0, 0, 1], abs=1e-12)  # nose up


def test_onboard_looks_along_heading_and_pitch_from_the_sonar_mount():
    vehicle = np.array([1.0, 1.0, 3.0])
    eye, target = camera.onboard(vehicle, math.pi / 2, 0.1)
    assert eye == pytest.approx(vehicle + [camera.MOUNT_AHEAD, 0, 0])
    direction = (target - eye) / np.linalg.norm(target - eye)
    assert direction == pytest.approx(camera.forward(math.pi / 2, 0.1))


def test_top_looks_straight_down_with_north_up_on_screen():
    centre = np.array([5.0, 5.0, 0.0])
    eye, target = camera.top(centre, 30.0)
    assert target == pytest.approx(centre)
    assert eye[2] == pytest.approx(30.0) and math.dist(eye[:2], centre[:2]) < 0.1
    rotation = camera.rotation(look(eye, target))
    north = rotation.T @ (centre + [0, 10, 0] - eye)
    east = rotation.T @ (centre + [10, 0, 0] - eye)
    assert north[1] < -5 and abs(north[0]) < 0.1  # up on screen (OpenCV: -y is up)
    assert east[0] > 5 and abs(east[1]) < 0.1  # right on screen


def test_fit_sees_the_whole_box():
    low, high = np.array([-60.0, -60.0, 0.0]), np.array([60.0, 60.0, 12.0])
    fov, aspect = math.radians(75), 1.2
    eye, target = camera.fit(low, high, fov, aspect)
    rotation = camera.rotation(look(eye, target))
    for corner in [(x, y, z) for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]:
        local = rotation.T @ (np.array(corner) - eye)
        assert local[2] > 0  # in front of the camera
        half = math.tan(fov / 2) * local[2]
        assert abs(local[0]) <= half * aspect and abs(local[1]) <= half, corner


def test_ray_through_the_image():
    eye, target = np.array([0.0, -10.0, 5.0]), np.zeros(3)
    wxyz = look(eye, target)
    ahead = (target - eye) / np.linalg.norm(target - eye)
    assert camera.ray(wxyz, 1.0, 1.5, 0.0, 0.0) == pytest.approx(ahead)
    assert camera.ray(wxyz, 1.0, 1.5, 1.0, 0.0)[0] > 0.3  # right of the middle is east here
    assert camera.ray(wxyz, 1.0, 1.5, 0.0, 1.0)[2] > ahead[2]  # the top of the image looks higher
    # the corner ray is at the edge of the field of view
    corner = camera.ray(wxyz, 1.0, 1.5, 0.0, 1.0)
    assert math.acos(float(np.dot(corner, ahead))) == pytest.approx(0.5)


def test_zoom_at_keeps_the_point_under_the_cursor():
    eye, target, point = np.array([0.0, -20.0, 10.0]), np.zeros(3), np.array([6.0, 3.0, 0.0])
    new_eye, new_target = camera.zoom_at(eye, target, point, 0.5)
    assert np.linalg.norm(new_eye - point) == pytest.approx(0.5 * np.linalg.norm(eye - point))
    # same view direction, and the point on the same ray from the eye: it stays where it was on screen
    assert (new_target - new_eye) / np.linalg.norm(new_target - new_eye) == \
        pytest.approx((target - eye) / np.linalg.norm(target - eye))
    sight = (point - eye) / np.linalg.norm(point - eye)
    assert (point - new_eye) / np.linalg.norm(point - new_eye) == pytest.approx(sight)


def test_zoom_at_stops_short_of_the_point():
    eye, point = np.array([0.0, 0.0, 2.0]), np.zeros(3)
    new_eye, _ = camera.zoom_at(eye, np.array([0.0, 1.0, 0.0]), point, 0.01)
    assert np.linalg.norm(new_eye - point) == pytest.approx(camera.NEAREST)


def test_smooth_angle_turns_the_short_way_and_settles():
    assert camera.smooth_angle(None, 1.0, 0.1, 0.5) == 1.0
    step = camera.smooth_angle(math.radians(350), math.radians(10), 0.1, 0.5)
    assert math.radians(350) < step < math.radians(370)  # through north, not back round
    angle = 0.0
    for _ in range(100):
        angle = camera.smooth_angle(angle, 2.0, 0.1, 0.5)
    assert angle == pytest.approx(2.0, abs=1e-6)
