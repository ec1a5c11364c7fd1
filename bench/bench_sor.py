"""Benchmark: zcut.sor_outliers against Open3D's remove_statistical_outlier on a 1920 x 1200 cloud.

A pinhole camera (fx = fy = 1700 px) 0.5 m above a bin-like scene: bin floor, slanted walls and rim,
a pile of spheres, a table around; depth noise along the rays, flying pixels at depth edges and NaN
holes, all seeded. Prints the times and the ratio; the masks must be equal (asserted).

    .venv/bin/python bench/bench_sor.py [--repeat N] [--seed S]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def make_cloud(seed: int = 0, *, height: int = 1200, width: int = 1920) -> np.ndarray:
    """(H, W, 3) float32 organized cloud in metres, camera optical frame, NaN = invalid."""
    rng = np.random.default_rng(seed)
    fx = fy = 1700.0
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    dx, dy = (u - cx) / fx, (v - cy) / fy

    floor_z, rim_z, table_z = 0.50, 0.35, 0.505
    half_x, half_y, slope, rim_w = 0.22, 0.13, 0.25, 0.02

    def scene_depth(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        # distance outside the floor rectangle, walls rise with the slope up to the rim
        ex = np.maximum(np.abs(X) - half_x, 0.0)
        ey = np.maximum(np.abs(Y) - half_y, 0.0)
        e = np.maximum(ex, ey)
        wall_len = (floor_z - rim_z) * slope
        z = np.where(e <= 0, floor_z, floor_z - (floor_z - rim_z) * np.minimum(e / wall_len, 1.0))
        return np.where(e > wall_len + rim_w, table_z, z)

    z = np.full((height, width), floor_z)
    for _ in range(4):  # fixed point: the ray through each pixel meets the height field
        z = scene_depth(dx * z, dy * z)

    # a pile of spheres on the floor (ray-sphere intersection, nearest hit)
    for _ in range(260):
        r = rng.uniform(0.012, 0.035)
        C = np.array([rng.uniform(-half_x, half_x), rng.uniform(-half_y, half_y), floor_z - r - rng.uniform(0, 0.04)])
        uc, vc = C[0] / C[2] * fx + cx, C[1] / C[2] * fy + cy
        rad = r / (C[2] - r) * fx * 1.2 + 2
        r0, r1 = int(max(0, vc - rad)), int(min(height, vc + rad + 1))
        c0, c1 = int(max(0, uc - rad)), int(min(width, uc + rad + 1))
        if r0 >= r1 or c0 >= c1:
            continue
        ddx, ddy = dx[r0:r1, c0:c1], dy[r0:r1, c0:c1]
        dd = ddx * ddx + ddy * ddy + 1.0
        b = ddx * C[0] + ddy * C[1] + C[2]
        disc = b * b - dd * (C @ C - r * r)
        t = (b - np.sqrt(np.maximum(disc, 0.0))) / dd
        hit = (disc > 0) & (t < z[r0:r1, c0:c1])
        z[r0:r1, c0:c1][hit] = t[hit]

    # flying pixels at depth edges, then noise along the rays
    edge = np.zeros_like(z, dtype=bool)
    jump = np.abs(np.diff(z, axis=1)) > 0.004
    edge[:, 1:] |= jump
    edge[:, :-1] |= jump
    jump = np.abs(np.diff(z, axis=0)) > 0.004
    edge[1:, :] |= jump
    edge[:-1, :] |= jump
    fly = edge & (rng.random(z.shape) < 0.3)
    zr = np.roll(z, 3, axis=1)
    z = np.where(fly, z + rng.random(z.shape) * (zr - z), z)
    z = z * (1.0 + rng.normal(0.0, 2e-4, z.shape))

    # NaN holes: sparse dropouts, blobs, and most of the steep edge pixels
    invalid = rng.random(z.shape) < 0.01
    for _ in range(150):
        rc, cc = rng.integers(0, height), rng.integers(0, width)
        rr = rng.integers(3, 25)
        invalid[max(0, rc - rr):rc + rr, max(0, cc - rr):cc + rr] = True
    invalid |= edge & ~fly & (rng.random(z.shape) < 0.5)

    xyz = np.stack([dx * z, dy * z, z], axis=-1).astype(np.float32)
    xyz[invalid] = np.nan
    return xyz


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--std-ratio", type=float, default=1.0)
    args = parser.parse_args()

    import open3d as o3d

    from zcut.sor import sor_outliers

    xyz = make_cloud(args.seed)
    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    print(f"cloud {xyz.shape[1]} x {xyz.shape[0]}, {pts.shape[0]} valid points, k={args.k}, std_ratio={args.std_ratio}")

    sor_outliers(xyz[:64, :64], k=args.k, std_ratio=args.std_ratio, convention="open3d")  # JIT warm-up
    sor_outliers(xyz[:64, :64], k=args.k, std_ratio=args.std_ratio, convention="pcl")

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    t_o3d, t_ours, t_pcl = [], [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        _, kept = pcd.remove_statistical_outlier(nb_neighbors=args.k, std_ratio=args.std_ratio)
        t_o3d.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ours = sor_outliers(xyz, k=args.k, std_ratio=args.std_ratio, convention="open3d")
        t_ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        pcl = sor_outliers(xyz, k=args.k, std_ratio=args.std_ratio, convention="pcl")
        t_pcl.append(time.perf_counter() - t0)

    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    expected = np.zeros(valid.shape, dtype=bool)
    expected[valid] = ~keep
    assert np.array_equal(ours, expected), f"masks differ at {int((ours != expected).sum())} pixels"
    print(f"outliers: open3d convention {int(ours.sum())}, pcl convention {int(pcl.sum())} (masks equal to Open3D: yes)")
    a, b, c = min(t_o3d), min(t_ours), min(t_pcl)
    print(f"Open3D remove_statistical_outlier   {a * 1000:8.1f} ms (best of {args.repeat})")
    print(f"sor_outliers(convention='open3d')   {b * 1000:8.1f} ms  -> {a / b:5.1f}x faster")
    print(f"sor_outliers(convention='pcl')      {c * 1000:8.1f} ms  -> {a / c:5.1f}x vs Open3D")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
