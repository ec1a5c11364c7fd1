"""The plots and the report page of ``zcut sweep`` (SPEC §6): PNG files and one self-contained HTML page.

:func:`write_report` turns the sweep's ``summary`` (the dict written as ``DIR/summary.json``) into
``DIR/plots/*.png`` and ``DIR/report.html``. The page embeds the same PNG bytes as base64 data URIs,
has its CSS inline and makes no request of its own; every text from the summary is escaped.

What is plotted (each plot is left out when the grid cannot draw it: one value on its axis, no SOR
sets, no defined value):

- ``counts_max_depth.png``, ``counts_rho.png``, ``counts_step.png`` — what the paper plots (Figs.
  16–20): the pixels each filter flags, summed over the frames, against d_max, ρ_thr and Δd (one
  z-cut line per value of the other parameter, SOR at its chosen k and std_ratio for reference), and
  the paper's N1 (SOR only), N2 (z-cut only), N_both whose ratios are θ and ω (SPEC §3).
- ``accuracy_zcut.png``, ``accuracy_sor.png`` — what the paper could not plot: precision, recall
  and F1 (SPEC §4) against each parameter with their 95 % interval bands, the other parameters held
  at the chosen point (the config's own), the paper's §5.4 range shaded.
- ``f1_map.png`` — F1 over every (d_max, ρ_thr) pair at the chosen Δd, chosen and tuned marked.
- ``precision_recall.png`` — every set on the precision–recall plane, the paper's nominal point, the
  chosen and tuned points and SOR's sets marked, iso-F1 curves; a zoomed panel when the sets crowd.
- ``ratios.png`` — the paper's α = N1/N2 and β_n = N_both/N_n (Fig. 15) against d_max and ρ_thr.

Matplotlib runs on its Agg canvas with explicit :class:`matplotlib.figure.Figure` objects (no
pyplot, no global figure state); the style is set in an ``rc_context`` that is restored after.

:func:`paper_findings` (also shown on the page) checks the paper's sensitivity findings (larger
d_max and smaller Δd flag more outliers, a smaller ρ_thr misses some, a larger one risks false
positives) against the true counts around the chosen point; a note over several sweeps (one per
part kind) can build its table from it.
"""

from __future__ import annotations

import base64
import html
import io
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PLOT_NAMES", "Plot", "findings_table", "make_plots", "paper_findings", "render_html", "write_report"]

#: Every plot file a report may write, in page order (those a grid cannot draw are not written,
#: and a stale one from an earlier run of the same folder is removed).
PLOT_NAMES = ("counts_max_depth.png", "counts_rho.png", "counts_step.png", "accuracy_zcut.png",
              "accuracy_sor.png", "f1_map.png", "precision_recall.png", "ratios.png")

PLOTS_DIR = "plots"
REPORT_NAME = "report.html"
TOP_N = 10
_DPI = 150            # PNG pixels per inch; the page shows 100 CSS px per inch (sharp on HiDPI screens)
_CSS_PX_PER_INCH = 100

# Okabe–Ito colours (readable with colour-blindness)
_METRIC_COLOURS = {"precision": "#0072B2", "recall": "#009E73", "f1": "#D55E00"}
_METRIC_NAMES = {"precision": "precision", "recall": "recall", "f1": "F1"}
_SOR_COLOUR = "#E69F00"
_ZCUT_COLOUR = "#0072B2"
_RC = {"font.size": 10, "axes.titlesize": 11, "axes.labelsize": 10, "xtick.labelsize": 9, "ytick.labelsize": 9,
       "legend.fontsize": 9, "axes.grid": True, "grid.alpha": 0.3, "grid.linewidth": 0.6,
       "axes.spines.top": False, "axes.spines.right": False, "figure.facecolor": "white",
       "savefig.facecolor": "white"}

_LABELS = {"step_mm": "Δd (mm)", "max_depth_mm": "$d_{max}$ (mm)", "rho_thr": r"$\rho_{thr}$ (= $\mu_{thr}$ / $a_{max}$)",
           "max_area_px": r"$\mu_{thr}$ (px)", "sor_k": "SOR k (neighbours)",
           "sor_std_ratio": "SOR std_ratio (multiples of σ)"}
_SHORT = {"step_mm": "Δd", "max_depth_mm": "d_max", "rho_thr": "ρ_thr", "max_area_px": "μ_thr", "sor_k": "k",
          "sor_std_ratio": "std_ratio"}
_UNITS = {"step_mm": " mm", "max_depth_mm": " mm", "rho_thr": "", "max_area_px": " px", "sor_k": "",
          "sor_std_ratio": ""}


# ------------------------------------------------------------------------------------------ the sets


def _key(v: Any) -> Any:
    """A parameter value as a lookup key (grid values like 0.10500000000000001 and 0.105 are one)."""
    return None if v is None else round(float(v), 9)


def _fmt_param(v: Any, key: str = "") -> str:
    if v is None:
        return "—"
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    return f"{float(v):.4g}{_UNITS.get(key, '')}"


@dataclass(frozen=True)
class _Sweep:
    """The summary seen as a grid: which parameters each method's sets vary, the chosen point, and a
    lookup of a set by its parameters."""

    summary: dict
    zsets: list[dict]
    ssets: list[dict]
    area: str                    # "rho_thr", or "max_area_px" when a_max was unknown
    zparams: tuple[str, ...]     # step, depth, area
    sparams: tuple[str, ...]     # k, std (and step, depth when SOR judges the top of the pile)
    chosen: dict[str, Any]       # every parameter at the config's own point
    a_max: float | None          # px, when one log (one a_max) was swept
    sor_enabled: bool
    config: dict
    index: dict[tuple, dict]     # (method, *its parameters as keys) -> the set

    @classmethod
    def of(cls, summary: dict) -> _Sweep:
        sets = [e for e in (summary.get("sets") or []) if isinstance(e, dict)]
        zsets = [e for e in sets if e.get("method") == "zcut"]
        ssets = [e for e in sets if e.get("method") == "sor"]
        area = "rho_thr" if any(e.get("rho_thr") is not None for e in zsets) or not zsets else "max_area_px"
        top = any(e.get("step_mm") is not None for e in ssets)
        try:
            config = tomllib.loads(summary.get("config") or "")
        except (tomllib.TOMLDecodeError, TypeError):
            config = {}
        grid_chosen = dict((summary.get("grid") or {}).get("chosen") or {})
        chosen_z = (summary.get("chosen") or {}).get("zcut") or {}
        chosen = {k: grid_chosen.get(k) for k in ("step_mm", "max_depth_mm", "rho_thr", "sor_k", "sor_std_ratio")}
        chosen["max_area_px"] = chosen_z.get("max_area_px")
        if area == "max_area_px" and chosen["max_area_px"] is None:
            areas = {_key(e.get("max_area_px")) for e in zsets}
            chosen["max_area_px"] = areas.pop() if len(areas) == 1 else None
        a_max = (config.get("zcut") or {}).get("a_max_px")
        if len(summary.get("logs") or []) != 1 or not isinstance(a_max, (int, float)):
            a_max = None
        sor_enabled = bool(ssets) and (config.get("sor") or {}).get("enabled", True) is not False
        zparams = ("step_mm", "max_depth_mm", area)
        sparams = ("sor_k", "sor_std_ratio") + (("step_mm", "max_depth_mm") if top else ())
        index: dict[tuple, dict] = {}
        for method, group, params in (("zcut", zsets, zparams), ("sor", ssets, sparams)):
            for e in group:
                index.setdefault((method, *(_key(e.get(k)) for k in params)), e)
        return cls(summary, zsets, ssets, area, zparams, sparams, chosen,
                   float(a_max) if a_max is not None else None, sor_enabled, config, index)

    def params(self, method: str) -> tuple[str, ...]:
        return self.zparams if method == "zcut" else self.sparams

    def values(self, method: str, key: str) -> list:
        sets = self.zsets if method == "zcut" else self.ssets
        vals = {_key(e.get(key)) for e in sets} - {None}
        return sorted(vals)

    def series(self, method: str, vary: str, fixed: dict[str, Any]) -> list[tuple[float, dict]]:
        """The sets of ``method`` along ``vary``, the other parameters at ``fixed`` (sorted by ``vary``)."""
        sets = self.zsets if method == "zcut" else self.ssets
        want = {k: _key(v) for k, v in fixed.items() if k in self.params(method) and k != vary}
        out = {}
        for e in sets:
            x = _key(e.get(vary))
            if x is None or any(_key(e.get(k)) != v for k, v in want.items()):
                continue
            out.setdefault(x, e)
        return sorted(out.items())

    def find(self, method: str, **params) -> dict | None:
        """The set of ``method`` with these parameters (the first match when some are not given)."""
        want = {k: _key(v) for k, v in params.items() if k in self.params(method)}
        if len(want) == len(self.params(method)):
            return self.index.get((method, *(want[k] for k in self.params(method))))
        sets = self.zsets if method == "zcut" else self.ssets
        for e in sets:
            if all(_key(e.get(k)) == v for k, v in want.items()):
                return e
        return None

    def chosen_sor_fixed(self) -> dict[str, Any]:
        return {k: self.chosen.get(k) for k in self.sparams}

    @property
    def ranges(self) -> dict | None:
        r = (self.summary.get("tuned") or {}).get("ranges")
        return r if isinstance(r, dict) else None


