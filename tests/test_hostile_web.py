"""The web app attacked: each test is one attack, run over real sockets against a real station and vehicle.

A token thief, a cross-site page, a DNS-rebinding page, a huge or endless
body, numbers JSON should never carry, a second viewer racing the operator's:
the station must answer each with a clear 4xx (or a refused websocket) and
keep serving the operator. The attacks that need a browser (script injected
through the 3D view, a socket to a foreign server) run in headless Chromium.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import socket
import threading
import time

import httpx
import msgspec
import pytest
import viser
import websockets
from harness import TOKEN, RunningStation, during, needs_chromium, small_scene, start_sim, wait_wall
from websockets.sync.client import connect as ws_connect

from groundstation.security import MAX_BODY, NO_HOST, Access, Gate

VIEWER = "operator-viewer-0123456789abcdef"
SUBPROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture(scope="module")
def scene():
    return small_scene()


@pytest.fixture(scope="module")
def station(scene):
    with RunningStation(scene, None) as running:
        yield running


@pytest.fixture(scope="module")
def api(station):
    with station.api() as client:
        yield client


@pytest.fixture(scope="module")
def vehicle(station, api, scene):
    """Vehicle 1, on the ground and disarmed; its onboard agent streams its map (its space: 60 m square)."""
    with start_sim(station, scene, sysid=1, start=(0.0, 0.0)) as sim:
        api.wait_vehicle(1, lambda v: v["position"] is not None and v["map"]["source"] == "vehicle",
                         sim_timeout=20, what="position and the vehicle's own map")
        yield sim


def ws_url(station: RunningStation, path: str) -> str:
    return station.base.replace("http://", "ws://") + path


def raw_request(station: RunningStation, head: str, body: bytes = b"", timeout: float = 5.0) -> bytes:
    """Send bytes as they are (no client library to tidy them up); whatever the server answers first."""
    with socket.create_connection(("127.0.0.1", station.http_port), timeout=timeout) as raw:
        raw.sendall(head.encode("latin-1") + body)
        try:
            return raw.recv(65536)
        except TimeoutError:
            return b""


# ---- 1. the 3D view must not connect anywhere else, nor run what a viser server sends ----------------------
def test_the_view_refuses_a_websocket_query(station):
    for path in ("/viz/", f"/viz/v/{VIEWER}/"):
        response = httpx.get(f"{station.base}{path}", params={"websocket": "ws://evil.example:8080"})
        assert response.status_code == 400, path
        assert "only to this station" in response.text
    assert httpx.get(f"{station.base}/viz/v/short/").status_code == 404  # not a viewer id


def test_every_response_says_nosniff_and_has_a_policy(station, api):
    for path in ("/", "/static/app.js", "/api/vehicles", "/api/nothing-here", "/viz/", "/docs"):
        response = api.get(path)
        assert response.headers["x-content-type-options"] == "nosniff", path
        policy = response.headers["content-security-policy"]
        assert "frame-ancestors 'self'" in policy or "default-src 'none'" in policy, path
    view = api.get("/viz/").headers["content-security-policy"]
    script = next(part for part in view.split(";") if part.strip().startswith("script-src"))
    assert "'unsafe-inline'" not in script and "'unsafe-eval'" not in script and "'sha256-" in script
    assert "connect-src 'self'" in view


# ---- 6. the token before the body; bodies capped --------------------------------------------------------------
def test_a_huge_body_without_the_token_is_refused_unread(station):
    head = (f"POST /api/vehicles/1/commands HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n"
            "Content-Type: application/json\r\nContent-Length: 1000000000\r\n\r\n")
    answer = raw_request(station, head)  # no body sent at all: an answer now means it was never waited for
    assert answer.startswith(b"HTTP/1.1 401"), answer[:200]


def test_a_body_over_the_cap_is_refused_even_with_the_token(station):
    head = (f"PUT /api/vehicles/1/mission HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n"
            f"Authorization: Bearer {TOKEN}\r\nContent-Length: {MAX_BODY + 1}\r\n\r\n")
    assert raw_request(station, head).startswith(b"HTTP/1.1 413")


def test_a_chunked_body_is_cut_off_at_the_cap(station, vehicle):
    head = (f"PUT /api/vehicles/1/mission HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n"
            f"Authorization: Bearer {TOKEN}\r\nTransfer-Encoding: chunked\r\n\r\n")
    chunk = b"x" * (1 << 20)
    answer = b""
    with socket.create_connection(("127.0.0.1", station.http_port), timeout=10) as raw:
        raw.sendall(head.encode())
        try:
            for _ in range(MAX_BODY // len(chunk) + 4):
                raw.sendall(f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n")
        except (BrokenPipeError, ConnectionResetError):
            pass  # it stopped listening: the answer is waiting
        answer = raw.recv(65536)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]


def test_a_body_of_exactly_the_cap_is_read_and_one_byte_more_is_refused_saying_the_cap(station, api, vehicle):
    """``MAX_BODY`` bytes are allowed, declared or chunked; one byte more is a 413 that names the cap."""
    cap = f"a request body may be at most {MAX_BODY} bytes"
    over = (
        f"POST /api/vehicles/99/commands HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n"
        f"Authorization: Bearer {TOKEN}\r\nContent-Length: {MAX_BODY + 1}\r\n\r\n"
    )
    answer = raw_request(station, over)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert json.loads(answer.split(b"\r\n\r\n", 1)[1]) == {"detail": cap}

    json_body = {"Content-Type": "application/json", **api.operator}
    declared = api.post("/api/vehicles/99/commands", content=b"x" * MAX_BODY, headers=json_body)
    assert declared.status_code == 422, declared.text[:200]  # read, and found no JSON
    chunked = api.put("/api/vehicles/1/mission", content=chunks(MAX_BODY), headers=api.operator)
    assert chunked.status_code == 422 and "not a QGC WPL 110 mission" in chunked.json()["detail"]
    too_long = api.put("/api/vehicles/1/mission", content=chunks(MAX_BODY + 1), headers=api.operator)
    assert too_long.status_code == 413 and too_long.json() == {"detail": cap}


def chunks(size: int, step: int = 1 << 20):
    """``size`` bytes in pieces (httpx sends a generator chunked, without Content-Length)."""
    for start in range(0, size, step):
        yield b"x" * min(step, size - start)


@pytest.mark.parametrize(("method", "path", "content_type"), [
    ("POST", "/api/vehicles/1/commands", "application/json"),
    ("PUT", "/api/vehicles/1/mission", "text/plain"),
])
def test_a_body_over_the_cap_is_413_naming_the_cap_on_every_route_declared_or_chunked(
        station, api, method, path, content_type):
    """A JSON route parses its body itself (FastAPI), the mission upload reads it raw: both answer a body one
    byte over the cap with the same 413 and message, whether it was declared up front or came chunked."""
    cap = {"detail": f"a request body may be at most {MAX_BODY} bytes"}
    declared = (f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n"
                f"Authorization: Bearer {TOKEN}\r\nContent-Type: {content_type}\r\n"
                f"Content-Length: {MAX_BODY + 1}\r\n\r\n")
    answer = raw_request(station, declared)  # no byte of it sent: the header alone is refused
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert json.loads(answer.split(b"\r\n\r\n", 1)[1]) == cap
    chunked = api.request(method, path, content=chunks(MAX_BODY + 1),
                          headers={"Content-Type": content_type, **api.operator})
    assert "content-length" not in chunked.request.headers  # it went chunked
    assert chunked.status_code == 413, chunked.text[:200]
    assert chunked.json() == cap


def test_a_chunked_json_body_under_the_cap_reaches_its_route_whole(station, api):
    """Read by the gate first, a chunked body still reaches the route whole: parsed, it names the action,
    and the route answers for the vehicle (there is none 99)."""
    command = json.dumps({"action": "rtl"}).encode()
    parts = (command[i:i + 3] for i in range(0, len(command), 3))
    response = api.post("/api/vehicles/99/commands", content=parts,
                        headers={"Content-Type": "application/json", **api.operator})
    assert response.request.headers.get("transfer-encoding") == "chunked"
    assert response.status_code == 404, response.text[:200]


# ---- the gate itself, message by message (ASGI, as uvicorn speaks to it) -------------------------------------
class Through:
    """One request through a ``Gate`` (cap ``max_body``) around an app that reads its body to the end and
    answers 200: what the client's side was asked for (``reads``), what the app got and what was sent back."""

    def __init__(self, messages: list[dict], headers: list[tuple[bytes, bytes]] | None = None,
                 kind: str = "http", max_body: int = 5):
        self.messages, self.reads, self.sent, self.got = list(messages), 0, [], None
        headers = [(b"host", b"127.0.0.1:8000")] if headers is None else headers
        scope = {"type": kind, "method": "POST", "path": "/api/vehicles/1/commands", "headers":
                 [(b"authorization", f"Bearer {TOKEN}".encode()), *headers], "client": ("127.0.0.1", 5000)}
        asyncio.run(Gate(self.app, Access(TOKEN), max_body=max_body)(scope, self.receive, self.send))

    async def receive(self) -> dict:
        self.reads += 1
        return self.messages.pop(0) if self.messages else {"type": "http.disconnect"}

    async def send(self, message: dict) -> None:
        self.sent.append(message)

    async def app(self, scope, receive, send) -> None:
        self.got = []
        while not self.got or self.got[-1].get("more_body"):
            self.got.append(await receive())
        self.got.append(await receive())  # after the body: what the server says next
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    @property
    def status(self) -> int | None:
        return next((m["status"] for m in self.sent if m["type"] == "http.response.start"), None)

    @property
    def detail(self) -> str:
        return json.loads(b"".join(m.get("body", b"") for m in self.sent if m["type"] == "http.response.body"))[
            "detail"]


