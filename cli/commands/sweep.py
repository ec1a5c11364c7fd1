"""``zcut sweep LOG… -o DIR``: a parameter study of the z-cut and SOR scored by true accuracy (docs/studies.md).

Writes ``DIR/sweep.parquet`` (one row per log × frame × parameter set × method), ``DIR/summary.json``
(pooled figures per set with 95 % intervals, the paper's relative figures, the tuned and the chosen
points), ``DIR/tuned.toml`` (a config ``zcut replay --config`` accepts), the plots (PNG) and
``DIR/report.html``. Running it again over the same DIR continues where it stopped.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from studies.summary import ParamSet, SweepSummary
    from studies.sweep import SweepOptions


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_pipeline_options, add_truth_option
    from studies.grid import DEFAULT_MAX_POINTS

    p.add_argument("inputs", nargs="+", metavar="LOG_OR_RESULTS.mcap", help="logs (or folders of them) with "
                   "synthetic truth, logs labelled in --labels, or results files of `zcut replay --out`")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder (created; rerun to continue)")
    g = p.add_argument_group(
        "the grid", "LIST: a,b,c or start:stop:count (inclusive, evenly spaced); values that agree to 1e-9 "
        "(relative, after rounding to 12 significant digits) are one value. An axis not given holds the "
        "config's value. Study points: unless --no-study-points, the d_max and ρ_thr axes also hold the "
        "config's own value and 0.5× and 1.5× it (ρ_thr ≤ 1), for the paper's sensitivity ratios ω and θ; so "
        "these two axes have three values when not given.")
    g.add_argument("--step", metavar="LIST", help="z-cut Δd values, mm")
    g.add_argument("--max-depth", metavar="LIST", help="z-cut d_max values, mm")
    g.add_argument("--rho", metavar="LIST", help="z-cut ρ_thr values (μ_thr = ρ_thr·a_max)")
    g.add_argument("--sor-k", metavar="LIST", help="SOR k values")
    g.add_argument("--sor-std", metavar="LIST", help="SOR std_ratio values")
    g.add_argument("--grid", action="append", metavar="SECTION.FIELD=LIST", default=None,
                   help="an axis of a filter of the bank (repeatable): e.g. radius.radius_mm=1,2,3, "
                   "radius.min_points=4,8; SECTION=default for the filter's default axes. The filter must be among "
                   "--methods; its other fields hold the config's values (docs/filters.md, 'The bank in a sweep')")
    g.add_argument("--no-study-points", dest="study_points", action="store_false",
                   help="the grid is exactly the values given (and the config's value on the axes not given): "
                   "no 0.5×/1.5× points (θ, ω and the paper's findings need them)")
    g.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS, metavar="N",
                   help=f"refuse grids larger than this without --force (default {DEFAULT_MAX_POINTS}); a LIST of "
                   "more values is refused before it is expanded")
    g.add_argument("--force", action="store_true", help="run a grid larger than --max-points; start afresh when "
                   "an input log changed content since the study in DIR began (its earlier results are removed)")
    p.add_argument("--objective", default="f1",
                   help="what tuned.toml maximises: f1 (default), recall@precision=P or precision@recall=R")
    p.add_argument("--labels", metavar="DB", help="score against an annotator's labels (default: the logs' recorded truth, --truth)")
    p.add_argument("--annotator", help="whose labels (when the store has several)")
    add_truth_option(p)
    p.add_argument("--region", default="zone", help="scored region: zone (default) or valid")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: the cores; 0: run in this process, one unit after another)")
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster: its address, or `auto`")
    p.add_argument("--frames-per-unit", type=int, default=4, metavar="N", help="frames per unit of work (default 4)")
    p.add_argument("--no-report", action="store_true", help="skip the plots and report.html")
    add_pipeline_options(p, zcut=False)


def options_of(args: argparse.Namespace) -> SweepOptions:
    """The command line's options as :func:`studies.sweep.run` takes them."""
    from cli.commands.common import pipeline_options
    from studies.sweep import SweepOptions

    return SweepOptions(inputs=tuple(args.inputs), out=args.out, pipeline=pipeline_options(args), labels=args.labels,
                        annotator=args.annotator, region=args.region, truth=args.truth, workers=args.workers, ray=args.ray,
                        frames_per_unit=args.frames_per_unit, force=args.force, step=args.step,
                        max_depth=args.max_depth, rho=args.rho, sor_k=args.sor_k, sor_std=args.sor_std,
                        grid=tuple(args.grid or ()), study_points=args.study_points, max_points=args.max_points,
                        objective=args.objective, report=not args.no_report)


def run(args: argparse.Namespace) -> int:
    from replay.process import EXIT_DATA_LOSS
    from studies import sweep

    result = sweep.run(options_of(args))
    if result.summary is None:
        print(f"error: no frame was scored, because a unit of work failed: {result.failure}", file=sys.stderr)
        return EXIT_DATA_LOSS
    _print(result.summary, result.tuned_path)
    return EXIT_DATA_LOSS if result.data_loss else 0


def _print(summary: SweepSummary, tuned_path: Path | None) -> None:
    def row(name: str, e: ParamSet | None) -> str:
        if e is None:
            return f"  {name:10s} -"
        cells = []
        for k in ("precision", "recall", "f1"):
            v, (lo, hi) = e.figure(k), e.ci(k)
            cells.append("-" if v is None else f"{v:.3f} [{lo:.3f}, {hi:.3f}]" if lo is not None and hi is not None
                         else f"{v:.3f} [too few frames]")
        params = (f"Δd {e.step_mm:g} d_max {e.max_depth_mm:g} ρ {e.rho_thr:g}" if e.method == "zcut"
                  else f"k {e.sor_k} std {e.sor_std_ratio:g}")
        return f"  {name:10s} {params:32s} " + "  ".join(f"{c:>22s}" for c in cells)

    from studies.summary import truth_text

    print(f"{summary.frames} frame(s) scored over the {summary.region} region against {truth_text(summary.truth)}; "
          f"objective {summary.objective}")
    if summary.bin_flagged:
        shown = ", ".join(str(f) for f in summary.bin_flagged[:10])
        print(f"warning: {len(summary.bin_flagged)} scored frame(s) flagged by the bin check (their scores rest on "
              f"a bin removal that did not work): {shown}" + (" …" if len(summary.bin_flagged) > 10 else ""),
              file=sys.stderr)
    print(f"  {'':10s} {'parameters':32s} " + "  ".join(f"{h:>22s}" for h in ("precision", "recall", "F1")))
    print(row("chosen", summary.chosen_zcut))
    print(row("nominal", summary.nominal))
    print(row("tuned", summary.tuned.zcut))
    print(row("SOR chosen", summary.chosen_sor))
    print(row("SOR tuned", summary.tuned.sor))
    if summary.tuned.note:
        print(f"note: {summary.tuned.note}")
    for line in summary.validation.messages() if summary.validation is not None else ():
        print(f"tuning: {line}")
    if tuned_path is not None:
        print(f"tuned config: {tuned_path}")
