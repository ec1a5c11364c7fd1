"""A rejected fit's pixels judged again (annotate/fits.py, :meth:`FrameFits.remeasure`; docs/labelling.md,
"Judging fits"): on a real synthetic log (hand-made spheres at 480 × 300, seed 9181, its part model attached),
the pipeline's zone as ``zcut annotate`` prepares it and the page's own :func:`annotate.fits.fit_frame`.

The oracle is the literal definition: the distance of each pixel of the rejected fit to the nearest of the
surfaces left, searched among *all* of them from scratch (:func:`zcut.explained.nearest_surface`), its Err
from that surface's residual, and the rule k × Err: the same pixels, the same distances within a float32
ulp (Open3D's closest point, found in a tree of fewer fits, can differ in its last bit).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from cli_helpers import synth_log

from annotate.fits import FIT_COLUMNS, PROPOSAL_COLUMNS, Job, fit_frame, known_surfaces
from annotate.payload import parse_bundle
from replay.options import PipelineOptions
from replay.pipeline.explained import run_explained
from replay.pipeline.stages import bin_zone
from zcut import explained as ex

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    log = synth_log(tmp_path_factory.mktemp("remeasure") / "spheres.mcap", parts="spheres", frames=1, seed=9181,
                    size="480x300")
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    job = Job.of(result)
    ff = fit_frame(frame, job, session.config, session.prepared.model)
    assert ff.status == "ready" and len(ff.fits) > 50, ff.message
    return session, frame, job, ff


def _oracle(ff, xyz, rejected):
    """Every pixel whose nearest surface was a rejected fit, judged against all the surfaces left."""
    left = ff.known([i for i in range(len(ff.fits)) if i not in rejected])
    H, W = ff.shape
    lost = np.zeros(H * W, bool)
    lost[ff.fit_pix[np.isin(ff.fit_of, sorted(rejected))]] = True
    lost[ff.un_pix[np.isin(ff.un_code, sorted(rejected))]] = True
    near = ex.nearest_surface(xyz, left, where=lost.reshape(H, W))
    err = ex.err_image(near, left, ex.footprint_mm(xyz, ff.f_px), floor_mm=ff.floor_mm)
    return lost, near.dist_mm.ravel(), err.ravel(), ex.unexplained(near.dist_mm, err, ff.k).ravel()


def test_the_surfaces_kept_give_the_methods_err_to_the_bit(fitted):
    session, frame, job, ff = fitted
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    _, detail, _ = run_explained(frame, zone, session.config, judge_above_rim=True)
    assert detail is not None
    surfaces, f_px = known_surfaces(frame, job, detail, session.prepared.model)
    xyz = frame.xyz.astype(np.float64) * 1000.0
    err = ex.err_image(ex.Nearest(detail.dist_mm, detail.surface), surfaces, ex.footprint_mm(xyz, f_px),
                       floor_mm=ff.floor_mm)
    np.testing.assert_array_equal(err, detail.err_mm)
    # and the frame's fits keep them: the bin and the table, the fits posed when needed
    assert f_px == ff.f_px and not ff.surfaces.parts and len(ff.known().parts) == len(ff.fits)
    kept = ex.err_image(ex.Nearest(detail.dist_mm, detail.surface), ff.known(), ex.footprint_mm(xyz, ff.f_px),
                        floor_mm=ff.floor_mm)
    assert ff.part_err_mm == tuple(float(e) for e in surfaces.part_err_mm)  # every fit judged with its own residual
    np.testing.assert_array_equal(kept, detail.err_mm)


@pytest.mark.parametrize("pick", ["largest", "smallest", "every third"])
def test_a_rejected_fits_pixels_are_judged_against_the_surfaces_left(fitted, pick):
    _, frame, _, ff = fitted
    xyz = frame.xyz.astype(np.float64) * 1000.0
    areas = np.bincount(ff.fit_of, minlength=len(ff.fits))
    rejected = {"largest": {int(np.argmax(areas))}, "smallest": {int(np.argmin(np.where(areas, areas, 1 << 30)))},
                "every third": set(range(0, len(ff.fits), 3))}[pick]
    got = ff.remeasure(rejected, xyz)
    lost, dist, err, off = _oracle(ff, xyz, rejected)
    mine = np.isin(ff.fit_of, sorted(rejected))
    want = ff.fit_pix[mine][off[ff.fit_pix[mine]]]
    np.testing.assert_array_equal(got.pix, np.sort(want))
    # the distances as the full search's, within a float32 ulp (Open3D's closest point found in another tree)
    np.testing.assert_allclose(got.dist, dist[got.pix], rtol=1e-6, atol=0)
    np.testing.assert_allclose(got.err, err[got.pix], rtol=1e-6, atol=0)
    assert set(got.fit.tolist()) <= rejected
    # the unexplained pixels nearest to a rejected fit: their distance to the surfaces left
    was = np.isin(ff.un_code, sorted(rejected))
    np.testing.assert_allclose(got.un_dist[was], dist[ff.un_pix[was]], rtol=1e-6, atol=0)
    np.testing.assert_array_equal(got.un_dist[~was], ff.un_dist[~was])
    assert (got.un_dist[was] >= ff.un_dist[was]).all()  # taking a surface away makes none nearer
    # some of the rejected fits' pixels another surface explains, and they are not proposed
    if pick == "every third":
        assert 0 < got.pix.size < mine.sum()


def test_the_bundle_proposes_them_with_their_distance_and_taking_back_restores_it(fitted):
    _, frame, job, ff = fitted
    xyz = frame.xyz.astype(np.float64) * 1000.0
    valid = job.valid
    heights = np.where(valid, -xyz[..., 2], np.nan)

    def bundle(rejected):
        return ff.bundle(heights_mm=heights, valid=valid, rejected=rejected, header={}, xyz_mm=xyz)

    areas = np.bincount(ff.fit_of, minlength=len(ff.fits))
    a, b = (int(i) for i in np.argsort(areas)[-2:])
    none, only_a, both = bundle(set()), bundle({a}), bundle({a, b})
    assert bundle({a}) == only_a and bundle(set()) == none  # K again: the state before, to the byte
    header, arrays = parse_bundle(both)
    H, W = ff.shape
    table = np.asarray(arrays["proposal_table"]).reshape(-1, len(PROPOSAL_COLUMNS))
    col = {c: i for i, c in enumerate(PROPOSAL_COLUMNS)}
    props = np.asarray(arrays["proposals"]).reshape(H, W)
    again = ff.remeasure({a, b}, xyz)
    for f in (a, b):
        rows = table[table[:, col["fit"]] == f]
        assert len(rows) and np.isfinite(rows[:, col["dist_mm"]]).all()
        assert (rows[:, col["dist_mm"]] > ff.k * rows[:, col["err_mm"]]).all()
        ids = rows[:, col["id"]].astype(np.int64)
        np.testing.assert_array_equal(np.flatnonzero(np.isin(props.ravel(), ids)), again.pix[again.fit == f])
    fits = np.asarray(arrays["fit_table"]).reshape(-1, len(FIT_COLUMNS))
    proposed = fits[:, FIT_COLUMNS.index("proposed")]
    assert proposed[a] == (again.fit == a).sum() and proposed[b] == (again.fit == b).sum()
    assert proposed.sum() == again.pix.size and header["n_rejected"] == 2
    # the unexplained groups are as before, their distances to the surfaces left
    h0, a0 = parse_bundle(none)
    un0 = np.asarray(a0["proposals"]).reshape(H, W)
    np.testing.assert_array_equal(np.where(np.isin(props, table[table[:, col["fit"]] < 0, col["id"]]), props, 0), un0)


def test_a_seeded_instance_is_a_surface_a_rejected_fit_is_judged_against(fitted):
    """A fit taken out of the frame (its pixels made unexplained) and seeded again at a click: it joins the
    fits and the known surfaces with the residual its fit states; rejecting it proposes its pixels again."""
    session, frame, _, ff = fitted
    xyz = frame.xyz.astype(np.float64) * 1000.0
    areas = np.bincount(ff.fit_of, minlength=len(ff.fits))
    j = int(np.argmax(areas))
    mine = ff.fit_of == j
    gone = ff.fit_pix[mine]
    un = np.concatenate([ff.un_pix, gone])
    order = np.argsort(un)
    keep = [i for i in range(len(ff.fits)) if i != j]
    missed = dataclasses.replace(
        ff, fits=ff.fits[:j] + ff.fits[j + 1:], fit_pix=ff.fit_pix[~mine],
        fit_of=np.where(ff.fit_of[~mine] > j, ff.fit_of[~mine] - 1, ff.fit_of[~mine]).astype(np.int32),
        un_pix=un[order], un_dist=np.concatenate([ff.un_dist, np.full(gone.size, 5.0, np.float32)])[order],
        un_err=np.concatenate([ff.un_err, np.full(gone.size, 0.5, np.float32)])[order],
        un_code=np.concatenate([ff.un_code, np.full(gone.size, ex.SURFACE_BIN, np.int32)])[order],
        part_err_mm=tuple(ff.part_err_mm[i] for i in keep))
    W = ff.shape[1]
    y, x = np.divmod(gone, W)
    c = int(np.argmin((x - np.median(x)) ** 2 + (y - np.median(y)) ** 2))
    seeded = missed.seeded(int(x[c]), int(y[c]), xyz, session.config)
    k = len(missed.fits)
    assert len(seeded.fits) > k and seeded.fits[k]["seeded"] and len(seeded.known().parts) == len(seeded.fits)
    assert seeded.part_err_mm[k] == seeded.fits[k]["err_mm"] and seeded.part_err_mm[:k] == missed.part_err_mm
    got = np.isin(seeded.fit_of, list(range(k, len(seeded.fits))))
    assert got.sum() >= 0.8 * gone.size and not np.isin(seeded.fit_pix[got], seeded.un_pix).any()
    assert np.array_equal(np.sort(seeded.fit_pix), seeded.fit_pix)
    again = seeded.remeasure({k}, xyz)
    _, dist, _, off = _oracle(seeded, xyz, {k})
    px = seeded.fit_pix[seeded.fit_of == k]
    np.testing.assert_array_equal(again.pix, px[off[px]])
    np.testing.assert_allclose(again.dist, dist[again.pix], rtol=1e-6, atol=0)
