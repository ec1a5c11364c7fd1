"""A fit the camera saw through, and the pixels a partly trusted fit keeps (zcut/fit_vetting.py,
:func:`see_through`, :func:`partly_trusted`; docs/labelling.md, "Twelfth round").

Closed forms: a pinhole camera looks at a plane; boxes are posed in front of it (floating: every silhouette pixel
seen through), behind it (occluded: none) or resting on it as part of the scan (the scan renders the box: none).
The oracle of the silhouette is the box's projection; of the gap, the plane's range minus the box's front face's along
each ray; of the rule, its definition pixel by pixel. Degenerate clouds: empty, all-NaN, one row, no fits.
"""

from __future__ import annotations

import numpy as np
import pytest

from zcut import fit_vetting as fv
from zcut.errors import InputShapeError, ParameterError

H, W, F = 120, 160, 200.0
PLANE_MM = 500.0
SIGMA = 0.3


def _plane(h: int = H, w: int = W, z: float = PLANE_MM) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    zz = np.full((h, w), z)
    return np.stack([(xx - w / 2 + 0.5) * zz / F, (yy - h / 2 + 0.5) * zz / F, zz], -1)


def _box(centre, half: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v + np.asarray(centre, float), t


def _render(xyz: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The scan with the box in it: each ray's nearer of the plane and the box's front face."""
    v, _ = box
    lo, hi = v.min(axis=0), v.max(axis=0)
    d = xyz / np.linalg.norm(xyz, axis=2, keepdims=True)
    t = lo[2] / d[..., 2]
    p = d * t[..., None]
    on = (p[..., 0] >= lo[0]) & (p[..., 0] <= hi[0]) & (p[..., 1] >= lo[1]) & (p[..., 1] <= hi[1])
    out = xyz.copy()
    out[on] = p[on]
    return out


def _in_silhouette(xyz: np.ndarray, box) -> np.ndarray:
    v, _ = box
    lo, hi = v.min(axis=0), v.max(axis=0)
    u, w = xyz[..., 0] / xyz[..., 2], xyz[..., 1] / xyz[..., 2]
    return (u >= lo[0] / lo[2]) & (u <= hi[0] / lo[2]) & (w >= lo[1] / lo[2]) & (w <= hi[1] / lo[2])


def test_a_box_floating_in_front_of_the_scan_is_seen_through_and_one_behind_it_is_not():
    xyz = _plane()
    front, behind = _box([0, 0, 480], 10.0), _box([5, -5, 530], 8.0)
    see = fv.see_through(xyz, [front, behind], [SIGMA, SIGMA], f_px=F, k=3.0)
    np.testing.assert_array_equal(see.share, [1.0, 0.0])
    sil = _in_silhouette(xyz, front).ravel()
    np.testing.assert_array_equal(see.pix[0], np.flatnonzero(sil))  # the box's projection, no more, no less
    # the gap along each ray: the plane's range minus the front face's (z 470)
    p = xyz.reshape(-1, 3)[see.pix[0]]
    rng = np.linalg.norm(p, axis=1)
    np.testing.assert_allclose(see.gap_mm[0], rng - rng * 470.0 / PLANE_MM, atol=1e-3)
    foot = PLANE_MM / F
    np.testing.assert_allclose(see.err_mm[0], np.sqrt(SIGMA ** 2 + 0.5 * foot ** 2), rtol=1e-6)
    assert (see.gap_mm[1] < 0).all() and not see.through[1].any()


def test_a_box_resting_in_the_scan_is_not_seen_through_and_keeps_every_pixel():
    box = _box([0, 0, 490], 10.0)
    xyz = _render(_plane(), box)
    see = fv.see_through(xyz, [box], [SIGMA], f_px=F)
    assert see.share[0] == 0.0 and see.pix[0].size > 50
    band = see.pix[0]
    keep = fv.partly_trusted(band, np.zeros(band.size, np.int64), see, shape=(H, W), max_share=0.0)
    assert keep.all()


def test_the_gap_threshold_is_k_times_err():
    xyz = _plane()
    foot = PLANE_MM / F
    err = np.sqrt(SIGMA ** 2 + 0.5 * foot ** 2)
    # the front face 2.9 / 3.1 Err in front of the plane (on the optical axis;  off it both scale alike)
    near = _box([0, 0, PLANE_MM - 2.9 * err + 5.0], 5.0)
    far = _box([0, 0, PLANE_MM - 3.1 * err + 5.0], 5.0)
    see = fv.see_through(xyz, [near, far], [SIGMA, SIGMA], f_px=F, k=3.0)
    assert see.share[0] == 0.0 and see.share[1] == 1.0


def test_invalid_pixels_are_never_counted():
    xyz = _plane()
    box = _box([0, 0, 480], 10.0)
    full = fv.see_through(xyz, [box], [SIGMA], f_px=F)
    holed = xyz.copy()
    holed[:, : W // 2] = np.nan
    half = fv.see_through(holed, [box], [SIGMA], f_px=F)
    valid = np.isfinite(holed).all(axis=2).ravel()
    np.testing.assert_array_equal(half.pix[0], full.pix[0][valid[full.pix[0]]])
    assert half.share[0] == 1.0


@pytest.mark.parametrize("cloud", ["empty", "all-NaN", "one row"])
def test_degenerate_clouds(cloud):
    box = _box([0, 0, 480], 10.0)
    xyz = {"empty": np.zeros((0, 0, 3)), "all-NaN": np.full((H, W, 3), np.nan), "one row": _plane(1, W)}[cloud]
    see = fv.see_through(xyz, [box], [SIGMA], f_px=F)
    assert see.share.shape == (1,) and len(see.pix) == 1
    if cloud == "one row":  # a single row: the rows' line is undefined, nothing measured
        assert see.share[0] == 0.0
    else:
        assert see.share[0] == 0.0 and see.pix[0].size == 0
    none = fv.see_through(_plane(), [], [], f_px=F)
    assert none.share.shape == (0,) and none.pix == ()
    assert fv.partly_trusted(np.zeros(0, np.int64), np.zeros(0, np.int64), none, shape=(H, W)).shape == (0,)


def test_errors_are_one_line():
    with pytest.raises(InputShapeError):
        fv.see_through(np.zeros((4, 4)), [], [], f_px=F)
    with pytest.raises(InputShapeError):
        fv.see_through(_plane(), [_box([0, 0, 480], 1.0)], [], f_px=F)
    with pytest.raises(ParameterError):
        fv.see_through(_plane(), [], [], f_px=0.0)
    see = fv.see_through(_plane(), [_box([0, 0, 480], 10.0)], [SIGMA], f_px=F)
    with pytest.raises(ParameterError):
        fv.partly_trusted(see.pix[0], np.zeros(see.pix[0].size, np.int64), see, shape=(H, W), rule="nope")
    with pytest.raises(InputShapeError):
        fv.partly_trusted(see.pix[0], np.ones(see.pix[0].size, np.int64), see, shape=(H, W))


def _half_seen():
    """A box whose left half the scan measures (its front face rendered) and whose right half it sees through."""
    box = _box([0, 0, 480], 10.0)
    plane = _plane()
    xyz = _render(plane, box)
    xx = np.mgrid[0:H, 0:W][1]
    xyz[xx >= W // 2] = plane[xx >= W // 2]
    return xyz, box


@pytest.mark.parametrize("rule", fv.TRUST_RULES)
def test_a_partly_trusted_fit_keeps_the_pixels_on_its_own_surface(rule):
    xyz, box = _half_seen()
    see = fv.see_through(xyz, [box], [SIGMA], f_px=F)
    sil = see.pix[0]
    cols = sil % W
    np.testing.assert_array_equal(see.through[0], cols >= W // 2)
    assert 0.4 < see.share[0] < 0.6
    # the band: the silhouette and a stray pixel beside it (within k × Err of the box's edge, not in its silhouette)
    stray = int(sil.min()) - W
    band = np.concatenate([[stray], sil])
    of = np.zeros(band.size, np.int64)
    # front_local: the local surface explains the stray pixel and every fourth silhouette pixel (0 mm), not the rest
    local = np.full(band.size, 50.0)
    local[0] = 0.0
    local[1::4] = 0.0
    err = np.full(band.size, 1.0)
    kw = {"local_mm": local, "band_err_mm": err}
    assert fv.partly_trusted(band, of, see, shape=(H, W), max_share=0.6, rule=rule, **kw).all()  # under the share
    keep = fv.partly_trusted(band, of, see, shape=(H, W), max_share=0.2, rule=rule, **kw)
    assert keep[0] == (rule == "front_local")  # off its silhouette: not on its own surface
    on = np.abs(see.gap_mm[0]) <= 3.0 * see.err_mm[0]
    want = {"front": on, "front_core": on, "tight": see.dist_mm[0] <= 1.0 * see.err_mm[0],
            "front_away": on & (cols < W // 2 - 2), "front_local": on | (local[1:] == 0.0)}[rule]
    np.testing.assert_array_equal(keep[1:], want)
