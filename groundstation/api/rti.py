"""Radio tomography: the live image's figures, peaks and links, and the image itself (``groundstation.rti_live``).

No frame yet (no radio records, or too few) is an empty answer, not a 404: the page asks with every status
frame, and a browser logs every 404 as an error.
"""

from __future__ import annotations

import asyncio
import base64
import functools
from typing import TYPE_CHECKING

from fastapi import APIRouter, Query, Response

from groundstation import rti_view
from groundstation.rti_live import LiveImager, picture

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation


def imager_for(station: GroundStation) -> LiveImager:
    """The station's live imager, made once: it images the radio log of the fleet shown (live or replayed)."""
    imager = getattr(station, "rti", None)
    if imager is None:
        imager = station.rti = LiveImager(lambda: getattr(station.fleet, "radio", None))
        imager.listeners.append(functools.partial(rti_view.draw, station.view.server.scene))  # the 3D view's ground
    return imager


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    imager = imager_for(station)
    router = APIRouter(on_startup=[imager.start], on_shutdown=[imager.stop])

    @router.get("/api/rti", tags=["rti"])
    def rti(links: bool = Query(True, description="include the last window's links")):
        """The latest frame's figures (t, bounds, links per second, coverage, latency), its peaks strongest
        first, the last window's links ([x0, y0, x1, y1] m), and the simulated targets when the station knows
        them; ``frame`` is null until one is imaged."""
        imager.start()
        frame = imager.latest()
        summary = None if frame is None else frame.summary()
        if summary is not None and not links:
            summary.pop("links")
        log = imager.source()
        return {"frame": summary, "targets": imager.targets, "frames": imager.frames, "skipped": imager.skipped,
                "records": 0 if log is None else len(log), "error": imager.error}

    @router.get("/api/rti/image", tags=["rti"],
                responses={200: {"content": {"application/json": {}, "image/png": {}}}})
    async def rti_image(format: str = Query("json", pattern="^(json|png)$")):
        """The latest image as a PNG data URL (north up, transparent where nothing is attenuated) with its
        bounds (west, south, east, north, m) and colour scale (``json``), or the PNG itself; ``image`` null
        (or 204 for ``png``) until a frame is imaged."""
        imager.start()
        frame = imager.latest()
        if frame is None:
            return Response(status_code=204) if format == "png" else {"image": None, "bounds": None, "t": None,
                                                                      "scale": None}
        drawn = await asyncio.to_thread(picture, frame)
        if format == "png":
            return Response(base64.b64decode(drawn["image"].split(",", 1)[1]), media_type="image/png")
        return drawn

    return router
