"""The fits under each arbitrary sign choice of the principal axes they start from, against an older tree's fits, on
the same frames in one process (issue 29: where the fits' own linear algebra lost quality, docs/fits.md).

    PYTHONPATH=. .venv/bin/python bench/bench_fits_signs.py --old /tmp/old [--seed 7751] [--frames 0,1,2] \\
        [--sensor handmade] [--variants old,J:D0,J:D1,J:D2,J:D3,C:D0,J:main,L:D0,L:main] [--cache DIR] \\
        [--trace FRAME:INSTANCE] [--json OUT]

Runs in a tree whose zcut/fits/fit.py has its own ``principal_axes`` (fbdd9d0, and on branch h/blas2 its pick a47c778
and the symmetry frame bc99e14; all reverted, docs/fits.md). ``--old``: a ``git archive`` of the older tree (main),
imported as bench/bench_fits_blas.py does. A variant ``RULE:MODEL`` fits with this tree's code and:

- ``RULE``, the signs of each region's axes: ``J`` as this tree computes them (``sym_eigh``: each vector's entry of
  largest magnitude positive), ``L`` LAPACK's (``np.linalg.eigh`` of ``np.cov`` of the centred points, main's call),
  ``C`` the least-variance axis (the region's normal) towards the camera, the middle one then signed to keep a right
  hand;
- ``MODEL``, the model's axes and guess templates: ``D0``..``D3`` this tree's axes times the proper sign patterns
  (1, 1, 1), (-1, -1, 1), (-1, 1, -1), (1, -1, -1), the templates made from them as this tree makes them (in the
  symmetries' frame where the tree has ``_symmetry_frame``), ``main`` the older tree's model's guess templates (made
  from LAPACK's axes).

``old`` is the older tree as it is. Each variant fits each frame once (bench/bench_fits_blas.py's frames and zone),
scored by bench/bench_fits.py's ``score``; per frame the fully visible instances whose rotation error grew most
from ``old`` are listed. ``--trace F:I`` follows instance I of frame F (bench/bench_fits.py's numbering) through
``_fit_general`` for ``J:D0`` and ``J:main``: each call whose region is mostly the instance's (its size, shifts, Err,
pose error) and, for the first such region, every guess's start error, coarse score and error after the coarse ICP.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_fits as BF  # noqa: E402
import bench_fits_blas as BB  # noqa: E402

SIGNS = ((1.0, 1.0, 1.0), (-1.0, -1.0, 1.0), (-1.0, 1.0, -1.0), (1.0, -1.0, -1.0))


def _rules(F: Any) -> dict[str, Any]:
    own = F.principal_axes

    def lapack(points: np.ndarray) -> np.ndarray:
        c = points.mean(axis=0)
        out: np.ndarray = np.linalg.eigh(np.cov((points - c).T))[1]
        return out

    def camera(points: np.ndarray) -> np.ndarray:
        ax: np.ndarray = own(points).copy()
        if float(ax[:, 0] @ points.mean(axis=0)) > 0:
            ax[:, 0] = -ax[:, 0]
        if np.linalg.det(ax[:, ::-1]) < 0:
            ax[:, 1] = -ax[:, 1]
        return ax

    return {"J": own, "L": lapack, "C": camera}


def _per_instance(truth: BF.Truth, fits: list[Any], model: Any, pose_error: Any) -> dict[int, float]:
    """{instance: rotation error (degrees)} of the fully visible matched instances (bench_fits.score's rule)."""
    ids, alone = BF.instance_ids(truth)
    n = len(truth.poses)
    valid = np.isfinite(truth.xyz_mm).all(axis=2)
    seen = np.bincount(ids.reshape(-1), minlength=n + 1)[1:]
    seen_valid = np.bincount(ids[valid], minlength=n + 1)[1:]
    share = np.where(alone > 0, seen / np.maximum(alone, 1), 0.0)
    full = np.flatnonzero((share >= 0.95) & (seen_valid >= 100) & (seen_valid >= 0.5 * seen))
    c = model.centroid
    fit_c = np.array([f.pose[:3, :3] @ c + f.pose[:3, 3] for f in fits]).reshape(-1, 3)
    out = {}
    for i in full:
        T = truth.poses[i]
        ci = T[:3, :3] @ c + T[:3, 3]
        if not len(fit_c):
            break
        j = int(np.argmin(np.linalg.norm(fit_c - ci, axis=1)))
        if np.linalg.norm(fit_c[j] - ci) <= 0.5 * model.extent_mm:
            out[int(i)] = float(pose_error(fits[j].pose, T, model)[1])
    return out


def _trace(F: Any, new: Any, truth: BF.Truth, zone: np.ndarray, models: dict[str, Any], inst: int) -> None:
    ids, _ = BF.instance_ids(truth)
    mine = np.flatnonzero(ids.reshape(-1) == inst + 1)
    T_true = truth.poses[inst]
    calls: list[dict[str, Any]] = []
    orig = F._fit_general

    def wrapped(frame: Any, flat: np.ndarray, model: Any, params: Any, shifts: int = 0) -> tuple[np.ndarray, float]:
        T, err = orig(frame, flat, model, params, shifts)
        if np.isin(flat, mine).sum() > 0.5 * len(flat):
            calls.append(dict(frame=frame, flat=flat.copy(), shifts=shifts, err=err, de=new.pose_error(T, T_true, model)))
        return T, err

    firsts = {}
    F._fit_general = wrapped
    try:
        for name in ("J:D0", "J:main"):
            calls.clear()
            new.fit_prepared(truth.xyz_mm, zone, models[name.split(":")[1]], intrinsics=truth.K, params=new.FitParams())
            print(f"trace {name}: the calls on instance {inst} (px, shifts, Err mm, error mm / deg): " + ", ".join(
                f"({len(c['flat'])}, {c['shifts']}, {c['err']:.3f}, {c['de'][0]:.2f} / {c['de'][1]:.2f})" for c in calls))
            if calls:
                firsts[name] = calls[0]
    finally:
        F._fit_general = orig
    if not firsts:
        return
    first = next(iter(firsts.values()))
    frame, flat, params = first["frame"], first["flat"], new.FitParams()
    print("the first region the same in both:", all(np.array_equal(c["flat"], flat) for c in firsts.values()))
    sub = F._subsample(flat, params.max_points)
    pts = frame.xyz.reshape(-1, 3)[sub]
    coarse = np.ascontiguousarray(pts[F._subsample(np.arange(len(pts)), F.COARSE_POINTS)])
    bnd = F._subsample(F._occluding_boundary(frame, flat, params.jump_mm), params.max_points // 2)
    epts = frame.xyz.reshape(-1, 3)[bnd]
    coarse_e = np.ascontiguousarray(epts[F._subsample(np.arange(len(epts)), F.COARSE_POINTS // 2)])
    px_mm = float(np.median(pts[:, 2])) / (0.5 * (frame.K[0] + frame.K[1]))
    edge_gate = max(3.0 * px_mm, params.k * params.err_floor_mm)
    score_tol = max(params.k * params.err_floor_mm, params.gate_mm / 4)
    ax = F.principal_axes(pts)
    print(f"the region's axes (ascending variance, columns):\n{np.round(ax, 4)}")
    for name in ("J:D0", "J:main"):
        model = models[name.split(":")[1]]
        ix = model.index
        Rs = np.stack(F.initial_rotations(pts, model, axes=ax))
        ts = F.guess_translations(pts, Rs, model)
        print(f"{name}: {len(Rs)} guesses (start error deg -> coarse score, error deg / mm after the coarse ICP)")
        for i in range(len(Rs)):
            _, R, t, sc = F.coarse_search(coarse, coarse_e, Rs[i:i + 1].copy(), ts[i:i + 1].copy(),
                                          int(params.coarse_iterations), float(params.gate_mm), float(params.k),
                                          float(params.err_floor_mm), float(edge_gate), float(model.extent_mm),
                                          float(score_tol), 1.5 * px_mm, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c,
                                          ix.n, ix.tri, ix.seg_grid, ix.p0, ix.p1, F.EDGE_WEAK, 2.0, F.STOP_EDGE)
            e0 = new.pose_error(F.pose_matrix(Rs[i], ts[i]), T_true, model)[1]
            e1 = new.pose_error(F.pose_matrix(R, t), T_true, model)
            print(f"  {i:2d}: {e0:6.2f} -> {sc:.4f}, {e1[1]:6.2f} / {e1[0]:5.2f}")
    mo, mn = models["main"], models["D0"]
    d = [min(float(np.abs(np.einsum("ij,kjl->kil", Mn, mn.symmetries) - Mo).max(axis=(1, 2)).min())
             for Mn in mn.guesses) for Mo in mo.guesses]
    print("each of main's templates: the largest entry difference to the nearest of this tree's (times a symmetry): "
          + ", ".join(f"{x:.3f}" for x in d))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="a git archive of the older tree")
    ap.add_argument("--seed", type=int, default=7751)
    ap.add_argument("--frames", default="0,1,2")
    ap.add_argument("--sensor", default="handmade", choices=("handmade", "raytraced"))
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--variants", default="old,J:D0,J:D1,J:D2,J:D3,C:D0,C:D1,C:D2,C:D3,J:main,L:D0,L:main")
    ap.add_argument("--cache", default=None, metavar="DIR", help="keep the synthesized frames in DIR")
    ap.add_argument("--trace", default=None, metavar="FRAME:INSTANCE")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from replay.process import configure_process

    configure_process()
    import zcut.fits as new
    import zcut.fits.fit as F

    if not hasattr(F, "principal_axes"):
        raise SystemExit("bench_fits_signs: this tree's zcut.fits.fit has no principal_axes (run it in a checkout of "
                         "fbdd9d0 or branch h/blas2)")
    if not (args.old / "zcut" / "fits" / "__init__.py").is_file():
        raise SystemExit(f"--old {args.old}: no zcut/fits/__init__.py there (a git archive of a zcut tree?)")
    import zcut.fits.model as FM
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, read_part_model_bytes
    from replay.synth.log import part_model_attachment

    def templates(A: np.ndarray, sym: np.ndarray, cont: np.ndarray | None) -> np.ndarray:
        # this tree's construction: in the symmetries' frame where the tree has one (bc99e14), else the axes'
        frame = FM._symmetry_frame(A, sym, cont) if hasattr(FM, "_symmetry_frame") else A
        out: np.ndarray = FM._guess_templates(frame, sym, cont)
        return out

    rules = _rules(F)
    w, h = (int(v) for v in args.size.split("x"))
    data = part_model_attachment(args.kind, raytraced=args.sensor == "raytraced")[PART_MODEL_ATTACHMENT][1]
    pm = read_part_model_bytes(data)
    scale = 1000.0 if pm.unit == "m" else 1.0
    with tempfile.TemporaryDirectory() as tmp:
        old = BB._load_old(args.old, Path(tmp))
        mo = old.prepare_model(pm.vertices * scale, pm.triangles, sphere_tolerance=old.FitParams().sphere_tolerance)
        mn = new.prepare_model(pm.vertices * scale, pm.triangles, sphere_tolerance=new.FitParams().sphere_tolerance)
        models: dict[str, Any] = {"main": dataclasses.replace(mn, guesses=mo.guesses)}
        for k, d in enumerate(SIGNS):
            A = mn.axes * np.array(d)
            models[f"D{k}"] = dataclasses.replace(mn, axes=A, guesses=templates(A, mn.symmetries, mn.continuous_axis))
        print(f"guess templates: main {len(mo.guesses)}, " + ", ".join(f"D{k} {len(models[f'D{k}'].guesses)}"
                                                                       for k in range(4)), flush=True)
        rows: list[dict[str, Any]] = []
        for index in (int(v) for v in args.frames.split(",")):
            truth = BB._truth(args.sensor, args.kind, args.seed, index, (h, w), args.cache)
            valid = np.isfinite(truth.xyz_mm).all(axis=2)
            zone = valid & ((truth.label == BF.LABEL_PART) | truth.outliers | truth.off)
            per: dict[str, dict[int, float]] = {}
            for v in args.variants.split(","):
                if v == "old":
                    mod, model = old, mo
                else:
                    rule, m = v.split(":")
                    mod, model = new, models[m]
                    F.principal_axes = rules[rule]
                c0 = time.process_time()
                try:
                    fits = mod.fit_prepared(truth.xyz_mm, zone, model, intrinsics=truth.K, params=mod.FitParams())
                finally:
                    F.principal_axes = rules["J"]
                cpu = time.process_time() - c0
                BF.pose_error = mod.pose_error
                s = BF.score(truth, fits, model, zone, with_proposals=False)
                per[v] = _per_instance(truth, fits, model, mod.pose_error)
                row = {k: s[k] for k in BB.KEYS} | dict(frame=index, variant=v, cpu_s=cpu, load=os.getloadavg()[0],
                                                        per_instance_deg=per[v])
                rows.append(row)
                print(f"{index} {v:7s} found {s['found_visible']:4d}/{s['visible']:<4d} med/p90 mm {s['median_mm']:.3f}/"
                      f"{s['p90_mm']:.3f} deg {s['median_deg']:.3f}/{s['p90_deg']:.3f} explained {s['explained_top']:.4f}"
                      f" nomatch {s['nomatch']:3d} fits {s['fits']} cpu {cpu:.2f} load {row['load']:.1f}", flush=True)
                if args.json:
                    with open(args.json, "w") as fh:
                        json.dump(rows, fh, indent=1)
            if "old" in per:
                grown = sorted(((per[v].get(i, np.nan) - d0, i) for v in per if v != "old" for i, d0 in per["old"].items()
                                if np.isfinite(per[v].get(i, np.nan))), reverse=True)
                top = list(dict.fromkeys(i for _, i in grown))[:6]
                for i in top:
                    print(f"  instance {i}: " + ", ".join(f"{v} {per[v].get(i, np.nan):.2f}" for v in per), flush=True)
            if args.trace and int(args.trace.split(":")[0]) == index:
                _trace(F, new, truth, zone, models, int(args.trace.split(":")[1]))
    print("\nper variant, over the frames: found, explained (mean), rotation deg median / p90 (medians of the frames'),"
          " translation mm median, nomatch, fits, CPU-s")
    for v in args.variants.split(","):
        rs = [r for r in rows if r["variant"] == v]
        print(f"{v:7s} {sum(r['found_visible'] for r in rs):4d} {np.mean([r['explained_top'] for r in rs]):.4f} "
              f"{np.median([r['median_deg'] for r in rs]):.3f} / {np.median([r['p90_deg'] for r in rs]):.3f} "
              f"{np.median([r['median_mm'] for r in rs]):.3f} {sum(r['nomatch'] for r in rs):4d} "
              f"{sum(r['fits'] for r in rs):4d} {sum(r['cpu_s'] for r in rs):.2f}")


if __name__ == "__main__":
    main()
