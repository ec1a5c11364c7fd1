"""The linter and the type checker, as part of the suite (README, "Lint and types").

ruff checks the whole repository with the rules chosen in pyproject.toml (``[tool.ruff.lint]``);
mypy checks ``zcut/`` and ``studies/`` strictly (``[tool.mypy]``: every function annotated, no
implicit Any, no unused ignores). A finding fails the test with the tool's own report.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the packages mypy checks strictly (the others follow when they are ready)
STRICT = ("zcut", "studies")


def _run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *argv], cwd=ROOT, capture_output=True, text=True, timeout=900)


def test_ruff_finds_nothing():
    out = _run("ruff", "check", "--no-cache", "--output-format", "concise", ".")
    assert out.returncode == 0, f"ruff:\n{out.stdout}{out.stderr}"


@pytest.mark.slow
def test_mypy_strict_finds_nothing():
    cache = ROOT / ".mypy_cache"  # kept between runs (git ignores it): a warm run takes seconds
    out = _run("mypy", "--cache-dir", str(cache), *STRICT)
    assert out.returncode == 0, f"mypy:\n{out.stdout}{out.stderr}"
    assert "Success: no issues found" in out.stdout


def test_mypy_is_strict_where_the_test_says():
    """The strict packages really are strict in the config (not merely checked)."""
    import tomllib

    overrides = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]["overrides"]
    strict = {m for o in overrides if o.get("strict") for m in o["module"]}
    for pkg in STRICT:
        assert pkg in strict and f"{pkg}.*" in strict