def part(body: bytes, more: bool) -> dict:
    return {"type": "http.request", "body": body, "more_body": more}


def test_a_body_in_pieces_up_to_the_cap_reaches_the_app_whole_then_what_follows():
    request = Through([part(b"ab", True), part(b"", True), part(b"cde", False)])
    assert request.got == [part(b"abcde", False), {"type": "http.disconnect"}]  # one message, then the server's
    assert request.reads == 4 and request.status == 200  # three for the body, one when the app asked again


def test_a_body_one_byte_over_the_cap_in_its_last_piece_is_413_and_never_reaches_the_app():
    for pieces in ([part(b"abcde", True), part(b"f", False)], [part(b"abc", True), part(b"def", True)]):
        request = Through(pieces)
        assert request.got is None and request.reads == 2, pieces
        assert request.status == 413 and request.detail == "a request body may be at most 5 bytes", pieces


def test_a_body_over_the_cap_is_not_read_past_the_piece_that_passed_it():
    request = Through([part(b"abcdef", True), part(b"g" * 100, True), part(b"", False)])
    assert request.got is None and request.reads == 1
    assert request.status == 413 and request.detail == "a request body may be at most 5 bytes"


def test_a_body_declared_over_the_cap_is_413_unread():
    for length in (b"6", b"-1", b"5 ", b"0x5"):
        request = Through([part(b"abc", False)], headers=[(b"host", b"127.0.0.1"), (b"content-length", length)])
        assert request.got is None and request.reads == 0, length
        assert request.status == 413 and request.detail == "a request body may be at most 5 bytes", length
    declared = Through([part(b"abcde", False)], headers=[(b"host", b"127.0.0.1"), (b"content-length", b"5")])
    assert declared.got == [part(b"abcde", False), {"type": "http.disconnect"}] and declared.status == 200


