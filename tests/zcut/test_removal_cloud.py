"""The removal's float32 cloud written when asked for (:class:`zcut.removal.FlooredCloud`), against the reference
kernel that wrote it with the height image (:func:`zcut.removal._finish`): the same bytes.

The fast path's cloud is also compared with ``reference=True``'s on synthetic logs, ray-traced frames, large invalid
regions and degenerate frames by ``tests/zcut/test_removal_fast.py``; here: random clouds with a tilted floor plane and
with the side view's constant floor, NaN and ±inf coordinates, float32 and float64 input, empty, one-row, one-column
and one-pixel frames, non-contiguous input, the real Kinect clouds, and the removal of a synthetic frame at 640 × 480.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replay.logs.pcd import read_pcd
from replay.pipeline import stages
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession
from replay.synth.log import write_synthetic_log
from zcut.removal import FlooredCloud, _finish, remove_table_and_bin

REAL = Path("/work/shared/data/real")


def _classes(rng: np.random.Generator, a: np.ndarray) -> tuple[np.ndarray, ...]:
    """Disjoint table, easy, bin masks of the valid pixels (some valid pixels in none), as the removal labels them."""
    k = np.where(np.isfinite(a).all(axis=2), rng.integers(0, 4, size=a.shape[:2]), 0)
    return k == 1, k == 2, k == 3


def _reference(a: np.ndarray, table: np.ndarray, easy: np.ndarray, binp: np.ndarray, plane: bool, floor: float,
               up: np.ndarray, z_far: float) -> np.ndarray:
    """The cloud as the reference kernel writes it (valid: finite x y z, as the reference takes it)."""
    valid = np.isfinite(a).all(axis=2)
    height = np.empty(a.shape[:2], np.float64)
    out = np.empty(a.shape, np.float32)
    _finish(np.ascontiguousarray(a), valid, table | easy | binp, plane, floor, up, z_far, height, out)
    return out


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("plane", [True, False])
@pytest.mark.parametrize("shape", [(0, 0), (1, 57), (43, 1), (1, 1), (61, 83)])
def test_cloud_equals_reference_kernel(dtype, plane, shape):
    rng = np.random.default_rng([np.dtype(dtype).itemsize, int(plane), *shape])
    a = rng.normal(0.0, 0.3, size=(*shape, 3)) + np.array([0.0, 0.0, 1.2])
    a[rng.random(shape) < 0.2] = np.nan
    a[rng.random(shape) < 0.03, 0] = np.inf
    a[rng.random(shape) < 0.03, 2] = -np.inf
    a = a.astype(dtype)
    table, easy, binp = _classes(rng, a)
    up = rng.normal(size=3)
    up /= np.linalg.norm(up)
    floor, z_far = float(rng.normal()), float(rng.uniform(0.5, 2.0))
    if not plane:
        floor = float("nan")
    cloud = FlooredCloud(a, table, easy, binp, plane=plane, floor_m=floor, up_cam=up, z_far_m=z_far)
    got = cloud.array()
    assert _same(got, _reference(a, table, easy, binp, plane, floor, up, z_far))
    again = cloud.array()
    assert _same(again, got) and not np.shares_memory(again, got) and not np.shares_memory(got, a)


def test_cloud_of_a_strided_input():
    rng = np.random.default_rng(5)
    big = rng.normal(size=(40, 60, 3)) + 1.0
    a = big[::2, 1::3]  # not contiguous
    table, easy, binp = _classes(rng, a)
    up = np.array([0.1, -0.2, -0.97])
    cloud = FlooredCloud(a, table, easy, binp, plane=True, floor_m=-1.3, up_cam=up, z_far_m=float("nan"))
    assert _same(cloud.array(), _reference(a, table, easy, binp, True, -1.3, up, float("nan")))


@pytest.mark.parametrize("name", sorted(p.name for p in REAL.glob("*.pcd")) if REAL.is_dir() else [])
def test_cloud_of_the_real_clouds(name):
    """The real scans (Kinect, stereo), with a floor plane through them and random classes."""
    a = read_pcd(REAL / name).xyz
    rng = np.random.default_rng(len(name))
    table, easy, binp = _classes(rng, a)
    up = np.array([0.05, 0.02, -1.0])
    up /= np.linalg.norm(up)
    for plane in (True, False):
        cloud = FlooredCloud(a, table, easy, binp, plane=plane, floor_m=-0.9, up_cam=up, z_far_m=1.7)
        assert _same(cloud.array(), _reference(a, table, easy, binp, plane, -0.9, up, 1.7))


def test_removal_cloud_at_640x480(tmp_path):
    """The replay's removal on a 640 × 480 synthetic frame: its cloud is written when asked for, the same bytes as the
    reference's, and reads the frame as it is when asked (not a copy)."""
    log = write_synthetic_log(tmp_path / "z.mcap", kind="zinc_nuts", frames=1, seed=6541, size=(480, 640))
    s = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    assert s.prepared is not None
    frame = next(iter(s.reader.frames()))
    loc = stages.locate_bin(frame, s.config, bin_model=s.prepared, seed=s.seed)
    assert loc.registration is not None and loc.registration.converged and loc.bin_mask is not None
    args = (frame.xyz, loc.bin_mask.mask)
    kw = dict(index=s.prepared.removal, T_cam_bin=loc.registration.T_cam_bin, ring=loc.ring)
    fast = remove_table_and_bin(*args, **kw)
    ref = remove_table_and_bin(*args, **kw, reference=True)
    assert isinstance(fast.cloud, FlooredCloud) and isinstance(ref.cloud, np.ndarray)
    assert fast.cloud.source is frame.xyz or np.shares_memory(fast.cloud.source, frame.xyz)
    assert fast.bin_points.any() and fast.table.any()
    assert _same(fast.xyz, ref.xyz)
