"""Pictures of a memory map that read at a glance, for people (the .npy beside them is the raw data).

One renderer for every picture of a map: ``vehicle experiment --map-out``,
the best maps of a sweep and the ground station's ``/api/vehicles/{id}/map``.
A whole map is 2,000 cells a side of which a mission explores a corner, so the
picture is cropped to what was explored and travelled (with a margin; waypoints
beyond it are left out rather than shrink everything else) and each
cell is drawn at least ``MIN_CELL`` pixels wide; where the explored part is too
big for that, a drawn cell stands for a block of cells, occupied if any of them
is (obstacles never vanish). Around it: a title, a north arrow, a scale bar and
a legend; on it, faint lines every scale-bar length, home, the trail, the last
position, the planned path and waypoints. The cells keep
the colours of ``memory_map.state_image`` over the dark ground unknown cells
have always had.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from vehicle.mapping.memory_map import UNKNOWN, state_image, states_of

MIN_CELL = 3  # pixels a drawn cell is wide, at least
MAX_CELL = 6  # and at most (a small patch gives a small picture, not a blown-up one)
TARGET_SIDE = 600  # pixels the longer side of the map aims at
MAX_SIDE = 1200  # pixels the longer side of the map may have
MARGIN = 0.1  # share of the explored extent added around it (at least MIN_MARGIN metres)
MIN_MARGIN = 2.0  # m
MIN_EXTENT = 10.0  # m: the window is never narrower
PAD = 14  # pixels around the map and between the parts of the picture
MIN_WIDTH = 520  # pixels: room for the title and the legend
SWATCH = 14  # pixels a legend swatch is wide

BACKGROUND = (24, 26, 30)
UNKNOWN_GROUND = (60, 60, 66)  # what shows through unknown (transparent) cells
TEXT = (230, 232, 236)
DIM_TEXT = (160, 164, 170)
TRAIL = (40, 150, 240)
PATH = (255, 230, 0)
WAYPOINT = (80, 200, 255)
HOME = (60, 220, 90)
POSITION = (255, 255, 255)

Point = tuple[float, float]


@dataclass
class Picture:
    """A picture of part of the scene seen from above, and where scene points fall on it."""

    image: Image.Image
    map_box: tuple[int, int, int, int]  # left, top, right, bottom pixels of the drawn area
    window: tuple[float, float, float, float]  # west, south, east, north scene metres it shows

    def pixel(self, x: float, y: float) -> tuple[float, float]:
        """Where a scene point falls on the picture."""
        west, south, east, north = self.window
        left, top, right, bottom = self.map_box
        scale = (right - left) / (east - west)
        return left + (x - west) * scale, top + (north - y) * scale

    def png(self) -> bytes:
        buffer = io.BytesIO()
        self.image.save(buffer, "PNG", optimize=True)
        return buffer.getvalue()

    def save(self, path: str | Path) -> None:
        self.image.save(path, "PNG", optimize=True)


@dataclass
class MapPicture(Picture):
    """A map's picture (for tests and callers that annotate it)."""

    cell_pixels: int  # pixels a drawn cell is wide
    block: int  # map cells a drawn cell stands for, along each side
    swatches: dict[str, tuple[int, int, int, int]] = field(default_factory=dict)  # legend entry -> its box


