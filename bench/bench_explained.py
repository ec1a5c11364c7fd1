"""Benchmark: the method ``explained`` against the paper's truth (issue 29 item 4).

Run: ``.venv/bin/python bench/bench_explained.py [--size 960x600] [--kinds LIST] [--frames N] [--method]
[--no-part-model [--no-fits]] [--no-rule] [--real DIR [--picture PNG]] [--proposals LOGS]``

**The rule and the truth are one definition.** Per (generator, kind), frames synthesised with seeds
used nowhere else (hand-made 9701.., ray-traced 9801..), the scene's true meshes standing in for the
fits (``tests/explained_helpers.py``: built as the generators build their truth), the frame's every
valid pixel judged by :mod:`zcut.explained`:

- ``IoU gen-Err``: the unexplained pixels with the generator's own Err against
  ``/ground_truth/off_surface`` (the distance and the rule alone);
- ``IoU own-Err``: the same with the Err the method estimates (:func:`zcut.explained.surface_sigmas`:
  each surface's robust residual, the pixel's footprint), as on a real scan, where no generator
  states the noise;
- ``CPU s``: CPU seconds of the distances (:func:`zcut.explained.nearest_surface`) per frame;
- ``vetted out``: the true meshes the vetting of the fits (:mod:`zcut.fit_vetting`) leaves out (none
  may be: true parts share no volume) and ``IoU own-Err vetted`` the IoU after it.

``--method``: also the whole method on a log of each (``zcut synth`` in a temporary folder; the
part fits of :mod:`zcut.fits`, the registered bin, the table plane): precision, recall and IoU of its
outliers with the paper's truth inside the zone, the share of the zone's pixels its fits explain and
its CPU seconds per frame.

``--no-part-model``: on logs of seeds used nowhere else (9951.. hand-made, 9961.. ray-traced; the
fallback's one parameter was chosen on 9901..9914 and 9905), the method with the part fits
(``--no-fits``: left out, they cost 1-40 CPU-s a frame), the method without a part model (the
parts' pixels against the edge-aware local surface, docs/accuracy.md "Explained without a part
model") and the z-cut, each scored as ``zcut accuracy`` scores (the zone and the points above the
rim, against ``/ground_truth/off_surface``): truth and flagged pixels, precision, recall, IoU, CPU s
of the method (``process_time``). ``--real DIR``: the fallback on the real scans of DIR (no truth:
the share it flags beside the z-cut's; ``--picture PNG`` saves the first one's depth with its flags).

``--proposals LOG[,LOG...]``: what the labelling page proposes with the log's part model (the
page's own :func:`annotate.fits.fit_frame` and :meth:`annotate.fits.FrameFits.bundle` on every frame
of each log, the pipeline's zone as ``zcut annotate`` prepares it): the paper's truth inside the zone
the page serves (the zone and the points above the rim), the share of it inside the proposals, where
the rest went (in a fit's pixels; above the rim and not proposed; elsewhere: the bin, the table),
the share of proposal pixels that are truth, the number of proposals and the CPU-s of the fits.
The truth is read only to score, after the page's bundle is made. Run it with ``PYTHONPATH`` of
another tree (``git archive``) for the before of a change, in the same session.

``--vetting LOG[,LOG...]``: the candidates for vetting the fits (:mod:`zcut.fit_vetting`;
docs/labelling.md, "Vetting the fits") on the first frame of each log, from one set of fits (fitted
once, as the page fits them), each judged as the page judges (the zone and the points above the rim):
no vetting (the fits as they come), the volume overlap at several thresholds (the rule: 5 %), a
robust residual above 3 × the frame's median one, a support below 0.7, a see-through share above 0.3
(the share of the pixels where the fit is the first surface on the camera ray and is measured whose
point lies farther than k × Err behind it: the camera saw through it), and the rule with the
residual's. Per candidate: the fits left out, the paper's truth inside the proposals, the proposal
pixels that are not truth, the proposals (groups, as the page joins them) and their precision; the
CPU-s of the vetting.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from explained_helpers import handmade_true_surfaces, raytraced_true_surfaces  # noqa: E402

from zcut import explained as ex  # noqa: E402

HANDMADE_SEED, RAYTRACED_SEED = 9701, 9801
#: the report seeds of ``--no-part-model`` (the fallback was looked at on 9901.. and 9911.. only)
FALLBACK_HANDMADE_SEED, FALLBACK_RAYTRACED_SEED = 9951, 9961


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    u = int((a | b).sum())
    return float((a & b).sum() / u) if u else 1.0


def rule_check(generator: str, kind: str, seed: int, size: tuple[int, int]) -> dict[str, float]:
    """IoU of the rule with the paper's truth on one frame, with the generator's Err and the method's own."""
    if generator == "handmade":
        from replay.synth.synthesize import synthesize_frame

        sf = synthesize_frame(kind=kind, seed=seed, index=0, size=size)
        parts, surfaces = handmade_true_surfaces(sf)
    else:
        from replay.synth.raytrace import synthesize_raytraced_frame

        sf = synthesize_raytraced_frame(kind=kind, seed=seed, index=0, size=size)
        parts, surfaces = raytraced_true_surfaces(sf, seed=seed, index=0)
    xyz = sf.frame.xyz.astype(np.float64) * 1000.0
    t = time.process_time()
    near = ex.nearest_surface(xyz, surfaces)
    cpu = time.process_time() - t
    truth = sf.off_surface
    gen = ex.unexplained(near.dist_mm, sf.err_mm.astype(np.float64), ex.K_ERR)
    c = ex.footprint_mm(xyz, ex.focal_px(xyz))
    sig, bin_sigma, table_sigma = ex.surface_sigmas(near, len(parts), c)
    assert surfaces.table is not None
    own_surfaces = dataclasses.replace(surfaces, part_err_mm=sig, bin_err_mm=bin_sigma,
                                       table=dataclasses.replace(surfaces.table, residual_mm=table_sigma))
    own_err = ex.err_image(near, own_surfaces, c)
    own = ex.unexplained(near.dist_mm, own_err, ex.K_ERR)
    # the vetting of the fits (zcut.fit_vetting) with the true meshes as fits: none may be left out
    from zcut.fit_vetting import explained_px, part_overlaps, vet_fits, without_fits

    kept = vet_fits(part_overlaps(parts), explained_px(near, own_err, len(parts), k=ex.K_ERR)).kept
    left, near_v = without_fits(xyz, near, own_surfaces, kept)
    vetted = ex.unexplained(near_v.dist_mm, ex.err_image(near_v, left, c), ex.K_ERR)
    return {"truth": float(truth.sum()), "iou_gen": _iou(gen, truth), "iou_own": _iou(own, truth), "cpu": cpu,
            "out": int((~kept).sum()), "parts": len(parts), "iou_vetted": _iou(vetted, truth)}


