"""Benchmark: the fits vetted out for lying behind the bin or the table (issue 29; docs/labelling.md, "Fifth round").

Two checks, the truth read only to score:

``--logs LOG[,LOG...]``: ``explained`` (:func:`replay.pipeline.explained.run_explained`, the log's part model and
exact bin model, the registered pose) on every frame: the fits kept, those vetted out for their overlaps and those
vetted out for lying behind the bin (:attr:`ExplainedDetail.vetted_behind`; a tree without the rule has none), each
of the latter scored by the share of its own fitted pixels (``PartFit.pixels``) that are the paper's truth
(``/ground_truth/off_surface``): a fit whose pixels are mostly truth stands on no true surface; then the method's
outliers in the zone against the truth: true / false positives, precision, recall, the zone's explained share and the
method's CPU-s (``process_time``). Run it with ``PYTHONPATH`` of another tree (``git archive``) for the before of a
change: the rows print a digest of the outliers, so that frames the rule leaves alone can be compared bit for bit.

``--true LOG[,LOG...]``: the scene's true parts (rebuilt from the log's ``zcut.synth`` record: the hand-made
generator's solids, the ray-traced generator's pile dropped again from its seed) as fits: the share of each one's
volume behind the registered bin or the table (:func:`zcut.fit_vetting.behind_shares`) — none may exceed
``MAX_BEHIND``.

    PYTHONPATH=. .venv/bin/python bench/bench_wall_vetting.py --logs A.mcap,B.mcap
    PYTHONPATH=. .venv/bin/python bench/bench_wall_vetting.py --true A.mcap,B.mcap
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from replay.logs import layout  # noqa: E402
from replay.logs.reader import LogReader  # noqa: E402
from replay.pipeline.bin_model import bin_model_for  # noqa: E402
from replay.pipeline.config import cli_layer  # noqa: E402
from replay.pipeline.explained import run_explained  # noqa: E402
from replay.pipeline.session import ReplaySession  # noqa: E402
from replay.pipeline.stages import bin_zone, locate_bin  # noqa: E402

#: a vetted-out fit stands on no true surface when more than this share of its fitted pixels is the paper's truth
ON_NOTHING = 0.5


def _session(log: Path) -> ReplaySession:
    return ReplaySession.open(log, bin_model=bin_model_for(LogReader(log), None).model,
                              overrides=cli_layer(methods="explained"))


def method_rows(log: Path) -> list[dict[str, Any]]:
    """The method on every frame of ``log`` (module docstring, ``--logs``)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from wall_recall import NEAR_MM, wall_mm

    from replay.pipeline.session import true_poses_of

    session = _session(log)
    cfg, pm = session.config, session.prepared
    poses = true_poses_of(session.reader.metadata)
    rows = []
    for frame in session.reader.frames():
        loc = locate_bin(frame, cfg, bin_model=pm, seed=session.seed)
        z = bin_zone(frame, cfg, bin_model=pm, located=loc)
        t0 = time.process_time()
        out, det, _ = run_explained(frame, z, cfg)
        cpu = time.process_time() - t0
        assert det is not None
        valid = np.isfinite(frame.xyz).all(axis=2)
        truth = frame.masks[layout.TRUTH_OFF_SURFACE] & valid & z.zone
        # beside the walls (bench/wall_recall.py's reading: the truth over the bin's opening, every valid pixel, the
        # method's mask = its zone outliers and the points above the rim; 10 mm of an inner wall face, true bin pose)
        dist, inside = wall_mm(frame.xyz, poses[frame.stamp_ns])
        t_all = frame.masks[layout.TRUTH_OFF_SURFACE] & valid & inside
        flagged = out | z.easy
        near, far = t_all & (dist <= NEAR_MM), t_all & ~(dist <= NEAR_MM)
        behind = tuple(getattr(det, "vetted_behind", ()))
        on_nothing = [float(truth.reshape(-1)[f.pixels].mean()) if len(f.pixels) else float("nan") for f in behind]
        tp, fp = int((out & truth).sum()), int((out & ~truth).sum())
        digest = hashlib.sha1(np.packbits(out).tobytes() + np.asarray(det.dist_mm).tobytes()
                              + np.asarray(det.surface).tobytes()).hexdigest()[:12]
        rows.append({"log": log.name, "frame": frame.index, "fits": len(det.fits),
                     "overlap_out": len(det.vetted_out) - len(behind), "behind_out": len(behind),
                     "behind_on_nothing": sum(s > ON_NOTHING for s in on_nothing), "behind_truth_share": on_nothing,
                     "zone": int(z.zone.sum()), "truth": int(truth.sum()), "tp": tp, "fp": fp,
                     "precision": tp / max(tp + fp, 1), "recall": tp / max(int(truth.sum()), 1),
                     "explained_share": 1.0 - float(out.sum()) / max(int(z.zone.sum()), 1), "cpu": cpu,
                     "near": int(near.sum()), "near_found": int((near & flagged).sum()), "far": int(far.sum()),
                     "far_found": int((far & flagged).sum()),
                     "near_missed_part": int((near & ~flagged & z.zone & (det.surface >= 0)).sum()),
                     "digest": digest})
        print(f"  {log.name} frame {frame.index} done ({cpu:.1f} CPU-s)", flush=True)
    return rows


