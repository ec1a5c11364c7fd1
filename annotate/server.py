"""The labelling page's server: a Starlette ASGI app on 127.0.0.1, one log and one label store.

Access (as Jupyter does it)
---------------------------
- **Token, then a cookie.** ``zcut annotate`` prints ``http://127.0.0.1:P/?token=T`` (T from
  ``secrets.token_urlsafe``). Only the page itself (``GET /``) takes the token from the URL: it
  answers with a ``SameSite=Strict; HttpOnly`` cookie holding a fresh random page-session id, and
  the page removes the token from the address bar and history (``history.replaceState``). Every
  other request carries that cookie, or the token in the ``X-Zcut-Token`` header (scripts, tests);
  anything else gets 403. The cookie's name carries a hash of the token, so two servers on
  127.0.0.1 keep their cookies apart.
- **Writes check Origin.** A request that changes something (any method but GET and HEAD) must
  name this server as its ``Origin`` (and, when the browser says, ``Sec-Fetch-Site: same-origin``);
  with the cookie alone and no Origin it is refused (403). Browsers always send Origin on such
  requests, so another site cannot make the browser write with the user's cookie.
- **Host** must be 127.0.0.1 or localhost (DNS rebinding), else 400.
- **The annotator is never taken from a request.** Either the server was started for one
  annotator (``--annotator``; every page labels as that name), or each page session chooses its
  name once (``--ask-annotator``: ``POST /api/annotator``, bound to the cookie's session and never
  changed). Names are normalised and look-alikes refused (:func:`annotate.store.normalize_annotator`,
  :meth:`annotate.store.LabelStore.check_new_annotator`). A label whose body names another
  annotator is refused (403).

Robustness
----------
- Frames are prepared by one background thread; a frame not prepared yet is answered at once with
  503 and ``Retry-After`` (never by holding a worker until it is ready).
- Request headers must arrive within :data:`HEADER_TIMEOUT_S` of the connection's first byte (or of
  the previous response), a body within :data:`BODY_TIMEOUT_S`; else 408 and the connection closes.
  Bodies above :data:`MAX_BODY_BYTES` get 413 before they are read whole.
- A malformed request is a 4xx with a one-line reason, never a 500: frame indices are parsed by a
  bounded pattern (a 5,000-digit index is 404), JSON that nests too deep or holds absurd numbers
  is 400, and so on.
- Another ``zcut annotate`` on the same store is detected through the store's ``servers`` table;
  the command says so when it starts and the page shows it.

An edit is acknowledged (200 with the new revision) only after the store committed it; a save
based on an old revision gets 409 with the latest revision and stores nothing (the page then shows
both versions and merges); a malformed or invalid label gets 4xx and stores nothing.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import hashlib
import hmac
import json
import math
import re
import secrets
import shutil
import tempfile
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs

import numpy as np
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route

from annotate.candidates import PipelineRunner
from annotate.payload import (
    PreparedFrame,
    ServedFrame,
    bundle_with_blobs,
    make_geometry,
    make_view,
    prepare_frame,
    runs_to_mask,
    turbo_lut,
)
from annotate.store import (
    FrameRecord,
    LabelConflictError,
    LabelStore,
    LabelSupersededError,
    LabelValidationError,
    LogRecord,
    ServerRecord,
    StoreError,
    unpack_mask,
)

MAX_BODY_BYTES = 8 * 1024 * 1024
HEADER_TIMEOUT_S = 10.0
BODY_TIMEOUT_S = 30.0
TOKEN_HEADER = "x-zcut-token"
STATIC_FILES = {"app.js": "text/javascript", "worker.js": "text/javascript", "view3d.js": "text/javascript",
                "style.css": "text/css"}
#: Largest rectangle of points one geometry request may ask for (pixels).
MAX_GEOMETRY_PX = 256 * 256
#: Page sessions kept per server (the oldest is forgotten beyond that: its page must reopen the URL).
MAX_CLIENTS = 256
HEARTBEAT_S = 5.0
_INDEX = re.compile(r"[0-9]{1,9}")
_CLIENT_ID = re.compile(r"[A-Za-z0-9_-]{8,64}")
MAX_JSON_DEPTH = 8


# --------------------------------------------------------------------------- frame catalog
class FrameNotReady(Exception):
    """The frame is still being prepared: ask again in ``retry_after_s`` seconds."""

    def __init__(self, index: int, retry_after_s: int) -> None:
        super().__init__(f"frame {index} is being prepared: retry in {retry_after_s} s")
        self.retry_after_s = retry_after_s


class GeometrySpill:
    """The frames' points on disk, one ``.npy`` per frame (x, y, z float32), read by rectangles.

    A 1920 x 1200 frame takes 27.6 MB in a temporary directory that :meth:`close` removes; the
    server keeps no dense arrays in memory.
    """

    def __init__(self) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="zcut-annotate-"))
        self._lock = threading.Lock()

    def _path(self, index: int) -> Path:
        return self.dir / f"frame{index}.npy"

    def put(self, index: int, xyz: np.ndarray) -> None:
        """Write the (H, W, 3) points of frame ``index``."""
        tmp = self.dir / f"frame{index}.part.npy"
        np.save(tmp, np.ascontiguousarray(xyz, dtype=np.float32))
        tmp.replace(self._path(index))

    def rect(self, index: int, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """(y1 - y0, x1 - x0, 3) float32 points of frame ``index`` (bounds already clipped)."""
        arr = np.load(self._path(index), mmap_mode="r")
        return np.array(arr[y0:y1, x0:x1])

    def close(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


@dataclass
class Catalog:
    """Frames of the log prepared for the page, in log order, by one background thread.

    ``prepare`` turns a :class:`replay.logs.frame.Frame` into a :class:`PreparedFrame`; every prepared
    frame is registered in the store (with its valid mask), its points spilled to ``geometry`` and
    kept as a :class:`ServedFrame`, by the frame's own index (a frame lost to damage leaves a gap).
    """

    frames_iter: Callable[[], Iterable]
    prepare: Callable[[object], PreparedFrame]
    store: LabelStore
    log: LogRecord
    geometry: GeometrySpill
    total_hint: int | None = None
    frames: dict[int, ServedFrame] = field(default_factory=dict)
    records: dict[int, FrameRecord] = field(default_factory=dict)
    done: bool = False
    error: str | None = None
    seconds_per_frame: float = 1.0
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="zcut-annotate-prepare", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)

    def _run(self) -> None:
        try:
            t = time.monotonic()
            for frame in self.frames_iter():
                if self._stop.is_set():
                    return
                pf = self.prepare(frame)
                sf = pf.served
                self.geometry.put(sf.index, pf.geometry)
                rec = self.store.add_frame(
                    self.log, topic=sf.topic, stamp_ns=sf.stamp_ns, index=sf.index,
                    shape=(sf.height, sf.width), frame_id=sf.frame_id, valid=pf.valid,
                )
                now = time.monotonic()
                with self._cond:
                    self.frames[sf.index] = sf
                    self.records[sf.index] = rec
                    self.seconds_per_frame = 0.5 * self.seconds_per_frame + 0.5 * (now - t)
                    self._cond.notify_all()
                t = now
        except Exception as e:  # noqa: BLE001 - shown on the page; the frames prepared so far stay usable
            with self._cond:
                self.error = f"{type(e).__name__}: {e}"
        finally:
            with self._cond:
                self.done = True
                self._cond.notify_all()

    def wait_until_done(self, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.done, timeout=timeout)

    def get(self, index: int) -> tuple[ServedFrame, FrameRecord] | None:
        """The prepared frame ``index``; None if the log has none.

        Raises
        ------
        FrameNotReady
            The frame may still come (preparation goes on): never waits for it.
        """
        with self._cond:
            if index in self.frames:
                return self.frames[index], self.records[index]
            if self.done or (self.total_hint is not None and index >= self.total_hint):
                return None
            if self.frames and index < max(self.frames):  # frames come in order: this one was lost
                return None
            ahead = max(1, index - max(self.frames, default=-1))
            wait = ahead * self.seconds_per_frame
        raise FrameNotReady(index, int(min(30, max(1, math.ceil(wait)))))

    def snapshot(self) -> list[tuple[ServedFrame, FrameRecord]]:
        """The prepared frames so far, in index order."""
        with self._cond:
            return [(self.frames[i], self.records[i]) for i in sorted(self.frames)]

    @property
    def total(self) -> int | None:
        with self._cond:
            return len(self.frames) if self.done else self.total_hint



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
        with self._lock:
            return sorted({c.annotator for c in self._by_id.values() if c.annotator})


# --------------------------------------------------------------------------- second servers
class Presence:
    """This server's row in the store's ``servers`` table and its heartbeat; :meth:`others` are the
    other live servers of the store (asked afresh: a server started a moment ago is seen at once)."""

    def __init__(self, store: LabelStore, *, log_sha256: str, port: int | None) -> None:
        self.store = store
        self.me: ServerRecord = store.register_server(log_sha256=log_sha256, port=port)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="zcut-annotate-heartbeat", daemon=True)
        self._thread.start()

    def others(self) -> list[ServerRecord]:
        return [s for s in self.store.live_servers() if s.id != self.me.id]

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_S):
            try:
                self.store.heartbeat_server(self.me.id)
            except StoreError:  # the store went away (shutting down): nothing to tell
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)
        try:
            self.store.unregister_server(self.me.id)
        except StoreError:
            pass


def describe_server(s: ServerRecord) -> str:
    """One line about another server: process, port and start time."""
    started = time.strftime("%H:%M:%S", time.localtime(s.started_ns / 1e9))
    port = f"port {s.port}" if s.port else "unknown port"
    return f"zcut annotate (pid {s.pid} on {s.host}, {port}, since {started})"


# --------------------------------------------------------------------------- ASGI middleware
async def _plain(send, status: int, text: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    body = text.encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class BodyGuard:
    """Bodies above ``limit`` bytes get 413 before they are read whole; a body that does not arrive
    within ``timeout_s`` seconds gets 408."""

    def __init__(self, app, *, limit: int, timeout_s: float) -> None:
        self.app = app
        self.limit = limit
        self.timeout_s = timeout_s

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        names = [k for k, _ in scope.get("headers", [])]
        if b"content-length" in names and b"transfer-encoding" in names:  # request smuggling's shape
            await _plain(send, 400, "Content-Length and Transfer-Encoding together")
            return
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                if not v.isdigit():
                    await _plain(send, 400, "bad Content-Length")
                    return
                if len(v) > 18 or int(v) > self.limit:
                    await _plain(send, 413, f"request body over {self.limit} bytes")
                    return
        state = {"seen": 0, "rejected": False, "started": False, "deadline": None}

        async def reject(status: int, text: str) -> dict:
            state["rejected"] = True
            if not state["started"]:
                state["started"] = True
                await _plain(send, status, text)
            return {"type": "http.disconnect"}

        async def guarded_receive():
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

        async def guarded_send(msg):
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


def cookie_name(token: str) -> str:
    """The page-session cookie's name for a server's token (servers on one host keep theirs apart)."""
    return "zcut-" + hashlib.sha256(token.encode()).hexdigest()[:16]


class AccessGate:
    """Token, cookie and Origin checks (module docstring); puts the caller in ``scope["zcut"]``:
    ``{"via": "query" | "header" | "cookie", "sid": page session id or None}``."""

    def __init__(self, app, *, token: str, clients: Clients, fixed_annotator: str | None,
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

    def _origin_ok(self, scope, headers: dict[bytes, bytes], via: str) -> str | None:
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

    async def __call__(self, scope, receive, send) -> None:
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
            await _plain(send, 403, "missing or wrong token (open the URL zcut annotate printed)")
            return
        if scope.get("method") not in ("GET", "HEAD"):
            why = self._origin_ok(scope, headers, via)
            if why is not None:
                await _plain(send, 403, why)
                return
        scope = {**scope, "zcut": {"via": via, "sid": sid}}
        if set_cookie is None:
            await self.app(scope, receive, send)
            return

        async def send_with_cookie(msg):
            if msg["type"] == "http.response.start":
                msg = {**msg, "headers": [*msg.get("headers", []), (b"set-cookie", set_cookie)]}
            await send(msg)

        await self.app(scope, receive, send_with_cookie)


# --------------------------------------------------------------------------- the app
class BadRequest(Exception):
    def __init__(self, status: int, message: str, *, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.headers = headers or {}


def _json_depth_ok(body: bytes, limit: int) -> bool:
    """True if no JSON nesting in ``body`` goes deeper than ``limit`` (strings skipped), checked
    before parsing: the parser's recursion is never reached."""
    depth, in_str, esc = 0, False, False
    for b in body:
        if in_str:
            if esc:
                esc = False
            elif b == 0x5C:
                esc = True
            elif b == 0x22:
                in_str = False
        elif b == 0x22:
            in_str = True
        elif b in (0x5B, 0x7B):
            depth += 1
            if depth > limit:
                return False
        elif b in (0x5D, 0x7D):
            depth -= 1
    return True


