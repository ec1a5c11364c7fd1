"""The sweep's plots (studies.plots), findings (studies.findings) and report page (studies.report): real PNG files, one self-contained HTML page,
checked in Debian's chromium (headless, Playwright) with every request off this machine refused.

The summaries are made the way ``zcut sweep`` makes them: per-frame rows written to a real Parquet
file and read back, pooled by ``studies.sweep.pooled_sets`` (bootstrap intervals), tuned by
``studies.sweep.tune``, the sensitivity by ``sensitivity_at``, as a ``studies.summary.SweepSummary``
round-tripped through JSON (NaN and ±inf as null). The counts come from a seeded model of a filter (recall rising with d_max and ρ_thr,
false positives rising with ρ_thr), so that the plots have something to show; the degenerate grids
(one value per axis, no SOR, a_max unknown, nothing flagged, no sets) must give a page, never an error.
"""

from __future__ import annotations

import dataclasses
import html
import json
import math
import tomllib
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from studies import findings, plots, report
from studies.grid import Grid
from studies.scoring import parse_objective
from studies.summary import SweepLog, SweepSummary
from studies.sweep import find_set, find_sor_set, pooled_sets, sensitivity_at, tune

A_MAX = 171.4
NOMINAL = (0.2, 30.0, 0.07)


# ------------------------------------------------------------------------------------ the summaries


def _config_toml(*, sor: bool, a_max: float | None) -> str:
    from replay.pipeline import config as cfg

    z = {"step_mm": 0.2, "max_depth_mm": 30.0}
    if a_max is not None:
        z.update(a_max_px=a_max, max_area_px=0.07 * a_max)
    else:
        z.update(max_area_px=12.0)
    d = {"zcut": z, "sor": {"enabled": sor, "region": "zone"}}
    if a_max is not None:
        d["part"] = "zinc_nuts"
    c = cfg.from_dict(d)
    return cfg.to_toml(c, header="zcut resolved config for <scan & co>.mcap")


def _rows(grid: Grid, *, n_frames: int, sor: bool, a_max: float | None, flag_nothing: bool, seed: int) -> list[dict]:
    """Per-frame rows as ``studies.sweep.sweep_frame`` writes them, counts from a seeded model."""
    rng = np.random.default_rng(seed)
    rows = []
    k0, std0 = grid.chosen[3], grid.chosen[4]

    def sor_rates(k, std):
        return 0.25 * math.exp(-(std - 0.5)) * (1 + 0.05 * k), 900 * math.exp(-1.5 * std) * (1 + 0.1 * k)

    for f in range(n_frames):
        truth = int(rng.integers(300, 600))
        base = {"log": "scan.mcap", "log_sha256": "ab" * 32, "frame": f, "stamp_ns": 1_000_000_000 * f}
        r0, fp0 = sor_rates(k0, std0)
        sor_ref = int(rng.binomial(truth, r0)) + int(rng.poisson(fp0)) if sor else 0
        areas = [(r, r * a_max) for r in grid.rhos] if a_max is not None else [(None, 12.0)]
        for step in grid.steps:
            for depth in grid.depths:
                for rho, area in areas:
                    rel = (rho if rho is not None else 0.07) / 0.08
                    recall = 0.92 * (1 - math.exp(-depth / 22)) * (0.35 + 0.65 * min(1.0, rel)) * (1 - 0.5 * step)
                    tp = 0 if flag_nothing else int(rng.binomial(truth, min(recall, 1.0)))
                    fp = 0 if flag_nothing else int(rng.poisson(2 + 1500 * max(0.0, rel * 0.08 - 0.06) ** 1.5
                                                                + 4 * depth / 30 + 0.5 / step))
                    n_pred = tp + fp + (0 if flag_nothing else int(rng.poisson(15)))
                    both = int(rng.binomial(min(n_pred, sor_ref), 0.35)) if sor else 0
                    rows.append({**base, "method": "zcut", "step_mm": step, "max_depth_mm": depth, "rho_thr": rho,
                                 "max_area_px": area, "sor_k": None, "sor_std_ratio": None, "tp": tp, "fp": fp,
                                 "fn": truth - tp, "n_pred": n_pred, "n_both": both, "n_sor_only": sor_ref - both,
                                 "n_zcut_only": n_pred - both})
        if sor:
            for k in grid.sor_ks:
                for std in grid.sor_stds:
                    r, fpr = sor_rates(k, std)
                    tp = int(rng.binomial(truth, min(r, 1.0)))
                    fp = int(rng.poisson(fpr))
                    rows.append({**base, "method": "sor", "step_mm": None, "max_depth_mm": None, "rho_thr": None,
                                 "max_area_px": None, "sor_k": k, "sor_std_ratio": std, "tp": tp, "fp": fp,
                                 "fn": truth - tp, "n_pred": tp + fp + int(rng.poisson(30)), "n_both": None,
                                 "n_sor_only": None, "n_zcut_only": None})
    return rows


