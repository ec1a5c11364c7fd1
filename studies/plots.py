"""The plots of ``zcut sweep``'s report (PNG, matplotlib on its Agg canvas).

:func:`make_plots` turns a sweep's summary into :class:`Plot` records, in page order; each plot is
left out when the grid cannot draw it (one value on its axis, no SOR sets, no defined value):

- ``counts_max_depth.png``, ``counts_rho.png``, ``counts_step.png`` — what the paper plots (Figs.
  16–20): the pixels each filter flags, summed over the frames, against d_max, ρ_thr and Δd (one
  z-cut line per value of the other parameter, SOR at its chosen k and std_ratio for reference), and
  the paper's N1 (SOR only), N2 (z-cut only), N_both whose ratios are θ and ω (``docs/accuracy.md``).
- ``accuracy_zcut.png``, ``accuracy_sor.png`` — what the paper could not plot: precision, recall
  and F1 against each parameter with their 95 % interval bands, the other parameters held at the
  chosen point (the config's own), the paper's §5.4 range shaded.
- ``f1_map.png`` — F1 over every (d_max, ρ_thr) pair at the chosen Δd, chosen and tuned marked.
- ``precision_recall.png`` — every set on the precision–recall plane, the paper's nominal point, the
  chosen and tuned points and SOR's sets marked, iso-F1 curves; a zoomed panel when the sets crowd.
- ``ratios.png`` — the paper's α = N1/N2 and β_n = N_both/N_n (Fig. 15) against d_max and ρ_thr.

Explicit :class:`matplotlib.figure.Figure` objects (no pyplot, no global figure state); the style is
set in an ``rc_context`` that is restored after.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from studies.findings import SHORT, param_text
from studies.setgrid import SetGrid, same_set
from studies.setgrid import key as _key
from studies.summary import ParamSet, SweepSummary

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure, SubFigure

#: Every plot file a report may write, in page order (those a grid cannot draw are not written,
#: and a stale one from an earlier run of the same folder is removed).
PLOT_NAMES = ("counts_max_depth.png", "counts_rho.png", "counts_step.png", "accuracy_zcut.png",
              "accuracy_sor.png", "f1_map.png", "precision_recall.png", "ratios.png")
#: The plots of a sweep with a filter bank (``summary.ranking``), after those of :data:`PLOT_NAMES`.
BANK_PLOT_NAMES = ("ranking.png",)

_DPI = 150            # PNG pixels per inch; the page shows 100 CSS px per inch (sharp on HiDPI screens)
_CSS_PX_PER_INCH = 100

# Okabe–Ito colours (readable with colour-blindness)
_METRIC_COLOURS = {"precision": "#0072B2", "recall": "#009E73", "f1": "#D55E00"}
_METRIC_NAMES = {"precision": "precision", "recall": "recall", "f1": "F1"}
_SOR_COLOUR = "#E69F00"
_ZCUT_COLOUR = "#0072B2"
_RC: dict[Any, Any] = {"font.size": 10, "axes.titlesize": 11, "axes.labelsize": 10, "xtick.labelsize": 9, "ytick.labelsize": 9,
       "legend.fontsize": 9, "axes.grid": True, "grid.alpha": 0.3, "grid.linewidth": 0.6,
       "axes.spines.top": False, "axes.spines.right": False, "figure.facecolor": "white",
       "savefig.facecolor": "white"}

_LABELS = {"step_mm": "Δd (mm)", "max_depth_mm": "$d_{max}$ (mm)", "rho_thr": r"$\rho_{thr}$ (= $\mu_{thr}$ / $a_{max}$)",
           "max_area_px": r"$\mu_{thr}$ (px)", "sor_k": "SOR k (neighbours)",
           "sor_std_ratio": "SOR std_ratio (multiples of σ)"}


def _f(v: float | None) -> float:
    """A figure as float (None -> NaN)."""
    return math.nan if v is None else float(v)


def _ci(e: ParamSet, metric: str) -> tuple[float, float]:
    lo, hi = e.ci(metric)
    return _f(lo), _f(hi)



# ----------------------------------------------------------------------------------------- plotting


@dataclass(frozen=True, slots=True)
class Plot:
    """One PNG plot of the report.

    Attributes
    ----------
    name : str
        File name under ``DIR/plots`` (one of :data:`PLOT_NAMES` or :data:`BANK_PLOT_NAMES`).
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


def _figure(nrows: int, ncols: int, *, width_in: float, height_in: float) -> tuple[Figure, Any]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _subfigures(n: int, *, width_in: float, height_in: float) -> tuple[Figure, list[SubFigure]]:
    """A figure of ``n`` side-by-side subfigures (each with its own legend below it)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    subs = fig.subfigures(1, n, wspace=0.03, squeeze=False)[0]
    return fig, list(subs)


def _legend_below(sub: SubFigure, ax: Axes) -> None:
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        sub.legend(handles, labels, loc="outside lower center", ncols=2 if len(labels) > 3 else len(labels),
                   frameon=False)


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})
    return buf.getvalue()


def _plot(name: str, title: str, caption: str, fig: Figure) -> Plot:
    return Plot(name, title, caption, _png(fig), round(fig.get_figwidth() * _CSS_PX_PER_INCH))


def _count_scale(ax: Axes, values: list[float]) -> None:
    """Counts spanning more than ~2 decades on a symmetric log axis (zeros stay visible)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    pos = v[v > 0]
    if pos.size and pos.max() / max(pos.min(), 1.0) > 100:
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylim(bottom=0)
    else:
        ax.set_ylim(bottom=0, top=max(1.0, float(v.max()) * 1.08 if v.size else 1.0))


