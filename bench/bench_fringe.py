"""The fitted parts' fringes (issue 29, h/fringe): the method ``explained`` and the page-only person's label with a
value of :mod:`zcut.explained`'s constants against another, paired per frame, in one process.

For every frame of each synthetic log (prepared as ``bench/bench_label_pageonly.py --diagnose`` prepares it), the page's
fits (:func:`annotate.fits.fit_frame`, the method ``explained`` with its vetting, pieces on top and sliver pass) are
computed once per variant, the part fits and the pieces on top shared between the variants
(:class:`bench_label_pageonly.shared_fits`: the same inputs give the same fits, computed once); each variant sets
constants of :mod:`zcut.explained` (``--variants NAME=CONST:VALUE[;CONST:VALUE],…``; the first variant is the
reference the others are paired with). Printed per frame and variant: the page-only person's label (the rule of
docs/labelling.md emulated on the page's bundle, :func:`bench_label_pageonly._emulated_person`) against the paper's
truth — IoU, the truth the proposals hold — and the method's own outliers (its zone outliers and the points above the
rim the pipeline flags itself, on the pixels the page serves) — precision, recall, F1 —, and the CPU-s of the
method's run after the fits (each variant once a frame, the order alternating by frame, after the session's own run
of the method warmed its kernels) beside the CPU-s of the fits and the pieces on top. The truth is read only to
score.

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_fringe.py LOG[,LOG…] --variants "main=CONST:0,new=" --json F

CONST: a constant of :mod:`zcut.explained` the method reads when it runs (``main=CONST:0`` the tree with it at 0,
``new=`` the tree as it is). The round of 2026-12-07c scored the pose refinement (``main=REFINE_STEPS:0,refine=``) in a
checkout of its commit (docs/accuracy.md, "The fitted parts' fringes"), the round of 2026-12-07d its second try the same
way in a checkout of a7bdbf2 with ``--rounds 3``, and its third try (h/fringe3) in a checkout of 5ac3e8e; this tree
keeps none of them. ``--rounds N`` runs each variant N times a
frame (the order alternating), the median timed.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
import bench_label_pageonly as B  # noqa: E402

#: each variant's runs a frame (``--rounds``; the order alternating by frame and by round, the median timed)
ROUNDS = 1


def parse_variants(text: str) -> list[tuple[str, dict[str, Any]]]:
    out = []
    for item in (v for v in text.split(",") if v):
        name, _, rest = item.partition("=")
        sets: dict[str, Any] = {}
        for kv in (v for v in rest.split(";") if v):
            k, _, val = kv.partition(":")
            sets[k] = json.loads(val)
        out.append((name, sets))
    if not out:
        raise SystemExit("error: --variants: none given")
    return out


@contextlib.contextmanager
def constants(sets: dict[str, Any]) -> Iterator[None]:
    import zcut.explained as ex

    saved = {k: getattr(ex, k) for k in sets}
    try:
        for k, v in sets.items():
            setattr(ex, k, v)
        yield
    finally:
        for k, v in saved.items():
            setattr(ex, k, v)


def prf(pred: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    tp = int((pred & truth).sum())
    fp = int((pred & ~truth).sum())
    fn = int((~pred & truth).sum())
    return {"tp": tp, "fp": fp, "fn": fn, "precision": tp / max(tp + fp, 1), "recall": tp / max(tp + fn, 1),
            "f1": 2 * tp / max(2 * tp + fp + fn, 1)}


def run(log: Path, variants: list[tuple[str, dict[str, Any]]], frames: set[int]) -> list[dict[str, Any]]:
    import zcut.fits
    import zcut.top_pieces
    from annotate.fits import fit_frame
    from replay.logs import layout

    rows = []
    with B.shared_fits():
        spent = [0.0]  # CPU-s of the fits and the pieces on top computed (the memo's hits cost nothing)

        def timed(fn: Any) -> Any:
            def wrapped(*a: Any, **kw: Any) -> Any:
                t = time.process_time()
                try:
                    return fn(*a, **kw)
                finally:
                    spent[0] += time.process_time() - t
            return wrapped

        zcut.fits.fit_prepared = timed(zcut.fits.fit_prepared)  # type: ignore[assignment]  # restored by shared_fits
        zcut.top_pieces.top_pieces = timed(zcut.top_pieces.top_pieces)  # type: ignore[assignment]
        session = B.pipeline_options().open_session(log)
        bin_model = session.prepared.model if session.prepared is not None else None
        for frame, r in session.results(in_flight=1):
            if frames and frame.index not in frames:
                spent[0] = 0.0
                continue
            cpu_fits = spent[0]
            spent[0] = 0.0
            from annotate.fits import Job

            job = Job.of(r)
            got: dict[str, Any] = {}
            cpu: dict[str, list[float]] = {name: [] for name, _ in variants}
            # the session's own run of the method warmed every kernel: each variant once, the order alternating
            order = variants if frame.index % 2 == 0 else variants[::-1]
            for rnd in range(ROUNDS):
                for name, sets in (order if rnd % 2 == 0 else order[::-1]):
                    with constants(sets):
                        t = time.process_time()
                        got[name] = fit_frame(frame, job, session.config, bin_model)
                        cpu[name].append(time.process_time() - t)
            valid, xyz, heights = B.frame_arrays(frame, job)
            easy = np.asarray(job.removal.easy_outliers, bool) if job.removal is not None else np.zeros_like(valid)
            zone = np.asarray(job.zone, bool)
            served = (zone | easy) & valid
            truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served
            for name, _ in variants:
                ff = got[name]
                label, ids, how = B._emulated_person(ff, xyz, heights, valid)
                label &= served
                un = np.zeros(valid.size, bool)
                un[ff.un_pix] = True
                method = ((un.reshape(valid.shape) & zone) | easy) & served
                sc = B.label_scores(label, ids, truth, served, None)
                row = {"log": log.name, "frame": frame.index, "variant": name, **B.log_kind(log),
                       "iou": sc["iou"], "held": sc["held"], "label": sc["label"], "truth": sc["truth"],
                       "fits": len(ff.fits), "unexplained": int(ff.un_pix.size),
                       "cpu_first": round(cpu[name][0], 2), "cpu_method": round(float(np.median(cpu[name])), 2),
                       "cpu_runs": [round(c, 2) for c in cpu[name]],
                       "cpu_fits": round(cpu_fits, 2),
                       "explained": prf(method, truth), "inputs": how["inputs"]}
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(rows: list[dict[str, Any]], ref: str) -> list[str]:
    base = {(r["log"], r["frame"]): r for r in rows if r["variant"] == ref}
    out = ["| log | frame | variant | IoU | Δ | held | Δ | explained F1 | Δ | CPU-s after the fits (median of the runs) | Δ | "
           "Δ / the method's CPU (fits + the rest) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b = base[(r["log"], r["frame"])]
        out.append(f"| {r['log']} | {r['frame']} | {r['variant']} | {r['iou']:.4f} | {r['iou'] - b['iou']:+.4f} | "
                   f"{r['held']:.4f} | {r['held'] - b['held']:+.4f} | {r['explained']['f1']:.4f} | "
                   f"{r['explained']['f1'] - b['explained']['f1']:+.4f} | {r['cpu_method']:.2f} | "
                   f"{r['cpu_method'] - b['cpu_method']:+.2f} | "
                   f"{(r['cpu_method'] - b['cpu_method']) / max(b['cpu_method'] + b.get('cpu_fits', 0.0), 1e-9):+.1%} |")
    for v in dict.fromkeys(r["variant"] for r in rows):
        if v == ref:
            continue
        d = [r["iou"] - base[(r["log"], r["frame"])]["iou"] for r in rows if r["variant"] == v]
        out.append(f"{v}: median paired ΔIoU {np.median(d):+.4f} over {len(d)} frames")
    return out


def main() -> int:
    global ROUNDS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs")
    ap.add_argument("--variants", required=True)
    ap.add_argument("--frames", default="")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--rounds", type=int, default=ROUNDS, help="each variant's runs a frame (the median timed)")
    ap.add_argument("--summary", type=Path, nargs="*", default=None, help="print the table of these JSON files")
    args = ap.parse_args()
    variants = parse_variants(args.variants)
    ROUNDS = max(1, args.rounds)
    rows = []
    for lg in (Path(v) for v in args.logs.split(",") if v):
        rows += run(lg, variants, {int(v) for v in args.frames.split(",") if v})
        if args.json is not None:
            args.json.write_text(json.dumps(rows, indent=1))
    print("\n".join(summary(rows, variants[0][0])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
