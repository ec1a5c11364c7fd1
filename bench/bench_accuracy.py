"""Benchmark: the cost of docs/accuracy.md true accuracy — per-frame counting and the bootstrap intervals.

Run: ``.venv/bin/python bench/bench_accuracy.py [--repeat N] [--kinds spheres,black_screws] [--size 1200x1920]``

CPU time (``process_time``; the machine is shared), median of ``--repeat``, printed with ratios
against a reference measured in the same run:

1. **Counting one frame** (pixels, clusters >= 2 px, singletons, kinds) for the four methods of the
   report, on ``replay.synth.synthesize_frame(kind=...)`` frames with their exact truth and kind
   image, scored over the zone (bin floor and part pixels plus the above-the-rim points).
   Predictions: the z-cut at the paper's nominal parameters on the zone's heights, and SOR
   (k = 4, std_ratio = 1) on the zone's points. ``frame_accuracy`` (the truth checked and labelled
   once, :class:`zcut.metrics.ScoredTruth`) against the reference = four independent
   ``accuracy_counts`` calls (the truth checked and labelled per method). Both must agree.
2. **Bootstrap intervals** (2000 resamples) of pooled precision, recall and F1:
   ``bootstrap_ci_many`` (one matrix product and one sort per figure for a whole batch) against
   a per-row numpy reference (fancy-indexed resample sums + ``np.nanpercentile``, one row at a
   time) for the report (4 methods × 10 frames) and a sweep (100 grid points × 4 methods × 20
   frames), and against the literal Python loop (``tests/zcut/test_metrics.py``'s reference
   resampling) for the report case. The script checks the three agree and exits 1 otherwise.

BLAS is limited to one thread (``threadpoolctl``), as the replay session limits it: on a shared
2-core machine OpenBLAS's spinning threads cost ~20x the CPU time of the small matrix products.
"""

from __future__ import annotations

import argparse
import math
import sys
from functools import partial

import numpy as np
from threadpoolctl import threadpool_limits
from timing import cpu

from annotate.accuracy import METHODS, N_KINDS, frame_accuracy, method_masks
from zcut.cuts import zcut_outliers
from zcut.metrics import BOOTSTRAP_STATS, accuracy_counts, bootstrap_ci_many, ratio
from zcut.params import NOMINAL_MAX_DEPTH_MM, NOMINAL_RHO_THR, NOMINAL_STEP_MM
from zcut.sor import sor_outliers

N_BOOT = 2000


def synth_frames(kinds: list[str], size: tuple[int, int]):
    """(name, truth, kind image, zone, {"zcut", "sor"}) per synthetic part kind."""
    from replay.synth import synthesize_frame
    from replay.synth.outliers import OUTLIER_ABOVE_RIM
    from replay.synth.scene import LABEL_FLOOR, LABEL_PART

    for kind in kinds:
        sf = synthesize_frame(kind=kind, size=size)
        xyz = sf.frame.xyz.astype(np.float64)
        valid = np.isfinite(xyz).all(axis=2)
        above_rim = sf.outlier_kind == OUTLIER_ABOVE_RIM
        zone = (np.isin(sf.surface, (LABEL_FLOOR, LABEL_PART)) | above_rim) & valid
        height = np.where(zone & ~above_rim, -1000.0 * xyz[..., 2], np.nan)
        z = zcut_outliers(height, step=NOMINAL_STEP_MM, max_depth=NOMINAL_MAX_DEPTH_MM,
                          max_area=NOMINAL_RHO_THR * sf.a_max_px) | (above_rim & valid)
        s = sor_outliers(np.where(zone[..., None], xyz, np.nan), k=4, std_ratio=1.0)
        truth = sf.truth & valid
        yield kind, truth, np.where(truth, sf.outlier_kind, 0).astype(np.uint8), zone, valid, {"zcut": z, "sor": s}


def bench_counting(args) -> bool:
    ok = True
    print(f"1. counting one frame, 4 methods ({args.size[0]} x {args.size[1]}, CPU ms, median of {args.repeat})")
    print(f"{'frame':<10} {'truth px':>9} {'zcut px':>9} {'sor px':>9} {'frame_accuracy':>15} "
          f"{'4x accuracy_counts':>19} {'ratio':>6}")
    for name, truth, kinds, zone, valid, preds in synth_frames(args.kinds, args.size):
        t_fast, fa = cpu(partial(frame_accuracy, 0, 0, preds, truth, valid=valid, region=zone, kinds=kinds),
                         args.repeat)
        t_ref, ref = cpu(partial(four_calls, method_masks(preds["zcut"], preds["sor"]), truth, valid=valid,
                                 region=zone, kinds=kinds), args.repeat)
        if ref != fa.counts:
            print(f"MISMATCH on {name}: frame_accuracy differs from accuracy_counts")
            ok = False
        print(f"{name:<10} {int(truth.sum()):>9} {int(preds['zcut'].sum()):>9} {int(preds['sor'].sum()):>9} "
              f"{1e3 * t_fast:>15.1f} {1e3 * t_ref:>19.1f} {t_ref / t_fast:>6.2f}")
    return ok


