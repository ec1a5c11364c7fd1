"""The page's views of the 3D data in the real browser: exact height and xyz under the cursor, the
height legend, the profile with the gap below a cluster, the WebGL 3D view, the minimap, the SOR
size filter and the frame list's counts and order."""

from __future__ import annotations

import re

import cv2
import httpx
import numpy as np
import pytest
from annotate_helpers import (
    ServerProcess,
    close_page,
    open_page,
    wait_until,
    write_review_log,
)

from annotate.groups import GCOL, GROUP_COLUMNS
from annotate.payload import COLUMN, SOURCE_ZCUT, parse_bundle
from replay.logs.reader import LogReader

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("views")
    log = d / "review.mcap"
    write_review_log(log, frames=2, shape=(480, 640))
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice")
    yield srv, log
    srv.stop()


def _image(page, selector) -> np.ndarray:
    png = page.locator(selector).screenshot()
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def test_height_and_xyz_under_the_cursor_and_the_legend(served, browser):
    srv, log = served
    xyz = next(iter(LogReader(log).frames())).xyz
    header, _ = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
    page, errors, blocked = open_page(browser, srv.url)
    try:
        for x, y in [(10, 10), (333, 222), (639, 479)]:
            pt = page.evaluate(f"window.zcut.imageToClient({x}, {y})")
            page.mouse.move(pt["x"], pt["y"])
            wait_until(page, "window.zcut.readout().includes('height') && !window.zcut.readout().includes('…')")
            text = page.evaluate("window.zcut.readout()")
            assert f"row {y} col {x}" in text
            got = dict(re.findall(r"\b(height|x|y|z) (-?[0-9.]+)", text))
            want = {"height": -1000 * float(xyz[y, x, 2]), "x": 1000 * float(xyz[y, x, 0]),
                    "y": 1000 * float(xyz[y, x, 1]), "z": 1000 * float(xyz[y, x, 2])}
            for k, v in want.items():
                assert float(got[k]) == pytest.approx(v, abs=0.006), (k, text)
        assert page.is_hidden("#legend")  # it describes the height map's colours: shown with the map
        page.keyboard.press("h")
        wait_until(page, "!document.getElementById('legend').hidden")
        assert page.text_content("#legendhi") == f"{header['height_hi_mm']:.1f} mm"
        assert page.text_content("#legendlo") == f"{header['height_lo_mm']:.1f} mm"
        bar = _image(page, "#legendbar")
        assert bar[:, bar.shape[1] // 2].std(axis=0).max() > 30  # a colour ramp, not a flat box
        assert not errors and not blocked
    finally:
        close_page(page)


def test_profile_and_3d_view_of_the_selected_cluster(served, browser):
    srv, _ = served
    _, arrays = parse_bundle(httpx.get(f"{srv.base}/api/frames/0/bundle", headers=srv.headers()).content)
    table = arrays["candidates"]
    z = table[table[:, COLUMN["source"]] == SOURCE_ZCUT]
    groups = arrays["group_table"].reshape(-1, len(GROUP_COLUMNS))
    page, errors, blocked = open_page(browser, srv.url, viewport=(1400, 900))
    try:
        blank3d = _image(page, "#view3d")
        page.keyboard.press("Tab")
        wait_until(page, "window.zcut.viewTimes.length === 1")
        st = page.evaluate("window.zcut.state()")
        sel = st["selected"]
        # the list's first row is a review group (z-cut clusters are listed only where no group holds them)
        if sel["src"] == "g":
            gap = float(groups[groups[:, GCOL["id"]] == sel["id"]][0][GCOL["gap_mm"]])
        else:
            gap = float(z[z[:, COLUMN["id"]] == sel["id"]][0][COLUMN["gap_mm"]])
        assert sel["gap"] == pytest.approx(gap)
        info = page.evaluate("window.zcut.profileInfo()")
        assert info.startswith(f"gap {gap:.2f} mm above the surface" if gap >= 0 else f"{-gap:.2f} mm below the surface")
        profile = _image(page, "#profile")
        assert (profile.reshape(-1, 3).std(axis=0) > 10).all()  # axes, points, the gap's arrow
        view3d = _image(page, "#view3d")
        assert np.abs(view3d.astype(int) - blank3d).sum(axis=2).astype(bool).mean() > 0.05
        assert "webgl" in page.text_content("#v3info")
        # the 3D view turns with a drag
        box = page.locator("#view3d").bounding_box()
        page.mouse.move(box["x"] + 100, box["y"] + 100)
        page.mouse.down()
        page.mouse.move(box["x"] + 180, box["y"] + 130, steps=5)
        page.mouse.up()
        assert not np.array_equal(_image(page, "#view3d"), view3d)
        # a profile along a line drawn with the profile tool (P)
        page.keyboard.press("p")
        a = page.evaluate(f"window.zcut.imageToClient({sel['cx'] - 20}, {sel['cy'] - 20})")
        b = page.evaluate(f"window.zcut.imageToClient({sel['cx'] + 20}, {sel['cy'] + 20})")
        page.mouse.move(a["x"], a["y"])
        page.mouse.down()
        page.mouse.move(b["x"], b["y"], steps=4)
        page.mouse.up()
        wait_until(page, f"window.zcut.profileInfo() !== {info!r}")
        assert "mm/px" in page.evaluate("window.zcut.profileInfo()")
        assert not np.array_equal(_image(page, "#profile"), profile)
        assert not errors and not blocked
    finally:
        close_page(page)


def test_minimap_sor_filter_and_frame_list(served, browser):
    srv, _ = served
    frames = httpx.get(f"{srv.base}/api/frames", headers=srv.headers()).json()["frames"]
    page, errors, blocked = open_page(browser, srv.url)
    try:
        # the frame list: candidates, decided, labelled pixels, disagreement per frame
        rows = page.eval_on_selector_all("#framelist li", "els => els.map(e => e.textContent)")
        for f, text in zip(frames, rows):
            assert text.startswith(f"{f['index']}{f['n_groups']} groups0 dec.0 px")  # the review groups
        page.select_option("#orderby", "disagreement")
        order = page.evaluate("window.zcut.state().order")
        assert order == [f["index"] for f in sorted(frames, key=lambda f: (-f["disagreement"], f["index"]))]
        # the SOR size filter changes the SOR overlay, not the list: it holds the review groups (SOR's
        # pixels no group holds are groups of their own, named after the method)
        n5 = page.evaluate("window.zcut.state().entries")
        page.locator("#sormin").fill("1")
        n1 = page.evaluate("window.zcut.state().entries")
        page.locator("#sormin").fill("60")
        n60 = page.evaluate("window.zcut.state().entries")
        assert n1 == n5 == n60 == frames[0]["n_groups"] >= 13
        # the minimap: a click looks there (no panning by hand)
        page.keyboard.press("Tab")
        wait_until(page, "window.zcut.viewTimes.length === 1")
        before = page.evaluate("window.zcut.state()")
        mm = page.locator("#minimap").bounding_box()
        page.mouse.click(mm["x"] + 5, mm["y"] + 5)
        after = page.evaluate("window.zcut.state()")
        assert after["selected"]["screen"] != before["selected"]["screen"] and after["zoom"] == before["zoom"]
        assert page.evaluate("window.zcut.pans") == 0
        assert not errors and not blocked
    finally:
        close_page(page)
