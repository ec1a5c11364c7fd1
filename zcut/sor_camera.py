"""Camera bounds of :mod:`zcut.sor`: a projective map fitted to the organized cloud, and the
half-space planes that bound the distance from a pixel to whole image regions.

A 3 × 4 matrix P maps a point p to U = P0·p̃ / P2·p̃ and V = P1·p̃ / P2·p̃ (p̃ = (p, 1)), which
grow with the column and the row of a camera cloud. If the depth P2·p̃ is positive at every valid
point, the points of a region whose U values are all >= t lie in the half-space
P0·p̃ - t·P2·p̃ >= 0, so the distance from a pixel to that half-space bounds its distance to every
point of the region from below -- whatever P is: a poor fit only makes the bounds useless.

Every bound is stored as a plane (n, o) with |n| = 1: the bound at q is max(0, n·q + o), where o is
lowered by a margin that covers the rounding of everything that led to it (``EPS`` relative, far
above the few ulp it absorbs, see :func:`_plane`). An empty region has n = 0, o = +inf: an
infinite bound. Evaluating a plane needs no branch, which keeps the window phase's fast loop
vectorized.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .sor_workspace import SorWorkspace

BLOCK = 32       # pixels per block edge; a band is two blocks and starts every block
TILE = 8         # pixels per tile edge (the leaves of the fallback's quadtree)
EPS = 1e-12      # relative margin of every camera bound
KEEP = 1.0 - EPS
_FIT_POINTS = 4096          # lattice sample for the camera fit
_FIT_MAX_RESIDUAL_PX = 4.0  # median reprojection error above which the fit is not used
_DISTORTION_MIN_PX = 0.25   # median reprojection error of the plain DLT above which a lens is modelled
_LAMBDA_MAX = 0.05          # the division model's λ searched in [-_LAMBDA_MAX, _LAMBDA_MAX] (normalised
_LAMBDA_STEPS = 21          # pixels: |λ| = 0.05 bends the corners of a 4:3 or 16:10 image by ~30 %) on a grid,
_LAMBDA_REFINE = 12         # then refined by golden section


# --------------------------------------------------------------------------------------------
# the camera model
# --------------------------------------------------------------------------------------------
def fit_camera(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
    """3 × 4 projective map P with ``(col, row) ≈ (P0·p̃ / P2·p̃, P1·p̃ / P2·p̃)`` (up to a
    normalisation of the pixel coordinates), or None if the cloud does not look like one camera.

    Direct linear transform on a lattice sample of the valid pixels (Hartley normalisation), the
    sign chosen so that the sample's depths P2·p̃ are positive. When its median reprojection error
    exceeds ``_DISTORTION_MIN_PX`` (a lens bends the image), P is the pinhole of a division model of
    radial distortion about the image centre if that reprojects the sample better
    (:func:`_fit_division`): U and V then stay constant along each ray, and only the lens's smooth
    bend is left within a band. Any P with positive depths keeps the bounds exact; a better one only
    makes them tighter.
    """
    H, W = valid.shape
    step = max(1, int(math.sqrt(H * W / _FIT_POINTS)))
    rr, cc = np.nonzero(valid[::step, ::step])
    rr, cc = rr * step, cc * step
    if rr.size < 64:  # a sparse lattice misses thin structures: take the valid pixels themselves
        rr, cc = np.nonzero(valid)
        if rr.size > _FIT_POINTS:
            pick = np.linspace(0, rr.size - 1, _FIT_POINTS).astype(np.int64)
            rr, cc = rr[pick], cc[pick]
    if rr.size < 12:
        return None
    normal, T, s_uv, mu_uv = _dlt_normal_matrix(x, y, z, rr, cc)
    if not (np.isfinite(normal).all() and np.isfinite(T).all() and s_uv > 0.0):
        return None
    try:  # a 12 x 12 eigenproblem: no BLAS threads woken up (their spinning costs CPU time)
        _, vecs = np.linalg.eigh(normal)
    except np.linalg.LinAlgError:
        return None
    P = np.ascontiguousarray(vecs[:, 0].reshape(3, 4) @ T)
    if not np.isfinite(P).all():
        return None
    sign, ok, median_res = _dlt_check(x, y, z, rr, cc, P, s_uv, mu_uv)
    if not (ok and median_res <= _DISTORTION_MIN_PX):  # a lens bends the rows and columns?
        c0 = ((W - 1) / 2.0 - mu_uv[0]) * s_uv, ((H - 1) / 2.0 - mu_uv[1]) * s_uv
        alt = _fit_division(x, y, z, rr, cc, normal, T, s_uv, mu_uv, c0)
        if alt is not None and alt[2] and (not ok or alt[3] < median_res):
            P, sign, ok, median_res = alt
    if not ok or not median_res <= _FIT_MAX_RESIDUAL_PX:
        return None
    return P * sign


def _fit_division(x: np.ndarray, y: np.ndarray, z: np.ndarray, rr: np.ndarray, cc: np.ndarray, normal: np.ndarray,
                  T: np.ndarray, s_uv: float, mu_uv: np.ndarray,
                  c0: tuple[float, float]) -> tuple[np.ndarray, float, bool, float] | None:
    """P of the pinhole behind a radially distorted image (division model about the image centre
    c0, in the normalised pixel coordinates: undistorted = c0 + (pixel - c0) / (1 + λ·r²)), its
    depth sign, whether the sample's depths are all positive, and the median distance in pixels
    between the pixels and the points' distorted reprojections; None if no λ gives a finite P.

    A plain DLT fitted to a distorted cloud moves its centre off the rays to bend its columns a
    little, so that U varies with the depth along a ray (a pile's relief: pixels apart across one
    band's rows); the pinhole of the division model keeps every ray at one U and V, leaving only
    the lens's smooth bend within a band. λ minimises that median over a grid and a golden-section
    refinement. The normal matrix is quadratic in λ (``normal`` its constant term)."""
    N1, N2 = _division_terms(x, y, z, rr, cc, T, s_uv, mu_uv, c0[0], c0[1])
    if not (np.isfinite(N1).all() and np.isfinite(N2).all()):
        return None

    def at(lam: float) -> tuple[float, np.ndarray | None, float, bool]:
        try:
            _, vecs = np.linalg.eigh(normal + lam * N1 + (lam * lam) * N2)
        except np.linalg.LinAlgError:
            return np.inf, None, 1.0, False
        P = np.ascontiguousarray(vecs[:, 0].reshape(3, 4) @ T)
        if not np.isfinite(P).all():
            return np.inf, None, 1.0, False
        sign, ok, res = _division_check(x, y, z, rr, cc, P, s_uv, mu_uv, c0[0], c0[1], lam)
        return (float(res) if ok and math.isfinite(res) else np.inf), P, sign, ok  # (NaN: a degenerate sample)

    grid = np.linspace(-_LAMBDA_MAX, _LAMBDA_MAX, _LAMBDA_STEPS)
    vals = [at(float(lam))[0] for lam in grid]
    i = int(np.argmin(vals))
    if not np.isfinite(vals[i]):
        return None
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    p, q = b - g * (b - a), a + g * (b - a)
    fp, fq = at(p)[0], at(q)[0]
    for _ in range(_LAMBDA_REFINE):
        if fp <= fq:
            b, q, fq = q, p, fp
            p = b - g * (b - a)
            fp = at(p)[0]
        else:
            a, p, fp = p, q, fq
            q = a + g * (b - a)
            fq = at(q)[0]
    best = min((vals[i], float(grid[i])), (fp, p), (fq, q))
    res, P, sign, ok = at(best[1])
    if P is None or not ok:
        return None
    return P, sign, ok, res


@nb.njit(cache=True, error_model="numpy")
def _division_terms(x, y, z, rr, cc, T, s_uv, muv, c0u, c0v):  # type: ignore[no-untyped-def]  # numba kernel
    # the DLT rows of the division model are A + λ·B (A: the plain DLT's rows [p̃, 0, -u p̃] and
    # [0, p̃, -v p̃]; B: r²·[p̃, 0, -c0u p̃] and r²·[0, p̃, -c0v p̃]), so the normal matrix is
    # AᵀA + λ·(AᵀB + BᵀA) + λ²·BᵀB: returns the last two
    n = rr.shape[0]
    N1 = np.zeros((12, 12))
    N2 = np.zeros((12, 12))
    A = np.zeros(12)
    B = np.zeros(12)
    ph = np.zeros(4)
    for i in range(n):
        for a in range(4):
            ph[a] = T[a, 0] * x[rr[i], cc[i]] + T[a, 1] * y[rr[i], cc[i]] + T[a, 2] * z[rr[i], cc[i]] + T[a, 3]
        u = (cc[i] - muv[0]) * s_uv
        v = (rr[i] - muv[1]) * s_uv
        r2 = (u - c0u) * (u - c0u) + (v - c0v) * (v - c0v)
        for side in range(2):
            t = u if side == 0 else v
            c = c0u if side == 0 else c0v
            A[:] = 0.0
            B[:] = 0.0
            for a in range(4):
                A[4 * side + a] = ph[a]
                A[8 + a] = -t * ph[a]
                B[4 * side + a] = r2 * ph[a]
                B[8 + a] = -r2 * c * ph[a]
            for a in range(12):
                for b in range(12):
                    N1[a, b] += A[a] * B[b] + B[a] * A[b]
                    N2[a, b] += B[a] * B[b]
    return N1, N2


@nb.njit(cache=True, error_model="numpy")
def _division_check(x, y, z, rr, cc, P, s_uv, muv, c0u, c0v, lam):  # type: ignore[no-untyped-def]  # numba kernel
    # _reprojection_check with the points' images distorted by the division model about (c0u, c0v)
    return _reprojection_check(x, y, z, rr, cc, P, s_uv, muv, c0u, c0v, lam, True)


@nb.njit(cache=True, error_model="numpy")
def _dlt_normal_matrix(x, y, z, rr, cc):  # type: ignore[no-untyped-def]  # numba kernel
    # Hartley-normalised DLT rows [p̃, 0, -u p̃] and [0, p̃, -v p̃]; returns MᵀM, the point
    # normalisation T (4 x 4), the pixel scale and the pixel mean
    n = rr.shape[0]
    mu = np.zeros(3)
    muv = np.zeros(2)
    for i in range(n):
        mu[0] += x[rr[i], cc[i]]
        mu[1] += y[rr[i], cc[i]]
        mu[2] += z[rr[i], cc[i]]
        muv[0] += cc[i]
        muv[1] += rr[i]
    mu /= n
    muv /= n
    sp = 0.0
    suv = 0.0
    for i in range(n):
        a = x[rr[i], cc[i]] - mu[0]
        b = y[rr[i], cc[i]] - mu[1]
        c = z[rr[i], cc[i]] - mu[2]
        sp += math.sqrt(a * a + b * b + c * c)
        a = cc[i] - muv[0]
        b = rr[i] - muv[1]
        suv += math.sqrt(a * a + b * b)
    s_p = math.sqrt(3.0) * n / sp if sp > 0.0 else np.inf
    s_uv = math.sqrt(2.0) * n / suv if suv > 0.0 else 0.0
    N = np.zeros((12, 12))
    row = np.zeros(12)
    ph = np.zeros(4)
    for i in range(n):
        ph[0] = (x[rr[i], cc[i]] - mu[0]) * s_p
        ph[1] = (y[rr[i], cc[i]] - mu[1]) * s_p
        ph[2] = (z[rr[i], cc[i]] - mu[2]) * s_p
        ph[3] = 1.0
        for side in range(2):
            t = ((cc[i] - muv[0]) if side == 0 else (rr[i] - muv[1])) * s_uv
            row[:] = 0.0
            for a in range(4):
                row[4 * side + a] = ph[a]
                row[8 + a] = -t * ph[a]
            for a in range(12):
                if row[a] != 0.0:
                    for b in range(12):
                        N[a, b] += row[a] * row[b]
    T = np.zeros((4, 4))
    for a in range(3):
        T[a, a] = s_p
        T[a, 3] = -s_p * mu[a]
    T[3, 3] = 1.0
    return N, T, s_uv, muv


@nb.njit(cache=True, error_model="numpy")
def _dlt_check(x, y, z, rr, cc, P, s_uv, muv):  # type: ignore[no-untyped-def]  # numba kernel
    # _reprojection_check of the plain pinhole
    return _reprojection_check(x, y, z, rr, cc, P, s_uv, muv, 0.0, 0.0, 0.0, False)


@nb.njit(cache=True, error_model="numpy")
def _reprojection_check(x, y, z, rr, cc, P, s_uv, muv, c0u, c0v, lam, lens):  # type: ignore[no-untyped-def]  # numba kernel
    # the depth sign that makes the sample's depths P2·p̃ positive, whether they all are, and the
    # median distance in pixels between each sample pixel and its point's reprojection: the
    # pinhole's (lens False) or, with lens, its image distorted by the division model about
    # (c0u, c0v) with λ = lam (inf where the model has no distorted image)
    n = rr.shape[0]
    d = np.empty(n)
    res = np.empty(n)
    for i in range(n):
        xq = x[rr[i], cc[i]]
        yq = y[rr[i], cc[i]]
        zq = z[rr[i], cc[i]]
        d[i] = P[2, 0] * xq + P[2, 1] * yq + P[2, 2] * zq + P[2, 3]
        u = (P[0, 0] * xq + P[0, 1] * yq + P[0, 2] * zq + P[0, 3]) / d[i]
        v = (P[1, 0] * xq + P[1, 1] * yq + P[1, 2] * zq + P[1, 3]) / d[i]
        if lens:
            du = u - c0u
            dv = v - c0v
            disc = 1.0 - 4.0 * lam * (du * du + dv * dv)
            if not disc >= 0.0:
                res[i] = np.inf
                continue
            k = 2.0 / (1.0 + math.sqrt(disc))
            u = c0u + du * k
            v = c0v + dv * k
        eu = u - (cc[i] - muv[0]) * s_uv
        ev = v - (rr[i] - muv[1]) * s_uv
        res[i] = math.sqrt(eu * eu + ev * ev) / s_uv
    sign = 1.0 if np.median(d) >= 0.0 else -1.0
    ok = True
    for i in range(n):
        if not sign * d[i] > 0.0:
            ok = False
    return sign, ok, np.median(res)


def camera_scale(P: np.ndarray, amax: np.ndarray) -> float:
    """Upper bound S on |each term| of ``P_i·p̃`` over the valid points (``amax`` = max |x|, |y|,
    |z|); the absolute error of every computed ``P_i·p̃`` is a few ulp of S."""
    return float(max(np.abs(P[i, :3]) @ amax + abs(P[i, 3]) for i in range(3)))


# --------------------------------------------------------------------------------------------
# planes
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _plane(P, i, t, ge, M, out):  # type: ignore[no-untyped-def]  # numba kernel
    """The plane of the region {U_i >= t} (``ge``) or {U_i <= t} (U_0 = U, U_1 = V) into out[:4].

    The region lies in {n*·p + o* <= 0} with n* = ±(t·D - N) / |t·D - N| exactly (N = P_i[:3],
    D = P_2[:3]); the computed n, o differ from n*, o* by a few ulp of the terms they come from,
    and their evaluation at q by a few ulp of |n|·M + |o| (M = max |coordinate|). The offset is
    lowered by twice a bound on both, with a factor EPS / (8 ulp) to spare.
    """
    if not (t > -np.inf and t < np.inf):  # empty region
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        out[3] = np.inf
        return
    sgn = 1.0 if ge else -1.0
    s = 0.0
    for a in range(3):
        g = sgn * (t * P[2, a] - P[i, a])
        out[a] = g
        s += g * g
    o = sgn * (t * P[2, 3] - P[i, 3])
    if not s > 0.0:  # a constant functional: no bound
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        out[3] = 0.0
        return
    inv = 1.0 / math.sqrt(s)
    terms = (abs(t) * (abs(P[2, 0]) + abs(P[2, 1]) + abs(P[2, 2])) + abs(P[i, 0]) + abs(P[i, 1]) + abs(P[i, 2])) * M
    terms += abs(t) * abs(P[2, 3]) + abs(P[i, 3])
    n1 = 0.0
    for a in range(3):
        out[a] *= inv
        n1 += abs(out[a])
    o *= inv
    out[3] = o - 2.0 * EPS * (inv * terms + n1 * M + abs(o))


@nb.njit(cache=True, inline="always")
def plane_bound(tab, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    """Lower bound (>= 0, possibly inf) on the distance from q to the region of plane tab[:4]."""
    return max(tab[0] * xq + tab[1] * yq + tab[2] * zq + tab[3], 0.0) * KEEP


@nb.njit(cache=True, inline="always")
def plane_bound_at(tab, k, j, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    """plane_bound of the plane tab[k:k + 4, j] (tables laid out field-major)."""
    return max(tab[k, j] * xq + tab[k + 1, j] * yq + tab[k + 2, j] * zq + tab[k + 3, j], 0.0) * KEEP


# --------------------------------------------------------------------------------------------
# one pass over the pixels: per-block U and V extremes, per-tile boxes
# --------------------------------------------------------------------------------------------
def new_stats(H: int, W: int, ws: SorWorkspace | None = None) -> tuple[np.ndarray, ...]:
    """Arrays filled by :func:`block_rows`: rowU (row blocks, W, 2) [min U_lo, max U_hi], colV
    (column blocks, H, 2) [min V_lo, max V_hi], tile count, tile box (x, y, z lo, x, y, z hi),
    tile [min U_lo, max U_hi, min V_lo, max V_hi, min depth], and per row block "some depth not
    safely positive". ``ws``: taken from that workspace (else new)."""
    ws = SorWorkspace(max_bytes=0) if ws is None else ws
    nrb, ncb = -(-H // BLOCK), -(-W // BLOCK)
    th, tw = -(-H // TILE), -(-W // TILE)
    rowU = ws.empty("rowU", (nrb, W, 2))
    rowU[..., 0], rowU[..., 1] = np.inf, -np.inf
    colV = ws.empty("colV", (ncb, H, 2))
    colV[..., 0], colV[..., 1] = np.inf, -np.inf
    tcount = ws.full("tcount", (th, tw), 0, np.int64)
    tbox = ws.empty("tbox", (th, tw, 6))
    tbox[..., :3], tbox[..., 3:] = np.inf, -np.inf
    tuv = ws.empty("tuv", (th, tw, 5))
    tuv[..., 0::2], tuv[..., 1::2] = np.inf, -np.inf
    bad = ws.full("bad", (nrb,), False, np.bool_)
    return rowU, colV, tcount, tbox, tuv, bad


_CH = 256  # columns per chunk of the vectorized pass (a multiple of TILE)


@nb.njit(cache=True, error_model="numpy")
def _uv_chunk(x, y, z, valid, r, c0, n, P, S, tau, buf):  # type: ignore[no-untyped-def]  # numba kernel
    """U_lo, U_hi, V_lo, V_hi and the depth of pixels (r, c0..c0+n-1) into buf[k·_CH + i] (±inf
    where invalid); returns the number of valid pixels whose depth is not safely positive.

    Straight-line code into one buffer at fixed offsets: the compiler vectorizes it. U = a · (1/d)
    is a few ulp of |U| plus those of a and d (a few ulp of S) from the true a/d, well within
    EPS·(1 + |U|)·(S/d + 1).
    """
    bad = 0
    for i in range(n):
        c = c0 + i
        ok = valid[r, c]
        xq = x[r, c] if ok else 0.0
        yq = y[r, c] if ok else 0.0
        zq = z[r, c] if ok else 0.0
        a = P[0, 0] * xq + P[0, 1] * yq + P[0, 2] * zq + P[0, 3]
        b = P[1, 0] * xq + P[1, 1] * yq + P[1, 2] * zq + P[1, 3]
        d = P[2, 0] * xq + P[2, 1] * yq + P[2, 2] * zq + P[2, 3]
        bad += np.int64(ok & (d <= tau))  # type: ignore[assignment]  # numba kernel: an int64 local
        d = max(d, tau)
        inv = 1.0 / d
        u = a * inv
        v = b * inv
        g = EPS * (S * inv + 1.0)
        eu = (1.0 + abs(u)) * g
        ev = (1.0 + abs(v)) * g
        buf[i] = u - eu if ok else np.inf
        buf[_CH + i] = u + eu if ok else -np.inf
        buf[2 * _CH + i] = v - ev if ok else np.inf
        buf[3 * _CH + i] = v + ev if ok else -np.inf
        buf[4 * _CH + i] = d if ok else np.inf
    return bad


@nb.njit(cache=True, nogil=True)
def block_rows(b0, b1, x, y, z, valid, span, P, S, use_cam, rowU, colV, tcount, tbox, tuv, bad):  # type: ignore[no-untyped-def]  # numba kernel
    """Row blocks b0..b1-1 of the statistics of :func:`new_stats`.

    Invalid pixels (+inf) change nothing, so a row is read only over the tiles of its valid span
    (``span[r]`` = first, last valid column), and U and V are computed only over its runs of tiles
    that hold a valid pixel of the row."""
    H, W = valid.shape
    tau = 1e-6 * S
    buf = np.empty(5 * _CH)
    rowcount = np.zeros(-(-W // TILE), np.int64)
    for blk in range(b0, b1):
        for r in range(blk * BLOCK, min(H, (blk + 1) * BLOCK)):
            if span[r, 0] > span[r, 1]:
                continue
            ti = r // TILE
            tj0 = span[r, 0] // TILE
            tj1 = span[r, 1] // TILE
            for tj in range(tj0, tj1 + 1):  # boxes and counts
                n = 0
                x0 = y0 = z0 = np.inf
                x1 = y1 = z1 = -np.inf
                for c in range(tj * TILE, min(W, (tj + 1) * TILE)):
                    ok = valid[r, c]
                    n += ok
                    x0 = min(x0, x[r, c])
                    y0 = min(y0, y[r, c])
                    z0 = min(z0, z[r, c])
                    x1 = max(x1, x[r, c] if ok else -np.inf)
                    y1 = max(y1, y[r, c] if ok else -np.inf)
                    z1 = max(z1, z[r, c] if ok else -np.inf)
                rowcount[tj] = n
                tcount[ti, tj] += n
                tbox[ti, tj, 0] = min(tbox[ti, tj, 0], x0)
                tbox[ti, tj, 1] = min(tbox[ti, tj, 1], y0)
                tbox[ti, tj, 2] = min(tbox[ti, tj, 2], z0)
                tbox[ti, tj, 3] = max(tbox[ti, tj, 3], x1)
                tbox[ti, tj, 4] = max(tbox[ti, tj, 4], y1)
                tbox[ti, tj, 5] = max(tbox[ti, tj, 5], z1)
            if not use_cam:
                continue
            ta = tj0
            while ta <= tj1:  # U and V over each run of tiles with a valid pixel
                if rowcount[ta] == 0:
                    ta += 1
                    continue
                te = ta
                while te < tj1 and rowcount[te + 1] > 0:
                    te += 1
                c_end = min(W, (te + 1) * TILE)
                for c0 in range(ta * TILE, c_end, _CH):  # tile-aligned chunks
                    n = min(_CH, c_end - c0)
                    if _uv_chunk(x, y, z, valid, r, c0, n, P, S, tau, buf):
                        bad[blk] = True
                    for i in range(n):
                        rowU[blk, c0 + i, 0] = min(rowU[blk, c0 + i, 0], buf[i])
                        rowU[blk, c0 + i, 1] = max(rowU[blk, c0 + i, 1], buf[_CH + i])
                    for t0 in range(0, n, TILE):
                        tj = (c0 + t0) // TILE
                        u0 = d0 = v0 = np.inf
                        u1 = v1 = -np.inf
                        for i in range(t0, min(n, t0 + TILE)):
                            u0 = min(u0, buf[i])
                            u1 = max(u1, buf[_CH + i])
                            v0 = min(v0, buf[2 * _CH + i])
                            v1 = max(v1, buf[3 * _CH + i])
                            d0 = min(d0, buf[4 * _CH + i])
                        tuv[ti, tj, 0] = min(tuv[ti, tj, 0], u0)
                        tuv[ti, tj, 1] = max(tuv[ti, tj, 1], u1)
                        tuv[ti, tj, 2] = min(tuv[ti, tj, 2], v0)
                        tuv[ti, tj, 3] = max(tuv[ti, tj, 3], v1)
                        tuv[ti, tj, 4] = min(tuv[ti, tj, 4], d0)
                        cb = (c0 + t0) // BLOCK
                        colV[cb, r, 0] = min(colV[cb, r, 0], v0)
                        colV[cb, r, 1] = max(colV[cb, r, 1], v1)
                ta = te + 1


# --------------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def band_tables(blocks, P, i, M, out):  # type: ignore[no-untyped-def]  # numba kernel
    """Band planes from per-block extremes (rowU with i = 0, or colV with i = 1).

    ``blocks`` is (n_blocks, L, 2); band b covers blocks b - 1 and b. Returns (n_blocks + 1, 8,
    L) in ``out``: fields 0..3 the plane of the band's points at positions >= j (their U_i >= the
    suffix minimum), fields 4..7 that of the points at positions <= j (U_i <= the prefix maximum).
    """
    nblk, L = blocks.shape[0], blocks.shape[1]
    pl = np.empty(4)
    for b in range(nblk + 1):
        run = np.inf
        last = np.nan  # the t of the plane in pl (a run over empty columns keeps it: no new plane)
        for j in range(L - 1, -1, -1):
            if b >= 1:
                run = min(run, blocks[b - 1, j, 0])
            if b < nblk:
                run = min(run, blocks[b, j, 0])
            if not (run == last and run != 0.0):  # (a zero may be -0.0: recomputed)
                _plane(P, i, run, True, M, pl)
                last = run
            for f in range(4):
                out[b, f, j] = pl[f]
        run = -np.inf
        last = np.nan
        for j in range(L):
            if b >= 1:
                run = max(run, blocks[b - 1, j, 1])
            if b < nblk:
                run = max(run, blocks[b, j, 1])
            if not (run == last and run != 0.0):
                _plane(P, i, run, False, M, pl)
                last = run
            for f in range(4):
                out[b, 4 + f, j] = pl[f]
    return out


@nb.njit(cache=True)
def corner_tables(tuv, P, S, M):  # type: ignore[no-untyped-def]  # numba kernel
    """Quadrant planes over blocks, and the per-cell floor of the corner bounds.

    Q[i, j, corner] = [U plane (4), V plane (4)] of the region: corner 0 rows >= BLOCK·i and
    cols >= BLOCK·j (min U_lo, min V_lo), 1 rows >= and cols < (max U_hi, min V_lo), 2 rows < and
    cols >= (min U_lo, max V_hi), 3 rows < and cols < (max U_hi, max V_hi); empty regions have
    infinite bounds. floor[b, bc] bounds the corner bound of every pixel of band cell (b, bc) from
    below: for a region with U >= t and a pixel with U(q) <= Umax < t, t·d(q) - a(q) =
    d(q)·(t - U(q)) >= d_min·(t - Umax), likewise for the other sides.
    """
    th, tw = tuv.shape[0], tuv.shape[1]
    f = BLOCK // TILE
    nrb = (th + f - 1) // f
    ncb = (tw + f - 1) // f
    cell = np.empty((nrb, ncb, 4))
    cell[:, :, 0::2] = np.inf
    cell[:, :, 1::2] = -np.inf
    for i in range(th):
        for j in range(tw):
            ci, cj = i // f, j // f
            cell[ci, cj, 0] = min(cell[ci, cj, 0], tuv[i, j, 0])
            cell[ci, cj, 1] = max(cell[ci, cj, 1], tuv[i, j, 1])
            cell[ci, cj, 2] = min(cell[ci, cj, 2], tuv[i, j, 2])
            cell[ci, cj, 3] = max(cell[ci, cj, 3], tuv[i, j, 3])
    # cum[i, j, corner] = extremes of U and V over the corner's region; region(i, j) is the block
    # (bi, bj) plus region(i ± 1, j) plus region(i, j ± 1), empty on the far border
    cum = np.empty((nrb + 1, ncb + 1, 4, 2))
    for corner in range(4):
        down = corner < 2          # rows >= BLOCK·i (else rows < BLOCK·i)
        right = corner % 2 == 0    # cols >= BLOCK·j (else cols < BLOCK·j)
        for ii in range(nrb + 1):
            i = nrb - ii if down else ii
            for jj in range(ncb + 1):
                j = ncb - jj if right else jj
                u = np.inf if right else -np.inf
                v = np.inf if down else -np.inf
                if ((i < nrb) if down else (i > 0)) and ((j < ncb) if right else (j > 0)):
                    bi = i if down else i - 1
                    bj = j if right else j - 1
                    pi = i + 1 if down else i - 1
                    pj = j + 1 if right else j - 1
                    if right:
                        u = min(cell[bi, bj, 0], min(cum[pi, j, corner, 0], cum[i, pj, corner, 0]))
                    else:
                        u = max(cell[bi, bj, 1], max(cum[pi, j, corner, 0], cum[i, pj, corner, 0]))
                    if down:
                        v = min(cell[bi, bj, 2], min(cum[pi, j, corner, 1], cum[i, pj, corner, 1]))
                    else:
                        v = max(cell[bi, bj, 3], max(cum[pi, j, corner, 1], cum[i, pj, corner, 1]))
                cum[i, j, corner, 0] = u
                cum[i, j, corner, 1] = v
    Q = np.empty((nrb + 1, ncb + 1, 4, 8))
    pl = np.empty(4)
    for i in range(nrb + 1):
        for j in range(ncb + 1):
            for corner in range(4):
                _plane(P, 0, cum[i, j, corner, 0], corner % 2 == 0, M, pl)
                Q[i, j, corner, 0:4] = pl
                _plane(P, 1, cum[i, j, corner, 1], corner < 2, M, pl)
                Q[i, j, corner, 4:8] = pl
    floor = np.zeros((nrb + 1, ncb + 1))
    keep2 = KEEP * KEEP
    for b in range(nrb + 1):
        for bc in range(ncb + 1):
            umin = np.inf
            umax = -np.inf
            vmin = np.inf
            vmax = -np.inf
            dmin = np.inf
            for i in range(max(0, f * b - f // 2), min(th, f * b + f // 2)):
                for j in range(max(0, f * bc - f // 2), min(tw, f * bc + f // 2)):
                    umin = min(umin, tuv[i, j, 0])
                    umax = max(umax, tuv[i, j, 1])
                    vmin = min(vmin, tuv[i, j, 2])
                    vmax = max(vmax, tuv[i, j, 3])
                    dmin = min(dmin, tuv[i, j, 4])
            dlo = dmin - EPS * S
            if not (dlo > 0.0 and dlo < np.inf):
                continue  # no pixel in the cell (or no depth margin): floor 0
            i1, i0, j1, j0 = min(b + 1, nrb), max(b - 1, 0), min(bc + 1, ncb), max(bc - 1, 0)
            lb = np.inf
            for corner in range(4):
                i = i1 if corner < 2 else i0
                j = j1 if corner % 2 == 0 else j0
                tU = cum[i, j, corner, 0]
                tV = cum[i, j, corner, 1]
                bu = np.inf
                bv = np.inf
                if tU > -np.inf and tU < np.inf:
                    gu = (tU - umax) if corner % 2 == 0 else (umin - tU)
                    bu = dlo * gu * _inv_norm(P, 0, tU) * keep2 if gu > 0.0 else 0.0
                if tV > -np.inf and tV < np.inf:
                    gv = (tV - vmax) if corner < 2 else (vmin - tV)
                    bv = dlo * gv * _inv_norm(P, 1, tV) * keep2 if gv > 0.0 else 0.0
                lb = min(lb, max(bu, bv))
            floor[b, bc] = lb
    return Q, floor


@nb.njit(cache=True)
def _inv_norm(P, i, t):  # type: ignore[no-untyped-def]  # numba kernel
    # 1 / |t·D - N| (0 for a null normal)
    s = 0.0
    for a in range(3):
        g = t * P[2, a] - P[i, a]
        s += g * g
    return 1.0 / math.sqrt(s) if s > 0.0 else 0.0


@nb.njit(cache=True)
def node_planes(uv, P, M):  # type: ignore[no-untyped-def]  # numba kernel
    """(n, 16) planes of the U >= min, U <= max, V >= min, V <= max half-spaces of each node."""
    n = uv.shape[0]
    out = np.empty((n, 16))
    pl = np.empty(4)
    for k in range(n):
        for side in range(4):
            _plane(P, side // 2, uv[k, side], side % 2 == 0, M, pl)
            out[k, 4 * side:4 * side + 4] = pl
    return out
