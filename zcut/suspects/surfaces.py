"""The edge-aware surfaces as the suspects use them: the frame's gate from brackets, the surfaces only where read.

:func:`zcut.edge_surface.edge_surfaces` solves every patch's 3 × 3 eigenproblem (2.1 M closed-form
solves per 1920 × 1200 frame, ~0.2 CPU-s of its ~0.3) for two things: the frame's gate (the median
over every fitted patch of rms / z²) and which patches are surfaces. The suspects read the surfaces
only around the pixels whose gap the edge-aware distance gives (a few % of the frame), so
:func:`lazy_surfaces` gives the same surfaces, planes and distances bit for bit with less work:

- **The gate's median from brackets.** Each patch's covariance is summed exactly as
  :func:`zcut.edge_surface._fit_at` sums it (the same points, the same order, so the same matrix);
  its smallest eigenvalue is then found by Newton's method on the characteristic polynomial from
  below (a few multiply-adds, no ``acos`` / ``cos``; a row's patches take four steps each without a
  branch, in the processor's vector lanes, as do their covariances, and only those the checks then
  reject iterate further) and bracketed: the polynomial's sign is checked on both sides of the bracket, and the
  closed form's own rounding (:func:`_smallest_eigvec`, well conditioned when the two smallest
  eigenvalues are apart, which is also checked) lies well inside it. Where a check fails (a patch on a line, one point, a tie of eigenvalues, anything not finite),
  the closed form itself is evaluated, as it is for a patch whose λ_min is at the rounding level (a
  flat patch of quantized depth: no bracket would tell those apart). The median is then found
  exactly (:func:`_gate_median`): it lies between the k-th smallest lower end and the k-th smallest
  upper end of the brackets, the patches whose bracket lies wholly outside that window are counted,
  and only the others are solved in closed form (2 of 1.66 M on a 1920 × 1200 zinc-nut frame).
- **Surfaces on demand.** A patch's surface test (its rms, depth and incidence against the gate) and
  its plane are computed the first time a distance reads it (:class:`LazySurfaces`), with
  :func:`zcut.edge_surface._fit_at`: the same arithmetic as the whole-frame pass.

``tests/zcut/test_suspects_fast.py`` checks the gate, the surfaces and the distances against
:func:`zcut.edge_surface.edge_surfaces` on synthetic, ray-traced and real frames and random fields.
"""

from __future__ import annotations

import math
import threading

import numba
import numpy as np

from ..edge_surface import (
    EdgeSurfaceParams,
    _decide,
    _grown,
    _nearest_search,
    _patch_moments,
    _reach_samples,
    _smallest_eigvec,
)
from ..errors import ZcutError
from ..sor_workspace import SorWorkspace
from ..types import Mask
from .select import kth_of_both, median, order_pair

# the brackets (tr: the covariance's trace). Newton's method stops when its step is at most
# _NEWTON_TOL · tr (its error is then ~ step² / (λ2 - λ1), well below _CHECK · tr); the characteristic
# polynomial's sign is checked at ± _CHECK · tr of its root, where |det| ~ _CHECK · tr · m exceeds 30 ×
# its rounding (~ 6 ε tr³) when the minors' sum m of C - λI, ~ (λ2 - λ1)(λ3 - λ1), is at least
# _MIN_MINORS · tr²; then the two smallest eigenvalues are at least _MIN_MINORS · tr apart and the
# closed form's rounding is below ~5e-14 · tr (its acos is ill-conditioned only as they meet), so
# the closed form's λ lies within ± _MARGIN · tr of Newton's root
_NEWTON_TOL = 1e-7
_NEWTON_MAX = 60
_CHECK = 1e-12
_MARGIN = 2e-12
_MIN_MINORS = 0.04
# λ_min below _TINY · tr: a bracket of ± _MARGIN · tr would not tell the ratios apart; solved directly
_TINY = 1e-9
# a patch is surely fitted (the closed form's normal determined) when m² / 3 (n0 >= m² / 3, its largest
# cross product of rows of C - λI) exceeds _FITTED_SAFETY × the closed form's threshold 1e-9 · tr², and
# surely not when m² (n0 <= m²) is below it / _FITTED_SAFETY
_FITTED_SAFETY = 100.0
# the fixed Newton steps of the whole-frame pass (:func:`_newton_fixed`): the others take :func:`_lambda_bracket`'s
# loop. Patches left to it, of 1.71 M fitted on the bench's black nuts / 1.86 M ray-traced: 76 k / 321 k with
# 3 steps, 24 k / 93 k with 4, 9 k / 49 k with 5; the gate's CPU ms, 3 → 4 steps: ray-traced 95 → 81, the
# real Kinect scans 17-26 → 11-19, the hand-made frames within ±2 %; 5 steps were no faster than 4
_FIXED_STEPS = 4
# the memo of the closed form's values (:func:`_keep_patch`): 2^_MEMO_BITS slots, a direct-mapped table
# (measured on the bench's quantized spheres: 96 % of the closed-form patches found with 4,096 slots)
_MEMO_BITS = 12
_MEMO_MIX = np.uint64(0x9E3779B97F4A7C15)


