"""The z-cut's window anchored on the pile's top (``zcut_top``, zcut/cut_top.py) against the paper's
(``zcut``): accuracy, where each window lies, and CPU (issue 31; docs/raytraced.md, "A robust top for
the z-cut's window").

    .venv/bin/python bench/zcut_top.py LOG.mcap [LOG.mcap ...] [--faces 0.25,0.5,1,2,4] [--json OUT]
    .venv/bin/python bench/zcut_top.py --real [--faces 1]      # the real Kinect clouds (no truth)

Logs: every frame runs the full pipeline (bin mask, ICP of the log's own exact bin model, removal,
the nominal z-cut, SOR, the ``zone`` baseline that flags every judged pixel), scored on the zone the
filters judge (the above-the-rim points, which the rim threshold takes for every filter, left out),
against the paper's truth (``/ground_truth/off_surface``) and the sensor's (``/ground_truth/outliers``).
``zcut_top`` runs on the same height image with the pile's top a component of ``f · a_max`` pixels
for every ``f`` of ``--faces``. Per log (pooled over its frames): P / R / F1 per method and truth;
the window's pixels per frame and where it lies: its top (z_max, or the pile's top z_top) and its
floor above the pile's own top (the 99.9th percentile of the zone pixels neither truth calls
outliers); the CPU ms of the z-cut and of ``zcut_top`` on the same images (``time.process_time``,
alternated, best of ``--repeat``).

``--real``: the real Kinect clouds of the real-data folder (docs/real_data.md; no bin, no truth):
the height image is the cloud's -z in mm, a_max 1 % of the image (the config's default without a
part); per cloud its invalid share, z_max, the pile's top and the window floor (mm below z_max), the
window's pixels and each variant's outliers.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from replay.logs import layout  # noqa: E402
from zcut.cut_top import find_clusters_top  # noqa: E402
from zcut.cuts import find_clusters  # noqa: E402
from zcut.metrics import ratio  # noqa: E402

METHODS = ("zcut", "sor")
TRUTHS = (("paper", layout.TRUTH_OFF_SURFACE), ("sensor", layout.TRUTH_OUTLIERS))
REAL_DATA = Path(os.environ.get("ZCUT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))


def _cpu(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return 1000.0 * best


def judge_log(path: Path, faces: list[float], *, repeat: int) -> dict:
    """Counts of one log, pooled over its frames (module docstring)."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.config import cli_layer
    from replay.pipeline.session import ReplaySession

    session = ReplaySession.open(path, overrides=cli_layer(methods=",".join(METHODS)),
                                 choose_bin_model=lambda reader: bin_model_for(reader, None))
    zc = session.config.zcut
    assert zc.a_max is not None
    variants = ["zcut", *(f"top{f:g}" for f in faces)]
    acc: dict = {"frames": 0, "zone": 0, "a_max": zc.a_max, "counts": {}, "window": {v: 0 for v in variants},
                 "top_above": {v: [] for v in variants}, "floor_above": {v: [] for v in variants},
                 "cpu": {v: 0.0 for v in variants}, "k_top": {v: [] for v in variants}}
    for frame, r in session.results():
        acc["frames"] += 1
        zone = r.zone & r.valid
        acc["zone"] += int(zone.sum())
        found = {m: r.outliers[m] & zone for m in METHODS}
        found["zone"] = zone
        truths = {t: frame.masks[k] & zone for t, k in TRUTHS if k in frame.masks}
        clean = zone.copy()
        for k in (layout.TRUTH_OFF_SURFACE, layout.TRUTH_OUTLIERS):
            if k in frame.masks:
                clean &= ~frame.masks[k]
        pile_top = float(np.percentile(r.height_mm[clean], 99.9)) if clean.any() else np.nan
        paper = find_clusters(r.height_mm, params=zc)
        z_max = paper.z_max
        assert (paper.outliers & zone == found["zcut"]).all()  # the session's z-cut judges the same image
        acc["cpu"]["zcut"] += _cpu(lambda h=r.height_mm: find_clusters(h, params=zc), repeat)
        acc["top_above"]["zcut"].append(z_max - pile_top)
        acc["floor_above"]["zcut"].append(z_max - zc.n_levels * zc.step - pile_top)
        acc["window"]["zcut"] += int((zone & (r.height_mm >= z_max - zc.n_levels * zc.step)).sum())
        acc["k_top"]["zcut"].append(0)
        for f, v in zip(faces, variants[1:]):
            res = find_clusters_top(r.height_mm, params=zc, top_area=f * zc.a_max)
            acc["cpu"][v] += _cpu(lambda h=r.height_mm, a=f * zc.a_max: find_clusters_top(h, params=zc, top_area=a),
                                  repeat)
            found[v] = res.outliers & zone
            acc["top_above"][v].append(res.z_top - pile_top)
            acc["floor_above"][v].append(res.floor - pile_top)
            acc["window"][v] += int((zone & (r.height_mm >= res.floor)).sum())
            acc["k_top"][v].append(res.k_top)
        for t, truth in truths.items():
            for m, mask in found.items():
                c = acc["counts"].setdefault(f"{m}/{t}", [0, 0, 0])
                c[0] += int((mask & truth).sum())
                c[1] += int((mask & ~truth).sum())
                c[2] += int((truth & ~mask).sum())
    return acc


