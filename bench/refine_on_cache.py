"""The pose refinement (zcut.explained.refine_poses) on the page's cached fits, no refit (issue 29, h/fringe): the page-only
person's label before and after each fit's pose is refined, IoU with the paper's truth and the truth held, and where the
truth the refined fits explain lies (its distance to the true surfaces: read only to score). The fits after the refinement
are not vetted again nor joined by pieces on top or slivers (they come before it in the method too).

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/refine_on_cache.py LOG CACHE_DIR [FRAMES] ['{"REFINE_REACH_MM": 2.0}']

CACHE_DIR: a ``bench/bench_label_pageonly.py --diagnose LOG --fits-cache DIR`` cache (the tree's fits without the
refinement; the remaining arguments: comma-separated frames, constants of zcut.explained as JSON, e.g.
``'{"REFINE_REACH_MM": 1.5, "REFINE_FRONT": 1}'``). The refinement runs as the method calls it
(:func:`zcut.explained.with_refined_poses`: the refinement, the nearest surfaces searched again, the residuals measured
again); ``cpu_refine`` is its CPU-s.
"""
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("bench", "tests", ".")]
import bench_label_pageonly as B  # noqa: E402

from replay.logs import layout  # noqa: E402
from zcut import explained as ex  # noqa: E402

log = Path(sys.argv[1])
B.FITS_CACHE = Path(sys.argv[2])
frames = {int(v) for v in sys.argv[3].split(",")} if len(sys.argv) > 3 else set()
variants = json.loads(sys.argv[4]) if len(sys.argv) > 4 else [{}]
variants = [variants] if isinstance(variants, dict) else variants
DEFAULTS = {n: getattr(ex, n) for n in dir(ex) if n.startswith("REFINE_")}
for frame, job, ff, _cpu, _ in B.fitted_frames(log):
    if frames and frame.index not in frames:
        continue
    valid, xyz, heights = B.frame_arrays(frame, job)
    H, W = valid.shape
    easy = np.asarray(job.removal.easy_outliers, bool)
    zone = np.asarray(job.zone, bool)
    served = (zone | easy) & valid
    truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served
    foot = np.abs(xyz[..., 2]) / ff.f_px
    known = ff.known()
    t0 = time.process_time()
    near = ex.nearest_surface(xyz, known, where=served)
    t1 = time.process_time()
    err = ex.err_image(near, known, foot, floor_mm=ff.floor_mm)
    un0 = ex.unexplained(near.dist_mm, err, ff.k) & served
    base = np.zeros(H * W, bool)
    base[ff.un_pix] = True
    base = base.reshape(H, W)
    poses = [np.asarray(f["pose"]) for f in ff.fits]
    stated = [float(f.get("err_mm", s_)) for f, s_ in zip(ff.fits, ff.part_err_mm)]
    base_score, true_s, base_label = None, None, None
    kind = np.asarray(frame.codes[layout.TRUTH_OUTLIER_KIND]) if layout.TRUTH_OUTLIER_KIND in frame.codes else None
    for kw in variants:
        for name, val in {**DEFAULTS, **kw}.items():  # constants of zcut.explained the refinement reads (REFINE_...)
            setattr(ex, name, type(DEFAULTS[name])(val))
        t2 = time.process_time()
        new, known2, near2 = ex.with_refined_poses(xyz, near, known, poses, ff.part_mesh, stated, foot, k=ff.k,
                                                   floor_mm=ff.floor_mm, zone=zone)
        t3 = time.process_time()
        moved = [i for i in range(len(poses)) if not np.array_equal(new[i], poses[i])]
        fits2 = tuple({**f, "pose": new[i].tolist()} for i, f in enumerate(ff.fits))
        known2b = dataclasses.replace(known2, part_err_mm=list(ff.part_err_mm))
        err2b = ex.err_image(near2, known2b, foot, floor_mm=ff.floor_mm)
        un2b = ex.unexplained(near2.dist_mm, err2b, ff.k) & served
        sig0 = np.asarray(ff.part_err_mm)
        sig2 = np.asarray(known2.part_err_mm)
        err2 = ex.err_image(near2, known2, foot, floor_mm=ff.floor_mm)
        un2 = ex.unexplained(near2.dist_mm, err2, ff.k) & served

        def ff_of(un, nr, er, kn, ff=ff, fits2=fits2, known2=known2):  # type: ignore[no-untyped-def]
            pix = np.flatnonzero(un.ravel())
            return dataclasses.replace(ff, fits=fits2 if kn is known2 else ff.fits, un_pix=pix,
                                       un_dist=nr.dist_mm.ravel()[pix].astype(np.float32),
                                       un_err=er.ravel()[pix].astype(np.float32),
                                       un_code=nr.surface.ravel()[pix].astype(np.int32),
                                       part_err_mm=tuple(kn.part_err_mm))
        res = {"variant": kw, "frame": frame.index, "fits": len(poses), "moved": len(moved), "cpu_near": round(t1 - t0, 2),
               "cpu_refine": round(t3 - t2, 2), "un_cache_vs_recomputed_xor": int((base ^ un0).sum()),
               "un0": int(un0.sum()), "un2": int(un2.sum()),
               "truth lost (un0 & truth & ~un2)": int((un0 & truth & ~un2).sum()),
               "nontruth freed": int((un0 & ~truth & ~un2).sum()), "newly un": int((un2 & ~un0).sum()),
               "old sigmas: truth lost": int((un0 & truth & ~un2b).sum()), "old sigmas: nontruth freed": int((un0 & ~truth & ~un2b).sum()),
               "sigma median before/after": [float(np.median(sig0)), float(np.median(sig2))], "sigma rose": int((sig2 > sig0 + 1e-9).sum())}
        lost = un0 & truth & ~un2
        if lost.any():
            if true_s is None:
                _, true_s = B._true_surfaces(log, frame)
            nt = ex.nearest_surface(xyz, true_s, where=lost)
            dt = nt.dist_mm[lost].astype(float)
            res["lost: d_true quartiles"] = np.percentile(dt, [10, 25, 50, 75, 90]).round(3).tolist()
            res["lost: d_true / err2 quartiles"] = np.percentile(dt / err2[lost], [10, 25, 50, 75, 90]).round(2).tolist()
            res["lost: d_true <= k err2"] = int((dt <= ff.k * err2[lost]).sum())
            res["lost: d_new quartiles"] = np.percentile(near2.dist_mm[lost], [10, 50, 90]).round(3).tolist()
            at_step = ex.between_steps(xyz, np.full(lost.shape, -np.inf), at=np.flatnonzero(lost.ravel()))
            res["lost: at a depth step (10 footprints)"] = int(at_step.sum())
            res["lost: at a depth step (4 footprints)"] = int(ex.between_steps(
                xyz, np.full(lost.shape, -np.inf), at=np.flatnonzero(lost.ravel()), step_footprints=4.0).sum())
            res["lost: d_old quartiles"] = np.percentile(near.dist_mm[lost], [10, 50, 90]).round(3).tolist()
        for name, f2 in (("base", None), ("refined", ff_of(un2, near2, err2, known2))):
            if f2 is None and base_score is not None:
                res[name] = base_score
                continue
            label, ids, how = B._emulated_person(f2 or ff_of(un0, near, err, known), xyz, heights, valid)
            label &= served
            sc = B.label_scores(label, ids, truth, served, None)
            res[name] = {k: sc[k] for k in ("iou", "held", "label", "truth")}
            if f2 is None:
                base_score, base_label = res[name], label
            elif kind is not None:  # the truth the label no longer holds, by the generator's outlier kind
                gone = base_label & truth & ~label
                res["label truth lost by kind"] = {int(c): int(n) for c, n in enumerate(np.bincount(kind[gone], minlength=9)) if n}
                res["unexplained truth lost by kind"] = {int(c): int(n) for c, n in enumerate(np.bincount(kind[lost], minlength=9)) if n}
        res["dIoU"] = round(res["refined"]["iou"] - res["base"]["iou"], 4)
        res["dheld"] = round(res["refined"]["held"] - res["base"]["held"], 4)
        print(json.dumps(res), flush=True)
