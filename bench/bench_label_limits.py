"""How close to the synthetic truth can labels made on the labelling page get? The ceilings of each way
of deciding, per frame, on the frames of ``bench/bench_label_truth.py`` (zone IoU against
``/ground_truth/outliers`` in the scored region of ``zcut accuracy``).

Per frame (the review groups exactly as ``zcut annotate`` builds them, ``annotate.groups.review_groups``):

- ``groups``: the review groups listed, and ``group limit``, the best IoU of one decision per group
  (a group is an outlier when at least half of its pixels are);
- ``brush``: the group limit after the residual brush on the 8 most mixed groups, each with the rise
  threshold (0.5-12 mm) that suits it best (a person's judgement, one threshold per group);
- ``split +N``: the limit after splitting the most mixed groups into their 8-connected pieces until
  the limit passes 0.9, and the extra decisions that took (``-``: never, within the 10 most mixed);
- ``pieces``: the pieces of all groups (8-connected components), and ``piece limit``, the best IoU of
  one decision per piece (thousands of decisions);
- ``oracle``: the share of the true outlier pixels the review groups hold at all (the best any
  decision on them can reach);
- ``learned``: a LightGBM classifier of the pieces trained on the *true* labels of the kind's other
  frames (leave one frame out): what an assistant proposing below the group could reach, with
  labels no person gives on a first frame.

    .venv/bin/python bench/bench_label_limits.py [--work DIR] [--frames 6] [--seeds 71,72]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

RISE_STEPS_MM = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    u = int((a | b).sum())
    return float((a & b).sum() / u) if u else 1.0


def majority(lab: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The label of one majority decision per region of ``lab`` (0 = none)."""
    n = int(lab.max())
    sz = np.bincount(lab.ravel(), minlength=n + 1)
    tp = np.bincount(lab.ravel(), weights=truth.ravel(), minlength=n + 1)
    take = tp >= 0.5 * sz
    take[0] = False
    return take[lab]


