"""The review groups in the real page (Debian's chromium, headless, driven by Playwright) and the defects
seen while labelling: counts that agree everywhere, gaps read as words, Shift+A said before it acts,
a frame without bin stages saying why, the 3D panel at 1366 x 768, clusters 50-80 mm above the floor in
the 3D view, the config's notes printed, and unsaved edits surviving a server restart."""

from __future__ import annotations

import dataclasses
import re
import socket

import cv2
import httpx
import numpy as np
import pytest
from annotate_helpers import ServerProcess, close_page, open_page, wait_until, write_spike_log

from annotate.groups import GCOL
from annotate.payload import parse_bundle
from annotate.store import LabelStore, file_sha256

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("groups")
    log = d / "spikes.mcap"
    truths = write_spike_log(log, frames=2, shape=(240, 320), seed=4)
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice")
    yield srv, log, truths
    srv.stop()


def _bundle(srv, i=0):
    return parse_bundle(httpx.get(f"{srv.base}/api/frames/{i}/bundle", headers=srv.headers()).content)


def test_counts_agree_and_gaps_read_as_words(served, browser):
    srv, _, _ = served
    header, arrays = _bundle(srv)
    n = header["n_groups"]
    assert n >= 4
    page, errors, blocked = open_page(browser, srv.url, viewport=(1400, 900))
    try:
        first = page.text_content("#framelist li")
        assert f"{n} groups" in first and "0 dec." in first
        assert page.text_content("#candcount").startswith(f"{n} groups · 0 decided")
        assert f"{n} groups" in page.text_content("#status")
        rows = page.evaluate("window.zcut.entries()")
        assert len(rows) == n and all(r["src"] == "g" and r["source"] for r in rows)
        cells = page.locator("#candlist .cand:not(.head) span:nth-child(3)").all_text_contents()
        for r, cell in zip(rows, cells):
            assert "-" not in cell and "−" not in cell, cell
            assert cell.endswith("up" if r["gap"] >= 0 else "down"), (r, cell)
        # a group below the surface (or the nearest to it) reads "... mm below the surface" in the profile
        k = int(np.argmin([r["gap"] for r in rows]))
        page.click(f"#candlist .cand[data-k='{k}']")
        wait_until(page, f"window.zcut.state().sel === {k} && window.zcut.profileInfo() !== ''")
        wait_until(page, "/(above|below) the surface/.test(window.zcut.profileInfo())")
        info = page.evaluate("window.zcut.profileInfo()")
        gap = rows[k]["gap"]
        assert info.startswith(f"gap {gap:.2f} mm above the surface" if gap >= 0 else f"{-gap:.2f} mm below the surface")
        # decide one: the frame list, the panel and the header still agree
        page.keyboard.press("a")
        wait_until(page, "window.zcut.unsaved().length === 0")
        wait_until(page, "document.querySelector('#framelist li').textContent.includes('1 dec.')")
        assert page.text_content("#candcount").startswith(f"{n} groups · 1 decided")
        assert not errors and not blocked
    finally:
        close_page(page)


def test_the_profile_crosses_a_pixel_of_every_group(tmp_path, browser):
    """A group of scattered specks has nothing at its centre: the default profile line goes through its
    pixel nearest the centre, so the profile shows the group (it showed "gap 0.00 mm" beside an empty
    mark on a real scan's speckle group)."""
    from annotate_helpers import spike_frame

    from replay.logs.writer import LogWriter

    frame, _ = spike_frame(0, shape=(240, 320), seed=8)
    rng = np.random.default_rng(8)
    xyz = frame.xyz.copy()
    for r, c in zip(rng.integers(10, 230, 300), rng.integers(10, 310, 300)):  # specks: more than 40 groups' worth
        xyz[r, c] *= (1.0 - 0.006) / 1.0
    log = tmp_path / "specks.mcap"
    with LogWriter(log) as w:
        w.write_frame(dataclasses.replace(frame, xyz=xyz))
    srv = ServerProcess(log, tmp_path / "labels.sqlite", annotator="alice")
    header, arrays = _bundle(srv)
    ids = arrays["groups"]
    table = arrays["group_table"]
    scattered = [g for g in range(1, header["n_groups"] + 1)
                 if ids[int(table[g - 1, GCOL["cy"]]), int(table[g - 1, GCOL["cx"]])] != g]
    assert scattered  # the frame has groups whose centre is not theirs (what the test is about)
    page, errors, blocked = open_page(browser, srv.url, viewport=(1400, 900))
    try:
        rows = page.evaluate("window.zcut.entries()")
        for k, r in enumerate(rows):
            page.click(f"#candlist .cand[data-k='{k}']")
            wait_until(page, f"window.zcut.state().sel === {k} && window.zcut.state().profile !== null")
            pr = page.evaluate("window.zcut.state().profile")
            assert pr["y0"] == pr["y1"]
            row = ids[pr["y0"], pr["x0"]:pr["x1"] + 1]
            assert (row == r["id"]).any(), (r, pr)
        assert not errors and not blocked
    finally:
        close_page(page)
        srv.stop()


