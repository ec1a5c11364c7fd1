"""A scripted person reviews a 1920 x 1200 frame with 13 small z-cut candidates in the real page
(Debian's chromium, headless, driven by Playwright): every candidate is found and decided with the
keyboard, without panning by hand, and the store holds exactly those decisions."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from annotate_helpers import (
    REVIEW_CLUSTERS,
    ServerProcess,
    close_page,
    open_page,
    wait_until,
    write_review_log,
)

from annotate.payload import parse_bundle
from annotate.store import LabelStore, file_sha256

pytestmark = [pytest.mark.browser, pytest.mark.slow]
MAX_INPUTS = 20


def test_a_person_reviews_a_1920x1200_frame_in_15_inputs(tmp_path, browser):
    log = tmp_path / "review.mcap"
    truths = write_review_log(log, frames=2)
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator="alice")
    try:
        header, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
        zids, valid = arrays["zcut"].astype(np.int64), arrays["valid"]
        assert (header["width"], header["height"], header["n_zcut"]) == (1920, 1200, len(REVIEW_CLUSTERS))
        assert np.array_equal(zids > 0, truths[0])  # the 13 floating clusters, twelve of them <= 4 px
        page, errors, blocked = open_page(browser, srv.url, viewport=(1600, 900))
        st = page.evaluate("window.zcut.state()")
        assert st["index"] == 0 and st["zoom"] < 0.6  # the overview: a 1-4 px candidate is 1-2 screen pixels
        listed = page.evaluate("window.zcut.entries()")
        assert [e["src"] for e in listed[:13]] == ["z"] * 13  # sorted by the gap to the surface below

        accepted = set()
        page.keyboard.press("Tab")
        for k in range(13):
            wait_until(page, f"window.zcut.viewTimes.length >= {k + 1}")  # the profile and 3D view are drawn
            st = page.evaluate("window.zcut.state()")
            sel, vp = st["selected"], st["viewport"]
            assert sel["src"] == "z" and st["states"][st["sel"]] == "undecided"
            # the view went to it: in the middle of the canvas, each image pixel at least 4 screen pixels
            assert abs(sel["screen"]["x"] - vp["width"] / 2) < 2 and abs(sel["screen"]["y"] - vp["height"] / 2) < 2
            assert st["zoom"] >= 4
            assert page.evaluate("window.zcut.profileInfo()").startswith(f"gap {sel['gap']:.2f} mm")
            accept = k % 3 != 2
            if accept:
                accepted.add(sel["id"])
            page.keyboard.press("a" if accept else "r")
        st = page.evaluate("window.zcut.state()")
        assert [s for e, s in zip(page.evaluate("window.zcut.entries()"), st["states"]) if e["src"] == "z"].count(
            "undecided") == 0
        assert "not reviewed yet" in st["status"]  # deciding candidates does not review the frame
        page.keyboard.press("Enter")  # the frame is reviewed (every valid pixel), on to the next
        wait_until(page, "window.zcut.state() && window.zcut.state().index === 1")
        inputs, pans = page.evaluate("[window.zcut.inputs, window.zcut.pans]")
        assert inputs == 15 <= MAX_INPUTS and pans == 0
        wait_until(page, "window.zcut.unsaved().length === 0")
        wait_until(page, "document.querySelector('#framelist li.rev') !== null")
        # every selection drew its views (the 13 z-cut ones, and the SOR candidate selected after them)
        assert len(page.evaluate("window.zcut.viewTimes")) >= 13
        assert not errors and not blocked and page.evaluate("window.zcut.errors") == []
        close_page(page)
    finally:
        srv.stop()
    with LabelStore(db) as s:
        lab = s.label(s.frames(s.log_by_sha(file_sha256(log)))[0], annotator="alice")
    assert np.array_equal(lab.outliers, np.isin(zids, sorted(accepted)))
    assert np.array_equal(lab.reviewed, valid) and len(accepted) == 9