def _pick(values: list[float], chosen: Any, n: int = 8) -> list[float]:
    """At most ``n`` values for one line each: evenly spread, always with the chosen one."""
    if len(values) <= n:
        return list(values)
    idx = set(np.round(np.linspace(0, len(values) - 1, n - 1)).astype(int).tolist())
    picked = [values[i] for i in sorted(idx)]
    c = _key(chosen)
    if c in values and c not in picked:
        picked.append(c)
    return sorted(picked)


def _line_colours(n: int) -> list[tuple[float, float, float, float]]:
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.05 + 0.8 * i / max(1, n - 1)) for i in range(n)]


def _mark_chosen(ax: Axes, x: Any) -> None:
    if x is not None:
        ax.axvline(float(x), color="0.35", linestyle=":", linewidth=1.2, zorder=1)


def _legend_right(ax: Axes, **kw: Any) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, frameon=False, **kw)


def _counts_plot(sw: SetGrid, vary: str, lines_by: str, *, name: str, paper: str) -> Plot | None:
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
        xs, ys = [p[0] for p in pts], [p[1].n_pred for p in pts]
        counts += ys
        is_chosen = _key(ch.get(lines_by)) == lv
        ax.plot(xs, ys, marker="o", ms=3.5, lw=2.4 if is_chosen else 1.3, color=colour, zorder=3 if is_chosen else 2,
                label=f"{SHORT[lines_by]} = {param_text(lv, lines_by)}" + (" (chosen)" if is_chosen else ""))
    s0 = sw.find("sor", **sw.chosen_at("sor"))
    if sw.ssets and s0 is not None:
        sor_label = f"SOR, k = {s0.sor_k}, std_ratio = {param_text(s0.sor_std_ratio)}"
        pts = sw.series("sor", vary, sw.chosen_at("sor")) if vary in sw.sparams else []
        if len(pts) >= 2:
            ys = [p[1].n_pred for p in pts]
            ax.plot([p[0] for p in pts], ys, color=_SOR_COLOUR, lw=1.8, ls="--", marker="s", ms=3.5, label=sor_label)
        else:
            ys = [s0.n_pred]
            ax.axhline(s0.n_pred, color=_SOR_COLOUR, lw=1.8, ls="--", label=sor_label + " (does not vary)")
        counts += ys
    _mark_chosen(ax, ch.get(vary))
    _count_scale(ax, counts)
    ax.set_xlabel(_LABELS[vary])
    ax.set_ylabel("flagged pixels (all frames)")
    ax.set_title(f"(a) outliers flagged vs {SHORT[vary]}")
    _legend_below(subs[0], ax)
    if with_overlap:
        ax2 = subs[1].subplots()
        fixed = {k: ch.get(k) for k in sw.zparams}
        pts = sw.series("zcut", vary, fixed)
        vals: list[float] = []
        for key, label, line_colour, style in (("n2", "$N_2$: z-cut only", _ZCUT_COLOUR, "-"),
                                               ("n1", "$N_1$: SOR only", _SOR_COLOUR, "--"),
                                               ("n_both", "$N_{both}$: both", "0.3", ":")):
            ns = [p[1].figure(key) for p in pts]
            vals += [float(y) for y in ns if y is not None]
            ax2.plot([p[0] for p in pts], [_f(y) for y in ns], marker="o", ms=3.5, lw=1.6, color=line_colour, ls=style,
                     label=label)
        _mark_chosen(ax2, ch.get(vary))
        _count_scale(ax2, vals)
        ax2.set_xlabel(_LABELS[vary])
        ax2.set_ylabel("pixels (all frames)")
        ax2.set_title("(b) found by one filter only (paper's $N_1$, $N_2$)")
        _legend_below(subs[1], ax2)
    held = ", ".join(f"{SHORT[k]} = {param_text(ch.get(k), k)}" for k in sw.zparams if k not in (vary, lines_by))
    caption = (f"The paper's {paper}, redone: pixels flagged as outliers, summed over the frames, against "
               f"{SHORT[vary]} ({held}; dotted line: the chosen {SHORT[vary]}). "
               + ("SOR at its chosen k and std_ratio for reference. " if s0 is not None and sw.ssets else "")
               + ("(b) The paper's N1 (flagged by SOR only, SOR at the config's own k and std_ratio) and N2 (by the "
                  f"z-cut only) at the chosen {SHORT[lines_by]}; θ and ω are their ratios at 0.5× and 1.5×."
                  if with_overlap else ""))
    title = f"Outliers flagged vs {SHORT[vary]}"
    return _plot(name, title, caption, fig)


