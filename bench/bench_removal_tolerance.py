"""Benchmark: the removal's frame tolerance alone (:func:`zcut.removal.frame_tolerance`), this tree against another.

Run: ``.venv/bin/python bench/bench_removal_tolerance.py LOG... --against OLD_TREE [--frames N] [--repeats R]``

The frame tolerance is the removal's fixed work per frame (its sample is capped at
:data:`zcut.removal.MAX_RESIDUAL_PX` ring pixels): what keeps a 640 x 480 frame's cost per Mpx above the
1920 x 1200 frame's (issue 32 item 4). Each log's frames after the first (a warm-up) are located as the replay
locates them (not timed); then on each frame, ``R`` times, this tree's ``frame_tolerance`` and OLD_TREE's (its
``zcut`` imported as ``zcut_prev``, as ``bench/bench_removal.py --against`` imports it; the same prepared index)
run one after the other, the order swapped every repeat, with BLAS on one thread as the replay session has it.
Every field of the two tolerances (τ, its percentile, the counts, the reach, the off-field count, σ_bin and the
pixel angle) must be identical bit for bit. Prints CPU ms a call (``time.process_time``, all threads), medians,
and the ratio OLD / this. After it, OLD_TREE's numba cache names ``zcut_prev``: delete its ``*.nbi``/``*.nbc``
before importing it as ``zcut`` (``bench/bench_replay.py --against``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")  # as `zcut` sets it

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_removal import located_frames, previous_removal  # noqa: E402

from zcut.removal import frame_tolerance  # noqa: E402

#: the :class:`zcut.removal.Tolerance` fields compared (all but the kept query, ``surface``)
FIELDS = ("tolerance_mm", "residual_mm", "n_pixels", "n_coherent", "reach_mm", "n_off_field", "sigma_mm",
          "pixel_rad")


def measure(log: Path, frames: int, repeats: int, prev: Any) -> tuple[float, float, int, tuple[int, ...]]:
    """Median CPU s of this tree's and the previous tree's ``frame_tolerance`` on the log's frames after the first,
    the number of calls each and the frames' (H, W)."""
    s, located = located_frames(log, frames + 1)
    assert s.prepared is not None
    index = s.prepared.removal
    times: dict[str, list[float]] = {"this": [], "prev": []}
    with threadpool_limits(limits=1, user_api="blas"):
        for rep in range(repeats):
            for xyz, _, ring, T in located[1:]:
                T = np.asarray(T, np.float64)
                order = (("prev", prev), ("this", frame_tolerance))
                out = {}
                for name, f in order if rep % 2 == 0 else order[::-1]:
                    t0 = time.process_time()
                    out[name] = f(xyz, ring, index, T)
                    times[name].append(time.process_time() - t0)
                for field in FIELDS:
                    a, b = getattr(out["this"], field), getattr(out["prev"], field)
                    if np.float64(a).tobytes() != np.float64(b).tobytes():
                        raise SystemExit(f"{log.name}: the tolerance's {field} differs from the previous tree's: {a} {b}")
    return (statistics.median(times["this"]), statistics.median(times["prev"]), len(times["this"]),
            located[0][0].shape[:2])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path, nargs="+")
    ap.add_argument("--against", type=Path, required=True, help="source tree of the previous commit")
    ap.add_argument("--frames", type=int, default=5, help="frames measured after the first (default 5)")
    ap.add_argument("--repeats", type=int, default=8)
    args = ap.parse_args()
    previous_removal(args.against)  # imports OLD_TREE's zcut as zcut_prev
    from zcut_prev.removal import frame_tolerance as prev  # type: ignore[import-not-found]

    print(f"frame_tolerance, CPU ms a call (time.process_time, all threads), medians; prev = {args.against}")
    print(f"  {'log':28s} {'size':>10s} {'this':>8s} {'prev':>8s} {'prev/this':>10s} {'calls':>6s} {'load':>5s}")
    for log in args.log:
        this, old, n, (h, w) = measure(log, args.frames, args.repeats, prev)
        print(f"  {log.name:28s} {f'{w}x{h}':>10s} {1000 * this:8.2f} {1000 * old:8.2f} {old / this:10.2f} {n:6d} "
              f"{os.getloadavg()[0]:5.1f}", flush=True)
    print("every Tolerance field identical to the previous tree's on every call")


if __name__ == "__main__":
    main()
