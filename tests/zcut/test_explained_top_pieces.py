"""The part instances the fits missed on top of the pile, fitted again on the unexplained pieces
(:mod:`zcut.top_pieces`, called by ``explained``: replay/pipeline/explained.py).

Clean ray-cast clouds of the hand-made zinc nut (tests/zcut/fits/fit_scenes.py): a nut lying on a floor
whose pixels no known surface explains (the fits missed it: before, every one of them was proposed to the
labelling page as an outlier) is found and explains them; the same nut seen through a tight window of nearer
surfaces (a piece framed by what lies in front of it) is not taken.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from explained_helpers import box_mesh  # noqa: E402
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation  # noqa: E402
from prepared_models import prepared  # noqa: E402

from zcut import explained as ex  # noqa: E402
from zcut.errors import InputShapeError  # noqa: E402
from zcut.fits import FitParams, pose_error  # noqa: E402
from zcut.top_pieces import nearer_share, top_pieces  # noqa: E402

FLOOR_Z = 320.0
NUT = pose(rotation((1, 0.2, 0), 12), (4, -2, 300))


def _noisy(xyz: np.ndarray, sigma: float = 0.03, seed: int = 0) -> np.ndarray:
    out = xyz.copy()
    out[..., 2] += np.random.default_rng(seed).normal(0.0, sigma, xyz.shape[:2])
    return out


@pytest.fixture(scope="module")
def nut():
    v, t = hex_nut_mesh()
    return v, t, prepared(v, t)  # the session's (tests/zcut/fits/prepared_models.py): the fits tests prepare it too


def test_a_missed_nut_on_the_floor_is_found_on_its_unexplained_pixels(nut):
    v, t, model = nut
    xyz, ids = render([(v, t, NUT)], floor_z_mm=FLOOR_Z)
    xyz = _noisy(xyz)
    found = top_pieces(xyz, ids > 0, model, intrinsics=K_TEST, params=FitParams())
    assert len(found) == 1
    dt, da = pose_error(found[0].pose, NUT, model)
    assert dt < 0.3 and da < 2.0
    z = xyz[..., 2]
    assert nearer_share(z, np.isfinite(z), found[0].pixels) == 0.0  # the floor around it lies behind it


def test_a_piece_framed_by_nearer_surfaces_is_not_taken(nut):
    v, t, model = nut
    xyz0, ids0 = render([(v, t, NUT)], floor_z_mm=FLOOR_Z)
    lo = np.nanmin(xyz0[ids0 > 0], axis=0)
    hi = np.nanmax(xyz0[ids0 > 0], axis=0)
    # four plates 8-12 mm in front of the nut's top, their window the nut's outline seen from the camera
    zp = lo[2] - 12.0
    s = zp / hi[2]  # a plate's edge at x projects where the nut's farthest points at x / s do
    x0, y0, x1, y1 = lo[0] * s, lo[1] * s, hi[0] * s, hi[1] * s
    plates = []
    for a, b in (((x0 - 40, y0 - 40), (x1 + 40, y0)), ((x0 - 40, y1), (x1 + 40, y1 + 40)),
                 ((x0 - 40, y0), (x0, y1)), ((x1, y0), (x1 + 40, y1))):
        bv, bt = box_mesh(np.array([a[0], a[1], zp]), np.array([b[0], b[1], zp + 4.0]))
        plates.append((bv, bt, np.eye(4)))
    xyz, ids = render([(v, t, NUT), *plates], floor_z_mm=FLOOR_Z)
    xyz = _noisy(xyz)
    piece = ids == 1
    assert piece.sum() > 200
    # the nut is found on its pixels (the fitting itself is not what refuses it) ...
    from zcut.fits import fit_prepared

    assert len(fit_prepared(xyz, piece, model, intrinsics=K_TEST)) == 1
    # ... but it is framed by nearer surfaces: no top piece
    assert top_pieces(xyz, piece, model, intrinsics=K_TEST, params=FitParams()) == []


def test_small_pieces_are_not_fitted_and_bad_input_is_one_line(nut):
    v, t, model = nut
    xyz, ids = render([(v, t, NUT)], floor_z_mm=FLOOR_Z)
    few = np.zeros(ids.shape, bool)
    r, c = np.nonzero(ids > 0)
    few[r[:10], c[:10]] = True  # 10 pixels: below MIN_PIECE_PX
    assert top_pieces(xyz, few, model, intrinsics=K_TEST, params=FitParams()) == []
    assert top_pieces(xyz, np.zeros(ids.shape, bool), model, intrinsics=K_TEST, params=FitParams()) == []
    with pytest.raises(InputShapeError, match="unexplained must be"):
        top_pieces(xyz, (ids > 0)[:-1], model, intrinsics=K_TEST, params=FitParams())


def test_explained_takes_the_missed_nut_as_a_known_surface(nut):
    """The method's step (replay.pipeline.explained): with no fit (the fitting missed the nut) every nut pixel
    is unexplained — a proposal of the page; after it the nut is a fit and its pixels are explained, the
    floor's pixels keep their nearest surface."""
    from replay.pipeline.explained import _with_top_pieces

    v, t, model = nut
    xyz, ids = render([(v, t, NUT)], floor_z_mm=FLOOR_Z)
    xyz = _noisy(xyz)
    valid = np.isfinite(xyz).all(axis=2)
    zone = valid.copy()
    surfaces = ex.KnownSurfaces(table=ex.Plane(np.array([0.0, 0.0, 1.0]), FLOOR_Z, 0.03))
    near = ex.nearest_surface(xyz, surfaces, where=zone)
    foot = ex.footprint_mm(xyz, K_TEST[0])
    p = SimpleNamespace(k=3.0, err_floor_mm=0.0, fit_max_err_mm=FitParams().max_err_mm,
                        fit_min_support=FitParams().min_support, fit_max_overlap=0.05)
    before = ex.unexplained(near.dist_mm, ex.err_image(near, surfaces, foot), p.k) & zone
    nut_px = ids == 1
    assert before[nut_px].mean() > 0.95  # the missed nut: all proposed
    fits, s2, near2, added = _with_top_pieces(xyz, SimpleNamespace(zone=zone), near, surfaces, (), v, t, model,
                                              K_TEST, foot, zone, p)
    assert added == 1 and len(fits) == 1 and len(s2.parts) == 1
    after = ex.unexplained(near2.dist_mm, ex.err_image(near2, s2, foot), p.k) & zone
    assert after[nut_px].mean() < 0.05
    assert (near2.surface[nut_px] == 0).mean() > 0.95
    floor = (ids == 0) & valid
    np.testing.assert_array_equal(near2.surface[floor] == ex.SURFACE_TABLE, near.surface[floor] == ex.SURFACE_TABLE)
    # the exact search: the same nearest surfaces as judging every pixel against all surfaces from scratch
    full = ex.nearest_surface(xyz, ex.KnownSurfaces(parts=list(s2.parts), part_err_mm=list(s2.part_err_mm),
                                                    table=surfaces.table), where=zone)
    np.testing.assert_array_equal(full.surface, near2.surface)
    np.testing.assert_allclose(full.dist_mm, near2.dist_mm, rtol=0, atol=1e-4)