def test_shift_a_says_what_it_will_accept_and_takes_only_the_listed_groups(served, browser):
    srv, _, _ = served
    header, arrays = _bundle(srv, 1)
    ids = arrays["groups"]
    page, errors, blocked = open_page(browser, srv.url + "#1", viewport=(1400, 900))
    try:
        wait_until(page, "window.zcut.state().index === 1")
        page.keyboard.press("2")  # SOR's overlay shown: it is not what Shift+A takes
        hint = page.text_content("#bulkhint")
        m = re.search(r"Shift\+A accepts the (\d+) undecided groups of this list \((\d+) px; not the z-cut or SOR", hint)
        assert m, hint
        want = int((ids > 0).sum())
        assert int(m.group(1)) == header["n_groups"] and int(m.group(2)) == want
        page.keyboard.press("Shift+A")
        wait_until(page, "window.zcut.unsaved().length === 0")
        st = page.evaluate("window.zcut.state()")
        assert st["nL"] == want  # the groups' pixels, not one SOR pixel more
        assert "accepts the 0 undecided groups" in page.text_content("#bulkhint")
        assert not errors and not blocked
    finally:
        close_page(page)


def test_a_frame_without_bin_stages_says_why(served, browser):
    srv, _, _ = served
    page, errors, _ = open_page(browser, srv.url)
    try:
        assert page.is_visible("#framewarn")
        text = page.text_content("#framewarn")
        assert "no RGB image" in text or "no bin model" in text
        assert "--bin-model" in text
    finally:
        close_page(page)


def test_the_3d_panel_fits_1366x768_and_shows_clusters_far_above_the_floor(served, browser):
    """The spikes stand 50-80 mm above the floor: their points are drawn in the 3D view, on screen."""
    srv, _, truths = served
    header, arrays = _bundle(srv)
    ids = arrays["groups"].astype(np.int64)
    table = arrays["group_table"]
    spike = np.unique(ids[truths[0] & (ids > 0)])
    far = [g for g in spike if table[g - 1, GCOL["gap_mm"]] > 45]
    assert far
    page, errors, blocked = open_page(browser, srv.url, viewport=(1366, 768))
    try:
        box = page.locator("#view3d").bounding_box()
        assert box["y"] >= 0 and box["y"] + box["height"] <= 768 and box["height"] >= 120
        rows = page.evaluate("window.zcut.entries()")
        for g in far:
            k = next(i for i, r in enumerate(rows) if r["id"] == g)
            n_views = page.evaluate("window.zcut.viewTimes.length")
            page.click(f"#candlist .cand[data-k='{k}']")
            wait_until(page, f"window.zcut.viewTimes.length > {n_views}")
            page.wait_for_timeout(150)
            wait_until(page, f"window.zcut.state().selected && window.zcut.state().selected.id === {g}")
            img = cv2.imdecode(np.frombuffer(page.locator("#view3d").screenshot(), np.uint8), cv2.IMREAD_COLOR)
            b, gr, r = (img[..., i].astype(int) for i in range(3))
            cyan = (b > 180) & (gr > 180) & (r < 90)  # the group's points, undecided (BGR)
            red = (r > 200) & (gr < 80) & (b < 110)  # ... or accepted by an earlier test
            assert (cyan | red).sum() >= 20, f"group {g}: its points are not in the 3D view"
            # ... and not cut by the view's border: the whole neighbourhood fits (no points on the edges)
            lit = img.max(axis=2) > 60
            assert not (lit[0].any() or lit[-1].any() or lit[:, 0].any() or lit[:, -1].any()), f"group {g}: cut off"
        assert not errors and not blocked
    finally:
        close_page(page)


def test_zcut_annotate_prints_the_resolved_configs_notes(served):
    srv, _, _ = served
    notes = [line for line in srv.stderr_lines if line.startswith("zcut: ")]
    assert any("a_max" in line for line in notes) and any("z-cut" in line for line in notes), srv.stderr_lines


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unsaved_edits_survive_a_server_restart(tmp_path, browser):
    log = tmp_path / "spikes.mcap"
    write_spike_log(log, frames=2, shape=(120, 160), seed=6)
    db = tmp_path / "labels.sqlite"
    port = _free_port()
    srv = ServerProcess(log, db, annotator="alice", extra=("--port", str(port)))
    page, errors, _ = open_page(browser, srv.url)
    try:
        srv.stop()  # the server goes away with the page open
        page.keyboard.press("Tab")
        page.keyboard.press("a")  # an edit the server cannot take
        wait_until(page, "window.zcut.errors.some((e) => e.includes('kept in this browser'))")
        n_l = page.evaluate("window.zcut.state().nL")
        assert n_l > 0
        srv = ServerProcess(log, db, annotator="alice", extra=("--port", str(port)))  # restarted, new token
        wait_until(page, "!document.getElementById('lost').hidden", timeout_s=30)
        text = page.text_content("#lostmsg")
        assert "kept in this browser" in text and f"--port {port}" in text and "frame(s) 0" in text
        page.fill("#lostin", srv.url)
        page.click("#lostform button")
        wait_until(page, "document.getElementById('lost').hidden")
        wait_until(page, "window.zcut.unsaved().length === 0")
        with LabelStore(db) as s:
            lab = s.label(s.frames(s.log_by_sha(file_sha256(log)))[0], annotator="alice")
        assert lab is not None and int(lab.outliers.sum()) == n_l
        # a reload with nothing pending restores nothing
        page.reload()
        wait_until(page, "window.zcut && window.zcut.ready === true")
        assert page.evaluate("window.zcut.restored || []") == []
    finally:
        close_page(page)
        srv.stop()
