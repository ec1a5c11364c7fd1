"""Stereo scenes as organized clouds with true outliers (docs/real_data.md, "Stereo scenes").

A rectified pair run through a stereo matcher gives a disparity d per pixel of the left image; with
the calibration (focal length f and principal point in px, baseline B in mm, the principal points'
offset ``doffs`` in px) its depth is ``Z = B · f / (d + doffs)`` and its point
``X = (u − cx) · Z / f``, ``Y = (v − cy) · Z / f``. The same formula turns a ground-truth disparity
into the true depth Z_GT. One pixel of disparity error at depth Z moves the point by about
``Z² / (f · B)``, so the tolerance of the truth grows with Z²::

    τ(Z_GT) = τ_d · Z_GT² / (f · B)          (τ_d in px of disparity, 1 by default)

and a matched pixel is a true outlier when ``|Z − Z_GT| > τ(Z_GT)``. Pixels whose ground truth is
unknown (no finite positive disparity) or occluded are *unknown*: they cannot be judged and are not
scored. Of the true outliers, the *detectable* ones are those that geometry alone can tell: the
pixel's depth differs from the median depth of its valid 8-neighbours by more than its tolerance
(or it has no valid neighbour). A wrong region still attached to a surface, or a wrong surface as
smooth as a right one, is not detectable by a filter that sees only the cloud.

Pure functions on arrays (no file I/O); the matcher wraps OpenCV's StereoSGBM / StereoBM with their
own post-filters off unless asked for. Each post-filter is also an outlier filter to score
(:func:`rejected_pixels`): the pixels a run of the matcher matches and the same run with the
post-filter on (at the strength of a :data:`POST_FILTERS` params class) leaves unmatched — except the
left-right check, which is done here (:func:`left_right_rejected`): OpenCV's own (``disp12MaxDiff``)
compares SGBM's disparity with the right view's winner of the *same* aggregated costs, and invalidated
no pixel on any of the ten Middlebury scenes (docs/filters.md, docs/labelling_real.md); the right view's
disparity is instead matched on its own (the mirrored pair), as a left-right check of two matchers is.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .params import StereoLrParams, StereoSpeckleParams, StereoTextureParams, StereoUniquenessParams

__all__ = [
    "MATCHERS",
    "POST_FILTERS",
    "MatcherParams",
    "PostFilter",
    "StereoCalibration",
    "StereoTruth",
    "depth_tolerance_mm",
    "detectable_outliers",
    "disparity_to_depth_mm",
    "left_right_disagree",
    "left_right_disagree_reference",
    "left_right_rejected",
    "match",
    "match_right",
    "rejected_pixels",
    "stereo_truth",
    "xyz_from_depth_mm",
]

#: The matchers of :func:`match`.
MATCHERS = ("sgbm", "bm")

#: The settings of one of the matcher's post-filters (fields named as :class:`MatcherParams`').
PostFilter = StereoUniquenessParams | StereoLrParams | StereoSpeckleParams | StereoTextureParams
#: The matcher's post-filters scored as methods: the method's name -> its settings class
#: (``stereo_texture``: StereoBM only).
POST_FILTERS: Mapping[str, type[PostFilter]] = types.MappingProxyType({
    "stereo_uniqueness": StereoUniquenessParams,
    "stereo_lr": StereoLrParams,
    "stereo_speckle": StereoSpeckleParams,
    "stereo_texture": StereoTextureParams,
})


@dataclass(frozen=True, slots=True)
class StereoCalibration:
    """Calibration of a rectified pair, in the left image's pixels.

    Attributes
    ----------
    focal_px : float
        Focal length f (px).
    cx, cy : float
        Principal point of the left image (px).
    baseline_mm : float
        Baseline B (mm).
    doffs_px : float
        x-difference of the principal points, ``cx_right − cx_left`` (px; 0 for a pair rectified
        to a common principal point).
    ndisp : int or None
        A bound on the disparities (Middlebury's ``ndisp``), when known.
    """

    focal_px: float
    cx: float
    cy: float
    baseline_mm: float
    doffs_px: float = 0.0
    ndisp: int | None = None

    def __post_init__(self) -> None:
        for name in ("focal_px", "baseline_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v) and v > 0):
                raise ParameterError(f"{name} must be a positive finite number, got {v!r}")
        for name in ("cx", "cy", "doffs_px"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v)):
                raise ParameterError(f"{name} must be a finite number, got {v!r}")
        if self.ndisp is not None and (int(self.ndisp) != self.ndisp or self.ndisp < 1):
            raise ParameterError(f"ndisp must be a positive integer, got {self.ndisp!r}")

    def as_dict(self) -> dict[str, float | int | None]:
        return {"focal_px": float(self.focal_px), "cx": float(self.cx), "cy": float(self.cy),
                "baseline_mm": float(self.baseline_mm), "doffs_px": float(self.doffs_px), "ndisp": self.ndisp}


@dataclass(frozen=True, slots=True)
class MatcherParams:
    """The stereo matcher and its settings (OpenCV's names).

    The post-filters (``uniqueness_ratio``, ``disp12_max_diff``, ``speckle_window``,
    ``texture_threshold``) are off (0, −1, 0, 0) unless set: they are outlier filters themselves.

    Attributes
    ----------
    matcher : {"sgbm", "bm"}
    num_disparities : int
        Disparity search range, a positive multiple of 16.
    block_size : int
        Matched block size (odd; BM needs >= 5).
    uniqueness_ratio : int
        Margin (%) by which the best cost must beat the second best; 0 = off.
    disp12_max_diff : int
        Largest left-right disparity difference kept; −1 = off.
    speckle_window : int
        Largest speckle (px) removed by the speckle filter; 0 = off.
    speckle_range : int
        Largest disparity variation inside a speckle (with ``speckle_window``).
    texture_threshold : int
        BM only: least texture a block needs; 0 = off.
    """

    matcher: str = "sgbm"
    num_disparities: int = 128
    block_size: int = 5
    uniqueness_ratio: int = 0
    disp12_max_diff: int = -1
    speckle_window: int = 0
    speckle_range: int = 2
    texture_threshold: int = 0

    def __post_init__(self) -> None:
        if self.matcher not in MATCHERS:
            raise ParameterError(f"matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        for name in ("num_disparities", "block_size", "uniqueness_ratio", "disp12_max_diff", "speckle_window",
                     "speckle_range", "texture_threshold"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise ParameterError(f"{name} must be an integer, got {v!r}")
        if self.num_disparities < 16 or self.num_disparities % 16:
            raise ParameterError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        lo = 5 if self.matcher == "bm" else 1
        if self.block_size < lo or self.block_size % 2 == 0 or self.block_size > 255:
            raise ParameterError(f"block_size must be odd, {lo}..255 for {self.matcher}, got {self.block_size}")
        if not 0 <= self.uniqueness_ratio <= 100:
            raise ParameterError(f"uniqueness_ratio must be 0..100, got {self.uniqueness_ratio}")
        if self.disp12_max_diff < -1:
            raise ParameterError(f"disp12_max_diff must be >= -1 (-1 = off), got {self.disp12_max_diff}")
        if self.speckle_window < 0 or self.speckle_range < 0 or self.texture_threshold < 0:
            raise ParameterError("speckle_window, speckle_range and texture_threshold must be >= 0")

    def as_dict(self) -> dict[str, int | str]:
        return {"matcher": self.matcher, "num_disparities": self.num_disparities, "block_size": self.block_size,
                "uniqueness_ratio": self.uniqueness_ratio, "disp12_max_diff": self.disp12_max_diff,
                "speckle_window": self.speckle_window, "speckle_range": self.speckle_range,
                "texture_threshold": self.texture_threshold}


def _image(a: object, name: str) -> np.ndarray:
    img = np.asarray(a)
    if img.dtype != np.uint8 or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)) or min(img.shape[:2]) < 2:
        raise InputShapeError(f"{name} must be an (H, W) or (H, W, 3) uint8 image, got {describe_array(img)}")
    return img


def match(left: np.ndarray, right: np.ndarray, params: MatcherParams) -> np.ndarray:
    """Disparity of the left image of a rectified pair.

    Parameters
    ----------
    left, right : (H, W, 3) or (H, W) uint8 ndarray
        The rectified images (RGB or gray), of one size.
    params : MatcherParams

    Returns
    -------
    (H, W) float32 ndarray
        Disparity in px (OpenCV's fixed point / 16); NaN where the matcher found no match (its
        invalid value, e.g. the left border of ``num_disparities`` columns).
    """
    import cv2

    lt, rt = _image(left, "left"), _image(right, "right")
    if lt.shape != rt.shape:
        raise InputShapeError(f"left and right must have one shape, got {lt.shape} and {rt.shape}")
    p = params
    m: cv2.StereoMatcher
    if p.matcher == "sgbm":
        ch = 1 if lt.ndim == 2 else 3
        m = cv2.StereoSGBM.create(
            minDisparity=0, numDisparities=p.num_disparities, blockSize=p.block_size,
            P1=8 * ch * p.block_size ** 2, P2=32 * ch * p.block_size ** 2, disp12MaxDiff=p.disp12_max_diff,
            preFilterCap=63, uniquenessRatio=p.uniqueness_ratio, speckleWindowSize=p.speckle_window,
            speckleRange=p.speckle_range, mode=cv2.STEREO_SGBM_MODE_SGBM,
        )
    else:
        bm = cv2.StereoBM.create(numDisparities=p.num_disparities, blockSize=p.block_size)
        bm.setUniquenessRatio(p.uniqueness_ratio)
        bm.setDisp12MaxDiff(p.disp12_max_diff)
        bm.setSpeckleWindowSize(p.speckle_window)
        bm.setSpeckleRange(p.speckle_range)
        bm.setTextureThreshold(p.texture_threshold)
        m = bm
        if lt.ndim == 3:
            lt, rt = cv2.cvtColor(lt, cv2.COLOR_RGB2GRAY), cv2.cvtColor(rt, cv2.COLOR_RGB2GRAY)
    raw = m.compute(np.ascontiguousarray(lt), np.ascontiguousarray(rt))
    disp = raw.astype(np.float32) / np.float32(16.0)
    disp[raw < 0] = np.nan  # minDisparity 0: OpenCV's invalid value is (0 - 1) * 16
    return disp


def match_right(left: np.ndarray, right: np.ndarray, params: MatcherParams) -> np.ndarray:
    """Disparity of the right image of a rectified pair: the matcher run on the mirrored pair (the right image,
    mirrored, as the left one), mirrored back. A right pixel ``x`` with disparity ``d`` sees the point of the
    left pixel ``x + d``. Same inputs and output as :func:`match`."""
    lt, rt = _image(left, "left"), _image(right, "right")
    if lt.shape != rt.shape:
        raise InputShapeError(f"left and right must have one shape, got {lt.shape} and {rt.shape}")
    return np.ascontiguousarray(match(rt[:, ::-1], lt[:, ::-1], params)[:, ::-1])


def _disparities(disp_left: object, disp_right: object, max_diff: object) -> tuple[np.ndarray, np.ndarray, float]:
    dl = np.asarray(disp_left)
    dr = np.asarray(disp_right)
    if dl.ndim != 2 or dl.dtype.kind != "f":
        raise InputShapeError(f"disp_left must be an (H, W) float array, got {describe_array(dl)}")
    if dr.shape != dl.shape or dr.dtype.kind != "f":
        raise InputShapeError(f"disp_right must be a float array of disp_left's shape {dl.shape}, got {describe_array(dr)}")
    if isinstance(max_diff, (bool, np.bool_)) or not isinstance(max_diff, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(max_diff) and max_diff >= 0):
        raise ParameterError(f"max_diff must be a finite number >= 0, got {max_diff!r}")
    return dl, dr, float(max_diff)


def left_right_disagree(disp_left: np.ndarray, disp_right: np.ndarray, max_diff: float) -> np.ndarray:
    """The matched left pixels whose disparity the right view does not confirm.

    A left pixel ``(v, u)`` with a finite disparity ``d`` sees the right pixel ``u2 = floor(u − d + 0.5)``; it
    disagrees when ``u2`` lies outside the image, the right view has no disparity there, or
    ``|d − disp_right[v, u2]| > max_diff``.

    Parameters
    ----------
    disp_left, disp_right : (H, W) float ndarray
        The left view's disparity (:func:`match`) and the right one's (:func:`match_right`), px, NaN unmatched.
    max_diff : float
        The largest difference kept (px, >= 0).

    Returns
    -------
    (H, W) bool ndarray
        False where ``disp_left`` is not finite. Equal to :func:`left_right_disagree_reference` bit for bit.
    """
    dl, dr, tol = _disparities(disp_left, disp_right, max_diff)
    H, W = dl.shape
    out = np.zeros((H, W), bool)
    if dl.size == 0:
        return out
    ok = np.isfinite(dl)
    v, u = np.nonzero(ok)
    d = dl[v, u].astype(np.float64)
    u2 = np.floor(u - d + 0.5)
    inside = (u2 >= 0) & (u2 < W)
    d2 = np.full(d.shape, np.nan)
    d2[inside] = dr[v[inside], u2[inside].astype(np.int64)]
    with np.errstate(invalid="ignore"):
        bad = ~inside | ~np.isfinite(d2) | (np.abs(d - d2) > tol)
    out[v, u] = bad
    return out


def left_right_disagree_reference(disp_left: np.ndarray, disp_right: np.ndarray, max_diff: float) -> np.ndarray:
    """:func:`left_right_disagree` pixel by pixel, in plain Python."""
    dl, dr, tol = _disparities(disp_left, disp_right, max_diff)
    H, W = dl.shape
    out = np.zeros((H, W), bool)
    for v in range(H):
        for u in range(W):
            d = float(dl[v, u])
            if d != d or d in (float("inf"), float("-inf")):
                continue
            u2 = int(np.floor(u - d + 0.5))
            if u2 < 0 or u2 >= W:
                out[v, u] = True
                continue
            d2 = float(dr[v, u2])
            out[v, u] = (d2 != d2 or d2 in (float("inf"), float("-inf"))) or abs(d - d2) > tol
    return out


def left_right_rejected(left: np.ndarray, right: np.ndarray, params: MatcherParams, max_diff: int, *,
                        matched: np.ndarray | None = None, disparity: np.ndarray | None = None,
                        disparity_right: np.ndarray | None = None) -> np.ndarray:
    """The pixels the left-right check invalidates: matched by ``params`` and not confirmed by the right view's
    own match (:func:`match_right` with the same ``params``; :func:`left_right_disagree` within ``max_diff`` px).

    ``matched``: the pixels to keep the result to (e.g. the cloud's valid ones). ``disparity``: ``match(left,
    right, params)`` when already computed (else matched here). ``disparity_right``: ``match_right(left, right,
    params)`` when already computed (else matched here; one match serves every tolerance). Returns an (H, W) bool
    ndarray."""
    dl = match(left, right, params) if disparity is None else disparity
    dr = match_right(left, right, params) if disparity_right is None else disparity_right
    out = left_right_disagree(dl, dr, max_diff)
    return out if matched is None else out & np.asarray(matched, dtype=bool)


def rejected_pixels(left: np.ndarray, right: np.ndarray, params: MatcherParams, post: PostFilter, *,
                    matched: np.ndarray | None = None, disparity: np.ndarray | None = None,
                    disparity_right: np.ndarray | None = None) -> np.ndarray:
    """The pixels one of the matcher's post-filters invalidates: matched by ``params``, unmatched by
    ``params`` with ``post``'s settings (the same run, that filter on at that strength); for the left-right
    check (:class:`~zcut.params.StereoLrParams`) the pixels :func:`left_right_rejected` gives.

    Parameters
    ----------
    left, right : (H, W, 3) or (H, W) uint8 ndarray
        The rectified pair, as for :func:`match`.
    params : MatcherParams
        The matcher run the cloud comes from.
    post : StereoUniquenessParams, StereoLrParams, StereoSpeckleParams or StereoTextureParams
        The post-filter and its strength (:data:`POST_FILTERS`).
    matched : (H, W) bool ndarray, optional
        ``isfinite(match(left, right, params))``, when already computed.
    disparity : (H, W) float ndarray, optional
        ``match(left, right, params)``, when already computed (the left-right check reads its values).
    disparity_right : (H, W) float ndarray, optional
        ``match_right(left, right, params)``, when already computed (the left-right check only: one match of the
        right view serves every tolerance).

    Returns
    -------
    (H, W) bool ndarray

    Raises
    ------
    ParameterError
        The texture threshold with SGBM (a StereoBM setting only).
    """
    if not isinstance(post, tuple(POST_FILTERS.values())):
        raise ParameterError(f"post must be one of {', '.join(c.__name__ for c in POST_FILTERS.values())}, got {post!r}")
    if isinstance(post, StereoTextureParams) and params.matcher != "bm":
        raise ParameterError(f"the texture threshold is a setting of StereoBM (matcher bm), not of {params.matcher}")
    if isinstance(post, StereoLrParams):
        return left_right_rejected(left, right, params, post.disp12_max_diff, matched=matched, disparity=disparity,
                                   disparity_right=disparity_right)
    if matched is None:
        matched = np.isfinite(match(left, right, params))
    on = dataclasses.replace(params, **dataclasses.asdict(post))
    return np.asarray(matched, dtype=bool) & ~np.isfinite(match(left, right, on))


def disparity_to_depth_mm(disparity: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """Depth ``Z = B · f / (d + doffs)`` (mm, float64) of a disparity image; NaN where ``d`` is not
    finite or ``d + doffs <= 0`` (no point in front of the camera; e.g. Middlebury's ``inf`` = unknown)."""
    d = np.asarray(disparity, dtype=np.float64)
    if d.ndim != 2:
        raise InputShapeError(f"disparity must be an (H, W) array, got {describe_array(d)}")
    den = d + float(calib.doffs_px)
    ok = np.isfinite(den) & (den > 0)
    z = np.full(d.shape, np.nan)
    z[ok] = float(calib.baseline_mm) * float(calib.focal_px) / den[ok]
    return z


def xyz_from_depth_mm(depth_mm: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """The organized cloud (H, W, 3) float32 in metres of a depth image in mm (NaN stays NaN):
    ``X = (u − cx) · Z / f``, ``Y = (v − cy) · Z / f`` at the pixel centres ``u, v = 0, 1, …``."""
    z = np.asarray(depth_mm, dtype=np.float64)
    if z.ndim != 2:
        raise InputShapeError(f"depth_mm must be an (H, W) array, got {describe_array(z)}")
    h, w = z.shape
    u = np.arange(w, dtype=np.float64)[None, :]
    v = np.arange(h, dtype=np.float64)[:, None]
    f = float(calib.focal_px)
    zm = z / 1000.0
    return np.stack([(u - calib.cx) * zm / f, (v - calib.cy) * zm / f, zm], axis=2).astype(np.float32)


def depth_tolerance_mm(depth_mm: np.ndarray, calib: StereoCalibration, tau_px: float) -> np.ndarray:
    """τ(Z) = τ_d · Z² / (f · B) in mm: the depth change of ``tau_px`` px of disparity at depth Z
    (first order), float64."""
    if not (np.isfinite(tau_px) and tau_px > 0):
        raise ParameterError(f"tau_px must be a positive finite number, got {tau_px!r}")
    z = np.asarray(depth_mm, dtype=np.float64)
    return float(tau_px) * z * z / (float(calib.focal_px) * float(calib.baseline_mm))


def _neighbour_median(z: np.ndarray) -> np.ndarray:
    """Median of the finite values among each pixel's 8 neighbours (NaN where there is none)."""
    h, w = z.shape
    pad = np.full((h + 2, w + 2), np.nan)
    pad[1:-1, 1:-1] = z
    stack = np.stack([pad[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx], axis=2)
    stack.sort(axis=2)  # NaN last
    n = np.isfinite(stack).sum(axis=2)
    lo = np.take_along_axis(stack, np.maximum(n - 1, 0)[..., None] // 2, axis=2)[..., 0]
    hi = np.take_along_axis(stack, (n // 2)[..., None], axis=2)[..., 0]
    med = (lo + hi) / 2.0
    med[n == 0] = np.nan
    return med


def detectable_outliers(depth_mm: np.ndarray, outliers: np.ndarray, tolerance_mm: np.ndarray) -> np.ndarray:
    """The true outliers that geometry alone can tell (module docstring).

    Parameters
    ----------
    depth_mm : (H, W) float ndarray
        Measured depth (mm), NaN where unmatched.
    outliers : (H, W) bool ndarray
        The true outliers.
    tolerance_mm : (H, W) float ndarray
        Each pixel's tolerance τ (mm), as the outliers were judged with.

    Returns
    -------
    (H, W) bool ndarray
        Outliers whose depth differs from the median depth of their valid 8-neighbours by more
        than τ, or that have no valid neighbour.
    """
    z = np.asarray(depth_mm, dtype=np.float64)
    med = _neighbour_median(z)
    lone = ~np.isfinite(med)
    with np.errstate(invalid="ignore"):
        apart = np.abs(z - np.where(lone, 0.0, med)) > tolerance_mm
    return np.asarray(outliers, dtype=bool) & (lone | apart)


@dataclass(frozen=True, slots=True)
class StereoTruth:
    """The truth of one stereo frame.

    Attributes
    ----------
    depth_mm : (H, W) float64 ndarray
        Z_GT (mm), NaN where unknown (occluded pixels keep their depth).
    outliers : (H, W) bool ndarray
        Valid, known pixels with ``|Z − Z_GT| > τ(Z_GT)``.
    unknown : (H, W) bool ndarray
        Ground truth unknown (no finite positive disparity) or occluded: not scored.
    detectable : (H, W) bool ndarray
        The outliers geometry can tell (:func:`detectable_outliers`).
    tolerance_mm : (H, W) float64 ndarray
        τ(Z_GT) (NaN where Z_GT is unknown).
    """

    depth_mm: np.ndarray
    outliers: np.ndarray
    unknown: np.ndarray
    detectable: np.ndarray
    tolerance_mm: np.ndarray


def stereo_truth(depth_mm: np.ndarray, gt_disparity: np.ndarray, calib: StereoCalibration, *,
                 tau_px: float = 1.0, occluded: np.ndarray | None = None) -> StereoTruth:
    """The truth of a measured depth image against a ground-truth disparity.

    Parameters
    ----------
    depth_mm : (H, W) float ndarray
        Measured depth (mm), NaN where unmatched (take it from the cloud as written, e.g. the
        float32 z in metres × 1000, so that the truth is the cloud's).
    gt_disparity : (H, W) float ndarray
        Ground-truth disparity (px); not finite (``inf``, NaN) or ``d + doffs <= 0`` = unknown.
    calib : StereoCalibration
    tau_px : float
        τ_d, the tolerance in px of disparity.
    occluded : (H, W) bool ndarray, optional
        Pixels whose ground truth is occluded or otherwise not to be judged.

    Returns
    -------
    StereoTruth
    """
    z = np.asarray(depth_mm, dtype=np.float64)
    if z.ndim != 2:
        raise InputShapeError(f"depth_mm must be an (H, W) array, got {describe_array(z)}")
    gt = np.asarray(gt_disparity)
    if gt.shape != z.shape:
        raise InputShapeError(f"gt_disparity is {describe_array(gt)}, the depth image {z.shape}")
    z_gt = disparity_to_depth_mm(gt, calib)
    unknown = ~np.isfinite(z_gt)
    if occluded is not None:
        occ = np.asarray(occluded)
        if occ.shape != z.shape or occ.dtype != np.bool_:
            raise InputShapeError(f"occluded must be an (H, W) bool array of shape {z.shape}, got {describe_array(occ)}")
        unknown = unknown | occ
    tol = depth_tolerance_mm(z_gt, calib, tau_px)
    valid = np.isfinite(z)
    with np.errstate(invalid="ignore"):
        outliers = valid & ~unknown & (np.abs(z - z_gt) > tol)
    return StereoTruth(depth_mm=z_gt, outliers=outliers, unknown=unknown,
                       detectable=detectable_outliers(z, outliers, tol), tolerance_mm=tol)
