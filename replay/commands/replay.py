"""``zcut replay LOG.mcap``: every stage of the pipeline on every frame, logged to Rerun.

Progress goes to stderr, the per-frame table (or ``--json`` summary) to stdout.
"""

from __future__ import annotations

import argparse
import json
import math
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG.mcap", help="ROS 2 MCAP log with an organized PointCloud2")
    sink = p.add_mutually_exclusive_group()
    sink.add_argument("--rrd", metavar="OUT.rrd", help="write a Rerun recording (open with `rerun OUT.rrd`)")
    sink.add_argument("--spawn", action="store_true", help="spawn a Rerun viewer and stream to it")
    sink.add_argument("--connect", metavar="URL", help="stream to a running viewer (e.g. rerun+http://127.0.0.1:9876/proxy)")
    p.add_argument("--out", metavar="RESULTS.mcap", help="write results: /zcut/outliers, /zcut/sor_outliers, "
                   "/zcut/bin_mask, /zcut/filtered (+ ground truth passed through)")
    p.add_argument("--config", metavar="F.toml", help="pipeline config (TOML); see the resolved config beside outputs")
    p.add_argument("--step", type=float, metavar="MM", help="z-cut step Δd in mm (overrides the config)")
    p.add_argument("--max-depth", type=float, metavar="MM", help="z-cut depth d_max in mm (overrides the config)")
    p.add_argument("--max-area", type=float, metavar="PX", help="z-cut cluster area threshold μ_thr in pixels")
    p.add_argument("--preset", metavar="KIND", help="part-kind preset (spheres, zinc_nuts, rods, black_screws, "
                   "black_nuts, sprockets); synthetic logs choose theirs from their metadata")
    p.add_argument("--frames", metavar="A:B", help="frame index range (B exclusive), or N for one frame")
    p.add_argument("--topic", metavar="T", help="cloud topic (when the log has several)")
    p.add_argument("--bin-model", metavar="PLY", help="bin model (from `zcut bin-model` or a CAD PLY); "
                   "without it the bin stages are skipped")
    p.add_argument("--full-detail", action="store_true", help="log full-resolution images and clouds to Rerun")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of the table")


def viewer_command() -> str:
    """How to start the Rerun viewer: the ``rerun`` binary beside this Python (a venv install
    does not put it on PATH), else plain ``rerun``."""
    import shutil
    from pathlib import Path

    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and shutil.which("rerun") != str(beside):
        return str(beside)
    return "rerun"


def _fmt(v: float, spec: str) -> str:
    if isinstance(v, float) and math.isnan(v):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return format(v, spec)


HEADER = (f"{'frame':>5} {'stamp_ns':>19} {'valid px':>9} {'z-cut':>7} {'SOR':>7} {'both':>6} "
          f"{'α':>6} {'β_SOR':>6} {'β_zcut':>6} {'fitness':>7} {'RMSE mm':>7} {'time s':>6}")


def format_row(row) -> str:
    return (f"{row.index:>5} {row.stamp_ns:>19} {row.valid_px:>9} {row.zcut:>7} {row.sor:>7} {row.both:>6} "
            f"{_fmt(row.alpha, '6.3f'):>6} {_fmt(row.beta_sor, '6.3f'):>6} {_fmt(row.beta_zcut, '6.3f'):>6} "
            f"{_fmt(row.fitness, '7.3f'):>7} {_fmt(row.rmse_mm, '7.2f'):>7} {row.time_s:>6.2f}")


def print_table_callbacks(*, json_mode: bool, total: int | None, out=None, err=None):
    """(on_start, on_frame) printing notes, warnings and progress on stderr, rows on stdout."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    seen_warnings: set[str] = set()

    planned = [total]

    def on_start(summary) -> None:
        if summary.n_planned is not None:
            planned[0] = summary.n_planned
        for note in summary.resolved.notes:
            print(f"zcut: {note}", file=err)
        if not json_mode:
            print(HEADER, file=out, flush=True)

    def on_frame(frame, result, row) -> None:
        for w in result.warnings:
            if w not in seen_warnings:
                seen_warnings.add(w)
                print(f"warning: {w}", file=err)
        if result.registration is not None and not result.registration.converged:
            print(f"warning: frame {frame.index}: registration failed: {result.registration.reason}", file=err)
        n = f"/{planned[0]}" if planned[0] else ""
        print(f"[{len(seen_rows) + 1}{n}] frame {frame.index}: {row.time_s:.2f} s", file=err, flush=True)
        seen_rows.append(row.index)
        if not json_mode:
            print(format_row(row), file=out, flush=True)

    seen_rows: list[int] = []
    return on_start, on_frame


def run(args: argparse.Namespace) -> int:
    from replay.cli import EXIT_DATA_LOSS
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import parse_frames, replay_log

    frames = parse_frames(args.frames)
    overrides = cfg.cli_layer(step=args.step, max_depth=args.max_depth, max_area=args.max_area,
                              preset=args.preset)
    cfg.from_dict(overrides, source="command line")  # bad values fail before reading the log
    model = load_bin_model(args.bin_model) if args.bin_model else None
    total = None if frames[1] is None else frames[1] - frames[0]
    on_start, on_frame = print_table_callbacks(json_mode=args.json, total=total)
    summary, _ = replay_log(
        args.log, config_file=args.config, overrides=overrides, frames=frames, topic=args.topic,
        bin_model=model, rrd=args.rrd, spawn=args.spawn, connect=args.connect, out=args.out,
        full_detail=args.full_detail, on_start=on_start, on_frame=on_frame)
    if args.json:
        print(json.dumps(summary.as_dict(), indent=1))
    if not summary.rows and not summary.damage:
        from replay.errors import ConfigError

        have = f" (it has {summary.n_log_frames} frames)" if summary.n_log_frames is not None else ""
        raise ConfigError(f"no frame of {args.log} in --frames {args.frames or '0:'}{have}")
    for name, path in summary.outputs.items():
        print(f"zcut: wrote {name}: {path}", file=sys.stderr)
    if "rrd" in summary.outputs:
        print(f"zcut: open it with: {viewer_command()} {summary.outputs['rrd']}", file=sys.stderr)
    if summary.viewer_error:
        print(f"warning: {summary.viewer_error}", file=sys.stderr)
    if summary.damage:
        for d in summary.damage:
            print(f"warning: data loss: {d}", file=sys.stderr)
        print(f"zcut: {len(summary.rows)} intact frame(s) processed; the log is damaged", file=sys.stderr)
        return EXIT_DATA_LOSS
    return 0
