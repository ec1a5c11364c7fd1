"""Benchmark: the removal's frame tolerance alone (:func:`zcut.removal.frame_tolerance`), this tree against another.

Run: ``.venv/bin/python bench/bench_removal_tolerance.py LOG... --against OLD_TREE [--frames N] [--repeats R]``

The frame tolerance is the removal's fixed work per frame (its sample is capped at
:data:`zcut.removal.MAX_RESIDUAL_PX` ring pixels): what keeps a 640 x 480 frame's cost per Mpx above the
1920 x 1200 frame's (issue 32 item 4). Each log's frames after the first (a warm-up) are located as the replay
locates them (not timed); then on each frame, ``R`` times, this tree's ``frame_tolerance`` and OLD_TREE's (its
``zcut`` imported as ``zcut_prev``, as ``bench/bench_removal.py --against`` imports it; the same prepared index)
run one after the other, the order swapped every repeat, with BLAS on one thread as the replay session has it.
Every field of the two tolerances (τ, its percentile, the counts, the reach, the off-field count, σ_bin and the
pixel angle) must be identical bit for bit. Prints CPU ms a call (``time.process_time``, all threads), medians,
and the ratio OLD / this. After it, OLD_TREE's numba cache names ``zcut_prev``: delete its ``*.nbi``/``*.nbc``
before importing it as ``zcut`` (``bench/bench_replay.py --against``).

``--pieces`` (no ``--against``): where this tree's fast tolerance spends its CPU, each piece of
``zcut.removal._frame_tolerance`` timed in its place, in the order the function runs them (the sample, the query's
gather, bin-frame product, grid, tree, residual parts, einsum and scatter, the neighbours' medians, the field fit,
the two percentiles, the reach's second query, σ_bin, the pixel angle), then the whole call; CPU ms a frame, medians
over the frames after the first × ``--repeats``, with the number of queried and sampled pixels. The process is set
up as ``zcut replay`` sets it (``replay.process.configure_process``: its malloc settings decide how many pages the
pieces fault in). docs/performance.md, "The 640 × 480 frame's fixed work, measured again" (h/px6).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

if "--pieces" in sys.argv:  # set up as `zcut replay` sets its process, before numba loads
    from replay.process import configure_process

    configure_process()
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")  # as `zcut` sets it

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_removal import located_frames, previous_removal  # noqa: E402

from zcut.removal import frame_tolerance  # noqa: E402

#: the :class:`zcut.removal.Tolerance` fields compared (all but the kept query, ``surface``)
FIELDS = ("tolerance_mm", "residual_mm", "n_pixels", "n_coherent", "reach_mm", "n_off_field", "sigma_mm",
          "pixel_rad")


def measure(log: Path, frames: int, repeats: int, prev: Any) -> tuple[float, float, int, tuple[int, ...]]:
    """Median CPU s of this tree's and the previous tree's ``frame_tolerance`` on the log's frames after the first,
    the number of calls each and the frames' (H, W)."""
    s, located = located_frames(log, frames + 1)
    assert s.prepared is not None
    index = s.prepared.removal
    times: dict[str, list[float]] = {"this": [], "prev": []}
    with threadpool_limits(limits=1, user_api="blas"):
        for rep in range(repeats):
            for xyz, _, ring, T in located[1:]:
                T = np.asarray(T, np.float64)
                order = (("prev", prev), ("this", frame_tolerance))
                out = {}
                for name, f in order if rep % 2 == 0 else order[::-1]:
                    t0 = time.process_time()
                    out[name] = f(xyz, ring, index, T)
                    times[name].append(time.process_time() - t0)
                for field in FIELDS:
                    a, b = getattr(out["this"], field), getattr(out["prev"], field)
                    if np.float64(a).tobytes() != np.float64(b).tobytes():
                        raise SystemExit(f"{log.name}: the tolerance's {field} differs from the previous tree's: {a} {b}")
    return (statistics.median(times["this"]), statistics.median(times["prev"]), len(times["this"]),
            located[0][0].shape[:2])


def _to_bin_frame(pts: np.ndarray, T: np.ndarray) -> np.ndarray:
    return pts @ T[:3, :3]  # zcut.removal._query's product (the gather took the translation off)


def _tree_rows(tree: Any, p_bin: np.ndarray, d: np.ndarray, j: np.ndarray, unsure: np.ndarray, ub: float) -> None:
    if unsure.any():  # zcut.removal._nearest_points' rows left to the tree
        d[unsure], j[unsure] = tree.query(p_bin[unsure], k=1, distance_upper_bound=ub)