@numba.njit(cache=True, error_model="numpy", inline="always")  # IEEE division, as _fit_at
def _cov_at(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`zcut.edge_surface._fit_at` up to its eigenproblem: (n, mz, c00, c01, c02, c11, c12, c22), the
    covariance divided by n as it is passed to :func:`_smallest_eigvec` (n < min_px: not fitted)."""
    n, _, _, mz, c00, c01, c02, c11, c12, c22 = _patch_moments(xyz, valid, i, j, r, min_px, per_px, tan, floor,
                                                               px, py, pz)
    return n, mz, c00, c01, c02, c11, c12, c22


@numba.njit(cache=True, inline="always")
def _charpoly(c00, c01, c02, c11, c12, c22, lam):  # type: ignore[no-untyped-def]  # numba kernel
    """det(C - λI) and the sum of the principal 2 × 2 minors of C - λI (= -d det / dλ)."""
    d0 = c00 - lam
    d1 = c11 - lam
    d2 = c22 - lam
    m12 = d1 * d2 - c12 * c12
    det = d0 * m12 - c01 * (c01 * d2 - c12 * c02) + c02 * (c01 * c12 - d1 * c02)
    return det, m12 + (d0 * d2 - c02 * c02) + (d0 * d1 - c01 * c01)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _certified(c00, c01, c02, c11, c12, c22, tr, lam):  # type: ignore[no-untyped-def]  # numba kernel
    """(ok, lo, hi, fitted) of :func:`_lambda_bracket` for ``lam``, a value Newton's method reached from below
    λ_min: the bracket [lo, hi] and whether the normal is determined when the checks make both certain;
    ok = False otherwise. The checks hold wherever ``lam`` lies: a sign change of the characteristic
    polynomial within ± _CHECK · tr of it (a wrong sign through rounding only within ~3e-14 · tr of an
    end, inside the margin) with its minors' sum m >= _MIN_MINORS · tr² (a lone root, λ_min's)."""
    det_lo, _ = _charpoly(c00, c01, c02, c11, c12, c22, lam - _CHECK * tr)
    det_hi, m = _charpoly(c00, c01, c02, c11, c12, c22, lam + _CHECK * tr)
    # a root between, and λ_2 - λ_1 >= m / (λ_3 - λ_1) >= _MIN_MINORS · tr (λ_3 - λ_1 <= ~tr)
    if not (det_lo > 0.0 and det_hi < 0.0 and m >= _MIN_MINORS * tr * tr):
        return False, 0.0, 0.0, False
    # the normal: the closed form's largest cross product n0 ~ m² · max_k v_k² lies in [m² / 3, m²]
    need = 1e-9 * tr * tr
    if m * m / 3.0 > _FITTED_SAFETY * need:
        fitted = True
    elif m * m < need / _FITTED_SAFETY:
        fitted = False
    else:
        return False, 0.0, 0.0, False
    return True, lam - _MARGIN * tr, lam + _MARGIN * tr, fitted


@numba.njit(cache=True, error_model="numpy", inline="always")
def _lambda_bracket(c00, c01, c02, c11, c12, c22):  # type: ignore[no-untyped-def]  # numba kernel
    """(ok, lo, hi, fitted): a bracket [lo, hi] of the λ_min :func:`_smallest_eigvec` returns for this
    matrix, and whether its normal is determined, when both are certain; ok = False otherwise."""
    tr = c00 + c11 + c22
    if not (np.isfinite(tr) and tr > 0.0):
        return False, 0.0, 0.0, False
    lam = -_CHECK * tr  # below λ_min (the covariance is positive semi-definite up to rounding)
    m = 0.0
    converged = False
    for _ in range(_NEWTON_MAX):
        det, m = _charpoly(c00, c01, c02, c11, c12, c22, lam)
        if not m > 0.0:
            break
        step = det / m
        lam += step
        if lam < _TINY * tr:  # λ_min at the closed form's rounding (a flat patch of quantized depth): no bracket
            break
        if abs(step) <= _NEWTON_TOL * tr:
            converged = True
            break
    if not converged:
        return False, 0.0, 0.0, False
    return _certified(c00, c01, c02, c11, c12, c22, tr, lam)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _newton_fixed(c00, c01, c02, c11, c12, c22):  # type: ignore[no-untyped-def]  # numba kernel
    """(sane, tr, lam): _FIXED_STEPS steps of :func:`_lambda_bracket`'s Newton's method, without a branch
    (the row's patches then overlap in the processor); ``sane``: every step had m > 0, the trace is
    finite and positive, and λ_min is not at the rounding level (>= _TINY · tr), else ``lam`` is not to
    be used (:func:`_lambda_bracket` decides)."""
    tr = c00 + c11 + c22
    lam = -_CHECK * tr
    sane = np.isfinite(tr) & (tr > 0.0)
    for _ in range(_FIXED_STEPS):
        det, m = _charpoly(c00, c01, c02, c11, c12, c22, lam)
        sane = sane & (m > 0.0)
        lam += det / m
    return sane & (lam >= _TINY * tr), tr, lam


@numba.njit(cache=True, error_model="numpy")
def _row_certified(k, c0, c1, c2, c3, c4, c5, mz, ok, rlo, rhi, fitted):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_newton_fixed` then :func:`_certified` of the first ``k`` patches of a row (their covariance
    entries c00, c01, c02, c11, c12, c22 and centroid depths ``mz``), without a branch, so that the
    processor runs neighbouring patches in its vector lanes: ``ok[q]`` where both would give a bracket
    [l0, l1], and then ``fitted`` theirs and the bracket of the ratio rms / z² as :func:`_ratio_brackets`
    takes it, sqrt(max(l0, 0)) / z² and sqrt(max(l1, 0)) / z² (``rlo``, ``rhi``: the same arithmetic; the
    other entries hold whatever, the caller takes :func:`_lambda_bracket`'s way)."""
    for q in range(k):
        c00, c01, c02, c11, c12, c22 = c0[q], c1[q], c2[q], c3[q], c4[q], c5[q]
        tr = c00 + c11 + c22
        lam = -_CHECK * tr
        sane = np.isfinite(tr) & (tr > 0.0)
        for _ in range(_FIXED_STEPS):
            det, m = _charpoly(c00, c01, c02, c11, c12, c22, lam)
            sane = sane & (m > 0.0)
            lam += det / m
        sane = sane & (lam >= _TINY * tr)
        det_lo, _ = _charpoly(c00, c01, c02, c11, c12, c22, lam - _CHECK * tr)
        det_hi, m = _charpoly(c00, c01, c02, c11, c12, c22, lam + _CHECK * tr)
        need = 1e-9 * tr * tr
        yes = m * m / 3.0 > _FITTED_SAFETY * need
        no = m * m < need / _FITTED_SAFETY
        ok[q] = sane & (det_lo > 0.0) & (det_hi < 0.0) & (m >= _MIN_MINORS * tr * tr) & (yes | no)
        fitted[q] = yes
        zz = mz[q] ** 2
        rlo[q] = math.sqrt(max(lam - _MARGIN * tr, 0.0)) / zz
        rhi[q] = math.sqrt(max(lam + _MARGIN * tr, 0.0)) / zz


@numba.njit(cache=True, error_model="numpy")
def _planar_row(xyz, valid, a, s, X, Y, Z, V):  # type: ignore[no-untyped-def]  # numba kernel
    """Row ``a`` of the frame into slot ``s`` of the row ring: its x, y, z and valid flags, each contiguous."""
    for b in range(valid.shape[1]):
        X[s, b] = xyz[a, b, 0]
        Y[s, b] = xyz[a, b, 1]
        Z[s, b] = xyz[a, b, 2]
        V[s, b] = valid[a, b]


@numba.njit(cache=True, error_model="numpy")  # IEEE division (n = 0 gives NaN here, then is skipped)
def _row_moments(i, r, per_px, tan, floor, W, X, Y, Z, V, zq, reach, sel, nn, mx, my, mz, c0, c1, c2, c3, c4, c5):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`zcut.edge_surface._patch_moments` of the patches of row ``i`` at columns r .. W - r - 1 (entry
    t: column r + t), all at once so that the processor runs neighbouring patches in its vector lanes: n
    (as a float), the centroid and the covariance divided by n, whatever n (the caller skips n < min_px).

    The same arithmetic in the same order: a point not in the patch (not valid, or beyond its centre's
    reach) adds +0.0 to each sum instead of being skipped, and that changes no sum, which starts at +0.0
    and so never is -0.0 (x + +0.0 = x for every x but -0.0). ``X``, ``Y``, ``Z``, ``V``: the ring of
    2r + 1 rows (:func:`_planar_row`, row a in slot a % (2r + 1)); ``sel``: scratch of (2r + 1)² × W."""
    L = 2 * r + 1
    cs = i % L
    m = W - 2 * r
    zc = Z[cs, r:W - r]
    for t in range(m):
        z = zc[t]
        zq[t] = z
        reach[t] = abs(z) * per_px * tan
        nn[t] = 0.0
        mx[t] = 0.0
        my[t] = 0.0
        mz[t] = 0.0
    k = 0
    for da in range(-r, r + 1):
        s = (i + da) % L
        for db in range(-r, r + 1):
            cheb = float(max(abs(da), abs(db)))
            xs = X[s, r + db:W - r + db]
            ys = Y[s, r + db:W - r + db]
            zs = Z[s, r + db:W - r + db]
            vs = V[s, r + db:W - r + db]
            sk = sel[k]
            for t in range(m):
                z = zs[t]
                ok = vs[t] & (abs(z - zq[t]) <= cheb * reach[t] + floor)
                sk[t] = ok
                nn[t] += 1.0 if ok else 0.0
                mx[t] += xs[t] if ok else 0.0
                my[t] += ys[t] if ok else 0.0
                mz[t] += z if ok else 0.0
            k += 1
    for t in range(m):
        n = nn[t]
        mx[t] = mx[t] / n
        my[t] = my[t] / n
        mz[t] = mz[t] / n
        c0[t] = 0.0
        c1[t] = 0.0
        c2[t] = 0.0
        c3[t] = 0.0
        c4[t] = 0.0
        c5[t] = 0.0
    k = 0
    for da in range(-r, r + 1):
        s = (i + da) % L
        for db in range(-r, r + 1):
            xs = X[s, r + db:W - r + db]
            ys = Y[s, r + db:W - r + db]
            zs = Z[s, r + db:W - r + db]
            sk = sel[k]
            for t in range(m):
                ok = sk[t]
                dx = xs[t] - mx[t]
                dy = ys[t] - my[t]
                dz = zs[t] - mz[t]
                c0[t] += dx * dx if ok else 0.0
                c1[t] += dx * dy if ok else 0.0
                c2[t] += dx * dz if ok else 0.0
                c3[t] += dy * dy if ok else 0.0
                c4[t] += dy * dz if ok else 0.0
                c5[t] += dz * dz if ok else 0.0
            k += 1
    for t in range(m):
        n = nn[t]
        c0[t] = c0[t] / n
        c1[t] = c1[t] / n
        c2[t] = c2[t] / n
        c3[t] = c3[t] / n
        c4[t] = c4[t] / n
        c5[t] = c5[t] / n


@numba.njit(cache=True, error_model="numpy", inline="always")
def _point_sums(v, x, y, z, zq, limit, n, sx, sy, sz):  # type: ignore[no-untyped-def]  # numba kernel
    """One point of :func:`_row_moments_r1`'s first pass: (in the patch, n, Σx, Σy, Σz) after it."""
    ok = v & (abs(z - zq) <= limit)
    return ok, n + (1.0 if ok else 0.0), sx + (x if ok else 0.0), sy + (y if ok else 0.0), sz + (z if ok else 0.0)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _point_products(ok, x, y, z, mx, my, mz, c0, c1, c2, c3, c4, c5):  # type: ignore[no-untyped-def]  # numba kernel
    """One point of :func:`_row_moments_r1`'s second pass: the six sums of products after it."""
    dx = x - mx
    dy = y - my
    dz = z - mz
    return (c0 + (dx * dx if ok else 0.0), c1 + (dx * dy if ok else 0.0), c2 + (dx * dz if ok else 0.0),
            c3 + (dy * dy if ok else 0.0), c4 + (dy * dz if ok else 0.0), c5 + (dz * dz if ok else 0.0))


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as _row_moments
def _row_moments_r1(i, per_px, tan, floor, W, X, Y, Z, V, nn, mz, c0, c1, c2, c3, c4, c5):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_row_moments` for r = 1 (the default patch): n, the centroid depth and the covariance of
    each patch of row ``i`` (entry t: column t + 1), its nine points unrolled, every sum held in a
    register (the general kernel keeps its sums in arrays, one pass over the row per point).

    The same arithmetic in the same order: the points in rows i - 1, i, i + 1 and, in each, columns
    t, t + 1, t + 2 (the general kernel's order of (da, db)), each sum starting at +0.0, a point not
    in the patch adding +0.0, and the reach's bound cheb · reach + floor with cheb 1.0 or 0.0 (the
    centre), as the general kernel computes it."""
    sa = (i - 1) % 3
    sb = i % 3
    sc = (i + 1) % 3
    xa, ya, za, va = X[sa], Y[sa], Z[sa], V[sa]
    xb, yb, zb, vb = X[sb], Y[sb], Z[sb], V[sb]
    xc, yc, zc, vc = X[sc], Y[sc], Z[sc], V[sc]
    for t in range(W - 2):
        zq = zb[t + 1]
        reach = abs(zq) * per_px * tan
        side = 1.0 * reach + floor
        centre = 0.0 * reach + floor
        n = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        k0, n, sx, sy, sz = _point_sums(va[t], xa[t], ya[t], za[t], zq, side, n, sx, sy, sz)
        k1, n, sx, sy, sz = _point_sums(va[t + 1], xa[t + 1], ya[t + 1], za[t + 1], zq, side, n, sx, sy, sz)
        k2, n, sx, sy, sz = _point_sums(va[t + 2], xa[t + 2], ya[t + 2], za[t + 2], zq, side, n, sx, sy, sz)
        k3, n, sx, sy, sz = _point_sums(vb[t], xb[t], yb[t], zb[t], zq, side, n, sx, sy, sz)
        k4, n, sx, sy, sz = _point_sums(vb[t + 1], xb[t + 1], yb[t + 1], zb[t + 1], zq, centre, n, sx, sy, sz)
        k5, n, sx, sy, sz = _point_sums(vb[t + 2], xb[t + 2], yb[t + 2], zb[t + 2], zq, side, n, sx, sy, sz)
        k6, n, sx, sy, sz = _point_sums(vc[t], xc[t], yc[t], zc[t], zq, side, n, sx, sy, sz)
        k7, n, sx, sy, sz = _point_sums(vc[t + 1], xc[t + 1], yc[t + 1], zc[t + 1], zq, side, n, sx, sy, sz)
        k8, n, sx, sy, sz = _point_sums(vc[t + 2], xc[t + 2], yc[t + 2], zc[t + 2], zq, side, n, sx, sy, sz)
        mx = sx / n
        my = sy / n
        m = sz / n
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        s0, s1, s2, s3, s4, s5 = _point_products(k0, xa[t], ya[t], za[t], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k1, xa[t + 1], ya[t + 1], za[t + 1], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k2, xa[t + 2], ya[t + 2], za[t + 2], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k3, xb[t], yb[t], zb[t], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k4, xb[t + 1], yb[t + 1], zb[t + 1], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k5, xb[t + 2], yb[t + 2], zb[t + 2], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k6, xc[t], yc[t], zc[t], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k7, xc[t + 1], yc[t + 1], zc[t + 1], mx, my, m, s0, s1, s2, s3, s4, s5)
        s0, s1, s2, s3, s4, s5 = _point_products(k8, xc[t + 2], yc[t + 2], zc[t + 2], mx, my, m, s0, s1, s2, s3, s4, s5)
        nn[t] = n
        mz[t] = m
        c0[t] = s0 / n
        c1[t] = s1 / n
        c2[t] = s2 / n
        c3[t] = s3 / n
        c4[t] = s4 / n
        c5[t] = s5 / n


@numba.njit(cache=True, inline="always")
def _memo_slot(c00, c01, c02, c11, c12, c22, key, bits):  # type: ignore[no-untyped-def]  # numba kernel
    """The covariance's bits into ``bits`` (a uint64 view of ``key``) and its slot in the memo of
    :func:`_keep_patch` (a multiplicative hash of the six words, its top _MEMO_BITS bits)."""
    key[0] = c00
    key[1] = c01
    key[2] = c02
    key[3] = c11
    key[4] = c12
    key[5] = c22
    h = np.uint64(0)
    for q in range(6):
        h = (h ^ bits[q]) * _MEMO_MIX
    h = (h ^ (h >> np.uint64(29))) * _MEMO_MIX
    return int(h >> np.uint64(64 - _MEMO_BITS))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _bracket_or_solve(c00, c01, c02, c11, c12, c22, memo):  # type: ignore[no-untyped-def]  # numba kernel
    """(ok, l0, l1, fitted, λ_min, normal determined): :func:`_lambda_bracket`'s bracket when it gives one
    (ok), else the closed form's values, from the memo when this covariance is in it (a covariance is
    put there only after :func:`_lambda_bracket` failed for it, and both depend on its bits alone)."""
    ok, l0, l1, fitted = _lambda_bracket(c00, c01, c02, c11, c12, c22)
    if ok:
        return True, l0, l1, fitted, 0.0, False
    words, values, key, bits = memo
    slot = _memo_slot(c00, c01, c02, c11, c12, c22, key, bits)
    hit = words[slot, 6] == 1
    for q in range(6):
        hit = hit and words[slot, q] == bits[q]
    if hit:
        return False, l0, l1, fitted, values[slot, 0], values[slot, 1] == 1.0
    lam, nx, _, _ = _smallest_eigvec(c00, c01, c02, c11, c12, c22)
    det = bool(np.isfinite(nx))
    for q in range(6):
        words[slot, q] = bits[q]
    words[slot, 6] = 1
    values[slot, 0] = lam
    values[slot, 1] = 1.0 if det else 0.0
    return False, l0, l1, fitted, lam, det


@numba.njit(cache=True, error_model="numpy")
def _keep_patch(c00, c01, c02, c11, c12, c22, zz, ok, l0, l1, fitted, rlo, rhi, pos, lo, hi, at, m, memo):  # type: ignore[no-untyped-def]  # numba kernel
    """One fitted patch of :func:`_ratio_brackets` (covariance, z², and what certifying it gave: ``ok``,
    [l0, l1], ``fitted``, the ratio's bracket [rlo, rhi] when ``ok``): its ratio's bracket into lo[m],
    hi[m], at[m] = ``pos`` when it has one (:func:`_lambda_bracket` where the certificate failed, the
    closed form where that fails too). Returns (m, solved: 1 when the closed form's value was taken, nan).

    ``memo`` = (words, values, key, bits): the closed form's (λ_min, normal determined) of the last
    covariances it was evaluated for, one per slot of :func:`_memo_slot` (``words[s, :6]`` the
    covariance's bits, ``words[s, 6]`` 1 when the slot is filled). Both functions depend on the
    covariance's bits alone, so a covariance found there (the same six words) gives the values they
    would: :func:`_lambda_bracket` failed for it, and the closed form returned these. A frame of
    quantized depth repeats a few flat patches' covariances (the bench's spheres: 1.16 M of 1.86 M
    patches at the rounding level, 36,395 distinct covariances)."""
    lam, det = 0.0, False
    if not ok:
        ok, l0, l1, fitted, lam, det = _bracket_or_solve(c00, c01, c02, c11, c12, c22, memo)
        rlo = math.sqrt(max(l0, 0.0)) / zz
        rhi = math.sqrt(max(l1, 0.0)) / zz
    if ok:
        if not fitted or not zz > 0:
            return m, 0, False
        lo[m] = rlo
        hi[m] = rhi
        at[m] = pos
        return m + 1, 0, False
    if not det or not zz > 0:
        return m, 1, False
    v = math.sqrt(max(lam, 0.0)) / zz
    lo[m] = v
    hi[m] = v
    at[m] = pos
    return m + 1, 1, bool(np.isnan(v))


@numba.njit(cache=True, error_model="numpy")
def _row_settle(k, idx, c0, c1, c2, c3, c4, c5, mz, good, rlo, rhi, fitted, memo):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_keep_patch`'s way for the row's patches idx[:k] whose certificate failed (entries of
    :func:`_row_certified`'s arrays): :func:`_lambda_bracket`'s bracket, else the closed form's value
    (from the memo when there), into ``rlo``, ``rhi`` and ``fitted`` (the normal determined), and
    ``good`` set, so that the row's loop takes them as certified. One call a row, the loop apart
    from the row's: the one-by-one work stays out of the row's loop. Returns (solved, nan: a kept
    ratio is NaN), as :func:`_keep_patch` counts them.

    :func:`_bracket_or_solve` written out, the memo's arrays unpacked once a row: called per patch (an inline
    function given the memo's arrays, most likely a reference taken and released per array and patch) it cost
    ~15 CPU ms more on the bench's quantized spheres (1.16 M patches settled). The same
    table, slots (:func:`_memo_slot`'s hash) and entries; ``tests/zcut/test_suspects_tenth.py`` checks the two
    against each other."""
    solved = 0
    nan = False
    words, values, key, bits = memo
    for u in range(k):
        q = idx[u]
        zz = mz[q] ** 2
        c00, c01, c02, c11, c12, c22 = c0[q], c1[q], c2[q], c3[q], c4[q], c5[q]
        ok, l0, l1, fit = _lambda_bracket(c00, c01, c02, c11, c12, c22)
        good[q] = True
        if ok:
            fitted[q] = fit
            rlo[q] = math.sqrt(max(l0, 0.0)) / zz
            rhi[q] = math.sqrt(max(l1, 0.0)) / zz
            continue
        # _memo_slot
        key[0] = c00
        key[1] = c01
        key[2] = c02
        key[3] = c11
        key[4] = c12
        key[5] = c22
        h = np.uint64(0)
        for w in range(6):
            h = (h ^ bits[w]) * _MEMO_MIX
        h = (h ^ (h >> np.uint64(29))) * _MEMO_MIX
        slot = int(h >> np.uint64(64 - _MEMO_BITS))
        # the memo's entry, else the closed form's values (into the memo)
        hit = words[slot, 6] == 1
        for w in range(6):
            hit = hit and words[slot, w] == bits[w]
        if hit:
            lam = values[slot, 0]
            det = values[slot, 1] == 1.0
        else:
            lam, nx, _, _ = _smallest_eigvec(c00, c01, c02, c11, c12, c22)
            det = bool(np.isfinite(nx))
            for w in range(6):
                words[slot, w] = bits[w]
            words[slot, 6] = 1
            values[slot, 0] = lam
            values[slot, 1] = 1.0 if det else 0.0
        solved += 1
        fitted[q] = det
        v = math.sqrt(max(lam, 0.0)) / zz
        rlo[q] = v
        rhi[q] = v
        nan = nan or (det and zz > 0 and np.isnan(v))
    return solved, nan


@numba.njit(cache=True, error_model="numpy")  # IEEE division, as _patch_gate_kernel
def _ratio_brackets(xyz, valid, r, min_px, per_px, tan, floor, lo, hi, at):  # type: ignore[no-untyped-def]  # numba kernel
    """For every fitted patch with z² > 0, in raster order, a bracket [lo, hi] of its rms / z² as
    :func:`zcut.edge_surface._patch_gate_kernel` computes it (lo = hi: solved in closed form here) and
    its pixel (``at``, i * W + j). Returns their count, the count solved, and whether a ratio is NaN.

    A row at least half measured, r or more from the border: its patches at once in vector lanes, their
    covariances (:func:`_row_moments`), then :func:`_row_certified` (Newton's fixed steps and the checks),
    and its 2r columns nearer the border one by one. The other rows: their fitted patches' covariances
    one by one (:func:`_cov_at`), compacted, then :func:`_row_certified`. Where certifying failed
    (:func:`_row_settle` for a row's, :func:`_keep_patch` for the border's): :func:`_lambda_bracket`, then the
    closed form (:func:`_bracket_or_solve`, with the memo of its values)."""
    H, W = valid.shape
    side = (2 * r + 1) * (2 * r + 1)
    px = np.empty(side)
    py = np.empty(side)
    pz = np.empty(side)
    # the vector path's row ring and per-column scratch (entry t: column r + t)
    L = 2 * r + 1
    vec = H > 2 * r and W > 2 * r
    X = np.empty((L, W))
    Y = np.empty((L, W))
    Z = np.empty((L, W))
    V = np.zeros((L, W), np.bool_)
    sel = np.empty((side, W), np.bool_)
    zq = np.empty(W)
    reach = np.empty(W)
    nn = np.empty(W)
    mx = np.empty(W)
    my = np.empty(W)
    mzs = np.empty(W)
    rc = np.empty((6, W))
    good = np.empty(W, np.bool_)
    fits = np.empty(W, np.bool_)
    rlos = np.empty(W)
    rhis = np.empty(W)
    cov = np.empty((7, W))  # the other rows' fitted patches: c00, c01, c02, c11, c12, c22, mz
    col = np.empty(W, np.int64)
    todo = np.empty(W, np.int64)
    key = np.empty(6)
    memo = (np.zeros((1 << _MEMO_BITS, 7), np.uint64), np.empty((1 << _MEMO_BITS, 2)), key, key.view(np.uint64))
    if vec:
        for a in range(2 * r):
            _planar_row(xyz, valid, a, a % L, X, Y, Z, V)
    m = 0
    solved = 0
    nan = False
    for i in range(H):
        inner = False
        if vec and r <= i < H - r:
            _planar_row(xyz, valid, i + r, (i + r) % L, X, Y, Z, V)
            nvalid = 0
            for j in range(W):
                nvalid += valid[i, j]
            # the lanes compute every column, the other way only the fitted patches: a row mostly
            # unmeasured takes the latter (the same values either way; measured on the bench's frame with
            # large invalid regions, 40 CPU ms either way, where a row of lanes everywhere took 69)
            inner = 2 * nvalid >= W
        if inner:
            if r == 1:
                _row_moments_r1(i, per_px, tan, floor, W, X, Y, Z, V, nn, mzs, rc[0], rc[1], rc[2], rc[3], rc[4], rc[5])
            else:
                _row_moments(i, r, per_px, tan, floor, W, X, Y, Z, V, zq, reach, sel, nn, mx, my, mzs,
                             rc[0], rc[1], rc[2], rc[3], rc[4], rc[5])
            _row_certified(W - 2 * r, rc[0], rc[1], rc[2], rc[3], rc[4], rc[5], mzs, good, rlos, rhis, fits)
            k = 0
            for t in range(W - 2 * r):  # the fitted patches the certificate failed, listed without a branch
                col[k] = t
                k += (not good[t]) & valid[i, r + t] & (nn[t] >= min_px)
            sv, nv = _row_settle(k, col, rc[0], rc[1], rc[2], rc[3], rc[4], rc[5], mzs, good, rlos, rhis, fits, memo)
            solved += sv
            nan = nan or nv
            for j in range(W):
                if not valid[i, j]:
                    continue
                if r <= j < W - r:
                    t = j - r
                    if nn[t] < min_px:
                        continue
                    # certified or settled: the row's bracket or value (_keep_patch's way, inline)
                    if fits[t] and mzs[t] ** 2 > 0:
                        lo[m] = rlos[t]
                        hi[m] = rhis[t]
                        at[m] = i * W + j
                        m += 1
                else:  # the columns near the border, one by one
                    n, mz, c00, c01, c02, c11, c12, c22 = _cov_at(xyz, valid, i, j, r, min_px, per_px, tan, floor,
                                                                  px, py, pz)
                    if n < min_px:
                        continue
                    zz = mz ** 2
                    ok, l0, l1, fitted = False, 0.0, 0.0, False
                    sane, tr, lam = _newton_fixed(c00, c01, c02, c11, c12, c22)
                    if sane:
                        ok, l0, l1, fitted = _certified(c00, c01, c02, c11, c12, c22, tr, lam)
                    m, sv, nv = _keep_patch(c00, c01, c02, c11, c12, c22, zz, ok, l0, l1, fitted,
                                            math.sqrt(max(l0, 0.0)) / zz, math.sqrt(max(l1, 0.0)) / zz, i * W + j,
                                            lo, hi, at, m, memo)
                    solved += sv
                    nan = nan or nv
            continue
        # the other rows: the fitted patches' covariances one by one, compacted, then certified in lanes
        k = 0
        for j in range(W):
            if not valid[i, j]:
                continue
            n, mz, c00, c01, c02, c11, c12, c22 = _cov_at(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz)
            if n < min_px:
                continue
            cov[0, k] = c00
            cov[1, k] = c01
            cov[2, k] = c02
            cov[3, k] = c11
            cov[4, k] = c12
            cov[5, k] = c22
            cov[6, k] = mz
            col[k] = j
            k += 1
        _row_certified(k, cov[0], cov[1], cov[2], cov[3], cov[4], cov[5], cov[6], good, rlos, rhis, fits)
        n_bad = 0
        for q in range(k):
            if not good[q]:
                todo[n_bad] = q
                n_bad += 1
        sv, nv = _row_settle(n_bad, todo, cov[0], cov[1], cov[2], cov[3], cov[4], cov[5], cov[6], good, rlos, rhis, fits,
                             memo)
        solved += sv
        nan = nan or nv
        for q in range(k):
            if fits[q] and cov[6, q] ** 2 > 0:
                lo[m] = rlos[q]
                hi[m] = rhis[q]
                at[m] = i * W + col[q]
                m += 1
    return m, solved, nan


@numba.njit(cache=True, error_model="numpy", inline="always")
def _window_block(xyz, valid, r, min_px, per_px, tan, floor, lo, hi, at, a, b, vals, k0, k1, px, py, pz, inside):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_window_exact`'s brackets ``k0 .. k1 - 1`` that meet the window: their ratios by the bracket when it
    is one value, else in closed form, those in it into ``vals`` from ``inside`` on. Returns (below, above,
    inside): those below or above the window by their ratio (added to the block's count of brackets)."""
    H, W = valid.shape
    below = 0
    above = 0
    for k in range(k0, k1):
        if (hi[k] < a) | (lo[k] > b):
            continue
        if lo[k] == hi[k]:
            v = lo[k]
        else:
            i = at[k] // W
            j = at[k] % W
            _, mz, c00, c01, c02, c11, c12, c22 = _cov_at(xyz, valid, i, j, r, min_px, per_px, tan, floor, px, py, pz)
            lam, _, _, _ = _smallest_eigvec(c00, c01, c02, c11, c12, c22)
            v = math.sqrt(max(lam, 0.0)) / mz ** 2
        if v < a:
            below += 1
        elif v > b:
            above += 1
        else:
            vals[inside] = v
            inside += 1
    return below, above, inside


@numba.njit(cache=True, error_model="numpy")
def _window_exact(xyz, valid, r, min_px, per_px, tan, floor, lo, hi, at, a, b, vals):  # type: ignore[no-untyped-def]  # numba kernel
    """Classify the ratios of :func:`_ratio_brackets` against the window [a, b]: (below, above, count
    in it), by their brackets where these decide, else by their closed-form value (the values in the
    window into ``vals``)."""
    H, W = valid.shape
    side = (2 * r + 1) * (2 * r + 1)
    px = np.empty(side)
    py = np.empty(side)
    pz = np.empty(side)
    below = 0
    above = 0
    inside = 0
    B = 1024
    for k0 in range(0, lo.size, B):
        k1 = min(k0 + B, lo.size)
        # a block's brackets counted without a branch, in vector lanes (a bracket is below the window about
        # half the time, at random; few are in it)
        n_in = 0
        for k in range(k0, k1):
            under = hi[k] < a
            over = lo[k] > b
            below += under
            above += over
            n_in += not (under | over)
        if n_in:
            bl, ab, inside = _window_block(xyz, valid, r, min_px, per_px, tan, floor, lo, hi, at, a, b, vals, k0, k1,
                                           px, py, pz, inside)
            below += bl
            above += ab
    return below, above, inside


# the reach's median (:func:`reach_median`): a pilot of every _PILOT_ROWS-th row's samples, and a window
# of its order statistics _PILOT_SHARE of the samples either side of the middle
_PILOT_ROWS = 16
_PILOT_SHARE = 0.03
# ... for frames whose samples' array (2 H W doubles) would exceed glibc's largest mmap threshold (32 MiB):
# below it the array comes from the heap (measured: 640 x 480 scans 2.2-4.3 CPU ms storing, 3.2-4.8 with
# the window; 1920 x 1200 frames 30-45 storing, 20-28 with the window)
_FRESH_BYTES = 32 << 20


@numba.njit(cache=True, error_model="numpy", inline="always")  # IEEE division, as _reach_samples
def _sample_x(xyz, i, j):  # type: ignore[no-untyped-def]  # numba kernel
    return abs(xyz[i, j + 1, 0] - xyz[i, j, 0]) / abs(xyz[i, j, 2])


@numba.njit(cache=True, error_model="numpy", inline="always")
def _sample_y(xyz, i, j):  # type: ignore[no-untyped-def]  # numba kernel
    return abs(xyz[i + 1, j, 1] - xyz[i, j, 1]) / abs(xyz[i, j, 2])


@numba.njit(cache=True, error_model="numpy")
def _reach_pilot(xyz, valid, every, out):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`zcut.edge_surface._reach_samples` of every ``every``-th row only (into ``out``; their count)."""
    H, W = valid.shape
    m = 0
    for i in range(0, H, every):
        for j in range(W - 1):
            if valid[i, j] and valid[i, j + 1]:
                v = _sample_x(xyz, i, j)
                if np.isfinite(v):
                    out[m] = v
                    m += 1
        if i < H - 1:
            for j in range(W):
                if valid[i, j] and valid[i + 1, j]:
                    v = _sample_y(xyz, i, j)
                    if np.isfinite(v):
                        out[m] = v
                        m += 1
    return m


@numba.njit(cache=True, error_model="numpy", inline="always")
def _tally_row(buf, m, a, b, vals, cap, inside):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_reach_window`'s tally of one row's samples ``buf[:m]`` (NaN where there is none): (finite, below a,
    equal to a, ``inside`` + strictly inside, equal to b), those strictly inside appended to ``vals`` from
    ``inside`` on (as many as fit in ``vals[:cap]``; ``vals[cap]`` takes the rest). Counts and stores without a
    branch on the values (half the samples fall below a, at random): the counts in the processor's vector lanes,
    then, when the row has samples inside, one store per sample at the next free entry, kept when inside."""
    n = 0
    below = 0
    n_a = 0
    n_in = 0
    n_b = 0
    for t in range(m):
        v = buf[t]
        fin = np.isfinite(v)  # an inf sample (|z| = 0) is left out, even at an end of the window
        n += fin
        below += v < a
        n_a += (v == a) & fin
        n_in += (v > a) & (v < b)
        n_b += (v == b) & fin
    if n_in:
        for t in range(m):
            v = buf[t]
            vals[min(inside, cap)] = v
            inside += (v > a) & (v < b)
    return n, below, n_a, inside, n_b


@numba.njit(cache=True, error_model="numpy")
def _reach_window(xyz, valid, a, b, vals):  # type: ignore[no-untyped-def]  # numba kernel
    """The samples of :func:`zcut.edge_surface._reach_samples` against the window [a, b] (a < b), without
    storing them: (count, below a, equal to a, strictly inside, equal to b), those strictly inside into
    ``vals[:-1]`` (as many as fit; the last entry is scratch), in the samples' order. The ends are counted
    apart: a quantized sensor's samples take few values. A row at a time: its samples (NaN where a pixel of
    the pair is not valid; a NaN or inf sample is counted nowhere, as it is left out) into a buffer, every
    pixel's computed (in vector lanes), then tallied (:func:`_tally_row`)."""
    H, W = valid.shape
    cap = vals.size - 1
    n = 0
    below = 0
    n_a = 0
    inside = 0
    n_b = 0
    buf = np.empty(W)
    for i in range(H):  # the row-adjacent pairs
        for j in range(W - 1):
            v = _sample_x(xyz, i, j)
            buf[j] = v if valid[i, j] & valid[i, j + 1] else np.nan
        c = _tally_row(buf, W - 1, a, b, vals, cap, inside)
        n += c[0]
        below += c[1]
        n_a += c[2]
        inside = c[3]
        n_b += c[4]
    for i in range(H - 1):  # the column-adjacent ones
        for j in range(W):
            v = _sample_y(xyz, i, j)
            buf[j] = v if valid[i, j] & valid[i + 1, j] else np.nan
        c = _tally_row(buf, W, a, b, vals, cap, inside)
        n += c[0]
        below += c[1]
        n_a += c[2]
        inside = c[3]
        n_b += c[4]
    return n, below, n_a, inside, n_b


def _window_rank(r: int, t: tuple[int, int, int, int, int], a: float, b: float, vals: np.ndarray) -> float | None:
    """The r-th smallest sample from :func:`_reach_window`'s tally, None when the window does not hold it."""
    _, below, n_a, inside, n_b = t
    r -= below
    if r < 0:
        return None
    if r < n_a:
        return a
    r -= n_a
    if r < inside:
        return None if inside > vals.size else order_pair(vals[:inside], r, r)[0]
    r -= inside
    return b if r < n_b else None


def reach_median(a: np.ndarray, valid: Mask) -> float:
    """``median(_reach_samples(a, valid))`` (0.0 without samples), the value
    :func:`zcut.edge_surface._edge_surfaces` takes for 1 / f, without the samples' array (26 MB at
    1920 × 1200, fresh pages every call): a pilot of every 16th row's samples gives a window of
    values around the median; one pass counts the samples below it and keeps those in it, and the
    median is selected among these when the window holds both middle ranks (else from every sample).
    The samples are >= +0.0 and finite, so their order is that of ``np.partition`` either way."""
    H, W = valid.shape
    if 2 * H * W * 8 <= _FRESH_BYTES:  # the samples' array comes from the heap: storing them is cheaper
        step = _reach_samples(a, valid)
        return median(step) if step.size else 0.0
    pilot = np.empty(2 * W * (-(-H // _PILOT_ROWS)))
    k = _reach_pilot(a, valid, _PILOT_ROWS, pilot)
    if k >= 64:
        pilot = pilot[:k]
        d = max(int(_PILOT_SHARE * k), 1)
        h = k // 2
        lo_v = order_pair(pilot, h - d, h - d)[0]
        hi_v = order_pair(pilot, h + d, h + d)[0]
        if not hi_v > lo_v:  # a quantized sensor: the pilot's middle is one value
            hi_v = float(np.nextafter(lo_v, np.inf))
        vals = np.empty(max(1 << 16, 2 * H * W // 16) + 1)  # the last entry: _reach_window's scratch
        n, below, n_a, inside, n_b = (int(v) for v in _reach_window(a, valid, lo_v, hi_v, vals))
        vals = vals[:-1]
        t = (n, below, n_a, inside, n_b)
        if n == 0:
            return 0.0
        h = n // 2
        x1 = _window_rank(h, t, lo_v, hi_v, vals)
        x0 = x1 if n % 2 else _window_rank(h - 1, t, lo_v, hi_v, vals)
        if x0 is not None and x1 is not None:
            return x1 if n % 2 else float((np.float64(x0) + np.float64(x1)) / 2.0)
    step = _reach_samples(a, valid)
    return median(step) if step.size else 0.0


#: the gate's arrays (:func:`_gate_median`: the brackets' ends and pixels, H · W each, ~55 MB at 1920 × 1200) are
#: kept between calls, one workspace per thread (:func:`gate_workspace`): made fresh each call, their pages were
#: faulted in afresh every call (docs/performance.md, the suspects' tenth round)
_GATE = threading.local()


#: what a thread's :func:`gate_workspace` keeps between calls at most (its ``max_bytes``): the three arrays of a
#: frame of up to ~5.5 M pixels (1920 × 1200: 55 MB); after a call on a larger frame it drops them
GATE_KEPT_BYTES = 128 << 20


def gate_workspace() -> SorWorkspace:
    """The calling thread's workspace of :func:`_gate_median`'s arrays when it is called on its own (made on
    first use, dropped with the thread; it keeps the arrays of the largest frame seen, up to
    :data:`GATE_KEPT_BYTES`, until ``gate_workspace().release()``). A call that finds it in use (re-entry)
    works in fresh arrays. :func:`zcut.suspects.suspects` gives the gate arrays of its own workspace instead
    (:func:`lazy_surfaces`' ``gate``)."""
    ws: SorWorkspace | None = getattr(_GATE, "workspace", None)
    if ws is None:
        ws = SorWorkspace(max_bytes=GATE_KEPT_BYTES)
        _GATE.workspace = ws
    return ws


def gate_arrays(ws: SorWorkspace, n: int, names: tuple[str, str, str] = ("gate_lo", "gate_hi", "gate_at")
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gate's three arrays of ``n`` entries from ``ws``: the brackets' lower and upper ends (float64) and
    their pixels (int64, a view of a float64 array of ``names[2]``: one dtype for every name, so a caller can
    give the names of its own arrays that are not in use while the gate runs)."""
    return (ws.empty(names[0], (n,)), ws.empty(names[1], (n,)), ws.empty(names[2], (n,)).view(np.int64))


def _gate_median(a: np.ndarray, valid: Mask, params: EdgeSurfaceParams, per_px: float, tan: float
                 ) -> tuple[int, float]:
    """(count, median) of the fitted patches' rms / z², the values :func:`zcut.edge_surface._edge_surfaces`
    takes: the count and ``_median_of_temporary`` of its ratios."""
    with gate_workspace().call() as ws:
        return _gate_median_in(a, valid, params, per_px, tan, *gate_arrays(ws, valid.size))


def _gate_median_in(a: np.ndarray, valid: Mask, params: EdgeSurfaceParams, per_px: float, tan: float,
                    lo: np.ndarray, hi: np.ndarray, at: np.ndarray) -> tuple[int, float]:
    """:func:`_gate_median` in the arrays ``lo``, ``hi`` (float64) and ``at`` (int64) of H · W entries each,
    uninitialized (nothing returned is one of them)."""
    r, min_px, floor = params.patch_radius_px, params.min_patch_px, params.side_step_mm
    m, _, nan = _ratio_brackets(a, valid, r, min_px, per_px, tan, floor, lo, hi, at)
    if m == 0:
        return 0, float("nan")
    if nan:
        return m, float("nan")
    lo, hi, at = lo[:m], hi[:m], at[:m]
    h = m // 2
    ranks = (h,) if m % 2 else (h - 1, h)
    # the k-th ratio lies between the k-th smallest lower end and the k-th smallest upper end
    wa, wb = kth_of_both(lo, hi, ranks[0], ranks[-1])  # order_pair(lo, ...)[0], order_pair(hi, ...)[0]
    vals = np.empty(m)  # only the first `inside` entries are written (few pages: fresh, not kept)
    below, _, inside = _window_exact(a, valid, r, min_px, per_px, tan, floor, lo, hi, at, wa, wb, vals)
    if not (below <= ranks[0] and ranks[-1] < below + inside):  # pragma: no cover - the brackets hold their ratios
        raise AssertionError("the gate's window does not hold the median: a bracket missed its ratio")
    a0, a1 = order_pair(vals[:inside], ranks[0] - below, ranks[-1] - below)
    if m % 2:
        return m, a1
    return m, float((np.float64(a0) + np.float64(a1)) / 2.0)


@numba.njit(cache=True)
def _listed_state(at, m, state):  # type: ignore[no-untyped-def]  # numba kernel
    """``state`` (H, W) int8: 2 (not decided yet) at the pixels ``at[:m]`` (:func:`_ratio_brackets`' list: every
    valid patch with n >= min_px, fitted, z² > 0), 0 (not a surface) elsewhere. A patch not listed is one
    :func:`zcut.edge_surface._decide` finds not valid, not fitted (the same :func:`_patch_moments` and the same
    closed form's rule, as the gate's count is the whole-frame pass's) or with z² = 0 (``zz > 0`` fails there):
    its state 0, its slot -1, as that decision leaves them, without reading its patch."""
    s = state.reshape(-1)
    s[:] = 0
    for k in range(m):
        s[at[k]] = 2


@numba.njit(cache=True, error_model="numpy")
def _decide_all(xyz, valid, r, min_px, per_px, tan, floor, gate_k, min_fit, cos_max, any_angle, state, slot, planes,  # type: ignore[no-untyped-def]  # numba kernel
                count):
    """:func:`zcut.edge_surface._decide` of every patch not decided yet (``state`` 2). Returns ``planes``
    (grown when it filled up)."""
    H, W = valid.shape
    side = (2 * r + 1) * (2 * r + 1)
    qx = np.empty(side)
    qy = np.empty(side)
    qz = np.empty(side)
    for a in range(H):
        for b in range(W):
            if state[a, b] == 2:
                if count[0] == planes.shape[0]:
                    planes = _grown(planes, count[0], 1)
                _decide(xyz, valid, a, b, r, min_px, per_px, tan, floor, gate_k, min_fit, cos_max, any_angle, state,
                        slot, planes, count, qx, qy, qz)
    return planes


class LazySurfaces:
    """The surfaces of one frame (:func:`lazy_surfaces`), decided where a distance reads them.

    :meth:`distance` is :meth:`zcut.edge_surface.EdgeSurfaces.distance`, the same values bit for bit. They own the
    frame in mm they were given until :meth:`release_frame` hands it back; after that nothing reads it."""

    __slots__ = ("_xyz", "_valid", "_params", "_per_px", "_tan", "_gate_k", "_state", "_slot", "_planes", "_count",
                 "n_fitted")
    _xyz: np.ndarray | None

    def __init__(self, xyz_mm: np.ndarray, valid: Mask, params: EdgeSurfaceParams, per_px: float, tan: float,
                 gate_k: float, n_fitted: int, state: np.ndarray | None = None) -> None:
        self._xyz, self._valid, self._params = xyz_mm, valid, params
        self._per_px, self._tan, self._gate_k = per_px, tan, gate_k
        self.n_fitted = n_fitted  # fitted patches with z² > 0 (0: no patch is a surface)
        # no ratio: no surface (as _edge_surfaces, which then leaves the mask empty)
        # per patch: 2 not decided yet, 1 a surface, 0 not (zcut.edge_surface._nearest_search); ``state``, when
        # given: 2 at the gate's listed patches only, the others decided already (:func:`_listed_state`)
        self._state = state if state is not None and n_fitted else np.full(valid.shape, 2 if n_fitted else 0, np.int8)
        self._slot = np.full(valid.shape, -1, np.int32)
        self._planes = np.empty((1024, 6))
        self._count = np.zeros(1, np.int64)

    def release_frame(self) -> np.ndarray | None:
        """The frame in mm these surfaces were given, handed back to the caller (None when it was already): from
        now on :meth:`distance`, :meth:`distance_at` and :attr:`surface` raise :class:`~zcut.errors.ZcutError`."""
        a, self._xyz = self._xyz, None
        return a

    def _frame(self) -> np.ndarray:
        if self._xyz is None:
            raise ZcutError("these surfaces' frame in mm was released (SuspectResult.release): "
                            "read surface_mm before releasing the result")
        return self._xyz

    @property
    def surface(self) -> Mask:
        """(H, W) bool: the patches that are surfaces (every patch decided)."""
        p = self._params
        self._planes = _decide_all(self._frame(), self._valid, p.patch_radius_px, p.min_patch_px, self._per_px, self._tan,
                                   p.side_step_mm, self._gate_k, p.min_fit_mm,
                                   math.cos(math.radians(p.max_incidence_deg)), p.max_incidence_deg >= 90.0,
                                   self._state, self._slot, self._planes, self._count)
        surface: Mask = self._state == 1
        return surface

    def _nearest(self, rows: np.ndarray, cols: np.ndarray, d: np.ndarray) -> None:
        p = self._params
        self._planes = _nearest_search(self._frame(), self._valid, rows, cols, p.patch_radius_px, p.min_patch_px,
                                       self._per_px, self._tan, p.side_step_mm, self._gate_k, p.min_fit_mm,
                                       math.cos(math.radians(p.max_incidence_deg)), p.max_incidence_deg >= 90.0,
                                       p.search_radius_px, p.max_search_radius_px, self._state, self._slot,
                                       self._planes, self._count, d)

    def distance_at(self, flat: np.ndarray) -> np.ndarray:
        """:meth:`distance` at the valid pixels of flat indices ``flat`` (increasing), as an array of theirs
        (the same values, read in the same order, without the frame of NaN around them)."""
        rows, cols = np.divmod(np.asarray(flat, np.int64), self._valid.shape[1])
        d = np.empty(rows.size)
        self._nearest(rows, cols, d)
        return d

    def distance(self, where: Mask | None = None) -> np.ndarray:
        """Signed distance (mm) of the valid pixels (of those in ``where`` too, when given) to the
        nearest surface: :meth:`zcut.edge_surface.EdgeSurfaces.distance`'s values there, NaN elsewhere."""
        at = self._valid if where is None else self._valid & where
        rows, cols = np.nonzero(at)
        d = np.empty(rows.size)
        self._nearest(rows, cols, d)
        out = np.full(at.shape, np.nan)
        out[rows, cols] = d
        return out


def lazy_surfaces(a: np.ndarray, valid: Mask, params: EdgeSurfaceParams, *,
                  gate: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> LazySurfaces:
    """:func:`zcut.edge_surface._edge_surfaces` (``a`` C-contiguous float64 in mm, finite where ``valid``,
    C-contiguous too) with the gate from brackets and the surfaces decided when read. ``gate``: the gate's
    arrays (:func:`gate_arrays`, H · W entries each) when the caller has them; else :func:`gate_workspace`'s. With
    ``gate``, the patches the gate did not list start decided (not surfaces, :func:`_listed_state`)."""
    per_px = reach_median(a, valid)  # 1 / f (_median_of_temporary's value)
    tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
    state = None
    if gate is None:
        m, g = _gate_median(a, valid, params, per_px, tan)
    else:
        m, g = _gate_median_in(a, valid, params, per_px, tan, *gate)
        if m:  # the patches the gate did not list are no surface: decided here, not one by one when read
            state = np.empty(valid.shape, np.int8)
            _listed_state(gate[2], m, state)
    gate_k = params.fit_k * g if m else float("nan")
    return LazySurfaces(a, valid, params, per_px, tan, gate_k, m, state)
