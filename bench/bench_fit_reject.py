"""Benchmark: what a rejected fit costs the labelling server (issue 29 item 5; docs/labelling.md, "Judging fits").

Run: ``.venv/bin/python bench/bench_fit_reject.py LOG [LOG ...] [--fits N] [--repeat R]``

On the first frame of each log (``zcut synth -o LOG --parts zinc_nuts --frames 1 --seed 6407 --size
1920x1200``, seeds used nowhere else), prepared and fitted as ``zcut annotate`` does it (the pipeline's zone,
:func:`annotate.fits.fit_frame`), CPU milliseconds (``time.process_time``, every thread of the process:
Open3D's searches run in several) of:

- ``known surfaces``: what :func:`annotate.fits.fit_frame` now adds to a frame's background fits (the
  surfaces a rejection is judged against: :func:`annotate.fits.known_surfaces`);
- per rejection of one fit (``N`` fits, evenly spread over their sizes), the server's answer to the page's
  ``PUT /api/frames/{i}/fits/{fit}``: ``bundle, not judged`` (the bundle as before: every pixel of the
  rejected fit proposed, no distance), ``bundle, judged again`` (now: :meth:`FrameFits.remeasure` then the
  bundle), and the search alone, ``remeasure`` (the fits within 30 mm first) against ``remeasure, all fits``
  (:data:`annotate.fits.REACH_MM` = inf: every fit left searched at once; the same pixels, the distances
  within 1e-6 relative: Open3D's closest point found in another tree), alternately, ``R`` times each,
  medians; and how many of the fit's pixels came back as proposals;
- one seed (:meth:`FrameFits.seeded`, the largest fit taken out and clicked at its centre): what a restarted
  server spends per stored seed when the page asks for the frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

import annotate.fits as af
from annotate.fits import Job, fit_frame, known_surfaces
from replay.options import PipelineOptions
from replay.pipeline.explained import run_explained
from replay.pipeline.stages import bin_zone
from zcut import explained as ex


def _cpu_ms(fn, *args, **kw):
    t = time.process_time()
    out = fn(*args, **kw)
    return 1000.0 * (time.process_time() - t), out


def bench_log(path: str, *, n_fits: int, repeat: int) -> None:
    session = PipelineOptions(methods="zcut,explained").open_session(path)
    frame, result = next(iter(session.results()))
    job = Job.of(result)
    ms, ff = _cpu_ms(lambda: fit_frame(frame, job, session.config, session.prepared.model))
    H, W = ff.shape
    print(f"{path}: {W}x{H}, {len(ff.fits)} fits, {ff.un_pix.size} unexplained px; fit_frame {ms:.0f} CPU ms")
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    _, detail, _ = run_explained(frame, zone, session.config, judge_above_rim=True)
    times = [_cpu_ms(known_surfaces, frame, job, detail, session.prepared.model)[0] for _ in range(repeat)]
    print(f"  known surfaces (added to the background fits): {statistics.median(times):.0f} CPU ms")
    xyz = frame.xyz.astype(np.float64) * 1000.0
    valid = job.valid
    heights = np.where(valid, -xyz[..., 2], np.nan)
    areas = np.bincount(ff.fit_of, minlength=len(ff.fits))
    order = np.argsort(areas)
    picks = sorted({int(order[int(q)]) for q in np.linspace(0, len(order) - 1, n_fits)}, key=lambda f: areas[f])
    print("  fit   px  proposed | bundle, not judged | bundle, judged again | remeasure | remeasure, all fits (ms)")
    rows = []
    for f in picks:
        t_old, t_new, t_re, t_all = [], [], [], []
        for _ in range(repeat):
            t_old.append(_cpu_ms(ff.bundle, heights_mm=heights, valid=valid, rejected={f}, header={})[0])
            t_new.append(_cpu_ms(ff.bundle, heights_mm=heights, valid=valid, rejected={f}, header={}, xyz_mm=xyz)[0])
            ms, got = _cpu_ms(ff.remeasure, {f}, xyz)
            t_re.append(ms)
            reach, af.REACH_MM = af.REACH_MM, float("inf")
            try:
                ms, full = _cpu_ms(ff.remeasure, {f}, xyz)
            finally:
                af.REACH_MM = reach
            t_all.append(ms)
            # the same pixels; the distances within a float32 ulp (Open3D's closest point on another tree)
            assert np.array_equal(got.pix, full.pix) and np.allclose(got.dist, full.dist, rtol=1e-6, atol=0)
        row = [statistics.median(t) for t in (t_old, t_new, t_re, t_all)]
        rows.append(row)
        print(f"  {f:4d} {areas[f]:5d} {got.pix.size:6d}   | {row[0]:8.0f} | {row[1]:8.0f} | {row[2]:8.0f} | {row[3]:8.0f}")
    a = np.asarray(rows)
    print(f"  median over the fits: not judged {np.median(a[:, 0]):.0f}, judged again {np.median(a[:, 1]):.0f} "
          f"(range {a[:, 1].min():.0f}-{a[:, 1].max():.0f}), remeasure {np.median(a[:, 2]):.0f}, "
          f"all fits {np.median(a[:, 3]):.0f} CPU ms")
    # one seed: the largest fit taken out, a click at its centre
    j = int(np.argmax(areas))
    mine = ff.fit_of == j
    gone = ff.fit_pix[mine]
    un = np.concatenate([ff.un_pix, gone])
    o = np.argsort(un)
    keep = [i for i in range(len(ff.fits)) if i != j]
    missed = dataclasses.replace(
        ff, fits=ff.fits[:j] + ff.fits[j + 1:], fit_pix=ff.fit_pix[~mine],
        fit_of=np.where(ff.fit_of[~mine] > j, ff.fit_of[~mine] - 1, ff.fit_of[~mine]).astype(np.int32),
        un_pix=un[o], un_dist=np.concatenate([ff.un_dist, np.full(gone.size, 5.0, np.float32)])[o],
        un_err=np.concatenate([ff.un_err, np.full(gone.size, 0.5, np.float32)])[o],
        un_code=np.concatenate([ff.un_code, np.full(gone.size, ex.SURFACE_BIN, np.int32)])[o],
        part_err_mm=tuple(ff.part_err_mm[i] for i in keep))
    y, x = np.divmod(gone, W)
    c = int(np.argmin((x - np.median(x)) ** 2 + (y - np.median(y)) ** 2))
    times = []
    for _ in range(repeat):
        ms, seeded = _cpu_ms(missed.seeded, int(x[c]), int(y[c]), xyz, session.config)
        times.append(ms)
    print(f"  one seed ({len(seeded.fits) - len(missed.fits)} found, {gone.size} px taken out): "
          f"{statistics.median(times):.0f} CPU ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--fits", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    for log in a.logs:
        bench_log(log, n_fits=a.fits, repeat=a.repeat)


if __name__ == "__main__":
    main()
