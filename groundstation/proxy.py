"""Reverse proxy for the viser client: its page under /viz/ and its websocket at /viz, on the app's port.

viser is not an ASGI app and has no authentication, so it listens on loopback
only and is reached through here. The proxy also ties each viser client to the
operator page that embeds it: the page opens the 3D view with ``?viewer=ID``
in its websocket URL, and the proxy connects one viewer at a time, so the
viser client id that appears next belongs to that viewer (viser reports a
client after its first message, so the relay runs while the proxy waits). That is how a click
in the 3D view reaches the right page (and never commands a vehicle by itself).
"""

from __future__ import annotations

import asyncio
import threading

import httpx
import websockets
from fastapi import Request, WebSocket, WebSocketDisconnect
from fastapi.responses import Response

CONNECT_WAIT = 3.0  # s for viser to report a new client


class VizProxy:
    def __init__(self, viser_port: int):
        self.base = f"127.0.0.1:{viser_port}"
        self.viewers: dict[int, str] = {}  # viser client id -> the page's viewer id
        self._pending: str | None = None
        self._connected = threading.Event()
        self._lock = asyncio.Lock()
        self._http = httpx.AsyncClient(base_url=f"http://{self.base}", timeout=10.0)

    def client_connected(self, client_id: int) -> None:
        """Called by the 3D view (in viser's thread) for every new viser client."""
        if self._pending is not None:
            self.viewers[client_id] = self._pending
        self._connected.set()

    async def close(self) -> None:
        await self._http.aclose()

    async def http(self, request: Request, path: str) -> Response:
        upstream = await self._http.get("/" + path, params=request.query_params)
        headers = {k: v for k, v in upstream.headers.items() if k.lower() in ("content-type", "cache-control")}
        return Response(upstream.content, status_code=upstream.status_code, headers=headers)

    async def websocket(self, client: WebSocket) -> None:
        requested = client.headers.get("sec-websocket-protocol", "")
        protocols = [p.strip() for p in requested.split(",") if p.strip()]
        viewer = client.query_params.get("viewer")
        if viewer is None:  # not from the page (a script, say): nothing to tie it to, no need to queue
            upstream = await self._connect(client, protocols)
            if upstream is not None:
                await self._relay(client, upstream)
            return
        async with self._lock:  # one page at a time, so the next viser client id is this viewer's
            self._pending, _ = viewer, self._connected.clear()
            upstream = await self._connect(client, protocols)
            if upstream is None:
                self._pending = None
                return
            # relay at once: viser reports a client only after its first message (the camera)
            relay = asyncio.create_task(self._relay(client, upstream))
            await asyncio.to_thread(self._connected.wait, CONNECT_WAIT)
            self._pending = None
        await relay

    async def _connect(self, client: WebSocket, protocols: list[str]):
        """Open the upstream websocket to viser and accept the client's; None if viser is not there."""
        try:
            upstream = await websockets.connect(f"ws://{self.base}", subprotocols=protocols or None,
                                                max_size=None, ping_interval=None, compression=None)
        except OSError:
            await client.close(code=1011)
            return None
        await client.accept(subprotocol=upstream.subprotocol)
        return upstream

    @staticmethod
    async def _relay(client: WebSocket, upstream) -> None:
        async def downstream() -> None:
            async for frame in upstream:
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
        except (WebSocketDisconnect, websockets.ConnectionClosed):
            pass
        finally:
            for task in tasks:
                task.cancel()
            await upstream.close()
            try:
                await client.close()
            except (RuntimeError, WebSocketDisconnect):
                pass  # the page already went