def _metric_panel(ax: Axes, pts: list[tuple[float, ParamSet]], *, legend: bool) -> None:
    xs = np.array([p[0] for p in pts], dtype=float)
    for m in ("precision", "recall", "f1"):
        y = np.array([_f(p[1].figure(m)) for p in pts])
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


def _accuracy_plot(sw: SetGrid, method: str) -> Plot | None:
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
    held = ", ".join(f"{SHORT[k]} = {param_text(sw.chosen.get(k), k)}" for k in sw.params(method))
    caption = (f"True accuracy of the {who} (docs/accuracy.md, pixels of the {sw.summary.region} region, pooled "
               f"over the frames) against each parameter with the others at the chosen point ({held}; dotted line). "
               "Bands: 95 % intervals over frames (docs/accuracy.md, Uncertainty). A gap means undefined (nothing "
               "flagged, or no true outlier) or too few frames for an interval.")
    name = "accuracy_zcut.png" if method == "zcut" else "accuracy_sor.png"
    return _plot(name, f"Precision, recall and F1 of the {who} vs its parameters", caption, fig)


def _f1_map(sw: SetGrid) -> Plot | None:
    depths, areas = sw.values("zcut", "max_depth_mm"), sw.values("zcut", sw.area)
    if len(depths) < 2 or len(areas) < 2:
        return None
    step = sw.chosen.get("step_mm")
    grid = np.full((len(depths), len(areas)), np.nan)
    for i, d in enumerate(depths):
        for j, a in enumerate(areas):
            e = sw.find("zcut", step_mm=step, max_depth_mm=d, **{sw.area: a})
            if e is not None:
                grid[i, j] = _f(e.f1)
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
    for what, e, style in (("chosen", sw.summary.chosen_zcut, {"ec": "white", "ls": "-"}),
                           ("tuned", sw.summary.tuned.zcut, {"ec": "#D55E00", "ls": "--"})):
        if e is None or _key(e.step_mm) != _key(step):
            continue
        depth, area = _key(e.max_depth_mm), _key(e.param(sw.area))
        if depth not in depths or area not in areas or depth is None or area is None:
            continue
        i, j = depths.index(depth), areas.index(area)
        from matplotlib.patches import Rectangle

        ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2.2, edgecolor=style["ec"], linestyle=style["ls"]))
        marks.append(f"{what}: {'white' if what == 'chosen' else 'orange dashed'} frame")
    caption = (f"F1 of the z-cut for every ({SHORT['max_depth_mm']}, {SHORT[sw.area]}) pair at Δd = "
               f"{param_text(step, 'step_mm')}; colours from 0 to the best F1; grey: undefined." + (f" Marked: {'; '.join(marks)}." if marks else ""))
    return _plot("f1_map.png", f"F1 over d_max × {SHORT[sw.area]}", caption, fig)


def _iso_f1(ax: Axes) -> None:
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


def _pr_plot(sw: SetGrid) -> Plot | None:
    from matplotlib.lines import Line2D

    def pr(e: ParamSet | None) -> tuple[float, float]:
        return (_f(e.recall), _f(e.precision)) if e else (math.nan, math.nan)

    zs = [(pr(e), e) for e in sw.zsets]
    ss = [(pr(e), e) for e in sw.ssets]
    pts = [p for p, _ in zs + ss if all(math.isfinite(v) for v in p)]
    if not pts:
        return None
    summ = sw.summary
    chosen_z, nominal, tuned_z = summ.chosen_zcut, summ.nominal, summ.tuned.zcut
    chosen_s, tuned_s = summ.chosen_sor, summ.tuned.sor
    marked: list[tuple[str, ParamSet | None, dict[str, Any]]] = [("paper's nominal" + (" = chosen" if same_set(chosen_z, nominal) else ""), nominal, {"marker": "*", "s": 260, "fc": "#F0E442", "ec": "black", "lw": 1.0, "zorder": 6}),
              ("chosen", None if same_set(chosen_z, nominal) else chosen_z,
               {"marker": "s", "s": 80, "fc": "white", "ec": "black", "lw": 1.4, "zorder": 6}),
              ("tuned z-cut", tuned_z, {"marker": "D", "s": 90, "fc": "#D55E00", "ec": "black", "lw": 1.0, "zorder": 7}),
              ("SOR chosen", chosen_s, {"marker": "P", "s": 120, "fc": _SOR_COLOUR, "ec": "black", "lw": 1.0, "zorder": 6}),
              ("SOR tuned", tuned_s, {"marker": "X", "s": 120, "fc": "#CC79A7", "ec": "black", "lw": 1.0, "zorder": 7})]
    rs = np.array([p[0] for p in pts])
    ps = np.array([p[1] for p in pts])
    span_r, span_p = rs.max() - rs.min(), ps.max() - ps.min()
    zoom = span_r < 0.45 or span_p < 0.45
    fig, axes = _figure(1, 2 if zoom else 1, width_in=11.0 if zoom else 7.6, height_in=4.8)
    depths = [_f(e.max_depth_mm) for _, e in zs]
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
        for _label, e, style in marked:
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


