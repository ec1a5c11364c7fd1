"""`zcut compare` keeps the pixels where A and B disagree (disagreement.npz), and `zcut annotate LOG
--disagreement DIR` lists exactly those pixels as review groups; a bad DIR is one line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from cli_helpers import run_cli
from session_logs import synth_once

from annotate.disagreement import FILE, ONLY_A, ONLY_B, load
from annotate.payload import parse_bundle, prepare_frame
from cli.main import main
from replay.pipeline.session import ReplaySession

SIZE = "120x180"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("disagreement")
    log = d / "log.mcap"
    # tests/replay/pipeline/test_replay_verdicts.py's log too: made once per session, copied here
    shutil.copyfile(synth_once(tmp_path_factory, parts="rods", frames=3, seed=5, size=SIZE), log)
    other = d / "other.mcap"
    assert main(["synth", "-o", str(other), "--parts", "spheres", "--frames", "2", "--seed", "6", "--size", SIZE]) == 0
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    assert main(["compare", str(log), "--a", "sor", "--b", str(d / "rho.toml"), "-o", str(d / "cmp"), "--no-rrd",
                 "--json"]) == 0
    return d


def test_compare_keeps_the_pixels_it_counts(data):
    rep = json.loads((data / "cmp" / "compare.json").read_text())
    assert rep["outputs"]["disagreement"].endswith(FILE)
    dis = load(data / "cmp", data / "log.mcap")
    assert dis.primaries == (rep["a"]["primary"], rep["b"]["primary"]) == ("sor", "zcut")
    assert len(dis.frames) == len(rep["frames"]) == 3
    for f in rep["frames"]:
        shape, pix, who = dis.frames[f["stamp_ns"]]
        assert shape == (180, 120)
        assert (int(np.count_nonzero(who == ONLY_A)), int(np.count_nonzero(who == ONLY_B))) == (f["only_a"], f["only_b"])
        assert np.all(np.diff(pix) > 0)
    assert dis.n_pixels == rep["agreement"]["only_a"] + rep["agreement"]["only_b"] > 0


def test_the_groups_are_exactly_the_disagreement(data):
    dis = load(data / "cmp", data / "log.mcap")
    session = ReplaySession.open(data / "log.mcap")
    results = session.results()
    try:
        for frame, r in results:
            focus = dis.focus(frame)
            header, arrays = parse_bundle(prepare_frame(frame, r, focus=focus).served.bundle)
            assert header["focus"] is True
            ids = arrays["groups"]
            assert np.array_equal(ids > 0, focus > 0), frame.index
            src = arrays["group_table"][:, 11].astype(int)  # GCOL["source"]
            names = [header["group_sources"][s] for s in src]
            for g, name in zip(arrays["group_table"][:, 0].astype(int), names):
                codes = set(focus[ids == g].tolist())
                assert codes == {ONLY_A if name == "removed only by A" else ONLY_B}, (g, name, codes)
            assert header["n_groups"] <= 40
            plain, _ = parse_bundle(prepare_frame(frame, r).served.bundle)
            assert plain["focus"] is False
    finally:
        results.close()


@pytest.mark.parametrize(("what", "message"), [
    ("missing", "not a folder"),
    ("empty", "not a zcut compare output (no compare.json"),
    ("no_npz", f"no {FILE} in it"),
    ("broken", f"{FILE} does not read"),
    ("other_log", "that comparison is of log.mcap, not of other.mcap"),
])
def test_a_bad_folder_is_one_line(data, tmp_path, capsys, what, message):
    log = data / ("other.mcap" if what == "other_log" else "log.mcap")
    d = tmp_path / "d"
    if what != "missing":
        d.mkdir()
    if what in ("no_npz", "broken", "other_log"):
        shutil.copy(data / "cmp" / "compare.json", d / "compare.json")
    if what == "broken":
        (d / FILE).write_bytes(b"PK\x03\x04 not a zip")
    if what == "other_log":
        shutil.copy(data / "cmp" / FILE, d / FILE)
    rc, out, err = run_cli(capsys, "annotate", log, "--db", tmp_path / "l.sqlite", "--no-browser",
                           "--disagreement", d)
    assert rc == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert not (tmp_path / "l.sqlite").exists()  # refused before the store is touched
