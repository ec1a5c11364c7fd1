"""Every edit counts, in the real browser: navigation keys that add up, "reviewed" only when asked,
an edit made just before a reload, conflicts merged; and the page's side of access: the token out
of the address bar, a name chosen once, a second server shown."""

from __future__ import annotations

import base64

import httpx
import numpy as np
import pytest
from annotate_helpers import (
    ServerProcess,
    close_page,
    open_page,
    wait_until,
    write_spike_log,
)

from annotate.guard import cookie_name
from annotate.payload import parse_bundle
from annotate.store import LabelStore, file_sha256, pack_mask

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def nine(tmp_path_factory):
    """A server on a log of nine small frames (fresh store per test: see ``fresh``)."""
    d = tmp_path_factory.mktemp("edits")
    log = d / "scan.mcap"
    write_spike_log(log, frames=9)
    return log


@pytest.fixture
def srv(nine, tmp_path):
    s = ServerProcess(nine, tmp_path / "labels.sqlite", annotator="erin")
    yield s
    s.stop()


@pytest.fixture(scope="module")
def viewed(nine, tmp_path_factory):
    """One server for the tests that save nothing (they move between frames, open and reopen the page)."""
    s = ServerProcess(nine, tmp_path_factory.mktemp("viewed") / "labels.sqlite", annotator="erin")
    yield s
    s.stop()


def _label(srv, log, index):
    with LabelStore(srv_db(srv)) as s:
        return s.label(s.frames(s.log_by_sha(file_sha256(log)))[index], annotator="erin")


def srv_db(srv):
    return srv.proc.args[srv.proc.args.index("--db") + 1]


def test_navigation_keys_add_up(viewed, browser):
    page, errors, blocked = open_page(browser, viewed.url)
    try:
        for _ in range(7):  # as fast as keys go: each press moves one frame further
            page.keyboard.press("ArrowRight")
        wait_until(page, "window.zcut.state().index === 7")
        page.wait_for_timeout(300)
        assert page.evaluate("window.zcut.state().index") == 7
        for _ in range(3):
            page.keyboard.press("ArrowLeft")
        wait_until(page, "window.zcut.state().index === 4")
        for _ in range(9):  # the end of the log stops it
            page.keyboard.press("PageDown")
        wait_until(page, "window.zcut.state().index === 8")
        assert page.url.endswith("/#8")
        assert not errors and not blocked
    finally:
        close_page(page)


def test_reviewed_only_when_asked_and_an_edit_just_before_a_reload_is_kept(srv, nine, browser):
    _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
    valid = arrays["valid"]
    page, errors, blocked = open_page(browser, srv.url)
    try:
        page.keyboard.press("Tab")
        sel = page.evaluate("window.zcut.state().selected")
        page.keyboard.press("r")  # not an outlier: those pixels reviewed, nothing else
        wait_until(page, "window.zcut.unsaved().length === 0")
        st = page.evaluate("window.zcut.state()")
        assert st["nR"] == sel["n"] and st["nL"] == 0 and "not reviewed yet · " in st["status"] and " · 1 decided" in st["status"]
        assert "reviewed 0 / 9" in st["progress"]
        lab = _label(srv, nine, 0)
        ids = {"g": arrays["groups"], "z": arrays["zcut"], "s": arrays["sor"]}[sel["src"]]  # the list's first: a group
        assert np.array_equal(lab.reviewed, ids == sel["id"]) and not lab.outliers.any()
        # the next candidate accepted, and the page reloaded at once (before the autosave's delay)
        sel2 = page.evaluate("window.zcut.state().selected")
        page.keyboard.press("a")
        page.reload()
        wait_until(page, "window.zcut && window.zcut.ready === true")
        # sent as the page went away (keepalive), or kept in the browser and sent by the reloaded page
        wait_until(page, "window.zcut.state().rev === 2 && window.zcut.unsaved().length === 0")
        st = page.evaluate("window.zcut.state()")
        assert st["nL"] == sel2["n"] and st["rev"] == 2
        # Enter: the whole frame reviewed, visibly
        page.keyboard.press("Enter")
        wait_until(page, "window.zcut.unsaved().length === 0 && window.zcut.state().index === 1")
        wait_until(page, "window.zcut.state().progress.startsWith('reviewed 1 / 9')")
        lab = _label(srv, nine, 0)
        assert np.array_equal(lab.reviewed, valid) and lab.outliers.sum() == sel2["n"]
        assert not errors and not blocked
    finally:
        close_page(page)