def _f(v: Any) -> float:
    """A JSON number as float (None -> NaN)."""
    return math.nan if v is None else float(v)


def _ci(e: dict, metric: str) -> tuple[float, float]:
    c = (e.get("ci95") or {}).get(metric) or (None, None)
    return _f(c[0]), _f(c[1])


def _same(a: dict | None, b: dict | None) -> bool:
    if a is None or b is None:
        return False
    keys = ("method", "step_mm", "max_depth_mm", "rho_thr", "max_area_px", "sor_k", "sor_std_ratio")
    return all(_key(a.get(k)) == _key(b.get(k)) if k != "method" else a.get(k) == b.get(k) for k in keys)


# ----------------------------------------------------------------------------------------- plotting


@dataclass(frozen=True, slots=True)
class Plot:
    """One PNG plot of the report.

    Attributes
    ----------
    name : str
        File name under ``DIR/plots`` (one of :data:`PLOT_NAMES`).
    title, caption : str
        Shown above and below it on the page (plain text).
    png : bytes
        The PNG file.
    width_px : int
        Its width on the page at 100 % zoom (CSS px; the PNG holds 1.5× as many pixels).
    """

    name: str
    title: str
    caption: str
    png: bytes
    width_px: int


def _figure(nrows: int, ncols: int, *, width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _subfigures(n: int, *, width_in: float, height_in: float):
    """A figure of ``n`` side-by-side subfigures (each with its own legend below it)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    subs = fig.subfigures(1, n, wspace=0.03, squeeze=False)[0]
    return fig, list(subs)


def _legend_below(sub, ax) -> None:
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        sub.legend(handles, labels, loc="outside lower center", ncols=2 if len(labels) > 3 else len(labels),
                   frameon=False)


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})
    return buf.getvalue()


def _plot(name: str, title: str, caption: str, fig) -> Plot:
    return Plot(name, title, caption, _png(fig), round(fig.get_figwidth() * _CSS_PX_PER_INCH))


def _count_scale(ax, values) -> None:
    """Counts spanning more than ~2 decades on a symmetric log axis (zeros stay visible)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    pos = v[v > 0]
    if pos.size and pos.max() / max(pos.min(), 1.0) > 100:
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylim(bottom=0)
    else:
        ax.set_ylim(bottom=0, top=max(1.0, float(v.max()) * 1.08 if v.size else 1.0))


def _pick(values: list, chosen: Any, n: int = 8) -> list:
    """At most ``n`` values for one line each: evenly spread, always with the chosen one."""
    if len(values) <= n:
        return list(values)
    idx = set(np.round(np.linspace(0, len(values) - 1, n - 1)).astype(int).tolist())
    picked = [values[i] for i in sorted(idx)]
    c = _key(chosen)
    if c in values and c not in picked:
        picked.append(c)
    return sorted(picked)


def _line_colours(n: int):
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.05 + 0.8 * i / max(1, n - 1)) for i in range(n)]


def _mark_chosen(ax, x: Any) -> None:
    if x is not None:
        ax.axvline(float(x), color="0.35", linestyle=":", linewidth=1.2, zorder=1)


def _legend_right(ax, **kw) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, frameon=False, **kw)


def _counts_plot(sw: _Sweep, vary: str, lines_by: str, *, name: str, paper: str) -> Plot | None:
    """Flagged pixels vs one z-cut parameter (one line per value of another) and, with SOR, the
    paper's N1, N2, N_both at the chosen point."""
    xs_all = sw.values("zcut", vary)
    if len(xs_all) < 2:
        return None
    ch = sw.chosen
    line_vals = _pick(sw.values("zcut", lines_by), ch.get(lines_by))
    with_overlap = sw.sor_enabled
    fig, subs = _subfigures(2 if with_overlap else 1, width_in=11.0 if with_overlap else 6.0, height_in=4.4)
    ax = subs[0].subplots()
    colours = _line_colours(len(line_vals))
    counts: list[float] = []
    for colour, lv in zip(colours, line_vals):
        fixed = {**{k: ch.get(k) for k in sw.zparams}, lines_by: lv}
        pts = sw.series("zcut", vary, fixed)
        if not pts:
            continue
        xs, ys = [p[0] for p in pts], [p[1]["n_pred"] for p in pts]
        counts += ys
        is_chosen = _key(ch.get(lines_by)) == lv
        ax.plot(xs, ys, marker="o", ms=3.5, lw=2.4 if is_chosen else 1.3, color=colour, zorder=3 if is_chosen else 2,
                label=f"{_SHORT[lines_by]} = {_fmt_param(lv, lines_by)}" + (" (chosen)" if is_chosen else ""))
    s0 = sw.find("sor", **sw.chosen_sor_fixed())
    if sw.ssets and s0 is not None:
        sor_label = f"SOR, k = {s0.get('sor_k')}, std_ratio = {_fmt_param(s0.get('sor_std_ratio'))}"
        pts = sw.series("sor", vary, sw.chosen_sor_fixed()) if vary in sw.sparams else []
        if len(pts) >= 2:
            ys = [p[1]["n_pred"] for p in pts]
            ax.plot([p[0] for p in pts], ys, color=_SOR_COLOUR, lw=1.8, ls="--", marker="s", ms=3.5, label=sor_label)
        else:
            ys = [s0["n_pred"]]
            ax.axhline(s0["n_pred"], color=_SOR_COLOUR, lw=1.8, ls="--", label=sor_label + " (does not vary)")
        counts += ys
    _mark_chosen(ax, ch.get(vary))
    _count_scale(ax, counts)
    ax.set_xlabel(_LABELS[vary])
    ax.set_ylabel("flagged pixels (all frames)")
    ax.set_title(f"(a) outliers flagged vs {_SHORT[vary]}")
    _legend_below(subs[0], ax)
    if with_overlap:
        ax2 = subs[1].subplots()
        fixed = {k: ch.get(k) for k in sw.zparams}
        pts = sw.series("zcut", vary, fixed)
        vals: list[float] = []
        for key, label, colour, style in (("n2", "$N_2$: z-cut only", _ZCUT_COLOUR, "-"),
                                          ("n1", "$N_1$: SOR only", _SOR_COLOUR, "--"),
                                          ("n_both", "$N_{both}$: both", "0.3", ":")):
            ys = [p[1].get(key) for p in pts]
            vals += [y for y in ys if y is not None]
            ax2.plot([p[0] for p in pts], [_f(y) for y in ys], marker="o", ms=3.5, lw=1.6, color=colour, ls=style,
                     label=label)
        _mark_chosen(ax2, ch.get(vary))
        _count_scale(ax2, vals)
        ax2.set_xlabel(_LABELS[vary])
        ax2.set_ylabel("pixels (all frames)")
        ax2.set_title("(b) found by one filter only (paper's $N_1$, $N_2$)")
        _legend_below(subs[1], ax2)
    held = ", ".join(f"{_SHORT[k]} = {_fmt_param(ch.get(k), k)}" for k in sw.zparams if k not in (vary, lines_by))
    caption = (f"The paper's {paper}, redone: pixels flagged as outliers, summed over the frames, against "
               f"{_SHORT[vary]} ({held}; dotted line: the chosen {_SHORT[vary]}). "
               + ("SOR at its chosen k and std_ratio for reference. " if s0 is not None and sw.ssets else "")
               + ("(b) The paper's N1 (flagged by SOR only, SOR at the config's own k and std_ratio) and N2 (by the "
                  f"z-cut only) at the chosen {_SHORT[lines_by]}; θ and ω are their ratios at 0.5× and 1.5×."
                  if with_overlap else ""))
    title = f"Outliers flagged vs {_SHORT[vary]}"
    return _plot(name, title, caption, fig)


