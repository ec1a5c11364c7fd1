"""bench/bench_label_pageonly.py per kind of frame (issue 29, docs/labelling.md "Fifteenth round"): ``--kinds`` (the
median and range of the scores over several frames a kind, the paired changes of a variant, the wrong pixels by
class), ``--no-causes`` (the scores without the true surfaces) and the fits shared by the rule and its variants."""

from __future__ import annotations

import json
from collections.abc import Iterator
from types import ModuleType

import numpy as np
import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def _row(bench: ModuleType, kind: str, seed: int, frame: int, variant: str, *, iou: float, held: float = 0.9,
         cpu: float = 10.0, causes: dict[str, int] | None = None) -> dict:
    row = {"log": f"{kind}_{seed}.mcap", "frame": frame, "variant": variant, "kind": kind, "seed": seed,
           "iou": iou, "iou_sensor": None if kind == "stereo" else iou / 2, "held": held, "limit": 0.7,
           "inputs": 2 + frame, "label": 1000 + frame, "truth": 900, "label_truth": 500, "cpu_fits": cpu,
           "cpu_slivers": cpu / 10}
    if causes is not None:
        row.update({k: 0 for k in (*bench.EXCESS, *bench.MISSED_CLASSES)}, non_truth=500, **causes)
    return row


def test_kinds_summary_medians_ranges_and_paired_changes(bench):
    rows = []
    for f, (a, b) in enumerate([(0.40, 0.45), (0.50, 0.52), (0.30, 0.30)]):
        rows += [_row(bench, "zinc_nuts hand-made", 7751, f, "base", iou=a, cpu=10.0 + f),
                 _row(bench, "zinc_nuts hand-made", 7751, f, "lever", iou=b, held=0.9 - 0.01 * f, cpu=10.3 + f)]
    rows += [_row(bench, "spheres hand-made", 7751, 0, "base", iou=0.7), _row(bench, "spheres hand-made", 7751, 0,
                                                                               "lever", iou=0.7)]
    lines = bench.kinds_summary(rows, against="base")
    assert lines[0] == "variant base:" and lines[1].count("|") == lines[2].count("|") == 11
    zn = next(v for v in lines if v.startswith("| zinc_nuts hand-made | 7751 | 3 |"))
    assert "| 0.400 [0.300–0.500] | 0.200 [0.150–0.250] | 0.900 [0.900–0.900] |" in zn
    assert "| 3 [2–4] | 1,001 [1,000–1,002] | 900 [900–900] |" in zn
    i = lines.index("lever against base (paired by frame; IoU: the medians, then the median and range of the changes):")
    d = next(v for v in lines[i:] if v.startswith("| zinc_nuts hand-made |"))
    assert d.startswith("| zinc_nuts hand-made | 7751 | 3 | 0.400 → 0.450 | 0.020 [0.000–0.050] | -0.010 [-0.020–0.000] |")
    assert "| 0.300 [0.300–0.300] | 0.030 [0.030–0.030] |" in d  # the method's CPU-s and the pass's
    assert any(v.startswith("| spheres hand-made | 7751 | 1 | 0.700 → 0.700 | 0.000 [0.000–0.000] |") for v in lines[i:])
    assert not any(v.startswith("the wrong label pixels") for v in lines)  # no row carries the causes
    assert bench.kinds_summary(rows)[0] == "variant base:"  # the first variant met by default
    with pytest.raises(SystemExit, match="--against 'x': no such variant among base, lever"):
        bench.kinds_summary(rows, against="x")
    assert bench.kinds_summary([]) == ["(no rows)"]


def test_kinds_summary_wrong_pixels_by_class_add_up(bench):
    """The excess classes and "other" add up to the label's non-truth pixels, the missed classes to the truth not in
    the label; shares of the two together."""
    c1 = {"non: unfitted instance": 300, "non: fitted inst, nearest is its fit, pose off (true surf within k Err)": 100, "non: bin": 50,
          "truth in rejected proposals": 100, "missed: misposed": 200, "missed: other": 100,
          "truth outside the served zone": 40}
    rows = [_row(bench, "black_nuts hand-made", 7751, 0, "base", iou=0.2, causes=c1),
            _row(bench, "black_nuts hand-made", 7751, 1, "base", iou=0.2, causes=c1),
            _row(bench, "black_nuts hand-made", 7751, 1, "lever", iou=0.3, causes=c1)]
    lines = bench.kinds_summary(rows, against="base")
    i = next(j for j, v in enumerate(lines) if v.startswith("the wrong label pixels of base"))
    head, rule, body = lines[i + 1], lines[i + 2], lines[i + 3]
    assert head.count("|") == rule.count("|") == body.count("|")
    cells = [c.strip() for c in body.strip("|").split("|")]
    names = [c.strip() for c in head.strip("|").split("|")]
    got = dict(zip(names, cells))
    # per frame 500 not truth (300 + 100 + 50 + 50 other) and 400 truth missed (900 - 500): 900 wrong a frame
    assert got["frames"] == "2" and got["wrong px (excess + missed)"] == "1,000 + 800"
    assert got["excess: on an instance no fit took"] == "600 (33%)" and got["excess: other"] == "100 (6%)"
    assert got["missed: in a proposal the rule rejected"] == "200 (11%)" and got["missed: a fit misposed"] == "400 (22%)"
    assert got["truth outside the served zone"] == "80"


