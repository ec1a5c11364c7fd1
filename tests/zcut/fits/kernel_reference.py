"""The ICP kernel as it was before the ninth round (docs/fits.md, "Ninth round: cost"): the oracle the
kernel of :mod:`zcut.fits.kernels` must equal to the bit (its normal matrices summed in arrays, the
eigen-decomposition at every step with edges)."""

from __future__ import annotations

import numba
import numpy as np

from zcut.fits.kernels import _match, _match_edge, _rodrigues

__all__ = ["icp_kernel_reference"]


@numba.njit(cache=False, nogil=True)
def icp_kernel_reference(points: np.ndarray, R0: np.ndarray, t0: np.ndarray, iterations: int, gate_mm: float, k: float,
               floor_mm: float, edge_points: np.ndarray, edge_gate_mm: float, extent: float, origin: np.ndarray,
               h: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray,
               seg_grid: np.ndarray, p0: np.ndarray, p1: np.ndarray, weak: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Point-to-plane ICP of ``points`` (camera frame) from (R0, t0) (model -> camera): the steps of
    :func:`zcut.fits.icp.icp` (surface matches gated and facing the camera, the occluding boundary's
    ``edge_points`` matched to the sharp edges in the directions the surface leaves free — those of
    eigenvalue below ``weak`` × the largest of the surface's normal matrix — Cauchy weights) with the
    index's correspondences. (R, t, rms of the last step's matches, their number)."""
    R = R0.copy()
    t = t0.copy()
    gate = gate_mm
    rms = np.inf
    n_used = 0
    inv_h = 1.0 / h
    slack = 0.8660254037844386 * h
    use_edges = len(edge_points) > 0 and len(p0) > 0
    scale = np.array([extent, extent, extent, 1.0, 1.0, 1.0])
    H = np.zeros((6, 6))
    g = np.zeros(6)
    He = np.zeros((6, 6))
    ge = np.zeros(6)
    row = np.zeros(6)
    J = np.zeros((3, 6))
    J[0, 3] = J[1, 4] = J[2, 5] = 1.0
    res = np.zeros(3)
    for _ in range(iterations):
        H[:] = 0.0
        g[:] = 0.0
        # camera centre in the model frame: -R^T t
        camx = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2])
        camy = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2])
        camz = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2])
        ssq = 0.0
        n_used = 0
        for i in range(len(points)):
            px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
            qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
            qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
            qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
            j, d, r, cx, cy, cz = _match(qx, qy, qz, origin, inv_h, slack, grid, a, b, c, n)
            if j < 0 or not d < gate:
                continue
            nx, ny, nz = n[j, 0], n[j, 1], n[j, 2]
            if nx * (camx - cx) + ny * (camy - cy) + nz * (camz - cz) <= 0.0:
                continue
            row[0] = (qy * nz - qz * ny) / scale[0]
            row[1] = (qz * nx - qx * nz) / scale[1]
            row[2] = (qx * ny - qy * nx) / scale[2]
            row[3], row[4], row[5] = nx, ny, nz
            for u in range(6):
                g[u] += row[u] * r
                for w in range(u, 6):  # the upper triangle; the lower is the same products (mirrored below)
                    H[u, w] += row[u] * row[w]
            ssq += r * r
            n_used += 1
        if n_used < 6:
            break
        for u in range(1, 6):
            for w in range(u):
                H[u, w] = H[w, u]
        if use_edges:
            He[:] = 0.0
            ge[:] = 0.0
            ne = 0
            egate = max(edge_gate_mm, min(gate, 2.0 * edge_gate_mm))
            s3 = edge_gate_mm / 3.0
            for i in range(len(edge_points)):
                px, py, pz = edge_points[i, 0] - t[0], edge_points[i, 1] - t[1], edge_points[i, 2] - t[2]
                qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
                qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
                qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
                de, ex, ey, ez = _match_edge(qx, qy, qz, origin, inv_h, seg_grid, p0, p1)
                if not de < egate:
                    continue
                # a silhouette point lies on the part: a mixed pixel between it and what lies
                # behind (off every surface) says nothing of where the edge is
                js, ds, _, _, _, _ = _match(qx, qy, qz, origin, inv_h, slack, grid, a, b, c, n)
                if js < 0 or not ds < gate:
                    continue
                w2 = 1.0 / (1.0 + (de / s3) ** 2)
                # rows of d(q + w x q + tau)/d(w, tau) = [-[q]x, I], scaled (J reused, no allocation)
                J[0, 1], J[0, 2] = qz / scale[1], -qy / scale[2]
                J[1, 0], J[1, 2] = -qz / scale[0], qx / scale[2]
                J[2, 0], J[2, 1] = qy / scale[0], -qx / scale[1]
                res[0], res[1], res[2] = qx - ex, qy - ey, qz - ez
                for m in range(3):
                    for u in range(6):
                        ju = w2 * J[m, u]
                        if ju == 0.0:
                            continue
                        ge[u] += ju * res[m]
                        for w in range(6):
                            He[u, w] += ju * J[m, w]
                ne += 1
            if ne >= 3:
                ev, V = np.linalg.eigh(H)
                top = max(ev.max(), 1e-300)
                P = np.zeros((6, 6))
                nw = 0
                for u in range(6):
                    if ev[u] < weak * top:
                        P += np.outer(V[:, u], V[:, u])
                        nw += 1
                if nw:
                    H = H + P @ He @ P
                    g = g + P @ ge
        x = np.linalg.solve(H + 1e-12 * np.eye(6), -g) / scale
        dR = _rodrigues(x[0], x[1], x[2])
        Rinv = dR @ R.T
        tinv = dR @ (-(R.T @ t)) + x[3:]
        R = Rinv.T.copy()
        t = -(R @ tinv)
        rms = np.sqrt(ssq / n_used)
        gate = min(gate, max(k * rms, k * floor_mm, 0.5 * gate))
        # converged: the step moves no point of the model by a micron
        if max(np.abs(x[:3]).max() * extent, np.abs(x[3:]).max()) < 1e-3:
            break
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return R, t, rms, n_used
