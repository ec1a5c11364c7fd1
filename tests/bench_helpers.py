"""Loading a script of bench/ as a module, for the tests of its pure helpers."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).resolve().parents[1] / "bench"


def bench_module(script: str) -> Iterator[ModuleType]:
    """bench/``script`` imported under a name of its own (registered in ``sys.modules`` while it is used, as its
    dataclasses need), then dropped: a generator for a pytest fixture."""
    name = f"{Path(script).stem}_under_test"
    spec = importlib.util.spec_from_file_location(name, BENCH / script)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        del sys.modules[name]
