"""Find the instances of a part in a frame's zone: :func:`fit_parts`.

The method (issue 29 item 2; paper §2 defines the residual Err these fits give):

1. **Segment** the zone's valid pixels into candidate regions by 3-D connectivity on the organized
   grid, broken at depth discontinuities (:mod:`zcut.fits.segment`).
2. **Fit** each region, largest first:

   - a **sphere** model (every vertex at one radius from the centroid) in closed form: the centre
     from normal votes p − R n, then linear least squares (algebraic sphere) refined with the radius
     fixed, trimming points farther than k × the residual (:mod:`zcut.fits.sphere`);
   - any other model by a **global initial guess that copes with its symmetries** — the region's
     principal axes matched to the model's in every proper signed permutation, those equivalent
     under the model's detected symmetry group dropped — each refined by a few point-to-plane ICP
     steps, the best (most points within the gate) refined fully (:mod:`zcut.fits.icp`).

3. **Accept** a fit when its residual Err (RMS distance of its matched points to the posed model)
   is at most ``max_err_mm``, its **support** (the share of the pixels where the posed model is
   predicted visible — ray cast through the intrinsics, minus those where something measured lies in
   front of it and those without a measurement — whose measured point lies within k × Err of the
   model) is at least
   ``min_support``, and it explains at least ``min_region_px`` pixels of its region. The pixels it explains
   leave the region; what is left is segmented again and fitted (touching parts), up to
   ``max_instances_per_region`` times.
4. **Second pass** (``seed_shifts`` > 0): the zone's pixels no accepted fit took are segmented again;
   each region of at least max(10, ``seed_min_share`` × a whole instance's projected area) pixels is
   fitted as in 2-3 as a partly visible instance — its guesses also put ``seed_shifts`` spread points
   of the model's facing side on its centroid (a piece's centroid is not the facing side's), no turns —
   and accepted at Err ≤ ``seed_err_ratio`` × max(the first pass's median Err, ``err_floor_mm``).
5. **Reassign pixels**: every zone pixel within k × max(Err, ``err_floor_mm``) of an accepted fit
   belongs to the nearest such fit.

The fits read only the cloud, the zone, the mesh and the intrinsics (estimated from the organized
cloud itself when not given): never a log's truth or the poses in its metadata.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from zcut.cancel import stop_point
from zcut.errors import InputShapeError, describe_array
from zcut.fit_vetting import pose_overlaps

from .icp import EDGE_WEAK, guess_translations, icp, initial_rotations, pose_matrix, shifted_guesses
from .kernels import (
    coarse_search,
    edge_distances,
    lower_bounds,
    occluding_boundary,
    surface_distances,
    window_band,
    window_pixels,
    window_rays,
)
from .model import PartModel, prepare_model, projected_area_px
from .params import FitParams
from .segment import segment
from .sphere import algebraic_sphere, refine_sphere, vote_centres

__all__ = ["PartFit", "estimate_intrinsics", "fit_parts", "fit_prepared"]

Intrinsics = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class PartFit:
    """One fitted instance of the part.

    Attributes
    ----------
    pose : (4, 4) float64 ndarray
        Part model frame (mm) -> camera optical frame (mm).
    err_mm : float
        RMS point-to-model distance of its support pixels (mm): the paper's Err.
    support : float
        Share (0..1) of the instance's predicted visible pixels that measured points support.
    pixels : (N,) int64 ndarray
        Flat indices (row-major, H × W) of the pixels it explains.
    """

    pose: np.ndarray
    err_mm: float
    support: float
    pixels: np.ndarray


def estimate_intrinsics(xyz_mm: np.ndarray) -> Intrinsics | None:
    """(fx, fy, cx, cy) of an organized cloud by least squares on col = fx x/z + cx and
    row = fy y/z + cy; None when fewer than two distinct columns or rows are valid."""
    H, W = xyz_mm.shape[:2]
    valid = np.isfinite(xyz_mm).all(axis=2) & (xyz_mm[..., 2] > 0)
    rows, cols = np.nonzero(valid)
    if len(rows) < 2:
        return None
    step = max(1, len(rows) // 20000)
    rows, cols = rows[::step], cols[::step]
    p = xyz_mm[rows, cols]
    out = []
    for pix, ratio in ((cols, p[:, 0] / p[:, 2]), (rows, p[:, 1] / p[:, 2])):
        if np.ptp(pix) == 0 or np.ptp(ratio) == 0:
            return None
        sol, *_ = np.linalg.lstsq(np.c_[ratio, np.ones(len(ratio))], pix.astype(np.float64), rcond=None)
        out.append(sol)
    return float(out[0][0]), float(out[1][0]), float(out[0][1]), float(out[1][1])


def _normals_at(xyz: np.ndarray, flat: np.ndarray, step: int = 2) -> np.ndarray:
    """(n, 3) unit normals toward the camera at the pixels ``flat`` from central differences ``step``
    pixels apart, NaN where a neighbour is missing or the pixel lies within ``step`` of the border."""
    H, W = xyz.shape[:2]
    s = step
    n = np.full((len(flat), 3), np.nan)
    r, c = np.divmod(np.asarray(flat, np.int64), W)
    inside = np.flatnonzero((r >= s) & (r < H - s) & (c >= s) & (c < W - s))
    if not len(inside):
        return n
    p = xyz.reshape(-1, 3)
    f = flat[inside]
    dx = p[f + s] - p[f - s]
    dy = p[f + s * W] - p[f - s * W]
    cr = np.cross(dx, dy)
    norm = np.linalg.norm(cr, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        cr = cr / norm
    flip = np.einsum("ij,ij->i", cr, p[f]) > 0
    cr[flip] = -cr[flip]
    n[inside] = cr
    return n


@dataclass(frozen=True, slots=True)
class _Frame:
    xyz: np.ndarray  # (H, W, 3)
    valid: np.ndarray  # (H, W) finite
    zone: np.ndarray  # (H, W) valid & zone
    K: Intrinsics


def _window(frame: _Frame, T: np.ndarray, model: PartModel) -> tuple[slice, slice] | None:
    fx, fy, cx, cy = frame.K
    H, W = frame.valid.shape
    c = T[:3, :3] @ model.centroid + T[:3, 3]
    z = c[2] - model.extent_mm
    if z <= 1e-6:
        return None
    ru = fx * model.extent_mm / z + 2
    rv = fy * model.extent_mm / z + 2
    u, v = fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy
    c0, c1 = max(int(np.floor(u - ru)), 0), min(int(np.ceil(u + ru)) + 1, W)
    r0, r1 = max(int(np.floor(v - rv)), 0), min(int(np.ceil(v + rv)) + 1, H)
    if c0 >= c1 or r0 >= r1:
        return None
    return slice(r0, r1), slice(c0, c1)


def _model_distance(frame: _Frame, T: np.ndarray, model: PartModel, flat: np.ndarray, within: float,
                    known: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`_near_distances` of the pixels ``flat``; those in ``known`` (sorted pixels, their
    distances to this fit at this ``within``) taken from it."""
    if known is not None and len(known[0]) and len(flat):
        kf, kd = known
        i = np.minimum(np.searchsorted(kf, flat), len(kf) - 1)
        have = kf[i] == flat
        out = np.empty(len(flat))
        out[have] = kd[i[have]]
        rest = ~have
        if rest.any():
            out[rest] = _near_distances(model, frame.xyz.reshape(-1, 3)[flat[rest]], T, within)
        return out
    return _near_distances(model, frame.xyz.reshape(-1, 3)[flat], T, within)


