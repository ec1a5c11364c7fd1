"""The labelling page's server: a Starlette ASGI app on 127.0.0.1, one log and one label store.

Safety (as Jupyter does it): a random token (``secrets.token_urlsafe``) must come with every request,
as ``?token=`` or the ``X-Zcut-Token`` header, else 403; the Host header must be 127.0.0.1 or
localhost (DNS rebinding); request bodies above :data:`MAX_BODY_BYTES` get 413 before they are read
whole (by Content-Length, and by counting the chunks of bodies without one). The page never names a
file: the server was started on one log and one database and only serves those, by frame index.

An edit is acknowledged (200 with the new revision) only after the store committed it; a save
based on an old revision gets 409 and stores nothing; a malformed or invalid label gets 4xx and
stores nothing.
"""

from __future__ import annotations

import base64
import binascii
import hmac
import json
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route

from annotate.candidates import PipelineRunner
from annotate.payload import PreparedFrame, ServedFrame, bundle_with_blobs, make_view
from annotate.store import (
    MAX_ANNOTATOR_LEN,
    FrameRecord,
    LabelConflictError,
    LabelStore,
    LabelValidationError,
    LogRecord,
    StoreError,
    unpack_mask,
)

MAX_BODY_BYTES = 8 * 1024 * 1024
TOKEN_HEADER = "x-zcut-token"
FRAME_WAIT_S = 300.0
STATIC_FILES = {"app.js": "text/javascript", "worker.js": "text/javascript", "style.css": "text/css"}


# --------------------------------------------------------------------------- frame catalog
@dataclass
class Catalog:
    """Frames of the log prepared for the page, in log order, by one background thread.

    ``prepare`` turns a :class:`replay.logs.frame.Frame` into a :class:`PreparedFrame` (candidates run
    once per frame); every prepared frame is registered in the store (with its valid mask) and
    kept as a :class:`ServedFrame`.
    """

    frames_iter: Callable[[], object]
    prepare: Callable[[object], PreparedFrame]
    store: LabelStore
    log: LogRecord
    total_hint: int | None = None
    frames: list[ServedFrame] = field(default_factory=list)
    records: list[FrameRecord] = field(default_factory=list)
    done: bool = False
    error: str | None = None
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
            for frame in self.frames_iter():
                if self._stop.is_set():
                    return
                pf = self.prepare(frame)
                rec = self.store.add_frame(
                    self.log, topic=pf.topic, stamp_ns=pf.stamp_ns, index=pf.index,
                    shape=(pf.height, pf.width), frame_id=pf.frame_id, valid=pf.valid,
                )
                with self._cond:
                    self.frames.append(pf.served())
                    self.records.append(rec)
                    self._cond.notify_all()
        except Exception as e:  # shown on the page; the frames prepared so far stay usable
            with self._cond:
                self.error = f"{type(e).__name__}: {e}"
        finally:
            with self._cond:
                self.done = True
                self._cond.notify_all()

    def wait_until_done(self, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.done, timeout=timeout)

    def get(self, index: int, *, timeout: float = FRAME_WAIT_S) -> tuple[ServedFrame, FrameRecord] | None:
        """The prepared frame ``index`` (waiting while it is being prepared); None if there is none."""
        with self._cond:
            self._cond.wait_for(lambda: len(self.frames) > index or self.done, timeout=timeout)
            if index < len(self.frames):
                return self.frames[index], self.records[index]
            return None

    @property
    def total(self) -> int | None:
        with self._cond:
            return len(self.frames) if self.done else self.total_hint


