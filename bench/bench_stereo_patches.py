"""The stereo scenes' true outliers the labelling page's review groups hold, and what a patch cue adds (issue 29
item 2; docs/labelling_real.md, "Stereo errors the page can hold").

Without a browser: for every frame of a ``zcut record-stereo`` log the page's review groups are computed as the page
computes them (:func:`annotate.groups.review_groups` on the replay's result, the page's zone and suspect parameters),
the fallback rule of docs/labelling.md ("A person who reads only the page": a group is an outlier when its gap exceeds
3 × τ, τ the rise slider's starting value, the frame's threshold to 0.1 mm; with no surface below, when it was grouped
as floating or above the rim) is applied to their table, and the label is scored against the measured truth
(``/ground_truth/outliers``, ``/ground_truth/unknown`` left out; on a synthetic log the paper's truth,
``/ground_truth/off_surface``; a real scan without truth gets the counts only): IoU, the truth held (its share inside any group), the
per-group limit (each group decided by the majority of its truth), the groups and the groups the rule calls outliers.
Run it in two trees (``--against DIR``: the same log scored by DIR's code in a subprocess, in the same run) to compare.

``--explore`` also prints, per frame, what the smooth patches (:func:`smooth_patches`: 4-connected pieces of the depth
image cut wherever neighbours differ by more than ``c`` × the suspects' jump) of at most N pixels hold of the truth
that no group holds — the cue's measure on the tuning scenes before anything is built.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_patches.py --log STEREO.mcap --scenes A,B,C [--frames 0,1]
        [--against /tmp/real2-old [--old-log OLD.mcap] [--old-methods LIST]] [--methods LIST] [--explore] [--json F]

``--methods`` runs the page's filter methods as ``zcut annotate --methods`` does (e.g. the stereo matcher's own
post-filters recorded in the log, ``stereo_uniqueness,stereo_speckle,stereo_lr``: docs/labelling_real.md, h/real3).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]  # the tree whose code runs is PYTHONPATH's (``--against``: a child's)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    u = (a | b).sum()
    return float((a & b).sum() / u) if u else 1.0


def fallback_label(ids: np.ndarray, table: np.ndarray, sources: tuple[str, ...], threshold_mm: float
                   ) -> tuple[np.ndarray, int]:
    """The label docs/labelling.md's fallback rule saves (every group it calls an outlier) and their count."""
    from annotate.groups import GCOL

    tau = float(f"{max(0.1, threshold_mm if np.isfinite(threshold_mm) and threshold_mm else 0.5):.1f}")
    out = []
    for row in table:
        gap = row[GCOL["gap_mm"]]
        src = sources[int(row[GCOL["source"]])]
        if np.isnan(gap):
            hit = src in ("floating", "above_rim")
        else:
            hit = abs(gap) > 3 * tau
        if hit:
            out.append(int(row[GCOL["id"]]))
    return np.isin(ids, out) & (ids > 0), len(out)


def limit_of(ids: np.ndarray, truth: np.ndarray, region: np.ndarray) -> float:
    n = int(ids.max())
    if n == 0:
        return iou(np.zeros_like(truth), truth)
    sz = np.bincount(ids.ravel(), weights=region.ravel(), minlength=n + 1)
    tp = np.bincount(ids.ravel(), weights=truth.ravel(), minlength=n + 1)
    best = np.isin(ids, [g for g in range(1, n + 1) if sz[g] and tp[g] >= 0.5 * sz[g]])
    return iou(best & region, truth)


