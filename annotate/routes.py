"""The labelling server's routes: plain functions of the served :class:`Page` and the request.

Every handler is ``handler(page, request) -> Response`` (``async`` where it reads a body), so it can
be read, called and tested alone; :data:`ROUTES` lists them with their paths and methods, and
:func:`annotate.server.create_app` binds them to one page. A handler never sees a request the
access gate refused (:mod:`annotate.guard`); the gate puts the caller's page session in
``request.scope["zcut"]``.

Labels: an edit is acknowledged (200 with the new revision) only after the store committed it; a
save based on an old revision gets 409 with the latest revision and stores nothing (the page then
shows both versions and merges); a malformed or invalid label gets 4xx and stores nothing. The
annotator is the server's fixed one, or the page session's own (chosen once,
``POST /api/annotator``), never a name taken from the request; a label body naming another
annotator is refused (403).
"""

from __future__ import annotations

import json
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request
from starlette.responses import HTMLResponse, JSONResponse, Response

from annotate.assistant import CONFIDENT, Trainer
from annotate.catalogue import Catalogue, FrameNotReady
from annotate.guard import Client, Clients
from annotate.inputs import (
    BadRequest,
    base_revision,
    client_seq,
    frame_index,
    label_masks,
    parse_json_body,
    uint,
)
from annotate.payload import ServedFrame, bundle_with_blobs, make_bundle, make_geometry, make_view, turbo_lut
from annotate.presence import Presence, describe_server
from annotate.store import (
    FrameRecord,
    LabelConflictError,
    LabelStore,
    LabelSupersededError,
    LabelValidationError,
    LogRecord,
)
from zcut.cloud import height_mm

if TYPE_CHECKING:
    from replay.pipeline.session import ReplaySession

STATIC_FILES = {"app.js": "text/javascript", "worker.js": "text/javascript", "view3d.js": "text/javascript",
                "style.css": "text/css"}
#: Largest rectangle of points one geometry request may ask for (pixels).
MAX_GEOMETRY_PX = 256 * 256
#: The page's own headers: no caching, no framing, no referrer, a strict content policy.
PAGE_HEADERS = {
    "Cache-Control": "no-store", "Referrer-Policy": "no-referrer", "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data: blob:; frame-ancestors 'none'; "
                               "base-uri 'none'; form-action 'none'; object-src 'none'",
}


@dataclass
class Page:
    """What one running labelling page serves: the log, its catalogue, the store, the token, the
    annotator mode.

    Attributes
    ----------
    log_path : Path
    store : LabelStore
    log : LogRecord
        The log's row in the store.
    catalogue : Catalogue
        The frames prepared so far.
    token : str
        The secret of the page's URL (:mod:`annotate.guard`).
    annotator : str or None
        The name every page labels as, or None when each page session chooses its own
        (``POST /api/annotator``).
    replay : ReplaySession or None
        The log opened for replay: its ``notes`` (what the config resolution decided) are shown on the
        page, with the catalogue's ``damage`` (what a damaged log lost).
    clients : Clients
        The page sessions (cookies).
    presence : Presence or None
        This server's row among the store's servers, once :meth:`announce` ran.
    assistant : Trainer or None
        The labelling assistant (:mod:`annotate.assistant`), retrained in the background when labels
        change.
    focus : dict or None
        With ``zcut annotate --disagreement``, what the page says of that review
        (:meth:`annotate.disagreement.Disagreement.summary`); None otherwise.
    """

    log_path: Path
    store: LabelStore
    log: LogRecord
    catalogue: Catalogue
    token: str
    annotator: str | None
    replay: ReplaySession | None = None
    clients: Clients = field(default_factory=Clients)
    presence: Presence | None = None
    assistant: Trainer | None = None
    turbo: list[list[int]] = field(default_factory=turbo_lut)
    focus: dict[str, Any] | None = None
    #: (frame record id, revision) -> (candidates decided, accepted) of that label
    decided: dict[tuple[int, int], tuple[int, int]] = field(default_factory=dict)
    #: why the page shows no fits ("" when a part model is known: :mod:`annotate.fits`)
    fits_note: str = ""
    #: (frame index, seeds, rejected fits) -> (the fits, their bundle: :meth:`annotate.fits.FrameFits.bundle`)
    fits_bundles: dict[tuple[int, tuple[tuple[int, int], ...], frozenset[int]], tuple[Any, bytes]] = \
        field(default_factory=dict)

    def announce(self, port: int | None) -> list[str]:
        """Register this server in the store; returns one line per other live server of the store."""
        self.presence = Presence(self.store, log_sha256=self.log.sha256, port=port)
        return [describe_server(s) for s in self.presence.others()]

    def close(self) -> None:
        """Stop preparing, leave the store's servers table, remove the spilled points, close the store."""
        self.catalogue.stop()
        if self.catalogue.fitter is not None:
            self.catalogue.fitter.stop()
        if self.assistant is not None:
            self.assistant.stop()
        if self.presence is not None:
            self.presence.stop()
        self.catalogue.geometry.close()
        self.store.close()


