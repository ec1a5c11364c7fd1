"""The sweep's tuning cross-validated (studies.validate): folds, the rule, the held-out figures, the
comparison with the nominal set, the frames that would separate the two best sets, the grid's edges.

The pure functions are checked against literal loops; the sweep's outputs on real synthetic logs
(one log, two logs, a frame without true positives, a tuned set on the grid's edge)."""

from __future__ import annotations

import json
import math

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli
from scipy import stats

from cli.main import main
from studies.validate import (
    Edge,
    FrameCounts,
    Validation,
    cross_validate,
    folds_of,
    frames_to_separate,
    grid_distance,
    grid_edges,
    paired_difference,
    select,
)


# ------------------------------------------------------------------------------- literal references
def _f(metric, t, f, n):
    num, den = {"precision": (t, t + f), "recall": (t, t + n), "f1": (2 * t, 2 * t + f + n)}[metric]
    return num / den if den else math.nan


def _diff_loop(a, b, metric="f1"):
    """Paired difference of pooled figures and its standard error, frame by frame."""
    (ta, fa, na), (tb, fb, nb) = a, b
    m = len(ta)
    ra, rb = _f(metric, sum(ta), sum(fa), sum(na)), _f(metric, sum(tb), sum(fb), sum(nb))
    parts = {"precision": lambda t, f, n: (t, t + f), "recall": lambda t, f, n: (t, t + n),
             "f1": lambda t, f, n: (2 * t, 2 * t + f + n)}[metric]
    sa = sum(parts(ta[i], fa[i], na[i])[1] for i in range(m))
    sb = sum(parts(tb[i], fb[i], nb[i])[1] for i in range(m))
    ss = 0.0
    for i in range(m):
        na_, da = parts(ta[i], fa[i], na[i])
        nb_, db = parts(tb[i], fb[i], nb[i])
        z = (na_ - ra * da) / sa - (nb_ - rb * db) / sb
        ss += z * z
    return ra - rb, math.sqrt(m / (m - 1) * ss)


def _select_loop(tp, fp, fn, cand, dist, rule):
    """The tuning rule, set by set (objective F1)."""
    n = tp.shape[0]
    f1 = [_f("f1", tp[i].sum(), fp[i].sum(), fn[i].sum()) for i in range(n)]
    ok = [i for i in range(n) if cand[i] and not math.isnan(f1[i])]
    if not ok:
        return None
    top = max(f1[i] for i in ok)
    best = min((i for i in ok if f1[i] == top), key=lambda i: (dist[i], i))
    if rule == "best":
        return best
    within = []
    for i in ok:
        d, se = _diff_loop((tp[best], fp[best], fn[best]), (tp[i], fp[i], fn[i]))
        if i == best or d <= se:
            within.append(i)
    return min(within, key=lambda i: (dist[i], -f1[i], i))


def _counts(rng, n_sets, m, *, zero_frame=None):
    tp = rng.integers(0, 60, (n_sets, m))
    fp = rng.integers(0, 30, (n_sets, m))
    fn = rng.integers(0, 60, (n_sets, m))
    if zero_frame is not None:  # a frame without true outliers: no TP, no FN for any set
        tp[:, zero_frame] = 0
        fn[:, zero_frame] = 0
    return tp, fp, fn


# ------------------------------------------------------------------------------- pure functions
def test_paired_difference_equals_the_loop():
    rng = np.random.default_rng(20)
    for trial in range(50):
        m = int(rng.integers(2, 12))
        tp, fp, fn = _counts(rng, 2, m, zero_frame=0 if trial % 3 == 0 else None)
        for metric, (num, den) in {"f1": (2 * tp, 2 * tp + fp + fn), "precision": (tp, tp + fp),
                                   "recall": (tp, tp + fn)}.items():
            d, se = paired_difference(num[0].astype(float), den[0].astype(float), num[1].astype(float),
                                      den[1].astype(float))
            ld, lse = _diff_loop((tp[0], fp[0], fn[0]), (tp[1], fp[1], fn[1]), metric)
            assert d == pytest.approx(ld, abs=1e-12) and se == pytest.approx(lse, rel=1e-9, abs=1e-15)
    # one frame: no standard error
    d, se = paired_difference(np.array([2.0]), np.array([3.0]), np.array([1.0]), np.array([3.0]))
    assert d == pytest.approx(1 / 3) and math.isnan(se)


