"""The bin mask's numba kernels load from their cache in a fresh process (as tests/zcut/test_kernel_cache.py
checks the z-cut's): a kernel whose cache always missed would be compiled anew by every ``zcut`` process."""

from __future__ import annotations

from kernel_cache_helpers import missed, second_process_stats

SCRIPT = r"""
import numpy as np
from zcut.binmask import bin_mask, bin_pixels

rng = np.random.default_rng(5)
rgb = np.full((120, 160, 3), 30, np.uint8)
rgb[20:100, 30:130] = 230           # the bin's plastic
rgb[35:85, 45:115] = 40             # its dark inside
rgb[50:60, 60:70] = 240             # a shiny part
xyz = rng.normal(0.0, 1.0, (120, 160, 3)).astype(np.float32)
xyz[::7] = np.nan
r = bin_mask(rgb)
assert r.found
bin_pixels(r, xyz)
bin_pixels(r, xyz.astype(np.float64), ring_frac=0.5)
"""


def test_the_bin_masks_kernels_load_from_the_cache_in_a_second_process():
    stats = second_process_stats(SCRIPT, prefix="zcut.binmask")
    assert {"zcut.binmask._pad_component", "zcut.binmask._ring_bounded", "zcut.binmask._assemble"} <= set(stats), \
        sorted(stats)
    assert missed(stats) == {}, f"compiled again in a second process (cache hits, misses): {missed(stats)}"
