"""Pictures for the page's 2D map: the scene from above, each memory map, and all of them merged.

Each comes as ``{"bounds": [west, south, east, north], "image": "data:image/png;base64,..."}``
(scene metres), so the page can lay it under the vehicles with a canvas and
no further requests. Memory maps are cropped to what has been explored and
drawn in the states the 3D view uses (free pale, occupied red, unknown
clear), at most ``MAX_PIXELS`` a side: ``vehicle.mapping.picture.overlay``,
the one crop and shrink that the 3D view and the map's PNG use too.

The merged map combines the vehicles' evidence cell by cell: each map holds
log-odds, and independent evidence about a cell adds up in log-odds, so the
merged cell is the sum of every map's value there, resampled onto one grid
at the finest resolution among them.
"""

from __future__ import annotations

import base64
import io
import math
import threading

import numpy as np
from PIL import Image

from vehicle.mapping import picture
from vehicle.mapping.memory_map import STATE_COLOURS
from vehicle.world.scene import Scene

MAX_PIXELS = 1024  # a side of a memory-map picture
SCENE_PIXELS = 1024  # the longer side of the scene's picture
MERGED_CELLS = 2000  # a side of the merged grid at most (coarser resolution beyond)
GROUND = (58, 64, 58)

Grid = tuple[np.ndarray, float, tuple[float, float]]  # log-odds (rows north), cells per metre, south-west corner


def data_url(rgba: np.ndarray) -> str:
    buffer = io.BytesIO()
    Image.fromarray(rgba, "RGBA" if rgba.shape[2] == 4 else "RGB").save(buffer, "PNG", optimize=False)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def scene_picture(scene: Scene) -> dict | None:
    """The scene seen from above: triangles painted lowest first in their own colours, darker the lower they
    are, so buildings stand out from the ground."""
    if scene is None or not len(scene.faces):
        return None
    from PIL import ImageDraw

    (x0, y0, z0), (x1, y1, z1) = scene.bounds
    scale = SCENE_PIXELS / max(x1 - x0, y1 - y0, 1e-6)
    width, height = max(1, int(math.ceil((x1 - x0) * scale))), max(1, int(math.ceil((y1 - y0) * scale)))
    image = Image.new("RGB", (width, height), GROUND)
    draw = ImageDraw.Draw(image)
    triangles = scene.triangles
    tops = triangles[:, :, 2].max(axis=1)
    span = max(z1 - z0, 1e-6)
    normals = scene.face_normals
    for index in np.argsort(tops, kind="stable"):
        if abs(normals[index][2]) < 0.05:
            continue  # a wall seen edge-on from above: its outline comes from the roofs and floors
        shade = 0.45 + 0.55 * (tops[index] - z0) / span
        colour = tuple(int(c * shade) for c in scene.face_colors[index][:3])
        points = [((x - x0) * scale, (y1 - y) * scale) for x, y, _ in triangles[index]]
        draw.polygon(points, fill=colour, outline=colour)
    rgba = np.asarray(image.convert("RGBA"))
    return {"bounds": [float(x0), float(y0), float(x1), float(y1)], "image": data_url(rgba)}


def overlay(grid: Grid) -> dict | None:
    """A memory map as a picture of its explored part, with its bounds; None when nothing is explored."""
    values, resolution, origin = grid
    found = picture.overlay(values, resolution, origin, MAX_PIXELS)
    if found is None:
        return None
    return {"bounds": [round(v, 3) for v in found.window], "resolution": resolution,
            "image": data_url(found.image)}


