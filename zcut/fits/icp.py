"""Initial guesses and point-to-plane ICP of one instance of a general part.

The measured points are moved into the model frame (the model's samples sit in a k-d tree built
once) and matched to their nearest surface sample; matches farther than the gate, or on a face
turned away from the camera, are ignored; each step solves the linearised point-to-plane problem
(6 × 6) exactly and composes the rotation by Rodrigues' formula.

Initial guesses (:func:`initial_rotations`): the region's principal axes matched to the model's in
the 24 proper signed permutations, and the same turned by 45° about the region's normal (its
least-variance axis: a flat face's in-plane turn is what its points leave free), the equivalent
ones under the model's symmetries dropped; the translation puts the centroid of the
model's camera-facing samples on the region's centroid.
"""

from __future__ import annotations

import numpy as np

from .kernels import farthest_points, icp_kernel
from .model import PartModel

__all__ = ["guess_translations", "icp", "icp_reference", "initial_pose", "initial_poses", "initial_rotations", "pose_matrix",
           "shifted_guesses", "shifted_poses"]


#: The silhouette's edges act in the directions whose eigenvalue of the surface's (normalised)
#: normal matrix is below this share of the largest (a flat face seen head-on: its turn and slide).
#: 1e-2 let the pixel-quantised silhouette override side faces and bore facets that hold the turn
#: (hand-made zinc nuts seen within 10° of head-on, ICP from the true pose turned 6°: 3.5° off,
#: 1.5° at 1e-3); 1e-4 left a clean head-on nut's turn to the guess alone.
EDGE_WEAK = 1e-3


def pose_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rodrigues(w: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(w))
    if a < 1e-15:
        return np.eye(3)
    k = w / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)
    return R


def initial_rotations(points: np.ndarray, model: PartModel, *, axes: np.ndarray | None = None) -> list[np.ndarray]:
    """Rotations (model -> camera) aligning the model's principal axes with the points', one per
    class of equivalent ones under the model's symmetries; those that put the model's least-variance
    axis on the points' (a part lying as it shows itself) first (the classes are the model's own,
    computed once: :attr:`PartModel.guesses`).

    ``axes``: the points' principal axes as the caller already has them, ``np.linalg.eigh(np.cov((points -
    points.mean(axis=0)).T))[1]`` (ascending variance; not modified), else computed here the same way."""
    if axes is None:
        c = points.mean(axis=0)
        _, axes = np.linalg.eigh(np.cov((points - c).T))
    ax = axes[:, ::-1].copy()
    if np.linalg.det(ax) < 0:
        ax[:, 2] = -ax[:, 2]
    return list(np.einsum("ij,kjl->kil", ax, model.guesses))


def initial_pose(points: np.ndarray, R: np.ndarray, model: PartModel) -> np.ndarray:
    """The pose with rotation ``R`` that puts the centroid of the model's camera-facing samples
    (seen along the direction of the points' centroid; an even subsample of them) on the points'
    centroid."""
    c = points.mean(axis=0)
    view = c / max(float(np.linalg.norm(c)), 1e-9)
    facing = (model.probe_normals @ R.T) @ view < 0
    front = model.probe_samples[facing] if facing.any() else model.probe_samples
    return pose_matrix(R, c - R @ front.mean(axis=0))


def initial_poses(points: np.ndarray, rotations: list[np.ndarray], model: PartModel) -> list[np.ndarray]:
    """:func:`initial_pose` of each rotation, in one pass."""
    if not rotations:
        return []
    c = points.mean(axis=0)
    view = c / max(float(np.linalg.norm(c)), 1e-9)
    Rs = np.stack(rotations)
    facing = model.probe_normals @ (Rs.transpose(0, 2, 1) @ view).T < 0  # (s, g): n·(Rᵀ view) = (R n)·view
    facing = facing.T
    counts = facing.sum(axis=1)
    sums = facing.astype(np.float64) @ model.probe_samples
    allm = model.probe_samples.mean(axis=0)
    front = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], allm)
    return [pose_matrix(R, c - R @ f) for R, f in zip(Rs, front)]


