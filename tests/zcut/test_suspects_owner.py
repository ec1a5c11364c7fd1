"""Who decides what among the suspects' detectors (issue 32 item 5; docs/labelling_real.md, "The patch detector only
without a part model"): the small floating components are the floating detector's, the patch detector runs only
where the page has no part model, and both union-finds are :mod:`zcut.components`'.

Small hand-made frames (a plane 120 × 160 with blocks in front of it and behind it); the fast path is checked against
its reference (:func:`zcut.suspects.suspects_reference`) on each, with and without the patch detector.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import zcut.components
from annotate.groups import GCOL, review_groups
from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.suspects import FLOATING, FLOATING_OWNED_RHO, PATCH, suspects, suspects_reference
from zcut.suspects import grouping as grouping_module
from zcut.suspects import patches as patches_module
from zcut.suspects.patches import PATCH_RHO

A_MAX = 1000.0
FRONT = (slice(20, 25), slice(30, 35))  # a 5 x 5 block 20 mm in front of the plane: a small floating component
BEHIND = (slice(60, 70), slice(100, 112))  # a 10 x 12 block 40 mm behind it: a patch the floating cut never sees
LARGE = (slice(80, 95), slice(20, 35))  # 15 x 15 = 225 px in front: larger than floating_rho · a_max (150), a patch


def frame(*, nan_beside_front: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz, height_mm, zone): the plane with its three blocks (heights on a grid of 1/8 mm)."""
    H, W = 120, 160
    rng = np.random.default_rng(29)
    r, c = np.mgrid[0:H, 0:W]
    h = np.round((100.0 + 0.05 * r + 0.02 * c + rng.normal(0.0, 0.05, (H, W))) * 8) / 8
    h[FRONT] += 20.0
    h[BEHIND] -= 40.0
    h[LARGE] += 30.0
    if nan_beside_front:  # one unmeasured pixel on its ring: its ring is not all measured (evidence_ring_valid 1 fails)
        h[22, 35] = np.nan
    xyz = np.stack([c * 1e-3, r * 1e-3, -h / 1000.0], axis=2)
    return xyz, -1000.0 * xyz[..., 2], np.isfinite(h)


def assert_same(fast, ref) -> None:
    for f in dataclasses.fields(fast):
        if f.name.startswith("_") or f.name == "noise_profile":
            continue
        a, b = np.asarray(getattr(fast, f.name)), np.asarray(getattr(ref, f.name))
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), f.name


def both(xyz, h, zone, params, *, patches: bool):
    fast = suspects(xyz, h, zone, params=params, edge_surface=EdgeSurfaceParams(), patches=patches)
    fast.release()
    assert_same(fast, suspects_reference(xyz, h, zone, params=params, edge_surface=EdgeSurfaceParams(),
                                         patches=patches))
    return fast


def test_the_union_finds_are_the_components_ones() -> None:
    """D1: the patch detector and the grouping use zcut.components' kernels, not copies of them."""
    assert patches_module.find_root is zcut.components.find_root
    assert patches_module.union_roots is zcut.components.union_roots is zcut.components._union
    assert grouping_module.union_roots is zcut.components.union_roots
    assert grouping_module.find_root is zcut.components.find_root
    assert not hasattr(patches_module, "_find") and not hasattr(grouping_module, "_union")


def test_a_small_floating_component_is_the_floating_detectors_not_a_patch() -> None:
    xyz, h, zone = frame()
    res = both(xyz, h, zone, SuspectParams(a_max=A_MAX), patches=True)
    det = res.detectors
    assert (det[FRONT] == FLOATING).all()  # floating, and only floating: the patch detector leaves it
    assert (det[BEHIND] & PATCH).all() and not (det[BEHIND] & FLOATING).any()  # behind: the floating cut never sees it
    assert 0.15 * A_MAX < 15 * 15 <= PATCH_RHO * A_MAX
    assert (det[LARGE] & PATCH).all() and not (det[LARGE] & FLOATING).any()  # too large for the floating cut