def model_summary(tmp: Path, *, steps=(0.1, 0.2, 0.3), depths=(10.0, 15.0, 20.0, 30.0, 40.0, 45.0, 60.0),
                  rhos=(0.02, 0.035, 0.05, 0.07, 0.09, 0.105, 0.15), sor_ks=(4, 8), sor_stds=(0.5, 1.0, 1.5, 2.0),
                  n_frames=6, sor=True, a_max: float | None = A_MAX, flag_nothing=False, seed=5,
                  objective="f1") -> dict:
    """A sweep summary made as ``zcut sweep`` makes it, from modelled per-frame counts (see the module
    docstring); the rows go through a real Parquet file and the summary through JSON."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    grid = Grid(tuple(steps), tuple(depths), tuple(rhos) if a_max is not None else (), tuple(sor_ks),
                tuple(sor_stds), (0.2, 30.0, 0.07 if a_max is not None else None, 4, 1.0))
    rows = _rows(grid, n_frames=n_frames, sor=sor, a_max=a_max, flag_nothing=flag_nothing, seed=seed)
    path = tmp / "sweep.parquet"
    pq.write_table(pa.Table.from_pylist(rows), path)
    sets = pooled_sets(pq.read_table(path))
    tuned = tune(sets, parse_objective(objective), part="zinc_nuts" if a_max is not None else None)
    rho = 0.07 if a_max is not None else None
    tz = tuned.zcut
    summary = SweepSummary(
        logs=(SweepLog("/data/<scan & co>.mcap", "ab" * 32, None),),
        frames=n_frames, region="zone", objective=objective, truth="synthetic",
        grid=grid, config=_config_toml(sor=sor, a_max=a_max),
        notes=("part: zinc_nuts (from the log's zcut.synth metadata)", "μ_thr = ρ_thr · a_max <b>not bold</b>"),
        sets=tuple(sets), tuned=tuned,
        chosen_zcut=find_set(sets, "zcut", 0.2, 30.0, rho), chosen_sor=find_sor_set(sets, 4, 1.0, 0.2, 30.0),
        nominal=find_set(sets, "zcut", 0.2, 30.0, 0.07) if a_max is not None else None,
        sensitivity_chosen=sensitivity_at(sets, grid.chosen[:3]) if a_max is not None else None,
        sensitivity_tuned=sensitivity_at(sets, (tz.step_mm, tz.max_depth_mm, tz.rho_thr)) if tz else None,
        reproduce="zcut sweep '/data/<scan & co>.mcap' -o out --rho 0.02:0.15:5", seconds=12.5,
    )
    if tz is not None:  # tuned.toml as `zcut sweep` writes it: the config with the tuned parameters
        from replay.pipeline import config as cfg

        base = cfg.from_dict(tomllib.loads(summary.config))
        z = dataclasses.replace(base.zcut, step=tz.step_mm, max_depth=tz.max_depth_mm,
                                max_area=(tz.rho_thr * A_MAX) if tz.rho_thr is not None else tz.max_area_px)
        (tmp / "tuned.toml").write_text(cfg.to_toml(base.replace(zcut=z), header=f"tuned by {objective}"))
    (tmp / "summary.json").write_text(json.dumps(summary.to_json(), allow_nan=False))
    return json.loads((tmp / "summary.json").read_text())


# ----------------------------------------------------------------------------------- page checks


class _Page(HTMLParser):
    """Every tag with its attributes, the section ids, and the text."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)


