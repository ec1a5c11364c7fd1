"""`zcut compare` scores both sides in one pass (`annotate.accuracy.frame_accuracies`): the counts and
classes equal two separate `frame_accuracy` calls, the same errors on bad input, and its components
(`components8`) equal `scipy.ndimage.label`'s, numbers included; on random, tied, border, invalid-heavy,
degenerate and real scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from annotate.accuracy import (
    N_KINDS,
    _frame_accuracies,
    _label_sparse8,
    components8,
    frame_accuracies,
    frame_accuracy,
)
from zcut.errors import ZcutError

REAL = Path("/work/shared/data/real")
if not REAL.is_dir():
    REAL = Path(__file__).resolve().parents[2] / "data" / "real"
EIGHT = np.ones((3, 3), dtype=bool)
KW = ("reviewed", "kinds", "detectable", "displacement_mm")


def _reference(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    lab, n = ndimage.label(mask, structure=EIGHT)
    idx = np.flatnonzero(mask)
    return n, idx, lab.ravel()[idx]


def _same_components(mask: np.ndarray) -> None:
    n, idx, lab = components8(mask)
    rn, ridx, rlab = _reference(mask)
    assert n == rn and np.array_equal(idx, ridx) and np.array_equal(lab, rlab)
    assert lab.dtype == np.int64
    # the union-find kernel at any density (components8 takes it below _SPARSE_SHARE, ndimage.label above)
    k, klab = _label_sparse8(ridx.astype(np.int64), mask.shape[1])
    assert k == rn and np.array_equal(klab, rlab) and klab.dtype == np.int64


def _real_masks() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, valid, depth edges) of each real scan: real invalid regions, real shapes."""
    from replay.logs.pcd import read_pcd

    out = []
    for f in sorted(REAL.glob("*.pcd"))[:4]:
        xyz = read_pcd(f).xyz
        valid = np.isfinite(xyz).all(axis=2)
        z = np.where(valid, xyz[..., 2], np.nan)
        step = np.zeros(valid.shape, dtype=bool)
        with np.errstate(invalid="ignore"):
            step[:, 1:] = np.abs(z[:, 1:] - z[:, :-1]) > 0.01
            step[1:, :] |= np.abs(z[1:, :] - z[:-1, :]) > 0.01
        out.append((f.name, valid, step & valid))
    return out


@pytest.mark.parametrize("density", [0.0005, 0.005, 0.02, 0.05, 0.3, 0.7])
def test_components_equal_ndimage_label_random(density):
    rng = np.random.default_rng(int(density * 1e4))
    for shape in ((1, 1), (1, 40), (40, 1), (7, 9), (64, 80), (300, 257)):
        _same_components(rng.random(shape) < density)
    # blobs (dilated specks: many pixels a component, merges from the row above and across it)
    specks = rng.random((200, 311)) < density / 8
    _same_components(ndimage.binary_dilation(specks, structure=EIGHT, iterations=2))


def test_components_do_not_wrap_across_rows_and_edge_cases():
    m = np.zeros((6, 5), dtype=bool)
    m[0, 4] = m[1, 0] = True  # flat neighbours (offset 1) but not image neighbours
    m[2, 0] = m[3, 4] = True  # offset W - 1 ... and W + 1 across the border
    m[4, 4] = m[5, 0] = True
    _same_components(m)
    assert components8(m)[0] == 4  # (1,0)-(2,0) touch; the others are alone
    for mask in (np.zeros((5, 5), bool), np.ones((5, 5), bool), np.eye(9, dtype=bool), np.eye(9, dtype=bool)[::-1],
                 np.ones((1, 12), bool), np.ones((12, 1), bool)):
        _same_components(mask)
    # a long snake: one component whose graph is deep (and numbered by its first pixel)
    s = np.zeros((41, 41), dtype=bool)
    s[::4, :] = True
    s[1::8, -1] = s[2::8, -1] = s[3::8, -1] = True
    s[5::8, 0] = s[6::8, 0] = s[7::8, 0] = True
    _same_components(s)
    assert components8(s)[0] == 1


def test_components_equal_ndimage_label_real_scans():
    for name, valid, edges in _real_masks():
        _same_components(edges)
        _same_components(~valid)
        _same_components(valid & ~edges)
        assert components8(edges)[0] > 10, name


