"""How well :func:`zcut.fits.fit_prepared` finds the parts of synthetic frames (issue 29 item 2).

    PYTHONPATH=. .venv/bin/python bench/bench_fits.py [--set tune|report] [--size 960x600]
        [--kinds spheres,zinc_nuts,rods,black_nuts] [--sensors handmade,raytraced] [--json OUT]
        [--param seed_shifts=0 ...] [--dump FITS.pkl] [--cache DIR] [--phases] [--guesses [--screen-steps N]] [--repeat N]
    PYTHONPATH=. .venv/bin/python bench/bench_fits.py --same OLD.pkl NEW.pkl

Per frame (both generators, each kind, the seeds of the set: ``tune`` 2951-2952, the fits' knobs
tuned on them; ``report`` 2971-2972, held out: used nowhere else, not even to tune) the fits get only what a log holds: the cloud (mm), the zone, the part
model the log attaches (``part_model.ply``, read back with ``read_part_model_bytes``) and the
intrinsics. The zone is the valid pixels that the bin and the table do not explain: the pixels whose
centre ray hits a part, plus every true outlier (the pipeline's zone keeps them too). The scene,
regenerated from the seed, then scores the fits — only to score them:

- **pose error** of the *fully visible* instances (≥ 95 % of the pixels the instance would cover
  alone are its own in the scene, ≥ 100 of them valid and at least half of them: an instance the
  sensor lost, a shiny nut's dropout, is no fit to score): the fit whose posed centroid is nearest the
  instance's (within half the part's extent) is its match; translation = distance of the centroids,
  rotation = the smallest angle modulo the model's symmetry group (a sphere: none; a body of
  revolution: the angle between the axes). Medians, with the share of fully visible instances matched.
- **explained** on the top layer: the share of the valid, on-surface (not ``/ground_truth/off_surface``)
  pixels of the instances at least half visible that lie in some fit's ``pixels`` (within
  3 × max(Err, floor) of a fitted instance).
- **CPU-s per frame**: ``time.process_time`` of ``fit_prepared`` (all threads), in a process with every ``zcut``
  command's settings (:func:`replay.process.configure_process`, as the page's; ``--bare``: without, as the
  figures before the round of 2026-12-07f were measured); preparing the model
  (once per log) is reported apart. ``--repeat N`` fits each frame N times (the CPU column: the smallest,
  all of them in the JSON); ``--phases`` fits it once more with each step wrapped in a CPU timer and
  prints where the time goes (:func:`phase_times`; the wrappers cost a few per cent; inclusive times, a
  step inside another counts in both); ``--cache DIR`` keeps the synthesized frames there (two trees'
  fits on the same frames: run this script with ``PYTHONPATH`` at each tree).

The instances' true poses: hand-made parts are ``[R · Rz(phase), centre]`` (the hexagon's random phase
about the part's axis; the model carries phase 0) in the world, ray-traced ones ``[R, t]`` of the
pile; the world -> camera map is (x, −y, 580 − z).
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from dataclasses import dataclass, replace

import numpy as np

from replay.logs.part_model import PART_MODEL_ATTACHMENT, read_part_model_bytes
from replay.synth.log import part_model_attachment
from replay.synth.sensor import CAMERA_HEIGHT_MM
from zcut.fits import FitParams, fit_prepared, pose_error, prepare_model

SEEDS = {"tune": (2951, 2952), "report": (2971, 2972), "tune6": (8531, 2951), "report6": (8541, 2971)}
_C = np.diag([1.0, -1.0, -1.0])
LABEL_PART = 5


@dataclass
class Truth:
    poses: list[np.ndarray]  # model -> camera (mm)
    meshes: list[tuple[np.ndarray, np.ndarray]]  # camera frame vertices, triangles
    xyz_mm: np.ndarray
    label: np.ndarray
    off: np.ndarray
    outliers: np.ndarray
    K: tuple[float, float, float, float]


def _to_cam(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _C @ R
    T[:3, 3] = _C @ t + np.array([0.0, 0.0, CAMERA_HEIGHT_MM])
    return T


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def handmade(kind: str, seed: int, size: tuple[int, int]) -> Truth:
    from replay.synth import synthesize_frame
    from replay.synth.raytrace.meshes import _icosphere
    from replay.synth.surfaces import solid_meshes

    sf = synthesize_frame(kind=kind, seed=seed, size=size)
    K = sf.frame.intrinsics
    poses, meshes = [], []
    prisms = [p for p in sf.scene.parts if p.solid is not None and p.solid[0][0][0] != "sphere"]
    solid_vt = dict(zip([id(p) for p in prisms], solid_meshes([p.solid for p in prisms])))  # type: ignore[misc]
    for p in sf.scene.parts:
        assert p.solid is not None
        prim = p.solid[0][0]
        if prim[0] == "sphere":
            m = _icosphere(float(prim[2]), 4)
            v_local, t_local = m.vertices + prim[1], m.triangles
            phase_R = np.eye(3)
        else:
            v_local, t_local = solid_vt[id(p)]
            phase_R = np.eye(3)
            if kind in ("zinc_nuts", "black_nuts"):
                poly = prim[5]
                phase_R = _rz(float(np.arctan2(poly[0, 1], poly[0, 0])))
        T = _to_cam(p.R @ phase_R, p.centre_mm)
        Tw = _to_cam(p.R, p.centre_mm)
        poses.append(T)
        meshes.append((v_local @ Tw[:3, :3].T + Tw[:3, 3], t_local))
    return Truth(poses, meshes, sf.frame.xyz.astype(np.float64) * 1000.0, sf.surface, sf.off_surface, sf.truth,
                 (K.fx, K.fy, K.cx, K.cy))


def raytraced(kind: str, seed: int, size: tuple[int, int]) -> Truth:
    from replay.synth.raytrace import synthesize_raytraced_frame
    from replay.synth.raytrace.meshes import part_mesh

    rf = synthesize_raytraced_frame(kind=kind, seed=seed, size=size)
    K = rf.frame.intrinsics
    m = part_mesh(kind)
    poses, meshes = [], []
    assert rf.pile is not None
    for R, t in zip(rf.pile.R, rf.pile.t_mm):
        T = _to_cam(R, t)
        poses.append(T)
        meshes.append((m.vertices @ T[:3, :3].T + T[:3, 3], m.triangles))
    return Truth(poses, meshes, rf.frame.xyz.astype(np.float64) * 1000.0, rf.surface, rf.off_surface, rf.truth,
                 (K.fx, K.fy, K.cx, K.cy))


def instance_ids(truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """(id image: i + 1 where the centre ray's first part hit is instance i and the surface is a part,
    alone: (n,) pixel count each instance would cover on its own)."""
    import open3d as o3d

    H, W = truth.label.shape
    fx, fy, cx, cy = truth.K
    rr, cc = np.mgrid[0:H, 0:W]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones((H, W))], axis=-1)
    rays = np.concatenate([np.zeros((H, W, 3)), d], axis=-1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    for v, t in truth.meshes:
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    hit = np.isfinite(ans["t_hit"].numpy())
    ids = np.where(hit & (truth.label == LABEL_PART), gid + 1, 0)
    alone = np.zeros(len(truth.meshes), np.int64)
    for i, (v, t) in enumerate(truth.meshes):
        u = fx * v[:, 0] / v[:, 2] + cx
        w = fy * v[:, 1] / v[:, 2] + cy
        c0, c1 = max(int(u.min()) - 1, 0), min(int(u.max()) + 2, W)
        r0, r1 = max(int(w.min()) - 1, 0), min(int(w.max()) + 2, H)
        if c0 >= c1 or r0 >= r1:
            continue
        one = o3d.t.geometry.RaycastingScene()
        one.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
        a = one.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays[r0:r1, c0:c1])))
        alone[i] = int(np.isfinite(a["t_hit"].numpy()).sum())
    return ids, alone


#: --no-proposals: the proposals' columns (the slowest of the scoring) left out
NAN_PROPOSALS: dict[str, float] = {k: float("nan") for k in ("truth_in_small", "truth_in_big", "truth_in_proposals",
                                                             "truth_in_vetted")}
NAN_PROPOSALS.update({k: -1 for k in ("prop_px", "prop_small_px", "prop_big_px", "prop_big_n", "big_nontruth_found_px",
                                      "big_nontruth_missed_px", "big_nontruth_nopart_px", "nontruth_vetted_px", "vetted")})


def score(truth: Truth, fits: list, model, zone: np.ndarray,  # type: ignore[no-untyped-def,type-arg]
          with_proposals: bool = True) -> dict[str, float]:
    ids, alone = instance_ids(truth)
    n = len(truth.poses)
    valid = np.isfinite(truth.xyz_mm).all(axis=2)
    seen = np.bincount(ids.reshape(-1), minlength=n + 1)[1:]
    seen_valid = np.bincount(ids[valid], minlength=n + 1)[1:]
    share = np.where(alone > 0, seen / np.maximum(alone, 1), 0.0)
    full = np.flatnonzero((share >= 0.95) & (seen_valid >= 100) & (seen_valid >= 0.5 * seen))
    top = np.flatnonzero(share >= 0.5)
    c = model.centroid
    fit_c = np.array([f.pose[:3, :3] @ c + f.pose[:3, 3] for f in fits]).reshape(-1, 3)
    dts, das = [], []
    matched = 0
    for i in full:
        T = truth.poses[i]
        ci = T[:3, :3] @ c + T[:3, 3]
        if len(fit_c) == 0:
            continue
        j = int(np.argmin(np.linalg.norm(fit_c - ci, axis=1)))
        if np.linalg.norm(fit_c[j] - ci) > 0.5 * model.extent_mm:
            continue
        matched += 1
        dt, da = pose_error(fits[j].pose, T, model)
        dts.append(dt)
        das.append(da)
    explained = np.zeros(ids.size, bool)
    for f in fits:
        explained[f.pixels] = True
    on_top = np.isin(ids, top + 1) & valid & ~truth.off
    found = _found(truth, fits, model)
    props = ({**proposals(truth, fits, model, zone, ids, found), **vetted_proposals(truth, fits, model, zone)}
             if with_proposals else dict(NAN_PROPOSALS))
    return {**props, **duplicates(truth, fits, model),
        "found": int(found.sum()), "visible": int((seen_valid >= VISIBLE_PX).sum()),
        "found_visible": int(found[seen_valid >= VISIBLE_PX].sum()),
        "instances": n, "fully_visible": len(full), "matched": matched, "fits": len(fits),
        "median_mm": float(np.median(dts)) if dts else float("nan"),
        "median_deg": float(np.median(das)) if das else float("nan"),
        "p90_mm": float(np.percentile(dts, 90)) if dts else float("nan"),
        "p90_deg": float(np.percentile(das, 90)) if das else float("nan"),
        "explained_top": float(explained[on_top.reshape(-1)].mean()) if on_top.any() else float("nan"),
        "top_px": int(on_top.sum()),
        "median_err_mm": float(np.median([f.err_mm for f in fits])) if fits else float("nan"),
    }


#: an instance with at least this many valid pixels of its own is "visible" (found/visible: the fits'
#: default ``min_region_px``)
VISIBLE_PX = 40
#: proposals smaller than this many pixels are "small" (the page's person decided those well, issue 29)
PROPOSAL_SPLIT = 10


def _found(truth: Truth, fits: list, model) -> np.ndarray:  # type: ignore[no-untyped-def,type-arg]
    """(n,) bool: instance i has a fit whose posed centroid lies within half the part's extent of its own."""
    c = model.centroid
    fit_c = np.array([f.pose[:3, :3] @ c + f.pose[:3, 3] for f in fits]).reshape(-1, 3)
    out = np.zeros(len(truth.poses), bool)
    if not len(fit_c):
        return out
    for i, T in enumerate(truth.poses):
        ci = T[:3, :3] @ c + T[:3, 3]
        out[i] = float(np.min(np.linalg.norm(fit_c - ci, axis=1))) <= 0.5 * model.extent_mm
    return out