def _ratios_plot(sw: SetGrid) -> Plot | None:
    if not sw.sor_enabled:
        return None
    cols = [k for k in ("max_depth_mm", sw.area) if len(sw.values("zcut", k)) >= 2]
    fixed = {k: sw.chosen.get(k) for k in sw.zparams}
    panels = [(k, sw.series("zcut", k, fixed)) for k in cols]
    panels = [(k, pts) for k, pts in panels if len(pts) >= 2]
    rows = (("alpha", r"$\alpha = N_1 / N_2$", ((("alpha", r"$\alpha$", "0.2", "-"),))),
            ("beta", r"$\beta_n = N_{both} / N_n$", (("beta_sor", r"$\beta_1$ (SOR)", _SOR_COLOUR, "--"),
                                                     ("beta_zcut", r"$\beta_2$ (z-cut)", _ZCUT_COLOUR, "-"))))
    if not panels or not any(math.isfinite(_f(p[1].figure(key))) for _, pts in panels for p in pts
                             for _, _, lines in rows for key, *_ in lines):
        return None
    fig, axes = _figure(2, len(panels), width_in=min(11.0, 1.8 + 4.2 * len(panels)), height_in=5.6)
    for j, (k, pts) in enumerate(panels):
        xs = [p[0] for p in pts]
        for i, (_, ylabel, lines) in enumerate(rows):
            ax = axes[i, j]
            undefined = 0
            for key, label, colour, style in lines:
                ys = [_f(p[1].figure(key)) for p in pts]
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
                ax.set_title(f"vs {SHORT[k]}")
            if j == len(panels) - 1:
                _legend_right(ax)
    held = ", ".join(f"{SHORT[k]} = {param_text(sw.chosen.get(k), k)}" for k in sw.zparams)
    caption = ("The paper's relative figures (Fig. 15, docs/accuracy.md) against the z-cut's parameters, the others at the "
               f"chosen point ({held}); SOR at the config's own k and std_ratio. Small α and β₂: most outliers are "
               "found by the z-cut alone — which, without truth, the paper could not tell apart from false positives "
               "(see the precision plots).")
    return _plot("ratios.png", "α and β vs the z-cut's parameters", caption, fig)


def _ranking_plot(ranking: Mapping[str, Any] | None) -> Plot | None:
    """Precision against recall of every method's tuned set (the filter bank's ranking over every log),
    with 95 % intervals over frames; None without a ranking."""
    rows = list(((ranking or {}).get("by_part") or {}).get("all") or [])
    pts = [r for r in rows if r.get("precision") is not None and r.get("recall") is not None]
    if not pts:
        return None
    fig, axes = _figure(1, 1, width_in=7.0, height_in=5.0)
    ax = axes[0][0]
    _iso_f1(ax)
    colours = _line_colours(len(pts))
    for c, r in zip(colours, pts):
        ci = r.get("ci95") or {}
        p, rc = float(r["precision"]), float(r["recall"])
        plo, phi = (ci.get("precision") or [None, None])[:2]
        rlo, rhi = (ci.get("recall") or [None, None])[:2]
        yerr = [[p - plo], [phi - p]] if plo is not None and phi is not None else None
        xerr = [[rc - rlo], [rhi - rc]] if rlo is not None and rhi is not None else None
        marker = "D" if "+" in str(r["method"]) else "o"
        ax.errorbar([rc], [p], xerr=xerr, yerr=yerr, fmt=marker, color=c, ms=6, capsize=2, lw=1,
                    label=f"{r['method']}  F1 {r['f1']:.3f}" if r.get("f1") is not None else str(r["method"]))
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    _legend_right(ax)
    caption = ("Every filter at its tuned parameters (the best set of its own axes by the objective), pooled over "
               "every log of the sweep, with 95 % intervals over frames; diamonds: unions. Grey: lines of equal F1.")
    return _plot("ranking.png", "The filter bank: each filter's tuned point", caption, fig)


def make_plots(summary: SweepSummary | Mapping[str, Any]) -> list[Plot]:
    """Every plot the sweep's grid can draw, in page order (see the module docstring).

    Parameters
    ----------
    summary : SweepSummary or dict
        The sweep's summary (a dict: ``DIR/summary.json``'s object).

    Returns
    -------
    list of Plot
        Plots whose grid lacks an axis or a defined value are left out (never an error).
    """
    import matplotlib

    sw = SetGrid.of(summary)
    makers: list[Callable[[], Plot | None]] = [lambda: _counts_plot(sw, "max_depth_mm", sw.area, name="counts_max_depth.png", paper="Figs. 16–17"),
              lambda: _counts_plot(sw, sw.area, "max_depth_mm", name="counts_rho.png", paper="Figs. 18–19"),
              lambda: _counts_plot(sw, "step_mm", "max_depth_mm", name="counts_step.png", paper="Fig. 20"),
              lambda: _accuracy_plot(sw, "zcut"), lambda: _accuracy_plot(sw, "sor"), lambda: _f1_map(sw),
              lambda: _pr_plot(sw), lambda: _ratios_plot(sw), lambda: _ranking_plot(sw.summary.ranking)]
    out: list[Plot] = []
    with matplotlib.rc_context(_RC):
        for make in makers:
            p = make()
            if p is not None:
                out.append(p)
    return out


