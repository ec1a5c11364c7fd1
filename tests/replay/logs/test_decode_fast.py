"""The reader decodes only what the frame holds (issue 32, the reader): with an Image paired, the
cloud's own colour field is not decoded (the frame's colours are the image's), and every frame is the
same bit for bit as the full decoding gives it (every field of the cloud, the image's colours).

Classes of log: a synthetic log (x, y, z, rgba and an rgb8 Image), a log whose colours come from the
cloud alone (no Image topic), a log where one frame's Image is missing (that frame takes the cloud's),
and the real Kinect log (x y z rgb label, no Image).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from kernel_calls import counted_calls
from log_helpers import decoded_in_full

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.logs.stream import without_colour
from replay.logs.writer import LogWriter
from replay.synth.log import write_synthetic_log


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_log(tmp_path_factory.mktemp("decode") / "zn.mcap", kind="zinc_nuts", frames=3, seed=8,
                               size=(120, 160))


def _oracle(path: Path) -> dict[int, tuple[np.ndarray, np.ndarray | None]]:
    """stamp -> (xyz, rgb) decoded in full: every field of the cloud, then the Image's colours when the
    log has one of that stamp."""
    clouds, images = decoded_in_full(path)
    return {s: (xyz, images.get(s, rgb)) for s, (xyz, rgb) in clouds.items()}


def _check(path: Path) -> list[Frame]:
    frames = list(LogReader(path).frames())
    want = _oracle(path)
    assert frames and len(frames) == len(want)
    for f in frames:
        xyz, rgb = want[f.stamp_ns]
        assert f.xyz.dtype == xyz.dtype and np.array_equal(f.xyz.view(np.uint32), xyz.view(np.uint32)), f.index
        if rgb is None:
            assert f.rgb is None
        else:
            assert f.rgb is not None and f.rgb.dtype == np.uint8 and np.array_equal(f.rgb, rgb), f.index
    return frames


@pytest.fixture
def colour_decodes(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the colour-unpacking kernels called (cloud_to_arrays calls them by module global)."""
    return counted_calls(monkeypatch, rm, ("_unpack_words_rgb", "_unpack_xyz_rgb"))


def test_with_an_image_the_cloud_colours_are_not_decoded(synthetic, colour_decodes):
    frames = list(LogReader(synthetic).frames())
    assert len(frames) == 3 and all(f.rgb is not None for f in frames)
    assert colour_decodes == []


def test_frames_equal_the_full_decoding_with_an_image(synthetic):
    _check(synthetic)


def test_without_an_image_and_with_one_image_missing(synthetic, tmp_path, colour_decodes):
    frames = list(LogReader(synthetic).frames())
    alone, gap = tmp_path / "alone.mcap", tmp_path / "gap.mcap"
    with LogWriter(alone) as a, LogWriter(gap) as g:
        for f in frames:
            # a colour of the cloud other than the image's, to see which one the frame takes
            cloud_rgb = (255 - f.rgb) if f.rgb is not None else None
            a.write_cloud(layout.CLOUD, f.xyz, rgb=cloud_rgb, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
            g.write_cloud(layout.CLOUD, f.xyz, rgb=cloud_rgb, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
            if f.index != 1:
                g.write_image(layout.IMAGE, f.rgb, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
    colour_decodes.clear()
    list(LogReader(alone).frames())
    assert len(colour_decodes) == len(frames)  # no image: the cloud's colours, decoded
    colour_decodes.clear()
    list(LogReader(gap).frames())
    assert len(colour_decodes) == 1  # the frame without its image only
    got = _check(alone)
    assert all(np.array_equal(x.rgb, 255 - f.rgb) for x, f in zip(got, frames))
    got = _check(gap)
    assert np.array_equal(got[1].rgb, 255 - frames[1].rgb)  # its image missing: the cloud's
    assert np.array_equal(got[0].rgb, frames[0].rgb) and np.array_equal(got[2].rgb, frames[2].rgb)


def test_the_real_kinect_log(real_data):
    frames = _check(real_data / "mosd_clutter_kinect_ros2.mcap")
    assert all(f.rgb is not None for f in frames)  # its rgb field


def test_without_colour_keeps_the_other_fields():
    fields = (rm.PointField("x", 0, rm.FLOAT32, 1), rm.PointField("y", 4, rm.FLOAT32, 1),
              rm.PointField("z", 8, rm.FLOAT32, 1), rm.PointField("rgb", 12, rm.FLOAT32, 1),
              rm.PointField("label", 16, rm.UINT32, 1))
    cloud = rm.CloudMsg(0, "c", 2, 1, fields, False, 20, 20, memoryview(bytes(40)), True)
    assert [f.name for f in without_colour(cloud).fields] == ["x", "y", "z", "label"]
    plain = rm.CloudMsg(0, "c", 2, 1, fields[:3], False, 12, 12, memoryview(bytes(24)), True)
    assert without_colour(plain) is plain