def four_calls(masks, truth, **kw):
    """The reference: one independent ``accuracy_counts`` per method."""
    return {m: accuracy_counts(masks[m], truth, n_kinds=N_KINDS, **kw) for m in METHODS}


def per_row_reference(tp, fp, fn, *, n_boot: int, seed: int) -> dict[str, np.ndarray]:
    """One row at a time: the resampled sums by fancy indexing, then ``np.nanpercentile``."""
    rows, n = tp.shape
    draws = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
    out = {k: np.full((rows, 2), np.nan) for k in BOOTSTRAP_STATS}
    with np.errstate(invalid="ignore", divide="ignore"):
        for r in range(rows):
            t, f_p, f_n = tp[r][draws].sum(1), fp[r][draws].sum(1), fn[r][draws].sum(1)
            for k, num, den in (("precision", t, t + f_p), ("recall", t, t + f_n), ("f1", 2 * t, 2 * t + f_p + f_n)):
                stat = num / den
                if not np.isnan(stat).all():
                    out[k][r] = np.nanpercentile(stat, [2.5, 97.5])
    return out


def python_loop(tp, fp, fn, *, n_boot: int, seed: int) -> dict[str, np.ndarray]:
    """The literal resampling, one resample, one frame at a time (pure Python sums)."""
    rows, n = tp.shape
    draws = np.random.default_rng(seed).integers(0, n, size=(n_boot, n)).tolist()
    out = {k: np.full((rows, 2), np.nan) for k in BOOTSTRAP_STATS}
    for r in range(rows):
        t_r, fp_r, fn_r = tp[r].tolist(), fp[r].tolist(), fn[r].tolist()
        vals = {k: [] for k in BOOTSTRAP_STATS}
        for frames in draws:
            t = sum(t_r[i] for i in frames)
            f_p = sum(fp_r[i] for i in frames)
            f_n = sum(fn_r[i] for i in frames)
            for k, v in (("precision", ratio(t, t + f_p)), ("recall", ratio(t, t + f_n)),
                         ("f1", ratio(2 * t, 2 * t + f_p + f_n))):
                if not math.isnan(v):
                    vals[k].append(v)
        for k, v in vals.items():
            if v:
                out[k][r] = np.percentile(v, [2.5, 97.5])
    return out


def same(a: dict, b: dict) -> bool:
    return all(np.allclose(a[k], b[k], rtol=1e-12, atol=0, equal_nan=True) for k in BOOTSTRAP_STATS)


def bench_bootstrap(args) -> bool:
    ok = True
    rng = np.random.default_rng(0)
    print(f"\n2. bootstrap intervals ({N_BOOT} resamples, CPU ms, median of {args.repeat})")
    print(f"{'case':<34} {'bootstrap_ci_many':>18} {'per-row numpy':>14} {'ratio':>7} {'python loop':>12} {'ratio':>7}")
    for case, rows, n in (("report: 4 methods x 10 frames", 4, 10),
                          ("sweep: 100 points x 4 methods x 20", 400, 20)):
        tp, fp, fn = (rng.integers(0, 5000, (rows, n)) for _ in range(3))
        fp[:, : n // 2] = 0  # half the frames without false positives (0/0 precision in some resamples)
        tp[:, : n // 4] = 0
        counts = (tp, fp, fn)
        t_fast, fast = cpu(partial(bootstrap_ci_many, *counts, n_boot=N_BOOT, seed=0), args.repeat)
        t_row, row = cpu(partial(per_row_reference, *counts, n_boot=N_BOOT, seed=0), 1 if rows > 10 else args.repeat)
        ok &= same(fast, row)
        loop = "-"
        ratio_loop = "-"
        if rows <= 10:
            t_loop, slow = cpu(partial(python_loop, *counts, n_boot=N_BOOT, seed=0), 1)
            ok &= same(fast, slow)
            loop, ratio_loop = f"{1e3 * t_loop:.1f}", f"{t_loop / t_fast:.0f}"
        print(f"{case:<34} {1e3 * t_fast:>18.1f} {1e3 * t_row:>14.1f} {t_row / t_fast:>7.1f} {loop:>12} {ratio_loop:>7}")
    if not ok:
        print("MISMATCH: the bootstrap implementations disagree")
    return ok


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--kinds", default="spheres,black_screws", help="synthetic part kinds for the counting benchmark")
    p.add_argument("--size", default="1200x1920", help="H x W of the synthetic frames")
    args = p.parse_args()
    args.kinds = [k for k in args.kinds.split(",") if k]
    args.size = tuple(int(v) for v in args.size.lower().split("x"))
    with threadpool_limits(limits=1, user_api="blas"):
        ok = bench_counting(args) & bench_bootstrap(args)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
