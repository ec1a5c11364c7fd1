"""Benchmark: the bin removal (and the bin check after it) per frame, fast path against the previous one.

Run: ``.venv/bin/python bench/bench_removal.py [--sizes 640x480,1920x1200,3840x2400] [--frames N] [--repeats R]
[--kind KIND] [--dir DIR] [--log LOG ...] [--against OLD_TREE]``

For each size, synthesises (once, cached in ``--dir``) a log of N filled-bin frames of ``--kind`` (its own
bin model attached), locates the bin in each frame as the replay does (bin mask, registration: not
timed), then times on each frame, alternating, ``R`` times each (BLAS limited to one thread, as the
replay session limits it: a multi-threaded BLAS spins ~30 CPU-ms in the residuals' small matrix product):

- ``removal``: :func:`zcut.removal.remove_table_and_bin` with ``reference=True`` (the previous
  implementation) and without (the fast path);
- ``stage``: the replay's removal stage, the removal then :func:`zcut.bin_check.check_bin_removal` (which
  reads the frame tolerance's residuals from the fast removal instead of measuring them again).

It checks that both give the same classes, height image and cloud bit for bit (and τ, the percentile it came from,
the bin test's radius, the rim, floor and up direction), and prints CPU ms per
frame (``time.process_time``, all threads: the machine is shared, wall time is not compared), medians
over frames and repeats, the ratio previous / fast and the cost per Mpx. ``--log`` measures existing
logs (with their bin model) instead, at their own size.

``--against OLD_TREE`` (a source tree of an earlier commit, e.g. ``git archive COMMIT | tar -x -C OLD_TREE``)
also times that tree's fast path and its stage (its ``zcut`` imported as ``zcut_prev``, on the same prepared
index and frames, alternating with this tree's), checks they give the same results bit for bit (the classes,
heights, cloud and those scalars; the bin check's count, flag, reason, ghosts, off-surface count and pixels), and prints
their ratios to this tree's (``prev/new``). Its numba cache then names ``zcut_prev``: delete OLD_TREE's
``*.nbi``/``*.nbc`` before importing it as ``zcut`` (``bench_replay.py --against``). ``--holes`` measures the frames with large invalid regions instead: their
left half and every 7th row set to NaN after locating (the same footprint, ring and pose).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import tempfile
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
from replay.synth.log import write_synthetic_log  # noqa: E402
from zcut.bin_check import check_bin_removal  # noqa: E402
from zcut.removal import remove_table_and_bin  # noqa: E402

FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz")
#: ... and the scalars: τ, the percentile it came from, the bin test's radius (the tolerance's reach), the rim, floor, up
SCALARS = ("tolerance_mm", "residual_mm", "radius_mm", "rim_m", "floor_m", "up_cam")


def located_frames(log: Path, frames: int):
    """The session and ``[(xyz, footprint, ring, T)]`` of the log's first ``frames`` frames."""
    s = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    out = []
    for i, frame in enumerate(s.reader.frames()):
        if i >= frames:
            break
        loc = stages.locate_bin(frame, s.config, bin_model=s.prepared, seed=s.seed)
        if loc.registration is None or not loc.registration.converged:
            continue
        out.append((frame.xyz, loc.bin_mask.mask, loc.ring, loc.registration.T_cam_bin))
    return s, out


def previous_removal(tree: Path) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """The ``remove_table_and_bin`` and ``check_bin_removal`` of the source tree ``tree`` (its ``zcut`` imported
    as ``zcut_prev``)."""
    spec = importlib.util.spec_from_file_location("zcut_prev", tree / "zcut" / "__init__.py",
                                                  submodule_search_locations=[str(tree / "zcut")])
    if spec is None or spec.loader is None:
        raise SystemExit(f"{tree}: no zcut package there")
    module = importlib.util.module_from_spec(spec)
    sys.modules["zcut_prev"] = module
    spec.loader.exec_module(module)
    from zcut_prev.bin_check import check_bin_removal as prev_check  # type: ignore[import-not-found]
    from zcut_prev.removal import remove_table_and_bin as prev  # type: ignore[import-not-found]

    return prev, prev_check