# --------------------------------------------------------------------------- what a request refers to
def requested_frame(page: Page, request: Request) -> tuple[ServedFrame, FrameRecord]:
    """The prepared frame of the path's ``{index}`` (404 unknown, 503 with Retry-After not ready)."""
    return _frame(page, frame_index(request.path_params["index"]))


def _frame(page: Page, index: int) -> tuple[ServedFrame, FrameRecord]:
    try:
        got = page.catalogue.get(index)
    except FrameNotReady as e:
        raise BadRequest(503, str(e), headers={"Retry-After": str(e.retry_after_s)}) from None
    if got is None:
        raise BadRequest(404, f"no frame {index}")
    return got


def client_of(page: Page, request: Request) -> Client | None:
    """The request's page session (None for the token header)."""
    z = request.scope.get("zcut", {})
    return page.clients.get(z["sid"]) if z.get("sid") else None


def annotator_of(page: Page, request: Request) -> str:
    """The annotator this request labels as: the server's, or the page session's binding (403 if none yet)."""
    if page.annotator is not None:
        return page.annotator
    c = client_of(page, request)
    if c is None or c.annotator is None:
        raise BadRequest(403, "no annotator chosen for this page yet (POST /api/annotator)")
    return c.annotator


def decisions(page: Page, sf: ServedFrame, rec: FrameRecord, who: str, revision: int) -> tuple[int, int]:
    """(candidates decided, accepted) by ``who``'s label at ``revision`` (cached per revision)."""
    key = (rec.id, revision)
    if key not in page.decided:
        lab = page.store.label(rec, annotator=who, revision=revision)
        page.decided[key] = (0, 0) if lab is None else sf.decisions(lab.outliers, lab.reviewed)
    return page.decided[key]


def _bytes(data: bytes, media: str = "application/octet-stream") -> Response:
    return Response(data, media_type=media, headers={"Cache-Control": "no-store"})


async def _read_body(request: Request) -> bytes:
    try:
        return await request.body()
    except ClientDisconnect:
        raise BadRequest(400, "the body did not arrive whole") from None


def _mode(page: Page) -> str:
    return "fixed" if page.annotator else "choose"


# --------------------------------------------------------------------------- the page and its files
def index(page: Page, request: Request) -> Response:
    """``GET /``: the page, with its boot data (log name, annotator mode) inlined."""
    html = (resources.files("annotate") / "static" / "index.html").read_text()
    c = client_of(page, request)
    boot = json.dumps({"log": page.log.name, "mode": _mode(page),
                       "annotator": page.annotator or (c.annotator if c else None),
                       "max_geometry_px": MAX_GEOMETRY_PX})  # the client tiles its geometry requests under it
    html = html.replace("{{BOOT}}", boot.replace("<", "\\u003c"))
    return HTMLResponse(html, headers=PAGE_HEADERS)


def static_file(page: Page, request: Request) -> Response:
    """``GET /static/{name}``: one of :data:`STATIC_FILES` (no path ever comes from the request)."""
    name = request.path_params["name"]
    if name not in STATIC_FILES:
        return Response("not found", status_code=404)
    return Response((resources.files("annotate") / "static" / name).read_bytes(), media_type=STATIC_FILES[name],
                    headers={"Cache-Control": "no-store"})


# --------------------------------------------------------------------------- the session and the annotator
def _notes(replay: Any) -> list[str]:
    """What the config resolution decided, and the warning of a log replayed without a bin model."""
    if replay is None:
        return []
    choice = getattr(replay, "bin_model_choice", None)
    return list(replay.notes) + ([choice.warning] if choice is not None and choice.warning else [])


