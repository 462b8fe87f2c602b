"""What may reach the web app at all: checked before any route runs, and before any request body is read.

Every request must name a Host the station serves under (an IP address,
``localhost`` or one given with ``--allowed-host``), so a page on a foreign
domain cannot reach it through DNS rebinding; a request that names no host at
all is refused too. A browser's websocket must come from the station's own
pages (its Origin names the same host), so another site cannot read live
telemetry. Anything that changes state (POST, PUT, DELETE
under ``/api/``) needs the operator token in ``Authorization`` before its body
is read, and no body may exceed ``MAX_BODY``: the Gate reads a body whole before
any route runs, so one over the cap gets the same 413 on every route whether it
was declared (``Content-Length``) or chunked. When the station serves beyond
loopback, watching needs a token too: the operator's or the read-only viewer
token, as a bearer header or as the cookie ``POST /api/session`` sets (a
browser cannot put headers on a frame or a websocket). Every response says
``nosniff`` and carries a Content-Security-Policy unless its route set a
stricter one of its own.

Written as plain ASGI middleware (not Starlette's ``BaseHTTPMiddleware``) so
it sees websockets too and can refuse a request while its body is still unread.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import logging
import time
from dataclasses import dataclass, field
from http.cookies import SimpleCookie
from urllib.parse import urlsplit

MAX_BODY = 8 << 20  # bytes: a mission of 65,535 waypoints is about 6 MB of WPL text
NO_HOST = "the request names no host (a Host header is required)"
SESSION_COOKIE = "scanstation_view"
WRITES = {"POST", "PUT", "DELETE", "PATCH"}
PUBLIC = ("/static/",)  # the page and its files: the sign-in form must load without a token
PUBLIC_EXACT = {"/", "/favicon.ico", "/api/session"}
PAGE_POLICY = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
               "connect-src 'self'; frame-src 'self'; frame-ancestors 'self'; base-uri 'none'; "
               "form-action 'self'; object-src 'none'")
LOG_EVERY = 10.0  # s: a refusal's reason is logged at most this often (with how many since), however many come
log = logging.getLogger("groundstation.security")
COMMON_HEADERS = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                  (b"x-frame-options", b"SAMEORIGIN")]


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _same(secret: str, offered: str) -> bool:
    """Constant-time comparison that any header value survives (non-ASCII included)."""
    return hmac.compare_digest(offered.encode("utf-8", "surrogateescape"), secret.encode("utf-8"))


@dataclass(frozen=True)
class Access:
    """Who may do what: the operator token commands; viewing is open on loopback, else it needs a token."""

    operator_token: str
    viewer_token: str | None = None
    viewing_needs_token: bool = False
    allowed_hosts: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def for_host(cls, bound: str, operator_token: str, viewer_token: str | None = None,
                 allowed_hosts: tuple[str, ...] = ()) -> Access:
        """The policy for a station bound to ``bound``: beyond loopback, watching needs a token."""
        return cls(operator_token, viewer_token or None, not is_loopback(bound),
                   frozenset(name.lower() for name in allowed_hosts))

    def is_operator(self, authorization: str | None) -> bool:
        scheme, _, token = (authorization or "").partition(" ")
        return scheme.lower() == "bearer" and _same(self.operator_token, token.strip())

    def may_view(self, authorization: str | None, cookie: str | None) -> bool:
        if not self.viewing_needs_token or self.is_operator(authorization):
            return True
        scheme, _, token = (authorization or "").partition(" ")
        if scheme.lower() == "bearer" and self.viewer_token is not None and _same(self.viewer_token, token.strip()):
            return True
        session = _cookie(cookie, SESSION_COOKIE)
        return session is not None and _same(self.session_value(), session)

    def session_value(self) -> str:
        """What the viewing cookie holds: derived from the operator token, so a restart with a new token
        ends every session."""
        return hmac.new(self.operator_token.encode("utf-8"), b"view", hashlib.sha256).hexdigest()

    def grants_session(self, authorization: str | None) -> bool:
        scheme, _, token = (authorization or "").partition(" ")
        token = token.strip()
        return scheme.lower() == "bearer" and (
            _same(self.operator_token, token) or (self.viewer_token is not None and _same(self.viewer_token, token)))

    def host_allowed(self, host_header: str) -> bool:
        """An IP address (no rebinding through a literal), localhost, or a name the operator allowed."""
        try:
            host = urlsplit(f"//{host_header}").hostname  # None for an empty header or one without a name
        except ValueError:  # a broken [IPv6] literal ("[", "[]", "[zz")
            return False
        if host is None:
            return False
        if host == "localhost" or host in self.allowed_hosts:
            return True
        try:
            ipaddress.ip_address(host)
        except ValueError:
            return False
        return True


def same_origin(origin: str, host_header: str) -> bool:
    """A browser's Origin names the host (and port) it asked: the page is one of ours."""
    try:
        parts = urlsplit(origin)
    except ValueError:  # a broken [IPv6] literal
        return False
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host_header.lower()


