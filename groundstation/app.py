"""The web app: the operator page, the REST API (OpenAPI at /docs), the status WebSocket and the 3D view proxy.

The routes live by area in ``groundstation.api`` (one module each); this
assembles them with the gate and the error answers. Anything that commands a
vehicle (or deletes a recording, or drives a replay) needs the operator token
as ``Authorization: Bearer TOKEN``; who may watch, and what reaches a route at
all, is ``security.Gate``'s business. Every input is checked before it is used:
a command's numbers must be finite and in range, a goto inside the vehicle's
space, a mission what MAVLink can carry; errors answer 4xx with what was wrong.
Blocking MAVLink exchanges run in worker threads so the event loop keeps
serving the page and the stream.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from groundstation.api import AREAS, page
from groundstation.api.common import Guards
from groundstation.link import LinkError, TransferBusy
from groundstation.security import Gate
from vehicle import __version__

if TYPE_CHECKING:
    from groundstation.server import GroundStation


def create_app(station: GroundStation) -> FastAPI:
    app = FastAPI(title="scanstation ground station", version=__version__, docs_url=None, redoc_url=None,
                  description="Watch and command scanning rovers and copters over MAVLink.")
    app.add_middleware(Gate, access=station.access)
    page.install(app)
    guards = Guards(station)
    for area in AREAS:
        app.include_router(area.routes(station, guards))

    @app.exception_handler(LinkError)
    async def link_error(request: Request, error: LinkError):
        return JSONResponse({"detail": str(error)}, status_code=504)

    @app.exception_handler(TransferBusy)
    async def transfer_busy(request: Request, error: TransferBusy):
        return JSONResponse({"detail": str(error)}, status_code=409)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, error: RequestValidationError):
        """What was wrong, without echoing the input (it may be NaN, which JSON cannot carry, or huge)."""
        return JSONResponse({"detail": [{"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")),
                                         "type": str(e.get("type", ""))} for e in error.errors()]},
                            status_code=422)

    return app
