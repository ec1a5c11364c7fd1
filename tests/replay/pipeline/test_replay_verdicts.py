"""`zcut replay --rrd` shows where each filter is wrong when the log has truth (or with --labels): the
real .rrd read back with rr.chunk.RrdReader, its TP / FP / FN per frame equal to `zcut accuracy`'s."""

from __future__ import annotations

import json
import shutil
from collections import defaultdict

import numpy as np
import pytest
import rerun as rr
from cli_helpers import run_cli
from log_helpers import without_truth
from session_logs import synth_once

SIZE = "120x180"
FRAMES = 3
METHODS = ("zcut", "sor")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("verdicts")
    log = d / "log.mcap"
    # tests/annotate/test_disagreement.py's log too: made once per session, copied here
    shutil.copyfile(synth_once(tmp_path_factory, parts="rods", frames=FRAMES, seed=5, size=SIZE), log)
    without_truth(log, d / "notruth.mcap")
    return d


def read_verdicts(path) -> dict:
    """{entity path: {frame: value}}: the verdict images (as (H, W) uint8), the verdict points' class ids,
    the precision/recall scalars; and the static entity paths under ``static``."""
    out: dict = defaultdict(dict)
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        p = chunk.entity_path
        rb = chunk.to_record_batch()
        if chunk.is_static:
            out["static"][p] = rb.schema.names
            continue
        if "verdicts" not in p and not p.startswith("/accuracy"):
            out[p] = {}
            continue
        frames = rb.column("frame").to_pylist()
        names = rb.schema.names
        for i, fr in enumerate(frames):
            if "SegmentationImage:buffer" in names:
                fmt = rb.column("SegmentationImage:format").to_pylist()[i][0]
                buf = np.asarray(rb.column("SegmentationImage:buffer").to_pylist()[i][0], np.uint8)
                out[p][fr] = buf.reshape(fmt["height"], fmt["width"])
            elif "Points3D:class_ids" in names:
                out[p][fr] = np.asarray(rb.column("Points3D:class_ids").to_pylist()[i], np.int64)
            elif "Scalars:scalars" in names:
                out[p][fr] = rb.column("Scalars:scalars").to_pylist()[i][0]
            elif any(n.startswith("Clear") for n in names):
                out[p][fr] = None
    return out


def _accuracy(capsys, *argv) -> dict:
    rc, out, err = run_cli(capsys, "accuracy", *argv, "--json")
    assert rc == 0, err
    return json.loads(out)