def _metric_panel(ax, pts: list[tuple[float, dict]], *, legend: bool) -> None:
    xs = np.array([p[0] for p in pts], dtype=float)
    for m in ("precision", "recall", "f1"):
        y = np.array([_f(p[1].get(m)) for p in pts])
        lo, hi = np.array([_ci(p[1], m) for p in pts]).reshape(-1, 2).T
        c = _METRIC_COLOURS[m]
        if len(xs) > 1:
            ax.fill_between(xs, lo, hi, color=c, alpha=0.16, linewidth=0)
        else:
            ax.errorbar(xs, y, yerr=[np.abs(y - lo), np.abs(hi - y)], color=c, capsize=3, ls="none")
        ax.plot(xs, y, color=c, marker="o", ms=3.5, lw=1.8, label=_METRIC_NAMES[m])
    ax.set_ylim(-0.02, 1.02)
    if legend:
        ax.set_ylabel("precision, recall, F1")


def _accuracy_plot(sw: _Sweep, method: str) -> Plot | None:
    """P/R/F1 with 95 % bands vs each of the method's parameters, the others at the chosen point."""
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    axes_keys = [k for k in (sw.zparams if method == "zcut" else ("sor_k", "sor_std_ratio"))
                 if len(sw.values(method, k)) >= 2]
    fixed = {k: sw.chosen.get(k) for k in sw.params(method)}
    panels = [(k, sw.series(method, k, fixed)) for k in axes_keys]
    panels = [(k, pts) for k, pts in panels if len(pts) >= 2]
    if not panels:
        return None
    n = len(panels)
    fig, axes = _figure(1, n, width_in=min(11.0, 1.6 + 3.3 * n), height_in=3.7)
    ranges = sw.ranges if method == "zcut" else None
    shaded = False
    for i, (k, pts) in enumerate(panels):
        ax = axes[0, i]
        x0, x1 = pts[0][0], pts[-1][0]
        if ranges and k in ranges and ranges[k] is not None:
            lo, hi = ranges[k]
            if lo <= x1 and hi >= x0:
                ax.axvspan(max(lo, x0), min(hi, x1), color="0.85", alpha=0.6, lw=0, zorder=0)
                shaded = True
        _metric_panel(ax, pts, legend=i == 0)
        ax.set_xlim(x0 - 0.04 * (x1 - x0), x1 + 0.04 * (x1 - x0))
        ax.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=k == "sor_k"))
        _mark_chosen(ax, sw.chosen.get(k))
        ax.set_xlabel(_LABELS[k])
        if i:
            ax.tick_params(labelleft=False)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    handles.append(Patch(color="0.5", alpha=0.25))
    labels.append("95 % interval")
    if shaded:
        handles.append(Patch(color="0.85", alpha=0.6))
        labels.append("paper's §5.4 range")
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), frameon=False)
    who = "z-cut" if method == "zcut" else "SOR"
    held = ", ".join(f"{_SHORT[k]} = {_fmt_param(sw.chosen.get(k), k)}" for k in sw.params(method))
    caption = (f"True accuracy of the {who} (SPEC §4, pixels of the {sw.summary.get('region', 'zone')} region, pooled "
               f"over the frames) against each parameter with the others at the chosen point ({held}; dotted line). "
               "Bands: 95 % intervals over frames (docs/accuracy.md, Uncertainty). A gap means undefined (nothing "
               "flagged, or no true outlier) or too few frames for an interval.")
    name = "accuracy_zcut.png" if method == "zcut" else "accuracy_sor.png"
    return _plot(name, f"Precision, recall and F1 of the {who} vs its parameters", caption, fig)


def _f1_map(sw: _Sweep) -> Plot | None:
    depths, areas = sw.values("zcut", "max_depth_mm"), sw.values("zcut", sw.area)
    if len(depths) < 2 or len(areas) < 2:
        return None
    step = sw.chosen.get("step_mm")
    grid = np.full((len(depths), len(areas)), np.nan)
    for i, d in enumerate(depths):
        for j, a in enumerate(areas):
            e = sw.find("zcut", step_mm=step, max_depth_mm=d, **{sw.area: a})
            if e is not None:
                grid[i, j] = _f(e.get("f1"))
    if not np.isfinite(grid).any():
        return None
    from matplotlib import colormaps

    fig, axes = _figure(1, 1, width_in=min(11.0, 3.2 + 0.62 * len(areas)), height_in=min(7.5, 1.6 + 0.42 * len(depths)))
    ax = axes[0, 0]
    ax.grid(False)
    cmap = colormaps["viridis"].with_extremes(bad="0.85")
    top = float(np.nanmax(grid))
    im = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=0, vmax=top if top > 0 else 1.0,
                   origin="lower", aspect="auto")
    fig.colorbar(im, ax=ax, label="F1", shrink=0.9)
    ax.set_xticks(range(len(areas)), [f"{a:.4g}" for a in areas], rotation=45 if len(areas) > 6 else 0)
    ax.set_yticks(range(len(depths)), [f"{d:.4g}" for d in depths])
    ax.set_xlabel(_LABELS[sw.area])
    ax.set_ylabel(_LABELS["max_depth_mm"])
    if len(depths) * len(areas) <= 160:
        digits = 2 if top >= 0.1 or top == 0 else (3 if top >= 0.01 else 4)
        for i in range(len(depths)):
            for j in range(len(areas)):
                v = grid[i, j]
                ax.text(j, i, "—" if not np.isfinite(v) else f"{v:.{digits}f}", ha="center", va="center", fontsize=7.5,
                        color="black" if not np.isfinite(v) or v > 0.6 * top else "white")
    marks = []
    for what, e, style in (("chosen", (sw.summary.get("chosen") or {}).get("zcut"), {"ec": "white", "ls": "-"}),
                           ("tuned", (sw.summary.get("tuned") or {}).get("zcut"), {"ec": "#D55E00", "ls": "--"})):
        if e is None or _key(e.get("step_mm")) != _key(step):
            continue
        try:
            i, j = depths.index(_key(e.get("max_depth_mm"))), areas.index(_key(e.get(sw.area)))
        except ValueError:
            continue
        from matplotlib.patches import Rectangle

        ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2.2, **style))
        marks.append(f"{what}: {'white' if what == 'chosen' else 'orange dashed'} frame")
    caption = (f"F1 of the z-cut for every ({_SHORT['max_depth_mm']}, {_SHORT[sw.area]}) pair at Δd = "
               f"{_fmt_param(step, 'step_mm')}; colours from 0 to the best F1; grey: undefined." + (f" Marked: {'; '.join(marks)}." if marks else ""))
    return _plot("f1_map.png", f"F1 over d_max × {_SHORT[sw.area]}", caption, fig)


def _iso_f1(ax) -> None:
    for f in (0.2, 0.4, 0.6, 0.8):
        r = np.linspace(f / (2 - f) + 1e-6, 1, 200)
        p = f * r / (2 * r - f)
        ax.plot(r, p, color="0.75", lw=0.8, zorder=0)
        ax.annotate(f"F1 = {f:.1f}", (1.0, f / (2 - f)), xytext=(2, 0), textcoords="offset points", fontsize=7.5,
                    color="0.45", va="center", annotation_clip=False)


def _zoom_limits(v: np.ndarray) -> tuple[float, float]:
    """Axis limits around values in [0, 1], padded, never far outside [0, 1]."""
    span = float(v.max() - v.min())
    pad = max(0.15 * span, 0.02)
    lo, hi = max(0.0, float(v.min()) - pad), min(1.0, float(v.max()) + pad)
    margin = 0.06 * (hi - lo)
    return lo - margin, hi + margin


