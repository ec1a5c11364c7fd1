"""Results files hold their masks bit-packed (``mono1`` Images, docs/formats.md "Results"): the packing
round-trips every shape, the readers read it and the ``mono8`` masks of the files the previous releases
wrote alike, and the counts read back from a results file are replay's."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from cli_helpers import accuracy_report, run_cli
from mcap.reader import make_reader

from replay.errors import LogFormatError
from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.reader import LogReader, read_mask_topics
from replay.logs.writer import LogWriter


def _literal_unpack(msg: rm.ImageMsg) -> np.ndarray:
    """The layout as docs/formats.md states it, pixel by pixel: row r's pixel c is bit 7 - c % 8 of byte
    r * step + c // 8."""
    out = np.zeros((msg.height, msg.width), bool)
    data = bytes(msg.data)
    for r in range(msg.height):
        for c in range(msg.width):
            out[r, c] = (data[r * msg.step + c // 8] >> (7 - c % 8)) & 1
    return out


@pytest.mark.parametrize("shape", [(1, 1), (3, 3), (1, 9), (7, 8), (5, 17), (16, 64), (31, 45)])
@pytest.mark.parametrize("fill", ["random", "none", "all"])
def test_packed_masks_round_trip_every_shape(shape, fill):
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    mask = {"random": rng.random(shape) < 0.3, "none": np.zeros(shape, bool), "all": np.ones(shape, bool)}[fill]
    bits = rm.mask_to_packed(mask)
    assert bits.shape == (shape[0], (shape[1] + 7) // 8)
    msg = rm.decode_image(rm.encode_image(stamp_ns=1, frame_id="c", height=shape[0], width=shape[1],
                                          encoding=rm.PACKED_MASK_ENCODING, step=bits.shape[1], data=bits.tobytes()))
    got = rm.image_to_mask(msg, where="t")
    assert got.dtype == bool and got.shape == shape
    assert np.array_equal(got, mask) and np.array_equal(_literal_unpack(msg), mask)


def test_a_padded_step_is_read_and_short_data_refused():
    mask = np.random.default_rng(3).random((4, 11)) < 0.5
    bits = rm.mask_to_packed(mask)  # 2 bytes a row
    padded = np.zeros((4, 5), np.uint8)
    padded[:, :2] = bits
    msg = rm.decode_image(rm.encode_image(stamp_ns=1, frame_id="c", height=4, width=11,
                                          encoding=rm.PACKED_MASK_ENCODING, step=5, data=padded.tobytes()))
    assert np.array_equal(rm.image_to_mask(msg, where="t"), mask)
    short = rm.decode_image(rm.encode_image(stamp_ns=1, frame_id="c", height=4, width=11,
                                            encoding=rm.PACKED_MASK_ENCODING, step=2, data=bits.tobytes()[:-1]))
    with pytest.raises(LogFormatError, match="needs 8 bytes of data but has 7"):
        rm.image_to_mask(short, where="t")
    narrow = rm.decode_image(rm.encode_image(stamp_ns=1, frame_id="c", height=4, width=11,
                                             encoding=rm.PACKED_MASK_ENCODING, step=1, data=bits.tobytes()))
    with pytest.raises(LogFormatError, match="step 1 is smaller"):
        rm.image_to_mask(narrow, where="t")
    with pytest.raises(LogFormatError, match="mono8 or mono1"):
        rm.image_to_mask(dataclasses.replace(msg, encoding="mono16"), where="t")


def _unpacked_copy(src, dst) -> None:
    """``dst``: ``src`` as the previous release wrote it: every mono1 mask written back as a mono8 one by
    LogWriter.write_mask (the old path), every other message, the metadata and attachments as they are."""
    reader = LogReader(src, cloudless=True)
    with open(src, "rb") as f:
        r = make_reader(f)
        attachments = {a.name: (a.media_type, a.data) for a in r.iter_attachments()}
    with open(src, "rb") as f, LogWriter(dst, metadata=reader.metadata, attachments=attachments) as w:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if schema.name == rm.IMAGE:
                msg = rm.decode_image(message.data)
                if msg.encoding == rm.PACKED_MASK_ENCODING:
                    w.write_mask(channel.topic, rm.image_to_mask(msg, where="copy"), stamp_ns=msg.stamp_ns,
                                 frame_id=msg.frame_id)
                    continue
            w._add(channel.topic, schema.name, message.data, message.log_time)


@pytest.fixture(scope="module", params=[("rods", "11"), ("zinc_nuts", "5")])
def files(request, tmp_path_factory):
    kind, seed = request.param
    from session_logs import replay_out_once, synth_once

    # the rods log and its results file are tests/replay/logs/test_cloudless_results.py's too: made once per session
    log = synth_once(tmp_path_factory, parts=kind, frames=2, seed=int(seed), size="240x384")
    res = replay_out_once(tmp_path_factory, log)
    old = tmp_path_factory.mktemp(f"packed_{kind}") / "old.mcap"
    _unpacked_copy(res, old)
    return log, res, old


def _encodings(path) -> dict[str, str]:
    return {t.topic: t.encoding for t in LogReader(path, cloudless=True).topics.values() if t.encoding}


def test_replay_writes_every_mask_packed(files):
    _, res, old = files
    enc = _encodings(res)
    masks = [layout.ZCUT_OUTLIERS, layout.SOR_OUTLIERS, layout.BIN_MASK, layout.VALID, layout.ZONE,
             layout.TRUTH_OUTLIERS, layout.TRUTH_OFF_SURFACE]
    assert all(enc[t] == rm.PACKED_MASK_ENCODING for t in masks), enc
    assert enc[layout.TRUTH_OUTLIER_KIND] == "mono8"  # codes, not a mask
    assert all(_encodings(old)[t] == "mono8" for t in masks)
    assert res.stat().st_size < old.stat().st_size


def test_the_new_and_the_previous_layout_read_alike(files):
    log, res, old = files
    new_frames = list(LogReader(res, cloudless=True).frames())
    old_frames = list(LogReader(old, cloudless=True).frames())
    assert len(new_frames) == len(old_frames) == 2
    for n, o, s in zip(new_frames, old_frames, LogReader(log).frames(), strict=True):
        assert (n.index, n.stamp_ns) == (o.index, o.stamp_ns) == (s.index, s.stamp_ns)
        assert n.masks.keys() == o.masks.keys()
        for k in n.masks:
            assert n.masks[k].dtype == bool and np.array_equal(n.masks[k], o.masks[k]), k
        assert np.array_equal(n.masks[layout.TRUTH_OUTLIERS], s.masks[layout.TRUTH_OUTLIERS])
        assert np.array_equal(n.codes[layout.TRUTH_OUTLIER_KIND], s.codes[layout.TRUTH_OUTLIER_KIND])
    _, a = read_mask_topics(res, (layout.ZCUT_OUTLIERS,))
    _, b = read_mask_topics(old, (layout.ZCUT_OUTLIERS,))
    assert a.keys() == b.keys() and all(np.array_equal(a[k][layout.ZCUT_OUTLIERS], b[k][layout.ZCUT_OUTLIERS]) for k in a)


def test_counts_read_back_are_replays(files, capsys):
    log, res, old = files
    rc, out, err = run_cli(capsys, "replay", log, "--json")
    assert rc == 0, err
    want = [(r["zcut"], r["sor"]) for r in json.loads(out)["frames"]]
    for path in (res, old):
        frames = list(LogReader(path, cloudless=True).frames())
        got = [(int(f.masks[layout.ZCUT_OUTLIERS].sum()), int(f.masks[layout.SOR_OUTLIERS].sum())) for f in frames]
        assert got == want and any(z for z, _ in got)


@pytest.mark.parametrize("truth", ["paper", "sensor"])
def test_accuracy_of_either_layout_is_that_of_the_log(files, capsys, truth):
    log, res, old = files
    reps = [accuracy_report(capsys, p, "--truth", truth) for p in (log, res, old)]
    assert reps[0]["frames"] and reps[0]["pooled"]
    for rep in reps[1:]:
        assert rep["pooled"] == reps[0]["pooled"] and rep["frames"] == reps[0]["frames"]