def shifted_poses(points: np.ndarray, rotations: list[np.ndarray], model: PartModel, n: int) -> list[np.ndarray]:
    """For each rotation, ``n`` poses that put ``n`` spread camera-facing samples of the model (farthest
    point sampling from the first facing one) on the points' centroid: the guesses of a region that
    shows only part of an instance (a partly occluded part), whose centroid is not the centroid of the
    model's whole facing side (:func:`initial_poses`) but may lie anywhere on it."""
    if n < 1 or not rotations:
        return []
    c = points.mean(axis=0)
    view = c / max(float(np.linalg.norm(c)), 1e-9)
    out: list[np.ndarray] = []
    for R in rotations:
        facing = (model.probe_normals @ R.T) @ view < 0
        fs = model.probe_samples[facing]
        if not len(fs):
            continue
        sel = farthest_points(np.ascontiguousarray(fs), min(n, len(fs)))  # the NumPy loop's indices, one call
        out.extend(pose_matrix(R, c - R @ fs[j]) for j in sel)
    return out


def guess_translations(points: np.ndarray, Rs: np.ndarray, model: PartModel) -> np.ndarray:
    """(k, 3) the translations of :func:`initial_poses` for the rotations ``Rs`` (k, 3, 3), C-contiguous, without
    a 4 × 4 matrix per guess: the same arithmetic (NumPy's stacked matmul gives each R @ f as the product of one
    pair does), so the same bits."""
    c = points.mean(axis=0)
    view = c / max(float(np.linalg.norm(c)), 1e-9)
    facing = model.probe_normals @ (Rs.transpose(0, 2, 1) @ view).T < 0
    facing = facing.T
    counts = facing.sum(axis=1)
    sums = facing.astype(np.float64) @ model.probe_samples
    allm = model.probe_samples.mean(axis=0)
    front = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], allm)
    out: np.ndarray = c - (Rs @ front[:, :, None])[:, :, 0]
    return out


def shifted_guesses(points: np.ndarray, Rs: np.ndarray, model: PartModel, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (m, 3, 3), translations (m, 3)) of :func:`shifted_poses` for the rotations ``Rs`` (k, 3, 3),
    C-contiguous, in its order, without a 4 × 4 matrix per guess (the same bits, as
    :func:`guess_translations`)."""
    if n < 1 or not len(Rs):
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    c = points.mean(axis=0)
    view = c / max(float(np.linalg.norm(c)), 1e-9)
    rs: list[np.ndarray] = []
    fronts: list[np.ndarray] = []
    for R in Rs:
        facing = (model.probe_normals @ R.T) @ view < 0
        fs = model.probe_samples[facing]
        if not len(fs):
            continue
        sel = farthest_points(np.ascontiguousarray(fs), min(n, len(fs)))
        rs.append(np.repeat(R[None], len(sel), axis=0))
        fronts.append(fs[sel])
    if not rs:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    R_all = np.concatenate(rs)
    out: np.ndarray = c - (R_all @ np.concatenate(fronts)[:, :, None])[:, :, 0]
    return R_all, out


def _skew_rows(q: np.ndarray) -> np.ndarray:
    """(3n, 6) Jacobian rows of q + ω × q + τ with respect to (ω, τ): [−[q]×, I] per point."""
    n = len(q)
    J = np.zeros((n, 3, 6))
    J[:, 0, 1], J[:, 0, 2] = q[:, 2], -q[:, 1]
    J[:, 1, 0], J[:, 1, 2] = -q[:, 2], q[:, 0]
    J[:, 2, 0], J[:, 2, 1] = q[:, 1], -q[:, 0]
    J[:, 0, 3] = J[:, 1, 4] = J[:, 2, 5] = 1.0
    return J.reshape(3 * n, 6)


def icp(points: np.ndarray, model: PartModel, T0: np.ndarray, *, iterations: int, gate_mm: float,
        k: float, floor_mm: float, edge_points: np.ndarray | None = None,
        edge_gate_mm: float = 1.0, robust_mm: float = 0.0) -> tuple[np.ndarray, float, int]:
    """Refine ``T0`` (model -> camera) on ``points`` (n, 3), camera frame: :func:`icp_reference`'s
    steps in one kernel (:func:`zcut.fits.kernels.icp_kernel`), the correspondences through the
    model's voxel index (the model without one: :func:`icp_reference`)."""
    ix = model.index
    if ix is None:
        return icp_reference(points, model, T0, iterations=iterations, gate_mm=gate_mm, k=k, floor_mm=floor_mm,
                             edge_points=edge_points, edge_gate_mm=edge_gate_mm, robust_mm=robust_mm)
    e = np.zeros((0, 3)) if edge_points is None else np.ascontiguousarray(edge_points, np.float64)
    R, t, rms, n = icp_kernel(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(T0[:3, :3], np.float64),
                              np.ascontiguousarray(T0[:3, 3], np.float64), int(iterations), float(gate_mm), float(k),
                              float(floor_mm), e, float(edge_gate_mm), float(model.extent_mm), ix.origin, ix.h,
                              ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri, ix.seg_grid, ix.p0, ix.p1, EDGE_WEAK,
                              float(robust_mm))
    return pose_matrix(R, t), float(rms), int(n)


