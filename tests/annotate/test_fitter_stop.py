"""The labelling page's fitter stops at once (:meth:`annotate.fits.Fitter.stop`; docs/labelling.md, the section of the
round of 2026-12-07a): a stop while a frame is being fitted ends that fit at its next stop point (:mod:`zcut.cancel`),
the frame stays unfitted (waiting, no result kept, none partial), and a fitter that is not stopped gives the page the
fits :func:`annotate.fits.fit_frame` gives outside any scope. A real synthetic log (hand-made rods, 384 × 240, its part
model attached, shared with other modules: tests/session_logs.py), prepared as ``zcut annotate`` prepares it."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from fitter_helpers import ends_of_fits
from session_logs import synth_once

from annotate.fits import STOP_WAIT_S, Fitter, Job, fit_frame
from replay.options import PipelineOptions
from replay.pipeline.explained import NAME

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    log = synth_once(tmp_path_factory, parts="rods", frames=2, seed=11, size="240x384")
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    assert session.prepared is not None
    return session, frame, result


def _fitter(session, points) -> Fitter:
    return Fitter(session.config, session.prepared.model, points, model_name="rods", model_points=[],
                  k=float(session.config.bank[NAME].k))


def test_a_stop_during_a_fit_ends_it_and_the_frame_stays_unfitted(prepared, monkeypatch):
    session, frame, result = prepared
    ends = ends_of_fits(monkeypatch)
    begun = threading.Event()
    stoppers: list[threading.Thread] = []

    def points(i: int) -> np.ndarray:
        # the fitting thread reads the frame's points as its fit begins: the page is closed now
        stoppers.append(threading.Thread(target=fitter.stop))
        stoppers[0].start()
        assert fitter._stop.wait(60)  # stop() asked before the fit goes on
        begun.set()
        return frame.xyz

    fitter = _fitter(session, points)
    fitter.submit(frame, result)
    fitter.start()
    assert begun.wait(300)
    stoppers[0].join(timeout=2 * STOP_WAIT_S)
    assert fitter._thread is not None
    fitter._thread.join(timeout=300)  # a loaded machine: not a wall-time assert, the property below is
    assert fitter.stopped
    assert ends == ["Cancelled"]  # the fit ended part-way (zcut.errors.Cancelled), not finished
    assert fitter.results == {} and fitter.status(frame.index) == ("waiting", None)
    assert fitter.wait(frame.index, timeout=0.1) is None


def test_a_fitter_not_stopped_gives_the_pages_fits_unchanged(prepared, monkeypatch):
    session, frame, result = prepared
    ends = ends_of_fits(monkeypatch)
    fitter = _fitter(session, lambda i: frame.xyz)
    fitter.submit(frame, result)
    fitter.start()
    got = fitter.wait(frame.index, timeout=600)
    fitter.stop()
    assert fitter.stopped and ends == ["returned"]
    plain = fit_frame(frame, Job.of(result), session.config, session.prepared.model)  # outside any scope
    assert got is not None and got.status == plain.status == "ready" and len(got.fits) > 0, got
    assert got.message == plain.message and got.fits == plain.fits
    for name in ("fit_pix", "fit_of", "un_pix", "un_dist", "un_err", "un_code"):
        np.testing.assert_array_equal(getattr(got, name), getattr(plain, name), err_msg=name)
