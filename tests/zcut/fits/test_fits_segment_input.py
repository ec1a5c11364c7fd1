"""zcut.fits.segment, round of 2026-12-06d (docs/fits.md, "Seventeenth round"): the
segmentation's kernel walks its ``flat`` pixels as a sorted set of the grid's pixels; input that is not (unsorted,
repeated, off the grid) is checked for and goes the reference's way — the answer is ``segment_reference``'s — while
sorted distinct input still goes the kernel's way."""

from __future__ import annotations

import numpy as np
import pytest
from fit_scenes import same_regions, segment_cloud

import zcut.fits.segment as S
from zcut.fits.segment import segment, segment_reference

KW = dict(f_px=500.0, jump_mm=1.5, jump_px=3.0)


@pytest.mark.parametrize("shape", [(1, 37), (29, 1), (17, 23), (40, 64)])
def test_unsorted_or_repeated_pixels_get_the_references_answer(shape):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(sum(shape) + 7)
    H, W = shape
    for trial in range(30):
        xyz = segment_cloud(rng, H, W, (0.0, 0.2, 0.5)[trial % 3])
        flat = np.flatnonzero(np.isfinite(xyz).all(axis=2).reshape(-1) & (rng.random(H * W) < 0.8))
        if len(flat) < 2:
            continue
        swapped = flat.copy()
        i = int(rng.integers(0, len(flat) - 1))
        swapped[[i, i + 1]] = swapped[[i + 1, i]]  # one pair out of order
        repeated = np.sort(np.concatenate([flat, rng.choice(flat, size=1 + len(flat) // 5)]))
        for bad in (rng.permutation(flat), flat[::-1].copy(), swapped, repeated, np.repeat(flat, 2)):
            assert not S._ascending_on_grid(bad, H * W)
            for min_px in (1, 4, 40):
                ref = segment_reference(xyz, bad, min_px=min_px, **KW)
                assert same_regions(segment(xyz, bad, min_px=min_px, **KW), ref)
        # a strided view of sorted pixels is sorted: the kernel's way, the same regions
        assert S._ascending_on_grid(flat[::2], H * W)
        assert same_regions(segment(xyz, flat[::2], min_px=1, **KW), segment_reference(xyz, flat[::2], min_px=1, **KW))


def test_sorted_distinct_input_goes_the_kernels_way_and_other_input_the_references(monkeypatch):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(4)
    xyz = segment_cloud(rng, 30, 40, 0.1)
    flat = np.flatnonzero(np.isfinite(xyz).all(axis=2))
    calls: list[int] = []
    reference = S.segment_reference

    def counted(*a, **k):  # type: ignore[no-untyped-def]
        calls.append(1)
        return reference(*a, **k)

    monkeypatch.setattr(S, "segment_reference", counted)
    regions = segment(xyz, flat, min_px=1, **KW)
    assert calls == [] and sum(map(len, regions)) == len(flat)
    segment(xyz, flat[::-1].copy(), min_px=1, **KW)
    assert calls == [1]


def test_pixels_off_the_grid_are_not_walked():
    rng = np.random.default_rng(9)
    H, W = 12, 15
    xyz = segment_cloud(rng, H, W, 0.0)
    flat = np.arange(0, H * W, 3)
    assert S._ascending_on_grid(flat, H * W) and S._ascending_on_grid(np.zeros(0, np.int64), H * W)
    # past the end: the reference's answer (it reads no point off the grid there), not the kernel's read past the cloud
    past = np.append(flat, H * W)
    assert not S._ascending_on_grid(past, H * W)
    assert same_regions(segment(xyz, past, min_px=1, **KW), segment_reference(xyz, past, min_px=1, **KW))
    # negative: NumPy's wrap-around, as the reference reads it
    neg = np.concatenate([[-1], flat])
    assert not S._ascending_on_grid(neg, H * W)
    assert same_regions(segment(xyz, neg, min_px=1, **KW), segment_reference(xyz, neg, min_px=1, **KW))


def test_degenerate_input_is_unchanged():
    xyz = np.full((5, 6, 3), np.nan)
    assert segment(xyz, np.zeros(0, np.int64), min_px=1, **KW) == []
    assert segment(np.zeros((0, 4, 3)), np.zeros(0, np.int64), min_px=1, **KW) == []
    xyz[2, 3] = (0.0, 0.0, 300.0)
    assert same_regions(segment(xyz, np.array([15, 15]), min_px=1, **KW),
                 segment_reference(xyz, np.array([15, 15]), min_px=1, **KW))
    assert same_regions(segment(xyz, np.array([15]), min_px=1, **KW), [np.array([15])])


SEGMENT_SCRIPT = r"""
import numpy as np
from zcut.components import speckle_outliers
from zcut.fits.segment import segment

rng = np.random.default_rng(5)
xyz = np.stack([rng.normal(0, 1, (40, 50)).cumsum(1), rng.normal(0, 1, (40, 50)).cumsum(0),
                300 + rng.normal(0, 0.3, (40, 50))], axis=-1)
segment(xyz, np.arange(0, 2000, 3), f_px=500.0, jump_mm=1.5, jump_px=3.0, min_px=1)
speckle_outliers(xyz, max_diff_mm=1.0, max_size_px=20)
"""


def test_the_segmentations_kernels_load_from_the_cache_in_a_second_process():
    # the union-find's root is zcut.components.find_root, inlined in zcut.fits.segment._components
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("kernel_cache_helpers",
                                                  Path(__file__).resolve().parents[1] / "kernel_cache_helpers.py")
    assert spec is not None and spec.loader is not None
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    stats = helpers.second_process_stats(SEGMENT_SCRIPT)
    assert {"zcut.fits.segment._components", "zcut.fits.segment._ascending_on_grid",
            "zcut.components._speckle_kernel"} <= set(stats), sorted(stats)
    assert helpers.missed(stats) == {}, f"compiled again in a second process (cache hits, misses): {helpers.missed(stats)}"
