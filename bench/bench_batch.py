"""Benchmark: ``zcut batch`` throughput on 1 and 2 local worker processes and on a 2-CPU Ray cluster,
at 1920 × 1200, and the figures of a scaling model.

Run: ``.venv/bin/python bench/bench_batch.py [--logs 2] [--frames 4] [--repeats 3] [--dir DIR] [--no-ray]``

Synthesises (once, cached in ``--dir``) ``--logs`` logs of ``--frames`` filled-bin frames each (≥ 8
frames in all) and five empty-bin scans, builds the bin model, then runs the real command
``zcut batch LOGS -o NEW_DIR --bin-model bin.ply`` ``--repeats`` times each way, alternating:

- ``local 1``: ``--workers 1`` with its thread pools at one thread (one core's worth: the per-core
  figure a scaling model needs; the 2-core estimate below assumes it); ``local 2``: ``--workers 2``
  (one thread each: the executors give each worker its share of the cores);
- ``ray 2``: ``--ray auto`` on a private 2-CPU Ray cluster (``ray start --head``) in network, PID and
  mount namespaces of its own (``tests/studies/ray_in_netns.py``: loopback only, stopped after).
  All ways run inside that namespace, so they see the same machine;
- with ``--threads-ab``, also ``local 2 x2t`` and ``ray 2 x2t``: the same with every worker's thread
  pools at the machine's core count (``NUMBA_NUM_THREADS`` / ``OMP_NUM_THREADS`` set: the behaviour
  before the executors sized them to a worker's share of the cores).

Each run is the whole command (start-up, planning, workers, tables). Printed, as medians of the
alternated runs with the load average (the machine is shared):

- frames/s on the wall clock (frames / the command's wall time);
- the CPU seconds of every process of the run, from ``/proc`` (``ray_in_netns.run_measured``): the
  driver, each worker, Ray's own processes; and from them the frames/s the run would reach on 2
  cores of its own: frames / max(driver + busiest worker, all CPU / 2). On this machine other
  sessions' processes take most of the cores, and the kernel shares the CPU between sessions
  (autogroup), so more workers do not get more CPU here: the wall-clock ratios say little, the
  CPU-based ones are the scaling figures;
- the ratios local 2 / local 1 (target ≥ 1.7) and Ray 2 / local 2 (target: Ray at most 15 % slower),
  the units' CPU seconds per frame and peak memory per worker (``summary.json``'s ``this_run``).

Then the scaling model's inputs, measured here:

- CPU seconds per frame in steady state (units of one frame; the first unit of each log in a worker
  also opens the log's session, reported apart), and the worker's start-up (imports) in CPU seconds;
- bytes a worker reads per frame (``/proc/self/io`` ``rchar`` while reading the log's frames) and
  the log's bytes per frame on disk;
- the driver's planning cost per log (content hash, chunk index, first frame, config), serial;
- from these: frames per hour of a 64-core machine and of a 10-node × 64-core cluster, and the read
  bandwidth they need.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "studies"))

from ray_in_netns import netns_unavailable, run_measured, run_with_ray_cluster

SIZE = (1200, 1920)
THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
ZCUT = str(Path(sys.executable).with_name("zcut"))


def prepare(d: Path, kind: str, logs: int, frames: int) -> tuple[list[Path], Path]:
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model, save_bin_model
    from replay.synth.log import write_synthetic_log

    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(logs):
        p = d / f"batch_{kind}_{frames}x{SIZE[1]}x{SIZE[0]}_s{i + 1}.mcap"
        if not p.is_file():
            print(f"synthesising {frames} frames of {kind} at {SIZE[1]}x{SIZE[0]} -> {p}", flush=True)
            write_synthetic_log(p, kind=kind, frames=frames, seed=i + 1, size=SIZE)
        paths.append(p)
    ply = d / f"batch_bin_{SIZE[1]}x{SIZE[0]}.ply"
    if not ply.is_file():
        empty = d / "batch_empty.mcap"
        print(f"synthesising 5 empty-bin scans -> {empty}", flush=True)
        write_synthetic_log(empty, empty=True, frames=5, seed=11, size=SIZE)
        model, _ = build_bin_model(LogReader(empty).frames())
        save_bin_model(model, ply)
    return paths, ply


def read_cost(logs: list[Path]) -> dict:
    """Bytes read per frame by a reader of the log (rchar) and the log's bytes per frame on disk."""
    from replay.logs.reader import LogReader

    def rchar() -> int:
        for line in Path("/proc/self/io").read_text().splitlines():
            if line.startswith("rchar:"):
                return int(line.split()[1])
        return 0

    n = 0
    before = rchar()
    for p in logs:
        for _ in LogReader(p).frames():
            n += 1
    read = rchar() - before
    disk = sum(p.stat().st_size for p in logs)
    return {"frames": n, "read_bytes_per_frame": read / n, "disk_bytes_per_frame": disk / n}


