"""Damaged and hostile logs: intact frames still come out, then a clear note; otherwise only our
own error types, no hang, no absurd memory. The mutator is seeded and bounded (< 60 s)."""

from __future__ import annotations

import re
import resource
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
from log_helpers import mutations
from mcap.writer import CompressionType, Writer

from cli.main import main
from replay.errors import LogDamageError, LogFormatError
from replay.logs import ros2_msgs as rm
from replay.logs.damage import damage_lines
from replay.logs.frame import Frame
from replay.logs.mcap_scan import McapFile
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter

H, W = 24, 32
N = 6

pytestmark = pytest.mark.timeout(60)  # a damaged log must never make the reader hang


def _frames(seed: int = 5) -> list[Frame]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(N):
        xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
        xyz[rng.random((H, W)) < 0.1] = np.nan
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        out.append(Frame(xyz=xyz, rgb=rgb, stamp_ns=10**9 * (i + 1), frame_id="cam", intrinsics=None,
                         topic="/camera/points", index=i,
                         masks={"/ground_truth/outliers": rng.random((H, W)) < 0.2}))
    return out


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """Six frames, chunks of ~4 KB so every frame spans its own chunks."""
    frames = _frames()
    path = tmp_path_factory.mktemp("damage") / "six.mcap"
    with LogWriter(path, chunk_size=4096) as w:
        for f in frames:
            w.write_frame(f)
    with McapFile(path) as mf:
        chunks = list(mf.summary.chunk_indexes)
        data_end = mf.data_end
        cloud_cid = next(c.id for c in mf.summary.channels.values() if c.topic == "/camera/points")
    # which chunk holds each cloud (file order)
    cloud_chunk_end = [c.chunk_start_offset + c.chunk_length for c in chunks if cloud_cid in c.message_index_offsets]
    assert len(cloud_chunk_end) == N
    return path, frames, chunks, data_end, cloud_chunk_end


def _read_all(path, **kw):
    """(the texts of one pass's damage records, its frames)."""
    stream = LogReader(path, **kw).frames()
    got = list(stream)
    return damage_lines(stream.damage), got


def _check_prefix(got, frames):
    for g in got:
        f = frames[g.index]
        np.testing.assert_array_equal(g.xyz, f.xyz)
        np.testing.assert_array_equal(g.rgb, f.rgb)
        assert g.stamp_ns == f.stamp_ns


def test_truncation_at_many_offsets(small_log, tmp_path):
    path, frames, chunks, data_end, cloud_end = small_log
    raw = path.read_bytes()
    offsets = sorted(set(np.linspace(30, len(raw) - 1, 45).astype(int)) | {c.chunk_start_offset + 5 for c in chunks[:6]}
                     | {data_end, data_end + 3, len(raw) - 1})
    seen_partial = False
    for t in offsets:
        p = tmp_path / f"cut{t}.mcap"
        p.write_bytes(raw[:t])
        expect = [k for k in range(N) if cloud_end[k] <= t]
        try:
            damage, got = _read_all(p)
        except LogDamageError:
            assert not expect, f"cut at {t}: raised although frames {expect} are intact"
            continue
        except LogFormatError as e:  # e.g. cut inside the header record, before any channel
            assert not expect and t < chunks[0].chunk_start_offset + 100, f"cut at {t}: {e}"
            continue
        assert [g.index for g in got] == expect, f"cut at {t}"
        _check_prefix(got, frames)
        if t < data_end:
            assert damage and "truncated" in damage[-1], f"cut at {t}: no damage note"
            seen_partial |= 0 < len(got) < N
        else:  # only the summary is lost: every frame is there, nothing to report
            assert len(got) == N and damage == []
    assert seen_partial


def _flip_chunk(raw: bytes, chunk, where: float) -> bytes:
    bad = bytearray(raw)
    pos = chunk.chunk_start_offset + 9 + 8 * 3 + 4 + 4 + 4 + 8 + int(where * (chunk.compressed_size - 1))
    bad[pos] ^= 0x5A
    return bytes(bad)