def frames_of(log: Path, wanted: set[int] | None, methods: str | None = None) -> Any:
    """(frame, result, page zone, valid, groups) of each frame wanted, as the page prepares them (``methods``: the
    filter methods the page runs, as ``zcut annotate --methods`` gives them; None: the config's, zcut and sor)."""
    from annotate.groups import review_groups
    from replay.pipeline import config as cfg
    from replay.pipeline.session import ReplaySession
    from zcut.params import SuspectParams

    session = ReplaySession.open(log, overrides=cfg.cli_layer(methods=methods) if methods else None)
    params = SuspectParams(a_max=session.config.zcut.a_max)
    results = session.results()
    try:
        for frame, r in results:
            if wanted is not None and frame.index not in wanted:
                continue
            valid = np.isfinite(frame.xyz).all(axis=2)
            easy = np.asarray(r.easy_outliers, bool) & valid
            zone = (np.asarray(r.zone, bool) | easy) & valid
            t0 = time.process_time()
            g = review_groups(frame.xyz, frame.rgb, height_mm=np.asarray(r.height_mm, np.float64), valid=valid,
                              zone=zone & valid, above_rim=easy,
                              outliers={k: np.asarray(v, bool) & valid for k, v in r.outliers.items()},
                              params=params)
            yield frame, r, zone, valid, g, time.process_time() - t0
    finally:
        results.close()


def score_log(log: Path, scenes: list[str], wanted: set[int] | None, methods: str | None = None) -> list[dict]:
    from annotate.groups import GCOL
    from replay.logs import layout

    rows = []
    for frame, _r, zone, valid, g, cpu in frames_of(log, wanted, methods):
        unknown = frame.masks.get(layout.TRUTH_UNKNOWN)
        scored = valid if unknown is None else valid & ~unknown
        region = zone & scored
        truth = frame.masks.get(layout.TRUTH_OFF_SURFACE, frame.masks.get(layout.TRUTH_OUTLIERS))  # the paper's first
        P = (truth if truth is not None else np.zeros_like(valid)) & region
        label, n_out = fallback_label(g.ids, g.table, g.sources, g.threshold_mm)
        label &= region
        held = (P & (g.ids > 0)).sum() / max(P.sum(), 1)
        patch_groups = [k for k in range(g.n) if g.sources[int(g.table[k, GCOL["source"]])] == "patch"]
        patch_out = int(np.isin([int(g.table[k, GCOL["id"]]) for k in patch_groups],
                                np.unique(g.ids[label])).sum()) if patch_groups else 0
        srcs = [g.sources[int(s)] for s in g.table[:, GCOL["source"]]] if g.n else []
        rows.append({"frame": frame.index, "scene": scenes[frame.index] if frame.index < len(scenes) else "?",
                     "groups": g.n, "outlier_groups": n_out, "tau_mm": round(float(g.threshold_mm), 1),
                     "truth_px": int(P.sum()), "held": float(held), "label_px": int(label.sum()),
                     "iou": iou(label, P), "limit": limit_of(g.ids, P, region), "group_px": int((g.ids > 0).sum()),
                     "by_source": {s: srcs.count(s) for s in dict.fromkeys(srcs)}, "cpu_groups_s": cpu,
                     "patch_groups": len(patch_groups), "patch_outlier_groups": patch_out,
                     "has_truth": truth is not None})
    return rows


def served_check(log: Path, wanted: set[int] | None, methods: str | None) -> list[dict]:
    """The groups the page's own server serves (``annotate.server.open_page`` with ``methods`` as ``zcut annotate
    --methods`` gives them, without a part model as a stereo log has none; each frame's bundle read over HTTP) against
    the groups this bench computes: the same ``group_ids`` image and table, frame by frame."""
    import tempfile

    sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "bench")]
    from annotate_helpers import LiveServer
    from page_helpers import get_bundle

    from annotate.server import open_page
    from replay.options import PipelineOptions
    from replay.pipeline import config as cfg

    computed = {frame.index: g for frame, _r, _z, _v, g, _ in frames_of(log, wanted, methods)}
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        srv = LiveServer(open_page(log, Path(tmp) / "labels.db", annotator="bench",
                                   overrides=cfg.cli_layer(methods=methods) if methods else None,
                                   choose_bin_model=PipelineOptions().model_chooser()))
        try:
            assert srv.page.catalogue.wait_until_done(3600)
            for index, g in computed.items():
                header, arrays = get_bundle(srv.base, srv.token, index)
                ids = arrays["groups"].astype(np.int64)
                table = np.asarray(arrays["group_table"], np.float64)
                same = bool(np.array_equal(ids, g.ids) and table.shape == g.table.shape
                            and np.allclose(table, g.table.astype(np.float32), equal_nan=True))
                out.append({"frame": index, "served_groups": int(header["n_groups"]), "groups": g.n,
                            "methods": header["methods"], "same": same})
                print(f"served frame {index}: {header['n_groups']} groups (methods {', '.join(header['methods'])}), "
                      f"computed {g.n}: {'the same' if same else 'DIFFERENT'}", flush=True)
        finally:
            srv.stop()
    return out


