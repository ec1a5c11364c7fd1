"""An edge-aware local surface model: each pixel's distance to the surfaces fitted on each side of an edge.

Where no part model is known, the only surfaces are the measured ones. A surface *continued* across
a depth discontinuity (a window's median, the linear continuation of the pixels on one side) reads
a part's real edge as off the surface: the window holds the floor below as well as the part's top,
and the top's last pixels stand millimetres above their mixture. Here the surfaces are fitted on
each side separately:

- **Patches.** Around every valid pixel q, the valid points of its (2r+1) × (2r+1) window that
  lie on q's side of any edge (their depth within k · footprint · tan(``max_incidence_deg``) +
  ``side_step_mm`` of q's, k pixels away; the footprint z / f with f estimated from the frame's
  adjacent points) — at least ``min_patch_px`` of them (r = ``patch_radius_px``) — get a
  least-squares plane in 3D (centroid and the eigenvector of the smallest eigenvalue of their
  covariance); the patch's residual is the RMS distance of its points to that plane. A ring two
  pixels wide (a nut's top) thus has patches of its own.
- **Surfaces.** A patch is a surface when its points fit one plane: a window that still straddles
  a depth discontinuity (a small step, flying pixels between the sides) or a rough spot does not.
  No plane fits points on a line (a column of mixed pixels at one depth). The threshold is the frame's own: ``fit_k`` × the median patch
  residual of the frame (the median being a smooth patch's), scaled by the square of the patch's
  depth over the frame's as a depth sensor's noise is (at least ``min_fit_mm``). A patch
  seen at grazing incidence (its normal more than ``max_incidence_deg`` from the viewing ray) is
  not a surface either: the mixed pixels of a step form such a steep "ramp" of their own.
- **Distance.** A pixel's distance is its distance to the nearest plane among the surfaces whose
  window does not hold it (centres farther than r, within ``search_radius_px``; the radius doubles
  up to ``max_search_radius_px`` while none is found, +inf past that). Leaving the pixel out of
  every plane that judges it keeps an outlier from explaining itself; an inlier at a part's edge
  is explained by the patches inside the part, a flying pixel between the part and the floor by
  neither side.

The sign (:func:`signed_edge_distance`) is toward the camera: the plane's normal is turned to face
the camera at the origin. Limits: a smooth blob at least 4 pixels across (an interreflection
ghost) is a surface of its own; a smooth steep "curtain" the sensor measured where a part overhangs
is one too; a surface curved over the search radius is approximated by planes
(the nearest patch, 2 px away, extrapolates least).

:func:`edge_aware_distance` and :func:`signed_edge_distance` are numba kernels;
:func:`signed_edge_distance_reference` is the same with plain loops and ``np.linalg.eigh`` (the
tests' oracle). :func:`edge_surfaces` fits the patches once and :meth:`EdgeSurfaces.distance`
measures only the pixels asked for (the suspects ask for the few whose gap it gives: the fits cost
~0.3 CPU-s per 1920 × 1200 frame, 2.1 M closed-form eigen solves, all needed for the frame's median
fit gate). The fitting pass keeps of each patch only what the surface test needs (its rms, depth and
incidence: 17 bytes a pixel instead of 56); a distance fits again the planes of the surfaces it reads,
once each (~40 k of 1.6 M on a zinc-nut frame). Its kernels repeat the previous ones' arithmetic in
the same order (the reach and the gate's median from the same samples, one plane routine for both
passes), so the surfaces and planes are the same bit for bit (``tests/zcut/test_suspects_fast.py``
checks them against the previous kernels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from .cloud import check_mask, check_xyz
from .errors import InputShapeError, ParameterError
from .params import _number
from .types import XYZ, Mask


@dataclass(frozen=True, slots=True)
class EdgeSurfaceParams:
    """Parameters of :func:`edge_aware_distance`.

    Attributes
    ----------
    patch_radius_px : int
        Half-size of a patch (1-8): planes are fitted to (2r+1) × (2r+1) windows. 1: a 3 × 3 patch
        fits on a nut's ring a few pixels wide.
    min_patch_px : int
        Valid points a patch needs (3 to (2r+1)²). 6 of 9.
    search_radius_px : int
        Patch centres within this many pixels (Chebyshev) of a pixel judge it (> patch_radius_px). 3.
    max_search_radius_px : int
        The search radius doubles while no surface is found, up to this (>= search_radius_px). 12.
    fit_k : float
        A patch is a surface when its RMS residual is at most ``fit_k`` × the frame's median patch
        residual, both taken relative to the square of the depth (> 0). 3.
    min_fit_mm : float
        ... and in any case up to this many mm (>= 0). 0.05.
    max_incidence_deg : float
        A patch whose normal makes more than this angle with its viewing ray is not a surface
        (0 < angle <= 90; 90: no such limit). 80.
    side_step_mm : float
        A patch holds only its centre's side of an edge: the points of its window whose depth differs
        from the centre's by at most k × footprint × tan(max_incidence_deg) + side_step_mm, k pixels
        away (>= 0). 1 mm.
    """

    patch_radius_px: int = 1
    min_patch_px: int = 6
    search_radius_px: int = 3
    max_search_radius_px: int = 12
    fit_k: float = 3.0
    min_fit_mm: float = 0.05
    max_incidence_deg: float = 80.0
    side_step_mm: float = 1.0

    def __post_init__(self) -> None:
        _number(self, "patch_radius_px", ge=1, le=8, integer=True)
        side = (2 * self.patch_radius_px + 1) ** 2
        _number(self, "min_patch_px", ge=3, le=side, integer=True)
        _number(self, "search_radius_px", ge=self.patch_radius_px + 1, le=256, integer=True)
        _number(self, "max_search_radius_px", ge=self.search_radius_px, le=4096, integer=True)
        _number(self, "fit_k", gt=0.0)
        _number(self, "min_fit_mm", ge=0.0)
        _number(self, "max_incidence_deg", gt=0.0, le=90.0)
        _number(self, "side_step_mm", ge=0.0)
        for name in ("patch_radius_px", "min_patch_px", "search_radius_px", "max_search_radius_px"):
            object.__setattr__(self, name, int(getattr(self, name)))
        for name in ("fit_k", "min_fit_mm", "max_incidence_deg", "side_step_mm"):
            object.__setattr__(self, name, float(getattr(self, name)))


# ---------------------------------------------------------------------------------------------- kernels

@numba.njit(cache=True)
def _smallest_eigvec(c00, c01, c02, c11, c12, c22):  # type: ignore[no-untyped-def]  # numba kernel
    """(λ_min, nx, ny, nz) of a symmetric 3 × 3 matrix (closed form); nx = NaN when the vector is
    undetermined (the two smallest eigenvalues equal: points on a line or one point)."""
    q = (c00 + c11 + c22) / 3.0
    p1 = c01 * c01 + c02 * c02 + c12 * c12
    p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
    if p2 <= 0.0:
        return q, np.nan, np.nan, np.nan
    p = math.sqrt(p2 / 6.0)
    b00 = (c00 - q) / p
    b11 = (c11 - q) / p
    b22 = (c22 - q) / p
    b01 = c01 / p
    b02 = c02 / p
    b12 = c12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(max(r, -1.0), 1.0)
    phi = math.acos(r) / 3.0
    lam = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    # rows of A - λI; the eigenvector is the largest cross product of two of them
    a0x, a0y, a0z = c00 - lam, c01, c02
    a1x, a1y, a1z = c01, c11 - lam, c12
    a2x, a2y, a2z = c02, c12, c22 - lam
    v0x, v0y, v0z = a0y * a1z - a0z * a1y, a0z * a1x - a0x * a1z, a0x * a1y - a0y * a1x
    v1x, v1y, v1z = a0y * a2z - a0z * a2y, a0z * a2x - a0x * a2z, a0x * a2y - a0y * a2x
    v2x, v2y, v2z = a1y * a2z - a1z * a2y, a1z * a2x - a1x * a2z, a1x * a2y - a1y * a2x
    n0 = v0x * v0x + v0y * v0y + v0z * v0z
    n1 = v1x * v1x + v1y * v1y + v1z * v1z
    n2 = v2x * v2x + v2y * v2y + v2z * v2z
    if n1 > n0 and n1 >= n2:
        v0x, v0y, v0z, n0 = v1x, v1y, v1z, n1
    elif n2 > n0:
        v0x, v0y, v0z, n0 = v2x, v2y, v2z, n2
    scale = (c00 + c11 + c22) ** 2
    if not n0 > 1e-9 * scale:
        return lam, np.nan, np.nan, np.nan
    s = 1.0 / math.sqrt(n0)
    return lam, v0x * s, v0y * s, v0z * s


# the fast path (issue 32): the same arithmetic in the same order as the kernels above and the numpy
# of _reach and _surfaces, without their whole-frame temporaries; the nearest surface only where asked

@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _reach_samples(xyz, valid):  # type: ignore[no-untyped-def]  # numba kernel
    """The finite |dx| / |z| of the row-adjacent valid pairs, then |dy| / |z| of the column-adjacent
    ones (what :func:`_reach` takes the median of)."""
    H, W = valid.shape
    out = np.empty(2 * H * W)
    m = 0
    for i in range(H):
        for j in range(W - 1):
            if valid[i, j] and valid[i, j + 1]:
                v = abs(xyz[i, j + 1, 0] - xyz[i, j, 0]) / abs(xyz[i, j, 2])
                if np.isfinite(v):
                    out[m] = v
                    m += 1
    for i in range(H - 1):
        for j in range(W):
            if valid[i, j] and valid[i + 1, j]:
                v = abs(xyz[i + 1, j, 1] - xyz[i, j, 1]) / abs(xyz[i, j, 2])
                if np.isfinite(v):
                    out[m] = v
                    m += 1
    return out[:m]


@numba.njit(cache=True, error_model="numpy", inline="always")  # IEEE division, as the numpy it replaces
def _patch_moments(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz):  # type: ignore[no-untyped-def]  # numba kernel
    """Pixel (i, j)'s patch (the pixels within its reach): (n, mx, my, mz, c00, c01, c02, c11, c12, c22),
    its centroid and covariance divided by n as :func:`_smallest_eigvec` takes it (n < min_px: not fitted,
    the rest 0). Shared by :func:`_fit_at` and the suspects' bracketed eigenvalues
    (:mod:`zcut.suspects.surfaces`). ``px``, ``py``, ``pz``: scratch of (2r+1)² values."""
    H, W = valid.shape
    zq = xyz[i, j, 2]
    reach = abs(zq) * per_px * tan
    n = 0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for a in range(max(i - r, 0), min(i + r + 1, H)):
        for b in range(max(j - r, 0), min(j + r + 1, W)):
            if valid[a, b]:
                z = xyz[a, b, 2]
                if abs(z - zq) <= max(abs(a - i), abs(b - j)) * reach + floor:
                    x = xyz[a, b, 0]
                    y = xyz[a, b, 1]
                    px[n] = x
                    py[n] = y
                    pz[n] = z
                    n += 1
                    sx += x
                    sy += y
                    sz += z
    if n < min_px:
        return n, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx = sx / n
    my = sy / n
    mz = sz / n
    c00 = 0.0
    c01 = 0.0
    c02 = 0.0
    c11 = 0.0
    c12 = 0.0
    c22 = 0.0
    for k in range(n):
        dx = px[k] - mx
        dy = py[k] - my
        dz = pz[k] - mz
        c00 += dx * dx
        c01 += dx * dy
        c02 += dx * dz
        c11 += dy * dy
        c12 += dy * dz
        c22 += dz * dz
    return n, mx, my, mz, c00 / n, c01 / n, c02 / n, c11 / n, c12 / n, c22 / n


@numba.njit(cache=True, error_model="numpy", inline="always")  # IEEE division, as the numpy it replaces
def _fit_at(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz):  # type: ignore[no-untyped-def]  # numba kernel
    """The plane of pixel (i, j)'s patch: (fitted, λ_min, mx, my, mz, nx, ny, nz), the normal facing the
    camera; the arithmetic of :func:`zcut.suspects._reference._patch_kernel` (the previous kernel) in its
    order, with the reach computed in place. ``px``, ``py``, ``pz``: scratch of (2r+1)² values."""
    n, mx, my, mz, c00, c01, c02, c11, c12, c22 = _patch_moments(xyz, valid, i, j, r, min_px, per_px, tan, floor,
                                                                 px, py, pz)
    if n < min_px:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    lam, nx, ny, nz = _smallest_eigvec(c00, c01, c02, c11, c12, c22)
    if not np.isfinite(nx):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if nx * mx + ny * my + nz * mz > 0.0:  # face the camera at the origin
        nx, ny, nz = -nx, -ny, -nz
    return True, lam, mx, my, mz, nx, ny, nz


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _patch_gate_kernel(xyz, valid, r, min_px, per_px, tan, floor, cos_max, rms, z2, steep, ratios):  # type: ignore[no-untyped-def]  # numba kernel
    """Every patch's fit, kept only as what the surface test needs: rms (NaN: no plane), the squared
    depth of its centroid, whether its incidence exceeds the limit (``steep``), and the ratios rms / z²
    of the fitted patches with z² > 0 in raster order (what :func:`_surfaces` takes the median of; their
    count is returned). The planes themselves are fitted again where a distance needs them
    (:class:`EdgeSurfaces`): the same arithmetic, so the same planes."""
    H, W = valid.shape
    side = (2 * r + 1) * (2 * r + 1)
    px = np.empty(side)
    py = np.empty(side)
    pz = np.empty(side)
    m = 0
    for i in range(H):
        for j in range(W):
            rms[i, j] = np.nan
            z2[i, j] = 0.0
            steep[i, j] = False
            if not valid[i, j]:
                continue
            fitted, lam, mx, my, mz, nx, ny, nz = _fit_at(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz)
            if not fitted:
                continue
            s = math.sqrt(max(lam, 0.0))
            rms[i, j] = s
            zz = mz ** 2
            z2[i, j] = zz
            if zz > 0:
                ratios[m] = s / zz
                m += 1
            norm = math.sqrt(mx * mx + my * my + mz * mz)
            cos_inc = abs(mx / norm * nx + my / norm * ny + mz / norm * nz)
            steep[i, j] = not cos_inc >= cos_max
    return m


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _surfaces_kernel(rms, z2, steep, min_fit, gate_k, any_angle, ok):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = rms.shape
    for i in range(H):
        for j in range(W):
            zz = z2[i, j]
            ok[i, j] = (np.isfinite(rms[i, j]) and zz > 0 and rms[i, j] <= max(min_fit, gate_k * zz)
                        and (any_angle or not steep[i, j]))


@numba.njit(cache=True, inline="always")
def _append_plane(planes, slot, count, a, b, mx, my, mz, nx, ny, nz):  # type: ignore[no-untyped-def]  # numba kernel
    """Append the plane of surface (a, b) (centroid, normal) to ``planes`` (``count[0]`` rows so far; room
    for one more), its row into ``slot[a, b]``; return the row. :func:`_fit_into` and :func:`_decide`
    both keep a plane this way."""
    s = count[0]
    planes[s, 0] = mx
    planes[s, 1] = my
    planes[s, 2] = mz
    planes[s, 3] = nx
    planes[s, 4] = ny
    planes[s, 5] = nz
    slot[a, b] = s
    count[0] = s + 1
    return s


@numba.njit(cache=True, error_model="numpy", inline="always")  # IEEE division, as the numpy it replaces
def _fit_into(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz, slot, planes, count):  # type: ignore[no-untyped-def]  # numba kernel
    """Append the plane of surface (a, b) (:func:`_fit_at`: centroid, normal) to ``planes`` (``count[0]``
    of them so far), its row in ``slot[a, b]``; return the row."""
    _, _, mx, my, mz, nx, ny, nz = _fit_at(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz)
    return _append_plane(planes, slot, count, a, b, mx, my, mz, nx, ny, nz)


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _fit_surfaces(xyz, valid, surface, r, min_px, per_px, tan, floor, slot, planes, count):  # type: ignore[no-untyped-def]  # numba kernel
    """The planes of every surface not fitted yet."""
    H, W = surface.shape
    side = (2 * r + 1) * (2 * r + 1)
    px = np.empty(side)
    py = np.empty(side)
    pz = np.empty(side)
    for a in range(H):
        for b in range(W):
            if surface[a, b] and slot[a, b] < 0:
                _fit_into(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz, slot, planes, count)


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _decide(xyz, valid, a, b, r, min_px, per_px, tan, floor, gate_k, min_fit, cos_max, any_angle, state, slot, planes,  # type: ignore[no-untyped-def]  # numba kernel
            count, px, py, pz):
    """Whether patch (a, b) is a surface (:func:`_patch_gate_kernel` then :func:`_surfaces_kernel`, for one
    patch: the suspects' lazy surfaces, :mod:`zcut.suspects.surfaces`): ``state[a, b]`` 1 and its plane
    into ``planes`` (which has room for one more, :func:`_grown`), its row into ``slot[a, b]``, when it
    is; ``state[a, b]`` 0 when not. Returns ``state[a, b]``."""
    state[a, b] = 0
    if not valid[a, b]:
        return 0
    fitted, lam, mx, my, mz, nx, ny, nz = _fit_at(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz)
    if not fitted:
        return 0
    s = math.sqrt(max(lam, 0.0))
    zz = mz ** 2
    norm = math.sqrt(mx * mx + my * my + mz * mz)
    cos_inc = abs(mx / norm * nx + my / norm * ny + mz / norm * nz)
    steep = not cos_inc >= cos_max
    ok = np.isfinite(s) and zz > 0 and s <= max(min_fit, gate_k * zz) and (any_angle or not steep)
    if not ok:
        return 0
    _append_plane(planes, slot, count, a, b, mx, my, mz, nx, ny, nz)
    state[a, b] = 1
    return 1


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _fit_once(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz, slot, planes, count):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_fit_into` as a call of its own: the search's rare first read, kept out of its inner loop
    (inlined there, it cost the loop 10-25 % on 1920 x 1200 frames)."""
    return _fit_into(xyz, valid, a, b, r, min_px, per_px, tan, floor, px, py, pz, slot, planes, count)


@numba.njit(cache=True)
def _grown(planes, t, more):  # type: ignore[no-untyped-def]  # numba kernel
    """``planes`` (``t`` rows filled) with room for at least ``more`` rows more: its rows in an array of
    max(2 t + 64, t + more)."""
    grown = np.empty((max(2 * t + 64, t + more), 6))
    grown[:t] = planes[:t]
    return grown


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as the numpy it replaces
def _nearest_search(xyz, valid, rows, cols, r, min_px, per_px, tan, floor, gate_k, min_fit, cos_max, any_angle, radius,  # type: ignore[no-untyped-def]  # numba kernel
                    max_radius, state, slot, planes, count, out):
    """:func:`zcut.suspects._reference._nearest_kernel` (the previous kernel) at the pixels (rows[k], cols[k])
    only: out[k]. ``state`` per patch: 1 a surface, 0 not, 2 not decided yet; ``slot``: the row of a
    surface's plane in ``planes``, -1 when not fitted yet. What a patch's first read does follows:

    - a surface not fitted yet (:class:`EdgeSurfaces`, where every patch is decided: ``state`` is the
      surface mask as int8): its plane is fitted (:func:`_fit_into`);
    - a patch not decided yet (the suspects' lazy surfaces, :mod:`zcut.suspects.surfaces`): it is tested
      against the gate ``gate_k``, ``min_fit``, ``cos_max``, ``any_angle`` (:func:`_decide`, which keeps
      a surface's plane).

    Returns ``planes`` (grown when it filled up)."""
    H, W = valid.shape
    side = (2 * r + 1) * (2 * r + 1)
    qx = np.empty(side)
    qy = np.empty(side)
    qz = np.empty(side)
    ring = (2 * max_radius + 1) * (2 * max_radius + 1)  # the most patches one pixel's search reads
    for k in range(rows.size):
        i = rows[k]
        j = cols[k]
        px = xyz[i, j, 0]
        py = xyz[i, j, 1]
        pz = xyz[i, j, 2]
        if count[0] + ring > planes.shape[0]:  # room for every plane this pixel's search may add
            planes = _grown(planes, count[0], ring)
        R = radius
        best = np.inf
        signed = np.inf
        while True:
            for a in range(max(i - R, 0), min(i + R + 1, H)):
                for b in range(max(j - R, 0), min(j + R + 1, W)):
                    if abs(a - i) <= r and abs(b - j) <= r:
                        continue
                    s = state[a, b]
                    if s != 1:
                        if s == 0:
                            continue
                        # not decided yet
                        if _decide(xyz, valid, a, b, r, min_px, per_px, tan, floor, gate_k, min_fit, cos_max,
                                   any_angle, state, slot, planes, count, qx, qy, qz) != 1:
                            continue
                    t = slot[a, b]
                    if t < 0:  # a surface not fitted yet
                        t = _fit_once(xyz, valid, a, b, r, min_px, per_px, tan, floor, qx, qy, qz, slot, planes, count)
                    d = (planes[t, 3] * (px - planes[t, 0]) + planes[t, 4] * (py - planes[t, 1])
                         + planes[t, 5] * (pz - planes[t, 2]))
                    if abs(d) < best:
                        best = abs(d)
                        signed = d
            if best < np.inf or R >= max_radius:
                break
            R = min(2 * R, max_radius)
        out[k] = signed
    return planes


def _median_of_temporary(x: np.ndarray) -> float:
    """``np.median`` of a 1-D float array the caller no longer needs (partitioned in place: no copy).
    The same value: the middle order statistic, or the mean of the two middle ones as ``np.mean``
    takes it; NaN when any is NaN."""
    n = x.size
    if n == 0 or np.isnan(x).any():
        return float("nan")
    h = n // 2
    if n % 2:
        x.partition(h)
        return float(x[h])
    x.partition((h - 1, h))
    return float((x[h - 1] + x[h]) / 2.0)


# ---------------------------------------------------------------------------------------------- API

def _check_args(xyz_mm: object, valid: object, params: object) -> tuple[np.ndarray, Mask, EdgeSurfaceParams]:
    a = check_xyz(xyz_mm, name="xyz_mm")  # type: ignore[arg-type]
    valid = check_mask(valid, name="valid", shape=a.shape[:2])
    if params is None:
        params = EdgeSurfaceParams()
    if not isinstance(params, EdgeSurfaceParams):
        raise ParameterError(f"params must be an EdgeSurfaceParams, got {type(params).__name__}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    finite = np.isfinite(a).all(axis=2)
    if (valid & ~finite).any():
        raise InputShapeError("valid must hold only pixels whose three coordinates are finite "
                              f"({int((valid & ~finite).sum())} valid pixels have NaN or inf)")
    return a, np.ascontiguousarray(valid), params


def _reach(a: np.ndarray, valid: Mask, params: EdgeSurfaceParams) -> np.ndarray:
    """Per pixel, how much farther (mm) a point one pixel away may lie along the ray and still be on
    the pixel's side: its footprint (z / f, f the frame's focal length in pixels, estimated from its
    adjacent points) × tan(max_incidence_deg)."""
    pairs = []
    for d0, d1 in ((0, 1), (1, 0)):
        p = a[: a.shape[0] - d0, : a.shape[1] - d1]
        q = a[d0:, d1:]
        both = valid[: a.shape[0] - d0, : a.shape[1] - d1] & valid[d0:, d1:]
        if both.any():
            pairs.append(np.abs(q[..., d0][both] - p[..., d0][both]) / np.abs(p[..., 2][both]))
    step = np.concatenate(pairs) if pairs else np.zeros(0)
    step = step[np.isfinite(step)]
    per_px = float(np.median(step)) if step.size else 0.0  # 1 / f
    tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
    reach: np.ndarray = np.ascontiguousarray(np.where(valid, np.abs(a[..., 2]) * per_px * tan, 0.0))
    return reach


def _surfaces(rms: np.ndarray, nrm: np.ndarray, cen: np.ndarray, params: EdgeSurfaceParams) -> Mask:
    """The patches that are surfaces: residual within the frame's gate, incidence within the limit.

    The gate grows with the square of the depth, as a depth sensor's noise does: fit_k × the median
    over the frame of rms / z², × z² of the patch (at least min_fit_mm)."""
    z2 = cen[..., 2] ** 2
    have = np.isfinite(rms) & (z2 > 0)
    if not have.any():
        return have
    with np.errstate(invalid="ignore", divide="ignore"):
        gate = np.maximum(params.min_fit_mm, params.fit_k * float(np.median(rms[have] / z2[have])) * z2)
        ray = cen / np.linalg.norm(cen, axis=2, keepdims=True)
        cos_inc = np.abs((ray * nrm).sum(axis=2))
    cos_max = math.cos(math.radians(params.max_incidence_deg))
    ok: Mask = have & (rms <= gate) & ((cos_inc >= cos_max) | (params.max_incidence_deg >= 90.0))
    return ok


class EdgeSurfaces:
    """The surfaces of one frame (:func:`edge_surfaces`): which patches are surfaces; :meth:`distance`
    measures pixels against their planes, fitted again (the same arithmetic, so the same planes) only
    where a measured pixel may reach them, once each."""

    __slots__ = ("_xyz", "_valid", "_params", "_per_px", "_tan", "surface", "_slot", "_planes", "_count")

    def __init__(self, xyz_mm: np.ndarray, valid: Mask, params: EdgeSurfaceParams, surface: Mask, per_px: float,
                 tan: float) -> None:
        self._xyz, self._valid, self._params = xyz_mm, valid, params
        self._per_px, self._tan = per_px, tan
        self.surface = surface
        self._slot = np.full(surface.shape, -1, np.int32)  # row of each fitted surface's plane in _planes
        self._planes = np.empty((int(surface.sum()), 6))  # centroid, normal; touched only as far as filled
        self._count = np.zeros(1, np.int64)

    @property
    def centre(self) -> np.ndarray:
        """(H, W, 3) float64: each surface's centroid (mm; 0 where not a surface)."""
        return self._all_planes()[0]

    @property
    def normal(self) -> np.ndarray:
        """(H, W, 3) float64: each surface's unit normal, facing the camera (0 where not a surface)."""
        return self._all_planes()[1]

    def _all_planes(self) -> tuple[np.ndarray, np.ndarray]:
        p = self._params
        _fit_surfaces(self._xyz, self._valid, self.surface, p.patch_radius_px, p.min_patch_px, self._per_px, self._tan,
                      p.side_step_mm, self._slot, self._planes, self._count)
        cen = np.zeros((*self.surface.shape, 3))
        nrm = np.zeros((*self.surface.shape, 3))
        cen[self.surface] = self._planes[self._slot[self.surface], :3]
        nrm[self.surface] = self._planes[self._slot[self.surface], 3:]
        return cen, nrm

    def distance(self, where: Mask | None = None) -> np.ndarray:
        """Signed distance (mm) of the valid pixels (of those in ``where`` too, when given) to the
        nearest surface: :func:`signed_edge_distance`'s values there, NaN elsewhere."""
        at = self._valid if where is None else self._valid & check_mask(where, name="where", shape=self._valid.shape)
        rows, cols = np.nonzero(at)
        d = np.empty(rows.size)
        p = self._params
        # the surface mask's bytes as the search's state (1 a surface, 0 not; never 2: nothing to decide)
        self._planes = _nearest_search(self._xyz, self._valid, rows, cols, p.patch_radius_px, p.min_patch_px,
                                       self._per_px, self._tan, p.side_step_mm, 0.0, 0.0, 0.0, False,
                                       p.search_radius_px, p.max_search_radius_px, self.surface.view(np.int8),
                                       self._slot, self._planes, self._count, d)
        out = np.full(at.shape, np.nan)
        out[rows, cols] = d
        return out


def edge_surfaces(xyz_mm: XYZ, valid: Mask, *, params: EdgeSurfaceParams | None = None) -> EdgeSurfaces:
    """The patches and surfaces of a frame (the module docstring says how), to measure pixels against
    with :meth:`EdgeSurfaces.distance` (all of them: :func:`signed_edge_distance`).

    The numba kernels do the arithmetic of the previous ones in the same order (the reach and the
    gate's median from the same samples, the planes from the same points), so the surfaces are the
    same bit for bit (``tests/zcut/test_suspects_fast.py``).
    """
    a, valid, params = _check_args(xyz_mm, valid, params)
    return _edge_surfaces(a, valid, params)


def _edge_surfaces(a: np.ndarray, valid: Mask, params: EdgeSurfaceParams) -> EdgeSurfaces:
    """:func:`edge_surfaces` of checked arguments: ``a`` C-contiguous float64, finite where ``valid``
    (C-contiguous too)."""
    H, W = valid.shape
    rms = np.empty((H, W))
    z2 = np.empty((H, W))
    steep = np.empty((H, W), bool)
    ratios = np.empty(H * W)
    step = _reach_samples(a, valid)
    per_px = _median_of_temporary(step) if step.size else 0.0  # 1 / f
    del step
    tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
    m = _patch_gate_kernel(a, valid, params.patch_radius_px, params.min_patch_px, per_px, tan, params.side_step_mm,
                           math.cos(math.radians(params.max_incidence_deg)), rms, z2, steep, ratios)
    surface = np.zeros((H, W), bool)
    if m:
        gate_k = params.fit_k * _median_of_temporary(ratios[:m])
        _surfaces_kernel(rms, z2, steep, params.min_fit_mm, gate_k, params.max_incidence_deg >= 90.0, surface)
    return EdgeSurfaces(a, valid, params, surface, per_px, tan)


def signed_edge_distance(xyz_mm: XYZ, valid: Mask, *, params: EdgeSurfaceParams | None = None) -> np.ndarray:
    """Signed distance (mm, positive = toward the camera) of every valid pixel to the nearest surface
    fitted on one side of an edge (the module docstring says how).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud in millimetres, camera frame (the camera at the origin), NaN invalid.
    valid : (H, W) bool ndarray
        The pixels to judge and to fit from; every one must be finite.
    params : EdgeSurfaceParams, optional

    Returns
    -------
    (H, W) float64 ndarray
        NaN where not valid; +inf where no surface lies within ``max_search_radius_px``.
    """
    return edge_surfaces(xyz_mm, valid, params=params).distance()


def edge_aware_distance(xyz_mm: XYZ, valid: Mask, *, params: EdgeSurfaceParams | None = None) -> np.ndarray:
    """Distance (mm) of every valid pixel to the nearest surface fitted on one side of an edge.

    ``abs`` of :func:`signed_edge_distance` (same parameters): NaN where not valid, +inf where no
    surface lies within ``max_search_radius_px``.
    """
    out: np.ndarray = np.abs(signed_edge_distance(xyz_mm, valid, params=params))
    return out


def signed_edge_distance_reference(xyz_mm: XYZ, valid: Mask, *, params: EdgeSurfaceParams | None = None
                                   ) -> np.ndarray:
    """:func:`signed_edge_distance` as plain loops with ``np.linalg.eigh`` (slow; the tests' oracle)."""
    a, valid, params = _check_args(xyz_mm, valid, params)
    H, W = valid.shape
    r = params.patch_radius_px
    cen = np.zeros((H, W, 3))
    nrm = np.zeros((H, W, 3))
    rms = np.full((H, W), np.nan)
    reach = _reach(a, valid, params)
    rows, cols = np.mgrid[0:H, 0:W]
    for i in range(H):
        for j in range(W):
            if not valid[i, j]:
                continue
            win = (slice(max(i - r, 0), i + r + 1), slice(max(j - r, 0), j + r + 1))
            cheb = np.maximum(np.abs(rows[win] - i), np.abs(cols[win] - j))
            side = valid[win] & (np.abs(a[win][..., 2] - a[i, j, 2]) <= cheb * reach[i, j] + params.side_step_mm)
            pts = a[win][side]
            if len(pts) < params.min_patch_px:
                continue
            m = pts.mean(axis=0)
            w, v = np.linalg.eigh((pts - m).T @ (pts - m) / len(pts))
            if not w[1] - w[0] > 1e-6 * max(w[2], 1e-300):  # a line or a point: no plane
                continue
            n = v[:, 0] if m @ v[:, 0] <= 0 else -v[:, 0]
            cen[i, j], nrm[i, j], rms[i, j] = m, n, math.sqrt(max(w[0], 0.0))
    surface = _surfaces(rms, nrm, cen, params)
    out = np.full((H, W), np.nan)
    for i, j in zip(*np.nonzero(valid)):
        R = params.search_radius_px
        while True:
            best = np.inf
            for a_ in range(max(i - R, 0), min(i + R + 1, H)):
                for b in range(max(j - R, 0), min(j + R + 1, W)):
                    if (abs(a_ - i) <= r and abs(b - j) <= r) or not surface[a_, b]:
                        continue
                    d = float(nrm[a_, b] @ (a[i, j] - cen[a_, b]))
                    if abs(d) < abs(best):
                        best = d
            if np.isfinite(best) or R >= params.max_search_radius_px:
                break
            R = min(2 * R, params.max_search_radius_px)
        out[i, j] = best
    return out
