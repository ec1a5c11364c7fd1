"""Synthetic scans: time per frame, and the paper's headline as true recall (z-cut vs SOR).

    .venv/bin/python bench/bench_synth.py [--size 1920x1200] [--seeds 2] [--kinds spheres,rods]

For each part kind: wall and CPU seconds per synthesised frame (the CPU time is what the machine's
load does not inflate), then, on the parts and the bin floor (paper §5.2: table and bin removed),
the nominal z-cut (step 0.2 mm, max depth 30 mm, rho 0.07 of a_max) and SOR (k = 4, 1 sd) against
the exact ground truth: share of floating clusters at least half found, share of their pixels
found, recall over all true outliers, precision.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from replay.synth import LABEL_FLOOR, LABEL_PART, PART_KINDS, synthesize_frame
from zcut.cuts import zcut_outliers
from zcut.sor import sor_outliers


def scores(pred, truth, cid):
    ids = np.unique(cid[cid > 0])
    area = np.bincount(cid.ravel(), minlength=cid.max() + 1)
    hit = np.bincount(cid.ravel(), weights=pred.ravel(), minlength=cid.max() + 1)
    ghosts = cid > 0
    return (
        float(np.mean(hit[ids] >= 0.5 * area[ids])) if len(ids) else float("nan"),
        (pred & ghosts).sum() / max(ghosts.sum(), 1),
        (pred & truth).sum() / max(truth.sum(), 1),
        (pred & truth).sum() / max(pred.sum(), 1),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--kinds", default=",".join(PART_KINDS))
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    synthesize_frame(kind="spheres", seed=0, size=(60, 80))  # numba compile / cache load
    print(f"size {w}x{h}, seeds 0..{args.seeds - 1}")
    print(f"{'kind':13s} {'wall s':>7s} {'cpu s':>6s} | {'truth':>6s} {'ghosts':>6s} | "
          f"z-cut: {'clus':>5s} {'px':>5s} {'rec':>5s} {'prec':>5s} | SOR: {'clus':>5s} {'px':>5s} {'rec':>5s} {'prec':>5s}")
    for kind in args.kinds.split(","):
        walls, cpus, zs, ss, nt, ng = [], [], [], [], 0, 0
        for seed in range(args.seeds):
            t0, c0 = time.perf_counter(), time.process_time()
            sf = synthesize_frame(kind=kind, seed=seed, size=(h, w))
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            roi = (sf.surface == LABEL_PART) | (sf.surface == LABEL_FLOOR)
            xyz = sf.frame.xyz.copy()
            xyz[~roi] = np.nan
            height = -1000.0 * xyz[..., 2].astype(np.float64)
            zc = zcut_outliers(height, step=0.2, max_depth=30.0, max_area=0.07 * sf.a_max_px)
            so = sor_outliers(xyz, k=4, std_ratio=1.0)
            truth = sf.truth & roi
            cid = np.where(roi, sf.cluster_id, 0)
            zs.append(scores(zc, truth, cid))
            ss.append(scores(so, truth, cid))
            nt += int(truth.sum())
            ng += len(np.unique(cid[cid > 0]))
        z = np.nanmean(zs, axis=0)
        s = np.nanmean(ss, axis=0)
        print(f"{kind:13s} {np.mean(walls):7.2f} {np.mean(cpus):6.2f} | {nt // args.seeds:6d} {ng // args.seeds:6d} | "
              f"       {z[0]:5.2f} {z[1]:5.2f} {z[2]:5.2f} {z[3]:5.2f} |      {s[0]:5.2f} {s[1]:5.2f} {s[2]:5.2f} {s[3]:5.2f}")


if __name__ == "__main__":
    main()
