"""The labelling page's server: a Starlette ASGI app on 127.0.0.1, one log and one label store.

Read it in this order:

- :func:`open_page` opens the log for replay (:meth:`replay.pipeline.session.ReplaySession.open`,
  as every command does) and the label store, and starts the frame catalogue
  (:mod:`annotate.catalogue`: frames prepared in log order by a background thread; a frame not
  prepared yet is answered at once with 503 and ``Retry-After``, never by holding a worker).
- :func:`create_app` binds the routes (:mod:`annotate.routes`: one plain function per route, taking
  the :class:`~annotate.routes.Page` and the request) and wraps them in the access and size guards
  (:mod:`annotate.guard`: token then cookie, Origin on writes, Host, body size and time limits).
- :func:`make_server` is the ``uvicorn.Server`` with the header timeout; ``zcut annotate``
  (:mod:`cli.commands.annotate`) runs it on its socket.

Another ``zcut annotate`` on the same store is detected through the store's ``servers`` table
(:mod:`annotate.presence`); the command says so when it starts and the page shows it. Request
bodies and parameters are parsed by :mod:`annotate.inputs` (a malformed request is a 4xx with a
one-line reason, never a 500).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from annotate.assistant import GATE, Trainer
from annotate.catalogue import Catalogue
from annotate.fits import fitter_for
from annotate.guard import (
    ALLOWED_HOSTS,
    BODY_TIMEOUT_S,
    HEADER_TIMEOUT_S,
    MAX_BODY_BYTES,
    AccessGate,
    ASGIApp,
    BodyGuard,
    new_token,
    timeout_protocol,
)
from annotate.inputs import BadRequest
from annotate.routes import ROUTES, Page
from annotate.store import LabelStore, LabelValidationError, StoreError, StoreFullError

if TYPE_CHECKING:
    from collections.abc import Callable

    import uvicorn

    from zcut.bin_model import BinModel


async def _bad_request(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, BadRequest)
    return JSONResponse({"error": str(exc)}, status_code=exc.status, headers=exc.headers)


async def _store_error(request: Request, exc: Exception) -> Response:
    return JSONResponse({"error": str(exc)}, status_code=500)


async def _store_full(request: Request, exc: Exception) -> Response:
    # 507 Insufficient Storage: nothing was written; the page keeps the edit and sends it again
    return JSONResponse({"error": str(exc), "disk_full": True}, status_code=507, headers={"Retry-After": "5"})


def create_app(page: Page, *, max_body_bytes: int = MAX_BODY_BYTES, body_timeout_s: float = BODY_TIMEOUT_S,
               allowed_hosts: tuple[str, ...] = ALLOWED_HOSTS) -> ASGIApp:
    """The ASGI app of a page: the access gate outermost, then the body guard, then the host check and
    the routes (:data:`annotate.routes.ROUTES`, each bound to ``page``)."""
    routes = [Route(path, functools.partial(handler, page), methods=[method]) for path, method, handler in ROUTES]
    app = Starlette(
        routes=routes,
        middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts))],
        exception_handlers={BadRequest: _bad_request, StoreError: _store_error, StoreFullError: _store_full},
    )
    guarded = BodyGuard(app, limit=max_body_bytes, timeout_s=body_timeout_s)
    return AccessGate(guarded, token=page.token, clients=page.clients, fixed_annotator=page.annotator,
                      allowed_hosts=allowed_hosts)


def make_server(page: Page, *, header_timeout_s: float = HEADER_TIMEOUT_S,
                body_timeout_s: float = BODY_TIMEOUT_S, max_body_bytes: int = MAX_BODY_BYTES) -> uvicorn.Server:
    """A ``uvicorn.Server`` for the page's app; run it with ``.run(sockets=[sock])``."""
    import uvicorn

    app = create_app(page, max_body_bytes=max_body_bytes, body_timeout_s=body_timeout_s)
    config = uvicorn.Config(app, log_level="warning", access_log=False, timeout_graceful_shutdown=5,
                            http=timeout_protocol(header_timeout_s), lifespan="off")
    return uvicorn.Server(config)


