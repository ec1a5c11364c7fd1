"""Benchmark: a 10 x 10 (d_max, ρ_thr) sweep at one Δd from one component tree vs per-point calls.

Run: ``.venv/bin/python bench/bench_sweep_grid.py [--repeat N] [--kinds spheres,rods]``

For each frame the grid is d_max ∈ linspace(10, 50, 10) mm × μ_thr = ρ_thr · a_max with
ρ_thr ∈ linspace(0.02, 0.2, 10), at Δd = 0.2 mm, scored against a truth mask over the valid
pixels (docs/accuracy.md pixel counts; predicted = (z-cut ∩ within) ∪ plus, as in the pipeline). Three
costs, in CPU time (``process_time``; the machine is shared):

- ``one call``: one ``zcut_outliers`` at the largest d_max (50 mm; median of ``--repeat``) and the
  mean of the 100 per-point calls;
- ``grid``: ``zcut_tree`` (one tree for d_max = 50 mm) + ``tree.counts`` of all 100 points,
  scoring included (median of ``--repeat``);
- ``per-point``: 100 ``zcut_outliers`` calls, each scored from its mask with numpy.

Targets (issue 13 item 3): grid / one call ≤ 5, per-point / grid ≥ 20. The script also checks
that ``tree.outliers`` equals every per-point mask and the counts equal the per-point counts,
and exits 1 otherwise.

Frames, 1920 x 1200 unless said:
- ``pile``: the synthetic bin of ``bench_zcut.py`` (parts piled ~100 mm deep, floating clusters,
  NaN shadows; walls and table NaN), a_max = 3000 px, truth = the z-cut at the paper's nominal
  parameters (no ground truth: the scoring costs the same);
- ``dense``: the worst case of ``bench_zcut.py``, every pixel within 25 mm of the top (so inside
  every cut), same a_max and truth;
- ``synth:<kind>``: ``replay.synth.synthesize_frame(kind=...)``, height = -1000·z on the pixels
  whose real surface is the bin floor or a part, as the pipeline's removal leaves them (table,
  walls, rim and the above-the-rim points NaN); a_max = the kind's ``a_max_px``, truth = the exact
  ground truth, scored over the zone (those pixels plus the above-the-rim points, which are the
  ``plus`` of the predicted mask);
- ``real:<file>``: the real PCDs of the real data folder (docs/real_data.md; $ZCUT_REAL_DATA) at their own size (480 x 640),
  a_max = 1 % of the image, truth = the z-cut at nominal parameters.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_zcut import dense_frame, pile_frame
from timing import cpu

from replay.presets import PART_KINDS
from zcut.cut_grid import zcut_tree
from zcut.cuts import zcut_outliers
from zcut.params import NOMINAL_MAX_DEPTH_MM, NOMINAL_RHO_THR, NOMINAL_STEP_MM

REAL_DIR = Path(os.environ.get("ZCUT_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
STEP = 0.2
MAX_DEPTHS = np.linspace(10.0, 50.0, 10)
RHOS = np.linspace(0.02, 0.2, 10)
SIZE = (1200, 1920)


def frames(kinds: list[str]):
    """(name, height mm, a_max px, truth, plus) of every frame class (truth None: the z-cut at
    nominal parameters; plus None: nothing)."""
    yield "pile", pile_frame(), 3000.0, None, None
    yield "dense", dense_frame(), 3000.0, None, None
    from replay.synth import synthesize_frame
    from replay.synth.outliers import OUTLIER_ABOVE_RIM
    from replay.synth.scene import LABEL_FLOOR, LABEL_PART

    for kind in kinds:
        sf = synthesize_frame(kind=kind, size=SIZE)
        z = -1000.0 * sf.frame.xyz[..., 2].astype(np.float64)
        above_rim = sf.outlier_kind == OUTLIER_ABOVE_RIM
        zone = np.isin(sf.surface, (LABEL_FLOOR, LABEL_PART)) & ~above_rim
        yield f"synth:{kind}", np.where(zone, z, np.nan), sf.a_max_px, sf.truth, above_rim & np.isfinite(z)
    from replay.logs.pcd import read_pcd

    for path in sorted(REAL_DIR.glob("*.pcd")):
        z = -1000.0 * read_pcd(path).xyz[..., 2].astype(np.float64)
        yield f"real:{path.stem[:18]}", z, 0.01 * z.size, None, None


def score(mask, truth, scored, within, plus):
    """docs/accuracy.md counts of one predicted mask, the way a per-point sweep would."""
    p = (mask & within) | plus
    ps = p & scored
    return (int(np.count_nonzero(ps & truth)), int(np.count_nonzero(ps & ~truth)),
            int(np.count_nonzero(truth & scored & ~p)), int(np.count_nonzero(p)))


def bench_frame(z: np.ndarray, a_max: float, truth: np.ndarray | None, plus: np.ndarray | None,
                repeat: int) -> dict:
    """CPU times (s) of one call, the grid and the per-point sweep on one frame, and whether the
    grid's masks and counts equal the per-point ones."""
    valid = np.isfinite(z)
    areas = RHOS * a_max
    if truth is None:
        truth = zcut_outliers(z, step=NOMINAL_STEP_MM, max_depth=NOMINAL_MAX_DEPTH_MM,
                              max_area=NOMINAL_RHO_THR * a_max)
    within = valid
    plus = np.zeros(z.shape, bool) if plus is None else plus
    scored = valid | plus
    d_top = float(MAX_DEPTHS[-1])
    c_one, _ = cpu(lambda: zcut_outliers(z, step=STEP, max_depth=d_top, max_area=float(areas[4])), repeat)

    def grid():
        tree = zcut_tree(z, step=STEP, max_depth=d_top)
        return tree, tree.counts(MAX_DEPTHS, areas, truth=truth, scored=scored, within=within, plus=plus)

    c_grid, (tree, counts) = cpu(grid, repeat)
    masks = {}
    brute = np.zeros((4, MAX_DEPTHS.size, areas.size), np.int64)
    c0 = time.process_time()
    for i, d in enumerate(MAX_DEPTHS):
        for j, a in enumerate(areas):
            m = zcut_outliers(z, step=STEP, max_depth=float(d), max_area=float(a))
            brute[:, i, j] = score(m, truth, scored, within, plus)
            masks[i, j] = m
    c_brute = time.process_time() - c0
    same = all(np.array_equal(tree.outliers(float(MAX_DEPTHS[i]), float(areas[j])), m)
               for (i, j), m in masks.items())
    same &= all(np.array_equal(counts[k], brute[n]) for n, k in enumerate(("tp", "fp", "fn", "n_pred")))
    in_range = np.count_nonzero(valid & (z >= np.nanmax(z) - d_top - STEP)) / max(z.size, 1)
    return {"one": c_one, "grid": c_grid, "brute": c_brute, "point": c_brute / len(masks),
            "same": bool(same), "in_range": in_range}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--kinds", default=",".join(PART_KINDS),
                    help="synthetic part kinds (comma-separated)")
    args = ap.parse_args()
    zcut_outliers(np.zeros((3, 3)), step=0.2, max_depth=1.0, max_area=5)  # numba: cache or compile
    t = zcut_tree(np.zeros((3, 3)), step=0.2, max_depth=1.0)
    t.outliers(1.0, 5)
    t.counts([1.0], [5], truth=np.zeros((3, 3), bool), scored=np.ones((3, 3), bool))

    print(f"grid: d_max {MAX_DEPTHS[0]:g}..{MAX_DEPTHS[-1]:g} mm x rho_thr {RHOS[0]:g}..{RHOS[-1]:g}"
          f" (10 x 10), step {STEP} mm; CPU times, medians of {args.repeat}")
    head = (f"{'frame':24s} {'size':>9s} {'in range':>8s} {'one call':>9s} {'mean call':>9s} "
            f"{'grid':>8s} {'per-point':>9s} {'grid/one':>8s} {'grid/mean':>9s} {'speed-up':>8s} "
            f"identical")
    print(head)
    print("-" * len(head))
    ok = True
    worst_one, worst_speedup = 0.0, np.inf
    for name, z, a_max, truth, plus in frames([k for k in args.kinds.split(",") if k]):
        row = bench_frame(z, a_max, truth, plus, args.repeat)
        ok &= row["same"]
        worst_one = max(worst_one, row["grid"] / row["one"])
        worst_speedup = min(worst_speedup, row["brute"] / row["grid"])
        print(f"{name:24s} {z.shape[1]:4d}x{z.shape[0]:<4d} {row['in_range']:8.1%} "
              f"{row['one'] * 1e3:6.1f} ms {row['point'] * 1e3:6.1f} ms {row['grid'] * 1e3:5.1f} ms "
              f"{row['brute'] * 1e3:6.0f} ms {row['grid'] / row['one']:7.2f}x "
              f"{row['grid'] / row['point']:8.2f}x {row['brute'] / row['grid']:7.1f}x  {row['same']}")
    print(f"worst: grid = {worst_one:.2f} x one call (target <= 5), per-point / grid = "
          f"{worst_speedup:.1f}x (target >= 20)")
    print("'one call' = zcut_outliers at d_max 50 mm; 'mean call' = the mean per-point call with its "
          "scoring; 'grid' = zcut_tree + counts of all 100 points")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
