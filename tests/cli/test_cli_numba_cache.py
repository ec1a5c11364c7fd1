"""A shared install whose numba cache folders cannot be written (docs/cli.md, "Exit status"): numba
itself would raise at import in every command (``--version`` included). The command line gives numba
a private folder of the temporary directory before it is imported, and ``--version`` imports no numba.

The install here is a copy of the packages; its ``__pycache__`` folders cannot be created (a file is
in their way, or the copy is on a read-only mount), nor can numba's per-user folder (HOME's
``.cache`` is a file, or on the read-only mount)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import cli
from cli.main import main

ROOT = Path(cli.__file__).resolve().parents[1]  # the install under test
PACKAGES = ("zcut", "replay", "annotate", "studies", "cli")


def _copy_install(dest: Path) -> None:
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dest / pkg, ignore=shutil.ignore_patterns("__pycache__"))


def _block_caches(tree: Path, home: Path) -> None:
    """A file where every ``__pycache__`` and ``~/.cache`` would be: none can be made."""
    for d in [tree, *(p for p in tree.rglob("*") if p.is_dir())]:
        (d / "__pycache__").write_text("not a folder\n")
    home.mkdir()
    (home / ".cache").write_text("not a folder\n")


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("nc_logs") / "log.mcap"
    assert main(["synth", "-o", str(p), "--parts", "rods", "--frames", "1", "--size", "128x96"]) == 0
    return p


@pytest.fixture(params=["a file in the way", "read-only mount"])
def install(request, tmp_path):
    tree, home = tmp_path / "site", tmp_path / "home"
    if request.param == "a file in the way":
        tree.mkdir()
        _copy_install(tree)
        _block_caches(tree, home)
        yield tree, home
        return
    if os.geteuid() != 0:
        pytest.skip("mounting a read-only tmpfs needs root")
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(ro)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        _copy_install(ro / "site")
        (ro / "home").mkdir()
        subprocess.run(["mount", "-o", "remount,ro", str(ro)], check=True, capture_output=True)
        yield ro / "site", ro / "home"
    finally:
        subprocess.run(["umount", "-l", str(ro)], capture_output=True)


def _zcut(install, tmp: Path, *argv) -> subprocess.CompletedProcess:
    tree, home = install
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_CACHE", "XDG_CACHE"))}
    env.update(PYTHONPATH=str(tree), HOME=str(home), TMPDIR=str(tmp), PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, "-m", "cli", *map(str, argv)], capture_output=True, text=True,
                          env=env, cwd=str(tmp), timeout=900)


def test_version_needs_no_cache_folder(install, tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = _zcut(install, tmp, "--version")
    assert r.returncode == 0 and r.stdout.startswith("zcut ") and r.stderr == "", r.stderr


def test_a_command_compiles_into_a_private_temporary_folder(install, tmp_path, log):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = _zcut(install, tmp, "topics", log, "--check")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    cache = tmp / f"zcut-numba-{os.getuid()}"
    assert cache.is_dir() and oct(cache.stat().st_mode & 0o777) == "0o700"
    assert list(cache.rglob("*.nbi")), "the kernels were cached there"
