"""The fitted parts' fringes the page-only person labels (issue 29, h/fringe): the label's pixels that are not the
paper's truth though their nearest true surface is a part instance some fit matches, split by cause.

For every frame of a synthetic log (fitted as the page fits it, :func:`bench_label_pageonly.fitted_frames`, or read
from a ``--fits-cache``), the page-only person's label is emulated (:func:`bench_label_pageonly._emulated_person`)
and its excess pixels E (labelled, not the paper's truth) whose nearest true surface is a fitted instance are split:

- **(a) pose**: the true surface lies within k × the page's Err of the pixel (a fit at the true pose with the
  method's Err would explain it): the fit's pose (or its mesh) is what is off;
- **(b) Err**: the true surface is farther than k × the page's Err (it lies within k × the truth's Err, else the
  pixel would be truth): the method's Err at the pixel is below the truth's;

each crossed with where the pixel lies: **(d) mixed** — at a depth step (its 8-neighbours' depths span more than
10 footprints) with its depth more than k × Err inside that span from both ends (a blend of two surfaces along its
ray); on a **hidden face** (the true closest point's face turns away from the camera); at a depth edge otherwise;
else on a face. **(c)** the pixels whose page-nearest surface is not their instance's fit (another fit, the bin,
the table: the instance's own fit is farther) are counted apart, and the excess whose nearest true surface is an
unfitted instance, the bin or the table (not this class) is given for scale. The generator's metadata scores only.

Also per matched fit, its pose error as a surface displacement: the distance of its posed mesh's vertices to the
instance's true mesh (median, 90th percentile), for all matched fits and for those holding (a) pixels.

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/diag_fringe.py LOG [--fits-cache DIR] [--frames 0,1] [--json F]
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


def _closest(meshes: list[tuple[np.ndarray, np.ndarray]], p: np.ndarray) -> dict[str, np.ndarray]:
    """Open3D's closest points of ``p`` (n, 3) on ``meshes``: points, geometry ids, normals (float64)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for v, t in meshes:
        scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]
                            o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]
    ans = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(p, np.float32)))  # type: ignore[call-overload]
    return {"points": ans["points"].numpy().astype(np.float64), "gid": ans["geometry_ids"].numpy().astype(np.int64),
            "normals": ans["primitive_normals"].numpy().astype(np.float64)}


def _handmade_err(log: Path, frame: Any) -> np.ndarray | None:
    """The hand-made generator's Err image of ``frame`` (its ``err_mm``, rebuilt from the log's record), or None for
    a ray-traced log (rebuilding it would trace the frame again)."""
    from replay.logs import layout
    from replay.logs.reader import LogReader

    meta = LogReader(log).metadata[layout.SYNTH_METADATA]
    if meta.get("sensor") == "raytraced":
        return None
    from replay.synth.synthesize import synthesize_frame

    sf = synthesize_frame(kind=meta["part_kind"], seed=int(meta["seed"]), index=frame.index,
                          size=(int(meta["height"]), int(meta["width"])))
    return np.asarray(sf.err_mm, np.float64)