def test_a_request_message_without_body_or_more_body_is_an_empty_body_that_ends():
    """ASGI's defaults: no ``body`` is empty, no ``more_body`` means the body ended."""
    request = Through([{"type": "http.request"}, part(b"never read", False)])
    assert request.got == [part(b"", False), part(b"never read", False)]
    assert request.reads == 2 and request.status == 200


def test_a_client_gone_before_its_body_ended_gets_no_answer_and_reaches_no_app():
    request = Through([part(b"ab", True), {"type": "http.disconnect"}])
    assert request.got is None and request.sent == [] and request.reads == 2


def test_a_request_with_no_host_name_or_an_empty_one_is_refused_unread_at_the_gate():
    for headers in ([], [(b"host", b"")]):
        request = Through([part(b"{}", False)], headers=headers)
        assert request.got is None and request.reads == 0, headers
        assert request.status == 400 and request.detail == NO_HOST, headers
    socket_ = Through([], headers=[], kind="websocket")
    assert socket_.sent == [{"type": "websocket.close", "code": 1008, "reason": NO_HOST}]


# ---- 7. a viewer's clicks reach that viewer's page only -------------------------------------------------------
def camera_message() -> bytes:
    return msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, -10.0, 10.0], "fov": 1.0,
        "near": 0.01, "far": 1000.0, "image_height": 480, "image_width": 640, "look_at": [0.0, 0.0, 0.0],
        "up_direction": [0.0, 0.0, 1.0]})


def click_message(x: float, y: float) -> bytes:
    return msgspec.msgpack.encode({
        "type": "ScenePointerMessage", "event_type": "click", "ray_origin": [x, y, 30.0],
        "ray_direction": [0.0, 0.0, -1.0], "screen_pos": [[0.5, 0.5]], "modifier": None})


def targets(stream, seconds: float) -> list[dict]:
    """The target notes a /ws stream brings within ``seconds``."""
    found = []
    for left in during(seconds):
        try:
            frame = json.loads(stream.recv(timeout=max(0.01, left)))
        except TimeoutError:
            break
        if frame.get("type") == "target":
            found.append(frame)
    return found


def test_a_racing_client_cannot_become_the_operators_viewer(station):
    clients = station.station.view.server.get_clients
    # the view sockets keep taking what viser sends (max_queue=None), as a browser does: a client that stops
    # reading its socket cannot close it before its close timeout, 10 s (this test took 37 s so)
    views = {"subprotocols": [SUBPROTOCOL], "max_size": None, "max_queue": None}
    with ws_connect(ws_url(station, f"/ws?viewer={VIEWER}")) as stream, \
            ws_connect(ws_url(station, "/viz"), **views) as intruder, \
            ws_connect(ws_url(station, f"/viz/v/{VIEWER}"), **views) as view:
        before = len(clients())
        intruder.send(camera_message())  # its first message while the operator's view is connecting
        wait_wall(lambda: len(clients()) == before + 1, 10, "viser knows the intruder")
        view.send(camera_message())
        wait_wall(lambda: VIEWER in station.station.proxy.viewers.values(), 10, "the operator's view is tied")
        intruder.send(click_message(3.0, -2.0))
        assert targets(stream, 2.0) == []  # the intruder's click is nobody's target
        view.send(click_message(-2.0, 1.0))
        assert [(t["x"], t["y"]) for t in targets(stream, 5.0)] == [(-2.0, 1.0)]
        with pytest.raises(websockets.InvalidStatus):  # a second connection cannot claim a live viewer id
            ws_connect(ws_url(station, f"/viz/v/{VIEWER}"), subprotocols=[SUBPROTOCOL]).recv(timeout=5)
    wait_wall(lambda: not station.station.proxy.viewers, 10, "ties released when the views close")


def test_connections_arriving_together_cannot_share_a_viewer_id(station):
    """Five sockets asking for one viewer id at the same moment: one gets it, the others are refused, and the
    id is free again once its holder closed (the claim was made only after connecting upstream, so all five
    opened, and the first to close freed the id while another still held it)."""
    viewer = "together-0123456789abcdef"

    async def race() -> list:
        return await asyncio.gather(*(websockets.connect(ws_url(station, f"/viz/v/{viewer}"),
                                                         subprotocols=[SUBPROTOCOL], max_size=None)
                                      for _ in range(5)), return_exceptions=True)

    async def attempt() -> None:
        opened = [c for c in await race() if not isinstance(c, Exception)]
        refused = [c for c in await race() if isinstance(c, websockets.InvalidStatus)]
        assert len(opened) == 1 and len(refused) == 5  # while one holds it, nobody else gets it
        await opened[0].close()
        await asyncio.sleep(0.5)
        again = [c for c in await race() if not isinstance(c, Exception)]
        assert len(again) == 1
        await again[0].close()

    asyncio.run(attempt())
    wait_wall(lambda: viewer not in station.station.proxy._claimed, 10, "the id released")


