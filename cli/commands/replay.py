"""``zcut replay LOG.mcap``: every stage of the pipeline on every frame, logged to Rerun.

Progress goes to stderr, the per-frame table (or ``--json`` summary) to stdout.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from annotate.judge import TruthJudge
    from replay.logs.frame import Frame
    from replay.outputs import OutputPlan
    from replay.pipeline.session import FrameRow, ReplaySession
    from replay.pipeline.sinks import FrameSink
    from replay.pipeline.stages import FrameResult


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_force_option, add_pipeline_options, add_truth_option

    p.add_argument("log", metavar="LOG.mcap", help="ROS 2 MCAP log with an organized PointCloud2")
    sink = p.add_mutually_exclusive_group()
    sink.add_argument("--rrd", metavar="OUT.rrd", help="write a Rerun recording (open with `rerun OUT.rrd`)")
    sink.add_argument("--spawn", action="store_true", help="spawn a Rerun viewer and stream to it")
    sink.add_argument("--connect", metavar="URL", help="stream to a running viewer (e.g. rerun+http://127.0.0.1:9876/proxy)")
    p.add_argument("--out", metavar="RESULTS.mcap", help="write results: /zcut/outliers, /zcut/sor_outliers, "
                   "/zcut/bin_mask, /zcut/zone, /zcut/valid (+ ground truth passed through); ~0.1 MB a 1920x1200 "
                   "frame")
    p.add_argument("--out-cloud", action="store_true", help="also write the filtered cloud /zcut/filtered and "
                   "the image to --out (~33 MB a 1920x1200 frame; needed to replay or label a results file)")
    p.add_argument("--frames", metavar="A:B", help="the frames to replay by their 0-based index in the log (the first "
                   "is 0): A:B from A up to B exclusive, A: or :B, or N for frame N alone")
    p.add_argument("--full-detail", action="store_true", help="log full-resolution images and clouds to Rerun")
    p.add_argument("--labels", metavar="DB", help="with --rrd/--spawn/--connect: show where each filter is wrong "
                   "against an annotator's labels in this label store (a log with recorded truth shows it "
                   "against that truth without this option)")
    p.add_argument("--annotator", metavar="NAME", help="whose labels in --labels (needed when several annotators "
                   "labelled the log)")
    add_truth_option(p)
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of the table")
    add_force_option(p)
    add_pipeline_options(p)


def viewer_command() -> str:
    """How to start the Rerun viewer: the ``rerun`` binary beside this Python (a venv that is not
    activated does not have it on the shell's PATH), else plain ``rerun``, with its server bound to
    127.0.0.1 (Rerun listens on every interface by default)."""
    from pathlib import Path

    from replay.pipeline.viz import VIEWER_BIND

    beside = Path(sys.executable).with_name("rerun")
    return f"{beside if beside.is_file() else 'rerun'} --bind {VIEWER_BIND}"


def _fmt(v: float, spec: str) -> str:
    if isinstance(v, float) and math.isnan(v):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return format(v, spec)


HEADER = (f"{'frame':>5} {'stamp_ns':>19} {'valid px':>9} {'z-cut':>7} {'SOR':>7} {'both':>6} "
          f"{'α':>6} {'β_SOR':>6} {'β_zcut':>6} {'fitness':>7} {'RMSE mm':>7} {'bin chk':>7} {'time s':>6}")


def _bin_check(row: FrameRow) -> str:
    """The bin check's column: its figure (pixels), ``!`` when it flagged the frame, ``failed`` when
    the bin stages failed, ``-`` when they did not run."""
    if math.isnan(row.bin_check):
        return "failed" if row.bin_flagged else "-"
    return f"{row.bin_check:.0f}" + ("!" if row.bin_flagged else "")


def header(others: tuple[str, ...] = ()) -> str:
    """The table's header; ``others``: the other filter methods' columns (``--methods``)."""
    return HEADER + "".join(f" {m:>{max(len(m), 7)}}" for m in others)


def format_row(row: FrameRow) -> str:
    return (f"{row.index:>5} {row.stamp_ns:>19} {row.valid_px:>9} {row.zcut:>7} {row.sor:>7} {row.both:>6} "
            f"{_fmt(row.alpha, '6.3f'):>6} {_fmt(row.beta_sor, '6.3f'):>6} {_fmt(row.beta_zcut, '6.3f'):>6} "
            f"{_fmt(row.fitness, '7.3f'):>7} {_fmt(row.rmse_mm, '7.2f'):>7} {_bin_check(row):>7} {row.time_s:>6.2f}"
            + "".join(f" {n:>{max(len(m), 7)}}" for m, n in row.others.items()))


class OnStart(Protocol):
    """The ``on_start`` of :func:`print_table_callbacks`: called once the session is open."""

    def __call__(self, session: ReplaySession, *, planned: int | None = None) -> None: ...


def print_table_callbacks(*, json_mode: bool, total: int | None, out: IO[str] | None = None,
                          err: IO[str] | None = None
                          ) -> tuple[OnStart, Callable[[Frame, FrameResult, FrameRow], None]]:
    """(on_start, on_frame) printing notes, warnings and progress on stderr, rows on stdout."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    seen_warnings: set[str] = set()

    planned_ = [total]

    def on_start(session: ReplaySession, *, planned: int | None = None) -> None:
        if planned is not None:
            planned_[0] = planned
        for note in session.notes:
            print(f"zcut: {note}", file=err)
        if not json_mode:
            others = tuple(m for m in session.config.base_methods if m not in ("zcut", "sor"))
            print(header(others), file=out, flush=True)

    def on_frame(frame: Frame, result: FrameResult, row: FrameRow) -> None:
        for w in result.warnings:
            if w not in seen_warnings:
                seen_warnings.add(w)
                print(f"warning: {w}", file=err)
        if result.registration is not None and not result.registration.converged:
            print(f"warning: frame {frame.index}: registration failed: {result.registration.reason}", file=err)
        if result.bin_flagged and result.bin_check is not None:  # flagged: it has a check
            print(f"warning: frame {frame.index}: bin check: {result.bin_check.reason}", file=err)
        n = f"/{planned_[0]}" if planned_[0] else ""
        print(f"[{len(seen_rows) + 1}{n}] frame {frame.index}: {row.time_s:.2f} s", file=err, flush=True)
        seen_rows.append(row.index)
        if not json_mode:
            print(format_row(row), file=out, flush=True)

    seen_rows: list[int] = []
    return on_start, on_frame


def plan_outputs(args: argparse.Namespace, plan: OutputPlan) -> list[FrameSink]:
    """Check ``--rrd``/``--out`` (and the configs written beside them) with ``plan`` (an
    :class:`replay.outputs.OutputPlan`, which locks them) before any work; the sinks.

    ``--rrd r.rrd --out r.mcap`` share one config beside them (``r.config.toml``): the same
    resolved config, written once."""
    from replay.outputs import config_path_for
    from replay.pipeline.sinks import ConfigBeside, RerunSink, ResultsSink

    sinks: list[FrameSink] = []
    configs: set[str] = set()

    def config_beside(output: str, what: str) -> None:
        path = config_path_for(output)
        key = os.path.abspath(path)
        if key not in configs:  # one file for two outputs of one stem
            configs.add(key)
            plan.add(path, f"the config beside {what}")
            sinks.append(ConfigBeside(output))

    if args.rrd is not None:
        plan.add(args.rrd, "the .rrd")
        sinks.append(RerunSink(rrd=args.rrd, full_detail=args.full_detail))
        config_beside(args.rrd, "the .rrd")
    elif args.spawn or args.connect is not None:
        if args.connect is not None:
            check_viewer_url(args.connect)
        sinks.append(RerunSink(spawn=args.spawn, connect=args.connect, full_detail=args.full_detail))
    if args.out is not None:
        plan.add(args.out, "the results file")
        sinks.append(ResultsSink(args.out, cloud=getattr(args, "out_cloud", False)))
        config_beside(args.out, "the results file")
    return sinks


def check_viewer_url(url: str) -> None:
    """A ``--connect`` URL must be rerun+http(s)://HOST:PORT/proxy (or plain http)."""
    from urllib.parse import urlsplit

    from replay.errors import ConfigError

    try:
        u = urlsplit(url)
        port = u.port
    except ValueError:
        u, port = None, None
    if u is None or u.scheme not in ("rerun+http", "rerun+https", "rerun", "http", "https") or not u.hostname \
            or port is None:
        raise ConfigError(f"--connect {url!r}: expected a viewer URL like rerun+http://127.0.0.1:9876/proxy")
    import socket

    try:
        with socket.create_connection((u.hostname, port), timeout=3.0):
            pass
    except OSError as e:
        raise ConfigError(f"--connect {url}: no viewer listens at {u.hostname}:{port} ({e.strerror or e}); "
                          "start one with `rerun` or use --spawn") from None


def run(args: argparse.Namespace) -> int:
    from cli.commands.common import inputs_of, overrides_of
    from replay.outputs import OutputPlan
    from replay.pipeline.session import parse_frames

    frames = parse_frames(args.frames)
    overrides = overrides_of(args)  # bad values fail before the log is read
    labels = [args.labels] if getattr(args, "labels", None) else []
    with OutputPlan([args.log, *inputs_of(args), *labels], force=args.force) as plan:  # locked until the end
        return _replay(args, plan_outputs(args, plan), frames=frames, overrides=overrides)


def _replay(args: argparse.Namespace, sinks: list[FrameSink], *, frames: tuple[int, int | None],
            overrides: dict[str, Any]) -> int:
    from cli.commands.common import open_session

    session = open_session(args.log, args, overrides=overrides)
    judge = _judge(args, session, sinks)
    try:
        return _run_session(args, session, sinks, frames=frames, judge=judge)
    finally:
        if judge is not None:
            judge.close()


def _judge(args: argparse.Namespace, session: ReplaySession, sinks: list[FrameSink]) -> TruthJudge | None:
    """What the recording shows each filter's mistakes against: ``--labels`` (with ``--annotator``), else
    the log's recorded truth, else nothing (docs/compare.md, "Where each filter is wrong")."""
    from annotate.judge import judge_for_log
    from replay.errors import ConfigError
    from replay.pipeline.sinks import RerunSink

    labels, annotator = getattr(args, "labels", None), getattr(args, "annotator", None)
    truth = getattr(args, "truth", None)
    if not any(isinstance(s, RerunSink) for s in sinks):
        if labels is not None or annotator is not None or truth is not None:
            raise ConfigError("--labels/--annotator/--truth show where each filter is wrong in Rerun: "
                              "give --rrd, --spawn or --connect")
        return None
    if annotator is not None and labels is None:
        raise ConfigError("--annotator needs --labels DB")
    if truth is not None and labels is not None:
        raise ConfigError("--truth chooses the log's recorded truth: not with --labels")
    return judge_for_log(args.log, session.reader.mask_topics, session.config.methods, labels=labels,
                         annotator=annotator, truth=truth)


def _run_session(args: argparse.Namespace, session: ReplaySession, sinks: list[FrameSink], *,
                 frames: tuple[int, int | None], judge: TruthJudge | None) -> int:
    from replay.errors import ConfigError
    from replay.logs import layout
    from replay.pipeline.sinks import BackgroundSinks
    from replay.process import EXIT_DATA_LOSS

    if layout.RESULTS_METADATA in session.reader.metadata:
        src = session.reader.metadata[layout.RESULTS_METADATA].get("source", "?")
        print(f"warning: {args.log} is a results file of zcut replay (of {src}): its cloud is "
              f"{session.reader.cloud_topic}, with the outliers already removed", file=sys.stderr)
    total = None if frames[1] is None else frames[1] - frames[0]
    on_start, on_frame = print_table_callbacks(json_mode=args.json, total=total)
    planned = _planned(session, frames)
    if planned == 0:
        assert session.reader.n_frames is not None  # a planned count comes from the log's frame count
        raise ConfigError(f"no frame of {args.log} in --frames {args.frames or '0:'} "
                          f"(it has {_frames_held(session.reader.n_frames)})")
    on_start(session, planned=planned)
    if judge is not None:
        print(f"zcut: the recording shows where each filter is wrong against {judge.source}", file=sys.stderr)
    summary = session.run(BackgroundSinks(sinks), frames=frames, on_frame=on_frame, judge=judge)
    if args.json:
        print(json.dumps(summary.as_dict(), indent=1))
    if not summary.rows and not summary.damage:
        have = f" (it has {_frames_held(summary.n_log_frames)})" if summary.n_log_frames is not None else ""
        raise ConfigError(f"no frame of {args.log} in --frames {args.frames or '0:'}{have}")
    flagged = [r.index for r in summary.rows if r.bin_flagged]
    if flagged:
        shown = ", ".join(str(i) for i in flagged[:20]) + (" …" if len(flagged) > 20 else "")
        print(f"warning: {len(flagged)} of {len(summary.rows)} frame(s) flagged by the bin check (their counts rest "
              f"on a bin removal that did not work): {shown}", file=sys.stderr)
    for name, path in summary.outputs.items():
        print(f"zcut: wrote {name}: {path}", file=sys.stderr)
    if "rrd" in summary.outputs:
        print(f"zcut: open it with: {viewer_command()} {summary.outputs['rrd']} (it opens on the frame timeline; "
              "choose depth_um in the time panel's timeline menu to scrub the z-cuts)", file=sys.stderr)
    if summary.viewer_error:
        print(f"error: {summary.viewer_error}", file=sys.stderr)
        return 1
    if summary.damage:
        for d in summary.damage:
            print(f"warning: data loss: {d.text}", file=sys.stderr)
        print(f"zcut: {len(summary.rows)} intact frame(s) processed; the log is damaged", file=sys.stderr)
        return EXIT_DATA_LOSS
    return 0


def _frames_held(n: int) -> str:
    """``3 frames, 0..2`` (indices are 0-based: ``--frames 3`` of a 3-frame log is past its end)."""
    return f"{n} frame{'s' if n != 1 else ''}" + (f", indices 0..{n - 1}" if n > 1 else ", index 0" if n == 1 else "")


def _planned(session: ReplaySession, frames: tuple[int, int | None]) -> int | None:
    n = session.reader.n_frames
    if n is None:
        return None
    end = n if frames[1] is None else min(frames[1], n)
    return max(end - frames[0], 0)
