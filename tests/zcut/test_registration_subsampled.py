"""zcut.registration.subsampled_points (the registration's target points, a serial numba pass) against NumPy's
strided boolean index and cast, ``xyz[::step, ::step][pixels[::step, ::step]].astype(np.float64)``, bit for bit:
float32 and float64 clouds, masks of every density and of runs with edges anywhere, widths that are and are not
whole 8-byte words, steps 1-5, strided, unaligned and Fortran-order masks, empty images."""

from __future__ import annotations

import numpy as np

from zcut.registration import subsampled_points


def test_subsampled_points_against_numpy():
    rng = np.random.default_rng(78)
    for t in range(120):
        h, w = int(rng.integers(1, 60)), int(rng.choice([1, 7, 8, 16, 24, 37, 64, 101, 640]))
        xyz = rng.normal(0.0, 1.0, (h, w, 3)).astype(np.float32 if t % 2 else np.float64)
        density = float(rng.choice([0.0, 0.02, 0.15, 0.5, 0.97, 1.0]))
        m = rng.random((h, w)) < density
        if t % 5 == 0:  # runs: whole words set and unset, edges anywhere in a word
            m[:] = False
            for _ in range(int(rng.integers(0, 6))):
                r0, c0 = int(rng.integers(0, h)), int(rng.integers(0, w))
                m[r0:r0 + int(rng.integers(1, 9)), c0:c0 + int(rng.integers(1, 40))] = True
        for step in (1, 2, 3, 4, 5):
            want = xyz[::step, ::step][m[::step, ::step]].astype(np.float64)
            got = subsampled_points(xyz, m, step=step)
            assert got.dtype == np.float64 and got.shape == want.shape and got.tobytes() == want.tobytes()
    big = rng.random((40, 96)) < 0.3
    xyz = rng.normal(0.0, 1.0, (40, 96, 3))
    for m in (big[:, :48], big[:, ::2], big[1:, 8:], np.asfortranarray(big)):  # strided, unaligned, Fortran
        x = np.ascontiguousarray(xyz[: m.shape[0], : m.shape[1]])
        for step in (1, 2, 3):
            want = x[::step, ::step][m[::step, ::step]].astype(np.float64)
            assert subsampled_points(x, m, step=step).tobytes() == want.tobytes()
    for h, w in ((0, 8), (5, 0), (0, 0)):
        assert subsampled_points(np.zeros((h, w, 3)), np.zeros((h, w), bool), step=1).shape == (0, 3)