def parse_json_body(body: bytes) -> dict:
    """The JSON object of a request body; :class:`BadRequest` (400/422) for anything else."""
    if not _json_depth_ok(body, MAX_JSON_DEPTH):
        raise BadRequest(400, f"body nests deeper than {MAX_JSON_DEPTH} levels")
    try:
        d = json.loads(body)
    except (ValueError, RecursionError):  # JSONDecodeError, bad UTF-8, a 5,000-digit number ...
        raise BadRequest(400, "body is not JSON") from None
    if not isinstance(d, dict):
        raise BadRequest(422, "body must be a JSON object")
    return d


def _decode_b64(value: object, name: str) -> bytes:
    if not isinstance(value, str):
        raise BadRequest(422, f"{name} must be a base64 string")
    try:
        return base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise BadRequest(422, f"{name} is not valid base64") from None


def _decode_mask(value: object, shape: tuple[int, int], name: str) -> np.ndarray:
    try:
        return unpack_mask(_decode_b64(value, name), shape)
    except LabelValidationError as e:
        raise BadRequest(422, f"{name}: {e}") from None


def _decode_runs(value: object, shape: tuple[int, int], name: str) -> np.ndarray:
    blob = _decode_b64(value, name)
    if len(blob) % 4:
        raise BadRequest(422, f"{name}: {len(blob)} bytes is not a whole number of uint32 runs")
    try:
        return runs_to_mask(np.frombuffer(blob, "<u4"), shape)
    except ValueError as e:
        raise BadRequest(422, f"{name}: {e}") from None