def _pr_plot(sw: _Sweep) -> Plot | None:
    from matplotlib.lines import Line2D

    def pr(e):
        return (_f(e.get("recall")), _f(e.get("precision"))) if e else (math.nan, math.nan)

    zs = [(pr(e), e) for e in sw.zsets]
    ss = [(pr(e), e) for e in sw.ssets]
    pts = [p for p, _ in zs + ss if all(math.isfinite(v) for v in p)]
    if not pts:
        return None
    summ = sw.summary
    chosen_z, nominal, tuned_z = (summ.get("chosen") or {}).get("zcut"), summ.get("nominal"), (summ.get("tuned") or {}).get("zcut")
    chosen_s, tuned_s = (summ.get("chosen") or {}).get("sor"), (summ.get("tuned") or {}).get("sor")
    marked = [("paper's nominal" + (" = chosen" if _same(chosen_z, nominal) else ""), nominal, {"marker": "*", "s": 260, "fc": "#F0E442", "ec": "black", "lw": 1.0, "zorder": 6}),
              ("chosen", None if _same(chosen_z, nominal) else chosen_z,
               {"marker": "s", "s": 80, "fc": "white", "ec": "black", "lw": 1.4, "zorder": 6}),
              ("tuned z-cut", tuned_z, {"marker": "D", "s": 90, "fc": "#D55E00", "ec": "black", "lw": 1.0, "zorder": 7}),
              ("SOR chosen", chosen_s, {"marker": "P", "s": 120, "fc": _SOR_COLOUR, "ec": "black", "lw": 1.0, "zorder": 6}),
              ("SOR tuned", tuned_s, {"marker": "X", "s": 120, "fc": "#CC79A7", "ec": "black", "lw": 1.0, "zorder": 7})]
    rs = np.array([p[0] for p in pts])
    ps = np.array([p[1] for p in pts])
    span_r, span_p = rs.max() - rs.min(), ps.max() - ps.min()
    zoom = span_r < 0.45 or span_p < 0.45
    fig, axes = _figure(1, 2 if zoom else 1, width_in=11.0 if zoom else 7.6, height_in=4.8)
    depths = [_f(e.get("max_depth_mm")) for _, e in zs]
    finite_depths = [d for d in depths if math.isfinite(d)]
    sc = None
    for n, ax in enumerate(axes[0]):
        if n == 0:
            _iso_f1(ax)
            ax.set_xlim(-0.02, 1.02)
            ax.set_ylim(-0.02, 1.04)
            ax.set_title("(a) every set" if zoom else "every parameter set")
        else:
            ax.set_xlim(*_zoom_limits(rs))
            ax.set_ylim(*_zoom_limits(ps))
            ax.set_title("(b) zoomed to the sets")
        zr = [p for p, _ in zs]
        if zr:
            cmin, cmax = (min(finite_depths), max(finite_depths)) if finite_depths else (0, 1)
            sc = ax.scatter([p[0] for p in zr], [p[1] for p in zr], c=depths, cmap="viridis", vmin=cmin,
                            vmax=cmax if cmax > cmin else cmin + 1, s=22, alpha=0.8, lw=0, zorder=3)
        if ss:
            ax.scatter([p[0] for p, _ in ss], [p[1] for p, _ in ss], marker="x", s=26, color=_SOR_COLOUR, lw=1.2,
                       zorder=3)
        for label, e, style in marked:
            if e is None:
                continue
            r, p = pr(e)
            if not (math.isfinite(r) and math.isfinite(p)):
                continue
            if n == len(axes[0]) - 1:
                (rlo, rhi), (plo, phi) = _ci(e, "recall"), _ci(e, "precision")
                ax.errorbar([r], [p], xerr=[[max(0, r - rlo)], [max(0, rhi - r)]] if math.isfinite(rlo) else None,
                            yerr=[[max(0, p - plo)], [max(0, phi - p)]] if math.isfinite(plo) else None,
                            color="0.25", lw=0.9, capsize=2, ls="none", zorder=5)
            ax.scatter([r], [p], **style)
        ax.set_xlabel("recall (true outlier pixels found)")
        ax.set_ylabel("precision (flagged pixels that are outliers)")
    handles = [Line2D([], [], marker="o", ls="none", color="#21918c", ms=5, label="z-cut sets (colour: $d_{max}$)")] if zs else []
    if ss:
        handles.append(Line2D([], [], marker="x", ls="none", color=_SOR_COLOUR, ms=6, mew=1.2, label="SOR sets"))
    for label, e, style in marked:
        if e is not None and all(math.isfinite(v) for v in pr(e)):
            handles.append(Line2D([], [], marker=style["marker"], ls="none", mfc=style["fc"], mec="black",
                                  ms=math.sqrt(style["s"]) * 0.8, label=label))
    if sc is not None and len(set(finite_depths)) > 1:
        fig.colorbar(sc, ax=axes[0, -1], label="$d_{max}$ (mm)", shrink=0.85)
    fig.legend(handles=handles, loc="outside lower center", ncols=min(4 if zoom else 3, len(handles)),
               frameon=False)
    undefined = sum(1 for p, _ in zs + ss if not all(math.isfinite(v) for v in p))
    caption = ("Every parameter set on the precision–recall plane (pooled over the frames); grey curves: equal F1. "
               + ("The paper's nominal point: Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07. " if nominal is not None
                  else "The paper's nominal point is not in the grid. ")
               + ("(b) shows the same sets zoomed, with the 95 % intervals of the marked points. " if zoom else
                  "Bars: the 95 % intervals of the marked points. ")
               + (f"{undefined} set(s) flag nothing in the region (precision undefined) and are not shown." if undefined
                  else ""))
    return _plot("precision_recall.png", "Precision–recall: every set, nominal, chosen, tuned and SOR", caption, fig)


def _ratios_plot(sw: _Sweep) -> Plot | None:
    if not sw.sor_enabled:
        return None
    cols = [k for k in ("max_depth_mm", sw.area) if len(sw.values("zcut", k)) >= 2]
    fixed = {k: sw.chosen.get(k) for k in sw.zparams}
    panels = [(k, sw.series("zcut", k, fixed)) for k in cols]
    panels = [(k, pts) for k, pts in panels if len(pts) >= 2]
    rows = (("alpha", r"$\alpha = N_1 / N_2$", ((("alpha", r"$\alpha$", "0.2", "-"),))),
            ("beta", r"$\beta_n = N_{both} / N_n$", (("beta_sor", r"$\beta_1$ (SOR)", _SOR_COLOUR, "--"),
                                                     ("beta_zcut", r"$\beta_2$ (z-cut)", _ZCUT_COLOUR, "-"))))
    if not panels or not any(math.isfinite(_f(p[1].get(key))) for _, pts in panels for p in pts
                             for _, _, lines in rows for key, *_ in lines):
        return None
    fig, axes = _figure(2, len(panels), width_in=min(11.0, 1.8 + 4.2 * len(panels)), height_in=5.6)
    for j, (k, pts) in enumerate(panels):
        xs = [p[0] for p in pts]
        for i, (_, ylabel, lines) in enumerate(rows):
            ax = axes[i, j]
            undefined = 0
            for key, label, colour, style in lines:
                ys = [_f(p[1].get(key)) for p in pts]
                undefined += sum(1 for y in ys if not math.isfinite(y))
                ax.plot(xs, ys, marker="o", ms=3.5, lw=1.6, color=colour, ls=style, label=label)
            if undefined:
                ax.text(0.98, 0.95, f"{undefined} point(s) undefined (÷ 0)", transform=ax.transAxes, ha="right",
                        va="top", fontsize=8, color="0.4")
            _mark_chosen(ax, sw.chosen.get(k))
            ax.set_ylim(bottom=0)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == 1:
                ax.set_xlabel(_LABELS[k])
            else:
                ax.set_title(f"vs {_SHORT[k]}")
            if j == len(panels) - 1:
                _legend_right(ax)
    held = ", ".join(f"{_SHORT[k]} = {_fmt_param(sw.chosen.get(k), k)}" for k in sw.zparams)
    caption = ("The paper's relative figures (Fig. 15, SPEC §3) against the z-cut's parameters, the others at the "
               f"chosen point ({held}); SOR at the config's own k and std_ratio. Small α and β₂: most outliers are "
               "found by the z-cut alone — which, without truth, the paper could not tell apart from false positives "
               "(see the precision plots).")
    return _plot("ratios.png", "α and β vs the z-cut's parameters", caption, fig)


def make_plots(summary: dict) -> list[Plot]:
    """Every plot the sweep's grid can draw, in page order (see the module docstring).

    Parameters
    ----------
    summary : dict
        The sweep's summary (``DIR/summary.json``).

    Returns
    -------
    list of Plot
        Plots whose grid lacks an axis or a defined value are left out (never an error).
    """
    import matplotlib

    sw = _Sweep.of(summary)
    makers = [lambda: _counts_plot(sw, "max_depth_mm", sw.area, name="counts_max_depth.png", paper="Figs. 16–17"),
              lambda: _counts_plot(sw, sw.area, "max_depth_mm", name="counts_rho.png", paper="Figs. 18–19"),
              lambda: _counts_plot(sw, "step_mm", "max_depth_mm", name="counts_step.png", paper="Fig. 20"),
              lambda: _accuracy_plot(sw, "zcut"), lambda: _accuracy_plot(sw, "sor"), lambda: _f1_map(sw),
              lambda: _pr_plot(sw), lambda: _ratios_plot(sw)]
    out = []
    with matplotlib.rc_context(_RC):
        for make in makers:
            p = make()
            if p is not None:
                out.append(p)
    return out


# ------------------------------------------------------------------------------ the paper's findings


