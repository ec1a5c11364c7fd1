"""Benchmark: two z-cuts of one zone that differ only in ρ_thr (max_area), as ``zcut compare`` runs A = the
paper's ρ 0.07 and B = ρ 0.035: ``find_clusters`` called twice against one tree answering both
(``zcut.cuts.find_clusters_many``), on the pipeline's own height images (the zone after the bin stages).

Run: ``.venv/bin/python bench/bench_cuts_many.py [--size 1920x1200] [--kind zinc_nuts] [--seed 7501]
[--frames 3] [--repeats 5] [--rho-b 0.035]``

Synthesises a log (``zcut synth``, cached under ``/tmp/bench_cuts_many``), replays it once to get each frame's
zone height (``FrameResult.height_mm``) and the log's resolved z-cut parameters (A), then times, alternating
the ways ``--repeats`` times over every frame, CPU time (``time.process_time``): A's ``find_clusters`` alone
(one replay's z-cut), A's and B's ``find_clusters`` (two trees), and ``find_clusters_many`` of both (one tree).
Checks the answers equal. Prints CPU-ms a frame (medians) and the ratios, with the load average.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--seed", type=int, default=7501)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rho-b", type=float, default=0.035)
    args = ap.parse_args()
    from replay.pipeline.session import ReplaySession
    from zcut.cuts import find_clusters, find_clusters_many

    d = Path("/tmp/bench_cuts_many")
    d.mkdir(exist_ok=True)
    log = d / f"{args.kind}_{args.size}_{args.seed}_{args.frames}.mcap"
    if not log.is_file():
        subprocess.run([sys.executable, "-m", "cli", "synth", "-o", str(log), "--parts", args.kind, "--frames",
                        str(args.frames), "--seed", str(args.seed), "--size", args.size],
                       env={**os.environ, "PYTHONPATH": str(HERE)}, check=True, capture_output=True)
    session = ReplaySession.open(log, overrides={"methods": ["zcut"]})
    heights = [r.height_mm for _, r in session.results()]
    a = session.resolved.config.zcut
    assert a.a_max is not None
    b = dataclasses.replace(a, max_area=args.rho_b * a.a_max)
    for z in heights:  # warm, and the answers are find_clusters'
        got = find_clusters_many(z, params=(a, b))
        for r, p in zip(got, (a, b), strict=True):
            want = find_clusters(z, params=p)
            assert all(np.array_equal(getattr(r, f), getattr(want, f)) for f in ("clusters", "levels", "areas",
                                                                                  "level_counts", "pixel_level"))

    ways = {
        "A alone (one replay's z-cut)": lambda z: find_clusters(z, params=a),
        "A and B, two trees": lambda z: (find_clusters(z, params=a), find_clusters(z, params=b)),
        "A and B, one tree": lambda z: find_clusters_many(z, params=(a, b)),
    }
    cpu: dict[str, list[float]] = {k: [] for k in ways}
    load = []
    for _ in range(args.repeats):
        for name, fn in ways.items():
            for z in heights:
                gc.collect()
                c0 = time.process_time()
                fn(z)
                cpu[name].append(time.process_time() - c0)
            load.append(os.getloadavg()[0])
    print(f"{len(heights)} frames of {args.kind} {args.size} (seed {args.seed}), A max_area {a.max_area:.1f} px, "
          f"B {b.max_area:.1f} px, {args.repeats} runs each; load average {min(load):.1f}-{max(load):.1f} on "
          f"{os.cpu_count()} cores")
    alone = statistics.median(cpu["A alone (one replay's z-cut)"])
    for name, xs in cpu.items():
        m = statistics.median(xs)
        print(f"{name:30s} {m * 1e3:7.1f} CPU-ms a frame (median; {min(xs) * 1e3:.1f}-{max(xs) * 1e3:.1f}); "
              f"x{m / alone:.2f} of A alone")


if __name__ == "__main__":
    main()