def test_select_equals_the_loop_for_both_rules():
    rng = np.random.default_rng(21)
    for trial in range(60):
        n, m = int(rng.integers(1, 15)), int(rng.integers(2, 10))
        tp, fp, fn = _counts(rng, n, m, zero_frame=1 if trial % 4 == 0 else None)
        if trial % 5 == 0:  # equal sets: ties broken by the distance to the config
            tp[-1], fp[-1], fn[-1] = tp[0], fp[0], fn[0]
        cand = rng.random(n) < 0.8
        dist = rng.integers(0, 5, n).astype(float)
        for rule in ("best", "one_se"):
            got = select(tp, fp, fn, objective=("f1", None), candidates=cand, distance=dist, rule=rule)
            assert got == _select_loop(tp, fp, fn, cand, dist, rule), (trial, rule)


def test_select_without_any_defined_figure_is_none():
    z = np.zeros((3, 4), dtype=np.int64)
    assert select(z, z, z, objective=("f1", None), candidates=np.ones(3, bool), distance=np.zeros(3)) is None
    with pytest.raises(ValueError, match="rule must be one of"):
        select(z, z, z, objective=("f1", None), candidates=np.ones(3, bool), distance=np.zeros(3), rule="max")


def test_the_one_se_rule_keeps_the_config_unless_the_gain_is_beyond_one_standard_error():
    # set 0 (the config) and set 1 (better by a hair, noisy): one_se keeps 0, best takes 1
    tp = np.array([[50, 50, 50, 50], [70, 30, 70, 40]])
    fp = np.array([[10, 10, 10, 10], [5, 15, 5, 10]])
    fn = np.array([[50, 50, 50, 50], [30, 70, 30, 60]])
    kw = dict(objective=("f1", None), candidates=np.ones(2, bool), distance=np.array([0.0, 1.0]))
    assert select(tp, fp, fn, rule="best", **kw) == 1
    assert select(tp, fp, fn, rule="one_se", **kw) == 0
    # a gain far beyond the noise: both rules take it
    tp[1] = [90, 90, 90, 90]
    fn[1] = [10, 10, 10, 10]
    assert select(tp, fp, fn, rule="one_se", **kw) == 1


def test_folds_of_logs_and_of_consecutive_frames():
    split, fold = folds_of(["b", "a", "b", "a", "c"], [0, 0, 1, 1, 0])
    assert split == "logs" and fold.tolist() == [1, 0, 1, 0, 2]
    split, fold = folds_of([f"l{i}" for i in range(7)], list(range(7)), max_folds=3)
    assert split == "logs" and fold.tolist() == [0, 1, 2, 0, 1, 2, 0]
    # one log: blocks of consecutive frames, whatever order the frames come in
    split, fold = folds_of(["x"] * 7, [6, 5, 4, 3, 2, 1, 0], max_folds=3)
    assert split == "frames" and fold.tolist() == [2, 2, 1, 1, 0, 0, 0]
    split, fold = folds_of(["x"] * 3, [0, 1, 2])
    assert fold.tolist() == [0, 1, 2]
    assert folds_of(["x"], [0])[0] == "none"


def _grid(steps, depths, rhos):
    return tuple((s, d, r, None) for s in steps for d in depths for r in rhos)


def test_grid_edges_say_which_way_to_widen():
    params = _grid((0.2,), (15.0, 30.0, 45.0), (0.035, 0.07, 1.0))
    cand = np.ones(len(params), dtype=bool)
    top = params.index((0.2, 45.0, 0.07, None))
    (e,) = grid_edges(params, cand, top)
    assert (e.axis, e.side, e.value, e.widen_to, e.by_ranges) == ("max_depth_mm", "upper", 45.0, 60.0, False)
    assert "widen --max-depth upward (e.g. add 60 mm)" in str(e)
    low = params.index((0.2, 15.0, 0.035, None))
    edges = {(e.axis, e.side): e for e in grid_edges(params, cand, low)}
    assert edges[("max_depth_mm", "lower")].widen_to == 7.5  # 15 − 15 would be 0: half of it
    assert edges[("rho_thr", "lower")].widen_to == pytest.approx(0.0175)
    assert grid_edges(params, cand, params.index((0.2, 30.0, 1.0, None)))[0].widen_to is None  # ρ_thr ≤ 1
    assert grid_edges(params, cand, params.index((0.2, 30.0, 0.07, None))) == ()
    # the end of the candidates (the §5.4 ranges), not of the grid
    cand = np.array([p[1] <= 30.0 for p in params])
    (e,) = grid_edges(params, cand, params.index((0.2, 30.0, 0.07, None)))
    assert e.by_ranges and e.side == "upper" and "§5.4" in str(e)
    # an axis of one value is not swept: no edge
    assert grid_edges(_grid((0.2,), (30.0,), (0.07,)), np.ones(1, bool), 0) == ()


