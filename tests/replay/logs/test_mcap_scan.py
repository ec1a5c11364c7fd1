"""The scanner's speed machinery changes nothing but speed: reused buffers are never handed out
while a view of them lives; read-ahead in worker threads (any depth, any byte budget) and the
chunks kept from opening a log give exactly the records, frames and damage notes of a plain
sequential scan, on intact and on damaged files."""

from __future__ import annotations

import gc
import zlib

import numpy as np
import pytest
from log_helpers import mutations

import replay.logs.mcap_scan as ms
from replay.errors import LogFormatError
from replay.logs.frame import Frame
from replay.logs.mcap_scan import BufferPool, McapFile
from replay.logs.reader import LogReader
from replay.logs.stream import FrameStream
from replay.logs.writer import LogWriter

pytestmark = pytest.mark.timeout(120)

H, W = 20, 28


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    rng = np.random.default_rng(3)
    path = tmp_path_factory.mktemp("scan") / "five.mcap"
    with LogWriter(path, chunk_size=2048) as w:
        for i in range(5):
            xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
            rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
            w.write_frame(Frame(xyz=xyz, rgb=rgb, stamp_ns=10**9 * (i + 1), frame_id="cam",
                                intrinsics=None, topic="/camera/points", index=i,
                                masks={"/ground_truth/outliers": rng.random((H, W)) < 0.3}))
    return path


