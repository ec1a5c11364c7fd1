"""The page-only person of docs/labelling.md in the browser on a ``zcut record-stereo`` log, the page opened with
filter methods of one's choice — as ``zcut annotate LOG --methods LIST`` opens it (docs/labelling_real.md, "The
sensor's own masks on the page", h/real3).

``bench/bench_label_pageonly.py --middlebury`` opens the page at its default methods; this runs the same person
(its ``run`` and ``score``: chromium, every request not to 127.0.0.1 blocked, the fallback rule on the rows the page
shows) with ``annotate.server.open_page`` given the methods as the command line's layer.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_browser.py --log STEREO.mcap --scenes A,B,…
        --methods zcut,sor,stereo_uniqueness,stereo_speckle,stereo_lr [--work DIR] [--json F]
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, required=True, help="a zcut record-stereo log")
    ap.add_argument("--scenes", default="", help="the scenes' names, in the log's frame order (for the table)")
    ap.add_argument("--methods", default="", help="the page's filter methods (zcut annotate --methods; default: the config's)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_stereo_browser"))
    ap.add_argument("--viewport", default="1600x900")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if not a.log.is_file():
        raise SystemExit(f"error: --log: {a.log}: no such file")
    import bench_label_pageonly as person
    from annotate_helpers import CHROMIUM, CHROMIUM_ARGS
    from playwright.sync_api import sync_playwright

    import annotate.server as server
    from replay.pipeline import config as cfg

    if a.methods:  # the page as `zcut annotate --methods` opens it
        server.open_page = functools.partial(server.open_page, overrides=cfg.cli_layer(methods=a.methods))
    scenes = [s for s in a.scenes.split(",") if s]
    a.work.mkdir(parents=True, exist_ok=True)
    db = a.work / f"{a.log.stem}_none.sqlite"
    for q in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
        q.unlink(missing_ok=True)
    vp = tuple(int(v) for v in a.viewport.split("x"))
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        rows = person.run(a.log, "none", db, browser, vp, a.work)
        person.score(rows, a.log)
        browser.close()
    print("| scene | groups | outlier groups | inputs | held | limit | label px | IoU with the truth |")
    print("|---|---|---|---|---|---|---|---|")
    out = []
    for r in rows:
        name = scenes[r["frame"]] if r["frame"] < len(scenes) else str(r["frame"])
        iou = r.get("iou_sensor", r.get("iou_paper"))
        print(f"| {name} | {r.get('groups', '–')} | {r.get('outlier_groups', '–')} | {r['inputs']} | "
              f"{person.fmt(r['held'])} | {person.fmt(r['limit'])} | {r['label_px']:,} | {person.fmt(iou)} |")
        out.append({"scene": name, **{k: v for k, v in r.items() if isinstance(v, (int, float, str)) or v is None}})
    if a.json:
        a.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
