"""viser's client on the app's own origin: its page under /viz/, its websocket relayed, each tied to its viewer.

viser is not an ASGI app and has no authentication, so it listens on loopback
only and is reached through here. Three things keep a hostile party out:

- The page is viser's own file, served with a Content-Security-Policy that
  lets in exactly its two scripts (by hash: its loader and the bundle the
  loader unpacks), WebAssembly, and websockets to this origin only; a
  ``?websocket=`` query (viser's client would connect wherever it names) is
  refused outright. Script that a viser server might send (HTML elements,
  ``RunJavascriptMessage``) cannot run, nor can viser's Gaussian-splat sorter
  (Emscripten's embind makes functions from strings); the page we serve starts
  that sorter only for the first splats, which the station never draws
  (``groundstation.viewerpage``), so it loads without an error.
- The operator page opens its view at ``/viz/v/VIEWER/``, and viser's client
  connects to the socket of the same path: the viewer id travels with that
  one connection. Only the first live connection may claim an id.
- The proxy learns which viser client a connection is from viser itself: on
  connect the 3D view sends each client alone a marker node naming its id
  (``CLIENT_MARKER``), and the proxy reads that connection's first frames
  for it. A click in the 3D view then reaches the page that owns the
  connection, and never another.
"""

from __future__ import annotations

import asyncio
import logging
import re

import msgspec
import websockets
import zstandard
from fastapi import WebSocket, WebSocketDisconnect
from fastapi.responses import Response

from groundstation.viewerpage import ViewerPage
from groundstation.viz import CLIENT_MARKER

VIEWER_ID = re.compile(r"[A-Za-z0-9_-]{8,64}")
MAX_VIEWS = 32  # viser connections at once (each holds a copy of the scene in its buffers)
MARKER_FRAMES = 400  # frames to read for the marker before giving up on tying the connection
log = logging.getLogger("groundstation.proxy")


class VizProxy:
    def __init__(self, viser_port: int):
        self.base = f"127.0.0.1:{viser_port}"
        self.page = ViewerPage.of_installed_viser()
        self.viewers: dict[int, str] = {}  # viser client id -> the page's viewer id, while connected
        self._claimed: set[str] = set()  # viewer ids a live connection holds
        self.connections = 0

    async def close(self) -> None:
        pass

    def connected(self, viewer: str | None) -> bool:
        """Is this viewer's 3D view connected now? Its page reloads a view that stays away (viser's client
        in a frame without focus does not reconnect by itself)."""
        return viewer in self._claimed

    def http(self, query: dict[str, str]) -> Response:
        """viser's page; never with a ``websocket`` query (it would connect wherever that names)."""
        if "websocket" in query:
            return Response("the 3D view connects only to this station", status_code=400, media_type="text/plain")
        return Response(self.page.html, media_type="text/html; charset=utf-8",
                        headers={"content-security-policy": self.page.policy, "cache-control": "no-store"})

    async def websocket(self, client: WebSocket, viewer: str | None) -> None:
        if viewer is not None and (not VIEWER_ID.fullmatch(viewer) or viewer in self._claimed):
            await client.close(code=1008, reason="that viewer id is malformed or already connected")
            return
        if self.connections >= MAX_VIEWS:
            await client.close(code=1013, reason="too many 3D views open; try again later")
            return
        # claimed and counted before the first await: connections arriving together see each other
        self.connections += 1
        if viewer is not None:
            self._claimed.add(viewer)
        tie = _Tie(self.viewers, viewer)
        try:
            requested = client.headers.get("sec-websocket-protocol", "")
            protocols = [p.strip() for p in requested.split(",") if p.strip()]
            try:
                upstream = await websockets.connect(f"ws://{self.base}", subprotocols=protocols or None,
                                                    max_size=None, ping_interval=None, compression=None)
            except OSError:
                await client.close(code=1011)
                return
            await client.accept(subprotocol=upstream.subprotocol)
            await _relay(client, upstream, tie)
        finally:
            self.connections -= 1
            self._claimed.discard(viewer)
            tie.release()


class _Tie:
    """Until it finds its marker, reads a connection's frames; then ties that viser client to the viewer."""

    def __init__(self, viewers: dict[int, str], viewer: str | None):
        self.viewers = viewers
        self.viewer = viewer
        self.client_id: int | None = None
        self.frames = 0 if viewer is not None else MARKER_FRAMES  # nothing to tie without a viewer

    def read(self, frame: bytes | str) -> None:
        if self.frames >= MARKER_FRAMES or not isinstance(frame, bytes):
            return
        self.frames += 1
        client_id = _marker_in(frame)
        if client_id is not None:
            self.client_id = client_id
            self.viewers[client_id] = self.viewer
            self.frames = MARKER_FRAMES
        elif self.frames == MARKER_FRAMES:
            log.warning("3D view of viewer %s: viser never named its client; its clicks go nowhere", self.viewer)

    def release(self) -> None:
        if self.client_id is not None:
            self.viewers.pop(self.client_id, None)


def _marker_in(frame: bytes) -> int | None:
    """The client id in a viser frame's marker node, if it has one. viser's wire format: the message
    block's size and its compressed size (two little-endian u64), zstd-compressed msgpack, binary buffers."""
    if len(frame) < 16:
        return None
    size, compressed = int.from_bytes(frame[:8], "little"), int.from_bytes(frame[8:16], "little")
    try:
        inner = zstandard.ZstdDecompressor().decompress(frame[16:16 + compressed], max_output_size=size)
        messages = msgspec.msgpack.decode(inner).get("messages", ())
    except (zstandard.ZstdError, msgspec.DecodeError, AttributeError, ValueError):
        return None
    for message in messages:
        name = message.get("name") if isinstance(message, dict) else None
        if isinstance(name, str) and name.startswith(CLIENT_MARKER) and name[len(CLIENT_MARKER):].isdigit():
            return int(name[len(CLIENT_MARKER):])
    return None


async def _relay(client: WebSocket, upstream, tie: _Tie) -> None:
    async def downstream() -> None:
        async for frame in upstream:
            tie.read(frame)
            if isinstance(frame, bytes):
                await client.send_bytes(frame)
            else:
                await client.send_text(frame)

    async def upstream_pump() -> None:
        while True:
            message = await client.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("bytes") is not None:
                await upstream.send(message["bytes"])
            elif message.get("text") is not None:
                await upstream.send(message["text"])

    tasks = [asyncio.create_task(downstream()), asyncio.create_task(upstream_pump())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await upstream.close()
        try:
            await client.close()
        except (RuntimeError, WebSocketDisconnect):
            pass  # the page already went
