"""Top-down pictures of a scene, optionally with a memory map, a path and a start marker.

Triangles are painted lowest first in their own colours, shaded by height, so
roofs cover floors as seen from above. Around them: lines on round scene
coordinates, labelled along the bottom (x, east) and the left (y, north), a
north arrow and a scale bar (the same as a map picture's, ``vehicle.mapping.picture``),
and the origin, so that a start (``--start X,Y``) can be read off the picture.
Pillow is enough for this; no renderer is needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.picture import (
    BACKGROUND,
    MIN_WIDTH,
    POSITION,
    TEXT,
    TRAIL,
    Picture,
    grid_lines,
    load_font,
    north_arrow,
    scale_bar,
)
from vehicle.world.scene import Scene

LEFT, TOP, RIGHT, BOTTOM = 56, 40, 16, 50  # pixels around the scene: labels, title and arrow, scale bar
ORIGIN = (255, 120, 60)


def draw_top_view(scene: Scene, size: int = 900, memory_map: MemoryMap | None = None,
                  route: list[tuple[float, float]] | None = None, start: tuple[float, ...] | None = None,
                  title: str = "") -> Picture:
    """The scene from above, its longer side ``size`` pixels, with the map, route and start given."""
    bounds = scene.bounds if len(scene.faces) else np.array([[-10.0, -10, 0], [10.0, 10, 1]])
    (x0, y0, z0), (x1, y1, z1) = bounds
    if start is not None:  # a start off the scene is still on the picture
        x0, y0, x1, y1 = min(x0, start[0]), min(y0, start[1]), max(x1, start[0]), max(y1, start[1])
    margin = 0.03 * max(x1 - x0, y1 - y0, 1.0)
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    scale = size / max(x1 - x0, y1 - y0)
    width, height = int((x1 - x0) * scale) + 1, int((y1 - y0) * scale) + 1
    canvas = max(LEFT + width + RIGHT, MIN_WIDTH)  # a narrow scene still has room for the title and the arrow
    left = LEFT + (canvas - LEFT - width - RIGHT) // 2
    image = Image.new("RGB", (canvas, TOP + height + BOTTOM), BACKGROUND)
    draw = ImageDraw.Draw(image, "RGBA")
    view = Picture(image, (left, TOP, left + width, TOP + height), (x0, y1 - height / scale, x0 + width / scale, y1))
    pixel = view.pixel

    triangles = scene.triangles
    tops = triangles[:, :, 2].max(axis=1)
    span = max(z1 - z0, 1e-6)
    for index in np.argsort(tops, kind="stable"):
        shade = 0.55 + 0.45 * (tops[index] - z0) / span
        colour = tuple(int(c * shade) for c in scene.face_colors[index][:3])
        draw.polygon([pixel(x, y) for x, y, _ in triangles[index]], fill=colour)
    if memory_map is not None:
        _paste_map(image, view, memory_map, scale)
    small = load_font(12)
    grid_lines(draw, view, small)
    _origin(draw, view, small)
    if route:
        draw.line([pixel(x, y) for x, y in route], fill=TRAIL, width=2)
    if start is not None:
        sx, sy = pixel(*start[:2])
        draw.ellipse([sx - 6, sy - 6, sx + 6, sy + 6], outline=POSITION, width=2)
        draw.text((sx + 9, sy - 9), "start", fill=POSITION, font=small, anchor="ld")
    draw.text((LEFT, TOP // 2), title, fill=TEXT, font=load_font(15), anchor="lm")
    north_arrow(draw, image.width - RIGHT - 12, 4, small)
    scale_bar(draw, view, LEFT, view.map_box[3] + 24, small)
    return view


def render_top_view(scene: Scene, path: str | Path, size: int = 900, memory_map: MemoryMap | None = None,
                    route: list[tuple[float, float]] | None = None, start: tuple[float, ...] | None = None,
                    title: str = "") -> None:
    """``draw_top_view`` written as a PNG file."""
    draw_top_view(scene, size, memory_map, route, start, title).save(path)


def _origin(draw: ImageDraw.ImageDraw, view: Picture, font) -> None:
    """A cross at the scene's origin (0, 0), where it is in the picture."""
    west, south, east, north = view.window
    if not (west <= 0 <= east and south <= 0 <= north):
        return
    x, y = view.pixel(0.0, 0.0)
    draw.line([(x - 7, y), (x + 7, y)], fill=ORIGIN, width=2)
    draw.line([(x, y - 7), (x, y + 7)], fill=ORIGIN, width=2)
    draw.text((x + 6, y + 5), "0,0", fill=ORIGIN, font=font, anchor="lt")


def _paste_map(image: Image.Image, view: Picture, memory_map: MemoryMap, scale: float) -> None:
    """The memory map over the scene, cut to the scene's part of the picture (a map reaches further than a
    small scene)."""
    side = int(2 * memory_map.space_size * scale)
    if side <= 0:
        return
    overlay = Image.fromarray(memory_map.image(), "RGBA").resize((side, side), Image.NEAREST)
    left, top = view.pixel(memory_map.origin[0], memory_map.origin[1] + 2 * memory_map.space_size)
    box = view.map_box
    area = image.crop(box)
    area.paste(overlay, (int(left) - box[0], int(top) - box[1]), overlay)
    image.paste(area, box[:2])
