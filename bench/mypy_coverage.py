"""How much of the package code mypy checks strictly (issue 34's "mypy coverage of package lines").

Covered = the lines of the modules of the packages tests/test_lint.py hands mypy (``STRICT``), under a
strict configuration, whose errors are reported (no ``ignore_errors`` override); the figure is their
share of all the lines of the five packages. Lines are physical lines (``wc -l``). An override applies
as mypy applies it: a module's exact name before a pattern, a longer pattern before a shorter one.

    python bench/mypy_coverage.py                  # the checkout's pyproject.toml and test_lint.py
    python bench/mypy_coverage.py --checked zcut studies --pyproject old.toml
"""

from __future__ import annotations

import argparse
import ast
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("zcut", "replay", "annotate", "studies", "cli")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _specificity(pattern: str, module: str) -> tuple[int, int] | None:
    """How closely ``pattern`` names ``module`` (higher wins), or None when it does not match."""
    if pattern == module:
        return (1, pattern.count(".") + 1)
    if pattern.endswith(".*"):
        base = pattern[:-2]
        if module == base or module.startswith(base + "."):
            return (0, base.count(".") + 1)
    return None


def option(config: dict[str, Any], module: str, key: str) -> Any:
    """The value of ``key`` for ``module``: the most specific override naming it, else the global one."""
    best: tuple[tuple[int, int], Any] | None = None
    for override in config.get("overrides", []):
        if key not in override:
            continue
        patterns = override["module"]
        for pattern in [patterns] if isinstance(patterns, str) else patterns:
            rank = _specificity(pattern, module)
            if rank is not None and (best is None or rank > best[0]):
                best = (rank, override[key])
    return best[1] if best is not None else config.get(key)


def strict_tree(config: dict[str, Any]) -> bool:
    """Whether strict is on: ``strict`` set anywhere in mypy's config sets the global strict flags."""
    return bool(config.get("strict")) or any(o.get("strict") for o in config.get("overrides", []))


def checked_packages(lint: Path) -> tuple[str, ...]:
    """The ``STRICT`` tuple of tests/test_lint.py (the packages its mypy call names)."""
    for node in ast.parse(lint.read_text()).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "STRICT" for t in node.targets):
            value = ast.literal_eval(node.value)
            return tuple(value)
    raise SystemExit(f"no STRICT in {lint}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pyproject", type=Path, default=ROOT / "pyproject.toml")
    parser.add_argument("--checked", nargs="*", help="the packages mypy is run on (default: tests/test_lint.py's)")
    parser.add_argument("--list", action="store_true", help="list the modules not covered")
    args = parser.parse_args()
    config = tomllib.loads(args.pyproject.read_text())["tool"]["mypy"]
    checked = tuple(args.checked) if args.checked else checked_packages(ROOT / "tests" / "test_lint.py")
    strict = strict_tree(config)
    total = covered = 0
    per_package: dict[str, list[int]] = {p: [0, 0] for p in PACKAGES}
    missing: list[tuple[int, str]] = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            lines = len(path.read_text().splitlines())
            name = module_name(path)
            ok = strict and package in checked and not option(config, name, "ignore_errors")
            total += lines
            per_package[package][1] += lines
            if ok:
                covered += lines
                per_package[package][0] += lines
            else:
                missing.append((lines, name))
    for package, (c, t) in per_package.items():
        print(f"{package:9s} {c:6d} / {t:6d} lines  {100 * c / max(t, 1):5.1f} %")
    print(f"{'all':9s} {covered:6d} / {total:6d} lines  {100 * covered / total:5.1f} %  (strict: {strict}, checked: {' '.join(checked)})")
    if args.list:
        for lines, name in sorted(missing, reverse=True):
            print(f"  not covered: {name} ({lines} lines)")


if __name__ == "__main__":
    main()