def duplicates(truth: Truth, fits: list, model) -> dict[str, float]:  # type: ignore[no-untyped-def,type-arg]
    """Each fit's nearest instance (posed centroids): ``nomatch`` = fits farther than half the part's extent
    from every instance's centroid; of the others, ``dups`` = those whose instance has a nearer fit (the
    fits beyond the first of an instance); ``per_inst`` = matched fits per instance with a fit."""
    c = model.centroid
    if not fits:
        return {"dups": 0, "nomatch": 0, "per_inst": float("nan")}
    fit_c = np.array([f.pose[:3, :3] @ c + f.pose[:3, 3] for f in fits]).reshape(-1, 3)
    inst_c = np.array([T[:3, :3] @ c + T[:3, 3] for T in truth.poses]).reshape(-1, 3)
    d = np.linalg.norm(fit_c[:, None, :] - inst_c[None, :, :], axis=2)
    nearest = np.argmin(d, axis=1)
    ok = d[np.arange(len(fits)), nearest] <= 0.5 * model.extent_mm
    per = np.bincount(nearest[ok], minlength=len(inst_c))
    return {"dups": int((per[per > 1] - 1).sum()), "nomatch": int((~ok).sum()),
            "per_inst": float(ok.sum() / max(int((per > 0).sum()), 1))}


