"""The radio tomography frame on the ground of a 3D view (viser): the image as one picture lying on the ground,
the peaks as red points with their value. Drawn once per new frame (at most one a window), never per 3D frame,
so the view's frame time does not grow: a frame is one image node, one point cloud and a label per peak."""

from __future__ import annotations

import numpy as np

from groundstation.rti_live import Frame, rgba

ROOT = "/layers/rti"
HEIGHT = 0.03  # m above the ground plane: over the grid, under everything else
PEAK_HEIGHT = 0.4  # m: the peaks' points and labels stand above the image


def draw(scene, frame: Frame | None) -> None:
    """Show ``frame`` in viser's ``scene`` (``server.scene``), replacing the last; None takes it away."""
    scene.remove_by_name(ROOT)
    if frame is None:
        return
    west, south, east, north = frame.bounds
    scene.add_image(f"{ROOT}/image", rgba(frame.image), render_width=east - west, render_height=north - south,
                    format="png", position=((west + east) / 2, (south + north) / 2, HEIGHT))
    if frame.peaks:
        points = np.array([(p["x"], p["y"], PEAK_HEIGHT) for p in frame.peaks], dtype=np.float32)
        scene.add_point_cloud(f"{ROOT}/peaks", points, colors=(255, 77, 79), point_size=0.25)
        for i, p in enumerate(frame.peaks):
            scene.add_label(f"{ROOT}/peak{i}", f"{i + 1}: {p['value']:.3g}", position=(p["x"], p["y"], PEAK_HEIGHT))
