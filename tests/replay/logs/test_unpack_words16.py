"""The x, y, z of zcut's own 16-byte points (x, y, z, rgba; rows back to back) are unpacked by a kernel
whose offsets and strides are constants (``_unpack_words16``): the same bits as the general word kernel
(``_unpack_words``) and as the literal per-point decoding (``_unpack_xyz`` over the structured view),
on nasty values (NaN payloads, +-inf, +-0, subnormals, all-zero points) and shapes (one pixel, one row,
one column); every other layout keeps the general kernel.
"""

from __future__ import annotations

import numpy as np
import pytest
from kernel_calls import counted_calls

from replay.logs import ros2_msgs as rm

#: bit patterns on the decoding's edges: +-inf, NaNs (quiet, signalling, with a payload), +-0, subnormals,
#: 1.0, the largest float32
SPECIAL = np.array([0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00001, 0x7F800001, 0, 0x80000000, 1, 0x80000001,
                    0x3F800000, 0x7F7FFFFF, 0x00800000], dtype=np.uint32)


def _words(h: int, w: int, step_words: int, seed: int) -> np.ndarray:
    """(h, w, step_words) uint32: random bits, half of them edge patterns, a tenth of the points all zero."""
    rng = np.random.default_rng(seed)
    words = rng.integers(0, 2**32, (h, w, step_words), dtype=np.uint64).astype(np.uint32)
    pick = rng.random(words.shape) < 0.5
    words[pick] = SPECIAL[rng.integers(0, len(SPECIAL), int(pick.sum()))]
    zero = rng.random((h, w)) < 0.1
    words[zero, :3] = rng.choice(np.array([0, 0x80000000], np.uint32), (int(zero.sum()), 3))
    return words


def _cloud(words: np.ndarray, *, offsets: tuple[int, int, int] = (0, 4, 8), row_pad: int = 0) -> rm.CloudMsg:
    """A little-endian FLOAT32 PointCloud2 over ``words`` (its points' bytes), rows ``row_pad`` bytes apart more
    than the points need."""
    h, w, sw = words.shape
    step = 4 * sw
    rows = np.zeros((h, w * step + row_pad), np.uint8)
    rows[:, : w * step] = words.view(np.uint8).reshape(h, w * step)
    fields = tuple(rm.PointField(n, o, rm.FLOAT32, 1) for n, o in zip("xyz", offsets))
    return rm.CloudMsg(0, "cam", h, w, fields, False, step, w * step + row_pad, memoryview(rows.tobytes()), False)


def _literal(cloud: rm.CloudMsg) -> np.ndarray:
    """The per-point decoding over the structured view (``_unpack_xyz``): the reference."""
    by = {f.name: f.offset for f in cloud.fields}
    dt = np.dtype({"names": list("xyz"), "formats": ["<f4"] * 3, "offsets": [by[n] for n in "xyz"],
                   "itemsize": cloud.point_step})
    pts = np.ndarray((cloud.height, cloud.width), dtype=dt, buffer=cloud.data, strides=(cloud.row_step, cloud.point_step))
    out = np.empty((cloud.height, cloud.width, 3), np.float32)
    rm._unpack_xyz(pts["x"], pts["y"], pts["z"], out)
    return out


@pytest.fixture
def kernels(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the x, y, z word kernels cloud_to_arrays calls (by module global)."""
    return counted_calls(monkeypatch, rm, ("_unpack_words", "_unpack_words16"))


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 1), (5, 13), (120, 160), (480, 640)])
def test_the_kernel_gives_the_general_kernels_bits(shape):
    h, w = shape
    words = _words(h, w, 4, seed=h * 1000 + w)
    general = np.empty((h, w, 3), np.float32)
    fast = np.empty((h, w, 3), np.float32)
    rm._unpack_words(words, 0, 1, 2, general)
    rm._unpack_words16(words.reshape(-1), fast.reshape(-1).view(np.uint32))
    assert np.array_equal(fast.view(np.uint32), general.view(np.uint32))


def test_no_point():
    out = np.empty((0, 3), np.float32)
    rm._unpack_words16(np.empty(0, np.uint32), out.reshape(-1).view(np.uint32))  # nothing to do, no error


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 1), (64, 48)])
def test_zcuts_layout_takes_the_kernel_and_decodes_literally(shape, kernels):
    cloud = _cloud(_words(*shape, 4, seed=7))
    xyz, rgb = rm.cloud_to_arrays(cloud, where="t")
    assert kernels == ["_unpack_words16"] and rgb is None
    assert np.array_equal(xyz.view(np.uint32), _literal(cloud).view(np.uint32))


@pytest.mark.parametrize(("step_words", "offsets", "row_pad"), [
    (4, (0, 4, 8), 16),  # padded rows
    (4, (4, 8, 0), 0),  # the coordinates in another order
    (8, (0, 4, 8), 0),  # PCL's 32-byte points
    (3, (0, 4, 8), 0),  # packed x, y, z
])
def test_other_layouts_keep_the_general_kernel(step_words, offsets, row_pad, kernels):
    cloud = _cloud(_words(6, 11, step_words, seed=step_words), offsets=offsets, row_pad=row_pad)
    xyz, _ = rm.cloud_to_arrays(cloud, where="t")
    assert kernels == ["_unpack_words"]
    assert np.array_equal(xyz.view(np.uint32), _literal(cloud).view(np.uint32))


def test_an_output_that_is_not_contiguous_keeps_the_general_kernel(kernels):
    cloud = _cloud(_words(6, 11, 4, seed=3))
    big = np.full((6, 11, 6), np.float32(7.0))

    def strided(shape: tuple[int, ...], dtype: object) -> np.ndarray:
        return big[..., ::2]  # every element is written, none of the others

    xyz, _ = rm.cloud_to_arrays(cloud, where="t", alloc=strided)
    assert kernels == ["_unpack_words"] and np.shares_memory(xyz, big)
    assert np.array_equal(xyz.view(np.uint32), _literal(cloud).view(np.uint32))
    assert np.all(big[..., 1::2] == 7.0)
