"""A rejected fit's pixels re-measured, in the real page (Debian's chromium, headless, driven by Playwright) on
a small synthetic spheres log that carries its part model (issue 29 item 5; docs/labelling.md, "Judging fits"):
K rejects a fit, the server judges its pixels again against the surfaces left, and those none explains come
back as proposals with their distance ("fit #n rej.", "x.x mm off"), as the server's own
:meth:`annotate.fits.FrameFits.remeasure` finds them; K again restores the page's previous state exactly
(the fits, the proposals, the list, the server's bundle to the byte). A screenshot of the re-measured
proposals is written to the test's temporary folder (``ZCUT_SCREENSHOTS=DIR``: there instead)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from annotate_helpers import LiveServer, close_page, open_page, page_client, wait_until

from annotate.server import open_page as open_server_page
from replay.options import PipelineOptions

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SEED = 9193  # used by no other test


@pytest.fixture(scope="module")
def spheres_log(tmp_path_factory):
    from cli_helpers import synth_log

    return synth_log(tmp_path_factory.mktemp("fitrej") / "spheres.mcap", parts="spheres", frames=1, seed=SEED,
                     size="480x300")


def test_k_proposes_a_rejected_fits_pixels_with_their_distance_and_k_again_restores(spheres_log, tmp_path, browser):
    srv = LiveServer(open_server_page(spheres_log, tmp_path / "labels.sqlite", annotator="alice",
                                      choose_bin_model=PipelineOptions().model_chooser()))
    try:
        assert srv.page.catalogue.wait_until_done(300)
        ff = srv.page.catalogue.fitter.wait(0, 300)
        assert ff is not None and ff.status == "ready", ff
        with page_client(srv.base, srv.token) as c:
            bundle_before = c.get("/api/frames/0/fits").content
        page, errors, blocked = open_page(browser, f"{srv.base}/?token={srv.token}", viewport=(1366, 768))
        try:
            wait_until(page, "window.zcut.fits() && window.zcut.fits().status === 'ready'", timeout_s=120)
            before, list_before = page.evaluate("window.zcut.fits()"), page.evaluate("window.zcut.entries()")
            rows_before = page.locator("#candlist .cand:not(.head)").all_text_contents()
            k = max((i for i, e in enumerate(list_before) if e["src"] == "f"), key=lambda i: list_before[i]["n"])
            fit = list_before[k]
            page.click(f"#candlist .cand[data-k='{k}']")
            page.keyboard.press("k")
            wait_until(page, "window.zcut.fits().n_rejected === 1")
            f = page.evaluate("window.zcut.fits()")
            mine = [p for p in f["proposals"] if p["fromFit"] == fit["fit"]]
            # what the server's remeasure finds: the fit's pixels no surface left explains, with their distance
            xyz = np.asarray(srv.page.catalogue.geometry.points(0), np.float64) * 1000.0
            again = ff.remeasure({fit["fit"]}, xyz)
            assert mine and sum(p["n"] for p in mine) == again.pix.size == f["fits"][fit["fit"]]["proposed"]
            assert again.pix.size <= fit["n"]
            assert all(np.isfinite(p["dist"]) and p["dist"] > 0 for p in mine)
            assert min(p["dist"] for p in mine) >= float(np.min(again.dist)) - 1e-4
            assert max(p["dist"] for p in mine) <= float(np.max(again.dist)) + 1e-4
            # the other proposals and fits are as they were
            assert [p for p in f["proposals"] if p["fromFit"] < 0] == before["proposals"]
            assert [dict(x, rejected=False, proposed=0) for x in f["fits"]] == before["fits"]
            # their rows: where they came from and how far they lie, the first one selected and shown
            sel = page.text_content("#candlist .cand.sel")
            assert f"fit #{fit['fit'] + 1} rej." in sel and "mm off" in sel, sel
            rows = [r for r in page.locator("#candlist .cand:not(.head)").all_text_contents()
                    if f"fit #{fit['fit'] + 1} rej." in r]
            assert len(rows) == len(mine) and all("mm off" in r for r in rows), rows
            wait_until(page, "/nearest known surface/.test(window.zcut.profileInfo())")
            assert f"pixels of rejected fit #{fit['fit'] + 1}" in page.evaluate("window.zcut.profileInfo()")
            shots = Path(os.environ.get("ZCUT_SCREENSHOTS") or tmp_path)
            page.screenshot(path=str(shots / "rejected_fit_remeasured.png"))
            assert (shots / "rejected_fit_remeasured.png").stat().st_size > 10_000
            # K again: the state before, exactly
            page.keyboard.press("k")
            wait_until(page, "window.zcut.fits().n_rejected === 0")
            assert page.evaluate("window.zcut.fits()") == before
            assert page.evaluate("window.zcut.entries()") == list_before
            assert page.locator("#candlist .cand:not(.head)").all_text_contents() == rows_before
            assert not errors and not blocked
        finally:
            close_page(page)
        with page_client(srv.base, srv.token) as c:
            assert c.get("/api/frames/0/fits").content == bundle_before
    finally:
        srv.stop()
