"""Interoperability: a client we did not write reads our logs.

The ``rerun`` binary shipped with rerun-sdk converts an .mcap to .rrd with its own ROS 2 decoders
(``rerun mcap convert``); reading the .rrd back with ``rr.chunk.RrdReader`` must show our clouds
(Points3D positions), colour images (Image), masks (mono8 -> DepthImage) and camera info (Pinhole),
with the header stamps on the ``ros2_timestamp`` timeline.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from replay.logs.writer import LogWriter
from zcut.cloud import Intrinsics

rr = pytest.importorskip("rerun")

H, W = 12, 16
STAMPS = [1_700_000_000_250_000_000, 1_700_000_001_250_000_000]


def _rerun_binary() -> str:
    exe = Path(sys.executable).with_name("rerun")
    found = str(exe) if exe.exists() else shutil.which("rerun")
    if found is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")
    return found


@pytest.fixture
def converted(tmp_path, rng):
    xyzs, rgbs, masks = [], [], []
    log = tmp_path / "ours.mcap"
    with LogWriter(log) as w:
        for stamp in STAMPS:
            xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
            xyz[2, 3] = np.nan  # invalid points travel as NaN
            rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
            mask = rng.random((H, W)) < 0.3
            w.write_cloud("/camera/points", xyz, rgb=rgb, stamp_ns=stamp, frame_id="cam")
            w.write_image("/camera/image", rgb, stamp_ns=stamp, frame_id="cam")
            w.write_mask("/zcut/outliers", mask, stamp_ns=stamp, frame_id="cam")
            w.write_camera_info("/camera/camera_info", Intrinsics(520.0, 521.0, 7.5, 5.5, W, H),
                                stamp_ns=stamp, frame_id="cam")
            xyzs.append(xyz)
            rgbs.append(rgb)
            masks.append(mask)
    rrd = tmp_path / "ours.rrd"
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "cfg"), HOME=str(tmp_path))
    subprocess.run([_rerun_binary(), "analytics", "disable"], env=env, capture_output=True, timeout=60)
    proc = subprocess.run([_rerun_binary(), "mcap", "convert", str(log), "-o", str(rrd)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return rrd, xyzs, rgbs, masks


def _rows(rrd: Path) -> dict[str, list[tuple[int, str, object]]]:
    """entity path -> [(ros2 stamp ns, component, value)] for the temporal columns."""
    out: dict[str, list] = {}
    for chunk in rr.chunk.RrdReader(str(rrd)).store().stream().to_chunks():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "ros2_timestamp" not in names:
            continue
        stamps = batch.column("ros2_timestamp").cast("int64").to_pylist()
        for name in names:
            if ":" not in name:
                continue
            for stamp, value in zip(stamps, batch.column(name).to_pylist(), strict=True):
                out.setdefault(str(chunk.entity_path), []).append((stamp, name, value))
    return out


@pytest.mark.timeout(180)
def test_rerun_reads_our_clouds_images_masks_and_camera_info(converted):
    rrd, xyzs, rgbs, masks = converted
    rows = _rows(rrd)
    assert {"/camera/points", "/camera/image", "/zcut/outliers", "/camera/camera_info"} <= rows.keys()

    points = sorted((s, v) for s, n, v in rows["/camera/points"] if n == "Points3D:positions")
    assert [s for s, _ in points] == STAMPS
    for (_, value), xyz in zip(points, xyzs, strict=True):
        # rerun keeps the organized row-major order, NaN included
        np.testing.assert_array_equal(np.asarray(value, dtype=np.float32), xyz.reshape(-1, 3))

    images = sorted((s, v) for s, n, v in rows["/camera/image"] if n == "Image:buffer")
    formats = [v for _, n, v in rows["/camera/image"] if n == "Image:format"]
    assert [s for s, _ in images] == STAMPS
    assert all(f[0]["width"] == W and f[0]["height"] == H for f in formats)
    for (_, value), rgb in zip(images, rgbs, strict=True):
        np.testing.assert_array_equal(np.asarray(value[0], dtype=np.uint8), rgb.reshape(-1))

    mono = sorted((s, v) for s, n, v in rows["/zcut/outliers"] if n.endswith("Image:buffer"))
    assert [s for s, _ in mono] == STAMPS
    for (_, value), mask in zip(mono, masks, strict=True):
        np.testing.assert_array_equal(np.asarray(value[0], dtype=np.uint8), mask.reshape(-1).astype(np.uint8) * 255)

    pinholes = [v for _, n, v in rows["/camera/camera_info"] if n == "Pinhole:image_from_camera"]
    k = np.asarray(pinholes[0][0]).reshape(3, 3).T  # stored column-major
    np.testing.assert_allclose(k, [[520.0, 0, 7.5], [0, 521.0, 5.5], [0, 0, 1]])
