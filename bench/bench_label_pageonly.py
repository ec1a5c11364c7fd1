"""A scripted person that decides **only from what the labelling page shows** (issue 29, "Measure"): zone IoU
of its labels against the paper's truth and the sensor's truth, its inputs per frame, with and without
part models, then the accuracy of the filter bank scored by those labels against the paper's truth.

The rule is docs/labelling.md's "A person who reads only the page" (written before any truth was read,
not tuned). The person reads the rows of the list and the numbers they draw (``window.zcut.entries()``,
``window.zcut.fits()``: the same fields the rows render), the fits line and the rise slider's τ; never the
truth topics nor the generator's metadata. The bench reads the truth only after the label is saved.

For each log (``--logs``: synthetic logs written by ``zcut synth``; seeds no test uses) the page is served
in this process (``annotate.server.open_page`` + the tests' ``LiveServer``), once with the log's part
model and once without (``--modes``; without: :func:`annotate.fits.fitter_for` answers "no part model",
the page's fallback — review groups with their gap to the edge-aware local surface), and driven in
Debian's chromium (Playwright; every request not to 127.0.0.1 blocked), frame after frame. Printed per
frame: inputs (the page's own count), zone IoU of the saved label against ``/ground_truth/off_surface``
(the paper's truth, ``zcut accuracy``'s default) and ``/ground_truth/outliers`` (the sensor's), and the
limit of per-group decisions (each proposal, or each review group without a model, decided by its
majority of the paper's truth). Then ``zcut accuracy LOG --labels DB --annotator page --json`` and
``zcut accuracy LOG --json`` (the paper's truth) for the bank's methods.

Real inputs: ``--kinect`` records the real Kinect-class scans (``$ZCUT_REAL_DATA``; docs/labelling_real.md)
into one log as bench_label_real.py does — no truth, no part model: the fallback, and the counts only (groups,
inputs, what each decision rested on); ``--middlebury SCENES`` turns Middlebury scenes (``$ZCUT_MIDDLEBURY``)
into one log with ``zcut record-stereo``, whose truth is the matcher's errors against the structured-light
disparity (``/ground_truth/outliers``; ``/ground_truth/unknown`` left out of the scores). A log without a part
model runs the fallback only, and its accuracy is scored from the fallback's labels.

``--diagnose LOGS`` (no browser): the rule with a part model emulated on the page's own bundle
(:func:`annotate.fits.fit_frame`, :meth:`annotate.fits.FrameFits.bundle`: the rows' distances and Err), its
label's pixels that are not the paper's truth broken down by cause — instances no fit matches, fitted
instances off their fit (the fit's pose, or Err below the truth's), other fits, the bin, the table, depth
edges — and the truth it misses (docs/labelling.md, "Third round: what the label holds beside the truth").
The scene's true meshes are rebuilt from the log's ``zcut.synth`` record, read only to score.
``--ring-below N`` (``--diagnose`` only) also rejects the proposals of N px or more that nothing around them lies
2 mm below (:func:`below_around`: a cue from the cloud alone, not shown on the page).
``--seed-px N`` (either mode) is the rule's variant that first Ctrl+clicks every proposal of N px or more at its centre,
the largest first, re-reading the list after each seed (:func:`seed_steps`; docs/labelling.md, "Eighth round"): in
the browser real Ctrl+clicks, in ``--diagnose`` the same :meth:`annotate.fits.FrameFits.seeded` the page's Ctrl+click
reaches, and there the rule as written is scored from the same fits in the same run (``--json F`` writes it to F, the
variant to ``F.seedN.json``). Both modes save each label with a part model as
``WORK/<log stem>_f<frame>_<variant>_<emulated|browser>.npy`` (``--work``; :func:`label_file`) so that the browser's label can be checked against the emulated one to the pixel.
``--config TOML`` (``--diagnose`` only) prepares the frames with that pipeline config file instead of the defaults (e.g.
``[removal] straggler_bound = "off"``: the zone of the seventh round's tree; docs/labelling.md, "Ninth round").
Each ``--diagnose`` row also splits the truth the proposals miss by cause (:func:`missed_causes`).
``--fits-cache DIR`` (``--diagnose`` only) pickles each frame's fits in DIR on the first run and scores them from
there on the next ones (:func:`fitted_frames`): one fitting pass for several scorings (``--large-px``,
``--ring-below``, the scoring's own changes).
``--compare BEFORE.json,AFTER.json`` prints two ``--diagnose --json`` files (two trees, the same logs) as one
table, before → after, and the largest cause of each log's wrong pixels in the after file.
``--no-causes`` (``--diagnose`` only) scores each frame without the scene's true surfaces: the IoU, the truth held, the
limit and the inputs, not the causes (the frames the causes are not read on: a held-out set).
``--kinds F1,F2,…`` prints ``--diagnose --json`` files (and their ``.slivers.json``) per kind of frame (the part and the
sensor, the seed: :func:`kinds_summary`): the median and the range over the frames of the IoU with the paper's truth
and the sensor's, the truth held, the limit and the inputs, per variant, the paired changes against a variant
(``--against NAME``), and, where the rows carry them, the wrong label pixels by class summed over the frames
(docs/labelling.md, "Fifteenth round").

    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --logs A.mcap,B.mcap [--modes model,none]
    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --diagnose A.mcap,B.mcap [--json F]
    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --diagnose A.mcap,B.mcap --seed-px N --json F
    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --diagnose A.mcap --config OFF.toml --json F
    cd WORKTREE && .venv/bin/python bench/bench_label_pageonly.py --compare BEFORE.json,AFTER.json
    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --diagnose A.mcap --slivers 150:12:2:8 [--no-causes] --json F
    cd WORKTREE && .venv/bin/python bench/bench_label_pageonly.py --kinds F1,F2 [--against slivers150x12x2x8]
    cd WORKTREE && PYTHONPATH=. .venv/bin/python bench/bench_label_pageonly.py --kinect --middlebury Teddy,Piano
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]  # bench/: page_helpers when imported as a module
from annotate_helpers import CHROMIUM, CHROMIUM_ARGS, LiveServer  # noqa: E402
from page_helpers import get_bundle, open_page, wait_until  # noqa: E402

BANK = "zcut,sor,radius,cluster,speckle,window,mixed_pixel"
K = 3.0  # the paper's k; the page shows its own (the fits line), which the person reads
REJECT = 10.0  # K rejects a fit whose Err exceeds REJECT × the frame's median Err (docs/labelling.md: tuned on seed 7731)
#: ``--large-px N``: the rule's variant that also rejects every proposal of N pixels or more (its row's "N px": a part
#: surface the fits missed); None, the rule as written. Chosen on the tuning seed 7751 (docs/labelling.md, "Sixth round").
LARGE_PX: int | None = None
#: ``--ring-below N`` (``--diagnose`` only: the page does not show it): the variant that also rejects every proposal
#: of N pixels or more that nothing around it lies below — no valid pixel beside it more than :data:`BELOW_MM`
#: farther from the camera than its median depth (a surface patch framed by what occludes it, not one floating
#: off what lies below it). None, the rule as written (docs/labelling.md, "Seventh round").
RING_BELOW: int | None = None
BELOW_MM = 2.0
#: ``--seed-px N``: the rule's variant that, before every other decision, Ctrl+clicks each proposal of N pixels or more
#: at its centre pixel, the largest first, reading the list again after each seed (a pixel is clicked once). None, the
#: rule as written (docs/labelling.md, "Eighth round").
SEED_PX: int | None = None
#: ``--config TOML`` (``--diagnose`` only): the pipeline config file the frames are prepared with (its zone, bin removal
#: and fits' parameters, e.g. ``[removal] straggler_bound = "off"``); None, the defaults (docs/labelling.md, "Ninth round").
CONFIG: Path | None = None
#: ``--fits-cache DIR`` (``--diagnose`` only): each frame's fits pickled there once and read back on later runs
#: (:func:`fitted_frames`); None, fitted on every run.
FITS_CACHE: Path | None = None
#: ``--slivers N:M[:C:R[:S]],…`` (``--diagnose`` only): the sliver pass inside the method (``replay.pipeline.explained``
#: ``SLIVER_MIN_PX`` = N, ``SLIVER_MAX_REGIONS`` = M, ``SLIVER_COARSE`` = C, ``SLIVER_REFINE`` = R, default 0 and
#: 1: every guess iterated in full; ``SLIVER_MAX_SEE_THROUGH`` = S, a share in [0, 1], default the tree's; N = 0: off)
#: scored beside the rule as written, each variant's
#: fits from the same frame and job, the frame's fits and pieces on top computed once (:func:`sliver_variants`); the
#: fits cache is then written with the pass off. None: the tree's defaults (docs/labelling.md, "Fourteenth round").
SLIVERS: list[tuple[float, ...]] | None = None
#: ``--free-space S:A,…`` (with ``--slivers``, one a variant, in order): the pass's regions cut at the scan's depth
#: steps of more than S footprints (``SLIVER_SPLIT_STEPS``; 0: no cut; docs/labelling.md, "Twenty-third round") and,
#: A > 0, a region tried only when it holds A of a whole part's projected area at its depth (``SLIVER_MIN_AREA_SHARE``;
#: "Twenty-fourth round"). A variant's name then ends in ``_free0``, ``sS`` where S > 0 and ``aA`` where A > 0
#: (``_free0s3a0.025``: the names the removed ``I:E:S:A`` form gave at I = 0, E = 0, so earlier rounds' rows compare by
#: name). None: the tree's.
FREE: list[tuple[float, float]] | None = None
#: ``--no-causes`` (``--diagnose`` only): each frame scored without the scene's true surfaces (no cause split)
NO_CAUSES = False


def iou(a: np.ndarray, b: np.ndarray) -> float:
    u = (a | b).sum()
    return float((a & b).sum() / u) if u else 1.0


def truths(log: Path) -> dict[int, dict[str, np.ndarray | None]]:
    """Per frame index: the paper's truth, the sensor's truth (either None where the log lacks it: a stereo
    log's one truth is its measured one, on ``/ground_truth/outliers``; a real scan has none) and the scored
    pixels (valid, not ``/ground_truth/unknown``). Read after the labels are saved."""
    from replay.logs import layout
    from replay.logs.reader import LogReader

    out = {}
    for f in LogReader(log).frames():
        v = np.isfinite(f.xyz).all(axis=2)
        unknown = f.masks.get(layout.TRUTH_UNKNOWN)
        scored = v if unknown is None else v & ~unknown
        paper, sensor = f.masks.get(layout.TRUTH_OFF_SURFACE), f.masks.get(layout.TRUTH_OUTLIERS)
        out[f.index] = {"paper": None if paper is None else paper & scored,
                        "sensor": None if sensor is None else sensor & scored, "scored": scored}
    return out


def has_truth(log: Path) -> bool:
    from replay.logs import layout
    from replay.logs.reader import LogReader

    topics = LogReader(log).mask_topics
    return layout.TRUTH_OFF_SURFACE in topics or layout.TRUTH_OUTLIERS in topics


def click_row(page, k: int) -> None:
    page.click(f"#candlist .cand[data-k='{k}']")


def person_with_model(page) -> dict:
    """docs/labelling.md's rule with a part model: with :data:`SEED_PX`, first the variant's Ctrl+clicks
    (:func:`seed_in_browser`); K (and R) the fits whose Err exceeds 10 × the median Err the fits line shows; R the
    proposals whose shown distance is not above k × their shown Err; Shift+U; Enter."""
    wait_until(page, "window.zcut.fits() && ['ready', 'none', 'error'].includes(window.zcut.fits().status)",
               timeout_s=1800)
    f = page.evaluate("window.zcut.fits()")
    if f["status"] != "ready":
        return {"note": f"no fits: {f['message']}", "rejected_fits": 0, "exceptions": 0}
    seeds = seed_in_browser(page) if SEED_PX is not None else {}
    f = page.evaluate("window.zcut.fits()")
    m = re.search(r"median Err ([0-9.]+) mm", f["info"])
    km = re.search(r"([0-9.]+) × Err", f["info"])
    k = float(km.group(1)) if km else K
    med = float(m.group(1)) if m else float("nan")
    rejected = 0
    for fit in [x for x in f["fits"] if x["err"] > REJECT * med and not x["rejected"]]:
        entries = page.evaluate("window.zcut.entries()")
        j = next(i for i, e in enumerate(entries) if e["src"] == "f" and e["fit"] == fit["fit"])
        click_row(page, j)
        page.keyboard.press("k")
        wait_until(page, f"window.zcut.fits().n_rejected === {rejected + 1}")
        wait_until(page, "window.zcut.state().selected && window.zcut.state().selected.src === 'u'")
        page.keyboard.press("r")  # its pixels: a part, measured, only badly fitted
        rejected += 1
    exceptions = 0
    for _ in range(10_000):
        entries = page.evaluate("window.zcut.entries()")
        j = next((i for i, e in enumerate(entries) if e["src"] == "u" and e["state"] == "undecided"
                  and e["dist"] is not None and not math.isnan(e["dist"])
                  and (not e["dist"] > k * e["err"] or (LARGE_PX is not None and e["n"] >= LARGE_PX))), None)
        if j is None:
            break
        click_row(page, j)
        page.keyboard.press("r")
        exceptions += 1
    page.keyboard.press("Shift+U")
    return {"note": "", "rejected_fits": rejected, "exceptions": exceptions, "median_err": med, **seeds}


def seed_in_browser(page) -> dict:
    """The variant's seeds (:data:`SEED_PX`), by real Ctrl+clicks: while the list holds an undecided proposal of
    ``SEED_PX`` px or more whose centre pixel was not clicked yet, the largest (the first in the list's order among
    equals) has its row clicked (the page centres the view on it) and the pixel holding its centre Ctrl+clicked;
    the bench waits for the page's answer ("seeded n fits" or "no instance found at the click")."""
    clicked: list[tuple[int, int]] = []
    found = 0
    for _ in range(10_000):
        entries = page.evaluate("window.zcut.entries()")
        cand = [(i, e) for i, e in enumerate(entries) if e["src"] == "u" and e["state"] == "undecided"
                and e["fromFit"] < 0 and e["n"] >= SEED_PX and centre_pixel(e["cx"], e["cy"]) not in clicked]
        if not cand:
            break
        j, e = max(cand, key=lambda t: (t[1]["n"], -t[0]))
        click_row(page, j)
        x, y = centre_pixel(e["cx"], e["cy"])
        clicked.append((x, y))
        at = page.evaluate(f"window.zcut.imageToClient({x}, {y})")
        with page.expect_response(lambda r: r.url.endswith("/fits/seed")) as resp:
            page.keyboard.down("Control")
            page.mouse.click(at["x"], at["y"])
            page.keyboard.up("Control")
        n = int(resp.value.headers.get("x-zcut-seeded", "0"))
        found += n > 0
        wait_until(page, "!document.getElementById('savestate').textContent.startsWith('fitting at the click')")
    return {"seeds_clicked": len(clicked), "seeds_found": found, "seed_pixels": clicked}


def centre_pixel(cx: float, cy: float) -> tuple[int, int]:
    """The image pixel (x, y) holding a row's centre (``cx``, ``cy``): the one a Ctrl+click at the centre of the view
    the row click centred hits."""
    return int(math.floor(cx)), int(math.floor(cy))


def person_without_model(page) -> dict:
    """docs/labelling.md's fallback rule: a group is an outlier when its shown gap exceeds 3 × τ (the rise
    slider's starting value), or, with no surface below, when it was grouped as floating or above the rim;
    the larger side in bulk, the other side row by row; Enter."""
    tau = float(page.text_content("#riseval"))
    entries = page.evaluate("window.zcut.entries()")

    def outlier(e: dict) -> bool:
        if e["gap"] is None or math.isnan(e["gap"]):
            return e["source"] in ("floating", "above_rim")
        return abs(e["gap"]) > 3 * tau

    groups = [(i, e) for i, e in enumerate(entries) if e["src"] == "g"]
    out = {e["id"] for _, e in groups if outlier(e)}
    bulk_accept = len(out) >= len(groups) - len(out)
    page.keyboard.press("Shift+A" if bulk_accept else "Shift+R")
    minority = [e["id"] for _, e in groups if (e["id"] in out) != bulk_accept]
    for gid in minority:
        entries = page.evaluate("window.zcut.entries()")
        j = next(i for i, e in enumerate(entries) if e["src"] == "g" and e["id"] == gid)
        click_row(page, j)
        page.keyboard.press("r" if bulk_accept else "a")
    # what the page gave the decision: a gap (a number to compare), or no surface below, where only the
    # group's source (floating / above the rim: outlier; a filter's or a detector's: not) decides
    no_gap = [e for _, e in groups if e["gap"] is None or math.isnan(e["gap"])]
    return {"note": f"τ {tau} mm", "groups": len(groups), "outlier_groups": len(out), "exceptions": len(minority),
            "no_surface": len(no_gap), "no_surface_out": sum(outlier(e) for e in no_gap),
            "near_threshold": sum(1 for _, e in groups if e not in no_gap and 1.5 * tau < abs(e["gap"]) <= 6 * tau),
            "outliers_by": sorted(((e["source"], e["n"], None if e["gap"] is None or math.isnan(e["gap"]) else
                                    round(e["gap"], 1)) for _, e in groups if e["id"] in out), key=lambda t: -t[1])}


def finish(page) -> None:
    n_switch = page.evaluate("window.zcut.switchTimes.length")
    page.keyboard.press("Enter")
    wait_until(page, f"window.zcut.switchTimes.length > {n_switch} || window.zcut.state().nR >= window.zcut.state().nValid")
    wait_until(page, "window.zcut.unsaved().length === 0")


def serve(log: Path, db: Path, annotator: str, with_model: bool) -> LiveServer:
    import annotate.server as server
    from annotate.server import open_page as open_server_page
    from replay.options import PipelineOptions

    if with_model:
        return LiveServer(open_server_page(log, db, annotator=annotator,
                                           choose_bin_model=PipelineOptions().model_chooser()))
    orig = server.fitter_for
    server.fitter_for = lambda *a, **kw: (None, "no part model (bench: the page's fallback)")
    try:
        return LiveServer(open_server_page(log, db, annotator=annotator,
                                           choose_bin_model=PipelineOptions().model_chooser()))
    finally:
        server.fitter_for = orig


def run(log: Path, mode: str, db: Path, browser, viewport, work: Path) -> list[dict]:
    with_model = mode == "model"
    t0 = time.process_time()
    srv = serve(log, db, "page", with_model)
    rows: list[dict] = []
    try:
        assert srv.page.catalogue.wait_until_done(3600)
        page, blocked = open_page(browser, srv.base, srv.token, viewport)
        # the list by score, rows that do not move when the assistant's proposals arrive: the person reads the rows,
        # then clicks one by its index, and a re-sort in between decided another group (docs/labelling_real.md,
        # h/stereo4; the page holds its order only while the pointer is over the list)
        page.select_option("#sortkey", "score")
        n = len(srv.page.catalogue.frames)
        for k in range(n):
            wait_until(page, "window.zcut.state() && window.zcut.state().entries >= 0")
            index = page.evaluate("window.zcut.state().index")
            in0 = page.evaluate("window.zcut.inputs")
            got = person_with_model(page) if with_model else person_without_model(page)
            finish(page)
            got["inputs"] = page.evaluate("window.zcut.inputs") - in0
            rows.append({"log": log.name, "mode": mode, "variant": variant_name(), "frame": index, **got})
            print(f"  {log.name} {mode} frame {index}: {got['inputs']} inputs {got}", flush=True)
            if k + 1 < n:
                wait_until(page, f"window.zcut.state().index !== {index}")
        if blocked:
            print(f"  blocked requests: {blocked}")
        page.context.close()
        # what the page saved and the groups it showed, read back from the server (after the labels)
        for r in rows:
            header, arrays = get_bundle(srv.base, srv.token, r["frame"])
            r["region"] = arrays.get("zone", arrays["valid"])
            _, lab = get_bundle(srv.base, srv.token, r["frame"], "label")
            r["label"] = lab.get("outliers", np.zeros(r["region"].shape, bool))
            if with_model:
                np.save(label_file(work, log, r["frame"], variant_name(), "browser"), r["label"])
                import httpx

                from annotate.payload import parse_bundle

                resp = httpx.get(f"{srv.base}/api/frames/{r['frame']}/fits", headers=srv.headers(), timeout=60)
                fh, fa = parse_bundle(resp.content)
                r["units"] = fa["proposals"].astype(np.int64) if "proposals" in fa else np.zeros(r["region"].shape, np.int64)
            else:
                r["units"] = arrays["groups"].astype(np.int64)
    finally:
        srv.stop()
    print(f"  {log.name} {mode}: {time.process_time() - t0:.0f} CPU-s of this process (server + bench)", flush=True)
    return rows


def score(rows: list[dict], log: Path) -> None:
    """IoU of each saved label with the truths the log has, in the page's zone minus the unscored pixels, and
    the per-proposal limit against the first truth it has (the paper's, else the measured one of a stereo
    log). A log without truth (a real scan) keeps only the counts."""
    tr = truths(log) if has_truth(log) else {}
    for r in rows:
        r.update(iou_paper=None, iou_sensor=None, limit=None, paper_px=None, held=None)
        t = tr.get(r["frame"])
        reg = r["region"]
        L = r["label"] & reg
        r["label_px"] = int(L.sum())
        if t is not None:
            reg = reg & t["scored"]
            L = L & reg
            r["label_px"] = int(L.sum())
            for key in ("paper", "sensor"):
                if t[key] is not None:
                    r[f"iou_{key}"] = iou(L, t[key] & reg)
            P = (t["paper"] if t["paper"] is not None else t["sensor"]) & reg
            u = r["units"]
            n = int(u.max())
            best = np.zeros_like(P)
            if n:
                sz = np.bincount(u.ravel(), weights=reg.ravel(), minlength=n + 1)
                tp = np.bincount(u.ravel(), weights=P.ravel(), minlength=n + 1)
                best = np.isin(u, [g for g in range(1, n + 1) if sz[g] and tp[g] >= 0.5 * sz[g]])
            r.update(limit=iou(best & reg, P), paper_px=int(P.sum()),
                     held=float((P & (u > 0)).sum() / P.sum()) if P.any() else None)
        for key in ("region", "label", "units"):
            del r[key]


def accuracy(log: Path, db: Path | None) -> dict:
    cmd = [sys.executable, "-m", "cli", "accuracy", str(log), "--json", "--methods", BANK]
    if db is not None:
        cmd += ["--labels", str(db), "--annotator", "page"]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed: {p.stderr.strip()[-400:]}")
    return json.loads(p.stdout)


REAL = Path(os.environ.get("ZCUT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
MIDDLEBURY = Path(os.environ.get("ZCUT_MIDDLEBURY", ROOT.parent / "shared" / "data" / "middlebury"))


def kinect_log(work: Path) -> Path:
    """``work/kinect.mcap``: the real organized Kinect-class scans (docs/labelling_real.md) recorded with
    ``zcut record``, as bench_label_real.py records them (no truth, no part model, no bin)."""
    from bench_label_real import real_inputs, record

    if not REAL.is_dir():
        raise SystemExit(f"error: --kinect: {REAL}: no such folder (set ZCUT_REAL_DATA; docs/real_data.md)")
    log = work / "kinect.mcap"
    if not log.exists():
        pcds, skipped = real_inputs(REAL)
        if skipped:
            print(f"left out: {', '.join(skipped)}")
        record(pcds, log)
    return log


def stereo_log(work: Path, scenes: list[str]) -> Path:
    """``work/stereo_<scenes>.mcap``: Middlebury scenes turned into frames by ``zcut record-stereo`` (SGBM's
    cloud, its errors against the structured-light truth on ``/ground_truth/outliers``; docs/real_data.md)."""
    for sc in scenes:
        if not (MIDDLEBURY / sc / "calib.txt").is_file():
            raise SystemExit(f"error: --middlebury: {MIDDLEBURY / sc}: no Middlebury scene there (set ZCUT_MIDDLEBURY)")
    log = work / f"stereo_{'_'.join(scenes)}.mcap"
    if not log.exists():
        cmd = [sys.executable, "-m", "cli", "record-stereo", *(str(MIDDLEBURY / sc) for sc in scenes), "-o", str(log)]
        r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if r.returncode:
            raise SystemExit(f"error: zcut record-stereo failed ({r.returncode}): {r.stderr.strip()[-400:]}")
    return log


def has_part_model(log: Path) -> bool:
    from replay.logs.part_model import carries_part_model
    from replay.logs.reader import LogReader

    return carries_part_model(LogReader(log))


# --------------------------------------------------------------------------------------------------------------
# --diagnose: the person's rule emulated on the page's own bundle (no browser), its label's pixels by cause


def _emulated_person(ff, xyz_mm: np.ndarray, heights: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                                   dict]:
    """(label, proposal ids) the rule of docs/labelling.md gives on the fits ``ff`` (:class:`annotate.fits.FrameFits`),
    read from the same bundle the page draws: the fits whose Err (the fit table's) exceeds :data:`REJECT` × the
    median the fits line shows are rejected and their first proposal rejected; every other proposal is an outlier
    unless its median distance is not above k × its Err (or, with :data:`LARGE_PX`, it has that many pixels or more)."""
    errs = sorted(float(f["err_mm"]) for f in ff.fits)
    med = errs[len(errs) >> 1] if errs else float("nan")
    rejected = {i for i, f in enumerate(ff.fits) if float(f["err_mm"]) > REJECT * med}
    col, ids = proposals_of(ff, xyz_mm, heights, valid, rejected)
    table = col["id"]
    below = below_around(ids, len(table), xyz_mm[..., 2], valid) if RING_BELOW is not None else None
    out = np.ones(len(table) + 1, bool)
    out[0] = False
    seen: set[int] = set()
    exceptions = 0
    for j in range(len(table)):
        f = int(col["fit"][j])
        if f >= 0 and f not in seen:  # K's proposal, selected at once: R
            seen.add(f)
            out[j + 1] = False
            continue
        d, e = col["dist_mm"][j], col["err_mm"][j]
        if not np.isnan(d) and (not d > ff.k * e or (LARGE_PX is not None and col["n"][j] >= LARGE_PX)):
            out[j + 1] = False
            exceptions += 1
        elif below is not None and RING_BELOW is not None and col["n"][j] >= RING_BELOW and not below[j + 1]:
            out[j + 1] = False
            exceptions += 1
    # the rule's inputs: Shift+U and Enter, a row click, K and R per rejected fit, a row click and R per exception
    return out[ids], ids, {"rejected_fits": len(rejected), "proposals": len(table),
                           "accepted": int(out[1:].sum()), "median_err": med,
                           "inputs": 2 + 3 * len(rejected) + 2 * exceptions}


def proposals_of(ff, xyz_mm: np.ndarray, heights: np.ndarray, valid: np.ndarray,  # type: ignore[no-untyped-def]
                 rejected: set[int]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The proposals the page draws from the fits ``ff`` with ``rejected`` fits (:meth:`annotate.fits.FrameFits.bundle`,
    parsed as the page parses it): their table's columns (:data:`annotate.fits.PROPOSAL_COLUMNS`, float64 of the
    bundle's float32) and their (H, W) id image (0 none, j + 1 the table's row j)."""
    from annotate.payload import parse_bundle

    H, W = valid.shape
    header, arrays = parse_bundle(ff.bundle(heights_mm=heights, valid=valid, rejected=rejected, header={},
                                            xyz_mm=xyz_mm))
    cols = header["proposal_columns"]
    table = np.asarray(arrays["proposal_table"]).reshape(-1, len(cols)) if "proposal_table" in arrays else \
        np.zeros((0, len(cols)))
    ids = np.asarray(arrays["proposals"], np.int64).reshape(H, W) if "proposals" in arrays else np.zeros((H, W), np.int64)
    return {c: table[:, i].astype(np.float64) for i, c in enumerate(cols)}, ids


def next_seed(col: dict[str, np.ndarray], clicked: Sequence[tuple[int, int]], min_px: int) -> tuple[int, int, int] | None:
    """The proposal the variant Ctrl+clicks next on the list ``col`` (:func:`proposals_of`, nothing decided yet):
    the largest undecided one of ``min_px`` px or more, not from a rejected fit, whose centre pixel is not in
    ``clicked``, the first in the list's order among equals (the page lists proposals farthest first, one with no
    distance first of all, then by ``cy``, then ``cx``): (x, y, its px), or None."""
    n = col["n"]
    if not n.size:
        return None
    far = np.where(np.isnan(col["dist_mm"]), 1e3, col["dist_mm"])  # the page's score: 1e6 + dist, no distance 1e3
    done = set(clicked)
    for j in np.lexsort((col["cx"], col["cy"], -far, -n)):
        if n[j] < min_px:
            return None
        x, y = centre_pixel(col["cx"][j], col["cy"][j])
        if col["fit"][j] < 0 and (x, y) not in done:
            return x, y, int(n[j])
    return None


@dataclass(frozen=True)
class SeedStep:
    """One state of :func:`seed_steps`: the fits after the seeds so far, the pixels clicked (in order), how many
    of those clicks found an instance, the CPU-s of the refits (:meth:`annotate.fits.FrameFits.seeded`) and of the
    list's re-reads (:meth:`annotate.fits.FrameFits.bundle`) so far, and the size of the proposal the next click
    would take (0: none left)."""

    ff: Any
    clicked: tuple[tuple[int, int], ...]
    found: int
    cpu_refit: float
    cpu_reread: float
    next_px: int


def seed_steps(ff, xyz_mm: np.ndarray, heights: np.ndarray, valid: np.ndarray, config: Any,  # type: ignore[no-untyped-def]
               min_px: int) -> Iterator[SeedStep]:
    """The variant's seeds emulated (:data:`SEED_PX`): the state before the first click, then after each Ctrl+click
    of :func:`next_seed` on the list re-read after every seed that found an instance (one that found nothing leaves
    the fits, so the list, as they were), through the same :meth:`annotate.fits.FrameFits.seeded` the page's
    Ctrl+click reaches (:meth:`annotate.fits.Fitter.seed`). The clicks of a larger ``min_px`` are a prefix of a
    smaller one's: a run stops where the next proposal is below its ``min_px``."""
    clicked: list[tuple[int, int]] = []
    found, cpu_refit, cpu_reread = 0, 0.0, 0.0
    t = time.process_time()
    col, _ = proposals_of(ff, xyz_mm, heights, valid, set())
    cpu_reread += time.process_time() - t
    while True:
        nxt = next_seed(col, clicked, min_px)
        yield SeedStep(ff, tuple(clicked), found, cpu_refit, cpu_reread, 0 if nxt is None else nxt[2])
        if nxt is None:
            return
        x, y, _ = nxt
        clicked.append((x, y))
        t = time.process_time()
        got = ff.seeded(x, y, xyz_mm, config)
        cpu_refit += time.process_time() - t
        if got is not ff:
            found += 1
            ff = got
            t = time.process_time()
            col, _ = proposals_of(ff, xyz_mm, heights, valid, set())
            cpu_reread += time.process_time() - t


def below_around(ids: np.ndarray, n: int, z_mm: np.ndarray, valid: np.ndarray, *, drop_mm: float = BELOW_MM
                 ) -> np.ndarray:
    """(n + 1,) bool: proposal j (of the id image ``ids``, 0 none) has a valid 8-neighbour not its own lying more
    than ``drop_mm`` farther from the camera (``z_mm``, the depth) than its median depth. Reads the cloud only."""
    from scipy import ndimage

    out = np.zeros(n + 1, bool)
    if not n:
        return out
    z = np.where(valid, z_mm, np.nan)
    med = np.zeros(n + 1)
    med[1:] = ndimage.median(np.nan_to_num(z), ids, index=np.arange(1, n + 1))
    H, W = ids.shape
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if not (dy or dx):
                continue
            a = ids[max(0, -dy):H - max(0, dy), max(0, -dx):W - max(0, dx)]
            zb = z[max(0, dy):H - max(0, -dy), max(0, dx):W - max(0, -dx)]
            b = ids[max(0, dy):H - max(0, -dy), max(0, dx):W - max(0, -dx)]
            with np.errstate(invalid="ignore"):
                hit = (a > 0) & (b != a) & (zb > med[a] + drop_mm)
            out[np.unique(a[hit])] = True
    return out


def _true_surfaces(log: Path, frame):  # type: ignore[no-untyped-def]
    """The scene's true surfaces (tests/explained_helpers.py) of a synthetic frame, rebuilt from the log's
    ``zcut.synth`` record (kind, seed, size, generator): read only to score."""
    from types import SimpleNamespace

    from explained_helpers import handmade_true_surfaces, raytraced_true_surfaces

    from replay.logs import layout
    from replay.logs.reader import LogReader

    meta = LogReader(log).metadata[layout.SYNTH_METADATA]
    kind, seed = meta["part_kind"], int(meta["seed"])
    size = (int(meta["height"]), int(meta["width"]))
    if meta.get("sensor") == "raytraced":
        from replay.synth.raytrace import synthesize as rs
        from replay.synth.synthesize import bin_pose_for, frame_rng

        pose = bin_pose_for(frame_rng(seed, frame.index, empty=False), empty=False, index=frame.index)
        rng = rs.raytrace_rng(seed, frame.index, empty=False)
        fill = float(rng.uniform(*rs.FILL_RANGE_MM))
        heap = rs.drop_parts(kind, pose, rng, count=min(rs.part_count(kind, fill), rs.MAX_PARTS))
        return raytraced_true_surfaces(SimpleNamespace(pile=heap), seed=seed, index=frame.index)  # type: ignore[arg-type]
    from replay.synth.synthesize import synthesize_frame

    sf = synthesize_frame(kind=kind, seed=seed, index=frame.index, size=size)
    return handmade_true_surfaces(sf)


def diagnose(log: Path, work: Path) -> tuple[list[dict], list[dict]]:
    """The person's label on every frame of ``log`` (the rule emulated on the page's bundle) broken down by cause,
    the truth read only to score: label pixels that are truth; label pixels that are not, by the true surface
    they lie on — an instance no fit matches (its centre within a quarter of the part's size of no fit's), a
    fitted instance (farther than k × Err from its fit: the true surface within k × the page's Err — the fit's
    pose is off; not — the page's Err is below the truth's; and of those, at a depth edge), the bin or table;
    the truth the proposals miss (in a fit's pixels; elsewhere) and the truth in proposals the rule rejected.
    Returns the rows of the rule as written and, with :data:`SEED_PX`, those of the variant from the same fits (its
    seeds applied by :func:`seed_steps`; else no rows). Each label is saved in ``work`` (:func:`label_file`)."""
    rows, seeded = [], []
    with shared_fits() if SLIVERS is not None else contextlib.nullcontext():
        for frame, job, ff, cpu, config in fitted_frames(log):
            rows.append(diagnose_frame(log, frame, job, ff, cpu, work=work))
            print(json.dumps(rows[-1], indent=1, default=float), flush=True)
            if SLIVERS is not None:
                for name, vff, vcpu, pass_cpu in sliver_variants(log, frame, job, SLIVERS, free=FREE):
                    row = diagnose_frame(log, frame, job, vff, vcpu, work=work, variant=name)
                    row["cpu_slivers"] = round(pass_cpu, 3)
                    seeded.append(row)
                    print(json.dumps(row, indent=1, default=float), flush=True)
            if SEED_PX is not None:
                valid, xyz, heights = frame_arrays(frame, job)
                *_, last = seed_steps(ff, xyz, heights, valid, config, SEED_PX)
                seeded.append(diagnose_frame(log, frame, job, last.ff, cpu, work=work, seeds=last))
                print(json.dumps(seeded[-1], indent=1, default=float), flush=True)
    return rows, seeded


def fitted_frames(log: Path, frames: Sequence[int] | None = None) -> Iterator[tuple[Any, Any, Any, float, Any]]:
    """(frame, job, fits, CPU-s of :func:`annotate.fits.fit_frame`, the session's config) of the frames ``frames``
    of ``log`` (frame indices; default every one), in log order, prepared and fitted as the page's server does.

    With :data:`FITS_CACHE` each frame's (frame, job, fits, CPU-s) is pickled there when it is fitted
    (``<log stem>_<digest of the log's bytes>_f<frame>.pkl``) and read back on later runs (then the config is None:
    no ``--seed-px`` from a cache), so one fitting pass serves several scorings; a frame without its pickle is fitted
    then, the others read back (the pipeline runs only over the missing frames: each frame's result depends on that
    frame alone: docs/pipeline.md, the session's seed). A run over every frame writes the indices the
    log gave (``<log stem>_<digest>_frames.json``), so that the next such run opens no session. The cache is the
    tree's: a tree whose fits differ needs its own DIR."""
    import hashlib
    import pickle

    from annotate.fits import Job, fit_frame

    base = ""
    cached: dict[int, Path] = {}
    if FITS_CACHE is not None:
        FITS_CACHE.mkdir(parents=True, exist_ok=True)
        with log.open("rb") as fh:
            base = f"{log.stem}_{hashlib.file_digest(fh, 'blake2b').hexdigest()[:16]}"
        for q in FITS_CACHE.glob(f"{base}_f*.pkl"):
            tail = q.stem[len(base) + 2:]
            if tail.isdigit():
                cached[int(tail)] = q
    every = frames is None
    wanted = None if every else sorted({int(i) for i in frames or ()})
    if every and FITS_CACHE is not None:
        with contextlib.suppress(OSError, ValueError, TypeError):
            wanted = sorted(int(i) for i in json.loads((FITS_CACHE / f"{base}_frames.json").read_text()))

    def read(i: int) -> tuple[Any, Any, Any, float, Any]:
        with cached[i].open("rb") as fh:
            frame, job, ff, cpu = pickle.load(fh)
        return frame, job, ff, cpu, None

    if wanted is not None and all(i in cached for i in wanted):
        for i in wanted:
            yield read(i)
        return
    session = pipeline_options().open_session(log)
    if wanted is None:
        n = session.reader.n_frames
        wanted = None if n is None else list(range(n))

    def fitted(frame: Any, r: Any) -> tuple[Any, Any, Any, float, Any]:
        job = Job.of(r)
        t = time.process_time()
        ff = fit_frame(frame, job, session.config, session.prepared.model if session.prepared is not None else None)
        cpu = time.process_time() - t
        if FITS_CACHE is not None:
            with (FITS_CACHE / f"{base}_f{frame.index}.pkl").open("wb") as fh:
                pickle.dump((frame, job, ff, cpu), fh, protocol=pickle.HIGHEST_PROTOCOL)
        return frame, job, ff, cpu, session.config

    given: list[int] = []
    if wanted is None:  # a log without a summary: one pass over every frame, the cached ones not fitted again
        for frame, r in session.results():
            given.append(frame.index)
            yield read(frame.index) if frame.index in cached else fitted(frame, r)
    else:
        i = 0
        while i < len(wanted):
            if wanted[i] in cached:
                given.append(wanted[i])
                yield read(wanted[i])
                i += 1
                continue
            j = i  # a run of consecutive frames without a pickle: one pass of the pipeline
            while j + 1 < len(wanted) and wanted[j + 1] == wanted[j] + 1 and wanted[j + 1] not in cached:
                j += 1
            for frame, r in session.results(frames=(wanted[i], wanted[j] + 1)):
                given.append(frame.index)
                yield fitted(frame, r)
            i = j + 1
    if every and FITS_CACHE is not None:
        (FITS_CACHE / f"{base}_frames.json").write_text(json.dumps(given))


def diag_arguments(description: str) -> argparse.ArgumentParser:
    """The arguments every ``bench/diag_*.py`` takes: the log, ``--fits-cache DIR`` (:data:`FITS_CACHE`),
    ``--frames`` (comma-separated indices, default every one) and ``--json F``; a diagnostic adds its own."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("log", type=Path)
    ap.add_argument("--fits-cache", type=Path, default=None, metavar="DIR")
    ap.add_argument("--frames", default="", help="comma-separated frame indices (default: every one)")
    ap.add_argument("--json", type=Path, default=None)
    return ap


def diag_frames(args: argparse.Namespace) -> Iterator[tuple[Any, Any, Any]]:
    """(frame, job, fits) of the frames :func:`diag_arguments`' ``args`` ask for, fitted only where needed
    (:func:`fitted_frames`, with ``args.fits_cache`` as :data:`FITS_CACHE`)."""
    global FITS_CACHE
    FITS_CACHE = args.fits_cache
    try:
        frames = [int(v) for v in args.frames.split(",") if v.strip()] or None
    except ValueError:
        raise SystemExit(f"--frames: comma-separated frame indices, not {args.frames!r}") from None
    for frame, job, ff, _cpu, _config in fitted_frames(args.log, frames):
        yield frame, job, ff


def _memo(fn: Any, keep: int = 16) -> Any:
    """``fn`` remembering its last ``keep`` results by the digests of its array arguments (one frame's fits, computed
    once for the rule as written and every sliver variant: they come before the pass and do not depend on it; the
    pipeline's own ``explained`` computes them first, for two frames at once and for the pieces on top's own fits too:
    a few frames' worth are kept). Thread-safe."""
    import hashlib
    import threading

    memo: dict[tuple[Any, ...], Any] = {}
    lock = threading.Lock()

    def key(a: Any) -> Any:
        if isinstance(a, np.ndarray):
            return (a.shape, a.dtype.str, hashlib.blake2b(np.ascontiguousarray(a).view(np.uint8)).hexdigest())
        try:
            hash(a)  # parameters (frozen dataclasses), the prepared model (by identity: lru-cached)
        except TypeError:
            return id(a)
        return a

    def wrapped(*args: Any, **kw: Any) -> Any:
        k = (tuple(key(a) for a in args), tuple((n, key(v)) for n, v in sorted(kw.items())))
        with lock:
            if k in memo:
                return memo[k]
        got = fn(*args, **kw)
        with lock:
            memo[k] = got
            while len(memo) > keep:
                memo.pop(next(iter(memo)))
        return got

    return wrapped


class shared_fits:
    """While open, the fits (:func:`zcut.fits.fit_prepared`) and the pieces on top (:func:`zcut.top_pieces.top_pieces`)
    are remembered by their inputs (:func:`_memo`): the same inputs, the same fits, computed once a frame for the
    pipeline's ``explained``, the rule as written and every ``--slivers`` variant."""

    def __enter__(self) -> shared_fits:
        import zcut.fits
        import zcut.top_pieces

        self.saved = (zcut.fits.fit_prepared, zcut.top_pieces.top_pieces)
        zcut.fits.fit_prepared = _memo(zcut.fits.fit_prepared)  # type: ignore[assignment]
        zcut.top_pieces.top_pieces = _memo(zcut.top_pieces.top_pieces)  # type: ignore[assignment]
        return self

    def __exit__(self, *exc: object) -> None:
        import zcut.fits
        import zcut.top_pieces

        zcut.fits.fit_prepared, zcut.top_pieces.top_pieces = self.saved  # type: ignore[assignment]


def sliver_variants(log: Path, frame: Any, job: Any, variants: Sequence[tuple[float, ...]], *,
                    free: Sequence[tuple[float, float]] | None = None) -> Iterator[tuple[str, Any, float, float]]:
    """(name, the page's fits, their CPU-s, the sliver pass's CPU-s) of ``frame`` for each variant (:data:`SLIVERS`):
    :func:`annotate.fits.fit_frame` with the pass's constants set (N, M, C, R, S; S the tree's where a variant gives
    four fields), under :class:`shared_fits` (the caller's): the fits and the pieces on top computed once for all. A
    variant's name is ``slivers`` and its fields joined by ``x`` (``slivers150x12x2x8``, ``slivers150x12x2x8x0.2``).
    With ``free`` (:data:`FREE`, one a variant) each variant's region cut and area floor, its name ending in
    ``_free0[sS][aA]``."""
    import replay.pipeline.explained as rex
    from annotate.fits import fit_frame

    session = pipeline_options().open_session(log)
    bin_model = session.prepared.model if session.prepared is not None else None
    saved = (rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE,
             rex.SLIVER_MAX_SEE_THROUGH, rex._with_slivers)
    saved_free = (rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE)
    if free is not None and len(free) != len(variants):
        raise ValueError(f"--free-space takes one S:A a --slivers variant ({len(variants)}), got {len(free)}")
    spent = [0.0]
    inner = rex._with_slivers

    def timed(*args: Any, **kw: Any) -> Any:
        t = time.process_time()
        try:
            return inner(*args, **kw)
        finally:
            spent[0] += time.process_time() - t

    rex._with_slivers = timed  # type: ignore[assignment]
    try:
        for j, v in enumerate(variants):
            n_px, m, c, r = (int(x) for x in (*v, 0, 1)[:4])
            fj = saved_free if free is None else (float(free[j][0]), float(free[j][1]))
            rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE = fj
            name = sliver_name(v) if free is None else \
                f"{sliver_name(v)}_free0{f's{fj[0]:g}' if fj[0] else ''}{f'a{fj[1]:g}' if fj[1] else ''}"
            rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE = n_px, m, c, r
            rex.SLIVER_MAX_SEE_THROUGH = float(v[4]) if len(v) > 4 else saved[4]
            spent[0] = 0.0
            t = time.process_time()
            ff = fit_frame(frame, job, session.config, bin_model)
            yield name, ff, time.process_time() - t, spent[0]
    finally:
        (rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE, rex.SLIVER_MAX_SEE_THROUGH,
         rex._with_slivers) = saved
        rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE = saved_free


def sliver_name(v: Sequence[float]) -> str:
    """A ``--slivers`` variant's name: ``slivers`` and its fields joined by ``x``, the counts as integers, the share as
    given (``(150, 12, 2, 8)`` → ``slivers150x12x2x8``, ``(150, 12, 2, 8, 0.2)`` → ``slivers150x12x2x8x0.2``)."""
    return "slivers" + "x".join([*(str(int(x)) for x in v[:4]), *(f"{x:g}" for x in v[4:])])


def parse_slivers(text: str) -> list[tuple[float, ...]]:
    """``--slivers``' variants: ``N:M[:C:R[:S]]``, comma-separated (N, M, C, R integers, S a share in [0, 1]).

    Raises
    ------
    ValueError
        One line naming what it got.
    """
    out: list[tuple[float, ...]] = []
    for v in text.split(","):
        if not v:
            continue
        f = v.split(":")
        try:
            ints = tuple(int(x) for x in f[:4])
            share = tuple(float(x) for x in f[4:])
        except ValueError:
            raise ValueError(f"--slivers takes N:M[:C:R[:S]], comma-separated, got {text!r}") from None
        if len(f) not in (2, 4, 5):
            raise ValueError(f"--slivers takes N:M[:C:R[:S]], comma-separated, got {text!r}")
        if ints[0] < 0 or min(ints[1:]) < 0 or ints[1] < 1 or (len(f) >= 4 and ints[3] < 1) or (
                share and not 0.0 <= share[0] <= 1.0):
            raise ValueError(f"--slivers takes N >= 0, M >= 1 (C >= 0, R >= 1, 0 <= S <= 1), got {text!r}")
        out.append((*ints, *share))
    if not out:
        raise ValueError(f"--slivers takes N:M[:C:R[:S]], comma-separated, got {text!r}")
    return out


def parse_free(text: str) -> list[tuple[float, float]]:
    """``--free-space``' variants: ``S:A``, comma-separated (S >= 0 footprints, the regions' cut; A a share of a whole
    part's projected area in [0, 1], their floor).

    Raises
    ------
    ValueError
        One line naming what it got (the removed ``I:E:S:A`` form of the free-space reading too).
    """
    out: list[tuple[float, float]] = []
    for v in text.split(","):
        f = v.split(":")
        if len(f) == 4:
            raise ValueError(f"--free-space takes S:A now: the I:E fields (the free-space reading off the rim and "
                             f"edges) were removed, got {text!r}")
        if len(f) != 2 or not all(x.replace(".", "", 1).isdigit() for x in f) or not float(f[1]) <= 1.0:
            raise ValueError(f"--free-space takes S:A (S >= 0, 0 <= A <= 1), comma-separated, got {text!r}")
        out.append((float(f[0]), float(f[1])))
    return out


def pipeline_options() -> Any:
    """The :class:`replay.options.PipelineOptions` ``--diagnose`` prepares each frame with: the z-cut and
    ``explained`` (the zone, the bin stages and the fits the page's server runs), with :data:`CONFIG`'s pipeline
    config file where ``--config`` gives one."""
    from replay.options import PipelineOptions

    return PipelineOptions(methods="zcut,explained", config=None if CONFIG is None else str(CONFIG))


def sliver_input(ff: Any, zone: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """The sliver pass's input on a frame's fits ``ff``: the unexplained pixels of ``zone`` ((H, W) bool) with the
    sliver fits' own pixels put back (the pass ran on them before they joined the fits); and those fits' indices."""
    H, W = zone.shape
    un = np.zeros(H * W, bool)
    un[ff.un_pix] = True
    sliver_ids = [i for i, f in enumerate(ff.fits) if f.get("sliver")]
    if sliver_ids:
        un[ff.fit_pix[np.isin(ff.fit_of, sliver_ids)]] = True
    return un.reshape(H, W) & zone, sliver_ids


def frame_arrays(frame, job) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """(valid (H, W) bool, xyz (H, W, 3) mm float64, heights (H, W) mm) of a frame as the page's fits read them."""
    valid = np.asarray(job.valid, bool)
    xyz = frame.xyz.astype(np.float64) * 1000.0
    heights = np.where(valid, -1000.0 * frame.xyz[..., 2].astype(np.float64), np.nan)
    return valid, xyz, heights


def variant_name() -> str:
    """The rule as the options set it: ``rule`` (as written) or ``seed<N>`` (``--seed-px N``)."""
    return "rule" if SEED_PX is None else f"seed{SEED_PX}"


def label_file(work: Path, log: Path, frame: int, variant: str, how: str) -> Path:
    """Where a scored label is saved: ``WORK/<log stem>_f<frame>_<variant>_<how>.npy`` (how: ``emulated`` or
    ``browser``), to check the browser's label against the emulated one to the pixel."""
    return work / f"{log.stem}_f{frame}_{variant}_{how}.npy"


def label_scores(label: np.ndarray, ids: np.ndarray, truth: np.ndarray, served: np.ndarray,
                 sensor: np.ndarray | None) -> dict[str, Any]:
    """The scores of a label (``label``, from the proposals ``ids``: 0 none) against the paper's truth ``truth`` and
    the sensor's ``sensor`` (None: not scored), both on the ``served`` pixels: IoU, the truth the proposals hold, the
    per-proposal limit (each proposal decided by the majority of the paper's truth), the label's and the truth's
    pixels. Any of (H, W)."""
    P = np.asarray(truth, bool)
    n = int(ids.max()) + 1 if ids.size else 1
    sz = np.bincount(ids.ravel(), weights=served.ravel(), minlength=n)
    tp = np.bincount(ids.ravel(), weights=P.ravel(), minlength=n)
    majority = (sz > 0) & (tp >= 0.5 * sz)
    majority[0] = False
    return {"iou_sensor": None if sensor is None else iou(label, sensor & served),
            "limit": iou(majority[ids] & served, P), "held": float((P & (ids > 0)).sum() / max(int(P.sum()), 1)),
            "truth": int(P.sum()), "label": int(label.sum()), "label_truth": int((label & P).sum()),
            "iou": iou(label, P), "truth in rejected proposals": int((P & (ids > 0) & ~label).sum()),
            "missed": int((P & (ids == 0)).sum())}


_KIND_MEMO: dict[str, dict[str, Any]] = {}


def log_kind(log: Path) -> dict[str, Any]:
    """``kind`` (the part and the sensor: ``zinc_nuts hand-made``, ``zinc_nuts ray-traced``) and ``seed`` of a
    synthetic log, from its ``zcut.synth`` record; ``kind`` the log's name and ``seed`` None for another log."""
    if str(log) not in _KIND_MEMO:
        from replay.logs import layout
        from replay.logs.reader import LogReader

        meta = LogReader(log).metadata.get(layout.SYNTH_METADATA)
        if meta is None:
            _KIND_MEMO[str(log)] = {"kind": log.stem, "seed": None}
        else:
            sensor = "ray-traced" if meta.get("sensor") == "raytraced" else "hand-made"
            _KIND_MEMO[str(log)] = {"kind": f"{meta['part_kind']} {sensor}", "seed": int(meta["seed"])}
    return _KIND_MEMO[str(log)]


#: the last frame's true surfaces and their nearest-surface image (:func:`diagnose_frame`), by (log, frame index)
_TRUTH_MEMO: dict[tuple[str, int], Any] = {}


def diagnose_frame(log: Path, frame, job, ff, cpu: float, *, work: Path,  # type: ignore[no-untyped-def]
                   seeds: SeedStep | None = None, variant: str | None = None) -> dict:
    """:func:`diagnose` on one frame's fits ``ff`` (:func:`annotate.fits.fit_frame` of ``frame`` and ``job``; with
    ``seeds``, their last step's fits: the variant's)."""
    from replay.logs import layout
    from zcut import explained as ex

    if True:
        valid, xyz, heights = frame_arrays(frame, job)
        H, W = valid.shape
        label, ids, how = _emulated_person(ff, xyz, heights, valid)
        variant = variant or ("rule" if seeds is None else f"seed{SEED_PX}")
        work.mkdir(parents=True, exist_ok=True)
        np.save(label_file(work, log, frame.index, variant, "emulated"), label)
        if seeds is not None:
            how = {**how, "inputs": how["inputs"] + 2 * len(seeds.clicked), "seeds_clicked": len(seeds.clicked),
                   "seeds_found": seeds.found, "seed_pixels": list(seeds.clicked),
                   "cpu_seed_refits": round(seeds.cpu_refit, 2), "cpu_seed_rereads": round(seeds.cpu_reread, 2)}
            cpu += seeds.cpu_refit
        easy = np.asarray(job.removal.easy_outliers, bool) if job.removal is not None else np.zeros((H, W), bool)
        served = (np.asarray(job.zone, bool) | easy) & valid
        label &= served
        # ---- the truth, read only from here on
        truth = frame.masks[layout.TRUTH_OFF_SURFACE] & served
        if NO_CAUSES:
            return {"log": log.name, "frame": frame.index, "variant": variant, **log_kind(log),
                    "cpu_fits": round(cpu, 1), **how, "config": None if CONFIG is None else str(CONFIG),
                    "served": int(served.sum()), "fits": len(ff.fits), **label_scores(label, ids, truth, served,
                                                                                       frame.masks.get(layout.TRUTH_OUTLIERS)),
                    "truth outside the served zone": int((frame.masks[layout.TRUTH_OFF_SURFACE] & valid
                                                          & ~served).sum())}
        key = (str(log), frame.index)
        if key not in _TRUTH_MEMO:  # the variants of one frame are scored against the same truth: rebuilt once
            _TRUTH_MEMO.clear()
            parts, true_s = _true_surfaces(log, frame)
            _TRUTH_MEMO[key] = (parts, ex.nearest_surface(xyz, true_s, where=served))
        parts, near_t = _TRUTH_MEMO[key]
        tcode, tdist = near_t.surface, near_t.dist_mm.astype(np.float64)
        assert ff.part_mesh is not None
        v0 = ff.part_mesh[0]
        size = float(np.linalg.norm(v0.max(axis=0) - v0.min(axis=0)))
        fit_c = np.array([ff.posed(i)[0].mean(axis=0) for i in range(len(ff.fits))]).reshape(-1, 3)
        true_c = np.array([v.mean(axis=0) for v, _ in parts]).reshape(-1, 3)
        if len(fit_c) and len(true_c):
            dd = np.linalg.norm(true_c[:, None, :] - fit_c[None, :, :], axis=2)
            matched = dd.min(axis=1) <= 0.25 * size
            match_of = np.where(matched, dd.argmin(axis=1), -1)
        else:
            matched, match_of = np.zeros(len(true_c), bool), np.full(len(true_c), -1)
        # each pixel's distance to the page's nearest known surface and its Err (the un_* of the unexplained)
        pdist = np.full(H * W, np.nan)
        perr = np.full(H * W, np.nan)
        pcode = np.full(H * W, -9, np.int64)
        pdist[ff.un_pix], perr[ff.un_pix], pcode[ff.un_pix] = ff.un_dist, ff.un_err, ff.un_code
        pdist, perr, pcode = pdist.reshape(H, W), perr.reshape(H, W), pcode.reshape(H, W)
        zz = np.where(valid, xyz[..., 2], np.nan)
        jump = np.zeros((H, W), bool)  # a depth edge: a neighbour (8) invalid or more than 10 footprints off
        pad = np.pad(zz, 1, constant_values=np.nan)
        tol = 10.0 * np.abs(zz) / ff.f_px
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    with np.errstate(invalid="ignore"):
                        jump |= ~(np.abs(pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] - zz) <= tol)
        jump &= valid
        non = label & ~truth
        on_part = non & (tcode >= 0)
        inst = np.where(tcode >= 0, tcode, 0)
        unfitted = on_part & ~matched[inst]
        fitted = on_part & matched[inst]
        own = fitted & (pcode == match_of[inst])
        true_ok = tdist <= ff.k * perr  # the true surface lies within k x the page's Err: the fit's pose is off
        vis = np.bincount(tcode[served & (tcode >= 0)].ravel(), minlength=len(parts))
        full = float(np.percentile(vis[vis > 0], 90)) if (vis > 0).any() else 1.0
        miss = truth & (ids == 0)
        fitpix = np.zeros(H * W, bool)
        fitpix[ff.fit_pix] = True
        fitpix = fitpix.reshape(H, W)
        un_inst = np.flatnonzero(~matched & (vis > 0))
        sensor = frame.masks.get(layout.TRUTH_OUTLIERS)
        P = np.asarray(truth, bool)
        sz = np.bincount(ids.ravel(), weights=served.ravel(), minlength=int(ids.max()) + 1)
        tp = np.bincount(ids.ravel(), weights=P.ravel(), minlength=int(ids.max()) + 1)
        majority = (sz > 0) & (tp >= 0.5 * sz)
        majority[0] = False
        row = {"log": log.name, "frame": frame.index, "variant": variant, **log_kind(log), "cpu_fits": round(cpu, 1),
               **how,
               "config": None if CONFIG is None else str(CONFIG), "served": int(served.sum()),
               "iou_sensor": None if sensor is None else iou(label, sensor & served),
               "limit": iou(majority[ids] & served, P), "held": float((P & (ids > 0)).sum() / max(int(P.sum()), 1)),
               "fits": len(ff.fits), "parts": len(parts), "parts_seen": int((vis > 0).sum()),
               "parts_unfitted_seen": int(un_inst.size),
               "unfitted_visible_share_median": float(np.median(vis[un_inst] / full)) if un_inst.size else None,
               "unfitted_px_in_label_share": float(unfitted.sum() / max(int(vis[un_inst].sum()), 1)),
               "truth": int(truth.sum()), "label": int(label.sum()), "label_truth": int((label & truth).sum()),
               "iou": iou(label, truth),
               "non_truth": int(non.sum()),
               "non: unfitted instance": int(unfitted.sum()),
               "non: fitted inst, nearest is its fit, pose off (true surf within k Err)": int((own & true_ok).sum()),
               "non: fitted inst, nearest is its fit, Err < truth's": int((own & ~true_ok).sum()),
               "  of those at a depth edge": int((own & jump).sum()),
               "non: fitted inst, nearest is another surface": int((fitted & ~own).sum()),
               "non: bin": int((non & (tcode == ex.SURFACE_BIN)).sum()),
               "non: table": int((non & (tcode == ex.SURFACE_TABLE)).sum()),
               "non: at a depth edge (all)": int((non & jump).sum()),
               "truth missed: in a fit's pixels": int((miss & fitpix).sum()),
               "truth missed: elsewhere": int((miss & ~fitpix).sum()),
               "truth in rejected proposals": int((truth & (ids > 0) & ~label).sum()),
               "truth outside the served zone": int((frame.masks[layout.TRUTH_OFF_SURFACE] & valid & ~served).sum()),
               **missed_causes(ff, miss, truth, fitpix, tcode, tdist, match_of, xyz, ids)}
        # the accepted proposals that are mostly not truth: how many and how large
        n = int(ids.max())
        if n:
            sz = np.bincount(ids.ravel(), weights=label.ravel(), minlength=n + 1)
            tp = np.bincount(ids.ravel(), weights=(label & truth).ravel(), minlength=n + 1)
            bad = (sz > 0) & (tp < 0.5 * sz)
            bad[0] = False
            row["accepted mostly non-truth: proposals"] = int(bad.sum())
            row["accepted mostly non-truth: px"] = int(sz[bad].sum())
            row["  of which in proposals >= 50 px"] = int(sz[bad & (sz >= 50)].sum())
    return row


#: the causes of the truth the proposals miss (:func:`missed_causes`), in the order they are assigned
MISSED = {"missed: displaced patch": "in a fit's band, the fit on a displaced patch (its band ≥ half truth)",
          "missed: Err above": "in a fit's band, the fit's k × Err above the truth's distance to its true surface",
          "missed: misposed": "in a fit's band, the fit misposed (the truth beyond k × Err of its true surface)",
          "missed: other instance": "in a fit's band, the fit stands for another instance (or none), misposed",
          "missed: bin or table": "nearest the bin or the table, within k × Err",
          "missed: other": "unexplained but in no proposal"}


def missed_causes(ff, miss: np.ndarray, truth: np.ndarray, fitpix: np.ndarray, tcode: np.ndarray,  # type: ignore[no-untyped-def]
                  tdist: np.ndarray, match_of: np.ndarray, xyz: np.ndarray, ids: np.ndarray) -> dict[str, int]:
    """The served truth no proposal holds (``miss``), each pixel given one cause (:data:`MISSED`), the first that
    applies: inside a fit's band (``fitpix``: its nearest surface a fit, within k × Err) — the fit's band is at least
    half truth (a part model fitted on a displaced patch the truth calls outlier); the pixel lies within the page's
    k × Err of its *true* surface (a fit at the true pose with this Err would explain it too: the Err is above the
    truth's); the fit stands for the pixel's true instance (misposed: the true surface lies beyond k × Err); another
    instance or none. Outside the fits' bands: explained by the bin or the table; else unexplained in no proposal."""
    H, W = miss.shape
    fit_of = np.full(H * W, -1, np.int64)
    fit_of[ff.fit_pix] = ff.fit_of
    fit_of = fit_of.reshape(H, W)
    n = len(ff.fits)
    band_truth = np.bincount(fit_of[fitpix], weights=truth[fitpix], minlength=n)
    band_n = np.bincount(fit_of[fitpix], minlength=n)
    patch = np.zeros(n + 1, bool)
    patch[:n] = (band_n > 0) & (band_truth >= 0.5 * band_n)
    sig = np.asarray(ff.part_err_mm, np.float64)
    f = np.where(fit_of >= 0, fit_of, 0)
    c = np.abs(xyz[..., 2]) / ff.f_px
    err = np.maximum(ff.floor_mm, np.sqrt(sig[f] ** 2 + 0.5 * c * c)) if n else np.full((H, W), np.nan)
    in_band = miss & fitpix
    disp = in_band & patch[np.where(fit_of >= 0, fit_of, n)]
    with np.errstate(invalid="ignore"):
        wide = in_band & ~disp & (tdist <= ff.k * err)
    own_fit = np.where(tcode >= 0, match_of[np.maximum(tcode, 0)] if len(match_of) else -1, -2)
    mis = in_band & ~disp & ~wide & (own_fit == fit_of)
    un = np.zeros(H * W, bool)
    un[ff.un_pix] = True
    un = un.reshape(H, W)
    rest = miss & ~fitpix
    return {"missed: displaced patch": int(disp.sum()), "missed: Err above": int(wide.sum()),
            "missed: misposed": int(mis.sum()), "missed: other instance": int((in_band & ~disp & ~wide & ~mis).sum()),
            "missed: bin or table": int((rest & ~un).sum()), "missed: other": int((rest & un).sum()),
            "missed": int(miss.sum())}


def fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


#: The causes of a label's pixels that are not the paper's truth, as :func:`diagnose_frame` names them (disjoint;
#: with the bin and the table they add up to ``non_truth``), and the short name a table gives each.
CAUSES = {"non: unfitted instance": "unfitted instances",
          "non: fitted inst, nearest is its fit, pose off (true surf within k Err)": "pose off",
          "non: fitted inst, nearest is its fit, Err < truth's": "Err < truth's",
          "non: fitted inst, nearest is another surface": "another surface"}
MISSED_IN_FITS = "truth missed: in a fit's pixels"


def compare(before: list[dict], after: list[dict]) -> list[str]:
    """Markdown lines: the rows of two ``--diagnose`` runs (the same logs and frames, two trees) before → after,
    the third round's columns, and per log the largest cause of the label's pixels that are not truth."""
    def arrow(a: dict, b: dict, key: str, f: str = "{:,}") -> str:
        return f"{f.format(a[key])} → {f.format(b[key])}"

    keyed = {(r["log"], r["frame"]): r for r in before}
    out = ["| log | frame | fits | IoU paper | label px | of it truth | not truth | on unfitted instances (instances) | "
           "pose off | Err < truth's | another surface | truth missed in a fit's pixels | CPU-s of the page's fits |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    largest = []
    for b in after:
        a = keyed.get((b["log"], b["frame"]))
        if a is None:
            raise SystemExit(f"error: --compare: {b['log']} frame {b['frame']} is not in the before file")
        out.append(f"| {b['log']} | {b['frame']} | {arrow(a, b, 'fits')} | {arrow(a, b, 'iou', '{:.3f}')} | "
                   f"{arrow(a, b, 'label')} | {arrow(a, b, 'label_truth')} | {arrow(a, b, 'non_truth')} | "
                   f"{arrow(a, b, 'non: unfitted instance')} ({arrow(a, b, 'parts_unfitted_seen')}) | "
                   + " | ".join(arrow(a, b, k) for k in list(CAUSES)[1:])
                   + f" | {arrow(a, b, MISSED_IN_FITS)} | {arrow(a, b, 'cpu_fits', '{:.1f}')} |")
        top = max(CAUSES, key=lambda k: b[k])
        largest.append(f"{b['log']} frame {b['frame']}: {CAUSES[top]}, {b[top]:,} of {b['non_truth']:,} px not truth "
                       f"({b[top] / max(b['non_truth'], 1):.0%})")
    return [*out, "", "largest cause (after):", *(f"  {v}" for v in largest)]


#: The classes of a label's wrong pixels (:func:`kinds_summary`), each a row key of :func:`diagnose_frame` and its
#: name: the excess (label pixels not the paper's truth; "other" the rest of ``non_truth``) and the missed truth (the
#: served truth not in the label: the rule rejected its proposal, or no proposal holds it, :data:`MISSED`).
EXCESS = {"non: unfitted instance": "excess: on an instance no fit took",
          **{k: f"excess: {v}" for k, v in list(CAUSES.items())[1:]},
          "non: bin": "excess: bin", "non: table": "excess: table"}
MISSED_CLASSES = {"truth in rejected proposals": "missed: in a proposal the rule rejected",
                  "missed: displaced patch": "missed: a fit on a displaced patch",
                  "missed: Err above": "missed: a fit's Err above the truth's",
                  "missed: misposed": "missed: a fit misposed",
                  "missed: other instance": "missed: a fit of another instance",
                  "missed: bin or table": "missed: bin or table",
                  "missed: other": "missed: in no proposal"}


def _med(v: Sequence[float]) -> str:
    """median [min–max] of ``v`` (3 decimals; None values left out; "-" when none is left)."""
    x = [float(a) for a in v if a is not None]
    if not x:
        return "-"
    return f"{float(np.median(x)):.3f} [{min(x):.3f}–{max(x):.3f}]"


def _ints(v: Sequence[float]) -> str:
    x = [int(a) for a in v]
    return f"{int(np.median(x)):,} [{min(x):,}–{max(x):,}]" if x else "-"


def kinds_summary(rows: Sequence[dict], *, against: str | None = None) -> list[str]:
    """Markdown lines: ``--diagnose`` rows (:func:`diagnose_frame`; the rule as written and its variants) per kind of
    frame and seed (:func:`log_kind`) — per variant the median and the range over the frames of the IoU with the
    paper's truth and with the sensor's, the truth held, the per-proposal limit and the inputs; the changes of each
    variant against ``against`` (default: the first variant met), paired by log and frame; and, where the rows carry
    the causes (not ``--no-causes``), the wrong label pixels of ``against``'s rows by class (:data:`EXCESS`,
    :data:`MISSED_CLASSES`), summed over the frames, with the truth outside the served zone beside them."""
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    if not variants:
        return ["(no rows)"]
    ref = against if against is not None else variants[0]
    if ref not in variants:
        raise SystemExit(f"error: --against {ref!r}: no such variant among {', '.join(variants)}")
    groups = list(dict.fromkeys((r["kind"], r["seed"]) for r in rows))
    out: list[str] = []
    for v in variants:
        out += [f"variant {v}:", "| kind | seed | frames | IoU paper | IoU sensor | truth held | limit | inputs | "
                "label px | truth px |", "|---|---|---|---|---|---|---|---|---|---|"]
        for kind, seed in groups:
            g = [r for r in rows if r["variant"] == v and (r["kind"], r["seed"]) == (kind, seed)]
            if g:
                out.append(f"| {kind} | {seed} | {len(g)} | {_med([r['iou'] for r in g])} | "
                           f"{_med([r['iou_sensor'] for r in g])} | {_med([r['held'] for r in g])} | "
                           f"{_med([r['limit'] for r in g])} | {_ints([r['inputs'] for r in g])} | "
                           f"{_ints([r['label'] for r in g])} | {_ints([r['truth'] for r in g])} |")
        out.append("")
    base = {(r["log"], r["frame"]): r for r in rows if r["variant"] == ref}
    for v in variants:
        if v == ref:
            continue
        out += [f"{v} against {ref} (paired by frame; IoU: the medians, then the median and range of the changes):",
                "| kind | seed | frames | median IoU | ΔIoU | Δheld | Δ CPU-s of the method | Δ CPU-s of the pass |",
                "|---|---|---|---|---|---|---|---|"]
        for kind, seed in groups:
            pairs = [(base[(r["log"], r["frame"])], r) for r in rows
                     if r["variant"] == v and (r["kind"], r["seed"]) == (kind, seed) and (r["log"], r["frame"]) in base]
            if not pairs:
                continue
            d = {k: [b[k] - a[k] for a, b in pairs if a.get(k) is not None and b.get(k) is not None]
                 for k in ("iou", "held", "cpu_fits", "cpu_slivers")}
            out.append(f"| {kind} | {seed} | {len(pairs)} | {np.median([a['iou'] for a, _ in pairs]):.3f} → "
                       f"{np.median([b['iou'] for _, b in pairs]):.3f} | "
                       + " | ".join(_med(d[k]) for k in ("iou", "held", "cpu_fits", "cpu_slivers")) + " |")
        out.append("")
    caused = [r for r in rows if r["variant"] == ref and "non_truth" in r]
    if caused:
        cols = {**EXCESS, "excess: other": "excess: other", **MISSED_CLASSES}
        out += [f"the wrong label pixels of {ref} by class, summed over the frames (px, share of the wrong pixels):",
                "| kind | seed | frames | wrong px (excess + missed) | " + " | ".join(cols.values())
                + " | truth outside the served zone |", "|---" * (len(cols) + 5) + "|"]
        for kind, seed in groups:
            g = [r for r in caused if (r["kind"], r["seed"]) == (kind, seed)]
            if not g:
                continue
            tot = {k: sum(int(r.get(k, 0)) for r in g) for k in (*EXCESS, *MISSED_CLASSES, "non_truth", "truth",
                                                                   "label_truth", "truth outside the served zone")}
            tot["excess: other"] = tot["non_truth"] - sum(tot[k] for k in EXCESS)
            wrong = tot["non_truth"] + tot["truth"] - tot["label_truth"]
            out.append(f"| {kind} | {seed} | {len(g)} | {tot['non_truth']:,} + {tot['truth'] - tot['label_truth']:,} | "
                       + " | ".join(f"{tot[k]:,} ({tot[k] / max(wrong, 1):.0%})" for k in cols)
                       + f" | {tot['truth outside the served zone']:,} |")
    return out


def kinds_rows(files: Sequence[Path]) -> list[dict]:
    """The rows of ``--diagnose --json`` files, each with its ``.slivers.json`` where there is one."""
    rows: list[dict] = []
    for f in files:
        if not f.is_file():
            raise SystemExit(f"error: --kinds: {f}: no such file")
        rows += json.loads(f.read_text())
        more = f.with_suffix(".slivers.json")
        if more.is_file():
            rows += json.loads(more.read_text())
    for r in rows:
        if "kind" not in r:
            raise SystemExit(f"error: --kinds: {r.get('log')} frame {r.get('frame')}: a row without its kind "
                             "(written before --kinds existed)")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="", help="comma-separated synthetic logs (zcut synth)")
    ap.add_argument("--kinect", action="store_true", help="also the real Kinect-class scans ($ZCUT_REAL_DATA; no truth)")
    ap.add_argument("--middlebury", default="", help="also these Middlebury scenes, comma-separated ($ZCUT_MIDDLEBURY), "
                    "as one log of zcut record-stereo (their real structured-light truth)")
    ap.add_argument("--modes", default="model,none", help="model (the log's part model), none (the fallback)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_label_pageonly"))
    ap.add_argument("--viewport", default="1600x900")
    ap.add_argument("--no-accuracy", action="store_true", help="skip zcut accuracy from the labels")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    ap.add_argument("--diagnose", default="", metavar="LOGS",
                    help="no browser: the rule emulated on the page's bundle of each log, its label broken down by cause")
    ap.add_argument("--large-px", type=int, default=None, metavar="N",
                    help="the rule's variant: also reject every proposal of N px or more (default: the rule as written)")
    ap.add_argument("--ring-below", type=int, default=None, metavar="N",
                    help="with --diagnose: also reject every proposal of N px or more that nothing around it lies "
                    f"{BELOW_MM:g} mm below (the cue measured in docs/labelling.md, 'Seventh round'; default: off)")
    ap.add_argument("--seed-px", type=int, default=None, metavar="N",
                    help="the rule's variant: first Ctrl+click every proposal of N px or more at its centre, the largest "
                    "first (docs/labelling.md, 'Eighth round'; default: the rule as written, no seeds)")
    ap.add_argument("--config", type=Path, default=None, metavar="TOML",
                    help="with --diagnose: prepare the frames with this pipeline config (e.g. [removal] "
                    "straggler_bound = \"off\"; default: the defaults)")
    ap.add_argument("--fits-cache", type=Path, default=None, metavar="DIR",
                    help="with --diagnose: pickle each frame's fits in DIR on the first run and score them from there "
                    "on the next ones (one fitting pass, several scorings; not with --seed-px or --config)")
    ap.add_argument("--compare", default="", metavar="BEFORE,AFTER",
                    help="two --diagnose --json files (two trees, the same logs): one table, before -> after")
    ap.add_argument("--slivers", default="", metavar="N:M[:C:R[:S]],…",
                    help="with --diagnose: also score the sliver pass inside the method at N px, at most M regions "
                    "(and C coarse ICP iterations for every guess, R guesses refined; default: all; S the largest "
                    "share of a pose's silhouette seen through, default the tree's) (N = 0: off), "
                    "from the same frames; rows in JSON.slivers.json (docs/labelling.md, 'Fourteenth "
                    "round')")
    ap.add_argument("--free-space", default="", metavar="S:A,…",
                    help="with --slivers, one a variant in order: the pass's regions cut at the depth steps of more "
                    "than S footprints (0: no cut) and (A > 0) a region tried only when it holds A of a whole part's "
                    "projected area at its depth (default: the tree's; docs/labelling.md, 'Twenty-third round', "
                    "'Twenty-fourth round')")
    ap.add_argument("--no-causes", action="store_true",
                    help="with --diagnose: score without the scene's true surfaces (no cause split; a held-out set)")
    ap.add_argument("--kinds", default="", metavar="F1,F2,…",
                    help="--diagnose --json files (and their .slivers.json): per kind of frame, the median and range "
                    "of the scores, the changes against a variant, the wrong pixels by class")
    ap.add_argument("--against", default=None, metavar="VARIANT",
                    help="with --kinds: the variant the others are compared with (default: the first; e.g. "
                    "slivers150x12x2x8, the tree's method)")
    args = ap.parse_args()
    if args.kinds:
        print("\n".join(kinds_summary(kinds_rows([Path(v) for v in args.kinds.split(",") if v]),
                                       against=args.against)))
        return 0
    if args.compare:
        files = [Path(v) for v in args.compare.split(",")]
        if len(files) != 2:
            raise SystemExit(f"error: --compare takes BEFORE.json,AFTER.json, got {args.compare!r}")
        print("\n".join(compare(*(json.loads(f.read_text()) for f in files))))
        return 0
    global LARGE_PX, RING_BELOW, SEED_PX, CONFIG, FITS_CACHE, SLIVERS, NO_CAUSES, FREE
    if args.no_causes and not args.diagnose:
        raise SystemExit("error: --no-causes is a --diagnose option")
    NO_CAUSES = args.no_causes
    if args.slivers:
        if not args.diagnose or args.seed_px is not None:
            raise SystemExit("error: --slivers is a --diagnose option, not with --seed-px")
        try:
            SLIVERS = parse_slivers(args.slivers)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
        import replay.pipeline.explained as rex

        rex.SLIVER_MIN_PX = 0  # the rule as written and the fits cache: the method without the pass
    if args.free_space:
        try:
            FREE = parse_free(args.free_space)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
        if SLIVERS is None or len(FREE) != len(SLIVERS):
            raise SystemExit(f"error: --free-space takes one S:A a --slivers variant, got {args.free_space!r}")
    if args.fits_cache is not None:
        if not args.diagnose or args.seed_px is not None or args.config is not None:
            raise SystemExit("error: --fits-cache is a --diagnose option, not with --seed-px or --config")
        FITS_CACHE = args.fits_cache
    LARGE_PX = args.large_px
    RING_BELOW = args.ring_below
    SEED_PX = args.seed_px
    if SEED_PX is not None and SEED_PX < 1:
        raise SystemExit(f"error: --seed-px takes a size of at least 1 px, got {SEED_PX}")
    if RING_BELOW is not None and not args.diagnose:
        raise SystemExit("error: --ring-below is a --diagnose variant (the page does not show the cue)")
    if args.config is not None:
        if not args.diagnose:
            raise SystemExit("error: --config is a --diagnose option (the browser's page serves the defaults)")
        if not args.config.is_file():
            raise SystemExit(f"error: --config: {args.config}: no such file")
        CONFIG = args.config
    if args.diagnose:
        rule, seeded = [], []
        for lg in args.diagnose.split(","):
            if lg:
                a, b = diagnose(Path(lg), args.work)
                rule += a
                seeded += b
        if args.json is not None:
            args.json.write_text(json.dumps(rule, indent=1, default=float))
            if SLIVERS is not None:
                other = args.json.with_suffix(".slivers.json")
                other.write_text(json.dumps(seeded, indent=1, default=float))
                print(f"the rule as written: {args.json}; --slivers: {other}")
            if SEED_PX is not None:
                other = args.json.with_suffix(f".seed{SEED_PX}.json")
                other.write_text(json.dumps(seeded, indent=1, default=float))
                print(f"the rule as written: {args.json}; --seed-px {SEED_PX}: {other} (--compare {args.json},{other})")
        return 0
    from playwright.sync_api import sync_playwright

    logs = [Path(v) for v in args.logs.split(",") if v]
    for lg in logs:
        if not lg.is_file():
            raise SystemExit(f"error: --logs: {lg}: no such file")
    modes = args.modes.split(",")
    if not set(modes) <= {"model", "none"}:
        raise SystemExit(f"error: --modes takes model and/or none, got {args.modes!r}")
    args.work.mkdir(parents=True, exist_ok=True)
    if args.kinect:
        logs.append(kinect_log(args.work))
    if args.middlebury:
        logs.append(stereo_log(args.work, args.middlebury.split(",")))
    if not logs:
        raise SystemExit("error: nothing to label: give --logs, --kinect or --middlebury")
    vp = tuple(int(v) for v in args.viewport.split("x"))
    rows, acc = [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for lg in logs:
            modelled = has_part_model(lg)
            lg_modes = modes if modelled else ["none"]  # a log without a part model has only the fallback
            truth = has_truth(lg)
            by_truth = None
            for mode in lg_modes:
                db = args.work / f"{lg.stem}_{mode}.sqlite"
                for q in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
                    q.unlink(missing_ok=True)
                got = run(lg, mode, db, browser, vp, args.work)
                score(got, lg)
                rows += got
                # accuracy from the labels: with the part model (the target), or the fallback where a log has none
                if not args.no_accuracy and truth and (mode == "model" or not modelled):
                    by_truth = by_truth or accuracy(lg, None)
                    acc.append((lg, mode, accuracy(lg, db), by_truth))
        browser.close()
    print()
    print("| log | part model | frame | inputs | IoU paper's truth | IoU sensor's truth | per-proposal limit | truth held | label px | truth px |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['log']} | {'yes' if r['mode'] == 'model' else 'no'} | {r['frame']} | {r['inputs']} | "
              f"{fmt(r['iou_paper'])} | {fmt(r['iou_sensor'])} | {fmt(r['limit'])} | {fmt(r['held'])} | {r['label_px']} | {r['paper_px']} |")
    print("\ninputs per frame, in the order the page served the frames (a first frame: target ≤ 60; after five: ≤ 20)")
    for key in dict.fromkeys((r["log"], r["mode"]) for r in rows):
        ins = [r["inputs"] for r in rows if (r["log"], r["mode"]) == key]
        late = ins[5:]
        print(f"  {key[0]} {key[1]}: {', '.join(map(str, ins))}; first {ins[0]}"
              + (f"; after five: max {max(late)}" if late else "; fewer than six frames"))
    falls = [r for r in rows if r["mode"] == "none"]
    if falls:
        print("\nthe fallback's groups: what the page gave each decision")
        print("| log | frame | groups | outlier groups | with a gap | gap within 2× of 3τ | no surface below | "
              "of those outliers (floating, above rim) | τ |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in falls:
            if "groups" in r:
                print(f"| {r['log']} | {r['frame']} | {r['groups']} | {r['outlier_groups']} | "
                      f"{r['groups'] - r['no_surface']} | {r['near_threshold']} | {r['no_surface']} | "
                      f"{r['no_surface_out']} | {r['note']} |")
    for lg, mode, by_labels, by_truth in acc:
        print(f"\naccuracy of {lg.name} ({mode}): labels ({by_labels['truth']}) vs {by_truth['truth']}")
        meths = list(by_truth["pooled"])
        fl = {m: by_labels["pooled"][m]["f1"] for m in meths}
        ft = {m: by_truth["pooled"][m]["f1"] for m in meths}
        rl = {m: i + 1 for i, m in enumerate(sorted(meths, key=lambda m: -fl[m]))}
        rt = {m: i + 1 for i, m in enumerate(sorted(meths, key=lambda m: -ft[m]))}
        print("| method | F1 by labels | F1 by truth | Δ | rank by labels | rank by truth |")
        print("|---|---|---|---|---|---|")
        for m in sorted(meths, key=lambda m: rt[m]):
            print(f"| {m} | {fl[m]:.3f} | {ft[m]:.3f} | {fl[m] - ft[m]:+.3f} | {rl[m]} | {rt[m]} |")
        print(f"within ± 0.03: {sum(abs(fl[m] - ft[m]) <= 0.03 for m in meths)} / {len(meths)}; "
              f"same ranking: {'yes' if rl == rt else 'no'}")
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": rows, "accuracy": [
            {"log": str(lg), "mode": mode, "labels": a["pooled"], "truth": b["pooled"], "truth_name": b["truth"]}
            for lg, mode, a, b in acc]}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