def test_garbage_on_the_view_socket_harms_no_one_else(station):
    for junk in (b"\xc1\xff\x00", "text viser never expects", msgspec.msgpack.encode({"type": "NoSuchMessage"})):
        with ws_connect(ws_url(station, "/viz"), subprotocols=[SUBPROTOCOL]) as hostile:
            hostile.send(junk)
            time.sleep(0.2)
    with ws_connect(ws_url(station, "/viz"), subprotocols=[SUBPROTOCOL], max_size=None) as view:
        view.send(camera_message())
        assert isinstance(view.recv(timeout=10), bytes)  # viser still serves a new client


# ---- 8. Host and Origin ---------------------------------------------------------------------------------------
def test_a_foreign_host_name_is_refused(station, api):
    for path in ("/", "/api/vehicles", "/api/recordings"):
        response = api.get(path, headers={"Host": "rebind.attacker.example"})
        assert response.status_code == 421, path
        assert response.json()["detail"] == "this station does not serve that host name (see --allowed-host)"
    assert api.get("/api/vehicles", headers={"Host": f"localhost:{station.http_port}"}).status_code == 200
    assert api.get("/api/vehicles", headers={"Host": f"[::1]:{station.http_port}"}).status_code == 200


def test_a_host_name_that_names_nothing_or_breaks_the_parser_is_refused_as_foreign(station):
    """A Host with a port but no name, a bare ``@``, or a broken IPv6 literal is a 421 like any foreign
    name: never served, never a 500."""
    for host in (f":{station.http_port}", "@", "[]", "[zz", "[::1"):
        answer = raw_request(station, f"GET /api/health HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n")
        assert answer.startswith(b"HTTP/1.1 421"), (host, answer[:100])
        detail = json.loads(answer.split(b"\r\n\r\n", 1)[1])["detail"]
        assert detail == "this station does not serve that host name (see --allowed-host)", host
    assert not Access(TOKEN, allowed_hosts=frozenset({""})).host_allowed(":8000")  # no name is no allowed name


