"""The z-cut benchmark's frame makers for the tests that run its kinds at seeds the benchmark does not use
(tests/zcut/test_cuts_prefetch.py, test_cuts_kept_marks.py, test_cuts_one_call.py, test_cuts_uphill.py) and its
own frames (tests/zcut/test_cuts_fast.py)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "bench"


def bench_zcut() -> ModuleType:
    """bench/bench_zcut.py as a module (its frame makers, ``A_MAX``); bench/ is on ``sys.path`` only for the
    import."""
    sys.path.insert(0, str(BENCH))
    try:
        import bench_zcut
    finally:
        sys.path.pop(0)
    return bench_zcut


def bench_kinds() -> dict[str, Callable[..., np.ndarray]]:
    """bench/bench_zcut.py's frame makers by kind, ``"pile"``, ``"holes"``, ``"dense"``: each takes a seed (the
    bench's own by default) and returns a 1920 x 1200 height image (mm, NaN where invalid)."""
    b = bench_zcut()
    return {"pile": b.pile_frame, "holes": b.holes_frame, "dense": b.dense_frame}
