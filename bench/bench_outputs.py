"""Benchmark: what replay's outputs cost per frame: the results file (``--out``, ``--out --out-cloud``) and
the Rerun recording (``--rrd``, default detail, with the truth's verdicts when the log has truth).

Run: ``.venv/bin/python bench/bench_outputs.py --log LOG.mcap [LOG2.mcap ...] [--frames N] [--repeats R]
[--rounds K] [--against OLD] [--outputs rrd,results,results+cloud] [--profile rrd|results] [--dump FRAMES.pickle]``

The pipeline runs once on the log's first N frames (this tree) and its frames and results are kept
(pickled to a temporary file, or to ``--dump``, which a later run reuses instead of running the pipeline
again). Then each output's sink is fed those same frames, ``--repeats`` times,
and for each output it prints the CPU ms per frame of its ``write`` (``time.process_time``: every thread
of the process, so Rerun's own encoder threads count; median over frames and repeats, the first frame
of each repeat excluded), the calling thread's share of it ("(caller)", ``time.thread_time``: the sink's own
Python and numpy; the rest is Rerun's encoder and writer threads), the CPU ms of ``close`` per frame, the
file's MB per frame, and "open ms": the CPU ms of making and starting the process's first sink of the output
(once a process: the libraries the sink loads, Rerun and pyarrow for the recording, included). ``--against
DIR`` measures the sinks of the source tree DIR (the previous release: ``git -C /work/main archive HEAD |
tar -x -C DIR``) on the same frames in subprocesses of the same run, ``--rounds`` times alternating with
this tree's (medians of the rounds), and prints the ratios old / new.
``--python-side`` measures only the recording's Python side (``viz.log_frame`` and ``viz.log_verdicts`` into a
recording that drops its input), this tree's and ``--against``'s ``viz.py`` alternating in one process.
``--profile rrd`` prints the cProfile of this tree's Rerun writes (where the time goes). Several logs
(e.g. a 640 x 480 and a 1920 x 1200 one) are measured one after the other, a table each; ``--outputs``
picks the outputs measured (the Rerun recording alone: ``--outputs rrd``).
The machine is shared: CPU time, not wall time, is compared.

Measured (issue 32, item 3: the recording at default detail, with the truth's verdicts): see
docs/performance.md, "Rerun logging and reading (issue 32, items 1 and 3)".
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

OUTPUTS = ("results", "results+cloud", "rrd")


def capture(log: Path, frames: int, dump: Path) -> None:
    """Run the pipeline on the first ``frames`` frames of ``log`` and pickle (info, [(frame, result)])."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession

    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    pairs: list[tuple[Any, Any]] = []

    class Keep:
        def start(self, info: Any) -> None:
            pass

        def write(self, frame: Any, result: Any) -> None:
            pairs.append((frame, result))

        def close(self, *, completed: bool) -> None:
            pass

        def outputs(self) -> dict[str, str]:
            return {}

    session.run(Keep(), frames=(0, frames))  # type: ignore[arg-type]  # a FrameSink
    info = session.start_info(None)
    with open(dump, "wb") as f:
        pickle.dump({"log": str(log), "info": info, "pairs": pairs}, f, protocol=pickle.HIGHEST_PROTOCOL)


def _sink(kind: str, path: Path) -> Any:
    from replay.pipeline.sinks import RerunSink, ResultsSink

    if kind == "rrd":
        return RerunSink(rrd=path)
    return ResultsSink(path, cloud=kind == "results+cloud")


def measure(dump: Path, repeats: int, out_dir: Path, profile: str | None,
            outputs: tuple[str, ...] = OUTPUTS) -> dict[str, dict[str, float]]:
    """CPU ms per frame of write and close, MB per frame, of every output of this process's tree."""
    import dataclasses

    with open(dump, "rb") as f:
        data = pickle.load(f)
    info, pairs = data["info"], data["pairs"]
    try:
        from annotate.judge import judge_for_log
        from replay.logs.reader import LogReader

        reader = LogReader(data["log"])
        judge = judge_for_log(data["log"], reader.mask_topics, info.config.methods)
    except Exception as e:  # noqa: BLE001 - a log without truth: the recording without verdicts
        print(f"no judge: {e}", file=sys.stderr)
        judge = None
    out: dict[str, dict[str, float]] = {}
    for kind in outputs:
        writes: list[float] = []
        mains: list[float] = []  # the calling thread's share of each write (the rest: Rerun's own threads)
        closes: list[float] = []
        opened = float("nan")  # CPU s of making and starting the first sink of the process (its imports included)
        size = 0.0
        prof = None
        if profile is not None and kind.startswith(profile) and kind != "results+cloud":
            import cProfile

            prof = cProfile.Profile()
        for rep in range(repeats):
            path = out_dir / (kind.replace("+", "_") + (".rrd" if kind == "rrd" else ".mcap"))
            c = time.process_time()
            sink = _sink(kind, path)
            sink.start(dataclasses.replace(info, judge=judge if kind == "rrd" else None))
            if rep == 0:
                opened = time.process_time() - c
            for i, (frame, result) in enumerate(pairs):
                if prof is not None:
                    prof.enable()
                c, m = time.process_time(), time.thread_time()
                sink.write(frame, result)
                dt, dm = time.process_time() - c, time.thread_time() - m
                if prof is not None:
                    prof.disable()
                if i > 0 or len(pairs) == 1:
                    writes.append(dt)
                    mains.append(dm)
            c = time.process_time()
            sink.close(completed=True)
            closes.append((time.process_time() - c) / len(pairs))
            size = path.stat().st_size / 1e6 / len(pairs)
        out[kind] = {"write_ms": 1000 * statistics.median(writes), "main_ms": 1000 * statistics.median(mains),
                     "close_ms": 1000 * statistics.median(closes), "mb": size, "open_ms": 1000 * opened}
        if prof is not None:
            import pstats

            pstats.Stats(prof, stream=sys.stderr).sort_stats("cumulative").print_stats(40)
    if judge is not None:
        judge.close()
    return out


