"""``zcut accuracy`` on real small logs, results files and a real label store."""

from __future__ import annotations

import json

import numpy as np
import pytest
from annotate_helpers import spike_frame, write_spike_log

from annotate.accuracy import agreement_counts
from annotate.store import LabelStore
from cli.main import main
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter
from zcut.metrics import cohen_kappa, mask_iou


@pytest.fixture(scope="module")
def spike_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("acc")
    log = d / "scan.mcap"
    truths = write_spike_log(log, frames=3)
    return log, truths


@pytest.fixture(scope="module")
def predictions(spike_log):
    """The pipeline's masks per frame, as `zcut replay` writes them to a results file."""
    log, _ = spike_log
    results = log.with_name("results.mcap")
    assert main(["replay", str(log), "--out", str(results)]) == 0
    preds = []
    for fr in LogReader(results, cloudless=True).frames():
        preds.append((fr.masks["/zcut/outliers"], fr.masks["/zcut/sor_outliers"]))
    return results, preds


def _json(capsys, argv):
    capsys.readouterr()
    code = main(argv)
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def _hand(P, L, R):
    return {"tp": int((P & L & R).sum()), "fp": int((P & R & ~L).sum()), "fn": int((L & R & ~P).sum())}


def test_ground_truth_from_log_and_from_results_agree_and_match_hand_counts(spike_log, predictions, capsys):
    log, truths = spike_log
    results, preds = predictions
    from_log = _json(capsys, ["accuracy", str(log), "--json"])
    from_results = _json(capsys, ["accuracy", str(results), "--json"])
    # the bin check: known on the log (no bin model: nothing flagged), not carried by a results file
    assert from_log.pop("bin_flagged") == 0 and from_results.pop("bin_flagged") is None
    for a, b in zip(from_log["frames"], from_results["frames"]):
        assert (a.pop("bin_check"), a.pop("bin_flagged")) == (None, False)
        assert (b.pop("bin_check"), b.pop("bin_flagged")) == (None, None)
    assert from_log == from_results
    assert [f["index"] for f in from_log["frames"]] == [0, 1, 2]
    pooled = {m: {"tp": 0, "fp": 0, "fn": 0} for m in ("zcut", "sor", "union", "intersection")}
    everything = np.ones(truths[0].shape, bool)
    for f, L, (z, s) in zip(from_log["frames"], truths, preds):
        for m, P in (("zcut", z), ("sor", s), ("union", z | s), ("intersection", z & s)):
            hand = _hand(P, L, everything)
            assert {k: f[m][k] for k in hand} == hand, m
            for k in hand:
                pooled[m][k] += hand[k]
    for m in pooled:
        assert {k: from_log["pooled"][m][k] for k in ("tp", "fp", "fn")} == pooled[m]
        assert all(isinstance(from_log["pooled"][m][k], int) for k in ("tp", "fp", "fn"))
    assert from_log["pooled"]["zcut"]["tp"] > 0  # the flying spikes are found at all


def test_table_output(spike_log, predictions, capsys):
    log, _ = spike_log
    results, _ = predictions
    assert main(["accuracy", str(results)]) == 0
    out = capsys.readouterr().out
    assert ("truth: the sensor's truth /ground_truth/outliers (the log has no /ground_truth/off_surface); "
            "predictions: from /zcut/outliers") in out
    assert "pooled over 3 frames" in out and "intersection" in out


def _label_store(db, log, labels_by_annotator):
    with LabelStore(db) as s:
        lg = s.add_log(log)
        recs = {}
        for fr in LogReader(log).frames():
            recs[fr.index] = s.add_frame(lg, topic=fr.topic, stamp_ns=fr.stamp_ns, index=fr.index, shape=fr.shape,
                                         frame_id=fr.frame_id, valid=np.isfinite(fr.xyz).all(axis=2))
        for who, per_frame in labels_by_annotator.items():
            for i, (L, R) in per_frame.items():
                s.save_label(recs[i], annotator=who, outliers=L, reviewed=R, base_revision=0)


def _truth_store(db, log, truths, frames):
    """A store at ``db`` in which "ann" labelled ``frames`` of ``log`` with their truth, every valid pixel
    reviewed; returns every frame's valid mask."""
    valid = [np.isfinite(fr.xyz).all(axis=2) for fr in LogReader(log).frames()]
    _label_store(db, log, {"ann": {i: (truths[i] & valid[i], valid[i]) for i in frames}})
    return valid