def vetted_proposals(truth: Truth, fits: list, model, zone: np.ndarray) -> dict[str, float]:  # type: ignore[no-untyped-def,type-arg]
    """The proposals as ``explained`` makes them in the pipeline (``replay/pipeline/explained.py``): each fit's
    robust residual (``zcut.explained.fit_sigmas``), the vetting (``zcut.fit_vetting``: a fit whose solid
    overlaps a better-ranked kept fit's by > 5 % is no known surface), the residuals measured again; the
    parts as the only known surfaces (the zone's pixels on the bin and the table count as explained, as in
    :func:`proposals`). ``T in vet``: the share of the paper's truth in the zone inside them; ``non-T vet``:
    their pixels that are not truth; ``vetted``: the fits vetted out."""
    import dataclasses

    from zcut import explained as ex
    from zcut.fit_vetting import MAX_OVERLAP, explained_px, instance_overlaps, vet_fits, without_fits

    v, t = model.vertices, model.triangles
    stated = [f.err_mm for f in fits]
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in fits], part_err_mm=stated)
    foot = ex.footprint_mm(truth.xyz_mm, 0.5 * (truth.K[0] + truth.K[1]))
    near = ex.nearest_surface(truth.xyz_mm, surfaces, where=zone)
    robust = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, stated, where=zone))
    vetted = 0
    if fits:
        err = ex.err_image(near, robust, foot, floor_mm=0.1)
        kept = vet_fits(instance_overlaps(v, t, [f.pose for f in fits]),
                        explained_px(near, err, len(fits), k=3.0, where=zone), max_overlap=MAX_OVERLAP).kept
        vetted = int((~kept).sum())
        if not kept.all():
            robust, near = without_fits(truth.xyz_mm, near, surfaces, kept)
            robust = dataclasses.replace(robust, part_err_mm=ex.fit_sigmas(near, robust.part_err_mm, where=zone))
    err = ex.err_image(near, robust, foot, floor_mm=0.1)
    on_other = ~((truth.label == LABEL_PART) | truth.off)
    un = ex.unexplained(near.dist_mm, err) & zone & ~on_other
    tz = truth.off & zone
    return {"truth_in_vetted": float((un & tz).sum() / tz.sum()) if tz.any() else float("nan"),
            "nontruth_vetted_px": int((un & ~truth.off).sum()), "vetted": vetted}


