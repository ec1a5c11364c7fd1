"""Damage as typed records: each loss is a :class:`Damage` of a :class:`DamageKind`, naming its frame,
stamp or log time, topic and byte; owned by the pass over the log that met it; the text a user reads
is rendered from it (and reads as it always did)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from raw_mcap import write_raw_log

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.damage import Damage, DamageKind, damage_lines, frames_lost
from replay.logs.frame import Frame
from replay.logs.mcap_scan import McapFile
from replay.logs.reader import LogReader
from replay.logs.stream import FrameStream
from replay.logs.writer import LogWriter
from replay.pipeline.session import ReplaySession

H, W = 4, 5


def _log(path, n=6, *, masks=True):
    """n frames, every message in a chunk of its own (a flipped chunk loses one message)."""
    rng = np.random.default_rng(3)
    with LogWriter(path, chunk_size=1) as w:
        for i in range(n):
            xyz = rng.uniform(0.5, 1.0, (H, W, 3)).astype(np.float32)
            rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
            m = {layout.TRUTH_OUTLIERS: rng.random((H, W)) < 0.3} if masks else {}
            w.write_frame(Frame(xyz=xyz, rgb=rgb, stamp_ns=(i + 1) * 10**9, frame_id="c", intrinsics=None,
                                topic=layout.CLOUD, index=i, masks=m))
    with McapFile(path) as mf:
        cid = {c.topic: c.id for c in mf.summary.channels.values()}
        chunks = mf.summary.chunk_indexes
    return {t: [c for c in chunks if i in c.message_index_offsets] for t, i in cid.items()}


def _flip(raw: bytearray, chunk) -> None:
    raw[chunk.chunk_start_offset + 9 + 40 + chunk.compressed_size // 2] ^= 0x5A


def test_a_lost_chunk_is_two_records_the_chunk_and_its_frame(tmp_path):
    p = tmp_path / "l.mcap"
    chunks = _log(p)
    victim = chunks[layout.CLOUD][2]
    raw = bytearray(p.read_bytes())
    _flip(raw, victim)
    p.write_bytes(bytes(raw))
    stream = LogReader(p).frames()
    assert [f.index for f in stream] == [0, 1, 3, 4, 5]
    chunk, frame = stream.damage
    assert chunk.kind is DamageKind.DAMAGED_CHUNK and chunk.byte == victim.chunk_start_offset
    assert chunk.frame_index is None and chunk.frames == range(0)
    assert (frame.kind, frame.frame_index, frame.n_frames, frame.log_time_ns, frame.topic, frame.byte) == (
        DamageKind.LOST_FRAMES, 2, 1, 3 * 10**9, layout.CLOUD, victim.chunk_start_offset)
    assert frame.text == f"frame 2 (log time 3.000000000) lost with the chunk at byte {victim.chunk_start_offset}"
    assert frames_lost(stream.damage) == 1


def test_kinds_of_skipped_frames(tmp_path):
    """A lost companion, a mask of the wrong size, a malformed and an oversized cloud: one record each,
    of its kind, naming the frame, its stamp or log time, and the topic."""
    p = tmp_path / "c.mcap"
    chunks = _log(p)
    raw = bytearray(p.read_bytes())
    _flip(raw, chunks[layout.TRUTH_OUTLIERS][1])  # frame 1 loses its truth mask
    p.write_bytes(bytes(raw))
    stream = LogReader(p).frames()
    assert [f.index for f in stream] == [0, 2, 3, 4, 5]
    lost = [d for d in stream.damage if d.kind is DamageKind.LOST_COMPANION]
    assert len(lost) == 1 and (lost[0].frame_index, lost[0].stamp_ns, lost[0].topic) == (1, 2 * 10**9,
                                                                                         layout.TRUTH_OUTLIERS)
    assert lost[0].text.startswith("frame 1 (stamp 2.000000000) skipped: c.mcap: topic /camera/points, message 1: "
                                   "its /ground_truth/outliers message was lost")

    q = tmp_path / "h.mcap"

    def cloud(stamp, h=H, w=W):
        return rm.encode_cloud(stamp_ns=stamp, frame_id="c", height=h, width=w, fields=rm.XYZ_FIELDS, point_step=16,
                               row_step=16 * w, data=bytes(16 * h * w), is_dense=False)

    def mono(h, w, stamp):
        return rm.encode_image(stamp_ns=stamp, frame_id="c", height=h, width=w, encoding="mono8", step=w,
                               data=bytes(h * w))

    write_raw_log(q, {"/p": rm.POINTCLOUD2, "/m": rm.IMAGE},
                  [("/p", cloud(1)), ("/m", mono(H, W, 1)),
                   ("/p", cloud(2)), ("/m", mono(H, W + 1, 2)),  # a mask of the wrong size
                   ("/p", cloud(3, 64, 64)), ("/m", mono(H, W, 3)),  # over max_pixels
                   ("/p", cloud(4)[:40]),  # cut short: not even its header decodes
                   ("/p", cloud(5)), ("/m", mono(H, W, 5))])
    stream = LogReader(q, max_pixels=1000).frames()
    assert [f.index for f in stream] == [0, 4]
    by_frame = {d.frame_index: d for d in stream.damage}
    assert [(i, by_frame[i].kind) for i in (1, 2, 3)] == [
        (1, DamageKind.WRONG_SIZE), (2, DamageKind.OVER_CAP), (3, DamageKind.MALFORMED_MESSAGE)]
    assert by_frame[1].topic == "/m" and by_frame[1].stamp_ns == 2
    assert by_frame[3].log_time_ns == 7 and by_frame[3].stamp_ns is None  # no header could be read
    assert all(d.n_frames == 1 and d.text.startswith(f"frame {d.frame_index} (") for d in stream.damage)


def test_each_pass_owns_its_records(tmp_path):
    p = tmp_path / "o.mcap"
    chunks = _log(p)
    raw = bytearray(p.read_bytes())
    _flip(raw, chunks[layout.CLOUD][4])
    p.write_bytes(bytes(raw))
    r = LogReader(p)
    whole = r.frames()
    assert len(list(whole)) == 5
    first = whole.damage
    assert [d.kind for d in first] == [DamageKind.DAMAGED_CHUNK, DamageKind.LOST_FRAMES]
    head = r.frames(stop=3)  # a pass that never reaches the damage: nothing lost, whatever came before
    assert [f.index for f in head] == [0, 1, 2] and head.damage == ()
    assert whole.damage == first  # the first pass's records are its own, final
    early = r.frames()
    next(early)
    early.close()  # stopped before the damage: final, and empty
    assert early.damage == () and list(early) == []
    assert not hasattr(r, "damage")  # the reader keeps no ledger


def test_a_damaged_summary_is_a_record_of_every_pass(tmp_path):
    p = tmp_path / "s.mcap"
    _log(p, 2)
    raw = bytearray(p.read_bytes())
    raw[-8 - 29 + 9 + 3] ^= 0xFF  # the footer's summary start: the summary cannot be read
    p.write_bytes(bytes(raw))
    r = LogReader(p)
    assert [d.kind for d in r.open_damage] == [DamageKind.DAMAGED_SUMMARY]
    for _ in range(2):
        stream = r.frames()
        assert len(list(stream)) == 2
        assert stream.damage[0].kind is DamageKind.DAMAGED_SUMMARY
        assert stream.damage[0].text.startswith("the summary section is damaged (")


def test_truncation_is_a_truncated_record(tmp_path):
    p = tmp_path / "t.mcap"
    chunks = _log(p)
    cut = chunks[layout.CLOUD][3].chunk_start_offset + 20
    p.write_bytes(p.read_bytes()[:cut])
    stream = LogReader(p).frames()
    assert [f.index for f in stream] == [0, 1, 2]
    assert stream.damage[-1].kind is DamageKind.TRUNCATED and stream.damage[-1].byte is not None
    assert stream.damage[-1].text.startswith("t.mcap is truncated: ")


@pytest.mark.parametrize("record,text", [
    (Damage(DamageKind.LOST_FRAMES, "lost with the chunk at byte 9", frame_index=3, n_frames=3, log_time_ns=4 * 10**9,
            last_log_time_ns=6 * 10**9 + 5),
     "frames 3-5 (log times 4.000000000 .. 6.000000005) lost with the chunk at byte 9"),
    (Damage(DamageKind.LOST_FRAMES, "lost: x", frame_index=1, n_frames=1), "frame 1 lost: x"),
    (Damage(DamageKind.WRONG_SIZE, "m.mcap: mask is 2x2", frame_index=7, n_frames=1, stamp_ns=-1_500_000_000),
     "frame 7 (stamp -1.500000000) skipped: m.mcap: mask is 2x2"),
    (Damage(DamageKind.UNKNOWN_LOSS, "the number of clouds in the lost chunk is unknown", frame_index=4),
     "the number of clouds in the lost chunk is unknown"),
    (Damage(DamageKind.MALFORMED_MESSAGE, "x.mcap: topic /i: bad; its frame cannot be told (not paired)",
            log_time_ns=5, topic="/i"), "x.mcap: topic /i: bad; its frame cannot be told (not paired)"),
])
def test_the_text_is_rendered_from_the_record(record, text):
    assert record.text == str(record) == text
    assert damage_lines([record, record]) == [text, text]
    d = record.as_dict()
    assert d["kind"] == record.kind.value and d["text"] == text
    assert pickle.loads(pickle.dumps(record)) == record  # crosses to and from worker processes
    with pytest.raises(AttributeError):
        record.message = "changed"  # frozen


def test_a_replay_summary_carries_the_records_and_renders_them(tmp_path):
    p = tmp_path / "r.mcap"
    chunks = _log(p, 4)
    raw = bytearray(p.read_bytes())
    _flip(raw, chunks[layout.CLOUD][1])
    p.write_bytes(bytes(raw))
    session = ReplaySession.open(p)
    results = session.results()
    assert [f.index for f, _ in results] == [0, 2, 3]
    assert [d.kind for d in results.damage] == [DamageKind.DAMAGED_CHUNK, DamageKind.LOST_FRAMES]
    summary = session.run()
    assert [d.kind for d in summary.damage] == [DamageKind.DAMAGED_CHUNK, DamageKind.LOST_FRAMES]
    assert summary.as_dict()["damage"] == damage_lines(summary.damage)
    assert summary.as_dict()["damage"][1].startswith("frame 1 (log time 2.000000000) lost with the chunk at byte ")


def test_frame_stream_is_what_frames_returns(tmp_path):
    p = tmp_path / "f.mcap"
    _log(p, 2, masks=False)
    stream = LogReader(p).frames()
    assert isinstance(stream, FrameStream) and iter(stream) is stream
    with stream:
        assert next(stream).index == 0
    assert list(stream) == []  # closed
