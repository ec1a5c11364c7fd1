"""The install's compilation of the kernels (``python -m replay.warmup``, run by scripts/install.sh)
says what it compiles as it goes: a line per kernel group, with its time."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_the_warmup_prints_a_line_per_kernel_group():
    r = subprocess.run([sys.executable, "-m", "replay.warmup"], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    groups = [ln for ln in lines if re.match(r"zcut: \[\d/\d\] .+… \d+ s$", ln)]
    n = int(re.search(r"in (\d+) groups", lines[0]).group(1))
    assert len(groups) == n >= 5, r.stderr
    assert lines[-1].startswith("zcut: kernels compiled in ")