def api_session(page: Page, request: Request) -> Response:
    """``GET /api/session``: the log, the annotator, preparation progress, notes, damage, other servers."""
    c = page.catalogue
    client = client_of(page, request)
    others = page.presence.others() if page.presence is not None else []
    replay = page.replay
    return JSONResponse({
        "log": page.log.name, "sha256": page.log.sha256, "mode": _mode(page),
        "annotator": page.annotator or (client.annotator if client else None),
        "total": c.total, "prepared": c.prepared, "done": c.done, "error": c.error,
        "notes": _notes(replay),
        "part": page.catalogue.part,
        "fits": {"model": page.catalogue.fitter.model_name, "k": page.catalogue.fitter.k}
        if page.catalogue.fitter is not None else {"model": None, "note": page.fits_note},
        "damage": [d.text for d in c.damage],
        "annotators": page.store.annotators(page.log),
        "other_servers": [describe_server(s) for s in others], "turbo": page.turbo,
        "focus": page.focus,
    })


async def api_annotator(page: Page, request: Request) -> Response:
    """``POST /api/annotator {"name"}``: a page session chooses its annotator, once."""
    if page.annotator is not None:
        raise BadRequest(409, f"this server labels as {page.annotator!r} (zcut annotate --annotator)")
    z = request.scope.get("zcut", {})
    if z.get("via") != "cookie":
        raise BadRequest(403, "an annotator is chosen by a page session (open the page's URL first)")
    d = parse_json_body(await _read_body(request))
    try:
        name = page.store.check_new_annotator(d.get("name"), also=page.clients.names())
    except LabelValidationError as e:
        raise BadRequest(422, str(e)) from None
    bound = page.clients.bind(z["sid"], name)
    if bound != name:
        return JSONResponse({"error": f"this page labels as {bound!r} already", "annotator": bound},
                            status_code=409)
    return JSONResponse({"annotator": bound})


# --------------------------------------------------------------------------- frames
def api_frames(page: Page, request: Request) -> Response:
    """``GET /api/frames``: every prepared frame with its counts and the annotator's progress on it."""
    who = annotator_of(page, request)
    current = page.store.current_labels(page.log, annotator=who)
    c = page.catalogue
    rows = []
    for sf, rec in c.snapshot():
        lab = current.get(rec.id)
        decided, accepted = decisions(page, sf, rec, who, lab.revision) if lab else (0, 0)
        p = page.assistant.predictions(sf) if page.assistant is not None else None
        uncertain = None if p is None else int((np.maximum(p, 1 - p) < CONFIDENT).sum())
        rows.append({"index": sf.index, "stamp_ns": sf.stamp_ns, "height": sf.height, "width": sf.width,
                     "n_zcut": sf.n_zcut, "n_sor": sf.n_sor,
                     "n_sor_listed": sf.n_sor_listed, "n_candidates": sf.n_groups, "n_groups": sf.n_groups,
                     "uncertain": uncertain, "bin_stages": sf.bin_stages,
                     "disagreement": sf.disagreement, "n_valid": sf.n_valid,
                     "revision": lab.revision if lab else 0,
                     "n_outliers": lab.n_outliers if lab else 0, "n_reviewed": lab.n_reviewed if lab else 0,
                     "reviewed": bool(lab and lab.n_reviewed >= sf.n_valid),
                     "decided": decided, "accepted": accepted})
    total = c.total
    return JSONResponse({"frames": rows, "total": total if total is not None else len(rows),
                         "reviewed": sum(r["reviewed"] for r in rows), "done": c.done, "error": c.error})