def _fallback_config(config: Any) -> Any:
    """``config`` with no part model: ``explained`` judges the parts against the edge-aware local surface."""
    e = dataclasses.replace(config.bank["explained"], part_model="")
    return dataclasses.replace(config, bank={**config.bank, "explained": e})


def method_check(generator: str, kind: str, seed: int, size: tuple[int, int], *,
                 fits: bool = True) -> dict[str, dict[str, Any]]:
    """The methods on a one-frame log (``zcut synth`` in a temporary folder) scored as ``zcut accuracy``
    scores them (the zone and the points above the rim, against ``/ground_truth/off_surface``):
    ``explained`` with the part fits (``fits``), ``explained`` without a part model (the fallback) and
    the z-cut; each with precision, recall, IoU and the CPU s of the method."""
    from cli.main import main
    from replay.logs import layout
    from replay.options import PipelineOptions
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone

    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "log.mcap"
        args = ["synth", "-o", str(log), "--parts", kind, "--seed", str(seed), "--size", f"{size[1]}x{size[0]}"]
        if generator == "raytraced":
            args += ["--sensor", "raytraced"]
        assert main(args) == 0
        session = PipelineOptions(methods="zcut,explained").open_session(log)
        frame, r = next(iter(session.results(config=_fallback_config(session.config))))  # the z-cut's mask
        zone = bin_zone(frame, session.config, bin_model=session.prepared)
        region = zone.zone | zone.easy
        truth = frame.masks[layout.TRUTH_OFF_SURFACE] & region
        runs = [("explained fits", session.config)] if fits else []
        runs.append(("explained fallback", _fallback_config(session.config)))
        rows: dict[str, dict[str, Any]] = {}

        def row(mask: np.ndarray, cpu: float, n_fits: int | str) -> dict[str, Any]:
            mask = mask & region
            tp = int((mask & truth).sum())
            return {"truth": int(truth.sum()), "flagged": int(mask.sum()), "precision": tp / max(int(mask.sum()), 1),
                    "recall": tp / max(int(truth.sum()), 1), "iou": _iou(mask, truth), "cpu": cpu, "fits": n_fits}

        for name, config in runs:
            t = time.process_time()
            mask, detail, _ = run_explained(frame, zone, config)
            cpu = time.process_time() - t
            rows[name] = row(mask | zone.easy, cpu, len(detail.fits) if detail is not None else 0)
        rows["zcut"] = row(r.outliers["zcut"], float("nan"), "")
    return rows


