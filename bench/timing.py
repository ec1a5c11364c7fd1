"""How the benchmarks time a call: CPU time of this process (the machine is shared; wall time is not ours)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any


def cpu(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Median CPU time of ``repeat`` calls and the last result."""
    times, out = [], None
    for _ in range(repeat):
        c0 = time.process_time()
        out = fn()
        times.append(time.process_time() - c0)
    return statistics.median(times), out