def pieces(log: Path, frames: int, repeats: int) -> None:
    """Print the fast tolerance's pieces, each timed in its place (the module docstring's ``--pieces``)."""
    from zcut import removal as rm

    s, located = located_frames(log, frames + 1)
    assert s.prepared is not None
    index = s.prepared.removal
    p, g = index.params, index.nearest
    assert g is not None and index.tree is not None and index.model.normals is not None
    ub = p.max_tolerance_mm / 1000.0
    times: dict[str, list[float]] = {}
    counts: tuple[int, int] = (0, 0)

    def timed(name: str, f: Any, *a: Any) -> Any:
        t0 = time.process_time()
        out = f(*a)
        times.setdefault(name, []).append(time.process_time() - t0)
        return out

    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(repeats):
            for xyz, _, ring, T in located[1:]:
                T = np.asarray(T, np.float64)
                t0 = time.process_time()
                flat, want, own_at, nb_at, steps = timed("sample", rm._sample_and_steps,
                                                         xyz, np.ascontiguousarray(ring), rm.MAX_RESIDUAL_PX)
                pts, ok = timed("query: gather", rm._gather_finite, xyz, want, np.ascontiguousarray(T[:3, 3]))
                p_bin = timed("query: bin-frame product", _to_bin_frame, pts, T)
                d, j, unsure = timed("query: grid", rm._nearest_grid, np.ascontiguousarray(p_bin), g.origin, g.cell,
                                     g.dims, g.start, g.points, g.empty_to, g.order, ub)
                timed("query: tree (unsure rows)", _tree_rows, index.tree, p_bin, d, j, unsure, ub)
                diff, nrm = timed("query: residual parts", rm._residual_parts, p_bin, j, index.model.points,
                                  index.model.normals)
                e = timed("query: einsum", np.einsum, "ij,ij->i", diff, nrm)
                q = rm._Queried(want, *timed("query: scatter", rm._scatter_query, ok, p_bin, d, j, e, True),
                                pts if len(pts) == len(want) else None)
                res, nbr = timed("neighbours", rm._own_and_neighbours, q.residual_mm, own_at, nb_at)
                around = timed("neighbours' medians", rm._around_median, nbr)
                with np.errstate(invalid="ignore"):
                    coherent = np.isfinite(res) & (np.abs(res - around) <= rm.COHERENCE_MM)
                off = timed("field fit and off-field", rm._off_field_fast, q, own_at, nb_at, coherent,
                            index.model.normals)
                keep = coherent & ~off
                timed("percentile (tau)", rm._percentile_higher, res[keep], p.residual_quantile)
                near = timed("reach: second query", rm._nearest_again, xyz, flat[keep], own_at[keep], index, T, q)
                timed("percentile (reach)", rm._percentile_higher, near, p.residual_quantile)
                timed("sigma_bin", rm.bin_sigma_m, res[keep])
                timed("pixel angle (median)", rm._median_of, steps)
                times.setdefault("the pieces together", []).append(time.process_time() - t0)
                timed("frame_tolerance (whole)", frame_tolerance, xyz, ring, index, T)
                counts = (len(want), len(flat))
    h, w = located[0][0].shape[:2]
    print(f"{log.name}: {w}x{h}, {counts[0]} queried pixels, {counts[1]} sampled; CPU ms a frame (medians of "
          f"{len(times['sample'])}); load average {os.getloadavg()[0]:.1f}")
    for name, v in times.items():
        print(f"  {name:28s} {1000 * statistics.median(v):7.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path, nargs="+")
    ap.add_argument("--against", type=Path, help="source tree of the previous commit")
    ap.add_argument("--pieces", action="store_true", help="this tree's pieces in place instead (no --against)")
    ap.add_argument("--frames", type=int, default=5, help="frames measured after the first (default 5)")
    ap.add_argument("--repeats", type=int, default=8)
    args = ap.parse_args()
    if args.pieces:
        for log in args.log:
            pieces(log, args.frames, args.repeats)
        return
    if args.against is None:
        ap.error("--against is required (or --pieces)")
    previous_removal(args.against)  # imports OLD_TREE's zcut as zcut_prev
    from zcut_prev.removal import frame_tolerance as prev  # type: ignore[import-not-found]

    print(f"frame_tolerance, CPU ms a call (time.process_time, all threads), medians; prev = {args.against}")
    print(f"  {'log':28s} {'size':>10s} {'this':>8s} {'prev':>8s} {'prev/this':>10s} {'calls':>6s} {'load':>5s}")
    for log in args.log:
        this, old, n, (h, w) = measure(log, args.frames, args.repeats, prev)
        print(f"  {log.name:28s} {f'{w}x{h}':>10s} {1000 * this:8.2f} {1000 * old:8.2f} {old / this:10.2f} {n:6d} "
              f"{os.getloadavg()[0]:5.1f}", flush=True)
    print("every Tolerance field identical to the previous tree's on every call")


if __name__ == "__main__":
    main()