def real_check(path: Path) -> dict[str, Any]:
    """The fallback on a real scan (``zcut record`` of a PCD in a temporary folder, no bin stages: the
    zone is every valid pixel, the local surface alone explains it): the share it flags, its
    local-surface σ and CPU s (``process_time`` of the method), and the mask for a picture."""
    from cli.main import main
    from replay.options import PipelineOptions
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone

    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "log.mcap"
        assert main(["record", str(path), "-o", str(log)]) == 0
        session = PipelineOptions(methods="zcut,explained").open_session(log)
        config = _fallback_config(session.config)
        frame, r = next(iter(session.results(config=config)))
        zone = bin_zone(frame, config, bin_model=session.prepared)
    t = time.process_time()
    mask, d_, _ = run_explained(frame, zone, config)
    cpu = time.process_time() - t
    assert d_ is not None
    valid = r.valid
    return {"valid": int(valid.sum()), "flagged": int(mask.sum()), "share": float(mask.sum() / max(int(valid.sum()), 1)),
            "zcut_share": float(r.outliers["zcut"].sum() / max(int(valid.sum()), 1)),
            "sigma": d_.local_err_mm, "cpu": cpu, "err_median": float(np.nanmedian(d_.err_mm)), "mask": mask,
            "frame": frame}


def proposals_check(log: Path) -> list[dict[str, Any]]:
    """The page's proposals on every frame of ``log`` (module docstring, ``--proposals``)."""
    from annotate.fits import Job, fit_frame
    from annotate.payload import parse_bundle
    from replay.logs import layout
    from replay.options import PipelineOptions

    session = PipelineOptions(methods="zcut,explained").open_session(log)
    rows = []
    for frame, r in session.results():
        job = Job.of(r)
        t = time.process_time()
        ff = fit_frame(frame, job, session.config, session.prepared.model if session.prepared is not None else None)
        cpu = time.process_time() - t
        valid = np.asarray(r.valid, bool)
        heights = np.where(valid, -1000.0 * frame.xyz[..., 2].astype(np.float64), np.nan)
        header, arrays = parse_bundle(ff.bundle(heights_mm=heights, valid=valid, rejected=set(), header={}))
        H, W = valid.shape
        prop = np.asarray(arrays["proposals"], np.int64).reshape(H, W) > 0 if "proposals" in arrays else \
            np.zeros((H, W), bool)
        easy = np.asarray(job.removal.easy_outliers, bool) if job.removal is not None else np.zeros((H, W), bool)
        served = (job.zone | easy) & valid
        truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served  # read only now, to score
        in_fit = np.zeros(H * W, bool)
        in_fit[ff.fit_pix] = True
        in_fit = in_fit.reshape(H, W)
        miss = truth & ~prop
        n = max(int(truth.sum()), 1)
        rows.append({"frame": frame.index, "truth": int(truth.sum()), "share": float((truth & prop).sum() / n),
                     "in_fits": float((miss & in_fit).sum() / n), "above_rim": float((miss & easy & ~in_fit).sum() / n),
                     "elsewhere": float((miss & ~easy & ~in_fit).sum() / n),
                     "precision": float((truth & prop).sum() / max(int(prop.sum()), 1)), "prop_px": int(prop.sum()),
                     "proposals": int(header.get("n_proposals", 0)), "fits": len(ff.fits), "cpu": cpu,
                     "status": ff.status})
    return rows


