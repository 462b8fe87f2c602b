"""Top-down pictures of a scene, optionally with a memory map, a path and a start marker.

Triangles are painted lowest first in their own colours, shaded by height, so
roofs cover floors as seen from above. Pillow is enough for this; no renderer
is needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from vehicle.mapping.memory_map import MemoryMap
from vehicle.world.scene import Scene


def render_top_view(scene: Scene, path: str | Path, size: int = 900, memory_map: MemoryMap | None = None,
                    route: list[tuple[float, float]] | None = None,
                    start: tuple[float, ...] | None = None) -> None:
    bounds = scene.bounds if len(scene.faces) else np.array([[-10.0, -10, 0], [10.0, 10, 1]])
    (x0, y0, z0), (x1, y1, z1) = bounds
    margin = 0.03 * max(x1 - x0, y1 - y0, 1.0)
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    scale = size / max(x1 - x0, y1 - y0)
    width, height = int((x1 - x0) * scale) + 1, int((y1 - y0) * scale) + 1
    image = Image.new("RGB", (width, height), (24, 26, 30))
    draw = ImageDraw.Draw(image)

    def pixel(x: float, y: float) -> tuple[float, float]:
        return (x - x0) * scale, height - (y - y0) * scale

    triangles = scene.triangles
    tops = triangles[:, :, 2].max(axis=1)
    span = max(z1 - z0, 1e-6)
    for index in np.argsort(tops, kind="stable"):
        shade = 0.55 + 0.45 * (tops[index] - z0) / span
        colour = tuple(int(c * shade) for c in scene.face_colors[index][:3])
        draw.polygon([pixel(x, y) for x, y, _ in triangles[index]], fill=colour)
    if memory_map is not None:
        overlay = Image.fromarray(memory_map.image(), "RGBA")
        left, top = pixel(memory_map.origin[0], memory_map.origin[1] + 2 * memory_map.space_size)
        side = int(2 * memory_map.space_size * scale)
        if side > 0:
            image.paste(overlay.resize((side, side), Image.NEAREST), (int(left), int(top)),
                        overlay.resize((side, side), Image.NEAREST))
    if route:
        draw.line([pixel(x, y) for x, y in route], fill=(80, 200, 255), width=2)
    if start is not None:
        sx, sy = pixel(*start[:2])
        draw.ellipse([sx - 6, sy - 6, sx + 6, sy + 6], outline=(255, 255, 255), width=2)
    image.save(path)
