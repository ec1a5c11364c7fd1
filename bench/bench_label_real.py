"""What the labelling page proposes on real Kinect scans, where no truth exists: per frame, the suspect
pixels of each detector, the review groups a person reviews (by source, the largest), and screenshots.

The organized PCDs of the real data folder (docs/real_data.md: ``$ZCUT_REAL_DATA``, default the
folder ``shared/data/real`` beside the checkout) are recorded into one log with ``zcut record`` and served with ``zcut
annotate --port 0 --no-browser`` — without a bin model, since these tabletop scans have no bin; the
folder's ROS 2 log of two mOSD scenes (``mosd_clutter_kinect_ros2.mcap``) is served as it is. The page
is opened in Debian's chromium (Playwright; every request not to 127.0.0.1 is blocked) and shown each
frame in turn.

Printed per frame: its size and valid pixels; the pixels each suspect detector flags
(:data:`zcut.suspects.DETECTORS`, from :func:`zcut.suspects.suspects` run here on the frame with the
inputs the page gives it — and checked against the count the page's bundle carries); the review
groups the page lists (``window.zcut.entries()``; checked against the bundle's group table), per
source (the detector or filter a group was grouped by) and the sizes of the largest; the page's
warning line (the missing bin model) and the profile and 3D read-outs of the largest group.
``--shots DIR`` (outside the repository) saves, per frame, the overview, the height colour map and the
largest group selected (its profile and 3D view). docs/labelling_real.md reports a run.

    .venv/bin/python bench/bench_label_real.py [--work DIR] [--shots DIR] [--viewport 1600x900]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from annotate_helpers import CHROMIUM, CHROMIUM_ARGS  # noqa: E402
from page_helpers import get_bundle, open_page, serving, wait_prepared, wait_until  # noqa: E402

REAL = Path(os.environ.get("ZCUT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
#: The real organized scans, in the order they are recorded (frame i of the log is the i-th found).
PCD_GLOBS = ("mosd_test*.pcd", "table_scene_mug_stereo_textured.pcd", "milk_cartoon_all_small_clorox.pcd",
             "frame_*.pcd")
ROS_LOG = "mosd_clutter_kinect_ros2.mcap"


def pcd_size(path: Path) -> tuple[int, int]:
    """(HEIGHT, WIDTH) of a PCD file's header (HEIGHT 1: not organized)."""
    h = w = 0
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("ascii", "replace").split()
            if not line:
                continue
            if line[0] == "WIDTH":
                w = int(line[1])
            elif line[0] == "HEIGHT":
                h = int(line[1])
            elif line[0] == "DATA":
                break
    return h, w


def real_inputs(real: Path) -> tuple[list[Path], list[str]]:
    """(organized PCDs, names of the left-out ones with why)."""
    pcds, skipped = [], []
    for pattern in PCD_GLOBS:
        for p in sorted(real.glob(pattern)):
            h, w = pcd_size(p)
            if h > 1 and w > 1:
                pcds.append(p)
            else:
                skipped.append(f"{p.name} (not organized: {h} x {w})")
    return pcds, skipped


def record(pcds: list[Path], out: Path) -> None:
    cmd = [sys.executable, "-m", "cli", "record", *map(str, pcds), "-o", str(out), "--force"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"error: zcut record failed ({r.returncode}): {r.stderr.strip()}")


def detector_pixels(log: Path) -> dict[int, dict]:
    """Per frame index: pixels per detector and in all, as :func:`zcut.suspects.suspects` finds them
    with the inputs the page gives it (:func:`annotate.groups.review_groups`)."""
    from replay.pipeline.session import ReplaySession
    from zcut.params import SuspectParams
    from zcut.suspects import DETECTORS, suspects

    session = ReplaySession.open(log)
    params = SuspectParams(a_max=session.config.zcut.a_max)
    out = {}
    results = session.results()
    try:
        for frame, r in results:
            valid = np.asarray(r.valid, bool)
            zone = np.asarray(r.zone, bool) & valid
            easy = np.asarray(r.easy_outliers, bool) & valid
            res = suspects(frame.xyz, np.asarray(r.height_mm, np.float64), zone, easy, params=params)
            det = res.detectors.astype(np.int64)
            out[frame.index] = {"per": {d: int(((det >> i) & 1).sum()) for i, d in enumerate(DETECTORS)},
                                "all": int(res.mask.sum()), "noise_mm": float(res.noise_mm),
                                "tau_mm": float(res.threshold_mm)}
    finally:
        results.close()
    return out


