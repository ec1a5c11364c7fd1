"""Benchmark: full replay (bin mask, ICP, removal, z-cut, SOR, metrics) on 1920 x 1200 synthetic frames.

Run: ``.venv/bin/python bench/bench_replay.py [--frames N] [--kind KIND] [--dir DIR]``

Synthesises (once, cached in ``--dir``) a log of N filled-bin frames and five empty-bin scans at
the sensor's full size, builds the bin model, then replays the log three ways, each after a warm-up
frame (numba compilation, model caches):

- ``no viewer``: the pipeline only (reading the log included), frames/s; target >= 2;
- ``.rrd``: the same with every stage logged to Rerun (default detail); overhead vs no viewer,
  target <= 50 %; .rrd size per frame, target <= 10 MB;
- both ``--repeats`` times, alternating, and the medians compared (on a shared, loaded machine one
  run of each swings the overhead by tens of percent either way);
- the per-stage times of the no-viewer run (median over frames). The replay overlaps stages: the
  next frame is decoded, and its bin mask and registration run, while the removal, z-cut and SOR
  finish the current frame (and Rerun logging runs behind them), so the stage times (measured
  under that contention) do not add up to the frame time.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from replay.logs.reader import LogReader
from replay.pipeline.bin_model import build_bin_model, load_bin_model, save_bin_model
from replay.pipeline.session import ReplaySession
from replay.pipeline.sinks import BackgroundSinks, RerunSink
from replay.synth.log import write_synthetic_log

SIZE = (1200, 1920)


def prepare(d: Path, kind: str, frames: int) -> tuple[Path, Path]:
    d.mkdir(parents=True, exist_ok=True)
    log = d / f"bench_{kind}_{frames}x{SIZE[1]}x{SIZE[0]}.mcap"
    ply = d / f"bench_bin_{SIZE[1]}x{SIZE[0]}.ply"
    if not log.is_file():
        print(f"synthesising {frames} frames of {kind} at {SIZE[1]}x{SIZE[0]} -> {log}")
        write_synthetic_log(log, kind=kind, frames=frames + 1, seed=11, size=SIZE)
    if not ply.is_file():
        empty = d / "bench_empty.mcap"
        print(f"synthesising 5 empty-bin scans -> {empty}")
        write_synthetic_log(empty, empty=True, frames=5, seed=11, size=SIZE)
        model, _ = build_bin_model(LogReader(empty).frames())
        save_bin_model(model, ply)
    return log, ply


def timed_replay(log: Path, model, *, rrd: Path | None = None) -> tuple[float, float, int, list]:
    """Replay frames 1.. after frame 0 as warm-up; returns (wall s, CPU s, frames, timings)."""
    session = ReplaySession.open(log, bin_model=model)
    session.run(frames=(0, 1))  # warm-up: numba kernels
    timings = []
    if rrd is not None and rrd.exists():
        rrd.unlink()
    sink = BackgroundSinks([RerunSink(rrd=rrd)] if rrd is not None else [])
    t0, c0 = time.perf_counter(), time.process_time()
    summary = session.run(sink, frames=(1, None), on_frame=lambda f, r, row: timings.append(r.timings))
    return time.perf_counter() - t0, time.process_time() - c0, len(summary.rows), timings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of each; medians compared")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_replay"))
    args = ap.parse_args()
    d = Path(args.dir)
    log, ply = prepare(d, args.kind, args.frames)
    model = load_bin_model(ply)

    rrd = d / "bench.rrd"
    plain, logged = [], []
    for _ in range(max(args.repeats, 1)):
        plain.append(timed_replay(log, model))
        logged.append(timed_replay(log, model, rrd=rrd))
    t_plain, c_plain = statistics.median(p[0] for p in plain), statistics.median(p[1] for p in plain)
    t_rrd, c_rrd = statistics.median(p[0] for p in logged), statistics.median(p[1] for p in logged)
    n, n2, timings = plain[0][2], logged[0][2], plain[0][3]
    fps = n / t_plain
    overhead = t_rrd / t_plain - 1.0
    size_mb = rrd.stat().st_size / 1e6 / n2
    print(f"\n{n} frames of {args.kind}, {SIZE[1]}x{SIZE[0]}, bin model {len(model.points)} points")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (a loaded machine slows the wall times)")
    print(f"no viewer : {t_plain:7.2f} s  {fps:5.2f} frames/s   (target >= 2; ratio {fps / 2:.2f}); "
          f"CPU {c_plain / n:.2f} s/frame")
    print(f".rrd      : {t_rrd:7.2f} s  overhead {100 * overhead:5.1f} %   (target <= 50 %; ratio {overhead / 0.5:.2f}); "
          f"CPU overhead {100 * (c_rrd / c_plain - 1):.1f} %")
    print("  per repeat: " + ", ".join(f"{100 * (lg[0] / pl[0] - 1):.0f} %" for pl, lg in zip(plain, logged))
          + f" (medians of {len(plain)} alternating runs above)")
    print(f".rrd size : {size_mb:7.2f} MB per frame (target <= 10 MB; ratio {size_mb / 10:.2f})")
    print("\nmedian stage times (no viewer; bin_mask and registration overlap the other stages):")
    for stage in timings[0]:
        print(f"  {stage:13s} {1000 * statistics.median(t[stage] for t in timings):8.1f} ms")


if __name__ == "__main__":
    main()