def merge(grids: list[Grid]) -> Grid | None:
    """The vehicles' maps as one: log-odds summed cell by cell on a grid at the finest of their resolutions,
    covering what any of them explored (coarser if that would pass MERGED_CELLS a side)."""
    parts = []
    for values, resolution, origin in grids:
        window = picture.explored(values)
        if window is not None:
            parts.append((values, resolution, origin, window))
    if not parts:
        return None
    west = min(o[0] + w[2] / r for _, r, o, w in parts)
    south = min(o[1] + w[0] / r for _, r, o, w in parts)
    east = max(o[0] + w[3] / r for _, r, o, w in parts)
    north = max(o[1] + w[1] / r for _, r, o, w in parts)
    resolution = max(r for _, r, _, _ in parts)
    resolution = min(resolution, MERGED_CELLS / max(east - west, north - south, 1e-6))
    rows = max(1, int(math.ceil((north - south) * resolution)))
    cols = max(1, int(math.ceil((east - west) * resolution)))
    total = np.zeros((rows, cols), dtype=np.int32)
    ys = south + (np.arange(rows) + 0.5) / resolution  # cell centres of the merged grid
    xs = west + (np.arange(cols) + 0.5) / resolution
    for values, own, origin, _ in parts:
        r = np.floor((ys - origin[1]) * own).astype(np.int64)
        c = np.floor((xs - origin[0]) * own).astype(np.int64)
        rin, cin = (r >= 0) & (r < values.shape[0]), (c >= 0) & (c < values.shape[1])
        if rin.any() and cin.any():
            total[np.ix_(rin, cin)] += values[np.ix_(r[rin], c[cin])]
    merged = np.clip(total, -127, 127).astype(np.int8)
    return merged, resolution, (west, south)


def legend() -> dict[str, str]:
    """The colours of the map's states, as CSS (the page's legend uses the same)."""
    names = ("unknown", "free", "occupied")
    return {name: "rgba({}, {}, {}, {:.2f})".format(*c[:3], c[3] / 255) for name, c in zip(names, STATE_COLOURS,
                                                                                          strict=True)}


MAX_TRAIL_POINTS = 1000  # per vehicle in a trails answer (evenly thinned)


class MapPictures:
    """The 2D map's pictures for one station, each made again only when what it shows has changed (the page
    asks every few seconds; a merged map of several large maps takes a while)."""

    def __init__(self):
        self._scene: tuple[object, dict | None] | None = None
        self._maps: dict[tuple, dict | None] = {}
        self._lock = threading.Lock()

    def scene(self, scene: Scene | None) -> dict | None:
        with self._lock:
            if self._scene is None or self._scene[0] is not scene:
                self._scene = (scene, scene_picture(scene))
            return self._scene[1]

    def vehicle(self, fleet, sysid: int) -> dict | None:
        """One vehicle's memory map (None: no such vehicle, or nothing explored)."""
        with fleet.lock:
            v = fleet.get(sysid)
            grid = None if v is None else v.map_grid()
            if grid is None:
                return None
            key = (id(fleet), sysid, fleet.map_version(v))
            if key in self._maps:
                return self._maps[key]
            grid = (grid[0].copy(), grid[1], grid[2])
        return self._keep(key, lambda: overlay(grid))

    def merged(self, fleet) -> dict | None:
        """Every vehicle's evidence in one map (None: no maps yet)."""
        with fleet.lock:
            chosen = [(sysid, v) for sysid, v in sorted(fleet.vehicles.items()) if v.map_grid() is not None]
            key = (id(fleet), "merged", tuple((sysid, fleet.map_version(v)) for sysid, v in chosen))
            if key in self._maps:
                return self._maps[key]
            grids = [(g[0].copy(), g[1], g[2]) for g in (v.map_grid() for _, v in chosen)]

        def make():
            grid = merge(grids)
            found = None if grid is None else overlay(grid)
            if found is not None:
                found["vehicles"] = [sysid for sysid, _ in chosen]
            return found
        return self._keep(key, make)

    def _keep(self, key: tuple, make) -> dict | None:
        made = make()
        with self._lock:
            if len(self._maps) > 64:
                self._maps.clear()
            self._maps[key] = made
        return made


def trails(fleet) -> dict[str, list[list[float]]]:
    """Each vehicle's trail, at most MAX_TRAIL_POINTS points (scene x, y)."""
    found = {}
    with fleet.lock:
        for sysid, v in sorted(fleet.vehicles.items()):
            points = list(v.trail)
            if len(points) > MAX_TRAIL_POINTS:
                pick = np.linspace(0, len(points) - 1, MAX_TRAIL_POINTS).round().astype(int)
                points = [points[i] for i in pick]
            found[str(sysid)] = [[round(float(p[0]), 2), round(float(p[1]), 2)] for p in points]
    return found