def test_kinds_rows_reads_the_variants_beside_and_refuses_rows_without_a_kind(bench, tmp_path):
    f = tmp_path / "a.json"
    f.write_text(json.dumps([_row(bench, "rods hand-made", 7741, 0, "rule", iou=0.5)]))
    f.with_suffix(".slivers.json").write_text(json.dumps([_row(bench, "rods hand-made", 7741, 0, "s", iou=0.6)]))
    assert [r["variant"] for r in bench.kinds_rows([f])] == ["rule", "s"]
    g = tmp_path / "old.json"
    g.write_text(json.dumps([{"log": "x.mcap", "frame": 0, "variant": "rule"}]))
    with pytest.raises(SystemExit, match="x.mcap frame 0: a row without its kind"):
        bench.kinds_rows([g])
    with pytest.raises(SystemExit, match="no such file"):
        bench.kinds_rows([tmp_path / "none.json"])


def test_label_scores_against_the_definitions(bench):
    rng = np.random.default_rng(2912)
    ids = rng.integers(0, 6, (30, 40))
    served = rng.random((30, 40)) < 0.9
    truth = (rng.random((30, 40)) < 0.3) & served
    sensor = rng.random((30, 40)) < 0.2
    out = np.array([False, True, False, True, True, False])
    label = out[ids] & served
    got = bench.label_scores(label, ids, truth, served, sensor)
    assert got["iou"] == (label & truth).sum() / (label | truth).sum()
    assert got["iou_sensor"] == (label & sensor & served).sum() / (label | (sensor & served)).sum()
    assert got["held"] == (truth & (ids > 0)).sum() / truth.sum()
    assert got["truth in rejected proposals"] + got["missed"] == got["truth"] - got["label_truth"]
    maj = [j for j in range(1, 6) if (truth & (ids == j)).sum() >= 0.5 * (served & (ids == j)).sum()]
    lim = np.isin(ids, maj) & served
    assert got["limit"] == (lim & truth).sum() / (lim | truth).sum()
    assert bench.label_scores(np.zeros((2, 2), bool), np.zeros((2, 2), np.int64), np.zeros((2, 2), bool),
                              np.ones((2, 2), bool), None) == {
        "iou_sensor": None, "limit": 1.0, "held": 0.0, "truth": 0, "label": 0, "label_truth": 0, "iou": 1.0,
        "truth in rejected proposals": 0, "missed": 0}


def test_memo_by_content_and_last_few(bench):
    calls = []

    def f(a, *, p=1):
        calls.append(1)
        return a.sum() * p

    m = bench._memo(f, keep=2)
    a = np.arange(6.0)
    assert m(a, p=2) == 30.0 and m(a.copy(), p=2) == 30.0 and len(calls) == 1  # the same content: remembered
    assert m(a, p=3) == 45.0 and len(calls) == 2
    b = a.copy()
    b[0] = 1.0
    assert m(b, p=2) == 32.0 and len(calls) == 3  # other content
    assert m(a, p=2) == 30.0 and len(calls) == 4  # only the last two kept


def test_no_causes_and_shared_fits_give_the_trees_method(bench, monkeypatch, tmp_path):
    """On a small hand-made frame: the variant 150:12:2:8 scored with the fits shared (computed once a frame, the
    pipeline's ``explained`` first) is the tree's method — its label and scores those of a run without ``--slivers``;
    ``--no-causes`` scores the same label the same; the rows carry the log's kind and seed."""
    import replay.pipeline.explained as rex
    import zcut.fits
    from replay.synth.log import write_synthetic_log

    log = write_synthetic_log(tmp_path / "zn.mcap", kind="zinc_nuts", frames=1, seed=2913, size=(240, 384))
    assert bench.log_kind(log) == {"kind": "zinc_nuts hand-made", "seed": 2913}
    real = zcut.fits.fit_prepared
    calls = []

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(zcut.fits, "fit_prepared", counted)
    monkeypatch.setattr(rex, "SLIVER_MIN_PX", 0)
    monkeypatch.setattr(bench, "SLIVERS", [(150, 12, 2, 8)])
    monkeypatch.setattr(bench, "NO_CAUSES", False)
    rule, var = bench.diagnose(log, tmp_path / "w1")
    shared = len(calls)  # the frame's fits (and the pieces on top's own, if any): once for the pipeline, the rule
    assert shared in (1, 2)  # and the variant
    assert zcut.fits.fit_prepared is counted  # put back
    monkeypatch.setattr(rex, "SLIVER_MIN_PX", 150)
    monkeypatch.setattr(bench, "SLIVERS", None)
    monkeypatch.setattr(bench, "NO_CAUSES", True)
    plain, _ = bench.diagnose(log, tmp_path / "w2")
    assert len(calls) == 3 * shared  # unshared: the pipeline's and the page's again
    keys = ("iou", "iou_sensor", "held", "limit", "truth", "label", "label_truth", "fits", "inputs",
            "truth in rejected proposals", "missed", "truth outside the served zone", "kind", "seed")
    assert {k: var[0][k] for k in keys} == {k: plain[0][k] for k in keys}
    assert var[0]["variant"] == "slivers150x12x2x8" and rule[0]["variant"] == "rule" and "non_truth" not in plain[0]
    a = np.load(bench.label_file(tmp_path / "w1", log, 0, "slivers150x12x2x8", "emulated"))
    b = np.load(bench.label_file(tmp_path / "w2", log, 0, "rule", "emulated"))
    assert (a == b).all()


@pytest.mark.parametrize(("argv", "match"), [
    (["--no-causes", "--logs", "a.mcap"], "--no-causes is a --diagnose option"),
    (["--kinds", "/nonexistent/r.json"], "--kinds: /nonexistent/r.json: no such file"),
])
def test_options_refused(bench, monkeypatch, argv, match):
    monkeypatch.setattr("sys.argv", ["bench_label_pageonly.py", *argv])
    with pytest.raises(SystemExit, match=match):
        bench.main()