def test_human_labels_and_agreement(spike_log, predictions, tmp_path, capsys):
    log, truths = spike_log
    results, preds = predictions
    rng = np.random.default_rng(11)
    valid = [np.isfinite(fr.xyz).all(axis=2) for fr in LogReader(log).frames()]
    # ann labels frames 0 and 2 with the truth, reviewing the left 3/4 of frame 2 only; bob labels frame 2
    R2 = valid[2].copy()
    R2[:, 120:] = False
    ann = {0: (truths[0] & valid[0], valid[0]), 2: (truths[2] & R2, R2)}
    bob_L = (truths[2] | (rng.random(R2.shape) < 0.02)) & valid[2]
    bob = {2: (bob_L, valid[2])}
    db = tmp_path / "labels.sqlite"
    _label_store(db, log, {"ann": ann, "bob": bob})

    # two annotators: must choose
    assert main(["accuracy", str(log), "--labels", str(db)]) == 1
    assert "--annotator" in capsys.readouterr().err
    assert main(["accuracy", str(log), "--labels", str(db), "--annotator", "zoe"]) == 1
    assert "zoe" in capsys.readouterr().err

    rep = _json(capsys, ["accuracy", str(log), "--labels", str(db), "--annotator", "ann", "--json"])
    assert [f["index"] for f in rep["frames"]] == [0, 2]  # frame 1 has no label: skipped
    for f in rep["frames"]:
        L, R = ann[f["index"]]
        z, s = preds[f["index"]]
        assert {k: f["zcut"][k] for k in ("tp", "fp", "fn")} == _hand(z, L, R)
        assert {k: f["sor"][k] for k in ("tp", "fp", "fn")} == _hand(s, L, R)
        # how much of each verdict fell on pixels ann left undecided (no bin stages: the zone is every valid pixel)
        v = valid[f["index"]]
        for m, p in (("zcut", z), ("sor", s), ("union", z | s), ("intersection", z & s)):
            assert f[m]["undecided"] == {"px": int((p & v & ~R).sum()), "flagged": int((p & v).sum()),
                                         "share": pytest.approx(int((p & v & ~R).sum()) / int((p & v).sum()))}, m
    assert rep["frames"][1]["union"]["undecided"]["px"] > 0 and rep["frames"][0]["union"]["undecided"]["px"] == 0
    u = rep["pooled"]["union"]["undecided"]
    assert u["px"] == rep["frames"][1]["union"]["undecided"]["px"] and u["share"] == pytest.approx(u["px"] / u["flagged"])
    rc = main(["accuracy", str(log), "--labels", str(db), "--annotator", "ann"])
    text = capsys.readouterr().out
    assert rc == 0 and "undecided" in text.split("pooled over 2 frames")[1].splitlines()[1]
    assert f"{u['share']:.3f} ({u['px']})" in text and "the labels left undecided" in text
    assert "undecided" not in json.dumps(_json(capsys, ["accuracy", str(log), "--json"]))  # recorded truth: none
    # the results file finds the same labels by stamp (its cloud topic is /zcut/filtered); it does not
    # carry the bin check
    from_results = _json(capsys, ["accuracy", str(results), "--labels", str(db), "--annotator", "ann", "--json"])
    assert from_results.pop("bin_flagged") is None and rep.pop("bin_flagged") == 0
    for f in (*rep["frames"], *from_results["frames"]):
        del f["bin_check"], f["bin_flagged"]
    # the log runs explained for the labels' agreement with the fits; this results file holds no mask of it
    assert rep.pop("labels_vs_fits")["frames"] == 2 and "labels_vs_fits" not in from_results
    for f in rep["frames"]:
        del f["labels_vs_fits"]
    assert from_results == rep

    agree = _json(capsys, ["accuracy", str(log), "--labels", str(db), "--agreement", "ann", "bob", "--json"])
    assert agree["annotators"] == ["ann", "bob"] and [f["index"] for f in agree["frames"]] == [2]
    where = R2 & valid[2]
    f = agree["frames"][0]
    assert f["pixels"] == int(where.sum())
    assert f["iou"] == pytest.approx(mask_iou(ann[2][0], bob_L, where=where))
    assert f["kappa"] == pytest.approx(cohen_kappa(ann[2][0], bob_L, where=where))
    assert agree["pooled"]["pixels"] == f["pixels"]
    assert main(["accuracy", str(log), "--labels", str(db), "--agreement", "ann", "bob"]) == 0
    assert "agreement of ann and bob" in capsys.readouterr().out


