"""The sliver pass's free-space test at the generator's true pose (issue 29, h/free): is the test miscalibrated for the
sensor, and where do the pixels it calls "seen through" lie?

For every frame of a synthetic log (fits read from a ``--fits-cache`` of ``bench/bench_label_pageonly.py``, or made as
the page makes them), the instances no fit matches (as bench/diag_unfit.py matches them) whose visible share is at least
``--min-share`` (default 0.6: the *whole* nuts) and, as a control, the fully visible instances a fit matches
(bench/bench_fits.py's rule), are posed at the generator's **true** pose (the log's record: read only to score; the
pose is the rigid transform of the part mesh onto the instance's true mesh) and
:func:`zcut.sliver_fits.see_through_share` is asked with the method's parameters (σ the frame's median fit residual,
k, Err's floor). Each seen-through pixel (its point more than k × Err behind the model's first hit) is split by

- *where* on the posed silhouette it lies: its outermost ring (1 px), the second ring (2 px), inside (chessboard
  distance to the silhouette's outside, the silhouette of the pixel centres' rays);
- *what* its measured point is: on the instance itself (within :data:`ON_MM` of its true mesh, the nearest true
  surface), on another instance, on the bin or table (a surface beneath), off every true surface;
- the generator's outlier kind there (``/ground_truth/outlier_kind``: interreflection, mixed pixel, saturation edge,
  ...), and whether the pixel is at a depth edge (a neighbour invalid or more than 10 footprints off in depth);
- whether the true instance is the first surface the pixel's ray meets in the scene (else another instance is in
  front of it there).

For the unmatched ones, the pass's own pose too: :func:`zcut.sliver_fits.fit_slivers` (the method's parameters, the free
space not bounded) on the instance's own unexplained visible pixels (bench/diag_unfit.py's oracle region): its
rotation error (up to the model's symmetries) and centre error against the true pose, and its see-through share.

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/diag_free.py LOG [--fits-cache DIR] [--frames 0,1] [--json F]
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
import diag_unfit as U  # noqa: E402

#: a measured point is on a true surface when it lies within this of it
ON_MM = 1.0
#: a pixel is at a depth edge when a 4-neighbour is invalid or more than this many footprints off in depth
EDGE_FOOTPRINTS = 10.0


def rigid(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """(pose (4, 4), RMS residual mm): the rigid transform taking points ``a`` onto ``b`` (least squares, Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _s, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T, float(np.sqrt(np.mean(np.sum((a @ R.T + T[:3, 3] - b) ** 2, axis=1))))


def see_through_pixels(xyz: np.ndarray, valid: np.ndarray, model: Any, pose: np.ndarray, *,
                       intrinsics: tuple[float, float, float, float], sigma_mm: float, k: float,
                       floor_mm: float) -> dict[str, Any]:
    """:func:`zcut.sliver_fits.see_through_share`'s computation, literally, keeping its pixels: the window, the
    silhouette pixels (valid, the ray of their point meets the model) and which of them are seen through."""
    H, W = valid.shape
    fx, fy, cx, cy = intrinsics
    R, t = pose[:3, :3], pose[:3, 3]
    v = model.vertices @ R.T + t
    u, w = fx * v[:, 0] / v[:, 2] + cx, fy * v[:, 1] / v[:, 2] + cy
    c0, c1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, W)
    r0, r1 = max(int(np.floor(w.min())) - 1, 0), min(int(np.ceil(w.max())) + 2, H)
    win = valid[r0:r1, c0:c1]
    rr, cc = np.nonzero(win)
    p = np.asarray(xyz[r0:r1, c0:c1], np.float64)[win]
    rng = np.linalg.norm(p, axis=1)
    d = p / rng[:, None]
    hit = model.ray_depths(np.repeat((-R.T @ t)[None], len(p), axis=0), d @ R)
    seen = np.isfinite(hit)
    foot = np.abs(p[seen, 2]) / fx
    err = np.maximum(floor_mm, np.sqrt(sigma_mm ** 2 + foot ** 2 / 2.0))
    behind = (rng[seen] - hit[seen]) > k * err
    # the silhouette of the pixel centres' rays over the whole window (valid or not), for the rings
    gr, gc = np.mgrid[r0:r1, c0:c1]
    dirs = np.stack([(gc - cx) / fx, (gr - cy) / fy, np.ones(gr.shape)], axis=-1).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    sil = np.isfinite(model.ray_depths(np.repeat((-R.T @ t)[None], len(dirs), axis=0), dirs @ R)).reshape(gr.shape)
    ring = ndimage.distance_transform_cdt(np.pad(sil, 1), metric="chessboard")[1:-1, 1:-1]
    return {"window": (r0, r1, c0, c1), "rows": rr[seen] + r0, "cols": cc[seen] + c0, "behind": behind,
            "gap_mm": (rng[seen] - hit[seen]), "kerr_mm": k * err, "ring": ring[rr[seen], cc[seen]],
            "share": float(behind.mean()) if seen.any() else 0.0, "silhouette": int(seen.sum())}