def test_a_conflict_shows_both_versions_and_merges(srv, nine, browser):
    _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
    valid = arrays["valid"]

    def theirs(base, square):
        L = np.zeros_like(valid)
        r, c = square
        L[r:r + 4, c:c + 4] = True
        L &= valid
        body = {"base_revision": base, "height": valid.shape[0], "width": valid.shape[1],
                "outliers": base64.b64encode(pack_mask(L)).decode(), "reviewed": base64.b64encode(pack_mask(L)).decode()}
        r = httpx.put(f"{srv.base}/api/frames/0/label", json=body, headers=srv.headers())
        assert r.status_code == 200, r.text
        return L

    def paint(x, y):  # a brush stroke of radius 2 (on the whole frame): a change that is sure to be saved
        page.keyboard.press("f")
        pt = page.evaluate(f"window.zcut.imageToClient({x}, {y})")
        page.mouse.click(pt["x"], pt["y"])

    page, errors, blocked = open_page(browser, srv.url)
    try:
        page.keyboard.press("b")
        for _ in range(6):
            page.keyboard.press("[")
        t1 = theirs(0, (40, 40))  # another tab of erin saves first
        paint(10, 10)
        wait_until(page, "window.zcut.state().conflict === 1")
        assert page.is_visible("#conflict")
        info = page.text_content("#conflictinfo")
        mine = page.evaluate("window.zcut.state().nL")
        assert f"Mine: {mine} outlier px" in info and f"Theirs: {int(t1.sum())} outlier px" in info
        page.keyboard.press("d")
        assert page.evaluate("document.querySelector('#conflict [data-view=theirs]').classList.contains('active')")
        page.keyboard.press("d")
        assert page.evaluate("window.zcut.overlayConsistent()")
        page.click("#conflict [data-merge=union]")
        wait_until(page, "window.zcut.unsaved().length === 0")
        lab = _label(srv, nine, 0)
        assert lab.revision == 2 and int(lab.outliers.sum()) == mine + int(t1.sum())
        assert (lab.outliers & t1).sum() == t1.sum()
        # theirs: nothing of mine is kept, nothing new is stored
        t3 = theirs(2, (60, 90))
        paint(20, 100)
        wait_until(page, "window.zcut.state().conflict === 3")
        page.click("#conflict [data-merge=theirs]")
        st = page.evaluate("window.zcut.state()")
        assert (st["rev"], st["conflict"], st["nL"], st["dirty"]) == (3, 0, int(t3.sum()), False)
        # mine: saved on top
        theirs(3, (20, 20))
        paint(100, 30)
        wait_until(page, "window.zcut.state().conflict === 4")
        page.click("#conflict [data-merge=mine]")
        wait_until(page, "window.zcut.unsaved().length === 0")
        lab = _label(srv, nine, 0)
        assert lab.revision == 5 and int(lab.outliers.sum()) == page.evaluate("window.zcut.state().nL")
        assert not page.is_visible("#conflict") and not errors and not blocked
    finally:
        close_page(page)


def test_the_token_leaves_the_address_bar_for_an_http_only_cookie(viewed, browser):
    srv = viewed
    page, errors, blocked = open_page(browser, srv.url)
    try:
        assert page.url == f"{srv.base}/#0" and srv.token not in page.url
        assert page.evaluate("document.cookie") == ""  # HttpOnly: the page's scripts cannot read it
        cookies = page.context.cookies()
        assert [(c["name"], c["httpOnly"], c["sameSite"]) for c in cookies] == [(cookie_name(srv.token), True, "Strict")]
        assert srv.token not in page.content()
        page.go_back()  # the history holds no URL with the token
        assert srv.token not in page.url
        page.goto(f"{srv.base}/")  # the cookie opens the page again
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert not errors and not blocked
    finally:
        close_page(page)


def test_a_name_chosen_once_and_a_second_server_shown(nine, tmp_path, browser):
    first = ServerProcess(nine, tmp_path / "labels.sqlite", annotator=None, extra=["--ask-annotator"])
    second = ServerProcess(nine, tmp_path / "labels.sqlite", annotator="bob")
    try:
        page, errors, blocked = open_page(browser, first.url, ready=False)
        wait_until(page, "!document.getElementById('namebox').hidden")
        assert "Another server uses this label store" in page.text_content("#banner")
        assert f"pid {second.proc.pid}" in page.text_content("#banner")
        page.fill("#namein", "\u0430lice")  # a Cyrillic а
        page.click("#nameform button")
        wait_until(page, "document.getElementById('namemsg').textContent.includes('mixes scripts')")
        page.fill("#namein", "B\u043eb")  # looks like bob (in use on the second server: once it has labels)
        page.click("#nameform button")
        wait_until(page, "document.getElementById('namemsg').textContent.includes('mixes scripts')")
        page.fill("#namein", "alice")
        page.click("#nameform button")
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert page.text_content("#who") == "annotator: alice" and page.is_hidden("#namebox")
        page.reload()  # the page session keeps its name
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert page.text_content("#who") == "annotator: alice"
        assert not errors and not blocked
        close_page(page)
        second.stop()
        page, errors, blocked = open_page(browser, first.url, ready=False)
        page.fill("#namein", "carol")
        page.click("#nameform button")
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert page.is_hidden("#banner")
        close_page(page)
    finally:
        second.stop()
        first.stop()
