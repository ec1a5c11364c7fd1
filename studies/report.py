"""The report page of ``zcut sweep``: ``DIR/report.html``, one self-contained HTML page, and the plots.

:func:`write_report` turns the sweep's summary into ``DIR/plots/*.png`` (:mod:`studies.plots`) and
``DIR/report.html``: what was swept, the best sets, the plots, the paper's findings checked with the
truth (:mod:`studies.findings`), the sensitivity ratios, the tuned and resolved configs, the notes
and the commands that reproduce it. The page embeds the same PNG bytes as base64 data URIs, has its
CSS inline and makes no request of its own.

The page is the Jinja2 template ``studies/templates/report.html`` with autoescaping on: every value
this module hands it (log names, notes, config text, commands) is escaped; the only markup is the
template's own. This module computes what the page shows, as plain values per section
(:func:`page_context`).
"""

from __future__ import annotations

import base64
import math
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from studies.findings import Finding, findings, fmt_num, param_text
from studies.plots import BANK_PLOT_NAMES, PLOT_NAMES, Plot, make_plots
from studies.setgrid import SetGrid, as_summary, same_set
from studies.setgrid import key as _key
from studies.summary import ParamSet, Sensitivities, SweepSummary, truth_text

__all__ = ["PLOTS_DIR", "PLOT_NAMES", "REPORT_NAME", "page_context", "render_html", "write_report"]

PLOTS_DIR = "plots"
REPORT_NAME = "report.html"
TOP_N = 10

SECTIONS = (("swept", "What was swept"), ("best", "Best parameter sets"),
            ("ranking", "The filter bank: each filter tuned, ranked"), ("plots", "Plots"),
            ("findings", "The paper's findings, scored by true accuracy"),
            ("sensitivity", "Sensitivity ratios θ and ω"), ("config", "Tuned and resolved config"),
            ("notes", "Notes and warnings"), ("reproduce", "How to reproduce"))
_REGIONS = {"zone": "zone: the pixels the filters judge (valid pixels minus table and bin, plus the above-the-rim "
                    "points)", "valid": "valid: every valid pixel"}
#: the lead's words for a truth ("scored against {them} truth")
_LEAD_TRUTHS = {"paper": "the paper's", "sensor": "the sensor's", "paper, sensor": "the paper's (else the sensor's)"}
_AXES = ("step_mm", "max_depth_mm", "rho_thr", "sor_k", "sor_std_ratio")


# ------------------------------------------------------------------------------------------ numbers
def _int(v: float | None) -> str:
    return "—" if v is None else f"{int(v):,}".replace(",", "\u2009")


def _ci_text(e: ParamSet) -> str:
    lo, hi = e.ci("f1")
    return f"[{fmt_num(lo)}, {fmt_num(hi)}]" if lo is not None and hi is not None else ""


def _metric(e: ParamSet, m: str) -> dict[str, str]:
    lo, hi = e.ci(m)
    return {"value": fmt_num(e.figure(m)), "ci": f"{fmt_num(lo)}–{fmt_num(hi)}" if lo is not None and hi is not None
            else ""}


def _set_params(e: ParamSet) -> str:
    if e.method == "zcut":
        area = (f"ρ_thr {param_text(e.rho_thr)}" if e.rho_thr is not None
                else f"μ_thr {param_text(e.max_area_px, 'max_area_px')}")
        return f"Δd {param_text(e.step_mm, 'step_mm')}, d_max {param_text(e.max_depth_mm, 'max_depth_mm')}, {area}"
    s = f"k {e.sor_k}, std_ratio {param_text(e.sor_std_ratio)}"
    if e.step_mm is not None:
        s += f" (top {param_text(e.max_depth_mm, 'max_depth_mm')})"
    return s


def _ratio_text(v: float | None, n_lo: float | None, n_mid: float | None) -> str:
    if v is not None:
        return f"{float(v):.3f}"
    if n_mid == 0 and n_lo is not None:
        return "∞" if n_lo > 0 else "0/0"
    return "—"


def _inside_ranges(e: ParamSet, ranges: dict[str, tuple[float, float]] | None) -> bool | None:
    if e.method != "zcut" or not ranges:
        return None
    for k, (lo, hi) in ranges.items():
        v = e.param(k)
        if v is None:
            return False
        if not (lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9)):
            return False
    return True