def _truth(rng: np.random.Generator, shape: tuple[int, int], valid: np.ndarray, share: float):
    blobs = ndimage.binary_dilation(rng.random(shape) < share / 4, structure=EIGHT,
                                    iterations=int(rng.integers(0, 2)))
    outliers = blobs & valid
    reviewed = valid.copy()
    reviewed[: shape[0] // 5] = False  # a strip left unreviewed (labels)
    outliers &= reviewed
    kinds = np.where(outliers, rng.integers(1, N_KINDS + 1, shape), 0).astype(np.uint8)
    detectable = rng.random(shape) < 0.6
    shift = np.where(rng.random(shape) < 0.1, np.nan, rng.exponential(10.0, shape))
    return outliers, reviewed, kinds, detectable, shift


def _check_equal(sides, outliers, **kw):
    got = frame_accuracies(3, 77, sides, outliers, **kw)
    fast = _frame_accuracies(3, 77, sides, outliers, **{k: kw.get(k) for k in KW})  # not frame_accuracy's own
    assert fast is not None and fast == got
    want = [frame_accuracy(3, 77, p, outliers, valid=v, region=g, **kw) for p, v, g in sides]
    assert got == want
    return got


def _pred(rng, truth, share, keep):
    return (truth & (rng.random(truth.shape) < keep)) | (rng.random(truth.shape) < share)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_frame_accuracies_equal_two_frame_accuracy_calls(seed):
    rng = np.random.default_rng(seed)
    shape = (90, 130)
    valid = rng.random(shape) > 0.05
    valid[40:70, 20:60] = False  # a large invalid region
    zone = np.zeros(shape, dtype=bool)
    zone[10:80, 15:120] = True
    zone &= valid
    outliers, reviewed, kinds, detectable, shift = _truth(rng, shape, valid, 0.08)
    za, sa = _pred(rng, outliers, 0.01, 0.7), _pred(rng, outliers, 0.02, 0.5)
    zb = _pred(rng, outliers, 0.03, 0.9)
    a = {"zcut": za, "sor": sa}
    b = {"zcut": zb, "sor": sa, "zcut+sor": za | sa}
    other_zone = zone.copy()
    other_zone[:, 100:] = False
    for kw in ({}, {"reviewed": reviewed}, {"kinds": np.where(valid, kinds, 0).astype(np.uint8) * (outliers > 0)},
               {"detectable": detectable, "displacement_mm": shift},
               {"reviewed": reviewed, "kinds": kinds, "detectable": detectable, "displacement_mm": shift}):
        kw = dict(kw)
        if "kinds" in kw:
            kw["kinds"] = np.where(outliers, kw["kinds"], 0).astype(np.uint8)
            kw["kinds"][outliers & (kw["kinds"] == 0)] = 1
        # shared region (the same arrays, then equal copies), different regions, valid as the region
        _check_equal([(a, valid, zone), (b, valid, zone)], outliers, **kw)
        _check_equal([(a, valid, zone), (b, valid.copy(), zone.copy())], outliers, **kw)
        _check_equal([(a, valid, zone), (b, valid, other_zone)], outliers, **kw)
        _check_equal([({"zcut": za}, valid, valid), ({"zcut": zb}, valid, valid)], outliers, **kw)


def test_frame_accuracies_degenerate_frames():
    rng = np.random.default_rng(9)
    shape = (40, 50)
    valid = np.ones(shape, dtype=bool)
    nothing = np.zeros(shape, dtype=bool)
    everything = np.ones(shape, dtype=bool)
    some = rng.random(shape) < 0.1
    for outliers in (nothing, some, everything):
        for pa, pb in ((nothing, nothing), (everything, nothing), (some, ~some), (outliers, outliers)):
            _check_equal([({"zcut": pa}, valid, valid), ({"zcut": pb}, valid, valid)], outliers)
            _check_equal([({"zcut": pa}, valid, nothing), ({"zcut": pb}, valid, nothing)], outliers)
    # nothing valid at all
    _check_equal([({"zcut": nothing}, nothing, nothing), ({"zcut": nothing}, nothing, nothing)], nothing)


def test_frame_accuracies_real_scans():
    rng = np.random.default_rng(17)
    for _name, valid, edges in _real_masks():
        grown = ndimage.binary_dilation(edges, structure=EIGHT) & valid
        pa = grown & (rng.random(valid.shape) < 0.8)
        pb = edges | (valid & (rng.random(valid.shape) < 0.01))
        got = _check_equal([({"zcut": pa, "sor": pb}, valid, valid), ({"zcut": pb}, valid, valid)], edges)
        assert got[0].counts["zcut"].tp > 0


def test_frame_accuracies_bad_input_raises_frame_accuracys_error():
    rng = np.random.default_rng(4)
    shape = (30, 40)
    valid = rng.random(shape) > 0.2
    outliers = rng.random(shape) < 0.1  # some outside valid: L ⊄ R
    p = {"zcut": outliers.copy()}
    cases = [
        dict(outliers=outliers),
        dict(outliers=outliers & valid, reviewed=np.ones(shape, dtype=bool)),  # R ⊄ valid
        dict(outliers=outliers & valid, kinds=np.zeros(shape, dtype=np.uint8)),  # no kind where L is set
        dict(outliers=(outliers & valid).astype(np.uint8)),  # not bool
        dict(outliers=outliers & valid, displacement_mm=np.zeros((3, 3))),
    ]
    for case in cases:
        o = case.pop("outliers")
        with pytest.raises(ZcutError) as want:
            frame_accuracy(0, 0, p, o, valid=valid, region=valid, **case)
        with pytest.raises(ZcutError) as got:
            frame_accuracies(0, 0, [(p, valid, valid), (p, valid, valid)], o, **case)
        assert type(got.value) is type(want.value) and str(got.value) == str(want.value)
    with pytest.raises(ZcutError) as got:  # a prediction of another shape
        frame_accuracies(0, 0, [(p, valid, valid), ({"zcut": np.zeros((3, 3), bool)}, valid, valid)],
                         outliers & valid)
    assert "shape" in str(got.value)


def test_displacement_read_where_scored_equals_the_whole_image():
    """compare's displacement classes: |Z − Z_GT| computed at the scored true outliers alone
    (`Displacement`) gives `displacement_mm`'s bits there and the same classes as two frame_accuracy calls
    given the whole image; NaN points and NaN true depth in no class."""
    from types import SimpleNamespace

    from annotate.accuracy import displacement_mm, frame_displacement

    rng = np.random.default_rng(31)
    shape = (70, 90)
    xyz = rng.random((*shape, 3)).astype(np.float32)
    xyz[rng.random(shape) < 0.1] = np.nan
    depth = (xyz[..., 2] + rng.normal(0.0, 0.02, shape)).astype(np.float32)
    depth[rng.random(shape) < 0.05] = np.nan
    frame = SimpleNamespace(xyz=xyz, truth_depth_m=depth)
    lazy, whole = frame_displacement(None, frame), displacement_mm(None, frame)
    assert lazy is not None and whole is not None
    idx = np.flatnonzero(rng.random(shape) < 0.3)
    assert np.array_equal(lazy.at(idx).view(np.int64), whole.ravel()[idx].view(np.int64))
    assert np.array_equal(lazy.image().view(np.int64), whole.view(np.int64))
    valid = np.isfinite(xyz).all(axis=2)
    outliers, reviewed, kinds, detectable, _ = _truth(rng, shape, valid, 0.1)
    zone = valid.copy()
    zone[:, :10] = False
    a = {"zcut": _pred(rng, outliers, 0.02, 0.6)}
    b = {"zcut": _pred(rng, outliers, 0.05, 0.8)}
    sides = [(a, valid, zone), (b, valid, zone)]
    got = frame_accuracies(1, 2, sides, outliers, reviewed=reviewed, kinds=kinds, detectable=detectable,
                           displacement_mm=lazy)
    want = [frame_accuracy(1, 2, p, outliers, reviewed=reviewed, valid=v, region=g, kinds=kinds,
                           detectable=detectable, displacement_mm=whole) for p, v, g in sides]
    assert got == want and "by_displacement" in got[0].classes["zcut"]
    assert sum(got[0].classes["zcut"]["by_displacement"].n) > 0
    # bad input with it still raises frame_accuracy's error
    with pytest.raises(ZcutError) as err:
        frame_accuracies(1, 2, sides, outliers & ~reviewed | ~valid, displacement_mm=lazy)
    with pytest.raises(ZcutError) as ref:
        frame_accuracy(1, 2, a, outliers & ~reviewed | ~valid, valid=valid, region=zone, displacement_mm=whole)
    assert str(err.value) == str(ref.value)


@pytest.mark.parametrize("seed", [4, 5])
def test_sparse_counts_equal_scored_truth_counts(seed):
    """The one-pass scoring's counts of a prediction (its components among its pixels, ``_sparse_counts``)
    are ``zcut.metrics.ScoredTruth.counts`` (the whole image labelled): both end in ``ScoredTruth.counts_of``;
    with kinds, a region, large invalid parts, and a real scan's edges as the prediction."""
    from annotate.accuracy import _sparse_counts
    from zcut.metrics import scored_truth

    rng = np.random.default_rng(seed)
    shape = (70, 110)
    valid = rng.random(shape) > 0.05
    valid[10:50, 30:80] = False
    outliers, reviewed, kinds, _, _ = _truth(rng, shape, valid, 0.1)
    region = np.zeros(shape, dtype=bool)
    region[5:65, 5:105] = True
    st = scored_truth(outliers, reviewed=reviewed, valid=valid, region=region, kinds=kinds, n_kinds=N_KINDS)
    preds = [_pred(rng, outliers, share, keep) for share, keep in ((0.0, 1.0), (0.02, 0.6), (0.3, 0.2), (0.0, 0.0))]
    for p in [*preds, np.ones(shape, dtype=bool), ~valid]:
        assert _sparse_counts(st, p) == st.counts(p)
    for _, v, edges in _real_masks()[:2]:
        st = scored_truth(edges, valid=v, region=v)
        for p in (edges, v & (rng.random(v.shape) < 0.01), np.roll(edges, 1, axis=1)):
            assert _sparse_counts(st, p) == st.counts(p)
