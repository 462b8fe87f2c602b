"""The web app: the operator page, the REST API (OpenAPI at /docs), the status WebSocket and the 3D view proxy.

Anything that commands a vehicle (or deletes a recording, or drives a
replay) needs the operator token as ``Authorization: Bearer TOKEN``; who may
watch, and what reaches a route at all, is ``security.Gate``'s business.
Every input is checked before it is used: a command's numbers must be finite
and in range, a goto inside the vehicle's space, a mission what MAVLink can
carry; errors answer 4xx with what was wrong. Blocking MAVLink exchanges run
in worker threads so the event loop keeps serving the page and the stream.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Literal
from urllib.parse import quote

import numpy as np
from fastapi import Depends, FastAPI, Header, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi import Path as FastPath
from fastapi.exceptions import RequestValidationError
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    RedirectResponse,
    Response,
    StreamingResponse,
)
from fastapi.staticfiles import StaticFiles
from fastapi.websockets import WebSocketState
from pydantic import BaseModel, ConfigDict, Field, field_validator

from groundstation.commands import Command, execute, outside_space
from groundstation.link import LinkError, TransferBusy
from groundstation.mapview import legend, trails
from groundstation.proxy import VIEWER_ID
from groundstation.replay import ReplayError
from groundstation.security import SESSION_COOKIE, Gate
from vehicle import __version__
from vehicle.mapping.memory_map import FREE_AT, OCCUPIED_AT
from vehicle.protocol.waypoints import WaypointError, mission_text, parse_mission

if TYPE_CHECKING:
    from groundstation.server import GroundStation

def _static() -> Path:
    """The operator page: package data (``groundstation/static``) in a wheel, the top-level ``static/`` of a
    checkout."""
    here = Path(__file__).resolve().parent
    return here / "static" if (here / "static").is_dir() else here.parent / "static"


STATIC = _static()


class ReplayStart(BaseModel):
    name: str = Field(max_length=255, description="a recording's name, as GET /api/recordings lists it")


class ReplayControl(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False, strict=True)

    play: bool | None = None
    speed: float | None = Field(None, ge=0.1, le=20)
    seek: float | None = Field(None, ge=0, le=1e7, description="seconds from the start of the recording")
    step: Literal[-1, 1] | None = None

    @field_validator("step", mode="before")
    @classmethod
    def _step_is_a_number(cls, value):
        if isinstance(value, bool):  # true == 1 to the Literal
            raise ValueError("step is -1 or 1, not true or false")
        return value


MAX_HISTORY = 3000  # samples per vehicle in a history or timeline answer
STREAM_PERIOD = 0.25  # s between status frames on /ws
MAX_STREAMS = 256  # /ws connections at once
EXCHANGES = 16  # commands and mission transfers under way at once (each waits on a vehicle, not on the CPU)
DOCS_ASSETS = "/docs/assets"
log = logging.getLogger("groundstation")


def attachment(name: str) -> str:
    """A Content-Disposition for a download called ``name`` (RFC 6266): the name itself percent-encoded as UTF-8
    for browsers, and for older clients an ASCII one without quotes, backslashes or control characters. A file
    in the record folder may be called anything: put in a header as it is, a non-ASCII name was a 500, and a
    line break in it ended the response."""
    plain = "".join(c if " " <= c < "\x7f" and c not in '"\\' else "_" for c in name)
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(name, safe='', errors='surrogateescape')}"


def _read_prefix(path: Path, size: int, chunk: int = 1 << 16):
    """The first ``size`` bytes of a file, in chunks."""
    with open(path, "rb") as handle:
        left = size
        while left > 0:
            data = handle.read(min(chunk, left))
            if not data:
                return
            left -= len(data)
            yield data


def create_app(station: GroundStation) -> FastAPI:
    app = FastAPI(title="scanstation ground station", version=__version__, docs_url=None, redoc_url=None,
                  description="Watch and command scanning rovers and copters over MAVLink.")
    app.add_middleware(Gate, access=station.access)

    def operator(authorization: str | None = Header(None, description="Bearer TOKEN (the operator token)")):
        if not station.access.is_operator(authorization):
            log.warning("refused a request without a valid operator token")
            raise HTTPException(401, "the operator token is missing or wrong",
                                headers={"WWW-Authenticate": "Bearer"})

    def vehicle_or_404(sysid: int):
        vehicle = station.fleet.get(sysid)
        if vehicle is None:
            raise HTTPException(404, f"no vehicle with system id {sysid}")
        return vehicle

    def live_only() -> None:
        if station.replay is not None:
            raise HTTPException(409, "commands are disabled in replay")

    # Exchanges with vehicles (commands, missions) wait on the radio, up to seconds each: on threads of their
    # own, so that slow or hostile vehicles never hold up what the page draws on asyncio's default threads.
    exchanges = ThreadPoolExecutor(max_workers=EXCHANGES, thread_name_prefix="vehicle-exchange")

    async def exchange(function, *args):
        return await asyncio.get_running_loop().run_in_executor(exchanges, functools.partial(function, *args))

    # ---- the page ---------------------------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def page():
        return FileResponse(STATIC / "index.html")

    @app.get("/favicon.ico", include_in_schema=False)
    def icon():
        """Where browsers and bookmarking tools look first, whatever the page names."""
        return FileResponse(STATIC / "favicon.svg", media_type="image/svg+xml")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/docs", include_in_schema=False)
    def docs():
        """Swagger UI from files installed with the station (no CDN: it works offline, under our policy)."""
        return HTMLResponse(_DOCS_PAGE, headers={"content-security-policy": _DOCS_POLICY})

    app.mount(DOCS_ASSETS, StaticFiles(directory=_swagger_assets()), name="docs-assets")

    @app.post("/api/session", tags=["status"], status_code=204,
              responses={401: {"description": "neither the operator nor the viewer token"}})
    def session(request: Request, authorization: str | None = Header(None, description="Bearer TOKEN")):
        """Let this browser watch (a cookie for the 3D view and the stream, which cannot carry a header).
        Needed only when the station serves beyond loopback; commands still need the operator token."""
        if not station.access.grants_session(authorization):
            raise HTTPException(401, "neither the operator nor the viewer token",
                                headers={"WWW-Authenticate": "Bearer"})
        response = Response(status_code=204)
        response.set_cookie(SESSION_COOKIE, station.access.session_value(), httponly=True, samesite="strict",
                            secure=request.url.scheme == "https", path="/")
        return response

    @app.get("/api/health", tags=["status"])
    @app.head("/api/health", include_in_schema=False)  # what uptime monitors send
    def health():
        scene = station.scene
        link = station.link.health() if station.link is not None else None
        troubled = link is not None and (link["thread"] != "ok" or link["recording_error"]
                                         or not all(port["up"] for port in link["links"]))
        return {"status": "degraded" if troubled else "ok", "version": __version__, "mode": station.mode,
                "vehicles": len(station.fleet.ids()), "links": station.link_urls, "link": link,
                "far_from_scene": station.far_from_scene(),
                "recording": None if station.recorder is None else {
                    "file": station.recorder.path.name, "error": link["recording_error"] if link else None},
                "scene": None if scene is None else {"name": scene.path.name if scene.path else None,
                                                     "triangles": len(scene.faces)}}

    @app.get("/api/auth", tags=["status"], dependencies=[Depends(operator)])
    def auth():
        """200 when the operator token is right (the page's sign-in uses this)."""
        return {"ok": True}

    # ---- vehicles ----------------------------------------------------------------------------------
    @app.get("/api/vehicles", tags=["vehicles"])
    def vehicles():
        return station.vehicles()

    @app.get("/api/vehicles/{sysid}", tags=["vehicles"])
    def vehicle(sysid: int):
        described = station.vehicles(sysid)
        if not described:
            raise HTTPException(404, f"no vehicle with system id {sysid}")
        return described[0]

    @app.get("/api/vehicles/{sysid}/map", tags=["vehicles"],
             responses={200: {"content": {"image/png": {}, "application/json": {}}}})
    def vehicle_map(sysid: int, format: str = Query("png", pattern="^(png|json)$")):
        """The memory map: a picture (north up; unknown dark, free pale, occupied red) or the log-odds cells."""
        v = vehicle_or_404(sysid)
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

    # ---- plots, the timeline and the 2D map -------------------------------------------------------------
    @app.get("/api/vehicles/{sysid}/history", tags=["vehicles"])
    def vehicle_history(sysid: int, since: float | None = Query(None, ge=0, le=1e11, allow_inf_nan=False,
                                                                 description="only samples and events after this "
                                                                             "time (the station's clock, s)"),
                        limit: int = Query(600, ge=1, le=MAX_HISTORY, description="samples at most (thinned)")):
        """The vehicle's sampled telemetry (every numeric field, by name, with units) and its events (mode
        changes, arming, commands and their ACKs, messages, the onboard agent's phases), oldest first."""
        fleet = station.fleet
        with fleet.lock:
            if fleet.get(sysid) is None:
                raise HTTPException(404, f"no vehicle with system id {sysid}")
            return {"sysid": sysid, **fleet.history.of(sysid).as_json(since, limit)}

    @app.get("/api/replay/timeline", tags=["replay"])
    def replay_timeline(limit: int = Query(1500, ge=1, le=MAX_HISTORY, description="samples per vehicle at most"),
                        sysid: int | None = Query(None, ge=1, le=255, description="only this vehicle's")):
        """The replayed log's whole history, every vehicle's (or one's), on the log's clock (``start`` is replay
        time 0): scanned in the background when the replay starts (``ready`` false meanwhile)."""
        replay, timeline = station.replay, station.timeline
        if replay is None or timeline is None:
            raise HTTPException(409, "nothing is being replayed")
        history = timeline.history
        vehicles = {} if history is None else {str(key): {"sysid": key, **found.as_json(None, limit)}
                                                for key, found in sorted(history.vehicles.items())
                                                if sysid is None or key == sysid}
        return {"ready": timeline.ready, "error": timeline.error, "skipped": timeline.skipped,
                "start": replay.index.start, "duration": replay.duration, "vehicles": vehicles}

    @app.get("/api/map2d/scene", tags=["map"])
    async def map2d_scene():
        """The scene seen from above, as a PNG data URL with its bounds (scene metres: west, south, east,
        north)."""
        scene = station.view.scene
        found = await asyncio.to_thread(station.pictures.scene, scene)
        if found is None:
            raise HTTPException(404, "no scene is shown")
        return found

    @app.get("/api/map2d/maps/{which}", tags=["map"])
    async def map2d_map(which: str = FastPath(pattern=r"^(merged|[0-9]{1,3})$")):
        """A memory map (a vehicle's system id, or ``merged``: every vehicle's evidence summed cell by cell in
        log-odds) as a PNG data URL of its explored part, with its bounds and the legend's colours."""
        fleet = station.fleet
        if which == "merged":
            found = await asyncio.to_thread(station.pictures.merged, fleet)
        else:
            found = await asyncio.to_thread(station.pictures.vehicle, fleet, int(which))
        if found is None:
            raise HTTPException(404, "no such map yet")
        return {**found, "legend": legend()}

    @app.get("/api/map2d/trails", tags=["map"])
    def map2d_trails():
        """Each vehicle's trail (scene x, y; at most 1000 points each, evenly thinned)."""
        return trails(station.fleet)

    @app.post("/api/vehicles/{sysid}/commands", tags=["commands"], dependencies=[Depends(operator)],
              responses={401: {"description": "no or wrong operator token"}, 404: {"description": "no such vehicle"},
                         409: {"description": "replaying"}, 504: {"description": "the vehicle did not answer"}})
    async def command(sysid: int, body: Command):
        """Send a command; answers with the vehicle's COMMAND_ACK result."""
        live_only()
        v = vehicle_or_404(sysid)
        if body.action == "goto":
            refusal = outside_space(station.fleet, v, body.x, body.y, station.scene)
            if refusal:
                raise HTTPException(422, refusal)
        try:
            result = await exchange(execute, station.link, v, body, station.fleet.datum, time.time())
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        log.info("vehicle %s: %s -> %s", sysid, body.action, result)
        return {"action": body.action, "result": result}

    @app.get("/api/vehicles/{sysid}/mission", tags=["missions"], response_class=PlainTextResponse)
    async def get_mission(sysid: int):
        """The AUTO mission, downloaded from the vehicle, as QGC WPL 110 text."""
        live_only()
        vehicle_or_404(sysid)
        try:
            items = await exchange(station.link.download_mission, sysid)
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        station.note_waypoints(sysid, items)
        return mission_text(items)

    @app.put("/api/vehicles/{sysid}/mission", tags=["missions"], dependencies=[Depends(operator)])
    async def put_mission(sysid: int, request: Request):
        """Upload an AUTO mission (QGC WPL 110 text; item 0 is home)."""
        live_only()
        vehicle_or_404(sysid)
        text = (await request.body()).decode("utf-8", "replace")  # at most security.MAX_BODY bytes: the Gate read it
        try:
            items = parse_mission(text)
        except WaypointError as error:
            raise HTTPException(422, str(error)) from None
        if not items:
            raise HTTPException(422, "the mission has no items")
        try:
            result = await exchange(station.link.upload_mission, sysid, items)
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        if result == "accepted":
            station.note_waypoints(sysid, items)
        return {"result": result, "items": len(items)}

    # ---- recordings and replay ----------------------------------------------------------------------
    def recording_or_404(name: str) -> Path:
        path = station.recording_path(name)
        if path is None:
            shown = name if len(name) <= 80 else f"{name[:80]}..."  # the start of a long name says enough
            raise HTTPException(404, f"no recording called {shown!r}")
        return path

    @app.get("/api/recordings", tags=["recordings"])
    def recordings():
        """The session recordings, newest first."""
        return station.recordings()

    @app.get("/api/recordings/{name}", tags=["recordings"])
    def recording(name: str):
        """Download a recording (.tlog, readable by mavlogdump.py, MAVExplorer, QGroundControl).

        The session being recorded goes on growing: its download is the file as it
        was when the request came (its last record may be cut short; replay reads
        up to it)."""
        path = recording_or_404(name)
        size = path.stat().st_size
        return StreamingResponse(_read_prefix(path, size), media_type="application/octet-stream",
                                 headers={"Content-Length": str(size),
                                          "Content-Disposition": attachment(name)})

    @app.delete("/api/recordings/{name}", tags=["recordings"], dependencies=[Depends(operator)])
    def delete_recording(name: str):
        path = recording_or_404(name)
        if station.recorder is not None and path == station.recorder.path:
            raise HTTPException(409, "that is the session being recorded now")
        if station.replay is not None and station.replay.index.path == path:
            raise HTTPException(409, "that recording is being replayed")
        path.unlink()
        return {"deleted": name}

    @app.get("/api/replay", tags=["replay"])
    def replay_status():
        replay = station.replay
        return {"mode": station.mode, "replay": replay.status() if replay is not None else None}

    @app.post("/api/replay", tags=["replay"], dependencies=[Depends(operator)])
    async def start_replay(body: ReplayStart):
        """Replay a recording in the page (instead of the live vehicles)."""
        path = recording_or_404(body.name)
        try:
            replay = await asyncio.to_thread(station.start_replay, path)
        except ReplayError as error:
            raise HTTPException(422, str(error)) from None
        return replay.status()

    @app.post("/api/replay/control", tags=["replay"], dependencies=[Depends(operator)])
    async def control_replay(body: ReplayControl):
        """Play or pause, change speed, seek to a time (s from the start) or step by a tenth of a second."""
        replay = station.replay
        if replay is None:
            raise HTTPException(409, "nothing is being replayed")
        return await asyncio.to_thread(replay.control, body.play, body.speed, body.seek, body.step)

    @app.post("/api/replay/stop", tags=["replay"], dependencies=[Depends(operator)])
    def stop_replay():
        """Back to the live vehicles."""
        station.stop_replay()
        return {"mode": station.mode}

    @app.get("/api/replay/export", tags=["replay"])
    async def export_replay():
        """The replay as one standalone HTML file that plays offline."""
        replay = station.replay
        if replay is None:
            raise HTTPException(409, "nothing is being replayed")
        html = await asyncio.to_thread(station.export_replay, replay)
        name = Path(replay.name).stem + ".html"
        return Response(html, media_type="text/html",
                        headers={"Content-Disposition": attachment(name)})

    # ---- the stream ----------------------------------------------------------------------------------
    @app.websocket("/ws")
    async def stream(socket: WebSocket, viewer: str | None = None):
        """Status frames every STREAM_PERIOD, and this viewer's own notes (its 3D view's clicks); it takes
        the viewer's requests for its own 3D view (see ``groundstation.views``)."""
        if viewer is not None and not VIEWER_ID.fullmatch(viewer):
            await socket.close(code=1008, reason="a viewer id is 8-64 letters, digits, - or _")
            return
        if station.streams >= MAX_STREAMS:
            await socket.close(code=1013, reason="too many streams open; try again later")
            return
        await socket.accept()
        inbox = station.subscribe(viewer)
        sender = asyncio.create_task(_send_status(socket, inbox, station))
        receiver = asyncio.create_task(_receive_view_requests(socket, inbox, station, viewer))
        try:  # until the page goes, or either half fails: then the page hears the stream end, and reconnects
            done, _ = await asyncio.wait((sender, receiver), return_when=asyncio.FIRST_COMPLETED)
        finally:
            sender.cancel()
            receiver.cancel()
            station.unsubscribe(viewer, inbox)
        failure = next((task.exception() for task in done if not task.cancelled() and task.exception()), None)
        gone = WebSocketState.DISCONNECTED in (socket.client_state, socket.application_state)
        if failure is not None and not isinstance(failure, WebSocketDisconnect) and not gone:
            log.error("the status stream failed: %r", failure, exc_info=failure)
            with contextlib.suppress(Exception):  # the page may be gone already
                await socket.close(code=1011, reason="the status stream failed; reconnect")

    # ---- the 3D view --------------------------------------------------------------------------------
    @app.get("/viz", include_in_schema=False)
    def viz_slash():
        return RedirectResponse("/viz/")

    @app.get("/viz/", include_in_schema=False)
    def viz_page(request: Request):
        return station.proxy.http(request.query_params)

    @app.get("/viz/v/{viewer}/", include_in_schema=False)
    def viz_viewer_page(request: Request, viewer: str):
        if not VIEWER_ID.fullmatch(viewer):
            raise HTTPException(404, "no such view")
        return station.proxy.http(request.query_params)

    @app.websocket("/viz")
    async def viz_socket(socket: WebSocket):
        await station.proxy.websocket(socket, None)

    @app.websocket("/viz/v/{viewer}")
    async def viz_viewer_socket(socket: WebSocket, viewer: str):
        await station.proxy.websocket(socket, viewer)

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


async def _receive_view_requests(socket: WebSocket, inbox: asyncio.Queue, station: GroundStation,
                                 viewer: str | None) -> None:
    """The page's requests for its own 3D view (camera, selection, layers), each answered to it alone; returns
    when the page goes."""
    while (message := await socket.receive())["type"] != "websocket.disconnect":
        station.view_request(viewer, message.get("text") or message.get("bytes") or "", inbox)


async def _send_status(socket: WebSocket, inbox: asyncio.Queue, station: GroundStation) -> None:
    """The status at once, then notes as they come, and the status when none came for a period. A frame
    that cannot be JSON (it never should: the fleet keeps only finite numbers) is logged and skipped, never
    sent as NaN."""
    frame = station.status()  # a new viewer sees the vehicles now, not a period later
    while True:
        try:
            text = json.dumps(frame, allow_nan=False)
        except ValueError as error:
            log.error("a status frame could not be sent: %s", error)
        else:
            await socket.send_text(text)
        try:
            frame = await asyncio.wait_for(inbox.get(), timeout=STREAM_PERIOD)
        except TimeoutError:
            frame = station.status()


def _swagger_assets() -> Path:
    import fastapi_offline

    return Path(fastapi_offline.__file__).parent / "static"


_DOCS_PAGE = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>scanstation ground station: API</title>
<link rel="stylesheet" href="{DOCS_ASSETS}/swagger-ui.css"><link rel="icon" href="{DOCS_ASSETS}/favicon.png">
</head><body><div id="swagger-ui"></div>
<script src="{DOCS_ASSETS}/swagger-ui-bundle.js"></script><script src="/static/docs.js"></script>
</body></html>"""
_DOCS_POLICY = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
                "connect-src 'self'; frame-ancestors 'self'; base-uri 'none'; form-action 'self'; object-src 'none'")
