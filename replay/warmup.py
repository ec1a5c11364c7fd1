"""Compile zcut's numba kernels ahead (``python -m replay.warmup``; ``scripts/install.sh`` runs it).

The kernels are compiled on first use and cached beside their modules; a first ``zcut demo`` would
otherwise wait minutes in silence (the whole set: 1.5-9 min measured; 1055 s on two cores shared by
five other jobs, load average 10). One line per kernel group says what is being compiled and how
long it took. This runs every kernel once on tiny inputs: the z-cut's kernels (flooding, union-find,
the grid), SOR in both conventions (its column search too), the filter bank, the suspect detectors
of the labelling page, a small synthetic log with its bin model through the whole pipeline (the
scene generator and the readers too) and the ray-traced sensor (``zcut synth --sensor raytraced``).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    import numpy as np

    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model
    from replay.pipeline.session import ReplaySession
    from replay.synth.log import write_synthetic_log
    from zcut import (
        Intrinsics,
        cluster_outliers,
        find_clusters,
        mixed_pixel_outliers,
        radius_outliers,
        sor_outliers,
        speckle_outliers,
        window_outliers,
        zcut_outliers,
        zcut_tree,
    )
    from zcut.params import SuspectParams, ZCutParams
    from zcut.suspects import suspects

    rng = np.random.default_rng(0)
    h = rng.normal(size=(40, 50)).cumsum(axis=0)
    xyz = np.dstack([*np.meshgrid(np.arange(50.0), np.arange(40.0)), 500 + h]).astype(np.float32)
    scattered = rng.normal(size=(40, 50, 3)).astype(np.float32)  # no camera: SOR's column search
    camera = Intrinsics(fx=300.0, fy=300.0, cx=25.0, cy=20.0, width=50, height=40)

    def zcut_kernels(d: Path) -> None:
        zcut_outliers(h, step=0.2, max_depth=3.0, max_area=20)
        for kernel in ("flood", "union-find"):
            find_clusters(h, params=ZCutParams(step=0.2, max_depth=3.0, max_area=20.0), kernel=kernel)
        tree = zcut_tree(h, step=0.2, max_depth=3.0)
        tree.counts([1.0, 3.0], [5.0, 20.0], truth=h > 1, scored=np.ones(h.shape, bool))

    def sor_kernels(d: Path) -> None:
        for convention in ("pcl", "open3d"):
            sor_outliers(xyz, k=4, convention=convention)
            sor_outliers(xyz.astype(np.float64) * [1, 1, -1], k=4, convention=convention)
            sor_outliers(scattered, k=4, convention=convention)

    def filter_bank(d: Path) -> None:
        for cloud in (xyz / 1000.0, scattered):  # float32 and float64
            for a in (cloud.astype(np.float32), cloud.astype(np.float64)):
                radius_outliers(a, 2.0, 8)
                cluster_outliers(a, max_neighbour_mm=3.0, min_area_mm2=50.0, intrinsics=camera)
                speckle_outliers(a, max_diff_mm=2.0, max_size_px=100)
                window_outliers(a, min_inliers=3, rel_tolerance=0.005)
                mixed_pixel_outliers(a, min_angle_deg=8.0)

    def suspect_detectors(d: Path) -> None:
        suspects(xyz / 1000.0, -np.asarray(xyz[..., 2], np.float64), np.ones(h.shape, bool), params=SuspectParams())

    def pipeline(d: Path) -> None:
        log, empty = d / "w.mcap", d / "e.mcap"
        write_synthetic_log(log, kind="rods", frames=1, seed=1, size=(60, 96))
        write_synthetic_log(empty, empty=True, frames=2, seed=1, size=(60, 96))
        model, _ = build_bin_model(LogReader(empty).frames())
        for bm in (model, None):
            ReplaySession.open(log, bin_model=bm).run()

    def raytraced(d: Path) -> None:
        from replay.synth.raytrace import write_raytraced_log

        write_raytraced_log(d / "r.mcap", kind="rods", frames=1, seed=1, size=(60, 96))

    groups = [
        ("the z-cut (flooding, union-find, the grid)", zcut_kernels),
        ("SOR (both conventions, the column search)", sor_kernels),
        ("the filter bank (radius, cluster, speckle, window, mixed pixel)", filter_bank),
        ("the suspect detectors of the labelling page", suspect_detectors),
        ("the synthetic scenes, the readers and the whole pipeline", pipeline),
        ("the ray-traced sensor", raytraced),
    ]
    t0 = time.perf_counter()
    print(f"zcut: compiling the numba kernels in {len(groups)} groups (once; cached beside the modules; "
          "1.5-9 min measured, 18 min on 2 busy cores)", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (what, compile_group) in enumerate(groups, 1):
            t = time.perf_counter()
            print(f"zcut: [{i}/{len(groups)}] {what}…", end="", file=sys.stderr, flush=True)
            compile_group(Path(tmp))
            print(f" {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    print(f"zcut: kernels compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    from replay.process import configure_process

    configure_process()
    sys.exit(main())
