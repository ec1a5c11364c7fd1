"""zcut.explained without a part model: the edge-aware local surface as the parts' surface (issue 29 item 3).

A hand-made organized frame (a pinhole camera over a floor with a box on it, flying pixels between
the box's edge and the floor, a ghost above the box) checks that the parts' real edges are explained
and the flying pixels are not; the combination with the known surfaces and the robust residual σ are
checked on closed forms.
"""

from __future__ import annotations

import numpy as np
import pytest

from zcut import explained as ex
from zcut.errors import InputShapeError, ParameterError

F_PX = 500.0


def _scene(rng: np.random.Generator, *, noise_mm: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz mm, flying pixels, the ghost's pixels) of a 60 × 80 frame: a floor at 600 mm, a box top
    at 570 mm over columns 30-49, flying pixels halfway down at its right edge, a ghost 8 mm above
    its top."""
    H, W = 60, 80
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = np.full((H, W), 600.0)
    z[10:50, 30:50] = 570.0
    flying = np.zeros((H, W), bool)
    flying[15:45, 50] = True
    z[flying] = 585.0
    ghost = np.zeros((H, W), bool)
    ghost[30, 38] = ghost[31, 39] = True
    z[ghost] = 562.0
    z = z + rng.normal(0.0, noise_mm, z.shape)
    xyz = np.dstack([(u - W / 2) * z / F_PX, (v - H / 2) * z / F_PX, z])
    return xyz, flying, ghost


def test_the_local_surface_explains_edges_and_not_the_pixels_between_them(rng):
    xyz, flying, ghost = _scene(rng)
    valid = np.isfinite(xyz).all(axis=2)
    d = ex.local_surface_distance(xyz, valid)
    err = np.sqrt(0.05**2 + 0.5 * ex.footprint_mm(xyz, F_PX) ** 2)
    out = ex.unexplained(d, err, ex.K_ERR)
    assert out[flying].all() and out[ghost].all()
    edges = np.zeros_like(valid)
    edges[10:50, 30] = edges[10:50, 49] = edges[10, 30:50] = edges[49, 30:50] = True  # the box top's own edge
    assert not out[edges & ~flying].any()
    assert out.sum() <= flying.sum() + ghost.sum() + 2  # and (next to) nothing else
    # judged only where asked
    where = np.zeros_like(valid)
    where[20] = True
    part = ex.local_surface_distance(xyz, valid, where=where)
    assert np.isnan(part[~where]).all() and np.isfinite(part[where]).all()


def test_the_nearer_surface_wins_and_unjudged_pixels_stay_so():
    near = ex.Nearest(np.array([[1.0, 2.0, np.inf, np.nan, 0.5]], np.float32),
                      np.array([[ex.SURFACE_BIN, ex.SURFACE_TABLE, ex.SURFACE_NONE, ex.SURFACE_NONE, ex.SURFACE_BIN]],
                               np.int32))
    local = np.array([[0.5, np.nan, 3.0, 0.1, 0.5]])
    out = ex.with_local_surface(near, local)
    np.testing.assert_allclose(out.dist_mm, [[0.5, 2.0, 3.0, np.nan, 0.5]])
    np.testing.assert_array_equal(out.surface, [[ex.SURFACE_LOCAL, ex.SURFACE_TABLE, ex.SURFACE_LOCAL,
                                                 ex.SURFACE_NONE, ex.SURFACE_BIN]])  # a tie: the known one
    with pytest.raises(InputShapeError, match="local_mm"):
        ex.with_local_surface(near, local[:, :2])


def test_the_local_sigma_is_robust_to_the_points_off_the_surface(rng):
    d = np.abs(rng.normal(0.0, 0.3, 20_000))
    d[:4_000] = rng.uniform(2.0, 30.0, 4_000)  # 20 % off every surface
    d[:10] = np.inf
    assert ex.local_sigma(d) == pytest.approx(0.3, rel=0.03)
    assert ex.residual_sigma(d) > 0.36  # one median alone is inflated by them
    assert np.isnan(ex.local_sigma(np.array([np.nan, np.inf])))
    with pytest.raises(ParameterError, match="gate"):
        ex.local_sigma(d, gate=0.0)


def test_err_of_a_locally_explained_pixel_takes_the_local_sigma():
    surfaces = ex.KnownSurfaces(bin_err_mm=0.1, local_err_mm=0.4)
    near = ex.Nearest(np.array([[1.0, 1.0]], np.float32), np.array([[ex.SURFACE_LOCAL, ex.SURFACE_BIN]], np.int32))
    err = ex.err_image(near, surfaces, np.full((1, 2), 0.2))
    np.testing.assert_allclose(err, [[np.sqrt(0.16 + 0.02), np.sqrt(0.01 + 0.02)]])
    assert surfaces.sigma(ex.SURFACE_LOCAL) == 0.4
