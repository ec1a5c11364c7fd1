"""Benchmark: the filters ranked side by side on both generators and against both truths (issue 31 item 5,
docs/filters.md "Rankings side by side, by truth").

Per generator (``handmade``, ``raytraced``) and part kind, two logs are synthesised: one to tune on (seed
``--tune-seed``), one to report on (``--report-seed``, a seed no test uses). Per truth (``paper``: the
points farther than 3·Err from every true surface, ``/ground_truth/off_surface``; ``sensor``: what the
sensor's footprint did not see, ``/ground_truth/outliers``; docs/accuracy.md "Two truths"), ``zcut sweep``
runs every method over its grid on both logs (the z-cut's study points, SOR's, the bank's default axes;
scored region: the zone). Each method's set is the one of best pooled F1 on the tune log; it is then
read, unchanged, from the report log's rows: every figure printed is out of sample. A trivial baseline,
``zone`` (flag every scored pixel: recall 1, precision the truth's share of the zone), is scored alike
through the registry's plug-in switch (``ZCUT_METHODS``). ``zcut_top`` (the z-cut with its window anchored on
the pile's top, docs/filters.md) is swept over its own axis ``top_faces`` (0.25, 1, 4) with the z-cut's section
at the log's nominal values (Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07), while ``zcut`` picks among its 9 study points;
beside the ranked rows, ``FIXED`` reads the z-cut at that nominal set and zcut_top at its default (1 face),
sets fixed before this ranking, and pairs them (the anchoring's effect alone). Per method on the report frames: pooled
precision, recall, F1, its rank, and the paired difference of F1 against the z-cut with its 95 %
interval over frames (``zcut.paired``; coverage measured in docs/compare.md) and the frames won/lost.

Real stereo truth (sensor's truth only: no paper truth exists for those scenes) is
``bench/bench_stereo_rank.py``'s table; docs/filters.md sets the three side by side.

    PYTHONPATH=. .venv/bin/python bench/rank_truths.py [--kinds zinc_nuts,spheres] [--sensors handmade,raytraced]
        [--size 480x300] [--frames 6] [--tune-seed 8101] [--report-seed 8201] [--out DIR] [--json FILE] [--doc]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

METHODS = ("zcut", "zcut_top", "sor", "radius", "cluster", "speckle", "window", "mixed_pixel", "zone")
#: Methods also read at a set fixed before this ranking (a piece of the sweep's set string that names it):
#: the z-cut at the paper's nominal set (Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07) and zcut_top at its default
#: top_faces = 1 (chosen on seed 73401, docs/raytraced.md) on that same nominal z-cut: the two differ only by
#: where the window starts, so their paired difference is the anchoring's alone.
FIXED = {"zcut": "0.2|30.0|0.07|", "zcut_top": '{"top_faces": 1.0}'}
GRIDS = ("zcut_top=default", "radius=default", "cluster=default", "speckle=default", "window=default",
         "mixed_pixel=default", "zone=default")


# ---------------------------------------------------------------- the trivial baseline, as a registry plug-in
from replay.pipeline.methods import Method, MethodOutput  # noqa: E402


@dataclass(frozen=True, slots=True)
class ZoneParams:
    """The baseline has no parameter (a field the config can hold, never read)."""

    on: bool = True


def _run_zone(frame, zone, config) -> MethodOutput:  # type: ignore[no-untyped-def]
    return MethodOutput(zone.zone.copy())


#: Plugged in as ``ZCUT_METHODS=rank_truths:ZONE`` (this folder on the path).
ZONE = Method(name="zone", params=ZoneParams, run=_run_zone, summary="zone: every pixel of the zone (a baseline)")


# ---------------------------------------------------------------- runs
def cli(*args: str) -> None:
    from cli.main import main

    rc = main([str(a) for a in args])
    if rc != 0:
        raise SystemExit(f"zcut {' '.join(map(str, args))} exited {rc}")


def synth(out: Path, sensor: str, kind: str, seed: int, frames: int, size: str) -> Path:
    p = out / f"{sensor}_{kind}_{seed}.mcap"
    if not p.exists():
        extra = ("--sensor", "raytraced") if sensor == "raytraced" else ()
        cli("synth", "-o", p, "--parts", kind, "--frames", frames, "--seed", seed, "--size", size, *extra)
    return p


def sweep(log: Path, truth: str, out: Path) -> dict[str, np.ndarray]:
    """The sweep's rows of every method and set on ``log`` against ``truth``: columns ``method``, ``set``
    (the set's parameters as one string), ``frame``, ``tp``, ``fp``, ``fn``."""
    import pyarrow.parquet as pq

    d = out / f"sweep_{log.stem}_{truth}"
    if not (d / "sweep.parquet").exists():
        grid = [a for g in GRIDS for a in ("--grid", g)]
        cli("sweep", log, "--methods", ",".join(METHODS), *grid, "--truth", truth, "--workers", "0", "--no-report",
            "-o", d)
    t = pq.read_table(d / "sweep.parquet").to_pydict()
    keys = [c for c in ("step_mm", "max_depth_mm", "rho_thr", "max_area_px", "sor_k", "sor_std_ratio", "params")
            if c in t]
    sets = ["|".join(str(t[c][i]) for c in keys) for i in range(len(t["method"]))]
    return {"method": np.array(t["method"], str), "set": np.array(sets, str), "frame": np.array(t["frame"], np.int64),
            **{k: np.array(t[k], np.int64) for k in ("tp", "fp", "fn")}}


def pooled(tp: float, fp: float, fn: float) -> tuple[float, float, float]:
    p = tp / (tp + fp) if tp + fp else math.nan
    r = tp / (tp + fn) if tp + fn else math.nan
    f = 2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else math.nan
    return p, r, f


def rank_one(tune: dict[str, np.ndarray], report: dict[str, np.ndarray]) -> list[dict]:
    """Per method: the best set on ``tune`` (pooled F1) and its per-frame counts on ``report``."""
    from zcut.paired import frame_outcomes, paired_differences

    rows: list[dict] = []
    per_frame: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for m in METHODS:
        sel = tune["method"] == m
        if not sel.any():
            continue
        sums: dict[str, np.ndarray] = {}
        for s_, tp, fp, fn in zip(tune["set"][sel], tune["tp"][sel], tune["fp"][sel], tune["fn"][sel]):
            sums[s_] = sums.get(s_, np.zeros(3, np.int64)) + (tp, fp, fn)
        f1s = {s_: pooled(*v)[2] for s_, v in sums.items()}
        best = max(f1s, key=lambda s_: -1.0 if math.isnan(f1s[s_]) else f1s[s_])
        rsel = (report["method"] == m) & (report["set"] == best)
        if not rsel.any():
            continue
        order = np.argsort(report["frame"][rsel], kind="stable")
        per_frame[m] = tuple(report[k][rsel][order] for k in ("tp", "fp", "fn"))  # type: ignore[assignment]
        p, r, f = pooled(*(float(x.sum()) for x in per_frame[m]))
        rows.append({"method": m, "set": best, "f1_tune": f1s[best], "precision": p, "recall": r, "f1": f,
                     "frames": int(rsel.sum()), "truth_px": int(per_frame[m][0].sum() + per_frame[m][2].sum())})
    rows.sort(key=lambda x: -(x["f1"] if not math.isnan(x["f1"]) else -1))
    for k, row in enumerate(rows):
        row["rank"] = k + 1
    # the methods at a set fixed beforehand (not chosen on the tune log): unranked rows beside the others
    for m, tail in FIXED.items():
        rsel = (report["method"] == m) & (np.char.find(report["set"], tail) >= 0)
        if not rsel.any():
            continue
        order = np.argsort(report["frame"][rsel], kind="stable")
        name = f"{m} (fixed)"
        per_frame[name] = tuple(report[k][rsel][order] for k in ("tp", "fp", "fn"))  # type: ignore[assignment]
        p, r, f = pooled(*(float(x.sum()) for x in per_frame[name]))
        tsel = (tune["method"] == m) & (np.char.find(tune["set"], tail) >= 0)
        f_tune = pooled(*(float(tune[k][tsel].sum()) for k in ("tp", "fp", "fn")))[2]
        rows.append({"method": name, "set": str(report["set"][rsel][0]), "f1_tune": f_tune, "precision": p,
                     "recall": r, "f1": f, "frames": int(rsel.sum()), "rank": "-",
                     "truth_px": int(per_frame[name][0].sum() + per_frame[name][2].sum())})
    for row in rows:
        if row["method"] != "zcut" and "zcut" in per_frame:
            d = paired_differences(per_frame["zcut"], per_frame[row["method"]])["f1"]
            o = frame_outcomes(per_frame["zcut"], per_frame[row["method"]])
            row.update(delta_f1=d.delta, lo=d.lo, hi=d.hi, wins=int((o > 0).sum()), losses=int((o < 0).sum()))
    if "zcut (fixed)" in per_frame and "zcut_top (fixed)" in per_frame:  # the anchoring alone, paired
        d = paired_differences(per_frame["zcut (fixed)"], per_frame["zcut_top (fixed)"])["f1"]
        o = frame_outcomes(per_frame["zcut (fixed)"], per_frame["zcut_top (fixed)"])
        next(r for r in rows if r["method"] == "zcut_top (fixed)").update(
            anchor_delta_f1=d.delta, anchor_lo=d.lo, anchor_hi=d.hi, anchor_wins=int((o > 0).sum()),
            anchor_losses=int((o < 0).sum()))
    return rows


def fmt(rows: list[dict], title: str) -> str:
    out = [f"#### {title}", "", "| rank | method | F1 (P / R), report seed | tune F1 | ΔF1 vs zcut [95 %] | frames won / lost |",
           "|---:|---|---|---:|---|---|"]
    for r in rows:
        d = ""
        if "delta_f1" in r:
            iv = "" if math.isnan(r["lo"]) else f" [{r['lo']:+.2f}, {r['hi']:+.2f}]"
            d = f"{r['delta_f1']:+.2f}{iv}"
        wl = f"{r['wins']} / {r['losses']}" if "wins" in r else ""
        out.append(f"| {r['rank']} | `{r['method']}` | {r['f1']:.2f} ({r['precision']:.2f} / {r['recall']:.2f}) | "
                   f"{r['f1_tune']:.2f} | {d} | {wl} |")
    return "\n".join(out)


def doc_tables(everything: list[dict]) -> str:
    """docs/filters.md's tables: per generator, one row per method, one column per truth and kind; each cell
    F1 on the report log, its rank (bold when first) and ΔF1 against the z-cut [95 %]; the truth's pixels
    in the report log's zone below (read from the ``zone`` baseline: its recall is 1)."""
    out: list[str] = []
    for sensor in dict.fromkeys(e["sensor"] for e in everything):
        cells = [e for e in everything if e["sensor"] == sensor]
        truths = list(dict.fromkeys(e["truth"] for e in cells))
        cells.sort(key=lambda e: truths.index(e["truth"]))  # truth-major, kinds in their order
        names = [m for m in (*METHODS, *(f"{m} (fixed)" for m in FIXED))
                 if any(r["method"] == m for e in cells for r in e["rows"])]
        gen = {"handmade": "hand-made", "raytraced": "ray-traced"}.get(sensor, sensor)
        head = [(f"{gen}, {e['truth']}: " if i == 0 or cells[i - 1]["truth"] != e["truth"] else "")
                + e["kind"].replace("_", " ") for i, e in enumerate(cells)]
        out += ["| method | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
        for m in names:
            row = []
            for e in cells:
                r = next((x for x in e["rows"] if x["method"] == m), None)
                if r is None:
                    row.append("")
                    continue
                if math.isnan(r["recall"]):
                    row.append("no truth")
                    continue
                c = f"{r['f1']:.2f} #{r['rank']}" if r["rank"] != "-" else f"{r['f1']:.2f}"
                c = f"**{c}**" if r["rank"] == 1 else c
                if "delta_f1" in r:
                    iv = "" if math.isnan(r["lo"]) else f" [{r['lo']:+.2f}, {r['hi']:+.2f}]"
                    c += f" {r['delta_f1']:+.2f}{iv}"
                if "anchor_delta_f1" in r:
                    iv = "" if math.isnan(r["anchor_lo"]) else f" [{r['anchor_lo']:+.2f}, {r['anchor_hi']:+.2f}]"
                    c += f"; vs `zcut (fixed)` {r['anchor_delta_f1']:+.2f}{iv}"
                row.append(c.replace("-", "−"))
            out.append(f"| `{m}`{' (baseline)' if m == 'zone' else ''} | " + " | ".join(row) + " |")
        out += ["", f"{gen}: truth pixels in the report log's zone: " + ", ".join(
            f"{e['truth']}: {e['kind']} {e['rows'][0]['truth_px']:,}" for e in cells), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="zinc_nuts,spheres")
    ap.add_argument("--sensors", default="handmade,raytraced")
    ap.add_argument("--truths", default="paper,sensor")
    ap.add_argument("--size", default="480x300")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--tune-seed", type=int, default=8101)
    ap.add_argument("--report-seed", type=int, default=8201)
    ap.add_argument("--out", type=Path, default=None, help="keep the logs and sweeps here (reused when present)")
    ap.add_argument("--json", type=Path, default=None, help="write every row here")
    ap.add_argument("--doc", action="store_true", help="also print docs/filters.md's side-by-side tables")
    a = ap.parse_args(argv)
    os.environ["ZCUT_METHODS"] = f"{Path(__file__).stem}:ZONE"
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # the plug-in is this module, by its name
    out = a.out or Path(tempfile.mkdtemp(prefix="rank_truths_"))
    out.mkdir(parents=True, exist_ok=True)
    everything = []
    for sensor in a.sensors.split(","):
        for kind in a.kinds.split(","):
            t0 = time.process_time()
            tune_log = synth(out, sensor, kind, a.tune_seed, a.frames, a.size)
            report_log = synth(out, sensor, kind, a.report_seed, a.frames, a.size)
            for truth in a.truths.split(","):
                rows = rank_one(sweep(tune_log, truth, out), sweep(report_log, truth, out))
                title = f"{sensor}, {kind}, {truth}'s truth ({a.size}, {a.frames} frames; tune seed {a.tune_seed}, report seed {a.report_seed})"
                print(fmt(rows, title), "\n", flush=True)
                everything.append({"sensor": sensor, "kind": kind, "truth": truth, "rows": rows})
            print(f"({sensor} {kind}: {time.process_time() - t0:.0f} CPU-s in this process)\n", flush=True)
    if a.json:
        a.json.write_text(json.dumps(everything, indent=1, default=float))
    if a.doc:
        print(doc_tables(everything))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