def paper_findings(summary: dict) -> list[dict[str, Any]]:
    """The paper's sensitivity findings, checked against the true counts around the chosen point.

    Each finding compares the chosen z-cut set with one changed parameter (0.5× or 1.5× d_max or
    ρ_thr, the grid's largest Δd below the chosen one): did the flagged count move as the paper says,
    and what were the pixels gained or lost (true outliers or not), and did F1 change beyond the 95 %
    intervals.

    Parameters
    ----------
    summary : dict
        The sweep's summary.

    Returns
    -------
    list of dict
        One per finding the grid can check: ``claim`` (the paper's words), ``figure``, ``parameter``,
        ``base`` and ``changed`` (the two sets), ``count_as_paper`` (True, False, or None when the
        count did not change), ``d_tp``, ``d_fp`` (changes in the scored region), ``f1``
        ("higher", "lower", "within the intervals" or None when undefined).
    """
    sw = _Sweep.of(summary)
    ch = sw.chosen
    base = sw.find("zcut", **{k: ch.get(k) for k in sw.zparams})
    if base is None:
        return []
    out = []
    steps = [s for s in sw.values("zcut", "step_mm") if ch.get("step_mm") is not None and s < _key(ch["step_mm"])]
    claims = [("max_depth_mm", 1.5, "larger d_max flags more outliers", "Figs. 16b, 17b", +1),
              ("max_depth_mm", 0.5, "smaller d_max flags fewer outliers (some are left)", "Figs. 16a, 17a", -1),
              (sw.area, 0.5, "smaller ρ_thr misses outliers", "Figs. 18a, 19", -1),
              (sw.area, 1.5, "larger ρ_thr flags more, at the risk of false positives", "Fig. 18b, §5.4", +1)]
    for key, factor, claim, fig, sign in claims:
        if ch.get(key) is None:
            continue
        other = sw.find("zcut", **{**{k: ch.get(k) for k in sw.zparams}, key: factor * ch[key]})
        if other is not None:
            out.append(_finding(claim, fig, key, base, other, sign))
    if steps:
        other = sw.find("zcut", **{**{k: ch.get(k) for k in sw.zparams}, "step_mm": steps[-1]})
        if other is not None:
            out.append(_finding("smaller Δd flags more outliers", "Fig. 20", "step_mm", base, other, +1))
    return out


_FINDING_COLUMNS = (("max_depth_mm", 1.5, "larger d_max"), ("max_depth_mm", 0.5, "smaller d_max"),
                    ("step_mm", None, "smaller Δd"), ("rho_thr", 0.5, "smaller ρ_thr"), ("rho_thr", 1.5, "larger ρ_thr"))