def page_text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _parse(page: str) -> _Page:
    p = _Page()
    p.feed(page)
    return p


SECTIONS = ("swept", "best", "plots", "findings", "sensitivity", "config", "notes", "reproduce")


def _check_page(path: Path, plot_names: set[str]) -> _Page:
    page = path.read_text(encoding="utf-8")
    p = _parse(page)
    ids = {a.get("id") for _, a in p.tags}
    assert set(SECTIONS) <= ids
    imgs = [a for t, a in p.tags if t == "img"]
    assert len(imgs) == len(plot_names)
    for a in imgs:
        assert a["src"].startswith("data:image/png;base64,") and a.get("alt")
    # nothing to fetch: no script, no stylesheet link, no URL other than in-page anchors and data:
    assert not [t for t, _ in p.tags if t in ("script", "link", "iframe", "object", "embed")]
    for t, a in p.tags:
        for k in ("src", "href"):
            if k in a:
                assert a[k].startswith(("data:", "#")), (t, a[k][:60])
    # the summary's texts are escaped (the log name and a note carry markup)
    assert "<scan & co>" not in page and "&lt;scan &amp; co&gt;" in page
    assert "<b>not bold</b>" not in page and "&lt;b&gt;not bold&lt;/b&gt;" in page
    return p


# --------------------------------------------------------------------------------------- the tests


def test_report_writes_every_plot_and_one_self_contained_page(tmp_path):
    import matplotlib.image

    summary = model_summary(tmp_path)
    path = report.write_report(tmp_path, summary)
    assert path == tmp_path / "report.html"
    pngs = {p.name for p in (tmp_path / "plots").glob("*.png")}
    assert pngs == set(report.PLOT_NAMES)
    for name in pngs:
        img = matplotlib.image.imread(tmp_path / "plots" / name)
        assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 600, name
        # not blank: a plot has ink
        assert (img[..., :3] < 0.5).mean() > 0.002, name
    p = _check_page(path, pngs)
    text = html.unescape("".join(p.text))
    # the tuned config and the resolved one, the commands, the findings and the ratios are on it
    tuned = summary["tuned"]["zcut"]
    assert f"max_depth_mm = {tuned['max_depth_mm']}" in text and "a_max_px = 171.4" in text
    assert "<mark>" in page_text(path)  # tuned.toml's changed lines are marked
    assert "zcut replay" in text and f"--config {tmp_path / 'tuned.toml'}" in text
    assert "zcut sweep '/data/<scan & co>.mcap'" in text
    assert f"zcut compare '/data/<scan & co>.mcap' --a zcut --b {tmp_path / 'tuned.toml'}" in text
    assert "larger d_max flags more outliers" in text and "smaller Δd flags more outliers" in text
    for role in ("tuned", "nominal", "chosen", "SOR tuned", "SOR chosen"):
        assert role in text
    # the embedded images are the files
    import base64

    embedded = sorted(base64.b64decode(a["src"].split(",", 1)[1]) for t, a in p.tags if t == "img")
    assert embedded == sorted((tmp_path / "plots" / n).read_bytes() for n in pngs)


def test_best_table_ranks_by_the_objective_and_marks_the_roles(tmp_path):
    summary = model_summary(tmp_path, objective="recall@precision=0.9")
    page = report.render_html(summary, [])
    rows = page.split("<table class=sets>")[1].split("</table>")[0].split("<tr")[2:]
    ranks = [r.split("<td class=num>")[1].split("<")[0] for r in rows]
    numeric = [int(x) for x in ranks if x != "—"]
    assert numeric == sorted(numeric) and numeric[0] == 1
    tuned = summary["tuned"]["zcut"]
    assert "tag-tuned" in page and f"{tuned['recall']:.3f}" in page


