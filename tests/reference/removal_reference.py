"""The previous removal (numpy + a numba grid search per point list), kept as the reference.

A verbatim copy of ``zcut.removal.remove_table_and_bin`` before it became fused numba kernels
(commit 9af0131): the fast version must give the same classes, height image and cloud. One
addition since: ``bin_first`` (the robust mode's order: a point near the model is bin before it
can be an easy outlier), written as literally as the rest; and ``straggler_err`` (issue 31 item 2:
the stragglers' distance bounded at each pixel by 3 of the bin's Err, ``zcut.removal.straggler_bound_m``), with
``straggler_top_m`` (the height above which no straggler is bounded: the ``"below_rim"`` bound).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from zcut.bin_model import BinModel
from zcut.removal import BIN_UP, STRAGGLER_PASSES, RemovalResult, check_removal_args, finite_xyz
from zcut.types import XYZ, Mask


@dataclass(frozen=True, slots=True)
class _ModelIndex:
    """Per-model search structures, built once: a grid of cells with their model points (CSR)."""

    cell: float
    origin: np.ndarray  # (3,) float64
    dims: np.ndarray  # (3,) int64
    start: np.ndarray  # (n_cells + 1,) int64: the points of cell c are order[start[c]:start[c + 1]]
    order: np.ndarray  # (N,) int64
    points: np.ndarray  # (N, 3) float64
    normals: np.ndarray  # (N, 3) float64 (zeros when the model has none)
    offsets: np.ndarray  # (N,) float64: n . m
    rim_b: float  # 99.5th percentile of the model's height (-z), bin frame
    floor_b: float  # 0.5th percentile


_INDEX: dict[tuple[int, float], tuple[np.ndarray, _ModelIndex]] = {}
GRID_CELL_M = 0.002


def _model_index(points: np.ndarray, normals: np.ndarray | None, radius: float) -> _ModelIndex:
    """Search structures of a model array, valid for search radii up to ``radius`` (cached)."""
    cell = max(GRID_CELL_M, float(radius))
    key = (id(points), cell)
    hit = _INDEX.get(key)
    if hit is not None and hit[0] is points:
        return hit[1]
    origin = points.min(axis=0) - 2 * cell
    ijk = np.floor((points - origin) / cell).astype(np.int64)
    dims = ijk.max(axis=0) + 3
    flat = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(flat, kind="stable").astype(np.int64)
    counts = np.bincount(flat, minlength=int(np.prod(dims)))
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    nrm = np.zeros_like(points) if normals is None else np.ascontiguousarray(normals, np.float64)
    h = -points[:, 2]
    index = _ModelIndex(cell, origin, dims.astype(np.int64), start, order,
                        np.ascontiguousarray(points, np.float64), nrm, np.einsum("ij,ij->i", points, nrm),
                        float(np.percentile(h, 99.5)), float(np.percentile(h, 0.5)))
    if len(_INDEX) >= 6:
        _INDEX.pop(next(iter(_INDEX)))
    _INDEX[key] = (points, index)
    return index


@numba.njit(parallel=True, cache=True)
def _grid_test(P, origin, cell, dims, start, order, pts, nrm, off, delta, radius, planes):  # pragma: no cover - numba
    """(M,) bool: some model point within ``radius`` passes (plane distance, or distance, <= delta[i])."""
    M = P.shape[0]
    ok = np.zeros(M, np.bool_)
    r2 = radius * radius
    for i in numba.prange(M):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            continue
        ci = int(np.floor((px - origin[0]) / cell))
        cj = int(np.floor((py - origin[1]) / cell))
        ck = int(np.floor((pz - origin[2]) / cell))
        # model points lie in cells 2 .. dims - 3: a point outside 1 .. dims - 2 is farther than a cell
        if ci < 1 or cj < 1 or ck < 1 or ci > dims[0] - 2 or cj > dims[1] - 2 or ck > dims[2] - 2:
            continue
        found = False
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    c = ((ci + dx) * dims[1] + (cj + dy)) * dims[2] + (ck + dz)
                    for s in range(start[c], start[c + 1]):
                        j = order[s]
                        ex = px - pts[j, 0]
                        ey = py - pts[j, 1]
                        ez = pz - pts[j, 2]
                        d2 = ex * ex + ey * ey + ez * ez
                        if d2 > r2:
                            continue
                        if planes:
                            d = abs(nrm[j, 0] * px + nrm[j, 1] * py + nrm[j, 2] * pz - off[j])
                        else:
                            d = np.sqrt(d2)
                        if d <= delta[i]:
                            found = True
                            break
                    if found:
                        break
                if found:
                    break
            if found:
                break
        ok[i] = found
    return ok


def _near_model(points: np.ndarray, model: np.ndarray, normals: np.ndarray | None, *,
                delta_m: float | np.ndarray, radius_m: float) -> np.ndarray:
    """(M,) bool: points within ``delta_m`` (one for all, or (M,): one per point) of the model surface.

    ``points`` and ``model`` in the same frame. With normals: some model point within ``radius_m``
    has its tangent plane within ``delta_m`` of the point; without: some model point lies within
    ``delta_m``. A grid of model points (cells of at least the radius) is searched in the 27 cells
    around each point, in parallel (numba).
    """
    if len(points) == 0 or len(model) == 0:
        return np.zeros(len(points), bool)
    planes = normals is not None
    radius = radius_m if planes else float(np.max(delta_m))  # per point: the farthest
    index = _model_index(model, normals, radius)
    return _grid_test(np.ascontiguousarray(points, np.float64), index.origin, index.cell, index.dims,
                      index.start, index.order, index.points, index.normals, index.offsets,
                      np.broadcast_to(np.asarray(delta_m, np.float64), (len(points),)).copy(), float(radius), planes)


_OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


def _straggler_passes(binp: Mask, table: Mask, valid: Mask, allowed: Mask, rows: np.ndarray,
                      cols: np.ndarray, p_bin: np.ndarray, model: BinModel, *, straggler_m: float,
                      radius_m: float, neighbours: int, bound_m: np.ndarray) -> None:
    """Grow ``binp`` (in place) along the noisy bin surface, see ``straggler_m``; a pixel's distance
    bound is ``bound_m`` there ((H, W) metres).

    Pass 1 looks at every allowed pixel; later passes only at the neighbours of the pixels the
    previous pass labelled (no other pixel's count of labelled neighbours changed, and a pixel
    once tested is not tested again: its distance to the model does not change).
    """
    import cv2

    H, W = valid.shape
    index = np.full(valid.shape, -1, np.int64)
    index[rows, cols] = np.arange(len(rows))
    index_f = index.reshape(-1)
    lab = (table | binp | ~valid).astype(np.uint8)  # invalid neighbours count as not zone
    n_lab = cv2.filter2D(lab, -1, np.ones((3, 3), np.float32), borderType=cv2.BORDER_CONSTANT) - lab
    cand = np.flatnonzero(allowed & ~binp & (n_lab >= neighbours))
    tried = np.zeros(H * W, bool)
    binp_f, lab_f, allowed_f = binp.reshape(-1), lab.reshape(-1), allowed.reshape(-1)
    for _ in range(STRAGGLER_PASSES):
        if cand.size == 0:
            break
        tried[cand] = True
        near = _near_model(p_bin[index_f[cand]], model.points, model.normals, delta_m=bound_m.reshape(-1)[cand],
                           radius_m=radius_m)
        new = cand[near]
        if new.size == 0:
            break
        binp_f[new] = True
        lab_f[new] = 1
        r, c = np.divmod(new, W)
        nr = (r[:, None] + _OFFSETS[None, :, 0]).ravel()
        nc = (c[:, None] + _OFFSETS[None, :, 1]).ravel()
        inb = (nr >= 0) & (nr < H) & (nc >= 0) & (nc < W)
        mark = np.zeros(H * W, bool)  # cheaper than np.unique on large passes
        mark[nr[inb] * W + nc[inb]] = True
        mark &= allowed_f & ~binp_f & ~tried
        nb = np.flatnonzero(mark)
        r, c = np.divmod(nb, W)
        count = np.zeros(len(nb), np.int64)
        for dr, dc in _OFFSETS:
            rr, cc = r + dr, c + dc
            ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
            count[ok] += lab[rr[ok], cc[ok]]
        cand = nb[count >= neighbours]


def remove_table_and_bin_reference(
    xyz: XYZ,
    footprint: Mask,
    *,
    model: BinModel | None = None,
    T_cam_bin: np.ndarray | None = None,
    delta_m: float = 1e-4,
    rim_offset_m: float = 0.005,
    search_radius_m: float | None = None,
    straggler_m: float = 0.0,
    straggler_neighbours: int = 5,
    bin_first: bool = False,
    straggler_radius_m: float | None = None,
    straggler_err: tuple[float, float] | None = None,
    straggler_top_m: float = np.inf,
) -> RemovalResult:
    """The removal as it was before the fused numba kernels (:func:`zcut.removal.remove_table_and_bin`
    has the same contract and parameters); kept to prove the fast path bit for bit.
    ``straggler_radius_m``: the stragglers' search radius (default the larger of the search radius
    and ``straggler_m``; the robust mode's measured radius gives its stragglers ``straggler_mm`` more).
    ``straggler_err``: ``(σ_bin m, the pixel's angle rad)``: a straggler is bin only within
    min(``straggler_m``, 3 × max(0.05 mm, √(σ_bin² + c²/2))) of the model, c = |z| × the angle the
    pixel's footprint (the robust mode's bound at 3 of the bin's Err); None: ``straggler_m``.
    ``straggler_top_m``: with ``straggler_err``, a pixel higher than this (its height -z in the bin frame, m) is not
    bounded (``straggler_m``); +inf: every pixel is."""
    a, fp = check_removal_args(
        xyz, footprint, model=model, T_cam_bin=T_cam_bin, delta_m=delta_m, rim_offset_m=rim_offset_m,
        straggler_m=straggler_m, straggler_neighbours=straggler_neighbours,
    )
    z64 = a[..., 2].astype(np.float64)
    valid = finite_xyz(a)
    table = valid & ~fp
    inside = valid & fp
    easy = np.zeros_like(valid)
    binp = np.zeros_like(valid)
    if model is None:
        up = BIN_UP.copy()
        rim = floor = float("nan")
        zfloor = np.full(z64.shape, np.nanmax(z64[valid]) if valid.any() else np.nan)
    else:
        T = np.asarray(T_cam_bin, dtype=np.float64)
        R, t = T[:3, :3], T[:3, 3]
        up = R @ BIN_UP
        # heights along up = -z in the bin frame; work in the bin frame so that the model's
        # KD-tree is built once per model, not once per frame
        mi = _model_index(model.points, model.normals, 0.0)
        rim_b, floor_b = mi.rim_b, mi.floor_b
        shift = float(t @ up)  # height of the bin origin along up, camera frame
        rim, floor = rim_b + shift, floor_b + shift
        rows, cols = np.nonzero(inside)
        p_bin = (a[rows, cols].astype(np.float64) - t) @ R
        h = -p_bin[:, 2]
        radius = search_radius_m if search_radius_m is not None else max(delta_m, 1.5 * model.spacing_m)
        radius = max(radius, delta_m, 1e-9)
        if bin_first:
            near = np.zeros(len(p_bin), bool)
            if delta_m > 0:
                near = _near_model(p_bin, model.points, model.normals, delta_m=delta_m, radius_m=radius)
            binp[rows[near], cols[near]] = True
            is_easy = ~near & (h > rim_b + rim_offset_m)
            easy[rows[is_easy], cols[is_easy]] = True
        else:
            is_easy = h > rim_b + rim_offset_m
            easy[rows[is_easy], cols[is_easy]] = True
            rest = np.flatnonzero(~is_easy)
            if delta_m > 0:
                near = _near_model(p_bin[rest], model.points, model.normals, delta_m=delta_m, radius_m=radius)
                binp[rows[rest[near]], cols[rest[near]]] = True
        if straggler_m > 0:
            bound = np.full(z64.shape, straggler_m)
            if straggler_err is not None:
                sigma, angle = straggler_err
                c = np.abs(z64) * angle  # the pixel's footprint (m)
                err = np.maximum(5e-5, np.sqrt(sigma * sigma + 0.5 * c * c))  # the bin's Err, at least 0.05 mm
                bound = np.minimum(straggler_m, 3.0 * err)
                height = np.full(z64.shape, -np.inf)
                height[rows, cols] = h  # -z in the bin frame, the pixels in the footprint
                bound = np.where(height > straggler_top_m, straggler_m, bound)
            _straggler_passes(binp, table, valid, inside & ~easy, rows, cols, p_bin, model,
                              straggler_m=straggler_m,
                              radius_m=max(radius, straggler_m) if straggler_radius_m is None else straggler_radius_m,
                              neighbours=int(straggler_neighbours), bound_m=bound)
        # floor plane {q : q . up = floor}: z at (x, y) solves x*ux + y*uy + z*uz = floor
        if abs(up[2]) > 1e-6:
            x64 = a[..., 0].astype(np.float64)
            y64 = a[..., 1].astype(np.float64)
            zfloor = (floor - x64 * up[0] - y64 * up[1]) / up[2]
        else:  # a bin seen from the side: fall back to the farthest point
            zfloor = np.full(z64.shape, np.nanmax(z64[valid]) if valid.any() else np.nan)
    labelled = table | easy | binp
    zone = valid & ~labelled
    z_new = np.where(labelled, zfloor, z64)
    height = -1000.0 * z_new
    height[~valid] = np.nan
    xyz_out = a.astype(np.float32, copy=True)
    xyz_out[..., 2] = np.where(labelled, zfloor, xyz_out[..., 2]).astype(np.float32)
    tol = float("nan") if model is None else delta_m * 1000.0
    return RemovalResult(table, easy, binp, zone, height, xyz_out, rim, floor, up, tol)
