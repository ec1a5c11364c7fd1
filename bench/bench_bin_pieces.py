"""Benchmark: the bin stages (bin mask, registration, removal) of a log taken apart, CPU ms per piece.

Run: ``.venv/bin/python bench/bench_bin_pieces.py LOG.mcap [--icp-repeats N]``

For each frame of the log (its own bin model attached) the frame is located as the replay locates it
(not timed), then each piece is timed alone on it (``time.process_time``, all threads; BLAS limited to
one thread as the replay session limits it): the bin mask, the bin pixels (``bin_pixels``), the ICP
target's preparation, the seed pose's fitness, the fine ICP from the seed pose (what a static bin
runs), the removal whole and its pieces (the frame tolerance and the query of the model for its
residuals, the classification, the straggler test's first pass and the passes after it, the masks and
height image), and the bin check. Medians and minima over the frames after the first (a warm-up).

``--warm`` also runs the fine ICP from the previous frame's pose (as a replay that carried each frame's pose
to the next would: a warm start) and prints, per frame, its CPU ms against the seed pose's, how far its pose
lies from the replay's (translation of the bin origin in mm, rotation in degrees) and whether the removal at
that pose gives the same masks and height image as at the replay's pose.

``--own-icp`` also runs the fine pass as a plain numpy point-to-plane ICP written after Open3D 0.20's
``registration_icp`` (correspondences from the prepared model's KD-tree, built once, instead of the tree Open3D
builds on every call; the same Jacobian, update and stopping rule) and prints how far its pose lies from
Open3D's, their fitness, RMSE and iterations, and both CPU times: the measure of whether such a step could
replace Open3D's (a prototype, not used by the pipeline).

``--icp-repeats N`` (default 6) also runs the fine ICP N times on the same frame and input and prints
how many distinct poses came back and the removal results they give (Open3D's ICP reduces over
threads in an order that varies: the pose may differ in its last bits from call to call).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")  # as `zcut` sets it

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from replay.pipeline import stages  # noqa: E402
from replay.pipeline.bin_model import bin_model_for  # noqa: E402
from replay.pipeline.session import ReplaySession  # noqa: E402
from zcut import removal as rm  # noqa: E402
from zcut.bin_check import check_bin_removal  # noqa: E402
from zcut.binmask import bin_mask, bin_pixels  # noqa: E402
from zcut.registration import pose_fitness, prepare_target, register_bin  # noqa: E402


def _euler(x: np.ndarray) -> np.ndarray:
    """Open3D's ``TransformVector6dToMatrix4d``: Rz(x[2]) Ry(x[1]) Rx(x[0]), translation x[3:]."""
    ca, sa, cb, sb, cc, sc = np.cos(x[0]), np.sin(x[0]), np.cos(x[1]), np.sin(x[1]), np.cos(x[2]), np.sin(x[2])
    U = np.eye(4)
    U[:3, :3] = (np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]]) @ np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
                 @ np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]))
    U[:3, 3] = x[3:]
    return U


