"""The linter and the type checker, as part of the suite (README, "Lint and types").

ruff checks the whole repository with the rules chosen in pyproject.toml (``[tool.ruff.lint]``);
mypy checks the five packages strictly (``[tool.mypy]``: every function annotated, no implicit Any,
no unused ignores). A finding fails the test with the tool's own report.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the packages mypy checks, all strictly
STRICT = ("zcut", "replay", "annotate", "studies", "cli")


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
    """One strict setting for the whole tree (not merely checked): no override turns a strict check
    off or leaves a module's errors unreported."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    assert config.get("strict") is True
    relaxed = {"zcut", "zcut.*"}  # warn_return_any off: a typed function may return what a numba kernel returned
    for override in config.get("overrides", []):
        modules = set(override["module"])
        for key, value in override.items():
            if key == "module":
                continue
            if key == "warn_return_any" and value is False:
                assert modules <= relaxed, f"warn_return_any off outside zcut: {sorted(modules - relaxed)}"
            else:
                raise AssertionError(f"an override of {sorted(modules)} sets {key} = {value!r}")


#: What the repository must not cite: contracts and style live in docs/ (docs/README.md), and no
#: file outside the checkout is a reference. Spelled in pieces so that this file does not match.
FOREIGN = ("SPEC" + " §", "STYLE" + ".md", ".." + "/shared")
#: The one place that may name the data folder beside the checkout: where the tests look for it.
MAY_NAME_DATA_FOLDER = {"docs/real_data.md": ".." + "/shared"}


def test_the_repository_cites_only_itself():
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    found = []
    for name in listed.stdout.decode().split("\0"):
        path = ROOT / name
        if not name or not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        for lineno, line in enumerate(text.splitlines(), 1):
            for word in FOREIGN:
                if word in line and MAY_NAME_DATA_FOLDER.get(name) != word:
                    found.append(f"{name}:{lineno}: {line.strip()[:100]}")
    assert found == [], "citations of files outside the repository (cite docs/ instead):\n" + "\n".join(found)
