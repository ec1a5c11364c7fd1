"""What the hand-made parts' geometry costs with the C library's trigonometry, against an older tree in the same run.

    .venv/bin/python bench/bench_part_meshes.py --against /tmp/old [--kinds zinc_nuts,sprockets] [--parts 300] \\
        [--reps 5] [--frame-size 1920x1200] [--seed 7]

Each rep runs, once with this tree's code and once with the tree at ``--against`` (a ``git archive`` of the
start), each in its own process (``PYTHONPATH`` at the tree), alternating which goes first: per kind,
``part_solid`` of ``--parts`` parts drawn from ``--seed`` (a frame's pile), ``solid_meshes`` of them (the
paper's truth's meshes of the hand-made frames) and ``kind_model_mesh`` (a log's ``part_model.ply``), CPU
seconds (``time.process_time``); with ``--frame-size``, also one whole hand-made frame
(``synthesize_frame``, the first kind, seed ``--seed``) as the scale those steps are a share of. Prints the
medians and their ratio new / old. docs/fits.md, "The part meshes built the same on every CPU".
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

_CHILD = """
import json, sys, time
import numpy as np
from replay.synth.parts import part_solid
from replay.synth.surfaces import kind_model_mesh, solid_meshes
kinds, n, seed, size = sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
solid_meshes([part_solid("zinc_nuts", np.random.default_rng(0)) for _ in range(2)])  # imports, warm caches
out = {}
for kind in kinds:
    rng = np.random.default_rng(seed)
    t0 = time.process_time()
    solids = [part_solid(kind, rng) for _ in range(n)]
    t1 = time.process_time()
    if kind != "spheres":
        solid_meshes(solids)
    t2 = time.process_time()
    for _ in range(10):
        kind_model_mesh(kind)
    t3 = time.process_time()
    out[f"{kind} part_solid"] = t1 - t0
    out[f"{kind} solid_meshes"] = t2 - t1
    out[f"{kind} kind_model_mesh x10"] = t3 - t2
if size:
    from replay.synth import synthesize_frame
    w, h = (int(v) for v in size.lower().split("x"))
    synthesize_frame(kind=kinds[0], seed=seed, size=(40, 64))  # numba's cache
    t0 = time.process_time()
    synthesize_frame(kind=kinds[0], seed=seed, size=(h, w))
    out[f"{kinds[0]} frame {size}"] = time.process_time() - t0
print(json.dumps(out))
"""


def _run(tree: Path, args: argparse.Namespace) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    p = subprocess.run([sys.executable, "-c", _CHILD, args.kinds, str(args.parts), str(args.seed), args.frame_size],
                       cwd=tree, env=env, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: {p.stderr.strip().splitlines()[-1]}")
    res: dict[str, float] = json.loads(p.stdout.strip().splitlines()[-1])
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--against", type=Path, required=True, help="the older tree (a git archive)")
    ap.add_argument("--kinds", default="zinc_nuts,rods,black_screws,sprockets")
    ap.add_argument("--parts", type=int, default=300, help="parts per kind (a frame's pile)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--frame-size", default="", help="WxH: also time one whole hand-made frame of the first kind")
    args = ap.parse_args()
    here = Path(__file__).resolve().parents[1]
    trees = {"old": args.against.resolve(), "new": here}
    cpu: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
    for rep in range(args.reps):
        for name in (["old", "new"] if rep % 2 == 0 else ["new", "old"]):
            res = _run(trees[name], args)
            cpu[name].append(res)
            print(f"rep {rep} {name}: " + " ".join(f"{k} {v:.4f}" for k, v in res.items())
                  + f"  load {os.getloadavg()[0]:.1f}", flush=True)
    for key in cpu["old"][0]:
        o = statistics.median(r[key] for r in cpu["old"])
        n = statistics.median(r[key] for r in cpu["new"])
        print(f"median {key:>34s}: old {o:8.4f} s  new {n:8.4f} s  new/old {n / o:.3f}" if o else
              f"median {key:>34s}: old {o:8.4f} s  new {n:8.4f} s")


if __name__ == "__main__":
    main()
