"""``zcut compare``'s ``per_class`` by displacement class and by part kind (issue 33 item 5): the
displacement classes are those ``zcut accuracy --by-displacement`` counts, frame by frame; a part
kind's figures are those of the frames of that kind's logs alone."""

from __future__ import annotations

import json

import pytest
from cli_helpers import run_cli

from cli.main import main

SIZE = "120x180"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare_classes")
    for name, frames, seed in (("rods", 3, 5), ("spheres", 2, 6)):
        assert main(["synth", "-o", str(d / f"{name}.mcap"), "--parts", name, "--frames", str(frames), "--seed",
                     str(seed), "--size", SIZE]) == 0
    return d


def _json(capsys, *argv) -> dict:
    rc, out, err = run_cli(capsys, *argv, "--json")
    assert rc == 0, err
    return json.loads(out)


def test_displacement_classes_equal_accuracys_frame_by_frame(data, tmp_path, capsys):
    log = data / "rods.mcap"
    rep = _json(capsys, "compare", log, "--a", "zcut", "--b", "sor", "-o", tmp_path / "c", "--no-rrd", "--workers",
                "0")
    acc = _json(capsys, "accuracy", log, "--methods", "zcut,sor", "--by-displacement")
    assert [f["index"] for f in rep["frames"]] == [f["index"] for f in acc["frames"]] == [0, 1, 2]
    for f, fa in zip(rep["frames"], acc["frames"], strict=True):
        for side, m in (("a", "zcut"), ("b", "sor")):
            assert f["by_displacement"][side] == fa[m]["by_displacement"], (f["index"], side)
    per = rep["per_class"]
    names = ("<=1mm", "1-5mm", "5-30mm", ">30mm")
    held = [n for n in names if acc["pooled"]["zcut"]["by_displacement"][n]["n"]]
    assert held and [k for k in per if k.startswith("displacement ")] == [f"displacement {n}" for n in held]
    for n in held:
        e = per[f"displacement {n}"]["recall"]
        assert e["a"] == pytest.approx(acc["pooled"]["zcut"]["by_displacement"][n]["recall"])
        assert e["b"] == pytest.approx(acc["pooled"]["sor"]["by_displacement"][n]["recall"])
        assert e["delta"] == pytest.approx(e["b"] - e["a"])
    # one part kind: its figures are the verdict's
    assert [k for k in per if k.startswith("part ")] == ["part rods"]
    for fig, e in per["part rods"].items():
        d = rep["verdict"]["differences"][fig]
        assert e == d, fig  # the same frames, the same figures
    assert [lg["part_kind"] for lg in rep["logs"]] == ["rods"]


def test_two_part_kinds_hold_their_own_frames(data, tmp_path, capsys):
    argv = ("--a", "zcut", "--b", "sor", "--no-rrd", "--workers", "0")
    both = _json(capsys, "compare", data / "rods.mcap", data / "spheres.mcap", *argv, "-o", tmp_path / "both")
    per = both["per_class"]
    assert [k for k in per if k.startswith("part ")] == ["part rods", "part spheres"]
    assert [lg["part_kind"] for lg in both["logs"]] == ["rods", "spheres"]
    for kind, frames in (("rods", 3), ("spheres", 2)):
        alone = _json(capsys, "compare", data / f"{kind}.mcap", *argv, "-o", tmp_path / kind)
        assert alone["verdict"]["frames"] == frames
        for fig in ("precision", "recall", "f1"):
            d = alone["verdict"]["differences"][fig]
            e = per[f"part {kind}"][fig]
            assert (e["a"], e["b"], e["delta"]) == pytest.approx((d["a"], d["b"], d["delta"])), (kind, fig)
            assert (e["ci"][0] is None) == (d["ci"][0] is None)


def test_displacement_mm_is_the_recorded_depths_difference(data):
    """displacement_mm (which compare calls every frame) against the literal formula on the depth read
    back by the project's own reader: the same float64 bits, every frame of a log."""
    import numpy as np

    from annotate.accuracy import displacement_mm
    from replay.pipeline.session import open_log
    from replay.synth.truth_depth import read_truth_depth

    log = data / "rods.mcap"
    depths = read_truth_depth(log)
    reader, _, _ = open_log(log)
    frames = list(reader.frames())
    assert len(frames) == 3
    for frame in frames:
        got = displacement_mm(log, frame)
        want = np.abs(frame.xyz[..., 2].astype(np.float64) - depths[frame.stamp_ns]) * 1000.0
        assert got is not None and got.dtype == np.float64
        assert np.array_equal(got, want, equal_nan=True), frame.index
        assert np.isfinite(got).sum() > 1000  # a frame of real depths, not all NaN
    assert displacement_mm(data / "missing.mcap", frames[0]) is None  # a log that cannot be read: no classes