def findings_table(summaries: dict[str, dict]) -> str:
    """A Markdown table over several sweeps (e.g. one per part kind): the paper's nominal set against
    the tuned one (F1 with 95 % intervals) and whether each of the paper's findings holds.

    Parameters
    ----------
    summaries : dict of str to dict
        A row name (e.g. the part kind) -> that sweep's summary.

    Returns
    -------
    str
        The table and a line explaining its cells: ``✓``/``✗`` the count moved as the paper says or
        not (``=`` unchanged), then F1 ``↑``/``↓`` beyond the 95 % intervals or ``≈`` within them.
    """
    def f1(e):
        if not e or e.get("f1") is None:
            return "—"
        lo, hi = (e.get("ci95") or {}).get("f1") or (None, None)
        return f"{e['f1']:.3f} [{_num(lo)}, {_num(hi)}]"

    head = ["", "nominal F1", "tuned Δd / d_max / ρ_thr", "tuned F1", "SOR tuned F1"] + [c for *_, c in _FINDING_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, summ in summaries.items():
        tz = (summ.get("tuned") or {}).get("zcut")
        params = (f"{_fmt_param(tz.get('step_mm'))} / {_fmt_param(tz.get('max_depth_mm'))} / "
                  f"{_fmt_param(tz.get('rho_thr') if tz.get('rho_thr') is not None else tz.get('max_area_px'))}"
                  if tz else "—")
        cells = [name, f1(summ.get("nominal")), params, f1(tz), f1((summ.get("tuned") or {}).get("sor"))]
        found = paper_findings(summ)
        for key, factor, _ in _FINDING_COLUMNS:
            hit = None
            for f in found:
                if f["parameter"] != key and not (key == "rho_thr" and f["parameter"] == "max_area_px"):
                    continue
                b, c = _key(f["base"].get(f["parameter"])), _key(f["changed"].get(f["parameter"]))
                if factor is None or (b and c is not None and abs(c / b - factor) < 1e-6):
                    hit = f
                    break
            if hit is None:
                cells.append("—")
                continue
            count = {True: "✓", False: "✗", None: "="}[hit["count_as_paper"]]
            cells.append(count + " " + {"higher": "F1↑", "lower": "F1↓", "within the intervals": "F1≈"}.get(hit["f1"], ""))
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    lines.append("")
    lines.append("Findings at each sweep's chosen point: ✓/✗ the number flagged moved as the paper says or not "
                 "(= unchanged); F1↑/F1↓ beyond the 95 % intervals, F1≈ within them; — not in the grid.")
    return "\n".join(lines) + "\n"


def _finding(claim, fig, key, base, other, sign) -> dict[str, Any]:
    dn = other["n_pred"] - base["n_pred"]
    f1 = None
    if base.get("f1") is not None and other.get("f1") is not None:
        (blo, bhi), (olo, ohi) = _ci(base, "f1"), _ci(other, "f1")
        if math.isfinite(olo) and math.isfinite(bhi) and olo > bhi:
            f1 = "higher"
        elif math.isfinite(ohi) and math.isfinite(blo) and ohi < blo:
            f1 = "lower"
        else:
            f1 = "within the intervals"
    return {"claim": claim, "figure": fig, "parameter": key, "base": base, "changed": other,
            "count_as_paper": None if dn == 0 else (dn * sign > 0), "d_tp": other["tp"] - base["tp"],
            "d_fp": other["fp"] - base["fp"], "f1": f1}


# ---------------------------------------------------------------------------------------- the page


def _e(v: Any) -> str:
    return html.escape(str(v), quote=True)


def _num(v: Any, digits: int = 3) -> str:
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{float(v):.{digits}f}"


def _metric_cell(e: dict | None, m: str) -> str:
    if e is None:
        return "<td class=num>—</td>"
    lo, hi = (e.get("ci95") or {}).get(m) or (None, None)
    ci = f"<br><span class=ci>{_num(lo)}–{_num(hi)}</span>" if lo is not None and hi is not None else ""
    return f"<td class=num>{_num(e.get(m))}{ci}</td>"


def _int(v: Any) -> str:
    return "—" if v is None else f"{int(v):,}".replace(",", "\u2009")


def _set_params(e: dict, sw: _Sweep) -> str:
    if e.get("method") == "zcut":
        area = (f"ρ_thr {_fmt_param(e.get('rho_thr'))}" if e.get("rho_thr") is not None
                else f"μ_thr {_fmt_param(e.get('max_area_px'), 'max_area_px')}")
        return f"Δd {_fmt_param(e.get('step_mm'), 'step_mm')}, d_max {_fmt_param(e.get('max_depth_mm'), 'max_depth_mm')}, {area}"
    s = f"k {e.get('sor_k')}, std_ratio {_fmt_param(e.get('sor_std_ratio'))}"
    if e.get("step_mm") is not None:
        s += f" (top {_fmt_param(e.get('max_depth_mm'), 'max_depth_mm')})"
    return s


def _objective(summary: dict):
    from studies.sweep import parse_objective

    try:
        return parse_objective(str(summary.get("objective") or "f1"))
    except ValueError:
        return ("f1", None)


def _inside_ranges(e: dict, ranges: dict | None) -> bool | None:
    if e.get("method") != "zcut" or not ranges:
        return None
    for k, r in ranges.items():
        if r is None or e.get(k) is None:
            return False if r is not None else None
        lo, hi = r
        if not (lo * (1 - 1e-9) <= e[k] <= hi * (1 + 1e-9)):
            return False
    return True


def _best_table(sw: _Sweep) -> str:
    from studies.sweep import score

    summ = sw.summary
    objective = _objective(summ)
    sets = sw.zsets + sw.ssets
    scored = sorted(((score(e, objective), i, e) for i, e in enumerate(sets)), key=lambda t: (-t[0], t[1]))
    rank: dict[int, int] = {}
    for pos, (s, i, _) in enumerate(scored):
        prev = scored[pos - 1] if pos else None
        rank[i] = rank[prev[1]] if prev is not None and prev[0] == s else pos + 1
    roles = [("tuned", (summ.get("tuned") or {}).get("zcut")), ("nominal", summ.get("nominal")),
             ("chosen", (summ.get("chosen") or {}).get("zcut")), ("SOR tuned", (summ.get("tuned") or {}).get("sor")),
             ("SOR chosen", (summ.get("chosen") or {}).get("sor"))]
    keep = [i for _, i, e in scored[:TOP_N]]
    keep += [i for _, i, e in scored if e.get("method") == "sor"][:3]
    tags: dict[int, list[str]] = {}
    for role, r in roles:
        for i, e in enumerate(sets):
            if _same(e, r):
                tags.setdefault(i, []).append(role)
                keep.append(i)
                break
    order = sorted(set(keep), key=lambda i: next(p for p, (_, j, _) in enumerate(scored) if j == i))
    ranges = sw.ranges
    rows = []
    for i in order:
        e = sets[i]
        s = next(t[0] for t in scored if t[1] == i)
        inside = _inside_ranges(e, ranges)
        chips = "".join(f"<span class='tag tag-{_e(t.split()[-1].lower())}'>{_e(t)}</span>" for t in tags.get(i, []))
        area = (_fmt_param(e.get("rho_thr")) if e.get("rho_thr") is not None else "—")
        mu = e.get("max_area_px")
        if mu is None and e.get("rho_thr") is not None and sw.a_max is not None:
            mu = e["rho_thr"] * sw.a_max
        zc = e.get("method") == "zcut"
        rows.append(
            "<tr" + (" class=marked" if i in tags else "") + ">"
            f"<td class=num>{rank[i] if math.isfinite(s) else '—'}</td><td>{chips}</td>"
            f"<td>{'z-cut' if zc else 'SOR'}</td>"
            f"<td class=num>{_fmt_param(e.get('step_mm'))}</td><td class=num>{_fmt_param(e.get('max_depth_mm'))}</td>"
            f"<td class=num>{area if zc else '—'}</td><td class=num>{_num(mu, 1) if zc else '—'}</td>"
            f"<td class=num>{_e(e.get('sor_k') if e.get('sor_k') is not None else '—')}</td>"
            f"<td class=num>{_fmt_param(e.get('sor_std_ratio'))}</td>"
            f"<td class=num>{_int(e.get('tp'))}</td><td class=num>{_int(e.get('fp'))}</td>"
            f"<td class=num>{_int(e.get('fn'))}</td><td class=num>{_int(e.get('n_pred'))}</td>"
            + _metric_cell(e, "precision") + _metric_cell(e, "recall") + _metric_cell(e, "f1")
            + f"<td class=c>{'' if inside is None else ('✓' if inside else '✗')}</td></tr>")
    if not rows:
        return "<p class=warn>No parameter set was scored.</p>"
    n_sor = sum(1 for e in sets if e.get("method") == "sor")
    head = ("<tr><th title='rank by the objective (ties share a rank)'>rank</th><th>role</th><th>method</th>"
            "<th>Δd<br>mm</th><th>d<sub>max</sub><br>mm</th><th>ρ<sub>thr</sub></th><th>μ<sub>thr</sub><br>px</th>"
            "<th>k</th><th>std<br>ratio</th><th>TP</th><th>FP</th><th>FN</th><th>flagged<br>px</th>"
            "<th>precision<br><span class=ci>95 %</span></th><th>recall<br><span class=ci>95 %</span></th>"
            "<th>F1<br><span class=ci>95 %</span></th><th title='inside the paper&#39;s §5.4 ranges'>§5.4</th></tr>")
    return (f"<p>The {TOP_N} best of {len(sets)} sets ({len(sets) - n_sor} z-cut, {n_sor} SOR) by the objective "
            f"<code>{_e(summ.get('objective') or 'f1')}</code>, the best SOR sets, and the marked sets wherever they "
            "rank. TP, FP, FN: pixels of the scored region; flagged: every pixel the filter flagged. "
            "Intervals: 95 % over frames, coverage measured (docs/accuracy.md, Uncertainty). §5.4: inside the paper's suggested ranges (the tuned z-cut set "
            "is chosen among those).</p>"
            f"<div class=scroll><table class=sets><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table></div>")


def _swept_section(sw: _Sweep) -> str:
    summ = sw.summary
    grid = summ.get("grid") or {}
    chosen = grid.get("chosen") or {}
    ranges = sw.ranges or {}
    logs = summ.get("logs") or []
    log_rows = "".join(
        f"<tr><td><code>{_e(l.get('log'))}</code></td><td><code>{_e(str(l.get('sha256') or '')[:12])}</code></td>"
        f"<td>{_e(l.get('error') or 'ok')}</td></tr>" for l in logs if isinstance(l, dict))
    axis_rows = []
    for key, name in (("step_mm", "z-cut Δd (mm)"), ("max_depth_mm", "z-cut d<sub>max</sub> (mm)"),
                      ("rho_thr", "z-cut ρ<sub>thr</sub> (μ<sub>thr</sub> = ρ<sub>thr</sub>·a<sub>max</sub>)"),
                      ("sor_k", "SOR k"), ("sor_std_ratio", "SOR std_ratio")):
        vals = grid.get(key) or []
        c = _key(chosen.get(key))
        cells = ", ".join(f"<b>{_fmt_param(v)}</b>" if _key(v) == c else _fmt_param(v) for v in vals) or "—"
        r = ranges.get(key)
        axis_rows.append(f"<tr><td>{name}</td><td>{len(vals)}</td><td>{cells}</td><td class=num>{_fmt_param(chosen.get(key))}</td>"
                         f"<td>{'—' if not r else f'{_fmt_param(r[0])} … {_fmt_param(r[1])}'}</td></tr>")
    region = summ.get("region")
    region_text = {"zone": "zone: the pixels the filters judge (valid pixels minus table and bin, plus the "
                           "above-the-rim points)", "valid": "valid: every valid pixel"}.get(region, region)
    truth = {"synthetic": "synthetic ground truth (/ground_truth/outliers)",
             "labels": "human labels (--labels)"}.get(summ.get("truth"), summ.get("truth"))
    facts = [("frames scored", _e(summ.get("frames"))), ("truth", _e(truth)), ("scored region", _e(region_text)),
             ("objective", f"<code>{_e(summ.get('objective'))}</code>"),
             ("parameter sets", f"{len(sw.zsets)} z-cut, {len(sw.ssets)} SOR"
              + ("" if sw.sor_enabled else " (SOR disabled in the config)"))]
    if summ.get("seconds") is not None:
        facts.append(("run time", f"{_e(round(float(summ['seconds']), 1))} s"))
    if sw.a_max is not None:
        facts.append(("a<sub>max</sub>", f"{sw.a_max:.1f} px (the part's largest face, from the config)"))
    dl = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in facts)
    return (f"<dl class=facts>{dl}</dl>"
            f"<h3>Logs ({len(logs)})</h3><div class=scroll><table><thead><tr><th>log</th><th>sha256</th><th>status</th>"
            f"</tr></thead><tbody>{log_rows}</tbody></table></div>"
            "<h3>Grid</h3><div class=scroll><table><thead><tr><th>axis</th><th>n</th><th>values (chosen in bold)</th>"
            "<th>chosen</th><th>paper's §5.4 range</th></tr></thead>"
            f"<tbody>{''.join(axis_rows)}</tbody></table></div>"
            "<p class=small>The chosen point is the resolved config's own; "
            + ("the grid holds 0.5× and 1.5× its d<sub>max</sub> and ρ<sub>thr</sub> for the paper's ratios θ and ω "
               "(study points).</p>" if (summ.get("grid") or {}).get("study_points", True) else
               "the sweep ran with --no-study-points: the grid is the values given.</p>"))


def _findings_section(summary: dict) -> str:
    found = paper_findings(summary)
    if not found:
        return "<p>The grid does not hold the chosen point's neighbours: nothing to check.</p>"
    rows = []
    for f in found:
        b, c, k = f["base"], f["changed"], f["parameter"]
        verdict = {True: "<span class=yes>yes</span>", False: "<span class=no>no</span>",
                   None: "<span class=same>no change</span>"}[f["count_as_paper"]]
        f1 = {"higher": "<span class=yes>higher</span>", "lower": "<span class=no>lower</span>",
              None: "undefined"}.get(f["f1"], _e(f["f1"]))
        rows.append(
            f"<tr><td>{_e(f['claim'])}<br><span class=ci>{_e(f['figure'])}</span></td>"
            f"<td class=num>{_e(_fmt_param(b.get(k), k))} →<br>{_e(_fmt_param(c.get(k), k))}</td>"
            f"<td class=num>{_int(b['n_pred'])} →<br>{_int(c['n_pred'])}</td><td class=c>{verdict}</td>"
            f"<td class=num>{f['d_tp']:+d}</td><td class=num>{f['d_fp']:+d}</td>"
            f"<td class=num>{_num(b.get('precision'))} →<br>{_num(c.get('precision'))}</td>"
            f"<td class=num>{_num(b.get('recall'))} →<br>{_num(c.get('recall'))}</td>"
            f"<td class=num>{_num(b.get('f1'))} <span class=ci>{_ci_text(b)}</span> →<br>{_num(c.get('f1'))} "
            f"<span class=ci>{_ci_text(c)}</span></td><td class=c>{f1}</td></tr>")
    return ("<p>The paper judged its parameters by the number of outliers flagged (it had no truth). Here each of "
            "its findings is checked at the chosen point with the truth: did the count move as the paper says, were "
            "the pixels gained (or lost) true outliers (ΔTP) or not (ΔFP), and did F1 move beyond its 95 % "
            "intervals?</p>"
            "<div class=scroll><table class=findings><thead><tr><th>paper's finding</th><th>change</th><th>flagged px</th>"
            "<th>count as<br>the paper?</th><th>ΔTP</th><th>ΔFP</th><th>precision</th><th>recall</th>"
            f"<th>F1 <span class=ci>[95 %]</span></th><th>F1 beyond<br>the intervals?</th></tr></thead><tbody>{''.join(rows)}</tbody></table></div>")