def planning_cost(logs: list[Path], bin_model: Path) -> dict:
    """The driver's serial work per log: hash, chunk index, first frame, config."""
    from studies.driver import plan_logs

    c0, t0 = time.process_time(), time.perf_counter()
    plan_logs([str(p) for p in logs], config_file=None, overrides={}, topic=None, frames_per_unit=8, whole=False)
    return {"cpu_s_per_log": (time.process_time() - c0) / len(logs), "wall_s_per_log": (time.perf_counter() - t0) / len(logs)}


def import_cost() -> float:
    """CPU seconds a fresh worker spends importing what a unit needs."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    code = "import studies.work, annotate.truth, replay.pipeline.session, replay.pipeline.stages, pyarrow"
    subprocess.run([sys.executable, "-c", code], check=True)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)


def batch_command(logs, ply, out: Path, how: str, extra=()) -> dict:
    argv = [ZCUT, "batch", *map(str, logs), "-o", str(out), "--bin-model", str(ply), *extra]
    argv += ["--ray", "auto"] if how.startswith("ray") else ["--workers", how.split()[1]]
    n = None
    if how == "local 1":  # one core's worth: the per-core cost, and a valid 2-core estimate below
        n = "1"
    elif how.endswith("x2t"):  # every worker's thread pools at the core count: oversubscribed
        n = str(os.cpu_count() or 2)
    env = {} if n is None else {k: n for k in THREAD_VARIABLES}
    return {"argv": argv, "env": env}


def run_all(commands: list[dict], use_ray: bool) -> list[dict]:
    if use_ray:
        return run_with_ray_cluster(commands, cpus=2, timeout=7200)["results"]
    return [run_measured(c["argv"], env={**os.environ, **c["env"]}, scope="tree") for c in commands]


RAY_AGENTS = ("ray::DashboardAgent", "ray::RuntimeEnvAgent")


def cpu_split(res: dict, cores: int) -> dict:
    """A run's CPU seconds: the driver, each worker, the rest (Ray's own processes), and the time the
    run would take on ``cores`` cores of its own: the driver and the busiest worker one after the
    other, or all the CPU spread over the cores, whichever is longer."""
    driver = sum(p["cpu_s"] for p in res["procs"] if p["pid"] == res["pid"])
    workers = [p["cpu_s"] for p in res["procs"]
               if (p["ppid"] == res["pid"] and "spawn_main" in p["cmd"])
               or (p["cmd"].startswith("ray::") and p["cmd"].split()[0] not in RAY_AGENTS)
               or "default_worker.py" in p["cmd"]]
    total = sum(p["cpu_s"] for p in res["procs"])
    other = total - driver - sum(workers)
    dedicated = max(driver + max(workers, default=0.0), total / cores)
    return {"driver": driver, "workers": workers, "other": other, "total": total, "dedicated_s": dedicated}


def unit_costs(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "parts").glob("*.json"))]


def _median_nth(lists: list[list[float]], i: int) -> float:
    """The median over runs of each run's i-th largest value."""
    return statistics.median(sorted(v, reverse=True)[i] for v in lists if len(v) > i)