def python_side(dump: Path, against: Path | None, rounds: int) -> None:
    """CPU ms a frame of the recording's Python side alone (``viz.log_frame`` and ``viz.log_verdicts`` into a
    recording that drops what it is given: the sink's numpy and the archetypes it builds, not Rerun's
    encoding), this tree's ``replay/pipeline/viz.py`` and ``against``'s loaded side by side in one process
    and alternated ``rounds`` times (medians): the frames, the truth's verdicts and the machine's load are
    the same for both."""
    import importlib.util

    from annotate.judge import judge_for_log
    from replay.logs.reader import LogReader
    from replay.pipeline import viz

    with open(dump, "rb") as f:
        data = pickle.load(f)
    info, pairs = data["info"], data["pairs"]
    pairs = pairs[1:] or pairs
    try:
        judge = judge_for_log(data["log"], LogReader(data["log"]).mask_topics, info.config.methods)
    except Exception:  # noqa: BLE001 - a log without truth: no verdicts
        judge = None
    verdicts = [None if judge is None else judge.judge(f, r) for f, r in pairs]
    trees: dict[str, Any] = {"this tree": viz}
    if against is not None:
        spec = importlib.util.spec_from_file_location("viz_previous", against / "replay" / "pipeline" / "viz.py")
        assert spec is not None and spec.loader is not None
        old = importlib.util.module_from_spec(spec)
        sys.modules["viz_previous"] = old  # its dataclasses look their module up
        spec.loader.exec_module(old)
        trees = {"previous": old, **trees}

    class Dropped:
        def log(self, *a: Any, **k: Any) -> None:
            pass

        def send_columns(self, *a: Any, **k: Any) -> None:
            pass

        def set_time(self, *a: Any, **k: Any) -> None:
            pass

    rec = Dropped()
    step = info.config.zcut.step
    got: dict[str, list[float]] = {k: [] for k in trees}
    for r in range(max(rounds, 1)):
        for name in list(trees) if r % 2 == 0 else list(trees)[::-1]:
            m = trees[name]
            opts = m.VizOptions()
            c = time.thread_time()
            for (frame, result), v in zip(pairs, verdicts):
                m.log_frame(rec, frame, result, step_mm=step, opts=opts)
                if v is not None:
                    m.log_verdicts(rec, frame, v, judge.methods, opts)  # type: ignore[union-attr]  # v: a judge's
            got[name].append((time.thread_time() - c) / len(pairs))
    h, w = pairs[0][0].xyz.shape[:2]
    med = {k: 1000 * statistics.median(v) for k, v in got.items()}
    line = ", ".join(f"{k} {v:.2f}" for k, v in med.items())
    ratio = f", previous / this {med['previous'] / med['this tree']:.2f}" if "previous" in med else ""
    print(f"python side of the recording, {Path(data['log']).name} ({w}x{h}, {len(pairs)} frames"
          f"{', verdicts' if judge is not None else ''}): CPU ms a frame, medians of {max(rounds, 1)} "
          f"alternating rounds: {line}{ratio}")