def test_the_only_value_within_the_ranges_is_said_once():
    """ρ_thr 0.07 alone inside the §5.4 range, the grid going on both ways: once "the only value", not
    "the largest" and "the smallest" on consecutive lines (issue 35 item 20)."""
    params = _grid((0.2,), (30.0,), (0.035, 0.07, 0.105))
    cand = np.array([p[2] == 0.07 for p in params])
    edges = grid_edges(params, cand, params.index((0.2, 30.0, 0.07, None)))
    assert [str(e) for e in edges] == ["ρ_thr 0.07 is the only value within the paper's §5.4 range: "
                                       "the best may lie outside it"]
    assert Edge.from_json(edges[0].to_json()) == edges[0]


def test_grid_distance_counts_grid_steps_to_the_config():
    params = _grid((0.1, 0.2), (15.0, 30.0, 45.0), (0.07,))
    d = grid_distance(params, (0.2, 30.0, 0.07, None))
    assert d.tolist() == [2, 1, 2, 1, 0, 1]


def test_cross_validation_equals_the_loop_and_handles_a_frame_without_true_positives():
    rng = np.random.default_rng(22)
    params = _grid((0.1, 0.2), (15.0, 30.0, 45.0), (0.035, 0.07))
    n, m = len(params), 9
    tp, fp, fn = _counts(rng, n, m, zero_frame=4)
    counts = FrameCounts(params, ("one.mcap",) * m, tuple(range(m)), tp, fp, fn)
    cand = np.ones(n, dtype=bool)
    point = (0.2, 30.0, 0.07, None)
    ref = params.index(point)
    v = cross_validate(counts, objective=("f1", None), candidates=cand, point=point, reference=ref,
                       reference_name="nominal", rule="one_se")
    assert v.split == "frames" and len(v.folds) == 5 and sum(f.frames for f in v.folds) == m
    # the loop: blocks of consecutive frames, pick on the others, score the pick on the block
    dist = grid_distance(params, point)
    _, fold = folds_of(counts.logs, counts.frames)
    held = np.zeros((3, m), dtype=np.int64)
    for k in range(5):
        train = fold != k
        pick = _select_loop(tp[:, train], fp[:, train], fn[:, train], cand, dist, "one_se")
        assert v.folds[k].chosen == params[pick]
        held[:, ~train] = tp[pick, ~train], fp[pick, ~train], fn[pick, ~train]
    T, F, N = held.sum(axis=1)
    assert v.f1_out_of_sample == pytest.approx(_f("f1", T, F, N))
    tuned = _select_loop(tp, fp, fn, cand, dist, "one_se")
    assert v.tuned == params[tuned]
    assert v.f1_in_sample == pytest.approx(_f("f1", tp[tuned].sum(), fp[tuned].sum(), fn[tuned].sum()))
    assert v.optimism == pytest.approx(v.f1_in_sample - v.f1_out_of_sample)
    lo, hi = v.ci95["f1"]
    assert lo is not None and lo <= v.f1_out_of_sample <= hi
    # against the nominal set: paired over frames
    d, se = _diff_loop(held, (tp[ref], fp[ref], fn[ref]))
    assert v.vs_reference.value == pytest.approx(d) and v.vs_reference.se == pytest.approx(se)
    # round trip through JSON
    again = Validation.from_json(json.loads(json.dumps(v.to_json())))
    assert again == v


