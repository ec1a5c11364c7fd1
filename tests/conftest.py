"""Shared fixtures. Seeds are fixed; files are real and live in tmp_path."""

from __future__ import annotations

import os
from pathlib import Path

# the command line's process settings (replay.cli.configure_process) before numba is imported:
# numba's own workqueue threads, not an old TBB that warns when probed
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL_DATA.is_dir():  # a checkout elsewhere may point at the data explicitly
    REAL_DATA = Path(os.environ.get("ZCUT_REAL_DATA", REAL_DATA))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240125)


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data folder not found: {REAL_DATA} (set ZCUT_REAL_DATA)")
    return REAL_DATA