def proposals(truth: Truth, fits: list, model, zone: np.ndarray, ids: np.ndarray,  # type: ignore[no-untyped-def,type-arg]
              found: np.ndarray) -> dict[str, float]:
    """The page's proposals of these fits, as ``explained`` makes them with the parts as the only known
    surfaces: the zone's pixels farther than 3 × Err (``zcut.explained.err_image``: the fit's residual
    and the pixel's footprint) from every fitted instance, joined as the page joins them
    (``annotate.fits.JOIN_PX``). The bin and the table are no surfaces here: the zone's pixels on them
    (a sensor outlier the paper's truth puts on a surface) count as explained, as the registered bin and
    the table explain them in the pipeline. Scored by the paper's truth (``off``): the share of proposal
    pixels that are truth, small (< PROPOSAL_SPLIT px) and large proposals apart; the share of the
    truth in the zone inside proposals; and the large proposals' pixels that are not truth, by whether
    their instance (the centre ray's first part) was found by some fit or missed."""
    from scipy import ndimage

    from annotate.fits import JOIN_PX
    from annotate.payload import EIGHT
    from zcut import explained as ex

    H, W = zone.shape
    v, t = model.vertices, model.triangles
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in fits],
                                part_err_mm=[f.err_mm for f in fits])
    near = ex.nearest_surface(truth.xyz_mm, surfaces, where=zone)
    err = ex.err_image(near, surfaces, ex.footprint_mm(truth.xyz_mm, 0.5 * (truth.K[0] + truth.K[1])), floor_mm=0.1)
    on_other = ~((truth.label == LABEL_PART) | truth.off)  # bin, table: explained in the pipeline
    un = ex.unexplained(near.dist_mm, err) & zone & ~on_other
    lab = np.zeros((H, W), np.int64)
    if un.any():
        joined, _ = ndimage.label(ndimage.binary_dilation(un, EIGHT, iterations=JOIN_PX), structure=EIGHT)
        lab[un] = joined[un]
    size = np.bincount(lab.reshape(-1))
    size[0] = 0
    big = (size[lab] >= PROPOSAL_SPLIT) & un
    small = un & ~big
    truth_z = truth.off & zone
    inst = ids[big & ~truth.off]
    inst_found = np.concatenate([[False], found])[inst]

    def share(a: np.ndarray, b: np.ndarray) -> float:
        return float((a & b).sum() / b.sum()) if b.any() else float("nan")

    return {"prop_px": int(un.sum()), "prop_small_px": int(small.sum()), "prop_big_px": int(big.sum()),
            "prop_big_n": int((size >= PROPOSAL_SPLIT).sum()),
            "truth_in_small": share(truth.off, small), "truth_in_big": share(truth.off, big),
            "truth_in_proposals": share(un, truth_z),
            "big_nontruth_found_px": int(((inst > 0) & inst_found).sum()),
            "big_nontruth_missed_px": int(((inst > 0) & ~inst_found).sum()),
            "big_nontruth_nopart_px": int((inst == 0).sum())}


