"""The valid pixels a frame's decoding writes in the pass that unpacks its points (``Frame.known_valid``, what the
replay's locator reads instead of a pass of ``zcut.removal.valid_pixels`` of its own): the same array as that pass,
on edge bit patterns, the real organized clouds, clouds with large invalid regions and degenerate ones (one pixel,
one row, one column, all invalid), through the log reader and ``locate_bin``; a frame made with other points has
none.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from replay.logs import ros2_msgs as rm
from replay.logs.frame import Frame
from zcut.removal import finite_xyz, valid_pixels

#: bit patterns on the decoding's edges: +-inf, NaNs (quiet, signalling, with a payload), +-0, subnormals, 1.0,
#: the largest float32 (as tests/replay/logs/test_unpack_words16.py's)
SPECIAL = np.array([0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00001, 0x7F800001, 0, 0x80000000, 1, 0x80000001,
                    0x3F800000, 0x7F7FFFFF, 0x00800000], dtype=np.uint32)


def _words(h: int, w: int, seed: int) -> np.ndarray:
    """(h, w, 4) uint32: random bits, half of them edge patterns, a tenth of the points all zero."""
    rng = np.random.default_rng(seed)
    words = rng.integers(0, 2**32, (h, w, 4), dtype=np.uint64).astype(np.uint32)
    pick = rng.random(words.shape) < 0.5
    words[pick] = SPECIAL[rng.integers(0, len(SPECIAL), int(pick.sum()))]
    zero = rng.random((h, w)) < 0.1
    words[zero, :3] = rng.choice(np.array([0, 0x80000000], np.uint32), (int(zero.sum()), 3))
    return words


def _cloud(words: np.ndarray, *, step_words: int = 4, rgb: bool = False) -> rm.CloudMsg:
    """A little-endian FLOAT32 PointCloud2 of zcut's layout over ``words`` (x, y, z at bytes 0, 4, 8)."""
    h, w, sw = words.shape
    assert sw == step_words
    fields = [rm.PointField(n, o, rm.FLOAT32, 1) for n, o in zip("xyz", (0, 4, 8))]
    if rgb:
        fields.append(rm.PointField("rgba", 12, rm.UINT32, 1))
    step = 4 * sw
    return rm.CloudMsg(0, "cam", h, w, tuple(fields), False, step, w * step, memoryview(words.tobytes()), False)


def _of_xyz(xyz: np.ndarray) -> rm.CloudMsg:
    """zcut's own cloud message of an (H, W, 3) float32 cloud (what the writer and the synthetic logs write)."""
    data = rm.arrays_to_cloud_data(xyz, None)
    h, w = xyz.shape[:2]
    return rm.CloudMsg(0, "cam", h, w, rm.XYZ_FIELDS, False, 16, 16 * w, data, False)


def _check(cloud: rm.CloudMsg) -> np.ndarray:
    """The decoding with its valid mask against the one without it and against the valid pixels' own pass."""
    xyz, rgb, valid = rm.cloud_to_arrays_valid(cloud, where="t")
    plain, plain_rgb = rm.cloud_to_arrays(cloud, where="t")
    assert np.array_equal(xyz.view(np.uint32), plain.view(np.uint32)) and rgb is None and plain_rgb is None
    assert valid is not None and valid.dtype == np.bool_ and valid.shape == xyz.shape[:2]
    assert np.array_equal(valid, valid_pixels(xyz)) and np.array_equal(valid, finite_xyz(xyz))
    return valid


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 1), (5, 13), (120, 160)])
def test_edge_bit_patterns(shape):
    valid = _check(_cloud(_words(*shape, seed=shape[0] * 1000 + shape[1])))
    if valid.size > 20:  # both kinds of pixel were drawn
        assert valid.any() and not valid.all()


def test_large_invalid_regions_and_all_invalid():
    rng = np.random.default_rng(5)
    xyz = rng.uniform(-1.0, 1.0, (90, 120, 3)).astype(np.float32)
    xyz[:45] = np.nan  # the top half
    for _ in range(12):  # blobs, and blobs of (0, 0, 0) points (invalid too)
        r, c = rng.integers(45, 85), rng.integers(0, 110)
        xyz[r:r + 5, c:c + 10] = np.nan if rng.random() < 0.5 else 0.0
    xyz[50, :, 1] = np.inf  # a row with one coordinate infinite
    valid = _check(_of_xyz(xyz))
    assert not valid[:45].any() and valid[45:].any()
    assert not _check(_of_xyz(np.full((4, 6, 3), np.nan, np.float32))).any()
    assert not _check(_of_xyz(np.zeros((3, 2, 3), np.float32))).any()


def test_real_clouds():
    """The real organized clouds (docs/real_data.md), written in zcut's layout and decoded."""
    from replay.logs.pcd import read_pcd

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    for path in clouds:
        xyz = np.ascontiguousarray(read_pcd(path).xyz, dtype=np.float32)
        valid = _check(_of_xyz(xyz))
        assert np.array_equal(valid, np.isfinite(xyz).all(axis=2) & (xyz != 0).any(axis=2))


@pytest.mark.parametrize(("step_words", "rgb"), [(4, True), (8, False)])
def test_other_layouts_give_none(step_words, rgb):
    words = _words(4, 6, seed=step_words)
    if step_words != 4:
        words = np.concatenate([words, words], axis=2)
    cloud = _cloud(words, step_words=step_words, rgb=rgb)
    xyz, _, valid = rm.cloud_to_arrays_valid(cloud, where="t")
    assert valid is None
    plain, _ = rm.cloud_to_arrays(cloud, where="t")
    assert np.array_equal(xyz.view(np.uint32), plain.view(np.uint32))
    assert rm.cloud_to_arrays_valid(_cloud(_words(2, 3, 1)), where="t", valid=False)[2] is None


def test_known_valid_only_for_its_own_points():
    xyz = np.zeros((2, 3, 3), np.float32)
    valid = np.ones((2, 3), bool)
    f = Frame(xyz=xyz, rgb=None, stamp_ns=1, frame_id="cam", intrinsics=None, topic="/p", index=0,
              decoded_valid=(xyz, valid))
    assert f.known_valid is valid
    assert dataclasses.replace(f, index=3).known_valid is valid
    assert dataclasses.replace(f, xyz=xyz.copy()).known_valid is None
    assert Frame(xyz=xyz, rgb=None, stamp_ns=1, frame_id="cam", intrinsics=None, topic="/p", index=0).known_valid is None


def test_the_readers_frames_and_the_locator(tmp_path):
    """Through a synthetic log: every frame carries its decoding's valid pixels, equal to the pass's; the locator's
    valid pixels are the same array's values whether the frame has them or not."""
    from replay.logs.reader import LogReader
    from replay.pipeline import config as cfg
    from replay.pipeline.stages import locate_bin
    from replay.synth.log import write_synthetic_log

    path = write_synthetic_log(tmp_path / "two.mcap", kind="zinc_nuts", frames=2, seed=23, size=(60, 80))
    frames = list(LogReader(path).frames())
    assert len(frames) == 2
    config = cfg.resolve(cfg.log_facts({}, frames[0])).config
    for f in frames:
        assert f.known_valid is not None and np.array_equal(f.known_valid, valid_pixels(f.xyz))
        located = locate_bin(f, config)  # no bin model: the valid pixels only
        assert located.valid is f.known_valid
        again = locate_bin(dataclasses.replace(f, decoded_valid=None), config)
        assert np.array_equal(again.valid, located.valid)
