"""replay.synth logs: SPEC §5 layout read back with LogReader, same bytes per seed, CLI, demo sample."""

from __future__ import annotations

import numpy as np
import pytest

from replay.cli import main
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.synth import (
    BIN,
    EMPTY_POSITIONS_MM,
    camera_distance_m,
    ensure_sample_log,
    sample_log_path,
    stamp_ns,
    synthesize_frame,
    write_synthetic_log,
)
from zcut.binmask import bin_mask
from zcut.errors import ParameterError

SIZE = (120, 160)


def test_log_holds_the_frames_and_their_truth(tmp_path):
    path = write_synthetic_log(tmp_path / "rods.mcap", kind="rods", frames=2, seed=9, size=SIZE)
    reader = LogReader(path)
    assert reader.cloud_topic == layout.CLOUD
    assert reader.image_topic == layout.IMAGE
    assert layout.TRUTH_OUTLIERS in reader.mask_topics
    assert reader.n_frames == 2
    meta = reader.metadata[layout.SYNTH_METADATA]
    assert meta["part_kind"] == "rods" and meta["seed"] == "9" and meta["shiny"] == "true"
    assert float(meta["camera_distance_m"]) == pytest.approx(camera_distance_m())
    assert 0.45 < camera_distance_m() < 0.55
    assert float(meta["bin_height_mm"]) == BIN.height_mm
    assert meta["size"] == "160x120" and meta["frames"] == "2"
    assert float(meta["p_min_mm"]) == 16.0 and float(meta["a_max_px"]) > 0
    frames = list(reader.frames())
    assert reader.damage == []
    assert len(frames) == 2
    for i, f in enumerate(frames):
        sf = synthesize_frame(kind="rods", seed=9, index=i, size=SIZE)
        assert f.stamp_ns == stamp_ns(9, i) == sf.frame.stamp_ns
        assert f.frame_id == sf.frame.frame_id
        np.testing.assert_array_equal(f.xyz, sf.frame.xyz)  # NaN where NaN, bit-equal elsewhere
        np.testing.assert_array_equal(f.rgb, sf.frame.rgb)
        np.testing.assert_array_equal(f.masks[layout.TRUTH_OUTLIERS], sf.truth)
        assert f.masks[layout.TRUTH_OUTLIERS].any()
        assert f.intrinsics == sf.frame.intrinsics
        assert np.isfinite(f.xyz[f.masks[layout.TRUTH_OUTLIERS]]).all()


def test_same_seed_same_bytes(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    kw = dict(kind="black_screws", frames=2, size=SIZE)
    a = write_synthetic_log(tmp_path / "a" / "log.mcap", seed=5, **kw).read_bytes()
    b = write_synthetic_log(tmp_path / "b" / "log.mcap", seed=5, **kw).read_bytes()
    c = write_synthetic_log(tmp_path / "c" / "log.mcap", seed=6, **kw).read_bytes()
    assert a == b
    assert a != c


def test_empty_bin_series_moves_the_bin(tmp_path):
    path = write_synthetic_log(tmp_path / "empty.mcap", empty=True, frames=5, seed=1, size=(240, 320))
    reader = LogReader(path)
    assert reader.metadata[layout.SYNTH_METADATA]["part_kind"] == "empty"
    assert reader.metadata[layout.SYNTH_METADATA]["empty"] == "true"
    centroids = []
    for f in reader.frames():
        assert not f.masks[layout.TRUTH_OUTLIERS][np.isnan(f.xyz[..., 2])].any()
        res = bin_mask(f.rgb)
        assert res.found
        centroids.append(res.centroid_rc)
    c = np.array(centroids)
    # the footprint (outlined by the rim, 460 mm from the camera) moves as the series says:
    # +x -> +col, +y (world) -> -row (camera y points down); +-3 mm jitter, +-2 deg yaw
    fx = 1600.0 * 320 / 1920
    shift = fx * np.array(EMPTY_POSITIONS_MM) / (580.0 - BIN.height_mm)
    np.testing.assert_allclose(c[:, 1] - c[0, 1], shift[:, 0] - shift[0, 0], atol=3.0)
    np.testing.assert_allclose(c[:, 0] - c[0, 0], -(shift[:, 1] - shift[0, 1]), atol=3.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(kind="bolts"), "kind must be one of"),
        (dict(kind="rods", frames=0), "frames must be a positive integer"),
        (dict(kind="rods", size=(4, 4)), "size must be"),
        (dict(kind="rods", size="big"), "size must be"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, match):
    with pytest.raises(ParameterError, match=match):
        write_synthetic_log(tmp_path / "x.mcap", **kwargs)


def test_cli_synth(tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    rc = main(["synth", "-o", str(out), "--parts", "black_nuts", "--frames", "2", "--size", "160x120",
               "--seed", "3", "--shiny"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "frame 1/2" in err and "frame 2/2" in err and "true outliers" in err
    meta = LogReader(out).metadata[layout.SYNTH_METADATA]
    assert meta["part_kind"] == "black_nuts" and meta["shiny"] == "true" and meta["seed"] == "3"
    assert main(["synth", "-o", str(tmp_path / "e.mcap"), "--empty", "--size", "160x120"]) == 0
    assert LogReader(tmp_path / "e.mcap").metadata[layout.SYNTH_METADATA]["part_kind"] == "empty"
    assert main(["synth", "-o", str(tmp_path / "z.mcap"), "--frames", "0"]) == 1
    assert "--frames must be at least 1" in capsys.readouterr().err


def test_sample_log_is_made_once(tmp_path, monkeypatch):
    monkeypatch.setenv("ZCUT_CACHE", str(tmp_path / "cache"))
    path = sample_log_path()
    assert path.parent == tmp_path / "cache"
    made = ensure_sample_log()
    assert made == path and path.is_file()
    assert list(path.parent.iterdir()) == [path]  # no temporary left behind
    mtime = path.stat().st_mtime_ns
    assert ensure_sample_log() == path and path.stat().st_mtime_ns == mtime
    reader = LogReader(path)
    meta = reader.metadata[layout.SYNTH_METADATA]
    assert meta["shiny"] == "true"
    assert reader.n_frames >= 2
    frames = list(reader.frames())
    assert all(f.masks[layout.TRUTH_OUTLIERS].sum() > 100 for f in frames)
