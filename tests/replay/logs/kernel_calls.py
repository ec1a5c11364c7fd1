"""The kernels a decoding calls, counted (tests/replay/logs is on sys.path for its test modules)."""

from __future__ import annotations

from types import ModuleType

import pytest


def counted_calls(monkeypatch: pytest.MonkeyPatch, module: ModuleType, names: tuple[str, ...]) -> list[str]:
    """Replace each kernel ``names`` of ``module`` (called by module global, as
    :func:`replay.logs.ros2_msgs.cloud_to_arrays` calls them) for the test by one that appends its name to the
    list returned, then runs the kernel."""
    calls: list[str] = []
    for name in names:
        kernel = getattr(module, name)

        def counted(*a, _k=kernel, _n=name):  # type: ignore[no-untyped-def]
            calls.append(_n)
            return _k(*a)

        monkeypatch.setattr(module, name, counted)
    return calls
