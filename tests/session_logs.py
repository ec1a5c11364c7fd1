"""Logs that several test modules read, made once per test session (tests/ is on sys.path).

``zcut synth`` of the same arguments is deterministic (tests/replay/synth/test_synth_log.py: the same seed gives
the same bytes), and so is ``zcut replay --out`` of one log: the modules that read the same log, or the same
results file, share one made in the session's temporary folder instead of making their own. The files are only
read by the tests (a test that changes a log makes its own copy); each is made the first time a module asks.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cli.main import main

_MADE: dict[tuple[str, ...], Path] = {}


def synth_once(tmp_path_factory: pytest.TempPathFactory, *, parts: str, frames: int, seed: int, size: str) -> Path:
    """``zcut synth -o LOG --parts PARTS --frames FRAMES --seed SEED --size SIZE``, made once per session: LOG."""
    key = ("synth", parts, str(frames), str(seed), size)
    if key not in _MADE:
        log = tmp_path_factory.mktemp(f"shared_{parts}") / "log.mcap"
        assert main(["synth", "-o", str(log), "--parts", parts, "--frames", str(frames), "--seed", str(seed),
                     "--size", size]) == 0
        _MADE[key] = log
    return _MADE[key]


def replay_out_once(tmp_path_factory: pytest.TempPathFactory, log: Path) -> Path:
    """``zcut replay LOG --out RESULTS`` (the default results file: masks, no cloud), made once per session per
    log: RESULTS."""
    key = ("replay --out", str(log))
    if key not in _MADE:
        res = tmp_path_factory.mktemp("shared_results") / "r.mcap"
        assert main(["replay", str(log), "--out", str(res)]) == 0
        _MADE[key] = res
    return _MADE[key]
