"""Round trips through LogWriter -> LogReader, and our files read by the mcap libraries."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from replay.errors import LogFormatError
from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter
from zcut.cloud import Intrinsics

H, W = 12, 16


def _frames(rng: np.random.Generator, n: int = 3) -> list[Frame]:
    out = []
    for i in range(n):
        xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
        xyz[rng.random((H, W)) < 0.2] = np.nan
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        masks = {
            "/ground_truth/outliers": rng.random((H, W)) < 0.1,
            "/zcut/outliers": rng.random((H, W)) < 0.3,
        }
        out.append(
            Frame(xyz=xyz, rgb=rgb, stamp_ns=1_700_000_000_000_000_000 + i * 100_000_000,
                  frame_id="zivid_optical_frame", intrinsics=Intrinsics(500.0, 501.0, 7.5, 5.5, W, H),
                  topic="/camera/points", index=i, masks=masks)
        )
    return out


@pytest.fixture
def log3(tmp_path, rng):
    frames = _frames(rng)
    path = tmp_path / "three.mcap"
    with LogWriter(path, metadata={"zcut.synth": {"part_kind": "spheres", "seed": "7"}}) as w:
        for f in frames:
            w.write_frame(f)
    return path, frames


def test_round_trip_is_exact(log3):
    path, frames = log3
    r = LogReader(path)
    assert (r.cloud_topic, r.image_topic, r.info_topic) == (
        "/camera/points", "/camera/image", "/camera/camera_info")
    assert r.mask_topics == ["/ground_truth/outliers", "/zcut/outliers"]
    assert r.n_frames == 3
    assert r.metadata["zcut.synth"] == {"part_kind": "spheres", "seed": "7"}
    stream = r.frames()
    got = list(stream)
    assert [g.index for g in got] == [0, 1, 2]
    assert stream.damage == ()
    for g, f in zip(got, frames, strict=True):
        assert g.xyz.dtype == np.float32 and g.xyz.shape == (H, W, 3)
        np.testing.assert_array_equal(g.xyz, f.xyz)  # NaN positions equal too
        np.testing.assert_array_equal(g.rgb, f.rgb)
        assert g.stamp_ns == f.stamp_ns and g.frame_id == f.frame_id
        assert g.intrinsics == f.intrinsics
        assert g.masks.keys() == f.masks.keys()
        for k in f.masks:
            np.testing.assert_array_equal(g.masks[k], f.masks[k])


def test_start_stop(log3):
    path, _ = log3
    r = LogReader(path)
    assert [f.index for f in r.frames(start=1)] == [1, 2]
    assert [f.index for f in r.frames(start=0, stop=2)] == [0, 1]
    assert [f.index for f in r.frames(start=1, stop=2)] == [1]
    only = list(r.frames(start=2, stop=3))
    assert len(only) == 1 and "/zcut/outliers" in only[0].masks and only[0].rgb is not None


def test_written_file_is_rosbag2_shaped(log3):
    path, frames = log3
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        assert header.profile == "ros2"
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert "reliability: 1" in ch.metadata["offered_qos_profiles"]
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        info = meta["rosbag2"]["serialized_metadata"]
        assert "storage_identifier: mcap" in info and "name: /camera/points" in info
        assert "message_count: 15" in info  # 3 x (cloud, image, info, two masks)
        # mcap_ros2's generic decoder agrees with ours
        seen = 0
        for _, _channel, _, msg in reader.iter_decoded_messages(topics=["/camera/points"]):
            assert (msg.height, msg.width, msg.point_step) == (H, W, 16)
            assert [f.name for f in msg.fields] == ["x", "y", "z", "rgba"]
            pts = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(H, W, 4)
            np.testing.assert_array_equal(pts[..., :3], frames[seen].xyz)
            assert msg.header.frame_id == "zivid_optical_frame"
            seen += 1
        assert seen == 3
        for _, _, _, msg in reader.iter_decoded_messages(topics=["/camera/camera_info"]):
            assert msg.k[0] == 500.0 and msg.k[4] == 501.0 and msg.k[2] == 7.5 and msg.width == W


def test_written_file_passes_mcap_validation(log3):
    """mcap's stream reader with every CRC checked (chunks and data section), its indexed reader,
    the message indexes against the messages, and the footer's summary CRC."""
    import struct
    import zlib

    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader, breakup_chunk

    path, frames = log3
    big = path.with_name("big.mcap")
    with LogWriter(big, chunk_size=2000) as w:  # several chunks
        for f in frames:
            w.write_frame(f)
    path = big
    kinds: dict[str, int] = {}
    chunks = []
    indexes = []
    with open(path, "rb") as fh:
        for rec in StreamReader(fh, validate_crcs=True, emit_chunks=True).records:
            kinds[type(rec).__name__] = kinds.get(type(rec).__name__, 0) + 1
            if isinstance(rec, Chunk):
                chunks.append(rec)
                indexes.append([])
            elif isinstance(rec, MessageIndex):
                indexes[-1].append(rec)
    assert kinds["Chunk"] >= 3 and kinds["DataEnd"] == 1 and kinds["Footer"] == 1
    assert kinds["Statistics"] == 1 and kinds["ChunkIndex"] == kinds["Chunk"] and kinds["SummaryOffset"] >= 4
    for chunk, idx in zip(chunks, indexes, strict=True):
        records = breakup_chunk(chunk, validate_crc=True)
        n_msgs = sum(type(r).__name__ == "Message" for r in records)
        assert n_msgs == sum(len(m.records) for m in idx)
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == 15
        assert sum(1 for _ in reader.iter_messages(topics=["/zcut/outliers"])) == 3
    raw = path.read_bytes()
    summary_start, offset_start, crc = struct.unpack_from("<QQI", raw, len(raw) - 8 - 20)
    assert zlib.crc32(raw[summary_start : len(raw) - 8 - 4]) == crc


