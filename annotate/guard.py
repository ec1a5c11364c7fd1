"""Who may talk to the labelling server, and how much: the access gate, the body guard, the header timeout.

Three layers wrap the page's routes (:func:`annotate.server.create_app` puts them together), each a
plain ASGI callable that can be run and tested alone.

Access (as Jupyter does it): :class:`AccessGate`
------------------------------------------------
- **Token, then a cookie.** ``zcut annotate`` prints ``http://127.0.0.1:P/?token=T`` (T from
  :func:`new_token`). Only the page itself (``GET /``) takes the token from the URL: it answers with
  a ``SameSite=Strict; HttpOnly`` cookie holding a fresh random page-session id (:class:`Clients`),
  and the page removes the token from the address bar and history (``history.replaceState``). Every
  other request carries that cookie, or the token in the ``X-Zcut-Token`` header (scripts, tests);
  anything else gets 403. The cookie's name carries a hash of the token (:func:`cookie_name`), so two
  servers on 127.0.0.1 keep their cookies apart.
- **Writes check Origin.** A request that changes something (any method but GET and HEAD) must name
  this server as its ``Origin`` (and, when the browser says, ``Sec-Fetch-Site: same-origin``); with
  the cookie alone and no Origin it is refused (403). Browsers always send Origin on such requests,
  so another site cannot make the browser write with the user's cookie.
- **Host** must be 127.0.0.1 or localhost (DNS rebinding), else 400 (Starlette's
  ``TrustedHostMiddleware`` with :data:`ALLOWED_HOSTS`).
- **The annotator is never taken from a request.** A page session is bound to the server's fixed
  annotator, or chooses its name once (:meth:`Clients.bind`); the routes read it from here.

Slow and large requests: :class:`BodyGuard`, :func:`timeout_protocol`
---------------------------------------------------------------------
Request headers must arrive within :data:`HEADER_TIMEOUT_S` of the connection's first byte (or of
the previous response), a body within :data:`BODY_TIMEOUT_S`; else 408 and the connection closes.
Bodies above :data:`MAX_BODY_BYTES` get 413 before they are read whole; ``Content-Length`` with
``Transfer-Encoding`` (request smuggling's shape) gets 400.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs

#: ASGI's three callables (typed loosely: the messages are dicts of the ASGI spec).
Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

MAX_BODY_BYTES = 8 * 1024 * 1024
HEADER_TIMEOUT_S = 10.0
BODY_TIMEOUT_S = 30.0
TOKEN_HEADER = "x-zcut-token"
ALLOWED_HOSTS = ("127.0.0.1", "localhost")
#: Page sessions kept per server (the oldest is forgotten beyond that: its page must reopen the URL).
MAX_CLIENTS = 256


def new_token() -> str:
    """A fresh random token for the page's URL."""
    return secrets.token_urlsafe(32)