def true_parts(log: Path, reader: LogReader, index: int, size: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The true part meshes of frame ``index`` of ``log`` (camera frame, mm), rebuilt from its synthesis record."""
    meta = reader.metadata["zcut.synth"]
    seed, kind = int(meta["seed"]), meta["part_kind"]
    pile = "walls" if "pile_walls" in meta else "floor"
    sys.path.insert(0, str(ROOT / "tests"))
    from explained_helpers import handmade_true_surfaces

    if "raytrace" not in meta.get("generator", ""):
        from replay.synth.synthesize import synthesize_frame

        return handmade_true_surfaces(synthesize_frame(kind=kind, seed=seed, index=index, size=size, pile=pile))[0]
    from replay.synth.raytrace import synthesize as rs
    from replay.synth.raytrace.meshes import part_mesh
    from replay.synth.scene import lean_walls
    from replay.synth.sensor import CAMERA_HEIGHT_MM

    # the pile alone, drawn as synthesize_raytraced_frame draws it (no ray tracing)
    pose = rs.bin_pose_for(rs.frame_rng(seed, index, empty=False), empty=False, index=index)
    rng = rs.raytrace_rng(seed, index, empty=False)
    fill = float(rng.uniform(*rs.FILL_RANGE_MM))
    count = min(rs.part_count(kind, fill), rs.MAX_PARTS)
    walls = lean_walls(seed, index) if pile == "walls" else ()
    heap = rs.check_pile(rs.drop_parts(kind, pose, rng, count=count, walls=walls), seed=seed, index=index)
    D = np.diag([1.0, -1.0, -1.0])
    local = part_mesh(kind)
    out = []
    for i in range(len(heap)):
        m = local.transformed(heap.R[i], heap.t_mm[i])
        out.append((np.asarray(m.vertices, np.float64) @ D.T + np.array([0.0, 0.0, CAMERA_HEIGHT_MM]), m.triangles))
    return out


def true_rows(log: Path) -> list[dict[str, Any]]:
    """The true parts as fits on every frame of ``log`` (module docstring, ``--true``)."""
    from replay.pipeline.explained import bin_and_table_surfaces
    from zcut import explained as ex
    from zcut import fit_vetting as fv

    session = _session(log)
    cfg, pm = session.config, session.prepared
    rows = []
    for frame in session.reader.frames():
        loc = locate_bin(frame, cfg, bin_model=pm, seed=session.seed)
        z = bin_zone(frame, cfg, bin_model=pm, located=loc)
        assert z.removal is not None and loc.registration is not None and loc.bin_model is not None
        xyz = frame.xyz.astype(np.float64) * 1000.0
        surfaces = bin_and_table_surfaces(xyz, z.removal, loc.registration, loc.bin_model, ex.KnownSurfaces())
        K = frame.intrinsics
        f_px = 0.5 * (K.fx + K.fy) if K is not None else ex.focal_px(xyz)
        p = cfg.bank["explained"]
        shares = []
        for v, t in true_parts(log, session.reader, frame.index, frame.xyz.shape[:2]):
            solid = fv.Solid(inside=fv.inside_samples(v, t), occupancy=None, ball=None)
            shares.append(float(fv.behind_shares(solid, [np.eye(4)], surfaces, f_px=f_px, floor_mm=p.err_floor_mm)[0]))
        s = np.asarray(shares)
        rows.append({"log": log.name, "frame": frame.index, "parts": len(s), "out": int((s > fv.MAX_BEHIND).sum()),
                     "max": float(s.max()) if len(s) else 0.0, "any_behind": int((s > 0).sum())})
        print(f"  {log.name} frame {frame.index}: {len(s)} true parts, {rows[-1]['out']} behind, "
              f"max share {rows[-1]['max']:.3f}", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default=None, help="the method on these logs (comma-separated)")
    ap.add_argument("--true", default=None, help="the true parts as fits on these logs (comma-separated)")
    a = ap.parse_args()
    if a.logs:
        rows = [r for log in a.logs.split(",") for r in method_rows(Path(log))]
        print("\n| log | frame | fits | out: overlap | out: behind (on no true surface) | truth share of their pixels | "
              "zone px | truth | TP | FP | precision | recall | explained share | CPU-s | digest |")
        print("|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
        print("\n| log | frame | near-wall truth | found | missed (a part fit explains) | elsewhere truth | found |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r['log']} | {r['frame']} | {r['near']} | {r['near_found']} | {r['near'] - r['near_found']} "
                  f"({r['near_missed_part']}) | {r['far']} | {r['far_found']} |")
        tot = {k: sum(r[k] for r in rows) for k in ("near", "near_found", "far", "far_found", "tp", "fp",
                                                    "behind_out", "behind_on_nothing", "overlap_out")}
        rn, rf = tot["near_found"] / max(tot["near"], 1), tot["far_found"] / max(tot["far"], 1)
        print(f"\nall: near {tot['near_found']}/{tot['near']} = {rn:.4f}, elsewhere {tot['far_found']}/{tot['far']} = "
              f"{rf:.4f}, delta {rn - rf:+.4f}; zone precision {tot['tp'] / max(tot['tp'] + tot['fp'], 1):.4f} "
              f"(TP {tot['tp']}, FP {tot['fp']}); out behind {tot['behind_out']} (on no true surface "
              f"{tot['behind_on_nothing']}), out by overlap {tot['overlap_out']}")
        for r in rows:
            shares = ", ".join(f"{s:.2f}" for s in r["behind_truth_share"]) or "–"
            print(f"| {r['log']} | {r['frame']} | {r['fits']} | {r['overlap_out']} | {r['behind_out']} "
                  f"({r['behind_on_nothing']}) | {shares} | {r['zone']} | {r['truth']} | {r['tp']} | {r['fp']} | "
                  f"{r['precision']:.4f} | {r['recall']:.4f} | {r['explained_share']:.4f} | {r['cpu']:.1f} | "
                  f"{r['digest']} |")
    if a.true:
        rows = [r for log in a.true.split(",") for r in true_rows(Path(log))]
        print("\n| log | frame | true parts | vetted out (share > MAX_BEHIND) | any sample behind | largest share |")
        print("|---|---:|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r['log']} | {r['frame']} | {r['parts']} | {r['out']} | {r['any_behind']} | {r['max']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
