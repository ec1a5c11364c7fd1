"""The part instances no fit takes (issue 29, h/unfit): every true instance with visible pixels and no matched fit,
split by cause, and the page-only person's excess on them by cause.

For every frame of a synthetic log (fitted as the page fits it, :func:`bench_label_pageonly.fitted_frames`, or read
from a ``--fits-cache``), the page-only person's label is emulated (:func:`bench_label_pageonly._emulated_person`);
the scene's true surfaces (rebuilt from the log's record) and the generator's poses only score. An instance is
*matched* when some fit's posed mesh centre lies within a quarter of the part's size of its own (as
bench/diag_fringe.py matches them). For each unmatched instance with visible pixels (served pixels whose nearest true
surface it is, within :data:`VISIBLE_MM`):

- its visible pixels, its whole silhouette alone (its mesh ray cast through the intrinsics, nothing in front) and
  the visible share (the pixels whose ray meets it first among the scene's instances / its silhouette alone);
- the first pass's candidate region (:func:`zcut.fits.segment` on the zone, the fits' own jump parameters, no size
  bound) holding most of its visible pixels: its size, how many true instances hold ≥ :data:`MERGED_PX` of it;
- its excess pixels (label, not the paper's truth, nearest true surface it) and the unexplained region
  (8-connected, the sliver pass's regions: the unexplained zone pixels with the sliver fits' pixels put back) that
  holds most of them, and what the sliver pass did with that region: **too small** (< 150 px), **too large**
  (> 2000 px), **beyond the budget** (not among the 12 largest), **tried** (then refused, or a sliver fit there);
- an *oracle* sliver fit (:func:`zcut.sliver_fits.fit_slivers`, the method's parameters) on the instance's own
  unexplained pixels: would the pass take it given its region alone — accepted (and whether at the true pose),
  else refused by what: the residual or the share explained, the overlap with a fit, the free space (each bound
  relaxed in turn to name the one that refuses).

With ``--split N`` (docs/labelling.md, "Twenty-third round") the unexplained regions are those the pass labels with its
regions cut at the scan's depth steps of more than N footprints (:func:`zcut.sliver_fits.depth_steps`;
``SliverParams.split_steps``), the excess at those steps in no region, and the oracle runs with the cut: what the lever
leaves of each instance's region. With ``--area-share A`` (docs/labelling.md, "Twenty-fourth round") a region is too
small under max(``--min-px`` N, A × a whole part's projected area at its median depth)
(:func:`zcut.sliver_fits.projected_area_px`; ``SliverParams.min_area_share``). The oracle reads the free space on the
whole silhouette, as the method does.

The causes' shares of the excess on unfitted instances are summed in pixels. Per frame also the instances found (those
of >= 40 visible px matched) and the fully visible ones matched (bench/bench_fits.py's rule: >= 95 % of the pixels
the instance covers alone are its own first hits, >= 100 of them valid and at least half of them).

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/diag_unfit.py LOG [--fits-cache DIR] [--frames 0,1] [--split N] [--json F]
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
import bench_label_pageonly as B  # noqa: E402

#: a served pixel is visible on a true instance when it lies within this of it (and it is its nearest true surface)
VISIBLE_MM = 1.0
#: a true instance counts in a region when it holds at least this many of its pixels
MERGED_PX = 20
#: the oracle sliver fit runs on instances with at least this many unexplained pixels (fewer: not tried)
ORACLE_MIN_PX = 30

_MODELS: dict[int, Any] = {}


def _prepared(v: np.ndarray, t: np.ndarray) -> Any:
    from zcut.fits import prepare_model

    key = id(v)
    if key not in _MODELS:
        _MODELS[key] = prepare_model(v, t)
    return _MODELS[key]


def _silhouette_px(v: np.ndarray, t: np.ndarray, K: tuple[float, float, float, float], H: int, W: int) -> int:
    """Pixels whose ray meets the mesh (v, t) alone (camera at the origin, pinhole ``K``)."""
    import open3d as o3d

    fx, fy, cx, cy = K
    if not (v[:, 2] > 0).all():
        return 0
    u, w = fx * v[:, 0] / v[:, 2] + cx, fy * v[:, 1] / v[:, 2] + cy
    c0, c1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, W)
    r0, r1 = max(int(np.floor(w.min())) - 1, 0), min(int(np.ceil(w.max())) + 2, H)
    if c0 >= c1 or r0 >= r1:
        return 0
    rr, cc = np.mgrid[r0:r1, c0:c1]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones_like(rr, float)], axis=-1).reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]
                        o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()  # type: ignore[call-overload]
    return int(np.isfinite(hit).sum())


def _first_hits(parts: list[tuple[np.ndarray, np.ndarray]], K: tuple[float, float, float, float], H: int,
                W: int) -> np.ndarray:
    """(H, W) the true instance each pixel's ray meets first (-1: none), all instances in one scene."""
    import open3d as o3d

    fx, fy, cx, cy = K
    rr, cc = np.mgrid[0:H, 0:W]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones((H, W))], axis=-1).reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    for v, t in parts:
        scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]
                            o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]
    ans = scene.cast_rays(o3d.core.Tensor(rays))  # type: ignore[call-overload]
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    return np.where(np.isfinite(ans["t_hit"].numpy()), gid, -1).reshape(H, W)