def _label_masks(d: dict, shape: tuple[int, int], valid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(L, R) from a label body: ``outliers``/``reviewed`` (zlib packed bits) or ``outliers_runs``/
    ``unreviewed_runs`` (uint32 runs of L and of valid ∧ ¬R)."""
    if "outliers_runs" in d or "unreviewed_runs" in d:
        if valid is None:
            raise BadRequest(422, "unreviewed_runs needs the frame's valid mask, which the store lacks")
        L = _decode_runs(d.get("outliers_runs"), shape, "outliers_runs")
        unrev = _decode_runs(d.get("unreviewed_runs"), shape, "unreviewed_runs")
        if (unrev & ~valid).any():
            raise BadRequest(422, "unreviewed_runs marks invalid pixels")
        return L, valid & ~unrev
    return _decode_mask(d.get("outliers"), shape, "outliers"), _decode_mask(d.get("reviewed"), shape, "reviewed")


def _uint(value: str | None, name: str, *, hi: int) -> int:
    if value is None or not re.fullmatch(r"[0-9]{1,9}", value) or int(value) > hi:
        raise BadRequest(400, f"{name} must be an integer in 0..{hi}, got {str(value)[:20]!r}")
    return int(value)


@dataclass
class Session:
    """What one running page serves: the log, its catalog, the store, the token, the annotator mode.

    ``annotator`` is the name every page labels as, or None when each page session chooses its own
    (``POST /api/annotator``).
    """

    log_path: Path
    store: LabelStore
    log: LogRecord
    catalog: Catalog
    token: str
    annotator: str | None
    pipeline: object | None = None  # has ``notes``: what the config resolution decided
    reader: object | None = None  # the LogReader: ``damage`` lists what a damaged log lost
    clients: Clients = field(default_factory=Clients)
    presence: Presence | None = None
    _decisions: dict[tuple[int, int], tuple[int, int]] = field(default_factory=dict)

    def announce(self, port: int | None) -> list[str]:
        """Register this server in the store; returns one line per other live server of the store."""
        self.presence = Presence(self.store, log_sha256=self.log.sha256, port=port)
        return [describe_server(s) for s in self.presence.others()]

    def close(self) -> None:
        """Stop preparing, leave the store's servers table, remove the spilled points, close the store."""
        self.catalog.stop()
        if self.presence is not None:
            self.presence.stop()
        self.catalog.geometry.close()
        self.store.close()


def create_app(session: Session, *, max_body_bytes: int = MAX_BODY_BYTES, body_timeout_s: float = BODY_TIMEOUT_S,
               allowed_hosts: tuple[str, ...] = ("127.0.0.1", "localhost")):
    """The ASGI app of a session (access gate outermost, then the body guard, then the host check)."""
    static = resources.files("annotate") / "static"
    turbo = turbo_lut()

    def _index(request: Request) -> int:
        raw = request.path_params["index"]
        if not _INDEX.fullmatch(raw):
            raise BadRequest(404, f"no frame {raw[:20]!r}")
        return int(raw)

    def _frame(request: Request) -> tuple[ServedFrame, FrameRecord]:
        index = _index(request)
        try:
            got = session.catalog.get(index)
        except FrameNotReady as e:
            raise BadRequest(503, str(e), headers={"Retry-After": str(e.retry_after_s)}) from None
        if got is None:
            raise BadRequest(404, f"no frame {index}")
        return got

    def _client(request: Request):
        z = request.scope.get("zcut", {})
        return session.clients.get(z["sid"]) if z.get("sid") else None

    def _who(request: Request) -> str:
        """The annotator this request labels as: the server's, or the page session's binding."""
        if session.annotator is not None:
            return session.annotator
        c = _client(request)
        if c is None or c.annotator is None:
            raise BadRequest(403, "no annotator chosen for this page yet (POST /api/annotator)")
        return c.annotator

    def _decisions(sf: ServedFrame, rec: FrameRecord, who: str, revision: int) -> tuple[int, int]:
        key = (rec.id, revision)
        if key not in session._decisions:
            lab = session.store.label(rec, annotator=who, revision=revision)
            session._decisions[key] = (0, 0) if lab is None else sf.decisions(lab.outliers, lab.reviewed)
        return session._decisions[key]

    def index(request: Request) -> Response:
        html = (static / "index.html").read_text()
        c = _client(request)
        boot = json.dumps({"log": session.log.name, "mode": "fixed" if session.annotator else "choose",
                           "annotator": session.annotator or (c.annotator if c else None)})
        html = html.replace("{{BOOT}}", boot.replace("<", "\\u003c"))
        return HTMLResponse(html, headers={
            "Cache-Control": "no-store", "Referrer-Policy": "no-referrer", "X-Frame-Options": "DENY",
            "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' data: blob:; frame-ancestors 'none'; "
                                       "base-uri 'none'; form-action 'none'; object-src 'none'",
        })

    def static_file(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC_FILES:  # a fixed list: no path ever comes from the request
            return Response("not found", status_code=404)
        return Response((static / name).read_bytes(), media_type=STATIC_FILES[name],
                        headers={"Cache-Control": "no-store"})

    def api_session(request: Request) -> Response:
        c = session.catalog
        c_ = _client(request)
        others = session.presence.others() if session.presence is not None else []
        return JSONResponse({
            "log": session.log.name, "sha256": session.log.sha256,
            "mode": "fixed" if session.annotator else "choose",
            "annotator": session.annotator or (c_.annotator if c_ else None),
            "total": c.total, "prepared": len(c.frames), "done": c.done, "error": c.error,
            "notes": list(getattr(session.pipeline, "notes", ())),
            "damage": list(getattr(session.reader, "damage", ())), "annotators": session.store.annotators(session.log),
            "other_servers": [describe_server(s) for s in others], "turbo": turbo,
        })

    async def api_annotator(request: Request) -> Response:
        if session.annotator is not None:
            raise BadRequest(409, f"this server labels as {session.annotator!r} (zcut annotate --annotator)")
        z = request.scope.get("zcut", {})
        if z.get("via") != "cookie":
            raise BadRequest(403, "an annotator is chosen by a page session (open the page's URL first)")
        d = parse_json_body(await _read_body(request))
        try:
            name = session.store.check_new_annotator(d.get("name"), also=session.clients.names())
        except LabelValidationError as e:
            raise BadRequest(422, str(e)) from None
        bound = session.clients.bind(z["sid"], name)
        if bound != name:
            return JSONResponse({"error": f"this page labels as {bound!r} already", "annotator": bound},
                                status_code=409)
        return JSONResponse({"annotator": bound})

    def api_frames(request: Request) -> Response:
        who = _who(request)
        current = session.store.current_labels(session.log, annotator=who)
        c = session.catalog
        rows = []
        for sf, rec in c.snapshot():
            lab = current.get(rec.id)
            decided, accepted = _decisions(sf, rec, who, lab.revision) if lab else (0, 0)
            rows.append({"index": sf.index, "stamp_ns": sf.stamp_ns, "n_zcut": sf.n_zcut, "n_sor": sf.n_sor,
                         "n_sor_listed": sf.n_sor_listed, "n_candidates": sf.n_zcut + sf.n_sor_listed,
                         "disagreement": sf.disagreement, "n_valid": sf.n_valid,
                         "revision": lab.revision if lab else 0,
                         "n_outliers": lab.n_outliers if lab else 0, "n_reviewed": lab.n_reviewed if lab else 0,
                         "reviewed": bool(lab and lab.n_reviewed >= sf.n_valid),
                         "decided": decided, "accepted": accepted})
        total = c.total
        return JSONResponse({"frames": rows, "total": total if total is not None else len(rows),
                             "reviewed": sum(r["reviewed"] for r in rows), "done": c.done, "error": c.error})

    def _bytes(data: bytes, media: str = "application/octet-stream") -> Response:
        return Response(data, media_type=media, headers={"Cache-Control": "no-store"})

    def api_bundle(request: Request) -> Response:
        sf, _ = _frame(request)
        return _bytes(sf.bundle)

    def api_image(request: Request) -> Response:
        sf, _ = _frame(request)
        kind = request.path_params["kind"]
        if kind == "height" or (kind == "rgb" and sf.rgb_jpeg is None):
            data = sf.height_jpeg
        elif kind == "rgb":
            data = sf.rgb_jpeg
        else:
            raise BadRequest(404, f"no image kind {kind[:20]!r}")
        return _bytes(data, "image/jpeg")

    def _label_bundle(sf: ServedFrame, rec: FrameRecord, who: str) -> bytes:
        got = session.store.label_blobs(rec, annotator=who)
        header = {"index": sf.index, "height": sf.height, "width": sf.width, "annotator": who,
                  "revision": got[0] if got else 0}
        blobs = [("outliers", got[1]), ("reviewed", got[2])] if got else []
        return bundle_with_blobs(header, blobs)

    def api_label_get(request: Request) -> Response:
        sf, rec = _frame(request)
        return _bytes(_label_bundle(sf, rec, _who(request)))

    def api_view(request: Request) -> Response:
        """Bundle + label (+ one JPEG unless ``image=none``) in one response."""
        sf, rec = _frame(request)
        kind = request.query_params.get("image", "rgb")
        if kind not in ("rgb", "height", "none"):
            raise BadRequest(400, f"image must be rgb, height or none, got {kind[:20]!r}")
        parts = [("bundle", sf.bundle), ("label", _label_bundle(sf, rec, _who(request)))]
        if kind != "none":
            parts.append(("image", sf.height_jpeg if kind == "height" or sf.rgb_jpeg is None else sf.rgb_jpeg))
        return _bytes(make_view(parts))

    def api_geometry(request: Request) -> Response:
        """The points of a rectangle ``x0 <= col < x1, y0 <= row < y1`` (clipped to the frame)."""
        sf, _ = _frame(request)
        q = request.query_params
        big = 1 << 30
        x0, y0 = _uint(q.get("x0"), "x0", hi=big), _uint(q.get("y0"), "y0", hi=big)
        x1, y1 = _uint(q.get("x1"), "x1", hi=big), _uint(q.get("y1"), "y1", hi=big)
        x0, x1 = min(x0, sf.width), min(x1, sf.width)
        y0, y1 = min(y0, sf.height), min(y1, sf.height)
        if x1 <= x0 or y1 <= y0:
            raise BadRequest(400, f"empty rectangle x {x0}..{x1}, y {y0}..{y1} in a {sf.width}x{sf.height} frame")
        if (x1 - x0) * (y1 - y0) > MAX_GEOMETRY_PX:
            raise BadRequest(400, f"rectangle of {(x1 - x0) * (y1 - y0)} px: at most {MAX_GEOMETRY_PX} per request")
        return _bytes(make_geometry(session.catalog.geometry.rect(sf.index, x0, y0, x1, y1), x0=x0, y0=y0))

    async def _read_body(request: Request) -> bytes:
        try:
            return await request.body()
        except ClientDisconnect:
            raise BadRequest(400, "the body did not arrive whole") from None

    async def api_label_put(request: Request) -> Response:
        index_ = _index(request)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            raise BadRequest(415, "label must be sent as application/json")
        who = _who(request)
        d = parse_json_body(await _read_body(request))
        from starlette.concurrency import run_in_threadpool

        return await run_in_threadpool(_save, index_, who, d)

    def _save(index_: int, who: str, d: dict) -> Response:
        try:
            got = session.catalog.get(index_)
        except FrameNotReady as e:
            raise BadRequest(503, str(e), headers={"Retry-After": str(e.retry_after_s)}) from None
        if got is None:
            raise BadRequest(404, f"no frame {index_}")
        sf, rec = got
        if "annotator" in d and d["annotator"] != who:
            raise BadRequest(403, f"this page labels as {who!r}: the annotator is never taken from a request")
        base = d.get("base_revision", 0)
        if base is None:
            base = 0
        if not isinstance(base, int) or isinstance(base, bool) or not 0 <= base < 1 << 53:
            raise BadRequest(422, "base_revision must be a non-negative integer")
        client, seq = d.get("client"), d.get("seq")
        if client is not None or seq is not None:
            if not isinstance(client, str) or not _CLIENT_ID.fullmatch(client):
                raise BadRequest(422, "client must be 8..64 characters of A-Z a-z 0-9 _ -")
            if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < 1 << 53:
                raise BadRequest(422, "seq must be a non-negative integer")
        if d.get("height") != sf.height or d.get("width") != sf.width:
            raise BadRequest(422, f"label shape must be {sf.height}x{sf.width}")
        shape = (sf.height, sf.width)
        outliers, reviewed = _label_masks(d, shape, session.store.valid_mask(rec))
        superseded = False
        try:
            rev = session.store.save_label(rec, annotator=who, outliers=outliers, reviewed=reviewed,
                                           base_revision=base, source="page", client=client, client_seq=seq)
        except LabelConflictError as e:
            return JSONResponse({"error": str(e), "latest": e.latest}, status_code=409)
        except LabelSupersededError as e:
            rev, superseded = e.latest, True
        except LabelValidationError as e:
            raise BadRequest(422, str(e)) from None
        if not superseded:
            session._decisions[(rec.id, rev)] = sf.decisions(outliers, reviewed)
        decided, accepted = _decisions(sf, rec, who, rev)
        n_reviewed = int(reviewed.sum())
        return JSONResponse({"revision": rev, "index": sf.index, "annotator": who, "superseded": superseded,
                             "n_outliers": int(outliers.sum()), "n_reviewed": n_reviewed,
                             "reviewed": n_reviewed >= sf.n_valid, "decided": decided, "accepted": accepted,
                             "committed_ns": time.time_ns()})

    async def bad_request(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, BadRequest)
        return JSONResponse({"error": str(exc)}, status_code=exc.status, headers=exc.headers)

    async def store_error(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": str(exc)}, status_code=500)

    routes = [
        Route("/", index, methods=["GET"]),
        Route("/static/{name}", static_file, methods=["GET"]),
        Route("/api/session", api_session, methods=["GET"]),
        Route("/api/annotator", api_annotator, methods=["POST"]),
        Route("/api/frames", api_frames, methods=["GET"]),
        Route("/api/frames/{index}/bundle", api_bundle, methods=["GET"]),
        Route("/api/frames/{index}/image/{kind}", api_image, methods=["GET"]),
        Route("/api/frames/{index}/view", api_view, methods=["GET"]),
        Route("/api/frames/{index}/geometry", api_geometry, methods=["GET"]),
        Route("/api/frames/{index}/label", api_label_get, methods=["GET"]),
        Route("/api/frames/{index}/label", api_label_put, methods=["PUT"]),
    ]
    app = Starlette(
        routes=routes,
        middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts))],
        exception_handlers={BadRequest: bad_request, StoreError: store_error},
    )
    guarded = BodyGuard(app, limit=max_body_bytes, timeout_s=body_timeout_s)
    return AccessGate(guarded, token=session.token, clients=session.clients, fixed_annotator=session.annotator,
                      allowed_hosts=allowed_hosts)