def look(page, base: str, token: str, index: int, shots: Path | None, tag: str) -> dict:
    """Show frame ``index`` on the page; what it lists and says (and screenshots)."""
    from annotate.groups import GCOL

    page.evaluate(f"window.zcut.goTo({index})")
    wait_until(page, f"window.zcut.state() && window.zcut.state().index === {index} && window.zcut.shown === {index}")
    header, arrays = get_bundle(base, token, index)
    table = arrays["group_table"]
    entries = [e for e in page.evaluate("window.zcut.entries()") if e["src"] == "g"]
    sources = [header["group_sources"][int(s)] for s in table[:, GCOL["source"]]]
    listed_sources = Counter(e["source"] for e in entries)
    if listed_sources != Counter(sources):
        raise SystemExit(f"frame {index}: the page lists {dict(listed_sources)}, the bundle holds {dict(Counter(sources))}")
    warn = page.inner_text("#framewarn") if page.is_visible("#framewarn") else ""
    from annotate.budget import review_budget
    from zcut.params import SuspectParams

    row = {"groups": len(entries), "n_groups": header["n_groups"], "by_source": dict(Counter(sources)),
           "budget": review_budget(SuspectParams(), len(header["methods"])),
           "largest": sorted((int(n) for n in table[:, GCOL["n"]]), reverse=True)[:5],
           "singletons": int((table[:, GCOL["n"]] == 1).sum()),
           "n_valid": header["n_valid"], "size": (header["height"], header["width"]),
           "n_suspect_px": header["n_suspect_px"], "noise_mm": header["noise_mm"],
           "tau_mm": header["threshold_mm"], "bin_stages": header["bin_stages"], "warning": warn,
           "group_px": int(table[:, GCOL["n"]].sum()) if len(table) else 0}
    if shots is not None:
        page.wait_for_timeout(300)
        page.screenshot(path=str(shots / f"{tag}_overview.png"))
        page.keyboard.press("h")
        page.wait_for_timeout(600)
        page.screenshot(path=str(shots / f"{tag}_height.png"))
        page.keyboard.press("h")
        page.wait_for_timeout(300)
    if entries:
        all_entries = page.evaluate("window.zcut.entries()")
        k = max((i for i, e in enumerate(all_entries) if e["src"] == "g"), key=lambda i: all_entries[i]["n"])
        n_views = page.evaluate("window.zcut.viewTimes.length")
        page.click(f"#candlist .cand[data-k='{k}']")
        wait_until(page, f"window.zcut.viewTimes.length > {n_views}")
        page.wait_for_timeout(300)
        row["selected"] = page.inner_text(f"#candlist .cand[data-k='{k}']").replace("\n", " ").replace("\t", " ")
        row["why"] = page.get_attribute(f"#candlist .cand[data-k='{k}']", "title")
        row["profile"] = page.evaluate("window.zcut.profileInfo()")
        row["view3d"] = page.inner_text("#v3info")
        if shots is not None:
            page.screenshot(path=str(shots / f"{tag}_largest_group.png"))
    return row


