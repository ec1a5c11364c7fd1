"""Frame switch time of the labelling page at 1920 x 1200 in headless chromium.

Synthesises a small full-resolution log (or takes one), serves it with ``zcut annotate``, and drives
Debian's chromium with Playwright. The page measures each switch itself with ``performance.now()``:
from the navigation key event (``event.timeStamp``) to the animation frame after the new frame was
drawn. Two cases:

- ``sequential``: the → / ← key with a dwell of ``--dwell`` ms on each frame, as an annotator works
  (the page has prefetched the neighbours meanwhile);
- ``random jump``: ``goTo`` a random frame at least 3 away, i.e. outside the page's cache and
  prefetch radius (one request, JPEG decode and unpacking of the masks all included).

Every request of the browser not to 127.0.0.1 is blocked. Prints p50 / p95 of both against the
150 ms target (issues 6 and 15), the median split of loading one frame and of the switch itself
(wait for the frame, draw the canvas, update the rest of the page, then paint), and the load average
(other processes on the machine slow the page down).

    .venv/bin/python bench/bench_annotate_switch.py [--log LOG.mcap] [--frames 8] [--switches 40] [--jumps 40]
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# the repository before tests/, whose replay/ and annotate/ folders mirror the packages
sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parents[1] / "tests")]
from annotate_helpers import CHROMIUM, CHROMIUM_ARGS
from page_helpers import open_page, serving, wait_prepared, wait_until

TARGET_MS = 150.0


def stats(name: str, ms: list[float]) -> None:
    a = np.asarray(ms)
    p50, p95 = np.percentile(a, [50, 95])
    print(f"{name:>11}: n={a.size:3d}  p50 {p50:6.1f} ms  p95 {p95:6.1f} ms  max {a.max():6.1f} ms  "
          f"p95/target {p95 / TARGET_MS:.2f}  ({'meets' if p95 <= TARGET_MS else 'MISSES'} the {TARGET_MS:.0f} ms target)")


def loadavg() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, default=None, help="a log to serve (default: synthesise 1920x1200 spheres)")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--switches", type=int, default=40, help="sequential switches")
    ap.add_argument("--jumps", type=int, default=40, help="random jumps to frames not prefetched (needs >= 7 frames)")
    ap.add_argument("--dwell", type=float, default=600.0, help="ms spent on a frame before the next key")
    ap.add_argument("--viewport", default="1920x1080")
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        log = args.log
        if log is None:
            from replay.synth.log import write_synthetic_log

            log = tmp / "bench.mcap"
            t0 = time.perf_counter()
            write_synthetic_log(log, kind="spheres", frames=args.frames, seed=7, size=(1200, 1920))
            print(f"synthesised {args.frames} frames of 1920x1200 in {time.perf_counter() - t0:.1f} s")
        with serving(log, tmp / "labels.sqlite") as (base, token):
            t_prep = wait_prepared(base, token)
            load_before = loadavg()
            print(f"server prepared the candidates in {t_prep:.1f} s")
            vw, vh = (int(v) for v in args.viewport.split("x"))
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page, blocked = open_page(browser, base, token, (vw, vh))
                st = page.evaluate("window.zcut.state()")
                print(f"frame {st['W']}x{st['H']} in a {vw}x{vh} viewport")
                n_frames = page.evaluate("document.querySelectorAll('#framelist li').length")

                def switch(action) -> float:
                    before = page.evaluate("window.zcut.switchTimes.length")
                    action()
                    wait_until(page, f"window.zcut.switchTimes.length > {before}")
                    return page.evaluate("window.zcut.switchTimes[window.zcut.switchTimes.length - 1]")

                nxt = []
                direction = 1
                for _ in range(args.switches):
                    cur = page.evaluate("window.zcut.state().index")
                    if not (0 <= cur + direction < n_frames):
                        direction = -direction
                    page.wait_for_timeout(args.dwell)
                    nxt.append(switch(lambda d=direction: page.keyboard.press("ArrowRight" if d > 0 else "ArrowLeft")))
                cold = []
                pick = random.Random(11)
                if n_frames >= 7:
                    for _ in range(args.jumps):
                        # beyond the cache and prefetch radius (2): never prefetched
                        cur = page.evaluate("window.zcut.state().index")
                        target = pick.choice([t for t in range(n_frames) if abs(t - cur) >= 3])
                        page.wait_for_timeout(args.dwell)
                        cold.append(switch(lambda t=target: page.evaluate(f"window.zcut.goTo({t})")))
                loads = page.evaluate("window.zcut.loads")
                parts = page.evaluate("window.zcut.switchParts")
                browser.close()
    print(f"load average (1/5/15 min) before {load_before}, after {loadavg()} on {os.cpu_count()} cores")
    print(f"frame switch, {st['W']}x{st['H']}, from the key event to the next animation frame after drawing:")
    stats("sequential", nxt)
    if cold:
        stats("random jump", cold)
    else:
        print("random jump: skipped (needs >= 7 frames)")
    keys = [k for k in ["worker", "fetch", "parse", "label", "overlay", "main", "image", "wait"] if k in loads[0]]
    med = {k: float(np.median([ld[k] for ld in loads])) for k in keys}
    print("loading one frame (median ms; worker = fetch + parse + label + overlay, then main; "
          "image = fetch + decode of the JPEG in the second worker, in parallel; wait = main waiting for it):")
    print("  " + "  ".join(f"{k} {v:.1f}" for k, v in med.items()))
    keys = ["wait", "canvas", "page", "paint"]
    print("one switch (median ms; wait = for the frame, canvas = image, overlay and markers, page = the lists and "
          "panels, paint = to the next animation frame):")
    print("  " + "  ".join(f"{k} {np.median([q[k] for q in parts]):.1f}" for k in keys))
    if blocked:
        print(f"blocked requests (not to 127.0.0.1): {blocked}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