def _cookie(header: str | None, name: str) -> str | None:
    if not header:
        return None
    jar = SimpleCookie()
    try:
        jar.load(header)
    except Exception:  # noqa: BLE001 - http.cookies raises its own CookieError and others on junk
        return None
    return jar[name].value if name in jar else None


class Gate:
    """ASGI middleware enforcing ``Access`` (see the module docstring)."""

    def __init__(self, app, access: Access, max_body: int = MAX_BODY):
        self.app = app
        self.access = access
        self.max_body = max_body
        self._logged: dict[str, tuple[float, int]] = {}  # reason -> (when last logged, refused since)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {key.decode("latin-1"): value.decode("latin-1") for key, value in scope["headers"]}
        refusal = self._refusal(scope, headers)
        if refusal is not None:
            status, reason = refusal
            self._note(scope, reason)
            if scope["type"] == "websocket":
                await send({"type": "websocket.close", "code": 1008, "reason": reason})  # before accept: a 403
            else:
                await _answer(send, status, reason)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        too_large = f"a request body may be at most {self.max_body} bytes"
        length = headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_body):
            await _answer(send, 413, too_large)  # declared too long: not a byte of it read
            return
        body = await self._body(receive)
        if body is None:  # the client left before its body ended: no one to answer
            return
        if len(body) > self.max_body:
            await _answer(send, 413, too_large)
            return
        await self.app(scope, _replay(body, receive), _with_headers(send))

    def _refusal(self, scope, headers: dict[str, str]) -> tuple[int, str] | None:
        host = headers.get("host")
        if not host:  # HTTP/1.0 needs none, and an empty one names nothing
            return 400, NO_HOST
        if not self.access.host_allowed(host):
            return 421, "this station does not serve that host name (see --allowed-host)"
        origin = headers.get("origin")
        if scope["type"] == "websocket" and origin is not None and not same_origin(origin, host):
            return 403, "websockets only from this station's own pages"
        path = scope["path"]
        authorization = headers.get("authorization")
        if scope["type"] == "http" and scope["method"] in WRITES and path.startswith("/api/") \
                and path != "/api/session" and not self.access.is_operator(authorization):
            return 401, "the operator token is missing or wrong"
        if path in PUBLIC_EXACT or path.startswith(PUBLIC):
            return None
        if not self.access.may_view(authorization, headers.get("cookie")):
            return 401, "watching this station needs a token (the viewer or the operator token)"
        return None

    def _note(self, scope, reason: str) -> None:
        """Log a refusal, at most once per reason every LOG_EVERY seconds (a flood must not flood the log)."""
        now = time.monotonic()
        last, since = self._logged.get(reason, (-LOG_EVERY, 0))
        if now - last < LOG_EVERY:
            self._logged[reason] = (last, since + 1)
            return
        client = scope.get("client") or ("?", 0)
        log.warning("refused %s %s from %s: %s%s", scope.get("method", "websocket"), scope["path"][:80], client[0],
                    reason, f" ({since} more since the last report)" if since else "")
        self._logged[reason] = (now, 0)

    async def _body(self, receive) -> bytes | None:
        """The request's body, read whole before any route runs (a route's own parsing never meets a body over
        the cap, declared or chunked), but not past the first message that passes ``max_body``: the rest is
        never read. None if the client left first."""
        parts, size, more = [], 0, True
        while more and size <= self.max_body:
            message = await receive()
            if message["type"] != "http.request":
                return None
            part = message.get("body", b"")
            parts.append(part)
            size += len(part)
            more = message.get("more_body", False)
        return b"".join(parts)


def _replay(body: bytes, receive):
    """``receive`` for the app: the body the Gate read, as one message, then what the server says next (that
    the client left, or the response ended)."""
    pending = [{"type": "http.request", "body": body, "more_body": False}]

    async def replaying():
        return pending.pop() if pending else await receive()

    return replaying


def _with_headers(send):
    async def sending(message) -> None:
        if message["type"] == "http.response.start":
            present = {key.lower() for key, _ in message.get("headers", [])}
            extra = [(k, v) for k, v in COMMON_HEADERS if k not in present]
            if b"content-security-policy" not in present:
                extra.append((b"content-security-policy", PAGE_POLICY.encode()))
            message = {**message, "headers": [*message.get("headers", []), *extra]}
        await send(message)

    return sending


async def _answer(send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
               *COMMON_HEADERS, (b"content-security-policy", b"default-src 'none'")]
    if status == 401:
        headers.append((b"www-authenticate", b"Bearer"))
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
