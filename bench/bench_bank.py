"""Benchmark: the filter bank against the z-cut's time per frame, and against the libraries that do
the same thing (Open3D's radius filter, OpenCV's filterSpeckles), per cloud class.

For every class (bench_sor.py's clouds: 1920 x 1200 synthetic frames, the real Kinect PCDs of
the real data folder (docs/real_data.md) at 640 x 480, and the steep-relief class of tall parts on end), in one run:

  zcut      zcut.zcut_outliers(height_mm(xyz)) with the paper's nominal parameters (0.2 mm, 30 mm,
            rho 0.07 of a_max = 3000 px): the time per frame every filter is held to
  <filter>  the filter's stage with its default parameters (zcut.params), and its ratio to the z-cut
            (<= 1.00: within the z-cut's time)
  zcut_top  zcut.cut_top.zcut_top_outliers on the same height image with the same parameters, its
            window anchored on the pile's top (top_area = 1 face = a_max, ZCutTopParams' default)
  Open3D    PointCloud.remove_radius_outlier(min_points, radius) on the valid points (float64), its
            ratio to the radius filter (how many times slower), and whether the masks are identical
  OpenCV    cv2.filterSpeckles on the int16 depth image in whole millimetres (0 = invalid); the
            speckle filter runs on the same cloud with its depths rounded to whole millimetres (so
            both see the same data), their ratio and whether the masks are identical

Times are CPU seconds of the whole process (time.process_time: every thread, so Open3D's OpenMP
threads count), best of --repeat (Open3D's radius filter once: it takes tens of seconds on the dense
frames). The cluster filter needs focal lengths: the synthetic frames' own (f = 1700 px at full
size), fitted to the PCDs by least squares (u = fx x / z + cx).

    .venv/bin/python bench/bench_bank.py [--repeat N] [--seed S] [--classes pile,steep,...]
                                         [--no-open3d] [--markdown]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_sor import (  # noqa: E402
    REAL_DATA,
    blobs_cloud,
    configure_process,
    cpu_best,
    pile_cloud,
    read_pcd,
    sparse_cloud,
    steep_cloud,
    walls_cloud,
)

A_MAX = 3000.0  # pixels of a part's largest face, for the z-cut's max_area
FILTERS = ("zcut_top", "radius", "cluster", "speckle", "window", "mixed_pixel")


def synth_frame(seed: int):
    """The project's synthetic scan (xyz, intrinsics), or why it could not be made."""
    try:
        from replay.synth import synthesize_frame

        frame = synthesize_frame(kind="spheres", seed=seed).frame
        return np.asarray(frame.xyz), frame.intrinsics
    except Exception as e:  # noqa: BLE001 - an optional class: any failure only skips it
        return f"{type(e).__name__}: {e}"


def fitted_intrinsics(xyz: np.ndarray):
    """Pinhole fx, fy, cx, cy fitted to an organized camera cloud (u = fx x / z + cx)."""
    from zcut import Intrinsics

    H, W = xyz.shape[:2]
    v, u = np.mgrid[0:H, 0:W]
    ok = np.isfinite(xyz).all(axis=2) & (xyz[..., 2] > 0)
    a = xyz[..., 0][ok] / xyz[..., 2][ok]
    b = xyz[..., 1][ok] / xyz[..., 2][ok]
    fx, cx = np.linalg.lstsq(np.stack([a, np.ones_like(a)], axis=1), u[ok].astype(float), rcond=None)[0]
    fy, cy = np.linalg.lstsq(np.stack([b, np.ones_like(b)], axis=1), v[ok].astype(float), rcond=None)[0]
    return Intrinsics(fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=W, height=H)


def camera(f: float, xyz: np.ndarray):
    from zcut import Intrinsics

    H, W = xyz.shape[:2]
    return Intrinsics(fx=f, fy=f, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)


