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


def test_the_reader_hands_each_frame_its_true_depth(data):
    """``LogReader(truth_depth=True)`` (how compare opens its logs) delivers each frame's recorded depth,
    the first frame (read at open) too; displacement_mm then takes it without reading the log (a path that
    does not exist still gives the same bits) and without the option the frames carry none."""
    import numpy as np

    from annotate.accuracy import displacement_mm
    from replay.pipeline.session import open_log
    from replay.synth.truth_depth import read_truth_depth
    from studies.compare import READER_OPTIONS

    log = data / "rods.mcap"
    depths = read_truth_depth(log)
    reader, first, _ = open_log(log, reader_options=READER_OPTIONS)
    frames = list(reader.frames(decoded=first))
    assert frames[0] is first and len(frames) == 3
    for frame in frames:
        assert frame.truth_depth_m is not None and not frame.truth_depth_m.flags.writeable
        assert np.array_equal(frame.truth_depth_m, depths[frame.stamp_ns], equal_nan=True)
        want = np.abs(frame.xyz[..., 2].astype(np.float64) - depths[frame.stamp_ns]) * 1000.0
        got = displacement_mm(data / "missing.mcap", frame)  # carried: the log is not read
        assert got is not None and np.array_equal(got, want, equal_nan=True)
    plain, _, _ = open_log(log)
    assert all(f.truth_depth_m is None for f in plain.frames())


@pytest.mark.parametrize("bad", ["wrong size", "another encoding", "missing"])
def test_a_frame_with_an_unusable_true_depth_has_none_and_is_not_skipped(tmp_path, bad):
    """A depth message of the wrong size or encoding, or none for a frame: that frame carries no depth
    (no displacement classes, as before), no damage, every frame delivered; the others keep theirs."""
    import numpy as np
    from log_helpers import read_frames

    from replay.logs import layout
    from replay.logs import ros2_msgs as rm
    from replay.logs.writer import LogWriter

    rng = np.random.default_rng(71)
    log = tmp_path / "depth.mcap"
    h, w = 6, 8
    depth = {}
    with LogWriter(log) as wr:
        for i in range(3):
            stamp = 1_000 + i
            xyz = rng.uniform(0.5, 1.0, (h, w, 3)).astype(np.float32)
            wr.write_cloud(layout.CLOUD, xyz, stamp_ns=stamp, frame_id="cam")
            depth[stamp] = xyz[..., 2] + np.float32(0.001)
            if i != 1:
                wr.write_depth(layout.TRUTH_DEPTH, depth[stamp], stamp_ns=stamp, frame_id="cam")
            elif bad == "wrong size":
                wr.write_depth(layout.TRUTH_DEPTH, depth[stamp][:, :-1].copy(), stamp_ns=stamp, frame_id="cam")
            elif bad == "another encoding":  # millimetres as 16-bit integers
                msg = rm.encode_image(stamp_ns=stamp, frame_id="cam", height=h, width=w, encoding="16UC1",
                                      step=2 * w, data=(1000 * depth[stamp]).astype("<u2").tobytes())
                wr._add(layout.TRUTH_DEPTH, rm.IMAGE, msg, stamp)
    frames, damage = read_frames(log, truth_depth=True)
    assert damage == [] and [f.index for f in frames] == [0, 1, 2]
    assert frames[1].truth_depth_m is None
    for f in (frames[0], frames[2]):
        assert np.array_equal(f.truth_depth_m, depth[f.stamp_ns])