def hash_cost(logs: list[Path]) -> float:
    """CPU seconds per byte of the driver's content hash (``file_sha256``)."""
    from studies.driver import file_sha256

    c0 = time.process_time()
    for p in logs:
        file_sha256(p)
    return (time.process_time() - c0) / sum(p.stat().st_size for p in logs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=2)
    ap.add_argument("--frames", type=int, default=4, help="frames per log (>= 8 frames in all)")
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of each way; medians compared")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_batch"))
    ap.add_argument("--no-ray", action="store_true", help="local processes only")
    ap.add_argument("--threads-ab", action="store_true",
                    help="also run 2 workers with oversubscribed thread pools (the behaviour before)")
    args = ap.parse_args()
    if args.logs * args.frames < 8:
        ap.error("need >= 8 frames in all (--logs x --frames)")
    d = Path(args.dir)
    logs, ply = prepare(d, args.kind, args.logs, args.frames)
    frames = args.logs * args.frames

    use_ray = not args.no_ray
    if use_ray:
        try:
            import ray  # noqa: F401
        except ImportError:
            print("no ray package (pip install 'zcut[ray]'): local processes only")
            use_ray = False
    if use_ray and (why := netns_unavailable()) is not None:
        print(f"Ray left out: {why}")
        use_ray = False
    ways = ["local 1", "local 2"] + (["ray 2"] if use_ray else [])
    if args.threads_ab:
        ways += ["local 2 x2t"] + (["ray 2 x2t"] if use_ray else [])

    runs = d / "runs"
    runs.mkdir(exist_ok=True)
    stamp = time.strftime("%H%M%S")
    commands, labels = [], []
    # warm-up (numba caches, page cache), not counted; then the alternated repeats
    for r in range(args.repeats + 1):
        for w in ways:
            out = runs / f"{stamp}-{r}-{w.replace(' ', '')}"
            commands.append(batch_command(logs, ply, out, w))
            labels.append((r, w, out))
    # steady-state per-frame cost: one worker, units of one frame
    fpu1 = runs / f"{stamp}-fpu1"
    commands.append(batch_command(logs, ply, fpu1, "local 1", ("--frames-per-unit", "1")))
    labels.append((-1, "fpu1", fpu1))

    load0 = os.getloadavg()
    print(f"{frames} frames ({args.logs} logs x {args.frames}) at {SIZE[1]}x{SIZE[0]}, {args.kind}; "
          f"{args.repeats} alternated repeats of {', '.join(ways)} (+1 warm-up); load average {load0[0]:.2f}",
          flush=True)
    results = run_all(commands, use_ray)
    load1 = os.getloadavg()

    per_way: dict[str, list[dict]] = {w: [] for w in ways}
    for (r, w, out), res in zip(labels, results):
        if res["rc"] != 0:
            raise SystemExit(f"{w} run {r} failed (exit {res['rc']}): {res['stderr'][-2000:]}")
        if r < 1:
            continue
        summ = json.loads((out / "summary.json").read_text())["this_run"]
        cpu = cpu_split(res, 2)
        per_way[w].append({"wall_s": res["wall_s"], "fps": frames / res["wall_s"], "cpu": cpu,
                           "fps_dedicated": frames / cpu["dedicated_s"], **summ})

    print("\nwall clock (the machine is shared: other sessions' processes take most of the 2 cores):")
    print(f"{'way':12s} {'frames/s':>9s} {'runs (frames/s)':>24s}")
    med = {w: statistics.median(x["fps"] for x in per_way[w]) for w in ways}
    for w in ways:
        each = " ".join(f"{x['fps']:.3f}" for x in per_way[w])
        print(f"{w:12s} {med[w]:9.3f} {each:>24s}")
    print("\nCPU seconds per run (from /proc; medians) and frames/s on 2 cores of its own "
          "(driver + busiest worker, or all CPU / 2):")
    print(f"{'way':12s} {'driver':>7s} {'workers':>15s} {'Ray own':>8s} {'total':>7s} {'CPU-s/frame':>11s} "
          f"{'frames/s':>9s} {'unit CPU-s/fr':>13s} {'peak MB/worker':>14s}")
    ded = {}
    for w in ways:
        rs = per_way[w]
        ded[w] = statistics.median(x["fps_dedicated"] for x in rs)
        cpu = {k: statistics.median(x["cpu"][k] for x in rs) for k in ("driver", "other", "total")}
        nw = max(len(x["cpu"]["workers"]) for x in rs)
        ws = "+".join(f"{_median_nth([x['cpu']['workers'] for x in rs], i):.1f}" for i in range(nw))
        unit = statistics.median(x["cpu_seconds_per_frame"] for x in rs)
        rss = max(x["peak_rss_mb_per_worker"] for x in rs)
        print(f"{w:12s} {cpu['driver']:7.1f} {ws:>15s} {cpu['other']:8.1f} {cpu['total']:7.1f} "
              f"{cpu['total'] / frames:11.2f} {ded[w]:9.3f} {unit:13.2f} {rss:14.0f}")
    for name, rate in (("wall clock", med), ("2 cores of its own", ded)):
        line = f"{name}: local 2 / local 1 = {rate['local 2'] / rate['local 1']:.2f}x (target >= 1.7)"
        if "ray 2" in rate:
            line += f"; ray 2 / local 2 = {rate['ray 2'] / rate['local 2']:.2f} (target >= 0.85)"
        for w in ("local 2", "ray 2"):
            if f"{w} x2t" in rate:
                line += f"; {w} sized / oversubscribed threads = {rate[w] / rate[w + ' x2t']:.2f}x"
        print(line)
    print(f"load average: {load0[0]:.2f} before, {load1[0]:.2f} after (2 cores)")

    # scaling-model inputs
    units = sorted(unit_costs(fpu1), key=lambda u: (u["log"], u["start"]))
    logs_seen: dict[str, list[dict]] = {}
    for u in units:
        logs_seen.setdefault(u["sha256"], []).append(u)
    rest = [u["cpu_seconds"] / max(u["frames"], 1) for us in logs_seen.values() for u in us[1:]]
    c_frame = statistics.median(rest)
    firsts = [us[0]["cpu_seconds"] - c_frame * us[0]["frames"] for us in logs_seen.values()]
    c_worker, c_open = max(firsts), statistics.median(sorted(firsts)[:-1] or firsts)  # the worker's very first unit
    imp = import_cost()
    rc = read_cost(logs)
    pc = planning_cost(logs, ply)
    rss = max(x["peak_rss_mb_per_worker"] for w in ways for x in per_way[w] if w.startswith("local"))
    print("\nscaling model inputs (this machine):")
    print(f"  CPU per frame, steady state: {c_frame:.2f} CPU-s (one worker, units of one frame, median of {len(rest)})")
    print(f"  opening a log in a worker (session, prepared bin model, first frame): {c_open:.2f} CPU-s per log "
          "and worker")
    print(f"  a worker's first unit, beyond that: {c_worker - c_open:.2f} CPU-s (bin model file, numba caches, "
          f"lazy imports); its start-up imports before it: {imp:.2f} CPU-s")
    print(f"  bytes read per frame: {rc['read_bytes_per_frame'] / 1e6:.1f} MB (rchar); on disk "
          f"{rc['disk_bytes_per_frame'] / 1e6:.1f} MB per frame (compressed chunks)")
    print(f"  driver planning per log ({args.frames} frames): {pc['cpu_s_per_log']:.2f} CPU-s "
          f"({pc['wall_s_per_log']:.2f} s wall), serial in the driver")
    h = hash_cost(logs) * rc["disk_bytes_per_frame"]
    print(f"  of which the content hash: {h:.3f} CPU-s per frame ({rc['disk_bytes_per_frame'] / h / 1e6:,.0f} MB/s)")
    print(f"  peak memory per local worker: {rss:.0f} MB")
    for name, cores in (("64-core machine", 64), ("10 nodes x 64 cores", 640)):
        fph = cores * 3600 / c_frame
        mbps = cores / c_frame * rc["disk_bytes_per_frame"] / 1e6
        print(f"  {name}: {fph:,.0f} frames/h at {c_frame:.2f} CPU-s/frame (if CPU-bound), reading "
              f"{mbps:,.0f} MB/s of logs, {cores * rss / 1024:,.0f} GB of worker memory; the driver's planning "
              f"content hashes (serial) alone take {fph * h / 3600:,.1f} h for an hour's frames")


if __name__ == "__main__":
    main()