#: (label, attribute of zcut.fits.fit) of the steps --phases times; a step the tree lacks is left out
PHASES = (("segmentation", "segment"), ("python per region", "_holds_many"), ("python per region", "_patch"),
          ("python per region", "_occluding_boundary"), ("global guess", "initial_rotations"),
          ("global guess", "initial_poses"), ("global guess", "shifted_poses"), ("global guess", "guess_translations"),
          ("global guess", "shifted_guesses"), ("coarse ICP", "coarse_search"),
          ("fine ICP", "icp"), ("acceptance", "_accept"),
          ("  of it: support", "_support"), ("sphere fits", "_fit_sphere"), ("sphere votes", "vote_centres"),
          ("assignment", "_assign"), ("candidates (whole)", "_fit_general"))


def phase_times(run):  # type: ignore[no-untyped-def]
    """Call ``run()`` with the steps of :data:`PHASES`, the claims' overlap test and the second pass
    (``_fit_region`` with shifts) wrapped in ``time.process_time`` timers: ({label: CPU-s}, {label: calls})."""
    import collections

    import zcut.fits.fit as F

    spent: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()
    saved = []

    def wrap(owner, name, label, pick=None):  # type: ignore[no-untyped-def]
        f = getattr(owner, name, None)
        if f is None:
            return

        def timed(*a, **k):  # type: ignore[no-untyped-def]
            lab = label if pick is None else pick(a, k)
            if lab is None:
                return f(*a, **k)
            c = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[lab] += time.process_time() - c
                calls[lab] += 1

        saved.append((owner, name, f))
        setattr(owner, name, timed)

    for label, name in PHASES:
        wrap(F, name, label)
    claims = getattr(F, "_Claims", None)
    if claims is not None:
        wrap(claims, "overlapping", "overlap tests")
    wrap(F, "_fit_region", "second pass (whole)", lambda a, k: "second pass (whole)" if k.get("shifts") else None)
    try:
        c0 = time.process_time()
        run()
        spent["total"] = time.process_time() - c0
    finally:
        for owner, name, f in reversed(saved):
            setattr(owner, name, f)
    return dict(spent), dict(calls)