def _oracle(xyz: np.ndarray, valid: np.ndarray, mask: np.ndarray, model: Any, poses: np.ndarray, sigma: float,
            K: tuple[float, float, float, float], true_pose_centre: np.ndarray, size: float, *,
            split: float = 0.0) -> dict[str, Any]:
    """The sliver pass (the method's parameters; ``split`` > 0: the regions cut at depth steps of more than ``split``
    footprints) on ``mask`` alone; when it refuses, the bound that does."""
    from replay.pipeline import explained as pe
    from zcut.sliver_fits import SliverParams, fit_slivers

    base = SliverParams(min_px=1, max_px=10 ** 9, max_regions=1, coarse=pe.SLIVER_COARSE, refine=pe.SLIVER_REFINE,
                        max_see_through=pe.SLIVER_MAX_SEE_THROUGH)
    if split:
        base = dataclasses.replace(base, split_steps=float(split))

    def run(p: SliverParams) -> list[Any]:
        return fit_slivers(xyz, valid, mask, model, poses, sigma_mm=sigma, params=p, intrinsics=K)

    got = run(base)
    if got:
        c = got[0].pose[:3, :3] @ model.centroid + got[0].pose[:3, 3]
        ok = float(np.linalg.norm(c - true_pose_centre)) <= 0.25 * size
        return {"oracle": "accepted, true pose" if ok else "accepted, wrong pose", "share": got[0].share}
    relaxed = [("free space", {"max_see_through": 1.0}), ("overlap with a fit", {"max_see_through": 1.0,
                                                                                  "max_overlap": 1.0}),
               ("residual / share", {"max_see_through": 1.0, "max_overlap": 1.0, "max_residual": 1e6,
                                     "min_share": 0.0})]
    for name, kw in relaxed:
        if run(dataclasses.replace(base, **kw)):
            return {"oracle": f"refused: {name}"}
    return {"oracle": "refused: no guess converged"}


