"""zcut.sor's full-frame temporaries taken from a per-thread workspace kept between calls.

The oracle is the one the search was always held to (tests/reference/sor_reference.py, and Open3D
for the ``open3d`` convention); on top of it: a sequence of growing and shrinking clouds (large,
small, one pixel, empty, all-NaN, large NaN regions, with and without ``mask``, the column search
forced) run through one workspace gives what a fresh workspace gives and what the reference gives,
also when every array the workspace holds is overwritten with garbage between calls (nothing is
read before the call writes it); the returned d̄ and masks never share memory with the workspace;
two threads running at once give what one gives; ``release`` and ``max_bytes`` free what is held,
except the column search's arrays (``KEPT_NAMES``), kept up to ``KEPT_NAMES_BYTES`` by default and
poisoned between calls like the rest.
"""

from __future__ import annotations

import functools
import threading

import bank_clouds
import numpy as np
import pytest
from reference.sor_reference import mean_distances_reference, outliers_from_mean_distances_reference

import zcut.sor as sor_module
from zcut.sor import sor_mean_distances, sor_outliers, sor_outliers_from_distances
from zcut.sor_workspace import KEPT_BYTES, KEPT_NAMES, KEPT_NAMES_BYTES, SorWorkspace, thread_workspace


# ------------------------------------------------------------------------------------------------
# the workspace itself
# ------------------------------------------------------------------------------------------------
def test_arrays_are_reused_grown_and_kept_apart() -> None:
    ws = SorWorkspace()
    a = ws.empty("a", (30, 40))
    assert a.shape == (30, 40) and a.dtype == np.float64 and a.flags.c_contiguous
    again = ws.empty("a", (20, 10))
    assert np.shares_memory(a, again)  # smaller: the same memory
    b = ws.empty("b", (30, 40))
    assert not np.shares_memory(a, b)  # two names never share
    grown = ws.empty("a", (60, 40))
    assert grown.shape == (60, 40) and not np.shares_memory(a, grown)
    assert ws.empty("a", (1500,)).base is grown.base  # grown by a quarter at least: 1500 fits
    flags = ws.full("a", (7,), True, bool)  # another dtype: a new array under the name
    assert flags.dtype == np.bool_ and flags.all()
    assert ws.empty("z", (0, 5)).shape == (0, 5)
    assert ws.nbytes > 0
    ws.release()
    assert ws.nbytes == 0


def test_max_bytes_bounds_what_is_kept_and_busy_workspaces_are_not_shared() -> None:
    ws = SorWorkspace(max_bytes=1000)
    with ws.call() as inner:
        assert inner is ws
        inner.empty("small", (100,), np.uint8)
        with ws.call() as nested:  # in use: a fresh one
            assert nested is not ws
    assert ws.nbytes == 100  # under the bound: kept
    with ws.call() as inner:
        inner.empty("big", (2000,), np.uint8)
    assert ws.nbytes == 0  # over the bound: dropped when the call ended


def test_kept_names_outlive_max_bytes_up_to_their_bound() -> None:
    ws = SorWorkspace(max_bytes=0, keep=frozenset({"a", "b"}), keep_bytes=1000)
    with ws.call() as inner:
        a = inner.empty("a", (600,), np.uint8)
        inner.empty("b", (400,), np.uint8)
        inner.empty("other", (10,), np.uint8)
    assert sorted(ws._arrays) == ["a", "b"] and ws.nbytes == 1000  # at the bound: kept, the rest dropped
    with ws.call() as inner:
        assert np.shares_memory(inner.empty("a", (500,), np.uint8), a)  # the kept one is reused
    assert ws.nbytes == 1000  # within max_bytes? no (0), but only kept names are held
    with ws.call() as inner:
        inner.empty("a", (601,), np.uint8)  # the kept names now hold more than keep_bytes
    assert ws.nbytes == 0  # dropped with the rest, as without the exception
    with ws.call() as inner:
        inner.empty("b", (10,), np.uint8)
    ws.release()
    assert ws.nbytes == 0  # release drops the kept names too
    unbounded = SorWorkspace(max_bytes=None, keep=frozenset({"a"}), keep_bytes=0)
    with unbounded.call() as inner:
        inner.empty("a", (10,), np.uint8)
        inner.empty("other", (10,), np.uint8)
    assert unbounded.nbytes == 20  # max_bytes None keeps everything, whatever keep_bytes says
    assert thread_workspace().keep == KEPT_NAMES and thread_workspace().keep_bytes == KEPT_NAMES_BYTES == 128 << 20


def test_each_thread_has_its_own_workspace() -> None:
    mine = thread_workspace()
    assert thread_workspace() is mine
    theirs: list[SorWorkspace] = []
    t = threading.Thread(target=lambda: theirs.append(thread_workspace()))
    t.start()
    t.join()
    assert theirs and theirs[0] is not mine