def guess_ranks(run, screen_iterations: int = 1):  # type: ignore[no-untyped-def]
    """Call ``run()`` with the coarse search of a general part's guesses wrapped: each guess is also searched alone
    (its own score after ``coarse_iterations`` steps, and after ``screen_iterations``: a short screen of the guesses,
    docs/fits.md "Fifteenth round"). {pass: [(guesses, position of the chosen guess in their order, rank of the guess
    of the best score among the screen's scores)]}; pass 1 the first pass, 2 the second (more guesses: the shifts).
    The second searches of each guess cost as much again as the coarse search (not timed)."""
    import zcut.fits.fit as F

    real = F.coarse_search
    out: dict[int, list[tuple[int, int, int]]] = {1: [], 2: []}
    n_first = [0]

    def wrapped(points, edge, Rs, ts, iterations, *rest):  # type: ignore[no-untyped-def]
        got = real(points, edge, Rs, ts, iterations, *rest)
        if rest[-2] > 1.0:  # the turns (no stop): not guesses
            return got
        alone = rest[:-2] + (2.0, rest[-1])
        full = [real(points, edge, Rs[i:i + 1], ts[i:i + 1], iterations, *alone)[3] for i in range(len(Rs))]
        short = [real(points, edge, Rs[i:i + 1], ts[i:i + 1], screen_iterations, *alone)[3] for i in range(len(Rs))]
        best = int(np.argmax(full))
        rank = 1 + int(np.flatnonzero(np.argsort(-np.asarray(short), kind="stable") == best)[0])
        n_first[0] = n_first[0] or len(Rs)
        out[1 if len(Rs) <= n_first[0] else 2].append((len(Rs), int(got[0]), rank))
        return got

    F.coarse_search = wrapped
    try:
        run()
    finally:
        F.coarse_search = real
    return out


