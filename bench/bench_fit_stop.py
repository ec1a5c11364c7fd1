"""The labelling page's fits stopped part-way (``annotate.fits.Fitter.stop``): how long a stop waits.

    PYTHONPATH=. .venv/bin/python bench/bench_fit_stop.py LOG [--frame 0] [--stops 12] [--seed 0] [--against DIR]

On frame ``--frame`` of LOG, prepared as ``zcut annotate`` prepares it (the pipeline with ``explained``, the frame's
``annotate.fits.Job``):

1. **Stop points** (this tree only): the frame's fits (``annotate.fits.fit_frame``) once inside
   ``zcut.cancel.stop_when`` with a check that never says stop and notes the process's CPU time at each call: how
   many stop points the fit passes, the largest CPU gap between two of them or from the fit's start to the first,
   and the CPU after the last one (what a stop can wait at most, in CPU seconds of this process: the machine's load
   does not change it); and whether the fits equal those of ``fit_frame`` outside a scope (they must).
2. **Stops**: a ``Fitter`` given the frame and stopped after a delay drawn uniformly in [0, 0.9 × the fit's wall
   time] (``--seed``), ``--stops`` times: ``stop()``'s wall and CPU time (``time.process_time``: the fitting
   thread's work while ``stop`` waits for it), whether the stop ended a fit part-way, and whether the thread was
   still running when ``stop`` returned. With ``--against DIR`` (a ``git archive`` of another tree) the same delays
   in worker processes of both trees (``PYTHONPATH`` at each), in turns (new, old, old, new: half the delays each).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _prepared(log: str, index: int) -> tuple[Any, Any, Any]:
    """(session, frame, result) of frame ``index`` of ``log`` as ``zcut annotate`` prepares it."""
    from replay.options import PipelineOptions

    session = PipelineOptions(methods="zcut,explained").open_session(log)
    for frame, result in session.results():
        if frame.index == index:
            return session, frame, result
    raise SystemExit(f"{log} has no frame {index}")


def _digest(ff: Any) -> str:
    import hashlib

    h = hashlib.sha256(ff.message.encode())
    for a in (ff.fit_pix, ff.fit_of, ff.un_pix, ff.un_dist, ff.un_err):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(json.dumps(ff.fits).encode())
    return h.hexdigest()[:16]


def stop_points(log: str, index: int) -> dict[str, Any]:
    """Step 1: the fit's stop points and the CPU between them."""
    from annotate.fits import Job, fit_frame
    from zcut.cancel import stop_when

    session, frame, result = _prepared(log, index)
    job = Job.of(result)
    model = session.prepared.model if session.prepared is not None else None
    fit_frame(frame, job, session.config, model)  # the first call pays the kernels' loading
    t0, c0 = time.perf_counter(), time.process_time()
    plain = fit_frame(frame, job, session.config, model)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    marks: list[float] = []

    def note() -> bool:
        marks.append(time.process_time())
        return False

    c0 = time.process_time()
    with stop_when(note):
        scoped = fit_frame(frame, job, session.config, model)
    c1 = time.process_time()
    edges = np.diff(np.r_[c0, marks, c1]) if marks else np.array([c1 - c0])
    return {"fits": len(plain.fits), "status": plain.status, "wall_s": wall, "cpu_s": cpu,
            "stop_points": len(marks), "largest_gap_cpu_s": float(edges[:-1].max()) if marks else float("nan"),
            "after_last_cpu_s": float(edges[-1]), "before_first_cpu_s": float(edges[0]),
            "same": _digest(plain) == _digest(scoped), "digest": _digest(plain)}


