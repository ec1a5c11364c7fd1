"""Reviewing 1920 x 1200 frames in the labelling page, in headless chromium: inputs and latencies.

Synthesises a log of review scenes (``tests/annotate_helpers.review_frame``: a floor with three
rounded parts and 13 small floating clusters, twelve of them at most 4 pixels, so that at the
overview each is a screen pixel or two), serves it with ``zcut annotate`` and drives Debian's
chromium with Playwright (every request not to 127.0.0.1 is blocked). A scripted person reviews
each frame the way the page is meant to be used: Tab to the first candidate, then A (outlier) or R
(not an outlier) on each of the 13 z-cut candidates — the page moves to the next one and zooms to
it — and Enter to mark the frame reviewed and go on. The script never pans or zooms by hand.

Printed:

- inputs per frame (keys, clicks, wheel and drags the page counted) and pans by hand;
- the time from the key that selects a candidate (``event.timeStamp``) to the animation frame after
  its profile and 3D view were drawn (exact points fetched for its neighbourhood), p50 / p95 against
  the 200 ms target, split into the first candidate of a frame and the others;
- the frame switch (Enter -> the next frame drawn), p50 / p95 against 150 ms;
- the load average (other processes on the machine slow the page down).

``--shots DIR`` also saves a screenshot of each view (overview with markers, candidate selected with
profile and 3D view, height map with the legend and the cursor read-out, a drawn profile line, the
frame list ordered by disagreement, a conflict) into DIR.

    .venv/bin/python bench/bench_label_page.py [--frames 4] [--shots /tmp/page_shots]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# the repository before tests/, whose replay/ and annotate/ folders mirror the packages
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
# the scene the tests review, built the same way, and the browser the tests use
from annotate_helpers import (
    CHROMIUM,
    CHROMIUM_ARGS,
    REVIEW_CLUSTERS,
    write_review_log,
)
from page_helpers import open_page, serving, wait_prepared, wait_until

SELECT_TARGET_MS = 200.0
SWITCH_TARGET_MS = 150.0
INPUTS_TARGET = 20


def stats(name: str, ms: list[float], target: float) -> None:
    a = np.asarray(ms)
    p50, p95 = np.percentile(a, [50, 95])
    print(f"{name:>28}: n={a.size:3d}  p50 {p50:6.1f} ms  p95 {p95:6.1f} ms  max {a.max():6.1f} ms  "
          f"p95/target {p95 / target:.2f}  ({'meets' if p95 <= target else 'MISSES'} the {target:.0f} ms target)")


def review_frame(page, *, dwell_ms: float, shots: Path | None, k_frame: int) -> dict:
    """The scripted person on the current frame; returns its inputs, pans and latencies."""
    inputs0, pans0 = page.evaluate("[window.zcut.inputs, window.zcut.pans]")
    n_views0 = page.evaluate("window.zcut.viewTimes.length")
    index = page.evaluate("window.zcut.state().index")
    page.wait_for_timeout(dwell_ms)
    page.keyboard.press("Tab")
    decided = 0
    for k in range(len(REVIEW_CLUSTERS)):
        wait_until(page, f"window.zcut.viewTimes.length > {n_views0 + k}")
        st = page.evaluate("window.zcut.state()")
        if st["selected"] is None or st["selected"]["src"] != "z":
            raise SystemExit(f"frame {index}: candidate {k} is not a z-cut candidate: {st['selected']}")
        if shots is not None and k_frame == 0 and k == 0:
            page.wait_for_timeout(100)
            page.screenshot(path=str(shots / "02_candidate_profile_3d.png"))
        page.wait_for_timeout(dwell_ms)  # looking at the profile and the 3D view
        page.keyboard.press("a" if k % 3 != 2 else "r")
        decided += 1
    wait_until(page, f"window.zcut.viewTimes.length >= {n_views0 + decided}")
    views = page.evaluate(f"window.zcut.viewTimes.slice({n_views0}, {n_views0 + decided})")
    n_switch = page.evaluate("window.zcut.switchTimes.length")
    page.keyboard.press("Enter")
    wait_until(page, f"window.zcut.switchTimes.length > {n_switch}")
    inputs, pans = page.evaluate("[window.zcut.inputs, window.zcut.pans]")
    return {"inputs": inputs - inputs0, "pans": pans - pans0, "first": views[0]["view3d"],
            "others": [v["view3d"] for v in views[1:]],
            "switch": page.evaluate("window.zcut.switchTimes[window.zcut.switchTimes.length - 1]")}


def take_shots(page, base: str, token: str, shots: Path) -> None:
    """The remaining views, on the current frame."""
    import base64

    import httpx

    page.keyboard.press("f")
    page.wait_for_timeout(200)
    page.screenshot(path=str(shots / "01_overview_markers_minimap.png"))
    page.keyboard.press("h")
    page.keyboard.press("Tab")
    wait_until(page, "window.zcut.state().selected !== null")
    sel = page.evaluate("window.zcut.state().selected")
    pt = page.evaluate(f"window.zcut.imageToClient({sel['x1'] + 3}, {sel['y1'] + 3})")
    page.mouse.move(pt["x"], pt["y"])
    wait_until(page, "window.zcut.readout().includes('height') && !window.zcut.readout().includes('…')")
    page.wait_for_timeout(200)
    page.screenshot(path=str(shots / "03_height_map_legend_readout.png"))
    page.keyboard.press("p")
    a = page.evaluate(f"window.zcut.imageToClient({sel['cx'] - 25}, {sel['cy'] + 15})")
    b = page.evaluate(f"window.zcut.imageToClient({sel['cx'] + 25}, {sel['cy'] - 15})")
    page.mouse.move(a["x"], a["y"])
    page.mouse.down()
    page.mouse.move(b["x"], b["y"], steps=5)
    page.mouse.up()
    page.wait_for_timeout(300)
    page.screenshot(path=str(shots / "04_profile_line.png"))
    page.keyboard.press("v")
    page.keyboard.press("h")
    page.select_option("#orderby", "disagreement")
    page.wait_for_timeout(200)
    page.locator("#side").screenshot(path=str(shots / "05_frame_list_by_disagreement.png"))
    # a conflict: another tab of the same annotator saved this frame meanwhile
    st = page.evaluate("window.zcut.state()")
    h, w = st["H"], st["W"]
    L = np.zeros((h, w), bool)
    L[300:340, 500:540] = True
    from annotate.store import pack_mask

    hdr = {"X-Zcut-Token": token}
    latest = httpx.get(f"{base}/api/frames", headers=hdr).json()["frames"][st["index"]]["revision"]
    body = {"base_revision": latest, "height": h, "width": w, "outliers": base64.b64encode(pack_mask(L)).decode(),
            "reviewed": base64.b64encode(pack_mask(L)).decode()}
    httpx.put(f"{base}/api/frames/{st['index']}/label", json=body, headers=hdr).raise_for_status()
    page.keyboard.press("a")
    wait_until(page, "window.zcut.state().conflict > 0")
    page.keyboard.press("d")
    page.keyboard.press("d")
    page.wait_for_timeout(200)
    page.screenshot(path=str(shots / "06_conflict_difference.png"))
    page.click("#conflict [data-merge=union]")


def loadavg() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4, help="frames to review")
    ap.add_argument("--dwell", type=float, default=150.0, help="ms the person looks before each key")
    ap.add_argument("--viewport", default="1600x900")
    ap.add_argument("--shots", type=Path, default=None, help="save a screenshot of each view here")
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    if args.shots is not None:
        args.shots.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        log = tmp / "review.mcap"
        t0 = time.perf_counter()
        write_review_log(log, frames=args.frames + 1)
        print(f"synthesised {args.frames + 1} review frames of 1920x1200 in {time.perf_counter() - t0:.1f} s")
        with serving(log, tmp / "labels.sqlite") as (base, token):
            print(f"server prepared the candidates in {wait_prepared(base, token):.1f} s")
            load_before = loadavg()
            vw, vh = (int(v) for v in args.viewport.split("x"))
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page, blocked = open_page(browser, base, token, (vw, vh))
                if args.shots is not None:
                    page.wait_for_timeout(300)
                    page.screenshot(path=str(args.shots / "01_overview_markers_minimap.png"))
                per_frame = [review_frame(page, dwell_ms=args.dwell, shots=args.shots, k_frame=k)
                             for k in range(args.frames)]
                errors = page.evaluate("window.zcut.errors")
                if args.shots is not None:
                    take_shots(page, base, token, args.shots)
                browser.close()
    print(f"load average (1/5/15 min) before {load_before}, after {loadavg()} on {os.cpu_count()} cores")
    inputs = [f["inputs"] for f in per_frame]
    pans = sum(f["pans"] for f in per_frame)
    print(f"inputs per frame (13 z-cut candidates, 1920x1200): {inputs} — target <= {INPUTS_TARGET}; "
          f"pans by hand: {pans}")
    print("selecting a candidate -> its profile and 3D view drawn:")
    stats("first candidate of a frame", [f["first"] for f in per_frame], SELECT_TARGET_MS)
    stats("the others", [v for f in per_frame for v in f["others"]], SELECT_TARGET_MS)
    stats("frame switch (Enter)", [f["switch"] for f in per_frame], SWITCH_TARGET_MS)
    if blocked or errors:
        print(f"blocked requests: {blocked}; page errors: {errors}")
    if args.shots is not None:
        print(f"screenshots in {args.shots}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