def _ci_text(e: dict) -> str:
    lo, hi = (e.get("ci95") or {}).get("f1") or (None, None)
    return f"[{_num(lo)}, {_num(hi)}]" if lo is not None and hi is not None else ""


def _ratio_text(v: Any, n_lo: Any, n_mid: Any) -> str:
    if v is not None:
        return f"{float(v):.3f}"
    if n_mid == 0 and n_lo is not None:
        return "∞" if n_lo > 0 else "0/0"
    return "—"


def _sensitivity_section(sw: _Sweep) -> str:
    summ = sw.summary
    sens = summ.get("sensitivity") or {}
    points = [("chosen", (summ.get("chosen") or {}).get("zcut"), sens.get("chosen")),
              ("tuned", (summ.get("tuned") or {}).get("zcut"), sens.get("tuned"))]
    blocks = []
    for name, e, s in points:
        if e is None:
            blocks.append(f"<h3>Around the {name} point</h3><p>No {name} z-cut set.</p>")
            continue
        head = f"<h3>Around the {name} point <span class=ci>({_e(_set_params(e, sw))})</span></h3>"
        if not s:
            blocks.append(head + "<p>The grid does not hold this point's 0.5× and 1.5× neighbours "
                                 "(or its ρ<sub>thr</sub> is unknown): no ratios.</p>")
            continue
        rows = []
        for ratio, key, pname in (("θ", sw.area, "ρ<sub>thr</sub>"), ("ω", "max_depth_mm", "d<sub>max</sub>")):
            fixed = {k: e.get(k) for k in sw.zparams}
            lo = sw.find("zcut", **{**fixed, key: 0.5 * e[key]}) if e.get(key) is not None else None
            hi = sw.find("zcut", **{**fixed, key: 1.5 * e[key]}) if e.get(key) is not None else None
            for n, nkey, who in ((1, "n1", "SOR only"), (2, "n2", "z-cut only")):
                v = s.get(f"{'theta' if ratio == 'θ' else 'omega'}_{n}")
                if v is None:
                    continue
                ns = [x.get(nkey) if x else None for x in (lo, e, hi)]
                rows.append(f"<tr><td>{ratio}<sub>{n},Lo</sub> / {ratio}<sub>{n},Hi</sub></td><td>{pname}</td>"
                            f"<td>N<sub>{n}</sub> ({who})</td>"
                            f"<td class=num>{' / '.join(_int(x) for x in ns)}</td>"
                            f"<td class=num>{_ratio_text(v.get('lo'), ns[0], ns[1])}</td>"
                            f"<td class=num>{_ratio_text(v.get('hi'), ns[2], ns[1])}</td></tr>")
        missing = [f"{r} (the grid lacks 0.5× or 1.5× its {p})" for r, p, k in
                   (("θ", "ρ<sub>thr</sub>", "theta_2"), ("ω", "d<sub>max</sub>", "omega_2")) if k not in s]
        if missing:
            rows.append(f"<tr><td colspan=6 class=small>No {' and no '.join(missing)}.</td></tr>")
        blocks.append(head + "<table><thead><tr><th>ratio</th><th>varied</th><th>count</th>"
                             "<th>N at 0.5× / 1× / 1.5×</th><th>Lo (0.5×)</th><th>Hi (1.5×)</th></tr></thead>"
                             f"<tbody>{''.join(rows)}</tbody></table>")
    return ("<p>SPEC §3 (paper eqs. 6, 7): θ<sub>n,Lo</sub> = N<sub>n</sub>(0.5·ρ<sub>thr</sub>) / "
            "N<sub>n</sub>(ρ<sub>thr</sub>), θ<sub>n,Hi</sub> = N<sub>n</sub>(1.5·ρ<sub>thr</sub>) / "
            "N<sub>n</sub>(ρ<sub>thr</sub>); ω likewise for d<sub>max</sub>. N<sub>1</sub>: pixels flagged by SOR "
            "only, N<sub>2</sub>: by the z-cut only (SOR at the config's own k and std_ratio). ∞: x/0; 0/0: "
            "undefined.</p>" + "".join(blocks))


def _tuned_section(sw: _Sweep, tuned_toml: str | None) -> str:
    """The tuned sets against the paper's nominal one."""
    summ = sw.summary
    tuned = summ.get("tuned") or {}
    parts = []
    for name, e in (("z-cut", tuned.get("zcut")), ("SOR", tuned.get("sor"))):
        if e is None:
            parts.append(f"<li>{name}: none</li>")
            continue
        parts.append(f"<li><b>{name}</b>: {_e(_set_params(e, sw))} — precision {_num(e.get('precision'))}, "
                     f"recall {_num(e.get('recall'))}, F1 {_num(e.get('f1'))} <span class=ci>{_ci_text(e)}</span></li>")
    nominal = summ.get("nominal")
    parts.append("<li>paper's nominal: " + (f"{_e(_set_params(nominal, sw))} — F1 {_num(nominal.get('f1'))} "
                                             f"<span class=ci>{_ci_text(nominal)}</span>" if nominal else
                                             "not in the grid") + "</li>")
    note = tuned.get("note")
    return (f"<h3>Tuned (written to tuned.toml)</h3><ul>{''.join(parts)}</ul>"
            + (f"<p class=warn>{_e(note)}</p>" if note else ""))


def _config_section(summary: dict, tuned_toml: str | None) -> str:
    """tuned.toml beside the resolved config, the tuned file's changed lines marked."""
    resolved = str(summary.get("config") or "")
    known = {line.strip() for line in resolved.splitlines()}

    def marked(text: str) -> str:
        lines = []
        for line in text.splitlines():
            t = line.strip()
            changed = t and not t.startswith("#") and t not in known
            lines.append(f"<mark>{_e(line)}</mark>" if changed else _e(line))
        return "\n".join(lines)

    why = "" if (summary.get("tuned") or {}).get("zcut") else " (no z-cut set met the objective)"
    left = (f"<pre>{marked(tuned_toml)}</pre>" if tuned_toml is not None
            else f"<p>No tuned.toml beside this report{why}.</p>")
    return ("<p>Left: <code>tuned.toml</code>, a config <code>zcut replay --config</code> accepts (lines that differ "
            "from the sweep's config are marked). Right: the config resolved for the (first) log, which the sweep "
            "varied.</p><div class=two><div><h3>tuned.toml</h3>" + left + "</div><div><h3>Resolved config used</h3>"
            f"<pre>{_e(resolved or '(none)')}</pre></div></div>")


def _notes_section(summary: dict) -> str:
    def items(xs, fmt=str, limit=50):
        xs = list(xs or [])
        body = "".join(f"<li>{_e(fmt(x))}</li>" for x in xs[:limit])
        more = f"<li>… and {len(xs) - limit} more</li>" if len(xs) > limit else ""
        return f"<ul>{body}{more}</ul>"

    def unscored(u):
        if isinstance(u, dict):
            log = f"{u['log']}: " if u.get("log") else ""
            return f"{log}frame {u.get('index')} (stamp {u.get('stamp_ns')} ns): {u.get('reason')}"
        return str(u)

    out = []
    if summary.get("notes"):
        out.append("<h3>How the parameters were resolved</h3>" + items(summary["notes"]))
    def damage(d):
        return f"{d['log']}: {d.get('note')}" if isinstance(d, dict) and d.get("log") else str(d)

    bad = [("Damage (frames lost: exit status 3)", summary.get("damage"), damage),
           ("Errors (logs or units that failed)", summary.get("errors"), str),
           ("Unscored frames (no truth for them)", summary.get("unscored"), unscored)]
    for title, xs, fmt in bad:
        if xs:
            out.append(f"<h3 class=warn>{_e(title)}: {len(xs)}</h3>" + items(xs, fmt))
    if not any(xs for _, xs, _ in bad):
        out.append("<p>No damage, no errors, every frame scored.</p>")
    return "".join(out)