def api_bundle(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/bundle``: the frame's masks and candidate table (:mod:`annotate.payload`)."""
    sf, _ = requested_frame(page, request)
    return _bytes(sf.bundle)


def _image(sf: ServedFrame, kind: str) -> bytes:
    """The RGB JPEG, or the height map's when asked or when the frame has no RGB image."""
    if kind == "height" or sf.rgb_jpeg is None:
        return sf.height_jpeg
    return sf.rgb_jpeg


def api_image(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/image/{kind}``: ``rgb`` or ``height`` JPEG."""
    sf, _ = requested_frame(page, request)
    kind = request.path_params["kind"]
    if kind not in ("rgb", "height"):
        raise BadRequest(404, f"no image kind {kind[:20]!r}")
    return _bytes(_image(sf, kind), "image/jpeg")


def label_bundle(page: Page, sf: ServedFrame, rec: FrameRecord, who: str) -> bytes:
    """``who``'s current label of a frame as a bundle (no sections when there is none)."""
    got = page.store.label_blobs(rec, annotator=who)
    header = {"index": sf.index, "height": sf.height, "width": sf.width, "annotator": who,
              "revision": got[0] if got else 0}
    blobs = [("outliers", got[1]), ("reviewed", got[2])] if got else []
    return bundle_with_blobs(header, blobs)


def api_label_get(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/label``: the annotator's current label (:func:`label_bundle`)."""
    sf, rec = requested_frame(page, request)
    return _bytes(label_bundle(page, sf, rec, annotator_of(page, request)))


def api_view(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/view?image=rgb|height|none``: bundle + label (+ one JPEG) in one response."""
    sf, rec = requested_frame(page, request)
    kind = request.query_params.get("image", "rgb")
    if kind not in ("rgb", "height", "none"):
        raise BadRequest(400, f"image must be rgb, height or none, got {kind[:20]!r}")
    parts = [("bundle", sf.bundle), ("label", label_bundle(page, sf, rec, annotator_of(page, request)))]
    if kind != "none":
        parts.append(("image", _image(sf, kind)))
    return _bytes(make_view(parts))


def api_geometry(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/geometry?x0&y0&x1&y1``: the points of a rectangle ``x0 <= col < x1,
    y0 <= row < y1`` (clipped to the frame; at most :data:`MAX_GEOMETRY_PX` pixels)."""
    sf, _ = requested_frame(page, request)
    q = request.query_params
    big = 1 << 30
    x0, y0 = uint(q.get("x0"), "x0", hi=big), uint(q.get("y0"), "y0", hi=big)
    x1, y1 = uint(q.get("x1"), "x1", hi=big), uint(q.get("y1"), "y1", hi=big)
    x0, x1 = min(x0, sf.width), min(x1, sf.width)
    y0, y1 = min(y0, sf.height), min(y1, sf.height)
    if x1 <= x0 or y1 <= y0:
        raise BadRequest(400, f"empty rectangle x {x0}..{x1}, y {y0}..{y1} in a {sf.width}x{sf.height} frame")
    if (x1 - x0) * (y1 - y0) > MAX_GEOMETRY_PX:
        raise BadRequest(400, f"rectangle of {(x1 - x0) * (y1 - y0)} px: at most {MAX_GEOMETRY_PX} per request")
    return _bytes(make_geometry(page.catalogue.geometry.rect(sf.index, x0, y0, x1, y1), x0=x0, y0=y0))


def api_proposals(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/proposals``: the assistant's outlier probability for each of the frame's
    groups (in group order), whether the page may pre-fill the confident ones, and why not."""
    sf, _ = requested_frame(page, request)
    tr = page.assistant
    st: dict[str, Any] = tr.status() if tr is not None else {"version": 0, "message": "no assistant", "model": None}
    p = tr.predictions(sf) if tr is not None else None
    why = st["model"]["why_not"] if st["model"] else None
    return JSONResponse({"index": sf.index, "version": st["version"], "message": st["message"],
                         "model": st["model"], "p": [] if p is None else [round(float(v), 4) for v in p],
                         "prefill": p is not None and why is None, "why_not": why, "confident": CONFIDENT},
                        headers={"Cache-Control": "no-store"})


def api_assistant(page: Page, request: Request) -> Response:
    """``GET /api/assistant``: the assistant's state (its model, held-out accuracy, last message)."""
    tr = page.assistant
    return JSONResponse(tr.status() if tr is not None else {"version": 0, "training": False,
                                                            "message": "no assistant", "model": None})


# --------------------------------------------------------------------------- part fits
def fits_bundle(page: Page, sf: ServedFrame, rec: FrameRecord, who: str) -> bytes:
    """The frame's fits as ``who`` judged them (:meth:`annotate.fits.FrameFits.bundle`: that annotator's
    seeds applied, :meth:`annotate.fits.Fitter.fits_for`, and rejected fits' pixels judged again), or their
    status (``none``: no part model; ``waiting``, ``fitting``; ``error``) in a bundle without sections."""
    fitter = page.catalogue.fitter
    header: dict[str, Any] = {"index": sf.index}
    if fitter is None:
        return make_bundle({**header, "status": "none", "message": page.fits_note, "height": sf.height,
                            "width": sf.width}, [], compress=False)
    header.update({"k": fitter.k, "model": fitter.model_name, "model_points": fitter.model_points})
    fitter.want(sf.index)
    status, _ = fitter.status(sf.index)
    seeds = page.store.fit_seeds(rec, annotator=who)
    ff = fitter.fits_for(sf.index, seeds)
    if ff is None:
        return make_bundle({**header, "status": status, "height": sf.height, "width": sf.width,
                            "message": "fitting the part model…" if status == "fitting" else "waiting to be fitted…"},
                           [], compress=False)
    rejected = ff.rejected(page.store.rejected_fits(rec, annotator=who))
    key = (sf.index, seeds, frozenset(rejected))
    got = page.fits_bundles.get(key)
    if got is None or got[0] is not ff:
        xyz = np.asarray(page.catalogue.geometry.points(sf.index))
        valid = np.isfinite(xyz).all(axis=2)
        while len(page.fits_bundles) >= 32:  # a few frames' worth, the oldest out first
            page.fits_bundles.pop(next(iter(page.fits_bundles)))
        data = ff.bundle(heights_mm=height_mm(xyz), valid=valid, rejected=rejected, header=header,
                         xyz_mm=xyz.astype(np.float64) * 1000.0 if rejected else None)
        page.fits_bundles[key] = got = (ff, data)
    return got[1]


def api_fits(page: Page, request: Request) -> Response:
    """``GET /api/frames/{index}/fits``: the frame's part fits and proposals (:func:`fits_bundle`)."""
    sf, rec = requested_frame(page, request)
    return _bytes(fits_bundle(page, sf, rec, annotator_of(page, request)))


async def api_fit_put(page: Page, request: Request) -> Response:
    """``PUT /api/frames/{index}/fits/{fit}`` ``{"rejected": bool}``: the annotator rejects a fit (its
    pixels return to review) or takes it back; stored with the labels; answers the new fits bundle."""
    sf, rec = requested_frame(page, request)
    who = annotator_of(page, request)
    fit = uint(request.path_params["fit"], "fit", hi=1 << 20)
    d = parse_json_body(await _read_body(request))
    if not isinstance(d.get("rejected"), bool):
        raise BadRequest(422, "a fit decision is {\"rejected\": true | false}")
    fitter = page.catalogue.fitter
    status, ff = (None, None) if fitter is None else fitter.status(sf.index)
    if ff is None or ff.status != "ready":
        raise BadRequest(409, f"frame {sf.index} has no fits to judge ({page.fits_note or status})")
    assert fitter is not None
    ff = await run_in_threadpool(fitter.fits_for, sf.index, page.store.fit_seeds(rec, annotator=who))
    assert ff is not None
    if fit >= len(ff.fits):
        raise BadRequest(404, f"frame {sf.index} has {len(ff.fits)} fits, no fit {fit}")

    def save() -> bytes:
        page.store.save_fit_decision(rec, annotator=who, fit=fit, position_mm=ff.position_mm(fit),
                                     rejected=bool(d["rejected"]))
        return fits_bundle(page, sf, rec, who)

    return _bytes(await run_in_threadpool(save))


async def api_fit_seed(page: Page, request: Request) -> Response:
    """``POST /api/frames/{index}/fits/seed`` ``{"x", "y"}``: seed a missed instance at that pixel
    (:meth:`annotate.fits.Fitter.seed`, on the annotator's earlier seeds); a seed that found an instance is
    stored (:meth:`annotate.store.LabelStore.save_fit_seed`); answers the new fits bundle,
    ``X-Zcut-Seeded`` how many were found."""
    sf, rec = requested_frame(page, request)
    who = annotator_of(page, request)
    d = parse_json_body(await _read_body(request))
    x, y = d.get("x"), d.get("y")
    if not (isinstance(x, int) and isinstance(y, int) and 0 <= x < sf.width and 0 <= y < sf.height):
        raise BadRequest(422, f"a seed is {{\"x\", \"y\"}}: a pixel of the {sf.width}x{sf.height} frame")
    fitter = page.catalogue.fitter
    status, ff = (None, None) if fitter is None else fitter.status(sf.index)
    if fitter is None or ff is None or ff.status != "ready":
        raise BadRequest(409, f"frame {sf.index} has no fits to add to ({page.fits_note or status})")

    def seed() -> tuple[int, bytes]:
        assert fitter is not None
        _, n = fitter.seed(sf.index, page.store.fit_seeds(rec, annotator=who), x, y)
        if n:
            page.store.save_fit_seed(rec, annotator=who, x=x, y=y, found=n)
        return n, fits_bundle(page, sf, rec, who)

    n, data = await run_in_threadpool(seed)
    return Response(data, media_type="application/octet-stream", headers={"Cache-Control": "no-store",
                                                                          "X-Zcut-Seeded": str(n)})


# --------------------------------------------------------------------------- saving a label
async def api_label_put(page: Page, request: Request) -> Response:
    """``PUT /api/frames/{index}/label`` (application/json): save a label (:func:`save_label`)."""
    index_ = frame_index(request.path_params["index"])
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        raise BadRequest(415, "label must be sent as application/json")
    who = annotator_of(page, request)
    d = parse_json_body(await _read_body(request))
    return await run_in_threadpool(save_label, page, index_, who, d)


def save_label(page: Page, index: int, who: str, d: dict[str, Any]) -> Response:
    """Store ``who``'s label body ``d`` for frame ``index``; the response says what was committed.

    200 ``{"revision", "superseded", "n_outliers", "n_reviewed", "reviewed", "decided", ...}`` once
    the store committed it (or found it superseded by the same page's later save); 409 ``{"latest"}``
    when based on an old revision; 4xx for a body that is not a valid label of this frame.
    """
    sf, rec = _frame(page, index)
    if "annotator" in d and d["annotator"] != who:
        raise BadRequest(403, f"this page labels as {who!r}: the annotator is never taken from a request")
    base = base_revision(d)
    client, seq = client_seq(d)
    if d.get("height") != sf.height or d.get("width") != sf.width:
        raise BadRequest(422, f"label shape must be {sf.height}x{sf.width}")
    outliers, reviewed = label_masks(d, (sf.height, sf.width), page.store.valid_mask(rec))
    superseded = False
    try:
        rev = page.store.save_label(rec, annotator=who, outliers=outliers, reviewed=reviewed,
                                    base_revision=base, source="page", client=client, client_seq=seq)
    except LabelConflictError as e:
        return JSONResponse({"error": str(e), "latest": e.latest}, status_code=409)
    except LabelSupersededError as e:
        rev, superseded = e.latest, True
    except LabelValidationError as e:
        raise BadRequest(422, str(e)) from None
    if not superseded:
        page.decided[(rec.id, rev)] = sf.decisions(outliers, reviewed)
        if page.assistant is not None:
            page.assistant.poke()
    decided, accepted = decisions(page, sf, rec, who, rev)
    n_reviewed = int(reviewed.sum())
    return JSONResponse({"revision": rev, "index": sf.index, "annotator": who, "superseded": superseded,
                         "n_outliers": int(outliers.sum()), "n_reviewed": n_reviewed,
                         "reviewed": n_reviewed >= sf.n_valid, "decided": decided, "accepted": accepted,
                         "committed_ns": time.time_ns()})


Handler = Callable[[Page, Request], Response | Awaitable[Response]]

#: (path, method, handler) of every route, in the order Starlette matches them.
ROUTES: tuple[tuple[str, str, Handler], ...] = (
    ("/", "GET", index),
    ("/static/{name}", "GET", static_file),
    ("/api/session", "GET", api_session),
    ("/api/annotator", "POST", api_annotator),
    ("/api/frames", "GET", api_frames),
    ("/api/frames/{index}/bundle", "GET", api_bundle),
    ("/api/frames/{index}/image/{kind}", "GET", api_image),
    ("/api/frames/{index}/view", "GET", api_view),
    ("/api/frames/{index}/geometry", "GET", api_geometry),
    ("/api/frames/{index}/label", "GET", api_label_get),
    ("/api/frames/{index}/label", "PUT", api_label_put),
    ("/api/frames/{index}/proposals", "GET", api_proposals),
    ("/api/assistant", "GET", api_assistant),
    ("/api/frames/{index}/fits", "GET", api_fits),
    ("/api/frames/{index}/fits/seed", "POST", api_fit_seed),
    ("/api/frames/{index}/fits/{fit}", "PUT", api_fit_put),
)