# --------------------------------------------------------------------------- ASGI middleware
class BodyLimit:
    """Reject request bodies above ``limit`` bytes with 413, before they are read whole."""

    def __init__(self, app, *, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                if not v.isdigit():
                    await _plain(send, 400, "bad Content-Length")
                    return
                if int(v) > self.limit:
                    await _plain(send, 413, f"request body over {self.limit} bytes")
                    return
        state = {"seen": 0, "rejected": False, "started": False}

        async def limited_receive():
            if state["rejected"]:
                return {"type": "http.disconnect"}
            msg = await receive()
            if msg["type"] == "http.request":
                state["seen"] += len(msg.get("body", b""))
                if state["seen"] > self.limit:
                    state["rejected"] = True
                    if not state["started"]:
                        state["started"] = True
                        await _plain(send, 413, f"request body over {self.limit} bytes")
                    return {"type": "http.disconnect"}
            return msg

        async def guarded_send(msg):
            if state["rejected"]:
                return  # the 413 went out already
            if msg["type"] == "http.response.start":
                state["started"] = True
            await send(msg)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except Exception:
            if not state["rejected"]:
                raise


class TokenGate:
    """403 for any request that does not carry the token (query ``token`` or header ``X-Zcut-Token``)."""

    def __init__(self, app, *, token: str) -> None:
        self.app = app
        self.token = token.encode()

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        given = b""
        for k, v in scope.get("headers", []):
            if k == TOKEN_HEADER.encode():
                given = v
        if not given:
            from urllib.parse import parse_qs

            q = parse_qs(scope.get("query_string", b"").decode("latin-1"))
            given = q.get("token", [""])[0].encode("latin-1")
        if not hmac.compare_digest(given, self.token):
            await _plain(send, 403, "missing or wrong token")
            return
        await self.app(scope, receive, send)


async def _plain(send, status: int, text: str) -> None:
    body = text.encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


# --------------------------------------------------------------------------- the app
class BadRequest(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def _annotator(value: object) -> str:
    if not isinstance(value, str) or not (1 <= len(value.strip()) <= MAX_ANNOTATOR_LEN) or not value.isprintable():
        raise BadRequest(422, f"annotator must be 1..{MAX_ANNOTATOR_LEN} printable characters")
    return value.strip()


def _decode_mask(value: object, shape: tuple[int, int], name: str) -> np.ndarray:
    if not isinstance(value, str):
        raise BadRequest(422, f"{name} must be a base64 string")
    try:
        blob = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise BadRequest(422, f"{name} is not valid base64") from None
    try:
        return unpack_mask(blob, shape)
    except LabelValidationError as e:
        raise BadRequest(422, f"{name}: {e}") from None


@dataclass
class Session:
    """What one running page serves: the log, its catalog, the store, the token, the default annotator."""

    log_path: Path
    store: LabelStore
    log: LogRecord
    catalog: Catalog
    token: str
    annotator: str
    pipeline: object | None = None  # has ``notes``: what the config resolution decided
    reader: object | None = None  # the LogReader: ``damage`` lists what a damaged log lost


def create_app(session: Session, *, max_body_bytes: int = MAX_BODY_BYTES, allowed_hosts: tuple[str, ...] = ("127.0.0.1", "localhost")):
    """The ASGI app of a session (token gate outermost, then the body limit, then the host check)."""
    static = resources.files("annotate") / "static"

    def _frame(request: Request) -> tuple[ServedFrame, FrameRecord]:
        raw = request.path_params["index"]
        got = session.catalog.get(raw)
        if got is None:
            raise BadRequest(404, f"no frame {raw}")
        return got

    def index(request: Request) -> Response:
        html = (static / "index.html").read_text()
        boot = json.dumps({"token": session.token, "annotator": session.annotator, "log": session.log.name})
        html = html.replace("{{BOOT}}", boot.replace("<", "\\u003c")).replace("{{TOKEN}}", session.token)
        return HTMLResponse(html, headers={
            "Cache-Control": "no-store", "Referrer-Policy": "no-referrer", "X-Frame-Options": "DENY",
            "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
        })

    def static_file(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC_FILES:  # a fixed list: no path ever comes from the request
            return Response("not found", status_code=404)
        return Response((static / name).read_bytes(), media_type=STATIC_FILES[name],
                        headers={"Cache-Control": "no-store"})

    def api_session(request: Request) -> Response:
        c = session.catalog
        return JSONResponse({
            "log": session.log.name, "sha256": session.log.sha256, "annotator": session.annotator,
            "total": c.total, "prepared": len(c.frames), "done": c.done, "error": c.error,
            "notes": list(getattr(session.pipeline, "notes", ())),
            "damage": list(getattr(session.reader, "damage", ())), "annotators": session.store.annotators(session.log),
        })

    def api_frames(request: Request) -> Response:
        who = _annotator(request.query_params.get("annotator", session.annotator))
        current = session.store.current_labels(session.log, annotator=who)
        c = session.catalog
        rows = []
        for pf, rec in zip(list(c.frames), list(c.records)):
            lab = current.get(rec.id)
            rows.append({"index": pf.index, "stamp_ns": pf.stamp_ns, "n_zcut": pf.n_zcut, "n_sor": pf.n_sor,
                         "revision": lab.revision if lab else 0,
                         "reviewed": bool(lab and lab.n_reviewed > 0),
                         "n_outliers": lab.n_outliers if lab else 0})
        total = c.total
        return JSONResponse({"frames": rows, "total": total if total is not None else len(rows),
                             "reviewed": sum(r["reviewed"] for r in rows), "done": c.done, "error": c.error})

    def api_bundle(request: Request) -> Response:
        pf, _ = _frame(request)
        return Response(pf.bundle, media_type="application/octet-stream", headers={"Cache-Control": "no-store"})

    def api_image(request: Request) -> Response:
        pf, _ = _frame(request)
        kind = request.path_params["kind"]
        if kind == "height" or (kind == "rgb" and pf.rgb_jpeg is None):
            data = pf.height_jpeg
        elif kind == "rgb":
            data = pf.rgb_jpeg
        else:
            raise BadRequest(404, f"no image kind {kind!r}")
        return Response(data, media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    def _label_bundle(pf: ServedFrame, rec: FrameRecord, request: Request) -> bytes:
        who = _annotator(request.query_params.get("annotator", session.annotator))
        got = session.store.label_blobs(rec, annotator=who)
        header = {"index": pf.index, "height": pf.height, "width": pf.width, "annotator": who,
                  "revision": got[0] if got else 0}
        blobs = [("outliers", got[1]), ("reviewed", got[2])] if got else []
        return bundle_with_blobs(header, blobs)

    def api_label_get(request: Request) -> Response:
        pf, rec = _frame(request)
        return Response(_label_bundle(pf, rec, request), media_type="application/octet-stream",
                        headers={"Cache-Control": "no-store"})

    def api_view(request: Request) -> Response:
        """Bundle + label (+ one JPEG unless ``image=none``) in one response."""
        pf, rec = _frame(request)
        kind = request.query_params.get("image", "rgb")
        if kind not in ("rgb", "height", "none"):
            raise BadRequest(400, f"image must be rgb, height or none, got {kind[:20]!r}")
        parts = [("bundle", pf.bundle), ("label", _label_bundle(pf, rec, request))]
        if kind != "none":
            parts.append(("image", pf.height_jpeg if kind == "height" or pf.rgb_jpeg is None else pf.rgb_jpeg))
        return Response(make_view(parts), media_type="application/octet-stream", headers={"Cache-Control": "no-store"})

    async def api_label_put(request: Request) -> Response:
        index_ = request.path_params["index"]
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            raise BadRequest(415, "label must be sent as application/json")
        try:
            body = await request.body()
        except ClientDisconnect:
            return Response(status_code=400)
        try:
            d = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise BadRequest(400, "body is not JSON") from None
        if not isinstance(d, dict):
            raise BadRequest(422, "body must be a JSON object")
        from starlette.concurrency import run_in_threadpool

        return await run_in_threadpool(_save, index_, d)

    def _save(index_: int, d: dict) -> Response:
        got = session.catalog.get(index_)
        if got is None:
            raise BadRequest(404, f"no frame {index_}")
        pf, rec = got
        who = _annotator(d.get("annotator"))
        base = d.get("base_revision", 0)
        if base is None:
            base = 0
        if not isinstance(base, int) or isinstance(base, bool) or base < 0:
            raise BadRequest(422, "base_revision must be a non-negative integer")
        if d.get("height") != pf.height or d.get("width") != pf.width:
            raise BadRequest(422, f"label shape must be {pf.height}x{pf.width}")
        shape = (pf.height, pf.width)
        outliers = _decode_mask(d.get("outliers"), shape, "outliers")
        reviewed = _decode_mask(d.get("reviewed"), shape, "reviewed")
        try:
            rev = session.store.save_label(rec, annotator=who, outliers=outliers, reviewed=reviewed,
                                           base_revision=base, source="page")
        except LabelConflictError as e:
            return JSONResponse({"error": str(e), "latest": e.latest}, status_code=409)
        except LabelValidationError as e:
            raise BadRequest(422, str(e)) from None
        return JSONResponse({"revision": rev, "index": pf.index, "annotator": who,
                             "n_outliers": int(outliers.sum()), "n_reviewed": int(reviewed.sum()),
                             "committed_ns": time.time_ns()})

    async def bad_request(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, BadRequest)
        return JSONResponse({"error": str(exc)}, status_code=exc.status)

    async def store_error(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": str(exc)}, status_code=500)

    routes = [
        Route("/", index),
        Route("/static/{name}", static_file),
        Route("/api/session", api_session),
        Route("/api/frames", api_frames),
        Route("/api/frames/{index:int}/bundle", api_bundle),
        Route("/api/frames/{index:int}/image/{kind}", api_image),
        Route("/api/frames/{index:int}/view", api_view),
        Route("/api/frames/{index:int}/label", api_label_get, methods=["GET"]),
        Route("/api/frames/{index:int}/label", api_label_put, methods=["PUT"]),
    ]
    app = Starlette(
        routes=routes,
        middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts))],
        exception_handlers={BadRequest: bad_request, StoreError: store_error},
    )
    return TokenGate(BodyLimit(app, limit=max_body_bytes), token=session.token)


def new_token() -> str:
    """A fresh random token for the page's URL."""
    return secrets.token_urlsafe(32)


# --------------------------------------------------------------------------- session from a log
def open_session(
    log_path: str | Path,
    db_path: str | Path,
    *,
    annotator: str,
    config_path: str | Path | None = None,
    bin_model=None,
    token: str | None = None,
) -> Session:
    """Open the log and the store, resolve the pipeline config and start preparing frames.

    Candidates come from ``replay.pipeline.stages.run_frame`` with the config resolved as ``zcut replay``
    does it (TOML file, else the preset of a synthetic log's part kind, else image-size defaults).
    """
    from replay.logs.reader import LogReader
    from zcut.errors import ParameterError

    try:
        annotator = _annotator(annotator)
    except BadRequest as e:
        raise ParameterError(f"annotator {annotator!r:.80}: {e}") from None
    log_path = Path(log_path)
    reader = LogReader(log_path)  # validates the log before anything is registered
    store = LabelStore(db_path)
    try:
        log = store.add_log(log_path)
        setup = PipelineRunner(reader.metadata, config_path=config_path, bin_model=bin_model)
        catalog = Catalog(frames_iter=lambda: reader.frames(), prepare=setup.prepare_for_page, store=store, log=log,
                          total_hint=reader.n_frames)
        session = Session(log_path=log_path, store=store, log=log, catalog=catalog,
                          token=token or new_token(), annotator=annotator, pipeline=setup, reader=reader)
    except BaseException:
        store.close()
        raise
    catalog.start()
    return session
