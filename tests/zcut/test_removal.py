"""The fused numba removal against the previous numpy implementation (tests/reference/).

Same classes, height image, cloud, rim and floor, bit for bit, on a noisy ray-cast bin scene
under the parameter combinations the two code paths branch on.
"""

from __future__ import annotations

import numpy as np
import pipeline_scene as ps
import pytest
from reference.removal_reference import remove_table_and_bin_reference

from replay.pipeline.bin_model import model_from_points
from zcut.bin_model import BinModel
from zcut.binmask import bin_mask
from zcut.params import RemovalParams
from zcut.removal import prepare_removal_index, remove_table_and_bin

H, W = 180, 240
FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz")


@pytest.fixture(scope="module")
def noisy():
    """A filled bin, 1 mm depth noise (a straggler tail on the walls), NaN holes, specks over the rim."""
    frame, _ = ps.scene(h=H, w=W, shift=(0.004, -0.003, 0.002), specks=10, seed=5)
    rng = np.random.default_rng(17)
    xyz = frame.xyz.copy()
    xyz *= (1.0 + rng.normal(0.0, 0.001, (H, W, 1)) / xyz[..., 2:]).astype(np.float32)
    xyz[rng.random((H, W)) < 0.02] = np.nan
    xyz[rng.random((H, W)) < 0.005, 0] = np.inf  # a non-finite x alone makes the pixel invalid
    for r, c in rng.integers((20, 20), (H - 20, W - 20), (6, 2)):
        xyz[r, c] *= np.float32(0.45 / xyz[r, c, 2])  # 5 cm above the rim
    return xyz, bin_mask(frame.rgb).mask


@pytest.fixture(scope="module")
def model() -> BinModel:
    return model_from_points(ps.model_from_empty(h=H, w=W), voxel_mm=1.0)


def _pose(angle_deg: float, shift=(0.004, -0.003, 0.002)) -> np.ndarray:
    a = np.deg2rad(angle_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    T[:3, 3] = shift
    return T


def _params(kw: dict) -> RemovalParams:
    """RemovalParams from the reference's metre keywords (the old function's defaults otherwise)."""
    mm = {k.replace("_m", "_mm"): v * 1000.0 for k, v in kw.items() if k.endswith("_m")}
    return RemovalParams(**{"mode": "paper", "straggler_mm": 0.0, "straggler_neighbours": 5, **mm,
                            **{k: v for k, v in kw.items() if not k.endswith("_m")}})


def _fast(xyz, fp, *, model=None, T_cam_bin=None, **kw):
    index = None if model is None else prepare_removal_index(model, _params(kw))
    return remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T_cam_bin)


def _reference(xyz, fp, **kw):
    """The reference with the very metre values the params give the fast path."""
    model = kw.pop("model", None)
    T = kw.pop("T_cam_bin", None)
    p = _params(kw)
    metres = dict(delta_m=p.delta_m, rim_offset_m=p.rim_offset_m, search_radius_m=p.search_radius_m,
                  straggler_m=p.straggler_m, straggler_neighbours=p.straggler_neighbours)
    with np.errstate(invalid="ignore"):  # the reference multiplies an infinite x by up_x = 0
        return remove_table_and_bin_reference(xyz, fp, model=model, T_cam_bin=T, **metres)


def _assert_same(fast, ref):
    for f in FIELDS:
        a, b = getattr(fast, f), getattr(ref, f)
        assert a.dtype == b.dtype and a.shape == b.shape, f
        assert np.array_equal(a, b, equal_nan=True), f"{f}: {int((a != b).sum())} pixels differ"
    for f in ("rim_m", "floor_m"):
        assert np.array_equal(getattr(fast, f), getattr(ref, f), equal_nan=True), f
    assert np.array_equal(fast.up_cam, ref.up_cam)


@pytest.mark.parametrize("kw", [
    {"delta_m": 1e-4},
    {"delta_m": 5e-4, "straggler_m": 0.002, "straggler_neighbours": 3},
    {"delta_m": 5e-4, "straggler_m": 0.003, "straggler_neighbours": 0},
    {"delta_m": 5e-4, "straggler_m": 0.002, "straggler_neighbours": 8},
    {"delta_m": 0.002, "search_radius_m": 0.005, "rim_offset_m": 0.0},
    {"delta_m": 0.0, "straggler_m": 0.002},
])
@pytest.mark.parametrize("normals", [True, False])
def test_fast_removal_equals_the_reference(noisy, model, kw, normals):
    xyz, fp = noisy
    m = model if normals else BinModel(model.points, None, model.spacing_m)
    T = _pose(0.0)
    fast = _fast(xyz, fp, model=m, T_cam_bin=T, **kw)
    ref = _reference(xyz, fp, model=m, T_cam_bin=T, **kw)
    _assert_same(fast, ref)
    if normals and kw["delta_m"] >= 5e-4:
        assert fast.bin_points.sum() > 0.05 * fp.sum()  # the test exercises the bin search
    if "straggler_m" in kw and kw["delta_m"] > 0 and kw.get("straggler_neighbours", 5) < 8:
        plain = _fast(xyz, fp, model=m, T_cam_bin=T, delta_m=kw["delta_m"])
        assert fast.bin_points.sum() > plain.bin_points.sum()  # and the straggler passes