@pytest.mark.parametrize("with_summary", [True, False])
def test_corrupt_chunk_keeps_the_others_and_indices(small_log, tmp_path, with_summary):
    path, frames, chunks, data_end, cloud_end = small_log
    raw = path.read_bytes()
    starts = [e for e in cloud_end]
    victim = next(c for c in chunks if c.chunk_start_offset + c.chunk_length == starts[2])  # frame 2's cloud
    bad = _flip_chunk(raw, victim, 0.5)
    if not with_summary:
        bad = bad[:data_end - 20]  # also lose the end: sequential scan, counts from MessageIndex records
    p = tmp_path / "flip.mcap"
    p.write_bytes(bad)
    damage, got = _read_all(p)
    # the chunk held frame 1's image and mask and frame 2's cloud: frame 1 cannot be read whole
    # (skipped, named), frame 2 is lost (named), the others keep their true indices
    assert [g.index for g in got] == [0, 3, 4, 5]
    _check_prefix(got, frames)
    assert any(f"chunk at byte {victim.chunk_start_offset} is corrupt" in d for d in damage)
    assert any(d.startswith("frame 1 (stamp 2.000000000) skipped: ") and "/camera/image message was lost" in d
               for d in damage), damage
    assert f"frame 2 (log time 3.000000000) lost with the chunk at byte {victim.chunk_start_offset}" in damage


def test_bad_record_length_resumes_at_next_chunk(small_log, tmp_path):
    path, frames, chunks, _, cloud_end = small_log
    raw = bytearray(path.read_bytes())
    victim = next(c for c in chunks if c.chunk_start_offset + c.chunk_length == cloud_end[1])
    raw[victim.chunk_start_offset + 1 : victim.chunk_start_offset + 9] = struct.pack("<Q", 2**62)
    p = tmp_path / "len.mcap"
    p.write_bytes(bytes(raw))
    damage, got = _read_all(p)
    assert [g.index for g in got] == [0, 2, 3, 4, 5]
    _check_prefix(got, frames)
    assert "skipped to the next chunk" in damage[0]


