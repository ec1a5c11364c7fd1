"""Where the real organized clouds are (docs/real_data.md): beside the checkout, or $ZCUT_REAL_DATA.

A module of its own so that a test can name the folder without ``import conftest``, which is ambiguous as soon as a
sub-folder has its own conftest.py (tests/zcut has one): the name then means whichever was loaded last."""

from __future__ import annotations

import os
from pathlib import Path

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL_DATA.is_dir():  # a checkout elsewhere may point at the data explicitly
    REAL_DATA = Path(os.environ.get("ZCUT_REAL_DATA", REAL_DATA))