def cloud_classes(seed: int) -> dict[str, object]:
    """Class name -> function returning (xyz, intrinsics) or a reason to skip."""
    f = 1700.0

    def with_camera(make):
        def build():
            xyz = make()
            return xyz, camera(f, xyz)
        return build

    classes: dict[str, object] = {
        "pile": with_camera(lambda: pile_cloud(seed)),
        "blobs20": with_camera(lambda: blobs_cloud(seed, invalid_frac=0.20)),
        "blobs50": with_camera(lambda: blobs_cloud(seed, invalid_frac=0.50)),
        "walls": with_camera(lambda: walls_cloud(seed)),
        "sparse": with_camera(lambda: sparse_cloud(seed)),
        "steep": with_camera(lambda: steep_cloud(seed)),
        "synth": lambda: synth_frame(seed),
    }
    for path in sorted(REAL_DATA.glob("*.pcd")):
        def real(path=path):
            xyz = read_pcd(path)
            return xyz, fitted_intrinsics(xyz)
        classes[f"kinect/{path.stem[:18]}"] = real
    return classes


def open3d_radius(xyz: np.ndarray, radius_mm: float, min_points: int) -> tuple[float, np.ndarray]:
    import open3d as o3d

    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    t, (_, kept) = cpu_best(lambda: cloud.remove_radius_outlier(nb_points=min_points, radius=radius_mm / 1000.0), 1)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = ~keep
    return t, out


