"""Bounded resources and the exit-status contract (docs/cli.md, issue 11): special files are refused
without blocking, decoded sizes are checked against the bytes present and the caps before any
allocation, every lost frame is named in the stream's ``damage`` with the log's own index, and the
log-level facts (intrinsics, first shape) do not depend on which frames survived."""

from __future__ import annotations

import os
import re
import resource
import socket
import struct

import numpy as np
import pytest
from log_helpers import read_frames
from mcap.writer import CompressionType, Writer
from raw_mcap import write_raw_log

from replay.errors import LogFormatError
from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.frame import Frame
from replay.logs.mcap_scan import McapFile
from replay.logs.pcd import read_pcd
from replay.logs.ply import read_ply
from replay.logs.reader import LogReader, read_mask_topics, stamp_text
from replay.logs.writer import LogWriter
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError

pytestmark = pytest.mark.timeout(60)  # a FIFO must never block a reader

H, W = 6, 8
K = Intrinsics(300.0, 301.0, 3.5, 2.5, W, H)


def _write(path, n=3, *, chunk_size=256, info=True):
    rng = np.random.default_rng(7)
    frames = []
    with LogWriter(path, chunk_size=chunk_size) as w:
        for i in range(n):
            f = Frame(xyz=rng.normal(size=(H, W, 3)).astype(np.float32), rgb=None, stamp_ns=10**9 * (i + 1),
                      frame_id="cam", intrinsics=K if info else None, topic=layout.CLOUD, index=i)
            w.write_frame(f)
            frames.append(f)
    return frames


# ----------------------------------------------------------------------------- special files
def _special(tmp_path, kind):
    if kind == "fifo":
        p = tmp_path / "x.fifo"
        os.mkfifo(p)
        return p, None, "is a FIFO \\(named pipe\\)"
    if kind == "dir":
        return tmp_path, None, "is a directory"
    if kind == "socket":
        p = tmp_path / "x.sock"
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
        return p, s, "is a socket"
    return "/dev/zero", None, "is a character device"


@pytest.mark.parametrize("kind", ["fifo", "dir", "socket", "devzero"])
@pytest.mark.parametrize("reader", [LogReader, read_pcd, read_ply])
def test_special_files_are_refused_without_blocking(tmp_path, kind, reader):
    p, keep, what = _special(tmp_path, kind)
    try:
        with pytest.raises(LogFormatError, match=f"^{re.escape(str(p))} {what}, not .*regular files only"):
            reader(p)
    finally:
        if keep is not None:
            keep.close()


@pytest.mark.parametrize("kw,match", [
    ({"max_pixels": 0}, "max_pixels must be a positive integer, got 0"),
    ({"max_message_bytes": -5}, "max_message_bytes must be a positive integer, got -5"),
    ({"max_pixels": 1.5}, "max_pixels must be a positive integer, got 1.5"),
])
def test_caps_are_validated(tmp_path, kw, match):
    p = tmp_path / "a.mcap"
    _write(p, 1)
    with pytest.raises(ValueError, match=match):
        LogReader(p, **kw)