def _reproduce_section(summary: dict, out_dir: Path | None) -> str:
    tuned = str(out_dir / "tuned.toml") if out_dir is not None else "DIR/tuned.toml"
    logs = [l.get("log") for l in summary.get("logs") or [] if isinstance(l, dict) and l.get("log")]
    import shlex

    replays = "\n".join(f"zcut replay {shlex.quote(str(l))} --config {shlex.quote(tuned)}" for l in logs[:5])
    if len(logs) > 5:
        replays += f"\n# … and {len(logs) - 5} more logs"
    return ("<p>This sweep (it continues where it stopped when run again over the same folder):</p>"
            f"<pre>{_e(summary.get('reproduce') or '(unknown)')}</pre>"
            "<p>Replay a log with the tuned parameters (add <code>--rrd OUT.rrd</code> to look at it in Rerun):</p>"
            f"<pre>{_e(replays or f'zcut replay LOG.mcap --config {tuned}')}</pre>")


_CSS = """
:root { --fg: #1d1d1f; --muted: #5f6368; --line: #dadce0; --bg2: #f6f8fa; --accent: #0b57d0; }
* { box-sizing: border-box; }
body { margin: 0; font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif;
       color: var(--fg); background: #fff; }
main { max-width: 1180px; margin: 0 auto; padding: 0 24px 48px; }
header { border-bottom: 1px solid var(--line); margin-bottom: 8px; }
h1 { font-size: 26px; margin: 24px 0 4px; }
h2 { font-size: 20px; margin: 36px 0 10px; padding-bottom: 4px; border-bottom: 1px solid var(--line); }
h3 { font-size: 16px; margin: 20px 0 8px; }
nav { font-size: 14px; margin: 8px 0 14px; display: flex; flex-wrap: wrap; gap: 4px 16px; }
nav a { color: var(--accent); text-decoration: none; white-space: nowrap; }
.lead { color: var(--muted); margin: 0 0 12px; }
table { border-collapse: collapse; font-size: 13.5px; font-variant-numeric: tabular-nums; }
th, td { border-bottom: 1px solid var(--line); padding: 5px 8px; vertical-align: top; text-align: left; }
th { background: var(--bg2); font-weight: 600; vertical-align: bottom; }
td.num, th.num { text-align: right; white-space: nowrap; }
td.c { text-align: center; }
tr.marked td { background: #fffbe6; }
.scroll { overflow-x: auto; max-width: 100%; }
.ci { color: var(--muted); font-size: 12px; font-weight: normal; }
.tag { display: inline-block; font-size: 11.5px; padding: 0 6px; margin: 1px 2px 1px 0; border-radius: 9px;
       background: #e8eaed; white-space: nowrap; }
.tag-tuned { background: #fde2d3; } .tag-nominal { background: #fbf3b0; } .tag-chosen { background: #dfe9fb; }
.yes { color: #137333; font-weight: 600; } .no { color: #b3261e; font-weight: 600; } .same { color: var(--muted); }
.warn { color: #8a4b00; }
dl.facts { display: grid; grid-template-columns: max-content 1fr; gap: 2px 16px; margin: 0; }
dl.facts dt { color: var(--muted); } dl.facts dd { margin: 0; }
pre { background: var(--bg2); border: 1px solid var(--line); padding: 10px 12px; font-size: 12.5px;
      overflow-x: auto; white-space: pre; max-height: 480px; }
code { font-size: 13px; }
figure { margin: 18px 0 28px; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: 13.5px; margin-top: 6px; max-width: 1100px; }
figure h3 { margin-bottom: 6px; }
.small { font-size: 13px; color: var(--muted); }
.two { display: grid; grid-template-columns: repeat(auto-fit, minmax(420px, 1fr)); gap: 0 20px; }
.two > div { min-width: 0; }
mark { background: #fbf3b0; }
table.findings td:first-child { min-width: 190px; }
"""


def render_html(summary: dict, plots: list[Plot], *, tuned_toml: str | None = None, out_dir: Path | None = None) -> str:
    """The report page: one self-contained HTML document (images as data URIs, CSS inline).

    Parameters
    ----------
    summary : dict
        The sweep's summary.
    plots : list of Plot
        From :func:`make_plots`.
    tuned_toml : str, optional
        The text of ``DIR/tuned.toml`` (None when none was written).
    out_dir : path, optional
        The sweep's folder (named in the commands that reproduce it).

    Returns
    -------
    str
        The page; every text taken from ``summary`` is escaped.
    """
    sw = _Sweep.of(summary)
    figures = "".join(
        f"<figure id='plot-{_e(p.name.removesuffix('.png'))}'><h3>{_e(p.title)}</h3>"
        f"<img src='data:image/png;base64,{base64.b64encode(p.png).decode('ascii')}' width='{p.width_px}' "
        f"alt='{_e(p.title)}'><figcaption>{_e(p.caption)} <span class=small>({_e(PLOTS_DIR + '/' + p.name)})</span>"
        "</figcaption></figure>" for p in plots) or "<p>The grid has no axis with two values: no plots.</p>"
    tuned = (summary.get("tuned") or {}).get("zcut")
    nominal = summary.get("nominal")
    lead = (f"{len(summary.get('logs') or [])} log(s), {_e(summary.get('frames'))} frame(s) scored against "
            f"{_e(summary.get('truth'))} truth over the {_e(summary.get('region'))} region; "
            f"{len(sw.zsets)} z-cut and {len(sw.ssets)} SOR parameter sets.")
    if tuned is not None:
        lead += (f" Tuned z-cut F1 {_num(tuned.get('f1'))} {_ci_text(tuned)}"
                 + (f" vs the paper's nominal {_num(nominal.get('f1'))} {_ci_text(nominal)}." if nominal else "."))
    sections = [("swept", "What was swept", _swept_section(sw)),
                ("best", "Best parameter sets", _best_table(sw) + _tuned_section(sw, tuned_toml)),
                ("plots", "Plots", figures),
                ("findings", "The paper's findings, scored by true accuracy", _findings_section(summary)),
                ("sensitivity", "Sensitivity ratios θ and ω", _sensitivity_section(sw)),
                ("config", "Tuned and resolved config", _config_section(summary, tuned_toml)),
                ("notes", "Notes and warnings", _notes_section(summary)),
                ("reproduce", "How to reproduce", _reproduce_section(summary, out_dir))]
    nav = "".join(f"<a href='#{sid}'>{_e(title)}</a>" for sid, title, _ in sections)
    body = "".join(f"<section id='{sid}'><h2>{_e(title)}</h2>{content}</section>" for sid, title, content in sections)
    return ("<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
            "<meta name=viewport content='width=device-width, initial-scale=1'>"
            "<meta http-equiv='Content-Security-Policy' content=\"default-src 'none'; img-src data:; "
            "style-src 'unsafe-inline'\">"
            f"<title>zcut sweep report</title><style>{_CSS}</style></head><body><main>"
            f"<header><h1>zcut sweep report</h1><p class=lead>{lead}</p><nav>{nav}</nav></header>"
            f"{body}</main></body></html>\n")


# --------------------------------------------------------------------------------------- the files


def _write_bytes(path: Path, data: bytes) -> None:
    from replay.outputs import AtomicOutput

    with AtomicOutput(path) as out:
        out.temp.write_bytes(data)


def write_report(out_dir: Path, summary: dict) -> Path:
    """Write ``out_dir/plots/*.png`` and ``out_dir/report.html`` for a sweep's summary.

    Parameters
    ----------
    out_dir : Path
        The sweep's output folder (exists; ``tuned.toml`` in it, when present, is shown on the page).
    summary : dict
        The sweep's summary (as written to ``summary.json``; NaN and ±inf as None).

    Returns
    -------
    Path
        ``out_dir / "report.html"``. Plots the grid cannot draw are not written (and removed when an
        earlier run left them).
    """
    out_dir = Path(out_dir)
    plots = make_plots(summary)
    plot_dir = out_dir / PLOTS_DIR
    plot_dir.mkdir(exist_ok=True)
    for p in plots:
        _write_bytes(plot_dir / p.name, p.png)
    made = {p.name for p in plots}
    for name in PLOT_NAMES:
        stale = plot_dir / name
        if name not in made and stale.is_file():
            stale.unlink()
    tuned_path = out_dir / "tuned.toml"
    tuned_toml = tuned_path.read_text(encoding="utf-8") if tuned_path.is_file() else None
    page = render_html(summary, plots, tuned_toml=tuned_toml, out_dir=out_dir)
    path = out_dir / REPORT_NAME
    _write_bytes(path, page.encode("utf-8", errors="backslashreplace"))
    return path
