"""Benchmark: the replay's removal stage (the removal, then the bin check) of this tree against another tree's, both
in one process, the order swapped every other repetition.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_removal_stage.py --against OLD_TREE [--frames N] [--repeats R]
LOG ...``

``OLD_TREE`` is a source tree of an earlier commit (``git archive COMMIT | tar -x -C OLD_TREE``); its ``zcut`` is
imported as ``zcut_prev`` (its numba cache then names ``zcut_prev``: do not share that tree with a bench that imports
it as ``zcut``). Each log's first N frames are located as the replay locates them (bin mask, registration: not timed;
``bench/bench_removal.py``'s ``located_frames``). On every frame both trees' results are first compared bit for bit (the
four class masks, the height image, the float32 cloud, τ, the radius, rim, floor and up; the bin check's count, flag,
reason, ghosts, off-surface count and candidates), then each tree's stage is timed R times per frame, alternating,
the process set up as ``zcut replay`` sets it (:func:`replay.process.configure_process`: without it glibc maps every
frame-sized array afresh and its page faults weigh on whichever tree allocates more) and BLAS on one thread. Prints CPU ms per frame (``time.process_time``, all threads: the machine is
shared), medians, the ratio previous / this, and the median of the per-frame paired ratios.
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", type=Path, nargs="+", help="logs with their bin model attached")
    ap.add_argument("--against", type=Path, required=True, help="a source tree of an earlier commit")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=6)
    args = ap.parse_args()
    prev = previous_removal(args.against)
    print(f"the removal stage (removal + bin check), CPU ms per frame, medians; previous = {args.against}")
    print(f"  {'log':32s} {'size':>10s} {'frames':>6s} {'previous':>9s} {'this':>9s} {'prev/this':>9s} "
          f"{'paired':>9s} {'load':>6s}")
    with threadpool_limits(limits=1, user_api="blas"):
        for log in args.logs:
            print(measure(log, args.frames, args.repeats, prev), flush=True)


if __name__ == "__main__":
    main()