def _check_counts(got: dict, acc: dict, frames: list[int], full_shape: tuple[int, int] = (180, 120)) -> None:
    by_frame = {f["index"]: f for f in acc["frames"]}
    assert sorted(by_frame) == frames
    for i in frames:
        for m in METHODS:
            want = tuple(by_frame[i][m][k] for k in ("tp", "fp", "fn"))
            img = got[f"/image/verdicts/{m}"][i]
            pts = got[f"/world/verdicts/{m}"][i]
            assert tuple(int(np.count_nonzero(pts == c)) for c in (1, 2, 3)) == want, (i, m)
            if img.shape == full_shape:  # --full-detail: a pixel each
                assert tuple(int(np.count_nonzero(img == c)) for c in (1, 2, 3)) == want, (i, m)
            else:  # default detail: each pixel the highest class of a 2 x 2 block
                assert img.shape == ((full_shape[0] + 1) // 2, (full_shape[1] + 1) // 2)
                n = sum(want)
                assert -(-n // 4) <= np.count_nonzero(img) <= n, (i, m)
                if n:
                    assert int(img.max()) == max(c for c, k in zip((1, 2, 3), want) if k), (i, m)
            tp, fp, fn = want
            if tp + fp:
                assert got[f"/accuracy/{m}/precision"][i] == pytest.approx(tp / (tp + fp))
            if tp + fn:
                assert got[f"/accuracy/{m}/recall"][i] == pytest.approx(tp / (tp + fn))


def test_the_verdicts_are_accuracy_s_counts(data, tmp_path, capsys):
    log = data / "log.mcap"
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", tmp_path / "r.rrd")
    assert rc == 0, err
    assert "where each filter is wrong against " in err
    got = read_verdicts(tmp_path / "r.rrd")
    _check_counts(got, _accuracy(capsys, log), list(range(FRAMES)))
    static = got["static"]
    for p in ("/image/verdicts", "/world/verdicts", "/accuracy/truth"):
        assert p in static, sorted(static)
    # some frame has mistakes of each class, so the test above compares something
    img = np.stack([got["/image/verdicts/sor"][i] for i in range(FRAMES)])
    assert all((img == c).any() for c in (1, 2, 3))


def test_the_truth_asked_for(data, tmp_path, capsys):
    log = data / "log.mcap"
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", tmp_path / "s.rrd", "--truth", "sensor", "--full-detail")
    assert rc == 0, err
    assert "/ground_truth/outliers" in err.split("wrong against", 1)[1].splitlines()[0]
    _check_counts(read_verdicts(tmp_path / "s.rrd"), _accuracy(capsys, log, "--truth", "sensor"), list(range(FRAMES)))
    rc, _, err = run_cli(capsys, "replay", data / "notruth.mcap", "--rrd", tmp_path / "p.rrd", "--truth", "paper")
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "/ground_truth/off_surface" in err, err


def test_the_blueprint_has_a_verdicts_tab():
    from replay.pipeline import viz

    root = viz.default_blueprint(("zcut", "sor"), ("zcut", "sor")).root_container
    assert isinstance(root, rr.blueprint.Tabs)
    assert [c.name for c in root.contents] == [viz.PIPELINE_TAB, viz.VERDICTS_TAB]
    view3d = root.contents[0].contents[1].contents[0]
    assert view3d.name == "3D: cloud, outliers, bin model"
    assert "- /world/verdicts/**" in str(view3d.contents)  # the verdicts' points stay in their own tab
    assert isinstance(viz.default_blueprint(("zcut", "sor")).root_container, rr.blueprint.Horizontal)  # no truth


def test_without_truth_nothing_new(data, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "replay", data / "notruth.mcap", "--rrd", tmp_path / "n.rrd")
    assert rc == 0, err
    assert "wrong against" not in err
    got = read_verdicts(tmp_path / "n.rrd")
    paths = set(got) | set(got["static"])
    assert not [p for p in paths if "verdicts" in p or p.startswith("/accuracy")], sorted(paths)


def test_labels_of_an_annotator(data, tmp_path, capsys):
    from annotate.store import LabelStore
    from replay.logs.reader import LogReader

    log = data / "log.mcap"
    db = tmp_path / "labels.sqlite"
    rng = np.random.default_rng(3)
    with LabelStore(db) as store:
        rec = store.add_log(log)
        for f in LogReader(log).frames():
            valid = np.isfinite(f.xyz).all(axis=2)
            fr = store.add_frame(rec, topic=f.topic, stamp_ns=f.stamp_ns, index=f.index, shape=f.shape,
                                 frame_id=f.frame_id, valid=valid)
            if f.index == 1:
                continue  # not labelled: not scored, its verdicts cleared
            reviewed = valid.copy()
            reviewed[:, : f.shape[1] // 3] = False  # the left third left undecided
            noisy = (f.masks["/ground_truth/outliers"] | (rng.random(f.shape) < 0.01)) & reviewed
            for who in ("ann", "bob"):
                store.save_label(fr, annotator=who, outliers=noisy, reviewed=reviewed, base_revision=0)
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", tmp_path / "l.rrd", "--labels", db)
    assert rc == 1 and err.strip().splitlines()[-1].startswith("error: ") and "--annotator" in err
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", tmp_path / "l.rrd", "--labels", db, "--annotator", "ann")
    assert rc == 0, err
    assert "labels by ann" in err
    got = read_verdicts(tmp_path / "l.rrd")
    _check_counts(got, _accuracy(capsys, log, "--labels", db, "--annotator", "ann"), [0, 2])
    assert got["/image/verdicts/zcut"][1] is None  # frame 1: cleared


def test_labels_need_a_recording(data, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "replay", data / "log.mcap", "--labels", tmp_path / "none.sqlite")
    assert rc == 1 and "give --rrd, --spawn or --connect" in err and len(err.strip().splitlines()) == 1
