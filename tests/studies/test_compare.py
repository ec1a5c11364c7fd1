"""`zcut compare`: two filters on the same frames; counts as two `zcut accuracy` runs, shared stages run
once, bad input one line, the recording read back."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli
from log_helpers import without_truth

from cli.main import main

SIZE = "120x180"
FRAMES = 3
#: the comparisons whose subject is not the executor (the output folder's --force, a comparison allowed or refused,
#: the recording's entities, the stage counts) run in this process, as tests/studies/test_study_inputs.py and
#: test_every_parameter.py run theirs: two spawned workers cost ~2 s a comparison (their start-up), and
#: tests/studies/test_compare_workers.py proves the outputs (compare.json, summary.parquet, disagreement.npz, the
#: recording's rows, the stage counts) of local workers equal those of one process. The tests of what the units
#: compute from another input (the figures against accuracy's, a results file as a side, no truth, --truth sensor)
#: keep the default executor (the cores' workers).
IN_PROCESS = ("--workers", "0")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare")
    log = d / "log.mcap"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--frames", str(FRAMES), "--seed", "5",
                 "--size", SIZE]) == 0
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    (d / "sor.toml").write_text("[sor]\nstd_ratio = 2.0\n")
    (d / "sor_default.toml").write_text("[sor]\nstd_ratio = 1.0\n")
    (d / "removal.toml").write_text("[removal]\nmax_tolerance_mm = 12.0\n")
    assert main(["replay", str(log), "--config", str(d / "rho.toml"), "--out", str(d / "rho.results.mcap")]) == 0
    other = d / "other.mcap"
    assert main(["synth", "-o", str(other), "--parts", "spheres", "--frames", "2", "--seed", "6",
                 "--size", SIZE]) == 0
    assert main(["replay", str(other), "--out", str(d / "other.results.mcap")]) == 0
    without_truth(log, d / "notruth.mcap")
    return d


def _accuracy(capsys, *argv) -> dict:
    rc, out, err = run_cli(capsys, "accuracy", *argv, "--json")
    assert rc == 0, err
    return json.loads(out)


def test_counts_equal_two_accuracy_runs(data, tmp_path, capsys):
    log = data / "log.mcap"
    rc, out, err = run_cli(capsys, "compare", log, "--a", "zcut", "--b", data / "rho.toml", "-o", tmp_path / "c",
                           "--json")
    assert rc == 0, err
    rep = json.loads(out)
    acc_a = _accuracy(capsys, log, "--methods", "zcut")
    acc_b = _accuracy(capsys, log, "--config", data / "rho.toml")
    assert [f["index"] for f in rep["frames"]] == [f["index"] for f in acc_a["frames"]] == list(range(FRAMES))
    for f, fa, fb in zip(rep["frames"], acc_a["frames"], acc_b["frames"]):
        for m in ("zcut",):
            assert {k: f["a"][m][k] for k in ("tp", "fp", "fn")} == {k: fa[m][k] for k in ("tp", "fp", "fn")}
        for m in ("zcut", "sor", "union", "intersection"):
            assert {k: f["b"][m][k] for k in ("tp", "fp", "fn")} == {k: fb[m][k] for k in ("tp", "fp", "fn")}
    for side, acc in (("a", acc_a), ("b", acc_b)):
        for m, e in rep["pooled"][side].items():
            assert (e["tp"], e["fp"], e["fn"]) == tuple(acc["pooled"][m][k] for k in ("tp", "fp", "fn"))
    v = rep["verdict"]
    assert v["wins"] + v["losses"] + v["ties"] == FRAMES and v["line"].startswith("B: F1 ")
    assert rep["config_difference"] == [{"key": "methods", "a": ["zcut"], "b": ["zcut", "sor"]},
                                        {"key": "zcut.max_area_px", "a": pytest.approx(rep["config_difference"][1]["a"]),
                                         "b": pytest.approx(rep["config_difference"][1]["a"] / 2)}]
    # summary.parquet: one row per frame, the primary counts
    rows = pq.read_table(tmp_path / "c" / "summary.parquet").to_pylist()
    assert [(r["frame"], r["a_tp"], r["b_fp"]) for r in rows] == [
        (f["index"], f["a"]["zcut"]["tp"], f["b"]["zcut"]["fp"]) for f in rep["frames"]]
    # the blobs: the only-A / only-B pixels of the primary masks, split into components
    for f in rep["frames"]:
        blobs = [b for b in rep["blobs"] if b["frame"] == f["index"]]
        assert sum(b["area_px"] for b in blobs if b["who"] == "A") == f["only_a"]
        assert sum(b["area_px"] for b in blobs if b["who"] == "B") == f["only_b"]
        assert all(b["fixes_px"] + b["breaks_px"] <= b["area_px"] for b in blobs)
    html = (tmp_path / "c" / "report.html").read_text()
    assert v["line"].split(":")[0] in html and "<script" not in html


def test_a_results_file_scores_as_accuracy_scores_it(data, tmp_path, capsys):
    log, res = data / "log.mcap", data / "rho.results.mcap"
    rc, out, err = run_cli(capsys, "compare", log, "--a", res, "--b", "zcut", "-o", tmp_path / "c", "--json",
                           "--no-rrd")
    assert rc == 0, err
    rep = json.loads(out)
    acc = _accuracy(capsys, res)
    for f, fa in zip(rep["frames"], acc["frames"], strict=True):
        for m in ("zcut", "sor"):
            assert {k: f["a"][m][k] for k in ("tp", "fp", "fn")} == {k: fa[m][k] for k in ("tp", "fp", "fn")}
    assert not (tmp_path / "c" / "compare.rrd").exists()


def test_shared_stages_run_once(data, tmp_path):
    from studies.compare import CompareOptions, run

    log = data / "log.mcap"
    # A and B differ only in SOR: the bin stages and the z-cut run once per frame, SOR twice
    r = run(CompareOptions(logs=(log,), a=str(data / "sor_default.toml"), b=str(data / "sor.toml"), out=tmp_path / "s",
                           rrd=False, report=False, workers=0))
    assert dict(r.stage_runs) == {"locate_bin": FRAMES, "bin_zone": FRAMES, "method:zcut": FRAMES,
                                  "method:sor": 2 * FRAMES}
    assert r.report["shared"] == {"bin_stages": True, "zone": True, "methods": ["zcut"]}
    assert r.report["config_difference"] == [{"key": "sor.std_ratio", "a": 1.0, "b": 2.0}]
    # another removal: every stage runs for each side
    r = run(CompareOptions(logs=(log,), a=str(data / "sor_default.toml"), b=str(data / "removal.toml"),
                           out=tmp_path / "r", rrd=False, report=False, workers=0))
    assert dict(r.stage_runs) == {"locate_bin": 2 * FRAMES, "bin_zone": 2 * FRAMES, "method:zcut": 2 * FRAMES,
                                  "method:sor": 2 * FRAMES}


def test_the_shared_masks_are_those_of_two_replays(data):
    """A zone and a z-cut handed from A to B give B exactly the masks of its own replay."""
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession, open_log
    from studies.compare import PairRunner

    log = data / "log.mcap"
    sa = ReplaySession.open(log, config_file=data / "sor_default.toml", choose_bin_model=lambda r: bin_model_for(r, None))
    sb = ReplaySession.open(log, config_file=data / "sor.toml", choose_bin_model=lambda r: bin_model_for(r, None))
    reader, first, _ = open_log(log)
    runner = PairRunner(log, reader, first, sa.resolved, sb.resolved, sa.bin_model)
    assert cfg.config_sha256(runner.a) != cfg.config_sha256(runner.b)
    pairs = list(runner.frames((0, None)))
    alone_a = [r for _, r in sa.results()]
    alone_b = [r for _, r in sb.results()]
    for (_, ra, rb), xa, xb in zip(pairs, alone_a, alone_b, strict=True):
        for m in ("zcut", "sor"):
            assert np.array_equal(ra.outliers[m], xa.outliers[m])
            assert np.array_equal(rb.outliers[m], xb.outliers[m])
        assert np.array_equal(ra.zone, xb.zone)


def test_without_truth_agreement_only(data, tmp_path, capsys):
    rc, out, err = run_cli(capsys, "compare", data / "notruth.mcap", "--a", "zcut", "--b", "sor", "-o", tmp_path / "n",
                           "--json")
    assert rc == 0, err
    assert "no truth: agreement only" in err
    rep = json.loads(out)
    assert rep["truth"] is None and rep["verdict"]["truth"] is False
    ag = rep["agreement"]
    assert ag["both"] + ag["only_a"] + ag["only_b"] > 0 and 0 <= ag["jaccard"] <= 1
    assert {b["consequence"] for b in rep["blobs"]} == {None}


@pytest.mark.parametrize(("a", "b", "extra", "message"), [
    ("zcut", "zcut", (), "differ in nothing"),
    ("sor_default.toml", "zcut", (), "its masks cannot differ"),  # both compare zcut, with the same parameters
    ("sor_default.toml", "sor", (), None),  # zcut vs sor: allowed
    ("sor_default.toml", "sor.toml", ("--region", "everything"), "--region must be one of"),
    ("zcut", "nonsense", (), "neither a file nor a method name"),
    ("zcut", "missing.toml", (), "no such file"),
    ("other.results.mcap", "zcut", (), "the results of other.mcap, not of log.mcap"),
    ("rho.results.mcap", "rho.results.mcap", (), "the same results file"),
    ("zcut", "sor", ("--frames", "5:2"), "--frames must satisfy"),
])
def test_bad_input_is_one_line(data, tmp_path, capsys, a, b, extra, message):
    def arg(x: str) -> str:
        return str(data / x) if x.endswith((".toml", ".mcap")) else x

    rc, _, err = run_cli(capsys, "compare", data / "log.mcap", "--a", arg(a), "--b", arg(b), "-o", tmp_path / "x",
                         "--no-rrd", *IN_PROCESS, *extra)
    if message is None:
        assert rc == 0, err
        return
    assert rc == 1, err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("error: ") and message in lines[-1], err
    assert "Traceback" not in err
    assert not any((tmp_path / "x").glob("*.json"))


def test_a_truth_a_log_lacks_is_one_line_before_anything_is_written(data, tmp_path, capsys):
    """``--truth`` asked of logs one of which lacks it (checked on the planning's reader): one line naming
    that log as given, exit 1, nothing written; the logs that have it compare."""
    for logs in ((data / "notruth.mcap",), (data / "log.mcap", data / "notruth.mcap")):
        rc, _, err = run_cli(capsys, "compare", *logs, "--a", "zcut", "--b", "sor", "--truth", "sensor", "-o",
                             tmp_path / "t", "--no-rrd")
        assert rc == 1, err
        lines = err.strip().splitlines()
        assert lines[-1] == (f"error: {data / 'notruth.mcap'} has no /ground_truth/outliers (--truth sensor): give "
                             "human labels with --labels DB"), err
        assert not (tmp_path / "t").exists() or not any((tmp_path / "t").iterdir())
    rc, out, err = run_cli(capsys, "compare", data / "log.mcap", "--a", "zcut", "--b", "sor", "--truth", "sensor",
                           "-o", tmp_path / "ok", "--no-rrd", "--json", *IN_PROCESS)
    assert rc == 0, err
    assert "sensor" in json.loads(out)["truth"]


@pytest.fixture(scope="module")
def other_labels(data):
    """A label store that holds labels of other.mcap only (frames of the same stamps as log.mcap's)."""
    from annotate_helpers import added_frames

    from annotate.store import LabelStore

    db = data / "other_labels.sqlite"
    if not db.exists():
        with LabelStore(db) as s:
            for rec, fr, valid in added_frames(s, s.add_log(data / "other.mcap"), data / "other.mcap"):
                s.save_label(rec, annotator="ann", outliers=np.zeros(fr.shape, bool), reviewed=valid,
                             base_revision=0)
    return db


@pytest.mark.parametrize(("log", "a", "b", "extra", "message"), [
    ("log.mcap", "zcut", "zcut", (), "they differ in nothing"),
    ("log.mcap", "other.results.mcap", "zcut", (), "the results of other.mcap, not of log.mcap"),
    ("notruth.mcap", "zcut", "sor", ("--truth", "sensor"), "notruth.mcap has no /ground_truth/outliers (--truth sensor)"),
    ("notruth.mcap", "zcut", "sor", ("--truth", "paper", "--ray", "127.0.0.1:1"),
     "notruth.mcap has no /ground_truth/off_surface (--truth paper)"),
    ("log.mcap", "zcut", "sor", ("--labels", "other_labels.sqlite"),
     "no labels of log.mcap (its content is not in the store; labelled logs: other.mcap)"),
])
def test_bad_input_is_one_line_before_anything_starts(data, other_labels, tmp_path, capsys, monkeypatch, log, a, b,
                                                      extra, message):
    """Issue 33, Deliver 1: configs that differ in nothing, a results file of another log, a truth the log
    lacks, labels of another log: one line, exit 1, before the executor is made (no worker started, no
    Ray cluster connected to: an unreachable one is not even reached) and before DIR is created."""
    from studies import executors

    made = []
    real = executors.make_executor
    monkeypatch.setattr(executors, "make_executor", lambda **kw: made.append(kw) or real(**kw))

    def arg(x: str) -> str:
        return str(data / x) if x.endswith((".toml", ".mcap", ".sqlite")) else x

    workers = () if "--ray" in extra else ("--workers", "1")
    rc, _, err = run_cli(capsys, "compare", data / log, "--a", arg(a), "--b", arg(b), "-o", tmp_path / "x",
                         *workers, *(arg(x) for x in extra))
    assert rc == 1, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("zcut: compiling")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert made == []  # nothing started
    assert not (tmp_path / "x").exists()  # nothing left


def test_existing_outputs_need_force(data, tmp_path, capsys):
    args = ("compare", data / "log.mcap", "--a", "zcut", "--b", "sor", "-o", tmp_path / "f", "--no-rrd", *IN_PROCESS)
    assert run_cli(capsys, *args)[0] == 0
    rc, _, err = run_cli(capsys, *args)
    assert rc == 1 and "use --force" in err
    assert run_cli(capsys, *args, "--force")[0] == 0


def test_the_recording_reads_back(data, tmp_path, capsys):
    import rerun as rr

    rc, _, err = run_cli(capsys, "compare", data / "log.mcap", "--a", "zcut", "--b", data / "rho.toml",
                         "-o", tmp_path / "r", *IN_PROCESS)
    assert rc == 0, err
    paths: dict[str, int] = {}
    config_text = ""
    for chunk in rr.chunk.RrdReader(str(tmp_path / "r" / "compare.rrd")).stream():
        paths[chunk.entity_path] = paths.get(chunk.entity_path, 0) + chunk.num_rows
        if chunk.entity_path == "/diff/config":
            rb = chunk.to_record_batch()
            for name in rb.schema.names:
                if name.endswith("text"):
                    config_text += "".join(str(x) for x in rb.column(name).to_pylist())
    for p in ("/diff/config", "/image/rgb", "/a/verdict", "/b/verdict", "/diff/consequence", "/diff/points",
              "/a/scalars/f1", "/b/scalars/f1", "/diff/scalars/delta_f1"):
        assert p in paths, (p, sorted(paths))
    assert "`zcut.max_area_px`" in config_text and "`methods`" in config_text


def test_a_blobs_height_and_distance_to_what_was_kept():
    """A blob floating 10 mm above a plane the two sides kept: its height is 10 mm and its distance to
    the kept surface 10 mm (it sits straight above it); a blob in the plane: 0 and the pixel pitch's
    distance; nothing kept: both unknown (docs/compare.md, ``blobs``)."""
    from studies.compare import disagreement_blobs

    h, w = 40, 50
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    xyz = np.dstack([cols * 0.001, rows * 0.001, np.full((h, w), 1.0)])  # a plane 1 m away, 1 mm pitch
    xyz[10:13, 10:13, 2] -= 0.010  # a patch 10 mm nearer the camera
    a = np.zeros((h, w), bool)
    b = np.zeros((h, w), bool)
    b[10:13, 10:13] = True  # B removed the floating patch
    a[30, 30] = True  # A removed one pixel of the plane
    where = np.ones((h, w), bool)
    where[:, 45:] = False
    blobs = {bl.who: bl for bl in disagreement_blobs("l", 0, 0, a, b, where, xyz=xyz.astype(np.float32))}
    assert blobs["B"].height_mm == pytest.approx(10.0, abs=1e-3)
    assert blobs["B"].part_mm == pytest.approx(10.0, abs=0.1)  # its edge pixels: 10 mm up, 1 mm across
    assert blobs["A"].height_mm == pytest.approx(0.0, abs=1e-3)
    assert blobs["A"].part_mm == pytest.approx(1.0, abs=1e-3)
    assert set(blobs["A"].as_dict()) >= {"height_mm", "part_mm"}
    xyz[..., 2] = np.nan  # nothing kept: unknown
    blobs = disagreement_blobs("l", 0, 0, a, b, where, xyz=xyz)
    assert all(bl.height_mm is None and bl.part_mm is None for bl in blobs)
    assert all(bl.height_mm is None for bl in disagreement_blobs("l", 0, 0, a, b, where))  # no points given


def test_per_class_figures_equal_accuracys(data, tmp_path, capsys):
    """compare.json's ``per_class``: A's and B's pooled cluster, singleton and per-kind figures are
    those ``zcut accuracy`` reports for each side's method, and Δ is B − A (issue 33 item 5)."""
    rc, out, err = run_cli(capsys, "compare", data / "log.mcap", "--a", "zcut", "--b", "sor", "--truth", "sensor",
                           "-o", tmp_path / "c", "--no-rrd", "--json")
    assert rc == 0, err
    per = json.loads(out)["per_class"]
    acc = _accuracy(capsys, data / "log.mcap", "--truth", "sensor", "--methods", "zcut,sor")["pooled"]
    for side, m in (("a", "zcut"), ("b", "sor")):
        assert per["clusters"]["recall"][side] == pytest.approx(acc[m]["cluster_recall"])
        assert per["singletons"]["precision"][side] == pytest.approx(acc[m]["singletons_precision"])
        for kind, k in acc[m]["by_kind"].items():
            if k["n"]:
                assert per[f"kind {kind}"]["recall"][side] == pytest.approx(k["recall"]), kind
    for cls in per.values():
        for e in cls.values():
            assert e["delta"] == pytest.approx(e["b"] - e["a"])
    page = (tmp_path / "c" / "report.html").read_text()
    assert "Per class of the truth" in page and "kind floating" in page


def test_a_shared_cut_tree_gives_the_masks_and_clusters_of_two_replays(data):
    """A = the paper's z-cut, B = ρ_thr 0.035: the same Δd, cuts and connectivity, so B's z-cut is read out
    of A's tree (one tree a frame), and every side's z-cut result is that of its own replay, bit for bit."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession, open_log
    from studies.compare import PairRunner

    log = data / "log.mcap"
    sa = ReplaySession.open(log, overrides={"methods": ["zcut"]}, choose_bin_model=lambda r: bin_model_for(r, None))
    sb = ReplaySession.open(log, config_file=data / "rho.toml", choose_bin_model=lambda r: bin_model_for(r, None))
    assert sa.resolved.config.zcut.max_area != sb.resolved.config.zcut.max_area
    reader, first, _ = open_log(log)
    runner = PairRunner(log, reader, first, sa.resolved, sb.resolved, sa.bin_model)
    assert runner.share_tree and runner.shared == ()
    pairs = list(runner.frames((0, None)))
    assert runner.trees == FRAMES
    assert runner.runs["method:zcut"] == 2 * FRAMES  # each side's z-cut answered, from one tree
    tagged = 0
    for (_, ra, rb), (_, xa), (_, xb) in zip(pairs, sa.results(), sb.results(), strict=True):
        for got, alone in ((ra, xa), (rb, xb)):
            assert got.outliers.keys() == alone.outliers.keys()
            for m in got.outliers:
                assert np.array_equal(got.outliers[m], alone.outliers[m])
            for name in ("outliers", "clusters", "areas", "rho", "levels", "level_counts", "pixel_level"):
                x, y = getattr(got.cut, name), getattr(alone.cut, name)
                assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name
        tagged += int(ra.cut.outliers.sum()) + int(rb.cut.outliers.sum())
    assert tagged > 0


def test_a_shared_cut_tree_gives_the_same_outputs(data, tmp_path, monkeypatch):
    """compare.json, summary.parquet and disagreement.npz of a comparison whose B reads A's tree equal
    those of the same comparison with a tree for each side (as before the tree was shared)."""
    import studies.compare as compare
    from studies.compare import CompareOptions, run

    log = data / "log.mcap"

    def outputs(out):
        rep = json.loads((out / "compare.json").read_text())
        for k in ("cost", "outputs"):
            rep.pop(k)
        with np.load(out / "disagreement.npz") as z:
            npz = {k: z[k].tolist() for k in z.files}
        return (json.dumps(rep, sort_keys=True).replace(str(out), "OUT"),
                pq.read_table(out / "summary.parquet").to_pylist(), npz)

    trees = []
    real = compare.PairRunner._shared_cuts

    def spy(self, zone):
        got = real(self, zone)
        trees.append(got is not None)
        return got

    monkeypatch.setattr(compare.PairRunner, "_shared_cuts", spy)
    opts = dict(logs=(log,), a="zcut", b=str(data / "rho.toml"), rrd=False, report=False, workers=0)
    run(CompareOptions(**opts, out=tmp_path / "shared"))
    shared = outputs(tmp_path / "shared")
    assert trees == [True] * FRAMES
    monkeypatch.setattr(compare, "shares_cut_tree", lambda a, b: False)
    run(CompareOptions(**opts, out=tmp_path / "alone"))
    alone = outputs(tmp_path / "alone")
    assert len(trees) == FRAMES  # no tree shared the second time
    assert shared == alone
    assert json.loads(shared[0])["frames"] and any(f["only_a"] for f in json.loads(shared[0])["frames"])
