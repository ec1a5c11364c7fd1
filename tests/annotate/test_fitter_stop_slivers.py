"""The labelling page's fitter stops a sliver pass under way (:meth:`annotate.fits.Fitter.stop`; docs/labelling.md, the
section of the round of 2026-12-07b): the method's sliver pass (:func:`zcut.sliver_fits.fit_slivers`, reached through
``replay.pipeline.explained``) has stop points (:mod:`zcut.cancel`), so a stop asked while it runs ends it at its next
one, the frame stays unfitted (waiting, no result kept), and a fitter not stopped gives the page the fits
:func:`annotate.fits.fit_frame` gives outside any scope, its sliver fits included. A real synthetic log (hand-made zinc
nuts, 640 × 480, seed 3, shared with other modules: tests/session_logs.py), prepared as ``zcut annotate`` prepares it;
its slivers are smaller than at 1920 × 1200, so the pass tries the regions of :data:`MIN_PX` px or more here (the
method's ``SLIVER_MIN_PX``, 150 px, leaves it no region on this frame: it would reach no stop point)."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest
from fitter_helpers import ends_of_fits
from session_logs import synth_once

import replay.pipeline.explained
import zcut.sliver_fits
from annotate.fits import STOP_WAIT_S, Fitter, Job, fit_frame
from replay.options import PipelineOptions
from replay.pipeline.explained import NAME
from zcut.errors import Cancelled

pytestmark = pytest.mark.slow
#: the sliver pass's smallest region on this small frame (``replay.pipeline.explained.SLIVER_MIN_PX`` in these tests)
MIN_PX = 30


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):  # type: ignore[no-untyped-def]
    log = synth_once(tmp_path_factory, parts="zinc_nuts", frames=4, seed=3, size="480x640")
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    assert session.prepared is not None
    return session, frame, result


def _fitter(session, points) -> Fitter:  # type: ignore[no-untyped-def]
    return Fitter(session.config, session.prepared.model, points, model_name="zinc nut", model_points=[],
                  k=float(session.config.bank[NAME].k))


def passes_of(monkeypatch: pytest.MonkeyPatch, on_entry: Any = None) -> list[str]:
    """How each sliver pass of the fitting thread or of this one ends (``returned`` with its fits' count, or
    ``Cancelled``; the session's own frame threads, which may run ahead, are not counted), ``on_entry()`` called as
    the fitting thread's begins."""
    ends: list[str] = []
    inner = zcut.sliver_fits.fit_slivers
    monkeypatch.setattr(replay.pipeline.explained, "SLIVER_MIN_PX", MIN_PX)
    here = threading.current_thread()

    def noted(*args: Any, **kw: Any) -> Any:
        me = threading.current_thread()
        if me is not here and me.name != "zcut-annotate-fits":
            return inner(*args, **kw)
        if on_entry is not None and me is not here:
            on_entry()
        try:
            got = inner(*args, **kw)
        except Cancelled:
            ends.append("Cancelled")
            raise
        ends.append(f"returned {len(got)}")
        return got

    monkeypatch.setattr(zcut.sliver_fits, "fit_slivers", noted)
    return ends


def test_a_stop_during_the_sliver_pass_ends_it_and_the_frame_stays_unfitted(prepared, monkeypatch):  # type: ignore[no-untyped-def]
    session, frame, result = prepared
    stoppers: list[threading.Thread] = []

    def page_closed() -> None:  # the sliver pass begins: the page is closed now, and the pass goes on
        stoppers.append(threading.Thread(target=fitter.stop))
        stoppers[0].start()
        assert fitter._stop.wait(60)

    passes = passes_of(monkeypatch, page_closed)
    ends = ends_of_fits(monkeypatch)
    fitter = _fitter(session, lambda i: frame.xyz)
    fitter.submit(frame, result)
    fitter.start()
    assert fitter._thread is not None
    fitter._thread.join(timeout=600)  # a loaded machine: not a wall-time assert, the properties below are
    stoppers[0].join(timeout=2 * STOP_WAIT_S)
    assert passes == ["Cancelled"]  # the pass itself raised at one of its stop points, after the fits'
    assert ends == ["Cancelled"] and fitter.stopped
    assert fitter.results == {} and fitter.status(frame.index) == ("waiting", None)


def test_a_fitter_not_stopped_gives_the_pages_fits_and_slivers_unchanged(prepared, monkeypatch):  # type: ignore[no-untyped-def]
    session, frame, result = prepared
    passes = passes_of(monkeypatch)
    fitter = _fitter(session, lambda i: frame.xyz)
    fitter.submit(frame, result)
    fitter.start()
    got = fitter.wait(frame.index, timeout=600)
    fitter.stop()
    plain = fit_frame(frame, Job.of(result), session.config, session.prepared.model)  # outside any scope
    assert len(passes) == 2 and passes[0] == passes[1] and passes[0] != "returned 0", passes  # slivers fitted
    assert got is not None and got.status == plain.status == "ready", got
    assert any(f.get("sliver") for f in got.fits)
    assert got.message == plain.message and got.fits == plain.fits
    for name in ("fit_pix", "fit_of", "un_pix", "un_dist", "un_err", "un_code"):
        np.testing.assert_array_equal(getattr(got, name), getattr(plain, name), err_msg=name)
