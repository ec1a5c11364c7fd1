"""`zcut annotate LOG --disagreement DIR` in the real page (Debian's chromium, headless, driven by
Playwright): every frame lists only the groups of the pixels where the comparison's A and B disagree,
as many pixels of each side as compare.json counts."""

from __future__ import annotations

import json

import pytest
from annotate_helpers import ServerProcess, close_page, open_page, wait_until

from annotate.groups import FOCUS_SOURCES
from cli.main import main

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("page_disagreement")
    log = d / "log.mcap"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--frames", "2", "--seed", "5", "--size", "160x120"]) == 0
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    # the comparison in this process (its workers are not what the page is tested on: ~2 s of start-up)
    assert main(["compare", str(log), "--a", "sor", "--b", str(d / "rho.toml"), "-o", str(d / "cmp"), "--no-rrd",
                 "--workers", "0"]) == 0
    rep = json.loads((d / "cmp" / "compare.json").read_text())
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice", extra=("--disagreement", str(d / "cmp")))
    yield srv, rep
    srv.stop()


def test_the_page_lists_only_the_disagreement(served, browser, tmp_path):
    srv, rep = served
    assert any("disagree" in line for line in srv.stderr_lines), srv.stderr_lines
    page, errors, blocked = open_page(browser, srv.url, viewport=(1400, 900))
    try:
        # the header says what this review is, with compare.json's counts, for as long as the page is open
        wait_until(page, "!document.getElementById('focusbar').hidden")
        bar = page.text_content("#focusbar")
        only_a = sum(f["only_a"] for f in rep["frames"])
        only_b = sum(f["only_b"] for f in rep["frames"])
        assert f"only the {only_a + only_b} pixels where A (sor) and B (" in bar, bar
        assert f"{only_a} removed by A alone, {only_b} by B alone" in bar, bar
        assert f"on {len(rep['frames'])} of the {len(rep['frames'])} compared frames" in bar, bar
        assert "zcut compare cmp" in bar, bar
        page.screenshot(path=str(tmp_path / "focusbar.png"))  # to look at (pytest --basetemp)
        for k, f in enumerate(rep["frames"]):
            assert f["only_a"] + f["only_b"] > 0  # something to list on every frame
            page.click(f"#framelist li:nth-child({k + 1})")
            wait_until(page, f"window.zcut.shown === {f['index']} && window.zcut.state().index === {f['index']}")
            rows = page.evaluate("window.zcut.entries()")
            assert rows and all(r["src"] == "g" and r["source"] in FOCUS_SOURCES for r in rows), rows
            px = {s: sum(r["n"] for r in rows if r["source"] == s) for s in FOCUS_SOURCES}
            assert px == {FOCUS_SOURCES[0]: f["only_a"], FOCUS_SOURCES[1]: f["only_b"]}, (f["index"], px)
            assert page.text_content("#candcount").startswith(f"{len(rows)} groups")
        assert not errors and not blocked
    finally:
        close_page(page)