def open_page(
    log_path: str | Path,
    db_path: str | Path,
    *,
    annotator: str | None,
    config_path: str | Path | None = None,
    bin_model: BinModel | None = None,
    token: str | None = None,
    overrides: dict[str, Any] | None = None,
    topic: str | None = None,
    choose_bin_model: Callable[[Any], Any] | None = None,
    assistant_gate: float | None = None,
    focus: Callable[[Any], Any] | None = None,
    focus_summary: dict[str, Any] | None = None,
) -> Page:
    """Open the log for replay and the store, and start preparing frames.

    Parameters
    ----------
    log_path, db_path : path-like
    annotator : str or None
        The name every page labels as; None: each page session chooses its own once.
    config_path : path-like, optional
    bin_model : zcut.bin_model.BinModel, optional
    token : str, optional
        Default: a fresh :func:`annotate.guard.new_token`.
    overrides : dict, optional
        The command line's config layer (:func:`replay.pipeline.config.cli_layer`).
    topic : str, optional
        The cloud topic.
    choose_bin_model : callable, optional
        Chooses the bin model from the opened reader when ``bin_model`` is None
        (:meth:`replay.pipeline.session.ReplaySession.open`); its warning is among the page's notes.
    assistant_gate : float, optional
        The held-out agreement the assistant needs before its proposals are pre-filled
        (default :data:`annotate.assistant.GATE`).
    focus : callable, optional
        Given a frame, the only pixels its review groups hold (``--disagreement``:
        :meth:`annotate.disagreement.Disagreement.focus`).
    focus_summary : dict, optional
        What the page's header says of that review (:meth:`annotate.disagreement.Disagreement.summary`).

    With a part model (the config's ``explained.part_model``, which ``--part-model`` sets, else the
    log's ``part_model.ply``) the frames are also fitted in the background (:mod:`annotate.fits`).

    Candidates come from :meth:`replay.pipeline.session.ReplaySession.results` with the config
    resolved as ``zcut replay`` resolves it. The log is read and its config resolved before the
    store is touched: nothing is created for a log that cannot be read.

    Raises
    ------
    LogFormatError, LogDamageError (no readable frame), ConfigError, ParameterError (``annotator``, a part
    model that is no mesh)
    """
    from replay.pipeline.session import ReplaySession
    from zcut.errors import ParameterError

    log_path = Path(log_path)
    replay = ReplaySession.open(log_path, config_file=config_path, overrides=overrides, topic=topic,
                                bin_model=bin_model, choose_bin_model=choose_bin_model)
    store = LabelStore(db_path)
    catalogue = None
    try:
        if annotator is not None:
            try:
                annotator = store.check_new_annotator(annotator)
            except LabelValidationError as e:
                raise ParameterError(f"--annotator: {e}") from None
        log = store.add_log(log_path)
        catalogue = Catalogue.of_replay(replay, store, log, focus=focus)
        if focus is None:
            catalogue.fitter, fits_note = fitter_for(replay, log_path, catalogue.geometry.points)
        else:  # the review is of a comparison's disagreement alone: no fits, no unexplained proposals
            fits_note = "no part fits: the page lists only the pixels where the comparison's A and B disagree"
        page = Page(log_path=log_path, store=store, log=log, catalogue=catalogue, token=token or new_token(),
                    annotator=annotator, replay=replay, focus=focus_summary, fits_note=fits_note,
                    assistant=Trainer(catalogue, store, log, part=catalogue.part,
                                      gate=GATE if assistant_gate is None else assistant_gate))
    except BaseException:
        if catalogue is not None:
            catalogue.geometry.close()
        store.close()
        raise
    if catalogue.fitter is not None:
        catalogue.fitter.start()
    catalogue.start()
    assert page.assistant is not None
    page.assistant.start()
    return page