def run_log(log: Path, names: dict[int, str], db: Path, browser, shots: Path | None, viewport, tag: str) -> list[dict]:
    print(f"{log.name}: suspects per detector ...", flush=True)
    t0 = time.process_time()
    dets = detector_pixels(log)
    print(f"  {len(dets)} frames in {time.process_time() - t0:.1f} s CPU", flush=True)
    rows = []
    with serving(log, db) as (base, token):
        print(f"{log.name}: server prepared the frames in {wait_prepared(base, token):.0f} s", flush=True)
        errors: list[str] = []
        page, blocked = open_page(browser, base, token, viewport, errors)
        frames = httpx.get(f"{base}/api/frames", headers={"X-Zcut-Token": token}, timeout=60).json()["frames"]
        for f in frames:
            i = f["index"]
            r = look(page, base, token, i, shots, f"{tag}_f{i}")
            d = dets[i]
            if d["all"] != r["n_suspect_px"]:
                raise SystemExit(f"{log.name} frame {i}: {d['all']} suspect px here, {r['n_suspect_px']} on the page")
            rows.append({"log": log.name, "frame": i, "name": names.get(i, f"frame {i}"), "det": d["per"], **r})
            print(f"  frame {i} ({rows[-1]['name']}): {r['groups']} groups {r['by_source']}, largest {r['largest']}; "
                  f"largest: {r.get('why', '-')}; profile: {r.get('profile', '-')}; "
                  f"3D: {r.get('view3d', '-')}", flush=True)
        if blocked:
            print(f"  blocked requests: {blocked}")
        if errors:
            print(f"  page errors: {errors}")
        page.context.close()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_label_real"))
    ap.add_argument("--viewport", default="1600x900")
    ap.add_argument("--shots", type=Path, default=None, help="screenshots of each frame (outside the repository)")
    args = ap.parse_args()
    if not REAL.is_dir():
        raise SystemExit(f"error: real data folder not found: {REAL}; docs/real_data.md lists the files and where "
                         "to get them; set ZCUT_REAL_DATA=/path/to/them")
    pcds, skipped = real_inputs(REAL)
    if not pcds:
        raise SystemExit(f"error: no organized PCD in {REAL} (docs/real_data.md lists them)")
    from playwright.sync_api import sync_playwright

    args.work.mkdir(parents=True, exist_ok=True)
    if args.shots is not None:
        args.shots.mkdir(parents=True, exist_ok=True)
    log = args.work / "kinect.mcap"
    record(pcds, log)
    logs = [(log, {i: p.name for i, p in enumerate(pcds)}, "kinect")]
    if (REAL / ROS_LOG).is_file():
        logs.append((REAL / ROS_LOG, {0: "mosd test55 (ROS 2)", 1: "mosd test60 (ROS 2)"}, "ros2"))
    if skipped:
        print(f"left out: {', '.join(skipped)}")
    db = args.work / "labels.sqlite"
    for p in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
        p.unlink(missing_ok=True)
    vp = tuple(int(v) for v in args.viewport.split("x"))
    rows = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for lg, names, tag in logs:
            rows += run_log(lg, names, db, browser, args.shots, vp, tag)
        browser.close()
    from zcut.suspects import DETECTORS

    print()
    print("| log | frame | scan | size | valid px | σ̂ / τ mm | " + " | ".join(DETECTORS)
          + " | suspect px | groups | 1-px groups | by source | largest groups (px) |")
    print("|---|---|---|---|---|---|" + "---|" * len(DETECTORS) + "---|---|---|---|---|")
    for r in rows:
        src = ", ".join(f"{k} {v}" for k, v in sorted(r["by_source"].items(), key=lambda kv: -kv[1]))
        print(f"| {r['log']} | {r['frame']} | {r['name']} | {r['size'][0]} × {r['size'][1]} | {r['n_valid']} | "
              f"{r['noise_mm']:.2f} / {r['tau_mm']:.1f} | " + " | ".join(str(r["det"][d]) for d in DETECTORS)
              + f" | {r['n_suspect_px']} | {r['groups']} | {r['singletons']} | {src} | "
              f"{', '.join(map(str, r['largest']))} |")
    no_bin = [r for r in rows if not r["bin_stages"]]
    said = [r for r in no_bin if "no bin model" in r["warning"]]
    over = [r for r in rows if r["groups"] > r["budget"]]
    print(f"frames: {len(rows)}; groups per frame: min {min(r['groups'] for r in rows)}, "
          f"median {int(np.median([r['groups'] for r in rows]))}, max {max(r['groups'] for r in rows)} "
          f"(the page's budget, {rows[0]['budget']}: {'kept' if not over else f'exceeded on {len(over)} frame(s)'}); "
          f"without bin stages: {len(no_bin)}, the page says 'no bin model' on {len(said)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
