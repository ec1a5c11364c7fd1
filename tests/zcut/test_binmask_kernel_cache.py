"""The bin mask's numba kernels load from their cache in a fresh process (as tests/zcut/test_kernel_cache.py
checks the z-cut's): a kernel whose cache always missed would be compiled anew by every ``zcut`` process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import json, sys
import numpy as np
from numba.core.dispatcher import Dispatcher
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
stats = {}
for name, mod in list(sys.modules.items()):
    if not name.startswith("zcut.binmask"):
        continue
    for attr, obj in list(vars(mod).items()):
        if isinstance(obj, Dispatcher) and obj.signatures and getattr(obj, "_cache", None) is not None:
            s = obj.stats
            stats[f"{name}.{attr}"] = [sum(s.cache_hits.values()), sum(s.cache_misses.values())]
print(json.dumps(stats))
"""


def _run() -> dict[str, list[int]]:
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_bin_masks_kernels_load_from_the_cache_in_a_second_process():
    _run()  # the first process may compile (a fresh checkout) and writes the caches
    stats = _run()
    assert {"zcut.binmask._pad_component", "zcut.binmask._ring_bounded", "zcut.binmask._assemble"} <= set(stats), \
        sorted(stats)
    missed = {k: v for k, v in stats.items() if v[1]}
    assert missed == {}, f"compiled again in a second process (cache hits, misses): {missed}"
