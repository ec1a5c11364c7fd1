"""A snippet of Python run in a fresh interpreter, for the tests of what a process sees from its start (imports
left out, environment, threading layers, signals, page faults): ``python -c code`` with this interpreter."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path


def run_python(code: str, *argv: str, cwd: Path | str | None = None, env: Mapping[str, str] | None = None,
               check: bool = False, timeout: float | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``code`` (then ``argv`` as its ``sys.argv[1:]``) in a new ``sys.executable``, stdout and stderr
    captured as text; ``cwd``, ``env``, ``check`` and ``timeout`` as :func:`subprocess.run` takes them (its
    defaults: the current folder, this environment, no check, no time limit)."""
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=cwd, env=env, capture_output=True, text=True,
                          check=check, timeout=timeout)
