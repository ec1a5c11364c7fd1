"""A frame's masks and codes read from a log are decoded when first read (``replay.logs.frame.LazyArrays``): each
the same array as the eager decoding gave (mono8 and bit-packed masks, codes), at shapes from one row to one
above the pool's smallest buffer; checked when the frame is paired (a bad message skips its frame as before);
decoded once (two threads get one array); never written over by later passes while the frame is kept, however
late it is read; a dict in every other way (keys without decoding, assignment, pop, clear, equality, copies).
"""

from __future__ import annotations

import copy
import pickle
import threading
from pathlib import Path

import numpy as np
import pytest
from raw_mcap import write_raw_log

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.frame import Frame, LazyArrays
from replay.logs.mcap_scan import BufferPool
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter

PACKED = "/zcut/outliers"  # a results topic: written bit-packed (mono1)


def _frames(shape: tuple[int, int], n: int, seed: int) -> list[Frame]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        xyz = rng.uniform(0.2, 1.0, (*shape, 3)).astype(np.float32)
        xyz[rng.random(shape) < 0.1] = np.nan
        masks = {layout.TRUTH_OUTLIERS: rng.random(shape) < 0.3, layout.TRUTH_OFF_SURFACE: rng.random(shape) < 0.05}
        codes = {layout.TRUTH_OUTLIER_KIND: rng.integers(0, 7, shape, dtype=np.uint8)}
        out.append(Frame(xyz=xyz, rgb=None, stamp_ns=1000 + i, frame_id="cam", intrinsics=None, topic=layout.CLOUD,
                         index=i, masks=masks, codes=codes))
    return out