@pytest.mark.parametrize("case", ["float64", "strided", "tilted", "side_view", "no_model", "all_nan"])
def test_fast_removal_equals_the_reference_on_odd_inputs(noisy, model, case):
    xyz, fp = noisy
    T = _pose(0.0)
    kw = {"model": model, "delta_m": 5e-4, "straggler_m": 0.002, "straggler_neighbours": 3}
    if case == "float64":
        xyz = xyz.astype(np.float64)
    elif case == "strided":
        xyz, fp = xyz[::2, ::-1], fp[::2, ::-1]
    elif case == "tilted":
        T = _pose(3.0)
    elif case == "side_view":
        T = _pose(90.0)
    elif case == "no_model":
        kw = {}
        T = None
    elif case == "all_nan":
        xyz = np.full_like(xyz, np.nan)
    fast = _fast(xyz, fp, T_cam_bin=T, **kw)
    ref = _reference(xyz, fp, T_cam_bin=T, **kw)
    _assert_same(fast, ref)


def _ring(xyz):
    """The certain bin pixels of the noisy scene (bin_pixels of its bin mask)."""
    from zcut.binmask import bin_pixels

    frame, _ = ps.scene(h=H, w=W, shift=(0.004, -0.003, 0.002), specks=10, seed=5)
    return bin_pixels(bin_mask(frame.rgb), xyz)


@pytest.mark.parametrize("kw", [
    {},
    {"straggler_mm": 0.0},
    {"tolerance_mm": 3.0},
    {"residual_quantile": 50.0, "residual_margin_mm": 0.0, "min_tolerance_mm": 0.0},
    {"max_tolerance_mm": 1.5, "straggler_neighbours": 5},
    {"search_radius_mm": 6.0, "rim_offset_mm": 0.0},
    {"straggler_bound": "global"},
    {"straggler_bound": "below_rim"},
    # the rim's band reaching 40 mm down the walls: unbounded there, bounded below
    {"straggler_bound": "below_rim", "rim_offset_mm": 40.0},
])
@pytest.mark.parametrize("angle", [0.0, 2.0])
@pytest.mark.parametrize("normals", [True, False])
def test_robust_removal_equals_the_reference_with_its_tolerance(noisy, model, kw, angle, normals):
    """The robust mode is the literal rule with δ = the frame's τ, the search radius at least the
    frame's measured reach (a model with normals, no radius given), the bin test first and the
    stragglers at τ + straggler_mm, searching straggler_mm beyond a measured radius."""
    from zcut.removal import _radius, frame_tolerance

    xyz, fp = noisy
    m = model if normals else BinModel(model.points, None, model.spacing_m)
    p = RemovalParams(**kw)
    index = prepare_removal_index(m, p)
    T = _pose(angle)
    ring = _ring(xyz)
    fast = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
    tol = frame_tolerance(xyz, ring, index, T)
    tau = tol.tolerance_mm
    assert fast.tolerance_mm == pytest.approx(tau)
    d = tau / 1000.0
    radius, straggler = _radius(p, m.spacing_m, d), p.straggler_m + d if p.straggler_m else 0.0
    r_str = max(radius, straggler)
    assert np.isfinite(tol.reach_mm) == (normals and p.tolerance_mm is None)  # measured with τ, across normals
    if np.isfinite(tol.reach_mm) and p.search_radius_mm is None:
        radius = max(radius, tol.reach_mm / 1000.0)
        r_str = max(radius + p.straggler_m, straggler)
    assert fast.radius_mm == pytest.approx(1000.0 * radius if normals else tau)
    # the stragglers' bound at 3 of the bin's Err: known where τ was measured (and most of its pixels have a model
    # point within max_tolerance_mm: not so with a max of 1.5 mm on this 1 mm-noise scene)
    known = np.isfinite(tol.sigma_mm) and np.isfinite(tol.pixel_rad)
    err = (tol.sigma_mm / 1000.0, tol.pixel_rad) if known and p.straggler_bound != "off" else None
    assert known == (p.tolerance_mm is None and p.max_tolerance_mm > 1.5)
    # "below_rim": no bound above the rim's band, rim_offset_mm below the model's rim (99.5th percentile of -z)
    top = np.percentile(-m.points[:, 2], 99.5) - p.rim_offset_m if p.straggler_bound == "below_rim" else np.inf
    with np.errstate(invalid="ignore"):
        ref = remove_table_and_bin_reference(
            xyz, fp, model=m, T_cam_bin=T, delta_m=d, rim_offset_m=p.rim_offset_m,
            search_radius_m=radius, straggler_m=straggler, straggler_radius_m=r_str,
            straggler_neighbours=p.straggler_neighbours, bin_first=True, straggler_err=err, straggler_top_m=top)
    _assert_same(fast, ref)
    assert fast.bin_points.sum() > 0.05 * fp.sum()


@pytest.mark.parametrize("neighbours", [0, 1, 3, 5, 8])
def test_straggler_start_counts_like_a_box_filter(neighbours):
    """The fused first pass of the straggler test: its masks and candidates are the numpy
    definitions (a 3x3 sum of the labelled pixels, minus the pixel, no neighbour beyond the edges)."""
    import cv2

    from zcut.removal import _straggler_start

    rng = np.random.default_rng(neighbours)
    shape = (37, 53)
    valid, table, binp, easy, fp = (rng.random(shape) < q for q in (0.8, 0.3, 0.3, 0.1, 0.7))
    lab, open_, cand = np.empty(shape, np.uint8), np.empty(shape, bool), np.empty(shape, bool)
    _straggler_start(valid, table, binp, easy, fp, neighbours, lab, open_, cand)
    want_lab = (table | binp | ~valid).astype(np.uint8)
    count = cv2.filter2D(want_lab, -1, np.ones((3, 3), np.float32), borderType=cv2.BORDER_CONSTANT) - want_lab
    want_open = valid & fp & ~easy & ~binp
    np.testing.assert_array_equal(lab, want_lab)
    np.testing.assert_array_equal(open_, want_open)
    np.testing.assert_array_equal(cand, want_open & (count >= neighbours))