def draw_map(grid: np.ndarray, resolution: float, origin: Point, title: str = "", home: Point | None = None,
             trail: Sequence[Sequence[float]] = (), planned_path: Sequence[Point] = (),
             waypoints: Sequence[Point] = (), position: Point | None = None) -> MapPicture:
    """Draw a log-odds ``grid`` (rows north, columns east, ``resolution`` cells/m, south-west corner at
    ``origin`` in scene metres); ``title`` may have a second line; points are scene metres."""
    states = states_of(grid)
    trail_points = [(float(p[0]), float(p[1])) for p in trail]
    path = list(planned_path)
    points = trail_points + path + [p for p in (home, position) if p is not None]
    r0, r1, c0, c1 = _window(states, resolution, origin, points)
    block = max(1, math.ceil(max(r1 - r0, c1 - c0) * MIN_CELL / MAX_SIDE))
    cells = block_max(states[r0:r1, c0:c1], block)
    r1, c1 = r0 + cells.shape[0] * block, c0 + cells.shape[1] * block
    cell_pixels = int(np.clip(TARGET_SIDE // max(cells.shape), MIN_CELL, MAX_CELL))
    window = (origin[0] + c0 / resolution, origin[1] + r0 / resolution,
              origin[0] + c1 / resolution, origin[1] + r1 / resolution)

    font, small = load_font(15), load_font(12)
    map_width, map_height = cells.shape[1] * cell_pixels, cells.shape[0] * cell_pixels
    width = max(map_width + 2 * PAD, MIN_WIDTH)
    lines = []
    for i, line in enumerate(line for line in title.splitlines() if line.strip()):
        lines += [(text, i == 0) for text in _wrap(line, font if i == 0 else small, width - 2 * PAD - 30)]
    header = PAD + len(lines) * 20 + (PAD // 2 if lines else 0)
    header = max(header, PAD + 34)  # room for the north arrow
    legend = _legend_items(trail_points, path, waypoints, home, position)
    legend_rows = _flow(legend, small, width - 2 * PAD)
    footer = PAD + 26 + len(legend_rows) * 22 + PAD
    image = Image.new("RGB", (width, header + map_height + footer), BACKGROUND)
    draw = ImageDraw.Draw(image, "RGBA")
    left = (width - map_width) // 2
    map_box = (left, header, left + map_width, header + map_height)
    picture = MapPicture(image, map_box, window, cell_pixels, block)

    for i, (line, first) in enumerate(lines):
        draw.text((PAD, PAD + 20 * i), line, fill=TEXT if first else DIM_TEXT, font=font if first else small)
    north_arrow(draw, width - PAD - 12, PAD, small)
    image.paste(_cells_image(cells, cell_pixels), map_box[:2])
    grid_lines(draw, picture)
    draw.rectangle([map_box[0] - 1, map_box[1] - 1, map_box[2], map_box[3]], outline=(110, 114, 120))
    _overlays(picture, trail_points, path, waypoints, home, position)
    below = map_box[3] + PAD
    scale_bar(draw, picture, PAD, below, small)
    picture.swatches = _draw_legend(draw, legend_rows, PAD, below + 26 + 4, small)
    return picture


def save_map_picture(target: str | Path, *args, **kwargs) -> None:
    """``draw_map(*args, **kwargs)`` written as a PNG file."""
    draw_map(*args, **kwargs).save(target)


# ---- the explored part, in blocks: the overlays (the page's 2D map, the 3D view) and the picture share it ----
def explored(values: np.ndarray, margin: int = 0) -> tuple[int, int, int, int] | None:
    """Rows and columns (r0, r1, c0, c1) holding every nonzero cell (log-odds evidence, or a known state),
    widened by ``margin`` cells within the grid; None when every cell is zero."""
    rows = np.flatnonzero(values.any(axis=1))
    if not len(rows):
        return None
    cols = np.flatnonzero(values.any(axis=0))
    return (max(0, int(rows[0]) - margin), min(values.shape[0], int(rows[-1]) + 1 + margin),
            max(0, int(cols[0]) - margin), min(values.shape[1], int(cols[-1]) + 1 + margin))


def block_max(states: np.ndarray, block: int) -> np.ndarray:
    """Each ``block`` x ``block`` cells of a state grid as one cell holding the most telling state in it
    (occupied over free over unknown), so an obstacle never vanishes. A last row or column of blocks that the
    grid only partly fills is padded with unknown, never cut off: the result covers ``shape * block`` cells
    from the grid's first row and column, which may reach past its far edges."""
    if block <= 1:
        return states
    rows, cols = -(-states.shape[0] // block) * block, -(-states.shape[1] // block) * block
    padded = np.full((rows, cols), UNKNOWN, dtype=states.dtype)
    padded[:states.shape[0], :states.shape[1]] = states
    return padded.reshape(rows // block, block, cols // block, block).max(axis=(1, 3))


@dataclass
class Overlay:
    """The explored part of a memory map as an RGBA image (north up; ``state_image``'s colours, unknown clear)
    and the scene metres it covers, to lay under or over a scene."""

    image: np.ndarray
    window: tuple[float, float, float, float]  # west, south, east, north
    block: int  # map cells a pixel stands for, along each side


def overlay(values: np.ndarray, resolution: float, origin: Point, max_pixels: int) -> Overlay | None:
    """A log-odds grid's known cells (cropped to them), at most ``max_pixels`` a side; None when none is known."""
    states = states_of(values)
    window = explored(states)
    if window is None:
        return None
    r0, r1, c0, c1 = window
    block = max(1, math.ceil(max(r1 - r0, c1 - c0) / max_pixels))
    cells = block_max(states[r0:r1, c0:c1], block)
    r1, c1 = r0 + cells.shape[0] * block, c0 + cells.shape[1] * block
    return Overlay(state_image(cells), (origin[0] + c0 / resolution, origin[1] + r0 / resolution,
                                        origin[0] + c1 / resolution, origin[1] + r1 / resolution), block)


# ---- the window -----------------------------------------------------------------------------------------
def _window(states: np.ndarray, resolution: float, origin: Point, points: list[Point]) -> tuple[int, int, int, int]:
    """Rows r0:r1 and columns c0:c1 of the grid to draw: the explored cells and the points, with a margin."""
    size_rows, size_cols = states.shape
    known = explored(states)  # UNKNOWN is 0
    spans: list[tuple[float, float, float, float]] = []  # west, south, east, north in metres
    if known is not None:
        row0, row1, col0, col1 = known
        spans.append((origin[0] + col0 / resolution, origin[1] + row0 / resolution,
                      origin[0] + col1 / resolution, origin[1] + row1 / resolution))
    if points:
        xs, ys = [p[0] for p in points], [p[1] for p in points]
        spans.append((min(xs), min(ys), max(xs), max(ys)))
    if not spans:  # nothing known: the middle of the map
        middle = (origin[0] + size_cols / resolution / 2, origin[1] + size_rows / resolution / 2)
        spans.append((*middle, *middle))
    west, south = min(s[0] for s in spans), min(s[1] for s in spans)
    east, north = max(s[2] for s in spans), max(s[3] for s in spans)
    margin = max(MIN_MARGIN, MARGIN * max(east - west, north - south))
    grow_x = max(margin, (MIN_EXTENT - (east - west)) / 2)
    grow_y = max(margin, (MIN_EXTENT - (north - south)) / 2)
    c0 = int(np.clip(math.floor((west - grow_x - origin[0]) * resolution), 0, size_cols - 1))
    c1 = int(np.clip(math.ceil((east + grow_x - origin[0]) * resolution), c0 + 1, size_cols))
    r0 = int(np.clip(math.floor((south - grow_y - origin[1]) * resolution), 0, size_rows - 1))
    r1 = int(np.clip(math.ceil((north + grow_y - origin[1]) * resolution), r0 + 1, size_rows))
    return r0, r1, c0, c1


def _cells_image(cells: np.ndarray, cell_pixels: int) -> Image.Image:
    """The states as ``state_image`` colours them, over the unknown ground, each cell a square of pixels."""
    rgba = state_image(cells).astype(np.float32)
    alpha = rgba[..., 3:4] / 255.0
    rgb = (rgba[..., :3] * alpha + np.array(UNKNOWN_GROUND, dtype=np.float32) * (1 - alpha)).astype(np.uint8)
    return Image.fromarray(rgb.repeat(cell_pixels, axis=0).repeat(cell_pixels, axis=1), "RGB")


# ---- what is drawn on and around the map ---------------------------------------------------------------
def _overlays(picture: MapPicture, trail: list[Point], path: Sequence[Point],
              waypoints: Sequence[Point], home: Point | None, position: Point | None) -> None:
    """Trail, path, waypoints, home and the last position, cut at the map's edge."""
    layer = Image.new("RGBA", picture.image.size, (0, 0, 0, 0))
    draw_clipped = ImageDraw.Draw(layer)
    if len(trail) >= 2:
        draw_clipped.line([picture.pixel(*p) for p in trail], fill=TRAIL, width=2, joint="curve")
    if len(path) >= 2:
        draw_clipped.line([picture.pixel(*p) for p in path], fill=PATH, width=3, joint="curve")
    for point in waypoints:
        _dot(draw_clipped, picture.pixel(*point), 5, WAYPOINT, outline=(20, 40, 60))
    if home is not None:
        _dot(draw_clipped, picture.pixel(*home), 7, HOME, outline=(10, 40, 20))
    if position is not None:
        _dot(draw_clipped, picture.pixel(*position), 4, POSITION, outline=(0, 0, 0))
    layer = layer.crop(picture.map_box)
    picture.image.paste(layer, picture.map_box[:2], layer)


def grid_lines(draw: ImageDraw.ImageDraw, picture: Picture, font=None) -> None:
    """Faint lines every scale-bar length, on round scene coordinates, to judge distances anywhere; with a
    ``font``, each labelled with its coordinate outside the drawn area (x below it, y left of it)."""
    west, south, east, north = picture.window
    step = grid_step(picture)
    left, top, right, bottom = picture.map_box
    for k in range(math.ceil(west / step), math.floor(east / step) + 1):  # whole multiples: no 1e-16 for 0
        column = round(picture.pixel(k * step, north)[0])
        if column < right:
            draw.line([(column, top), (column, bottom - 1)], fill=(255, 255, 255, 30))
            if font is not None:
                draw.text((column, bottom + 4), f"{k * step:g}", fill=DIM_TEXT, font=font, anchor="mt")
    for k in range(math.ceil(south / step), math.floor(north / step) + 1):
        row = round(picture.pixel(west, k * step)[1])
        if row > top:
            draw.line([(left, row), (right - 1, row)], fill=(255, 255, 255, 30))
            if font is not None:
                draw.text((left - 6, row), f"{k * step:g}", fill=DIM_TEXT, font=font, anchor="rm")


def grid_step(picture: Picture) -> float:
    """The scale bar's length and the grid's spacing: a round length near a quarter of the longer side."""
    west, south, east, north = picture.window
    return nice_length(max(east - west, north - south) / 4)


def _wrap(text: str, font, width: float) -> list[str]:
    """``text`` in lines no wider than ``width`` (broken at spaces)."""
    lines = [""]
    for word in text.split(" "):
        joined = f"{lines[-1]} {word}" if lines[-1] else word
        if lines[-1] and font.getlength(joined) > width:
            lines.append(word)
        else:
            lines[-1] = joined
    return lines


def _dot(draw: ImageDraw.ImageDraw, centre: tuple[float, float], radius: float, fill, outline) -> None:
    x, y = centre
    draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=fill, outline=outline, width=2)


def north_arrow(draw: ImageDraw.ImageDraw, x: float, top: float, font) -> None:
    """An arrow pointing up (north: rows run north) with an N under it."""
    draw.polygon([(x, top), (x - 7, top + 16), (x, top + 12), (x + 7, top + 16)], fill=TEXT)
    draw.text((x, top + 18), "N", fill=TEXT, font=font, anchor="mt")


def scale_bar(draw: ImageDraw.ImageDraw, picture: Picture, x: float, y: float, font) -> None:
    """A bar of a round length (1, 2 or 5 times a power of ten metres) near a quarter of the longer side."""
    west, _, east, _ = picture.window
    left, _, right, _ = picture.map_box
    metres = grid_step(picture)
    length = metres * (right - left) / (east - west)
    draw.rectangle([x, y + 6, x + length, y + 11], fill=TEXT)
    for tick in (x, x + length / 2, x + length):
        draw.line([(tick, y + 2), (tick, y + 15)], fill=TEXT, width=1)
    label = f"{metres:g} m"
    draw.text((x + length + 8, y + 9), label, fill=TEXT, font=font, anchor="lm")


def nice_length(target: float) -> float:
    """The largest of 1, 2, 5 times a power of ten metres that is at most ``target`` (0.1 m at least)."""
    target = max(target, 0.1)
    power = 10 ** math.floor(math.log10(target))
    return max(step * power for step in (1, 2, 5) if step * power <= target)


def _legend_items(trail: list[Point], path: Sequence[Point], waypoints: Sequence[Point], home: Point | None,
                  position: Point | None) -> list[tuple[str, str, tuple]]:
    """(name, kind of swatch, colour) of what the picture shows."""
    items = [("unknown", "cell", UNKNOWN_GROUND), ("free", "cell", _cell_colour(1)),
             ("occupied", "cell", _cell_colour(2))]
    if len(trail) >= 2:
        items.append(("trail", "line", TRAIL))
    if len(path) >= 2:
        items.append(("planned path", "line", PATH))
    if waypoints:
        items.append(("waypoints", "dot", WAYPOINT))
    if home is not None:
        items.append(("home", "dot", HOME))
    if position is not None:
        items.append(("last position", "dot", POSITION))
    return items


def _cell_colour(state: int) -> tuple[int, int, int]:
    rgba = state_image(np.array([[state]], dtype=np.uint8))[0, 0].astype(np.float32)
    alpha = rgba[3] / 255.0
    return tuple(int(v) for v in rgba[:3] * alpha + np.array(UNKNOWN_GROUND) * (1 - alpha))


def _flow(items: list, font, width: float) -> list[list]:
    """The legend's items in rows that fit ``width``."""
    rows: list[list] = [[]]
    used = 0.0
    for item in items:
        need = SWATCH + 6 + font.getlength(item[0]) + 18
        if rows[-1] and used + need > width:
            rows.append([])
            used = 0.0
        rows[-1].append(item)
        used += need
    return rows


def _draw_legend(draw: ImageDraw.ImageDraw, rows: list[list], x0: float, y0: float,
                 font) -> dict[str, tuple[int, int, int, int]]:
    swatches = {}
    for r, row in enumerate(rows):
        x, y = x0, y0 + 22 * r
        for name, kind, colour in row:
            box = (int(x), int(y), int(x) + SWATCH, int(y) + SWATCH)
            if kind == "cell":
                draw.rectangle([box[0], box[1], box[2] - 1, box[3] - 1], fill=colour, outline=(110, 114, 120))
            elif kind == "line":
                draw.line([(box[0], y + SWATCH / 2), (box[2], y + SWATCH / 2)], fill=colour, width=3)
            else:
                _dot(draw, (x + SWATCH / 2, y + SWATCH / 2), SWATCH / 2 - 1, colour, outline=colour)
            swatches[name] = box
            draw.text((x + SWATCH + 6, y + SWATCH / 2), name, fill=TEXT, font=font, anchor="lm")
            x += SWATCH + 6 + font.getlength(name) + 18
    return swatches


def load_font(size: int):
    """Pillow's scalable font at ``size`` pixels (its small bitmap font where FreeType is missing)."""
    try:
        return ImageFont.load_default(size=size)  # Pillow's own scalable font (needs FreeType)
    except (TypeError, ImportError, OSError):
        return ImageFont.load_default()
