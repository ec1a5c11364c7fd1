"""zcut.stereo's left-right check: the vectorised rule equals its pixel-by-pixel reference bit for bit, by-hand
cases, bad inputs in one line, and on a real pair (scikit-image's Motorcycle) it flags what OpenCV's own check
(``disp12MaxDiff``) does not (docs/labelling_real.md, h/real3)."""

from __future__ import annotations

import numpy as np
import pytest

from zcut.errors import InputShapeError, ParameterError
from zcut.params import StereoLrParams
from zcut.stereo import (
    MatcherParams,
    left_right_disagree,
    left_right_disagree_reference,
    left_right_rejected,
    match,
    match_right,
    rejected_pixels,
)


def test_by_hand():
    dl = np.array([[0.0, 1.0, 1.4, 2.6, np.nan, 5.0]], np.float32)
    dr = np.array([[0.0, 1.0, 3.0, np.nan, 1.0, 1.0]], np.float32)
    # u=0 d=0 -> u2 0, 0 vs 0: kept; u=1 d=1 -> u2 0 (d2 0, |1-0| = 1 <= 1): kept; u=2 d=1.4 -> floor(1.1) = 1,
    # d2 1: kept; u=3 d=2.6 -> floor(0.9) = 0, d2 0, 2.6 > 1: off; u=4 unmatched; u=5 d=5 -> u2 0, |5-0| > 1: off
    assert left_right_disagree(dl, dr, 1).tolist() == [[False, False, False, True, False, True]]
    assert left_right_disagree(dl, dr, 3).tolist() == [[False, False, False, False, False, True]]
    dl2 = np.array([[np.nan, 3.0, 0.0]])  # u=1 d=3 -> u2 -2: outside; u=2 -> u2 2: right view unmatched there
    assert left_right_disagree(dl2, np.array([[1.0, 1.0, np.nan]]), 0).tolist() == [[False, True, True]]


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (1, 9), (7, 1), (23, 31)])
@pytest.mark.parametrize("seed", [0, 1])
def test_equals_reference(shape, seed):
    rng = np.random.default_rng(seed)
    dl = rng.uniform(-1, 12, shape).round(rng.integers(0, 2)).astype(np.float32)
    dr = (dl + rng.normal(0, 1.5, shape)).astype(np.float32)
    for a in (dl, dr):
        a[rng.random(shape) < 0.2] = np.nan
    dl[rng.random(shape) < 0.05] = np.inf
    for tol in (0, 1, 2.5):
        got = left_right_disagree(dl, dr, tol)
        assert got.dtype == np.bool_ and np.array_equal(got, left_right_disagree_reference(dl, dr, tol))


@pytest.mark.parametrize(("args", "message"), [
    ((np.zeros(3), np.zeros(3), 1), "disp_left must be an (H, W) float array"),
    ((np.zeros((2, 2)), np.zeros((2, 3)), 1), "disp_right must be a float array of disp_left's shape"),
    ((np.zeros((2, 2), int), np.zeros((2, 2)), 1), "disp_left must be an (H, W) float array"),
    ((np.zeros((2, 2)), np.zeros((2, 2)), -1), "max_diff must be a finite number >= 0"),
    ((np.zeros((2, 2)), np.zeros((2, 2)), np.nan), "max_diff must be a finite number >= 0"),
])
def test_bad_inputs_one_line(args, message):
    for fn in (left_right_disagree, left_right_disagree_reference):
        with pytest.raises((InputShapeError, ParameterError), match=None) as e:
            fn(*args)
        assert message in str(e.value) and "\n" not in str(e.value)


def test_real_pair_flags_what_opencv_does_not():
    skd = pytest.importorskip("skimage.data")
    left, right, _ = skd.stereo_motorcycle()
    left, right = left[::2, ::2].copy(), right[::2, ::2].copy()  # a quarter of the pixels: a second, not ten
    p = MatcherParams(num_disparities=64)
    dl = match(left, right, p)
    dr = match_right(left, right, p)
    # the right view's match of the mirrored pair: a right pixel u sees the left pixel u + d
    assert dr.shape == dl.shape and np.isfinite(dr).mean() > 0.5
    matched = np.isfinite(dl)
    got = rejected_pixels(left, right, p, StereoLrParams(disp12_max_diff=1), matched=matched)
    assert np.array_equal(got, left_right_rejected(left, right, p, 1))
    assert np.array_equal(got, matched & left_right_disagree_reference(dl, dr, 1))
    assert 0.01 < got.sum() / matched.sum() < 0.5, got.sum()
    # OpenCV's own check at the same strength invalidates (next to) nothing on this pair
    opencv = matched & ~np.isfinite(match(left, right, MatcherParams(num_disparities=64, disp12_max_diff=1)))
    assert got.sum() > 10 * max(int(opencv.sum()), 1)
    # a wider tolerance flags a subset
    assert not (rejected_pixels(left, right, p, StereoLrParams(disp12_max_diff=4)) & ~got).any()


def test_one_right_match_serves_every_tolerance(monkeypatch):
    """``disparity_right=``: the right view's match given once gives every tolerance's mask, equal to the one matched
    inside; no match of the right view is run then (h/stereo4)."""
    skd = pytest.importorskip("skimage.data")
    import zcut.stereo as stereo

    left, right, _ = skd.stereo_motorcycle()
    left, right = left[::4, ::4].copy(), right[::4, ::4].copy()
    p = MatcherParams(num_disparities=32)
    dl, dr = match(left, right, p), match_right(left, right, p)
    matched = np.isfinite(dl)
    want = {t: rejected_pixels(left, right, p, StereoLrParams(disp12_max_diff=t), matched=matched) for t in (0, 1, 2, 4)}
    assert want[0].sum() > want[4].sum() > 0

    def no_right_match(*_a, **_k):
        raise AssertionError("the right view matched again")

    monkeypatch.setattr(stereo, "match_right", no_right_match)
    for t, w in want.items():
        got = rejected_pixels(left, right, p, StereoLrParams(disp12_max_diff=t), matched=matched, disparity=dl,
                              disparity_right=dr)
        assert np.array_equal(got, w), t
        assert np.array_equal(stereo.left_right_rejected(left, right, p, t, disparity=dl, disparity_right=dr),
                              left_right_disagree_reference(dl, dr, t))