def test_findings_follow_the_counts(tmp_path):
    summary = model_summary(tmp_path)
    found = {(f["parameter"], f["changed"]["max_depth_mm"], f["changed"]["rho_thr"], f["changed"]["step_mm"]): f
             for f in findings.paper_findings(summary)}
    assert len(found) == 5
    f = found[("max_depth_mm", 45.0, 0.07, 0.2)]
    assert f["count_as_paper"] == (f["changed"]["n_pred"] > f["base"]["n_pred"])
    assert f["d_tp"] == f["changed"]["tp"] - f["base"]["tp"]
    assert f["f1"] in ("higher", "lower", "within the intervals")
    assert ("step_mm", 30.0, 0.07, 0.1) in found


def test_findings_table_over_part_kinds(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    table = findings.findings_table({"zinc_nuts": model_summary(tmp_path / "a"),
                                   "one point": model_summary(tmp_path / "b", steps=(0.2,), depths=(30.0,),
                                                              rhos=(0.07,), sor_ks=(4,), sor_stds=(1.0,))})
    lines = table.splitlines()
    assert lines[0].startswith("|  | nominal F1 |") and len(lines) == 6
    rich, poor = lines[2].split(" | "), lines[3].split(" | ")
    assert all(c.strip()[0] in "✓✗=" for c in rich[5:]), rich
    # a grid without the neighbours: only the chosen point (which is nominal and tuned)
    assert poor[5:] == ["—"] * 4 + ["— |"] and poor[1] == poor[3]


@pytest.mark.parametrize("case, kw, expected", [
    ("one value per axis", {"steps": (0.2,), "depths": (30.0,), "rhos": (0.07,), "sor_ks": (4,), "sor_stds": (1.0,)},
     {"precision_recall.png"}),
    ("no SOR", {"sor": False},
     {"counts_max_depth.png", "counts_rho.png", "counts_step.png", "accuracy_zcut.png", "f1_map.png",
      "precision_recall.png"}),
    ("a_max unknown", {"a_max": None, "steps": (0.2,)},
     {"counts_max_depth.png", "accuracy_zcut.png", "accuracy_sor.png", "precision_recall.png", "ratios.png"}),
    # zero counts and zero recall are drawn; precision is undefined everywhere: no precision-recall chart
    ("nothing flagged", {"flag_nothing": True, "sor": False, "steps": (0.2,)},
     {"counts_max_depth.png", "counts_rho.png", "accuracy_zcut.png", "f1_map.png"}),
    ("one frame", {"n_frames": 1}, set(report.PLOT_NAMES)),
])
def test_degenerate_grids_give_a_page(tmp_path, case, kw, expected):
    summary = model_summary(tmp_path, **kw)
    path = report.write_report(tmp_path, summary)
    pngs = {p.name for p in (tmp_path / "plots").glob("*.png")}
    assert pngs == expected, case
    _check_page(path, pngs)


def test_empty_and_null_summary_fields(tmp_path):
    summary = model_summary(tmp_path)
    summary.update(sets=[], chosen={"zcut": None, "sor": None}, nominal=None,
                   tuned={"zcut": None, "sor": None, "ranges": None, "note": "no z-cut set meets the floor"},
                   sensitivity={"chosen": None, "tuned": None}, config="not = [valid toml",
                   damage=["chunk at byte 123 is corrupt (<crc>)"], errors=["scan.mcap: boom"],
                   unscored=[{"index": 3, "stamp_ns": 5, "reason": "no label"}] * 60)
    path = report.write_report(tmp_path, summary)
    assert not list((tmp_path / "plots").glob("*.png"))
    page = path.read_text()
    assert "No parameter set was scored" in page and "no z-cut set meets the floor" in page
    assert "&lt;crc&gt;" in page and "… and 10 more" in page and "Unscored frames" in page


def test_a_rerun_removes_plots_the_new_grid_cannot_draw(tmp_path):
    report.write_report(tmp_path, model_summary(tmp_path))
    assert (tmp_path / "plots" / "ratios.png").is_file()
    report.write_report(tmp_path, model_summary(tmp_path, sor=False))
    assert not (tmp_path / "plots" / "ratios.png").exists()
    assert not (tmp_path / "plots" / "accuracy_sor.png").exists()
    assert not [p for p in tmp_path.rglob("*partial*")]


def test_plotting_leaves_no_pyplot_state(tmp_path):
    import sys

    import matplotlib

    before = dict(matplotlib.rcParams)
    plots.make_plots(model_summary(tmp_path))
    assert dict(matplotlib.rcParams) == before
    if "matplotlib.pyplot" in sys.modules:  # imported by someone else: no figure of ours in it
        assert not sys.modules["matplotlib.pyplot"].get_fignums()


# ------------------------------------------------------------------------------------- the browser


@pytest.mark.browser
@pytest.mark.slow
def test_report_in_chromium_loads_offline_and_every_image_decodes(tmp_path, browser):
    summary = model_summary(tmp_path)
    path = report.write_report(tmp_path, summary)
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    requests, refused, errors = [], [], []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)

    def route(r):
        url = r.request.url
        requests.append(url)
        if url.startswith(("file://", "http://127.0.0.1")):
            r.continue_()
        else:
            refused.append(url)
            r.abort()

    page.route("**/*", route)
    page.goto(path.as_uri())
    page.wait_for_load_state("load")
    assert refused == [] and errors == []
    assert requests == [path.as_uri()]  # the page itself, nothing else
    images = page.evaluate("[...document.images].map(i => [i.complete, i.naturalWidth, i.naturalHeight, "
                           "i.getBoundingClientRect().width])")
    assert len(images) == len(report.PLOT_NAMES)
    for complete, w, h, shown in images:
        assert complete and w > 0 and h > 0 and 0 < shown <= 1280
    for sid in SECTIONS:
        assert page.locator(f"section#{sid} h2").count() == 1, sid
    assert page.locator("table.sets tbody tr").count() >= 10
    # readable at 100 %: nothing wider than the window
    assert page.evaluate("document.documentElement.scrollWidth") <= 1280
    shot = tmp_path / "report.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    page.close()