def _page_groups(un: np.ndarray) -> int:
    """The number of proposals the page makes of these unexplained pixels (:data:`annotate.fits.JOIN_PX`)."""
    from scipy import ndimage

    from annotate.fits import JOIN_PX
    from annotate.payload import EIGHT

    if not un.any():
        return 0
    joined, _ = ndimage.label(ndimage.binary_dilation(un, EIGHT, iterations=JOIN_PX), structure=EIGHT)
    return int(np.unique(joined[un]).size)


def _see_through(xyz: np.ndarray, valid: np.ndarray, parts: list[tuple[np.ndarray, np.ndarray]], sigma: np.ndarray,
                 footprint: np.ndarray, k: float, floor: float) -> np.ndarray:
    """(n,) per fit: of the measured pixels where it is the first fitted surface on the camera ray, the
    share whose point lies farther than k × Err behind it (the camera saw through it)."""
    import open3d as o3d

    n = len(parts)
    scene = o3d.t.geometry.RaycastingScene()
    for v, t in parts:
        scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]
                            o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]
    p = xyz[valid]
    rng = np.linalg.norm(p, axis=1)
    rays = np.concatenate([np.zeros_like(p), p / rng[:, None]], axis=1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))  # type: ignore[call-overload]
    th = ans["t_hit"].numpy().astype(np.float64)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    hit = np.isfinite(th)
    g = np.where(hit, gid, n)
    tol = k * np.maximum(floor, np.sqrt(np.asarray(sigma)[np.clip(gid, 0, n - 1)] ** 2 + 0.5 * footprint[valid] ** 2))
    behind = hit & (rng > th + tol)
    agree = hit & ~behind & (rng >= th - tol)
    nb = np.bincount(g[behind], minlength=n + 1)[:n]
    na = np.bincount(g[agree], minlength=n + 1)[:n]
    out: np.ndarray = nb / np.maximum(nb + na, 1)
    return out