def test_real_log_truncations_and_flips(real_data, tmp_path):
    raw = (real_data / "mosd_clutter_kinect_ros2.mcap").read_bytes()
    full = list(LogReader(real_data / "mosd_clutter_kinect_ros2.mcap").frames())
    assert len(full) == 2
    with McapFile(real_data / "mosd_clutter_kinect_ros2.mcap") as mf:
        c0, c1 = mf.summary.chunk_indexes
    for t in (c0.chunk_start_offset + c0.chunk_length + 100, c1.chunk_start_offset + c1.chunk_length // 2):
        p = tmp_path / "cut.mcap"
        p.write_bytes(raw[:t])
        damage, got = _read_all(p)
        assert [g.index for g in got] == [0]
        np.testing.assert_array_equal(got[0].xyz, full[0].xyz)
        assert damage and "truncated" in damage[0]
    p = tmp_path / "flip.mcap"
    p.write_bytes(_flip_chunk(raw, c0, 0.3))
    damage, got = _read_all(p)
    assert [g.index for g in got] == [1]
    np.testing.assert_array_equal(got[0].xyz, full[1].xyz)
    assert "is corrupt" in damage[0]
    p.write_bytes(raw[: c0.chunk_start_offset + 1000])
    with pytest.raises(LogDamageError, match="mosd|flip|is damaged|no frame"):
        list(LogReader(p).frames())


# ---------------------------------------------------------------------------- hostile messages
def _raw_log(path, messages, *, schema=rm.POINTCLOUD2):
    """A valid MCAP holding hand-made CDR messages: [(topic, type, bytes)]."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="test")
        ids = {}
        for i, (topic, msg_type, data) in enumerate(messages):
            if topic not in ids:
                sid = w.register_schema(name=msg_type, encoding="ros2msg", data=rm.SCHEMAS[msg_type].encode())
                ids[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
            w.add_message(ids[topic], log_time=i, publish_time=i, data=data)
        w.finish()


def _cloud(h, w, **over):
    kw = dict(stamp_ns=7, frame_id="c", height=h, width=w, fields=rm.XYZRGBA_FIELDS, point_step=16,
              row_step=(16 * w) % 2**32, is_dense=False)
    kw.update(over)
    if "data" not in kw:
        kw["data"] = bytes(16 * h * w)
    return rm.encode_cloud(**kw)


def _image(h, w, enc="rgb8", stamp=7):
    ch = {"rgb8": 3, "mono8": 1}[enc]
    return rm.encode_image(stamp_ns=stamp, frame_id="c", height=h, width=w, encoding=enc, step=w * ch,
                           data=bytes(h * w * ch))


@pytest.mark.parametrize(
    "messages,where,match",
    [
        ([("/flat", rm.POINTCLOUD2, _cloud(1, 50))], "open",
         "no organized PointCloud2: /flat has height 1 \\(width 50\\); zcut needs organized clouds"),
        ([("/a", rm.POINTCLOUD2, _cloud(4, 5)), ("/b", rm.POINTCLOUD2, _cloud(4, 6))], "open",
         "several organized PointCloud2 topics: /a \\(4x5\\), /b \\(4x6\\); choose one with --topic"),
        ([("/img", rm.IMAGE, _image(4, 5))], "open", "has no sensor_msgs/msg/PointCloud2 topic \\(topics: /img"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/img", rm.IMAGE, _image(4, 6))], "open",
         "image topic /img is 4x6 but cloud topic /p is 4x5"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/img", rm.IMAGE, _image(4, 5)),
          ("/p", rm.POINTCLOUD2, _cloud(4, 5, stamp_ns=9)), ("/img", rm.IMAGE, _image(3, 5, stamp=9))], "frames",
         "topic /img, stamp 0.000000009: image is 3x5 but its cloud \\(/p, message 1\\) is 4x5"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/p", rm.POINTCLOUD2, _cloud(4, 2**31 - 1, row_step=16, data=bytes(64)))],
         "frames", "topic /p, message 1: PointCloud2 row_step 16 is smaller"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/p", rm.POINTCLOUD2, _cloud(2**20, 2**11, data=bytes(64)))],
         "frames", "topic /p, message 1: PointCloud2 of 1048576x2048 .* needs 34359738368 bytes of data but has 64"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/p", rm.POINTCLOUD2, _cloud(4, 5)[:40])], "frames",
         "topic /p, message 1: (claims 4 point fields, more than the message can hold|.*needs)"),
        ([("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/p", rm.POINTCLOUD2, _cloud(1, 20))], "frames",
         "topic /p, message 1: unorganized cloud \\(height 1, width 20\\)"),
    ],
)
def test_hostile_messages(tmp_path, messages, where, match):
    p = tmp_path / "h.mcap"
    _raw_log(p, messages)
    if where == "open":
        with pytest.raises(LogFormatError, match="^h.mcap.*" + match):
            LogReader(p)
    else:  # docs/cli.md: the unreadable frame 1 is skipped and named, the stream goes on
        _raw_log(p, [*messages, ("/p", rm.POINTCLOUD2, _cloud(4, 5, stamp_ns=11))])
        damage, got = _read_all(p)
        assert [f.index for f in got] == [0, 2]
        assert len(damage) == 1, damage
        assert re.match(r"^frame 1 \((stamp|log time) [0-9.]+\) skipped: h.mcap: " + match, damage[0]), damage


def test_choose_topic_explicitly(tmp_path):
    p = tmp_path / "two.mcap"
    _raw_log(p, [("/a", rm.POINTCLOUD2, _cloud(4, 5)), ("/b", rm.POINTCLOUD2, _cloud(4, 6)),
                 ("/flat", rm.POINTCLOUD2, _cloud(1, 6))])
    assert [f.shape for f in LogReader(p, cloud_topic="/b").frames()] == [(4, 6)]
    with pytest.raises(LogFormatError, match="topic /flat holds unorganized clouds \\(height 1, width 6\\)"):
        LogReader(p, cloud_topic="/flat")
    with pytest.raises(LogFormatError, match="has no PointCloud2 topic '/c' \\(PointCloud2 topics: /a \\(4x5\\)"):
        LogReader(p, cloud_topic="/c")


def test_several_colour_images(tmp_path, capsys):
    p = tmp_path / "imgs.mcap"
    _raw_log(p, [("/cam/points", rm.POINTCLOUD2, _cloud(4, 5)), ("/other/image", rm.IMAGE, _image(4, 5)),
                 ("/cam/image", rm.IMAGE, _image(4, 5)), ("/cam/small", rm.IMAGE, _image(2, 3))])
    r = LogReader(p)
    assert r.image_topic == "/cam/image"  # the cloud's size, then its namespace
    assert "several colour Image topics" in r.notes[-1] and "using /cam/image" in r.notes[-1]
    assert LogReader(p, image_topic="/other/image").image_topic == "/other/image"
    with pytest.raises(LogFormatError, match="image topic /cam/small is 2x3 but cloud topic /cam/points is 4x5"):
        LogReader(p, image_topic="/cam/small")
    assert main(["topics", str(p)]) == 0
    assert "note: several colour Image topics" in capsys.readouterr().out


def test_interleaved_pairing_within_window(tmp_path):
    """Images and masks may arrive before or after their cloud, in any order within the window."""
    msgs = []
    for k, s in enumerate([10, 20, 30]):
        img = rm.encode_image(stamp_ns=s, frame_id="c", height=4, width=5, encoding="rgb8", step=15,
                              data=bytes([k + 1]) * 60)
        mask = rm.encode_image(stamp_ns=s, frame_id="c", height=4, width=5, encoding="mono8", step=5,
                               data=bytes([255 * (k % 2)]) * 20)
        msgs.append((s, [("/img", rm.IMAGE, img), ("/m", rm.IMAGE, mask)]))
    order = [
        ("/m", 10), ("/p", 10), ("/img", 20), ("/p", 20), ("/img", 10), ("/p", 30), ("/m", 30), ("/m", 20),
        ("/img", 30),
    ]
    lookup = {(t, s): d for s, lst in msgs for t, _, d in lst}
    seq = []
    for topic, s in order:
        if topic == "/p":
            xyz = np.full((4, 5, 3), s, np.float32)
            data = rm.arrays_to_cloud_data(xyz, None)
            seq.append(("/p", rm.POINTCLOUD2, _cloud(4, 5, stamp_ns=s, data=data)))
        else:
            seq.append((topic, rm.IMAGE, lookup[(topic, s)]))
    p = tmp_path / "il.mcap"
    _raw_log(p, seq)
    r = LogReader(p)
    assert (r.image_topic, r.mask_topics) == ("/img", ["/m"])
    got = list(r.frames())
    assert [g.stamp_ns for g in got] == [10, 20, 30]
    for k, g in enumerate(got):
        assert (g.xyz == g.stamp_ns).all()
        assert (g.rgb == k + 1).all()
        assert g.masks["/m"].all() == bool(k % 2) and "/m" in g.masks


# ---------------------------------------------------------------------------- seeded mutator
def _uncompressed_log(path):
    """Same frames, chunks stored without compression and without CRCs (flips reach the decoder)."""
    frames = _frames(9)[:3]
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE, chunk_size=2048, enable_crcs=False)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(name=rm.POINTCLOUD2, encoding="ros2msg", data=rm.SCHEMAS[rm.POINTCLOUD2].encode())
        iid = w.register_schema(name=rm.IMAGE, encoding="ros2msg", data=rm.SCHEMAS[rm.IMAGE].encode())
        pc = w.register_channel(topic="/p", message_encoding="cdr", schema_id=sid)
        im = w.register_channel(topic="/i", message_encoding="cdr", schema_id=iid)
        for i, fr in enumerate(frames):
            data = rm.arrays_to_cloud_data(fr.xyz, fr.rgb)
            w.add_message(pc, log_time=i, publish_time=i, data=rm.encode_cloud(
                stamp_ns=fr.stamp_ns, frame_id="c", height=H, width=W, fields=rm.XYZRGBA_FIELDS,
                point_step=16, row_step=16 * W, data=data, is_dense=False))
            w.add_message(im, log_time=i, publish_time=i, data=rm.encode_image(
                stamp_ns=fr.stamp_ns, frame_id="c", height=H, width=W, encoding="rgb8", step=3 * W,
                data=fr.rgb.tobytes()))
        w.finish()


def test_seeded_mutator(small_log, real_data, tmp_path):
    """~320 mutants of three logs: only LogFormatError (or subclasses) may come out."""
    rng = np.random.default_rng(20240611)
    plain = tmp_path / "plain.mcap"
    _uncompressed_log(plain)
    real = (real_data / "mosd_clutter_kinect_ros2.mcap").read_bytes()
    sources = [("small", small_log[0].read_bytes(), 150), ("plain", plain.read_bytes(), 150), ("real", real, 24)]
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    outcomes: dict[str, int] = {}
    p = tmp_path / "m.mcap"
    for name, raw, n in sources:
        for kind, data in mutations(raw, rng, n):
            p.write_bytes(data)
            try:
                damage, got = _read_all(p)
                key = "damaged" if damage else "ok"
                for g in got:
                    assert g.xyz.dtype == np.float32 and g.xyz.ndim == 3
            except LogFormatError as e:
                msg = str(e)
                assert msg and "\n" not in msg, f"{name} kind {kind}: multi-line message {msg!r}"
                key = type(e).__name__
            outcomes[key] = outcomes.get(key, 0) + 1
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert rss_after - rss_before < 600 * 1024, f"peak RSS grew by {(rss_after - rss_before) // 1024} MB"
    assert outcomes.get("damaged", 0) > 0 and outcomes.get("LogFormatError", 0) > 0, outcomes


# ---------------------------------------------------------------------------- CLI exit codes
def test_cli_exit_codes(small_log, real_data, tmp_path, capsys):
    path = small_log[0]
    assert main(["topics", "--check", str(path)]) == 0
    assert "check: 6 frames decoded (6 with colour)" in capsys.readouterr().out
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: small_log[4][3] + 10])
    assert main(["topics", "--check", str(cut)]) == 3
    cap = capsys.readouterr()
    assert "check: 4 frames decoded" in cap.out
    assert "warning: cut.mcap is truncated" in cap.err and "Traceback" not in cap.err
    notmcap = tmp_path / "x.mcap"
    notmcap.write_bytes(b"\x89MCAP0\r\n" + bytes(3))
    proc = subprocess.run([sys.executable, "-m", "cli", "topics", str(notmcap)], capture_output=True, text=True)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ")
    proc = subprocess.run([sys.executable, "-m", "cli", "topics", str(tmp_path / "none.mcap")],
                          capture_output=True, text=True)
    assert proc.returncode == 1 and proc.stderr.startswith("error: no such file")


def test_chunk_crc_is_checked(small_log, tmp_path):
    """A chunk whose bytes decompress fine but differ from what was written is caught by its CRC."""
    path, frames, chunks, _, cloud_end = small_log
    with McapFile(path) as mf:
        assert all(c.compression == "zstd" for c in mf.summary.chunk_indexes)
    raw = bytearray(path.read_bytes())
    victim = next(c for c in chunks if c.chunk_start_offset + c.chunk_length == cloud_end[4])
    crc_at = victim.chunk_start_offset + 9 + 24
    raw[crc_at : crc_at + 4] = struct.pack("<I", zlib.crc32(b"other") or 1)
    p = tmp_path / "crc.mcap"
    p.write_bytes(bytes(raw))
    damage, got = _read_all(p)
    # the chunk held frame 3's image and mask and frame 4's cloud (contract: both named, skipped)
    assert [g.index for g in got] == [0, 1, 2, 5]
    assert "fails its CRC check" in damage[0]
    assert sorted(d.split(" (")[0] for d in damage[1:]) == ["frame 3", "frame 4"], damage


def test_zeroed_region_is_damage_not_a_slow_scan(small_log, tmp_path):
    """A run of zero bytes (opcode 0 is reserved) ends the scan or skips to the next indexed chunk
    at once, instead of walking it 9 bytes at a time."""
    path, frames, chunks, _, cloud_end = small_log
    raw = bytearray(path.read_bytes())
    victim = next(c for c in chunks if c.chunk_start_offset + c.chunk_length == cloud_end[3])
    raw[victim.chunk_start_offset : victim.chunk_start_offset + 64] = bytes(64)
    p = tmp_path / "zeros.mcap"
    p.write_bytes(bytes(raw))
    damage, got = _read_all(p)
    assert [g.index for g in got] == [0, 1, 4, 5]  # frame 2's image and frame 3 were in it
    assert damage[0].startswith(f"invalid record opcode 0x00 at byte {victim.chunk_start_offset}")
    cut = tmp_path / "zeros_tail.mcap"
    cut.write_bytes(bytes(raw[: victim.chunk_start_offset]) + bytes(50_000_000))  # no summary left
    damage, got = _read_all(cut)
    assert [g.index for g in got] == [0, 1, 2]
    assert "invalid record opcode 0x00" in damage[0] and "the rest is lost" in damage[0]


def test_rosbag2_per_message_zstd_compression(tmp_path):
    """``ros2 bag record --compression-mode message --compression-format zstd`` stores each CDR
    message as a zstd frame: read transparently; a damaged frame is a one-line error."""
    import zstandard

    xyz = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3) + 1
    cloud = _cloud(4, 5, data=rm.arrays_to_cloud_data(xyz, None))
    p = tmp_path / "msgz.mcap"
    _raw_log(p, [("/p", rm.POINTCLOUD2, zstandard.compress(cloud)),
                 ("/i", rm.IMAGE, zstandard.compress(_image(4, 5)))])
    r = LogReader(p)
    assert r.image_topic == "/i"
    (f,) = r.frames()
    np.testing.assert_array_equal(f.xyz, xyz)
    bad = bytearray(zstandard.compress(cloud))
    bad[-6] ^= 0xFF
    _raw_log(p, [("/p", rm.POINTCLOUD2, _cloud(4, 5)), ("/p", rm.POINTCLOUD2, bytes(bad))])
    damage, got = _read_all(p)
    assert [f.index for f in got] == [0]  # docs/cli.md: skipped and named, not the end of the run
    assert re.match(r"^frame 1 \(log time 0\.000000001\) skipped: msgz.mcap: topic /p, message 1: "
                    "zstd-compressed message", damage[0]), damage


def _statistics_counts_at(raw: bytes) -> list[int]:
    """Byte offsets of the per-channel message counts in the Statistics record."""
    with_counts = []
    pos = 8
    while pos + 9 <= len(raw):
        op, length = struct.unpack_from("<BQ", raw, pos)
        if op == 0x0B:  # Statistics: u64 message_count, u16, 4 x u32, 2 x u64 times, then the map
            m = pos + 9 + 8 + 2 + 4 * 4 + 8 + 8
            end = m + 4 + struct.unpack_from("<I", raw, m)[0]
            with_counts += list(range(m + 4 + 2, end, 10))
        pos += 9 + length
    return with_counts


@pytest.mark.parametrize("count", [2**62, 2**64 - 1])
def test_absurd_summary_count_is_damage_not_a_hang(small_log, tmp_path, count):
    """A summary claiming 2**62 clouds (a flipped or lying Statistics record) is a damage note naming
    the missing frames as a range, found at once (found by the fuzz suite: it was iterated)."""
    path, frames = small_log[0], small_log[1]
    raw = bytearray(path.read_bytes())
    for at in _statistics_counts_at(bytes(raw)):
        raw[at:at + 8] = struct.pack("<Q", count)
    p = tmp_path / "lie.mcap"
    p.write_bytes(bytes(raw))
    damage, got = _read_all(p)
    assert [g.index for g in got] == list(range(N))
    _check_prefix(got, frames)
    assert damage == [f"frames {N}-{count - 1} lost: the summary lists {count} messages on /camera/points, "
                      f"the file holds {N}"]
    part = LogReader(p).frames(start=1, stop=3)
    assert [g.index for g in part] == [1, 2] and part.damage == ()  # a range stops early
