"""zcut.explained: distances to the known surfaces, Err, the unexplained points (issue 29 item 4).

The distances are checked against closed forms (a box's faces, a plane, a sampled plane with
normals); the rule against the paper's truth the generators write (``/ground_truth/off_surface``)
with the scene's true meshes standing in for the fits: the rule and the truth are one definition.
"""

from __future__ import annotations

import numpy as np
import pytest
from explained_helpers import box_mesh as _box
from explained_helpers import handmade_true_surfaces, raytraced_true_surfaces

from zcut import explained as ex
from zcut.errors import InputShapeError, ParameterError


def _box_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Exact distance of points to the surface of an axis-aligned box."""
    q = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    outside = np.linalg.norm(q, axis=1)
    inside = np.min(np.minimum(p - lo, hi - p), axis=1)
    return np.where(outside > 0, outside, inside)


def test_distances_and_nearest_surface_match_closed_forms():
    rng = np.random.default_rng(0)
    lo1, hi1 = np.array([-30.0, -10, 480]), np.array([-10.0, 10, 500])
    lo2, hi2 = np.array([10.0, -10, 470]), np.array([30.0, 10, 500])
    table = ex.Plane(np.array([0.0, 0.0, 1.0]), 560.0, 0.1)
    surfaces = ex.KnownSurfaces(parts=[_box(lo1, hi1), _box(lo2, hi2)], part_err_mm=[0.2, 0.3], table=table)
    xyz = np.column_stack([rng.uniform(-40, 40, 600), rng.uniform(-15, 15, 600), rng.uniform(460, 570, 600)])
    xyz = xyz.reshape(20, 30, 3)
    xyz[0, 0] = np.nan
    near = ex.nearest_surface(xyz, surfaces)
    p = xyz.reshape(-1, 3)
    want = np.column_stack([_box_distance(p, lo1, hi1), _box_distance(p, lo2, hi2), np.abs(p[:, 2] - 560.0)])
    ok = np.isfinite(p).all(axis=1)
    d = near.dist_mm.reshape(-1)
    assert np.isnan(d[0]) and near.surface.reshape(-1)[0] == ex.SURFACE_NONE
    np.testing.assert_allclose(d[ok], want[ok].min(axis=1), atol=2e-4)
    codes = np.array([0, 1, ex.SURFACE_TABLE])[want[ok].argmin(axis=1)]
    clear = np.sort(want[ok], axis=1)[:, 1] - want[ok].min(axis=1) > 1e-3  # no tie between two surfaces
    np.testing.assert_array_equal(near.surface.reshape(-1)[ok][clear], codes[clear])
    # judged only where asked
    where = np.zeros((20, 30), bool)
    where[5] = True
    part = ex.nearest_surface(xyz, surfaces, where=where)
    assert np.isnan(part.dist_mm[~where]).all() and np.isfinite(part.dist_mm[where]).all()


def test_a_bin_model_cloud_is_judged_point_to_plane_near_it():
    g = np.arange(-50.0, 50.1, 1.0)
    X, Y = np.meshgrid(g, g)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 600.0)])
    nrm = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    surfaces = ex.KnownSurfaces(bin_points=(pts, nrm), bin_spacing_mm=1.0, bin_err_mm=0.1)
    xyz = np.array([[[0.3, 0.4, 598.8], [0.0, 0.0, 590.0], [80.0, 0.0, 600.0]]])
    near = ex.nearest_surface(xyz, surfaces)
    np.testing.assert_allclose(near.dist_mm[0], [1.2, 10.0, 30.0], atol=1e-4)  # near: to the plane; far: to the point
    assert (near.surface == ex.SURFACE_BIN).all()


def test_unexplained_is_farther_than_k_err():
    d = np.array([[0.3, 0.31, np.nan, np.inf]])
    err = np.full((1, 4), 0.1)
    np.testing.assert_array_equal(ex.unexplained(d, err, 3.0), [[False, True, False, True]])
    with pytest.raises(ParameterError, match="k must be"):
        ex.unexplained(d, err, 0.0)
    with pytest.raises(InputShapeError, match="one shape"):
        ex.unexplained(d, err[:, :2])


def test_err_per_pixel_takes_its_surface_residual_and_footprint():
    parts = [_box(np.zeros(3), np.ones(3))]
    surfaces = ex.KnownSurfaces(parts=parts, part_err_mm=[0.3], bin_err_mm=float("nan"),
                                table=ex.Plane(np.array([0.0, 0.0, 1.0]), 0.0, 0.1))
    near = ex.Nearest(np.array([[1.0, 1.0, 1.0, np.inf, np.nan]], np.float32),
                      np.array([[0, ex.SURFACE_TABLE, ex.SURFACE_BIN, ex.SURFACE_NONE, ex.SURFACE_NONE]], np.int32))
    c = np.full((1, 5), 0.4)
    err = ex.err_image(near, surfaces, c, floor_mm=0.2)
    s = np.array([0.3, 0.1, 0.3, 0.3])  # the bin's unknown residual and "none" take the largest known one
    np.testing.assert_allclose(err[0, :4], np.maximum(0.2, np.sqrt(s**2 + 0.08)))
    assert np.isnan(err[0, 4])


def test_err_image_where_gives_the_whole_images_values_there():
    """``where`` computes Err on some pixels only (the vetting's ranking reads it on the zone's part
    pixels; the method computes the whole image once): the same values there, NaN elsewhere."""
    rng = np.random.default_rng(4)
    surfaces = ex.KnownSurfaces(parts=[_box(np.zeros(3), np.ones(3))] * 3, part_err_mm=[0.3, float("nan"), 0.12],
                                bin_err_mm=0.2, table=ex.Plane(np.array([0.0, 0.0, 1.0]), 0.0, 0.1),
                                local_err_mm=0.4)
    codes = np.array([0, 1, 2, ex.SURFACE_TABLE, ex.SURFACE_BIN, ex.SURFACE_LOCAL, ex.SURFACE_NONE], np.int32)
    code = rng.choice(codes, (40, 50)).astype(np.int32)
    dist = rng.uniform(0.0, 3.0, (40, 50)).astype(np.float32)
    dist[rng.random((40, 50)) < 0.1] = np.nan
    dist[code == ex.SURFACE_NONE] = np.inf
    near = ex.Nearest(dist, code)
    c = rng.uniform(0.1, 0.8, (40, 50))
    full = ex.err_image(near, surfaces, c, floor_mm=0.15)
    where = rng.random((40, 50)) < 0.5
    part = ex.err_image(near, surfaces, c, floor_mm=0.15, where=where)
    inside = where & ~np.isnan(dist)
    np.testing.assert_array_equal(part[inside], full[inside])
    assert np.isnan(part[~inside]).all() and np.isfinite(full[inside]).all()
    with pytest.raises(InputShapeError, match="where must be"):
        ex.err_image(near, surfaces, c, where=where[:, :3])


def test_fit_sigmas_are_robust_to_attached_ghosts_and_never_widen_the_band():
    """Instance 0: a half-normal residual of σ 0.1 mm with 30 % ghosts 0.5-3 mm off (its RMS, what a fit
    states, is ~1 mm): its robust σ is the noise's. Instance 1: too few pixels, keeps its stated value.
    Instance 2: a stated residual below the measured one stays. Pixels outside ``where`` do not count."""
    rng = np.random.default_rng(7)
    n0 = 4000
    d0 = np.abs(rng.normal(0.0, 0.1, n0))
    d0[: int(0.3 * n0)] = rng.uniform(0.5, 3.0, int(0.3 * n0))
    d2 = np.abs(rng.normal(0.0, 0.5, 500))
    d = np.concatenate([d0, [0.05] * 5, d2, [50.0] * 300, [np.nan, np.inf]]).astype(np.float32)
    code = np.concatenate([np.zeros(n0), np.ones(5), np.full(500, 2), np.zeros(300),
                           [ex.SURFACE_NONE, ex.SURFACE_NONE]]).astype(np.int32)
    where = np.ones(d.size, bool)
    where[n0 + 505: n0 + 805] = False  # far points of instance 0 outside the judged pixels
    near = ex.Nearest(d[None, :], code[None, :])
    stated = [float(np.sqrt(np.mean(d0.astype(np.float64) ** 2))), 0.2, 0.3]
    assert stated[0] > 0.9
    sig = ex.fit_sigmas(near, stated, where=where[None, :])
    assert 0.09 < sig[0] < 0.12 and sig[1] == 0.2 and sig[2] == 0.3
    assert ex.fit_sigmas(near, stated, where=where[None, :], min_pixels=4)[1] < 0.2  # 5 pixels now enough
    assert ex.fit_sigmas(near, stated)[0] >= sig[0]  # the 300 far points, within no gate, move the median a little
    assert ex.fit_sigmas(ex.Nearest(np.full((2, 2), np.nan, np.float32), np.full((2, 2), -1, np.int32)), [0.4]) == [0.4]
    with pytest.raises(InputShapeError, match="instance 2"):
        ex.fit_sigmas(near, stated[:2])
    with pytest.raises(InputShapeError, match="where"):
        ex.fit_sigmas(near, stated, where=np.ones((2, 2), bool))


def test_plane_fit_and_focal_length_from_the_cloud():
    rng = np.random.default_rng(1)
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    p = rng.uniform(-100, 100, (5000, 3))
    p -= np.outer(p @ n - 550.0, n)
    p += np.outer(rng.normal(0, 0.2, len(p)), n)
    p[:200] += np.outer(rng.uniform(5, 50, 200), n)  # things on the table
    plane = ex.fit_plane(p)
    np.testing.assert_allclose(plane.normal, n, atol=1e-3)
    assert abs(plane.offset - 550.0) < 0.05 and 0.17 < plane.residual_mm < 0.23
    f, H, W = 700.0, 30, 40
    u, v = np.meshgrid(np.arange(W) - 20.0, np.arange(H) - 15.0)
    z = rng.uniform(400, 600, (H, W))
    xyz = np.dstack([u * z / f, v * z / f, z])
    assert abs(ex.focal_px(xyz) - f) < 1e-6
    np.testing.assert_allclose(ex.footprint_mm(xyz, f), z / f)
    with pytest.raises(InputShapeError, match="at least 3"):
        ex.fit_plane(p[:2])


def test_bad_inputs_are_one_line():
    with pytest.raises(InputShapeError, match="xyz_mm"):
        ex.nearest_surface(np.zeros((4, 3)), ex.KnownSurfaces())
    with pytest.raises(InputShapeError, match="part 0"):
        ex.KnownSurfaces(parts=[(np.zeros((3, 3)), np.array([[0, 1, 5]]))], part_err_mm=[0.1])
    with pytest.raises(InputShapeError, match="residuals"):
        ex.KnownSurfaces(parts=[_box(np.zeros(3), np.ones(3))])


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    u = (a | b).sum()
    return float((a & b).sum() / u) if u else 1.0


@pytest.mark.slow
@pytest.mark.parametrize("generator", ["handmade", "raytraced"])
def test_true_meshes_as_fits_give_the_papers_truth(generator):
    """With the scene's true meshes as the fits and the generator's own Err, ``explained`` is
    ``/ground_truth/off_surface``: the rule and the truth are one definition; and the vetting of the fits
    keeps every true mesh."""
    if generator == "handmade":
        from replay.synth.synthesize import synthesize_frame

        sf = synthesize_frame(kind="zinc_nuts", seed=9501, index=0, size=(150, 240))
        _, surfaces = handmade_true_surfaces(sf)
    else:
        from replay.synth.raytrace import synthesize_raytraced_frame

        sf = synthesize_raytraced_frame(kind="spheres", seed=9502, index=0, size=(150, 240))
        _, surfaces = raytraced_true_surfaces(sf, seed=9502, index=0)
    xyz = sf.frame.xyz.astype(np.float64) * 1000.0
    near = ex.nearest_surface(xyz, surfaces)
    mine = ex.unexplained(near.dist_mm, sf.err_mm.astype(np.float64), ex.K_ERR)
    assert sf.off_surface.sum() > 20
    assert _iou(mine, sf.off_surface) >= 0.99
    # the vetting of the fits (zcut.fit_vetting) leaves none of the true parts out: they share no volume
    from zcut import fit_vetting as fv

    support = fv.explained_px(near, sf.err_mm.astype(np.float64), len(surfaces.parts), k=ex.K_ERR)
    assert fv.vet_fits(fv.part_overlaps(surfaces.parts), support).kept.all()
