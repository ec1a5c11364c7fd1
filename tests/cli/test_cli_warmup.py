"""The install's compilation of the kernels (``python -m replay.warmup``, run by scripts/install.sh)
says what it compiles as it goes: a line per kernel group, with its time."""

from __future__ import annotations

import re

import pytest


@pytest.mark.slow
def test_the_warmup_prints_a_line_per_kernel_group(warmup_run):
    r = warmup_run  # the session's `python -m replay.warmup` (tests/conftest.py; the fuzz corpus relies on it too)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    groups = [ln for ln in lines if re.match(r"zcut: \[\d/\d\] .+… \d+ s$", ln)]
    n = int(re.search(r"in (\d+) groups", lines[0]).group(1))
    assert len(groups) == n >= 5, r.stderr
    assert lines[-1].startswith("zcut: kernels compiled in ")
