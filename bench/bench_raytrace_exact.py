"""What the ray tracer's exact hits cost and how far they moved a frame, against an older tree in the same run.

    .venv/bin/python bench/bench_raytrace_exact.py --against /tmp/old [--size 1920x1200] [--kind zinc_nuts] \\
        [--seed 7741] [--reps 3]

Each rep makes frame 0 of ``--kind`` with ``--seed`` at ``--size`` once with this tree's code and once with
the tree at ``--against`` (a ``git archive`` of the start), each in its own process (``PYTHONPATH`` at the
tree), alternating which goes first. Prints per rep and tree the CPU seconds (``time.process_time``) of
the frame's steps (``RaytracedFrame.cpu_s``) and of the whole frame, then the medians and their ratio
new / old; then what moved between the two trees' frames: pixels whose point changed (bytes), pixels
measured by one tree only, the largest depth change (mm) over pixels both measured, and the pixels whose
truth mask, outlier kind, paper's truth or true depth changed.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

_CHILD = """
import json, sys, time
import numpy as np
from replay.synth.raytrace import synthesize_raytraced_frame
kind, seed, w, h, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
t0 = time.process_time()
rf = synthesize_raytraced_frame(kind=kind, seed=seed, size=(h, w))
total = time.process_time() - t0
np.savez(out, xyz=rf.frame.xyz, truth=rf.truth, kind=rf.outlier_kind, off=rf.off_surface, depth=rf.depth_true_m)
print(json.dumps({"total": total, **{k: float(v) for k, v in rf.cpu_s.items()}}))
"""


def _run(tree: Path, args: argparse.Namespace, out: Path) -> dict[str, float]:
    w, h = (int(x) for x in args.size.lower().split("x"))
    env = {**os.environ, "PYTHONPATH": str(tree)}
    p = subprocess.run([sys.executable, "-c", _CHILD, args.kind, str(args.seed), str(w), str(h), str(out)],
                       cwd=tree, env=env, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: {p.stderr.strip().splitlines()[-1]}")
    res: dict[str, float] = json.loads(p.stdout.strip().splitlines()[-1])
    return res


def _moved(old: Path, new: Path) -> dict[str, float]:
    a, b = np.load(old), np.load(new)
    xa, xb = a["xyz"], b["xyz"]
    va, vb = np.isfinite(xa).all(axis=-1), np.isfinite(xb).all(axis=-1)
    both = va & vb
    changed = (xa.view(np.uint32) != xb.view(np.uint32)).any(axis=-1)
    dz = np.abs(xa[..., 2][both].astype(np.float64) - xb[..., 2][both].astype(np.float64)) * 1000.0
    da, db = a["depth"], b["depth"]
    fin = np.isfinite(da) & np.isfinite(db)
    return {
        "pixels": float(va.size),
        "points changed": float(changed.sum()),
        "measured by one tree only": float((va != vb).sum()),
        "max |dz| mm (both measured)": float(dz.max()) if dz.size else 0.0,
        "median |dz| mm of changed": float(np.median(dz[dz > 0])) if (dz > 0).any() else 0.0,
        "truth changed": float((a["truth"] != b["truth"]).sum()),
        "kind changed": float((a["kind"] != b["kind"]).sum()),
        "off_surface changed": float((a["off"] != b["off"]).sum()),
        "true depth changed": float((da.view(np.uint32) != db.view(np.uint32)).sum()),
        "max |true depth change| mm": float(np.abs(da[fin].astype(np.float64) - db[fin]).max() * 1000.0)
        if fin.any() else 0.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--against", type=Path, required=True, help="the older tree (a git archive)")
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--seed", type=int, default=7741)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="keep the first rep's frames here (old.npz, new.npz)")
    args = ap.parse_args()
    here = Path(__file__).resolve().parents[1]
    trees = {"old": args.against.resolve(), "new": here}
    cpu: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as d:
        if args.keep is not None:
            args.keep.mkdir(parents=True, exist_ok=True)
        first = {k: (args.keep or Path(d)) / f"{k}.npz" for k in trees}
        for rep in range(args.reps):
            order = ["old", "new"] if rep % 2 == 0 else ["new", "old"]
            for name in order:
                res = _run(trees[name], args, first[name] if rep == 0 else Path(d) / "x.npz")
                cpu[name].append(res)
                steps = " ".join(f"{k} {v:.2f}" for k, v in res.items() if k != "total")
                print(f"rep {rep} {name}: total {res['total']:.2f} s CPU ({steps})  load {os.getloadavg()[0]:.1f}",
                      flush=True)
        for key in cpu["old"][0]:
            o = statistics.median(r[key] for r in cpu["old"])
            n = statistics.median(r.get(key, float("nan")) for r in cpu["new"])
            print(f"median {key:>10s}: old {o:7.2f} s  new {n:7.2f} s  new/old {n / o:.3f}" if o else
                  f"median {key:>10s}: old {o:7.2f} s  new {n:7.2f} s")
        for k, v in _moved(first["old"], first["new"]).items():
            print(f"{k}: {v:g}")


if __name__ == "__main__":
    main()