def _frame(sensor: str, kind: str, seed: int, size: tuple[int, int], cache: str | None) -> Truth:
    """The scene of the frame, synthesized or read back from ``cache`` (written there the first time)."""
    import os
    import pickle

    path = None if cache is None else os.path.join(cache, f"{sensor}_{kind}_{seed}_{size[1]}x{size[0]}.pkl")
    if path is not None and os.path.exists(path):
        with open(path, "rb") as fh:
            got = pickle.load(fh)
        return got if isinstance(got, Truth) else Truth(**(got if isinstance(got, dict) else vars(got)))
    truth = handmade(kind, seed, size) if sensor == "handmade" else raytraced(kind, seed, size)
    if path is not None:
        os.makedirs(cache, exist_ok=True)
        with open(path, "wb") as fh:
            pickle.dump(vars(truth), fh)
    return truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=tuple(SEEDS), default="report")
    ap.add_argument("--size", default="960x600")
    ap.add_argument("--kinds", default="spheres,zinc_nuts,rods,black_nuts")
    ap.add_argument("--sensors", default="handmade,raytraced")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds instead of the set's")
    ap.add_argument("--json", default=None)
    ap.add_argument("--dump", default=None, metavar="FILE.pkl",
                    help="write every frame's fits (pose, Err, support, pixels) to FILE.pkl, keyed by "
                         "(fits, sensor, kind, seed): two trees' fits compared to the bit with --same")
    ap.add_argument("--same", nargs=2, default=None, metavar=("A.pkl", "B.pkl"),
                    help="only compare two --dump files: per frame, whether the fits are identical to the bit")
    ap.add_argument("--before", action="store_true",
                    help="also the fits without the sixth round's claims (claim=false: the fifth round's fits to "
                         "the bit) on each frame, just before")
    ap.add_argument("--cache", default=None, metavar="DIR", help="keep the synthesized frames in DIR")
    ap.add_argument("--phases", action="store_true", help="also where each frame's CPU goes (a second fit)")
    ap.add_argument("--guesses", action="store_true",
                    help="also, per pass, how many guesses a region's search tries and where its winner ranks (a "
                         "second fit: guess_ranks)")
    ap.add_argument("--screen-steps", type=int, default=1, metavar="N",
                    help="with --guesses: the winner's rank among the guesses' scores after N coarse ICP steps")
    ap.add_argument("--no-proposals", action="store_true", help="score the fits only, not the proposals")
    ap.add_argument("--repeat", type=int, default=1, help="fit each frame this many times (CPU: the smallest)")
    ap.add_argument("--bare", action="store_true",
                    help="without the process settings of every zcut command (replay.process.configure_process)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a FitParams field (e.g. seed_shifts=0: the fits without their second pass)")
    ap.add_argument("--variant", action="append", default=[], metavar="LABEL:NAME=VALUE[,NAME=VALUE...]",
                    help="also fit each frame with these FitParams fields over --param's, in the same process, "
                         "after the plain run and in the order given (LABEL, at most 6 characters, names its rows; "
                         "the order is reversed on every other frame: old and new alternate)")
    args = ap.parse_args()
    if not args.bare:
        from replay.process import configure_process

        configure_process()  # as `zcut annotate`'s process (cli.main), where the page's fits run
    if args.same:
        _same(*args.same)
        return
    w, h = (int(v) for v in args.size.split("x"))
    seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else list(SEEDS[args.set])
    params = FitParams(**{k: _value(getattr(FitParams(), k), v) for k, v in (a.split("=") for a in args.param)})
    variants = [("after", params)]
    if args.before:  # the fits without the sixth round's claims, on the same frame, just before
        variants.insert(0, ("before", replace(params, claim=False)))
    for spec in args.variant:
        label, _, fields = spec.partition(":")
        pairs = [f.split("=") for f in fields.split(",") if f]
        variants.append((label[:6], replace(params, **{k: _value(getattr(FitParams(), k), v) for k, v in pairs})))
    n_frame = 0
    rows = []
    dumped: dict[tuple[str, str, str, int], list[tuple[np.ndarray, float, float, np.ndarray]]] = {}
    print(f"size {w}x{h}, seeds {seeds}; CPU seconds per frame (process_time, all threads)")
    print(f"{'fits':6s} {'sensor':9s} {'kind':10s} {'seed':>5s} {'inst':>4s} {'full':>4s} {'match':>5s} {'fits':>4s} "
          f"{'med mm':>7s} {'med deg':>7s} {'p90 mm':>7s} {'p90 deg':>7s} {'expl':>5s} {'Err':>5s} {'cpu s':>6s} "
          f"{'prep s':>6s} {'found':>7s} {'prop':>6s} {'<10 T':>5s} {'>=10':>6s} {'>=10 T':>6s} {'T in':>5s} "
          f"{'big: found/missed/none px':>25s} {'dups':>4s} {'nomat':>5s} {'f/inst':>6s} {'vetd':>4s} {'Tin vet':>7s} "
          f"{'nonT vet':>8s}")
    for sensor in args.sensors.split(","):
        for kind in args.kinds.split(","):
            data = part_model_attachment(kind, raytraced=sensor == "raytraced")[PART_MODEL_ATTACHMENT][1]
            pm = read_part_model_bytes(data)
            scale = 1000.0 if pm.unit == "m" else 1.0
            c0 = time.process_time()
            model = prepare_model(pm.vertices * scale, pm.triangles, sphere_tolerance=params.sphere_tolerance)
            prep = time.process_time() - c0
            for seed in seeds:
                truth = _frame(sensor, kind, seed, (h, w), args.cache)
                valid = np.isfinite(truth.xyz_mm).all(axis=2)
                zone = valid & ((truth.label == LABEL_PART) | truth.outliers | truth.off)
                n_frame += 1
                for label, p in (variants if n_frame % 2 or not args.variant else variants[::-1]):
                    cpus = []
                    for _ in range(max(1, args.repeat)):
                        c0 = time.process_time()
                        fits = fit_prepared(truth.xyz_mm, zone, model, intrinsics=truth.K, params=p)
                        cpus.append(time.process_time() - c0)
                    cpu = min(cpus)
                    s = score(truth, fits, model, zone, with_proposals=not args.no_proposals)
                    s.update(sensor=sensor, kind=kind, seed=seed, cpu_s=cpu, cpu_all=cpus, prepare_s=prep,
                             fits_run=label)
                    if args.phases:
                        spent, calls = phase_times(functools.partial(fit_prepared, truth.xyz_mm, zone, model,
                                                                     intrinsics=truth.K, params=p))
                        s.update(phases=spent, phase_calls=calls)
                        print("   phases (CPU-s, calls): " + ", ".join(
                            f"{k} {v:.2f}" + (f" ({calls[k]})" if k in calls else "")
                            for k, v in sorted(spent.items(), key=lambda kv: -kv[1])), flush=True)
                    if args.guesses:
                        ranks = guess_ranks(functools.partial(fit_prepared, truth.xyz_mm, zone, model,
                                                              intrinsics=truth.K, params=p), args.screen_steps)
                        s.update(guesses={k: v for k, v in ranks.items()})
                        for k, v in ranks.items():
                            if not v:
                                continue
                            g, pos, rank = (np.asarray(c) for c in zip(*v))
                            print(f"   guesses, pass {k}: {len(v)} searches, {int(np.median(g))} guesses (median); "
                                  f"the chosen one's position median {np.median(pos):.0f}, p90 {np.percentile(pos, 90):.0f}, "
                                  f"< 4 {np.mean(pos < 4):.2f}"
                                  f"; the best one's rank by the {args.screen_steps}-step screen ≤ 1/2/4/8: "
                                  + "/".join(f"{np.mean(rank <= q):.2f}" for q in (1, 2, 4, 8)), flush=True)
                    rows.append(s)
                    _row(s, label)
                    dumped[(label, sensor, kind, seed)] = [(f.pose, f.err_mm, f.support, f.pixels) for f in fits]
    if args.dump:
        import pickle

        with open(args.dump, "wb") as fh:
            pickle.dump(dumped, fh)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