# ------------------------------------------------------------------------------------------ sections
def _lead(g: SetGrid) -> dict[str, Any]:
    s = g.summary
    tuned, nominal = s.tuned.zcut, s.nominal
    return {"logs": len(s.logs), "frames": s.frames, "truth": _LEAD_TRUTHS.get(s.truth, s.truth), "region": s.region, "n_zcut": len(g.zsets),
            "n_sor": len(g.ssets),
            "tuned_f1": f"{fmt_num(tuned.f1)} {_ci_text(tuned)}" if tuned is not None else None,
            "nominal_f1": f"{fmt_num(nominal.f1)} {_ci_text(nominal)}" if nominal is not None else None}


def _swept(g: SetGrid) -> dict[str, Any]:
    s = g.summary
    grid = s.grid.as_dict() if s.grid is not None else {}
    chosen = grid.get("chosen") or {}
    ranges = g.ranges or {}
    axes = []
    for k in _AXES:
        values = grid.get(k) or []
        c = _key(chosen.get(k))
        r = ranges.get(k)
        axes.append({"key": k, "n": len(values), "cells": [(param_text(v), _key(v) == c) for v in values],
                     "chosen": param_text(chosen.get(k)),
                     "range": "—" if not r else f"{param_text(r[0])} … {param_text(r[1])}"})
    return {"frames": s.frames, "truth": truth_text(s.truth), "region": _REGIONS.get(s.region, s.region),
            "objective": s.objective, "n_zcut": len(g.zsets), "n_sor": len(g.ssets), "sor_enabled": g.sor_enabled,
            "seconds": round(float(s.seconds), 1) if s.seconds is not None else None,
            "a_max": f"{g.a_max:.1f}" if g.a_max is not None else None,
            "logs": [{"log": lg.log, "sha256": str(lg.sha256 or "")[:12],
                      "status": lg.error or ("ok" if lg.truth is None or lg.truth == s.truth
                                             else f"ok; scored against {truth_text(lg.truth)}")} for lg in s.logs],
            "axes": axes, "study_points": bool(grid.get("study_points", True))}


def _objective(s: SweepSummary) -> tuple[str, float | None]:
    from replay.errors import ConfigError
    from studies.scoring import parse_objective

    try:
        return parse_objective(s.objective)
    except (ConfigError, ValueError):
        return ("f1", None)


def _best(g: SetGrid) -> dict[str, Any]:
    from studies.scoring import score

    s = g.summary
    objective = _objective(s)
    sets = g.zsets + g.ssets
    scored = sorted(((score(e, objective), i, e) for i, e in enumerate(sets)), key=lambda t: (-t[0], t[1]))
    position = {i: pos for pos, (_, i, _) in enumerate(scored)}
    rank: dict[int, int] = {}
    for pos, (value, i, _) in enumerate(scored):
        prev = scored[pos - 1] if pos else None
        rank[i] = rank[prev[1]] if prev is not None and prev[0] == value else pos + 1
    roles = [("tuned", s.tuned.zcut), ("nominal", s.nominal), ("chosen", s.chosen_zcut), ("SOR tuned", s.tuned.sor),
             ("SOR chosen", s.chosen_sor)]
    keep = [i for _, i, _ in scored[:TOP_N]]
    keep += [i for _, i, e in scored if e.method == "sor"][:3]
    tags: dict[int, list[str]] = {}
    for role, r in roles:
        for i, e in enumerate(sets):
            if same_set(e, r):
                tags.setdefault(i, []).append(role)
                keep.append(i)
                break
    rows = []
    for i in sorted(set(keep), key=lambda i: position[i]):
        e = sets[i]
        zc = e.method == "zcut"
        mu = e.max_area_px
        if mu is None and e.rho_thr is not None and g.a_max is not None:
            mu = e.rho_thr * g.a_max
        inside = _inside_ranges(e, g.ranges)
        rows.append({"rank": rank[i] if math.isfinite(scored[position[i]][0]) else "—", "tags": tags.get(i, []),
                     "method": "z-cut" if zc else "SOR", "step": param_text(e.step_mm),
                     "depth": param_text(e.max_depth_mm), "rho": param_text(e.rho_thr) if zc else "—",
                     "mu": fmt_num(mu, 1) if zc else "—", "k": e.sor_k if e.sor_k is not None else "—",
                     "std": param_text(e.sor_std_ratio), "tp": _int(e.tp), "fp": _int(e.fp), "fn": _int(e.fn),
                     "n_pred": _int(e.n_pred), "precision": _metric(e, "precision"), "recall": _metric(e, "recall"),
                     "f1": _metric(e, "f1"), "inside": "" if inside is None else ("✓" if inside else "✗")})

    def tuned_item(name: str, e: ParamSet | None) -> dict[str, Any]:
        if e is None:
            return {"name": name, "params": None}
        return {"name": name, "params": _set_params(e), "precision": fmt_num(e.precision), "recall": fmt_num(e.recall),
                "f1": fmt_num(e.f1), "ci": _ci_text(e)}

    nominal = s.nominal
    return {"rows": rows, "top_n": TOP_N, "n_sets": len(sets), "n_zcut": len(g.zsets), "n_sor": len(g.ssets),
            "objective": s.objective or "f1",
            "tuned": [tuned_item("z-cut", s.tuned.zcut), tuned_item("SOR", s.tuned.sor)],
            "nominal": None if nominal is None else {"params": _set_params(nominal), "f1": fmt_num(nominal.f1),
                                                     "ci": _ci_text(nominal)},
            "note": s.tuned.note}