# ------------------------------------------------------------------------------------------------
# results through a reused workspace
# ------------------------------------------------------------------------------------------------
def poison(ws: SorWorkspace) -> None:
    """Overwrite every array the workspace holds (what a previous call left must never matter)."""
    for a in ws._arrays.values():
        if a.dtype == np.bool_:
            a.fill(True)
        elif np.issubdtype(a.dtype, np.integer):
            a.fill(-123456789)
        else:
            a.fill(np.nan)


def cloud_sequence() -> list[tuple[str, np.ndarray, np.ndarray | None]]:
    """Clouds that grow and shrink: (name, xyz, mask or None)."""
    rng = np.random.default_rng(2026)
    big = bank_clouds.with_holes(rng, bank_clouds.pinhole(rng, 70, 90), 0.05)
    steep = bank_clouds.with_holes(rng, bank_clouds.steep(rng, 80, 100), 0.02)
    walls = big.copy()
    walls[10:60, 20:70] = np.nan  # a large invalid region
    mask = np.zeros(big.shape[:2], bool)
    mask[5:50, 8:80] = rng.random((45, 72)) < 0.7
    one = np.full((1, 1, 3), 0.5)
    return [
        ("big", big, None),
        ("small", bank_clouds.quantized(rng, 9, 13), None),
        ("steep", steep, None),
        ("one pixel", one, None),
        ("walls", walls, None),
        ("empty", np.zeros((0, 0, 3)), None),
        ("big masked", big, mask),
        ("all NaN", np.full((30, 40, 3), np.nan), None),
        ("coincident", bank_clouds.coincident(rng, 12, 17), None),
        ("steep float32", steep.astype(np.float32), None),
        ("crop masked", big[3:40, 10:60], mask[3:40, 10:60]),
        ("one row", bank_clouds.pinhole(rng, 1, 60), None),
    ]