def test_pool_reuses_a_buffer_only_when_no_view_is_left():
    pool = BufferPool()
    n = 2 * BufferPool.MIN_BYTES
    a = pool.get(n)
    base = a.base
    view = memoryview(a)[10:20]  # what a record keeps
    del a
    gc.collect()
    b = pool.get(n)
    assert b.base is not base  # still referenced through the view: a new buffer
    view[0] = 7
    del view
    gc.collect()
    c = pool.get(n - 5)  # n - 5 .. 2 (n - 5) bytes fit
    assert c.base is base and c.size == n - 5
    assert pool.get(n // 3).base is not b.base  # too big a buffer for a third of it
    small = pool.get(100)
    assert small.base is None and small.size == 100  # small requests bypass the pool
    pool.close()
    del b, c
    gc.collect()
    assert pool._free == []  # a closed pool keeps nothing


def _scan(path, **kw):
    damage: list = []
    out = []
    try:
        with McapFile(path) as mf:
            for op, rec in mf.records(damage, **kw):
                if op == ms.OP_MESSAGE:
                    out.append((op, rec.channel_id, rec.log_time, zlib.crc32(rec.data)))
                elif op == ms.OP_LOST:
                    out.append((op, rec))
                else:
                    out.append((op, repr(rec)))
    except LogFormatError as e:
        return "error", str(e)
    return out, damage


def test_read_ahead_changes_nothing(log, tmp_path, monkeypatch):
    raw = log.read_bytes()
    rng = np.random.default_rng(11)
    variants = [raw] + [m for _, m in mutations(raw, rng, 24)]
    for i, data in enumerate(variants):
        p = tmp_path / f"m{i}.mcap"
        p.write_bytes(data)
        plain = _scan(p, prefetch=0)
        assert _scan(p, prefetch=1) == plain
        assert _scan(p, prefetch=3) == plain
        assert _scan(p) == plain  # the default, ms.PREFETCH chunks ahead
        assert _scan(p, prefetch=2 * ms.PREFETCH) == plain
        monkeypatch.setattr(ms, "PREFETCH_BYTES", 0)  # budget: never more than one chunk ahead
        assert _scan(p, prefetch=3) == plain
        monkeypatch.undo()
    assert _scan(log, prefetch=0)[1] == []


def _frames(path):
    try:
        r = LogReader(path)
    except LogFormatError as e:
        return "error", type(e).__name__, str(e)
    out = []
    for attempt in range(2):  # the first scan uses the chunks kept from opening, the second not
        got = []
        stream = r.frames()
        try:
            for f in stream:
                got.append((f.index, f.stamp_ns, f.xyz.tobytes(), None if f.rgb is None else f.rgb.tobytes(),
                            {k: m.tobytes() for k, m in f.masks.items()}))
        except LogFormatError as e:
            got.append(("error", type(e).__name__, str(e)))
        out.append((got, stream.damage))
        if attempt == 0:
            assert r._chunks == {}  # handed to the first scan, not kept
    return out


def test_chunks_kept_from_opening_give_the_same_frames(log, tmp_path):
    r = LogReader(log)
    assert r._chunks  # the first chunks were kept
    first, second = _frames(log)
    assert first == second and len(first[0]) == 5 and first[1] == ()
    raw = log.read_bytes()
    for i, (_, data) in enumerate(mutations(raw, np.random.default_rng(5), 30)):
        p = tmp_path / f"f{i}.mcap"
        p.write_bytes(data)
        got = _frames(p)
        if got[0] != "error":
            assert got[0] == got[1], f"mutant {i}"


def test_frames_read_ahead_or_not_are_the_same(log, tmp_path):
    """A frame stream with the chunks read ahead (the default, :data:`~replay.logs.mcap_scan.PREFETCH`) delivers
    the same frames and damage as one that reads every chunk in its own thread, from the start and from a later
    frame, to the end or over a range (no chunk past the one of the cloud after the range is read ahead), on the
    log and its damaged mutants (the clouds before and after the range read for their stamps)."""
    assert ms.PREFETCH >= 4  # a frame's chunks ahead (docs/performance.md, "Where the last core-fraction waits")

    def frames(path, start, stop, prefetch):  # type: ignore[no-untyped-def]
        try:
            r = LogReader(path)
            stream = FrameStream(r.index(first_pass=False), start=start, stop=stop, prefetch=prefetch)
            got = [(f.index, f.stamp_ns, f.xyz.tobytes(), None if f.rgb is None else f.rgb.tobytes(),
                    {k: m.tobytes() for k, m in f.masks.items()}) for f in stream]
            return got, stream.damage
        except LogFormatError as e:
            return "error", type(e).__name__, str(e)

    raw = log.read_bytes()
    paths = [log]
    for i, (_, data) in enumerate(mutations(raw, np.random.default_rng(17), 20)):
        paths.append(tmp_path / f"r{i}.mcap")
        paths[-1].write_bytes(data)
    for path in paths:
        for start, stop in ((0, None), (2, None), (0, 1), (1, 3), (3, 4), (2, 2)):
            assert frames(path, start, stop, None) == frames(path, start, stop, 0), (path.name, start, stop)
    assert len(frames(log, 0, None, None)[0]) == 5 and len(frames(log, 1, 3, None)[0]) == 2


def test_a_range_reads_ahead_no_chunk_past_the_cloud_after_it(log, monkeypatch):
    """Over frames 0-1 of a log of five, no chunk past the one holding cloud 3 is read (cloud 2 is read for the
    pairing, and the pass ends at cloud 3 at the latest: the window of frame 1 is then full); to the end every
    chunk is."""
    read: list[int] = []
    chunk_at = McapFile._chunk_at

    def counted(self, ref):  # type: ignore[no-untyped-def]
        read.append(ref.offset)
        return chunk_at(self, ref)

    monkeypatch.setattr(McapFile, "_chunk_at", counted)
    r = LogReader(log)
    index = r.index(first_pass=False)
    bound = index.seek(3)[0]
    assert bound is not None
    assert [f.index for f in FrameStream(index, start=0, stop=2)] == [0, 1]
    assert read and max(read) <= bound
    read.clear()
    assert len(list(FrameStream(r.index(first_pass=False)))) == 5
    assert max(read) > bound


def test_frames_own_their_memory(log):
    """Frames never view the chunk buffers (which are reused): rgb from an Image is a copy."""
    for f in LogReader(log).frames():
        for a in (f.xyz, f.rgb, *f.masks.values()):
            assert a.flags.owndata