def frame_split(log: Path, frame: Any, job: Any, ff: Any) -> dict[str, Any]:
    from replay.logs import layout
    from zcut import explained as ex

    valid, xyz, heights = B.frame_arrays(frame, job)
    H, W = valid.shape
    label, ids, _ = B._emulated_person(ff, xyz, heights, valid)
    easy = np.asarray(job.removal.easy_outliers, bool)
    served = (np.asarray(job.zone, bool) | easy) & valid
    label &= served
    truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served
    parts, true_s = B._true_surfaces(log, frame)
    err_true = _handmade_err(log, frame)
    near_t = ex.nearest_surface(xyz, true_s, where=served)
    tcode, tdist = near_t.surface, near_t.dist_mm.astype(np.float64)
    v0 = ff.part_mesh[0]
    size = float(np.linalg.norm(v0.max(axis=0) - v0.min(axis=0)))
    fit_c = np.array([ff.posed(i)[0].mean(axis=0) for i in range(len(ff.fits))]).reshape(-1, 3)
    true_c = np.array([v.mean(axis=0) for v, _ in parts]).reshape(-1, 3)
    dd = np.linalg.norm(true_c[:, None, :] - fit_c[None, :, :], axis=2)
    matched = dd.min(axis=1) <= 0.25 * size
    match_of = np.where(matched, dd.argmin(axis=1), -1)
    pdist = np.full(H * W, np.nan)
    perr = np.full(H * W, np.nan)
    pcode = np.full(H * W, -9, np.int64)
    pdist[ff.un_pix], perr[ff.un_pix], pcode[ff.un_pix] = ff.un_dist, ff.un_err, ff.un_code
    pdist, perr, pcode = pdist.reshape(H, W), perr.reshape(H, W), pcode.reshape(H, W)
    k = float(ff.k)
    zz = np.where(valid, xyz[..., 2], np.nan)
    foot = np.abs(zz) / ff.f_px
    pad = np.pad(zz, 1, constant_values=np.nan)
    zmin = np.full((H, W), np.inf)
    zmax = np.full((H, W), -np.inf)
    jump = np.zeros((H, W), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                nb = pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                with np.errstate(invalid="ignore"):
                    jump |= ~(np.abs(nb - zz) <= 10.0 * foot)
                zmin = np.fmin(zmin, nb)
                zmax = np.fmax(zmax, nb)
    jump &= valid
    with np.errstate(invalid="ignore"):
        mixed = (jump & (zmax - zmin > 10.0 * foot) & (zz - zmin > k * perr) & (zmax - zz > k * perr))
    non = label & ~truth
    inst = np.where(tcode >= 0, tcode, 0)
    on_fitted = non & (tcode >= 0) & matched[inst]
    E = on_fitted
    own = E & (pcode == match_of[inst])
    # the true closest point on the pixel's instance: its face turns away from the camera -> a hidden face
    e_idx = np.flatnonzero(E.ravel())
    p = xyz.reshape(-1, 3)[e_idx]
    hidden = np.zeros(H * W, bool)
    d_own = np.full(H * W, np.nan)
    if e_idx.size:
        ti = tcode.ravel()[e_idx]
        got = _closest([parts[i] for i in range(len(parts))], p)
        # the closest point found among every true instance; keep the pixel's own (its nearest by construction)
        facing = np.einsum("ij,ij->i", got["normals"], got["points"])  # normal . (point - camera at origin)
        hidden[e_idx] = facing > 0
        # distance of each E pixel to its instance's fit's mesh (one scene per fit holding E pixels)
        fj = match_of[ti]
        for j in np.unique(fj):
            sel = fj == j
            g = _closest([ff.posed(int(j))], p[sel])
            d_own[e_idx[sel]] = np.linalg.norm(g["points"] - p[sel], axis=1)
    hidden = hidden.reshape(H, W)
    d_own = d_own.reshape(H, W)
    pose = E & (tdist <= k * perr)
    errc = E & ~(tdist <= k * perr)
    where = {"mixed (d)": E & mixed, "hidden face": E & ~mixed & hidden,
             "depth edge, visible face": E & ~mixed & ~hidden & jump, "face (no edge)": E & ~mixed & ~hidden & ~jump}
    row: dict[str, Any] = {"log": log.name, "frame": frame.index, **B.log_kind(log), "label": int(label.sum()),
                           "truth": int(truth.sum()), "excess": int(non.sum()),
                           "excess: unfitted instance": int((non & (tcode >= 0) & ~matched[inst]).sum()),
                           "excess: bin": int((non & (tcode == ex.SURFACE_BIN)).sum()),
                           "excess: table": int((non & (tcode == ex.SURFACE_TABLE)).sum()),
                           "excess: fitted instance (E)": int(E.sum()),
                           "E: page-nearest is its own fit": int(own.sum()),
                           "E: page-nearest another surface (c)": int((E & ~own).sum()),
                           "E (a) pose": int(pose.sum()), "E (b) Err": int(errc.sum())}
    for name, m in where.items():
        row[f"E (a) pose, {name}"] = int((pose & m).sum())
        row[f"E (b) Err, {name}"] = int((errc & m).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (tdist / perr)[errc]
        row["E (b): truth dist / page Err, quartiles"] = [round(float(q), 2) for q in np.percentile(r, [25, 50, 75])] \
            if r.size else None
        ratio = (perr / foot)[E]
        row["E: page Err / footprint, quartiles"] = [round(float(q), 3) for q in np.percentile(ratio, [25, 50, 75])] \
            if ratio.size else None
        row["E: page Err mm, quartiles"] = [round(float(q), 3) for q in np.percentile(perr[E], [25, 50, 75])] \
            if E.any() else None
        cost = (d_own - tdist)[pose & own]
        row["E (a) own fit: d_fit - d_true mm, quartiles"] = [round(float(q), 3) for q in
                                                              np.percentile(cost, [25, 50, 75])] if cost.size else None
        row["E (a): d_true / page Err, quartiles"] = [round(float(q), 2) for q in
                                                      np.percentile((tdist / perr)[pose], [25, 50, 75])] \
            if pose.any() else None
        row["truth: page Err mm (label & truth), median"] = float(np.nanmedian(perr[label & truth])) \
            if (label & truth).any() else None
    if err_true is not None:  # the hand-made generator's own Err at each pixel (the ray-traced one is not rebuilt)
        with np.errstate(invalid="ignore", divide="ignore"):
            q = (err_true / perr)[E]
            row["E: truth Err / page Err, quartiles"] = [round(float(v), 3) for v in np.percentile(q, [25, 50, 75])]
            row["E: truth Err mm, quartiles"] = [round(float(v), 3) for v in np.percentile(err_true[E], [25, 50, 75])]
            lt = label & truth
            row["label & truth: truth Err / page Err, median"] = float(np.nanmedian((err_true / perr)[lt])) \
                if lt.any() else None
    # each matched fit's pose error: its posed mesh's vertices' distance to the instance's true mesh
    disp = []
    a_fits = set(match_of[inst[pose & own]].tolist())
    for ti in np.flatnonzero(matched):
        j = int(match_of[ti])
        v, _ = ff.posed(j)
        g = _closest([parts[ti]], v)
        d = np.linalg.norm(g["points"] - v, axis=1)
        disp.append((float(np.median(d)), float(np.percentile(d, 90)), j in a_fits))
    if disp:
        a = np.asarray(disp)
        row["fits matched"] = len(disp)
        row["pose error: vertex-to-true median mm (all fits), quartiles"] = [round(float(q), 3) for q in
                                                                            np.percentile(a[:, 0], [25, 50, 75])]
        row["pose error: vertex-to-true p90 mm (all fits), quartiles"] = [round(float(q), 3) for q in
                                                                         np.percentile(a[:, 1], [25, 50, 75])]
        sel = a[:, 2] > 0
        if sel.any():
            row["pose error: p90 mm (fits with (a) px), quartiles"] = [round(float(q), 3) for q in
                                                                      np.percentile(a[sel, 1], [25, 50, 75])]
    return row


def main() -> int:
    ap = B.diag_arguments(__doc__.splitlines()[0])
    args = ap.parse_args()
    rows = []
    for frame, job, ff in B.diag_frames(args):
        rows.append(frame_split(args.log, frame, job, ff))
        print(json.dumps(rows[-1], indent=1), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
