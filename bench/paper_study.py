"""The paper's findings, measured by true accuracy on the six synthetic part kinds, tuned on one seed
set and scored on another (issues 10, 13 and 20).

For each part kind of the paper's Figure 8 it synthesises training logs and test logs (other seeds),
builds the bin model from synthetic empty-bin scans (the paper's five positions), and runs the real
commands:

- ``zcut sweep`` over the training logs: the tuning (its rule, ``studies.validate.RULE``) and its
  cross-validated out-of-sample estimate (folds of logs);
- ``zcut sweep`` over the test logs with the same grid: every set scored on frames the tuning never
  saw, with the intervals of measured coverage (``docs/accuracy.md``, "Uncertainty"); the tuned sets
  of both rules (``best``, ``one_se``) and the paper's nominal set read there;
- ``zcut accuracy`` on each test log at the nominal parameters: recall per outlier kind, cluster
  precision.

It writes ``docs/paper_study.md`` and keeps the outputs under ``--work`` (reused when present). CPU
time (this process and its children) is measured with ``resource.getrusage``.

    .venv/bin/python bench/paper_study.py [--logs 3] [--frames 2] [--size 960x600] \\
        [--train-seed 90001] [--test-seed 90011] [--work /tmp/zcut_paper_study_cv]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

KINDS = ("spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ZCUT = [sys.executable, "-m", "cli"]
GRID = ["--step", "0.1,0.2,0.4", "--max-depth", "15:90:6", "--rho", "0.035,0.05,0.07,0.105",
        "--sor-k", "4,8", "--sor-std", "0.5,1,2"]
SHINY = ("spheres", "zinc_nuts", "rods", "sprockets")
MATTE = ("black_screws", "black_nuts")


def zcut(*args, capture: bool = False) -> str:
    out = subprocess.run([*ZCUT, *map(str, args)], cwd=ROOT, check=False, text=True,
                         stdout=subprocess.PIPE if capture else subprocess.DEVNULL)
    if out.returncode not in (0, 3):
        sys.exit(f"zcut {' '.join(map(str, args))} failed with {out.returncode}")
    return out.stdout or ""


def _cpu() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _scale(size: str) -> str:
    """How the size compares with the sensor's 1920x1200."""
    w, h = (int(x) for x in size.lower().split("x"))
    return "" if (w, h) == (1920, 1200) else f" ({w / 1920:.2g} × the sensor's 1920x1200 in each direction, to keep the run modest)"


def _seeds(base: int, kind_index: int, n: int) -> list[int]:
    return [base + 1000 * kind_index + j for j in range(n)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=3, help="logs per kind and split (default 3)")
    ap.add_argument("--frames", type=int, default=2, help="frames per log (default 2)")
    ap.add_argument("--size", default="960x600", help="WxH (default 960x600, half the sensor's 1920x1200)")
    ap.add_argument("--train-seed", type=int, default=90001)
    ap.add_argument("--test-seed", type=int, default=90011)
    ap.add_argument("--bin-seed", type=int, default=2024)
    ap.add_argument("--work", default="/tmp/zcut_paper_study_cv")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "paper_study.md"))
    args = ap.parse_args()
    if abs(args.train_seed - args.test_seed) < args.logs:
        sys.exit("the training and test seeds overlap")
    work = Path(args.work) / args.size
    work.mkdir(parents=True, exist_ok=True)
    t0, c0 = time.perf_counter(), _cpu()
    empty, model = work / "empty.mcap", work / "bin.ply"
    if not model.is_file():
        zcut("synth", "-o", empty, "--empty", "--frames", 5, "--seed", args.bin_seed, "--size", args.size, "--force")
        zcut("bin-model", empty, "-o", model, "--force")
    grid_tag = hashlib.sha1(" ".join(GRID).encode()).hexdigest()[:8]
    results = {}
    for i, kind in enumerate(KINDS):
        split_logs = {}
        for split, base in (("train", args.train_seed), ("test", args.test_seed)):
            logs = []
            for seed in _seeds(base, i, args.logs):
                log = work / f"{kind}_{seed}_{args.frames}.mcap"
                if not log.is_file():
                    zcut("synth", "-o", log, "--parts", kind, "--frames", args.frames, "--seed", seed, "--size", args.size)
                logs.append(log)
            split_logs[split] = logs
        sweeps = {}
        for split, logs in split_logs.items():
            out = work / f"sweep_{kind}_{split}_{args.logs}x{args.frames}_{grid_tag}"
            if not (out / "summary.json").is_file():
                zcut("sweep", *logs, "-o", out, "--bin-model", model, *GRID, "--workers", args.workers, "--force",
                     "--no-report")
            sweeps[split] = out
        acc = []
        for log in split_logs["test"]:
            cached = log.with_suffix(".accuracy.json")
            if not cached.is_file():
                cached.write_text(zcut("accuracy", log, "--bin-model", model, "--json", capture=True))
            acc.append(json.loads(cached.read_text()))
        results[kind] = evaluate(sweeps["train"], sweeps["test"], acc)
        print(f"{kind}: done ({time.perf_counter() - t0:.0f} s, {_cpu() - c0:.0f} s CPU)", file=sys.stderr, flush=True)
    # the cost of computing the outputs, summed over the runs that computed them (a run over cached
    # outputs only renders)
    cost_file = work / "cost.json"
    cost = json.loads(cost_file.read_text()) if cost_file.is_file() else {"seconds": 0.0, "cpu_seconds": 0.0}
    cost = {"seconds": cost["seconds"] + time.perf_counter() - t0, "cpu_seconds": cost["cpu_seconds"] + _cpu() - c0}
    cost_file.write_text(json.dumps(cost))
    text = render(results, args, cost["seconds"], cost["cpu_seconds"])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    print(text)
    return 0