# ------------------------------------------------------------------------- SVG panels (no matplotlib)
# ``zcut compare``'s page draws its two small plots as SVG text here, in the style above (matplotlib's
# defaults and :data:`_RC`: DejaVu Sans, the same sizes, ticks, grid, margins and colours), without
# matplotlib: importing it and rendering two figures cost the page 0.3-1 CPU-s (docs/compare.md, "Cost").
# Its ticks, tick labels and autoscaled views are held to matplotlib's own on the same inputs by
# tests/studies/test_plots_svg.py, so the sweep's PNGs and compare's SVGs cannot drift apart there.

_PT = _CSS_PX_PER_INCH / 72.0  # CSS px per point
_TICK_PT, _TICK_PAD_PT, _LABEL_PAD_PT, _FIG_PAD_PX = 3.5, 3.5, 4.0, 0.04167 * _CSS_PX_PER_INCH
_GRID = "#b0b0b0"
_FONT = "DejaVu Sans, Bitstream Vera Sans, Arial, sans-serif"
# DejaVu Sans advance widths (em) of the characters tick labels and legends use; others ~0.6 em
_ADVANCE = {**dict.fromkeys("0123456789", 0.636), ".": 0.318, ",": 0.318, " ": 0.318, "−": 0.838, "-": 0.361,
            "+": 0.838, "(": 0.39, ")": 0.39, "Δ": 0.684, "i": 0.278, "l": 0.278, "t": 0.392, "r": 0.411,
            "f": 0.352, "j": 0.278, "m": 0.974, "w": 0.818, "A": 0.684, "B": 0.686, "F": 0.575, "P": 0.603,
            "R": 0.695, "=": 0.838, "%": 0.95}


def _text_px(text: str, size_pt: float) -> float:
    """The width (CSS px) of ``text`` in DejaVu Sans at ``size_pt``."""
    return sum(_ADVANCE.get(ch, 0.6) for ch in text) * size_pt * _PT


@dataclass
class SvgPanel:
    """One panel (axes) of an SVG figure (:func:`svg_figure`), in data coordinates.

    ``lines``: ``(xs, ys, colour, marker, marker_pt, width_pt, label)``, marker ``"o"``, ``"s"`` or
    ``""``; non-finite points are left out. ``bars``: ``(x, height, colour)``, 0.8 wide from 0.
    ``hlines`` / ``vlines``: ``(value, colour, width_pt)`` across the panel. ``xinteger``: integer
    ticks on x (``MaxNLocator(integer=True)``). ``yticks``: fixed ``(values, labels)`` on y.
    """

    lines: list[tuple[list[float], list[float], str, str, float, float, str]] = field(default_factory=list)
    bars: list[tuple[float, float, str]] = field(default_factory=list)
    hlines: list[tuple[float, str, float]] = field(default_factory=list)
    vlines: list[tuple[float, str, float]] = field(default_factory=list)
    xlabel: str = ""
    ylabel: str = ""
    xinteger: bool = False
    yticks: tuple[list[float], list[str]] | None = None
    legend: bool = False