# ----------------------------------------------------------------------------- size caps
def _bomb_log(path, big_hw):
    """frame 0 small, frame 1 a cloud of zeros of ``big_hw`` (a zstd bomb), frame 2 small."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(name=rm.POINTCLOUD2, encoding="ros2msg", data=rm.SCHEMAS[rm.POINTCLOUD2].encode())
        cid = w.register_channel(topic="/p", message_encoding="cdr", schema_id=sid)
        for i, (h, w_) in enumerate([(H, W), big_hw, (H, W)]):
            xyz = np.ones((h, w_, 3), np.float32) if i != 1 else None
            data = rm.arrays_to_cloud_data(xyz, None) if xyz is not None else bytes(16 * h * w_)
            msg = rm.encode_cloud(stamp_ns=i + 1, frame_id="c", height=h, width=w_, fields=rm.XYZ_FIELDS,
                                  point_step=16, row_step=16 * w_, data=data, is_dense=False)
            w.add_message(cid, log_time=i + 1, publish_time=i + 1, data=msg, sequence=i)
        w.finish()


def test_zstd_bomb_is_skipped_before_allocation(tmp_path):
    p = tmp_path / "bomb.mcap"
    _bomb_log(p, (2048, 2048))  # 64 MiB of zeros in a few kB
    assert p.stat().st_size < 100_000
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    got, damage = read_frames(p, max_pixels=1 << 20)
    assert [f.index for f in got] == [0, 2]
    assert damage == [
        "frame 1 (stamp 0.000000002) skipped: bomb.mcap: topic /p, message 1: PointCloud2 of 2048x2048 = "
        "4194304 pixels is more than the cap of 1048576 (max_pixels; raise it with ZCUT_MAX_PIXELS)"
    ]
    got, damage = read_frames(p, max_message_bytes=1 << 20)  # the message itself is over the byte cap
    assert [f.index for f in got] == [0, 2]
    assert re.match(r"^frame 1 \(log time 0\.000000002\) skipped: .*message of \d+ bytes, more than the cap "
                    r"of 1048576", damage[0]), damage
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown < 400 * 1024, f"peak RSS grew by {grown // 1024} MB"  # never the 4M-point arrays


def test_chunk_claiming_a_huge_size_is_refused_before_decompressing(tmp_path):
    p = tmp_path / "claims.mcap"
    _write(p, 3, info=False)
    with McapFile(p) as mf:
        chunks = mf.summary.chunk_indexes
    victim = chunks[1]
    raw = bytearray(p.read_bytes())
    struct.pack_into("<Q", raw, victim.chunk_start_offset + 9 + 16, 1 << 40)  # uncompressed_size
    p.write_bytes(bytes(raw))
    frames, damage = read_frames(p)
    got = [f.index for f in frames]
    assert 1 not in got and got == [0, 2]
    assert f"claims {1 << 40} uncompressed bytes, more than the cap" in damage[0]
    assert damage[1] == f"frame 1 (log time 2.000000000) lost with the chunk at byte {victim.chunk_start_offset}"


def _ply(tmp_path, header: str, body: bytes = b"") -> object:
    p = tmp_path / "huge.ply"
    p.write_bytes(header.encode() + body)
    return p


@pytest.mark.parametrize("header,match", [
    ("ply\nformat binary_little_endian 1.0\nobj_info num_rows 200000\nobj_info num_cols 123000\n"
     "element vertex 24600000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
     "PLY has 24600000000 vertices, more than the cap of 16777216 \\(max_pixels"),
    ("ply\nformat binary_little_endian 1.0\nobj_info num_rows 4000\nobj_info num_cols 4000\n"
     "element vertex 16000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
     "PLY vertex data has 48 bytes after the header, needs 192000000 \\(truncated\\)"),
    ("ply\nformat ascii 1.0\nobj_info num_rows 4000\nobj_info num_cols 4000\n"
     "element vertex 16000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
     "PLY vertex data has 48 bytes after the header, needs 96000000 \\(truncated\\)"),
    ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
     "property float z\nelement range_grid 100000000000\nproperty list uchar int vertex_indices\nend_header\n",
     "PLY element 'range_grid' has 100000000000 items, more than the cap"),
    ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
     "property float z\nelement camera 1\nproperty float viewportx\nproperty float viewporty\nend_header\n",
     "PLY camera data has 48 bytes after the header, needs 56"),
])
def test_ply_header_asking_for_a_huge_grid(tmp_path, header, match):
    p = _ply(tmp_path, header, bytes(48))
    with pytest.raises(LogFormatError, match="^huge.ply: " + match):
        read_ply(p)


def test_ply_camera_with_inf_viewport(tmp_path):
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nelement camera 1\nproperty float viewportx\nproperty float viewporty\nend_header\n")
    p = _ply(tmp_path, head, bytes(48) + struct.pack("<ff", np.inf, 2.0))
    with pytest.raises(LogFormatError, match="^huge.ply: PLY with 4 vertices has no organization info"):
        read_ply(p)


@pytest.mark.parametrize("kw,header,match", [
    ({}, "WIDTH 100000\nHEIGHT 100000\nPOINTS 10000000000\nDATA binary\n",
     "PCD grid 100000x100000 = 10000000000 points is more than the cap of 16777216"),
    ({"max_message_bytes": 1000}, "WIDTH 100\nHEIGHT 100\nPOINTS 10000\nDATA binary\n",
     "PCD data of 120000 bytes is more than the cap of 1000"),
    ({}, "WIDTH 1000\nHEIGHT 1000\nPOINTS 1000000\nDATA binary_compressed\n",
     "PCD binary_compressed claims 4294967295 uncompressed bytes, fields need 12000000"),
])
def test_pcd_header_asking_for_too_much(tmp_path, kw, header, match):
    p = tmp_path / "huge.pcd"
    p.write_bytes(("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n" + header).encode()
                  + struct.pack("<II", 10, 2**32 - 1) + bytes(10))
    with pytest.raises(LogFormatError, match="^huge.pcd: " + match):
        read_pcd(p, **kw)


# ----------------------------------------------------------------------------- lost frames
def _cut_chunk(raw: bytes, chunk) -> bytes:
    """The file without one chunk record and its MessageIndex records (as if never written)."""
    start = chunk.chunk_start_offset
    end = start + chunk.chunk_length + chunk.message_index_length
    return raw[:start] + raw[end:]


@pytest.mark.parametrize("writer", ["zcut", "mcap"])
def test_missing_chunk_and_damaged_summary_keep_indices(tmp_path, writer):
    """A chunk cut out of the file shifts every later offset, so the summary is useless: the
    per-channel sequence numbers show the gap, frame 2 keeps its index and frame 1 is named."""
    p = tmp_path / "three.mcap"
    if writer == "zcut":
        _write(p, 3, info=False)
    else:
        with open(p, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD, chunk_size=64)
            w.start(profile="ros2", library="test")
            sid = w.register_schema(name=rm.POINTCLOUD2, encoding="ros2msg", data=rm.SCHEMAS[rm.POINTCLOUD2].encode())
            cid = w.register_channel(topic="/camera/points", message_encoding="cdr", schema_id=sid)
            for i in range(3):
                data = rm.arrays_to_cloud_data(np.full((H, W, 3), i + 1, np.float32), None)
                w.add_message(cid, log_time=10**9 * (i + 1), publish_time=0, sequence=i, data=rm.encode_cloud(
                    stamp_ns=10**9 * (i + 1), frame_id="c", height=H, width=W, fields=rm.XYZ_FIELDS,
                    point_step=16, row_step=16 * W, data=data, is_dense=True))
            w.finish()
    with McapFile(p) as mf:
        chunks = [c for c in mf.summary.chunk_indexes if c.message_index_offsets]
    assert len(chunks) == 3
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(_cut_chunk(p.read_bytes(), chunks[1]))
    got, damage = read_frames(cut)
    assert [f.index for f in got] == [0, 2]
    assert [f.stamp_ns for f in got] == [10**9, 3 * 10**9]
    assert any("summary section is damaged" in d for d in damage), damage
    assert "frame 1 lost: /camera/points message sequence jumps from 0 to 2 (a chunk is missing)" in damage


def test_summary_counts_name_frames_a_scan_cannot_reach(tmp_path):
    """The summary lists three clouds; the data section ends early but the summary is intact."""
    p = tmp_path / "three.mcap"
    _write(p, 3, info=False)
    with McapFile(p) as mf:
        last = [c for c in mf.summary.chunk_indexes if c.message_index_offsets][-1]
    raw = bytearray(p.read_bytes())
    # an early DataEnd in place of the last chunk's record: the scan stops there
    raw[last.chunk_start_offset] = 0x0F
    p.write_bytes(bytes(raw))
    got, damage = read_frames(p)
    assert [f.index for f in got] == [0, 1]
    assert any(d.startswith("frame 2 ") for d in damage), damage


# ----------------------------------------------------------------------------- log-level facts
def test_intrinsics_and_shape_do_not_depend_on_surviving_frames(tmp_path):
    p = tmp_path / "info.mcap"
    _write(p, 3)  # every message in a chunk of its own
    r = LogReader(p)
    assert (r.intrinsics, r.first_shape) == (K, (H, W))
    with McapFile(p) as mf:
        info_cid = next(c.id for c in mf.summary.channels.values() if c.topic == layout.CAMERA_INFO)
        cloud_cid = next(c.id for c in mf.summary.channels.values() if c.topic == layout.CLOUD)
        first_info = next(c for c in mf.summary.chunk_indexes if info_cid in c.message_index_offsets)
        first_cloud = next(c for c in mf.summary.chunk_indexes if cloud_cid in c.message_index_offsets)
    raw = bytearray(p.read_bytes())
    for c in (first_info, first_cloud):  # lose frame 0's cloud and its CameraInfo
        raw[c.chunk_start_offset + 9 + 40 + c.compressed_size // 2] ^= 0x55
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    r = LogReader(bad)
    assert (r.intrinsics, r.first_shape) == (K, (H, W))  # from frame 1's messages
    got, damage = read_frames(bad)
    assert [f.index for f in got] == [1, 2] and damage
    no_info = tmp_path / "noinfo.mcap"
    _write(no_info, 1, info=False)
    assert LogReader(no_info).intrinsics is None


def test_malformed_first_camera_info_is_passed_over(tmp_path):
    p = tmp_path / "m.mcap"
    good = rm.encode_camera_info(K, stamp_ns=2, frame_id="c")
    cloud = rm.encode_cloud(stamp_ns=2, frame_id="c", height=H, width=W, fields=rm.XYZ_FIELDS, point_step=16,
                            row_step=16 * W, data=rm.arrays_to_cloud_data(np.ones((H, W, 3), np.float32), None),
                            is_dense=True)
    write_raw_log(p, {layout.CAMERA_INFO: rm.CAMERAINFO, layout.CLOUD: rm.POINTCLOUD2},
                  [(layout.CAMERA_INFO, good[:30]),  # truncated
                   (layout.CAMERA_INFO, good), (layout.CLOUD, cloud)],
                  times=[1, 2, 2], compression=CompressionType.NONE)
    r = LogReader(p)
    assert r.intrinsics == K and r.info_topic == layout.CAMERA_INFO
    got, damage = read_frames(p)
    assert [f.intrinsics for f in got] == [K]
    assert len(damage) == 1 and damage[0].startswith("m.mcap: topic /camera/camera_info, message at log "
                                                     "time 0.000000001: ")


# ----------------------------------------------------------------------------- stamps
@pytest.mark.parametrize("stamp", [-1, rm.MAX_STAMP_NS + 1, 10**30])
def test_writer_refuses_stamps_outside_ros_time(tmp_path, stamp):
    with LogWriter(tmp_path / "s.mcap") as w:  # a ZcutError: the command line makes it one line, exit 1
        with pytest.raises(ParameterError, match="ROS 2 time range 0 .. 2147483647999999999 .*2038"):
            w.write_cloud("/p", np.ones((2, 2, 3), np.float32), stamp_ns=stamp, frame_id="f")
        w.write_cloud("/p", np.ones((2, 2, 3), np.float32), stamp_ns=rm.MAX_STAMP_NS, frame_id="f")
    (f,) = LogReader(tmp_path / "s.mcap").frames()
    assert f.stamp_ns == rm.MAX_STAMP_NS and stamp_text(f.stamp_ns) == "2147483647.999999999"



# ----------------------------------------------------------------------------- strings (found by the fuzz suite)
def test_writer_strings_that_are_not_utf8(tmp_path):
    """Undecodable bytes of a command-line argument (lone surrogates): a ``--frame-id`` (data) is a
    one-line ParameterError, not a UnicodeEncodeError; a file name in a metadata value or the log's own
    name (descriptions) are written backslash-escaped."""
    bad = os.fsdecode(b"\xff\xfecam")
    with LogWriter(tmp_path / "s.mcap") as w:
        with pytest.raises(ParameterError, match=r"^frame_id '\\udcff\\udcfecam' is not valid UTF-8 text"):
            w.write_cloud("/p", np.ones((2, 2, 3), np.float32), stamp_ns=1, frame_id=bad)
    path = tmp_path / (bad + ".mcap")
    with LogWriter(path, metadata={"zcut.record": {"sources": bad}}) as w:
        w.write_cloud("/p", np.ones((2, 2, 3), np.float32), stamp_ns=1, frame_id="c")
    r = LogReader(path)
    assert r.metadata["zcut.record"] == {"sources": "\\udcff\\udcfecam"}
    assert "\\udcff\\udcfecam.mcap" in r.metadata["rosbag2"]["serialized_metadata"]
    assert len(list(r.frames())) == 1


def test_mask_files_are_bounded(tmp_path):
    """A label file's masks are capped one by one and in all (a few KB of zstd zeros would otherwise
    decode to gigabytes); within the caps they read back exactly."""
    rng = np.random.default_rng(5)
    masks = {10**9 + i: rng.random((64, 80)) < 0.3 for i in range(10)}
    with LogWriter(tmp_path / "l.mcap") as w:
        for stamp, m in masks.items():
            w.write_mask("/labels/outliers", m, stamp_ns=stamp, frame_id="c")
            w.write_mask("/labels/reviewed", ~m, stamp_ns=stamp, frame_id="c")
    _, got = read_mask_topics(tmp_path / "l.mcap", ("/labels/outliers", "/labels/reviewed"))
    assert sorted(got) == sorted(masks)
    for stamp, m in masks.items():
        np.testing.assert_array_equal(got[stamp]["/labels/outliers"], m)
        np.testing.assert_array_equal(got[stamp]["/labels/reviewed"], ~m)
    with pytest.raises(LogFormatError, match=r"l.mcap: its masks hold more than 100000 pixels in all"):
        read_mask_topics(tmp_path / "l.mcap", ("/labels/outliers", "/labels/reviewed"), max_total_pixels=100_000)
    with pytest.raises(LogFormatError, match=r"Image of 64x80 = 5120 pixels is more than the cap of 5000"):
        read_mask_topics(tmp_path / "l.mcap", ("/labels/outliers",), max_pixels=5000)