# ------------------------------------------------------------------------------------ the measures
def evaluate(train_dir: Path, test_dir: Path, acc: list[dict]) -> dict:
    """Both tuning rules run on the training sweep, every choice and the nominal set scored on the
    test sweep's frames (pooled figures with the measured-coverage intervals, and the paired
    difference against the nominal set)."""
    import pyarrow.parquet as pq

    from studies import scoring, sweep
    from studies.setgrid import same_set
    from studies.summary import SweepSummary
    from studies.validate import RULES, _parts, paired_difference
    from zcut.metrics import pooled_interval

    train = SweepSummary.from_json(json.loads((train_dir / "summary.json").read_text()))
    test = SweepSummary.from_json(json.loads((test_dir / "summary.json").read_text()))
    train_table = pq.read_table(train_dir / "sweep.parquet")
    test_table = pq.read_table(test_dir / "sweep.parquet")
    objective = scoring.parse_objective(train.objective)
    chosen = train.grid.chosen
    point = (chosen[0], chosen[1], chosen[2], None)
    base_tuned = sweep.tune(list(train.sets), objective, part=_part(train))
    test_z = [e for e in test.sets if e.method == "zcut"]
    counts = sweep.frame_counts(test_table, test_z)
    nominal = test.nominal
    i_nom = next(i for i, e in enumerate(test_z) if same_set(e, nominal))
    out = {"train": train, "test": test, "acc": acc, "rules": {}}
    for rule in RULES:
        tuned, v = sweep.validate_tuning(train_table, list(train.sets), base_tuned, objective, point=point, rule=rule)
        z = tuned.zcut
        i = next(i for i, e in enumerate(test_z) if same_set(e, z))
        t = test_z[i]
        num_a, den_a = _parts("f1", counts.tp[i], counts.fp[i], counts.fn[i])
        num_b, den_b = _parts("f1", counts.tp[i_nom], counts.fp[i_nom], counts.fn[i_nom])
        d, se = paired_difference(num_a[None].astype(float), den_a[None].astype(float), num_b[None].astype(float),
                                  den_b[None].astype(float))
        from scipy import stats

        m = counts.n_frames
        q = float(stats.t.ppf(0.975, m - 1))
        out["rules"][rule] = {"set": z, "validation": v, "test": t, "d": float(d[0]), "d_ci": (float(d[0] - q * se[0]),
                              float(d[0] + q * se[0])), "ci": pooled_interval(counts.tp[i], counts.fp[i], counts.fn[i])}
    # SOR: the training sweep's best SOR set, read on the test frames
    s = base_tuned.sor
    out["sor_test"] = next((e for e in test.sets if same_set(e, s)), None) if s is not None else None
    return out


def _part(s) -> str | None:
    import tomllib

    try:
        return tomllib.loads(s.config).get("part")
    except (tomllib.TOMLDecodeError, AttributeError):
        return None