def _scale_range(vmin: float, vmax: float, n: int) -> tuple[float, float]:
    dv = abs(vmax - vmin)
    meanv = (vmax + vmin) / 2
    offset = 0.0 if abs(meanv) / dv < 100 else math.copysign(10 ** (math.log10(abs(meanv)) // 1), meanv)
    return 10 ** (math.log10(dv / n) // 1), offset


def _ticks(vmin: float, vmax: float, nbins: int, *, integer: bool) -> list[float]:
    """matplotlib's ``MaxNLocator`` ticks of the view ``[vmin, vmax]`` (its ``_raw_ticks``): steps 1, 2,
    2.5, 5, 10 (``AutoLocator``), or those of ``MaxNLocator(integer=True)`` (at most 10 bins)."""
    if integer:
        base = np.array([1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10])
        nbins = 10
    else:
        base = np.array([1, 2, 2.5, 5, 10])
    steps = np.concatenate([0.1 * base[:-1], base, [10 * base[1]]])
    scale, offset = _scale_range(vmin, vmax, nbins)
    lo, hi = vmin - offset, vmax - offset
    steps = steps * scale
    if integer:
        steps = steps[(steps < 1) | (np.abs(steps - np.round(steps)) < 0.001)]
    raw = (hi - lo) / nbins
    istep = int(np.nonzero(steps >= raw)[0][0])
    ticks = np.zeros(0)
    for step in steps[:istep + 1][::-1]:
        if integer and math.floor(hi) - math.ceil(lo) >= 1:
            step = max(1.0, step)
        best = (lo // step) * step
        d, m = divmod(lo - best, step)
        low = d + 1 if abs(m / step - 1) < 1e-10 else d
        d, m = divmod(hi - best, step)
        high = d if abs(m / step) < 1e-10 else d + 1
        ticks = np.arange(low, high + 1) * step + best
        if int(((ticks <= hi) & (ticks >= lo)).sum()) >= 2:
            break
    return [float(t) for t in ticks + offset]


def _tick_format(locs: list[float]) -> Callable[[float], str]:
    """matplotlib's ``ScalarFormatter`` decimals for these ticks (the fewest that tell them apart), its
    minus sign U+2212."""
    arr = np.asarray(locs, dtype=float)
    span = float(np.ptp(arr)) if arr.size > 1 else (abs(float(arr[0])) if arr.size else 1.0)
    oom = math.floor(math.log10(span)) if span > 0 else 0
    sig = max(0, 3 - oom)
    thresh = 1e-3 * 10 ** oom
    while sig >= 0 and arr.size and float(np.abs(arr - np.round(arr, decimals=sig)).max()) < thresh:
        sig -= 1
    sig = min(sig + 1, 8)

    def fmt(v: float) -> str:
        s = f"{v:.{sig}f}"
        if float(s) == 0:
            s = s.lstrip("-")
        return s.replace("-", "−")

    return fmt


def _limits(values: list[float], sticky: list[float]) -> tuple[float, float]:
    """The autoscaled view of data spanning ``values``: matplotlib's 5 % margins (``axes.[xy]margin``),
    not past a sticky edge (a bar's 0) that bounds the data; a single value widened by 5 %."""
    lo, hi = min(values), max(values)
    if hi - lo <= 1e-15 * max(abs(lo), abs(hi), 1e-300):
        lo, hi = (-0.05, 0.05) if lo == 0 else (lo - 0.05 * abs(lo), hi + 0.05 * abs(hi))
    below = [s for s in sticky if s <= lo]
    above = [s for s in sticky if s >= hi]
    delta = (hi - lo) * 0.05
    lo2, hi2 = lo - delta, hi + delta
    if below:
        lo2 = max(lo2, max(below))
    if above:
        hi2 = min(hi2, min(above))
    return lo2, hi2


def _esc(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace("'", "&#39;")


def _num_svg(v: float) -> str:
    return f"{v:.2f}".rstrip("0").rstrip(".")


def svg_figure(panels: list[SvgPanel], *, width_in: float, height_in: float) -> str:
    """Side-by-side panels as one SVG document of ``width_in`` x ``height_in`` inches (100 CSS px an
    inch, as the sweep's PNGs are shown), laid out as matplotlib's constrained layout lays them out
    (equal panels, each with room for its tick labels and axis labels)."""
    W, H = width_in * _CSS_PX_PER_INCH, height_in * _CSS_PX_PER_INCH
    tick_font, label_font = float(_RC["xtick.labelsize"]), float(_RC["axes.labelsize"])
    line_h_tick, line_h_label = tick_font * _PT * 1.17, label_font * _PT * 1.17
    tick_out = (_TICK_PT + _TICK_PAD_PT) * _PT
    views = []
    for p in panels:
        xs = [x for xs_, _, *_ in p.lines for x in xs_] + [b[0] + s for b in p.bars for s in (-0.4, 0.4)]
        xs += [v[0] for v in p.vlines]
        ys = [y for _, ys_, *_ in p.lines for y in ys_] + [h for b in p.bars for h in (0.0, b[1])]
        ys += [v[0] for v in p.hlines]
        xs = [x for x in xs if math.isfinite(x)] or [0.0, 1.0]
        ys = [y for y in ys if math.isfinite(y)] or [0.0, 1.0]
        views.append((_limits(xs, []), _limits(ys, [0.0] if p.bars else [])))
    # the y tick labels' widths need the ticks, which need the panel's height: y first
    bottom = _FIG_PAD_PX + tick_out + line_h_tick + _LABEL_PAD_PT * _PT + line_h_label
    top = _FIG_PAD_PX + line_h_tick / 2
    ax_h = H - top - bottom
    yt: list[tuple[list[float], list[str]]] = []
    lefts = []
    for p, (_, (y0, y1)) in zip(panels, views, strict=True):
        if p.yticks is not None:
            vals, labels = p.yticks
        else:
            vals = _ticks(y0, y1, max(1, min(int(ax_h / _PT // (tick_font * 2)), 9)), integer=False)
            f = _tick_format(vals)
            labels = [f(v) for v in vals]
        shown = [(v, s) for v, s in zip(vals, labels, strict=True) if y0 - 1e-12 <= v <= y1 + 1e-12]
        yt.append(([v for v, _ in shown], [s for _, s in shown]))
        widest = max((_text_px(s, tick_font) for _, s in shown), default=0.0)
        lefts.append(tick_out + widest + (_LABEL_PAD_PT * _PT + line_h_label if p.ylabel else 0.0) + _FIG_PAD_PX)
    # room right of each panel for its last x tick label's half where it sticks out (found in two passes)
    rights = [_FIG_PAD_PX] * len(panels)
    xts: list[list[tuple[float, str]]] = []
    for _ in range(2):
        ax_w = (W - sum(lefts) - sum(rights)) / len(panels)
        xts = []
        for i, (p, ((x0, x1), _)) in enumerate(zip(panels, views, strict=True)):
            xv = _ticks(x0, x1, max(1, min(int(ax_w / _PT // (tick_font * 3)), 9)), integer=p.xinteger)
            f = _tick_format(xv)
            xts.append([(v, f(v)) for v in xv if x0 - 1e-12 <= v <= x1 + 1e-12])
            v, s = xts[-1][-1] if xts[-1] else (x1, "")
            rights[i] = _FIG_PAD_PX + max(0.0, _text_px(s, tick_font) / 2 - (x1 - v) / (x1 - x0) * ax_w)
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{_num_svg(W)}' height='{_num_svg(H)}' "
           f"viewBox='0 0 {_num_svg(W)} {_num_svg(H)}' font-family='{_FONT}'>",
           f"<rect width='{_num_svg(W)}' height='{_num_svg(H)}' fill='white'/>"]
    x_at = 0.0
    for p, ((x0, x1), (y0, y1)), (yv, ylab), left, right, xt in zip(panels, views, yt, lefts, rights, xts,
                                                                     strict=True):
        ax_x = x_at + left
        x_at = ax_x + ax_w + right

        def px(x: float, x0: float = x0, x1: float = x1, ax_x: float = ax_x) -> float:
            return ax_x + (x - x0) / (x1 - x0) * ax_w

        def py(y: float, y0: float = y0, y1: float = y1) -> float:
            return top + ax_h - (y - y0) / (y1 - y0) * ax_h

        out.append(f"<clipPath id='c{len(out)}'><rect x='{_num_svg(ax_x)}' y='{_num_svg(top)}' "
                   f"width='{_num_svg(ax_w)}' height='{_num_svg(ax_h)}'/></clipPath>")
        clip = f"c{len(out) - 1}"
        out.append(f"<g clip-path='url(#{clip})'>")
        for x, h, colour in p.bars:  # patches below the grid (axes.axisbelow: "line")
            ya, yb = sorted((py(0.0), py(h)))
            out.append(f"<rect x='{_num_svg(px(x - 0.4))}' y='{_num_svg(ya)}' width='{_num_svg(px(x + 0.4) - px(x - 0.4))}' "
                       f"height='{_num_svg(yb - ya)}' fill='{colour}'/>")
        grid = f"stroke='{_GRID}' stroke-opacity='{_RC['grid.alpha']}' stroke-width='{_num_svg(_RC['grid.linewidth'] * _PT)}'"
        for v, _ in xt:
            out.append(f"<line x1='{_num_svg(px(v))}' x2='{_num_svg(px(v))}' y1='{_num_svg(top)}' "
                       f"y2='{_num_svg(top + ax_h)}' {grid}/>")
        for v in yv:
            out.append(f"<line x1='{_num_svg(ax_x)}' x2='{_num_svg(ax_x + ax_w)}' y1='{_num_svg(py(v))}' "
                       f"y2='{_num_svg(py(v))}' {grid}/>")
        for v, colour, lw in p.hlines:
            out.append(f"<line x1='{_num_svg(ax_x)}' x2='{_num_svg(ax_x + ax_w)}' y1='{_num_svg(py(v))}' "
                       f"y2='{_num_svg(py(v))}' stroke='{colour}' stroke-width='{_num_svg(lw * _PT)}'/>")
        for v, colour, lw in p.vlines:
            out.append(f"<line x1='{_num_svg(px(v))}' x2='{_num_svg(px(v))}' y1='{_num_svg(top)}' "
                       f"y2='{_num_svg(top + ax_h)}' stroke='{colour}' stroke-width='{_num_svg(lw * _PT)}'/>")
        for xs_, ys_, colour, marker, ms, lw, _label in p.lines:
            pts = [(px(x), py(y)) for x, y in zip(xs_, ys_, strict=True) if math.isfinite(x) and math.isfinite(y)]
            if len(pts) > 1 and lw > 0:
                out.append("<polyline fill='none' stroke-linejoin='round' stroke-linecap='square' "
                           f"stroke='{colour}' stroke-width='{_num_svg(lw * _PT)}' points='"
                           + " ".join(f"{_num_svg(a)},{_num_svg(b)}" for a, b in pts) + "'/>")
            out += [_marker(marker, a, b, ms, colour) for a, b in pts if marker]
        out.append("</g>")
        # spines (left, bottom), ticks, tick labels, axis labels
        spine = f"stroke='black' stroke-width='{_num_svg(0.8 * _PT)}'"
        out.append(f"<line x1='{_num_svg(ax_x)}' x2='{_num_svg(ax_x)}' y1='{_num_svg(top)}' y2='{_num_svg(top + ax_h)}' "
                   f"{spine} stroke-linecap='square'/>")
        out.append(f"<line x1='{_num_svg(ax_x)}' x2='{_num_svg(ax_x + ax_w)}' y1='{_num_svg(top + ax_h)}' "
                   f"y2='{_num_svg(top + ax_h)}' {spine} stroke-linecap='square'/>")
        tick = _TICK_PT * _PT
        for v, s in xt:
            out.append(f"<line x1='{_num_svg(px(v))}' x2='{_num_svg(px(v))}' y1='{_num_svg(top + ax_h)}' "
                       f"y2='{_num_svg(top + ax_h + tick)}' {spine}/>")
            out.append(f"<text x='{_num_svg(px(v))}' y='{_num_svg(top + ax_h + tick_out + tick_font * _PT * 0.93)}' "
                       f"font-size='{_num_svg(tick_font * _PT)}' text-anchor='middle'>{_esc(s)}</text>")
        for v, s in zip(yv, ylab, strict=True):
            out.append(f"<line x1='{_num_svg(ax_x - tick)}' x2='{_num_svg(ax_x)}' y1='{_num_svg(py(v))}' "
                       f"y2='{_num_svg(py(v))}' {spine}/>")
            out.append(f"<text x='{_num_svg(ax_x - tick_out)}' y='{_num_svg(py(v) + tick_font * _PT * 0.36)}' "
                       f"font-size='{_num_svg(tick_font * _PT)}' text-anchor='end'>{_esc(s)}</text>")
        if p.xlabel:
            out.append(f"<text x='{_num_svg(ax_x + ax_w / 2)}' y='{_num_svg(H - _FIG_PAD_PX - line_h_label * 0.25)}' "
                       f"font-size='{_num_svg(label_font * _PT)}' text-anchor='middle'>{_esc(p.xlabel)}</text>")
        if p.ylabel:
            widest = max((_text_px(s, tick_font) for s in ylab), default=0.0)
            lx = ax_x - tick_out - widest - _LABEL_PAD_PT * _PT - line_h_label * 0.25
            out.append(f"<text transform='translate({_num_svg(lx)},{_num_svg(top + ax_h / 2)}) rotate(-90)' "
                       f"font-size='{_num_svg(label_font * _PT)}' text-anchor='middle'>{_esc(p.ylabel)}</text>")
        if p.legend:
            out += _legend(p, ax_x, top, ax_w, ax_h, px, py)
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _marker(marker: str, x: float, y: float, ms_pt: float, colour: str) -> str:
    """A marker of ``ms_pt`` points (its edge 1 pt, matplotlib's ``lines.markeredgewidth``) at ``(x, y)``."""
    r = ms_pt * _PT / 2
    edge = f"fill='{colour}' stroke='{colour}' stroke-width='{_num_svg(_PT)}'"
    if marker == "s":
        return f"<rect x='{_num_svg(x - r)}' y='{_num_svg(y - r)}' width='{_num_svg(2 * r)}' height='{_num_svg(2 * r)}' {edge}/>"
    return f"<circle cx='{_num_svg(x)}' cy='{_num_svg(y)}' r='{_num_svg(r)}' {edge}/>"


def _legend(p: SvgPanel, ax_x: float, top: float, ax_w: float, ax_h: float, px: Callable[[float], float],
            py: Callable[[float], float]) -> list[str]:
    """The panel's legend without a frame, where matplotlib's ``loc="best"`` puts it: of its places in
    its order, the first over the fewest data points and lines."""
    entries = [(c, m, ms, lw, label) for _, _, c, m, ms, lw, label in p.lines if label]
    if not entries:
        return []
    fs = float(_RC["legend.fontsize"])
    em = fs * _PT
    text_w = max(_text_px(e[4], fs) for e in entries)
    row = em * 1.17
    bw = (0.4 * 2 + 2.0 + 0.8) * em + text_w
    bh = len(entries) * row + (len(entries) - 1) * 0.5 * em + 0.8 * em
    pad = 0.5 * em
    xl, xc, xr = ax_x + pad, ax_x + (ax_w - bw) / 2, ax_x + ax_w - pad - bw
    yt_, yc, yb = top + pad, top + (ax_h - bh) / 2, top + ax_h - pad - bh
    places = [(xr, yt_), (xl, yt_), (xl, yb), (xr, yb), (xr, yc), (xl, yc), (xr, yc), (xc, yb), (xc, yt_), (xc, yc)]
    vertices: list[tuple[float, float]] = []
    paths: list[list[tuple[float, float]]] = []
    for xs_, ys_, *_ in p.lines:
        pts = [(px(x), py(y)) for x, y in zip(xs_, ys_, strict=True) if math.isfinite(x) and math.isfinite(y)]
        vertices += pts
        paths.append([(a + (c - a) * t, b + (d - b) * t) for (a, b), (c, d) in zip(pts, pts[1:], strict=False)
                      for t in np.linspace(0.0, 1.0, 41)])

    def bad(place: tuple[float, float]) -> int:
        """matplotlib's badness: the data vertices under the legend, and one per line crossing it."""
        x, y = place

        def inside(q: tuple[float, float]) -> bool:
            return x <= q[0] <= x + bw and y <= q[1] <= y + bh

        return sum(map(inside, vertices)) + sum(any(map(inside, path)) for path in paths)

    x, y = min(places, key=bad)
    out = []
    for i, (colour, marker, ms, lw, label) in enumerate(entries):
        cy = y + 0.4 * em + i * (row + 0.5 * em) + row / 2
        hx = x + 0.4 * em
        out.append(f"<line x1='{_num_svg(hx)}' x2='{_num_svg(hx + 2 * em)}' y1='{_num_svg(cy)}' y2='{_num_svg(cy)}' "
                   f"stroke='{colour}' stroke-width='{_num_svg(lw * _PT)}'/>")
        if marker:
            out.append(_marker(marker, hx + em, cy, ms, colour))
        out.append(f"<text x='{_num_svg(hx + 2.8 * em)}' y='{_num_svg(cy + em * 0.36)}' "
                   f"font-size='{_num_svg(em)}'>{_esc(label)}</text>")
    return out