def test_hostile_names_and_texts_are_escaped_everywhere(tmp_path):
    """A log name, a note, a damage or error line, the command line, the config and the tuned note
    carrying markup and ampersands: the page shows them as text and runs nothing."""
    hostile = "<script>alert('x')</script> & <img src=x onerror=alert(1)>"
    summary = model_summary(tmp_path)
    summary.update(
        logs=[{"log": f"/data/{hostile}.mcap", "sha256": "<b>" * 8, "error": hostile}],
        notes=[hostile], damage=[{"log": f"{hostile}.mcap", "note": hostile}], errors=[hostile],
        unscored=[{"log": f"{hostile}.mcap", "index": 1, "stamp_ns": 2, "reason": hostile}],
        reproduce=f"zcut sweep '{hostile}.mcap' -o out", truth=hostile, region=hostile,
        config=summary["config"] + f"\n# {hostile}\n",
        tuned={**summary["tuned"], "note": hostile})
    path = report.write_report(tmp_path, summary)
    page = path.read_text(encoding="utf-8")
    p = _parse(page)
    assert not [t for t, _ in p.tags if t == "script"]
    assert all(a["src"].startswith("data:image/png;base64,") for t, a in p.tags if t == "img")
    assert not [a for _, a in p.tags if any(k.startswith("on") for k in a)]
    assert "<script" not in page.lower() and "onerror=alert(1)>" not in page
    text = html.unescape("".join(p.text))
    assert text.count(hostile) >= 9  # every one of them shown as text
    assert "&lt;script&gt;" in page and "&amp; &lt;img" in page


