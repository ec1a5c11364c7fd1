"""Two 3 x 3 rules of the filter bank: Basler's outlier removal and the mixed-pixel test.

Both judge a pixel from its immediate image neighbours only, in one pass (numba), each beside a
literal numpy reference with the same float64 arithmetic (the tests check they agree bit for bit):

- :func:`window_outliers`: a pixel is kept when enough of its 8 neighbours have a depth within a
  relative tolerance of its own (Basler blaze cameras' OutlierRemoval).
- :func:`mixed_pixel_outliers`: a pixel is removed when, along an image axis, the surface through it
  is seen at a grazing angle on both sides (ifm's mixed-pixel filter; the jump-edge test).

``xyz`` is an (H, W, 3) organized cloud in the camera optical frame (metres, camera at the origin
looking along +z); a pixel is valid iff its three coordinates are finite. Invalid pixels are never
outliers and never count as neighbours. docs/filters.md, "The filter bank", describes both.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .errors import ParameterError
from .grid_input import as_cloud, depth_plane, depth_plane_reference, plain_number, valid_at
from .params import MixedPixelParams, WindowParams
from .types import XYZ, Mask

__all__ = [
    "mixed_pixel_outliers",
    "mixed_pixel_outliers_reference",
    "mixed_pixel_stage",
    "window_outliers",
    "window_outliers_reference",
    "window_stage",
]

_NEIGHBOURS_8 = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


# --------------------------------------------------------------------------------------------
# Basler's 3 x 3 outlier removal
# --------------------------------------------------------------------------------------------
def _window_params(min_inliers: object, rel_tolerance: object) -> WindowParams:
    return WindowParams(min_inliers=plain_number(min_inliers), rel_tolerance=plain_number(rel_tolerance))


@nb.njit(cache=True, nogil=True)
def _window_kernel(z, min_inliers, tol, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = z.shape
    for r in range(H):
        for c in range(W):
            zc = z[r, c]
            if np.isnan(zc):
                out[r, c] = False
                continue
            lim = tol * abs(zc)
            n = 0
            for dr in range(-1, 2):
                rr = r + dr
                if rr < 0 or rr >= H:
                    continue
                for dc in range(-1, 2):
                    cc = c + dc
                    if (dr == 0 and dc == 0) or cc < 0 or cc >= W:
                        continue
                    n += abs(z[rr, cc] - zc) <= lim  # False for an invalid (NaN) neighbour
            out[r, c] = n < min_inliers


def window_outliers(xyz: XYZ, *, min_inliers: int, rel_tolerance: float) -> Mask:
    """The 3 x 3 rule of Basler's OutlierRemoval on an organized cloud.

    Basler's blaze cameras (documentation "Outlier Removal") decide from a pixel's 3 x 3
    neighbourhood: a neighbour is an inlier when its distance relative to the centre pixel is within
    a tolerance (OutlierRemovalTolerance), and the pixel is kept only when enough of its neighbours
    are inliers (OutlierRemovalThreshold); the other pixels are set invalid. Here the distance is
    the depth z: neighbour ``n`` is an inlier of centre ``c`` iff both are valid and
    ``|z_n - z_c| <= rel_tolerance * |z_c|`` (float64). Pixels on the image border have fewer
    neighbours (the missing ones are not inliers).

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud, camera optical frame (metres); NaN (any non-finite coordinate) = invalid.
    min_inliers : int
        0..8; a valid pixel with fewer inlier neighbours is an outlier (0: no outliers).
    rel_tolerance : float
        >= 0, fraction of the centre's depth.

    Returns
    -------
    (H, W) bool ndarray
        True at the valid pixels with fewer than ``min_inliers`` inlier neighbours.
    """
    p = _window_params(min_inliers, rel_tolerance)
    a = as_cloud(xyz)
    z, _ = depth_plane(a, 1.0)
    out = np.empty(z.shape, dtype=bool)
    _window_kernel(z, p.min_inliers, p.rel_tolerance, out)
    return out


def window_outliers_reference(xyz: XYZ, *, min_inliers: int, rel_tolerance: float) -> Mask:
    """:func:`window_outliers` as eight shifted numpy comparisons (slow, obviously correct)."""
    p = _window_params(min_inliers, rel_tolerance)
    a = as_cloud(xyz)
    z, valid = depth_plane_reference(a, 1.0)
    H, W = z.shape
    padded = np.full((H + 2, W + 2), np.nan)
    padded[1:H + 1, 1:W + 1] = z
    count = np.zeros((H, W), dtype=np.int64)
    with np.errstate(over="ignore", invalid="ignore"):  # huge depths: inf, as in the kernel
        lim = p.rel_tolerance * np.abs(z)
        for dr, dc in _NEIGHBOURS_8:
            zn = padded[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
            count += np.abs(zn - z) <= lim
    return valid & (count < p.min_inliers)


def window_stage(xyz: XYZ, *, params: WindowParams) -> Mask:
    """:func:`window_outliers` with the parameters of a :class:`~zcut.params.WindowParams`."""
    if not isinstance(params, WindowParams):
        raise ParameterError(f"params must be a WindowParams, got {type(params).__name__}")
    return window_outliers(xyz, min_inliers=params.min_inliers, rel_tolerance=params.rel_tolerance)


# --------------------------------------------------------------------------------------------
# mixed pixels: the angle between the viewing ray and the surface
# --------------------------------------------------------------------------------------------
def _mixed_params(min_angle_deg: object) -> MixedPixelParams:
    return MixedPixelParams(min_angle_deg=plain_number(min_angle_deg))


def grazing_cos2(min_angle_deg: float) -> float:
    """cos² of the threshold angle: a segment d from point p is grazing iff
    ``(p·d)² > cos2 · (|p|² · |d|²)`` (its angle to the ray through p is below the threshold)."""
    c = math.cos(math.radians(min_angle_deg))
    return c * c


@nb.njit(cache=True, nogil=True, inline="always")
def _grazing(row, j, px, py, pz, pp, cos2):  # type: ignore[no-untyped-def]  # numba kernel
    # (valid, grazing) of the segment from p to pixel j of the row
    if not valid_at(row, j):
        return False, False
    dx = np.float64(row[j, 0]) - px
    dy = np.float64(row[j, 1]) - py
    dz = np.float64(row[j, 2]) - pz
    dot = (px * dx + py * dy) + pz * dz
    dd = (dx * dx + dy * dy) + dz * dz
    return True, dot * dot > cos2 * (pp * dd)


@nb.njit(cache=True, nogil=True)
def _mixed_kernel_scalar(a, cos2, r, c):  # type: ignore[no-untyped-def]  # numba kernel
    # the rule for one pixel (image border: fewer neighbours)
    H, W = a.shape[0], a.shape[1]
    row = a[r]
    px = np.float64(row[c, 0])
    py = np.float64(row[c, 1])
    pz = np.float64(row[c, 2])
    if not px * 0.0 + py * 0.0 + pz * 0.0 == 0.0:  # invalid
        return False
    pp = (px * px + py * py) + pz * pz
    flagged = False
    for axis in range(2):
        seen = False
        grazing = True
        for s in range(-1, 2, 2):
            rr = r + s * (axis == 1)
            cc = c + s * (axis == 0)
            if 0 <= rr < H and 0 <= cc < W:
                ok, g = _grazing(a[rr], cc, px, py, pz, pp, cos2)
                seen = seen or ok
                grazing = grazing and (g or not ok)
        flagged = flagged or (seen and grazing)
    return flagged


@nb.njit(cache=True, nogil=True, inline="always")
def _graze(xq, yq, zq, vq, px, py, pz, pp, cos2):  # type: ignore[no-untyped-def]  # numba kernel
    # (valid, grazing or invalid) of the segment from p to q, without a branch
    dx = xq - px
    dy = yq - py
    dz = zq - pz
    dot = (px * dx + py * dy) + pz * dz
    dd = (dx * dx + dy * dy) + dz * dz
    return vq, (dot * dot > cos2 * (pp * dd)) | (not vq)


@nb.njit(cache=True, nogil=True)
def _mixed_kernel(a, cos2, out):  # type: ignore[no-untyped-def]  # numba kernel
    # inner pixels from float64 row buffers (three rows in a ring), straight-line code the compiler
    # vectorizes; the image border one pixel at a time
    H, W = a.shape[0], a.shape[1]
    X = np.empty((3, W))
    Y = np.empty((3, W))
    Z = np.empty((3, W))
    V = np.empty((3, W), np.bool_)
    for r in range(H):
        if r == 0:
            for k in range(min(2, H)):
                row = a[k]
                for c in range(W):
                    X[k, c], Y[k, c], Z[k, c] = row[c, 0], row[c, 1], row[c, 2]
                    V[k, c] = X[k, c] * 0.0 + Y[k, c] * 0.0 + Z[k, c] * 0.0 == 0.0
        elif r + 1 < H:
            k = (r + 1) % 3
            row = a[r + 1]
            for c in range(W):
                X[k, c], Y[k, c], Z[k, c] = row[c, 0], row[c, 1], row[c, 2]
                V[k, c] = X[k, c] * 0.0 + Y[k, c] * 0.0 + Z[k, c] * 0.0 == 0.0
        o = out[r]
        if r == 0 or r == H - 1 or W < 3:
            for c in range(W):
                o[c] = _mixed_kernel_scalar(a, cos2, r, c)
            continue
        xu, yu, zu, vu = X[(r - 1) % 3], Y[(r - 1) % 3], Z[(r - 1) % 3], V[(r - 1) % 3]
        xm, ym, zm, vm = X[r % 3], Y[r % 3], Z[r % 3], V[r % 3]
        xd, yd, zd, vd = X[(r + 1) % 3], Y[(r + 1) % 3], Z[(r + 1) % 3], V[(r + 1) % 3]
        for c in range(1, W - 1):
            px, py, pz = xm[c], ym[c], zm[c]
            pp = (px * px + py * py) + pz * pz
            vl, gl = _graze(xm[c - 1], ym[c - 1], zm[c - 1], vm[c - 1], px, py, pz, pp, cos2)
            vr, gr = _graze(xm[c + 1], ym[c + 1], zm[c + 1], vm[c + 1], px, py, pz, pp, cos2)
            vt, gt = _graze(xu[c], yu[c], zu[c], vu[c], px, py, pz, pp, cos2)
            vb, gb = _graze(xd[c], yd[c], zd[c], vd[c], px, py, pz, pp, cos2)
            o[c] = vm[c] & (((vl | vr) & gl & gr) | ((vt | vb) & gt & gb))
        o[0] = _mixed_kernel_scalar(a, cos2, r, 0)
        o[W - 1] = _mixed_kernel_scalar(a, cos2, r, W - 1)


def mixed_pixel_outliers(xyz: XYZ, *, min_angle_deg: float) -> Mask:
    """Mixed pixels: points the surface through them is seen at a grazing angle, on both sides.

    At a depth discontinuity a pixel's footprint covers both surfaces and a time-of-flight or
    structured-light sensor returns a depth in between: a "mixed pixel" floating in the gap, on its
    own viewing ray. ifm's O3R cameras remove them with an angular threshold, the minimum angle
    between the surface tangent and the viewing ray (``mixedPixelThresholdRad``); laser scanners'
    shadow (veil) filters and the jump-edge filters compared by Tang, Huber and Akinci (3DIM 2007)
    test the same angle between the ray and the segment to a neighbour, and PCL's ShadowPoints
    thresholds the angle between the normal and the ray.

    Here, with p the point of a valid pixel (the ray runs from the camera at the origin through p)
    and d = q - p the segment to a valid 4-neighbour q, the segment is grazing iff its angle to the
    ray is below ``min_angle_deg``: ``(p·d)² > cos²(min_angle) · (|p|² · |d|²)`` in float64 (dot
    products summed as (x + y) + z). The pixel is a mixed pixel iff, along the row or along the
    column, it has a valid neighbour and the segments to all of its valid neighbours on that axis
    are grazing: the surface leaves it along the ray on both sides. A real edge pixel, which keeps
    a non-grazing neighbour on its own surface, stays; a surface seen at less than the angle
    everywhere goes, by design.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud, camera optical frame (metres); NaN (any non-finite coordinate) = invalid.
    min_angle_deg : float
        0..90 degrees (0: no outliers).

    Returns
    -------
    (H, W) bool ndarray
        True at the mixed pixels.
    """
    p = _mixed_params(min_angle_deg)
    a = as_cloud(xyz)
    out = np.zeros(a.shape[:2], dtype=bool)
    if p.min_angle_deg == 0.0:
        return out
    _mixed_kernel(a, grazing_cos2(p.min_angle_deg), out)
    return out


def mixed_pixel_outliers_reference(xyz: XYZ, *, min_angle_deg: float) -> Mask:
    """:func:`mixed_pixel_outliers` with shifted numpy arrays (slow, obviously correct)."""
    p = _mixed_params(min_angle_deg)
    a = as_cloud(xyz)
    H, W = a.shape[:2]
    valid = np.isfinite(a).all(axis=2)
    if p.min_angle_deg == 0.0:
        return np.zeros((H, W), dtype=bool)
    cos2 = grazing_cos2(p.min_angle_deg)
    P = np.where(valid[..., None], a.astype(np.float64), np.nan)
    padded = np.full((H + 2, W + 2, 3), np.nan)
    padded[1:H + 1, 1:W + 1] = P
    px, py, pz = P[..., 0], P[..., 1], P[..., 2]
    flagged = np.zeros((H, W), dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: inf, as in the kernel
        pp = (px * px + py * py) + pz * pz
        for axis_steps in (((0, -1), (0, 1)), ((-1, 0), (1, 0))):
            seen = np.zeros((H, W), dtype=bool)
            all_grazing = np.ones((H, W), dtype=bool)
            for dr, dc in axis_steps:
                Q = padded[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
                ok = np.isfinite(Q).all(axis=2) & valid
                dx, dy, dz = Q[..., 0] - px, Q[..., 1] - py, Q[..., 2] - pz
                dot = (px * dx + py * dy) + pz * dz
                dd = (dx * dx + dy * dy) + dz * dz
                grazing = dot * dot > cos2 * (pp * dd)
                seen |= ok
                all_grazing &= ~ok | grazing
            flagged |= seen & all_grazing
    return flagged & valid


def mixed_pixel_stage(xyz: XYZ, *, params: MixedPixelParams) -> Mask:
    """:func:`mixed_pixel_outliers` with the parameters of a :class:`~zcut.params.MixedPixelParams`."""
    if not isinstance(params, MixedPixelParams):
        raise ParameterError(f"params must be a MixedPixelParams, got {type(params).__name__}")
    return mixed_pixel_outliers(xyz, min_angle_deg=params.min_angle_deg)