def _validation(s: SweepSummary) -> dict[str, Any]:
    """The tuning cross-validated (studies.validate): figures in and out of sample, the folds, the
    sentences the command prints."""
    from studies.validate import params_text

    v, t = s.validation, s.tuned.zcut
    if v is None:
        return {"folds": [], "messages": [], "rule": "", "split": ""}
    oos = {}
    for m in ("precision", "recall", "f1"):
        lo, hi = v.ci95.get(m, (None, None))
        oos[m] = {"value": fmt_num(v.out_of_sample.get(m)),
                  "ci": f"{fmt_num(lo)}–{fmt_num(hi)}" if lo is not None and hi is not None else ""}
    split = {"logs": "one fold per log (or group of logs)", "frames": "blocks of consecutive frames of one log"}
    return {"rule": v.rule, "split": split.get(v.split, v.split), "oos": oos,
            "in_sample": {m: fmt_num(t.figure(m) if t is not None else None) for m in ("precision", "recall", "f1")},
            "optimism": fmt_num(v.optimism),
            "folds": [{"logs": ", ".join(f.logs), "frames": f.frames,
                       "chosen": params_text(f.chosen) if f.chosen is not None else "—", "f1": fmt_num(f.f1)}
                      for f in v.folds],
            "messages": v.messages()}


def _plots(plots: list[Plot]) -> list[dict[str, Any]]:
    return [{"id": p.name.removesuffix(".png"), "title": p.title, "caption": p.caption, "width_px": p.width_px,
             "base64": base64.b64encode(p.png).decode("ascii"), "path": f"{PLOTS_DIR}/{p.name}"} for p in plots]


def _finding_row(f: Finding) -> dict[str, Any]:
    b, c, k = f.base, f.changed, f.parameter
    return {"claim": f.claim, "figure": f.figure, "param": (param_text(b.param(k), k), param_text(c.param(k), k)),
            "n_pred": (_int(b.n_pred), _int(c.n_pred)), "as_paper": f.count_as_paper, "d_tp": f"{f.d_tp:+d}",
            "d_fp": f"{f.d_fp:+d}", "precision": (fmt_num(b.precision), fmt_num(c.precision)),
            "recall": (fmt_num(b.recall), fmt_num(c.recall)), "f1": (fmt_num(b.f1), fmt_num(c.f1)),
            "f1_ci": (_ci_text(b), _ci_text(c)), "f1_moved": f.f1}


def _sensitivity_block(g: SetGrid, name: str, e: ParamSet | None, s: Sensitivities | None) -> dict[str, Any]:
    if e is None:
        return {"name": name, "params": None}
    rows, missing = [], []
    if s:
        for ratio, column in (("θ", g.area), ("ω", "max_depth_mm")):
            fixed = {k: e.param(k) for k in g.zparams}
            v0 = e.param(column)
            lo = g.find("zcut", **{**fixed, column: 0.5 * v0}) if v0 is not None else None
            hi = g.find("zcut", **{**fixed, column: 1.5 * v0}) if v0 is not None else None
            for n, who in ((1, "SOR only"), (2, "z-cut only")):
                pair = s.get(f"{'theta' if ratio == 'θ' else 'omega'}_{n}")
                if pair is None:
                    continue
                ns = [x.figure(f"n{n}") if x is not None else None for x in (lo, e, hi)]
                rows.append({"ratio": ratio, "n": n, "who": who, "counts": " / ".join(_int(x) for x in ns),
                             "lo": _ratio_text(pair.lo, ns[0], ns[1]), "hi": _ratio_text(pair.hi, ns[2], ns[1])})
        missing = [r for r, k in (("θ", "theta_2"), ("ω", "omega_2")) if k not in s]
    return {"name": name, "params": _set_params(e), "rows": rows, "missing": missing}