def _near_distances(model: PartModel, points: np.ndarray, T: np.ndarray, within: float) -> np.ndarray:
    """The exact distances of camera-frame ``points`` to the posed model where they may be at most
    ``within``, inf where a lower bound through the model's voxel index is farther (the same answer to
    every "d <= within" and the same d below it, without the exact query of the points far away)."""
    ix = model.index
    if ix is None or len(points) == 0:
        return model.distance((points - T[:3, 3]) @ T[:3, :3])
    p = np.ascontiguousarray(points, np.float64)
    lb = lower_bounds(p, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), ix.origin, ix.h,
                      ix.centre_dist, ix.margin)
    out = np.full(len(p), np.inf)
    near = lb <= within
    if near.any():
        out[near] = model.distance((p[near] - T[:3, 3]) @ T[:3, :3])
    return out


def _support(frame: _Frame, T: np.ndarray, model: PartModel, tol: float,
             known: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Share of the pixels where the posed model is predicted visible, measured, and nothing measured
    lies in front of it, whose measured point lies within ``tol`` of the model (``known``: see
    :func:`_model_distance`)."""
    win = _window(frame, T, model)
    if win is None:
        return 0.0
    fx, fy, cx, cy = frame.K
    rs, cs = win
    R, t = T[:3, :3], T[:3, 3]
    # only the window's rays that meet the model's box grown by SUPPORT_BOX_MM (a cheap test of every
    # ray in numba) are cast: the others miss the box the ray casts test (grown by 0.01 mm) and every
    # triangle in it. The rays cast are computed as before, one by one: the same hits.
    lo = model.vertices.min(axis=0) - SUPPORT_BOX_MM
    hi = model.vertices.max(axis=0) + SUPPORT_BOX_MM
    rr, cc = window_rays(rs.start, rs.stop, cs.start, cs.stop, fx, fy, cx, cy, np.ascontiguousarray(R),
                         np.ascontiguousarray(t), lo, hi)
    if not len(rr):
        return 0.0
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones(rr.shape)], axis=-1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origin = np.broadcast_to(-R.T @ t, d.shape)
    hit = model.ray_depths(np.ascontiguousarray(origin), d @ R)
    predicted = np.isfinite(hit)
    if not predicted.any():
        return 0.0
    pts = frame.xyz[rr[predicted], cc[predicted]]
    pflat = (rr * frame.valid.shape[1] + cc)[predicted]
    ok = np.isfinite(pts).all(axis=1)
    rng = np.full(len(pts), np.nan)
    rng[ok] = np.linalg.norm(pts[ok], axis=1)
    dist = np.full(len(pts), np.inf)
    dist[ok] = _model_distance(frame, T, model, pflat[ok], tol, known)
    supported = dist <= tol
    with np.errstate(invalid="ignore"):
        occluded = ok & (rng < hit[predicted] - tol) & ~supported
    # a pixel without a measurement (a projector's shadow, a dropout) neither supports nor contradicts
    denom = int((ok & ~occluded).sum())
    return float(supported.sum() / denom) if denom else 0.0


#: The support casts only the rays that meet the model's bounding box grown by this (mm): a margin far
#: above the rounding of the cheap test, outside the 0.01 mm of the ray casts' own box test.
SUPPORT_BOX_MM = 0.05


#: At most this many of a sphere's points (an even subsample) fit its centre; the pixels it explains
#: and its support are then decided on every pixel.
SPHERE_POINTS = 1500


def _fit_sphere(frame: _Frame, flat: np.ndarray, model: PartModel, params: FitParams,
                centre: np.ndarray) -> tuple[np.ndarray, float]:
    """(pose, err) of the sphere near ``centre`` in the region's points: algebraic least squares
    and radius-fixed Gauss-Newton on the points within a gate that shrinks to k × the robust
    residual."""
    assert model.sphere_radius is not None
    R = model.sphere_radius
    pts = frame.xyz.reshape(-1, 3)[flat]
    c = np.asarray(centre, np.float64)
    gate = params.gate_mm
    pts = pts[np.linalg.norm(pts - c, axis=1) <= R + gate]  # its own points: within R of its centre
    pts = pts[_subsample(np.arange(len(pts)), SPHERE_POINTS)]  # even: the centre's noise is σ / √n
    err = np.inf
    res = np.zeros(0)
    for _ in range(6):
        res = np.abs(np.linalg.norm(pts - c, axis=1) - R)
        use = res <= gate
        if use.sum() < 4:
            return pose_matrix(np.eye(3), c - model.centroid), np.inf
        c0, r0 = algebraic_sphere(pts[use])
        if np.isfinite(r0) and abs(r0 - R) < 0.1 * R:
            c = c0
        c = refine_sphere(pts[use], c, R)
        res = np.abs(np.linalg.norm(pts - c, axis=1) - R)
        robust = 1.4826 * float(np.median(res[use]))
        err = float(np.sqrt(np.mean(res[use] ** 2)))
        gate = max(params.k * max(robust, params.err_floor_mm), 0.5 * gate)
        if gate <= params.k * max(robust, params.err_floor_mm) + 1e-12:
            break
    use = res <= params.k * max(err, params.err_floor_mm)
    if use.any():
        err = float(np.sqrt(np.mean(res[use] ** 2)))
    return pose_matrix(np.eye(3), c - model.centroid), err


def _subsample(flat: np.ndarray, n: int) -> np.ndarray:
    if len(flat) <= n:
        return flat
    return flat[np.linspace(0, len(flat) - 1, n).round().astype(np.int64)]


def _occluding_boundary(frame: _Frame, flat: np.ndarray, jump_mm: float) -> np.ndarray:
    """The pixels of the region whose 4-neighbour outside it is missing or lies farther than
    ``jump_mm`` behind: where the region's own silhouette is seen (not where something occludes it). One kernel
    walk (:func:`zcut.fits.kernels.occluding_boundary`), the pixels of :func:`_occluding_boundary_reference`."""
    H, W = frame.valid.shape
    out: np.ndarray = occluding_boundary(frame.xyz.reshape(-1, 3), frame.valid.reshape(-1),
                                         np.ascontiguousarray(flat, np.int64), H, W, float(jump_mm))
    return out


def _occluding_boundary_reference(frame: _Frame, flat: np.ndarray, jump_mm: float) -> np.ndarray:
    """:func:`_occluding_boundary` in NumPy (the rounds before 2026-12-06c)."""
    H, W = frame.valid.shape
    z = frame.xyz[..., 2].reshape(-1)
    valid = frame.valid.reshape(-1)
    r, c = np.divmod(flat, W)
    if not len(flat):
        return flat[:0]
    # the region's membership on its bounding box grown by a pixel (not on the whole frame: a region is small)
    r0, c0 = max(int(r.min()) - 1, 0), max(int(c.min()) - 1, 0)
    bw = min(int(c.max()) + 2, W) - c0
    inside = np.zeros((min(int(r.max()) + 2, H) - r0) * bw, bool)
    inside[(r - r0) * bw + (c - c0)] = True
    edge = np.zeros(len(flat), bool)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rr, cc = r + dr, c + dc
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        nb = np.where(ok, rr * W + cc, 0)
        out = ok & ~inside[np.where(ok, (rr - r0) * bw + (cc - c0), 0)]
        far = ~valid[nb] | (z[nb] > z[flat] + jump_mm)
        edge |= out & far
    return flat[edge]


def _surface_distances(model: PartModel, points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Distances of camera-frame points to the posed model: through its voxel index when it has one
    (:func:`zcut.fits.kernels.surface_distances`), else exact."""
    ix = model.index
    if ix is None:
        return model.distance((points - T[:3, 3]) @ T[:3, :3])
    out: np.ndarray = surface_distances(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(T[:3, :3]),
                                        np.ascontiguousarray(T[:3, 3]), ix.origin, ix.h, ix.tri_grid, ix.a, ix.b,
                                        ix.c, ix.n, ix.tri)
    return out


def _edge_distances(model: PartModel, points: np.ndarray, T: np.ndarray) -> np.ndarray:
    ix = model.index
    if ix is None:
        return model.nearest_edges((points - T[:3, 3]) @ T[:3, :3])[0]
    out: np.ndarray = edge_distances(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(T[:3, :3]),
                                     np.ascontiguousarray(T[:3, 3]), ix.origin, ix.h, ix.seg_grid, ix.p0, ix.p1)
    return out


#: At most this many of a region's points (and half as many of its boundary) score the initial guesses.
COARSE_POINTS = 150

#: A region's guesses stop at the first whose coarse fit has at least this share of its points within the
#: score's tolerance and ...
STOP_INL = 0.95
#: ... this share of its boundary points on the model's sharp edges.
STOP_EDGE = 0.7

#: The turns (degrees) about the region's normal tried from the best initial guess (:func:`_fit_general`).
TURNS_DEG = (-24.0, -16.0, -8.0, 8.0, 16.0, 24.0)


def _turn(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
    return R


def _fit_general(frame: _Frame, flat: np.ndarray, model: PartModel, params: FitParams,
                 shifts: int = 0) -> tuple[np.ndarray, float]:
    """(pose, err) of one instance of a general model in the region's points.

    Every initial guess takes ``coarse_iterations`` ICP steps on an even subsample of
    ``COARSE_POINTS`` points; the best (most points within the score tolerance, plus the boundary
    points on the model's edges) and its turns by ``TURNS_DEG`` about the region's normal the same,
    and the best of all is refined on up to ``max_points`` points. A guess whose points nearly all
    fit stops the search of the guesses.

    ``shifts`` > 0 (the second pass, a region that may show only part of an instance): the guesses
    also put ``shifts`` spread points of the model's facing side on the region's centroid
    (:func:`zcut.fits.icp.shifted_poses`), and the turns are not tried."""
    sub = _subsample(flat, params.max_points)
    pts = frame.xyz.reshape(-1, 3)[sub]
    coarse = np.ascontiguousarray(pts[_subsample(np.arange(len(pts)), COARSE_POINTS)])
    bnd = _subsample(_occluding_boundary(frame, flat, params.jump_mm), params.max_points // 2)
    epts = frame.xyz.reshape(-1, 3)[bnd]
    coarse_e = np.ascontiguousarray(epts[_subsample(np.arange(len(epts)), COARSE_POINTS // 2)])
    f = 0.5 * (frame.K[0] + frame.K[1])
    px_mm = float(np.median(pts[:, 2])) / f  # the pixel footprint
    edge_gate = max(3.0 * px_mm, params.k * params.err_floor_mm)
    score_tol = max(params.k * params.err_floor_mm, params.gate_mm / 4)
    opts = dict(gate_mm=params.gate_mm, k=params.k, floor_mm=params.err_floor_mm, edge_gate_mm=edge_gate)

    def coarse_fit(T0: np.ndarray) -> tuple[float, float, float, np.ndarray]:
        # the model without a voxel index (not made by prepare_model): the same steps in Python
        T, _, _ = icp(coarse, model, T0, iterations=params.coarse_iterations, edge_points=coarse_e, **opts)
        d = _surface_distances(model, coarse, T)
        inl, near = float(np.mean(d <= score_tol)), float(np.mean(np.minimum(d, score_tol))) / score_tol
        e_inl = float(np.mean(_edge_distances(model, coarse_e, T) <= 1.5 * px_mm)) if len(coarse_e) else 1.0
        score = inl - 0.01 * near + (0.5 * e_inl if len(coarse_e) else 0.0)
        return score, inl, e_inl, T

    def search(Rs: np.ndarray, ts: np.ndarray, stop: bool) -> tuple[float, np.ndarray] | None:
        """The best (score, pose) of the coarse ICP from each of the poses (``Rs`` (k, 3, 3), ``ts`` (k, 3),
        C-contiguous; the first of equal scores), stopping at a guess whose points nearly all fit when ``stop``."""
        if not len(Rs):
            return None
        ix = model.index
        if ix is not None:  # every guess in one kernel call (:func:`zcut.fits.kernels.coarse_search`)
            i, R, t, score = coarse_search(coarse, coarse_e, Rs, ts, int(params.coarse_iterations),
                                           float(params.gate_mm), float(params.k), float(params.err_floor_mm),
                                           float(edge_gate), float(model.extent_mm), float(score_tol), 1.5 * px_mm,
                                           ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri, ix.seg_grid, ix.p0,
                                           ix.p1, EDGE_WEAK, STOP_INL if stop else 2.0, STOP_EDGE)
            return (float(score), pose_matrix(R, t)) if i >= 0 else None
        found: tuple[float, np.ndarray] | None = None
        for R0, t0 in zip(Rs, ts):
            score, inl, e_inl, T = coarse_fit(pose_matrix(R0, t0))
            if found is None or score > found[0]:
                found = (score, T)
            if stop and inl >= STOP_INL and e_inl >= STOP_EDGE:
                break
        return found

    # the points' principal axes, once: the guesses' rotations and the turns' axis (the same arithmetic as
    # initial_rotations' own, so the same bits)
    c = pts.mean(axis=0)
    _, ax = np.linalg.eigh(np.cov((pts - c).T))
    # the guesses as (rotations, translations) arrays, not a 4 × 4 matrix each (initial_poses' and shifted_poses'
    # arithmetic: the same bits)
    Rs = np.stack(initial_rotations(pts, model, axes=ax))
    ts = guess_translations(pts, Rs, model)
    if shifts:
        Rsh, tsh = shifted_guesses(pts, Rs, model, shifts)
        Rs, ts = np.concatenate([Rs, Rsh]), np.concatenate([ts, tsh])
    best = search(Rs, ts, stop=True)
    assert best is not None
    # the guesses turn 45° apart about the region's normal, the turn its surface leaves nearly free:
    # the best one's turns in between, about its own centroid, each refined the same way
    T_best = best[1]
    turns = () if shifts else TURNS_DEG
    Rt_all = np.empty((len(turns), 3, 3))
    tt_all = np.empty((len(turns), 3))
    for m, deg in enumerate(turns):
        Rt = _turn(ax[:, 0], np.radians(deg))
        Rt_all[m] = Rt @ T_best[:3, :3]
        tt_all[m] = Rt @ (T_best[:3, 3] - c) + c
    better = search(Rt_all, tt_all, stop=False)
    if better is not None and better[0] > best[0]:
        best = better
    T, rms, _ = icp(pts, model, best[1], iterations=params.icp_iterations, edge_points=epts,
                    **opts)
    gate = params.k * max(rms if np.isfinite(rms) else params.gate_mm, params.err_floor_mm)
    d = _near_distances(model, pts, T, gate)
    inl_mask = d <= gate
    err = float(np.sqrt(np.mean(d[inl_mask] ** 2))) if inl_mask.any() else np.inf
    if params.fine_points > 0 and np.isfinite(err):
        T, err = _fine(frame, flat, pts, epts, model, params, opts, T, err)
    return T, err


def _fine(frame: _Frame, flat: np.ndarray, pts: np.ndarray, epts: np.ndarray, model: PartModel, params: FitParams,
          opts: dict[str, float], T: np.ndarray, err: float) -> tuple[np.ndarray, float]:
    """The last refinement of a candidate's pose (``FitParams.fine_points``, docs/fits.md "Eighth round"): the
    ICP again from ``T`` on up to ``fine_points`` of the region's points (an even subsample of all of them, not
    of the ``max_points`` the search used) that lie within k × max(``err``, floor) of the posed model — trimmed:
    a neighbour's or a ghost's points farther off take no part — with the gate at that band from the start.
    The refined pose is kept when its Err, measured as before on the search's points ``pts``, is at most
    ``FINE_KEEP`` × ``err`` (the refinement minimises over more points, the Err is measured on fewer).

    ``FitParams.fine_window`` (docs/fits.md, "Eleventh round"): the points are those of the region **and of the
    zone in the posed model's window** within that band — a region holds a median 75 % of a fully visible
    ray-traced nut's pixels, the rest cut off by the segmentation, a patch or a neighbour's claims — and
    ``FitParams.fine_robust`` > 0 weighs them by Tukey's biweight of their distance at ``fine_robust`` ×
    max(``err``, floor) (the ICP kernel's ``robust_mm``): a mixed pixel or a ghost inside the band pulls less."""
    tol = params.k * max(err, params.err_floor_mm)
    use = _band_points(frame, flat, model, T, tol, window=params.fine_window)
    use = use[_subsample(np.arange(len(use)), params.fine_points)]
    if len(use) < 20:
        return T, err
    robust = params.fine_robust * max(err, params.err_floor_mm)
    T2, rms, _ = icp(use, model, T, iterations=params.icp_iterations, edge_points=epts,
                     **{**opts, "gate_mm": tol}, robust_mm=robust)
    gate = params.k * max(rms if np.isfinite(rms) else params.gate_mm, params.err_floor_mm)
    d = _near_distances(model, pts, T2, gate)
    inl = d <= gate
    err2 = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else np.inf
    return (T2, err2) if err2 <= FINE_KEEP * err else (T, err)


def _band_points(frame: _Frame, flat: np.ndarray, model: PartModel, T: np.ndarray, tol: float, *,
                 window: bool) -> np.ndarray:
    """(m, 3) the points of the pixels ``flat`` (ascending) — with ``window``, and of the zone's pixels in the posed
    model's window (:func:`_window`) — within ``tol`` of the model posed at ``T``, in ascending flat order: one
    kernel walk (:func:`zcut.fits.kernels.window_band`) for a model with a voxel index."""
    ix = model.index
    if not window or ix is None:
        if window:
            flat = np.union1d(flat, _window_flat(frame, T, model))
        allp = frame.xyz.reshape(-1, 3)[flat]
        out: np.ndarray = allp[_surface_distances(model, allp, T) <= tol]
        return out
    win = _window(frame, T, model)
    (r0, r1), (c0, c1) = ((0, 0), (0, 0)) if win is None else ((win[0].start, win[0].stop), (win[1].start, win[1].stop))
    out = window_band(frame.xyz.reshape(-1, 3), frame.zone.reshape(-1), np.ascontiguousarray(flat, np.int64), r0, r1,
                      c0, c1, frame.valid.shape[1], np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
                      float(tol), ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
    return out


#: :func:`_fine` keeps the refined pose when its Err is at most this many times the search's.
FINE_KEEP = 1.1


def fit_prepared(xyz_mm: np.ndarray, zone: np.ndarray, model: PartModel, *, intrinsics: Intrinsics | None = None,
                 params: FitParams | None = None) -> list[PartFit]:
    """:func:`fit_parts` with the part model already prepared (:func:`zcut.fits.model.prepare_model`),
    for many frames of one part. Inside a :func:`zcut.cancel.stop_when` scope it raises
    :class:`zcut.errors.Cancelled` between regions and candidates once the scope's check says stop."""
    params = FitParams() if params is None else params
    xyz = np.asarray(xyz_mm)
    z = np.asarray(zone)
    if xyz.ndim != 3 or xyz.shape[2] != 3 or not np.issubdtype(xyz.dtype, np.floating):
        raise InputShapeError(f"xyz_mm must be (H, W, 3) float, got {describe_array(xyz)}")
    if z.shape != xyz.shape[:2] or z.dtype != np.bool_:
        raise InputShapeError(f"zone must be (H, W) bool matching xyz_mm {xyz.shape[:2]}, got {describe_array(z)}")
    xyz = xyz.astype(np.float64, copy=False)
    valid = np.isfinite(xyz).all(axis=2)
    zv = z & valid
    if zv.sum() < params.min_region_px:
        return []
    K = intrinsics if intrinsics is not None else estimate_intrinsics(xyz)
    if K is None:
        return []
    K = (float(K[0]), float(K[1]), float(K[2]), float(K[3]))
    frame = _Frame(xyz=xyz, valid=valid, zone=zv, K=K)
    f = 0.5 * (K[0] + K[1])
    H, W = zv.shape
    accepted: list[tuple[np.ndarray, float, float]] = []
    known: list[tuple[np.ndarray, np.ndarray]] = []  # each fit's distances at its region's (window's) pixels
    # the pixels an accepted fit took from its region (params.claim: every zone pixel it explains)
    explained = np.zeros(H * W, bool)
    claims = _Claims(model, params, H * W) if params.claim else None
    pending = segment(xyz, np.flatnonzero(zv), f_px=f, jump_mm=params.jump_mm, jump_px=params.jump_px,
                      min_px=params.min_region_px)
    for region in pending:
        stop_point()  # a caller's stop (zcut.cancel) is seen between regions and candidates
        pending.extend(_fit_region(frame, region, model, params, accepted, known, explained, shifts=0,
                                   claims=claims))
    held: list[tuple[tuple[np.ndarray, float, float], tuple[np.ndarray, np.ndarray]]] = []
    if claims is not None and params.first_err_ratio > 0 and accepted:
        # a fit of the first pass whose Err is far above the frame's (a pose between two parts, or pulled by a
        # neighbour's face or ghosts) is held back: its claims are released and its pixels fitted again by the
        # second pass; it comes back after it when no fit then overlaps it (docs/fits.md, "Eighth round")
        live = [e for (_, e, _), ok in zip(accepted, claims.alive) if ok]
        lim = params.first_err_ratio * max(float(np.median(live)), params.err_floor_mm)
        for j, (_, e, _) in enumerate(accepted):
            if claims.alive[j] and e > lim:
                held.append((accepted[j], known[j]))
                claims.kill(j)
    if claims is not None:  # a replaced fit is no fit; the pixels no live fit claims are unexplained
        accepted, known = _alive(accepted, claims), _alive(known, claims)
        explained = claims.count > 0
    if params.seed_shifts > 0 and accepted:
        # the second pass: what no fit explains, segmented again; each region a partly visible instance
        seeds = [r for r in segment(xyz, np.flatnonzero(zv.reshape(-1) & ~explained), f_px=f, jump_mm=params.jump_mm,
                                    jump_px=params.jump_px, min_px=SEED_MIN_PX)]
        noise = max(float(np.median([e for _, e, _ in accepted])), params.err_floor_mm)
        if claims is not None:  # the live fits, renumbered as in accepted
            claims = _Claims.of(claims)
        seed_params = replace(params, max_err_mm=min(params.max_err_mm, params.seed_err_ratio * noise),
                              min_support=params.seed_min_support)
        for piece in seeds:
            stop_point()
            todo = _unclaimed(piece, claims, SEED_MIN_PX)
            if todo is None:
                continue
            min_px = max(SEED_MIN_PX, int(np.ceil(params.seed_min_share * _projected_area(frame, todo, model))))
            if len(todo) >= min_px:
                seeds.extend(_fit_region(frame, todo, model, seed_params, accepted, known, explained,
                                         shifts=params.seed_shifts, min_px=min_px, claims=claims))
    if claims is not None and held:
        claims = _Claims.of(claims) if len(claims.alive) != len(accepted) else claims
        for fit, kn in held:  # the held-back fits no fit of the second pass overlaps: the best the frame has there
            if not claims.overlapping(fit[0]):
                accepted.append(fit)
                known.append(kn)
                claims.add(fit[0], fit[1], kn)
    if claims is not None:
        accepted, known = _alive(accepted, claims), _alive(known, claims)
    return _assign(frame, model, accepted, params, known)


_T = TypeVar("_T")


def _alive(items: list[_T], claims: _Claims) -> list[_T]:
    return [x for x, ok in zip(items, claims.alive) if ok]


class _Claims:
    """What the accepted fits hold (``FitParams.claim``): the zone pixels each explains in its window (a
    pixel is claimed while a live fit claims it) and their solids, against which a candidate's volume
    overlap is measured on the model's inside samples. A candidate that overlaps accepted fits replaces
    them when it is better than each (:meth:`better`), else it is refused; a replaced fit is dead: its
    claims are released and it is no fit."""

    def __init__(self, model: PartModel, params: FitParams, size: int) -> None:
        self.model = model
        self.params = params
        self.count = np.zeros(size, np.int32)
        self.poses: list[np.ndarray] = []
        self.errs: list[float] = []
        self.known: list[tuple[np.ndarray, np.ndarray]] = []
        self.pixels: list[np.ndarray] = []
        self.alive: list[bool] = []
        self.centres = np.zeros((0, 3))

    @classmethod
    def of(cls, other: _Claims) -> _Claims:
        """The live fits of ``other`` alone, renumbered in their order (the accepted list without the dead)."""
        out = cls(other.model, other.params, len(other.count))
        out.count = other.count
        keep = [i for i, ok in enumerate(other.alive) if ok]
        out.poses = [other.poses[i] for i in keep]
        out.errs = [other.errs[i] for i in keep]
        out.known = [other.known[i] for i in keep]
        out.pixels = [other.pixels[i] for i in keep]
        out.alive = [True] * len(keep)
        out.centres = other.centres[keep].reshape(-1, 3)
        return out

    def claimed(self, flat: np.ndarray) -> np.ndarray:
        """Whether each pixel is claimed: within k × max(Err, floor) of a live fit."""
        out: np.ndarray = self.count[flat] > 0
        return out

    def _tol(self, err: float) -> float:
        return self.params.k * max(err, self.params.err_floor_mm)

    def add(self, T: np.ndarray, err: float, known: tuple[np.ndarray, np.ndarray]) -> None:
        """Accept the fit (pose ``T``, ``err``, its distances ``known`` at its window's and region's pixels)."""
        kf, kd = known
        pix = kf[kd <= self._tol(err)]
        self.count[pix] += 1
        self.poses.append(T)
        self.errs.append(err)
        self.known.append(known)
        self.pixels.append(pix)
        self.alive.append(True)
        c = T[:3, :3] @ self.model.centroid + T[:3, 3]
        self.centres = np.vstack([self.centres, c[None]])

    def kill(self, j: int) -> None:
        self.count[self.pixels[j]] -= 1
        self.alive[j] = False
        self.centres[j] = np.inf

    def overlapping(self, T: np.ndarray) -> list[int]:
        """The live accepted fits whose solid shares more than ``max_overlap`` of its volume with the solid
        posed at ``T``, or of whose volume that solid holds as much (the vetting's measure: the share of
        one's inside samples inside the other; only the fits whose centres lie within twice the model's
        extent can overlap)."""
        m = self.model
        near = self.near(T)
        if not len(near):
            return []
        Tc = np.broadcast_to(T, (len(near), 4, 4))
        Tn = np.stack([self.poses[int(j)] for j in near])
        # the vetting's rule (zcut.fit_vetting.pose_overlaps): the candidate's samples in each fit, and back
        share = np.maximum(pose_overlaps(m.solid, Tc, Tn), pose_overlaps(m.solid, Tn, Tc))
        return [int(j) for j, sh in zip(near, share) if sh > self.params.max_overlap]

    def near(self, T: np.ndarray) -> np.ndarray:
        """The live accepted fits (indices) whose solid may overlap the solid posed at ``T``: their centres
        lie within twice the model's extent (none when overlaps are not tested)."""
        m = self.model
        if not len(self.poses) or not len(m.inside) or self.params.max_overlap >= 1:
            return np.zeros(0, np.int64)
        c = T[:3, :3] @ m.centroid + T[:3, 3]
        out: np.ndarray = np.flatnonzero(np.linalg.norm(self.centres - c, axis=1) < 2.0 * m.extent_mm)
        return out

    def better(self, err: float, known: tuple[np.ndarray, np.ndarray], j: int) -> bool:
        """Whether a candidate (``err``, its distances ``known``) explains more zone pixels than the accepted
        fit ``j`` within one tolerance, k × max(the smaller Err, floor): of two fits of one part the one
        closer to it explains more at the noise of the better one."""
        tol = self._tol(min(err, self.errs[j]))
        return int((known[1] <= tol).sum()) > int((self.known[j][1] <= tol).sum())


def _unclaimed(region: np.ndarray, claims: _Claims | None, min_px: int) -> np.ndarray | None:
    """``region`` (of the second pass), or None when accepted fits claimed all but fewer than ``min_px`` of
    its pixels (``claims`` None: never). The first pass fits every region whole: a fit claiming a region's
    pixels may be a wrong fit of a piece of its part (its Err inflated, its band as wide as the part),
    which the region's own fit then replaces."""
    if claims is None or int((~claims.claimed(region)).sum()) >= min_px:
        return region
    return None


#: The second pass never fits a region of fewer unexplained pixels than this (the labelling page's
#: person decides proposals this small well: issue 29).
SEED_MIN_PX = 10


def _projected_area(frame: _Frame, flat: np.ndarray, model: PartModel) -> float:
    """π (extent · f / z)² pixels, z the median depth of the pixels ``flat``: the area a whole
    instance there covers at most."""
    z = float(np.median(frame.xyz.reshape(-1, 3)[_subsample(flat, 500), 2]))
    return float(projected_area_px(model, z, 0.5 * (frame.K[0] + frame.K[1])))


def _fit_region(frame: _Frame, region: np.ndarray, model: PartModel, params: FitParams,
                accepted: list[tuple[np.ndarray, float, float]], known: list[tuple[np.ndarray, np.ndarray]],
                explained: np.ndarray, *, shifts: int, min_px: int | None = None,
                claims: _Claims | None = None) -> list[np.ndarray]:
    """Fit the instances of one candidate region (module docstring, steps 2-3), appending each accepted
    fit to ``accepted`` and ``known`` and marking its pixels in ``explained``; ``shifts``: see
    :func:`_fit_general`; ``min_px``: the smallest region (and fit) taken, default ``min_region_px``;
    ``claims``: ``FitParams.claim`` (:class:`_Claims`). Returns the further regions its leftovers split
    into, to fit the same way."""
    min_px = params.min_region_px if min_px is None else min_px
    H, W = frame.valid.shape
    f = 0.5 * (frame.K[0] + frame.K[1])
    more: list[np.ndarray] = []
    left = region
    attempts = 0
    tried: np.ndarray | None = None  # seeds of patches already fitted in this region (made when first needed)
    while len(left) >= min_px and attempts < params.max_instances_per_region:
        stop_point()
        progress = False
        many = model.sphere_radius is None and _holds_many(frame, left, model)
        if many:
            if tried is None:
                tried = np.zeros(H * W, bool)
            patch = _patch(frame, left, model, tried)
            if patch is None:
                break
            cands = ([_fit_general(frame, patch, model, params, shifts=shifts)]
                     if len(patch) >= min_px else [])
        else:
            cands = _candidates(frame, left, model, params, shifts=shifts)
            if claims is not None and len(cands) > 1:
                cands = _ranked(frame, left, model, params, cands)
        for T, err in cands:
            stop_point()
            attempts += 1
            fit = _accept(frame, left, model, params, T, err, min_px, claims)
            if fit is None:
                continue
            accepted.append(fit[0])
            known.append(fit[2])
            explained[left[fit[1]]] = True
            if claims is not None:
                for j in fit[3]:  # the accepted fits it replaces
                    claims.kill(j)
                claims.add(T, err, fit[2])
            left = left[~fit[1]]
            progress = True
            if len(left) < min_px or attempts >= params.max_instances_per_region:
                break
        if not progress and claims is not None:
            # a candidate refused for its overlap with a better fit: that fit's pixels leave the region
            # (its part is fitted), the rest is fitted on (other parts of it; the old fits accepted the
            # duplicate and fitted on the rest)
            free = ~claims.claimed(left)
            if not free.all():
                left = left[free]
                progress = True
        if not progress:
            if many:
                continue  # the next patch
            break
        parts = segment(frame.xyz, left, f_px=f, jump_mm=params.jump_mm, jump_px=params.jump_px,
                        min_px=min_px)
        if not parts:
            break
        left = parts[0]
        more.extend(parts[1:])
    return more


def _holds_many(frame: _Frame, flat: np.ndarray, model: PartModel) -> bool:
    """Whether the region spreads farther than one instance can: the 98th percentile of its points' distances
    to their centroid (2 % of them lie farther) above 1.3 × the model's extent."""
    pts = frame.xyz.reshape(-1, 3)[_subsample(flat, 2000)]
    r = np.linalg.norm(pts - pts.mean(axis=0), axis=1)
    return _percentile_above(r, 98.0, 1.3 * model.extent_mm)


def _percentile_above(r: np.ndarray, q: float, thr: float) -> bool:
    """``np.percentile(r, q) > thr`` for finite ``r`` (not empty), without sorting when counts decide it: the
    percentile interpolates between the sorted values s[i] and s[i + 1], i = floor(q / 100 (n − 1)), so s[i − 1]
    clearly above ``thr`` says yes and s[i + 2] clearly below says no (a neighbour more each way: an index
    rounded the other way changes neither; the margin, 1e-9 × |thr| + 1e-12, lies far above the rounding of the
    interpolation); otherwise NumPy's percentile decides."""
    n = len(r)
    i = int(np.floor(q / 100.0 * (n - 1)))
    margin = 1e-9 * abs(thr) + 1e-12
    lo, hi = max(i - 1, 0), min(i + 2, n - 1)
    if n and int(np.count_nonzero(r > thr + margin)) >= n - lo:  # s[lo] > thr + margin
        return True
    if n and int(np.count_nonzero(r > thr - margin)) < n - hi:  # s[hi] <= thr - margin
        return False
    return bool(np.percentile(r, q) > thr)


def _patch(frame: _Frame, flat: np.ndarray, model: PartModel, tried: np.ndarray) -> np.ndarray | None:
    """The pixels of a region holding several instances that one instance may cover: seeded at the
    untried point nearest the camera (the top of a pile is the least occluded), the points within the
    model's extent of the seed, then twice those within it of their centroid (the patch slides onto
    the instance the seed lies on). The seed's neighbourhood (half the extent) is marked tried.
    None when every point was tried."""
    pts = frame.xyz.reshape(-1, 3)[flat]
    free = ~tried[flat]
    if not free.any():
        return None
    cand = np.flatnonzero(free)
    seed = pts[cand[int(np.argmin(pts[cand, 2]))]]
    tried[flat[np.linalg.norm(pts - seed, axis=1) <= 0.5 * model.extent_mm]] = True
    centre = seed
    near = np.linalg.norm(pts - centre, axis=1) <= model.extent_mm
    for _ in range(2):
        centre = pts[near].mean(axis=0)
        near = np.linalg.norm(pts - centre, axis=1) <= model.extent_mm
    out: np.ndarray = flat[near]
    return out


def _candidates(frame: _Frame, flat: np.ndarray, model: PartModel, params: FitParams,
                shifts: int = 0) -> list[tuple[np.ndarray, float]]:
    """The fits to try in a region: one per vote cluster for a sphere, the best one otherwise."""
    if model.sphere_radius is None:
        return [_fit_general(frame, flat, model, params, shifts=shifts)]
    pts = frame.xyz.reshape(-1, 3)[flat]
    nrm = _normals_at(frame.xyz, flat)
    centres = vote_centres(pts, nrm, model.sphere_radius, min_votes=max(3, params.min_region_px // 4))
    if not centres:
        c, _ = algebraic_sphere(pts)
        centres = [c]
    return [_fit_sphere(frame, flat, model, params, c) for c in centres[: params.max_instances_per_region]]


def _ranked(frame: _Frame, flat: np.ndarray, model: PartModel, params: FitParams,
            cands: list[tuple[np.ndarray, float]]) -> list[tuple[np.ndarray, float]]:
    """``cands`` (a sphere region's, one per vote cluster) in order of the region's points each explains
    within one tolerance, k × max(the smallest Err of them, floor), most first (ties: their order): a
    candidate a few millimetres off its ball, on its ghosts or its fringe, explains fewer at the noise
    of the best one and is tried after it (then refused by its overlap with it, ``FitParams.claim``)."""
    errs = [e for _, e in cands if np.isfinite(e)]
    if not errs:
        return cands
    tol = params.k * max(min(errs), params.err_floor_mm)
    pts = frame.xyz.reshape(-1, 3)[flat]
    counts = [int((_near_distances(model, pts, T, tol) <= tol).sum()) if np.isfinite(e) else -1 for T, e in cands]
    return [cands[i] for i in np.argsort(-np.asarray(counts), kind="stable")]


def _window_flat(frame: _Frame, T: np.ndarray, model: PartModel, outside: np.ndarray | None = None) -> np.ndarray:
    """The zone pixels (flat, ascending) of the posed model's window (:func:`_window`), those of ``outside`` (flat,
    ascending) left out: one kernel walk (:func:`zcut.fits.kernels.window_pixels`)."""
    win = _window(frame, T, model)
    if win is None:
        return np.zeros(0, np.int64)
    region = np.zeros(0, np.int64) if outside is None else np.ascontiguousarray(outside, np.int64)
    if len(region) > 1 and not bool(np.all(region[1:] > region[:-1])):  # the walk needs it ascending
        region = np.unique(region)
    out: np.ndarray = window_pixels(frame.zone.reshape(-1), region, win[0].start, win[0].stop, win[1].start,
                                    win[1].stop, frame.valid.shape[1])
    return out


def _window_flat_reference(frame: _Frame, T: np.ndarray, model: PartModel) -> np.ndarray:
    """:func:`_window_flat` in NumPy (the rounds before 2026-12-06c)."""
    win = _window(frame, T, model)
    if win is None:
        return np.zeros(0, np.int64)
    W = frame.valid.shape[1]
    rr, cc = np.mgrid[win]
    flat = (rr * W + cc).reshape(-1)
    out: np.ndarray = flat[frame.zone.reshape(-1)[flat]]
    return out


def _accept(frame: _Frame, flat: np.ndarray, model: PartModel, params: FitParams, T: np.ndarray,
            err: float, min_px: int | None = None, claims: _Claims | None = None
            ) -> tuple[tuple[np.ndarray, float, float], np.ndarray, tuple[np.ndarray, np.ndarray], list[int]] | None:
    """((pose, err, support), the region's pixels it explains, the region's pixels of finite distance
    and their distances) when the fit is accepted (it explains at least ``min_px`` of them, default
    ``min_region_px``), else None; the last item: the accepted fits it replaces. With ``claims``
    (``FitParams.claim``): a fit whose solid overlaps accepted ones is refused unless it is better than each
    (:meth:`_Claims.better`; it then replaces them), and the known distances cover its window's zone pixels
    too (sorted)."""
    min_px = params.min_region_px if min_px is None else min_px
    if not (np.isfinite(err) and err <= params.max_err_mm):
        return None
    rivals = claims.overlapping(T) if claims is not None else []
    tol = params.k * max(err, params.err_floor_mm)
    d = _model_distance(frame, T, model, flat, tol)
    near = d <= tol
    if near.sum() < min_px:
        return None
    finite = np.isfinite(d)
    known = (flat[finite], d[finite])
    if claims is not None:  # the window's other zone pixels: the claim, the support and the assignment
        wf = _window_flat(frame, T, model, outside=flat)  # the window's other zone pixels
        wd = _model_distance(frame, T, model, wf, tol)
        kf = np.concatenate([flat, wf])  # inf kept: the assignment asks for every window pixel again
        kd = np.concatenate([d, wd])
        order = np.argsort(kf, kind="stable")
        known = (kf[order], kd[order])
    # the overlap before the support (the conditions are all required: the same answer), so a candidate
    # refused for it casts no rays
    if claims is not None and not all(claims.better(err, known, j) for j in rivals):
        return None
    support = _support(frame, T, model, tol, known)
    if support < params.min_support:
        return None
    return (T, err, support), near, known, rivals


def _assign(frame: _Frame, model: PartModel, accepted: list[tuple[np.ndarray, float, float]],
            params: FitParams, known: list[tuple[np.ndarray, np.ndarray]] | None = None) -> list[PartFit]:
    """Every zone pixel within k × max(Err, floor) of an accepted fit goes to the nearest one."""
    H, W = frame.zone.shape
    best = np.full(H * W, np.inf)
    owner = np.full(H * W, -1, np.int64)
    zone_flat = frame.zone.reshape(-1)
    for i, (T, err, _) in enumerate(accepted):
        win = _window(frame, T, model)
        if win is None:
            continue
        rs, cs = win
        rr, cc = np.mgrid[rs, cs]
        flat = (rr * W + cc).reshape(-1)
        flat = flat[zone_flat[flat]]
        tol = params.k * max(err, params.err_floor_mm)
        d = _model_distance(frame, T, model, flat, tol, None if known is None else known[i])
        take = (d <= tol) & (d < best[flat])
        best[flat[take]] = d[take]
        owner[flat[take]] = i
    # each fit's pixels, ascending: the owned pixels grouped by owner in one stable sort (not a pass over
    # the frame per fit)
    taken = np.flatnonzero(owner >= 0)
    by_owner = taken[np.argsort(owner[taken], kind="stable")].astype(np.int64)
    counts = np.bincount(owner[taken], minlength=len(accepted))
    ends = np.cumsum(counts)
    out = []
    for i, (T, err, support) in enumerate(accepted):
        pix = by_owner[ends[i] - counts[i]:ends[i]].copy()
        out.append(PartFit(pose=T, err_mm=float(err), support=float(support), pixels=pix))
    return out


def fit_parts(xyz_mm: np.ndarray, zone: np.ndarray, vertices_mm: np.ndarray, triangles: np.ndarray, *,
              intrinsics: Intrinsics | None = None, params: FitParams | None = None) -> list[PartFit]:
    """Find the instances of the part (mesh ``vertices_mm``, ``triangles``) in the zone.

    Segments the zone into candidate regions at depth discontinuities, fits each (closed form for a
    sphere mesh, else symmetry-aware initial guesses + point-to-plane ICP), accepts a fit by its
    residual and support and reassigns the pixels to the nearest fit (module docstring).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        Camera optical frame, mm; NaN where invalid.
    zone : (H, W) bool ndarray
        The pixels to explain.
    vertices_mm, triangles : (n, 3) float ndarray, (m, 3) int ndarray
        The part's mesh in its model frame (mm).
    intrinsics : (fx, fy, cx, cy) or None
        Pixels; None: estimated from the organized cloud.
    params : FitParams or None

    Returns
    -------
    list of PartFit
        Empty when the zone has no valid pixels.

    Raises
    ------
    zcut.errors.ParameterError
        The mesh is degenerate (one line).
    zcut.errors.InputShapeError
        An array has the wrong shape or dtype.
    zcut.errors.Cancelled
        Inside a :func:`zcut.cancel.stop_when` scope whose check said stop (no fits: none is partial).
    """
    params = FitParams() if params is None else params
    model = prepare_model(vertices_mm, triangles, sphere_tolerance=params.sphere_tolerance)
    return fit_prepared(xyz_mm, zone, model, intrinsics=intrinsics, params=params)