def test_agreement_counts_match_metrics(rng):
    for _ in range(30):
        a, b, ra, rb = (rng.random((13, 7)) < p for p in (0.3, 0.3, 0.8, 0.7))
        a &= ra
        b &= rb
        c = agreement_counts(a, ra, b, rb)
        assert c.n == int((ra & rb).sum())
        k = cohen_kappa(a, b, where=ra & rb)
        assert (np.isnan(k) and np.isnan(c.kappa)) or c.kappa == pytest.approx(k)
        assert c.iou == pytest.approx(mask_iou(a, b, where=ra & rb), nan_ok=True)


def test_errors(spike_log, tmp_path, capsys):
    log, _ = spike_log
    bare = tmp_path / "bare.mcap"
    with LogWriter(bare) as w:
        fr, _ = spike_frame(0)
        w.write_cloud("/camera/points", fr.xyz, stamp_ns=fr.stamp_ns, frame_id="cam")
    cases = [
        (["accuracy", str(bare)], "no /ground_truth/outliers"),
        (["accuracy", str(tmp_path / "missing.mcap")], "no such file"),
        (["accuracy", str(log), "--agreement", "a", "b"], "--agreement needs --labels"),
        (["accuracy", str(log), "--labels", str(tmp_path / "none.sqlite")], "no such file"),
    ]
    for argv, msg in cases:
        assert main(argv) == 1, argv
        assert msg in capsys.readouterr().err
    empty = tmp_path / "empty.sqlite"
    LabelStore(empty).close()
    assert main(["accuracy", str(log), "--labels", str(empty)]) == 1
    assert "no labels of scan.mcap (its content is not in the store; labelled logs: none)" in capsys.readouterr().err


def test_labels_list_export_import(spike_log, tmp_path, capsys):
    log, truths = spike_log
    db = tmp_path / "labels.sqlite"
    valid = _truth_store(db, log, truths, (0, 1))
    assert main(["labels", "list", str(log), "--db", str(db)]) == 0
    assert "ann: 2 frame(s) labelled" in capsys.readouterr().out
    out = tmp_path / "ann.mcap"
    assert main(["labels", "export", str(log), "--db", str(db), "-o", str(out)]) == 0
    assert "wrote 2 labelled frame(s) by ann" in capsys.readouterr().out
    # its rosbag2 record names the file, not the temporary it was written to
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        bag = next(dict(m.metadata)["serialized_metadata"] for m in make_reader(f).iter_metadata()
                   if m.name == "rosbag2")
    assert "partial" not in bag and "relative_file_paths:\n    - ann.mcap\n" in bag
    # the export is an MCAP with mono8 /labels/outliers and /labels/reviewed, stamped like the clouds
    from annotate.label_files import read_label_masks

    meta, masks = read_label_masks(out)
    stamps = sorted(masks)
    assert stamps == [fr.stamp_ns for fr in LogReader(log).frames()][:2]
    assert np.array_equal(masks[stamps[1]]["/labels/outliers"], truths[1] & valid[1])
    # import as another annotator: accuracy by them equals accuracy by ann
    # an annotator name from undecodable command-line bytes is refused before the store is queried
    assert main(["labels", "import", str(out), "--db", str(db), "--annotator", "\udcff\udcfe"]) == 1
    assert "character U+DCFF (unnamed) is not allowed" in capsys.readouterr().err
    assert main(["labels", "import", str(out), "--db", str(db), "--annotator", "dan"]) == 0
    assert "imported 2 label(s)" in capsys.readouterr().out
    a = _json(capsys, ["accuracy", str(log), "--labels", str(db), "--annotator", "ann", "--json"])
    d = _json(capsys, ["accuracy", str(log), "--labels", str(db), "--annotator", "dan", "--json"])
    # the same figures; the report names whose labels scored it
    assert a.pop("truth").startswith("labels by ann (") and d.pop("truth").startswith("labels by dan (")
    assert a == d
    assert main(["labels", "export", str(log), "--db", str(db), "-o", str(out)]) == 1
    assert "exists (use --force" in capsys.readouterr().err  # outputs are checked before anything else
    assert main(["labels", "export", str(log), "--db", str(db), "-o", str(out.with_name("two.mcap"))]) == 1
    assert "2 annotators" in capsys.readouterr().err
    other = tmp_path / "other.mcap"
    write_spike_log(other, frames=1, seed=5)
    assert main(["labels", "list", str(other), "--db", str(db)]) == 1
    assert "not registered" in capsys.readouterr().err


