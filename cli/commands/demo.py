"""``zcut demo``: the whole job on the bundled synthetic sample, with its true accuracy.

Synthesises the sample log on first use (cached), replays the sample with its part-kind preset and
its own bin model (the ``bin_model.ply`` attachment every synthetic log carries; a sample cached
before logs carried one gets a model built once from 5 synthetic empty-bin scans), writes an .rrd
and a results MCAP, prints the per-frame table and the true accuracy of the z-cut and SOR against
the sample's exact truth (``--truth``: the paper's ``/ground_truth/off_surface`` by default, or the
sensor's ``/ground_truth/outliers``; docs/accuracy.md, "Two truths").
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.session import FrameRow
    from replay.pipeline.sinks import FrameSink
    from replay.pipeline.stages import FrameResult


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out-dir", default="out", metavar="DIR", help="where to write the .rrd and results (default ./out)")
    p.add_argument("--no-bin", action="store_true", help="skip the bin stages (z-cut on the whole frame)")
    p.add_argument("--full-detail", action="store_true", help="log full-resolution images and clouds to Rerun")
    p.add_argument("--json", action="store_true", help="print a JSON summary (replay + accuracy) instead of tables")
    from cli.commands.common import add_truth_option

    add_truth_option(p)


def run(args: argparse.Namespace) -> int:
    from replay.outputs import OutputPlan, config_path_for
    from replay.synth.log import sample_log_path

    out_dir = make_out_dir(Path(args.out_dir))
    rrd = out_dir / "zcut_demo.rrd"
    results = out_dir / "zcut_demo_results.mcap"
    # the demo replaces its own outputs in its own folder (never the sample it reads); a second demo
    # writing into the same folder meanwhile is refused before any work (the plan locks them until
    # they are written)
    with OutputPlan([sample_log_path()], force=True) as plan:
        for path, what in ((rrd, "the .rrd"), (results, "the results file")):
            plan.add(path, what)
            plan.add(config_path_for(path), f"the config beside {what}")
        return _demo(args, out_dir=out_dir, rrd=rrd, results=results)


def make_out_dir(out_dir: Path) -> Path:
    """The demo's folder, created if missing; as for a study's ``-o``, its parent must exist (a
    mistyped path is refused, not created)."""
    from replay.errors import ConfigError

    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"--out-dir {out_dir}: exists and is not a folder")
    parent = Path(os.path.abspath(out_dir)).parent
    if not parent.is_dir():
        raise ConfigError(f"--out-dir {out_dir}: the folder {parent} does not exist")
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as e:
        raise ConfigError(f"--out-dir {out_dir}: cannot create the folder: {e.strerror or e}") from None
    return out_dir


def _demo(args: argparse.Namespace, *, out_dir: Path, rrd: Path, results: Path) -> int:
    from annotate.accuracy import (
        accuracy_report,
        format_accuracy_table,
        frame_accuracy,
        jsonable,
    )
    from annotate.truth import SyntheticTruth, scored_region, synthetic_truth
    from cli.commands.replay import print_table_callbacks
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import BinModelChoice, bin_model_for, load_bin_model
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.sinks import BackgroundSinks, ConfigBeside, RerunSink, ResultsSink
    from replay.process import EXIT_DATA_LOSS
    from replay.synth.log import ensure_sample_bin_model, ensure_sample_log, sample_log_path

    err = sys.stderr

    def progress(i: int, n: int, sf: object, seconds: float) -> None:
        print(f"  synthesising scan {i + 1}/{n} ({seconds:.1f} s)", file=err, flush=True)

    if not sample_log_path().is_file():
        print(f"zcut: synthesising the sample log (once): {sample_log_path()}", file=err, flush=True)
    sample = ensure_sample_log(progress=progress)
    model_path: Path | None = None

    def sample_model(reader: LogReader) -> BinModelChoice:
        nonlocal model_path
        choice = bin_model_for(reader, None)
        if choice.model is not None:
            print("zcut: bin model: the sample's own (its bin_model.ply attachment)", file=err, flush=True)
            return choice
        print("zcut: bin model of the sample (built once from 5 synthetic empty-bin scans)", file=err, flush=True)
        model_path = ensure_sample_bin_model(progress=progress)
        return BinModelChoice(load_bin_model(model_path), "explicit")

    frames_acc = []
    on_start, on_frame_print = print_table_callbacks(json_mode=args.json, total=None)

    truth_src: SyntheticTruth | None = None

    def on_frame(frame: Frame, result: FrameResult, row: FrameRow) -> None:
        on_frame_print(frame, result, row)
        assert truth_src is not None  # chosen when the session opened
        t = truth_src.truth(frame, result.valid)
        if not isinstance(t, str):
            frames_acc.append(frame_accuracy(frame.index, frame.stamp_ns,
                                             {"zcut": result.zcut_outliers, "sor": result.sor_outliers},
                                             t.outliers, reviewed=t.reviewed, valid=result.valid,
                                             region=scored_region(result, "zone"), kinds=t.kind))

    session = ReplaySession.open(sample, choose_bin_model=None if args.no_bin else sample_model)
    # the paper's truth by default (a sample cached before it has only the sensor's: the report says so)
    truth_src = synthetic_truth(getattr(args, "truth", None), session.reader.mask_topics, sample) or SyntheticTruth()
    on_start(session, planned=session.reader.n_frames)
    sinks: list[FrameSink] = [RerunSink(rrd=rrd, full_detail=args.full_detail), ConfigBeside(rrd), ResultsSink(results),
                              ConfigBeside(results)]
    summary = session.run(BackgroundSinks(sinks), on_frame=on_frame)
    report = accuracy_report(frames_acc, region="zone", truth=truth_src.name) if frames_acc else None
    if args.json:
        print(json.dumps({"replay": summary.as_dict(), "accuracy": jsonable(report) if report else None}, indent=1))
    elif report is not None:
        print()
        print(f"True accuracy against the sample's exact truth, {truth_src.name}, over the zone the filters judge:")
        print(format_accuracy_table(report, per_frame=False))
        pz, ps = report["pooled"]["zcut"], report["pooled"]["sor"]
        print(f"\nz-cut found {pz['tp']} of {pz['tp'] + pz['fn']} true outliers "
              f"(recall {_pct(pz['recall'])}, precision {_pct(pz['precision'])}); "
              f"SOR found {ps['tp']} (recall {_pct(ps['recall'])}, precision {_pct(ps['precision'])}).")
        if (note := uninformative_note(report)) is not None:
            print(note)
    for name, written in summary.outputs.items():
        print(f"zcut: wrote {name}: {written}", file=err)
    print(next_steps(sample=sample, bin_model=model_path, rrd=rrd, results=results, out_dir=out_dir),
          file=sys.stdout if not args.json else err)
    if summary.damage:
        for d in summary.damage:
            print(f"warning: data loss: {d.text}", file=err)
        return EXIT_DATA_LOSS
    return 0


def next_steps(*, sample: Path, bin_model: Path | None, rrd: Path, results: Path, out_dir: Path) -> str:
    """The demo's last lines: the exact commands that go on from its own outputs (the viewer,
    labelling, true accuracy, a sweep, a batch)."""
    import shlex

    from cli.commands.replay import viewer_command

    here = Path(sys.executable).with_name("zcut")
    zcut = shlex.quote(str(here)) if here.is_file() else "zcut"

    def q(p: Path) -> str:
        return shlex.quote(str(p))

    model = f" --bin-model {q(bin_model)}" if bin_model is not None else ""
    steps = [
        ("every stage in the viewer (a browser: add --web-viewer)", f"{viewer_command()} {q(rrd)}"),
        ("label true outliers in a local page", f"{zcut} annotate {q(sample)}{model} --db "
         f"{q(out_dir / 'zcut_demo.labels.sqlite')} --annotator {shlex.quote(annotator_name())}"),
        ("true accuracy of the results file", f"{zcut} accuracy {q(results)}"),
        ("tune the z-cut and SOR parameters", f"{zcut} sweep {q(sample)}{model} -o {q(out_dir / 'sweep')} "
         "--step 0.1,0.2,0.4 --rho 0.035:0.105:3"),
        ("replay many logs (here one) on every core", f"{zcut} batch {q(sample)}{model} -o {q(out_dir / 'batch')}"),
    ]
    return "\nNext steps on the demo's own outputs:\n" + "\n".join(f"  # {what}\n  {cmd}" for what, cmd in steps)


#: An interval that holds this much of [0, 1] or more says nothing yet about the figure.
UNINFORMATIVE_WIDTH = 0.9


def uninformative_note(report: dict[str, Any]) -> str | None:
    """One line naming the pooled figures whose 95 % interval holds nearly all of [0, 1] (at the
    demo's 3 frames, every method's precision: ``0.933 [0.000, 1.000]``), None when there is none."""
    pooled = report.get("pooled") or {}
    by_figure: dict[str, list[str]] = {}
    for method, e in pooled.items():
        for figure, (lo, hi) in (e.get("ci95") or {}).items():
            if lo is not None and hi is not None and hi - lo >= UNINFORMATIVE_WIDTH:
                by_figure.setdefault(figure, []).append(method)
    if not by_figure:
        return None
    n = len(report.get("frames") or ())
    which = "; ".join(f"{figure} of {', '.join(methods)}" for figure, methods in by_figure.items())
    return (f"note: intervals uninformative at {n} frame{'s' if n != 1 else ''} ({which}: each holds "
            f"{UNINFORMATIVE_WIDTH * 100:.0f} % or more of [0, 1]); more frames narrow them, see docs/coverage.md")


def annotator_name() -> str:
    """A name for the suggested ``--annotator``: the login name (``$USER`` is empty in many
    containers), else ``me``; never an empty string."""
    import getpass

    try:
        name = getpass.getuser()
    except (OSError, KeyError):  # no login name in the environment and no passwd entry
        name = ""
    return name.strip() or "me"


def _pct(v: float | None) -> str:
    if v is None or v != v:
        return "-"
    return f"{100 * v:.1f} %"