def depth_edges(xyz: np.ndarray, valid: np.ndarray, fx: float) -> np.ndarray:
    """(H, W) bool: a valid pixel with a 4-neighbour invalid or more than :data:`EDGE_FOOTPRINTS` footprints off in z."""
    z = np.where(valid, xyz[..., 2], np.nan)
    foot = np.abs(z) / fx
    out = np.zeros(valid.shape, bool)
    zp = np.pad(z, 1, constant_values=np.nan)
    H, W = valid.shape
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        n = zp[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
        with np.errstate(invalid="ignore"):
            out |= ~np.isfinite(n) | (np.abs(n - z) > EDGE_FOOTPRINTS * foot)
    return out & valid


def rot_err_deg(model: Any, A: np.ndarray, B_: np.ndarray) -> float:
    """The smallest rotation angle (degrees) between A's and B's rotations up to the model's symmetries."""
    best = 180.0
    for S in model.symmetries:
        Rr = (A[:3, :3] @ S).T @ B_[:3, :3]
        c = float(np.clip((np.trace(Rr) - 1.0) / 2.0, -1.0, 1.0))
        best = min(best, float(np.degrees(np.arccos(c))))
    return best


def frame_rows(log: Path, frame: Any, job: Any, ff: Any, *, min_share: float, control: bool) -> dict[str, Any]:
    from replay.logs import layout
    from replay.pipeline import explained as pe
    from zcut import explained as ex
    from zcut.sliver_fits import SliverParams, fit_slivers, see_through_share

    valid, xyz, _ = B.frame_arrays(frame, job)
    H, W = valid.shape
    zone = np.asarray(job.zone, bool) & valid
    easy = np.asarray(job.removal.easy_outliers, bool)
    served = (zone | easy) & valid
    parts, true_s = B._true_surfaces(log, frame)
    # valid & finite: the test's pixels (the method passes isfinite(xyz) as valid; xyz is NaN where invalid)
    tv = np.isfinite(xyz).all(axis=2)
    near = ex.nearest_surface(xyz, true_s, where=tv)
    tcode, tdist = near.surface, near.dist_mm.astype(np.float64)
    kind = np.asarray(frame.codes[layout.TRUTH_OUTLIER_KIND]) if layout.TRUTH_OUTLIER_KIND in frame.codes else \
        np.zeros((H, W), np.uint8)
    off_truth = np.asarray(frame.masks[layout.TRUTH_OFF_SURFACE], bool)
    K = frame.intrinsics
    Kt = (float(K.fx), float(K.fy), float(K.cx), float(K.cy))
    edges = depth_edges(xyz, tv, Kt[0])
    v0, t0 = ff.part_mesh
    model = U._prepared(v0, t0)
    size = float(np.linalg.norm(v0.max(axis=0) - v0.min(axis=0)))
    fit_c = np.array([ff.posed(i)[0].mean(axis=0) for i in range(len(ff.fits))]).reshape(-1, 3)
    true_c = np.array([v.mean(axis=0) for v, _ in parts]).reshape(-1, 3)
    dd = np.linalg.norm(true_c[:, None, :] - fit_c[None, :, :], axis=2)
    matched = dd.min(axis=1) <= 0.25 * size if len(fit_c) else np.zeros(len(true_c), bool)
    best_fit = dd.argmin(axis=1) if len(fit_c) else np.zeros(len(true_c), np.int64)
    n_inst = len(parts)
    inst = np.where(tcode >= 0, tcode, n_inst)
    visible = served & (tcode >= 0) & (tdist <= U.VISIBLE_MM)
    vis_n = np.bincount(inst[visible], minlength=n_inst + 1)[:n_inst]
    hits = U._first_hits(parts, Kt, H, W)
    seen_n = np.bincount(hits[hits >= 0], minlength=n_inst)[:n_inst]
    seen_valid = np.bincount(hits[(hits >= 0) & valid], minlength=n_inst)[:n_inst]
    sig = np.asarray([e for e, f in zip(ff.part_err_mm, ff.fits) if not f.get("sliver")], np.float64)
    sig = sig[np.isfinite(sig)]
    sigma = float(np.median(sig))
    k, floor = float(ff.k), float(ff.floor_mm)
    poses = np.stack([np.asarray(f["pose"], np.float64) for f in ff.fits if not f.get("sliver")])
    un, _ = B.sliver_input(ff, zone)
    base = SliverParams(min_px=1, max_px=10 ** 9, max_regions=1, coarse=pe.SLIVER_COARSE, refine=pe.SLIVER_REFINE,
                        max_see_through=1.0)
    rows = []
    for i in range(n_inst):
        if vis_n[i] == 0:
            continue
        alone = U._silhouette_px(*parts[i], Kt, H, W)
        share_vis = seen_n[i] / alone if alone else 0.0
        full = share_vis >= 0.95 and seen_valid[i] >= 100 and seen_valid[i] >= 0.5 * seen_n[i]
        if matched[i]:
            if not (control and full):
                continue
            group = "matched, fully visible"
        elif share_vis >= min_share:
            group = "unmatched, whole"
        else:
            continue
        T, fit_rms = rigid(v0, parts[i][0])
        st = see_through_pixels(xyz, tv, model, T, intrinsics=Kt, sigma_mm=sigma, k=k, floor_mm=floor)
        ref = see_through_share(xyz, tv, model, T, intrinsics=Kt, sigma_mm=sigma, k=k, floor_mm=floor)
        assert abs(ref[0] - st["share"]) < 1e-12 and ref[1] == st["silhouette"], (ref, st["share"], st["silhouette"])
        r, c, b = st["rows"], st["cols"], st["behind"]
        rb, cb = r[b], c[b]
        tc, td = tcode[rb, cb], tdist[rb, cb]
        what = np.where(td > ON_MM, "off every true surface",
                        np.where(tc == i, "on the instance itself",
                                 np.where(tc >= 0, "on another instance", "on the bin or table")))
        ring = np.where(st["ring"][b] == 1, "ring 1 px", np.where(st["ring"][b] == 2, "ring 2 px", "inside"))
        row: dict[str, Any] = {
            "instance": i, "group": group, "visible_share": round(float(share_vis), 3), "visible_px": int(vis_n[i]),
            "pose_rms_mm": fit_rms, "silhouette": st["silhouette"], "see_through_true": round(st["share"], 4),
            "seen_through_px": int(b.sum()),
            "by_place": dict(Counter(ring.tolist())),
            "by_what": dict(Counter(what.tolist())),
            "by_place_what": dict(Counter(f"{a} | {w}" for a, w in zip(ring.tolist(), what.tolist()))),
            "by_kind": dict(Counter(str(B_kind(int(x))) for x in kind[rb, cb].tolist())),
            "by_cause": dict(Counter(causes(st["ring"][b], edges[rb, cb], kind[rb, cb], what).tolist())),
            "paper_truth": int(off_truth[rb, cb].sum()),
            "depth_edge": int(edges[rb, cb].sum()),
            "first_hit_self": int((hits[rb, cb] == i).sum()),
            "first_hit_other": int(((hits[rb, cb] >= 0) & (hits[rb, cb] != i)).sum()),
            "gap_over_kerr_median": float(np.median(st["gap_mm"][b] / st["kerr_mm"][b])) if b.any() else None,
            "gap_mm_median": float(np.median(st["gap_mm"][b])) if b.any() else None,
            "silhouette_ring1": int((st["ring"] == 1).sum()), "silhouette_ring2": int((st["ring"] == 2).sum()),
            "rules_true": rule_shares(st, edges),
        }
        if matched[i]:
            Tf = np.asarray(ff.fits[int(best_fit[i])]["pose"], np.float64)
            row["fit_rot_err_deg"] = rot_err_deg(model, Tf, T)
            row["fit_centre_err_mm"] = float(np.linalg.norm((Tf[:3, :3] - T[:3, :3]) @ model.centroid
                                                             + Tf[:3, 3] - T[:3, 3]))
            row["see_through_fit"] = round(see_through_share(xyz, tv, model, Tf, intrinsics=Kt, sigma_mm=sigma, k=k,
                                                             floor_mm=floor)[0], 4)
        else:
            mask = un & (inst == i) & (tdist <= U.VISIBLE_MM) & served
            row["unexplained_visible_px"] = int(mask.sum())
            if mask.sum() >= U.ORACLE_MIN_PX:
                got = fit_slivers(xyz, tv, mask, model, poses, sigma_mm=sigma, intrinsics=Kt,
                                  params=dataclasses.replace(base, k=k, floor_mm=floor))
                if got:
                    P = got[0].pose
                    row["pass_rot_err_deg"] = rot_err_deg(model, P, T)
                    row["pass_centre_err_mm"] = float(np.linalg.norm((P[:3, :3] - T[:3, :3]) @ model.centroid
                                                                     + P[:3, 3] - T[:3, 3]))
                    sp = see_through_pixels(xyz, tv, model, P, intrinsics=Kt, sigma_mm=sigma, k=k, floor_mm=floor)
                    row["see_through_pass"] = round(sp["share"], 4)
                    bp = sp["behind"]
                    row["pass_by_place"] = dict(Counter(np.where(
                        sp["ring"][bp] == 1, "ring 1 px", np.where(sp["ring"][bp] == 2, "ring 2 px",
                                                                   "inside")).tolist()))
                    row["pass_seen_through_px"] = int(bp.sum())
                    row["rules_pass"] = rule_shares(sp, edges)
                    row["pass_silhouette"] = sp["silhouette"]
                else:
                    row["pass_rot_err_deg"] = None
        rows.append(row)
    return {"log": log.name, "frame": frame.index, **B.log_kind(log), "sigma": sigma, "k": k,
            "instances": n_inst, "rows": rows}


def causes(ring: np.ndarray, edge: np.ndarray, kind: np.ndarray, what: np.ndarray) -> np.ndarray:
    """Each seen-through pixel's cause, the first that applies: the silhouette's outer two rings; inside, at a depth
    edge of the scan; inside, off the edges, an interreflection ghost (the generator's kind); inside, off the edges,
    its point on a surface beneath (another instance, the bin or table); else other."""
    from replay.logs import layout

    inter = next(c for c, n in layout.OUTLIER_KINDS.items() if n == "interreflection")
    beneath = (what == "on another instance") | (what == "on the bin or table")
    return np.select([ring <= 2, edge, kind == inter, beneath],
                     ["rim (rings 1-2)", "inside, depth edge", "inside, interreflection ghost",
                      "inside, a surface beneath"], "inside, other")


#: the free-space test's candidate readings: which silhouette pixels count (numerator and denominator)
RULES = ("all", "no depth edge", "ring >= 3", "ring >= 3, no depth edge", "ring >= 2", "ring >= 2, no depth edge")


def rule_shares(st: dict[str, Any], edges: np.ndarray) -> dict[str, float]:
    """The see-through share of :func:`see_through_pixels`' result when only some silhouette pixels count
    (:data:`RULES`): those not at a depth edge, those at least 3 (2) rings inside the silhouette, both."""
    e = edges[st["rows"], st["cols"]]
    ring = st["ring"]
    out = {}
    for name in RULES:
        keep = np.ones(len(ring), bool)
        if "ring >= 3" in name:
            keep &= ring >= 3
        if "ring >= 2" in name:
            keep &= ring >= 2
        if "no depth edge" in name:
            keep &= ~e
        out[name] = round(float(st["behind"][keep].mean()), 4) if keep.any() else 0.0
    return out


def B_kind(code: int) -> str:
    from replay.logs import layout

    return "not an outlier" if code == 0 else layout.OUTLIER_KINDS.get(code, f"code {code}")


def main() -> int:
    ap = B.diag_arguments(__doc__.splitlines()[0])
    ap.add_argument("--min-share", type=float, default=0.6, help="the unmatched instances of at least this visible share")
    ap.add_argument("--no-control", action="store_true", help="skip the matched fully visible instances")
    args = ap.parse_args()
    out = []
    for frame, job, ff in B.diag_frames(args):
        row = frame_rows(args.log, frame, job, ff, min_share=args.min_share, control=not args.no_control)
        out.append(row)
        print(json.dumps({"frame": row["frame"], "sigma": row["sigma"], "rows": len(row["rows"])}), flush=True)
        if args.json is not None:
            args.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
