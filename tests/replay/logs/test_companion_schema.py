"""A message of another schema on a topic zcut reads (a second channel on the topic, e.g. an Image
on the camera info topic): the topics are chosen by the schema of their first channel, so such a
message is damage -- a ``malformed_message`` record naming the topic, the message's schema and the
topic's -- and its frame is skipped, whichever companion it is (docs/formats.md, "Damage")."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import run_cli

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.damage import DamageKind
from replay.logs.reader import LogReader
from replay.logs.writer import OFFERED_QOS_PROFILES, LogWriter
from zcut.cloud import Intrinsics

H, W = 12, 16
K = Intrinsics(fx=50.0, fy=50.0, cx=8.0, cy=6.0, width=W, height=H)
SEC = 1_000_000_000


def _foreign(w: LogWriter, topic: str, schema: str, data: bytes, t: int) -> None:
    """``data`` on ``topic`` through a channel of its own carrying ``schema`` (a second channel on the topic)."""
    if schema not in w._schemas:
        text = rm.SCHEMAS.get(schema, "string data\n")
        w._schemas[schema] = w._writer.register_schema(name=schema, encoding="ros2msg", data=text.encode())
    cid = w._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=w._schemas[schema],
                                     metadata={"offered_qos_profiles": OFFERED_QOS_PROFILES})
    w._writer.add_message(channel_id=cid, log_time=t, data=data, publish_time=t, sequence=0)


def _image(t: int, rgb: np.ndarray) -> bytes:
    return rm.encode_image(stamp_ns=t, frame_id="camera", height=H, width=W, encoding="rgb8", step=3 * W,
                           data=rgb.tobytes())


#: per companion topic: the schema of the stray message written there at frame 1, and the topic's own
STRAYS = {
    layout.CAMERA_INFO: (rm.IMAGE, rm.CAMERAINFO),
    layout.IMAGE: (rm.CAMERAINFO, rm.IMAGE),
    layout.TRUTH_OUTLIERS: (rm.CAMERAINFO, rm.IMAGE),
    layout.CLOUD: (rm.IMAGE, rm.POINTCLOUD2),
}


def _log(path, stray_topic: str, *, also_own: str | None = None, schema: str | None = None, frames: int = 3):
    """``frames`` frames (cloud, image, camera info, truth mask; stamps 1, 2, … s); frame 1's message on
    ``stray_topic`` is one of another schema on a second channel (``schema``, else :data:`STRAYS`'s), and
    its own message too when ``also_own`` is "before" or "after" it."""
    rng = np.random.default_rng(5)
    xyz = rng.uniform(0.4, 0.6, (H, W, 3)).astype(np.float32)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    truth = np.zeros((H, W), bool)
    truth[2:4, 3:6] = True
    with LogWriter(path) as w:
        for i in range(frames):
            t = (i + 1) * SEC
            own = {
                layout.CLOUD: lambda t=t: w.write_cloud(layout.CLOUD, xyz, rgb=rgb, stamp_ns=t, frame_id="camera"),
                layout.IMAGE: lambda t=t: w.write_image(layout.IMAGE, rgb, stamp_ns=t, frame_id="camera"),
                layout.CAMERA_INFO: lambda t=t: w.write_camera_info(layout.CAMERA_INFO, K, stamp_ns=t,
                                                                    frame_id="camera"),
                layout.TRUTH_OUTLIERS: lambda t=t: w.write_mask(layout.TRUTH_OUTLIERS, truth, stamp_ns=t,
                                                                frame_id="camera"),
            }
            for topic, write in own.items():
                if i != 1 or topic != stray_topic:
                    write()
                    continue
                if also_own == "before":
                    write()
                kind = schema or STRAYS[topic][0]
                data = (rm.encode_camera_info(K, stamp_ns=t, frame_id="camera") if kind == rm.CAMERAINFO
                        else _image(t, rgb) if kind == rm.IMAGE else b"\x00\x01\x00\x00\x03\x00\x00\x00ab\x00")
                _foreign(w, topic, kind, data, t)
                if also_own == "after":
                    write()
    return path


@pytest.mark.parametrize("topic", [layout.CAMERA_INFO, layout.IMAGE, layout.TRUTH_OUTLIERS])
def test_a_companion_of_another_schema_skips_its_frame(tmp_path, topic):
    """Before: the frame stream stopped with an AttributeError ('ImageMsg' object has no attribute 'k')
    or decoded a CameraInfo as an Image; now the frame is skipped with one record, the others intact."""
    p = _log(tmp_path / "m.mcap", topic)
    r = LogReader(p)
    assert (r.cloud_topic, r.image_topic, r.info_topic, r.mask_topics) == (
        layout.CLOUD, layout.IMAGE, layout.CAMERA_INFO, [layout.TRUTH_OUTLIERS])
    stream = r.frames()
    frames = list(stream)
    assert [f.index for f in frames] == [0, 2]
    assert all(f.intrinsics == K and f.rgb is not None and f.masks[layout.TRUTH_OUTLIERS].sum() == 6 for f in frames)
    (d,) = stream.damage
    have, want = STRAYS[topic]
    assert (d.kind, d.frame_index, d.n_frames, d.stamp_ns, d.topic) == (DamageKind.MALFORMED_MESSAGE, 1, 1, 2 * SEC,
                                                                        topic)
    assert d.text.startswith(f"frame 1 (stamp 2.000000000) skipped: m.mcap: topic {topic}, stamp 2.000000000: "
                             f"a {have} message (channel ")
    assert d.text.endswith(f"), not a {want}") and "\n" not in d.text


@pytest.mark.parametrize("order", ["before", "after"])
@pytest.mark.parametrize("topic", [layout.CAMERA_INFO, layout.IMAGE, layout.TRUTH_OUTLIERS])
def test_the_frame_is_skipped_whichever_arrives_first(tmp_path, topic, order):
    """Its own message at the same stamp as well: the frame is still skipped (not the arrival order decides)."""
    stream = LogReader(_log(tmp_path / "m.mcap", topic, also_own=order)).frames()
    assert [f.index for f in stream] == [0, 2]
    assert [(d.kind, d.frame_index, d.topic) for d in stream.damage] == [(DamageKind.MALFORMED_MESSAGE, 1, topic)]


def test_a_message_of_a_type_zcut_does_not_decode_is_named_by_its_log_time(tmp_path):
    """A schema zcut cannot read a stamp from: the record names the topic and log time (its frame
    cannot be told), and the frame of the same log time is skipped, as for any companion that does not decode."""
    stream = LogReader(_log(tmp_path / "s.mcap", layout.CAMERA_INFO, schema="std_msgs/msg/String")).frames()
    assert [f.index for f in stream] == [0, 2]
    bad, lost = stream.damage
    assert (bad.kind, bad.frame_index, bad.log_time_ns, bad.topic) == (
        DamageKind.MALFORMED_MESSAGE, None, 2 * SEC, layout.CAMERA_INFO)
    assert bad.text.startswith(f"s.mcap: topic {layout.CAMERA_INFO}, message at log time 2.000000000: "
                               "a std_msgs/msg/String message (channel ")
    assert bad.text.endswith(f"), not a {rm.CAMERAINFO}; its frame cannot be told (not paired)")
    assert (lost.kind, lost.frame_index) == (DamageKind.LOST_COMPANION, 1)


def test_a_cloud_of_another_schema_is_a_malformed_frame(tmp_path):
    """An Image on the cloud topic is a frame of its own that does not decode, named with both schemas."""
    stream = LogReader(_log(tmp_path / "c.mcap", layout.CLOUD)).frames()
    assert [f.index for f in stream] == [0, 2]
    (d,) = stream.damage
    assert (d.kind, d.frame_index, d.topic) == (DamageKind.MALFORMED_MESSAGE, 1, layout.CLOUD)
    assert d.text.startswith(f"frame 1 (log time 2.000000000) skipped: c.mcap: topic {layout.CLOUD}, message 1: "
                             f"a {rm.IMAGE} message (channel ")
    assert d.text.endswith(f"), not a {rm.POINTCLOUD2}")


def test_replay_warns_in_one_line_and_exits_3(tmp_path, capsys):
    """``zcut replay``: the frames before and after are processed, the skipped one is one warning line
    (the record's text), exit status 3 (finished with data loss)."""
    p = _log(tmp_path / "m.mcap", layout.CAMERA_INFO)
    stream = LogReader(p).frames()
    list(stream)
    (d,) = stream.damage
    rc, out, err = run_cli(capsys, "replay", p)
    assert rc == 3 and "Traceback" not in err
    assert [s for s in err.splitlines() if "frame 1" in s] == [f"warning: data loss: {d.text}"]
    assert f"topic {layout.CAMERA_INFO}, stamp 2.000000000: a {rm.IMAGE} message" in d.text
    assert [s.split()[0] for s in out.splitlines()[1:]] == ["0", "2"]