def _write(path: Path, frames: list[Frame]) -> Path:
    with LogWriter(path) as w:
        for f in frames:
            w.write_frame(f)
            for topic, c in f.codes.items():
                w.write_codes(topic, c, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
            w.write_mask(PACKED, f.masks[layout.TRUTH_OUTLIERS] ^ f.masks[layout.TRUTH_OFF_SURFACE],
                         stamp_ns=f.stamp_ns, frame_id=f.frame_id, packed=True)
    return path


def _pending(f: Frame) -> set[str]:
    """The topics of the frame's masks and codes not decoded yet."""
    return {k for m in (f.masks, f.codes) for k, v in m._items.items() if not isinstance(v, np.ndarray)}  # type: ignore[attr-defined]


def _check(got: Frame, want: Frame) -> None:
    assert isinstance(got.masks, LazyArrays) and isinstance(got.codes, LazyArrays)
    assert set(got.masks) == {layout.TRUTH_OUTLIERS, layout.TRUTH_OFF_SURFACE, PACKED}
    for k, m in want.masks.items():
        assert got.masks[k].dtype == np.bool_ and np.array_equal(got.masks[k], m), k
    assert np.array_equal(got.masks[PACKED], want.masks[layout.TRUTH_OUTLIERS] ^ want.masks[layout.TRUTH_OFF_SURFACE])
    kinds = got.codes[layout.TRUTH_OUTLIER_KIND]
    assert kinds.dtype == np.uint8 and np.array_equal(kinds, want.codes[layout.TRUTH_OUTLIER_KIND])


# (2, 5): one row of bytes short of a word; (1100, 960): a mask above the pool's 1 MB, in pooled memory
@pytest.mark.parametrize("shape", [(2, 5), (3, 1), (37, 61), (1100, 960)])
def test_decoded_on_first_read_as_the_eager_decoding(tmp_path, shape):
    want = _frames(shape, 3, seed=shape[0] + shape[1])
    path = _write(tmp_path / "m.mcap", want)
    frames = list(LogReader(path).frames())
    assert [f.index for f in frames] == [0, 1, 2]
    for f, w in zip(frames, want, strict=True):
        assert _pending(f) == {layout.TRUTH_OUTLIERS, layout.TRUTH_OFF_SURFACE, PACKED, layout.TRUTH_OUTLIER_KIND}
        assert layout.TRUTH_OUTLIERS in f.masks and len(f.masks) == 3 and list(f.codes) == [layout.TRUTH_OUTLIER_KIND]
        assert _pending(f) and f.masks.keys() == {layout.TRUTH_OUTLIERS, layout.TRUTH_OFF_SURFACE, PACKED}
        _check(f, w)
        assert not _pending(f)
        assert f.masks[layout.TRUTH_OUTLIERS] is f.masks[layout.TRUTH_OUTLIERS]  # decoded once
        # the eager functions decode the same messages to the same arrays
        msg = rm.decode_image(rm.encode_image(stamp_ns=1, frame_id="c", height=shape[0], width=shape[1],
                                              encoding="mono8", step=shape[1],
                                              data=(255 * w.masks[layout.TRUTH_OUTLIERS]).astype(np.uint8).tobytes()),
                              where="m")
        assert np.array_equal(rm.image_to_mask(msg, where="m"), rm.mask_decoding(msg, where="m")())


def test_a_frame_kept_unread_is_never_written_over(tmp_path):
    """Frames kept with their masks unread while later passes decode theirs into the reused memory: the masks
    read last are the log's (a pending decoding holds its message's chunk, which is not reused meanwhile)."""
    shape = (1100, 960)
    want = _frames(shape, 3, seed=5)
    reader = LogReader(_write(tmp_path / "k.mcap", want))
    kept = list(reader.frames())
    for _ in range(3):
        for f in reader.frames():
            for m in (*f.masks.values(), *f.codes.values()):
                m[...] = ~m if m.dtype == np.bool_ else 255 - m  # what a later user could do to its own frame
        del f
    assert all(_pending(f) for f in kept)
    for f, w in zip(kept, want, strict=True):
        _check(f, w)


def test_a_bad_mask_still_skips_its_frame_when_paired(tmp_path):
    """The checks run when the frame is paired (not when a mask is read): a mask whose bytes are short skips its
    frame with the damage record it had."""
    from replay.logs.damage import DamageKind

    h, w = 6, 8

    def cloud(stamp):
        return rm.encode_cloud(stamp_ns=stamp, frame_id="c", height=h, width=w, fields=rm.XYZ_FIELDS, point_step=16,
                               row_step=16 * w, data=bytes(16 * h * w), is_dense=False)

    def mono(stamp, data, encoding="mono8"):
        return rm.encode_image(stamp_ns=stamp, frame_id="c", height=h, width=w, encoding=encoding, step=w,
                               data=data)

    q = tmp_path / "bad.mcap"
    write_raw_log(q, {layout.CLOUD: rm.POINTCLOUD2, layout.TRUTH_OUTLIERS: rm.IMAGE},
                  [(layout.CLOUD, cloud(1)), (layout.TRUTH_OUTLIERS, mono(1, bytes(h * w))),
                   (layout.CLOUD, cloud(2)), (layout.TRUTH_OUTLIERS, mono(2, bytes(h * w - 3))),  # short
                   (layout.CLOUD, cloud(3)), (layout.TRUTH_OUTLIERS, mono(3, bytes(h * w), encoding="mono16")),
                   (layout.CLOUD, cloud(4)), (layout.TRUTH_OUTLIERS, mono(4, b"\x07" * (h * w)))])
    stream = LogReader(q).frames()
    got = list(stream)
    assert [f.index for f in got] == [0, 3]
    assert [(d.frame_index, d.kind) for d in stream.damage] == [(1, DamageKind.MALFORMED_MESSAGE),
                                                               (2, DamageKind.MALFORMED_MESSAGE)]
    assert "needs 48 bytes of data but has 45" in stream.damage[0].text
    assert not got[0].masks[layout.TRUTH_OUTLIERS].any() and got[1].masks[layout.TRUTH_OUTLIERS].all()  # 7 -> True


def test_threads_reading_one_topic_get_one_array(tmp_path):
    path = _write(tmp_path / "t.mcap", _frames((300, 400), 1, seed=8))
    for _ in range(5):
        f = next(iter(LogReader(path).frames()))
        got: list[np.ndarray] = []
        barrier = threading.Barrier(6)

        threads = [threading.Thread(target=_read_after, args=(barrier, f, got)) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(got) == 6 and all(g is got[0] for g in got)


def _read_after(barrier: threading.Barrier, f: Frame, got: list[np.ndarray]) -> None:
    barrier.wait()
    got.append(f.masks[layout.TRUTH_OUTLIERS])


def test_a_dict_in_every_other_way(tmp_path):
    want = _frames((20, 30), 1, seed=9)[0]
    f = next(iter(LogReader(_write(tmp_path / "d.mcap", [want])).frames()))
    m = f.masks
    assert m == {**m} == dict(m) and m != {} and dict(m).keys() == m.keys()
    for other in (pickle.loads(pickle.dumps(m)), copy.deepcopy(m)):  # every value decoded, then copied
        assert isinstance(other, LazyArrays) and other.keys() == m.keys()
        assert all(np.array_equal(other[k], m[k]) and other[k] is not m[k] for k in m)
    assert "LazyArrays(" in repr(m) and m.get("/nothing") is None and "/nothing" not in m
    f2 = next(iter(LogReader(tmp_path / "d.mcap").frames()))
    popped = f2.masks.pop(layout.TRUTH_OFF_SURFACE)
    assert np.array_equal(popped, want.masks[layout.TRUTH_OFF_SURFACE]) and layout.TRUTH_OFF_SURFACE not in f2.masks
    f2.masks["/mine"] = np.ones((20, 30), bool)
    assert f2.masks["/mine"].all() and len(f2.masks) == 3
    f2.masks.clear()
    assert f2.masks == {} and len(f2.masks) == 0
    assert LazyArrays() == {} and LazyArrays({"a": lambda: np.zeros(2)})["a"].shape == (2,)


def test_pooled_masks_go_back_to_the_pool(tmp_path):
    """A mask decoded into the pool's memory, and the chunk a pending decoding holds, go back once the frame is
    gone: a later pass reuses them (no fresh buffers every frame)."""
    import gc

    path = _write(tmp_path / "p.mcap", _frames((1100, 960), 3, seed=11))
    reader = LogReader(path)
    assert isinstance(reader.pool, BufferPool)
    for f in reader.frames():
        _ = f.masks[layout.TRUTH_OUTLIERS]
    del f
    gc.collect()
    free = len(reader.pool._free)
    assert free > 0
    for f in reader.frames():  # half read, half not
        if f.index % 2:
            _ = dict(f.masks)
    del f
    gc.collect()
    assert len(reader.pool._free) >= free