def new_token() -> str:
    """A fresh random token for the page's URL."""
    return secrets.token_urlsafe(32)


# --------------------------------------------------------------------------- HTTP protocol with timeouts
def _timeout_protocol(header_timeout_s: float):
    """uvicorn's h11 protocol with a header read timeout: from a connection's first byte (or the end
    of the previous response) the request's headers must be complete within ``header_timeout_s``
    seconds, else the server answers 408 and closes. (uvicorn itself only times out idle keep-alive
    connections, and stops that timer at the first byte of the next request.)"""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class TimeoutH11Protocol(H11Protocol):
        _zcut_timer = None

        def connection_made(self, transport) -> None:
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

        def connection_lost(self, exc) -> None:
            self._zcut_disarm()
            super().connection_lost(exc)

    return TimeoutH11Protocol


def make_server(session: Session, *, header_timeout_s: float = HEADER_TIMEOUT_S,
                body_timeout_s: float = BODY_TIMEOUT_S, max_body_bytes: int = MAX_BODY_BYTES):
    """A ``uvicorn.Server`` for the session's app; run it with ``.run(sockets=[sock])``."""
    import uvicorn

    app = create_app(session, max_body_bytes=max_body_bytes, body_timeout_s=body_timeout_s)
    config = uvicorn.Config(app, log_level="warning", access_log=False, timeout_graceful_shutdown=5,
                            http=_timeout_protocol(header_timeout_s), lifespan="off")
    return uvicorn.Server(config)


