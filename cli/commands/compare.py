"""``zcut compare LOG… --a A --b B -o DIR``: two filters on the same frames, pixel by pixel, with a
paired verdict (docs/compare.md). A and B: a config file, a method name or a results file.

Writes ``DIR/compare.json``, ``DIR/summary.parquet``, ``DIR/report.html``, ``DIR/compare.rrd`` and
``DIR/disagreement.npz`` (:func:`studies.compare.run`) and prints the one-line verdict. The frames run
as ``zcut batch``'s do: in units on local processes (``--workers``) or a Ray cluster (``--ray``), kept in
``DIR/parts``; running it again over an interrupted DIR runs only the units not done.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: as :data:`studies.compare.FRAMES_PER_UNIT` (not imported: ``--help`` stays light)
FRAMES_PER_UNIT = 8


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_truth_option

    p.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP logs (the same frames for A and B)")
    p.add_argument("--a", required=True, metavar="A",
                   help="the reference: a config file (TOML), a method name (zcut, sor, radius, …) or a results "
                        "file of `zcut replay --out`")
    p.add_argument("--b", required=True, metavar="B", help="the candidate, as --a")
    p.add_argument("-o", "--out", required=True, type=Path, metavar="DIR", help="output folder (created)")
    p.add_argument("--labels", type=Path, metavar="DB", help="score against an annotator's labels "
                   "(default: the log's recorded truth, --truth; without either: agreement only)")
    p.add_argument("--annotator", help="whose labels (when the store has several)")
    add_truth_option(p)
    p.add_argument("--region", default="zone", help="scored region: zone (default) or valid")
    p.add_argument("--bin-model", type=Path, metavar="PLY", help="bin model (default: the log's attachment)")
    p.add_argument("--topic", metavar="T", help="cloud topic (when the log has several)")
    p.add_argument("--part-model", type=Path, metavar="FILE", help="the part's mesh (PLY, STL or OBJ) for the "
                   "method explained (default: the log's part_model.ply attachment)")
    p.add_argument("--part-model-unit", choices=("mm", "m"), default="mm",
                   help="the unit of --part-model's vertices (default mm)")
    p.add_argument("--frames", metavar="A:B", help="frame range (as zcut replay's)")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: the cores; "
                   "0: run in this process, one unit after another)")
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster: its address, or `auto` (RAY_ADDRESS)")
    p.add_argument("--frames-per-unit", type=int, default=FRAMES_PER_UNIT, metavar="N",
                   help=f"frames per unit of work: whole chunks of one log (default {FRAMES_PER_UNIT})")
    p.add_argument("--no-rrd", action="store_true", help="do not write compare.rrd")
    p.add_argument("--json", action="store_true", help="print compare.json to stdout")
    p.add_argument("--force", action="store_true", help="replace existing outputs (the units done in DIR are "
                   "kept); start afresh when an input log changed content since the comparison in DIR began")


def run(args: argparse.Namespace) -> int:
    import json

    from annotate.accuracy import jsonable
    from replay.pipeline.session import parse_frames
    from replay.process import EXIT_DATA_LOSS
    from studies.compare import CompareOptions
    from studies.compare import run as compare

    opts = CompareOptions(logs=tuple(args.logs), a=args.a, b=args.b, out=args.out, labels=args.labels,
                          annotator=args.annotator, region=args.region, bin_model=args.bin_model, topic=args.topic,
                          part_model=args.part_model, part_model_unit=args.part_model_unit,
                          frames=parse_frames(args.frames), force=args.force, rrd=not args.no_rrd, truth=args.truth,
                          workers=args.workers, ray=args.ray, frames_per_unit=args.frames_per_unit)
    result = compare(opts)
    rep = result.report
    for log in rep["logs"]:
        for n in log["notes"]:
            print(f"warning: {n}", file=sys.stderr)
        for d in log["damage"]:
            print(f"warning: data loss: {d}", file=sys.stderr)
    if not rep["verdict"].get("truth"):
        print("zcut: no truth: agreement only (give --labels DB for a verdict)", file=sys.stderr)
    print(f"zcut: wrote {', '.join(result.outputs.values())}", file=sys.stderr)
    cost = rep["cost"]
    if cost.get("frames_this_run"):
        per = cost["cpu_s_per_frame"]
        print(f"zcut: this run: {cost['frames_this_run']} frames in {cost['wall_s']:.1f} s"
              + (f", {per:.2f} CPU-s/frame" if per is not None else "")
              + f" on {cost['workers']} worker(s) ({cost['executor']})", file=sys.stderr)
    if args.json:
        print(json.dumps(jsonable(rep), indent=1))
    else:
        ag = rep["agreement"]
        if rep.get("truth"):  # which truth scored it (docs/accuracy.md, "Two truths")
            t = rep["truth"]
            print(f"truth: {t if isinstance(t, str) else '; '.join(t)}")
        print(rep["verdict"]["line"])
        print(f"removed by both {ag['both']} px, only by A {ag['only_a']} px, only by B {ag['only_b']} px "
              f"(Jaccard {_f(ag['jaccard'])}); {rep['blobs_total']} disagreement blobs")
    return EXIT_DATA_LOSS if result.data_loss else 0


def _f(v: float | None) -> str:
    return "-" if v is None or v != v else f"{v:.3f}"
