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


#: the first lines of a bench's worker process (``python -c``): the process settings every ``zcut`` command takes
#: (:func:`replay.process.configure_process`: numba's threading layer, one malloc arena, the freed memory kept), set
#: before numba loads, as the labelling page's process has them; ``ZCUT_BENCH_BARE=1`` in the worker's environment
#: leaves glibc's and numba's defaults (the benches' ``--bare``). A tree older than ``configure_process`` (before
#: 2026-12-05) runs bare and says so on stderr: its page had no such settings.
WORKER_SETTINGS = """
import os as _os, sys as _sys
if _os.environ.get("ZCUT_BENCH_BARE") != "1":
    try:
        from replay.process import configure_process as _configure
    except ImportError:
        print("this tree has no replay.process.configure_process: measured bare", file=_sys.stderr)
    else:
        _configure()
"""


def worker_env(tree: str, *, bare: bool) -> dict[str, str]:
    """The environment of a worker process running ``tree``'s code (:data:`WORKER_SETTINGS` reads ``bare``)."""
    import os

    env = {**os.environ, "PYTHONPATH": tree}
    env.pop("ZCUT_BENCH_BARE", None)
    if bare:
        env["ZCUT_BENCH_BARE"] = "1"
    return env
