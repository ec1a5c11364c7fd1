"""``zcut accuracy LOG_OR_RESULTS.mcap``: true accuracy of z-cut, SOR, union and intersection (docs/accuracy.md),
and of ``learned``, the labelling assistant's model (``--learned DB`` or a ``--labels`` store holding one), only
on the frames it was not trained on (docs/labelling.md).

Predictions come from the pipeline, resolved and run as ``zcut replay`` runs it (the same options
resolve the same filter), or from a results file of ``zcut replay --out``; the truth from the log's
recorded truth (``--truth``: the paper's ``/ground_truth/off_surface`` by default where the log has it,
else the sensor's ``/ground_truth/outliers`` with its ``/ground_truth/outlier_kind``) or from an
annotator's labels (``--labels DB``; the report then says how much of each method's verdict fell on
pixels the annotator left undecided, and the labels' own agreement with the fits: the method ``explained``,
with the part model when known, else the edge-aware local surface). Counts are taken over the scored region (``--region``: ``zone``,
the pixels the filters judge, by default; ``valid``: every valid pixel).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from annotate.accuracy import AccuracyOptions
    from replay.logs.damage import Damage


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_pipeline_options, add_truth_option

    p.add_argument("log", type=Path, metavar="LOG_OR_RESULTS.mcap",
                   help="a log (predictions computed by the pipeline) or a results file of `zcut replay`")
    p.add_argument("--labels", type=Path, default=None, metavar="DB",
                   help="human labels (zcut annotate's SQLite file); default: the log's recorded truth (--truth)")
    p.add_argument("--annotator", default=None, help="whose labels (needed when the DB has several annotators)")
    p.add_argument("--agreement", nargs=2, metavar=("A", "B"), default=None,
                   help="instead: agreement of two annotators (IoU, Cohen's kappa over the pixels both reviewed)")
    p.add_argument("--region", default="zone",
                   help="the scored region: zone (default: what the filters judge) or valid (every valid pixel)")
    p.add_argument("--per-frame", action="store_true", help="also print the per-frame table")
    p.add_argument("--learned", type=Path, default=None, metavar="DB",
                   help="also score `learned`, the labelling assistant's newest model in this label store "
                        "(zcut labels train), on the frames it was not trained on (default: the --labels store, "
                        "when it holds a model)")
    p.add_argument("--by-displacement", action="store_true",
                   help="also give recall by displacement |Z - Z_GT| (<=1, 1-5, 5-30, >30 mm) from the log's "
                        "/ground_truth/depth (a log, not a results file)")
    add_truth_option(p)
    p.add_argument("--json", action="store_true", help="print the docs/accuracy.md JSON object instead of tables")
    add_pipeline_options(p)


def options_of(args: argparse.Namespace) -> AccuracyOptions:
    """The command line's options as :func:`annotate.accuracy.run` takes them."""
    from annotate.accuracy import AccuracyOptions
    from cli.commands.common import pipeline_options

    return AccuracyOptions(log=args.log, labels=args.labels, annotator=args.annotator,
                           agreement=tuple(args.agreement) if args.agreement else None, region=args.region,
                           learned=args.learned, by_displacement=args.by_displacement, truth=args.truth,
                           pipeline=pipeline_options(args))


def run(args: argparse.Namespace) -> int:
    from annotate.accuracy import AgreementResult, format_accuracy_table, format_agreement_table, report_json
    from annotate.accuracy import run as accuracy
    from replay.logs import layout

    result = accuracy(options_of(args))
    if isinstance(result, AgreementResult):
        rep = result.report
        print(report_json(rep, indent=None) if args.json else format_agreement_table(rep))
        return _status(result.damage)
    report = result.report
    if args.json:
        print(report_json(report))
    else:
        print(f"truth: {result.truth}; predictions: {result.predictions}")
        for note in result.notes:
            print(f"zcut: {note}", file=sys.stderr)
        if result.learned is not None:
            n_seen = result.learned_left_out
            print(f"learned: the assistant's model ({result.learned}), scored on the "
                  f"{len(report['frames']) - n_seen} frame(s) it was not trained on ({n_seen} left out)")
        print(format_accuracy_table(report, per_frame=args.per_frame))
        if args.labels is not None and "labels_vs_fits" not in report:
            print("labels against the fits: not known (a results file without explained's mask "
                  f"{layout.method_topic('explained')}: score the log itself, or replay it with --methods ...,explained)")
        if result.from_results:
            print("bin check: not known (a results file does not carry it; score the log itself to see "
                  "which frames' removal did not work)")
    return _status(result.damage)


def _status(damage: tuple[Damage, ...]) -> int:
    """Exit status 3 when the pass over the log lost frames (each loss printed as a warning)."""
    if damage:
        for d in damage:
            print(f"warning: {d.text}", file=sys.stderr)
        return 3
    return 0
