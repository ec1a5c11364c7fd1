"""The paper's sensitivity findings, checked against a sweep's true counts around the chosen point.

The paper judged its parameters by the number of outliers flagged (it had no truth): a larger d_max
and a smaller Δd flag more, a smaller ρ_thr misses some, a larger one risks false positives. Each
:class:`Finding` compares the chosen z-cut set with one changed parameter (0.5× or 1.5× d_max or
ρ_thr, the grid's largest Δd below the chosen one): did the flagged count move as the paper says,
were the pixels gained or lost true outliers or not, and did F1 move beyond the 95 % intervals.
:func:`findings_table` puts several sweeps (one per part kind) side by side in Markdown.

Pure functions of the typed summary (:class:`studies.summary.SweepSummary`, or ``summary.json``'s
object): no plotting, no HTML, no files.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from studies.setgrid import SetGrid, key
from studies.summary import ParamSet, SweepSummary


@dataclass(frozen=True, slots=True)
class Finding:
    """One of the paper's findings checked at the chosen point.

    Attributes
    ----------
    claim, figure : str
        The paper's words and where it shows them.
    parameter : str
        The changed parameter's column (``max_depth_mm``, ``rho_thr``, ``max_area_px``, ``step_mm``).
    base, changed : ParamSet
        The chosen set and the set with the changed parameter.
    count_as_paper : bool or None
        The flagged count moved as the paper says (None: it did not change).
    d_tp, d_fp : int
        Changes of TP and FP in the scored region.
    f1 : str or None
        ``"higher"``, ``"lower"``, ``"within the intervals"``, or None when F1 is undefined.
    """

    claim: str
    figure: str
    parameter: str
    base: ParamSet
    changed: ParamSet
    count_as_paper: bool | None
    d_tp: int
    d_fp: int
    f1: str | None

    def to_json(self) -> dict[str, Any]:
        return {"claim": self.claim, "figure": self.figure, "parameter": self.parameter, "base": self.base.to_json(),
                "changed": self.changed.to_json(), "count_as_paper": self.count_as_paper, "d_tp": self.d_tp,
                "d_fp": self.d_fp, "f1": self.f1}


def _bound(v: float | None) -> float:
    return math.nan if v is None else v


def _finding(claim: str, figure: str, parameter: str, base: ParamSet, other: ParamSet, sign: int) -> Finding:
    dn = other.n_pred - base.n_pred
    f1 = None
    if base.f1 is not None and other.f1 is not None:
        (blo, bhi), (olo, ohi) = (tuple(map(_bound, base.ci("f1"))), tuple(map(_bound, other.ci("f1"))))
        if math.isfinite(olo) and math.isfinite(bhi) and olo > bhi:
            f1 = "higher"
        elif math.isfinite(ohi) and math.isfinite(blo) and ohi < blo:
            f1 = "lower"
        else:
            f1 = "within the intervals"
    return Finding(claim, figure, parameter, base, other, None if dn == 0 else (dn * sign > 0),
                   other.tp - base.tp, other.fp - base.fp, f1)


def findings(grid: SetGrid) -> list[Finding]:
    """Every finding the sweep's grid can check (see the module docstring), in a fixed order: larger
    and smaller d_max, smaller and larger ρ_thr (μ_thr when a_max was unknown), smaller Δd."""
    ch = grid.chosen
    base = grid.find("zcut", **grid.chosen_at("zcut"))
    if base is None:
        return []
    out = []
    claims = [("max_depth_mm", 1.5, "larger d_max flags more outliers", "Figs. 16b, 17b", +1),
              ("max_depth_mm", 0.5, "smaller d_max flags fewer outliers (some are left)", "Figs. 16a, 17a", -1),
              (grid.area, 0.5, "smaller ρ_thr misses outliers", "Figs. 18a, 19", -1),
              (grid.area, 1.5, "larger ρ_thr flags more, at the risk of false positives", "Fig. 18b, §5.4", +1)]
    for name, factor, claim, fig, sign in claims:
        if ch.get(name) is None:
            continue
        other = grid.find("zcut", **{**grid.chosen_at("zcut"), name: factor * ch[name]})
        if other is not None:
            out.append(_finding(claim, fig, name, base, other, sign))
    chosen_step = key(ch.get("step_mm"))
    steps = [s for s in grid.values("zcut", "step_mm") if chosen_step is not None and s < chosen_step]
    if steps:
        other = grid.find("zcut", **{**grid.chosen_at("zcut"), "step_mm": steps[-1]})
        if other is not None:
            out.append(_finding("smaller Δd flags more outliers", "Fig. 20", "step_mm", base, other, +1))
    return out


def paper_findings(summary: SweepSummary | Mapping[str, Any]) -> list[dict[str, Any]]:
    """:func:`findings` of a sweep's summary, as JSON objects (``base`` and ``changed`` as the sets'
    ``summary.json`` objects).

    Parameters
    ----------
    summary : SweepSummary or dict
        The sweep's summary (a dict: ``summary.json``'s object).

    Returns
    -------
    list of dict
        One per finding the grid can check: ``claim``, ``figure``, ``parameter``, ``base``,
        ``changed``, ``count_as_paper`` (True, False, or None when the count did not change), ``d_tp``,
        ``d_fp``, ``f1`` ("higher", "lower", "within the intervals" or None when undefined).
    """
    return [f.to_json() for f in findings(SetGrid.of(summary))]


_FINDING_COLUMNS = (("max_depth_mm", 1.5, "larger d_max"), ("max_depth_mm", 0.5, "smaller d_max"),
                    ("step_mm", None, "smaller Δd"), ("rho_thr", 0.5, "smaller ρ_thr"), ("rho_thr", 1.5, "larger ρ_thr"))


#: Short names and units of the parameter columns, as the report and the plots write them.
SHORT = {"step_mm": "Δd", "max_depth_mm": "d_max", "rho_thr": "ρ_thr", "max_area_px": "μ_thr", "sor_k": "k",
         "sor_std_ratio": "std_ratio"}
UNITS = {"step_mm": " mm", "max_depth_mm": " mm", "rho_thr": "", "max_area_px": " px", "sor_k": "",
         "sor_std_ratio": ""}


def param_text(v: Any, name: str = "") -> str:
    """A value of parameter column ``name`` with its unit (``0.2 mm``; ``—`` when absent)."""
    return fmt_param(v, UNITS.get(name, ""))


def fmt_param(v: Any, unit: str = "") -> str:
    """A parameter value as the report writes it (``—`` when absent; 4 significant digits)."""
    if v is None:
        return "—"
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    return f"{float(v):.4g}{unit}"


def fmt_num(v: Any, digits: int = 3) -> str:
    """A figure with ``digits`` decimals (``—`` when undefined)."""
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{float(v):.{digits}f}"


def _f1_text(e: ParamSet | None) -> str:
    if e is None or e.f1 is None:
        return "—"
    lo, hi = e.ci("f1")
    return f"{e.f1:.3f} [{fmt_num(lo)}, {fmt_num(hi)}]"


def _cell(found: list[Finding], name: str, factor: float | None) -> str:
    for f in found:
        if f.parameter != name and not (name == "rho_thr" and f.parameter == "max_area_px"):
            continue
        b, c = key(f.base.param(f.parameter)), key(f.changed.param(f.parameter))
        if factor is None or (b and c is not None and abs(c / b - factor) < 1e-6):
            count = {True: "✓", False: "✗", None: "="}[f.count_as_paper]
            return count + " " + {"higher": "F1↑", "lower": "F1↓", "within the intervals": "F1≈"}.get(f.f1 or "", "")
    return "—"


def findings_table(summaries: Mapping[str, SweepSummary | Mapping[str, Any]]) -> str:
    """A Markdown table over several sweeps (e.g. one per part kind): the paper's nominal set against
    the tuned one (F1 with 95 % intervals) and whether each of the paper's findings holds.

    Parameters
    ----------
    summaries : dict of str to SweepSummary or dict
        A row name (e.g. the part kind) -> that sweep's summary.

    Returns
    -------
    str
        The table and a line explaining its cells: ``✓``/``✗`` the count moved as the paper says or
        not (``=`` unchanged), then F1 ``↑``/``↓`` beyond the 95 % intervals or ``≈`` within them.
    """
    head = ["", "nominal F1", "tuned Δd / d_max / ρ_thr", "tuned F1", "SOR tuned F1"] + [c for *_, c in _FINDING_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, summary in summaries.items():
        grid = SetGrid.of(summary)
        s = grid.summary
        tz = s.tuned.zcut
        params = (f"{fmt_param(tz.step_mm)} / {fmt_param(tz.max_depth_mm)} / "
                  f"{fmt_param(tz.rho_thr if tz.rho_thr is not None else tz.max_area_px)}" if tz else "—")
        cells = [name, _f1_text(s.nominal), params, _f1_text(tz), _f1_text(s.tuned.sor)]
        found = findings(grid)
        cells += [_cell(found, col, factor) for col, factor, _ in _FINDING_COLUMNS]
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    lines.append("")
    lines.append("Findings at each sweep's chosen point: ✓/✗ the number flagged moved as the paper says or not "
                 "(= unchanged); F1↑/F1↓ beyond the 95 % intervals, F1≈ within them; — not in the grid.")
    return "\n".join(lines) + "\n"