def pieces_of(ids: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    out = np.zeros_like(ids)
    off = 0
    for g, sl in enumerate(ndimage.find_objects(ids), start=1):
        if sl is None:
            continue
        lab, n = ndimage.label(ids[sl] == g, structure=np.ones((3, 3), bool))
        view = out[sl]
        view[lab > 0] = lab[lab > 0] + off
        off += n
    return out


def piece_features(pc: np.ndarray, ids: np.ndarray, gap: np.ndarray, resid: np.ndarray, codes: np.ndarray,
                   valid: np.ndarray, tau: float) -> np.ndarray:
    import cv2
    from scipy import ndimage

    n = int(pc.max())
    idx = np.arange(1, n + 1)
    size = np.bincount(pc.ravel(), minlength=n + 1)[1:].astype(np.float64)
    g = np.nan_to_num(gap, nan=0.0)
    med = ndimage.median(g, pc, idx)
    ar = np.where(np.isfinite(resid), np.minimum(np.abs(resid), 1e3), 0.0)
    grp = ndimage.maximum(ids, pc, idx).astype(np.int64)
    gsize = np.bincount(ids.ravel())[grp].astype(np.float64)
    edge = cv2.distanceTransform(valid.astype(np.uint8), cv2.DIST_L2, 3)
    cols = [np.log1p(size), med, np.abs(med), med / tau, ndimage.maximum(np.abs(g), pc, idx),
            ndimage.median(ar, pc, idx), np.log1p(gsize), ndimage.median(edge, pc, idx)]
    cols += [ndimage.mean(((codes >> i) & 1).astype(np.float64), pc, idx) for i in range(5)]
    return np.column_stack(cols)


def frame_rows(log: Path, ply: Path) -> list[dict]:
    from annotate.groups import review_groups
    from replay.logs import layout
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import ReplaySession
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    s = ReplaySession.open(log, bin_model=load_bin_model(ply))
    params = SuspectParams(a_max=s.resolved.config.zcut.a_max)
    rows = []
    for frame, result in s.results():
        valid = np.asarray(result.valid, bool)
        zone = np.asarray(result.zone, bool) & valid
        easy = np.asarray(result.easy_outliers, bool) & valid
        h = np.asarray(result.height_mm, np.float64)
        g = review_groups(frame.xyz, frame.rgb, height_mm=h, valid=valid, zone=zone, above_rim=easy,
                          outliers={k: np.asarray(v, bool) & valid for k, v in result.outliers.items()}, params=params)
        r = suspects(frame.xyz, h, zone, easy, params=params)  # again: its per-pixel gaps, residuals and detectors
        truth = frame.masks[layout.TRUTH_OUTLIERS] & valid & (zone | easy)
        ids = g.ids.astype(np.int64)
        rows.append({"index": frame.index, "ids": ids, "pieces": pieces_of(ids), "rise": g.rise_mm, "gap": r.gap_mm,
                     "resid": r.residual_mm, "codes": r.detectors, "valid": valid, "tau": float(r.threshold_mm),
                     "truth": truth})
    return rows


def limits(row: dict) -> dict:
    ids, T, rise = row["ids"], row["truth"], row["rise"]
    L = majority(ids, T)
    out = {"frame": row["index"], "truth_px": int(T.sum()), "groups": int(ids.max()), "group": iou(L, T),
           "oracle": float((T & (ids > 0)).sum() / max(int(T.sum()), 1))}
    n = int(ids.max())
    sz = np.bincount(ids.ravel(), minlength=n + 1)
    tp = np.bincount(ids.ravel(), weights=T.ravel(), minlength=n + 1)
    loss = np.minimum(tp, sz - tp)
    loss[0] = 0
    # the residual brush, one judged threshold per group, on the 8 most mixed groups
    gains = []
    for k in np.flatnonzero(loss):
        m = ids == k
        best = (loss[k], None)
        for t in RISE_STEPS_MM:
            sel = rise[m] >= t
            wrong = int((sel & ~T[m]).sum() + (~sel & T[m]).sum())
            if wrong < best[0]:
                best = (wrong, t)
        if best[1] is not None:
            gains.append((loss[k] - best[0], int(k), best[1]))
    LB = L.copy()
    for _, k, t in sorted(gains, reverse=True)[:8]:
        m = ids == k
        LB[m] = rise[m] >= t
    out["brush"] = iou(LB, T)
    # splitting the most mixed groups into pieces
    pc = row["pieces"]
    LS, extra, out["split_extra"] = L.copy(), 0, None
    for k in np.argsort(-loss)[:10]:
        if loss[k] == 0 or out["group"] >= 0.9:
            break
        m = ids == k
        LS[m] = majority(np.where(m, pc, 0), T)[m]
        extra += len(np.unique(pc[m]))
        if iou(LS, T) >= 0.9:
            out["split_extra"] = extra
            break
    out["pieces"] = int(pc.max())
    out["piece"] = iou(majority(pc, T), T)
    return out


def learned(rows: list[dict]) -> list[float]:
    import lightgbm as lgb

    data = []
    for r in rows:
        pc = r["pieces"]
        X = piece_features(pc, r["ids"], r["gap"], r["resid"], r["codes"], r["valid"], r["tau"])
        n = int(pc.max())
        size = np.bincount(pc.ravel(), minlength=n + 1)[1:]
        tp = np.bincount(pc.ravel(), weights=r["truth"].ravel(), minlength=n + 1)[1:]
        data.append((X, (tp >= 0.5 * size).astype(int), size))
    out = []
    for i, r in enumerate(rows):
        X = np.vstack([d[0] for j, d in enumerate(data) if j != i])
        y = np.concatenate([d[1] for j, d in enumerate(data) if j != i])
        w = np.sqrt(np.concatenate([d[2] for j, d in enumerate(data) if j != i]))
        model = lgb.train({"objective": "binary", "learning_rate": 0.05, "num_leaves": 15, "min_data_in_leaf": 10,
                           "verbose": -1, "num_threads": 1, "seed": 0}, lgb.Dataset(X, y, weight=w), 200)
        p = model.predict(data[i][0]) >= 0.5
        out.append(iou(np.concatenate([[False], p])[r["pieces"]], r["truth"]))
    return out


def main() -> int:
    from bench_label_truth import KINDS, make_inputs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_label_truth"))
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--seeds", default=",".join(str(s) for _, s in KINDS))
    args = ap.parse_args()
    seeds = [int(v) for v in args.seeds.split(",")]
    if len(seeds) != len(KINDS):
        raise SystemExit(f"error: --seeds takes {len(KINDS)} seeds, got {args.seeds!r}")
    logs, ply = make_inputs(args.work, args.frames, tuple((k, s) for (k, _), s in zip(KINDS, seeds)))
    print("| kind | frame | truth px | groups | group limit | brush | split | pieces | piece limit | oracle | "
          "learned (true labels) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for kind, log in logs.items():
        rows = frame_rows(log, ply)
        lims = [limits(r) for r in rows]
        for lim, lr in zip(lims, learned(rows)):
            split = "-" if lim["split_extra"] is None else f"+{lim['split_extra']}"
            if lim["group"] >= 0.9:
                split = "0"
            print(f"| {kind} | {lim['frame']} | {lim['truth_px']} | {lim['groups']} | {lim['group']:.3f} | "
                  f"{lim['brush']:.3f} | {split} | {lim['pieces']} | {lim['piece']:.3f} | {lim['oracle']:.3f} | "
                  f"{lr:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
