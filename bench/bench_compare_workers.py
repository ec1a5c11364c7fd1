"""Benchmark: ``zcut compare`` on local worker processes against one process, and against the previous
code (the one-process comparison before it ran in units) measured in the same run.

Run: ``.venv/bin/python bench/bench_compare_workers.py [--logs 3] [--frames 4] [--size 240x320]
[--kinds rods,spheres,zinc_nuts] [--seed 10] [--repeats 2] [--dir DIR] [--old OLD_TREE] [--vs-replay]
[--b-zcut-only] [--processes]``

Synthesises (once, cached in ``--dir``) ``--logs`` small synthetic logs (rods, spheres, …) of
``--frames`` frames, rechunked to a frame per chunk (a unit per frame with ``--frames-per-unit 1``),
then runs the real command ``zcut compare LOGS --a zcut --b RHO.toml -o NEW_DIR`` ``--repeats`` times
each way, alternating:

- ``old``: the previous code (``--old``: a tree from ``git -C /work/main archive HEAD``, run with
  ``PYTHONPATH=OLD``; skipped without it), one process;
- ``workers 0``: this tree, the units one after another in this process;
- ``workers 2``: this tree, two local worker processes.

Each run is the whole command (start-up, planning, workers, the writer): its CPU time is that of the
command and of every process it waited for (``resource.getrusage(RUSAGE_CHILDREN)`` around it), which
counts the workers' imports and start-up too. Printed as medians, with the load average (the machine
is shared: wall-clock figures say little, CPU-s are the figures), CPU-s per frame each way and the
ratios to ``workers 0`` and ``old``; the outputs of every way are checked equal (compare.json but its
cost and paths, summary.parquet, disagreement.npz).

``--vs-replay``: instead, the cost of a comparison against one replay of A on the same logs (the
issue's target: at most 1.3 x when A and B share the bin stages), all in this process (numba's kernels
warmed by a first run of each way, not measured), CPU time of the process (``time.process_time``,
its threads included; the garbage left by the way before collected first, not counted), alternating the ways
``--repeats`` times (each comparison's run also against the replay run of the same repeat: the issue's
target holds run by run, not only in the medians; every run's ratio is printed, and the same by user CPU
alone, without the kernel's time: page faults): ``zcut replay LOG --methods zcut``
over every log (the table to a string, no outputs; then with ``--rrd``), the same of B
(``--config RHO.toml``: z-cut at ρ_thr 0.035 and SOR), ``studies.compare.run`` with
``workers=0`` without ``.rrd`` and report, with the ``.rrd``, and the whole command (``.rrd`` and
``report.html``). Then, per frame of the first log, what the one writer's recording costs either way
(a unit's part holding the frame's content, or the writer reading the frame again from its log):
CPU of making the content (JPEG, points) in the unit, of reading it back from the part, of reading
and decoding the frame again, and the part's bytes with and without it.

``--vs-replay --processes [--old OLD]``: the same target as users run it, each command in a process of its
own (start-up and imports counted, as ``report.html``'s plotting library was): ``zcut replay`` against
``zcut compare --workers 0`` without and with the recordings, this tree and the old one alternating.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE / "tests" / "studies"))


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(argv: list[str], *, tree: Path, cwd: Path) -> tuple[float, float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    c0, t0 = _cpu_children(), time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "cli", *argv], cwd=cwd, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(argv)}: exit {p.returncode}: {p.stderr[-2000:]}")
    return _cpu_children() - c0, time.perf_counter() - t0


def _outputs(d: Path) -> tuple:
    import numpy as np
    import pyarrow.parquet as pq

    rep = json.loads((d / "compare.json").read_text())
    for k in ("cost", "outputs"):
        rep.pop(k)
    for lg in rep["logs"]:
        lg["log"] = Path(lg["log"]).name
    with np.load(d / "disagreement.npz") as z:
        npz = {k: z[k].tolist() for k in z.files}
    return json.dumps(rep, sort_keys=True), pq.read_table(d / "summary.parquet").to_pylist(), json.dumps(npz)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=3)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--size", default="240x320")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/bench_compare_workers"))
    ap.add_argument("--old", type=Path, help="the previous code's tree (git archive of the base)")
    ap.add_argument("--kinds", default="rods,spheres,zinc_nuts", help="the logs' part kinds, in turn")
    ap.add_argument("--seed", type=int, default=10, help="the first log's seed (then +1 each)")
    ap.add_argument("--b-zcut-only", action="store_true",
                    help="B runs the z-cut alone (methods = [\"zcut\"]), as A; default: the default methods")
    ap.add_argument("--vs-replay", action="store_true", help="compare's cost against one replay of A, in process")
    ap.add_argument("--processes", action="store_true",
                    help="with --vs-replay: each way the whole command in a process of its own (start-up, imports)")
    args = ap.parse_args()
    from test_batch_ray import rechunk

    d = args.dir
    d.mkdir(parents=True, exist_ok=True)
    kinds = tuple(args.kinds.split(","))
    logs = []
    for i in range(args.logs):
        log = d / f"log{i}.mcap"
        if not log.is_file():
            whole = d / f"log{i}_whole.mcap"
            subprocess.run([sys.executable, "-m", "cli", "synth", "-o", str(whole), "--parts", kinds[i % len(kinds)],
                            "--frames", str(args.frames), "--seed", str(args.seed + i), "--size", args.size],
                           env={**os.environ, "PYTHONPATH": str(HERE)}, check=True, capture_output=True)
            rechunk(whole, log, chunk_size=16 * 1024)
        logs.append(log.name)
    (d / "rho.toml").write_text(('methods = ["zcut"]\n' if args.b_zcut_only else "") + "[zcut]\nrho_thr = 0.035\n")
    if args.vs_replay and args.processes:
        vs_replay_processes(d, logs, args)
        return
    if args.vs_replay:
        vs_replay(d, logs, args)
        return
    base = ["compare", *logs, "--a", "zcut", "--b", "rho.toml"]
    ways: dict[str, tuple[list[str], Path]] = {}
    if args.old is not None:
        ways["old"] = (base, args.old)
    ways["workers 0"] = ([*base, "--workers", "0", "--frames-per-unit", "1"], HERE)
    ways["workers 2"] = ([*base, "--workers", "2", "--frames-per-unit", "1"], HERE)
    for name, (argv, tree) in ways.items():  # warm numba's caches of each tree (not measured)
        out = d / f"warm {name}"
        shutil.rmtree(out, ignore_errors=True)
        _run([*argv, "-o", str(out)], tree=tree, cwd=d)
    cpu: dict[str, list[float]] = {k: [] for k in ways}
    wall: dict[str, list[float]] = {k: [] for k in ways}
    outputs = {}
    for r in range(args.repeats):
        for name, (argv, tree) in ways.items():
            out = d / f"run {name} {r}"
            shutil.rmtree(out, ignore_errors=True)
            c, w = _run([*argv, "-o", str(out)], tree=tree, cwd=d)
            cpu[name].append(c)
            wall[name].append(w)
            outputs[name] = _outputs(out)
    n = args.logs * args.frames
    print(f"{args.logs} logs x {args.frames} frames of {args.size}, {args.repeats} runs each, load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    ref = statistics.median(cpu["workers 0"])
    for name in ways:
        c = statistics.median(cpu[name])
        line = (f"{name:10s} CPU {c:6.1f} s ({', '.join(f'{x:.1f}' for x in cpu[name])}), {c / n:.2f} CPU-s/frame, "
                f"wall {statistics.median(wall[name]):.1f} s; x{c / ref:.2f} of workers 0")
        if "old" in cpu:
            line += f", x{c / statistics.median(cpu['old']):.2f} of old"
        print(line)
    same = len({v for v in (json.dumps(o, sort_keys=True, default=str) for o in outputs.values())}) == 1
    print("outputs identical every way:", same)


def vs_replay(d: Path, logs: list[str], args: argparse.Namespace) -> None:
    import contextlib
    import io

    from cli.main import main as cli
    from studies.compare import CompareOptions, run

    paths = tuple(d / lg for lg in logs)

    def replay(rrd: bool, side: tuple[str, ...] = ("--methods", "zcut")) -> None:
        for i, log in enumerate(paths):
            extra = ["--rrd", str(d / "vs" / f"replay{i}.rrd"), "--force"] if rrd else []
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                assert cli(["replay", str(log), *side, *extra]) == 0

    def compare(rrd: bool, report: bool) -> None:
        out = d / "vs" / "compare"
        shutil.rmtree(out, ignore_errors=True)
        with contextlib.redirect_stderr(io.StringIO()):
            run(CompareOptions(logs=paths, a="zcut", b=str(d / "rho.toml"), out=out, workers=0, rrd=rrd,
                               report=report))

    (d / "vs").mkdir(exist_ok=True)
    ways = {"replay A": lambda: replay(False), "replay B": lambda: replay(False, ("--config", str(d / "rho.toml"))),
            "compare": lambda: compare(False, False),
            "replay A --rrd": lambda: replay(True), "compare .rrd": lambda: compare(True, False),
            "compare .rrd + report": lambda: compare(True, True)}
    for fn in ways.values():  # warm
        fn()
    cpu: dict[str, list[float]] = {k: [] for k in ways}
    user: dict[str, list[float]] = {k: [] for k in ways}
    load = []
    for _ in range(args.repeats):
        for name, fn in ways.items():
            gc.collect()  # the garbage of the way before is not charged to this one
            c0, u0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
            fn()
            cpu[name].append(time.process_time() - c0)
            user[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_utime - u0)
            load.append(os.getloadavg()[0])
    n = args.logs * args.frames
    print(f"{args.logs} logs ({', '.join(logs)}) x {args.frames} frames of {args.size}, {args.repeats} runs each, "
          f"in process, load average {min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores")
    for name in ways:
        c = statistics.median(cpu[name])
        ref_name = "replay A --rrd" if ".rrd" in name else "replay A"
        ref = statistics.median(cpu[ref_name])
        line = (f"{name:22s} CPU {c:6.2f} s ({', '.join(f'{x:.2f}' for x in cpu[name])}), {c / n:.3f} CPU-s/frame; "
                f"x{c / ref:.2f} of {ref_name}")
        if name.startswith("compare"):  # each run against the replay run just before it in the same repeat
            each = [x / r for x, r in zip(cpu[name], cpu[ref_name], strict=True)]
            line += f"; run by run x{min(each):.2f}-{max(each):.2f}, {sum(e <= 1.3 for e in each)}/{len(each)} <= 1.3"
            users = [x / r for x, r in zip(user[name], user[ref_name], strict=True)]
            line += (f"\n{'':24s}every run: {', '.join(f'{e:.2f}' for e in each)}; user CPU alone: "
                     f"{', '.join(f'{e:.2f}' for e in users)}")
        print(line)
    writer_cost(paths[0], d)


def vs_replay_processes(d: Path, logs: list[str], args: argparse.Namespace) -> None:
    """``--vs-replay --processes``: the commands as a user runs them, each in a process of its own (CPU of
    the process and its children, ``resource.getrusage``: start-up and imports included), alternating
    ``--repeats`` times after a warm run of each, this tree and (``--old``) the old one in turn:
    ``zcut replay LOG --methods zcut`` per log, without outputs and with ``--rrd``; ``zcut compare LOGS
    --a zcut --b rho.toml --workers 0``, with ``--no-rrd`` (its JSON, parquet and page) and with
    ``compare.rrd``."""
    out = d / "vs"
    out.mkdir(exist_ok=True)
    trees = {"": HERE, **({"old ": args.old} if args.old is not None else {})}

    def replay(tree: Path, rrd: bool) -> float:
        total = 0.0
        for i, log in enumerate(logs):
            extra = ["--rrd", str(out / f"replay{i}.rrd"), "--force"] if rrd else []
            total += _run(["replay", log, "--methods", "zcut", *extra], tree=tree, cwd=d)[0]
        return total

    def compare(tree: Path, rrd: bool) -> float:
        target = out / "compare_cli"
        shutil.rmtree(target, ignore_errors=True)
        extra = [] if rrd else ["--no-rrd"]
        return _run(["compare", *logs, "--a", "zcut", "--b", "rho.toml", "--workers", "0", "-o", str(target), *extra],
                    tree=tree, cwd=d)[0]

    ways: dict[str, Any] = {}
    for tag, tree in trees.items():
        ways.update({f"{tag}zcut replay": lambda t=tree: replay(t, False),
                     f"{tag}zcut compare --no-rrd": lambda t=tree: compare(t, False),
                     f"{tag}zcut replay --rrd": lambda t=tree: replay(t, True),
                     f"{tag}zcut compare": lambda t=tree: compare(t, True)})
    for fn in ways.values():  # warm (numba's caches of each tree)
        fn()
    cpu: dict[str, list[float]] = {k: [] for k in ways}
    load = []
    for _ in range(args.repeats):
        for name, fn in ways.items():
            cpu[name].append(fn())
            load.append(os.getloadavg()[0])
    n = args.logs * args.frames
    print(f"{args.logs} logs ({', '.join(logs)}) x {args.frames} frames of {args.size}, {args.repeats} runs each, "
          f"a process each, load average {min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores")
    for name in ways:
        c = statistics.median(cpu[name])
        tag = "old " if name.startswith("old ") else ""
        ref_name = f"{tag}zcut replay --rrd" if name.endswith("zcut compare") else f"{tag}zcut replay"
        ref = statistics.median(cpu[ref_name])
        print(f"{name:26s} CPU {c:6.2f} s ({', '.join(f'{x:.2f}' for x in cpu[name])}), {c / n:.3f} CPU-s/frame; "
              f"x{c / ref:.2f} of {ref_name}")


def writer_cost(log: Path, d: Path) -> None:
    """Per frame: the recording's content kept in the part against the frame read again by the writer."""
    import pyarrow.parquet as pq

    from replay.logs.reader import LogReader
    from studies.compare_outputs import frame_view
    from studies.compare_records import FrameImages

    rows = sorted(pq.read_table(next((d / "vs" / "compare" / "parts").glob("*.parquet"))).to_pylist(),
                  key=lambda r: r["frame"])
    make, back, plain, again, with_b, without_b = [], [], [], [], [], []
    reader = LogReader(log)
    frames = {f.index: f for f in reader.frames()}
    for row in rows:
        if row["images"] is None:
            continue
        img = FrameImages.from_bytes(row["images"])
        bare = FrameImages(img.verdict_a, img.verdict_b, img.diff, img.who)
        f = frames[row["frame"]]
        c0 = time.process_time()
        full = FrameImages(img.verdict_a, img.verdict_b, img.diff, img.who, frame_view(f, img.diff)).to_bytes()
        c1 = time.process_time()
        bare_b = bare.to_bytes()
        c2 = time.process_time()
        FrameImages.from_bytes(full)
        c3 = time.process_time()
        FrameImages.from_bytes(bare_b)
        c4 = time.process_time()
        make.append((c1 - c0) - (c2 - c1))  # the content made and packed, beyond the bare images
        back.append((c3 - c2) - (c4 - c3))
        plain.append(c4 - c3)
        with_b.append(len(full))
        without_b.append(len(bare_b))
    diffs = {row["frame"]: FrameImages.from_bytes(row["images"]).diff for row in rows if row["images"] is not None}
    c0 = time.process_time()
    for f in LogReader(log).frames():  # as the writer read them again: one stream per unit, here one per log
        if f.index in diffs:
            frame_view(f, diffs[f.index])
    again.append((time.process_time() - c0) / max(len(diffs), 1))
    med = statistics.median
    print(f"the recording's content per frame ({len(make)} frames of {log.name}): in the part +{med(make) * 1e3:.1f} "
          f"CPU-ms in the unit (JPEG, points, packing), +{med(back) * 1e3:.1f} ms for the writer to unpack, part "
          f"{med(without_b) / 1e3:.1f} -> {med(with_b) / 1e3:.1f} kB; read again by the writer instead: "
          f"{med(again) * 1e3:.1f} CPU-ms (open, read, decode the frame, JPEG, points)")


if __name__ == "__main__":
    main()
