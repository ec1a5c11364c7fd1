"""The page's proposals with a part model (annotate/fits.py): the zone the page serves, above the rim included.

A real ray-traced log (``write_raytraced_log``, spheres at 320 × 200: its interreflection ghosts put
some 250 points above the bin's rim), the pipeline's zone as ``zcut annotate`` prepares it, the page's
own :func:`annotate.fits.fit_frame` and bundle.
"""

from __future__ import annotations

import numpy as np
import pytest

from annotate.fits import Job, fit_frame
from annotate.payload import parse_bundle
from replay.options import PipelineOptions
from replay.pipeline.explained import NAME, run_explained
from replay.pipeline.stages import bin_zone
from zcut import explained as ex

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    from replay.synth.raytrace import write_raytraced_log

    log = write_raytraced_log(tmp_path_factory.mktemp("rtprop") / "rt.mcap", kind="spheres", frames=1, seed=9633,
                              size=(200, 320))
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    assert session.prepared is not None
    return session, frame, result


def test_proposals_hold_the_unexplained_points_above_the_rim(prepared):
    session, frame, r = prepared
    job = Job.of(r)
    easy = np.asarray(job.removal.easy_outliers, bool)
    assert easy.sum() > 100 and not (easy & job.zone).any()
    ff = fit_frame(frame, job, session.config, session.prepared.model)
    assert ff.status == "ready", ff.message
    H, W = ff.shape
    un = np.zeros(H * W, bool)
    un[ff.un_pix] = True
    un = un.reshape(H, W)
    served = (job.zone | easy) & job.valid
    assert not (un & ~served).any()
    # in the zone: the method's own outliers, to the pixel
    np.testing.assert_array_equal(un & job.zone, np.asarray(r.outliers[NAME], bool) & job.zone)
    # above the rim: judged by the same rule against the same surfaces
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    _, detail, _ = run_explained(frame, zone, session.config, judge_above_rim=True)
    assert detail is not None and np.isfinite(detail.dist_mm[easy]).all()
    far = ex.unexplained(detail.dist_mm, detail.err_mm, session.config.bank[NAME].k) & easy
    assert far.sum() > 100
    np.testing.assert_array_equal(un & easy, far)
    # every unexplained pixel is in a proposal of the bundle, and nothing else is
    valid = job.valid
    heights = np.where(valid, -1000.0 * frame.xyz[..., 2].astype(np.float64), np.nan)
    header, arrays = parse_bundle(ff.bundle(heights_mm=heights, valid=valid, rejected=set(), header={}))
    np.testing.assert_array_equal(np.asarray(arrays["proposals"]).reshape(H, W) > 0, un)
    assert 0 < header["n_proposals"] <= un.sum()


def test_judging_above_the_rim_changes_nothing_in_the_zone(prepared):
    session, frame, _ = prepared
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    a_out, a, _ = run_explained(frame, zone, session.config)
    b_out, b, _ = run_explained(frame, zone, session.config, judge_above_rim=True)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a_out, b_out)
    z = zone.zone
    np.testing.assert_array_equal(a.dist_mm[z], b.dist_mm[z])
    np.testing.assert_array_equal(a.err_mm[z], b.err_mm[z])
    np.testing.assert_array_equal(a.surface[z], b.surface[z])
    assert np.isnan(a.dist_mm[zone.easy]).all() and np.isfinite(b.dist_mm[zone.easy]).all()


@pytest.fixture(scope="module")
def handmade(tmp_path_factory):
    from cli_helpers import synth_log

    log = synth_log(tmp_path_factory.mktemp("rtprop_hm") / "spheres.mcap", parts="spheres", frames=1, seed=9634,
                    size="320x200")
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    return session, frame, result


def test_the_fits_residuals_are_measured_robustly_never_above_the_stated(handmade):
    """The Err of a fitted instance's pixels comes from :func:`zcut.explained.fit_sigmas` on its zone
    pixels: at most the fit's stated RMS, below it on the fits whose attached outliers inflate it
    (hand-made spheres at 320 × 200: the ray-traced ones are not fitted at that size)."""
    session, frame, _ = handmade
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    _, d, _ = run_explained(frame, zone, session.config)
    assert d is not None and d.fits
    stated = np.array([f.err_mm for f in d.fits])
    c = ex.footprint_mm(frame.xyz.astype(np.float64) * 1000.0, 0.5 * (frame.intrinsics.fx + frame.intrinsics.fy))
    part = (d.surface >= 0) & zone.zone
    sigma = np.sqrt(np.maximum(d.err_mm[part] ** 2 - 0.5 * c[part] ** 2, 0.0))
    floor = session.config.bank[NAME].err_floor_mm
    used = np.where(d.err_mm[part] > floor, sigma, 0.0)
    assert (used <= stated[d.surface[part]] + 1e-9).all()
    robust = ex.fit_sigmas(ex.Nearest(d.dist_mm, d.surface), list(stated), where=zone.zone)
    np.testing.assert_allclose(sigma[d.err_mm[part] > floor],
                               np.asarray(robust)[d.surface[part]][d.err_mm[part] > floor], rtol=1e-9, atol=1e-9)
    assert (np.asarray(robust) < stated).any()

