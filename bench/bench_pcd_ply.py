"""PCD and PLY import: zcut's readers (library parsing + zcut's checks) against the libraries alone.

PCD: ``read_pcd`` (pypcd4 parses, zcut checks organisation and sizes first and builds xyz/rgb)
vs pypcd4 alone (structured array only) vs Open3D ``read_point_cloud`` (flat float64, no
HEIGHT/WIDTH). PLY at ``--size``: ``read_ply`` (plyfile header and dtypes, numba range_grid) vs
``plyfile.PlyData.read`` alone, for a binary grid without and with PCL's range_grid, and ascii.
CPU time (``time.process_time``), best of ``--repeat``; ratios against zcut's reader.
Usage: .venv/bin/python bench/bench_pcd_ply.py [--repeat R] [--size HxW]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# the repository before tests/, whose replay/ and annotate/ folders mirror the packages
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "replay" / "logs"), str(ROOT / "tests")]

from replay.logs.pcd import read_pcd  # noqa: E402
from replay.logs.ply import read_ply  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"


def best(fn, repeat: int) -> float:
    b = np.inf
    for _ in range(repeat):
        t = time.process_time()
        fn()
        b = min(b, time.process_time() - t)
    return b


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--size", default="600x960")
    args = ap.parse_args()
    import open3d as o3d
    from plyfile import PlyData
    from pypcd4 import PointCloud

    pcds = sorted(REAL.glob("*.pcd"))
    read_pcd(pcds[0])
    t = {"zcut read_pcd (pypcd4 + checks, xyz/rgb)": 0.0, "pypcd4 PointCloud.from_path (array only)": 0.0,
         "Open3D read_point_cloud (flat, float64)": 0.0}
    fns = list(t)
    for p in pcds:
        t[fns[0]] += best(lambda p=p: read_pcd(p), args.repeat)
        t[fns[1]] += best(lambda p=p: PointCloud.from_path(p).pc_data, args.repeat)
        t[fns[2]] += best(lambda p=p: o3d.io.read_point_cloud(str(p), remove_nan_points=False,
                                                                remove_infinite_points=False), args.repeat)
    print(f"PCD: {len(pcds)} real 480x640 binary_compressed files, CPU ms per file (best of {args.repeat})")
    ref = t[fns[0]]
    for k, v in t.items():
        print(f"  {k:48s} {v / len(pcds) * 1e3:7.1f} ms   ratio {v / ref:4.2f}x")

    from test_pcd_ply_import import write_ply

    h, w = (int(v) for v in args.size.split("x"))
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(h, w, 3)).astype(np.float32)
    xyz[rng.random((h, w)) < 0.1] = np.nan
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    print(f"\nPLY {h}x{w}, CPU ms (best of {args.repeat}; plyfile alone = arrays only, no grid)")
    with tempfile.TemporaryDirectory() as d:
        for fmt, grid in (("binary_little_endian", False), ("binary_little_endian", True), ("ascii", False)):
            p = Path(d) / f"c_{fmt}_{grid}.ply"
            write_ply(p, xyz, rgb, fmt=fmt, grid=grid)
            read_ply(p)
            reps = args.repeat if fmt != "ascii" else 1
            a = best(lambda p=p: read_ply(p), reps)
            b = best(lambda p=p: [np.asarray(e.data) for e in PlyData.read(str(p)).elements], reps)
            print(f"  {fmt:22s} range_grid={grid!s:5s}  zcut read_ply {a * 1e3:8.1f} ms   "
                  f"plyfile.PlyData.read {b * 1e3:8.1f} ms   ratio {b / a:5.1f}x")


if __name__ == "__main__":
    main()
