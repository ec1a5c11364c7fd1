"""Fits the camera saw through, only partly trusted (annotate/fits.py, :meth:`FrameFits.partly_trusted`;
docs/labelling.md, "Twelfth round"): on a real synthetic log (hand-made zinc nuts at 480 × 300, seed 9181, its part
model attached), the pipeline's zone as ``zcut annotate`` prepares it and the page's own
:func:`annotate.fits.fit_frame`.

The oracle is the literal definition: the see-through share of every fit (:func:`zcut.fit_vetting.see_through`),
the pixels a partly trusted fit keeps (:func:`zcut.fit_vetting.partly_trusted`), and every other pixel of its band
judged against all the other surfaces from scratch (:func:`zcut.explained.nearest_surface` with the fit left out,
its Err from that surface's residual, the rule k × Err).
"""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import synth_log

from annotate.fits import Job, fit_frame
from replay.options import PipelineOptions
from zcut import explained as ex
from zcut import fit_vetting as fv

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    log = synth_log(tmp_path_factory.mktemp("partly") / "nuts.mcap", parts="zinc_nuts", frames=1, seed=9181,
                    size="480x300")
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    job = Job.of(result)
    ff = fit_frame(frame, job, session.config, session.prepared.model)
    assert ff.status == "ready" and len(ff.fits) > 10, ff.message
    return frame, ff


def test_no_fit_above_the_share_changes_nothing(fitted):
    frame, ff = fitted
    xyz = frame.xyz.astype(np.float64) * 1000.0
    assert ff.partly_trusted(xyz, max_share=1.0) is ff


@pytest.mark.parametrize("share", [0.0, 0.05])
def test_the_pixels_off_a_partly_trusted_fits_surface_are_judged_against_the_other_surfaces(fitted, share):
    frame, ff = fitted
    xyz = frame.xyz.astype(np.float64) * 1000.0
    n = len(ff.fits)
    see = fv.see_through(xyz, [ff.posed(i) for i in range(n)], ff.part_err_mm, f_px=ff.f_px, k=ff.k,
                         floor_mm=ff.floor_mm)
    keep = fv.partly_trusted(ff.fit_pix, ff.fit_of, see, shape=ff.shape, max_share=share, k=ff.k)
    assert (~keep).any(), "the frame has no pixel to judge again"
    got = ff.partly_trusted(xyz, max_share=share)
    H, W = ff.shape
    expl = np.zeros(H * W, np.int64) - 1
    un = np.zeros(H * W, bool)
    dist = np.full(H * W, np.nan)
    err = np.full(H * W, np.nan)
    code = np.full(H * W, -9, np.int64)
    expl[ff.fit_pix[keep]] = ff.fit_of[keep]
    un[ff.un_pix] = True
    dist[ff.un_pix], err[ff.un_pix], code[ff.un_pix] = ff.un_dist, ff.un_err, ff.un_code
    for i in np.unique(ff.fit_of[~keep]).tolist():  # the oracle: each fit's pixels against every other surface
        px = ff.fit_pix[~keep & (ff.fit_of == i)]
        others = [j for j in range(n) if j != i]
        left = ff.known(others)
        where = np.zeros(H * W, bool)
        where[px] = True
        near = ex.nearest_surface(xyz, left, where=where.reshape(H, W))
        e = ex.err_image(near, left, ex.footprint_mm(xyz, ff.f_px), floor_mm=ff.floor_mm).ravel()
        d, c = near.dist_mm.ravel().astype(np.float64), near.surface.ravel()
        off = ex.unexplained(d[px][None], e[px][None], ff.k)[0]
        named = np.where(c[px] >= 0, np.asarray(others + [0])[np.maximum(c[px], 0)], c[px])
        expl[px[~off & (named >= 0)]] = named[~off & (named >= 0)]
        un[px[off]] = True
        dist[px[off]], err[px[off]], code[px[off]] = d[px][off], e[px][off], named[off]
    np.testing.assert_array_equal(got.fit_pix, np.flatnonzero(expl >= 0))
    np.testing.assert_array_equal(got.fit_of, expl[got.fit_pix])
    np.testing.assert_array_equal(got.un_pix, np.flatnonzero(un))
    np.testing.assert_array_equal(got.un_code, code[got.un_pix])
    np.testing.assert_allclose(got.un_dist, dist[got.un_pix], rtol=1e-6, atol=0)
    np.testing.assert_allclose(got.un_err, err[got.un_pix], rtol=1e-6, atol=0)
    # every pixel a partly trusted fit kept of its own is on its visible surface: in its silhouette, within k × Err of
    # the first hit along its ray
    for i in np.flatnonzero(see.share > share).tolist():
        px = ff.fit_pix[keep & (ff.fit_of == i)]
        if px.size:
            j = np.minimum(np.searchsorted(see.pix[i], px), see.pix[i].size - 1)
            assert (see.pix[i][j] == px).all()
            assert (np.abs(see.gap_mm[i][j]) <= ff.k * see.err_mm[i][j]).all()
