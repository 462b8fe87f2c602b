"""Streams and the 3D view: the status WebSocket (/ws) and the proxied viser view (/viz)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import secrets
from collections.abc import Callable
from typing import TYPE_CHECKING

from fastapi import APIRouter, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import RedirectResponse
from fastapi.websockets import WebSocketState

from groundstation.api.common import log
from groundstation.proxy import VIEWER_ID

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation

STREAM_PERIOD = 0.25  # s between status frames on /ws
MAX_STREAMS = 256  # /ws connections at once


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter()
    session = secrets.token_hex(8)  # this station's run: a page that sees it change knows the station restarted

    @router.websocket("/ws")
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
        sender = asyncio.create_task(_send_status(socket, inbox, lambda: {
            **station.status(), "session": session, "view": station.proxy.connected(viewer)}))
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

    @router.get("/viz", include_in_schema=False)
    def viz_slash():
        return RedirectResponse("/viz/")

    @router.get("/viz/", include_in_schema=False)
    def viz_page(request: Request):
        return station.proxy.http(request.query_params)

    @router.get("/viz/v/{viewer}/", include_in_schema=False)
    def viz_viewer_page(request: Request, viewer: str):
        if not VIEWER_ID.fullmatch(viewer):
            raise HTTPException(404, "no such view")
        return station.proxy.http(request.query_params)

    @router.websocket("/viz")
    async def viz_socket(socket: WebSocket):
        await station.proxy.websocket(socket, None)

    @router.websocket("/viz/v/{viewer}")
    async def viz_viewer_socket(socket: WebSocket, viewer: str):
        await station.proxy.websocket(socket, viewer)

    return router


async def _receive_view_requests(socket: WebSocket, inbox: asyncio.Queue, station: GroundStation,
                                 viewer: str | None) -> None:
    """The page's requests for its own 3D view (camera, selection, layers), each answered to it alone; returns
    when the page goes."""
    while (message := await socket.receive())["type"] != "websocket.disconnect":
        station.view_request(viewer, message.get("text") or message.get("bytes") or "", inbox)


async def _send_status(socket: WebSocket, inbox: asyncio.Queue, status: Callable[[], dict]) -> None:
    """The status at once, then notes as they come, and the status when none came for a period. A frame
    that cannot be JSON (it never should: the fleet keeps only finite numbers) is logged and skipped, never
    sent as NaN. The status says this station's ``session`` and whether this page's 3D ``view`` is connected."""
    frame = status()  # a new viewer sees the vehicles now, not a period later
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
            frame = status()