# --------------------------------------------------------------------------- session from a log
def open_session(
    log_path: str | Path,
    db_path: str | Path,
    *,
    annotator: str | None,
    config_path: str | Path | None = None,
    bin_model=None,
    token: str | None = None,
    overrides: dict | None = None,
    topic: str | None = None,
) -> Session:
    """Open the log and the store, resolve the pipeline config and start preparing frames.

    Parameters
    ----------
    log_path, db_path : path-like
    annotator : str or None
        The name every page labels as; None: each page session chooses its own once.
    config_path : path-like, optional
    bin_model : replay.pipeline.bin_model.BinModel, optional
    token : str, optional
        Default: a fresh :func:`new_token`.
    overrides : dict, optional
        The command line's config layer (:func:`replay.pipeline.config.cli_layer`).
    topic : str, optional
        The cloud topic.

    Candidates come from ``replay.pipeline.stages.run_frame`` with the config resolved as ``zcut replay``
    does it, through :class:`annotate.candidates.PipelineRunner`.
    """
    from replay.logs.reader import LogReader
    from zcut.errors import ParameterError

    log_path = Path(log_path)
    reader = LogReader(log_path, cloud_topic=topic)  # validates the log before anything is registered
    store = LabelStore(db_path)
    geometry = None
    try:
        if annotator is not None:
            try:
                annotator = store.check_new_annotator(annotator)
            except LabelValidationError as e:
                raise ParameterError(f"--annotator: {e}") from None
        log = store.add_log(log_path)
        runner = PipelineRunner(reader.metadata, config_path=config_path, bin_model=bin_model, overrides=overrides,
                                intrinsics=reader.intrinsics)
        geometry = GeometrySpill()
        catalog = Catalog(frames_iter=lambda: reader.frames(), prepare=lambda frame: prepare_frame(frame, runner.run(frame)),
                          store=store, log=log, geometry=geometry, total_hint=reader.n_frames)
        session = Session(log_path=log_path, store=store, log=log, catalog=catalog,
                          token=token or new_token(), annotator=annotator, pipeline=runner, reader=reader)
    except BaseException:
        if geometry is not None:
            geometry.close()
        store.close()
        raise
    catalog.start()
    return session
