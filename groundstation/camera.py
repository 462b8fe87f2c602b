"""Where a viewer's camera goes in each camera mode: plain geometry, no viser.

Scene frame: x east, y north, z up, metres; a vehicle's yaw is its compass
heading in radians (0 north, clockwise). A pose is (eye, target): where the
camera is and the point it looks at; "up" is always +z, so the horizon stays
level (the attitude indicator shows the roll).

- follow: a chase camera behind the vehicle and above it, looking past it
  along its heading. The vehicle's position is followed exactly (so it stays
  still on screen) and its heading smoothly (so turns do not whip the view).
- onboard: the vehicle's own view, from its sonar mount along its heading
  and pitch, where its sonar beams point.
- top: straight down onto the vehicle (or the scene's centre), north up.
- fit: an oblique view from the south-west of a box (the scene, the vehicles).
- zoom_at: towards the point under the cursor, keeping it under the cursor.
"""

from __future__ import annotations

import math

import numpy as np

Pose = tuple[np.ndarray, np.ndarray]  # eye, target
MOUNT_AHEAD = 0.35  # m ahead of the body's centre: the sonars' mount, outside the hull
NEAREST = 0.5  # m: a zoom stops this far from the point it zooms to


def forward(yaw: float, pitch: float = 0.0) -> np.ndarray:
    return np.array([math.sin(yaw) * math.cos(pitch), math.cos(yaw) * math.cos(pitch), math.sin(pitch)])


def follow(position, heading: float, distance: float) -> Pose:
    p = np.asarray(position, dtype=float)
    ahead = forward(heading)
    eye = p - ahead * distance + np.array([0.0, 0.0, distance * 0.4])
    return eye, p + ahead * distance * 0.2


def onboard(position, heading: float, pitch: float) -> Pose:
    p = np.asarray(position, dtype=float)
    eye = p + forward(heading) * MOUNT_AHEAD
    return eye, eye + forward(heading, pitch) * 10.0


def top(centre, height: float) -> Pose:
    """Looking down from ``height`` above ``centre``; the eye a hair south of it, so north is up on screen."""
    c = np.asarray(centre, dtype=float)
    return c + np.array([0.0, -height * 1e-3, height]), c


FIT_FROM = np.array([-0.35, -0.45, 0.4]) / np.linalg.norm([-0.35, -0.45, 0.4])  # south-west, 35 degrees up


def fit(low, high, fov: float = math.radians(50), aspect: float = 1.0) -> Pose:
    """An oblique view of the box from the south-west that shows all of it: the box's bounding sphere
    fits the narrower of the two fields of view (``fov`` vertical, radians; ``aspect`` width / height)."""
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    centre = (low + high) / 2
    radius = max(float(np.linalg.norm(high - low)) / 2, 5.0)
    half = min(fov / 2, math.atan(math.tan(fov / 2) * aspect))
    return centre + FIT_FROM * radius / math.sin(half), centre


def overview(position, heading: float, distance: float = 8.0) -> Pose:
    """Near a vehicle, from behind and above it, looking at it."""
    p = np.asarray(position, dtype=float)
    return p - forward(heading) * distance + np.array([0.0, 0.0, distance * 0.6]), p


def rotation(wxyz) -> np.ndarray:
    w, x, y, z = (float(v) for v in wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def ray(wxyz, fov: float, aspect: float, x: float, y: float) -> np.ndarray:
    """The direction through a point of the image (x, y from -1 to 1, y up), for a camera in viser's
    (OpenCV's) convention: +z ahead, +x right, -y up; ``fov`` vertical, radians."""
    half = math.tan(fov / 2)
    local = np.array([x * half * aspect, -y * half, 1.0])
    direction = rotation(wxyz) @ local
    return direction / np.linalg.norm(direction)


def zoom_at(eye, target, point, factor: float) -> Pose:
    """Scale the camera about ``point`` (factor < 1 comes closer): the point stays where it is on screen."""
    eye, target, point = (np.asarray(v, dtype=float) for v in (eye, target, point))
    reach = float(np.linalg.norm(eye - point))
    if reach * factor < NEAREST:
        factor = NEAREST / max(reach, 1e-9)
    return point + (eye - point) * factor, point + (target - point) * factor


def blend(start: Pose, end: Pose, t: float) -> Pose:
    """Part ``t`` (0..1) of the way from one pose to another, eased in and out."""
    s = t * t * (3 - 2 * t)
    return start[0] + (end[0] - start[0]) * s, start[1] + (end[1] - start[1]) * s


def smooth_angle(current: float | None, goal: float, dt: float, tau: float) -> float:
    """An angle that follows ``goal`` with time constant ``tau`` the short way round."""
    if current is None:
        return goal
    delta = (goal - current + math.pi) % (2 * math.pi) - math.pi
    return current + delta * (1 - math.exp(-dt / tau))