def test_the_frames_needed_to_separate_the_two_best_sets():
    # a constant per-frame gap with noise: the standard error shrinks as 1/sqrt(m)
    rng = np.random.default_rng(23)
    m = 6
    tp = np.vstack([rng.integers(40, 60, m), np.zeros(m, dtype=np.int64)])
    tp[1] = tp[0] - rng.integers(-3, 6, m)
    fp = np.full((2, m), 10)
    fn = 100 - tp
    counts = FrameCounts(((0.2, 30.0, 0.07, None), (0.2, 45.0, 0.07, None)), ("a",) * m, tuple(range(m)), tp, fp, fn)
    v = cross_validate(counts, objective=("f1", None), candidates=np.ones(2, bool), point=(0.2, 30.0, 0.07, None),
                       reference=0, reference_name="nominal", rule="best")
    t = v.two_best
    assert t is not None and t.frames == m
    if t.separated:
        assert t.frames_needed is None
    else:
        n = t.frames_needed
        assert n > m and n >= math.ceil(m * (1.959963984540054 * t.se / abs(t.value)) ** 2)
        q = stats.t.ppf(0.975, [n - 2, n - 1])  # n frames separate them, n - 1 do not
        assert q[1] * t.se * math.sqrt(m / n) < abs(t.value) <= q[0] * t.se * math.sqrt(m / (n - 1))
        assert any("more frames" in s for s in v.messages())
    n = frames_to_separate(0.01, 0.01, 10)
    assert stats.t.ppf(0.975, n - 1) * 0.01 * math.sqrt(10 / n) < 0.01 <= stats.t.ppf(0.975, n - 2) * 0.01 * math.sqrt(10 / (n - 1))


def test_too_few_frames_or_nothing_defined_is_said():
    params = _grid((0.2,), (30.0,), (0.07,))
    one = FrameCounts(params, ("a",), (0,), np.array([[3]]), np.array([[1]]), np.array([[2]]))
    v = cross_validate(one, objective=("f1", None), candidates=np.ones(1, bool), point=params[0], reference=0)
    assert v.split == "none" and "at least 2" in v.note and v.f1_out_of_sample is None
    assert v.messages() == [f"no cross-validation: {v.note}"]
    z = np.zeros((1, 4), dtype=np.int64)
    none = FrameCounts(params, ("a",) * 4, tuple(range(4)), z, z, z)
    v = cross_validate(none, objective=("f1", None), candidates=np.ones(1, bool), point=params[0], reference=0)
    assert v.split == "none" and v.tuned is None and "no z-cut set has a defined figure" in v.note


# ------------------------------------------------------------------------------- the sweep, real logs
GRID = ["--step", "0.2,0.5", "--max-depth", "10:40:4", "--rho", "0.03,0.07", "--sor-k", "4", "--sor-std", "1"]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("cv_logs")
    out = {}
    for name, parts, seed in (("nuts", "zinc_nuts", 5), ("spheres", "spheres", 6)):
        p = d / f"{name}.mcap"
        assert main(["synth", "-o", str(p), "--parts", parts, "--frames", "4", "--seed", str(seed),
                     "--size", "150x240"]) == 0
        out[name] = p
    p = d / "empty.mcap"  # an empty bin: frames without any true outlier
    assert main(["synth", "-o", str(p), "--empty", "--frames", "2", "--seed", "7", "--size", "150x240"]) == 0
    out["empty"] = p
    return out


def _sweep(capsys, out, *argv):
    rc, stdout, err = run_cli(capsys, "sweep", *argv, "-o", out, "--workers", "0", "--no-report")
    assert rc == 0, err
    return json.loads((out / "summary.json").read_text()), stdout


def _held_out_f1(table, folds_json):
    """The out-of-sample F1 from the table's rows: each fold's pick scored on its held-out frames."""
    T = F = N = 0
    for f in folds_json:
        c = f["chosen"]
        for r in table:
            if (r["method"] == "zcut" and r["log"] in f["logs"] and r["step_mm"] == c["step_mm"]
                    and r["max_depth_mm"] == c["max_depth_mm"] and abs(r["rho_thr"] - c["rho_thr"]) < 1e-12):
                T, F, N = T + r["tp"], F + r["fp"], N + r["fn"]
    return 2 * T / (2 * T + F + N)