# ------------------------------------------------------------------------------------ the page
def _f(v, d=3) -> str:
    return "—" if v is None or v != v else f"{v:.{d}f}"


def _fci(v, ci) -> str:
    lo, hi = ci if ci is not None else (None, None)
    if lo is None or hi is None or lo != lo:
        return f"{_f(v)} [too few frames]"
    return f"{_f(v)} [{_f(lo, 2)}, {_f(hi, 2)}]"


def _set_ci(e, key: str) -> str:
    return "—" if e is None else _fci(e.figure(key), e.ci(key))


def _params(e) -> str:
    return "—" if e is None else f"{e.step_mm:g} / {e.max_depth_mm:g} / {e.rho_thr:g}"


def _alpha(e):
    o = e.overlap if e is not None else None
    if o is None:
        return None, None, None
    return o.alpha, o.beta_sor, o.beta_zcut


def _verdict(d: float, ci: tuple[float, float], same: bool) -> str:
    if same:
        return "= nominal"
    lo, hi = ci
    if lo > 0:
        return f"better: {d:+.3f} [{lo:+.3f}, {hi:+.3f}]"
    if hi < 0:
        return f"worse: {d:+.3f} [{lo:+.3f}, {hi:+.3f}]"
    return f"indistinguishable: {d:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def render(results: dict, args, seconds: float, cpu: float) -> str:
    from studies.findings import findings_table
    from studies.setgrid import same_set
    from studies.validate import RULE

    n_frames = args.logs * args.frames
    lines = [
        "# The paper's findings, measured by true accuracy: tuned on one seed set, scored on another",
        "",
        f"Generated by `bench/paper_study.py --logs {args.logs} --frames {args.frames} --size {args.size} "
        f"--train-seed {args.train_seed} --test-seed {args.test_seed}` ({seconds / 60:.0f} min wall, "
        f"{cpu / 60:.1f} min CPU of this process and its children on this shared 2-core machine; load average "
        f"{os.getloadavg()[0]:.1f} at the end).",
        "",
        f"- **Data.** Synthetic logs of the paper's six part kinds (generator and its assumptions: "
        f"`docs/synthetic.md`) at {args.size} px{_scale(args.size)}. Per kind: **training** {args.logs} logs × {args.frames} frames, seeds "
        f"{args.train_seed}–{args.train_seed + args.logs - 1} (+1000 for each next kind in the order of the "
        f"tables); **test** {args.logs} logs × {args.frames} frames, seeds "
        f"{args.test_seed}–{args.test_seed + args.logs - 1} (+1000 likewise). One bin model from five "
        f"synthetic empty-bin scans (seed {args.bin_seed}). Full pipeline (bin mask, ICP, removal, z-cut, SOR on "
        "the top of the pile), scored over the zone the filters judge.",
        "- **Tuning** on the training logs only: `zcut sweep` over " + " ".join(GRID) + ", the z-cut set "
        "chosen within the paper's §5.4 ranges for the part, by F1. Two rules (`docs/studies.md`, \"Out of "
        "sample\"): `best` (the highest F1) and `one_se` (the set nearest the config's own values whose F1 is "
        "within one standard error of the best's). The sweep's own out-of-sample estimate is its "
        f"cross-validation over the {args.logs} training logs (one fold per log).",
        f"- **Scoring** on the test logs only ({n_frames} frames per kind): every figure below comes from "
        "frames the tuning never saw. Intervals: 95 %, the pooled interval of measured coverage "
        "(`docs/accuracy.md`, \"Uncertainty\"); \"too few frames\" where it cannot be given. Tuned against "
        "nominal: the paired per-frame difference of F1 on the test frames with its 95 % t interval.",
        "",
        "The earlier version of this study tuned and scored on the same 3 frames per kind, with a percentile "
        "bootstrap whose \"95 %\" intervals held the population figure in as few as 62 % of samples "
        "(`docs/accuracy.md`, \"Uncertainty\"); "
        "its tuned F1 was an in-sample figure and its \"beyond the intervals\" findings rested on those "
        "intervals. Every finding below is restated on held-out frames with intervals of measured coverage.",
        "",
        "## 1. The paper's nominal parameters (Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07), per kind, test frames",
        "",
        "| kind | z-cut precision | z-cut recall | z-cut F1 | SOR precision | SOR recall | SOR F1 | α | β_SOR | β_zcut |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for kind, r in results.items():
        t = r["test"]
        nom, sor = t.nominal, t.chosen_sor
        a, b1, b2 = _alpha(nom)
        lines.append(f"| {kind} | {_set_ci(nom, 'precision')} | {_set_ci(nom, 'recall')} | {_set_ci(nom, 'f1')} | "
                     f"{_set_ci(sor, 'precision')} | {_set_ci(sor, 'recall')} | {_set_ci(sor, 'f1')} | {_f(a, 2)} | "
                     f"{_f(b1, 2)} | {_f(b2, 2)} |")
    lines += ["", "SOR at the config's own k and std_ratio (the replay's); α = N1/N2, β_SOR = N_both/N1, "
              "β_zcut = N_both/N2 over the zone.", "",
              "Recall by outlier kind at the nominal parameters (z-cut / SOR; n = true outlier pixels of the kind "
              "in the zone, summed over the test logs):", "",
              "| kind | floating | spike_up | spike_down | flying | above_rim |", "|---|---|---|---|---|---|"]
    for kind, r in results.items():
        cells = []
        for k in ("floating", "spike_up", "spike_down", "flying", "above_rim"):
            n = sum(a["pooled"]["zcut"].get("by_kind", {}).get(k, {}).get("n", 0) for a in r["acc"])
            fz = sum(a["pooled"]["zcut"].get("by_kind", {}).get(k, {}).get("found", 0) for a in r["acc"])
            fs = sum(a["pooled"]["sor"].get("by_kind", {}).get(k, {}).get("found", 0) for a in r["acc"])
            cells.append(f"{fz / n:.2f} / {fs / n:.2f} (n {n})" if n else "—")
        lines.append(f"| {kind} | " + " | ".join(cells) + " |")

    lines += ["", "## 2. Tuned on the training logs, scored on the test logs", "",
              "| kind | nominal F1 (test) | rule | tuned Δd / d_max / ρ_thr | F1 training (in sample) | "
              "F1 cross-validated (training) | F1 test | tuned − nominal on test |",
              "|---|---|---|---|---|---|---|---|"]
    optimism = {rule: [] for rule in ("best", "one_se")}
    for kind, r in results.items():
        nom = r["test"].nominal
        for rule, x in r["rules"].items():
            v = x["validation"]
            lo, hi = v.ci95.get("f1", (None, None))
            optimism[rule].append((kind, x["set"].f1, v.f1_out_of_sample, x["test"].f1))
            lines.append(f"| {kind} | {_set_ci(nom, 'f1')} | `{rule}` | {_params(x['set'])} | {_f(x['set'].f1)} | "
                         f"{_fci(v.f1_out_of_sample, (lo, hi))} | {_fci(x['test'].f1, x['ci']['f1'])} | "
                         f"{_verdict(x['d'], x['d_ci'], same_set(x['set'], r['train'].nominal))} |")
    lines += [""]
    for rule, rows in optimism.items():
        ok = [(a, b, c) for _, a, b, c in rows if a is not None and c is not None]
        mean_in = sum(a for a, _, _ in ok) / len(ok)
        mean_test = sum(c for _, _, c in ok) / len(ok)
        cv = [(b, c) for _, _, b, c in rows if b is not None and c is not None]
        mean_cv = sum(b for b, _ in cv) / len(cv) if cv else float("nan")
        lines.append(f"- `{rule}`: mean over the six kinds of the tuned set's F1 — in sample {mean_in:.3f}, "
                     f"cross-validated on the training logs {mean_cv:.3f}, on the test logs {mean_test:.3f} "
                     f"(optimism in sample − test {mean_in - mean_test:+.3f}; cross-validated − test "
                     f"{mean_cv - mean_test:+.3f}).")
    lines += ["", f"The sweep's default rule is `{RULE}` (`studies/validate.py`; `docs/studies.md`, \"Out of sample\").",
              ""]
    d = {k: r["rules"][RULE] for k, r in results.items()}
    gap = {k: abs(x["validation"].f1_out_of_sample - x["test"].f1) for k, x in d.items()
           if x["validation"].f1_out_of_sample is not None and x["test"].f1 is not None}
    beat = [k for k, x in d.items() if x["d_ci"][0] > 0]
    lost = [k for k, x in d.items() if x["d_ci"][1] < 0]
    sign = [k for k, x in d.items() if x["d"] > 0]
    lines += [f"Reading: tuned on {n_frames} frames and scored on {n_frames} others, the tuned set beats the nominal "
              f"one beyond the interval of the paired difference on {len(beat)} of {len(d)} kinds"
              + (f" ({', '.join(beat)})" if beat else "") + f", loses on {len(lost)}"
              + (f" ({', '.join(lost)})" if lost else "") + f"; its F1 is higher on {len(sign)} of {len(d)} kinds ("
              + ", ".join(f"{k} {d[k]['d']:+.3f}" for k in d) + "). The sweep's cross-validated estimate on the "
              f"training logs lay within {max(gap.values()):.3f} of the test F1 on every kind (mean "
              f"{sum(gap.values()) / len(gap):.3f}). More frames, not a finer grid, are what would settle the gains: "
              "the sweep prints how many.", ""]

    # the paper's sensitivity findings, at the nominal point on the test frames; the tuned columns are
    # the training-tuned sets (the default rule) read on the test frames
    tables = {}
    for kind, r in results.items():
        t = r["test"]
        tuned = dataclasses.replace(t.tuned, zcut=r["rules"][RULE]["test"], sor=r["sor_test"])
        tables[kind] = dataclasses.replace(t, tuned=tuned)
    lines += ["## 3. The paper's sensitivity findings, on the test frames", "",
              f"At the nominal point; \"tuned\" is the set tuned on the training logs (rule `{RULE}`) and its F1 on "
              "the test frames; \"SOR tuned\" likewise.", "", findings_table(tables), ""]
    lines += findings(results)
    lines += ["## 5. What the generator could bias", "",
              "- *Floating clusters*: their size range (0.002–0.15 a_max), the share attached to the surface below, "
              "their texture and depth spread set how many the z-cut can see (it needs a gap ≥ Δd all around) and "
              "how many SOR can (it needs sparse neighbourhoods). Both filters' recall of this kind moves with them.",
              "- *Flying pixels* sit between two surfaces at depth edges: the z-cut cannot separate them by design "
              "(no gap), so its recall there is ~0 whatever the parameters; their number per edge pixel sets how "
              "much SOR's recall is worth.",
              "- *Figure 11 slivers*: calibrated to the paper's 2 false components per frame (§5.4); a higher rate "
              "would favour larger μ_thr in the tuning.",
              "- *Sensor noise* (smoothed, 1.5 px) decides the false positives of small Δd (Fig. 20); real Zivid "
              "noise on shiny parts may be rougher.",
              f"- *Resolution*: {args.size}{_scale(args.size)}; a_max and the part sizes in pixels scale with it.",
              f"- *Few frames per kind* ({n_frames} for tuning, {n_frames} for scoring): a finding inside the "
              "intervals is not settled; the intervals say how far from settled.",
              ""]
    return "\n".join(lines)


def findings(results: dict) -> list[str]:
    """The paper's Figs. 14-21 findings, each checked per kind on the test frames."""
    from studies.findings import findings as sweep_findings
    from studies.setgrid import SetGrid, same_set
    from studies.validate import RULE

    def verdict(ok: list[bool]) -> str:
        return "holds" if all(ok) else ("does not hold" if not any(ok) else f"holds on {sum(ok)} of {len(ok)} kinds")

    def beyond(a, b) -> str | None:
        """"higher"/"lower" when a's interval lies above/below b's, None when they overlap or are unknown."""
        (alo, ahi), (blo, bhi) = a.ci("f1"), b.ci("f1")
        if None in (alo, ahi, blo, bhi):
            return None
        return "higher" if alo > bhi else "lower" if ahi < blo else None

    out = ["## 4. The paper's findings (Figs. 14–21), checked on the test frames", ""]
    nom = {k: r["test"].nominal for k, r in results.items()}
    sor = {k: r["test"].chosen_sor for k, r in results.items()}
    a = {k: _alpha(nom[k])[0] for k in results}
    ok = [a[k] is not None and a[k] < 1.0 for k in SHINY]
    out.append(f"- **Fig. 15, shiny parts (a, b, c, f): α small, the z-cut finds most of what either finds** — "
               f"{verdict(ok)}: α = " + ", ".join(f"{k} {_f(a[k], 2)}" for k in SHINY) + ".")
    ok = [a[k] is not None and a[k] > 1.0 for k in MATTE]
    out.append(f"- **Fig. 15, matte parts (d, e): α and β_zcut large** — {verdict(ok)}: α = "
               + ", ".join(f"{k} {_f(a[k], 1)}" for k in MATTE) + "; SOR's extra outliers there are mostly false "
               "positives (§6, Fig. 21): SOR precision " + ", ".join(f"{k} {_set_ci(sor[k], 'precision')}"
                                                                       for k in MATTE) + ".")
    ok = [(nom[k].recall or 0) > (sor[k].recall or 0) if sor[k] is not None else False for k in SHINY]
    out.append(f"- **Figs. 13–14: on shiny parts the z-cut finds outliers SOR misses** — {verdict(ok)} by true "
               "recall (z-cut / SOR): " + ", ".join(f"{k} {_f(nom[k].recall, 2)} / {_f(sor[k].recall if sor[k] else None, 2)}"
                                                   for k in SHINY)
               + f". At the nominal parameters the z-cut's recall is at most {max(nom[k].recall or 0 for k in nom):.2f} "
               "on any kind: flying pixels (no gap to the surface) and ghosts attached to the surface below are "
               "invisible to it by design.")

    def cp(r, m):
        vals = [x["pooled"][m].get("cluster_precision") for x in r["acc"]]
        vals = [v for v in vals if v is not None]
        return f"{min(vals):.2f}–{max(vals):.2f}" if vals else "—"

    out.append("- **Fig. 14: the z-cut's outliers come in large connected clusters, SOR's as isolated pixels** — "
               "cluster precision (≥ 2 px; range over the test logs) z-cut / SOR: "
               + ", ".join(f"{k} {cp(r, 'zcut')} / {cp(r, 'sor')}" for k, r in results.items()) + ".")
    found = {k: sweep_findings(SetGrid.of(r["test"])) for k, r in results.items()}
    for start, claim in (("larger d_max", "Figs. 16–17: a larger d_max flags more outliers"),
                         ("smaller d_max", "Figs. 16–17: a smaller d_max leaves outliers"),
                         ("smaller ρ_thr", "Figs. 18–19: a smaller ρ_thr misses outliers"),
                         ("larger ρ_thr", "Fig. 18: a larger ρ_thr flags more, at the risk of false positives"),
                         ("smaller Δd", "Fig. 20: a smaller Δd flags more (and, too small, false) outliers")):
        hits = {k: f for k in found for f in found[k] if f.claim.startswith(start)}
        okc = [f.count_as_paper for f in hits.values()]
        better = [k for k, f in hits.items() if f.f1 == "higher"]
        worse = [k for k, f in hits.items() if f.f1 == "lower"]
        f1 = []
        if better:
            f1.append(f"rises beyond the intervals on {', '.join(better)}")
        if worse:
            f1.append(f"falls beyond them on {', '.join(worse)}")
        out.append(f"- **{claim}** — the counts: {verdict([bool(x) for x in okc]) if okc else 'not in the grid'}; "
                   "scored by true accuracy, F1 " + ("; ".join(f1) if f1 else "stays within the intervals") + ".")
    parts = []
    for k, r in results.items():
        x = r["rules"][RULE]
        z = x["set"]
        if same_set(z, r["train"].nominal):
            parts.append(f"{k} 30 (nominal kept)")
            continue
        lo, hi = x["d_ci"]
        word = "better than" if lo > 0 else "worse than" if hi < 0 else "indistinguishable from"
        parts.append(f"{k} {z.max_depth_mm:g} ({word} nominal on the test frames, F1 {x['d']:+.3f})")
    other = {k: r["rules"]["best" if RULE != "best" else "one_se"]["set"].max_depth_mm for k, r in results.items()}
    out.append("- **The nominal d_max (30 mm) for every dataset** — tuned on the training logs (rule "
               f"`{RULE}`), d_max is " + "; ".join(parts) + " mm. The other rule's d_max: "
               + ", ".join(f"{k} {v:g}" for k, v in other.items()) + " mm.")
    out.append("")
    return out


if __name__ == "__main__":
    sys.exit(main())