def measure_tree(tree: Path, dump: Path, repeats: int, profile: str | None,
                 outputs: tuple[str, ...] = OUTPUTS) -> dict[str, dict[str, float]]:
    """:func:`measure` with the code of the source tree ``tree``, in a subprocess."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")
    cmd = [sys.executable, __file__, "--measure-json", str(dump), str(repeats), "--outputs", ",".join(outputs)]
    if profile:
        cmd += ["--profile", profile]
    res = subprocess.run(cmd, env=env, cwd=str(tree), check=True, stdout=subprocess.PIPE, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def _medians(runs: list[dict[str, dict[str, float]]]) -> dict[str, dict[str, float]]:
    return {k: {f: statistics.median(r[k][f] for r in runs) for f in runs[0][k]} for k in runs[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, nargs="+", required=False,
                    help="logs with their bin model attachment, measured one after the other")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=2, help="repeats of the frames in one process")
    ap.add_argument("--rounds", type=int, default=3, help="alternating processes of the previous tree and this one")
    ap.add_argument("--against", type=Path, help="source tree of the previous release, measured in the same run")
    ap.add_argument("--profile", choices=("rrd", "results"), help="cProfile this tree's writes of that output")
    ap.add_argument("--outputs", default=",".join(OUTPUTS), help=f"the outputs measured, of {','.join(OUTPUTS)}")
    ap.add_argument("--python-side", action="store_true",
                    help="only the recording's Python side (viz into a recording that drops its input), this tree's "
                         "viz.py and --against's in one process, alternating --rounds times")
    ap.add_argument("--dump", type=Path, help="keep the captured frames in this file and reuse them when it exists "
                    "(one log only): the pipeline then runs once over several invocations")
    ap.add_argument("--measure-json", nargs=2, help=argparse.SUPPRESS)  # DUMP REPEATS: one JSON line
    args = ap.parse_args()
    outputs = tuple(o for o in OUTPUTS if o in args.outputs.split(","))
    if not outputs:
        ap.error(f"--outputs: none of {','.join(OUTPUTS)}")
    if args.measure_json:
        with tempfile.TemporaryDirectory(prefix="zcut_bench_outputs_") as d:
            print(json.dumps(measure(Path(args.measure_json[0]), int(args.measure_json[1]), Path(d), args.profile,
                                     outputs)))
        return
    if args.log is None:
        ap.error("--log LOG.mcap is required (e.g. a 1920x1200 `zcut synth` log with its bin model)")
    if args.dump is not None and len(args.log) != 1:
        ap.error("--dump goes with one --log")
    if args.python_side:
        for log in args.log:
            with tempfile.TemporaryDirectory(prefix="zcut_bench_outputs_") as d:
                dump = Path(d) / "frames.pickle" if args.dump is None else args.dump
                if args.dump is None or not dump.exists():
                    capture(log, args.frames, dump)
                python_side(dump, args.against, args.rounds)
        return
    for log in args.log:
        bench_log(log, args, outputs)


def bench_log(log: Path, args: argparse.Namespace, outputs: tuple[str, ...]) -> None:
    """Measure the outputs of one log (this tree, and ``--against``'s in the same run) and print its table."""
    with tempfile.TemporaryDirectory(prefix="zcut_bench_outputs_") as d:
        dump = Path(d) / "frames.pickle" if args.dump is None else args.dump
        if args.dump is None or not dump.exists():
            capture(log, args.frames, dump)
        with open(dump, "rb") as f:
            pairs = pickle.load(f)["pairs"]
        h, w = pairs[0][0].xyz.shape[:2]
        olds: list[dict[str, dict[str, float]]] = []
        news: list[dict[str, dict[str, float]]] = []
        for r in range(max(args.rounds, 1)):  # alternating: a shared machine's load swings both alike
            if args.against:
                olds.append(measure_tree(args.against, dump, args.repeats, None, outputs))
            news.append(measure_tree(Path(__file__).resolve().parents[1], dump, args.repeats,
                                     args.profile if r == 0 else None, outputs))
        old = _medians(olds) if olds else None
        new = _medians(news)
    print(f"\noutputs of {log.name}: {len(pairs)} frames of {w}x{h}; CPU ms per frame (medians of "
          f"{args.rounds} alternating rounds of {args.repeats} repeats, first frame of each excluded) and MB per frame")
    head = f"  {'output':14s} {'write ms':>9s} {'(caller)':>9s} {'close ms':>9s} {'MB':>7s} {'open ms':>8s}"
    if old is not None:
        head += (f" | {'prev write':>10s} {'(caller)':>9s} {'prev close':>10s} {'prev MB':>8s} | {'write x':>8s}"
                 f" {'caller x':>8s} {'MB x':>6s}")
    print(head)
    for kind in outputs:
        n = new[kind]
        line = (f"  {kind:14s} {n['write_ms']:9.1f} {n['main_ms']:9.1f} {n['close_ms']:9.1f} {n['mb']:7.3f}"
                f" {n.get('open_ms', float('nan')):8.1f}")
        if old is not None:
            o = old[kind]
            line += (f" | {o['write_ms']:10.1f} {o['main_ms']:9.1f} {o['close_ms']:10.1f} {o['mb']:8.3f} | "
                     f"{o['write_ms'] / max(n['write_ms'], 1e-9):8.2f} {o['main_ms'] / max(n['main_ms'], 1e-9):8.2f}"
                     f" {o['mb'] / max(n['mb'], 1e-9):6.2f} | prev open {o.get('open_ms', float('nan')):.1f}")
        print(line)


if __name__ == "__main__":
    main()
