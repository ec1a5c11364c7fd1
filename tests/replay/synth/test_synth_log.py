"""replay.synth logs: docs/formats.md layout read back with LogReader and the mcap library, outlier kinds,
true poses, same bytes per seed, CLI, demo sample."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy import ndimage

from cli.main import main
from replay.errors import LogFormatError
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.synth import (
    BIN,
    EMPTY_POSITIONS_MM,
    GENERATOR_VERSION,
    LABEL_RIM,
    camera_distance_m,
    default_intrinsics,
    ensure_sample_log,
    frame_pose,
    sample_log_path,
    stamp_ns,
    synthesize_frame,
    true_poses,
    write_synthetic_log,
)
from replay.synth.sensor import pixel_rays
from replay.synth.truth_depth import read_truth_depth
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
    stream = reader.frames()
    frames = list(stream)
    assert stream.damage == ()
    assert len(frames) == 2
    made = [synthesize_frame(kind="rods", seed=9, index=i, size=SIZE) for i in range(2)]
    for i, (f, sf) in enumerate(zip(frames, made)):
        assert f.stamp_ns == stamp_ns(9, i) == sf.frame.stamp_ns
        assert f.frame_id == sf.frame.frame_id
        np.testing.assert_array_equal(f.xyz, sf.frame.xyz)  # NaN where NaN, bit-equal elsewhere
        np.testing.assert_array_equal(f.rgb, sf.frame.rgb)
        np.testing.assert_array_equal(f.masks[layout.TRUTH_OUTLIERS], sf.truth)
        assert f.masks[layout.TRUTH_OUTLIERS].any()
        assert f.intrinsics == sf.frame.intrinsics
        assert np.isfinite(f.xyz[f.masks[layout.TRUTH_OUTLIERS]]).all()
        # the kind image comes back as codes, nonzero exactly where the truth is
        np.testing.assert_array_equal(f.codes[layout.TRUTH_OUTLIER_KIND], sf.outlier_kind)
        np.testing.assert_array_equal(f.codes[layout.TRUTH_OUTLIER_KIND] > 0, f.masks[layout.TRUTH_OUTLIERS])
    # read with the mcap library's own ROS 2 decoder: one image per cloud, the cloud's stamp
    kinds = _kind_images(path)
    assert sorted(kinds) == [stamp_ns(9, 0), stamp_ns(9, 1)]
    for i, sf in enumerate(made):
        np.testing.assert_array_equal(kinds[stamp_ns(9, i)], sf.outlier_kind)
    assert meta["outlier_kind_topic"] == layout.TRUTH_OUTLIER_KIND
    assert meta["generator_version"] == GENERATOR_VERSION and meta["quantize_mm"] == "0"


def _kind_images(path) -> dict[int, np.ndarray]:
    """``/ground_truth/outlier_kind`` of a log: header stamp -> (H, W) uint8 codes."""
    out = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, _, _, msg in reader.iter_decoded_messages(topics=[layout.TRUTH_OUTLIER_KIND]):
            assert msg.encoding == "mono8" and msg.step == msg.width
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert stamp not in out
            out[stamp] = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width)
    return out


def test_log_carries_the_true_poses(tmp_path):
    path = write_synthetic_log(tmp_path / "nuts.mcap", kind="black_nuts", frames=3, seed=4, size=SIZE)
    reader = LogReader(path)
    poses = true_poses(reader.metadata)
    assert reader.metadata[layout.SYNTH_METADATA]["poses_metadata"] == layout.SYNTH_POSES_METADATA
    assert sorted(poses) == [f.stamp_ns for f in reader.frames()]
    for i, stamp in enumerate(sorted(poses)):
        T = poses[stamp]
        assert T.shape == (4, 4) and T.dtype == np.float64
        np.testing.assert_array_equal(T, frame_pose(4, i))  # bit-exact through the text
        np.testing.assert_array_equal(T, synthesize_frame(kind="black_nuts", seed=4, index=i, size=SIZE).T_cam_bin)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0) and (T[3] == [0, 0, 0, 1]).all()
    # a log without poses (a recorded one) has none
    assert true_poses({layout.SYNTH_METADATA: {"part_kind": "rods"}}) == {}


@pytest.mark.parametrize(
    "record, match",
    [
        ({"frame0": ",".join(["0"] * 16)}, "expected an integer stamp and 16 comma-separated floats"),
        ({"12": "1,0,0"}, "expected 16 finite comma-separated floats, got 3 values"),
        ({"12": ",".join(["nan"] * 16)}, "expected 16 finite comma-separated floats"),
        ({"12": "a,b"}, "expected an integer stamp and 16 comma-separated floats"),
    ],
)
def test_bad_pose_metadata(record, match):
    with pytest.raises(LogFormatError, match=match):
        true_poses({layout.SYNTH_POSES_METADATA: record})


def test_true_pose_maps_the_nominal_bin_onto_the_frames_bin():
    """T_cam_bin carries the bin seen at its nominal pose (the empty series' first scan, the frame a
    bin model built from that series is in) onto the bin of a frame: its rim lands on the rim."""
    size = (480, 640)
    ref = synthesize_frame(empty=True, seed=2, index=0, size=size)
    np.testing.assert_array_equal(ref.T_cam_bin, np.eye(4))  # the series starts at the nominal pose
    K = default_intrinsics(size)
    rim = ndimage.binary_erosion(ref.surface == LABEL_RIM, np.ones((7, 7), bool))
    pts = pixel_rays(K)[rim] * (ref.surface_depth_mm[rim, None] / 1000.0)  # noise-free, metres

    def landing_on_rim(frame, T):
        p = pts @ T[:3, :3].T + T[:3, 3]
        col = np.rint(K.fx * p[:, 0] / p[:, 2] + K.cx).astype(int)
        row = np.rint(K.fy * p[:, 1] / p[:, 2] + K.cy).astype(int)
        inside = (row >= 0) & (row < size[0]) & (col >= 0) & (col < size[1])
        return np.mean(frame.surface[row[inside], col[inside]] == LABEL_RIM)

    for index in range(3):
        sf = synthesize_frame(kind="sprockets", seed=2, index=index, size=size)
        assert landing_on_rim(sf, sf.T_cam_bin) > 0.99
        assert landing_on_rim(sf, np.eye(4)) < 0.95  # the test can tell a wrong pose


def test_same_seed_same_bytes(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    (tmp_path / "d").mkdir()
    (tmp_path / "e").mkdir()
    kw = {"kind": "black_screws", "frames": 2, "size": SIZE}
    a = write_synthetic_log(tmp_path / "a" / "log.mcap", seed=5, **kw).read_bytes()
    b = write_synthetic_log(tmp_path / "b" / "log.mcap", seed=5, **kw).read_bytes()
    c = write_synthetic_log(tmp_path / "c" / "log.mcap", seed=6, **kw).read_bytes()
    assert a == b
    assert a != c
    d = write_synthetic_log(tmp_path / "d" / "log.mcap", seed=5, quantize_mm=1.0, **kw).read_bytes()
    e = write_synthetic_log(tmp_path / "e" / "log.mcap", seed=5, quantize_mm=1.0, **kw).read_bytes()
    assert d == e and d != a


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
    poses = true_poses(reader.metadata)
    np.testing.assert_array_equal(poses[stamp_ns(1, 0)], np.eye(4))  # the model's frame
    # the footprint (outlined by the rim, 460 mm from the camera) moves as the series says:
    # +x -> +col, +y (world) -> -row (camera y points down); +-3 mm jitter, +-2 deg yaw
    fx = 1600.0 * 320 / 1920
    shift = fx * np.array(EMPTY_POSITIONS_MM) / (580.0 - BIN.height_mm)
    np.testing.assert_allclose(c[:, 1] - c[0, 1], shift[:, 0] - shift[0, 0], atol=3.0)
    np.testing.assert_allclose(c[:, 0] - c[0, 0], -(shift[:, 1] - shift[0, 1]), atol=3.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kind": "bolts"}, "kind must be one of"),
        ({"kind": "rods", "frames": 0}, "frames must be a positive integer"),
        ({"kind": "rods", "size": (4, 4)}, "size must be"),
        ({"kind": "rods", "size": "big"}, "size must be"),
        ({"kind": "rods", "quantize_mm": -2}, "quantize_mm must be between 0 and 10 mm, got -2"),
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


@pytest.mark.parametrize("sensor, extra", [("handmade", ()), ("raytraced", ("--empty",))])
def test_cli_synth_same_seed_same_bytes(tmp_path, capsys, sensor, extra):
    """Through the command (it writes a temporary file and renames it): two runs with the same
    arguments give the same bytes, and the rosbag2 record names the final file, not the temporary."""
    runs = []
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        out = tmp_path / d / "scan.mcap"
        argv = ["synth", "-o", str(out), "--sensor", sensor, "--size", "64x40", "--seed", "4", *extra]
        assert main(argv) == 0
        runs.append(out.read_bytes())
    assert runs[0] == runs[1]
    # a third run over the first output (--force) gives the same bytes again
    assert main(["synth", "-o", str(tmp_path / "a" / "scan.mcap"), "--sensor", sensor, "--size", "64x40",
                 "--seed", "4", "--force", *extra]) == 0
    assert (tmp_path / "a" / "scan.mcap").read_bytes() == runs[0]
    capsys.readouterr()
    bag = LogReader(tmp_path / "a" / "scan.mcap").metadata["rosbag2"]["serialized_metadata"]
    assert "partial" not in bag
    assert "relative_file_paths:\n    - scan.mcap\n" in bag and "    - path: scan.mcap\n" in bag


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
    # the cache file's name carries the version that added /ground_truth/depth: an older sample
    # (without it) is never taken for this one
    assert path.name.endswith(f"_v{GENERATOR_VERSION}.mcap") and int(GENERATOR_VERSION) >= 3
    assert sorted(read_truth_depth(path)) == [f.stamp_ns for f in frames]
