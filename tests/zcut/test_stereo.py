"""zcut.stereo: depth from disparity, the truth's tolerance, detectable outliers, the matcher's settings;
replay.stereo_scene: PFM in both byte orders, calib.txt."""

from __future__ import annotations

import numpy as np
import pytest

from replay.errors import LogFormatError
from replay.stereo_scene import parse_calib, read_pfm
from zcut.errors import ParameterError
from zcut.params import StereoLrParams, StereoSpeckleParams, StereoTextureParams, StereoUniquenessParams
from zcut.stereo import (
    POST_FILTERS,
    MatcherParams,
    StereoCalibration,
    depth_tolerance_mm,
    detectable_outliers,
    disparity_to_depth_mm,
    match,
    rejected_pixels,
    stereo_truth,
    xyz_from_depth_mm,
)

CAL = StereoCalibration(focal_px=1000.0, cx=2.0, cy=1.0, baseline_mm=100.0, doffs_px=10.0)


def test_depth_point_and_tolerance_by_hand():
    d = np.array([[90.0, np.inf], [-10.0, np.nan]])
    z = disparity_to_depth_mm(d, CAL)
    assert z[0, 0] == 100.0 * 1000.0 / 100.0 and np.isnan(z[0, 1]) and np.isnan(z[1, 0]) and np.isnan(z[1, 1])
    xyz = xyz_from_depth_mm(np.full((2, 4), 1000.0), CAL)
    assert xyz[1, 3].tolist() == pytest.approx([0.001, 0.0, 1.0])
    # one pixel of disparity at 1 m: Z² / (f B) = 1e6 / 1e5 = 10 mm
    assert depth_tolerance_mm(np.array(1000.0), CAL, 1.0) == pytest.approx(10.0)


def test_truth_of_a_small_frame_by_hand():
    gt = np.full((3, 3), 90.0)  # Z_GT = 1000 mm everywhere, τ = 10 mm
    gt[0, 0] = np.inf
    z = np.full((3, 3), 1000.0)
    z[1, 1] = 1020.0  # 20 mm off, alone on its surface: outlier, detectable
    z[2, 2] = 1005.0  # inside τ
    z[0, 1] = np.nan  # unmatched
    occ = np.zeros((3, 3), bool)
    occ[2, 0] = True
    t = stereo_truth(z, gt, CAL, occluded=occ)
    assert t.outliers.tolist() == [[False, False, False], [False, True, False], [False, False, False]]
    assert t.unknown.tolist() == [[True, False, False], [False, False, False], [True, False, False]]
    assert t.detectable.tolist() == t.outliers.tolist()


def test_detectable_is_the_neighbours_median_rule():
    z = np.array([[1000.0, 1000.0, 1030.0], [1030.0, 1030.0, 1030.0], [np.nan, np.nan, np.nan]])
    out = np.ones_like(z, bool) & np.isfinite(z)
    tol = np.full(z.shape, 10.0)
    det = detectable_outliers(z, out, tol)
    # (0, 0): neighbours 1000, 1030, 1030 -> median 1030, 30 mm away: detectable
    # (1, 1): neighbours 1000, 1000, 1030, 1030, 1030 -> median 1030: not
    # (0, 1): neighbours 1000, 1030, 1030, 1030, 1030 -> 1030: detectable
    # (1, 0): neighbours 1000, 1000, 1030 -> median 1000: detectable
    assert det[0].tolist() == [True, True, False] and det[1].tolist() == [True, False, False]
    lone = np.full((3, 3), np.nan)
    lone[1, 1] = 5.0
    assert detectable_outliers(lone, np.isfinite(lone), tol)[1, 1]  # no valid neighbour


@pytest.mark.parametrize(("kw", "message"), [
    ({"num_disparities": 20}, "multiple of 16"), ({"block_size": 4}, "odd"), ({"matcher": "bm", "block_size": 3}, "5..255"),
    ({"uniqueness_ratio": 101}, "0..100"), ({"disp12_max_diff": -2}, "-1 = off"), ({"matcher": "x"}, "sgbm, bm"),
])
def test_matcher_settings_are_checked(kw, message):
    with pytest.raises(ParameterError, match=message):
        MatcherParams(**kw)