def masked_copy(xyz: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    return xyz if mask is None else np.where(mask[..., None], xyz, np.nan).astype(xyz.dtype)


def expected(xyz: np.ndarray, n: int, k: int, convention: str, method: str) -> tuple[np.ndarray, np.ndarray]:
    """The reference's d̄ and mask; with fewer valid points than a full neighbourhood, d̄ averages
    over all the others (the reference with a smaller k) and nothing is an outlier."""
    if n == 0 or (convention == "pcl" and n == 1):
        return np.where(np.isfinite(xyz).all(axis=2), 0.0, np.nan), np.zeros(xyz.shape[:2], bool)
    m = k + 1 if convention == "pcl" else k
    small = n < m
    kk = (n - 1 if convention == "pcl" else n) if small else k
    want = mean_distances_reference(xyz, k=kk, convention=convention, method=method)
    if n < k + 1:
        return want, np.zeros(xyz.shape[:2], bool)
    return want, outliers_from_mean_distances_reference(want, k=k, std_ratio=1.0, convention=convention)


@functools.cache
def sequence_expected(convention: str) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
    """:func:`expected` of every cloud of :func:`cloud_sequence` (its NaN-masked copy) for k = 1 and 4, by name and
    k: the oracle, computed once for the search paths that are held to it (read-only)."""
    wants = {}
    for name, xyz, mask in cloud_sequence():
        copy = masked_copy(xyz, mask)
        method = "brute" if copy.shape[0] * copy.shape[1] <= 3000 else "kdtree"
        n = int(np.isfinite(copy).all(axis=2).sum())
        for k in (1, 4):
            wants[name, k] = expected(copy, n, k, convention, method)
            for a in wants[name, k]:
                a.setflags(write=False)
    return wants


SEARCH_PATHS = {  # the unproven pixels through each search (each takes its arrays from the workspace)
    "default": {},
    "columns": {"_COLUMNS_MIN_SHARE": 1 << 40, "_COLUMNS_COST": 0.0},
    "tiles": {"_USE_COLUMNS": False},
    "kdtree": {"_USE_COLUMNS": False, "_TILE_SCAN_CAP": 0},
    "no-camera": {"_USE_CAMERA": False, "_WINDOW_MAX": 2},
}


@pytest.mark.parametrize("path", list(SEARCH_PATHS))
@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_growing_and_shrinking_clouds_equal_the_reference(convention: str, path: str,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in SEARCH_PATHS[path].items():
        monkeypatch.setattr(sor_module, name, value)
    ws = thread_workspace()
    monkeypatch.setattr(ws, "max_bytes", None)  # kept between calls (not the default): poisoned between them
    clouds = cloud_sequence()
    wants = sequence_expected(convention)
    kept: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for round_ in range(2):
        for name, xyz, mask in clouds:
            for k in (1, 4):
                want, want_mask = wants[name, k]
                if round_:
                    poison(ws)
                dbar = sor_mean_distances(xyz, k=k, convention=convention, mask=mask)
                np.testing.assert_array_equal(dbar, want, err_msg=f"{name}, k={k}")
                if round_:
                    poison(ws)
                got = sor_outliers(xyz, k=k, convention=convention, mask=mask)
                np.testing.assert_array_equal(got, want_mask, err_msg=f"{name}, k={k}")
                sweep = sor_outliers_from_distances(dbar, k=k, std_ratios=[1.0, 2.0], convention=convention)
                np.testing.assert_array_equal(sweep[0], want_mask, err_msg=f"{name}, k={k}")
                for out in (dbar, got, sweep):  # the caller's arrays are never the workspace's
                    assert not any(np.shares_memory(out, a) for a in ws._arrays.values()), name
                kept.append((dbar, want, got, want_mask))
    assert ws.nbytes > 0
    for dbar, want, got, want_mask in kept:  # later calls changed nothing the caller kept
        np.testing.assert_array_equal(dbar, want)
        np.testing.assert_array_equal(got, want_mask)


@pytest.mark.parametrize("max_bytes", [None, 0])
def test_a_reused_workspace_equals_a_fresh_one(max_bytes: int | None) -> None:
    # a steep frame large enough for every stage (row stages, growing windows, column search)
    rng = np.random.default_rng(77)
    frames = [bank_clouds.with_holes(rng, bank_clouds.steep(rng, h, w), 0.03)
              for h, w in ((160, 200), (48, 64), (200, 240), (120, 90))]
    ws = thread_workspace()
    ws.max_bytes = max_bytes
    try:
        fresh = []
        for xyz in frames:
            ws.release()
            fresh.append({c: (sor_mean_distances(xyz, k=4, convention=c), sor_outliers(xyz, k=4, convention=c))
                          for c in ("pcl", "open3d")})
        for _ in range(2):
            for xyz, want in zip(frames, fresh, strict=True):
                for c, (dbar, mask) in want.items():
                    np.testing.assert_array_equal(sor_mean_distances(xyz, k=4, convention=c), dbar)
                    np.testing.assert_array_equal(sor_outliers(xyz, k=4, convention=c), mask)
        if max_bytes == 0:  # at most the column search's arrays stay (these frames are well under their bound)
            assert set(ws._arrays) <= KEPT_NAMES
        else:
            assert not set(ws._arrays) <= KEPT_NAMES
    finally:
        ws.max_bytes = KEPT_BYTES


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_the_kept_column_arrays_change_nothing(convention: str, monkeypatch: pytest.MonkeyPatch) -> None:
    # the default workspace (KEPT_BYTES: nothing kept but the column search's arrays), the column search
    # forced, clouds that grow and shrink, what it keeps poisoned between calls: what a fresh workspace gives
    monkeypatch.setattr(sor_module, "_COLUMNS_MIN_SHARE", 1 << 40)
    monkeypatch.setattr(sor_module, "_COLUMNS_COST", 0.0)
    ws = thread_workspace()
    assert ws.max_bytes == KEPT_BYTES == 0
    clouds = cloud_sequence()
    fresh = {}
    for name, xyz, mask in clouds:
        ws.release()
        fresh[name] = sor_mean_distances(xyz, k=4, convention=convention, mask=mask)
    held = set()
    for name, xyz, mask in clouds + clouds[::-1]:
        poison(ws)
        dbar = sor_mean_distances(xyz, k=4, convention=convention, mask=mask)
        np.testing.assert_array_equal(dbar, fresh[name], err_msg=name)
        assert set(ws._arrays) <= KEPT_NAMES, name
        assert not any(np.shares_memory(dbar, a) for a in ws._arrays.values()), name
        held |= set(ws._arrays)
    assert held == KEPT_NAMES  # the column search ran and kept every one of its arrays
    monkeypatch.setattr(ws, "keep_bytes", 0)  # over the bound: dropped after the call, as before
    np.testing.assert_array_equal(sor_mean_distances(clouds[2][1], k=4, convention=convention), fresh["steep"])
    assert ws.nbytes == 0


def test_two_threads_at_once_equal_one_thread() -> None:
    rng = np.random.default_rng(5)
    frames = [bank_clouds.with_holes(rng, bank_clouds.steep(rng, 120, 150), 0.03),
              bank_clouds.with_holes(rng, bank_clouds.pinhole(rng, 90, 110), 0.1)]
    want = [{c: sor_mean_distances(xyz, k=4, convention=c) for c in ("pcl", "open3d")} for xyz in frames]
    errors: list[str] = []
    start = threading.Barrier(2)

    def work(i: int) -> None:
        start.wait()
        for rnd in range(6):
            xyz = frames[(i + rnd) % 2]
            for c in ("pcl", "open3d"):
                if not np.array_equal(sor_mean_distances(xyz, k=4, convention=c), want[(i + rnd) % 2][c],
                                      equal_nan=True):
                    errors.append(f"thread {i}, round {rnd}, {c}")

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors


def test_the_pool_is_kept_between_calls_and_stopped_by_release() -> None:
    ws = SorWorkspace()
    pool = ws.pool(2)
    assert ws.pool(2) is pool and pool.submit(lambda: 7).result() == 7
    assert ws.pool(3) is not pool  # another number of threads: a new pool
    ws.release()
    assert ws.pool(2) is not pool
    ws.release()
    with pytest.raises(RuntimeError, match="shutdown"):
        pool.submit(lambda: 7)