def cookie_name(token: str) -> str:
    """The page-session cookie's name for a server's token (servers on one host keep theirs apart)."""
    return "zcut-" + hashlib.sha256(token.encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- page sessions
@dataclass
class Client:
    """One page session (a cookie): the annotator it is bound to (None until chosen)."""

    annotator: str | None
    created: float


class Clients:
    """Page sessions by their random id, at most :data:`MAX_CLIENTS` (oldest forgotten first)."""

    def __init__(self) -> None:
        self._by_id: OrderedDict[str, Client] = OrderedDict()
        self._lock = threading.Lock()

    def new(self, annotator: str | None) -> str:
        """A new page session bound to ``annotator`` (None: it chooses later); returns its id."""
        sid = secrets.token_urlsafe(32)
        with self._lock:
            self._by_id[sid] = Client(annotator, time.time())
            while len(self._by_id) > MAX_CLIENTS:
                self._by_id.popitem(last=False)
        return sid

    def get(self, sid: str) -> Client | None:
        with self._lock:
            return self._by_id.get(sid)

    def bind(self, sid: str, name: str) -> str:
        """Bind ``name`` to the session unless it has one; returns the session's annotator."""
        with self._lock:
            c = self._by_id[sid]
            if c.annotator is None:
                c.annotator = name
            return c.annotator

    def names(self) -> list[str]:
        """The annotators the page sessions are bound to, sorted."""
        with self._lock:
            return sorted({c.annotator for c in self._by_id.values() if c.annotator})


# --------------------------------------------------------------------------- ASGI layers
async def plain_response(send: Send, status: int, text: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """A ``text/plain`` response that closes the connection (what the layers refuse with)."""
    body = text.encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class BodyGuard:
    """Bodies above ``limit`` bytes get 413 before they are read whole; a body that does not arrive
    within ``timeout_s`` seconds gets 408."""

    def __init__(self, app: ASGIApp, *, limit: int, timeout_s: float) -> None:
        self.app = app
        self.limit = limit
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        names = [k for k, _ in scope.get("headers", [])]
        if b"content-length" in names and b"transfer-encoding" in names:  # request smuggling's shape
            await plain_response(send, 400, "Content-Length and Transfer-Encoding together")
            return
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                if not v.isdigit():
                    await plain_response(send, 400, "bad Content-Length")
                    return
                if len(v) > 18 or int(v) > self.limit:
                    await plain_response(send, 413, f"request body over {self.limit} bytes")
                    return
        state: dict[str, Any] = {"seen": 0, "rejected": False, "started": False, "deadline": None}

        async def reject(status: int, text: str) -> Message:
            state["rejected"] = True
            if not state["started"]:
                state["started"] = True
                await plain_response(send, status, text)
            return {"type": "http.disconnect"}

        async def guarded_receive() -> Message:
            if state["rejected"]:
                return {"type": "http.disconnect"}
            loop = asyncio.get_running_loop()
            if state["deadline"] is None:
                state["deadline"] = loop.time() + self.timeout_s
            try:
                msg = await asyncio.wait_for(receive(), max(0.0, state["deadline"] - loop.time()))
            except TimeoutError:
                return await reject(408, f"request body not received within {self.timeout_s:g} s")
            if msg["type"] == "http.request":
                state["seen"] += len(msg.get("body", b""))
                if state["seen"] > self.limit:
                    return await reject(413, f"request body over {self.limit} bytes")
            return msg

        async def guarded_send(msg: Message) -> None:
            if state["rejected"]:
                return  # the 413 / 408 went out already
            if msg["type"] == "http.response.start":
                state["started"] = True
            await send(msg)

        try:
            await self.app(scope, guarded_receive, guarded_send)
        except Exception:
            if not state["rejected"]:
                raise


class AccessGate:
    """Token, cookie and Origin checks (module docstring); puts the caller in ``scope["zcut"]``:
    ``{"via": "query" | "header" | "cookie", "sid": page session id or None}``."""

    def __init__(self, app: ASGIApp, *, token: str, clients: Clients, fixed_annotator: str | None,
                 allowed_hosts: tuple[str, ...]) -> None:
        self.app = app
        self.token = token.encode()
        self.cookie = cookie_name(token)
        self.clients = clients
        self.fixed = fixed_annotator
        self.allowed_hosts = allowed_hosts

    def _cookie_sid(self, headers: list[tuple[bytes, bytes]]) -> str | None:
        prefix = self.cookie + "="
        for k, v in headers:
            if k != b"cookie":
                continue
            for part in v.decode("latin-1").split(";"):
                part = part.strip()
                if part.startswith(prefix):
                    sid = part[len(prefix):]
                    if self.clients.get(sid) is not None:
                        return sid
        return None

    def _origin_ok(self, scope: Scope, headers: dict[bytes, bytes], via: str) -> str | None:
        """None if a write may go on, else the reason to refuse it."""
        port = (scope.get("server") or ("", None))[1]
        origin = headers.get(b"origin")
        if origin is None:
            return None if via == "header" else "writes need an Origin header"
        allowed = {f"http://{h}:{port}".encode() for h in self.allowed_hosts}
        if origin not in allowed:
            return f"Origin {origin.decode('latin-1')[:80]!r} is not this server"
        site = headers.get(b"sec-fetch-site")
        if site is not None and site not in (b"same-origin", b"none"):
            return f"Sec-Fetch-Site {site.decode('latin-1')[:40]!r}: writes must come from this page"
        return None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        raw = scope.get("headers", [])
        headers = dict(raw)
        given = headers.get(TOKEN_HEADER.encode(), b"")
        via, sid, set_cookie = None, None, None
        if given:
            if hmac.compare_digest(given, self.token):
                via = "header"
        else:
            sid = self._cookie_sid(raw)
            if sid is not None:
                via = "cookie"
            elif scope.get("path") == "/" and scope.get("method") in ("GET", "HEAD"):
                q = parse_qs(scope.get("query_string", b"").decode("latin-1"))
                if hmac.compare_digest(q.get("token", [""])[0].encode("latin-1"), self.token):
                    via, sid = "query", self.clients.new(self.fixed)
                    set_cookie = f"{self.cookie}={sid}; Path=/; HttpOnly; SameSite=Strict".encode()
        if via is None:
            await plain_response(send, 403, "missing or wrong token (open the URL zcut annotate printed)")
            return
        if scope.get("method") not in ("GET", "HEAD"):
            why = self._origin_ok(scope, headers, via)
            if why is not None:
                await plain_response(send, 403, why)
                return
        scope = {**scope, "zcut": {"via": via, "sid": sid}}
        if set_cookie is None:
            await self.app(scope, receive, send)
            return
        cookie = set_cookie

        async def send_with_cookie(msg: Message) -> None:
            if msg["type"] == "http.response.start":
                msg = {**msg, "headers": [*msg.get("headers", []), (b"set-cookie", cookie)]}
            await send(msg)

        await self.app(scope, receive, send_with_cookie)


# --------------------------------------------------------------------------- HTTP protocol with timeouts
def timeout_protocol(header_timeout_s: float) -> type:
    """uvicorn's h11 protocol with a header read timeout: from a connection's first byte (or the end
    of the previous response) the request's headers must be complete within ``header_timeout_s``
    seconds, else the server answers 408 and closes. (uvicorn itself only times out idle keep-alive
    connections, and stops that timer at the first byte of the next request.)"""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class TimeoutH11Protocol(H11Protocol):
        _zcut_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: Any) -> None:
            super().connection_made(transport)
            self._zcut_arm()

        def _zcut_arm(self) -> None:
            self._zcut_disarm()
            self._zcut_timer = self.loop.call_later(header_timeout_s, self._zcut_expired)

        def _zcut_disarm(self) -> None:
            if self._zcut_timer is not None:
                self._zcut_timer.cancel()
                self._zcut_timer = None

        def _zcut_expired(self) -> None:
            self._zcut_timer = None
            if self.transport.is_closing() or (self.cycle is not None and not self.cycle.response_complete):
                return
            body = f"request headers not received within {header_timeout_s:g} s".encode()
            self.transport.write(b"HTTP/1.1 408 Request Timeout\r\ncontent-type: text/plain; charset=utf-8\r\n"
                                 b"connection: close\r\ncontent-length: " + str(len(body)).encode() + b"\r\n\r\n" + body)
            self.transport.close()

        def data_received(self, data: bytes) -> None:
            before = self.cycle
            idle = before is None or before.response_complete
            if idle and self._zcut_timer is None:
                self._zcut_arm()  # the first byte of a request on a kept-alive connection
            super().data_received(data)
            if self.cycle is not before:
                self._zcut_disarm()  # the headers of a request are complete

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._zcut_disarm()  # idle now: uvicorn's keep-alive timeout applies

        def connection_lost(self, exc: Exception | None) -> None:
            self._zcut_disarm()
            super().connection_lost(exc)

    return TimeoutH11Protocol