@pytest.mark.parametrize("plain_rho", [0.0, 0.07])
def test_plain_rho_moves_the_union_on_its_own(plain_rho: float) -> None:
    """Without evidence (every test of it failing on this block), plain_rho alone decides the small component: at 0
    it leaves the union (no patch takes it back), at 0.07 it is in it."""
    xyz, h, zone = frame(nan_beside_front=True)
    params = SuspectParams(a_max=A_MAX, plain_rho=plain_rho, evidence_holes=1.0, evidence_inconsistent=1.0,
                           evidence_ring_valid=1.0)
    res = both(xyz, h, zone, params, patches=True)
    front = res.mask[FRONT]
    assert front.all() if plain_rho > 0 else not front.any()
    assert not (res.detectors[FRONT] & PATCH).any()
    assert (res.detectors[BEHIND] & PATCH).all() and (res.detectors[LARGE] & PATCH).all()  # the patches unchanged


def test_a_larger_floating_component_without_evidence_stays_a_patch() -> None:
    """Above FLOATING_OWNED_RHO · a_max (70 px) the floating detector does not own a component: one it leaves for
    want of evidence (10 x 10 = 100 px, below plain_rho · a_max's test) is still proposed, as a patch."""
    xyz, h, zone = frame(nan_beside_front=True)
    block = (slice(40, 50), slice(60, 70))
    hb = h.copy()
    hb[block] += 15.0
    hb[45, 70] = np.nan  # its ring is not all measured
    xyz = np.stack([xyz[..., 0], xyz[..., 1], -hb / 1000.0], axis=2)
    params = SuspectParams(a_max=A_MAX, evidence_holes=1.0, evidence_inconsistent=1.0, evidence_ring_valid=1.0)
    assert FLOATING_OWNED_RHO * A_MAX < 100 < params.floating_rho * A_MAX
    res = both(xyz, hb, np.isfinite(hb), params, patches=True)
    assert not (res.detectors[block] & FLOATING).any() and (res.detectors[block] & PATCH).all()
    assert res.mask[FRONT].all() and (res.detectors[FRONT] == FLOATING).all()  # 25 px: owned, kept by its size


def test_without_the_patch_detector_no_pixel_is_a_patch_and_the_others_are_unchanged() -> None:
    xyz, h, zone = frame()
    params = SuspectParams(a_max=A_MAX)
    on = both(xyz, h, zone, params, patches=True)
    off = both(xyz, h, zone, params, patches=False)
    assert not (off.detectors & PATCH).any()
    assert np.array_equal(off.detectors, on.detectors & ~np.uint8(PATCH))
    assert not off.mask[BEHIND].any() and not off.mask[LARGE].any()
    assert off.mask[FRONT].all()
    assert np.array_equal(off.residual_mm, on.residual_mm, equal_nan=True)


@pytest.mark.parametrize("case", ["0x0", "1xN", "all NaN", "one row of blocks"])
def test_degenerate_frames_with_and_without_patches(case: str) -> None:
    xyz, h, zone = frame()
    if case == "0x0":
        xyz, h, zone = xyz[:0, :0], h[:0, :0], zone[:0, :0]
    elif case == "1xN":
        xyz, h, zone = xyz[22:23], h[22:23], zone[22:23]
    elif case == "all NaN":
        xyz = np.full_like(xyz, np.nan)
        h, zone = -1000.0 * xyz[..., 2], np.zeros(zone.shape, bool)
    else:
        xyz, h, zone = xyz[18:27], h[18:27], zone[18:27]
    for patches in (True, False):
        res = both(xyz, h, zone, SuspectParams(a_max=A_MAX), patches=patches)
        assert not patches or not (res.detectors & PATCH)[~zone].any()


def test_the_page_lists_no_patch_group_where_it_fits_a_part_model() -> None:
    xyz, h, zone = frame()
    kw = {"height_mm": h, "valid": zone, "zone": zone, "above_rim": np.zeros(zone.shape, bool),
          "outliers": {"zcut": np.zeros(zone.shape, bool)}, "params": SuspectParams(a_max=A_MAX)}
    fallback = review_groups(xyz, None, **kw)
    fitted = review_groups(xyz, None, **kw, fits=True)
    patch = fallback.sources.index("patch")
    assert (fallback.table[:, GCOL["source"]] == patch).sum() >= 2  # behind and the large block
    assert not (fitted.table[:, GCOL["source"]] == patch).any()
    assert not (fitted.table[:, GCOL["detectors"]].astype(np.int64) & PATCH).any()
    # the floating block is a group in both, the same pixels
    g_a, g_b = np.unique(fallback.ids[FRONT]), np.unique(fitted.ids[FRONT])
    assert g_a.size == 1 and g_b.size == 1 and g_a[0] > 0 and g_b[0] > 0
    assert np.array_equal(fallback.ids == g_a[0], fitted.ids == g_b[0])
