"""Clouds that share a header stamp (docs/formats.md, "Pairing"): their images, camera info and truth
cannot be told apart, so the frames are skipped and named (exit 3), never paired with another
frame's truth. The logs are written by the independent ``mcap`` + ``mcap_ros2`` libraries, in an order
a hostile-but-valid writer may use."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_cli
from mcap_ros2.writer import Writer as Ros2Writer

from replay.errors import LogDamageError
from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.damage import DamageKind
from replay.logs.reader import LogReader

H, W = 6, 8
N = 10


def _truth(k: int) -> np.ndarray:
    """Frame k's truth: its first k + 1 pixels (row-major), so a swap shows in the count."""
    m = np.zeros(H * W, bool)
    m[: k + 1] = True
    return m.reshape(H, W)


def _write(path, stamps: list[int], order) -> None:
    """A log of len(stamps) frames (cloud, rgb8 image, truth mask) written with mcap_ros2; ``order(k)``
    lists frame k's messages as (topic, frame) pairs, so a frame's messages can be moved."""
    rng = np.random.default_rng(12)
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schemas = {t: w.register_msgdef(t, rm.SCHEMAS[t]) for t in (rm.POINTCLOUD2, rm.IMAGE)}

        def header(k):
            return {"stamp": {"sec": stamps[k] // 10**9, "nanosec": stamps[k] % 10**9}, "frame_id": "camera"}

        msgs = {}
        for k in range(len(stamps)):
            xyz = np.dstack([*np.meshgrid(np.linspace(-0.1, 0.1, W), np.linspace(-0.1, 0.1, H)),
                             np.full((H, W), 0.8 + 0.01 * k)]).astype(np.float32)
            msgs[(layout.CLOUD, k)] = (schemas[rm.POINTCLOUD2], {
                "header": header(k), "height": H, "width": W, "is_bigendian": False, "point_step": 12,
                "row_step": 12 * W, "is_dense": True, "data": xyz.tobytes(),
                "fields": [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1} for i, n in enumerate("xyz")]})
            msgs[(layout.IMAGE, k)] = (schemas[rm.IMAGE], {
                "header": header(k), "height": H, "width": W, "encoding": "rgb8", "is_bigendian": 0, "step": 3 * W,
                "data": rng.integers(0, 255, (H, W, 3), dtype=np.uint8).tobytes()})
            msgs[(layout.TRUTH_OUTLIERS, k)] = (schemas[rm.IMAGE], {
                "header": header(k), "height": H, "width": W, "encoding": "mono8", "is_bigendian": 0, "step": W,
                "data": (_truth(k).astype(np.uint8) * 255).tobytes()})
        t = 0
        for k in range(len(stamps)):
            for topic, j in order(k):
                schema, body = msgs[(topic, j)]
                t += 1
                w.write_message(topic, schema, body, log_time=t, publish_time=t)
        w.finish()


def _in_order(k):
    return [(layout.CLOUD, k), (layout.IMAGE, k), (layout.TRUTH_OUTLIERS, k)]


def _swapped_truth(k):
    """Frames 7 and 8: both clouds first, then 8's image and truth before 7's."""
    if k == 7:
        return [(layout.CLOUD, 7), (layout.CLOUD, 8), (layout.IMAGE, 8), (layout.TRUTH_OUTLIERS, 8),
                (layout.IMAGE, 7), (layout.TRUTH_OUTLIERS, 7)]
    if k == 8:
        return []
    return _in_order(k)


def _stamps(dup: dict[int, int]) -> list[int]:
    s = [(k + 1) * 10**9 for k in range(N)]
    for k, like in dup.items():
        s[k] = s[like]
    return s


@pytest.mark.parametrize("order", [_in_order, _swapped_truth])
def test_two_frames_sharing_a_stamp_are_skipped_not_mispaired(tmp_path, order):
    p = tmp_path / "dup.mcap"
    _write(p, _stamps({8: 7}), order)
    r = LogReader(p)
    assert (r.image_topic, r.mask_topics) == (layout.IMAGE, [layout.TRUTH_OUTLIERS])
    stream = r.frames()
    got = list(stream)
    assert [f.index for f in got] == [0, 1, 2, 3, 4, 5, 6, 9]
    for f in got:  # every delivered frame has its own truth
        np.testing.assert_array_equal(f.masks[layout.TRUTH_OUTLIERS], _truth(f.index))
    assert [(d.kind, d.frame_index, d.stamp_ns) for d in stream.damage] == [
        (DamageKind.DUPLICATE_STAMP, 7, 8 * 10**9), (DamageKind.DUPLICATE_STAMP, 8, 8 * 10**9)]
    assert stream.damage[0].text == (
        "frame 7 (stamp 8.000000000) skipped: its header stamp is also frame 8's: images, "
        "camera info and masks are paired by stamp, so the two frames' cannot be told apart")
    assert stream.damage[1].text.startswith("frame 8 (stamp 8.000000000) skipped: its header stamp is also frame 7's")
    for start, stop in ((0, 8), (7, 10), (8, None), (6, 8), (9, None), (3, 7)):  # any range reads the same
        part = r.frames(start=start, stop=stop)
        want = [k for k in [0, 1, 2, 3, 4, 5, 6, 9] if k >= start and (stop is None or k < stop)]
        assert [f.index for f in part] == want, (start, stop)
        assert [d.frame_index for d in part.damage] == [k for k in (7, 8) if k >= start and (stop is None or k < stop)]
    with pytest.raises(LogDamageError, match="no frame could be read: frame 7 .* skipped: its header stamp"):
        list(r.frames(start=7, stop=9))


def test_a_shared_stamp_two_clouds_apart(tmp_path):
    """Frame 5 has frame 3's stamp: frame 3 was complete and delivered when frame 4's cloud came, so
    frame 5 alone is skipped, naming frame 3; reading from frame 4 or 5 says the same."""
    p = tmp_path / "dup2.mcap"
    _write(p, _stamps({5: 3}), _in_order)
    r = LogReader(p)
    for start in (0, 4, 5):
        stream = r.frames(start=start)
        assert [f.index for f in stream] == [k for k in (0, 1, 2, 3, 4, 6, 7, 8, 9) if k >= start]
        (d,) = stream.damage
        assert (d.kind, d.frame_index) == (DamageKind.DUPLICATE_STAMP, 5)
        assert "its header stamp is also frame 3's" in d.text


def test_without_companions_a_shared_stamp_harms_nothing(tmp_path):
    p = tmp_path / "clouds.mcap"
    _write(p, _stamps({8: 7, 2: 1}), lambda k: [(layout.CLOUD, k)])
    stream = LogReader(p).frames()
    assert [f.index for f in stream] == list(range(N)) and stream.damage == ()


def test_accuracy_exits_3_and_scores_no_frame_against_another_frames_truth(tmp_path, capsys):
    """The fault campaign's case: frame 8 was scored against frame 7's truth, exit 0, no warning."""
    p = tmp_path / "dup.mcap"
    _write(p, _stamps({8: 7}), _swapped_truth)
    code, out, err = run_cli(capsys, "accuracy", p, "--json", "--region", "valid")
    assert code == 3, err
    frames = json.loads(out)["frames"]
    assert [f["index"] for f in frames] == [0, 1, 2, 3, 4, 5, 6, 9]
    for f in frames:  # the truth each frame was scored against is its own (k + 1 true pixels)
        z = f["zcut"]
        assert z["tp"] + z["fn"] == f["index"] + 1
    assert "warning: frame 7 (stamp 8.000000000) skipped: its header stamp is also frame 8's" in err
    assert "warning: frame 8 (stamp 8.000000000) skipped: its header stamp is also frame 7's" in err
