"""Stopping a long computation part-way: a scope in which zcut's long loops ask whether to go on.

A caller that runs a frame's fits in a background thread and may have to give up on them at once (the labelling
page is closed: ``annotate.fits.Fitter.stop``) runs them inside :func:`stop_when` with its check, e.g. an event's
``is_set``. The loops that take the time (the fits' regions and candidates, :mod:`zcut.fits.fit`) call
:func:`stop_point` between their steps; once the check returns True it raises :class:`zcut.errors.Cancelled`, and the
caller catches it. Outside a scope :func:`stop_point` does nothing.

Nothing a computation returns depends on the scope: it either finishes as it would without one (the check is only
read, never a number of the computation) or raises. The check is read at each stop point, so how soon a stop is
seen is the longest step between two of them (docs/labelling.md, the section of the round of 2026-12-07a).

Why a scope and not a keyword argument: the fits a page shows are reached through the method ``explained``
(``replay.pipeline.explained.run_explained``) and the pieces on top (:func:`zcut.top_pieces.top_pieces`, which
calls :func:`zcut.fits.fit_prepared` again); a ``should_stop`` keyword would travel through each of those
signatures to be read at the bottom. The scope is a :class:`contextvars.ContextVar`, as :func:`numpy.errstate`
is: it belongs to the thread (and asyncio task) that entered it, is restored on exit and keeps nothing across
calls — a request thread's fits, outside the scope, are never stopped by it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from contextvars import ContextVar

from zcut.errors import Cancelled

__all__ = ["stop_point", "stop_when"]

#: the check of the innermost :func:`stop_when` scope of this context (None: outside every scope)
_SHOULD_STOP: ContextVar[Callable[[], bool] | None] = ContextVar("zcut_should_stop", default=None)


@contextlib.contextmanager
def stop_when(should_stop: Callable[[], bool]) -> Iterator[None]:
    """Within the block, :func:`stop_point` raises :class:`zcut.errors.Cancelled` once ``should_stop()`` is True.

    Parameters
    ----------
    should_stop : callable () -> bool
        Asked at each stop point; cheap and thread-safe (e.g. ``threading.Event().is_set``).
    """
    token = _SHOULD_STOP.set(should_stop)
    try:
        yield
    finally:
        _SHOULD_STOP.reset(token)


def stop_point() -> None:
    """Raise :class:`zcut.errors.Cancelled` when inside a :func:`stop_when` scope whose check says stop; else
    nothing."""
    check = _SHOULD_STOP.get()
    if check is not None and check():
        raise Cancelled("stopped by the caller before the end (zcut.cancel.stop_when)")