def stops(log: str, index: int, delays: list[float]) -> list[dict[str, Any]]:
    """Step 2 in this process's tree: one Fitter per delay, stopped after it."""
    import annotate.fits as af

    session, frame, result = _prepared(log, index)
    model = session.prepared.model if session.prepared is not None else None
    k = float(session.config.bank["explained"].k)
    xyz = frame.xyz
    af.fit_frame(frame, af.Job.of(result), session.config, model)  # the kernels' loading, not in the first stop
    from zcut.errors import Cancelled

    inner, cancelled = af.fit_frame, []

    def noted(*a: Any, **kw: Any) -> Any:  # a fit the Fitter ran that a stop ended part-way (zcut.errors.Cancelled)
        try:
            return inner(*a, **kw)
        except Cancelled:
            cancelled.append(True)
            raise

    af.fit_frame = noted  # type: ignore[assignment]  # the Fitter looks it up at each fit
    out = []
    for delay in delays:
        cancelled.clear()
        fitter = af.Fitter(session.config, model, lambda i: xyz, model_name="m", model_points=[], k=k)
        fitter.submit(frame, result)
        fitter.start()
        time.sleep(delay)
        t0, c0 = time.perf_counter(), time.process_time()
        fitter.stop()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        thread = fitter._thread
        alive = thread is not None and thread.is_alive()
        if thread is not None:
            thread.join()  # a stop that did not wait for the end: the fit goes on, not into the next trial
        out.append({"delay_s": delay, "stop_wall_s": wall, "stop_cpu_s": cpu, "alive_after_stop": alive,
                    "fitted": frame.index in fitter.results,
                    "cancelled": bool(cancelled)})
    return out


def _worker(tree: Path, args: argparse.Namespace, delays: list[float]) -> list[dict[str, Any]]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), str(Path(args.log).resolve()), "--frame", str(args.frame),
           "--worker", json.dumps(delays)]
    got = subprocess.run(cmd, env=env, cwd=str(tree), check=True, capture_output=True, text=True)
    return [json.loads(line) for line in got.stdout.splitlines() if line.startswith("{")]


def _row(name: str, recs: list[dict[str, Any]]) -> str:
    wall = [r["stop_wall_s"] for r in recs]
    cpu = [r["stop_cpu_s"] for r in recs]
    return (f"{name:4s} {len(recs):5d} {sum(r['cancelled'] for r in recs):9d} {sum(r['fitted'] for r in recs):6d} "
            f"{sum(r['alive_after_stop'] for r in recs):6d} {statistics.median(wall):8.3f} {max(wall):8.3f} "
            f"{statistics.median(cpu):8.3f} {max(cpu):8.3f} {sum(cpu):8.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--stops", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--against", type=Path, default=None)
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        for rec in stops(args.log, args.frame, json.loads(args.worker)):
            print(json.dumps(rec), flush=True)
        return
    print(f"{args.log} frame {args.frame}; load {os.getloadavg()[0]:.1f}")
    pts = stop_points(args.log, args.frame)
    print(f"1. the fit: {pts['status']}, {pts['fits']} fits, {pts['cpu_s']:.2f} CPU-s ({pts['wall_s']:.2f} s wall); "
          f"{pts['stop_points']} stop points; CPU-s before the first {pts['before_first_cpu_s']:.3f}, largest gap "
          f"{pts['largest_gap_cpu_s']:.3f}, after the last {pts['after_last_cpu_s']:.3f}; the fits in a scope "
          f"{'identical' if pts['same'] else 'DIFFERENT'} ({pts['digest']})", flush=True)
    rng = np.random.default_rng(args.seed)
    delays = [float(d) for d in rng.uniform(0.0, 0.9 * pts["wall_s"], args.stops)]
    half = len(delays) // 2
    if args.against is None:
        runs = {"new": stops(args.log, args.frame, delays)}
    else:
        runs = {"new": [], "old": []}
        for name, part in (("new", delays[:half]), ("old", delays[:half]), ("old", delays[half:]),
                           ("new", delays[half:])):
            runs[name] += _worker(ROOT if name == "new" else args.against.resolve(), args, part)
    print(f"2. stops, delays uniform in [0, {0.9 * pts['wall_s']:.2f}] s (seed {args.seed}); load "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'tree':4s} {'stops':>5s} {'cancelled':>9s} {'fitted':>6s} {'alive':>6s} {'med wall':>8s} {'max wall':>8s} "
          f"{'med cpu':>8s} {'max cpu':>8s} {'sum cpu':>8s}")
    for name, recs in runs.items():
        print(_row(name, recs))


if __name__ == "__main__":
    main()
