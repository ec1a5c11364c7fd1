"""Benchmark: the replay's removal stage (the removal, then the bin check) of this tree against another tree's, both
in one process, the order swapped every other repetition.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_removal_stage.py --against OLD_TREE [--frames N] [--repeats R]
LOG ...`` (or ``--pieces`` instead of ``--against OLD_TREE``)

``OLD_TREE`` is a source tree of an earlier commit (``git archive COMMIT | tar -x -C OLD_TREE``); its ``zcut`` is
imported as ``zcut_prev`` (its numba cache then names ``zcut_prev``: do not share that tree with a bench that imports
it as ``zcut``). Each log's first N frames are located as the replay locates them (bin mask, registration: not timed;
``bench/bench_removal.py``'s ``located_frames``). On every frame both trees' results are first compared bit for bit (the
four class masks, the height image, the float32 cloud, τ, the radius, rim, floor and up; the bin check's count, flag,
reason, ghosts, off-surface count and candidates), then each tree's stage is timed R times per frame, alternating,
the process set up as ``zcut replay`` sets it (:func:`replay.process.configure_process`: without it glibc maps every
frame-sized array afresh and its page faults weigh on whichever tree allocates more) and BLAS on one thread. Prints CPU ms per frame (``time.process_time``, all threads: the machine is
shared), medians, the ratio previous / this, and the median of the per-frame paired ratios.

``--pieces`` (no ``--against``): where this tree's stage spends its CPU, each step of the fast
:func:`zcut.removal.remove_table_and_bin` (a floor that is a plane) timed in its place, in the order the function runs
them (the frame tolerance, the classes and heights in one pass, the straggler test's first pass and the later ones),
then the whole removal and the bin check, and the locator's :func:`zcut.removal.valid_pixels` of the same frame; CPU
ms a frame, medians over the frames × ``--repeats``, with the straggler test's candidates and the pixels it labelled.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from replay.process import configure_process  # noqa: E402

configure_process()  # as `zcut replay` sets itself up: its threading layer, one malloc arena, freed memory kept

import numpy as np  # noqa: E402
from bench_removal import located_frames, previous_removal  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from zcut.bin_check import check_bin_removal  # noqa: E402
from zcut.removal import remove_table_and_bin  # noqa: E402

ARRAYS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz")
SCALARS = ("tolerance_mm", "residual_mm", "radius_mm", "rim_m", "floor_m", "up_cam")


def _same(a: Any, b: Any) -> bool:
    x, y = np.asarray(a), np.asarray(b)
    return x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


def measure(log: Path, frames: int, repeats: int, prev: tuple[Any, Any]) -> str:
    """One line: the stage's CPU ms of both trees on ``log``'s first ``frames`` frames."""
    s, located = located_frames(log, frames)
    if not located:
        return f"{log.name}: no frame with a converged registration"
    assert s.prepared is not None
    index, params, band = s.prepared.removal, s.config.removal, s.config.zcut.max_depth
    trees = {"this": (remove_table_and_bin, check_bin_removal), "previous": prev}

    def stage(tree: str, xyz: np.ndarray, fp: np.ndarray, ring: np.ndarray, T: np.ndarray) -> tuple[float, Any, Any]:
        remove, check = trees[tree]
        t0 = time.process_time()
        rem = remove(xyz, fp, index=index, T_cam_bin=T, ring=ring)
        c = check(rem, ring, params=params, band_mm=band, xyz=xyz, index=index, T_cam_bin=T)
        return time.process_time() - t0, rem, c

    for i, (xyz, fp, ring, T) in enumerate(located):  # warm-up (numba) and the bit-for-bit check
        _, a, ca = stage("this", xyz, fp, ring, T)
        _, b, cb = stage("previous", xyz, fp, ring, T)
        for f in ARRAYS + SCALARS:
            if not _same(getattr(a, f), getattr(b, f)):
                raise SystemExit(f"{log.name} frame {i}: the removal's {f} differs from the previous tree's")
        if (ca.value, ca.flagged, ca.reason, ca.ghosts, ca.off_surface) != \
                (cb.value, cb.flagged, cb.reason, cb.ghosts, cb.off_surface) or not _same(ca.offending, cb.offending):
            raise SystemExit(f"{log.name} frame {i}: the bin check differs from the previous tree's")
    times: dict[str, list[float]] = {"this": [], "previous": []}
    paired = []
    for k in range(repeats):
        order = ("previous", "this") if k % 2 == 0 else ("this", "previous")
        for xyz, fp, ring, T in located:
            got = {}
            for tree in order:
                got[tree] = stage(tree, xyz, fp, ring, T)[0]
                times[tree].append(got[tree])
            paired.append(got["previous"] / got["this"])
    new, old = (1000 * statistics.median(times[t]) for t in ("this", "previous"))
    h, w = located[0][0].shape[:2]
    return (f"  {log.name[:32]:32s} {w:>5d}x{h:<4d} {len(located):6d} {old:9.2f} {new:9.2f} {old / new:9.3f} "
            f"{statistics.median(paired):9.3f} {os.getloadavg()[0]:6.1f}")


def pieces(log: Path, frames: int, repeats: int) -> None:
    """Print the stage's steps, each timed in its place (the module docstring's ``--pieces``)."""
    from zcut import removal as rm

    s, located = located_frames(log, frames)
    if not located:
        print(f"{log.name}: no frame with a converged registration")
        return
    assert s.prepared is not None
    index, params, band = s.prepared.removal, s.config.removal, s.config.zcut.max_depth
    p, planes = index.params, index.model.normals is not None
    if not p.robust or index.straggler is None:
        raise SystemExit("--pieces times the default removal (robust, with the straggler test)")
    times: dict[str, list[float]] = {}

    def timed(name: str, f: Any, *a: Any, **kw: Any) -> Any:
        t0 = time.process_time()
        out = f(*a, **kw)
        times.setdefault(name, []).append(time.process_time() - t0)
        return out

    for k in range(repeats + 1):  # the first round warms up (numba) and is not counted
        for xyz, fp, ring, T in located:
            timed("valid_pixels (the locator's)", rm.valid_pixels, xyz)
            t0 = time.process_time()
            a, fp, T = xyz, np.ascontiguousarray(fp), np.asarray(T, np.float64)
            R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
            up = R @ rm.BIN_UP
            floor = index.floor_b + float(t @ up)
            tol = timed("frame tolerance", rm.frame_tolerance, a, ring, index, T)
            delta_m = tol.tolerance_mm / 1000.0
            bound = rm.straggler_bound_args(p, tol, index.rim_b)
            radius_m = rm._radius(p, index.model.spacing_m, delta_m)
            straggler_m = p.straggler_m + delta_m
            r_str = max(radius_m, straggler_m)
            if p.search_radius_mm is None and np.isfinite(tol.reach_mm):
                radius_m = max(radius_m, tol.reach_mm / 1000.0)
                r_str = max(radius_m + p.straggler_m, straggler_m)
            r_bin = radius_m if planes else delta_m
            g, st = index.bin, index.straggler
            code = np.empty(fp.shape, np.uint8)
            table, easy, binp, zone = (np.empty(fp.shape, bool) for _ in range(4))
            height = np.empty(fp.shape, np.float64)
            rows = timed("classes and heights (one pass)", rm._classify_finish, a, fp, R, t,
                         index.rim_b + p.rim_offset_m, delta_m > 0, p.robust, *rm._grid_args(g), g.ijk, g.busy, g.box,
                         float(delta_m), float(r_bin), planes, float(floor), up, code, table, easy, binp, zone, height)
            grid = (*rm._grid_args(st), st.ijk, st.busy, st.box, float(straggler_m),
                    float(r_str if planes else straggler_m), planes, *bound)
            n = code.size
            buf = np.empty(n + (-n % 8), np.uint8)
            buf[n:] = 0
            passed = timed("stragglers: first pass", rm._straggler_first, a, code, int(p.straggler_neighbours), R, t,
                           *grid, buf[:n].reshape(code.shape))
            done = np.zeros(0, np.int64)
            if passed.any():
                done = timed("stragglers: later passes", rm._straggler_rest, a, code, buf.view(np.uint64),
                             int(p.straggler_neighbours), rm.STRAGGLER_PASSES, R, t, *grid)
                timed("stragglers: relabelled", rm._relabel_bin, a, done, float(floor), up, binp, zone, height, *rows)
            timed("the zone's top", rm._zone_top_of, *rows)
            times.setdefault("the steps together", []).append(time.process_time() - t0)
            rem = timed("removal (whole)", remove_table_and_bin, xyz, fp, index=index, T_cam_bin=T, ring=ring)
            timed("bin check", check_bin_removal, rem, ring, params=params, band_mm=band, xyz=xyz, index=index,
                  T_cam_bin=T)
            times.setdefault("stragglers: candidates (count)", []).append(float(np.count_nonzero(buf)))
            times.setdefault("stragglers: labelled (count)", []).append(float(len(done)))
        if k == 0:
            times.clear()
    h, w = located[0][0].shape[:2]
    print(f"{log.name}: {w}x{h}, {len(located)} frames x {repeats}; CPU ms a frame, medians; load average "
          f"{os.getloadavg()[0]:.1f}")
    for name, v in times.items():
        m = statistics.median(v)
        print(f"  {name:34s} {m:9.0f}" if name.endswith("(count)") else f"  {name:34s} {1000 * m:9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", type=Path, nargs="+", help="logs with their bin model attached")
    ap.add_argument("--against", type=Path, help="a source tree of an earlier commit")
    ap.add_argument("--pieces", action="store_true", help="this tree's steps in place instead (no --against)")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=6)
    args = ap.parse_args()
    if args.pieces:
        with threadpool_limits(limits=1, user_api="blas"):
            for log in args.logs:
                pieces(log, args.frames, args.repeats)
        return
    if args.against is None:
        ap.error("--against is required (or --pieces)")
    prev = previous_removal(args.against)
    print(f"the removal stage (removal + bin check), CPU ms per frame, medians; previous = {args.against}")
    print(f"  {'log':32s} {'size':>10s} {'frames':>6s} {'previous':>9s} {'this':>9s} {'prev/this':>9s} "
          f"{'paired':>9s} {'load':>6s}")
    with threadpool_limits(limits=1, user_api="blas"):
        for log in args.logs:
            print(measure(log, args.frames, args.repeats, prev), flush=True)


if __name__ == "__main__":
    main()
