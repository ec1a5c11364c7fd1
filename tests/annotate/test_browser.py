"""The labelling page in Debian's chromium (headless, driven by Playwright) against a real server."""

from __future__ import annotations

import json
import subprocess
import sys

import httpx
import numpy as np
import pytest
from annotate_helpers import ServerProcess, wait_until, write_spike_log
from scipy import ndimage

from annotate.payload import parse_bundle
from annotate.store import LabelStore, file_sha256

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _open(browser, url):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    wait_until(page, "window.zcut && window.zcut.ready === true")
    return page, errors


def _wait_saved(page):
    wait_until(page, "window.zcut.state() && !window.zcut.state().dirty && !window.zcut.state().saving")
    # no timer pending: nothing unsaved
    page.wait_for_timeout(400)
    wait_until(page, "window.zcut.state() && !window.zcut.state().dirty && !window.zcut.state().saving")


def _click_pixel(page, x, y):
    pt = page.evaluate(f"window.zcut.imageToClient({x}, {y})")
    page.mouse.click(pt["x"], pt["y"])


def test_label_by_clicking_and_painting_persists_and_counts(tmp_path, browser):
    log = tmp_path / "scan.mcap"
    truths = write_spike_log(log, frames=2)
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator="alice")
    try:
        _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
        zids, valid = arrays["zcut"].astype(np.int64), arrays["valid"]
        assert zids.max() >= 2, "the test log should give at least two z-cut clusters"
        page, errors = _open(browser, srv.url)
        st = page.evaluate("window.zcut.state()")
        assert st["index"] == 0 and st["nL"] == 0 and st["rev"] == 0
        assert "reviewed 0 / 2" in st["progress"]

        def first_pixel(cid):
            r, c = np.argwhere(zids == cid)[0]
            return int(c), int(r)

        # accept cluster 1, accept cluster 2, undo the second
        _click_pixel(page, *first_pixel(1))
        _click_pixel(page, *first_pixel(2))
        assert page.evaluate("window.zcut.state().nL") == int((zids == 1).sum() + (zids == 2).sum())
        page.keyboard.press("Control+z")
        assert page.evaluate("window.zcut.state().nL") == int((zids == 1).sum())

        # paint the truth spike the z-cut covers least, with a brush of radius 3
        comps, n = ndimage.label(truths[0], structure=np.ones((3, 3), bool))
        cover = [((zids > 0) & (comps == k)).sum() / (comps == k).sum() for k in range(1, n + 1)]
        k = int(np.argmin(cover)) + 1
        r0, c0 = np.round(ndimage.center_of_mass(comps == k)).astype(int)
        page.keyboard.press("b")
        for _ in range(5):
            page.keyboard.press("[")
        assert page.evaluate("window.zcut.state().brush") == 3
        _click_pixel(page, int(c0), int(r0))
        _wait_saved(page)
        st = page.evaluate("window.zcut.state()")
        # edits do not make the frame reviewed: only what was decided is
        assert st["rev"] >= 1 and "reviewed 0 / 2" in st["progress"] and "not reviewed yet" in st["status"]

        # the store has what the page shows: cluster 1 + a disc of radius ~3 around the spike centre,
        # reviewed where decided (here: where accepted)
        with LabelStore(db) as s:
            fr0 = s.frames(s.log_by_sha(file_sha256(log)))[0]
            lab = s.label(fr0, annotator="alice")
        rr, cc = np.mgrid[0:valid.shape[0], 0:valid.shape[1]]
        d2 = (rr - r0) ** 2 + (cc - c0) ** 2
        assert lab.revision == st["rev"]
        assert np.array_equal(lab.reviewed, lab.outliers)
        assert (lab.outliers[zids == 1]).all() and not (lab.outliers & (zids == 2) & (d2 > 16)).any()
        assert lab.outliers[(d2 <= 4) & valid].all()
        assert not (lab.outliers & (zids != 1) & (d2 > 16)).any()
        assert int(lab.outliers.sum()) == st["nL"]

        # reload: the labels persist
        page.close()
        page, errors2 = _open(browser, srv.url)
        st2 = page.evaluate("window.zcut.state()")
        assert (st2["index"], st2["rev"], st2["nL"]) == (0, st["rev"], st["nL"])
        assert page.evaluate("window.zcut.overlayConsistent()")
        # height colour map, then mark frame 0 reviewed (Enter: all of it) and go on; frame 1 reviewed with
        # no outliers
        page.keyboard.press("h")
        assert page.evaluate("window.zcut.state().view") == "height"
        page.keyboard.press("Enter")
        wait_until(page, "window.zcut.state().index === 1")
        page.keyboard.press("Enter")
        _wait_saved(page)
        wait_until(page, "window.zcut.state().progress.startsWith('reviewed 2 / 2')")
        assert not errors and not errors2, errors + errors2
        assert page.evaluate("window.zcut.errors") == []
        page.close()
        # the z-cut candidates the page showed (the accuracy command recomputes them with the pipeline)
        candidates = [parse_bundle(httpx.get(f"{srv.base}/api/frames/{i}/bundle", headers=srv.headers()).content)[1]["zcut"]
                      for i in range(2)]
    finally:
        srv.stop()

    # accuracy against these labels matches a count by hand (numpy on the stored masks)
    out = subprocess.run([sys.executable, "-m", "cli", "accuracy", str(log), "--labels", str(db), "--json"],
                         check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    with LabelStore(db) as s:
        frs = s.frames(s.log_by_sha(file_sha256(log)))
        labs = [s.label(f, annotator="alice") for f in frs]
    assert labs[1].outliers.sum() == 0 and labs[1].reviewed.sum() > 0.9 * labs[1].reviewed.size
    tot = {"tp": 0, "fp": 0, "fn": 0}
    for i, lab in enumerate(labs):
        P = candidates[i] > 0
        L, R = lab.outliers, lab.reviewed
        hand = {"tp": int((P & L & R).sum()), "fp": int((P & R & ~L).sum()), "fn": int((L & ~P).sum())}
        got = report["frames"][i]["zcut"]
        assert {k: got[k] for k in hand} == hand
        for k in tot:
            tot[k] += hand[k]
    assert {k: report["pooled"]["zcut"][k] for k in tot} == tot
    assert report["frames"][1]["zcut"]["fn"] == 0 and report["frames"][1]["zcut"]["recall"] is None


def _drag(page, pts, *, shift=False):
    xy = [page.evaluate(f"window.zcut.imageToClient({x}, {y})") for x, y in pts]
    if shift:
        page.keyboard.down("Shift")
    page.mouse.move(xy[0]["x"], xy[0]["y"])
    page.mouse.down()
    for p in xy[1:]:
        page.mouse.move(p["x"], p["y"], steps=3)
    page.mouse.up()
    if shift:
        page.keyboard.up("Shift")


def test_box_lasso_eraser_unreviewed_undo_redo_zoom(tmp_path, browser):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1)
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator="carol")
    try:
        _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
        valid = arrays["valid"]
        page, errors = _open(browser, srv.url)
        state = lambda: page.evaluate("window.zcut.state()")

        page.keyboard.press("x")  # box: fills the valid pixels whose centres are inside
        _drag(page, [(10, 10), (40, 30)])
        n_box = state()["nL"]
        assert abs(n_box - int(valid[10:31, 10:41].sum())) <= 2 * (31 + 21)  # up to the border pixels
        _drag(page, [(15, 12), (25, 20)], shift=True)  # shift: box erase
        n_erased = state()["nL"]
        assert n_erased < n_box - 0.8 * int(valid[13:20, 16:25].sum())
        # lasso: around a review group away from the box; it takes only the groups' pixels inside
        gids = arrays["groups"].astype(np.int64)
        boxes = ndimage.find_objects(gids)
        H, W = gids.shape
        far = [b for b in boxes if b is not None and min(b[0].start, b[1].start) >= 5 and b[0].stop + 5 <= H
               and b[1].stop + 5 <= W and (b[0].start >= 37 or b[1].start >= 47 or b[0].stop <= 5)]
        assert far, "the test log should give a review group away from the box"
        ys, xs = max(far, key=lambda b: int((gids[b] != 0).sum()))
        y0, y1, x0, x1 = ys.start - 2, ys.stop + 2, xs.start - 2, xs.stop + 2
        page.keyboard.press("l")  # the polygon's corners on pixel corners (imageToClient gives centres)
        _drag(page, [(x0 - 0.5, y0 - 0.5), (x1 - 0.5, y0 - 0.5), (x1 - 0.5, y1 - 0.5), (x0 - 0.5, y1 - 0.5),
                     (x0 - 0.5, y0 - 0.5)])
        n_lasso = state()["nL"]

        def suspects_in(m):  # group pixels in the box grown by m (the pointer lands to a fraction of a pixel)
            return int((gids[y0 - m:y1 + m, x0 - m:x1 + m] != 0).sum())

        assert 0 < suspects_in(-1) <= n_lasso - n_erased <= suspects_in(1)
        assert int(valid[y0 + 1:y1 - 1, x0 + 1:x1 - 1].sum()) > suspects_in(1)  # no suspect: not taken
        page.keyboard.press("u")  # not reviewed: takes pixels out of R (and L)
        _drag(page, [(12, 12), (38, 12)])
        st = state()
        assert st["nR"] < int(valid.sum()) and st["nL"] < n_lasso
        page.keyboard.press("e")  # eraser, across the lassoed group
        cy, cx = (ys.start + ys.stop) // 2, (xs.start + xs.stop) // 2
        _drag(page, [(xs.start, cy), (cx, cy), (xs.stop - 1, cy)])
        n_final = state()["nL"]
        assert n_final < st["nL"]
        for _ in range(5):
            page.keyboard.press("Control+z")
        assert state()["nL"] == 0
        for _ in range(5):
            page.keyboard.press("Control+y")
        assert state()["nL"] == n_final
        # Shift+A: every undecided candidate of the list at once (SOR's of any size), one undo step
        page.keyboard.press("v")
        page.locator("#sormin").fill("1")
        undecided = [e for e in page.evaluate("window.zcut.entries()") if e["state"] == "undecided"]
        assert undecided, "the test frame should have candidates left to decide"
        page.keyboard.press("Shift+A")
        assert n_final < state()["nL"] <= n_final + sum(e["n"] for e in undecided)
        assert all(s != "undecided" for s in state()["states"])
        page.keyboard.press("Control+z")
        assert state()["nL"] == n_final
        # zoom with the wheel around the cursor, pan with a right drag, fit back
        z0 = state()["zoom"]
        page.mouse.move(400, 300)
        page.mouse.wheel(0, -400)
        wait_until(page, f"window.zcut.state().zoom > {z0} * 1.5")
        page.keyboard.press("f")
        assert state()["zoom"] == pytest.approx(z0)
        _wait_saved(page)
        page.reload()
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert state()["nL"] == n_final and state()["nR"] < int(valid.sum())
        assert page.evaluate("window.zcut.overlayConsistent()")  # incl. the not-reviewed shading
        assert not errors
        page.close()
    finally:
        srv.stop()
    with LabelStore(db) as s:
        lab = s.label(s.frames(s.log_by_sha(file_sha256(log)))[0], annotator="carol")
    assert int(lab.outliers.sum()) == n_final
    assert not (lab.outliers & ~lab.reviewed).any() and not (lab.reviewed & ~valid).any()
    # reviewed: the box, the lasso and the eraser's stroke, not the not-reviewed stroke along row 12
    assert 0 < lab.reviewed.sum() < valid.sum() and not lab.reviewed[12, 14:36].any()
    assert lab.reviewed[cy, xs.start:xs.stop].sum() == valid[cy, xs.start:xs.stop].sum()


