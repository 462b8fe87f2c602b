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
- recentre: the orbit camera slid across the ground (its angle kept) so that a vehicle that left the
  view, or went under the page's 2D map, is back in the open part of it.
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


def project(wxyz, eye, fov: float, aspect: float, point) -> tuple[float, float] | None:
    """Where ``point`` shows in the image (x, y from -1 to 1 at the edges, y up; ``ray``'s inverse), or None
    when it is behind the camera."""
    local = rotation(wxyz).T @ (np.asarray(point, dtype=float) - np.asarray(eye, dtype=float))
    if local[2] <= 1e-6:
        return None
    half = math.tan(fov / 2)
    return float(local[0] / local[2] / (half * aspect)), float(-local[1] / local[2] / half)


Box = tuple[float, float, float, float]  # x0, y0, x1, y1 in image coordinates (as ``project``'s)
EDGE = 0.9  # of the image's half-width: a vehicle further out is as good as gone


def in_sight(spot: tuple[float, float] | None, covered: Box | None) -> bool:
    """A point of the image the viewer sees: in front, inside the edges, not under the page's 2D map."""
    if spot is None or abs(spot[0]) > EDGE or abs(spot[1]) > EDGE:
        return False
    return covered is None or not (covered[0] <= spot[0] <= covered[2] and covered[1] <= spot[1] <= covered[3])


def open_middle(covered: Box | None) -> tuple[float, float]:
    """Where in the image to bring a vehicle back to: the middle, or, with a corner under the 2D map, as far
    from the map's corner as from the opposite edges (halfway between the map's edge and the image's)."""
    if covered is None:
        return 0.0, 0.0
    x0, y0, x1, y1 = covered
    x = (x1 + 1.0) / 2 if x0 <= -0.99 and x1 < 0.99 else (x0 - 1.0) / 2 if x1 >= 0.99 and x0 > -0.99 else 0.0
    y = (y1 + 1.0) / 2 if y0 <= -0.99 and y1 < 0.99 else (y0 - 1.0) / 2 if y1 >= 0.99 and y0 > -0.99 else 0.0
    return x, y


def recentre(eye, target, wxyz, fov: float, aspect: float, point, spot: tuple[float, float]) -> Pose:
    """The camera slid (not turned) so that ``point`` shows at ``spot`` of the image: level when the ray
    through the spot comes down onto the point's height, else along the ray at the point's distance."""
    eye, target, point = (np.asarray(v, dtype=float) for v in (eye, target, point))
    direction = ray(wxyz, fov, aspect, *spot)
    reach = (point[2] - eye[2]) / direction[2] if direction[2] < -1e-3 else float(np.linalg.norm(point - eye))
    shift = point - (eye + direction * max(reach, NEAREST))
    return eye + shift, target + shift


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