def millimetre_cloud(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cloud with depths rounded to whole millimetres (x, y scaled along the rays) and the int16
    depth image OpenCV filters (0 = invalid); depths outside 1..32767 mm become invalid."""
    valid = np.isfinite(xyz).all(axis=2)
    z = xyz[..., 2].astype(np.float64)
    mm = np.where(valid, np.round(z * 1000.0), 0.0)
    # the few depths whose mm / 1000 does not give mm back exactly in float64 are dropped in both
    ok = valid & (mm >= 1) & (mm <= 32767) & (1000.0 * (mm / 1000.0) == mm)
    scale = np.where(ok, (mm / 1000.0) / np.where(ok, z, 1.0), np.nan)
    out = xyz.astype(np.float64) * scale[..., None]
    out[..., 2] = np.where(ok, mm / 1000.0, np.nan)
    return out.astype(xyz.dtype) if xyz.dtype == np.float64 else out, np.where(ok, mm, 0).astype(np.int16)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--classes", default="", help="comma-separated class names or prefixes (default: all)")
    parser.add_argument("--no-open3d", action="store_true", help="skip Open3D's radius filter (slow)")
    parser.add_argument("--markdown", action="store_true", help="print the table as markdown")
    args = parser.parse_args()

    configure_process()
    import cv2

    import zcut
    from zcut.cut_top import zcut_top_outliers
    from zcut.params import (
        ClusterParams,
        MixedPixelParams,
        RadiusParams,
        SpeckleParams,
        WindowParams,
        ZCutParams,
        ZCutTopParams,
    )

    zp = ZCutParams.nominal(a_max=A_MAX)
    rp, cp, sp, wp, mp = RadiusParams(), ClusterParams(), SpeckleParams(), WindowParams(), MixedPixelParams()
    tp = ZCutTopParams()
    stages = {
        "zcut_top": lambda xyz, K: zcut_top_outliers(zcut.height_mm(xyz), step=zp.step, max_depth=zp.max_depth,
                                                     max_area=zp.max_area, top_area=tp.top_faces * A_MAX),
        "radius": lambda xyz, K: zcut.radius_stage(xyz, params=rp),
        "cluster": lambda xyz, K: zcut.cluster_stage(xyz, params=cp, intrinsics=K),
        "speckle": lambda xyz, K: zcut.speckle_stage(xyz, params=sp),
        "window": lambda xyz, K: zcut.window_stage(xyz, params=wp),
        "mixed_pixel": lambda xyz, K: zcut.mixed_pixel_stage(xyz, params=mp),
    }

    def zcut_frame(xyz):
        return zcut.zcut_outliers(zcut.height_mm(xyz), step=zp.step, max_depth=zp.max_depth, max_area=zp.max_area)

    classes = cloud_classes(args.seed)
    wanted = [c for c in args.classes.split(",") if c]
    if wanted:
        classes = {name: f for name, f in classes.items() if any(name.startswith(w) for w in wanted)}

    warm = pile_cloud(0, height=60, width=90)  # JIT compile / cache load of every path
    zcut_frame(warm)
    for stage in stages.values():
        stage(warm, camera(60.0, warm))
    zcut.speckle_outliers(millimetre_cloud(warm)[0], max_diff_mm=sp.max_diff_mm, max_size_px=sp.max_size_px)

    print(f"defaults: radius {rp.radius_mm} mm / {rp.min_points} points; cluster {cp.max_neighbour_mm} mm / "
          f"{cp.min_area_mm2} mm²; speckle {sp.max_diff_mm} mm / {sp.max_size_px} px; window {wp.min_inliers} / "
          f"{wp.rel_tolerance}; mixed pixel {mp.min_angle_deg} deg; z-cut {zp.step} / {zp.max_depth} mm / "
          f"{zp.max_area:g} px")
    print(f"CPU ms of the process (all threads), best of {args.repeat}; ratio = filter / z-cut; "
          f"{os.cpu_count()} cores")
    cols = ["class", "H x W", "valid", "zcut ms"] + [f"{f} ms (×zcut)" for f in FILTERS] + [
        "Open3D radius ms (×ours, same)", "cv2 speckle ms (×ours, same)"]
    rows = []
    worst = {f: 0.0 for f in FILTERS}
    for name, make in classes.items():
        made = make()
        if isinstance(made, str):
            print(f"{name}: skipped ({made})", flush=True)
            continue
        xyz, K = made
        valid = np.isfinite(xyz).all(axis=2)
        t_zcut, _ = cpu_best(lambda xyz=xyz: zcut_frame(xyz), args.repeat)
        row = [name, f"{xyz.shape[0]}x{xyz.shape[1]}", f"{int(valid.sum())}", f"{1000 * t_zcut:.1f}"]
        masks = {}
        for f in FILTERS:
            t, masks[f] = cpu_best(lambda f=f, xyz=xyz, K=K: stages[f](xyz, K), args.repeat)
            row.append(f"{1000 * t:.1f} ({t / t_zcut:.2f})")
            worst[f] = max(worst[f], t / t_zcut)
            masks[f + "_t"] = t
        if args.no_open3d:
            row.append("-")
        else:
            t_o3d, want = open3d_radius(xyz, rp.radius_mm, rp.min_points)
            same = "yes" if np.array_equal(masks["radius"], want) else f"NO ({int((masks['radius'] != want).sum())} px)"
            row.append(f"{1000 * t_o3d:.0f} ({t_o3d / masks['radius_t']:.0f}x, {same})")
        xyz_mm, depth = millimetre_cloud(xyz)
        t_cv, _ = cpu_best(lambda depth=depth: cv2.filterSpeckles(depth.copy(), 0, sp.max_size_px, sp.max_diff_mm), args.repeat)
        img = depth.copy()
        cv2.filterSpeckles(img, 0, sp.max_size_px, sp.max_diff_mm)
        t_sp, got = cpu_best(lambda xyz_mm=xyz_mm: zcut.speckle_stage(xyz_mm, params=sp), args.repeat)
        same = "yes" if np.array_equal(got, (depth != 0) & (img == 0)) else "NO"
        row.append(f"{1000 * t_cv:.1f} ({t_cv / t_sp:.2f}x, {same})")
        rows.append(row)
        print(" | ".join(row), flush=True)
    print()
    if args.markdown:
        print("| " + " | ".join(cols) + " |")
        print("|" + "---|" * len(cols))
        for row in rows:
            print("| " + " | ".join(row) + " |")
    else:
        print("   ".join(cols))
        for row in rows:
            print("   ".join(row))
    print("largest ratio to the z-cut: " + ", ".join(f"{f} {worst[f]:.2f}" for f in FILTERS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
