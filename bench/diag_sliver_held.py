"""The sliver poses that hold truth (issue 29, h/sliver6): every sliver fit the method's pass accepts on a synthetic
log, with the paper's truth it takes and what the scan alone says of it.

For every frame of a synthetic log (fitted as the page fits it, or read from a ``--fits-cache``), the sliver pass runs
as each ``--slivers`` variant sets it (:func:`bench_label_pageonly.sliver_variants`, the ``--free-space`` cut and
floor one a variant). For each sliver fit it prints the pixels it explains in the page's fits and how many of them are
the paper's truth (``/ground_truth/off_surface``; read only to score, with the truth's kind codes), and cues read off
the scan and the fits alone (never the truth):

- ``twin``: the nearest fitted instance (not a sliver) of the same rotation up to the model's symmetries (Frobenius
  distance below :data:`TWIN_ROT`): the offset of the sliver's centroid from it along the ray through the sliver's
  centroid (mm, positive toward the camera) and across it (mm) — a patch displaced along the rays off a posed part
  is fitted by that part's pose moved along the line of sight;
- ``behind``: the rays through the sliver's own pixels cast against the fitted instances (not slivers) whose centres
  lie within two extents: the share of those pixels whose ray meets one behind the point by more than k × Err, and
  the median and spread (p75 − p25) of that gap (mm);
- ``err_ratio``: the sliver's residual over the frame's median Err at its depth; ``share``, ``see_through``.

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/diag_sliver_held.py LOG --fits-cache DIR \\
        --slivers 10:12:2:8,10:24:2:8 --free-space 3:0.025,3:0.025 [--json F]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
import bench_label_pageonly as B  # noqa: E402

#: two rotations are one up to the model's symmetries below this Frobenius distance (about 12°)
TWIN_ROT = 0.3


def _rot_dist(model: Any, A: np.ndarray, Bm: np.ndarray) -> float:
    return min(float(np.linalg.norm(A @ S - Bm)) for S in model.symmetries)


def sliver_cues(model: Any, xyz: np.ndarray, pose: np.ndarray, pix: np.ndarray, fit_poses: np.ndarray, *,
                f_px: float, sigma: float, k: float, floor_mm: float) -> dict[str, Any]:
    """The scan's and the fits' cues of one sliver fit (module docstring)."""
    c = pose[:3, :3] @ model.centroid + pose[:3, 3]
    ray = c / np.linalg.norm(c)
    cs = fit_poses[:, :3, :3] @ model.centroid + fit_poses[:, :3, 3]
    twin: dict[str, Any] = {}
    best = np.inf
    for j in range(len(fit_poses)):
        if _rot_dist(model, pose[:3, :3], fit_poses[j, :3, :3]) >= TWIN_ROT:
            continue
        d = c - cs[j]
        along = float(-(d @ ray))  # toward the camera: positive
        across = float(np.linalg.norm(d + along * ray))
        if across < best:
            best = across
            twin = {"fit": j, "along_mm": round(along, 2), "across_mm": round(across, 2)}
    pts = xyz.reshape(-1, 3)[pix].astype(np.float64)
    rng = np.linalg.norm(pts, axis=1)
    dirs = pts / rng[:, None]
    near = np.flatnonzero(np.linalg.norm(cs - c, axis=1) <= 2.0 * model.extent_mm)
    hit = np.full(len(pts), np.inf)
    for j in near.tolist():
        R, t = fit_poses[j, :3, :3], fit_poses[j, :3, 3]
        h = model.ray_depths(np.repeat((-R.T @ t)[None], len(pts), axis=0), dirs @ R)
        hit = np.minimum(hit, h)
    foot = np.abs(pts[:, 2]) / f_px
    err = np.maximum(floor_mm, np.sqrt(sigma ** 2 + foot ** 2 / 2.0))
    gap = hit - rng
    met = np.isfinite(gap)
    behind = met & (gap > k * err)
    d_own = model.distance((pts - pose[:3, 3]) @ pose[:3, :3])
    out: dict[str, Any] = {"own_rms_mm": round(float(np.sqrt(np.mean(d_own ** 2))), 3) if len(pts) else 0.0,
                           "own_p90_err": round(float(np.percentile(d_own / err, 90)), 2) if len(pts) else 0.0,
                           "twin": twin, "behind_share": round(float(behind.mean()), 3) if len(pts) else 0.0,
                           "met_share": round(float(met.mean()), 3) if len(pts) else 0.0}
    if behind.any():
        g = gap[behind]
        out["behind_gap_mm"] = round(float(np.median(g)), 2)
        out["behind_spread_mm"] = round(float(np.percentile(g, 75) - np.percentile(g, 25)), 2)
        out["behind_gap_err"] = round(float(np.median(g / err[behind])), 1)
    return out


def frame_slivers(log: Path, frame: Any, job: Any, variants: list[tuple[float, ...]],
                  free: list[tuple[float, float]] | None, truth: dict[str, Any], kinds: np.ndarray | None
                  ) -> list[dict[str, Any]]:
    from zcut import explained as ex
    from zcut.fits import prepare_model

    valid, xyz, _ = B.frame_arrays(frame, job)
    parts, true_s = B._true_surfaces(log, frame)  # the truth: read only to score
    tnear = ex.nearest_surface(xyz, true_s, where=valid)
    tdist = tnear.dist_mm.astype(np.float64).ravel()
    true_c = np.array([v.mean(axis=0) for v, _ in parts]).reshape(-1, 3)
    paper = np.asarray(truth["paper"], bool).ravel()
    rows = []
    model = None
    for name, vff, _cpu, pass_cpu in B.sliver_variants(log, frame, job, variants, free=free):
        if model is None:
            model = prepare_model(*vff.part_mesh)
        poses = np.asarray([f["pose"] for f in vff.fits], np.float64).reshape(-1, 4, 4)
        sl = [i for i, f in enumerate(vff.fits) if f.get("sliver")]
        fitted = poses[[i for i in range(len(vff.fits)) if i not in set(sl)]]
        sigma = float(np.median([e for e in vff.part_err_mm if np.isfinite(e)]))
        for i in sl:
            pix = vff.fit_pix[vff.fit_of == i]
            tp = paper[pix]
            kd = {} if kinds is None else {int(a): int(b) for a, b in zip(*np.unique(kinds.ravel()[pix[tp]],
                                                                                     return_counts=True))}
            f = vff.fits[i]
            med_z = float(np.median(np.abs(xyz.reshape(-1, 3)[pix, 2]))) if len(pix) else float("nan")
            med_err = max(vff.floor_mm, float(np.sqrt(sigma ** 2 + (med_z / vff.f_px) ** 2 / 2.0)))
            row = {"log": log.name, "frame": int(frame.index), "variant": name, "fit": i, "px": int(len(pix)),
                   "truth_px": int(tp.sum()), "truth_share": round(float(tp.mean()) if len(pix) else 0.0, 3),
                   "truth_kinds": kd, "truth_total": int(paper.sum()), "err_mm": round(float(f["err_mm"]), 3),
                   "share": round(float(f["support"]), 3), "err_ratio": round(float(f["err_mm"]) / med_err, 2),
                   "cpu_slivers": round(pass_cpu, 2),
                   **sliver_cues(model, xyz, np.asarray(f["pose"], np.float64), pix, fitted, f_px=float(vff.f_px),
                                 sigma=sigma, k=float(vff.k), floor_mm=float(vff.floor_mm))}
            posed = np.asarray(vff.part_mesh[0], np.float64) @ np.asarray(f["pose"])[:3, :3].T + np.asarray(f["pose"])[:3, 3]
            size = float(np.linalg.norm(vff.part_mesh[0].max(axis=0) - vff.part_mesh[0].min(axis=0)))
            dc = np.linalg.norm(true_c - posed.mean(axis=0), axis=1) if len(true_c) else np.array([np.inf])
            row["true_instance"] = bool(dc.min() <= 0.25 * size)
            row["truth_tdist_mm"] = round(float(np.median(tdist[pix[tp]])), 2) if tp.any() else None
            rows.append(row)
            print(json.dumps(row, default=float), flush=True)
    return rows


def main() -> int:
    ap = B.diag_arguments(__doc__.splitlines()[0])
    ap.add_argument("--slivers", required=True, help="N:M[:C:R[:S]],… as bench_label_pageonly.py takes them")
    ap.add_argument("--free-space", default=None, help="S:A,… one a --slivers variant")
    args = ap.parse_args()
    try:
        variants = B.parse_slivers(args.slivers)
        free = None if args.free_space is None else B.parse_free(args.free_space)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    from replay.logs import layout
    from replay.logs.reader import LogReader

    truths = B.truths(args.log)
    kinds = {f.index: f.codes.get(layout.TRUTH_OUTLIER_KIND) for f in LogReader(args.log).frames()}
    out: list[dict[str, Any]] = []
    with B.shared_fits():
        for frame, job, _ff in B.diag_frames(args):
            out += frame_slivers(args.log, frame, job, variants, free, truths[frame.index], kinds.get(frame.index))
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