def own_icp(src: np.ndarray, icp: Any, dist: float, T: np.ndarray, max_iterations: int
            ) -> tuple[np.ndarray, float, float, int]:
    """Point-to-plane ICP as Open3D 0.20's ``registration_icp`` runs it, on the prepared model's KD-tree:
    ``(T, fitness, rmse, iterations)``."""
    pts, nrm = np.asarray(icp.fine.points), np.asarray(icp.fine.normals)
    pcd = src @ T[:3, :3].T + T[:3, 3]

    def correspond(pcd: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        d, j = icp.tree.query(pcd, k=1, distance_upper_bound=dist)
        ok = np.isfinite(d)
        n = int(ok.sum())
        return ok, j, n / len(pcd), float(np.sqrt((d[ok] ** 2).sum() / n)) if n else 0.0

    ok, j, fit, rmse = correspond(pcd)
    its = 0
    for _ in range(max_iterations):
        its += 1
        vs, vt, nt = pcd[ok], pts[j[ok]], nrm[j[ok]]
        r = np.einsum("ij,ij->i", vs - vt, nt)
        J = np.concatenate([np.cross(vs, nt), nt], axis=1)
        U = _euler(np.linalg.solve(J.T @ J, -(J.T @ r)))
        T = U @ T
        pcd = pcd @ U[:3, :3].T + U[:3, 3]
        fit0, rmse0 = fit, rmse
        ok, j, fit, rmse = correspond(pcd)
        if abs(fit0 - fit) < 1e-6 and abs(rmse0 - rmse) < 1e-6:  # Open3D's relative_fitness, relative_rmse
            break
    return T, fit, rmse, its


def own_against_open3d(icp: Any, target: Any, c: Any, T_seed: np.ndarray) -> str:
    """The fine pass from ``T_seed`` by Open3D and by :func:`own_icp`: their poses' difference and CPU times."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    T0 = np.linalg.inv(T_seed)
    t0 = time.process_time()
    ref = reg.registration_icp(target.cloud, icp.fine, c.fine_correspondence_m, T0,
                               reg.TransformationEstimationPointToPlane(),
                               reg.ICPConvergenceCriteria(max_iteration=int(c.max_iterations)))
    t1 = time.process_time()
    T, fit, rmse, its = own_icp(np.asarray(target.cloud.points), icp, c.fine_correspondence_m, T0,
                                int(c.max_iterations))
    t2 = time.process_time()
    Tr = np.asarray(ref.transformation)
    return (f"own ICP off Open3D's by {1000 * np.abs(T[:3, 3] - Tr[:3, 3]).max():.1e} mm (rotation entries "
            f"{np.abs(T[:3, :3] - Tr[:3, :3]).max():.1e}); fitness {fit - ref.fitness:+.1e}, RMSE "
            f"{rmse - ref.inlier_rmse:+.1e} m; {its} iterations; Open3D {1000 * (t1 - t0):.1f} ms, own "
            f"{1000 * (t2 - t1):.1f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--icp-repeats", type=int, default=6)
    ap.add_argument("--warm", action="store_true", help="also the fine ICP from the previous frame's pose")
    ap.add_argument("--own-icp", action="store_true", help="also a numpy point-to-plane ICP against Open3D's")
    args = ap.parse_args()
    session = ReplaySession.open(args.log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg, pm = session.config, session.prepared
    assert pm is not None and session.seed is not None, "the log needs its bin model and a registered first frame"
    index, p, c = pm.removal, pm.removal.params, cfg.registration
    times: dict[str, list[float]] = {}
    distinct: list[str] = []
    warm: list[str] = []
    own: list[str] = []
    previous: np.ndarray | None = None

    def timed(name: str, f: Callable[..., Any], *a: Any, **k: Any) -> Any:
        t0 = time.process_time()
        out = f(*a, **k)
        times.setdefault(name, []).append(time.process_time() - t0)
        return out

    with threadpool_limits(1, "blas"):
        for i, frame in enumerate(session.reader.frames()):
            loc = stages.locate_bin(frame, cfg, bin_model=pm, seed=session.seed)
            if loc.registration is None or not loc.registration.converged:
                print(f"frame {i}: not registered, skipped", file=sys.stderr)
                continue
            a, T = frame.xyz, loc.registration.T_cam_bin
            bm = timed("bin mask", bin_mask, frame.rgb, params=cfg.bin_mask)
            ring = timed("registration: bin_pixels", bin_pixels, bm, a, ring_frac=c.ring_frac)
            s = max(1, int(np.ceil(np.sqrt(ring.sum() / stages.REGISTRATION_MAX_POINTS))))
            sub = a[::s, ::s][ring[::s, ::s]].astype(np.float64)  # ~0.1 ms, not timed
            target = timed("registration: prepare_target", prepare_target, sub, voxel_m=c.voxel_m,
                           intrinsics=frame.intrinsics)
            timed("registration: pose_fitness", pose_fitness, pm.icp, target, session.seed.T_cam_bin,
                  max_correspondence_m=c.fine_correspondence_m)
            timed("registration: fine ICP", register_bin, pm.icp, target, params=c, init=session.seed.T_cam_bin,
                  coarse=False)
            rem = timed("removal: whole", rm.remove_table_and_bin, a, loc.bin_mask.mask, index=index, T_cam_bin=T,
                        ring=loc.ring)
            if args.warm and previous is not None:
                w = timed("registration: fine ICP, warm start", register_bin, pm.icp, target, params=c, init=previous,
                          coarse=False)
                Tw = w.T_cam_bin
                rem_w = rm.remove_table_and_bin(a, loc.bin_mask.mask, index=index, T_cam_bin=Tw, ring=loc.ring)
                same = all(np.array_equal(getattr(rem, f), getattr(rem_w, f), equal_nan=True)
                           for f in ("table", "easy_outliers", "bin_points", "zone"))
                cos = np.clip((np.trace(T[:3, :3].T @ Tw[:3, :3]) - 1) / 2, -1.0, 1.0)
                warm.append(f"frame {i}: warm {1000 * times['registration: fine ICP, warm start'][-1]:.1f} ms, seed "
                            f"{1000 * times['registration: fine ICP'][-1]:.1f} ms; pose off the replay's by "
                            f"{1000 * np.linalg.norm(Tw[:3, 3] - T[:3, 3]):.2e} mm, {np.degrees(np.arccos(cos)):.1e} deg; "
                            f"masks {'the same' if same else 'DIFFER'}, height image "
                            f"{'the same' if np.array_equal(rem.height_mm, rem_w.height_mm, equal_nan=True) else 'differs'}, "
                            f"converged {w.converged}")
            previous = T
            if args.own_icp:
                own.append(f"frame {i}: " + own_against_open3d(pm.icp, target, c, session.seed.T_cam_bin))
            timed("removal: frame_tolerance", rm.frame_tolerance, a, loc.ring, index, T)
            flat = rm._ring_sample(a, loc.ring)
            nb = rm._ring_neighbours(a.shape[:2], loc.ring, flat, 4)
            mark = np.zeros(a.shape[0] * a.shape[1], bool)
            mark[flat] = True
            mark[nb[nb >= 0]] = True
            timed("removal:   the residuals' query", rm._query, a, np.flatnonzero(mark), index, T)
            R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
            planes = index.model.normals is not None
            code = np.empty(a.shape[:2], np.uint8)
            g = index.bin
            delta_m, r_bin = rem.tolerance_mm / 1000.0, rem.radius_mm / 1000.0
            timed("removal: classify", rm._classify_codes, a, loc.bin_mask.mask, R, t, index.rim_b + p.rim_offset_m,
                  delta_m > 0, p.robust, *rm._grid_args(g), g.ijk, g.busy, g.box, float(delta_m), float(r_bin),
                  planes, code)
            if index.straggler is not None:
                gs = index.straggler
                straggler_m = p.straggler_m + delta_m
                grid = (*rm._grid_args(gs), gs.ijk, gs.busy, gs.box, float(straggler_m),
                        float(max(r_bin + p.straggler_m, straggler_m)), planes)
                first = np.empty(code.shape, np.uint8)
                timed("removal: straggler first pass", rm._straggler_first, a, code, int(p.straggler_neighbours),
                      R, t, *grid, first)
                timed("removal: straggler later passes", rm._straggler_rest, a, code, first,
                      int(p.straggler_neighbours), rm.STRAGGLER_PASSES, R, t, *grid)
            masks = [np.empty(code.shape, bool) for _ in range(5)]
            timed("removal: finish (masks, heights)", rm._finish_codes, a, code, True, float(rem.floor_m),
                  rem.up_cam, float("nan"), *masks, np.empty(code.shape), np.empty(a.shape, np.float32))
            rim_in_view = min(loc.registration.n_rim / len(pm.icp.rim), 1.0) if len(pm.icp.rim) else 0.0
            timed("removal: bin check", check_bin_removal, rem, loc.ring, params=cfg.removal,
                  band_mm=cfg.zcut.max_depth, rim_in_view=rim_in_view, xyz=a, index=index, T_cam_bin=T)
            if args.icp_repeats > 1:
                poses = [register_bin(pm.icp, target, params=c, init=session.seed.T_cam_bin, coarse=False).T_cam_bin
                         for _ in range(args.icp_repeats)]
                outs = [rm.remove_table_and_bin(a, loc.bin_mask.mask, index=index, T_cam_bin=q, ring=loc.ring)
                        for q in poses]
                spread = max(float(np.abs(q - poses[0]).max()) for q in poses)
                distinct.append(
                    f"frame {i}: {len({q.tobytes() for q in poses})} distinct poses of {len(poses)} (max diff "
                    f"{spread:.1e}); their removals: masks {len({o.bin_points.tobytes() + o.zone.tobytes() + o.easy_outliers.tobytes() for o in outs})} distinct, "  # noqa: E501
                    f"height images {len({o.height_mm.tobytes() for o in outs})}, "
                    f"tolerances {len({o.tolerance_mm for o in outs})}")
    h, w = a.shape[:2]
    print(f"{args.log.name}: {w}x{h}, CPU ms per frame (medians over frames 1.., min)")
    for name, v in times.items():
        v = v[1:] or v
        print(f"  {name:36s} {1000 * statistics.median(v):7.1f}  (min {1000 * min(v):6.1f})")
    for line in distinct + warm + own:
        print(" ", line)


if __name__ == "__main__":
    main()
