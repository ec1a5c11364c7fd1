"""``zcut accuracy --labels``: the labels' own agreement with the fits (``labels_vs_fits``, issue 29 item 6).

Real small logs (spike frames without a bin model: ``explained`` judges them against the local
surface alone; a synthetic spheres log with its part model: the part fits), a real SQLite label
store, a results file holding ``explained``'s mask; the counts checked by hand against the method's
mask as ``zcut replay --out`` writes it.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from annotate_helpers import write_spike_log
from cli_helpers import synth_log

from annotate.accuracy import (
    AgreementCounts,
    LabelsVsFits,
    accuracy_report,
    format_accuracy_table,
    frame_accuracy,
    labels_vs_fits,
)
from annotate.store import LabelStore
from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader


def _json(capsys, argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def _label(db, log, labels):
    """``labels``: frame index -> (outliers, reviewed), saved by "ann" in a new store at ``db``."""
    with LabelStore(db) as s:
        lg = s.add_log(log)
        for fr in LogReader(log).frames():
            rec = s.add_frame(lg, topic=fr.topic, stamp_ns=fr.stamp_ns, index=fr.index, shape=fr.shape,
                              frame_id=fr.frame_id, valid=np.isfinite(fr.xyz).all(axis=2))
            if fr.index in labels:
                L, R = labels[fr.index]
                s.save_label(rec, annotator="ann", outliers=L, reviewed=R, base_revision=0)


def _explained_masks(log, out, *extra):
    """Per frame: (explained's outliers, the scored zone) of ``zcut replay --out`` with explained."""
    assert main(["replay", str(log), "--methods", "zcut,explained", "--out", str(out), *map(str, extra)]) == 0
    return {fr.index: (fr.masks[layout.method_topic("explained")], fr.masks.get(layout.ZONE))
            for fr in LogReader(out, cloudless=True).frames()}


def _hand(L, R, U):
    return {"decided": int(R.sum()), "both": int((L & U & R).sum()),
            "labelled_outlier_explained": int((L & R & ~U).sum()),
            "labelled_inlier_unexplained": int((U & R & ~L).sum())}


@pytest.fixture(scope="module")
def spikes(tmp_path_factory):
    d = tmp_path_factory.mktemp("fits")
    log = d / "scan.mcap"
    truths = write_spike_log(log, frames=3)
    masks = _explained_masks(log, d / "res.mcap")
    return log, truths, masks, d / "res.mcap"


def test_labels_against_the_local_surface_counted_by_hand(spikes, tmp_path, capsys):
    log, truths, masks, results = spikes
    valid = [np.isfinite(fr.xyz).all(axis=2) for fr in LogReader(log).frames()]
    R2 = valid[2].copy()
    R2[:, 100:] = False  # frame 2 decided on its left part only
    rng = np.random.default_rng(3)
    # a careless annotator: stray pixels labelled, and what explained flags left out
    L0 = (truths[0] | (rng.random(valid[0].shape) < 0.01)) & valid[0] & ~masks[0][0]
    labels = {0: (L0, valid[0]), 2: (truths[2] & R2, R2)}
    db = tmp_path / "labels.sqlite"
    _label(db, log, labels)
    rep = _json(capsys, ["accuracy", log, "--labels", db, "--annotator", "ann", "--json"])
    assert [m for m in rep["pooled"]] == ["zcut", "sor", "union", "intersection"]  # explained is not reported
    total = {"decided": 0, "both": 0, "labelled_outlier_explained": 0, "labelled_inlier_unexplained": 0}
    for f in rep["frames"]:
        L, R = labels[f["index"]]
        U, _ = masks[f["index"]]
        vs = f["labels_vs_fits"]
        want = _hand(L, R, U)  # no bin stages: the zone is every valid pixel
        assert {k: vs[k] for k in want} == want and vs["surfaces"] == "local surface"
        assert vs["iou"] == pytest.approx(want["both"] / (want["both"] + want["labelled_outlier_explained"]
                                                          + want["labelled_inlier_unexplained"]))
        for k in total:
            total[k] += want[k]
    assert total["labelled_inlier_unexplained"] > 0 and total["labelled_outlier_explained"] > 0  # they disagree
    pooled = rep["labels_vs_fits"]
    assert {k: pooled[k] for k in total} == total and pooled["frames"] == 2
    assert pooled["surfaces"] == "local surface"
    # the text says it
    capsys.readouterr()
    assert main(["accuracy", str(log), "--labels", str(db), "--annotator", "ann"]) == 0
    text = capsys.readouterr().out
    assert "labels against the fits (explained, local surface) on 2 frames" in text
    assert f"{total['labelled_outlier_explained']} labelled outlier but explained" in text
    assert f"{total['labelled_inlier_unexplained']} labelled inlier but unexplained" in text
    # a results file holding explained's mask gives the same counts
    again = _json(capsys, ["accuracy", results, "--labels", db, "--annotator", "ann", "--json"])
    assert again["labels_vs_fits"] == {**pooled, "surfaces": "results file"}
    # the recorded truth: no labels, no such entry
    assert "labels_vs_fits" not in _json(capsys, ["accuracy", log, "--json"])


def test_a_results_file_without_explained_has_no_agreement(spikes, tmp_path, capsys):
    log, truths, _, _ = spikes
    plain = tmp_path / "plain.mcap"
    assert main(["replay", str(log), "--out", str(plain)]) == 0
    valid = np.isfinite(next(iter(LogReader(log).frames())).xyz).all(axis=2)
    db = tmp_path / "labels.sqlite"
    _label(db, log, {0: (truths[0] & valid, valid)})
    rep = _json(capsys, ["accuracy", plain, "--labels", db, "--json"])
    assert "labels_vs_fits" not in rep and "labels_vs_fits" not in rep["frames"][0]
    capsys.readouterr()
    assert main(["accuracy", str(plain), "--labels", str(db)]) == 0
    assert "labels against the fits: not known" in capsys.readouterr().out


@pytest.mark.slow
def test_labels_against_the_part_fits(tmp_path, capsys):
    """A log with its part model: the agreement is with the part fits (labels: the paper's truth)."""
    log = synth_log(tmp_path / "spheres.mcap", parts="spheres", frames=1, seed=9602, size="320x200")
    frame = next(iter(LogReader(log).frames()))
    valid = np.isfinite(frame.xyz).all(axis=2)
    db = tmp_path / "labels.sqlite"
    _label(db, log, {0: (frame.masks[layout.TRUTH_OFF_SURFACE] & valid, valid)})
    rep = _json(capsys, ["accuracy", log, "--labels", db, "--json"])
    vs = rep["labels_vs_fits"]
    assert vs["surfaces"] == "part fits" and vs["frames"] == 1 and vs["both"] > 0
    assert vs["both"] + vs["labelled_outlier_explained"] + vs["labelled_inlier_unexplained"] + vs["neither"] \
        == vs["decided"] > 0.2 * valid.sum()  # the zone and the points above the rim


def test_labels_vs_fits_pooled_and_shown():
    L = np.zeros((4, 5), bool)
    L[0, :3] = True
    U = np.zeros_like(L)
    U[0, 1:4] = True
    R = np.ones_like(L)
    R[3] = False
    region = np.ones_like(L)
    region[:, 4] = False
    vs = labels_vs_fits(L, R, U, region, surfaces="part fits")
    assert vs.counts == AgreementCounts(both=2, only_a=1, only_b=1, neither=8)
    assert vs.as_dict() == {"surfaces": "part fits", "decided": 12, "both": 2, "labelled_outlier_explained": 1,
                            "labelled_inlier_unexplained": 1, "neither": 8, "iou": 0.5,
                            "kappa": pytest.approx(vs.counts.kappa)}
    other = LabelsVsFits(AgreementCounts(1, 0, 0, 3), "local surface")
    assert (vs + other).surfaces == "part fits, local surface" and (vs + other).counts.both == 3
    frames = [frame_accuracy(i, i, {"zcut": U}, L, reviewed=R, region=region, undecided=True) for i in range(3)]
    frames[0] = dataclasses.replace(frames[0], labels_vs_fits=vs)
    frames[2] = dataclasses.replace(frames[2], labels_vs_fits=other)
    rep = accuracy_report(frames, region="zone")
    assert rep["labels_vs_fits"]["frames"] == 2 and rep["labels_vs_fits"]["both"] == 3
    assert "labels_vs_fits" in rep["frames"][0] and "labels_vs_fits" not in rep["frames"][1]
    text = format_accuracy_table(rep)
    assert "labels against the fits (explained, part fits, local surface) on 2 frames: over the 16 decided pixels" in text
    assert "labels_vs_fits" not in accuracy_report(frames[1:2], region="zone")
