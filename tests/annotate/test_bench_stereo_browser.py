"""bench/bench_stereo_browser.py's person decides the groups it means (h/stereo4): the rule's decision checked against
each group's state in the page (``misdecided``), and in a real browser on a small ``zcut record-stereo`` log the label
the page saves is, frame by frame, the label bench/bench_stereo_patches.py's emulation of the same rule gives."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from types import ModuleType

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_stereo_browser.py")


def _e(gid: int, gap: float | None, state: str, source: str = "patch", src: str = "g") -> dict:
    return {"src": src, "id": gid, "gap": gap, "state": state, "source": source}


def test_misdecided_reads_the_rule_against_the_pages_states(bench):
    tau = 10.0
    entries = [_e(1, 31.0, "accepted"), _e(2, -31.0, "accepted"), _e(3, 30.0, "rejected"), _e(4, None, "accepted", "floating"),
               _e(5, math.nan, "rejected", "stereo_lr"), _e(6, 5.0, "rejected", src="L"), _e(7, 29.0, "undecided")]
    assert bench.misdecided(entries, tau) == []
    swapped = [_e(1, 31.0, "rejected"), _e(3, 30.0, "accepted"), _e(4, None, "rejected", "above_rim"),
               _e(5, None, "accepted", "stereo_uniqueness"), _e(8, 45.0, "undecided")]
    assert bench.misdecided(swapped, tau) == [1, 3, 4, 5, 8]


@pytest.mark.browser
@pytest.mark.slow
def test_the_page_saves_the_rules_label(bench, tmp_path):
    from browser_helpers import CHROMIUM

    pytest.importorskip("playwright.sync_api")
    if not os.path.exists(CHROMIUM):
        if os.environ.get("CI"):
            pytest.fail(f"{CHROMIUM} not installed (run: bash scripts/install.sh --test)")
        pytest.skip(f"{CHROMIUM} not installed")
    from stereo_helpers import motorcycle, write_scene

    from cli.main import main

    d = write_scene(tmp_path / "Motorcycle", motorcycle(4))
    log = tmp_path / "m.mcap"
    assert main(["record-stereo", str(d), str(d), "-o", str(log)]) == 0
    out = tmp_path / "rows.json"
    assert bench.main(["--log", str(log), "--work", str(tmp_path / "work"), "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["frame"] for r in rows] == [0, 1] and all(r["misdecided"] == 0 for r in rows)
    assert all(r["groups"] > 0 for r in rows)
    patches = bench_module("bench_stereo_patches.py")
    try:
        want = next(patches).score_log(log, [], None)
    finally:
        patches.close()
    assert [(r["label_px"], round(r["iou_sensor"], 12)) for r in rows] == [(w["label_px"], round(w["iou"], 12)) for w in want]
