"""Which closed solid of a scene holds a point: a goto's target inside a building is refused by the station,
and a mission's default corner inside one is moved out of it by the simulator."""

from __future__ import annotations

import numpy as np

EDGE_NUDGE = (1.3e-7, 0.7e-7)  # m a point is moved off the scene's triangle edges before it is looked at


def solid_at(scene, x: float, y: float, z: float) -> str | None:
    """The name of the closed solid of ``scene`` that holds (x, y, z) (its DEF name, else "shape N"), or None.
    A vertical line through the point meets a closed solid's surface an odd number of times above the point
    and an odd number below when the point is inside (a roof alone, or a floor, is met on one side only). The
    point is nudged off the triangles' shared edges, which a line through them would meet twice."""
    px, py = x + EDGE_NUDGE[0], y + EDGE_NUDGE[1]
    corners = scene.triangles
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    ab, ac = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    ap = np.array([px, py]) - a[:, :2]
    area = ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):  # an upright triangle has no area seen from above
        u = (ap[:, 0] * ac[:, 1] - ap[:, 1] * ac[:, 0]) / area
        v = (ab[:, 0] * ap[:, 1] - ab[:, 1] * ap[:, 0]) / area
        met = (area != 0) & (u >= 0) & (v >= 0) & (u + v <= 1)
        height = a[:, 2] + u * (b[:, 2] - a[:, 2]) + v * (c[:, 2] - a[:, 2])
    objects = scene.face_object
    above = np.bincount(objects[met & (height > z)], minlength=scene.objects)
    below = np.bincount(objects[met & (height < z)], minlength=scene.objects)
    holding = np.flatnonzero((above % 2 == 1) & (below % 2 == 1))
    if not len(holding):
        return None
    index = int(holding[0])
    names = scene.object_names
    return names[index] if index < len(names) and names[index] else f"shape {index}"
