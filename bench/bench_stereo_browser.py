"""The page-only person of docs/labelling.md in the browser on a ``zcut record-stereo`` log, the page opened with
filter methods of one's choice — as ``zcut annotate LOG --methods LIST`` opens it (docs/labelling_real.md, "The
sensor's own masks on the page", h/real3).

``bench/bench_label_pageonly.py --middlebury`` opens the page at its default methods; this runs the same person
(its ``run`` and ``score``: chromium, every request not to 127.0.0.1 blocked, the fallback rule on the rows the page
shows) with ``annotate.server.open_page`` given the methods as the command line's layer.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_browser.py --log STEREO.mcap --scenes A,B,…
        [--methods LIST] [--work DIR] [--json F]

The rows do not move under the person (h/stereo4): the page's list is sorted "assistant least sure first" by default,
and when the assistant's proposals arrive (the server trains it as the labels are saved) the list re-sorts; the
person reads the rows, then clicks a row by its index, and a re-sort between the two decided another group than the
one it meant (PianoL: 17,704 label px where the rule gives 25,091 on the same groups, docs/labelling_real.md). So the
person first sorts the list by score (the page's ``#sortkey``, a real input; the order "auto" gives before any
proposal), and after each frame the bench checks every group's state in the page against the rule's decision
(``misdecided``: must be 0).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]


def rule_outlier(e: dict, tau: float) -> bool:
    """docs/labelling.md's fallback rule on one row of ``window.zcut.entries()`` (``bench_label_pageonly``'s)."""
    if e["gap"] is None or math.isnan(e["gap"]):
        return e["source"] in ("floating", "above_rim")
    return abs(e["gap"]) > 3 * tau


def misdecided(entries: list[dict], tau: float) -> list[int]:
    """The review groups whose state in the page is not the rule's decision (accepted = outlier)."""
    return [e["id"] for e in entries if e["src"] == "g" and (e["state"] == "accepted") != rule_outlier(e, tau)]


def steady_person(person_without_model: Callable[[Any], dict]) -> Callable[[Any], dict]:
    """The page-only person with the list sorted by score first (rows that do not move when the assistant's
    proposals arrive), and the page's decisions checked against the rule's after it."""
    def person(page: Any) -> dict:
        page.select_option("#sortkey", "score")
        got = person_without_model(page)
        tau = float(page.text_content("#riseval"))
        got["misdecided"] = len(misdecided(page.evaluate("window.zcut.entries()"), tau))
        return got
    return person


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

    scenes = [s for s in a.scenes.split(",") if s]
    a.work.mkdir(parents=True, exist_ok=True)
    db = a.work / f"{a.log.stem}_none.sqlite"
    for q in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
        q.unlink(missing_ok=True)
    vp = tuple(int(v) for v in a.viewport.split("x"))
    plain_person, plain_open = person.person_without_model, server.open_page
    person.person_without_model = steady_person(plain_person)
    if a.methods:  # the page as `zcut annotate --methods` opens it
        server.open_page = functools.partial(plain_open, overrides=cfg.cli_layer(methods=a.methods))
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            rows = person.run(a.log, "none", db, browser, vp, a.work)
            person.score(rows, a.log)
            browser.close()
    finally:
        person.person_without_model, server.open_page = plain_person, plain_open
    print("| scene | groups | outlier groups | misdecided | inputs | held | limit | label px | IoU with the truth |")
    print("|---|---|---|---|---|---|---|---|---|")
    out = []
    for r in rows:
        name = scenes[r["frame"]] if r["frame"] < len(scenes) else str(r["frame"])
        iou = r.get("iou_sensor", r.get("iou_paper"))
        print(f"| {name} | {r.get('groups', '–')} | {r.get('outlier_groups', '–')} | {r.get('misdecided', '–')} | {r['inputs']} | "
              f"{person.fmt(r['held'])} | {person.fmt(r['limit'])} | {r['label_px']:,} | {person.fmt(iou)} |")
        out.append({"scene": name, **{k: v for k, v in r.items() if isinstance(v, (int, float, str)) or v is None}})
    if a.json:
        a.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
