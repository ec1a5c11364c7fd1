"""``zcut batch INPUT… -o DIR``: replay every frame of many logs on all cores or a Ray cluster.

Writes ``DIR/frames.parquet`` (one row per frame) and ``DIR/summary.json``; ``--results`` and ``--rrd``
add one results MCAP and one .rrd per log under ``DIR/results`` and ``DIR/rrd``. Running it again over
the same DIR skips the frames already done (a log whose content changed since is refused, or starts
the study afresh with ``--force``); a damaged log does not stop the others (exit 3 at the end).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from studies.batch import BatchOptions
    from studies.summary import BatchSummary

FRAMES_PER_UNIT = 8


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_pipeline_options, add_truth_option

    p.add_argument("inputs", nargs="+", metavar="INPUT", help="MCAP logs or folders of them")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder (created; rerun to resume)")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: the cores; 0: run in this process, one unit after another)")
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster: its address, or `auto` (RAY_ADDRESS)")
    p.add_argument("--labels", metavar="DB", help="score against an annotator's labels (default: the logs' recorded truth, --truth)")
    p.add_argument("--annotator", help="whose labels (when the store has several)")
    add_truth_option(p)
    p.add_argument("--region", default="zone", help="scored region: zone (default, what the filters judge) or valid")
    p.add_argument("--results", action="store_true", help="also write a results MCAP per log (DIR/results)")
    p.add_argument("--results-cloud", action="store_true", help="with --results: also write the filtered cloud "
                   "and the image (as zcut replay --out-cloud; ~33 MB a 1920x1200 frame)")
    p.add_argument("--rrd", action="store_true", help="also write a Rerun .rrd per log (DIR/rrd)")
    p.add_argument("--frames-per-unit", type=int, default=FRAMES_PER_UNIT, metavar="N",
                   help=f"frames per unit of work: whole chunks of one log (default {FRAMES_PER_UNIT})")
    p.add_argument("--force", action="store_true", help="start afresh when an input log changed content since "
                   "the study in DIR began (its earlier results are removed; without it: refused)")
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    add_pipeline_options(p)


def options_of(args: argparse.Namespace) -> BatchOptions:
    """The command line's options as :func:`studies.batch.run` takes them."""
    from cli.commands.common import pipeline_options
    from studies.batch import BatchOptions

    return BatchOptions(inputs=tuple(args.inputs), out=args.out, pipeline=pipeline_options(args), labels=args.labels,
                        annotator=args.annotator, region=args.region, truth=args.truth, workers=args.workers, ray=args.ray,
                        frames_per_unit=args.frames_per_unit, force=args.force, results=args.results,
                        results_cloud=args.results_cloud, rrd=args.rrd)


def run(args: argparse.Namespace) -> int:
    from replay.process import EXIT_DATA_LOSS
    from studies import batch

    result = batch.run(options_of(args))
    summ, err = result.summary, sys.stderr
    for lg in summ.logs:
        for d in lg.damage:
            print(f"warning: data loss: {d}", file=err)
        for x in lg.errors:
            print(f"warning: {lg.log}: {x}", file=err)
    print(f"zcut: wrote {result.frames_path} ({result.table.num_rows} frames) and {result.summary_path}", file=err)
    if args.json:
        print(json.dumps(summ.to_json(), indent=1))
    else:
        _print_table(summ)
    return EXIT_DATA_LOSS if result.data_loss else 0


def _print_table(summ: BatchSummary) -> None:
    t = summ.totals
    print(f"{t.frames} frames of {t.logs} log(s): z-cut {t.zcut} px, SOR {t.sor} px, "
          f"both {t.both} px, above the rim {t.above_rim} px")
    if t.bin_flagged:
        print(f"warning: {t.bin_flagged} frame(s) flagged by the bin check ({t.bin_flagged_scored} of them scored): "
              "their counts rest on a bin removal that did not work (frames.parquet: bin_flagged, warnings)",
              file=sys.stderr)
    if summ.pooled:
        from studies.summary import truth_text

        print(f"true accuracy over the scored region ({summ.region}) against {truth_text(summ.truth)}, pooled:")
        sensor = [Path(lg.log).name for lg in summ.logs if lg.truth == "sensor"]
        if summ.truth is not None and "paper" in summ.truth and sensor:
            print(f"  (the sensor's truth for {len(sensor)} log(s) without /ground_truth/off_surface: "
                  f"{', '.join(sensor[:5])}{' …' if len(sensor) > 5 else ''})")
        print(f"  {'method':13s} {'precision':>22s} {'recall':>22s} {'F1':>22s}")
        for m, e in summ.pooled.items():
            cells = []
            for k in ("precision", "recall", "f1"):
                v, ci = getattr(e, k), e.ci95[k]
                cells.append("-" if v is None else f"{v:.3f} [{_f(ci[0])}, {_f(ci[1])}]" if _f(ci[0]) != "-"
                             else f"{v:.3f} [too few frames]")
            print(f"  {m:13s} " + " ".join(f"{c:>22s}" for c in cells))
    r = summ.this_run
    if r.frames:
        print(f"this run: {r.frames} frames in {r.seconds:.1f} s ({r.frames_per_s:.2f} frames/s, "
              f"{r.cpu_seconds_per_frame:.2f} CPU-s/frame) on {r.workers} worker(s) ({r.executor}), "
              f"peak {r.peak_rss_mb_per_worker:.0f} MB per worker")


def _f(v: float | None) -> str:
    return "-" if v is None or v != v else f"{v:.2f}"
