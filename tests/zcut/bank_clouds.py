"""Seeded organized clouds for the tests of the filter bank (zcut.local_rules, zcut.components,
zcut.radius) and of SOR's steep relief: camera clouds with flying pixels and holes, values on the
filters' thresholds, heaps of identical points, clouds with no camera at all, tall parts on end,
and the degenerate shapes."""

from __future__ import annotations

import numpy as np


def pinhole(rng: np.random.Generator, h: int, w: int, *, f: float = 60.0, flying: float = 0.05) -> np.ndarray:
    """A wavy surface ~0.5 m in front of a pinhole camera with a depth step, noise along the rays,
    flying pixels (metres, float64)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = 0.5 + 0.03 * np.sin(u / rng.uniform(3, 15)) * np.cos(v / rng.uniform(3, 15))
    z = z + (u > w * rng.uniform(0.3, 0.7)) * rng.uniform(-0.1, 0.1)
    z = z * (1 + rng.normal(0, 1e-3, z.shape))
    fly = rng.random(z.shape) < flying
    z = np.where(fly, z + rng.normal(0, 0.05, z.shape), z)
    return np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1)


def quantized(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Coordinates on a grid of 1/8, 1/64 or 1/1024 m: exact ties on the thresholds the tests pick
    (differences, squares and the filters' products of such values are exact in float64)."""
    q = float(rng.choice([1 / 8, 1 / 64, 1 / 1024]))
    base = pinhole(rng, h, w, f=rng.uniform(2, 60))
    return np.round(base / q) * q


def coincident(rng: np.random.Generator, h: int, w: int, *, cloud=None) -> np.ndarray:
    """Runs of exactly identical points in a pinhole cloud (made by ``cloud``, :func:`pinhole` by default)."""
    xyz = (cloud or pinhole)(rng, h, w, flying=0.0)
    for _ in range(max(1, h * w // 20)):
        r, c = rng.integers(0, h), rng.integers(0, max(1, w - 6))
        xyz[r, c:c + rng.integers(2, 7)] = xyz[r, c]
    return xyz


def scattered(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """No camera at all: random points, organized only by name."""
    return rng.normal(size=(h, w, 3)) * rng.uniform(0.01, 1.0)


def steep(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Tall narrow boxes standing on a floor, seen from an angle: image neighbours on their sides
    are far apart in depth."""
    f = rng.uniform(30, 120)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = np.full((h, w), 0.8)
    for _ in range(max(1, h * w // 150)):
        r0, c0 = rng.integers(0, h), rng.integers(0, w)
        rh, cw = rng.integers(1, 4), rng.integers(1, 4)
        top = rng.uniform(0.4, 0.75)
        ramp = np.linspace(top, 0.8, rng.integers(2, 8))  # the side seen at a grazing angle
        for k, zk in enumerate(ramp):
            rr = slice(r0 + k, r0 + k + rh)
            z[rr, c0:c0 + cw] = np.minimum(z[rr, c0:c0 + cw], zk)
    z = z * (1 + rng.normal(0, 2e-4, z.shape))
    return np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1)


def with_holes(rng: np.random.Generator, xyz: np.ndarray, frac: float) -> np.ndarray:
    """Random NaN pixels, a NaN block, and one pixel with a single NaN coordinate."""
    xyz = xyz.copy()
    xyz[rng.random(xyz.shape[:2]) < frac] = np.nan
    if xyz.shape[0] > 4 and xyz.shape[1] > 4:
        r, c = rng.integers(0, xyz.shape[0] - 3), rng.integers(0, xyz.shape[1] - 3)
        xyz[r:r + 3, c:c + 3] = np.nan
        xyz[rng.integers(0, xyz.shape[0]), rng.integers(0, xyz.shape[1]), rng.integers(0, 3)] = np.nan
    return xyz


KINDS = {"pinhole": pinhole, "quantized": quantized, "coincident": coincident, "scattered": scattered,
         "steep": steep}


def random_cloud(seed: int, kind: str, *, max_side: int = 40) -> np.ndarray:
    """A seeded cloud of the kind, 1..max_side pixels a side, with holes, sometimes float32."""
    rng = np.random.default_rng(1000 * seed + len(kind))
    h, w = int(rng.integers(1, max_side + 1)), int(rng.integers(1, max_side + 1))
    xyz = with_holes(rng, KINDS[kind](rng, h, w), float(rng.choice([0.0, 0.05, 0.3])))
    if rng.random() < 0.3 and kind != "quantized":
        xyz = xyz.astype(np.float32)
    return xyz


def degenerate_clouds() -> dict[str, np.ndarray]:
    """Empty, all-NaN, one valid pixel, one row / column, identical points, inf coordinates."""
    rng = np.random.default_rng(99)
    one = np.full((5, 7, 3), np.nan)
    one[2, 3] = (0.01, -0.02, 0.6)
    inf = pinhole(rng, 6, 8)
    inf[1, 1, 0] = np.inf
    inf[2, 2, 2] = -np.inf
    return {
        "empty-0x0": np.zeros((0, 0, 3)),
        "empty-0x5": np.zeros((0, 5, 3)),
        "empty-4x0": np.zeros((4, 0, 3)),
        "single": np.array([[[0.0, 0.0, 0.5]]]),
        "all-nan": np.full((6, 9, 3), np.nan),
        "all-nan-f32": np.full((3, 4, 3), np.nan, dtype=np.float32),
        "one-valid": one,
        "row": pinhole(rng, 1, 60),
        "column": pinhole(rng, 50, 1),
        "identical": np.broadcast_to(np.array([0.1, -0.2, 0.5]), (12, 15, 3)).copy(),
        "identical-f32": np.broadcast_to(np.array([0.1, -0.2, 0.5], np.float32), (8, 8, 3)).copy(),
        "inf": inf,
    }


def assert_equals_reference(fast, reference, xyz: np.ndarray, *args, **kw) -> np.ndarray:
    """``fast(xyz, *args, **kw)`` is an (H, W) bool mask of measured pixels only, equal to ``reference``'s
    with the same arguments; returns it."""
    got = fast(xyz, *args, **kw)
    valid = np.isfinite(xyz).all(axis=2)
    assert got.shape == xyz.shape[:2] and got.dtype == bool and not (got & ~valid).any()
    np.testing.assert_array_equal(got, reference(xyz, *args, **kw))
    return got
