"""Benchmark: the labelling page's review groups and their suspects, this tree against another, with a part model
and without (issue 32 item 5; docs/labelling_real.md, "The patch detector only without a part model").

For every frame of each log the page's inputs are prepared once, in this tree, as the page prepares them
(:class:`replay.pipeline.session.ReplaySession` of the log with the bin model ``zcut annotate`` chooses, the
replay's result: the measured pixels, the zone and the points above the rim, every method's outliers,
``SuspectParams(a_max=<the config's a_max>)``) and written to ``--work`` as .npz. Then each tree (``--against OLD``, e.g. a ``git archive`` of main, and this one) computes in its
own process, alternating ``--rounds`` times, what the page computes (:func:`annotate.groups.review_groups`):

- mode ``model``: the page with a part model (``review_groups(..., fits=True)`` where the tree has the option; a
  tree without it runs every detector, as the page did);
- mode ``none``: the page without one (the fallback; every detector).

Per frame and tree: the CPU seconds of the suspects as the page calls them (:func:`zcut.suspects.suspects` with
``edge_surface=EdgeSurfaceParams()``, then ``release()``; median of ``--repeat`` calls) and of the whole review
groups (median of ``--repeat``), and the groups themselves. Printed: the CPU old / new and their ratio, the groups
old -> new, the patch groups (grouped by ``patch``) old -> new, how many of the new tree's groups are a group of the
old tree to the pixel (and of the old tree's groups that are not patch groups, how many the new tree lists to the
pixel), the pixels whose group membership differs; where the log carries a truth (``/ground_truth/off_surface``,
else ``/ground_truth/outliers``, ``/ground_truth/unknown`` left out), the truth held by the groups and the IoU of the
fallback rule of docs/labelling.md (a group is an outlier when its gap exceeds 3 τ; with no surface below, when it
was grouped as floating or above the rim: ``bench/bench_stereo_patches.py``'s emulation).

Each worker runs in the process settings of every ``zcut`` command (:func:`replay.process.configure_process`, as
the page's own process); ``--bare`` leaves glibc's and numba's defaults (this bench's measure before 2026-12-07g).

    PYTHONPATH=. .venv/bin/python bench/bench_suspects_page.py --logs ZINC.mcap,RT.mcap --frames 0 --modes model \\
        --against /tmp/old [--work DIR] [--repeat 3] [--rounds 2] [--json F] [--bare]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
from timing import WORKER_SETTINGS, worker_env

ROOT = Path(__file__).resolve().parents[1]

#: the worker: one tree's page groups and suspects' CPU on the .npz inputs (argv: mode repeat out inputs...)
_WORKER = WORKER_SETTINGS + r"""
import inspect, sys, time
import numpy as np
from annotate.groups import review_groups
from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.suspects import suspects
mode, repeat, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
model = mode == "model"
g_kw = {"fits": True} if model and "fits" in inspect.signature(review_groups).parameters else {}
s_kw = {"patches": False} if model and "patches" in inspect.signature(suspects).parameters else {}
for k, path in enumerate(sys.argv[4:]):
    d = np.load(path)
    xyz, h, valid, zone, easy = d["xyz"], d["height_mm"], d["valid"], d["zone"], d["easy"]
    outliers = {str(n): d["out_" + str(n)] for n in d["methods"]}
    params = SuspectParams(a_max=None if np.isnan(d["a_max"]) else float(d["a_max"]))
    def groups():
        return review_groups(xyz, None, height_mm=h, valid=valid, zone=zone, above_rim=easy, outliers=outliers,
                             params=params, **g_kw)
    def sus():
        r = suspects(xyz, h, zone, easy, params=params, edge_surface=EdgeSurfaceParams(), **s_kw)
        r.release()
        return r
    g = groups()
    ts, tg = [], []
    for _ in range(repeat):
        c0 = time.process_time()
        sus()
        ts.append(time.process_time() - c0)
        c0 = time.process_time()
        groups()
        tg.append(time.process_time() - c0)
    np.savez(f"{out}.{k}.npz", ids=g.ids, table=g.table, sources=np.array(g.sources), tau=g.threshold_mm)
    print(float(np.median(ts)), float(np.median(tg)), flush=True)