def vetting_check(log: Path) -> list[dict[str, Any]]:
    """The vetting candidates on the first frame of ``log`` (module docstring, ``--vetting``)."""
    from annotate.fits import Job
    from replay.logs import layout
    from replay.options import PipelineOptions
    from replay.pipeline.explained import NAME, bin_and_table_surfaces, part_model, with_part_model
    from zcut.fit_vetting import explained_px, instance_overlaps, vet_fits, without_fits
    from zcut.fits import FitParams, fit_prepared

    session = PipelineOptions(methods="zcut").open_session(log)
    config = with_part_model(session.resolved, log).config
    p = config.bank[NAME]
    frame, r = next(iter(session.results()))
    job = Job.of(r)
    assert job.removal is not None and job.registration is not None and session.prepared is not None
    v, t, prepared = part_model(p.part_model, p.part_model_unit)
    xyz = frame.xyz.astype(np.float64) * 1000.0
    K = frame.intrinsics
    assert K is not None
    fits = fit_prepared(xyz, job.zone, prepared, intrinsics=(K.fx, K.fy, K.cx, K.cy),
                        params=FitParams(k=p.k, max_err_mm=p.fit_max_err_mm, min_support=p.fit_min_support))
    easy = np.asarray(job.removal.easy_outliers, bool)
    served = (job.zone | easy) & job.valid
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in fits],
                                part_err_mm=[f.err_mm for f in fits])
    surfaces = bin_and_table_surfaces(xyz, job.removal, job.registration, session.prepared.model, surfaces)
    c = ex.footprint_mm(xyz, 0.5 * (K.fx + K.fy))
    near = ex.nearest_surface(xyz, surfaces, where=served)
    robust = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, surfaces.part_err_mm, where=job.zone))
    err = ex.err_image(near, robust, c, floor_mm=p.err_floor_mm)
    support_px = explained_px(near, err, len(fits), k=p.k, where=job.zone)
    sigma = np.asarray(robust.part_err_mm)
    stated_support = np.array([f.support for f in fits])
    t0 = time.process_time()
    see = _see_through(xyz, job.valid, list(surfaces.parts), sigma, c, p.k, p.err_floor_mm)
    see_cpu = time.process_time() - t0
    t0 = time.process_time()
    overlaps = instance_overlaps(v, t, [f.pose for f in fits])
    overlap_cpu = time.process_time() - t0
    candidates: list[tuple[str, Any]] = [("none", lambda: np.ones(len(fits), bool))]
    for th in (0.01, 0.05, 0.1, 0.2):
        candidates.append((f"overlap > {th:g}" + (" (rule)" if th == 0.05 else ""),
                           lambda th=th: vet_fits(overlaps, support_px, max_overlap=th).kept))
    med = float(np.median(sigma)) if len(sigma) else 0.0
    candidates += [("residual > 3 x median", lambda: ~(sigma > 3.0 * med)),
                   ("support < 0.7", lambda: ~(stated_support < 0.7)),
                   ("see-through > 0.3", lambda: ~(see > 0.3)),
                   ("rule + residual", lambda: vet_fits(overlaps, support_px).kept & ~(sigma > 3.0 * med))]
    truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served  # read only now, to score
    rows = []
    for name, rule in candidates:
        t0 = time.process_time()
        kept = np.asarray(rule(), bool)
        cpu = time.process_time() - t0 + (see_cpu if "see" in name else 0.0) + (overlap_cpu if "rule" in name or
                                                                                  "overlap" in name else 0.0)
        left, near2 = without_fits(xyz, near, surfaces, kept)
        left = dataclasses.replace(left, part_err_mm=ex.fit_sigmas(near2, left.part_err_mm, where=job.zone))
        un = ex.unexplained(near2.dist_mm, ex.err_image(near2, left, c, floor_mm=p.err_floor_mm), p.k) & served
        rows.append({"candidate": name, "fits": len(fits), "out": int((~kept).sum()), "truth": int(truth.sum()),
                     "share": float((truth & un).sum() / max(int(truth.sum()), 1)), "non_truth": int((un & ~truth).sum()),
                     "proposals": _page_groups(un), "precision": float((truth & un).sum() / max(int(un.sum()), 1)),
                     "cpu": cpu})
    return rows


