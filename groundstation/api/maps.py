"""Map pictures: a vehicle's memory map (PNG or cells), and the 2D map's scene, maps and trails."""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Response
from fastapi import Path as FastPath

from groundstation.mapview import legend, trails
from vehicle.mapping.memory_map import FREE_AT, OCCUPIED_AT

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter()

    @router.get("/api/vehicles/{sysid}/map", tags=["vehicles"],
                responses={200: {"content": {"image/png": {}, "application/json": {}}}})
    def vehicle_map(sysid: int, format: str = Query("png", pattern="^(png|json)$")):
        """The memory map: a picture (north up; unknown dark, free pale, occupied red) or the log-odds cells."""
        v = guards.vehicle_or_404(sysid)
        with station.fleet.lock:
            grid = v.map_grid()
            source = v.map_source
            grid = None if grid is None else (grid[0].copy(), grid[1], grid[2])
        if grid is None:
            raise HTTPException(404, f"vehicle {sysid} has no map yet")
        values, resolution, origin = grid
        if format == "json":
            rows = np.flatnonzero(values.any(axis=1))
            cols = np.flatnonzero(values.any(axis=0))
            r0, c0 = (int(rows[0]), int(cols[0])) if len(rows) else (0, 0)
            r1, c1 = (int(rows[-1]) + 1, int(cols[-1]) + 1) if len(rows) else (0, 0)
            return {"source": source, "resolution": resolution, "origin": list(origin), "size": values.shape[0],
                    "occupied_at": OCCUPIED_AT, "free_at": FREE_AT,
                    "occupied": int(np.count_nonzero(values >= OCCUPIED_AT)),
                    "window": {"row": r0, "col": c0, "rows": r1 - r0, "cols": c1 - c0},
                    "values": values[r0:r1, c0:c1].tolist()}
        return Response(station.map_picture(v, grid), media_type="image/png")

    @router.get("/api/map2d/scene", tags=["map"])
    async def map2d_scene():
        """The scene seen from above, as a PNG data URL with its bounds (scene metres: west, south, east,
        north)."""
        scene = station.view.scene
        found = await asyncio.to_thread(station.pictures.scene, scene)
        if found is None:  # a station without a scene: an empty answer (the page asks on every load, and a
            return {"image": None, "bounds": None}  # browser logs every 404 as an error in the console)
        return found

    @router.get("/api/map2d/maps/{which}", tags=["map"])
    async def map2d_map(which: str = FastPath(pattern=r"^(merged|[0-9]{1,3})$")):
        """A memory map (a vehicle's system id, or ``merged``: every vehicle's evidence summed cell by cell in
        log-odds) as a PNG data URL of its explored part, with its bounds and the legend's colours."""
        fleet = station.fleet
        if which == "merged":
            found = await asyncio.to_thread(station.pictures.merged, fleet)
        else:
            found = await asyncio.to_thread(station.pictures.vehicle, fleet, int(which))
        if found is None:
            if not fleet.vehicles if which == "merged" else fleet.get(int(which)) is None:
                raise HTTPException(404, "no such map yet")
            # a vehicle whose map holds nothing explored yet: an empty answer, not an error (the page asks as
            # soon as the status says the vehicle has a map, and a browser logs every 404 as an error)
            return {"image": None, "bounds": None, "legend": legend()}
        return {**found, "legend": legend()}

    @router.get("/api/map2d/trails", tags=["map"])
    def map2d_trails():
        """Each vehicle's trail (scene x, y; at most 1000 points each, evenly thinned)."""
        return trails(station.fleet)

    return router