def test_one_log_is_cross_validated_over_blocks_of_frames(logs, tmp_path, capsys):
    s, stdout = _sweep(capsys, tmp_path / "one", logs["nuts"], *GRID)
    v = s["validation"]
    assert v["split"] == "frames" and [f["frames"] for f in v["folds"]] == [1, 1, 1, 1]
    tz = s["tuned"]["zcut"]
    # the fixed keys: the out-of-sample F1 and its interval beside the in-sample figure
    assert tz["f1_out_of_sample"] == v["f1_out_of_sample"] and "f1" in tz["ci95_out_of_sample"]
    assert tz["optimism"] == pytest.approx(tz["f1"] - tz["f1_out_of_sample"])
    assert tz["f1"] == pytest.approx(v["f1_in_sample"])
    # each fold held out one frame: the picks scored on them, from the table, give the figure
    table = pq.read_table(tmp_path / "one" / "sweep.parquet").to_pylist()
    by_frame = []
    for f, frame in zip(v["folds"], sorted({r["frame"] for r in table})):
        rows = [r for r in table if r["frame"] == frame]
        by_frame.append((f, rows))
    T = F = N = 0
    for f, rows in by_frame:
        c = f["chosen"]
        (r,) = [r for r in rows if r["method"] == "zcut" and r["step_mm"] == c["step_mm"]
                and r["max_depth_mm"] == c["max_depth_mm"] and abs(r["rho_thr"] - c["rho_thr"]) < 1e-12]
        T, F, N = T + r["tp"], F + r["fp"], N + r["fn"]
    assert v["f1_out_of_sample"] == pytest.approx(2 * T / (2 * T + F + N))
    assert "out of sample" in stdout and "optimism" in stdout
    assert v["reference"] == "nominal" and v["vs_reference"] is not None
    assert any("nominal" in m for m in v["messages"])
    # the report shows both figures, the folds and the sentences
    from studies.report import write_report

    page = write_report(tmp_path / "one", s).read_text()
    assert "Out of sample (the tuning cross-validated)" in page and f"{v['f1_out_of_sample']:.3f}" in page
    assert page.count("<tr><td><code>nuts.mcap</code></td>") == 4  # a row per fold
    # tuned.toml carries the tuned set (the rule's pick)
    import tomllib

    cfg = tomllib.loads((tmp_path / "one" / "tuned.toml").read_text())
    assert (cfg["zcut"]["step_mm"], cfg["zcut"]["max_depth_mm"]) == (v["tuned"]["step_mm"], v["tuned"]["max_depth_mm"])


def test_two_logs_and_a_log_without_true_positives_are_folds_of_logs(logs, tmp_path, capsys):
    s, _ = _sweep(capsys, tmp_path / "three", logs["nuts"], logs["spheres"], logs["empty"], *GRID)
    v = s["validation"]
    assert v["split"] == "logs" and sorted(tuple(f["logs"]) for f in v["folds"]) == [
        ("empty.mcap",), ("nuts.mcap",), ("spheres.mcap",)]
    table = pq.read_table(tmp_path / "three" / "sweep.parquet").to_pylist()
    empty = [r for r in table if r["log"] == "empty.mcap" and r["method"] == "zcut"]
    # an empty bin's frame without a true outlier: no TP (nor FN) for any set
    assert any(all(r["tp"] == 0 and r["fn"] == 0 for r in empty if r["frame"] == f) for f in {r["frame"] for r in empty})
    assert v["f1_out_of_sample"] == pytest.approx(_held_out_f1(table, v["folds"]))
    (fe,) = [f for f in v["folds"] if f["logs"] == ["empty.mcap"]]
    assert fe["frames"] == 2 and (fe["f1"] is None or 0 <= fe["f1"] <= 1)
    # two logs: a fold each
    s2, _ = _sweep(capsys, tmp_path / "two", logs["nuts"], logs["spheres"], *GRID)
    assert s2["validation"]["split"] == "logs" and len(s2["validation"]["folds"]) == 2
    assert s2["tuned"]["zcut"]["f1_out_of_sample"] is not None


def test_a_tuned_set_on_the_grids_edge_says_which_way_to_widen(logs, tmp_path, capsys):
    s, stdout = _sweep(capsys, tmp_path / "edge", logs["nuts"], "--step", "0.2", "--max-depth", "5,10",
                       "--rho", "0.07", "--no-study-points", "--part", "zinc_nuts")
    v = s["validation"]
    assert v["tuned"]["max_depth_mm"] == 10.0
    (e,) = [e for e in v["edges"] if e["axis"] == "max_depth_mm"]
    assert e["side"] == "upper" and e["widen_to"] == 15.0 and not e["by_ranges"]
    assert "widen --max-depth upward" in stdout
