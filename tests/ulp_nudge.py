"""One test helper of the ray casts' exactness tests: float32 results moved by a few ulp.

Used by tests/zcut/fits/test_fits_ray_hits.py (the fits' ray depths) and
tests/replay/synth/test_raytrace_exact.py (the ray-traced sensor's hits), which both check that what they
compute does not move with Embree's last bits.
"""

from __future__ import annotations

import numpy as np


def nudge(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each finite element of float32 ``a`` moved by -2, -1, +1 or +2 ulp (inf and NaN kept)."""
    out = a.copy()
    steps = rng.choice(np.array([-2, -1, 1, 2]), size=a.shape)
    for k in (1, 2):
        for sign in (-1, 1):
            m = (steps == sign * k) & np.isfinite(out)
            for _ in range(k):
                out[m] = np.nextafter(out[m], np.float32(sign * np.inf))
    return out