@pytest.mark.parametrize(("make", "message"), [
    (lambda: StereoUniquenessParams(uniqueness_ratio=0), "StereoUniquenessParams.uniqueness_ratio must be an integer"),
    (lambda: StereoLrParams(disp12_max_diff=-1), "StereoLrParams.disp12_max_diff must be an integer >= 0"),
    (lambda: StereoSpeckleParams(speckle_window=0), "StereoSpeckleParams.speckle_window must be"),
    (lambda: StereoSpeckleParams(speckle_range=1.5), "StereoSpeckleParams.speckle_range must be an integer"),
    (lambda: StereoTextureParams(texture_threshold=True), "StereoTextureParams.texture_threshold must be"),
])
def test_post_filter_strengths_are_checked(make, message):
    with pytest.raises(ParameterError, match=message):
        make()


def test_rejected_pixels_are_the_filter_on_run_minus_the_plain_one():
    rng = np.random.default_rng(3)
    right = rng.integers(0, 255, size=(40, 96), dtype=np.uint8)
    left = np.roll(right, 6, axis=1)  # a shift of 6 px: a plane, with a textureless stripe
    left[:, 50:70] = 128
    plain = MatcherParams(num_disparities=16)
    got = rejected_pixels(left, right, plain, StereoUniquenessParams(uniqueness_ratio=30))
    want = np.isfinite(match(left, right, plain)) & ~np.isfinite(
        match(left, right, MatcherParams(num_disparities=16, uniqueness_ratio=30)))
    assert np.array_equal(got, want) and got.any()
    assert not rejected_pixels(left, right, plain, StereoUniquenessParams(30), matched=np.zeros(got.shape, bool)).any()
    assert set(POST_FILTERS) == {"stereo_uniqueness", "stereo_lr", "stereo_speckle", "stereo_texture"}
    with pytest.raises(ParameterError, match="texture threshold is a setting of StereoBM"):
        rejected_pixels(left, right, plain, StereoTextureParams())
    with pytest.raises(ParameterError, match="post must be one of"):
        rejected_pixels(left, right, plain, plain)  # type: ignore[arg-type]
    bm = MatcherParams(matcher="bm", num_disparities=16, block_size=9)
    tex = rejected_pixels(left, right, bm, StereoTextureParams(texture_threshold=400))
    want = np.isfinite(match(left, right, bm)) & ~np.isfinite(
        match(left, right, MatcherParams(matcher="bm", num_disparities=16, block_size=9, texture_threshold=400)))
    assert np.array_equal(tex, want) and tex[:, 55:65].any()  # the flat stripe has no texture


def test_calibration_is_checked():
    with pytest.raises(ParameterError, match="focal_px must be a positive finite number"):
        StereoCalibration(focal_px=0.0, cx=1.0, cy=1.0, baseline_mm=1.0)


@pytest.mark.parametrize("scale", [-1.0, 1.0])
def test_pfm_rows_bottom_up_in_both_byte_orders(tmp_path, scale):
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    p = tmp_path / "d.pfm"
    p.write_bytes(f"Pf\n3 2\n{scale}\n".encode() + a[::-1].astype("<f4" if scale < 0 else ">f4").tobytes())
    assert np.array_equal(read_pfm(p), a)


def test_calib_txt_and_its_errors():
    v = parse_calib("cam0=[10 0 3; 0 10 4; 0 0 1]\ncam1=[10 0 5; 0 10 4; 0 0 1]\ndoffs=2\nbaseline=50\n"
                    "width=8\nheight=6\nndisp=16\nisint=0\n", name="c")
    assert v == {"focal": 10.0, "cx": 3.0, "cy": 4.0, "doffs": 2.0, "baseline": 50.0, "width": 8.0, "height": 6.0,
                 "ndisp": 16.0}
    with pytest.raises(LogFormatError, match="c: line 1 is not 'key=value'"):
        parse_calib("hello world\n", name="c")
