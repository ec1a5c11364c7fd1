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

``--against-open3d`` also registers every frame as the replay does (the seed pose's fine pass when it still
fits, else coarse then fine) a second time with Open3D's ``registration_icp`` (``register_bin(...,
reference=True)``), the two alternating in which runs first, and prints per frame how far the poses lie apart
(largest entry of the difference, relative to the largest entry), the fitness and RMSE of both, the iterations of
both passes (Open3D's counted from its debug log, :func:`zcut.icp_fast.icp_open3d`), whether the removal at the two
poses gives the same masks (table, easy outliers, bin points, zone), height image and tolerance, and both CPU ms;
then a summary line (largest relative pose difference, frames whose iterations or masks differ, medians of the
CPU ms).

``--against TREE`` instead alternates the bin mask (``bin_mask``) and the ring (``bin_pixels``) of this tree and of
the source tree TREE (its ``zcut`` imported under another name, without numba's cache) on every frame of the log,
``--repeats`` times, the order swapped every other call; every result is compared bit for bit (the masks, the
counts, the box, the centroid, the ring) and the CPU ms of each, medians, are printed with their ratio.

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


def replay_registration(pm: Any, target: Any, seed: Any, c: Any, *, reference: bool) -> Any:
    """The registration ``replay.pipeline.stages.locate_bin`` runs on a prepared target (the seed pose's fine
    pass when its fitness still holds, else the full coarse and fine one), with ``reference`` passed on."""
    init = seed.T_cam_bin if seed.converged and c.seed_from_first_frame else None
    if init is not None:
        f0 = pose_fitness(pm.icp, target, init, max_correspondence_m=c.fine_correspondence_m)
        if f0 >= stages.SEED_FITNESS_KEPT * seed.fitness:
            r = register_bin(pm.icp, target, params=c, init=init, coarse=False, reference=reference)
            if r.converged:
                return r
    return register_bin(pm.icp, target, params=c, reference=reference)


def open3d_iterations(pm: Any, target: Any, c: Any, reg: Any) -> tuple[int, ...]:
    """Open3D's iterations of each pass of ``reg`` (a reference registration), from its debug log: the passes
    run again from ``reg.T_init`` as :func:`register_bin` runs them."""
    from zcut.icp_fast import icp_open3d
    from zcut.registration import to_open3d, voxel_down

    T = np.linalg.inv(reg.T_init)
    passes = [(target.cloud, pm.icp.fine, c.fine_correspondence_m)]
    if len(reg.iterations) == 2:
        passes.insert(0, (voxel_down(to_open3d(target.cloud), 2.0 * c.voxel_m, "the target"), pm.icp.coarse,
                          c.max_correspondence_m))
    its = []
    for s_pc, d_pc, dist in passes:
        o = icp_open3d(np.asarray(s_pc.points), np.asarray(d_pc.points), np.asarray(d_pc.normals), max_distance=dist,
                       init=T, point_to_plane=c.method == "point_to_plane", max_iteration=int(c.max_iterations),
                       count_iterations=True)
        its.append(o.iterations)
        T = o.transformation
    return tuple(its)


def same_removal(a: Any, b: Any) -> tuple[bool, bool, bool]:
    """(masks, height image, tolerance) of two removals equal."""
    masks = all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("table", "easy_outliers", "bin_points", "zone"))
    return masks, bool(np.array_equal(a.height_mm, b.height_mm, equal_nan=True)), a.tolerance_mm == b.tolerance_mm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--icp-repeats", type=int, default=6)
    ap.add_argument("--warm", action="store_true", help="also the fine ICP from the previous frame's pose")
    ap.add_argument("--against-open3d", action="store_true",
                    help="also the replay's registration by Open3D (reference=True): poses, iterations, masks, CPU")
    ap.add_argument("--against", type=Path, help="a source tree: its bin mask and ring alternating with this tree's")
    ap.add_argument("--repeats", type=int, default=8, help="--against: calls of each a frame")
    args = ap.parse_args()
    if args.against is not None:
        against(args.log, args.against, args.repeats)
        return
    session = ReplaySession.open(args.log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg, pm = session.config, session.prepared
    assert pm is not None and session.seed is not None, "the log needs its bin model and a registered first frame"
    index, p, c = pm.removal, pm.removal.params, cfg.registration
    times: dict[str, list[float]] = {}
    distinct: list[str] = []
    warm: list[str] = []
    own: list[str] = []
    worst_rel, differ_its, differ_masks = 0.0, 0, 0
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
                seed_its = register_bin(pm.icp, target, params=c, init=session.seed.T_cam_bin, coarse=False).iterations
                warm.append(f"frame {i}: warm {1000 * times['registration: fine ICP, warm start'][-1]:.1f} ms "
                            f"({w.iterations[0]} iterations), seed {1000 * times['registration: fine ICP'][-1]:.1f} ms "
                            f"({seed_its[0]} iterations); pose off the replay's by "
                            f"{1000 * np.linalg.norm(Tw[:3, 3] - T[:3, 3]):.2e} mm, {np.degrees(np.arccos(cos)):.1e} deg; "
                            f"masks {'the same' if same else 'DIFFER'}, height image "
                            f"{'the same' if np.array_equal(rem.height_mm, rem_w.height_mm, equal_nan=True) else 'differs'}, "
                            f"converged {w.converged}")
            previous = T
            if args.against_open3d:
                runs = [("registration: replay's, new ICP", False), ("registration: replay's, Open3D", True)]
                out = {ref: timed(name, replay_registration, pm, target, session.seed, c, reference=ref)
                       for name, ref in (runs if i % 2 == 0 else runs[::-1])}
                new, o3d_reg = out[False], out[True]
                rel = float(np.abs(new.T_cam_bin - o3d_reg.T_cam_bin).max() / np.abs(o3d_reg.T_cam_bin).max())
                worst_rel = max(worst_rel, rel)
                o3d_its = open3d_iterations(pm, target, c, o3d_reg)
                differ_its += o3d_its != new.iterations
                same = same_removal(rm.remove_table_and_bin(a, loc.bin_mask.mask, index=index, T_cam_bin=new.T_cam_bin,
                                                            ring=loc.ring),
                                    rm.remove_table_and_bin(a, loc.bin_mask.mask, index=index,
                                                            T_cam_bin=o3d_reg.T_cam_bin, ring=loc.ring))
                differ_masks += not same[0]
                own.append(f"frame {i}: pose off Open3D's by {rel:.1e} (relative); fitness {new.fitness:.4f} / "
                           f"{o3d_reg.fitness:.4f}, icp fitness {new.icp_fitness:.6f} / {o3d_reg.icp_fitness:.6f}, RMSE "
                           f"{new.inlier_rmse * 1000:.9f} / {o3d_reg.inlier_rmse * 1000:.9f} mm; iterations "
                           f"{new.iterations} / {o3d_its}; masks {'the same' if same[0] else 'DIFFER'}, height image "
                           f"{'the same' if same[1] else 'differs'}, tolerance {'the same' if same[2] else 'differs'}; "
                           f"CPU {1000 * times[runs[0][0]][-1]:.1f} / {1000 * times[runs[1][0]][-1]:.1f} ms")
            tol = timed("removal: frame_tolerance", rm.frame_tolerance, a, loc.ring, index, T)
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
                # the bound's (σ_bin², the pixel's angle) as the removal passes them (none when off or not known)
                grid = (*rm._grid_args(gs), gs.ijk, gs.busy, gs.box, float(straggler_m),
                        float(max(r_bin + p.straggler_m, straggler_m)), planes,
                        *(rm.straggler_bound_args(p, tol) if p.robust else rm._NO_BOUND))
                n = code.size
                buf = np.zeros(n + (-n % 8), np.uint8)  # as zcut.removal._straggler_codes pads it
                timed("removal: straggler first pass", rm._straggler_first, a, code, int(p.straggler_neighbours),
                      R, t, *grid, buf[:n].reshape(code.shape))
                timed("removal: straggler later passes", rm._straggler_rest, a, code, buf.view(np.uint64),
                      int(p.straggler_neighbours), rm.STRAGGLER_PASSES, R, t, *grid)
            masks = [np.empty(code.shape, bool) for _ in range(4)]
            timed("removal: finish (masks, heights)", rm._finish_codes, a, code, True, float(rem.floor_m),
                  rem.up_cam, float("nan"), *masks, np.empty(code.shape))
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
    if args.against_open3d:
        new_ms = 1000 * statistics.median(times["registration: replay's, new ICP"])
        o3d_ms = 1000 * statistics.median(times["registration: replay's, Open3D"])
        print(f"  against Open3D: largest relative pose difference {worst_rel:.1e}; frames whose iterations differ "
              f"{differ_its}, whose masks differ {differ_masks}, of {len(own)}; CPU ms (median, all frames) "
              f"{new_ms:.1f} new, {o3d_ms:.1f} Open3D ({o3d_ms / new_ms:.2f} x)")


def against(log: Path, tree: Path, repeats: int) -> None:
    """The bin mask and the ring of every frame of ``log`` by this tree's ``zcut`` and by ``tree``'s, alternating
    ``repeats`` times a frame; every result compared bit for bit; CPU ms medians and their ratio."""
    import dataclasses
    import importlib
    import shutil
    import tempfile

    import zcut.binmask as this

    root = Path(tempfile.mkdtemp(prefix="zcut_against_"))
    shutil.copytree(tree / "zcut", root / "zcut_against", ignore=shutil.ignore_patterns("*.nbi", "*.nbc", "__pycache__"))
    sys.path.insert(0, str(root))
    prev = importlib.import_module("zcut_against.binmask")
    prev_params = importlib.import_module("zcut_against.params")
    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg = session.config
    params = {"this": cfg.bin_mask, "previous": prev_params.BinMaskParams(
        **{f.name: getattr(cfg.bin_mask, f.name) for f in dataclasses.fields(cfg.bin_mask)})}
    mods = {"this": this, "previous": prev}
    frames = list(session.reader.frames())
    times: dict[tuple[str, str], list[float]] = {}
    for rep in range(repeats):
        for i, frame in enumerate(frames):
            order = ["this", "previous"] if (rep + i) % 2 == 0 else ["previous", "this"]
            out = {}
            for name in order:
                t0 = time.process_time()
                bm = mods[name].bin_mask(frame.rgb, params=params[name])
                t1 = time.process_time()
                ring = mods[name].bin_pixels(bm, frame.xyz, ring_frac=cfg.registration.ring_frac)
                t2 = time.process_time()
                times.setdefault((name, "bin_mask"), []).append(t1 - t0)
                times.setdefault((name, "bin_pixels"), []).append(t2 - t1)
                out[name] = (bm, ring)
            (a, ra), (b, rb) = out["this"], out["previous"]
            assert np.array_equal(ra, rb), f"frame {i}: the rings differ"
            for f in ("mask", "walls"):
                assert np.array_equal(getattr(a, f), getattr(b, f)), f"frame {i}: {f} differs"
            for f in ("found", "area_px", "n_components", "bbox_rc", "covers_centre"):
                assert getattr(a, f) == getattr(b, f), f"frame {i}: {f} differs"
            assert np.array_equal(np.array(a.centroid_rc), np.array(b.centroid_rc), equal_nan=True), f"frame {i}"
    h, w = frames[0].rgb.shape[:2]
    print(f"{log.name}: {w}x{h}, {len(frames)} frames x {repeats} alternating calls, every result identical; "
          f"CPU ms a call (medians); load average {os.getloadavg()[0]:.1f}")
    for piece in ("bin_mask", "bin_pixels"):
        o = 1000 * statistics.median(times[("previous", piece)])
        n = 1000 * statistics.median(times[("this", piece)])
        print(f"  {piece:11s} previous {o:7.2f}  this {n:7.2f}  previous / this {o / n:5.2f}")


if __name__ == "__main__":
    main()