def _picture(out: Path, frame: Any, mask: np.ndarray) -> None:
    """The scan's depth (grey, near bright) with the flagged pixels in red, saved as a PNG."""
    from PIL import Image

    z = frame.xyz[..., 2].astype(np.float64)
    ok = np.isfinite(z)
    lo, hi = (np.percentile(z[ok], [1, 99]) if ok.any() else (0.0, 1.0))
    g = np.where(ok, 255 * (1 - np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)), 0).astype(np.uint8)
    img = np.dstack([g, g, g])
    img[mask] = (255, 0, 0)
    Image.fromarray(img).save(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="960x600", help="WIDTHxHEIGHT (default 960x600)")
    ap.add_argument("--kinds", default="zinc_nuts,black_nuts,spheres,rods")
    ap.add_argument("--frames", type=int, default=1, help="frames (seeds) per generator and kind")
    ap.add_argument("--generators", default="handmade,raytraced")
    ap.add_argument("--method", action="store_true", help="also run the whole method (part fits) on a log of each")
    ap.add_argument("--no-part-model", action="store_true",
                    help="the method without a part model (the edge-aware local surface) beside the fits and the "
                         "z-cut, on logs of seeds 9951.. (hand-made) and 9961.. (ray-traced); with --no-fits "
                         "the fits are left out (they cost 10-60 CPU-s a frame)")
    ap.add_argument("--no-fits", action="store_true", help="with --no-part-model: leave out the part fits")
    ap.add_argument("--no-rule", action="store_true", help="leave out the true-meshes check")
    ap.add_argument("--real", type=Path, default=None, metavar="DIR",
                    help="the fallback on the real scans of DIR (*.pcd; no truth: the share it flags)")
    ap.add_argument("--proposals", default=None, metavar="LOGS",
                    help="the labelling page's proposals on every frame of these logs (comma-separated), against "
                         "the paper's truth")
    ap.add_argument("--vetting", default=None, metavar="LOGS",
                    help="the candidates for vetting the fits on the first frame of these logs (comma-separated), "
                         "against the paper's truth")
    ap.add_argument("--picture", type=Path, default=None, metavar="PNG",
                    help="with --real: save the first scan's depth with the flagged pixels in red")
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    if a.vetting:
        print("vetting the fits: the page's proposals with the fits each candidate keeps, against "
              "/ground_truth/off_surface in the zone the page serves (one set of fits per log)")
        print(f"{'log':<34} {'candidate':<24} {'fits':>4} {'out':>4} {'truth':>7} {'in props':>8} {'non-truth':>9} "
              f"{'props':>6} {'precision':>9} {'CPU s':>6}")
        for log in a.vetting.split(","):
            for rr in vetting_check(Path(log)):
                print(f"{Path(log).name:<34} {rr['candidate']:<24} {rr['fits']:>4} {rr['out']:>4} {rr['truth']:>7} "
                      f"{rr['share']:>8.3f} {rr['non_truth']:>9} {rr['proposals']:>6} {rr['precision']:>9.3f} "
                      f"{rr['cpu']:>6.2f}", flush=True)
        return
    if a.proposals:
        print("the page's proposals (part model of the log) against /ground_truth/off_surface in the zone the page "
              "serves; missed truth: in a fit's pixels, above the rim, elsewhere (bin, table)")
        print(f"{'log':<34} {'frame':>5} {'truth':>7} {'in props':>8} {'in fits':>7} {'a. rim':>6} {'else':>6} "
              f"{'precision':>9} {'prop px':>7} {'props':>5} {'fits':>4} {'CPU s':>6}")
        for log in a.proposals.split(","):
            for rr in proposals_check(Path(log)):
                print(f"{Path(log).name:<34} {rr['frame']:>5} {rr['truth']:>7} {rr['share']:>8.3f} {rr['in_fits']:>7.3f} "
                      f"{rr['above_rim']:>6.3f} {rr['elsewhere']:>6.3f} {rr['precision']:>9.3f} {rr['prop_px']:>7} "
                      f"{rr['proposals']:>5} {rr['fits']:>4} {rr['cpu']:>6.1f}", flush=True)
        return
    if not a.no_rule:
        print(f"true meshes as fits, {w}x{h}; IoU with /ground_truth/off_surface (every valid pixel)")
        print(f"{'generator':<10} {'kind':<11} {'seed':>5} {'truth px':>8} {'IoU gen-Err':>11} {'IoU own-Err':>11} "
              f"{'CPU s':>6} {'vetted out':>10} {'IoU own-Err vetted':>18}")
        rows = []
        for g in a.generators.split(","):
            for k_i, kind in enumerate(a.kinds.split(",")):
                for f in range(a.frames):
                    seed = (HANDMADE_SEED if g == "handmade" else RAYTRACED_SEED) + 10 * k_i + f
                    r = rule_check(g, kind, seed, (h, w))
                    rows.append(r)
                    print(f"{g:<10} {kind:<11} {seed:>5} {r['truth']:>8.0f} {r['iou_gen']:>11.4f} "
                          f"{r['iou_own']:>11.4f} {r['cpu']:>6.2f} {r['out']:>4}/{r['parts']:<5} "
                          f"{r['iou_vetted']:>18.4f}", flush=True)
        print(f"min IoU gen-Err {min(r['iou_gen'] for r in rows):.4f}, own-Err {min(r['iou_own'] for r in rows):.4f}")
    if a.method or a.no_part_model:
        fits = a.method or not a.no_fits
        print(f"\nthe methods ({w}x{h}) in the zone and above the rim, against /ground_truth/off_surface"
              + ("" if not a.no_part_model else "; explained with the part fits, without a part model "
                 "(the local surface), the z-cut"))
        print(f"{'generator':<10} {'kind':<11} {'seed':>5} {'method':<19} {'fits':>4} {'truth':>6} {'flagged':>7} "
              f"{'precision':>9} {'recall':>7} {'IoU':>6} {'CPU s':>6}")
        base = (FALLBACK_HANDMADE_SEED, FALLBACK_RAYTRACED_SEED) if a.no_part_model else (HANDMADE_SEED, RAYTRACED_SEED)
        for g in a.generators.split(","):
            for k_i, kind in enumerate(a.kinds.split(",")):
                for f in range(a.frames if a.no_part_model else 1):
                    seed = base[g != "handmade"] + 10 * f + k_i if a.no_part_model else base[g != "handmade"] + 10 * k_i
                    try:
                        res = method_check(g, kind, seed, (h, w), fits=fits)
                    except Exception as e:  # noqa: BLE001 - a failing fit is a row of the table, not the end of it
                        print(f"{g:<10} {kind:<11} {seed:>5} failed: {type(e).__name__}: {e}", flush=True)
                        continue
                    if not a.no_part_model:
                        res.pop("explained fallback", None)
                        res.pop("zcut", None)
                    for name, m in res.items():
                        print(f"{g:<10} {kind:<11} {seed:>5} {name:<19} {m['fits']!s:>4} {m['truth']:>6} "
                              f"{m['flagged']:>7} {m['precision']:>9.3f} {m['recall']:>7.3f} {m['iou']:>6.3f} "
                              f"{m['cpu']:>6.2f}", flush=True)
    if a.real is not None:
        print(f"\nthe fallback on the real scans of {a.real} (no bin stages: every valid pixel judged against the "
              "local surface alone; no truth)")
        print(f"{'scan':<36} {'valid':>7} {'flagged':>7} {'share':>7} {'z-cut':>7} {'σ mm':>6} {'Err mm':>6} "
              f"{'CPU s':>6}")
        first = True
        for pcd in sorted(a.real.glob("*.pcd")):
            rr = real_check(pcd)
            print(f"{pcd.stem:<36} {rr['valid']:>7} {rr['flagged']:>7} {rr['share']:>7.4f} {rr['zcut_share']:>7.4f} "
                  f"{rr['sigma']:>6.2f} {rr['err_median']:>6.2f} {rr['cpu']:>6.2f}", flush=True)
            if first and a.picture is not None:
                _picture(a.picture, rr["frame"], rr["mask"])
                first = False


if __name__ == "__main__":
    main()
