"""``zcut.fits.fit_prepared`` at ``FitParams.seed_alternatives`` variants, alternating in one process on the frames of a
``--fits-cache`` (bench/bench_label_pageonly.py's; the frames and their zones only, not its fits): per frame and
variant its CPU-s, its fits, the instances found (>= 40 visible px, matched) and the fully visible ones matched
(bench/bench_fits.py's rule, as bench/diag_unfit.py counts them). The scene's true surfaces only score.

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/fit_alternatives_on_cache.py LOG CACHE 0,1,2 REPEATS OUT.json
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
import bench_label_pageonly as B  # noqa: E402
import diag_unfit as D  # noqa: E402


def main() -> int:
    from zcut import explained as ex
    from zcut.fits import FitParams, fit_prepared, prepare_model

    log, B.FITS_CACHE = Path(sys.argv[1]), Path(sys.argv[2])
    variants = [int(v) for v in sys.argv[3].split(",")]
    reps, outp = int(sys.argv[4]), Path(sys.argv[5])
    model = None
    out: list[dict[str, Any]] = []
    for frame, job, ff, cpu, _ in B.fitted_frames(log):
        if model is None:
            model = prepare_model(*ff.part_mesh)
        valid, xyz, _ = B.frame_arrays(frame, job)
        zone = np.asarray(job.zone, bool)
        H, W = zone.shape
        K = frame.intrinsics
        intr = (float(K.fx), float(K.fy), float(K.cx), float(K.cy))
        parts, ts = B._true_surfaces(log, frame)
        n = len(parts)
        served = (zone | np.asarray(job.removal.easy_outliers, bool)) & valid
        nt = ex.nearest_surface(xyz, ts, where=served)
        vis = served & (nt.surface >= 0) & (nt.dist_mm <= D.VISIBLE_MM)
        vis_n = np.bincount(nt.surface[vis], minlength=n)[:n]
        hits = D._first_hits(parts, intr, H, W)
        seen = np.bincount(hits[hits >= 0], minlength=n)[:n]
        seen_valid = np.bincount(hits[(hits >= 0) & valid], minlength=n)[:n]
        alone = np.zeros(n, np.int64)
        for i in np.flatnonzero(seen > 0):
            alone[i] = D._silhouette_px(*parts[i], intr, H, W)
        share = np.where(alone > 0, seen / np.maximum(alone, 1), 0.0)
        full = (share >= 0.95) & (seen_valid >= 100) & (seen_valid >= 0.5 * seen)
        true_c = np.array([v.mean(axis=0) for v, _ in parts])
        v0 = ff.part_mesh[0]
        size = float(np.linalg.norm(v0.max(axis=0) - v0.min(axis=0)))
        res: dict[int, dict[str, Any]] = {}
        for _ in range(reps):
            for a in variants:
                t = time.process_time()
                fits = fit_prepared(xyz, zone, model, intrinsics=intr, params=FitParams(seed_alternatives=a))
                c = time.process_time() - t
                fc = np.array([(v0 @ f.pose[:3, :3].T + f.pose[:3, 3]).mean(axis=0) for f in fits]).reshape(-1, 3)
                dd = np.linalg.norm(true_c[:, None] - fc[None], axis=2)
                matched = dd.min(axis=1) <= 0.25 * size
                r = res.setdefault(a, {"cpu": []})
                r["cpu"].append(round(c, 3))
                r.update(fits=len(fits), found=int((matched & (vis_n >= 40)).sum()), visible40=int((vis_n >= 40).sum()),
                         full=int(full.sum()), full_matched=int((full & matched).sum()),
                         false_fits=int((dd.min(axis=0) > 0.25 * size).sum()))
                print(log.name, frame.index, a, r, time.strftime("%H:%M:%S"), flush=True)
        out.append({"log": log.name, "frame": frame.index, "cpu_fit_frame_cached": cpu, "res": res})
        outp.write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
