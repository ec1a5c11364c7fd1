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
MAX_INPUTS = 60  # a first frame, before the assistant has seen any label (docs/labelling.md, Measured)


def test_a_person_reviews_a_1920x1200_frame_group_by_group(tmp_path, browser):
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
        # the list holds the review groups, each judged as a person would: an outlier when at least half of
        # its pixels are (the 13 clusters are floating suspects: groups hold them)
        listed = page.evaluate("window.zcut.entries()")
        assert listed and all(e["src"] == "g" for e in listed)
        gids = arrays["groups"].astype(np.int64)
        assert (gids[truths[0]] > 0).all()
        n = len(listed)

        def outlier(gid):
            return 2 * int((truths[0] & (gids == gid)).sum()) >= int((gids == gid).sum())

        accepted = set()
        page.keyboard.press("Tab")
        for k in range(n):
            wait_until(page, f"window.zcut.viewTimes.length >= {k + 1}")  # the profile and 3D view are drawn
            st = page.evaluate("window.zcut.state()")
            sel, vp = st["selected"], st["viewport"]
            assert sel["src"] == "g" and st["states"][st["sel"]] == "undecided"
            # the view went to it: in the middle of the canvas
            assert abs(sel["screen"]["x"] - vp["width"] / 2) < 2 and abs(sel["screen"]["y"] - vp["height"] / 2) < 2
            info = page.evaluate("window.zcut.profileInfo()")
            assert info.startswith(f"gap {sel['gap']:.2f} mm" if sel["gap"] >= 0 else f"{-sel['gap']:.2f} mm below")
            if outlier(sel["id"]):
                accepted.add(sel["id"])
            page.keyboard.press("a" if outlier(sel["id"]) else "r")
        st = page.evaluate("window.zcut.state()")
        assert st["states"].count("undecided") == 0
        assert "not reviewed yet" in st["status"]  # deciding groups does not review the frame
        page.keyboard.press("Enter")  # the frame is reviewed (every valid pixel), on to the next
        wait_until(page, "window.zcut.state() && window.zcut.state().index === 1")
        inputs, pans = page.evaluate("[window.zcut.inputs, window.zcut.pans]")
        assert inputs == n + 2 <= MAX_INPUTS and pans == 0  # Tab, one key per group, Enter
        wait_until(page, "window.zcut.unsaved().length === 0")
        wait_until(page, "document.querySelector('#framelist li.rev') !== null")
        assert len(page.evaluate("window.zcut.viewTimes")) >= n  # every selection drew its views
        assert not errors and not blocked and page.evaluate("window.zcut.errors") == []
        close_page(page)
    finally:
        srv.stop()
    with LabelStore(db) as s:
        lab = s.label(s.frames(s.log_by_sha(file_sha256(log)))[0], annotator="alice")
    assert accepted and np.array_equal(lab.outliers, np.isin(gids, sorted(accepted)))
    assert np.array_equal(lab.reviewed, valid)