def test_conflicting_save_is_shown_and_resolved(tmp_path, browser):
    import base64

    from annotate.store import pack_mask

    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1, shape=(96, 128))
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator="erin")
    try:
        _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
        valid = arrays["valid"]
        page, errors = _open(browser, srv.url)
        # another tab of erin saves first
        theirs = np.zeros_like(valid)
        theirs[40:44, 40:44] = True
        theirs &= valid
        body = {"base_revision": 0, "height": valid.shape[0], "width": valid.shape[1],
                "outliers": base64.b64encode(pack_mask(theirs)).decode(),
                "reviewed": base64.b64encode(pack_mask(valid)).decode()}
        assert httpx.put(f"{srv.base}/api/frames/0/label", json=body, headers=srv.headers()).json()["revision"] == 1
        # this page, still at revision 0, paints: its save is refused and the conflict shown
        page.keyboard.press("b")
        _click_pixel(page, 10, 10)
        wait_until(page, "window.zcut.state().conflict === 1")
        assert page.is_visible("#conflict")
        mine = page.evaluate("window.zcut.state().nL")
        assert "They differ at" in page.text_content("#conflictinfo")
        page.click("#conflict [data-merge=mine]")  # keep mine: saved on top of theirs, as revision 2
        _wait_saved(page)
        st = page.evaluate("window.zcut.state()")
        assert (st["rev"], st["conflict"], st["nL"]) == (2, 0, mine)
        assert not page.is_visible("#conflict")
        assert not errors
        page.close()
    finally:
        srv.stop()
    with LabelStore(db) as s:
        fr = s.frames(s.log_by_sha(file_sha256(log)))[0]
        assert s.revisions(fr, annotator="erin") == [1, 2]
        assert np.array_equal(s.label(fr, annotator="erin", revision=1).outliers, theirs)  # kept in the history
        assert int(s.label(fr, annotator="erin").outliers.sum()) == mine
