"""Benchmark: ``zcut compare`` on local worker processes against one process, and against the previous
code (the one-process comparison before it ran in units) measured in the same run.

Run: ``.venv/bin/python bench/bench_compare_workers.py [--logs 3] [--frames 4] [--size 240x320]
[--repeats 2] [--dir DIR] [--old OLD_TREE]``

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
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

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
    args = ap.parse_args()
    from test_batch_ray import rechunk

    d = args.dir
    d.mkdir(parents=True, exist_ok=True)
    kinds = ("rods", "spheres", "zinc_nuts", "rods", "spheres")
    logs = []
    for i in range(args.logs):
        log = d / f"log{i}.mcap"
        if not log.is_file():
            whole = d / f"log{i}_whole.mcap"
            subprocess.run([sys.executable, "-m", "cli", "synth", "-o", str(whole), "--parts", kinds[i % len(kinds)],
                            "--frames", str(args.frames), "--seed", str(10 + i), "--size", args.size],
                           env={**os.environ, "PYTHONPATH": str(HERE)}, check=True, capture_output=True)
            rechunk(whole, log, chunk_size=16 * 1024)
        logs.append(log.name)
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
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


if __name__ == "__main__":
    main()