"""


def prepare(logs: list[Path], frames: set[int] | None, work: Path) -> list[tuple[str, Path]]:
    """(label, .npz) of every frame wanted (``frames``: indices; None: every frame): the page's inputs, written once
    (a log whose wanted frames are all in ``work`` is not replayed)."""
    from replay.logs import layout
    from replay.options import PipelineOptions
    from replay.pipeline.session import ReplaySession

    work.mkdir(parents=True, exist_ok=True)
    out = []
    for log in logs:
        done = sorted(work.glob(f"{log.stem}_f*.npz"), key=lambda q: int(q.stem.rsplit("_f", 1)[1]))
        if frames is not None and all((work / f"{log.stem}_f{k}.npz").exists() for k in frames):
            out += [(f"{log.stem} f{k}", work / f"{log.stem}_f{k}.npz") for k in sorted(frames)]
            continue
        if frames is None and done:
            out += [(f"{log.stem} f{q.stem.rsplit('_f', 1)[1]}", q) for q in done]
            continue
        # the bin model as zcut annotate chooses it: the log's own attachment (synthetic logs), else none
        session = ReplaySession.open(log, choose_bin_model=PipelineOptions().model_chooser())
        a_max = session.config.zcut.a_max
        results = session.results()
        try:
            for frame, r in results:
                if frames is not None and frame.index not in frames:
                    continue
                f = work / f"{log.stem}_f{frame.index}.npz"
                valid = np.isfinite(frame.xyz).all(axis=2)
                easy = np.asarray(r.easy_outliers, bool) & valid
                zone = (np.asarray(r.zone, bool) | easy) & valid
                truth = frame.masks.get(layout.TRUTH_OFF_SURFACE, frame.masks.get(layout.TRUTH_OUTLIERS))
                unknown = frame.masks.get(layout.TRUTH_UNKNOWN)
                np.savez(f, xyz=frame.xyz, height_mm=np.asarray(r.height_mm, np.float64), valid=valid, zone=zone,
                         easy=easy, methods=np.array(list(r.outliers)), a_max=np.nan if a_max is None else float(a_max),
                         truth=np.zeros_like(valid) if truth is None else truth, has_truth=truth is not None,
                         unknown=np.zeros_like(valid) if unknown is None else unknown,
                         **{f"out_{n}": np.asarray(v, bool) & valid for n, v in r.outliers.items()})
                out.append((f"{log.stem} f{frame.index}", f))
        finally:
            results.close()
    return out


def fallback_scores(ids: np.ndarray, table: np.ndarray, sources: tuple[str, ...], d: Any) -> dict[str, float]:
    """The truth held and the fallback rule's IoU (``bench/bench_stereo_patches.py``'s emulation)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_stereo_patches import fallback_label, iou

    region = d["zone"] & d["valid"] & ~d["unknown"]
    P = d["truth"] & region
    # the threshold the page shows: the suspects' τ, which every group table of a frame shares; from the table's
    # rows the rule reads gap and source only
    label, n_out = fallback_label(ids, table, sources, float(d["tau_mm"]))
    label &= region
    return {"held": float((P & (ids > 0)).sum() / max(P.sum(), 1)), "iou": iou(label, P), "outlier_groups": n_out,
            "label_px": int(label.sum())}


