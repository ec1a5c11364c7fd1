"""The ray-traced sensor held against the paper's real scans (issue 31, items 3-4): the statistics the
paper reports, per kind, with and without the camera's own filters, and their sensitivity.

    .venv/bin/python bench/raytrace_paper.py [--kinds spheres,zinc_nuts,black_nuts] [--size 480x300] \\
        [--frames 2] [--seed 73201] [--variants base,filters,spec_half,bounces2,strict] \\
        [--max-depth MM] [--work /tmp/zcut_rt_paper] [--json OUT.json]

Per variant of the sensor and part kind it ray-traces ``--frames`` frames of seed ``--seed`` (a
seed no test or other bench uses; nothing here is tuned, every figure is a check), runs the full
pipeline on each (bin mask, ICP of the log's own exact bin model, removal, nominal z-cut, SOR, and
the bank's ``radius`` and ``cluster`` at their default settings) and pools over the frames, on the
zone the filters judge (the above-the-rim points, which the rim threshold takes for every filter,
left out):

- **Fig. 14** (paper §7: the z-cut's outliers "grouped in large clusters of connected pixels", SOR's
  "mostly single, isolated pixels"): the share of each filter's flagged pixels lying in 8-connected
  components of at least 2 pixels (``clustered%``), and the median component size in pixels.
- **Fig. 15** (α = N1 / N2, β_SOR = N_both / N1, β_zcut = N_both / N2; shiny parts: α and β_zcut
  small; matte parts d, e: both large).
- **Figs. 12b, 21** (matte clouds are clean; SOR's extra finds there are mostly false): the paper's
  truth (``/ground_truth/off_surface``) as a share of the zone, SOR's precision and false pixels per
  frame.
- **Where the z-cut looks**: how far the zone's highest point z_max (from which the z-cut's window
  of d_max reaches down; SOR runs on the same top part) lies above the pile's own top (the 99.9th
  percentile of the pixels neither truth calls outliers), the window's pixels and their truth
  share; the share of the true outliers that float (components at least Δd nearer the camera than
  every valid pixel around them) and of those, the share wholly below the window.
- **The ranking** (docs/filters.md, ray-traced truth): F1 of ``zcut``, ``sor``, ``radius``,
  ``cluster`` and the ``zone`` baseline (flag every judged pixel) under the paper's truth and the
  sensor's (``/ground_truth/outliers``).

Variants: ``base`` (the sensor as it is), ``filters`` (``--camera-filters``: noise SNR < 7,
reflection, outlier 5 mm), ``spec_half`` (every part's specular share halved: the materials are
substituted in this process only, not a sensor option), ``bounces2`` (two camera-side bounces),
``strict`` (a stricter decoder: fringe contrast >= 0.5 instead of 0.35, signal >= 0.008 instead of
0.004). ``--max-depth``: the z-cut's d_max instead of the nominal 30 mm (a pipeline setting, not a
sensor variant). CPU seconds (``time.process_time``) per variant are printed; logs are kept under
``--work`` and reused. Then a table of which observations and conclusions hold, per kind and variant.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_raytrace import VARIANTS, specular_scaled, variant_options, variant_specular  # noqa: E402  (the variants)

from replay.logs import layout  # noqa: E402
from replay.synth.raytrace import write_raytraced_log  # noqa: E402
from zcut.metrics import ratio  # noqa: E402  (x / 0 = inf, 0 / 0 = NaN, as the reports)

EIGHT = np.ones((3, 3), bool)
METHODS = ("zcut", "sor", "radius", "cluster")
SHINY = ("spheres", "zinc_nuts", "rods", "sprockets")
#: fewer flagged pixels than this (pooled) and a share of them says nothing
FEW = 30


def make_log(path: Path, kind: str, variant: str, *, seed: int, frames: int, size: tuple[int, int]) -> float:
    """Write the log unless it exists; CPU seconds spent."""
    if path.exists():
        return 0.0
    opts = variant_options(variant)
    scale = variant_specular(variant)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".part")
    t0 = time.process_time()
    with specular_scaled(scale):
        write_raytraced_log(tmp, kind=kind, frames=frames, seed=seed, size=size, bag_name=path.name, **opts)
    tmp.rename(path)
    return time.process_time() - t0


def _components(mask: np.ndarray) -> np.ndarray:
    lab, n = ndimage.label(mask, structure=EIGHT)
    return np.bincount(lab.ravel(), minlength=n + 1)[1:]


def floating_pixels(truth: np.ndarray, z_mm: np.ndarray, height_mm: np.ndarray, *, floor_mm: float,
                    gap_mm: float = 0.2) -> tuple[int, int]:
    """Pixels of ``truth`` in 8-connected components lying at least ``gap_mm`` nearer the camera than
    every valid pixel bordering them (the outliers a z-cut of step ``gap_mm`` can separate; a patch
    next to a higher surface, or behind its own, joins that surface's cluster at every level), as
    (those reaching above ``floor_mm`` of height, the z-cut's lowest level z_max - d_max; those
    lying wholly below it, out of its reach)."""
    lab, _ = ndimage.label(truth, structure=EIGHT)
    valid = np.isfinite(z_mm)
    within = below = 0
    for i, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        r0, r1 = max(sl[0].start - 1, 0), sl[0].stop + 1
        c0, c1 = max(sl[1].start - 1, 0), sl[1].stop + 1
        comp = lab[r0:r1, c0:c1] == i
        ring = ndimage.binary_dilation(comp, structure=EIGHT) & ~comp & valid[r0:r1, c0:c1]
        zb = z_mm[r0:r1, c0:c1]
        if ring.any() and zb[comp].max() > zb[ring].min() - gap_mm:
            continue
        if np.nanmax(height_mm[r0:r1, c0:c1][comp]) >= floor_mm:
            within += int(comp.sum())
        else:
            below += int(comp.sum())
    return within, below


def judge_log(path: Path, *, max_depth: float | None = None) -> dict:
    """Pool the statistics of the module docstring over the frames of one log (``max_depth``: the
    z-cut's d_max in mm instead of the nominal 30)."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.config import cli_layer
    from replay.pipeline.session import ReplaySession

    session = ReplaySession.open(path, overrides=cli_layer(methods=",".join(METHODS), max_depth=max_depth),
                                 choose_bin_model=lambda reader: bin_model_for(reader, None))
    acc: dict = {"frames": 0, "zone": 0, "valid": 0, "pixels": 0, "paper": 0, "sensor": 0,
                 "n_both": 0, "n1": 0, "n2": 0, "sizes": {m: [] for m in METHODS},
                 "tp": {}, "fp": {}, "fn": {}, "flagged": {m: 0 for m in METHODS}}
    for frame, r in session.results():
        acc["frames"] += 1
        zone = r.zone & r.valid
        acc["zone"] += int(zone.sum())
        acc["valid"] += int(r.valid.sum())
        acc["pixels"] += int(r.valid.size)
        found = {m: r.outliers[m] & zone for m in METHODS}
        found["zone"] = zone
        z, s = found["zcut"], found["sor"]
        acc["n_both"] += int((z & s).sum())
        acc["n1"] += int((s & ~z).sum())
        acc["n2"] += int((z & ~s).sum())
        for m in METHODS:
            acc["sizes"][m].extend(_components(found[m]).tolist())
            acc["flagged"][m] += int(found[m].sum())
        # the z-cut's window: the zone within d_max of its highest point z_max; where z_max lies
        # above the pile's own top (the 99.9th percentile of the pixels no truth calls outliers)
        if zone.any():
            h = np.where(zone, r.height_mm, np.nan)
            top = float(np.nanmax(h))
            window = zone & (r.height_mm >= top - session.config.zcut.max_depth)
            clean = zone & ~frame.masks[layout.TRUTH_OFF_SURFACE] & ~frame.masks[layout.TRUTH_OUTLIERS]
            if clean.any():
                acc.setdefault("top_above_pile", []).append(top - float(np.nanpercentile(r.height_mm[clean], 99.9)))
            acc["window"] = acc.get("window", 0) + int(window.sum())
            acc["window_truth"] = acc.get("window_truth", 0) + int((window & frame.masks[layout.TRUTH_OFF_SURFACE]).sum())
        for tname, key in (("paper", layout.TRUTH_OFF_SURFACE), ("sensor", layout.TRUTH_OUTLIERS)):
            t = frame.masks[key] & zone
            acc[tname] += int(t.sum())
            acc.setdefault(f"{tname}_sizes", []).extend(_components(t).tolist())
            z_mm = frame.xyz[..., 2].astype(np.float64) * 1000.0
            top = float(np.nanmax(np.where(zone, r.height_mm, np.nan))) if zone.any() else 0.0
            within, below = floating_pixels(t, z_mm, r.height_mm, floor_mm=top - session.config.zcut.max_depth)
            acc[f"{tname}_floating"] = acc.get(f"{tname}_floating", 0) + within + below
            acc[f"{tname}_floating_below"] = acc.get(f"{tname}_floating_below", 0) + below
            lab, n = ndimage.label(found["zcut"], structure=EIGHT)
            hit = np.unique(lab[t & found["zcut"]])
            acc[f"zcut_false_comps_{tname}"] = acc.get(f"zcut_false_comps_{tname}", 0) + n - int((hit > 0).sum())
            for m, f in found.items():
                for what, v in (("tp", f & t), ("fp", f & ~t), ("fn", t & ~f)):
                    acc[what][(m, tname)] = acc[what].get((m, tname), 0) + int(v.sum())
    return acc


def summarize(acc: dict) -> dict:
    out: dict = {"frames": acc["frames"], "nan%": 100 * (1 - ratio(acc["valid"], acc["pixels"])),
                 "paper_rate%": 100 * ratio(acc["paper"], acc["zone"]),
                 "sensor_rate%": 100 * ratio(acc["sensor"], acc["zone"]),
                 "alpha": ratio(acc["n1"], acc["n2"]), "beta_sor": ratio(acc["n_both"], acc["n1"]),
                 "beta_zcut": ratio(acc["n_both"], acc["n2"]), "n_both": acc["n_both"], "n1": acc["n1"],
                 "n2": acc["n2"],
                 "top_above_pile_mm": float(np.mean(acc["top_above_pile"])) if acc.get("top_above_pile") else float("nan"),
                 "window_px_per_frame": ratio(acc.get("window", 0), acc["frames"]),
                 "window_truth%": 100 * ratio(acc.get("window_truth", 0), acc.get("window", 0))}
    for t in ("paper", "sensor"):
        out[f"zcut_false_comps_{t}_per_frame"] = ratio(acc.get(f"zcut_false_comps_{t}", 0), acc["frames"])
        out[f"{t}_floating%"] = 100 * ratio(acc.get(f"{t}_floating", 0), acc[t])
        out[f"{t}_floating_below%"] = 100 * ratio(acc.get(f"{t}_floating_below", 0), acc[t])
        sizes = np.asarray(acc.get(f"{t}_sizes", []), np.int64)
        out[f"{t}_clustered%"] = 100 * ratio(int(sizes[sizes >= 2].sum()), int(sizes.sum()))
    for m in METHODS:
        sizes = np.asarray(acc["sizes"][m], np.int64)
        tot = int(sizes.sum())
        out[f"{m}_flagged"] = tot
        out[f"{m}_clustered%"] = 100 * ratio(int(sizes[sizes >= 2].sum()), tot)
        out[f"{m}_median_size"] = float(np.median(sizes)) if sizes.size else float("nan")
        out[f"{m}_weighted_size"] = ratio(float((sizes.astype(float) ** 2).sum()), tot)
    for m in (*METHODS, "zone"):
        for t in ("paper", "sensor"):
            tp, fp, fn = acc["tp"][(m, t)], acc["fp"][(m, t)], acc["fn"][(m, t)]
            out[f"{m}_{t}_P"] = ratio(tp, tp + fp)
            out[f"{m}_{t}_R"] = ratio(tp, tp + fn)
            out[f"{m}_{t}_F1"] = ratio(2 * tp, 2 * tp + fp + fn)
            out[f"{m}_{t}_fp_per_frame"] = ratio(fp, acc["frames"])
    return out


def fmt(v: float, nd: int = 2) -> str:
    if isinstance(v, float) and not np.isfinite(v):
        return "–" if np.isnan(v) else "∞"
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def tables(rows: dict[tuple[str, str], dict], variants: list[str], kinds: list[str]) -> str:
    lines = ["### Figs. 14, 15, 12b/21: per kind and variant (zone, above-the-rim points left out)", "",
             "| kind | variant | NaN % | z_max above the pile's top (mm) / window px per frame / truth % of it | paper truth % of zone / clustered % / floating % (below d_max %) | z-cut flagged / clustered % / median comp | "
             "SOR flagged / clustered % / median comp | α | β_SOR | β_zcut | SOR P (paper) | SOR false px/frame | "
             "z-cut P / R (paper) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for k in kinds:
        for v in variants:
            r = rows.get((k, v))
            if r is None:
                continue
            lines.append(
                f"| {k} | {v} | {fmt(r['nan%'], 1)} | {fmt(r['top_above_pile_mm'], 0)} / "
                f"{fmt(r['window_px_per_frame'], 0)} / {fmt(r['window_truth%'], 0)} | {fmt(r['paper_rate%'], 2)} / {fmt(r['paper_clustered%'], 0)} / {fmt(r['paper_floating%'], 0)} ({fmt(r['paper_floating_below%'], 0)}) | "
                f"{r['zcut_flagged']} / {fmt(r['zcut_clustered%'], 0)} / {fmt(r['zcut_median_size'], 0)} | "
                f"{r['sor_flagged']} / {fmt(r['sor_clustered%'], 0)} / {fmt(r['sor_median_size'], 0)} | "
                f"{fmt(r['alpha'])} | {fmt(r['beta_sor'])} | {fmt(r['beta_zcut'])} | {fmt(r['sor_paper_P'])} | "
                f"{fmt(r['sor_paper_fp_per_frame'], 0)} | {fmt(r['zcut_paper_P'])} / {fmt(r['zcut_paper_R'])} |")
    lines += ["", "### The ranking at default settings: F1 (paper's truth / sensor's truth)", "",
              "| kind | variant | " + " | ".join((*METHODS, "zone")) + " |",
              "|---|---|" + "---|" * (len(METHODS) + 1)]
    for k in kinds:
        for v in variants:
            r = rows.get((k, v))
            if r is None:
                continue
            cells = [f"{fmt(r[f'{m}_paper_F1'])} / {fmt(r[f'{m}_sensor_F1'])}" for m in (*METHODS, "zone")]
            lines.append(f"| {k} | {v} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _holds(flag: bool | None) -> str:
    return "n/a" if flag is None else ("holds" if flag else "**fails**")


#: The paper's observations on its real scans and the ray-traced ranking's conclusions, each as a
#: test on one kind's row: (name, kinds it applies to, test -> (bool or None, figure shown)).
def _checks() -> list[tuple[str, str, object]]:
    def fig14_zcut(r: dict) -> tuple[bool | None, str]:
        zc, n = r["zcut_clustered%"], r["zcut_flagged"]
        if n < FEW:
            return None, f"{fmt(zc, 0)} % of {n} px: too few"
        return bool(zc > 50), f"{fmt(zc, 0)} % of {n} px, median component {fmt(r['zcut_median_size'], 0)} px"

    def fig14_sor(r: dict) -> tuple[bool | None, str]:
        so, n = r["sor_clustered%"], r["sor_flagged"]
        if n < FEW:
            return None, f"{fmt(so, 0)} % of {n} px: too few"
        return bool(so < 50), f"{fmt(so, 0)} % of {n} px"

    def fig15_shiny(r: dict) -> tuple[bool | None, str]:
        a, b = r["alpha"], r["beta_zcut"]
        return bool(a < 1 and b < 0.5), f"α {fmt(a)}, β_zcut {fmt(b)}"

    def fig15_matte(r: dict) -> tuple[bool | None, str]:
        a, b = r["alpha"], r["beta_zcut"]
        return bool(a > 1 and b > 0.5), f"α {fmt(a)}, β_zcut {fmt(b)}"

    def fig21(r: dict) -> tuple[bool | None, str]:
        p = r["sor_paper_P"]
        return (None if not np.isfinite(p) else bool(p < 0.5)), f"SOR P {fmt(p)}, {fmt(r['sor_paper_fp_per_frame'], 0)} false px/frame"

    def zcut_over_sor(r: dict) -> tuple[bool | None, str]:
        a, b = r["zcut_paper_F1"], r["sor_paper_F1"]
        return bool(a > b), f"{fmt(a)} vs {fmt(b)}"

    def bank_over_zcut(r: dict) -> tuple[bool | None, str]:
        z, c = r["zcut_paper_F1"], r["cluster_paper_F1"]
        return bool(c > z), f"{fmt(c)} vs {fmt(z)}"

    def shiny_dirty(r: dict) -> tuple[bool | None, str]:
        return bool(r["paper_rate%"] > 1.0), f"{fmt(r['paper_rate%'])} % of the zone"

    def matte_clean(r: dict) -> tuple[bool | None, str]:
        return bool(r["paper_rate%"] < 0.5), f"{fmt(r['paper_rate%'])} % of the zone"

    def rare_false_clusters(r: dict) -> tuple[bool | None, str]:
        n = r["zcut_false_comps_paper_per_frame"]
        return bool(n <= 2), f"{fmt(n, 0)} false components/frame, {fmt(r['zcut_paper_fp_per_frame'], 0)} px"

    def low_recall(r: dict) -> tuple[bool | None, str]:
        rec = r["zcut_paper_R"]
        return bool(rec < 0.1), f"R {fmt(rec)}"

    def zone_over_zcut(r: dict) -> tuple[bool | None, str]:
        a, b = r["zone_sensor_F1"], r["zcut_sensor_F1"]
        return bool(a > b), f"{fmt(a)} vs {fmt(b)}"

    return [
        ("paper Fig. 12a: shiny clouds contaminated (paper's truth > 1 % of the zone)", "shiny", shiny_dirty),
        ("paper Figs. 12b, 21: matte clouds clean (paper's truth < 0.5 % of the zone)", "matte", matte_clean),
        ("paper §5.4: the z-cut's false clusters rare (≤ 2 per frame; the paper saw 2 in all its M8-screw data)",
         "matte", rare_false_clusters),
        ("paper Fig. 14: the z-cut's finds lie in clusters (> 50 % of its pixels in components of >= 2 px)", "shiny",
         fig14_zcut),
        ("paper Fig. 14: SOR's finds are isolated pixels (< 50 % in components of >= 2 px)", "shiny", fig14_sor),
        ("paper Fig. 15, shiny: α < 1 and β_zcut < 0.5", "shiny", fig15_shiny),
        ("paper Fig. 15, matte: α > 1 and β_zcut > 0.5", "matte", fig15_matte),
        ("paper Figs. 12b, 21, matte: SOR's finds mostly false (precision < 0.5, paper's truth)", "matte", fig21),
        ("ranking: z-cut F1 above SOR's (paper's truth)", "shiny", zcut_over_sor),
        ("ranking: `cluster` above the z-cut (paper's truth)", "shiny", bank_over_zcut),
        ("ranking: the z-cut's recall below 0.1 (paper's truth)", "shiny", low_recall),
        ("ranking: the `zone` baseline above the z-cut (sensor's truth)", "shiny", zone_over_zcut),
    ]


def survival(rows: dict[tuple[str, str], dict], variants: list[str], kinds: list[str]) -> str:
    """Which observations and conclusions hold under each variant, per kind."""
    lines = ["### What holds under each variant (per kind: holds / **fails**, with the figure)", "",
             "| observation or conclusion | kind | " + " | ".join(variants) + " |",
             "|---|---|" + "---|" * len(variants)]
    for name, applies, test in _checks():
        for k in kinds:
            if (applies == "shiny") != (k in SHINY):
                continue
            cells = []
            for v in variants:
                r = rows.get((k, v))
                if r is None:
                    cells.append("–")
                    continue
                ok, fig = test(r)  # type: ignore[operator]
                cells.append(f"{_holds(ok)} ({fig})")
            lines.append(f"| {name} | {k} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="spheres,zinc_nuts,black_nuts")
    ap.add_argument("--size", default="480x300", help="WxH (default 480x300)")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--seed", type=int, default=73201)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--work", default="/tmp/zcut_rt_paper")
    ap.add_argument("--json", default=None, help="also write the rows as JSON")
    ap.add_argument("--max-depth", type=float, default=None,
                    help="the z-cut's d_max in mm (default: the nominal 30; the window then reaches down from z_max)")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.lower().split("x"))
    kinds = args.kinds.split(",")
    variants = args.variants.split(",")
    for v in variants:
        if v not in VARIANTS:
            sys.exit(f"error: unknown variant {v!r} (known: {', '.join(VARIANTS)})")
    work = Path(args.work)
    rows: dict[tuple[str, str], dict] = {}
    for v in variants:
        t_make = t_judge = 0.0
        for k in kinds:
            log = work / f"{v}_{k}_{args.seed}_{w}x{h}_{args.frames}.mcap"
            t_make += make_log(log, k, v, seed=args.seed, frames=args.frames, size=(h, w))
            t0 = time.process_time()
            rows[(k, v)] = summarize(judge_log(log, max_depth=args.max_depth))
            t_judge += time.process_time() - t0
            print(f"{v} {k}: done", file=sys.stderr, flush=True)
        print(f"variant {v}: CPU {t_make:.1f} s tracing (0 when reused), {t_judge:.1f} s judging", file=sys.stderr)
    print(f"size {w}x{h}, seed {args.seed}, {args.frames} frame(s) per kind and variant"
          + (f", z-cut d_max {args.max_depth:g} mm" if args.max_depth is not None else "") + "\n")
    print(tables(rows, variants, kinds))
    print()
    print(survival(rows, variants, kinds))
    if args.json:
        Path(args.json).write_text(json.dumps({f"{k}/{v}": r for (k, v), r in rows.items()}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
