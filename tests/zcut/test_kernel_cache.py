"""The z-cut's numba kernels load from their cache in a fresh process: a kernel whose cache always
misses is compiled anew by every ``zcut`` process (~2 CPU-s for the flood), which no timing test sees.
Seen in round 2026-12-06b: the flood's variants captured the bit map's dispatchers in their closure,
and numba keys a closure's cache entry by the closure's pickled bytes, which differ in every process."""

from __future__ import annotations

from kernel_cache_helpers import missed, second_process_stats

SCRIPT = r"""
import numpy as np
from zcut.cuts import find_clusters, zcut_outliers
from zcut.params import ZCutParams

rng = np.random.default_rng(5)
h = rng.normal(0.0, 5.0, (60, 80)).cumsum(0)
find_clusters(h, params=ZCutParams(step=1.0, max_depth=20.0, max_area=400))          # few levels
find_clusters(h, params=ZCutParams(step=0.01, max_depth=60.0, max_area=400))          # past SHALLOW_LEVELS: the deep flood
zcut_outliers(h, step=1.0, max_depth=20.0, max_area=400)                             # the pruned path
h[10:30, 20:50] = np.nan
find_clusters(h, params=ZCutParams(step=1.0, max_depth=20.0, max_area=400))          # with invalid pixels
"""


SOR_SCRIPT = r"""
import numpy as np
from zcut.sor import sor_outliers

rng = np.random.default_rng(5)
u, v = np.meshgrid(np.arange(120.0), np.arange(90.0))
z = 0.5 + 0.02 * np.sin(u / 7.0) + rng.normal(0.0, 1e-4, u.shape)
xn, yn = (u - 60.0) / 60.0, (v - 45.0) / 60.0
xyz = np.stack([xn * z, yn * z, z], axis=-1)
sor_outliers(xyz, k=4)                                           # a pinhole cloud
bend = 1.0 + 0.1 * (xn * xn + yn * yn)
sor_outliers(np.stack([xn * bend * z, yn * bend * z, z], axis=-1), k=4, convention="open3d")  # through a lens
"""


def test_the_cuts_kernels_load_from_the_cache_in_a_second_process():
    stats = second_process_stats(SCRIPT)
    flood = {k: v for k, v in stats.items() if "flood_core" in k}
    assert set(flood) >= {"zcut.cut_tree.flood_core", "zcut.cut_tree.flood_core_deep"}, sorted(stats)
    assert missed(stats) == {}, f"compiled again in a second process (cache hits, misses): {missed(stats)}"
    assert all(v[0] for v in flood.values()), flood


def test_the_sor_kernels_load_from_the_cache_in_a_second_process():
    # the division model's kernels (zcut.sor_camera, a distorted cloud) as well as the others
    stats = second_process_stats(SOR_SCRIPT)
    assert {"zcut.sor_camera._division_terms", "zcut.sor_camera._division_check", "zcut.sor_window.window_rows"} <= set(stats)
    assert missed(stats) == {}, f"compiled again in a second process (cache hits, misses): {missed(stats)}"