def test_writer_rejects_bad_arrays(tmp_path):
    with LogWriter(tmp_path / "x.mcap") as w:
        with pytest.raises(ValueError, match=r"xyz must be an \(H, W, 3\) float array, got shape \(4, 4\)"):
            w.write_cloud("/c", np.zeros((4, 4)), stamp_ns=0, frame_id="f")
        with pytest.raises(ValueError, match="rgb must be an"):
            w.write_cloud("/c", np.zeros((4, 4, 3)), rgb=np.zeros((4, 4, 3)), stamp_ns=0, frame_id="f")
        with pytest.raises(ValueError, match="mask must be an"):
            w.write_mask("/m", np.zeros((4, 4), np.uint8), stamp_ns=0, frame_id="f")


def test_not_mcap(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not an mcap file")
    with pytest.raises(LogFormatError, match="not an MCAP file"):
        LogReader(p)


def test_frame_without_colour_stays_without(tmp_path):
    xyz = np.ones((3, 4, 3), np.float32)
    with LogWriter(tmp_path / "nocolour.mcap") as w:
        w.write_cloud("/camera/points", xyz, stamp_ns=5, frame_id="f")
    r = LogReader(tmp_path / "nocolour.mcap")
    assert r.image_topic is None and r.topics["/camera/points"].fields == ("x", "y", "z")
    (f,) = r.frames()
    assert f.rgb is None and f.intrinsics is None and f.masks == {}
    np.testing.assert_array_equal(f.xyz, xyz)


def test_results_topics_of_spec(tmp_path, rng):
    """The docs/formats.md result topics: masks as mono8 Images, /zcut/filtered as an organized cloud."""
    xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
    out = xyz.copy()
    out[rng.random((H, W)) < 0.3] = np.nan
    topics = ["/zcut/outliers", "/zcut/sor_outliers", "/zcut/bin_mask", "/ground_truth/outliers",
              "/labels/outliers", "/labels/reviewed"]
    masks = {t: rng.random((H, W)) < 0.5 for t in topics}
    p = tmp_path / "results.mcap"
    with LogWriter(p) as w:
        w.write_cloud("/camera/points", xyz, stamp_ns=9, frame_id="f")
        w.write_cloud("/zcut/filtered", out, stamp_ns=9, frame_id="f")
        for t, m in masks.items():
            w.write_mask(t, m, stamp_ns=9, frame_id="f")
    assert LogReader(p).cloud_topic == "/camera/points"  # zcut's own output is not the input
    r = LogReader(p, cloud_topic="/zcut/filtered")
    assert r.mask_topics == sorted(topics)
    (f,) = r.frames()
    np.testing.assert_array_equal(f.xyz, out)
    for t, m in masks.items():
        np.testing.assert_array_equal(f.masks[t], m)
    with open(p, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        enc = {ch.topic: msg.encoding for _, ch, _, msg in reader.iter_decoded_messages() if hasattr(msg, "encoding")}
    assert enc == {t: "mono8" for t in topics}


def test_real_ros2_kinect_log_equals_its_pcd_sources(real_data):
    """mosd_clutter_kinect_ros2.mcap holds mOSD test55 and test60 (float-packed rgb, label field)."""
    from replay.logs.pcd import read_pcd

    r = LogReader(real_data / "mosd_clutter_kinect_ros2.mcap")
    assert (r.cloud_topic, r.image_topic, r.n_frames) == ("/camera/depth/points", None, 2)
    assert r.topics["/camera/depth/points"].fields == ("x", "y", "z", "rgb", "label")
    frames = list(r.frames())
    for f, name in zip(frames, ["mosd_test55.pcd", "mosd_test60.pcd"], strict=True):
        src = read_pcd(real_data / name)
        np.testing.assert_array_equal(f.xyz, src.xyz)
        np.testing.assert_array_equal(f.rgb, src.rgb)  # colours from the cloud's packed rgb
        assert f.frame_id == "camera_depth_optical_frame"
    assert [f.stamp_ns for f in frames] == [0, 1_000_000_000]


def test_real_ros2_ouster_log(real_data):
    """64 x 2048 lidar: organized, (0, 0, 0) invalid although is_dense is true, mono8 side images."""
    r = LogReader(real_data / "ouster_os1_64_ros2_reencoded.mcap")
    assert r.cloud_topic == "/os1_cloud_node/points" and r.image_topic is None
    assert r.mask_topics == ["/img_node/intensity_image", "/img_node/noise_image", "/img_node/range_image"]
    stream = r.frames()
    frames = list(stream)
    assert len(frames) == 2 and stream.damage == ()
    with open(real_data / "ouster_os1_64_ros2_reencoded.mcap", "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        raw = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/os1_cloud_node/points"])]
    for f, m in zip(frames, raw, strict=True):
        assert m.is_dense and f.shape == (64, 2048) and f.rgb is None
        pts = np.frombuffer(bytes(m.data), dtype="<f4").reshape(64, 2048, 12)[..., :3]
        zero = (pts == 0).all(axis=2)
        assert 0 < zero.sum() < 64 * 2048
        assert np.isnan(f.xyz[zero]).all()
        np.testing.assert_array_equal(f.xyz[~zero], pts[~zero])
        assert f.stamp_ns == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec


def test_ros1_log_is_refused(real_data):
    with pytest.raises(LogFormatError, match=r"^ouster_os1_64_ros1_original.mcap is a ROS 1 log \(message encoding ros1\)"):
        LogReader(real_data / "ouster_os1_64_ros1_original.mcap")


def test_start_seeks_through_the_summary(tmp_path, rng):
    """frames(start=k) jumps to the right chunk (indices and pairing unchanged), with or without
    the summary."""
    frames = _frames(rng, 8)
    p = tmp_path / "eight.mcap"
    with LogWriter(p, chunk_size=1024) as w:
        for f in frames:
            w.write_frame(f)
    r = LogReader(p)
    offset, before = r.index().seek(5)
    assert offset is not None and before == 5  # one cloud per chunk here
    for start in range(8):
        got = list(r.frames(start=start, stop=start + 2))
        assert [g.index for g in got] == list(range(start, min(start + 2, 8)))
        for g in got:
            np.testing.assert_array_equal(g.xyz, frames[g.index].xyz)
            np.testing.assert_array_equal(g.masks["/zcut/outliers"], frames[g.index].masks["/zcut/outliers"])
            assert g.intrinsics == frames[g.index].intrinsics
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[:-200])  # no summary: scans from the start, same answer
    assert [g.index for g in LogReader(cut).frames(start=6)] == [6, 7]
    with pytest.raises(ValueError, match="need 0 <= start <= stop, got start=3, stop=1"):
        list(r.frames(start=3, stop=1))


def test_a_frame_already_decoded_is_delivered_again_as_it_is(tmp_path, rng):
    """frames(decoded=f): the frame an earlier pass delivered comes out of this pass as that object
    (not decoded again), the other frames and the pass's damage as without it."""
    p = tmp_path / "three.mcap"
    with LogWriter(p, chunk_size=1024) as w:
        for f in _frames(rng, 3):
            w.write_frame(f)
    r = LogReader(p)
    it = r.frames()
    first = next(it)
    it.close()
    plain = list(r.frames())
    again = r.frames(decoded=first)
    got = list(again)
    assert got[0] is first and [g.index for g in got] == [0, 1, 2] and again.damage == ()
    for a, b in zip(got, plain):
        np.testing.assert_array_equal(a.xyz, b.xyz)
        assert a.stamp_ns == b.stamp_ns and a.masks.keys() == b.masks.keys()
    assert list(r.frames(start=1, decoded=first))[0] is not first  # not in the range: not delivered