def frame_split(log: Path, frame: Any, job: Any, ff: Any, *, oracle: bool = True, split: float = 0.0,
                min_px: int | None = None, area_share: float = 0.0) -> dict[str, Any]:
    from replay.logs import layout
    from replay.pipeline import explained as pe
    from zcut import explained as ex
    from zcut.fits import FitParams
    from zcut.fits.segment import segment

    valid, xyz, heights = B.frame_arrays(frame, job)
    H, W = valid.shape
    label, _ids, _ = B._emulated_person(ff, xyz, heights, valid)
    easy = np.asarray(job.removal.easy_outliers, bool)
    zone = np.asarray(job.zone, bool) & valid
    served = (zone | easy) & valid
    label &= served
    truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served
    parts, true_s = B._true_surfaces(log, frame)
    near_t = ex.nearest_surface(xyz, true_s, where=served)
    tcode, tdist = near_t.surface, near_t.dist_mm.astype(np.float64)
    v0, t0 = ff.part_mesh
    size = float(np.linalg.norm(v0.max(axis=0) - v0.min(axis=0)))
    fit_c = np.array([ff.posed(i)[0].mean(axis=0) for i in range(len(ff.fits))]).reshape(-1, 3)
    true_c = np.array([v.mean(axis=0) for v, _ in parts]).reshape(-1, 3)
    dd = np.linalg.norm(true_c[:, None, :] - fit_c[None, :, :], axis=2)
    matched = dd.min(axis=1) <= 0.25 * size if len(fit_c) else np.zeros(len(true_c), bool)
    non = label & ~truth
    n_inst = len(parts)
    inst = np.where(tcode >= 0, tcode, n_inst)
    visible = served & (tcode >= 0) & (tdist <= VISIBLE_MM)
    vis_n = np.bincount(inst[visible], minlength=n_inst + 1)[:n_inst]
    exc_n = np.bincount(inst[non & (tcode >= 0)], minlength=n_inst + 1)[:n_inst]
    un, sliver_ids = B.sliver_input(ff, zone)
    K = frame.intrinsics
    Kt = (float(K.fx), float(K.fy), float(K.cx), float(K.cy))
    if split:  # the pass's regions cut at the scan's depth steps: the step pixels in none
        from zcut.sliver_fits import depth_steps

        un = un & ~depth_steps(xyz, valid & np.isfinite(xyz).all(axis=2), Kt[0], split)
    lab, nreg = ndimage.label(un, structure=np.ones((3, 3), bool))
    sizes = np.bincount(lab.ravel(), minlength=nreg + 1)
    n_min = pe.SLIVER_MIN_PX if min_px is None else int(min_px)
    floor = np.full(nreg + 1, float(n_min))  # each region's size floor: N, or N and A of a part's area at its depth
    if area_share > 0:
        from zcut.sliver_fits import projected_area_px

        idx = np.flatnonzero((sizes >= n_min) & (sizes <= 2000))
        idx = idx[idx > 0]
        if idx.size:
            z_med = np.asarray(ndimage.median(np.asarray(xyz[..., 2], np.float64), lab, idx), np.float64)
            floor[idx] = np.maximum(n_min, np.ceil(area_share * projected_area_px(
                _prepared(*ff.part_mesh), z_med, 0.5 * (Kt[0] + Kt[1]))))
    small = f"too small (< {n_min} px)" if area_share <= 0 else f"too small (< max({n_min} px, {area_share:g} area))"
    elig = np.flatnonzero((sizes >= floor) & (sizes <= 2000))
    elig = elig[elig > 0]
    elig = elig[np.argsort(-sizes[elig], kind="stable")]
    tried = set(elig[:pe.SLIVER_MAX_REGIONS].tolist())
    sliver_regions = set()
    for i in sliver_ids:
        px = ff.fit_pix[ff.fit_of == i]
        r = lab.ravel()[px]
        r = r[r > 0]
        if r.size:
            sliver_regions.add(int(np.bincount(r).argmax()))
    # the first pass's candidate regions (no size bound)
    fp = FitParams()
    f_px = 0.5 * (Kt[0] + Kt[1])
    seg = segment(xyz, np.flatnonzero(zone.ravel()), f_px=f_px, jump_mm=fp.jump_mm, jump_px=fp.jump_px, min_px=1)
    seg_lab = np.zeros(H * W, np.int64)
    for j, r in enumerate(seg):
        seg_lab[r] = j + 1
    seg_sizes = np.array([0] + [len(r) for r in seg])
    model = _prepared(v0, t0) if oracle else None
    sig = np.asarray([e for e, f in zip(ff.part_err_mm, ff.fits) if not f.get("sliver")], np.float64)
    sig = sig[np.isfinite(sig)]
    sigma = float(np.median(sig)) if sig.size else float("nan")
    poses = np.stack([np.asarray(f["pose"], np.float64) for f in ff.fits if not f.get("sliver")]) \
        if ff.fits else np.zeros((0, 4, 4))
    rows = []
    # fully visible (bench/bench_fits.py's rule): >= 95 % of the pixels the instance covers alone are its first hits
    # in the scene, >= 100 of them valid and at least half of them
    hits = _first_hits(parts, Kt, H, W)
    seen = np.bincount(hits[hits >= 0], minlength=n_inst)[:n_inst]
    seen_valid = np.bincount(hits[(hits >= 0) & valid], minlength=n_inst)[:n_inst]
    alone_n = np.zeros(n_inst, np.int64)
    for i in np.flatnonzero((vis_n > 0) | (seen > 0)):
        alone_n[i] = _silhouette_px(*parts[i], Kt, H, W)
    with np.errstate(invalid="ignore", divide="ignore"):
        share_all = np.where(alone_n > 0, seen / np.maximum(alone_n, 1), 0.0)
    full = (share_all >= 0.95) & (seen_valid >= 100) & (seen_valid >= 0.5 * seen)
    flat_inst = inst.ravel()
    flat_vis = visible.ravel()
    flat_non = (non & (tcode >= 0)).ravel()
    seg_pair = Counter(zip(seg_lab[flat_vis].tolist(), flat_inst[flat_vis].tolist()))
    un_pair = Counter(zip(lab.ravel()[flat_non & un.ravel()].tolist(), flat_inst[flat_non & un.ravel()].tolist()))
    for i in range(n_inst):
        if matched[i] or vis_n[i] == 0:
            continue
        row: dict[str, Any] = {"instance": i, "visible_px": int(vis_n[i]), "excess_px": int(exc_n[i])}
        alone = int(alone_n[i])
        row["silhouette_px"] = alone
        row["visible_share"] = round(float(share_all[i]), 3) if alone else None
        own = flat_vis & (flat_inst == i)
        sl = seg_lab[own]
        sl = sl[sl > 0]
        if sl.size:
            r = int(np.bincount(sl).argmax())
            row["first_pass_region_px"] = int(seg_sizes[r])
            row["first_pass_region_instances"] = sum(1 for (rr, _), c in seg_pair.items() if rr == r and c >= MERGED_PX)
        else:
            row["first_pass_region_px"] = 0
            row["first_pass_region_instances"] = 0
        mine = flat_non & (flat_inst == i) & un.ravel()
        ul = lab.ravel()[mine]
        if ul.size:
            r = int(np.bincount(ul).argmax())
            s = int(sizes[r])
            row["un_region_px"] = s
            row["un_region_instances"] = sum(1 for (rr, _), c in un_pair.items() if rr == r and c >= MERGED_PX)
            if r in sliver_regions:
                row["pass"] = "tried, a sliver fit there"
            elif s < floor[r]:
                row["pass"] = small
            elif s > 2000:
                row["pass"] = "too large (> 2000 px)"
            elif r not in tried:
                row["pass"] = "beyond the 12-region budget"
            else:
                row["pass"] = "tried, refused"
        else:
            row["un_region_px"] = 0
            row["un_region_instances"] = 0
            row["pass"] = "no unexplained pixel (excess elsewhere)"
        un_own = int((un.ravel() & (flat_inst == i) & (tdist.ravel() <= VISIBLE_MM) & served.ravel()).sum())
        row["unexplained_visible_px"] = un_own
        if oracle and un_own >= ORACLE_MIN_PX and np.isfinite(sigma) and len(poses):
            mask = (un.ravel() & (flat_inst == i) & (tdist.ravel() <= VISIBLE_MM)).reshape(H, W)
            row.update(_oracle(xyz, valid, mask, model, poses, sigma, Kt, true_c[i], size, split=split))
        else:
            row["oracle"] = f"not run (< {ORACLE_MIN_PX} unexplained visible px)"
        rows.append(row)
    total = int(non.sum())
    on_unfit = int(sum(r["excess_px"] for r in rows))
    by_pass: Counter[str] = Counter()
    by_oracle: Counter[str] = Counter()
    by_share: Counter[str] = Counter()
    for r in rows:
        by_pass[r["pass"]] += r["excess_px"]
        by_oracle[r["oracle"]] += r["excess_px"]
        s = r["visible_share"]
        by_share["< 10 %" if s is None or s < 0.1 else "10-30 %" if s < 0.3 else "30-60 %" if s < 0.6 else
                 ">= 60 %"] += r["excess_px"]
    return {"log": log.name, "frame": frame.index, **B.log_kind(log), "label": int(label.sum()),
            "truth": int(truth.sum()), "excess": total, "excess on unfitted instances": on_unfit,
            "true instances": n_inst, "matched": int(matched.sum()), "unfitted with visible px": len(rows),
            "unfitted with excess px": sum(1 for r in rows if r["excess_px"] > 0),
            "found (visible >= 40 px, matched)": int((matched & (vis_n >= 40)).sum()),
            "visible >= 40 px": int((vis_n >= 40).sum()),
            "fully visible": int(full.sum()), "fully visible matched": int((full & matched).sum()),
            "sliver fits": len(sliver_ids), "fits": len(ff.fits), "sigma": sigma,
            "excess by the pass's treatment of the region": dict(by_pass.most_common()),
            "excess by the oracle sliver fit": dict(by_oracle.most_common()),
            "excess by visible share": dict(by_share.most_common()),
            "unfitted": rows}