def with_holes(xyz: np.ndarray) -> np.ndarray:
    """The frame with large invalid regions: its left half and every 7th row NaN."""
    a = xyz.copy()
    a[:, : a.shape[1] // 2] = np.nan
    a[::7] = np.nan
    return a


def measure(log: Path, frames: int, repeats: int, prev: tuple[Callable[..., Any], Callable[..., Any]] | None = None,
            holes: bool = False) -> dict[str, float]:
    s, located = located_frames(log, frames)
    if holes:
        located = [(with_holes(xyz), fp, ring, T) for xyz, fp, ring, T in located]
    assert s.prepared is not None
    index, params, band = s.prepared.removal, s.config.removal, s.config.zcut.max_depth
    times: dict[str, list[float]] = {"removal old": [], "removal new": [], "stage old": [], "stage new": [],
                                     "removal prev": [], "stage prev": []}

    def stage(xyz, fp, ring, T, reference: bool) -> tuple[float, float]:
        t0 = time.process_time()
        rem = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring, reference=reference)
        t1 = time.process_time()
        check_bin_removal(rem, ring, params=params, band_mm=band, xyz=xyz, index=index, T_cam_bin=T)
        return t1 - t0, time.process_time() - t0

    for xyz, fp, ring, T in located:  # warm-up (numba) and the bit-for-bit check
        old = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring, reference=True)
        new = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
        was = prev[0](xyz, fp, index=index, T_cam_bin=T, ring=ring) if prev is not None else None
        for f in FIELDS + SCALARS:
            if not np.array_equal(getattr(old, f), getattr(new, f), equal_nan=True):
                raise SystemExit(f"{log.name}: the fast removal's {f} differs from the previous one's")
            if was is not None and not np.array_equal(getattr(was, f), getattr(new, f), equal_nan=True):
                raise SystemExit(f"{log.name}: the removal's {f} differs from the previous tree's")
        if prev is not None:  # the bin check's verdict too
            c_new = check_bin_removal(new, ring, params=params, band_mm=band, xyz=xyz, index=index, T_cam_bin=T)
            c_prev = prev[1](was, ring, params=params, band_mm=band, xyz=xyz, index=index, T_cam_bin=T)
            if (c_new.value, c_new.flagged, c_new.reason, c_new.ghosts, c_new.off_surface) != \
                    (c_prev.value, c_prev.flagged, c_prev.reason, c_prev.ghosts, c_prev.off_surface) \
                    or not np.array_equal(c_new.offending, c_prev.offending):
                raise SystemExit(f"{log.name}: the bin check differs from the previous tree's")
    for _ in range(repeats):
        for xyz, fp, ring, T in located:
            for ref in (True, False):
                rem, st = stage(xyz, fp, ring, T, ref)
                times["removal old" if ref else "removal new"].append(rem)
                times["stage old" if ref else "stage new"].append(st)
            if prev is not None:
                t0 = time.process_time()
                rem = prev[0](xyz, fp, index=index, T_cam_bin=T, ring=ring)
                t1 = time.process_time()
                prev[1](rem, ring, params=params, band_mm=band, xyz=xyz, index=index, T_cam_bin=T)
                times["removal prev"].append(t1 - t0)
                times["stage prev"].append(time.process_time() - t0)
    h, w = located[0][0].shape[:2]
    return {k: 1000 * statistics.median(v) for k, v in times.items() if v} | {"mpx": h * w / 1e6, "w": w, "h": h,
                                                                         "frames": len(located)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="640x480,1920x1200", help="WxH,... (3840x2400 takes minutes to synthesise)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_removal"))
    ap.add_argument("--log", type=Path, nargs="+", help="existing logs (with their bin model) instead of synthetic ones")
    ap.add_argument("--against", type=Path, help="a source tree of an earlier commit: time its fast path too")
    ap.add_argument("--holes", action="store_true", help="the frames with large invalid regions")
    args = ap.parse_args()
    prev = previous_removal(args.against) if args.against is not None else None
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    logs = []
    if args.log is not None:
        logs.extend(args.log)
    else:
        for size in args.sizes.split(","):
            w, h = (int(v) for v in size.lower().split("x"))
            log = d / f"removal_{args.kind}_{args.frames}x{w}x{h}.mcap"
            if not log.is_file():
                print(f"synthesising {args.frames} frames of {args.kind} at {w}x{h} -> {log}")
                write_synthetic_log(log, kind=args.kind, frames=args.frames, seed=11, size=(h, w))
            logs.append(log)
    print("CPU ms per frame (time.process_time, all threads), medians; old = reference=True, new = fast path; "
          "stage = removal + bin check")
    if prev is not None:
        print(f"prev = the fast path of {args.against}")
    print(f"  {'log':32s} {'size':>10s} {'what':8s} {'old':>8s} {'new':>8s} {'old/new':>8s} {'old/Mpx':>8s} "
          f"{'new/Mpx':>8s}" + (f" {'prev':>8s} {'prev/new':>8s}" if prev is not None else ""))
    for log in logs:
        with threadpool_limits(limits=1, user_api="blas"):
            r = measure(log, args.frames, args.repeats, prev, args.holes)
        for what in ("removal", "stage"):
            o, n = r[f"{what} old"], r[f"{what} new"]
            extra = ""
            if prev is not None:
                extra = f" {r[what + ' prev']:8.1f} {r[what + ' prev'] / n:8.2f}"
            print(f"  {log.name[:32]:32s} {int(r['w']):>5d}x{int(r['h']):<4d} {what:8s} {o:8.1f} {n:8.1f} "
                  f"{o / n:8.2f} {o / r['mpx']:8.1f} {n / r['mpx']:8.1f}" + extra, flush=True)


if __name__ == "__main__":
    main()
