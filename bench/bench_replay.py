"""Benchmark: full replay (bin mask, ICP, removal, z-cut, SOR, metrics) on 1920 x 1200 synthetic frames.

Run: ``.venv/bin/python bench/bench_replay.py [--frames N] [--kind KIND] [--dir DIR] [--stages] [--against OLD]``
(or ``--stages-only --log LOG.mcap [--against OLD] [--repeats N]`` for the cost per stage of an existing log, the
two trees alternating N times, and ``--bin-stages --log LOG.mcap --against OLD [--repeats N]`` for its bin stages
alone)

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
- "Cost per stage" (``--stages``): CPU ms per frame of every stage, the stages run one after the
  other in this thread (the stage timers of :mod:`replay.pipeline.stages` read
  ``time.process_time``, which counts numba's worker threads too; nothing else runs meanwhile),
  medians over the frames after a warm-up one. ``--against DIR`` runs the same measurement on the
  source tree DIR (e.g. the previous release: ``git archive 1f542c6 | tar -x -C DIR``) in a
  subprocess of the same run and prints the ratio old / new per stage. ``--stages-only`` skips
  the frames/s and .rrd measurements; with ``--log LOG --against DIR`` the two trees alternate ``--repeats``
  times (one subprocess a run, the order swapped every other repetition): medians of the runs, every run's
  total and the paired runs' ratios previous / this (a lever's bar reads the median and the least of them).
  The machine is shared: CPU time, not wall time, is compared.
- "Stage table" (``--table``, issue 32 item 8): the cost per stage above, CPU ms and wall ms (each
  stage's timer read with ``time.process_time`` on one pass over the frames, with
  ``time.perf_counter`` on a second), for every size of ``--sizes`` (default 640x480, 1280x800,
  1920x1200, 3840x2400: one synthetic log each, cached in ``--dir``, replayed with its own bin
  model attachment) and every core count of ``--cores`` (default 1 and 2: the measuring subprocess
  pins itself with ``os.sched_setaffinity`` and runs numba with as many threads). Each row also says
  the CPU cost per Mpx and its ratio to the 1920x1200 row's (1.00: cost proportional to pixels;
  issue 32 item 4 asks for 0.75-1.25), and with ``--against DIR`` the previous tree's CPU ms and
  the ratio previous / this, measured in the same run. ``docs/performance.md`` holds the budget per
  stage and a run's figures.
- "Whole replay" (``--throughput [--log LOG] [--against DIR] [--repeats N] [--outputs none,rrd,out,rrd+out]``,
  issue 32, both cores):
  ``ReplaySession.run`` over the log's frames after a warm-up one (no outputs; the replay's own
  threads: the reader, the locator, frames in flight), CPU s and wall s per frame, for this tree with
  one frame in flight and with two, and for the tree DIR, alternating N times in subprocesses, medians
  and every run's figures, with the load average: on a shared machine the wall times are indicative
  only. ``--outputs rrd,out,rrd+out`` adds this tree (and DIR) with those outputs (``zcut replay``'s sinks in
  their background thread, written to a temporary folder and closed), and every row says the frames/s
  bound of two fully used cores, 2 / (CPU s a frame). This tree's children run under the numba threading
  layer its ``configure_process`` chooses (``--layers workqueue``: also under that layer, the one chosen before
  the round of 2026-12-05d, 1 and 2 frames in flight), and so do the previous tree's, 1 and 2 frames in flight
  (before the round of 2026-12-05e: under workqueue, its default number); every row says its
  layer, the busiest thread's CPU s a frame (``/proc/self/task``, sampled at each frame) and the bound of two
  quiet cores, 1 / max(CPU s a frame / 2, the busiest thread's).
  The measuring children (these, ``--threads`` and the stage table's) set their process up as ``zcut replay``
  does (``replay.process.configure_process`` of their tree: its malloc settings decide how many pages a stage
  faults in). ``--warm-passes N``: N whole passes over the log's frames before the measured one (the
  same session), so that a short log is measured as a long log's later frames (buffers reused).
- "Threads" (``--threads --log LOG [--against DIR] [--repeats N] [--warm-passes N] [--in-flight N]``): where a
  whole replay's CPU goes, per thread (the reader, the chunk readers, the locator, the main thread, SOR's, the
  native threads of numba, OpenCV and OpenBLAS): user and system CPU ms and minor page faults per frame, from
  ``/proc/self/task``, this tree and DIR alternating, each under its own threading layer, N frames in flight
  (default: each tree's own default) (docs/performance.md, "The replay outside its stages"); and where they
  wait (docs/performance.md, "Where the last core-fraction waits"): a tracer thread samples, every 5 ms, every
  thread's run time and run-queue wait (``schedstat``), its state and, for Python's threads, the place in zcut's
  code it is at (``sys._current_frames``), so that each thread group's wall splits into running, waiting for a
  core and off the CPU, the last by place (a queue, a future, a lock, a kernel's line: blocked there on the GIL
  or a native wait); the frames' pieces in time (read, locate, bin stages, methods, delivery); and what the run
  implies for two quiet cores (:func:`quiet_estimate`: each 50 ms of the run did its work with the threads
  ready then, at most two at a time).
- "Timeline" (``--timeline --log LOG [--against DIR] [--repeats N] [--warm-passes N] [--in-flight N]
  [--timeline-save DIR]``, issue 32 item 1: where the second core idles): the ``--threads`` tracer keeping every
  sample (each thread's run time, run-queue wait, state and place), this tree and DIR alternating; per run the idle
  share of two quiet cores (:func:`idle_causes`: each sample as long as its work takes on two quiet cores, the
  missing core-fraction credited to the frame workers' states: busy, waiting for a location, for SOR's threads, off
  the CPU in a kernel call, idle; and the main thread's when neither works), split into the pass's start, middle and
  end, and the last run's timeline per thread in 20 ms characters. On a loaded machine every thread also waits for a
  core: the estimate then counts fewer idle cores than two quiet ones would have (read it as an attribution).
- "Fixed costs" (``--startup --log LOG [--against DIR] [--repeats N]``, issue 32 item 2): ``zcut replay
  LOG`` as a user runs it (``python -m cli``, a fresh process), with ``--frames 0:1`` and over all N
  frames, for this tree and DIR alternating N times. The CPU s of a process (user + sys of all its
  threads, interpreter start and teardown included, from ``os.wait4``) is F + n f for n frames: f =
  (T(N) - T(1)) / (N - 1), F = T(1) - f is what the process spends besides its frames (the imports,
  numba loading its cached kernels, opening the log, the bin model, the seed registration, the first
  frame's extra cost), and F / T(N) is the share before the first frame (issue: <= 20 %). Also the
  wall s until the first frame's progress line, ``zcut --help``, ``zcut replay --help`` and ``zcut
  accuracy --help`` (CPU s), the floor (a process that imports the libraries a replay cannot do without
  and loads one cached kernel: ``FLOOR_CODE``) and the share of T(N) before the first frame were F
  only that floor, the load average, and the ratio DIR / this tree. The child processes may write their .pyc files
  (``PYTHONDONTWRITEBYTECODE`` is dropped for them: an installed zcut has its bytecode compiled).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

if any(mode in sys.argv for mode in ("--throughput-json", "--threads-json", "--stage-json", "--timeline-json")):
    # a measuring child (a whole replay, its threads, or the stage table): the process set up as `zcut replay`
    # sets it up, before numba, OpenCV and Open3D load (the tree's own replay.process.configure_process)
    from replay.process import configure_process

    configure_process()

from replay.logs.reader import LogReader
from replay.pipeline.bin_model import build_bin_model, load_bin_model, save_bin_model
from replay.pipeline.session import ReplaySession
from replay.pipeline.sinks import BackgroundSinks, RerunSink
from replay.synth.log import write_synthetic_log

SIZE = (1200, 1920)
#: the sizes of the stage table, (H, W): the issue's four, 640x480 to 3840x2400
TABLE_SIZES = ((480, 640), (800, 1280), (1200, 1920), (2400, 3840))


def table_log(d: Path, kind: str, frames: int, size: tuple[int, int]) -> Path:
    """A synthetic log of ``frames`` + 1 frames at ``size`` (H, W), with its bin model attachment
    (made once, cached in ``d``)."""
    d.mkdir(parents=True, exist_ok=True)
    log = d / f"table_{kind}_{frames}x{size[1]}x{size[0]}.mcap"
    if not log.is_file():
        print(f"synthesising {frames + 1} frames of {kind} at {size[1]}x{size[0]} -> {log}", flush=True)
        tmp = log.with_suffix(".tmp.mcap")
        write_synthetic_log(tmp, kind=kind, frames=frames + 1, seed=11, size=size)
        tmp.replace(log)
    return log


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


STAGES = ("read", "bin_mask", "registration", "removal", "zcut", "sor", "metrics", "total")


def stage_costs(log: Path, ply: Path | None, *, clock: str = "cpu", bin_only: bool = False) -> dict[str, float]:
    """CPU ms (``clock`` "cpu") or wall ms ("wall") per frame of every stage (medians over frames 1..;
    frame 0 warms up), stages run serially; the bin model ``ply``, else the log's own. ``bin_only``: the bin
    stages only (``stages.bin_zone``: bin mask, registration, removal and its check; no method runs, the
    other stages read 0 and ``total`` is the read and the bin stages). BLAS runs on one thread, as the replay
    runs it."""
    import types

    from replay.pipeline import stages
    from replay.pipeline.bin_model import bin_model_for

    if ply is not None:
        session = ReplaySession.open(log, bin_model=load_bin_model(ply))
    else:
        session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    now = time.process_time if clock == "cpu" else time.perf_counter
    if clock == "cpu":
        stages.time = types.SimpleNamespace(perf_counter=time.process_time)  # type: ignore[attr-defined]  # the stage timers count CPU seconds (all threads)
    rows: list[dict[str, float]] = []
    height = width = 0
    frames = session.reader.frames()
    # BLAS on one thread, as ReplaySession.run has it (a multi-threaded BLAS spins in small products: without the
    # limit the removal's figures here were inflated, h/regrem)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    while True:
        t = now()
        frame = next(frames, None)
        read = now() - t
        if frame is None:
            break
        t = now()
        located = stages.locate_bin(frame, session.config, bin_model=session.prepared, seed=session.seed)
        if bin_only:
            z = stages.bin_zone(frame, session.config, bin_model=session.prepared, located=located)
            rows.append({"read": read, **z.timings, "total": read + now() - t})
        else:
            r = stages.run_frame(frame, session.config, bin_model=session.prepared, located=located)
            rows.append({"read": read, **r.timings, "total": read + r.timings["total"]})
        height, width = frame.xyz.shape[:2]
    rows = rows[1:] or rows
    return ({k: 1000 * statistics.median(row.get(k, 0.0) for row in rows) for k in STAGES}
            | {"frames": len(rows), "width": width, "height": height})


def print_stage_table(new: dict[str, float], old: dict[str, float] | None) -> None:
    size = f"{int(new['width'])}x{int(new['height'])}" if "width" in new else f"{SIZE[1]}x{SIZE[0]}"
    print(f"\ncost per stage, CPU ms per {size} frame (medians of {int(new['frames'])} frames; stages "
          "run one after the other)")
    head = f"  {'stage':13s} {'this tree':>10s}"
    if old is not None:
        head += f" {'previous':>10s} {'previous/this':>14s}"
    print(head)
    for k in STAGES:
        line = f"  {k:13s} {new[k]:10.1f}"
        if old is not None:
            line += f" {old[k]:10.1f} {old[k] / new[k] if new[k] else float('nan'):14.2f}"
        print(line)


#: the measuring children's modes (this script run with the code of another tree): one JSON line each
CHILD_MODES = ("--stage-json", "--throughput-json", "--threads-json", "--timeline-json")


def child_json(tree: Path, mode: str, *args: str, env: dict[str, str] | None = None, layer: str | None = None) -> dict:
    """Run this script as a measuring child with the code of the source tree ``tree`` (its ``PYTHONPATH`` and
    working folder; numba's workqueue threads, as ``zcut`` chose them before the round of 2026-12-05d) in ``mode``
    (:data:`CHILD_MODES`) with ``args``, ``env`` added to its environment; returns the JSON object of the last
    line it printed (:func:`child_main` prints it). ``layer``: numba's threading layer instead, "default" for the
    one the tree's ``configure_process`` chooses."""
    import json
    import subprocess

    assert mode in CHILD_MODES
    full = dict(os.environ, PYTHONPATH=str(tree), **(env or {}))
    if layer is None:
        full.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")  # as `zcut` set it
    else:
        for name in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"):
            full.pop(name, None)
        if layer != "default":
            full["NUMBA_THREADING_LAYER"] = layer
    out = subprocess.run([sys.executable, __file__, mode, *args], env=full, cwd=str(tree), check=True,
                         capture_output=True, text=True).stdout
    result: dict = json.loads(out.strip().splitlines()[-1])
    return result


def stage_costs_of_tree(tree: Path, log: Path, ply: Path | None, *, cores: int | None = None,
                        clock: str = "cpu", bin_only: bool = False) -> dict[str, float]:
    """:func:`stage_costs` with the code of the source tree ``tree`` (a subprocess; this script's own
    copy of the function runs against that tree's modules), pinned to ``cores`` cores (numba runs as
    many threads) when given."""
    extra = ["--clock", clock]
    env = {}
    if cores is not None:
        env["NUMBA_NUM_THREADS"] = str(cores)
        extra += ["--pin", str(cores)]
    if bin_only:
        extra.append("--bin-stages")
    return child_json(tree, "--stage-json", str(log), str(ply or "-"), *extra, env=env)


def stage_table(logs: dict[tuple[int, int], Path], cores: list[int], against: Path | None) -> None:
    """Print the stage table: per size and core count, CPU and wall ms per stage, CPU ms per Mpx and
    its ratio to the 1920x1200 row, and the previous tree's CPU ms with the ratio previous / this."""
    this_tree = Path(__file__).resolve().parents[1]
    load = os.getloadavg()[0]
    print(f"\nstage table: ms per frame, medians of the frames after a warm-up one, stages one after the other; "
          f"load average {load:.1f} on {os.cpu_count()} cores (wall times on a loaded machine are not the "
          "quiet machine's; CPU times count every thread)")
    results: dict[tuple[tuple[int, int], int], dict[str, dict[str, float]]] = {}
    for n in cores:
        for size, log in logs.items():
            got = {"cpu": stage_costs_of_tree(this_tree, log, None, cores=n, clock="cpu"),
                   "wall": stage_costs_of_tree(this_tree, log, None, cores=n, clock="wall")}
            if against is not None:
                got["old"] = stage_costs_of_tree(against, log, None, cores=n, clock="cpu")
            results[(size, n)] = got
    ref_size = (1200, 1920) if (1200, 1920) in logs else next(iter(logs))
    for n in cores:
        for size in logs:
            got = results[(size, n)]
            mpx = size[0] * size[1] / 1e6
            ref = results[(ref_size, n)]["cpu"]
            ref_mpx = ref_size[0] * ref_size[1] / 1e6
            print(f"\n{size[1]}x{size[0]} ({mpx:.2f} Mpx), {n} core(s), {int(got['cpu']['frames'])} frames")
            head = (f"  {'stage':13s} {'CPU ms':>8s} {'wall ms':>8s} {'CPU ms/Mpx':>11s} "
                    f"{'/Mpx vs ' + str(ref_size[1]) + 'x' + str(ref_size[0]):>18s}")
            if "old" in got:
                head += f" {'previous CPU':>13s} {'previous/this':>14s}"
            print(head)
            for k in STAGES:
                c, w = got["cpu"][k], got["wall"][k]
                per = c / mpx
                rel = per / (ref[k] / ref_mpx) if ref[k] else float("nan")
                line = f"  {k:13s} {c:8.1f} {w:8.1f} {per:11.1f} {rel:18.2f}"
                if "old" in got:
                    o = got["old"][k]
                    line += f" {o:13.1f} {o / c if c else float('nan'):14.2f}"
                print(line)


BIN_STAGES = ("bin_mask", "registration", "removal")


def alternating_stage_table(log: Path, ply: Path | None, against: Path | None, repeats: int, *,
                            bin_only: bool = False) -> None:
    """Print the stages' CPU ms per frame (medians over the frames after a warm-up one) of this tree and
    ``against``'s, alternating ``repeats`` times (one subprocess each, the order swapped every other repetition),
    the medians of the runs, the ratio previous / this, the CPU ms per Mpx, and every run's total with the paired
    runs' ratios (run i of each tree). ``bin_only``: the bin stages alone (bin mask, registration, removal and its
    check; ``stages.bin_zone``), their sum the total."""
    this_tree = Path(__file__).resolve().parents[1]
    trees = {"this tree": this_tree} | ({"previous": against} if against is not None else {})
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    loads = []
    for i in range(max(repeats, 1)):
        for name, tree in (trees.items() if i % 2 == 0 else reversed(trees.items())):
            loads.append(os.getloadavg()[0])
            runs[name].append(stage_costs_of_tree(tree, log, ply, bin_only=bin_only))
    keys = (*BIN_STAGES, "bin stages") if bin_only else STAGES
    for rs in runs.values():
        for r in rs:
            r["bin stages"] = sum(r[k] for k in BIN_STAGES)
    first = runs["this tree"][0]
    mpx = first["width"] * first["height"] / 1e6
    what = "bin stages" if bin_only else "stages (read, then one after the other)"
    print(f"\n{what} of {log.name} ({int(first['width'])}x{int(first['height'])}, {int(first['frames'])} frames "
          f"after a warm-up one), CPU ms per frame, medians of {len(runs['this tree'])} alternating runs; load "
          f"average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores")
    med = {name: {k: statistics.median(r[k] for r in rs) for k in keys} for name, rs in runs.items()}
    head = f"  {'stage':13s} {'this tree':>10s} {'ms/Mpx':>8s}"
    if against is not None:
        head += f" {'previous':>10s} {'previous/this':>14s}"
    print(head)
    for k in keys:
        c = med["this tree"][k]
        line = f"  {k:13s} {c:10.1f} {c / mpx:8.1f}"
        if against is not None:
            o = med["previous"][k]
            line += f" {o:10.1f} {o / c if c else float('nan'):14.2f}"
        print(line)
    total = keys[-1] if bin_only else "total"
    for name, rs in runs.items():
        print(f"  {name} per run ({'/'.join(BIN_STAGES) if bin_only else 'total'}): "
              + ", ".join("/".join(f"{r[k]:.1f}" for k in BIN_STAGES) if bin_only else f"{r[total]:.1f}"
                          for r in rs))
    if against is not None:
        ratios, median, least = paired_ratios(runs["previous"], runs["this tree"], total)
        print(f"  previous / this, {total}, run by run: " + ", ".join(f"{v:.3f}" for v in ratios)
              + f" (median {median:.3f}, least {least:.3f})")


def paired_ratios(previous: list[dict[str, float]], this: list[dict[str, float]], key: str
                  ) -> tuple[list[float], float, float]:
    """The ratios previous / this of ``key`` run by run (run i of each tree, measured one after the other), their
    median and the least: what a lever's bar reads ("median >= 1.05, every run > 1.00")."""
    if len(previous) != len(this) or not this:
        raise ValueError(f"paired_ratios: as many runs of each tree, at least one (got {len(previous)} and {len(this)})")
    ratios = [o[key] / t[key] for o, t in zip(previous, this, strict=True)]
    return ratios, statistics.median(ratios), min(ratios)


#: the outputs ``--throughput --outputs`` may replay with: none, the Rerun recording (``--rrd``), the results
#: file (``--out``), both (as ``zcut replay`` writes them: one background sink thread)
THROUGHPUT_OUTPUTS = ("none", "rrd", "out", "rrd+out")


#: ``--warm-passes N`` (passed to the measuring children as this variable): whole passes over frames 1.. of the
#: same session before the measured one, so that a short log is measured as a long log's later frames are
WARM_PASSES_VARIABLE = "ZCUT_BENCH_WARM_PASSES"


def warm_passes() -> int:
    return int(os.environ.get(WARM_PASSES_VARIABLE, "0") or 0)


#: the sampling period of ``--threads``' wait tracer, s
TRACE_PERIOD_S = 0.005

#: the folders whose code names where a Python thread is (:func:`_where`; not their tests')
_OWN_CODE = (f"{os.sep}replay{os.sep}", f"{os.sep}zcut{os.sep}")


def _schedstat(tid: int) -> tuple[int, int, bool] | None:
    """(ns run, ns waited on a run queue, whether it is ready to run now: running or waiting for a core) of a
    thread of this process (``/proc/self/task/TID/schedstat`` and ``stat``)."""
    try:  # os.open and os.read: a third of the cost of Python's file objects (the tracer reads ~40 files a sample)
        run, queued, _ = _read_proc(f"/proc/self/task/{tid}/schedstat").split()
        state = _read_proc(f"/proc/self/task/{tid}/stat").rsplit(b")", 1)[1].split(None, 1)[0]
    except (OSError, ValueError, IndexError):
        return None
    return int(run), int(queued), state == b"R"


def _read_proc(path: str) -> bytes:
    """The bytes of a small file of /proc (one ``read``)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        return os.read(fd, 4096)
    finally:
        os.close(fd)


def _where(frame: Any) -> str:
    """Where a Python thread is: the innermost frame of zcut's own code (``file:function:line`` and the line's
    text) and, when the innermost frame is another module's (a wait of ``threading``, ``queue``,
    ``concurrent.futures``), that frame's function; a thread in no code of zcut's, its innermost frame."""
    import linecache

    def name(g: Any) -> str:
        return f"{Path(g.f_code.co_filename).name}:{g.f_code.co_name}:{g.f_lineno}"

    def own(path: str) -> bool:
        return any(p in path for p in _OWN_CODE) and f"{os.sep}tests{os.sep}" not in path

    f = frame
    while f is not None and not own(f.f_code.co_filename):
        f = f.f_back
    if f is None:
        return name(frame)
    out = f"{name(f)} `{linecache.getline(f.f_code.co_filename, f.f_lineno).strip()[:56]}`"
    return out if frame is f else f"{out} <- {frame.f_code.co_name}"


def _group(name: str) -> str:
    """A thread's group: its name without the pool's number (``zcut-frame_0`` -> ``zcut-frame``)."""
    return name.split("_")[0].rstrip("0123456789-") if "_" in name else name.rstrip("0123456789-")


class _WaitTracer:
    """Where a whole replay's threads wait (``--threads``): a thread of its own samples, every
    :data:`TRACE_PERIOD_S`, every thread's run time and run-queue wait (``schedstat``, ns) and, for Python's
    threads, where it is (:func:`_where`; a thread Python does not know, numba's, OpenCV's, OpenBLAS's, is
    ``native``). Each sample's interval is credited to the place the thread was at its start: per thread and
    place, the wall s it ran, waited for a core, and was off the CPU (blocked: on a queue, a lock, a future,
    the GIL, a native barrier). Every fourth sample also reads :func:`thread_stats` (user, system CPU and page
    faults, so that a thread that ends during the run is counted up to its last sample)."""

    def __init__(self) -> None:
        import threading

        self.names: dict[int, str] = {}
        self.last: dict[int, tuple[int, int]] = {}
        self.where: dict[int, str] = {}
        #: tid -> place -> [run s, run-queue s, off-CPU s]
        self.spent: dict[int, dict[str, list[float]]] = {}
        #: per sample: its end (s from the start), the run time of every thread but the tracer's (CPU s) and the
        #: threads ready to run at its end (running or waiting for a core: the run's parallelism then)
        self.busy: list[tuple[float, float, float]] = []
        self.seen: dict[int, tuple[str, float, float, int]] = {}
        self.t0 = 0.0
        self._t = 0.0
        self._n = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-sampler", daemon=True)
        self.own_tid = -1
        #: ``--timeline``: per sample, its end (s from the start), its length (s) and every thread's
        #: (tid, run s, run-queue s, ready at the end, place at the start); None: not kept
        self.records: list[tuple[float, float, list[tuple[int, float, float, bool, str]]]] | None = None

    def start(self) -> None:
        self.t0 = self._t = time.perf_counter()
        self._sample(first=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()

    def _run(self) -> None:
        import threading

        self.own_tid = threading.get_native_id()
        while not self._stop.wait(TRACE_PERIOD_S):
            self._sample()

    def _sample(self, first: bool = False) -> None:
        import threading

        if self._n % 4 == 0:
            self.seen.update(thread_stats(self.seen))
        self._n += 1
        now = time.perf_counter()
        dt, self._t = now - self._t, now
        was = dict(self.where)
        frames = sys._current_frames()
        for th in threading.enumerate():
            if th.native_id is not None:
                self.names[th.native_id] = th.name
                fr = frames.get(th.ident or -1)
                if fr is not None:
                    self.where[th.native_id] = _where(fr)
        del frames
        ran, ready = 0.0, 0
        rows: list[tuple[int, float, float, bool, str]] = []
        for tid in map(int, os.listdir("/proc/self/task")):
            got = _schedstat(tid)
            if got is None:
                continue
            old = self.last.get(tid)
            self.last[tid] = got
            if first or tid == self.own_tid:
                continue
            if old is None:  # a thread new since the last sample: its run time, no off-CPU time known
                run_s, queued_s, off_s = got[0] / 1e9, got[1] / 1e9, 0.0
            else:
                run_s, queued_s = (got[0] - old[0]) / 1e9, (got[1] - old[1]) / 1e9
                off_s = max(dt - run_s - queued_s, 0.0)
            ran += run_s
            ready += got[2]
            place = was.get(tid, self.where.get(tid, "native"))
            rows.append((tid, run_s, queued_s, got[2], place))
            acc = self.spent.setdefault(tid, {}).setdefault(place, [0.0] * 3)
            acc[0] += run_s
            acc[1] += queued_s
            acc[2] += off_s
        if not first and dt > 0:
            self.busy.append((now - self.t0, ran, ready))
            if self.records is not None:
                self.records.append((now - self.t0, dt, rows))

    def places(self, n: int, wall_s: float) -> dict[str, dict[str, object]]:
        """Per thread group: its threads, the share of the wall it ran, waited for a core and was off the CPU
        (summed over its threads), and its off-CPU ms a frame by place (the largest first)."""
        out: dict[str, dict[str, object]] = {}
        for tid, by_place in self.spent.items():
            name = self.names.get(tid) or self.seen.get(tid, ("native",))[0]
            if name == "bench-sampler":
                continue
            g = out.setdefault(_group(name), {"threads": 0, "run": 0.0, "queued": 0.0, "off": 0.0, "places": {}})
            g["threads"] = int(g["threads"]) + 1  # type: ignore[call-overload]
            for place, (run_s, queued_s, off_s) in by_place.items():
                g["run"] = float(g["run"]) + run_s / wall_s  # type: ignore[arg-type]
                g["queued"] = float(g["queued"]) + queued_s / wall_s  # type: ignore[arg-type]
                g["off"] = float(g["off"]) + off_s / wall_s  # type: ignore[arg-type]
                p = g["places"].setdefault(place, [0.0, 0.0])  # type: ignore[union-attr]
                p[0] += 1000 * run_s / n
                p[1] += 1000 * off_s / n
        return out


def _frame_events(session: Any, t0: list[float]) -> list[tuple[int, str, str, float, float]]:
    """Record, in a measuring child, when each frame's pieces of a replay start and end: (frame index, piece,
    thread, start s, end s) from ``t0[0]``, appended to the list returned. The session module's names are
    wrapped (the reader's next frame, ``locate_bin``, ``bin_zone``, ``judge_zone``, ``run_frame``, a frame
    worker's whole ``_frame_result``): the same functions, timed."""
    import functools
    import threading

    from replay.pipeline import session as sm

    events: list[tuple[int, str, str, float, float]] = []

    def timed(piece: str, fn: Any, index_of: Any) -> Any:
        @functools.wraps(fn)
        def run(*a: Any, **kw: Any) -> Any:
            s = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                events.append((index_of(a), piece, threading.current_thread().name, s - t0[0],
                               time.perf_counter() - t0[0]))
        return run

    first = lambda a: a[0].index  # noqa: E731 - the frame is the first argument
    for piece in ("locate_bin", "bin_zone", "judge_zone", "run_frame"):
        if hasattr(sm, piece):
            setattr(sm, piece, timed(piece, getattr(sm, piece), first))
    if hasattr(sm.ReplaySession, "_frame_result"):
        sm.ReplaySession._frame_result = timed("frame worker", sm.ReplaySession._frame_result,  # type: ignore[method-assign]
                                               lambda a: a[1].index)
    prefetched = sm.prefetched

    def read_timed(frames: Any, **kw: Any) -> Any:
        def reading() -> Any:
            while True:
                s = time.perf_counter()
                f = next(frames, None)
                if f is None:
                    return
                events.append((f.index, "read", threading.current_thread().name, s - t0[0],
                               time.perf_counter() - t0[0]))
                yield f
        return prefetched(reading(), **kw)

    sm.prefetched = read_timed  # type: ignore[assignment]
    return events


def thread_accounting(log: Path, in_flight: int | None, timeline: bool = False) -> dict[str, object]:
    """Where the CPU of a whole replay goes, per thread, and where its threads wait (``--threads``):
    ``ReplaySession.run`` over frames 1.. after frame 0 (and ``--warm-passes``), no outputs, ``in_flight`` frames
    at once (None: the tree's default); every thread's user and system CPU ms and minor page faults per frame
    from ``/proc/self/task/*/stat``, grouped by thread name (numba's, OpenCV's and OpenBLAS's threads are not
    Python's: ``native``), the process's own figures (``getrusage``), and :class:`_WaitTracer`'s shares and
    places, the cores busy over the run, and the frames' pieces in time (:func:`_frame_events`)."""
    import inspect
    import resource

    from replay.pipeline.bin_model import bin_model_for

    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    kw = {}
    if in_flight is not None and "in_flight" in inspect.signature(session.run).parameters:
        kw["in_flight"] = in_flight
    session.run(frames=(0, 1), **kw)
    for _ in range(warm_passes()):
        session.run(frames=(1, None), **kw)
    t0 = [0.0]
    events = _frame_events(session, t0)
    delivered: list[tuple[int, float]] = []
    tracer = _WaitTracer()
    if timeline:
        tracer.records = []
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    tracer.start()
    base = dict(tracer.seen)
    t0[0] = tracer.t0
    c0 = time.process_time()
    summary = session.run(frames=(1, None),
                          on_frame=lambda f, r, row: delivered.append((f.index, time.perf_counter() - t0[0])), **kw)
    cpu = time.process_time() - c0
    wall = time.perf_counter() - t0[0]
    tracer.stop()
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    n = max(len(summary.rows), 1)
    groups: dict[str, list[float]] = {}
    sampler_ms = 0.0
    for tid, (name, u, sy, fl) in tracer.seen.items():
        b = base.get(tid, (name, 0.0, 0.0, 0))
        if name == "bench-sampler":
            sampler_ms = 1000 * (u + sy - b[1] - b[2]) / n
            continue
        g = groups.setdefault(_group(name), [0.0, 0.0, 0.0, 0.0])
        g[0] += 1000 * (u - b[1]) / n
        g[1] += 1000 * (sy - b[2]) / n
        g[2] += (fl - b[3]) / n
        g[3] += 1
    return {"frames": len(summary.rows), "cpu_ms": 1000 * cpu / n, "wall_ms": 1000 * wall / n,
            "user_ms": 1000 * (ru1.ru_utime - ru0.ru_utime) / n, "sys_ms": 1000 * (ru1.ru_stime - ru0.ru_stime) / n,
            "minflt": (ru1.ru_minflt - ru0.ru_minflt) / n, "threads": groups, "sampler_ms": sampler_ms,
            "places": tracer.places(n, wall), "events": events, "delivered": delivered,
            "in_flight": in_flight or 0, "layer": _layer_run(__import__("numba")),
            "quiet": quiet_estimate(tracer.busy, delivered), "samples": tracer.busy,
            "records": tracer.records or [], "names": {str(tid): name for tid, name in tracer.names.items()}}


#: the functions of threading, queue and concurrent.futures in which a thread is blocked waiting (a thread
#: :func:`_where` places in one of them waits there; off the CPU elsewhere, it waits for the GIL or in native code)
_WAITS = ("wait", "acquire", "get", "result", "join", "_wait_for_tstate_lock", "sleep", "select")


#: calls of zcut's code that block in C without a Python frame of their own (``queue.SimpleQueue.get``, a lock's
#: ``acquire``): a thread off the CPU at a line of Python that makes one of them waits there
_C_WAITS = ("q.get(", ".acquire(", "wait(", ".result(", ".join(", "sleep(")


def wait_kind(place: str) -> str:
    """What a thread off the CPU at ``place`` (:func:`_where`) waits for: ``waits at FILE:FUNCTION `line```
    (blocked in a wait of threading, queue or concurrent.futures called from that line of zcut's code), ``idle in
    its pool`` (a pool's worker waiting for work), ``native`` (a thread Python does not know), else ``GIL or native
    call at FILE:FUNCTION `line``` (off the CPU at a line of Python: waiting for the GIL, or inside a C call that
    blocks); a line that calls one of :data:`_C_WAITS` waits there."""
    if place == "native":
        return "native"
    head, _, tail = place.partition(" <- ")
    file_fn, _, text = head.partition(" `")
    where = ":".join(file_fn.split(":")[:2]) + (f" `{text}" if text else "")
    if tail in _WAITS or any(call in text for call in _C_WAITS):
        return f"waits at {where}"
    if not text:  # no frame of zcut's code: a pool's worker between jobs, or the interpreter's own wait
        return "idle in its pool" if ":_worker:" in place or place.endswith(":_worker") else f"waits at {where}"
    return f"GIL or native call at {where}"


def idle_causes(records: list, names: dict[str, str], cores: int = 2, busy_share: float = 0.5) -> dict[str, object]:
    """Where ``cores`` quiet cores would idle in a traced run (``--timeline``: :class:`_WaitTracer`'s records), and
    why.

    Each sample of length dt: the process's threads ran R CPU s and waited W s for a core; on quiet cores it had
    P = min((R + W) / dt, ``cores``) cores' worth of work ready, so the sample takes R / P s there and leaves
    (``cores`` - P) x R / P core-s idle. That idle is credited to the state of the frame workers (``zcut-frame``
    threads) over the sample: one that ran or waited for a core at least ``busy_share`` of it is ``busy``, else
    :func:`wait_kind` of its place; the label names the workers not busy (and, when none is busy, the main
    thread's state: it hands the frames to them). Returns the quiet wall s, the idle core-s, the idle share of the
    cores (idle / (``cores`` x wall)) and the idle core-s by label."""
    wall = idle = 0.0
    by: dict[str, float] = {}
    for _, dt, rows in records:
        run = sum(r[1] for r in rows)
        want = sum(r[1] + r[2] for r in rows)
        par = min(want / dt, float(cores)) if dt > 0 else 0.0
        q = run / par if par > 0 else dt
        wall += q
        gap = (cores - par) * q
        if gap <= 0:
            continue
        idle += gap
        state = {}
        for tid, run_s, queued_s, _, place in rows:
            name = names.get(str(tid), "native")
            state.setdefault(_group(name), []).append(
                "busy" if run_s + queued_s >= busy_share * dt else wait_kind(place))
        workers = state.get("zcut-frame", [])
        off = sorted(w for w in workers if w != "busy")
        if not workers:
            label = "no frame worker: main " + ("busy" if "busy" in state.get("MainThread", []) else
                                                 ", ".join(state.get("MainThread", ["?"])))
        elif len(off) < len(workers):
            label = f"{len(workers) - len(off)} frame worker(s) busy; the other(s): " + " / ".join(off)
        else:
            main = state.get("MainThread", ["?"])[0]
            label = "no frame worker busy: " + " / ".join(off) + f"; main: {main}"
        by[label] = by.get(label, 0.0) + gap
    return {"wall_s": wall, "idle_s": idle, "idle_share": idle / (cores * wall) if wall else float("nan"),
            "by": by}


#: ``--timeline``: the bins of the printed timeline, s, and the most of them printed
TIMELINE_BIN_S = 0.02
TIMELINE_BINS = 120


def print_timeline(run: dict, label: str, cores: int = 2) -> None:
    """One traced run (``--timeline``): the idle share of ``cores`` quiet cores and its causes
    (:func:`idle_causes`, ms a frame), then the run's first :data:`TIMELINE_BINS` bins of :data:`TIMELINE_BIN_S`
    on quiet cores (each sample as long as :func:`idle_causes` makes it) per thread (one character a bin: ``#`` ran
    >= 2/3 of it, ``+`` >= 1/3, ``-`` > 0, ``g`` off the CPU at a line of Python, the GIL or a native call, ``w``
    blocked in a wait, ``.`` idle in its pool or ended) and the cores the process used in each bin."""
    names, records = run["names"], run["records"]
    n = max(int(run["frames"]), 1)
    got = idle_causes(records, names, cores)
    print(f"\n  {label}: {run['frames']} frames, {run['in_flight'] or 'default'} in flight, layer {run['layer']}; "
          f"CPU {run['cpu_ms']:.1f} ms a frame; on {cores} quiet cores (idle_causes): wall {1000 * got['wall_s'] / n:.1f} "
          f"ms a frame, idle {1000 * got['idle_s'] / n:.1f} core-ms a frame = {100 * got['idle_share']:.1f} % of the "
          f"cores")
    times = sorted(t for _, t in run.get("delivered", []))
    if len(times) >= 3:  # the pass's start (to the first frame delivered), its end (after the last but one), the rest
        parts = {"start": [r for r in records if r[0] <= times[0]],
                 "middle": [r for r in records if times[0] < r[0] <= times[-2]],
                 "end": [r for r in records if r[0] > times[-2]]}
        split = {k: idle_causes(v, names, cores) for k, v in parts.items()}
        print("    by part of the pass: " + "; ".join(
            f"{k} {1000 * v['idle_s'] / n:.1f} core-ms a frame idle of {1000 * v['wall_s']:.0f} ms "
            f"({100 * v['idle_share']:.1f} %)" for k, v in split.items()))
    for what, s in sorted(got["by"].items(), key=lambda kv: -kv[1])[:14]:
        print(f"    {1000 * s / n:6.1f} core-ms a frame ({100 * s / max(got['idle_s'], 1e-12):4.1f} % of the idle)  {what}")
    rows: dict[str, list[list[float]]] = {}
    quiet_t = 0.0  # the sample's middle on quiet cores (each sample's length there: idle_causes)
    for _, dt, rs in records:
        run = sum(r[1] for r in rs)
        par = min(sum(r[1] + r[2] for r in rs) / dt, float(cores)) if dt > 0 else 0.0
        q = run / par if par > 0 else dt
        b = int((quiet_t + q / 2) / TIMELINE_BIN_S)
        quiet_t += q
        if b >= TIMELINE_BINS:
            break
        for tid, run_s, queued_s, _, place in rs:
            name = names.get(str(tid), "native")
            key = name if _group(name) in ("MainThread", "zcut-frame", "zcut-locate", "zcut-frame-reader") else _group(name)
            cells = rows.setdefault(key, [[0.0] * 4 for _ in range(TIMELINE_BINS)])
            kind = wait_kind(place) if run_s + queued_s < 0.5 * dt else ""
            cells[b][0] += run_s
            cells[b][1] += queued_s
            cells[b][2] += q if kind.startswith("GIL") else 0.0
            cells[b][3] += q if kind.startswith("waits") else 0.0
    print(f"  the first {TIMELINE_BINS * TIMELINE_BIN_S:.1f} s on quiet cores, {1000 * TIMELINE_BIN_S:.0f} ms a "
          "character (# ran >= 2/3, + >= 1/3, - less; g off CPU at a Python line: GIL / native, w blocked in a wait, "
          ". idle or ended):")
    total = [0.0] * TIMELINE_BINS
    for key in sorted(rows, key=lambda k: (k != "MainThread", k)):
        threads = max(1, sum(1 for tid, nm in names.items() if (nm if _group(nm) in ("MainThread", "zcut-frame",
                      "zcut-locate", "zcut-frame-reader") else _group(nm)) == key))
        line = []
        for i, (r, _, g, w) in enumerate(rows[key]):
            total[i] += r
            f = r / (TIMELINE_BIN_S * threads)
            line.append("#" if f >= 2 / 3 else "+" if f >= 1 / 3 else "-" if r > 0 else
                        "g" if g > w and g > 0.3 * TIMELINE_BIN_S else "w" if w > 0.3 * TIMELINE_BIN_S else ".")
        print(f"    {key[:18]:18s} {''.join(line)}")
    print(f"    {'cores used':18s} " + "".join(str(min(9, round(c / TIMELINE_BIN_S))) for c in total))


def alternating_children(flag: str, log: Path, against: Path | None, repeats: int, in_flight: int | None, *,
                         save: Path | None = None) -> tuple[dict[str, list[dict]], list[float]]:
    """Run ``child_json(tree, flag, log, in_flight)`` in this tree and ``against``'s (layer ``default``), alternating
    ``repeats`` times; returns each tree's runs ("this tree", "previous") and the load average before each run.
    ``save``: a folder each run is also written to (one JSON file a run)."""
    this_tree = Path(__file__).resolve().parents[1]
    trees = {"this tree": this_tree} | ({"previous": against} if against is not None else {})
    got: dict[str, list[dict]] = {k: [] for k in trees}
    loads = []
    for _ in range(max(repeats, 1)):
        for name, tree in trees.items():
            loads.append(os.getloadavg()[0])
            got[name].append(child_json(tree, flag, str(log), str(in_flight or 0), layer="default"))
            if save is not None:
                import json

                save.mkdir(parents=True, exist_ok=True)
                (save / f"{name.replace(' ', '_')}_{len(got[name])}.json").write_text(json.dumps(got[name][-1]))
    return got, loads


def timeline_table(log: Path, against: Path | None, repeats: int, in_flight: int | None,
                   save: Path | None = None) -> None:
    """``--timeline``: traced runs (:func:`thread_accounting` keeping every sample) of this tree and ``against``'s,
    alternating ``repeats`` times; per tree the idle shares of two quiet cores of every run and their median, then
    the last run's causes and timeline (:func:`print_timeline`). ``save``: a folder the runs are written to (one
    JSON file each), for :func:`print_timeline` later."""
    got, loads = alternating_children("--timeline-json", log, against, repeats, in_flight, save=save)
    print(f"\nwhere two quiet cores would idle in a whole replay of {log.name}, {in_flight or 'the default number of'} "
          f"frame(s) in flight, {warm_passes()} warm pass(es); load average {min(loads):.1f}-{max(loads):.1f} on "
          f"{os.cpu_count()} cores; the tracer samples every {1000 * TRACE_PERIOD_S:.0f} ms")
    for name, rs in got.items():
        shares = [idle_causes(r["records"], r["names"])["idle_share"] for r in rs]
        print(f"  {name}: idle share of the two cores " + ", ".join(f"{100 * v:.1f} %" for v in shares)
              + f" (median {100 * statistics.median(shares):.1f} %); CPU ms a frame "
              + ", ".join(f"{r['cpu_ms']:.1f}" for r in rs))
    for name, rs in got.items():
        print_timeline(rs[-1], name)


def quiet_estimate(samples: list[tuple[float, float, float]], delivered: list[tuple[int, float]],
                   cores: int = 2, window: int = 10) -> dict[str, object]:
    """What a traced run (:class:`_WaitTracer`'s samples) implies for ``cores`` quiet cores.

    In each ``window`` of samples the run did its CPU s of work with, on average, D of the process's threads
    ready to run (running, or waiting for a core: the parallelism the run had then; the state of every thread
    at each sample). On quiet cores that work takes CPU s / min(D, ``cores``): a loaded machine stretches the
    run, not the order of its work. Summed over the windows, that is the run's wall on quiet cores if its pieces
    overlap as they did here (an estimate: on quiet cores the threads keep another pace relative to each
    other). Returns the estimated wall ms a frame, cores busy, the share of that wall with fewer than ``cores``
    threads ready, and the estimated delivery time of each frame (ms from the start)."""
    quiet, short, work = 0.0, 0.0, 0.0
    at: list[tuple[float, float]] = [(0.0, 0.0)]  # (window end here, the same on quiet cores), s
    for i in range(0, len(samples), window):
        part = samples[i : i + window]
        ran = sum(r for _, r, _ in part)
        ready = sum(d for _, _, d in part) / len(part)
        q = ran / min(max(ready, 1.0), cores)
        quiet += q
        work += ran
        if ready < cores:
            short += q
        at.append((part[-1][0], quiet))

    def quiet_at(t: float) -> float:
        for (t0, q0), (t1, q1) in zip(at, at[1:]):
            if t <= t1:
                return q0 + (q1 - q0) * ((t - t0) / (t1 - t0) if t1 > t0 else 1.0)
        return at[-1][1]

    n = max(len(delivered), 1)
    return {"wall_ms": 1000 * quiet / n, "cores_busy": work / quiet if quiet else float("nan"),
            "short_share": short / quiet if quiet else float("nan"),
            "delivered_ms": [(i, 1000 * quiet_at(t)) for i, t in delivered]}


def thread_table(log: Path, against: Path | None, repeats: int, in_flight: int | None = None) -> None:
    """Print :func:`thread_accounting` of this tree and ``against``'s (each under the numba threading layer its
    own ``configure_process`` chooses, ``in_flight`` frames at once, None: its default), alternating ``repeats``
    times (one subprocess each), the medians per thread group; then, per tree, where each thread group waits
    (the medians of its wall shares, its places of the last run) and the last run's frames in time."""
    got, loads = alternating_children("--threads-json", log, against, repeats, in_flight)
    print(f"\nwhere a whole replay's CPU goes, per thread, {log.name} ({got['this tree'][0]['frames']} frames after a "
          f"warm-up one, {warm_passes()} warm pass(es), {in_flight or 'the default number of'} frame(s) in flight, "
          f"layer {got['this tree'][0].get('layer')}); medians of {repeats} alternating runs, CPU ms per frame "
          f"(user + sys) and minor page faults per frame; load average {min(loads):.1f}-{max(loads):.1f} on "
          f"{os.cpu_count()} cores")
    groups = sorted({g for rs in got.values() for r in rs for g in r["threads"]})
    med = {name: {g: [statistics.median(r["threads"].get(g, [0, 0, 0, 0])[i] for r in rs) for i in range(3)]
                  for g in groups} for name, rs in got.items()}
    head = f"  {'thread':20s}" + "".join(f" {name + ' user/sys/faults':>32s}" for name in got)
    print(head)
    for g in sorted(groups, key=lambda g: -sum(med["this tree"][g][:2])):
        print(f"  {g:20s}" + "".join(f" {med[name][g][0]:10.1f} {med[name][g][1]:10.1f} {med[name][g][2]:10.0f}"
                                     for name in got))
    for k, label in (("user_ms", "process user"), ("sys_ms", "process sys"), ("minflt", "minor faults"),
                     ("cpu_ms", "process CPU"), ("wall_ms", "wall"), ("sampler_ms", "(the tracer's own CPU)")):
        print(f"  {label:20s}" + "".join(f" {statistics.median(r.get(k, 0.0) for r in got[name]):32.1f}"
                                         for name in got))
    for name, rs in got.items():
        print_waits(name, rs)


def print_waits(name: str, runs: list[dict]) -> None:
    """Where each thread group of ``runs`` (one tree's :func:`thread_accounting`) ran and waited: the medians of
    its wall shares (summed over its threads: 1.00 = one thread busy all the run), the cores busy, and the last
    run's places off the CPU (ms a frame) and frames in time."""
    print(f"\n  {name}: cores busy (CPU / wall) " + ", ".join(f"{r['cpu_ms'] / r['wall_ms']:.2f}" for r in runs))
    print(f"  on {os.cpu_count()} quiet cores, were the pieces to overlap as here (quiet_estimate): wall ms a frame "
          + ", ".join(f"{r['quiet']['wall_ms']:.1f}" for r in runs) + "; cores busy "
          + ", ".join(f"{r['quiet']['cores_busy']:.2f}" for r in runs) + "; share of that wall with fewer threads "
          "ready than cores " + ", ".join(f"{r['quiet']['short_share']:.2f}" for r in runs))
    print("  the frames' delivery on quiet cores (estimated ms from the start), the last run: "
          + ", ".join(f"{i}: {t:.0f}" for i, t in runs[-1]["quiet"]["delivered_ms"]))
    print(f"  {'thread group':20s} {'threads':>7s} {'running':>8s} {'run queue':>10s} {'off CPU':>8s}   (ms a frame "
          "summed over the group's threads, schedstat; medians)")
    groups = sorted({g for r in runs for g in r["places"]}, key=lambda g: -statistics.median(
        r["places"].get(g, {}).get("run", 0.0) for r in runs))
    for g in groups:
        vals = [r["places"].get(g, {"threads": 0, "run": 0.0, "queued": 0.0, "off": 0.0}) | {"wall": r["wall_ms"]}
                for r in runs]
        print(f"  {g:20s} {statistics.median(v['threads'] for v in vals):7.0f} "
              + " ".join(f"{statistics.median(v[k] * v['wall'] for v in vals):{w}.1f}"
                         for k, w in (("run", 8), ("queued", 10), ("off", 8))))
    print(f"  {'all':20s} {'':7s} " + f"{statistics.median(sum(g['run'] for g in r['places'].values()) * r['wall_ms'] for r in runs):8.1f}")
    last = runs[-1]
    print("  the last run's places, ms a frame running / off the CPU (each group's places above 2 ms):")
    for g in groups:
        places = last["places"].get(g, {}).get("places", {})
        for place, (run_ms, off_ms) in sorted(places.items(), key=lambda kv: -(kv[1][0] + kv[1][1])):
            if run_ms + off_ms >= 2.0:
                print(f"    {g:18s} {run_ms:7.1f} {off_ms:7.1f}  {place}")
    print("  the last run's frames in time (ms from the run's start: piece start-end [thread]):")
    by_frame: dict[int, list] = {}
    for idx, piece, thread, s, e in last["events"]:
        by_frame.setdefault(idx, []).append((s, e, piece, thread))
    done = dict((i, t) for i, t in last["delivered"])
    for idx in sorted(by_frame):
        parts = "  ".join(f"{piece} {1000 * s:.0f}-{1000 * e:.0f} [{thread}]" for s, e, piece, thread in sorted(by_frame[idx]))
        print(f"    frame {idx}: {parts}  delivered {1000 * done.get(idx, float('nan')):.0f}")


def throughput(log: Path, in_flight: int | None, outputs: str = "none") -> dict[str, float]:
    """CPU s and wall s per frame of a whole replay (``ReplaySession.run``: read, bin stages, z-cut, SOR,
    metrics, with the replay's own threads; ``outputs``: :data:`THROUGHPUT_OUTPUTS`, written to a temporary
    folder by the sinks ``zcut replay --rrd/--out`` uses, closing them included) over frames 1.. after
    frame 0 as warm-up, the log's own bin model; ``in_flight`` frames at once (None: the tree's default;
    a tree whose ``run`` has no such argument runs its own way)."""
    import inspect

    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.sinks import ResultsSink

    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    kw = {}
    if in_flight is not None and "in_flight" in inspect.signature(session.run).parameters:
        kw["in_flight"] = in_flight
    session.run(frames=(0, 1), **kw)  # warm-up: numba kernels, the first chunk
    for _ in range(warm_passes()):  # steady state: the buffers of a long log's later frames
        session.run(frames=(1, None), **kw)
    import numba

    clock = _ThreadClock()
    with tempfile.TemporaryDirectory(prefix="zcut_bench_throughput_") as d:
        sinks: list = []
        if "rrd" in outputs:
            sinks.append(RerunSink(rrd=Path(d) / "out.rrd"))
        if "out" in outputs:
            sinks.append(ResultsSink(Path(d) / "results.mcap"))
        clock.sample()
        t0, c0 = time.perf_counter(), time.process_time()
        if sinks:
            summary = session.run(BackgroundSinks(sinks), frames=(1, None), on_frame=clock.on_frame, **kw)
        else:  # no sink at all, as before --outputs
            summary = session.run(frames=(1, None), on_frame=clock.on_frame, **kw)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = max(len(summary.rows), 1)
    busy = clock.busiest(n)
    return {"cpu_s": cpu / n, "wall_s": wall / n, "frames": len(summary.rows), "layer": _layer_run(numba),
            "busiest_s": busy[1], "busiest": busy[0]}


def _layer_run(numba: object) -> str:
    """numba's threading layer, or "none" when no parallel kernel ran (a log without the bin stages, e.g. the
    real Kinect log: numba then has no layer to name)."""
    try:
        return str(numba.threading_layer())  # type: ignore[attr-defined]
    except ValueError:
        return "none"


def thread_stats(known: dict[int, tuple]) -> dict[int, tuple[str, float, float, int]]:
    """Every thread of this process now (``/proc/self/task/*/stat``): its name, user and system CPU s and minor
    page faults. Python's threads by their name; a thread Python does not know (numba's, OpenCV's, OpenBLAS's)
    keeps the name ``known`` gave it, else ``native``. A thread that ended while it was read is left out."""
    import threading

    hz = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[int, tuple[str, float, float, int]] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            st = _read_proc(f"/proc/self/task/{tid}/stat").decode().rsplit(")", 1)[1].split()
        except OSError:
            continue
        old = known.get(int(tid))
        out[int(tid)] = (names.get(int(tid)) or (old[0] if old else "native"), int(st[11]) / hz, int(st[12]) / hz,
                         int(st[7]))
    return out


class _ThreadClock:
    """Every thread's CPU s (user + system, ``/proc/self/task``), sampled before a run and at each of its frames
    (``on_frame``, in the calling thread: no sampler thread of its own whose CPU the process time would count).
    A thread that ends between two frames is counted up to the frame before."""

    def __init__(self) -> None:
        self.base: dict[int, tuple[str, float]] | None = None
        self.seen: dict[int, tuple[str, float]] = {}

    def sample(self) -> None:
        self.seen.update({tid: (name, u + sy) for tid, (name, u, sy, _) in thread_stats(self.seen).items()})
        if self.base is None:
            self.base = dict(self.seen)

    def on_frame(self, *args: object) -> None:
        self.sample()

    def busiest(self, n: int) -> tuple[str, float]:
        """The thread that was busiest during the run: its name and CPU s a frame (``n`` frames)."""
        base = self.base or {}
        name, most = "", 0.0
        for tid, (nm, c) in self.seen.items():
            used = (c - base.get(tid, (nm, 0.0))[1]) / n
            if used > most:
                name, most = nm, used
        return name, most


def throughput_of_tree(tree: Path, log: Path, in_flight: int | None, outputs: str = "none",
                       layer: str | None = None) -> dict[str, float]:
    """:func:`throughput` with the code of the source tree ``tree``, in a subprocess (``layer``: :func:`child_json`)."""
    return child_json(tree, "--throughput-json", str(log), str(in_flight or 0), outputs, layer=layer)


def throughput_table(log: Path, against: Path | None, repeats: int, outputs: tuple[str, ...] = ("none",),
                     layers: tuple[str, ...] = ()) -> None:
    """Print CPU s and wall s per frame of whole replays: this tree and the previous tree (``against``) with one
    frame in flight and with two (numba's threading layer each tree's ``configure_process`` chooses),
    alternating ``repeats`` times, medians; with ``layers`` (e.g. workqueue, the previous layer), this tree under
    each of them with one and two frames in flight too; with ``outputs`` other than none, this tree (its default
    frames in flight) with each of them too. Every row says the frames/s bound of two fully used cores
    (2 / CPU s a frame), the busiest thread's CPU s a frame and the bound of two quiet cores, 1 / max(CPU s / 2,
    the busiest thread's): no thread can go faster than its own work."""
    this_tree = Path(__file__).resolve().parents[1]
    runs: dict[str, tuple[Path, int | None, str, str | None]] = {
        "this tree, 1 frame in flight": (this_tree, 1, "none", "default"),
        "this tree, 2 frames in flight": (this_tree, 2, "none", "default")}
    for layer in layers:
        runs[f"this tree, {layer}, 1 in flight"] = (this_tree, 1, "none", layer)
        runs[f"this tree, {layer}, 2 in flight"] = (this_tree, 2, "none", layer)
    if against is not None:  # under the layer its own configure_process chooses, as `zcut replay` runs it
        runs["previous tree, 1 frame in flight"] = (against, 1, "none", "default")
        runs["previous tree, 2 frames in flight"] = (against, 2, "none", "default")
    for o in outputs:
        if o != "none":
            runs[f"this tree, --{o.replace('+', ' --')}"] = (this_tree, None, o, "default")
            if against is not None:
                runs[f"previous, --{o.replace('+', ' --')}"] = (against, None, o, "default")
    got: dict[str, list[dict]] = {k: [] for k in runs}
    loads = []
    for _ in range(max(repeats, 1)):
        for name, (tree, n, o, layer) in runs.items():
            loads.append(os.getloadavg()[0])
            got[name].append(throughput_of_tree(tree, log, n, o, layer))
    frames = int(next(iter(got.values()))[0]["frames"])
    print(f"\nwhole replay of {log.name} ({frames} frames after a warm-up one), medians of {repeats} "
          f"alternating runs; load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores "
          "(wall times on a shared machine are indicative only)")
    base = statistics.median(r["cpu_s"] for r in got[next(iter(runs))])
    base_w = statistics.median(r["wall_s"] for r in got[next(iter(runs))])
    print(f"  {'':32s} {'CPU s/frame':>12s} {'wall s/frame':>13s} {'frames/s':>9s} {'wall vs 1 in flight':>20s}"
          f" {'2-core bound':>13s} {'layer':>10s} {'busiest s/frame':>16s} {'quiet bound':>12s}")
    for name, rs in got.items():
        c, w = statistics.median(r["cpu_s"] for r in rs), statistics.median(r["wall_s"] for r in rs)
        b = statistics.median(r.get("busiest_s", float("nan")) for r in rs)
        layer = "/".join(sorted({str(r.get("layer", "?")) for r in rs}))
        print(f"  {name:32s} {c:12.3f} {w:13.3f} {1 / w:9.2f} {base_w / w:20.2f} {2 / c:13.2f} {layer:>10s}"
              f" {b:16.3f} {1 / max(c / 2, b):12.2f}"
              + ("" if name == next(iter(runs)) else f"   (CPU {c / base:.2f} x)"))
        print("    per run (CPU, wall, busiest thread): "
              + ", ".join(f"{r['cpu_s']:.3f}/{r['wall_s']:.3f}/{r.get('busiest', '?')} {r.get('busiest_s', 0):.3f}"
                          for r in rs))


def _command_cost(tree: Path, argv: list[str], *, code: str | None = None) -> dict[str, float]:
    """``python -m cli ARGV`` in a fresh process with the code of ``tree`` (``python -c CODE`` with
    ``code``): CPU s (user + sys, all threads, start to exit), wall s, wall s at the first frame's
    progress line (``[1/...] frame``), and the standard output."""
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # an install has its bytecode compiled: so do these trees
    t0 = time.perf_counter()
    head = ["-c", code] if code is not None else ["-m", "cli"]
    p = subprocess.Popen([sys.executable, *head, *argv], cwd=tree, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    first = float("nan")
    assert p.stderr is not None and p.stdout is not None
    err = []
    for line in p.stderr:
        err.append(line)
        if first != first and line.startswith("[1/"):
            first = time.perf_counter() - t0
    out = p.stdout.read()
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode not in (0, 3):
        raise SystemExit(f"{tree}: zcut {' '.join(argv)} failed ({p.returncode}):\n{''.join(err[-20:])}")
    return {"cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall, "first_wall_s": first, "stdout": out}


def startup_costs(tree: Path, log: Path, n_frames: int) -> dict[str, float]:
    """One measurement of the fixed costs of ``zcut replay LOG`` with ``tree``'s code (see the module
    docstring, "Fixed costs"): T(1), T(N), f, F, F / T(N), the wall to the first frame, --help."""
    one = _command_cost(tree, ["replay", str(log), "--frames", "0:1"])
    every = _command_cost(tree, ["replay", str(log)])
    f = (every["cpu_s"] - one["cpu_s"]) / max(n_frames - 1, 1)
    fixed = one["cpu_s"] - f
    return {"t1": one["cpu_s"], "tn": every["cpu_s"], "f": f, "fixed": fixed, "share": fixed / every["cpu_s"],
            "first_wall": every["first_wall_s"], "wall": every["wall_s"],
            "help": _command_cost(tree, ["--help"])["cpu_s"],
            "replay_help": _command_cost(tree, ["replay", "--help"])["cpu_s"],
            "accuracy_help": _command_cost(tree, ["accuracy", "--help"])["cpu_s"],
            "floor": _command_cost(tree, [], code=FLOOR_CODE)["cpu_s"]}


#: The libraries a replay of a log with a bin model cannot do without, and numba's target context,
#: in a process that runs no zcut code (but the command line's process settings and one cached kernel,
#: the reader's, on a tiny cloud): the floor of F, which no import placement moves. The 40-odd
#: other cached kernels of a frame (~5 ms each) come on top. Not Open3D: a replay whose prepared bin
#: model comes from its cache no longer imports it (docs/performance.md, "Open3D out of the replay").
FLOOR_CODE = """
from replay.process import configure_process
configure_process()
import numpy as np, scipy.spatial, cv2, numba
from replay.logs import ros2_msgs
words = np.zeros((2, 2, 4), np.uint32)
ros2_msgs._unpack_words(words, 0, 1, 2, np.empty((2, 2, 3), np.float32))
"""


def startup_table(log: Path, against: Path | None, repeats: int) -> None:
    """Print the fixed costs of ``zcut replay LOG`` (this tree and ``against``, alternating ``repeats``
    times; medians, and every run's F and share)."""
    reader = LogReader(log)
    n = reader.n_frames
    if n is None or n < 2:
        raise SystemExit(f"{log}: --startup needs a log of at least 2 frames whose count is known")
    trees = {"this tree": Path(__file__).resolve().parents[1]}
    if against is not None:
        trees["previous"] = against
    got: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    loads = []
    for tree in trees.values():  # a first run each (its .pyc files written, the page cache warm): not counted
        _command_cost(tree, ["replay", str(log), "--frames", "0:1"])
    for _ in range(max(repeats, 1)):
        for name, tree in trees.items():
            loads.append(os.getloadavg()[0])
            got[name].append(startup_costs(tree, log, n))
    print(f"\nfixed costs of `zcut replay {log.name}` ({n} frames), CPU s of the whole process, medians of "
          f"{repeats} alternating runs; load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores")
    keys = (("t1", "T(1)"), ("tn", f"T({n})"), ("f", "f/frame"), ("fixed", "F"), ("share", "F/T(N)"),
            ("first_wall", "wall 1st"), ("wall", "wall"), ("help", "--help"), ("replay_help", "replay -h"),
            ("accuracy_help", "acc. -h"), ("floor", "floor"))
    print(f"  {'':12s}" + "".join(f" {h:>9s}" for _, h in keys))
    med = {name: {k: statistics.median(r[k] for r in rs) for k, _ in keys} for name, rs in got.items()}
    for name, m in med.items():
        print(f"  {name:12s}" + "".join(f" {m[k]:9.3f}" for k, _ in keys))
        print("    per run (F, share): " + ", ".join(f"{r['fixed']:.2f}/{r['share']:.2f}" for r in got[name]))
    if against is not None:
        a, b = med["previous"], med["this tree"]
        print(f"  {'previous/this':12s}" + "".join(f" {a[k] / b[k] if b[k] else float('nan'):9.2f}" for k, _ in keys))
    print("  (F = T(1) - f: what the process spends besides its frames; the issue asks F/T(N) <= 0.20; floor: a\n"
          "  process importing NumPy, numba, SciPy's KD-tree and OpenCV and loading one cached kernel)")
    floor = statistics.median(r["floor"] for rs in got.values() for r in rs)
    m = med["this tree"]
    print(f"  the floor's share of T({n}) were the rest of F gone: {floor / (m['tn'] - m['fixed'] + floor):.2f}")


def child_main(args: argparse.Namespace) -> None:
    """A measuring child (:func:`child_json` launched it): its one measurement, printed as one JSON line."""
    import json

    if args.stage_json:
        if args.pin:
            os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[: args.pin])
        log_, ply_ = args.stage_json
        got = stage_costs(Path(log_), None if ply_ == "-" else Path(ply_), clock=args.clock, bin_only=args.bin_stages)
    elif args.threads_json:
        log_, n_ = args.threads_json
        got = thread_accounting(Path(log_), int(n_) or None)
    elif args.timeline_json:
        log_, n_ = args.timeline_json
        got = thread_accounting(Path(log_), int(n_) or None, timeline=True)
    else:
        log_, n_, o_ = args.throughput_json
        got = throughput(Path(log_), int(n_) or None, o_)
    print(json.dumps(got))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of each; medians compared")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_replay"))
    ap.add_argument("--stages", action="store_true", help="print the CPU cost per stage")
    ap.add_argument("--stages-only", action="store_true", help="only the cost per stage")
    ap.add_argument("--against", type=Path, help="source tree of the previous release, measured in the same run")
    ap.add_argument("--log", type=Path, help="an existing log (with its bin model attachment) for the cost per stage")
    ap.add_argument("--table", action="store_true", help="the stage table: sizes x cores, CPU and wall, per Mpx")
    ap.add_argument("--sizes", default=",".join(f"{w}x{h}" for h, w in TABLE_SIZES),
                    help="WxH,... of the stage table (default the issue's four)")
    ap.add_argument("--cores", default="1,2", help="core counts of the stage table (default 1,2)")
    ap.add_argument("--throughput", action="store_true",
                    help="whole replays of --log (or the synthetic log), CPU and wall s per frame: this tree with "
                         "1 and 2 frames in flight, and --against's tree, alternating --repeats times")
    ap.add_argument("--startup", action="store_true",
                    help="the fixed costs of `zcut replay --log LOG` (share before the first frame), this tree and "
                         "--against's, alternating --repeats times")
    ap.add_argument("--outputs", default="none",
                    help=f"--throughput: also replay with these outputs, of {','.join(THROUGHPUT_OUTPUTS)} (default none)")
    ap.add_argument("--layers", default="",
                    help="--throughput: also this tree under these numba threading layers, 1 and 2 frames in flight "
                         "(e.g. workqueue, the layer before the round of 2026-12-05d)")
    ap.add_argument("--throughput-json", nargs=3, help=argparse.SUPPRESS)  # LOG IN_FLIGHT (0: default) OUTPUTS: one line
    ap.add_argument("--threads", action="store_true",
                    help="where a whole replay of --log spends its CPU, per thread (user, system, page faults), this "
                         "tree and --against's alternating --repeats times")
    ap.add_argument("--threads-json", nargs=2, help=argparse.SUPPRESS)  # LOG IN_FLIGHT (0: default): one JSON line
    ap.add_argument("--timeline", action="store_true",
                    help="where two quiet cores would idle in a whole replay of --log and why: each thread's timeline "
                         "and the idle share's causes, this tree and --against's alternating --repeats times")
    ap.add_argument("--timeline-save", type=Path, help="--timeline: write each traced run to this folder (JSON)")
    ap.add_argument("--timeline-json", nargs=2, help=argparse.SUPPRESS)  # LOG IN_FLIGHT (0: default): one JSON line
    ap.add_argument("--in-flight", type=int, default=0,
                    help="--threads: frames in flight (default 0: each tree's own default)")
    ap.add_argument("--warm-passes", type=int, default=0,
                    help="--throughput, --threads: whole passes over the log before the measured one (a short log "
                         "measured as a long log's later frames; default 0)")
    ap.add_argument("--stage-json", nargs=2, help=argparse.SUPPRESS)  # LOG PLY|-: one JSON line
    ap.add_argument("--clock", default="cpu", choices=("cpu", "wall"), help=argparse.SUPPRESS)
    ap.add_argument("--pin", type=int, help=argparse.SUPPRESS)  # cores the --stage-json process runs on
    ap.add_argument("--bin-stages", action="store_true",
                    help="--stages-only: the bin stages only (bin mask, registration, removal), this tree and --against's "
                         "alternating --repeats times (each a subprocess), medians and every run's figures")
    args = ap.parse_args()
    if args.warm_passes:
        os.environ[WARM_PASSES_VARIABLE] = str(args.warm_passes)  # the measuring children read it
    if args.stage_json or args.threads_json or args.throughput_json or args.timeline_json:
        child_main(args)
        return
    if args.timeline:
        if args.log is None:
            raise SystemExit("--timeline needs --log LOG")
        timeline_table(args.log, args.against, args.repeats, args.in_flight or None, args.timeline_save)
        return
    if args.threads:
        if args.log is None:
            raise SystemExit("--threads needs --log LOG")
        thread_table(args.log, args.against, args.repeats, args.in_flight or None)
        return
    if args.startup:
        if args.log is None:
            raise SystemExit("--startup needs --log LOG (e.g. `zcut synth --parts zinc_nuts --frames 6 -o LOG`)")
        startup_table(args.log, args.against, args.repeats)
        return
    if args.throughput:  # (each child gets its layer: throughput_table)
        log = args.log if args.log is not None else prepare(Path(args.dir), args.kind, args.frames)[0]
        outs = tuple(o for o in args.outputs.split(",") if o)
        if not set(outs) <= set(THROUGHPUT_OUTPUTS):
            ap.error(f"--outputs: of {','.join(THROUGHPUT_OUTPUTS)}")
        throughput_table(log, args.against, args.repeats, outs, tuple(v for v in args.layers.split(",") if v))
        return
    if args.table:
        os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")
        sizes = [tuple(int(v) for v in s.lower().split("x"))[::-1] for s in args.sizes.split(",")]
        logs = {(h, w): table_log(Path(args.dir), args.kind, args.frames, (h, w)) for h, w in sizes}
        stage_table(logs, [int(c) for c in args.cores.split(",")], args.against)
        return
    d = Path(args.dir)
    if args.log is not None and (args.stages_only or args.bin_stages):
        log, ply = args.log, None
    else:
        log, ply = prepare(d, args.kind, args.frames)
    if args.bin_stages or (args.stages_only and args.against is not None):
        os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")
        alternating_stage_table(log, ply, args.against, args.repeats, bin_only=args.bin_stages)
        return
    if args.stages or args.stages_only or args.against:
        os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")
        old = stage_costs_of_tree(args.against, log, ply) if args.against else None
        print_stage_table(stage_costs_of_tree(Path(__file__).resolve().parents[1], log, ply), old)
        if args.stages_only:
            return
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