def summarize(acc: dict) -> dict:
    out: dict = {"frames": acc["frames"], "a_max": acc["a_max"], "scores": {}, "where": {}}
    for key, (tp, fp, fn) in acc["counts"].items():
        out["scores"][key] = {"P": ratio(tp, tp + fp), "R": ratio(tp, tp + fn), "F1": ratio(2 * tp, 2 * tp + fp + fn),
                              "tp": tp, "fp": fp, "fn": fn}
    for v in acc["window"]:
        out["where"][v] = {"window_px_per_frame": ratio(acc["window"][v], acc["frames"]),
                           "top_above_pile_mm": [round(x, 1) for x in acc["top_above"][v]],
                           "floor_above_pile_mm": [round(x, 1) for x in acc["floor_above"][v]],
                           "k_top": acc["k_top"][v],
                           "cpu_ms_per_frame": acc["cpu"][v] / max(acc["frames"], 1)}
    return out


def fmt(v: float, nd: int = 2) -> str:
    if isinstance(v, float) and not np.isfinite(v):
        return "–" if np.isnan(v) else "∞"
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def table(rows: dict[str, dict]) -> str:
    lines = ["| log | method | F1 paper (P / R) | F1 sensor (P / R) | window px/frame | window top / floor above the pile's top (mm) | CPU ms/frame |",
             "|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        methods = [*r["where"], "sor", "zone"]
        for m in methods:
            cells = []
            for t in ("paper", "sensor"):
                s = r["scores"].get(f"{m}/{t}")
                cells.append("–" if s is None else f"{fmt(s['F1'])} ({fmt(s['P'])} / {fmt(s['R'])})")
            w = r["where"].get(m)
            if w is None:
                where = ["", "", ""]
            else:
                tops = "..".join(fmt(x, 0) for x in (min(w["top_above_pile_mm"]), max(w["top_above_pile_mm"])))
                floors = "..".join(fmt(x, 0) for x in (min(w["floor_above_pile_mm"]), max(w["floor_above_pile_mm"])))
                where = [fmt(w["window_px_per_frame"], 0), f"{tops} / {floors}", fmt(w["cpu_ms_per_frame"], 1)]
            lines.append(f"| {name} | {m} | {cells[0]} | {cells[1]} | " + " | ".join(where) + " |")
    return "\n".join(lines)


def pooled(rows: dict[str, dict]) -> str:
    """The logs pooled by name with their seed left out (``rt_spheres_73402_960x600`` and ``..._73403_...``
    pool as ``rt_spheres_960x600``): counts summed, window pixels per frame over all frames, the ranges of
    where the windows lie and the mean CPU per frame."""
    groups: dict[str, dict] = {}
    for name, r in rows.items():
        g = groups.setdefault(re.sub(r"_\d+(?=_|$)", "", name, count=1),
                              {"frames": 0, "a_max": r["a_max"], "scores": {}, "where": {}})
        g["frames"] += r["frames"]
        for key, s in r["scores"].items():
            c = g["scores"].setdefault(key, {"tp": 0, "fp": 0, "fn": 0})
            for k in ("tp", "fp", "fn"):
                c[k] += s[k]
        for v, w in r["where"].items():
            gw = g["where"].setdefault(v, {"window_px": 0.0, "top_above_pile_mm": [], "floor_above_pile_mm": [],
                                           "k_top": [], "cpu_ms": 0.0})
            gw["window_px"] += w["window_px_per_frame"] * r["frames"]
            gw["cpu_ms"] += w["cpu_ms_per_frame"] * r["frames"]
            for k in ("top_above_pile_mm", "floor_above_pile_mm", "k_top"):
                gw[k] += w[k]
    for g in groups.values():
        for c in g["scores"].values():
            tp, fp, fn = c["tp"], c["fp"], c["fn"]
            c.update(P=ratio(tp, tp + fp), R=ratio(tp, tp + fn), F1=ratio(2 * tp, 2 * tp + fp + fn))
        for gw in g["where"].values():
            gw["window_px_per_frame"] = gw.pop("window_px") / g["frames"]
            gw["cpu_ms_per_frame"] = gw.pop("cpu_ms") / g["frames"]
    return table(groups)


def real(faces: list[float], repeat: int) -> int:
    from replay.logs.pcd import read_pcd
    from zcut.params import ZCutParams

    print("| cloud | NaN % | z_max − pile's top (mm) | window floor below z_max: zcut / top (mm) | window px: zcut / top "
          "| outliers: zcut / top | k_top | CPU ms: zcut / top |")
    print("|---|---|---|---|---|---|---|---|")
    for path in sorted(REAL_DATA.glob("*.pcd")):
        xyz = read_pcd(path).xyz
        full = -np.asarray(xyz[..., 2], np.float64) * 1000.0
        full[~np.isfinite(xyz).all(axis=2)] = np.nan
        holed = full.copy()
        holed[:, : full.shape[1] // 2] = np.nan  # a large invalid region: the left half
        for name, h in ((path.stem[:24], full), (f"{path.stem[:24]}, left half NaN", holed)):
            a_max = 0.01 * h.size
            zc = ZCutParams.nominal(a_max=a_max)
            paper = find_clusters(h, params=zc)
            z_max = paper.z_max
            w0 = int((h >= z_max - zc.n_levels * zc.step).sum())
            c0 = _cpu(lambda h=h, zc=zc: find_clusters(h, params=zc), repeat)
            for f in faces:
                res = find_clusters_top(h, params=zc, top_area=f * a_max)
                assert not (res.outliers & np.isnan(h)).any()
                w1 = int((h >= res.floor).sum())
                c1 = _cpu(lambda h=h, zc=zc, a=f * a_max: find_clusters_top(h, params=zc, top_area=a), repeat)
                print(f"| {name} (faces {f:g}) | {100 * np.isnan(h).mean():.1f} | {z_max - res.z_top:.1f} | "
                      f"{zc.n_levels * zc.step:.1f} / {z_max - res.floor:.1f} | {w0} / {w1} | "
                      f"{int(paper.outliers.sum())} / {int(res.outliers.sum())} | {res.k_top} | {c0:.1f} / {c1:.1f} |")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--faces", default="1", help="the pile's top footprints, in a_max (comma-separated)")
    ap.add_argument("--repeat", type=int, default=1, help="CPU timing: best of N runs")
    ap.add_argument("--real", action="store_true", help="the real Kinect clouds instead of logs")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    faces = [float(x) for x in args.faces.split(",")]
    if args.real:
        return real(faces, args.repeat)
    rows: dict[str, dict] = {}
    for log in args.logs:
        rows[log.stem] = summarize(judge_log(log, faces, repeat=args.repeat))
        print(f"{log.name}: done", file=sys.stderr, flush=True)
    print(table(rows))
    print()
    print(pooled(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