def _config(s: SweepSummary, tuned_toml: str | None) -> dict[str, Any]:
    known = {line.strip() for line in s.config.splitlines()}
    lines = None
    if tuned_toml is not None:
        lines = [(line, bool(t) and not t.startswith("#") and t not in known)
                 for line in tuned_toml.splitlines() for t in (line.strip(),)]
    return {"tuned_lines": lines, "resolved": s.config or "(none)",
            "why": "" if s.tuned.zcut else " (no z-cut set met the objective)"}


def _notes(s: SweepSummary, limit: int = 50) -> dict[str, Any]:
    bad = [("Damage (frames lost: exit status 3)", [str(d) for d in s.damage]),
           ("Errors (logs or units that failed)", list(s.errors)),
           ("Unscored frames (no truth for them)", [str(u) for u in s.unscored]),
           ("Frames flagged by the bin check (their scores rest on a bin removal that did not work)",
            [str(f) for f in s.bin_flagged])]
    return {"resolved": list(s.notes),
            "bad": [(title, xs[:limit], max(0, len(xs) - limit)) for title, xs in bad if xs]}


def _reproduce(s: SweepSummary, out_dir: Path | None) -> dict[str, str]:
    tuned = str(out_dir / "tuned.toml") if out_dir is not None else "DIR/tuned.toml"
    logs = [lg.log for lg in s.logs if lg.log]
    replays = "\n".join(f"zcut replay {shlex.quote(str(lg))} --config {shlex.quote(tuned)}" for lg in logs[:5])
    if len(logs) > 5:
        replays += f"\n# … and {len(logs) - 5} more logs"
    return {"sweep": s.reproduce or "(unknown)", "replays": replays or f"zcut replay LOG.mcap --config {tuned}",
            "compare": _compare_command(s, logs, tuned, out_dir)}


def _compare_command(s: SweepSummary, logs: list[str], tuned: str, out_dir: Path | None) -> str:
    """``zcut compare`` of the sweep's own config (A: its ``--config``, else the logs' defaults, ``zcut``)
    against ``tuned.toml`` (B) on the same logs, truth and region: the paired verdict per frame."""
    given: dict[str, str] = {}
    try:
        words = shlex.split(s.reproduce or "")
    except ValueError:  # pragma: no cover - reproduce is written with shlex.quote
        words = []
    for flag in ("--config", "--bin-model", "--topic", "--labels", "--annotator"):
        if flag in words[:-1]:
            given[flag] = words[words.index(flag) + 1]
    a = given.pop("--config", "zcut")
    parts = ["zcut", "compare", *(logs or ["LOG.mcap"]), "--a", a, "--b", tuned,
             "-o", str(out_dir / "compare") if out_dir is not None else "DIR/compare"]
    for flag, v in given.items():
        parts += [flag, v]
    if s.region and s.region != "zone":
        parts += ["--region", s.region]
    if s.truth in ("paper", "sensor") and "--labels" not in given:
        parts += ["--truth", s.truth]
    return " ".join(shlex.quote(str(p)) for p in parts)


def _num(v: Any, fmt: str = ".3f") -> str:
    return "—" if v is None else format(v, fmt)


def _ranking(s: SweepSummary) -> dict[str, Any]:
    """The filter bank's ranking per part kind (``summary.ranking``): one table per part."""
    r = s.ranking or {}
    kinds = r.get("kinds") or {}
    tables = []
    for part, rows in (r.get("by_part") or {}).items():
        codes = sorted({k for row in rows for k in (row.get("kind_recall") or {})}, key=int)
        out = []
        for i, row in enumerate(rows, 1):
            ci = row.get("ci95") or {}

            def cell(m: str, row: dict[str, Any] = row, ci: dict[str, Any] = ci) -> dict[str, str]:
                lo, hi = (list(ci.get(m) or []) + [None, None])[:2]
                return {"value": _num(row.get(m)),
                        "ci": "" if lo is None or hi is None else f"[{lo:.3f}, {hi:.3f}]"}

            params = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}"
                               for k, v in (row.get("params") or {}).items())
            secs = row.get("seconds")
            out.append({"rank": i, "method": row.get("method"), "params": params or "(the config's)",
                        "precision": cell("precision"), "recall": cell("recall"), "f1": cell("f1"),
                        "kinds": [_num((row.get("kind_recall") or {}).get(k)) for k in codes],
                        "ms": "—" if secs is None else f"{1000 * secs:.1f}", "frames": row.get("frames")})
        tables.append({"part": part, "kinds": [kinds.get(k, k) for k in codes], "rows": out})
    return {"tables": tables}