def test_json_says_which_frames_learned_left_out(tmp_path, capsys):
    """``learned`` is scored only on frames its model was not trained on; the JSON says per method how many
    frames it scored, which it left out and why (docs/accuracy.md), as the table's line does."""
    from annotate_helpers import label_groups

    log, db = tmp_path / "spikes.mcap", tmp_path / "labels.sqlite"
    truths = write_spike_log(log, frames=4, shape=(120, 160), seed=2)
    with LabelStore(db) as store:
        # frame 3 stays unlabelled: the model is not trained on it; a person takes the groups of >= 20 px
        taken = label_groups(store, log, skip=(3,))
    assert len(taken) == 3 and all(0 < n < listed for n, listed in taken)
    assert main(["labels", "train", str(log), "--db", str(db)]) == 0
    rep = _json(capsys, ["accuracy", str(log), "--learned", str(db), "--json"])
    learned = rep["pooled"]["learned"]
    assert learned["frames_scored"] == 1 and learned["frames_left_out"] == [0, 1, 2]
    assert "trained on" in learned["left_out_reason"]
    for m in ("zcut", "sor", "union", "intersection"):
        assert rep["pooled"][m]["frames_scored"] == 4
        assert rep["pooled"][m]["frames_left_out"] == [] and rep["pooled"][m]["left_out_reason"] is None
    by_frame = {f["index"]: f["learned"] for f in rep["frames"]}
    assert all(by_frame[i]["tp"] == by_frame[i]["fp"] == by_frame[i]["fn"] == 0 for i in (0, 1, 2))
    assert by_frame[3]["tp"] + by_frame[3]["fn"] == int(truths[3].sum())  # frame 3 is scored for learned
    assert learned["tp"] == by_frame[3]["tp"] and learned["fp"] == by_frame[3]["fp"]
    capsys.readouterr()
    assert main(["accuracy", str(log), "--learned", str(db)]) == 0
    assert "scored on the 1 frame(s) it was not trained on (3 left out)" in capsys.readouterr().out


def test_unscored_frames_are_listed_once(spike_log, tmp_path, capsys):
    """Issue 35 item 19: `--labels` printed the unscored frames three times."""
    log, truths = spike_log
    db = tmp_path / "labels.sqlite"
    _truth_store(db, log, truths, (0, 2))
    capsys.readouterr()
    assert main(["accuracy", str(log), "--labels", str(db)]) == 0
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert text.count("not labelled") == 1, text
    assert "unscored: 1 frame\n  frame 1 (stamp_ns 1100000000): not labelled" in cap.out


def test_a_log_the_store_does_not_hold_is_one_line_not_another_logs_labels(spike_log, tmp_path, capsys):
    """A log whose frames have the stamps of a labelled log but other content was scored against that log's
    labels (the stamp fallback is for results files): now one line naming the logs the store holds."""
    log, truths = spike_log
    db = tmp_path / "labels.sqlite"
    valid = [np.isfinite(fr.xyz).all(axis=2) for fr in LogReader(log).frames()]
    _label_store(db, log, {"ann": {0: (truths[0] & valid[0], valid[0])}})
    other = tmp_path / "other.mcap"
    write_spike_log(other, frames=3, seed=5)  # the same stamps, other points
    assert [f.stamp_ns for f in LogReader(other).frames()] == [f.stamp_ns for f in LogReader(log).frames()]
    capsys.readouterr()
    assert main(["accuracy", str(other), "--labels", str(db)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no labels of other.mcap" in err[0] and "scan.mcap" in err[0], err
    assert main(["batch", str(other), "--labels", str(db), "-o", str(tmp_path / "b"), "--workers", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert any("no labels of other.mcap" in e for e in err), err