def _value(default: object, text: str) -> object:
    """``text`` as the type of the field's ``default`` (a bool from true/false/1/0)."""
    if isinstance(default, bool):
        if text.lower() not in ("true", "false", "1", "0"):
            raise SystemExit(f"--param: {text!r} is not true or false")
        return text.lower() in ("true", "1")
    return type(default)(text)


def _same(a: str, b: str) -> None:
    """Print, per frame of two --dump files, whether their fits are the same to the bit."""
    import pickle

    with open(a, "rb") as fa, open(b, "rb") as fb:
        da, db = pickle.load(fa), pickle.load(fb)
    for key in sorted(set(da) | set(db), key=str):
        fa_, fb_ = da.get(key), db.get(key)
        same = (fa_ is not None and fb_ is not None and len(fa_) == len(fb_)
                and all(np.array_equal(x[0], y[0]) and x[1] == y[1] and x[2] == y[2] and np.array_equal(x[3], y[3])
                        for x, y in zip(fa_, fb_)))
        print(" ".join(map(str, key)), "identical" if same else "DIFFERENT", flush=True)


def _row(s: dict, label: str) -> None:  # type: ignore[type-arg]
    sensor, kind, seed, cpu, prep = s["sensor"], s["kind"], s["seed"], s["cpu_s"], s["prepare_s"]
    print(f"{label:6s} {sensor:9s} {kind:10s} {seed:5d} {s['instances']:4d} {s['fully_visible']:4d} "
          f"{s['matched']:5d} {s['fits']:4d} {s['median_mm']:7.3f} {s['median_deg']:7.3f} "
          f"{s['p90_mm']:7.3f} {s['p90_deg']:7.3f} {s['explained_top']:5.3f} "
          f"{s['median_err_mm']:5.3f} {cpu:6.2f} {prep:6.2f} {s['found_visible']:3d}/{s['visible']:<3d} "
          f"{s['prop_px']:6d} {s['truth_in_small']:5.2f} {s['prop_big_px']:6d} {s['truth_in_big']:6.2f} "
          f"{s['truth_in_proposals']:5.2f} {s['big_nontruth_found_px']:8d}/{s['big_nontruth_missed_px']:d}/"
          f"{s['big_nontruth_nopart_px']:d} {s['dups']:4d} {s['nomatch']:5d} {s['per_inst']:6.3f} {s['vetted']:4d} "
          f"{s['truth_in_vetted']:7.3f} {s['nontruth_vetted_px']:8d}", flush=True)


if __name__ == "__main__":
    main()