def main() -> int:
    ap = B.diag_arguments(__doc__.splitlines()[0])
    ap.add_argument("--no-oracle", action="store_true", help="skip the oracle sliver fits")
    ap.add_argument("--split", type=float, default=0.0, metavar="N", help="the pass's regions cut at the scan's depth "
                    "steps of more than N footprints, the oracle with the cut (docs/labelling.md, 'Twenty-third round')")
    ap.add_argument("--min-px", type=int, default=None, metavar="N", help="the pass's size floor (default: the "
                    "method's SLIVER_MIN_PX)")
    ap.add_argument("--area-share", type=float, default=0.0, metavar="A", help="a region too small also under A of a "
                    "whole part's projected area at its depth (docs/labelling.md, 'Twenty-fourth round')")
    args = ap.parse_args()
    if args.min_px is not None and args.min_px < 1 or not 0.0 <= args.area_share <= 1.0:
        raise SystemExit(f"error: --min-px takes N >= 1 and --area-share A in [0, 1], got {args.min_px} and "
                         f"{args.area_share}")
    out = []
    for frame, job, ff in B.diag_frames(args):
        row = frame_split(args.log, frame, job, ff, oracle=not args.no_oracle, split=args.split, min_px=args.min_px,
                          area_share=args.area_share)
        out.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "unfitted"}, indent=1, default=float), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