def test_a_websocket_whose_origin_breaks_the_parser_is_refused(station, monkeypatch):
    """An Origin with a broken IPv6 literal names no page of ours: the socket is refused (403), not a 500."""
    monkeypatch.setattr("groundstation.security.LOG_EVERY", 0.0)  # no refusal held back to be counted later
    head = (f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n")
    for origin in ("http://[zz", "http://[127.0.0.1"):
        answer = raw_request(station, f"{head}Origin: {origin}\r\n\r\n")
        assert answer.startswith(b"HTTP/1.1 403"), (origin, answer[:100])
    assert raw_request(station, f"{head}Origin: http://127.0.0.1:{station.http_port}\r\n\r\n").startswith(
        b"HTTP/1.1 101")  # the same handshake from our own page is taken


def test_a_request_naming_no_host_name_is_refused_as_such(station, caplog, monkeypatch):
    """HTTP/1.0 needs no Host header, and an empty one names nothing: either is a 400 saying so, logged,
    whatever the path (the page, the API, a write with the token), never served as if it named a host."""
    monkeypatch.setattr("groundstation.security.LOG_EVERY", 0.0)  # each refusal logged, whatever came before
    caplog.set_level(logging.WARNING, logger="groundstation")
    heads = [
        "GET /api/vehicles HTTP/1.0\r\n\r\n",
        "GET / HTTP/1.0\r\n\r\n",
        f"POST /api/vehicles/1/commands HTTP/1.0\r\nAuthorization: Bearer {TOKEN}\r\nContent-Length: 2\r\n\r\n{{}}",
        "GET /api/health HTTP/1.1\r\nHost: \r\nConnection: close\r\n\r\n",
    ]
    for head in heads:
        answer = raw_request(station, head)
        assert answer.startswith(b"HTTP/1.1 400"), (head, answer[:100])
        assert json.loads(answer.split(b"\r\n\r\n", 1)[1]) == {"detail": NO_HOST}, head
    said = [record.getMessage() for record in caplog.records]
    assert sum(message.endswith(f": {NO_HOST}") for message in said) == len(heads), said


def test_a_name_given_with_allowed_host_is_served(scene):
    with RunningStation(None, None, access=Access(TOKEN, allowed_hosts=frozenset({"station.lan"}))) as running:
        assert httpx.get(f"{running.base}/api/health", headers={"Host": "station.lan:80"}).status_code == 200
        assert httpx.get(f"{running.base}/api/health", headers={"Host": "other.lan"}).status_code == 421


def test_websockets_from_a_foreign_origin_are_refused(station, caplog, monkeypatch):
    monkeypatch.setattr("groundstation.security.LOG_EVERY", 0.0)  # each refusal logged, whatever came before
    caplog.set_level(logging.WARNING, logger="groundstation")
    for path in ("/ws", "/viz", f"/viz/v/{VIEWER}"):
        with pytest.raises(websockets.InvalidStatus) as refused:
            ws_connect(ws_url(station, path), origin="http://evil.example", subprotocols=[SUBPROTOCOL])
        assert refused.value.response.status_code == 403, path
    said = [record.getMessage() for record in caplog.records]
    assert sum(message.endswith(": websockets only from this station's own pages") for message in said) == 3, said
    with ws_connect(ws_url(station, "/ws"), origin=station.base) as own:  # the station's own page
        assert json.loads(own.recv(timeout=5))["type"] == "vehicles"


def test_the_stations_own_origin_by_name_or_over_https_may_open_a_websocket(station):
    """A page of the station's own, opened by the name ``localhost`` (in any case) or served over TLS, may
    open the stream: its Origin names the host the browser asked, which is all that is compared."""
    port = station.http_port
    for url, origin in (
        (f"ws://localhost:{port}/ws", f"http://localhost:{port}"),
        (f"ws://LocalHost:{port}/ws", f"http://localhost:{port}"),
        (f"ws://127.0.0.1:{port}/ws", f"https://127.0.0.1:{port}"),
    ):
        with ws_connect(url, origin=origin) as own:
            assert json.loads(own.recv(timeout=5))["type"] == "vehicles", (url, origin)
    with pytest.raises(websockets.InvalidStatus) as refused:  # the same host under another scheme is not a page
        ws_connect(f"ws://127.0.0.1:{port}/ws", origin=f"ftp://127.0.0.1:{port}")
    assert refused.value.response.status_code == 403


# ---- 9. 4xx, never 500 ------------------------------------------------------------------------------------
def post_raw_json(api, text: str, sysid: int = 1, headers: dict | None = None) -> httpx.Response:
    return api.post(f"/api/vehicles/{sysid}/commands", content=text.encode("utf-8"),
                    headers={"Content-Type": "application/json", **(api.operator if headers is None else headers)})


@pytest.mark.parametrize("body", [
    '{"action": "takeoff", "altitude": NaN}', '{"action": "takeoff", "altitude": Infinity}',
    '{"action": "takeoff", "altitude": 1e300}', '{"action": "speed", "speed": NaN}',
    '{"action": "speed", "speed": -Infinity}', '{"action": "goto", "x": NaN, "y": 0}',
    '{"action": "goto", "x": 0, "y": Infinity}', '{"action": "goto", "x": 1e7, "y": 0}',
    '{"action": "goto", "x": 1e300, "y": 1e300}', '{"action": "kill", "confirm": "yes"}',
    '{"action": "kill", "confirm": 1}', '{"action": "set_mode", "mode": "' + "G" * 5000 + '"}',
    '{"action": "goto", "x": "5", "y": 0}', '{"action": "goto", "x": true, "y": 0}',  # flew to (5, 0) and (1, 0)
    '{"action": "speed", "speed": "2"}', '{"action": "set_mode", "mode": 4}',
])
def test_unusable_numbers_and_lax_truths_are_422(api, vehicle, body):
    response = post_raw_json(api, body)
    assert response.status_code == 422, (body[:60], response.status_code, response.text[:200])
    assert "NaN" not in response.text and "Infinity" not in response.text
    assert response.json()["detail"]


def test_kill_needs_json_true(api, vehicle):
    assert post_raw_json(api, '{"action": "kill", "confirm": true}').status_code == 200


def test_a_goto_outside_the_vehicles_space_is_refused_before_sending(station, api, vehicle):
    sent = station.station.link.stats["sent"]
    response = api.command(1, action="goto", x=500.0, y=0.0)
    assert response.status_code == 422
    assert "outside vehicle 1's space" in response.json()["detail"]
    time.sleep(0.2)
    beats = station.station.link.stats["sent"] - sent
    assert beats <= 2  # at most the heartbeats of the moment: no command went out


def test_a_non_ascii_token_is_401(station):
    head = (f"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1:{station.http_port}\r\n").encode() + \
        "Authorization: Bearer ÿÿ-токен\r\n\r\n".encode()
    with socket.create_connection(("127.0.0.1", station.http_port), timeout=5) as raw:
        raw.sendall(head)
        assert raw.recv(65536).startswith(b"HTTP/1.1 401")


@pytest.mark.parametrize("body", ['{"seek": NaN}', '{"step": true}', '{"step": 0}', '{"seek": "3"}'])
def test_replay_control_rejects_what_is_no_such_number(api, body):
    response = api.post("/api/replay/control", content=body.encode(),
                        headers={"Content-Type": "application/json", **api.operator})
    assert response.status_code == 422, body


HOME = "QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.363261\t149.165230\t584\t1\n"


@pytest.mark.parametrize(("text", "reason"), [
    ("QGC WPL 110\n" + "".join(f"{i}\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n" for i in range(65536)),
     "at most 65535"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\tnan\t149.16\t0\t1\n", "not a number"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36\tinf\t0\t1\n", "not a number"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-135.36\t149.16\t0\t1\n", "not on Earth"),
    ("QGC WPL 110\n0 1 0 16 0 0 0\n", "not a QGC WPL 110 mission"),
    ("A" * 2_000_000 + "\n", "its first line names no waypoint format mavwp reads"),  # was echoed whole: 2 MB
    (HOME + "1\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t1e39\t1\n", "altitude beyond"),  # was a 500
    (HOME + "1\t0\t3\t16\t3.5e38\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "float32"),  # was a 500
    (HOME + "1\t0\t3\t16\t0\t0\t0\t0\t1_0\t149.16\t10\t1\n", "line 3: field 9 is not a decimal number"),
    (HOME + "1\t0\t3\t16\t0x10\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "field 5 is not a decimal number"),
    (HOME + "1\t0\t3.0\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "field 3 is not a whole number (frame)"),
    (HOME + "1\t0\t200\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "out of range"),  # no MAV_FRAME
    (HOME + "5\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "numbered 0, 1, 2, ... in order"),
    (HOME + "1\t7\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n", "'current' is 0 or 1"),
])
def test_a_mission_mavlink_cannot_carry_is_422_naming_no_path(api, vehicle, text, reason):
    before = api.get("/api/vehicles/1/mission").text
    response = api.put("/api/vehicles/1/mission", content=text.encode(), headers=api.operator)
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert reason in detail and "/tmp" not in detail and ".waypoints" not in detail and len(detail) < 300
    assert api.get("/api/vehicles/1/mission").text == before  # the vehicle's mission is untouched


def test_a_mission_with_comments_blank_lines_and_nan_params_is_taken(api, vehicle):
    """What planners write and MAVLink allows still goes: comment and blank lines, signs and exponents, and
    NaN in a parameter where it means "leave unchanged" (QGroundControl writes a waypoint's yaw, param4, so)."""
    text = (HOME + "# a comment\n\n1\t0\t3\t16\t0\t+0\t.5\tnan\t-3.536E1\t149.16\t10\t1\n")
    response = api.put("/api/vehicles/1/mission", content=text.encode(), headers=api.operator)
    assert response.status_code == 200 and response.json() == {"result": "accepted", "items": 2}


# ---- 10. nothing left behind ----------------------------------------------------------------------------------
def test_streams_leave_nothing_behind_and_are_capped(station, monkeypatch):
    import groundstation.api.streams as app

    for n in range(200):
        with ws_connect(ws_url(station, f"/ws?viewer=passing-viewer-{n:06d}")) as passing:
            passing.recv(timeout=5)
    wait_wall(lambda: not station.station._inboxes, 10, "every stream's inbox forgotten")
    with pytest.raises(websockets.InvalidStatus):
        ws_connect(ws_url(station, "/ws?viewer=bad id!"))
    monkeypatch.setattr(app, "MAX_STREAMS", 2)
    with ws_connect(ws_url(station, "/ws")), ws_connect(ws_url(station, "/ws")):
        with pytest.raises(websockets.InvalidStatus) as refused:
            ws_connect(ws_url(station, "/ws"))
        assert refused.value.response.status_code == 403
    with ws_connect(ws_url(station, "/ws")) as later:  # room again once they went
        assert json.loads(later.recv(timeout=5))["type"] == "vehicles"


# ---- viewers beyond loopback ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def guarded():
    """A station as it is served beyond loopback: watching needs the viewer or the operator token."""
    with RunningStation(None, None, access=Access(TOKEN, "viewer-token-1234", viewing_needs_token=True)) as running:
        yield running


def test_beyond_loopback_watching_needs_a_token(guarded):
    base, viewer = guarded.base, {"Authorization": "Bearer viewer-token-1234"}
    for path in ("/api/vehicles", "/api/health", "/api/recordings", "/viz/", "/openapi.json"):
        assert httpx.get(base + path).status_code == 401, path
        assert httpx.get(base + path, headers=viewer).status_code == 200, path
    assert httpx.get(base + "/").status_code == 200  # the page itself, to sign in
    assert httpx.get(base + "/static/app.js").status_code == 200
    with pytest.raises(websockets.InvalidStatus):
        ws_connect(ws_url(guarded, "/ws"))
    assert httpx.post(base + "/api/vehicles/1/commands", json={"action": "rtl"}, headers=viewer).status_code == 401


def test_a_session_cookie_lets_a_browser_watch(guarded):
    refused = httpx.post(guarded.base + "/api/session", headers={"Authorization": "Bearer wrong"})
    assert refused.status_code == 401
    granted = httpx.post(guarded.base + "/api/session", headers={"Authorization": "Bearer viewer-token-1234"})
    assert granted.status_code == 204
    cookie = granted.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie.replace("Strict", "strict")
    name, value = cookie.split(";")[0].split("=", 1)
    with httpx.Client(base_url=guarded.base, cookies={name: value}) as browser:
        assert browser.get("/api/vehicles").status_code == 200
        assert browser.get(f"/viz/v/{VIEWER}/").status_code == 200
        assert browser.post("/api/vehicles/1/commands", json={"action": "rtl"}).status_code == 401  # still no
    with ws_connect(ws_url(guarded, "/ws"), additional_headers={"Cookie": f"{name}={value}"}) as stream:
        assert json.loads(stream.recv(timeout=5))["type"] == "vehicles"


EXPOSED_VIEWER = "a viewer pass phrase 5678"  # spaces and all, as a person may choose one


@pytest.fixture(scope="module")
def exposed():
    """The policy of a station bound to 192.0.2.7 with a viewer token and ``--allowed-host Station.LAN``
    (served on loopback for the test: the address only picks the policy)."""
    access = Access.for_host("192.0.2.7", TOKEN, EXPOSED_VIEWER, ("Station.LAN",))
    with RunningStation(None, None, access=access) as running:
        yield running


def test_a_station_bound_beyond_loopback_asks_a_token_to_watch_and_serves_its_allowed_names(exposed):
    """Bound beyond loopback, watching needs the viewer's or the operator's token, and a name given with
    ``--allowed-host`` is served whatever its case, while other names are refused."""
    base, port = exposed.base, exposed.http_port
    viewer, operator = {"Authorization": f"Bearer {EXPOSED_VIEWER}"}, {"Authorization": f"Bearer {TOKEN}"}
    assert httpx.get(base + "/api/vehicles").status_code == 401
    assert httpx.get(base + "/api/vehicles", headers=viewer).status_code == 200
    assert httpx.get(base + "/api/vehicles", headers=operator).status_code == 200
    assert httpx.post(base + "/api/vehicles/1/commands", json={"action": "rtl"}, headers=viewer).status_code == 401
    for name in ("station.lan", "STATION.lan"):
        assert httpx.get(base + "/api/health", headers={**viewer, "Host": f"{name}:{port}"}).status_code == 200, name
    assert httpx.get(base + "/api/health", headers={**viewer, "Host": f"other.lan:{port}"}).status_code == 421


def test_an_empty_viewer_token_lets_no_one_watch_beyond_loopback():
    """``--viewer-token ''`` is no viewer token: an empty bearer token neither watches nor gets a session."""
    access = Access.for_host("192.0.2.7", TOKEN, "")
    assert access.viewer_token is None and access.viewing_needs_token
    for header in ("Bearer ", "Bearer"):
        assert not access.may_view(header, None) and not access.grants_session(header), header
    assert access.may_view(f"Bearer {TOKEN}", None)


def test_a_viewer_token_with_spaces_in_it_is_traded_for_a_session(exposed):
    """The whole viewer token after ``Bearer`` counts, spaces in it too: it gets a session cookie that
    watches, as the same header watches itself."""
    granted = httpx.post(exposed.base + "/api/session", headers={"Authorization": f"Bearer {EXPOSED_VIEWER}"})
    assert granted.status_code == 204, granted.text
    name, value = granted.headers["set-cookie"].split(";")[0].split("=", 1)
    with httpx.Client(base_url=exposed.base, cookies={name: value}) as browser:
        assert browser.get("/api/vehicles").status_code == 200
    half = httpx.post(exposed.base + "/api/session", headers={"Authorization": "Bearer phrase 5678"})
    assert half.status_code == 401  # the token's last words alone are not the token


def test_a_cookie_other_than_the_session_is_no_token_to_watch(exposed):
    """A browser's other cookies (or junk in the Cookie header) neither let it watch nor break the
    station: a clear 401, and the session cookie among other cookies still counts."""
    for cookie in ("theme=dark", "theme=dark; lang=en", '=;; "junk;=='):
        refused = httpx.get(exposed.base + "/api/vehicles", headers={"Cookie": cookie})
        assert refused.status_code == 401, (cookie, refused.status_code)
        assert refused.json()["detail"] == "watching this station needs a token (the viewer or the operator token)"
    granted = httpx.post(exposed.base + "/api/session", headers={"Authorization": f"Bearer {TOKEN}"})
    session = granted.headers["set-cookie"].split(";")[0]
    assert httpx.get(exposed.base + "/api/vehicles", headers={"Cookie": f"theme=dark; {session}"}).status_code == 200


# ---- in the browser -------------------------------------------------------------------------------------------


@needs_chromium
@pytest.mark.browser
def test_script_a_viser_server_sends_does_not_run(station, browser):
    server = station.station.view.server
    page = browser.new_page()
    try:
        page.goto(f"{station.base}/viz/v/{VIEWER}/")
        page.wait_for_selector("canvas", state="attached", timeout=30_000)
        with server.gui.add_modal("Injected"):  # as a foreign viser server would: HTML with a handler in it
            server.gui.add_html('<img id="injected" src="/no-such-image" onerror="window.__stolen = 1">')
        page.wait_for_selector("#injected", state="attached", timeout=30_000)
        page.wait_for_timeout(500)
        assert page.evaluate("window.__stolen") is None
    finally:
        page.close()


@needs_chromium
@pytest.mark.browser
def test_the_view_cannot_open_a_socket_to_another_server(station, browser):
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(2.0)
    foreign = f"ws://127.0.0.1:{listener.getsockname()[1]}/"
    page = browser.new_page()
    try:
        page.goto(f"{station.base}/viz/v/{VIEWER}/")
        outcome = page.evaluate("""url => new Promise(resolve => {
            document.addEventListener('securitypolicyviolation', e => resolve('blocked: ' + e.violatedDirective));
            try { new WebSocket(url); } catch (error) { resolve('blocked: ' + error.name); }
            setTimeout(() => resolve('not blocked'), 3000);
        })""", foreign)
        assert outcome.startswith("blocked"), outcome
        with pytest.raises(TimeoutError):
            listener.accept()  # and nothing ever knocked
    finally:
        page.close()
        listener.close()


@needs_chromium
@pytest.mark.browser
def test_the_api_page_needs_nothing_from_the_internet(station, browser):
    page = browser.new_page()
    foreign = []
    page.on("request", lambda request: foreign.append(request.url) if not request.url.startswith(station.base)
            else None)
    try:
        page.goto(f"{station.base}/docs")
        page.wait_for_selector(".opblock", timeout=30_000)
        assert foreign == []
    finally:
        page.close()



@needs_chromium
@pytest.mark.browser
def test_the_page_asks_a_token_to_watch_and_a_viewer_token_only_watches(guarded, browser):
    from playwright.sync_api import expect

    context = browser.new_context()  # a browser of its own: no cookie from before
    page = context.new_page()
    try:
        page.goto(guarded.base + "/")
        expect(page.locator("#watch-hint")).to_be_visible()
        expect(page.locator("#connection-text")).to_have_text("this station needs a token to watch: sign in")
        assert page.locator("#view").get_attribute("src") is None  # no 3D view to refuse

        page.fill("#token", "viewer-token-1234")
        page.click("#sign-in")
        expect(page.locator("#auth-status")).to_have_text("Watching (the viewer token cannot command)")
        expect(page.locator("#watch-hint")).to_be_hidden()
        expect(page.locator("#connection-text")).to_have_text("connected", timeout=15_000)
        assert page.locator("#view").get_attribute("src").startswith("/viz/v/")
        view = page.frame_locator("#view")
        expect(view.locator("canvas").first).to_be_attached(timeout=30_000)  # viser's page, not a 401
        expect(page.locator("#go-here")).to_be_disabled()

        page.click("#sign-out")
        page.fill("#token", TOKEN)
        page.click("#sign-in")
        expect(page.locator("#auth-status")).to_have_text("Signed in")
    finally:
        context.close()


@needs_chromium
@pytest.mark.browser
def test_the_page_says_when_a_link_is_down(browser):
    from playwright.sync_api import expect

    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))  # a port nothing listens on
    port = closed.getsockname()[1]
    with RunningStation(None, None, urls=[f"tcp:127.0.0.1:{port}"]) as running:
        page = browser.new_page()
        try:
            page.goto(running.base + "/")
            banner = page.locator("#health-banner")
            expect(banner).to_be_visible(timeout=15_000)
            expect(banner.locator("li").first).to_have_text(re.compile(rf"^MAVLink tcp:127\.0\.0\.1:{port} is down"))
        finally:
            page.close()
    closed.close()


@needs_chromium
@pytest.mark.browser
def test_the_page_says_when_a_vehicle_flies_far_from_the_scene(browser):
    """A vehicle in Zurich, placed by a datum in Canberra, was drawn 15,700 km away: the 3D view showed the scene
    alone and nothing said why. A vehicle in the scene is no such case."""
    from mavlink_peer import Peer, position, vehicle_heartbeat
    from playwright.sync_api import expect

    with RunningStation(small_scene(), None) as running:
        with Peer(("127.0.0.1", running.mavlink_port), sysid=7) as zurich, \
                Peer(("127.0.0.1", running.mavlink_port), sysid=8) as here:

            def far():
                zurich.send(vehicle_heartbeat(), position(47.3769, 8.5417))
                here.send(vehicle_heartbeat(), position())  # at the datum: the scene's origin
                health = running.http.get("/api/health").json()
                return health["vehicles"] == 2 and health["far_from_scene"]

            listed = wait_wall(far, 10, "the far vehicle listed")
            assert [v["sysid"] for v in listed] == [7] and 15_000 < listed[0]["km"] < 17_000
            page = browser.new_page()
            try:
                page.goto(running.base + "/")
                banner = page.locator("#health-banner")
                expect(banner).to_be_visible(timeout=15_000)
                expect(banner.locator("li").first).to_have_text(re.compile(
                    r"^vehicle 7 is 15,\d{3}\.\d km from the scene: is the station's datum where it flies\?"))
            finally:
                page.close()


@needs_chromium
@pytest.mark.browser
def test_the_page_says_when_messages_in_a_vehicles_name_come_from_elsewhere(browser):
    """The station drops them (they moved the vehicle on the page); the operator should know someone sends them."""
    from mavlink_peer import Peer, position, vehicle_heartbeat
    from playwright.sync_api import expect

    with RunningStation(small_scene(), None) as running:
        address = ("127.0.0.1", running.mavlink_port)
        with Peer(address, sysid=9) as vehicle, Peer(address, sysid=9) as attacker:
            beating = threading.Event()

            def beat():  # its heartbeat keeps coming, so its place stays its own
                while not beating.wait(0.5):
                    vehicle.send(vehicle_heartbeat(), position())

            threading.Thread(target=beat, daemon=True).start()
            wait_wall(lambda: running.http.get("/api/health").json()["vehicles"] == 1, 10, "the vehicle heard")
            page = browser.new_page()
            try:
                page.goto(running.base + "/")
                banner = page.locator("#health-banner")
                expect(banner).to_have_attribute("data-checked", "200")
                expect(banner).to_be_hidden()
                attacker.send(*[position(47.3769, 8.5417)] * 5)
                wait_wall(lambda: running.http.get("/api/health").json()["link"]["from_elsewhere"], 10,
                          "the station counting them")
                page.reload()  # its first look (a page's timers may be slowed while another page is in front)
                expect(banner).to_be_visible(timeout=15_000)
                expect(banner.locator("li").first).to_have_text(
                    "vehicle 9: 5 messages in its autopilot's name dropped, from elsewhere than its heartbeat "
                    "(a second link to it, or someone sending as it)")
            finally:
                beating.set()
                page.close()


@needs_chromium
@pytest.mark.browser
def test_a_healthy_station_shows_no_health_banner(station, browser):
    from playwright.sync_api import expect

    page = browser.new_page()
    try:
        page.goto(station.base + "/")
        expect(page.locator("#health-banner")).to_have_attribute("data-checked", "200")  # it has looked
        assert page.locator("#health-banner").is_hidden()
        assert station.http.get("/api/health").json()["status"] == "ok"
    finally:
        page.close()