def page_context(summary: SweepSummary | Mapping[str, Any], plots: list[Plot], *, tuned_toml: str | None = None,
                 out_dir: Path | None = None) -> dict[str, Any]:
    """Everything the page shows, section by section, as plain values (strings, numbers, lists):
    what :func:`render_html` hands the template. Arguments as :func:`render_html`'s."""
    g = SetGrid.of(as_summary(summary))
    s = g.summary
    return {
        "sections": SECTIONS, "titles": dict(SECTIONS), "lead": _lead(g), "swept": _swept(g),
        "best": _best(g), "validation": _validation(s), "ranking": _ranking(s), "plots": _plots(plots),
        "findings": [_finding_row(f) for f in findings(g)],
        "sensitivity": [_sensitivity_block(g, "chosen", s.chosen_zcut, s.sensitivity_chosen),
                        _sensitivity_block(g, "tuned", s.tuned.zcut, s.sensitivity_tuned)],
        "config": _config(s, tuned_toml), "notes": _notes(s), "reproduce": _reproduce(s, out_dir),
    }


def render_html(summary: SweepSummary | Mapping[str, Any], plots: list[Plot], *, tuned_toml: str | None = None,
                out_dir: Path | None = None) -> str:
    """The report page: one self-contained HTML document (images as data URIs, CSS inline).

    Parameters
    ----------
    summary : SweepSummary or dict
        The sweep's summary (a dict: ``summary.json``'s object).
    plots : list of Plot
        From :func:`studies.plots.make_plots`.
    tuned_toml : str, optional
        The text of ``DIR/tuned.toml`` (None when none was written).
    out_dir : path, optional
        The sweep's folder (named in the commands that reproduce it).

    Returns
    -------
    str
        The page; every text taken from ``summary`` is escaped (the template autoescapes).
    """
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("studies", "templates"), autoescape=True,
                             trim_blocks=True, lstrip_blocks=True, undefined=jinja2.StrictUndefined)
    return env.get_template("report.html").render(page_context(summary, plots, tuned_toml=tuned_toml,
                                                               out_dir=out_dir))


# --------------------------------------------------------------------------------------- the files
def _write_bytes(path: Path, data: bytes) -> None:
    from replay.outputs import AtomicOutput

    with AtomicOutput(path) as out:
        out.temp.write_bytes(data)


def write_report(out_dir: Path, summary: SweepSummary | Mapping[str, Any]) -> Path:
    """Write ``out_dir/plots/*.png`` and ``out_dir/report.html`` for a sweep's summary.

    Parameters
    ----------
    out_dir : Path
        The sweep's output folder (exists; ``tuned.toml`` in it, when present, is shown on the page).
    summary : SweepSummary or dict
        The sweep's summary (a dict: as written to ``summary.json``).

    Returns
    -------
    Path
        ``out_dir / "report.html"``. Plots the grid cannot draw are not written (and removed when an
        earlier run left them).
    """
    out_dir = Path(out_dir)
    summary = as_summary(summary)
    plots = make_plots(summary)
    plot_dir = out_dir / PLOTS_DIR
    plot_dir.mkdir(exist_ok=True)
    for p in plots:
        _write_bytes(plot_dir / p.name, p.png)
    made = {p.name for p in plots}
    for name in PLOT_NAMES + BANK_PLOT_NAMES:
        stale = plot_dir / name
        if name not in made and stale.is_file():
            stale.unlink()
    tuned_path = out_dir / "tuned.toml"
    tuned_toml = tuned_path.read_text(encoding="utf-8") if tuned_path.is_file() else None
    page = render_html(summary, plots, tuned_toml=tuned_toml, out_dir=out_dir)
    path = out_dir / REPORT_NAME
    _write_bytes(path, page.encode("utf-8", errors="backslashreplace"))
    return path
