"""Shared fixtures. Seeds are fixed; files are real and live in tmp_path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# the command line's process settings (replay.process.configure_process) before numba is imported:
# numba's own workqueue threads, not an old TBB that warns when probed
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")

# the suite's caches (prepared bin models, the demo's sample log) live in one folder of its own,
# shared by the session's tests and removed at the end: never the user's ~/.cache/zcut
import atexit  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

_CACHE = tempfile.mkdtemp(prefix="zcut-test-cache-")
os.environ["ZCUT_CACHE"] = _CACHE
atexit.register(shutil.rmtree, _CACHE, True)

# the processes the tests start (every `zcut` command, the workers, the Ray cluster) write the bytecode of the
# modules they compile where Python keeps it (the git-ignored ``__pycache__`` beside each module, where numba keeps
# its kernels), and the next process reads it, as an installed zcut does: under PYTHONDONTWRITEBYTECODE=1 every
# process compiled every module of the checkout again (+0.2 CPU s a replay, docs/performance.md).
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
# and this process too, from here on: pytest keeps the test modules it rewrites for their asserts (and Python the
# helper modules they import) as bytecode in those folders, and reads it back in the next run while the source is
# unchanged (size and modification time); under PYTHONDONTWRITEBYTECODE=1 every run rewrote and compiled every test
# module again (docs/testing.md, the round of 2026-12-08a).
sys.dont_write_bytecode = False

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from real_data_path import REAL_DATA  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240125)


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The real organized clouds (where docs/real_data.md says: beside the checkout, or $ZCUT_REAL_DATA).

    Missing data skips the tests on a developer's machine and fails them under CI (CI set).
    """
    if not REAL_DATA.is_dir():
        why = (f"real data folder not found: {REAL_DATA}; docs/real_data.md lists the files (names, sizes, "
               "SHA-256, where they come from and where the tests look for them): put them there "
               "or set ZCUT_REAL_DATA=/path/to/them")
        if os.environ.get("CI"):
            pytest.fail(why)
        pytest.skip(why)
    return REAL_DATA


@pytest.fixture(scope="module")
def browser():
    """Debian's chromium, headless, through Playwright (one per test module).

    CI installs chromium (scripts/install.sh --test): there a missing browser is a failure, not a
    reason to pass without the browser tests."""
    from browser_helpers import CHROMIUM, CHROMIUM_ARGS

    sync_api = pytest.importorskip("playwright.sync_api")
    if not os.path.exists(CHROMIUM):
        if os.environ.get("CI"):
            pytest.fail(f"{CHROMIUM} not installed (run: bash scripts/install.sh --test)")
        pytest.skip(f"{CHROMIUM} not installed (run: bash scripts/install.sh --test)")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="session")
def warmup_run() -> subprocess.CompletedProcess:
    """``python -m replay.warmup`` (what scripts/install.sh runs: every kernel group compiled into numba's cache)
    run once per session from the checkout, its output captured: tests/cli/test_cli_warmup.py checks what it
    prints, and the fuzz corpus (tests/fuzz/test_fuzz_fast.py) needs its kernels compiled before any case runs
    under its time cap; the corpus process ran the whole warm-up a second time (~10 s)."""
    return subprocess.run([sys.executable, "-m", "replay.warmup"], capture_output=True, text=True, timeout=1800,
                          cwd=ROOT)


@pytest.fixture(scope="session")
def ray_cluster_runs(tmp_path_factory):
    """The Ray tests' one cluster (tests/studies/test_batch_ray.py, test_compare_ray.py): starting a cluster in
    its namespaces costs tens of seconds, so the session starts one and runs both modules' commands on it
    in turn; their inputs and local runs first. (Here, not in tests/studies/conftest.py: a second
    conftest module would take the name ``conftest`` that tests import for ``REAL_DATA``.)"""
    from ray_in_netns import netns_unavailable, run_with_ray_cluster
    from test_batch_ray import _ray_missing, _require, collect_batch, prepare_batch
    from test_compare_ray import collect_compare, prepare_compare

    _require(_ray_missing() or netns_unavailable())
    batch, batch_cmds = prepare_batch(tmp_path_factory.mktemp("batch_ray"))
    compare, compare_cmds = prepare_compare(tmp_path_factory.mktemp("compare_ray"))
    cluster = run_with_ray_cluster([*batch_cmds, *compare_cmds], cpus=2, timeout=1500)
    results = cluster["results"]
    return {"batch": collect_batch(batch, results[:len(batch_cmds)], cluster["interfaces"]),
            "compare": collect_compare(compare, results[len(batch_cmds):], cluster["interfaces"])}
