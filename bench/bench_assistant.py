"""Which library the labelling assistant uses: LightGBM, XGBoost and scikit-learn's HistGradientBoosting
on the same review groups, scored on held-out frames.

Synthetic 1920 x 1200 logs (``zcut synth``; kinds and seeds below, none used by the tests) are replayed
with the bin stages (a bin model built from an empty-bin series) and their review groups built as the
page builds them (:func:`annotate.assistant.frame_groups`); a group's label is the truth's (an outlier
when at least half of its pixels are true outliers), as a careful person's would be. Each backend is
trained with whole frames held out (leave one frame out) and scored on them; CPU time
(``time.process_time``, the machine is shared) of fitting and of predicting one frame's groups is
measured in the same run, with the format each library stores its model in. XGBoost and scikit-learn
are not zcut's dependencies: a library that is not installed is listed as such.

    .venv/bin/python bench/bench_assistant.py [--work DIR] [--kinds zinc_nuts,black_nuts] [--seeds 41,43] [--frames 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

BACKENDS = ("lightgbm", "xgboost", "hgb")
STORED_AS = {"lightgbm": "LightGBM text model (model_to_string)", "xgboost": "XGBoost JSON (save_raw)",
             "hgb": "pickle only (zcut does not store pickles)"}


def frames_of(work: Path, kinds, seeds, frames: int):
    """(kind, frame index, features, y) of every frame."""
    from page_helpers import synthetic_bin_model, synthetic_log

    from annotate.assistant import frame_groups, page_fits
    from annotate.groups import group_targets
    from replay.logs import layout
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import ReplaySession

    ply = synthetic_bin_model(work)
    import hashlib

    # the features depend on how groups are made: a change of those modules makes a new cache
    modules = [ROOT / "annotate/groups.py", ROOT / "annotate/budget.py", *sorted((ROOT / "zcut/suspects").glob("*.py"))]
    code = hashlib.sha256(b"".join(m.read_bytes() for m in modules))
    cache = work / f"assistant_features_{code.hexdigest()[:12]}"
    cache.mkdir(exist_ok=True)
    out = []
    for kind in kinds:
        for seed in seeds:
            log = synthetic_log(work, kind, seed, frames)
            done = sorted(cache.glob(f"{log.stem}.*.npz"))
            if len(done) < frames:
                session = ReplaySession.open(log, bin_model=load_bin_model(ply))
                results = session.results()
                try:
                    for frame, result in results:
                        feats, pix, starts, _ = frame_groups(frame, result, config=session.config,
                                                             fits=page_fits(session))
                        truth = frame.masks[layout.TRUTH_OUTLIERS]
                        _, share = group_targets(pix, starts, truth, np.ones_like(truth))
                        np.savez(cache / f"{log.stem}.{frame.index}.npz", X=feats, y=share >= 0.5)
                        print(f"  {log.name} frame {frame.index}: {feats.shape[0]} groups", flush=True)
                finally:
                    results.close()
                done = sorted(cache.glob(f"{log.stem}.*.npz"))
            for p in done:
                d = np.load(p)
                out.append((kind, p.name, d["X"], d["y"]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_assistant"))
    ap.add_argument("--kinds", default="zinc_nuts,black_nuts")
    ap.add_argument("--seeds", default="41,43")
    ap.add_argument("--frames", type=int, default=3)
    args = ap.parse_args()
    from annotate.assistant import fit_booster

    data = frames_of(args.work, args.kinds.split(","), [int(s) for s in args.seeds.split(",")], args.frames)
    n_groups = sum(len(y) for *_, y in data)
    print(f"{len(data)} frames, {n_groups} groups, {sum(int(y.sum()) for *_, y in data)} outliers")
    print("| library | held-out accuracy | log loss | fit CPU s | predict CPU ms per frame | stored as |")
    print("|---|---|---|---|---|---|")
    for backend in BACKENDS:
        try:
            __import__({"hgb": "sklearn"}.get(backend, backend))
        except ImportError:
            print(f"| {backend} | not installed (pip install {'scikit-learn' if backend == 'hgb' else backend}) "
                  f"| | | | {STORED_AS[backend]} |")
            continue
        right, total, loss, fit_s, pred_s = 0, 0, 0.0, 0.0, 0.0
        for k in range(len(data)):
            Xtr = np.concatenate([d[2] for j, d in enumerate(data) if j != k])
            ytr = np.concatenate([d[3] for j, d in enumerate(data) if j != k])
            c0 = time.process_time()
            m = fit_booster(Xtr, ytr, backend=backend)
            c1 = time.process_time()
            p = m.predict(data[k][2])
            c2 = time.process_time()
            fit_s += c1 - c0
            pred_s += c2 - c1
            y = data[k][3]
            right += int(((p >= 0.5) == y).sum())
            total += y.size
            q = np.clip(p, 1e-6, 1 - 1e-6)
            loss += float(-(y * np.log(q) + (~y) * np.log(1 - q)).sum())
        print(f"| {backend} | {right / total:.3f} | {loss / total:.3f} | {fit_s / len(data):.3f} | "
              f"{1000 * pred_s / len(data):.2f} | {STORED_AS[backend]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
