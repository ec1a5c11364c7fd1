"""``zcut record-stereo`` matches the right view once a frame, whatever the number of left-right tolerances it
records (h/stereo4): the masks are test_record_stereo_rejected's (checked there against the check built in the test);
here the number of right-view matches is counted and the masks compared with each tolerance recorded on its own."""

from __future__ import annotations

import numpy as np
import pytest
from stereo_helpers import motorcycle, write_scene

import zcut.stereo as stereo
from replay.logs.reader import LogReader


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("once") / "Motorcycle", motorcycle(4))


def _masks(path):
    return [{t: m for t, m in f.masks.items() if t.startswith("/stereo/rejected/")} for f in LogReader(path).frames()]


def test_the_right_view_is_matched_once_a_frame(scene_dir, tmp_path, monkeypatch):
    from cli.main import main

    calls = []
    real = stereo.match_right
    monkeypatch.setattr(stereo, "match_right", lambda *a, **k: calls.append(1) or real(*a, **k))
    many = tmp_path / "many.mcap"
    assert main(["record-stereo", str(scene_dir), str(scene_dir), "-o", str(many), "--reject-axes"]) == 0
    assert len(calls) == 2  # two frames, four tolerances (0, 1, 2, 4) each
    got = _masks(many)
    assert all(len([t for t in g if "disp12_max_diff" in t]) == 4 for g in got)
    calls.clear()
    none = tmp_path / "none.mcap"
    assert main(["record-stereo", str(scene_dir), "-o", str(none), "--reject-lr", "none"]) == 0
    assert calls == []  # no left-right tolerance: the right view is not matched
    for tol in (0, 1, 2, 4):  # each tolerance recorded alone gives the mask recorded among the others
        one = tmp_path / f"lr{tol}.mcap"
        assert main(["record-stereo", str(scene_dir), "-o", str(one), "--reject-lr", str(tol),
                     "--reject-uniqueness", "none", "--reject-speckle", "none"]) == 0
        (alone,) = _masks(one)
        topic = f"/stereo/rejected/disp12_max_diff_{tol}"
        assert alone.keys() == {topic}
        for g in got:
            assert np.array_equal(g[topic], alone[topic]), tol