# ---------------------------------------------------------------------------------------------------------------------
# --explore: smooth patches on the tuning scenes


def smooth_patches(h: np.ndarray, valid: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """4-connected labels (1..n, 0 unmeasured) of the measured pixels, two neighbours joined when their heights
    differ by at most the smaller of their ``jump``."""
    H, W = h.shape
    idx = np.arange(H * W).reshape(H, W)
    pairs = []
    for a, b in (((slice(None), slice(0, W - 1)), (slice(None), slice(1, W))),
                 ((slice(0, H - 1), slice(None)), (slice(1, H), slice(None)))):
        ok = valid[a] & valid[b] & (np.abs(h[a] - h[b]) <= np.minimum(jump[a], jump[b]))
        pairs.append((idx[a][ok], idx[b][ok]))
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    i = np.concatenate([p[0] for p in pairs])
    j = np.concatenate([p[1] for p in pairs])
    graph = coo_matrix((np.ones(i.size, np.int8), (i, j)), shape=(H * W, H * W))
    _, lab = connected_components(graph, directed=False)
    lab = lab.reshape(H, W) + 1
    lab[~valid] = 0
    u, inv = np.unique(lab, return_inverse=True)
    return (inv.reshape(H, W) + (0 if u[0] == 0 else 1)).astype(np.int64)


def explore(log: Path, scenes: list[str], wanted: set[int] | None, cs: list[float], sizes: list[int],
            shares: list[float]) -> list[dict]:
    from replay.logs import layout
    from zcut.params import SuspectParams
    from zcut.suspects.noise import noise_profile
    from zcut.suspects.union import _sigma_px

    out = []
    for frame, _r, zone, valid, g, _ in frames_of(log, wanted):
        unknown = frame.masks.get(layout.TRUTH_UNKNOWN)
        scored = valid if unknown is None else valid & ~unknown
        region = zone & scored
        P = frame.masks[layout.TRUTH_OUTLIERS] & region
        held = g.ids > 0
        h = np.where(valid, -1000.0 * frame.xyz[..., 2].astype(np.float64), np.nan)
        prof = noise_profile(h, zone)
        sp = SuspectParams()
        sigma = _sigma_px(prof, h)
        jump = np.maximum(sp.jump_mm, sp.noise_k * sigma)
        name = scenes[frame.index] if frame.index < len(scenes) else "?"
        print(f"{name}: truth {int(P.sum())} px, held {int((P & held).sum())} ({(P & held).sum() / max(P.sum(), 1):.3f}),"
              f" zone {int(region.sum())} px, median jump {np.nanmedian(jump[zone]):.1f} mm", flush=True)
        H, W = h.shape
        for c in cs:
            lab = smooth_patches(h, valid, c * jump)
            n = int(lab.max())
            size = np.bincount(lab.ravel(), minlength=n + 1)
            tp = np.bincount(lab.ravel(), weights=P.ravel(), minlength=n + 1)
            steps = np.zeros(n + 1, np.int64)
            opn = np.zeros(n + 1, np.int64)
            pl = np.pad(lab, 1, constant_values=0)
            for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                nb = pl[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
                steps += np.bincount(lab[valid & (nb > 0) & (nb != lab)], minlength=n + 1)
                opn += np.bincount(lab[valid & (nb == 0)], minlength=n + 1)
            share = steps / np.maximum(steps + opn, 1)
            for s in sizes:
                for v in shares:
                    small = (size <= s) & (steps > 0) & (share >= v)
                    small[0] = False
                    m = small[lab] & region
                    new = P & m & ~held
                    row = {"scene": name, "c": c, "max_px": s, "share": v, "patches": int(small.sum()), "px": int(m.sum()),
                           "truth_in": int((P & m).sum()), "precision": float((P & m).sum() / max(m.sum(), 1)),
                           "held_new": float(((P & held) | (P & m)).sum() / max(P.sum(), 1)),
                           "added_truth": int(new.sum()), "patch_major": int(((tp >= 0.5 * size) & small).sum())}
                    out.append(row)
                    print(f"  c {c:g} ≤{s} px step share ≥{v:g}: {row['patches']} patches ({row['patch_major']} mostly "
                          f"truth), {row['px']} px, precision {row['precision']:.2f}, held {row['held_new']:.3f}",
                          flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, required=True, help="a zcut record-stereo log")
    ap.add_argument("--scenes", default="", help="the scenes' names, in the log's frame order (for the table)")
    ap.add_argument("--frames", default="", help="frame indices to score (default: all)")
    ap.add_argument("--against", type=Path, default=None, help="also score the log with this tree's code (a git archive)")
    ap.add_argument("--explore", action="store_true", help="the smooth patches' truth, per frame (no groups changed)")
    ap.add_argument("--c", default="0.5,1,2", help="--explore: multiples of the suspects' jump")
    ap.add_argument("--sizes", default="100,400,1600,6400,25600", help="--explore: largest patch sizes (px)")
    ap.add_argument("--shares", default="0,0.5,0.8", help="--explore: least share of a patch's border that is a step")
    ap.add_argument("--methods", default="", help="the filter methods the page runs (zcut annotate --methods; "
                    "default: the config's); with --against also --old-methods")
    ap.add_argument("--old-methods", default=None, help="--against: the old tree's page runs these (default: --methods)")
    ap.add_argument("--old-log", type=Path, default=None, help="--against: the old tree scores this log (default: --log)")
    ap.add_argument("--served", action="store_true", help="check the page's own server serves the groups computed "
                    "here (with --methods), frame by frame; nothing else")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    scenes = [s for s in a.scenes.split(",") if s]
    wanted = {int(v) for v in a.frames.split(",") if v} or None
    if a.explore:
        rows = explore(a.log, scenes, wanted, [float(v) for v in a.c.split(",")], [int(v) for v in a.sizes.split(",")],
                       [float(v) for v in a.shares.split(",")])
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))
        return 0
    if a.served:
        rows = served_check(a.log, wanted, a.methods or None)
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))
        return 0 if all(r["same"] for r in rows) else 1
    if a.child:
        print(json.dumps(score_log(a.log, scenes, wanted, a.methods or None)))
        return 0
    trees = [("new", ROOT)] + ([("old", a.against.resolve())] if a.against else [])
    res: dict[str, list[dict]] = {}
    for name, tree in trees:
        old = name == "old"
        methods = a.old_methods if old and a.old_methods is not None else a.methods
        log = a.old_log if old and a.old_log is not None else a.log
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--log", str(log), "--scenes", a.scenes,
               "--frames", a.frames, "--methods", methods]
        env = {**os.environ, "PYTHONPATH": str(tree)}
        t0 = time.time()
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=tree, env=env)
        if p.returncode:
            raise SystemExit(f"{name} tree failed: {p.stderr.strip()[-800:]}")
        res[name] = json.loads(p.stdout.strip().splitlines()[-1])
        print(f"{name} ({tree}): {time.time() - t0:.0f} s wall", file=sys.stderr, flush=True)
    print("| scene | tree | groups | outlier groups | patch groups (outliers) | τ mm | truth px | held | label px | IoU "
          "| limit | group px | CPU-s groups |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for k in range(len(res["new"])):
        for name in reversed(list(res)):
            r = res[name][k]
            t = r["has_truth"]
            print(f"| {r['scene']} | {name} | {r['groups']} | {r['outlier_groups']} | {r['patch_groups']} "
                  f"({r['patch_outlier_groups']}) | {r['tau_mm']} | {r['truth_px']:,} | "
                  + (f"{r['held']:.3f} | {r['label_px']:,} | {r['iou']:.3f} | {r['limit']:.3f}" if t else
                     f"– | {r['label_px']:,} | – | –") + f" | {r['group_px']:,} | {r['cpu_groups_s']:.2f} |")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
