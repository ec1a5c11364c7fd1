"""``zcut.removal.valid_pixels`` (the bin locator's valid mask, one kernel pass) equals ``zcut.removal.finite_xyz``
(its literal reference) bit for bit, on every kind of cloud a frame can hold."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from zcut.removal import finite_xyz, valid_pixels

_SPECIAL = (np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-45, 3.4e38, -1.0)


def _nasty(shape: tuple[int, int], dtype: type, rng: np.random.Generator) -> np.ndarray:
    """A cloud with NaN, ±inf, zeros, subnormals and huge values in single channels and whole pixels."""
    xyz = rng.normal(0.0, 1.0, (*shape, 3)).astype(dtype)
    pick = rng.random((*shape, 3)) < 0.3
    xyz[pick] = rng.choice(np.array(_SPECIAL, dtype=dtype), size=int(pick.sum()))
    return xyz


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (5, 0), (1, 1), (1, 17), (17, 1), (48, 64), (121, 160)])
def test_equals_the_reference_on_nasty_clouds(shape: tuple[int, int], dtype: type) -> None:
    rng = np.random.default_rng(6321)
    for _ in range(3):
        xyz = _nasty(shape, dtype, rng)
        got = valid_pixels(xyz)
        assert got.dtype == np.bool_ and got.shape == shape
        assert np.array_equal(got, finite_xyz(xyz))


def test_all_invalid_all_valid_and_a_large_invalid_region() -> None:
    rng = np.random.default_rng(7)
    nan = np.full((30, 40, 3), np.nan, np.float32)
    assert not valid_pixels(nan).any()
    ok = rng.normal(size=(30, 40, 3)).astype(np.float32)
    assert valid_pixels(ok).all()
    ok[5:25, 3:38] = np.nan
    assert np.array_equal(valid_pixels(ok), finite_xyz(ok))


def test_views_read_only_arrays_and_other_inputs() -> None:
    rng = np.random.default_rng(11)
    xyz = _nasty((40, 60), np.float32, rng)
    views = [xyz[::2, ::3], xyz[:, ::-1], np.swapaxes(xyz, 0, 1), np.asfortranarray(xyz)]
    ro = xyz.copy()
    ro.flags.writeable = False
    views += [ro, np.broadcast_to(np.float32(np.nan), (20, 30, 3)),  # a results file's cloudless frame
              np.broadcast_to(np.float32(1.0), (20, 30, 3))]
    for v in views:
        assert np.array_equal(valid_pixels(v), finite_xyz(v))
    # not an (H, W, 3) float cloud: the reference answers
    four = rng.normal(size=(10, 12, 4)).astype(np.float32)
    four[2, 3, 1] = np.nan
    assert np.array_equal(valid_pixels(four), finite_xyz(four))
    f16 = rng.normal(size=(10, 12, 3)).astype(np.float16)
    f16[1, 2, 0], f16[3, 4, 2] = np.nan, np.inf
    assert np.array_equal(valid_pixels(f16), finite_xyz(f16))


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(st.sampled_from([np.float32, np.float64]),
                  hnp.array_shapes(min_dims=3, max_dims=3, min_side=0, max_side=9).map(lambda s: (s[0], s[1], 3)),
                  elements=st.floats(allow_nan=True, allow_infinity=True, width=32)))
def test_equals_the_reference_on_any_cloud(xyz: np.ndarray) -> None:
    assert np.array_equal(valid_pixels(xyz), finite_xyz(xyz))