def icp_reference(points: np.ndarray, model: PartModel, T0: np.ndarray, *, iterations: int, gate_mm: float,
                  k: float, floor_mm: float, edge_points: np.ndarray | None = None,
                  edge_gate_mm: float = 1.0, robust_mm: float = 0.0) -> tuple[np.ndarray, float, int]:
    """Refine ``T0`` (model -> camera) on ``points`` (n, 3), camera frame (the matches: the nearest of
    the model's surface samples, a k-d tree query per step).

    ``edge_points`` (camera frame): points on the region's occluding boundary, matched point to point
    to the model's sharp edges (:attr:`PartModel.edges`) within ``edge_gate_mm``; they hold what the
    surface alone leaves free (a flat face seen head-on: its turn about its normal, its slide).

    ``robust_mm`` > 0: the surface matches weighted by Tukey's biweight of their distance at that scale
    (none beyond it), re-weighted at every step; the rms stays unweighted. 0: no weights.

    Returns
    -------
    T : (4, 4) ndarray
    rms_mm : float
        RMS point-to-plane residual of the last step's surface matches.
    n_matched : int
        Number of surface matches of the last step.
    """
    R = T0[:3, :3].copy()
    t = T0[:3, 3].copy()
    gate = gate_mm
    rms = np.inf
    n_used = 0
    use_edges = edge_points is not None and len(edge_points) > 0 and len(model.edges) > 0
    scale = np.array([model.extent_mm] * 3 + [1.0] * 3)
    weak = 1e-2
    for _ in range(iterations):
        q = (points - t) @ R  # model frame
        d, idx = model.nearest_samples(q)
        m = model.samples[idx]
        n = model.normals[idx]
        cam = -R.T @ t
        use = (d < gate) & (np.einsum("ij,ij->i", n, cam - m) > 0)
        n_used = int(use.sum())
        if n_used < 6:
            break
        qu, mu, nu = q[use], m[use], n[use]
        r = np.einsum("ij,ij->i", qu - mu, nu)
        A = np.c_[np.cross(qu, nu), nu]
        An = A / scale  # normalised unknowns xn = (extent · ω, τ)
        if robust_mm > 0:  # Tukey's biweight of the distance: rows and residuals times sqrt(w)
            sw = np.clip(1.0 - (d[use] / robust_mm) ** 2, 0.0, None)
            Hn = (An * sw[:, None]).T @ (An * sw[:, None])
            gn = (An * sw[:, None]).T @ (r * sw)
        else:
            Hn = An.T @ An
            gn = An.T @ r
        if use_edges:
            assert edge_points is not None
            qe = (edge_points - t) @ R
            de, ie = model.nearest_edges(qe)
            ue = de < max(edge_gate_mm, min(gate, 2 * edge_gate_mm))
            if ue.sum() >= 3:
                # Cauchy weights at a third of the gate: the silhouette is quantised to pixels and
                # a boundary point may be no edge at all (a steep wall cut by the segmentation)
                sw = np.repeat(1.0 / np.sqrt(1.0 + (de[ue] / (edge_gate_mm / 3.0)) ** 2), 3)
                # the edges act only in the directions the surface leaves (nearly) free
                ev, V = np.linalg.eigh(Hn)
                Vw = V[:, ev < weak * max(float(ev.max()), 1e-300)]
                if Vw.shape[1]:
                    P = Vw @ Vw.T
                    Jn = _skew_rows(qe[ue]) / scale * sw[:, None]
                    re = (qe[ue] - model.edges[ie[ue]]).reshape(-1) * sw
                    Hn = Hn + P @ (Jn.T @ Jn) @ P
                    gn = gn + P @ (Jn.T @ re)
        x = np.linalg.solve(Hn + 1e-12 * np.eye(6), -gn) / scale
        dR = _rodrigues(x[:3])
        dt = x[3:]
        # q' = dR q + dt  =>  inverse pose Rinv' = dR R^T, tinv' = dR (-R^T t) + dt
        Rinv = dR @ R.T
        tinv = dR @ (-R.T @ t) + dt
        R = Rinv.T
        t = -R @ tinv
        rms = float(np.sqrt(np.mean(r * r)))
        gate = min(gate, max(k * rms, k * floor_mm, 0.5 * gate))
        if np.abs(x).max() < 1e-6:
            break
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return pose_matrix(R, t), rms, n_used