def compare_groups(a_ids: np.ndarray, a_src: list[str], b_ids: np.ndarray, b_src: list[str]) -> dict[str, int]:
    """How many of b's groups are one of a's to the pixel; of a's non-patch groups, how many b lists to the pixel."""
    def sets(ids: np.ndarray) -> list[frozenset[int]]:
        flat = ids.ravel()
        pix = np.flatnonzero(flat)
        lab = flat[pix]
        order = np.argsort(lab, kind="stable")
        bounds = np.searchsorted(lab[order], np.arange(1, int(ids.max()) + 2))
        return [frozenset(pix[order][bounds[k]:bounds[k + 1]].tolist()) for k in range(int(ids.max()))]

    sa, sb = sets(a_ids), sets(b_ids)
    in_a = set(sa)
    in_b = set(sb)
    return {"b_in_a": sum(s in in_a for s in sb),
            "a_nonpatch": sum(src != "patch" for src in a_src),
            "a_nonpatch_in_b": sum(s in in_b for s, src in zip(sa, a_src) if src != "patch"),
            "px_moved": int(((a_ids > 0) != (b_ids > 0)).sum())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", required=True, help="comma-separated logs (synthetic, record-stereo, recorded scans)")
    ap.add_argument("--frames", default="", help="frame indices, comma-separated (default: every frame)")
    ap.add_argument("--names", default="", help="names of the frames, comma-separated, in order (for the table)")
    ap.add_argument("--modes", default="model,none", help="model (the page with a part model), none (without)")
    ap.add_argument("--against", type=Path, required=True, help="the other tree (a git archive)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_suspects_page"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--bare", action="store_true",
                    help="workers without the process settings of every zcut command (replay.process.configure_process)")
    args = ap.parse_args()
    frames = {int(v) for v in args.frames.split(",") if v} or None
    inputs = prepare([Path(v) for v in args.logs.split(",") if v], frames, args.work)
    names = [v for v in args.names.split(",") if v]
    files = [str(f) for _, f in inputs]
    here = ROOT
    rows = []
    for mode in args.modes.split(","):
        cpu: dict[str, list[list[tuple[float, float]]]] = {"old": [], "new": []}
        for _ in range(args.rounds):
            for tag, tree in (("old", args.against.resolve()), ("new", here)):
                res = subprocess.run([sys.executable, "-c", _WORKER, mode, str(args.repeat),
                                      str(args.work / f"{mode}_{tag}"), *files],
                                     cwd=tree, env=worker_env(str(tree), bare=args.bare),
                                     check=True, capture_output=True, text=True)
                cpu[tag].append([tuple(float(x) for x in line.split()) for line in res.stdout.split("\n") if line.strip()])
        print(f"\nmode {mode} ({'the page with a part model' if mode == 'model' else 'the page without one'}); "
              f"old = {args.against}, new = {here}; CPU s, median of {args.repeat} calls, each of {args.rounds} "
              f"alternating rounds; {'bare processes' if args.bare else 'the page process settings'}; "
              f"load {os.getloadavg()[0]:.1f}")
        print(f"{'frame':28s} {'suspects old/new':>22s} {'ratio':>6s} {'groups old/new':>22s} {'ratio':>6s} "
              f"{'groups':>8s} {'patch':>6s} {'new=old':>8s} {'old kept':>9s} {'px':>7s}  truth")
        for k, (label, f) in enumerate(inputs):
            so = [r[k][0] for r in cpu["old"]]
            sn = [r[k][0] for r in cpu["new"]]
            go = [r[k][1] for r in cpu["old"]]
            gn = [r[k][1] for r in cpu["new"]]
            a = np.load(args.work / f"{mode}_old.{k}.npz")
            b = np.load(args.work / f"{mode}_new.{k}.npz")
            from annotate.groups import GCOL

            a_src = [str(a["sources"][int(s)]) for s in a["table"][:, GCOL["source"]]]
            b_src = [str(b["sources"][int(s)]) for s in b["table"][:, GCOL["source"]]]
            cmp_ = compare_groups(a["ids"], a_src, b["ids"], b_src)
            d = dict(np.load(f))
            row: dict[str, Any] = {
                "mode": mode, "frame": names[k] if k < len(names) else label,
                "cpu_suspects": [float(np.median(so)), float(np.median(sn))],
                "cpu_groups": [float(np.median(go)), float(np.median(gn))],
                "groups": [len(a_src), len(b_src)], "patch_groups": [a_src.count("patch"), b_src.count("patch")],
                **cmp_, "load": os.getloadavg()[0]}
            if bool(d["has_truth"]):  # τ: the one each tree's page shows (the rise slider's)
                row["old"] = fallback_scores(a["ids"], a["table"], tuple(str(s) for s in a["sources"]),
                                             {**d, "tau_mm": float(a["tau"])})
                row["new"] = fallback_scores(b["ids"], b["table"], tuple(str(s) for s in b["sources"]),
                                             {**d, "tau_mm": float(b["tau"])})
            rows.append(row)
            truth = ""
            if "old" in row:
                truth = (f"held {row['old']['held']:.3f} -> {row['new']['held']:.3f}, IoU {row['old']['iou']:.3f} -> "
                         f"{row['new']['iou']:.3f}, outlier groups {row['old']['outlier_groups']} -> "
                         f"{row['new']['outlier_groups']}")
            print(f"{row['frame'][:28]:28s} {'/'.join(f'{v:.3f}' for v in so):>11s} "
                  f"{'/'.join(f'{v:.3f}' for v in sn):>11s} {np.median(so) / np.median(sn):6.2f} "
                  f"{'/'.join(f'{v:.2f}' for v in go):>11s} {'/'.join(f'{v:.2f}' for v in gn):>11s} "
                  f"{np.median(go) / np.median(gn):6.2f} {len(a_src):>3d}->{len(b_src):<3d} "
                  f"{a_src.count('patch'):>2d}->{b_src.count('patch'):<2d} {cmp_['b_in_a']:>3d}/{len(b_src):<3d} "
                  f"{cmp_['a_nonpatch_in_b']:>3d}/{cmp_['a_nonpatch']:<4d} {cmp_['px_moved']:>7d}  {truth}", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