def test_tuning_says_when_the_grids_best_z_cut_lies_outside_the_papers_ranges(tmp_path):
    """``tuned.toml`` keeps the best set within the §5.4 ranges; when the grid's best set lies outside
    them, the tuned note (printed by the sweep, in tuned.toml's header and summary.json) names it, which
    of its values lie outside, and both F1s (issue 31: 0.164 within vs 0.559 outside went unexplained)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    def row(depth, rho, tp, fp, fn=100):
        return {"log": "scan.mcap", "log_sha256": "ab" * 32, "frame": 0, "stamp_ns": 0, "method": "zcut",
                "step_mm": 0.2, "max_depth_mm": depth, "rho_thr": rho, "max_area_px": rho * A_MAX, "sor_k": None,
                "sor_std_ratio": None, "tp": tp, "fp": fp, "fn": fn, "n_pred": tp + fp, "n_both": 0,
                "n_sor_only": 0, "n_zcut_only": tp + fp}

    pq.write_table(pa.Table.from_pylist([row(30.0, 0.07, 20, 80), row(120.0, 0.14, 80, 20)]), tmp_path / "s.parquet")
    sets = pooled_sets(pq.read_table(tmp_path / "s.parquet"))
    tuned = tune(sets, parse_objective("f1"), part="zinc_nuts")
    assert tuned.zcut is not None and tuned.zcut.max_depth_mm == 30.0  # within the ranges
    note = tuned.note or ""
    assert "outside the paper's §5.4 ranges" in note, note
    assert "d_max 120 (range 10.8–84)" in note and "ρ 0.14 (range 0.05–0.075)" in note and "Δd 0.2," in note, note
    assert "F1 0.571 against F1 0.182 for the set within them" in note, note
    # the best set within the ranges is the grid's best: no note
    pq.write_table(pa.Table.from_pylist([row(30.0, 0.07, 80, 20), row(120.0, 0.14, 20, 80)]), tmp_path / "t.parquet")
    assert tune(pooled_sets(pq.read_table(tmp_path / "t.parquet")), parse_objective("f1"), part="zinc_nuts").note is None


def test_the_report_gives_the_compare_command_of_its_config_against_tuned(tmp_path):
    """The report's reproduce section ends with ``zcut compare`` of the sweep's own config (A) against
    ``tuned.toml`` (B) on the same logs, with the sweep's region and truth (issue 33). The page is rendered as
    ``write_report`` renders it into ``tmp_path``, without drawing the plots (~3 s a page), which this section
    does not show; the written page's commands are checked by
    ``test_report_writes_every_plot_and_one_self_contained_page``."""
    import shlex

    def page_of(summary) -> str:
        return report.render_html(summary, [], tuned_toml=(tmp_path / "tuned.toml").read_text(encoding="utf-8"),
                                  out_dir=tmp_path)

    summary = model_summary(tmp_path)
    summary["reproduce"] = ("zcut sweep /data/a.mcap -o out --config '/c/my cfg.toml' --bin-model /m/b.ply "
                            "--truth sensor --region valid")
    summary["region"], summary["truth"] = "valid", "sensor"
    page = page_of(summary)
    cmd = html.unescape(page.split("paired verdict")[1].split("<pre>")[1].split("</pre>")[0])
    words = shlex.split(cmd)
    assert words[:2] == ["zcut", "compare"] and "/data/<scan & co>.mcap" in words
    assert words[words.index("--a") + 1] == "/c/my cfg.toml"
    assert words[words.index("--b") + 1] == str(tmp_path / "tuned.toml")
    assert words[words.index("-o") + 1] == str(tmp_path / "compare")
    assert words[words.index("--bin-model") + 1] == "/m/b.ply"
    assert words[words.index("--region") + 1] == "valid" and words[words.index("--truth") + 1] == "sensor"
    summary["reproduce"], summary["region"], summary["truth"] = "zcut sweep /data/a.mcap -o out", "zone", "paper, sensor"
    words = shlex.split(html.unescape(page_of(summary)
                                      .split("paired verdict")[1].split("<pre>")[1].split("</pre>")[0]))
    assert words[words.index("--a") + 1] == "zcut" and "--region" not in words and "--truth" not in words
