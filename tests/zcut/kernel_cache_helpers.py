"""A second fresh process's numba cache statistics, for the tests that check a module's kernels load from their
cache (tests/zcut/test_kernel_cache.py, test_binmask_kernel_cache.py, test_suspects_eleventh.py).

A kernel whose cache always misses is compiled anew by every ``zcut`` process (~2 CPU-s for the flood of round
2026-12-06b, whose closure captured dispatchers: numba keys a closure's cache entry by its pickled bytes), which no
timing test sees. :func:`second_process_stats` runs a script twice, first in the test's own process (it may
compile, on a fresh checkout, and writes the caches: numba writes a kernel's cache entry when it compiles it, here as
in any process; a first fresh process for it cost ~1-2 CPU-s a test), then in a fresh process, and returns, for
every cached dispatcher of the modules under ``prefix`` that the fresh process called, its (cache hits, cache
misses)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: appended to every script: the cache statistics of the dispatchers of the modules under ``PREFIX``
_STATS = r"""
import json as _json, sys as _sys
from numba.core.dispatcher import Dispatcher as _Dispatcher
_stats = {}
for _name, _mod in list(_sys.modules.items()):
    if not _name.startswith(PREFIX):
        continue
    for _attr, _obj in list(vars(_mod).items()):
        if isinstance(_obj, _Dispatcher) and _obj.signatures and getattr(_obj, "_cache", None) is not None:
            _s = _obj.stats
            _stats[f"{_name}.{_attr}"] = [sum(_s.cache_hits.values()), sum(_s.cache_misses.values())]
print(_json.dumps(_stats))
"""


def _run(script: str, prefix: str, timeout: float) -> dict[str, list[int]]:
    code = f"PREFIX = {prefix!r}\n{script}\n{_STATS}"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-3000:]
    stats: dict[str, list[int]] = json.loads(out.stdout.strip().splitlines()[-1])
    return stats


def second_process_stats(script: str, *, prefix: str = "zcut", timeout: float = 600) -> dict[str, list[int]]:
    """(cache hits, cache misses) of every cached numba dispatcher of the modules whose name starts with ``prefix``,
    after ``script`` ran in a fresh process (it ran in this process first, to fill the caches)."""
    exec(compile(script, "<kernel cache script>", "exec"), {"__name__": "kernel_cache_script"})
    return _run(script, prefix, timeout)


def missed(stats: dict[str, list[int]]) -> dict[str, list[int]]:
    """The dispatchers that compiled again (a cache miss) in the second process."""
    return {k: v for k, v in stats.items() if v[1]}
