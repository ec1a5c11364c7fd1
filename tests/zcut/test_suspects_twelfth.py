"""The suspects' twelfth round (issue 32, item 5): the reach's window tallied a row at a time without a branch on
the samples (:func:`zcut.suspects.surfaces._reach_window`), the gate's window counted a block of brackets at a
time (:func:`zcut.suspects.surfaces._window_exact`), and the lazy surfaces started with the patches the gate did
not list decided (:func:`zcut.suspects.surfaces._listed_state`): the same tallies, values, decisions and distances
as the code they replace, and the whole call still ``suspects_reference``'s."""

from __future__ import annotations

import math

import numpy as np
from test_suspects_fast import _fuzz_cloud, assert_same
from test_suspects_fifth import _cloud
from test_suspects_ninth import _quantized_frame

from zcut.edge_surface import EdgeSurfaceParams, _reach_samples, _smallest_eigvec
from zcut.params import SuspectParams
from zcut.sor_workspace import SorWorkspace
from zcut.suspects import suspects, suspects_reference
from zcut.suspects.surfaces import (
    LazySurfaces,
    _cov_at,
    _ratio_brackets,
    _reach_window,
    _window_exact,
    gate_arrays,
    lazy_surfaces,
    reach_median,
)


def _tally_oracle(a: np.ndarray, valid: np.ndarray, lo: float, hi: float) -> tuple[tuple[int, ...], np.ndarray]:
    """The previous kernel's tally from the samples' array: (count, below, equal to lo, strictly inside, equal
    to hi) and the samples strictly inside, in the samples' order."""
    s = _reach_samples(a, valid)
    inside = (s > lo) & (s < hi)
    return (s.size, int((s < lo).sum()), int((s == lo).sum()), int(inside.sum()), int((s == hi).sum())), s[inside]


def _frames(rng: np.random.Generator):  # type: ignore[no-untyped-def]
    """Smooth, quantized, sparse and degenerate clouds (mm), and clouds with |z| = 0 (inf samples, left out)."""
    for t in range(60):
        if t % 6 == 0:
            H, W = int(rng.integers(1, 4)), int(rng.integers(1, 9))  # 1 × 1, one row, one column
        else:
            H, W = int(rng.integers(20, 90)), int(rng.integers(20, 120))
        a = _cloud(rng, H, W, float(rng.choice([0.0, 0.0, 0.5, 2.0])))
        if t % 5 == 2:
            a[:, :, 2] = np.where(rng.random((H, W)) < 0.1, 0.0, a[:, :, 2])
        if t % 11 == 7:
            a[:] = np.nan
        yield t, np.ascontiguousarray(a)


def test_reach_window_equals_the_samples_tally() -> None:
    """Windows at the samples' middle, wide ones, ones whose ends are sample values (ties at both ends, as a
    quantized sensor's), ones holding no sample, and ``vals`` too small for the samples inside (only the first
    ones are kept, the count runs on)."""
    rng = np.random.default_rng(1201)
    for t, a in _frames(rng):
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        s = np.sort(_reach_samples(a, valid))
        windows = [(0.0, 1e-300), (1e300, math.inf)]
        if s.size:
            m = s.size // 2
            windows += [(float(s[max(m - 3, 0)]), float(s[min(m + 3, s.size - 1)])),
                        (float(s[0]), float(s[-1])), (float(s[0]) / 2, float(s[-1]) * 2),
                        (float(s[m]), float(np.nextafter(s[m], np.inf)))]
        for lo, hi in windows:
            if not lo < hi:
                continue
            want, inside = _tally_oracle(a, valid, lo, hi)
            for cap in (1 << 16, 5, 1, 0):
                vals = np.full(cap + 1, -1.0)
                got = tuple(int(v) for v in _reach_window(a, valid, lo, hi, vals))
                assert got == want, (t, lo, hi, cap)
                k = min(cap, want[3])
                assert np.array_equal(vals[:k], inside[:k]), (t, lo, hi, cap)


def test_reach_median_of_large_frames_equals_the_median_of_the_samples() -> None:
    """Frames above the size where the window is used (``_FRESH_BYTES``): smooth, quantized, with holes."""
    from zcut.suspects.select import median

    rng = np.random.default_rng(1202)
    for quantum in (0.0, 1.0):
        a = _cloud(rng, 1100, 1000, quantum)
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        s = _reach_samples(a, valid)
        assert reach_median(a, valid) == median(s)


def _window_oracle(a: np.ndarray, valid: np.ndarray, params: EdgeSurfaceParams, per_px: float, tan: float,
                   lo: np.ndarray, hi: np.ndarray, at: np.ndarray, wa: float, wb: float) -> tuple[int, int, np.ndarray]:
    """The previous ``_window_exact``, bracket by bracket: (below, above, the ratios in [wa, wb] in order)."""
    r, min_px, floor = params.patch_radius_px, params.min_patch_px, params.side_step_mm
    W = valid.shape[1]
    side = (2 * r + 1) ** 2
    px, py, pz = np.empty(side), np.empty(side), np.empty(side)
    below = above = 0
    vals = []
    for k in range(lo.size):
        if hi[k] < wa:
            below += 1
            continue
        if lo[k] > wb:
            above += 1
            continue
        if lo[k] == hi[k]:
            v = lo[k]
        else:
            _, mz, c00, c01, c02, c11, c12, c22 = _cov_at(a, valid, int(at[k]) // W, int(at[k]) % W, r, min_px, per_px,
                                                          tan, floor, px, py, pz)
            lam = _smallest_eigvec(c00, c01, c02, c11, c12, c22)[0]
            v = math.sqrt(max(lam, 0.0)) / mz ** 2
        if v < wa:
            below += 1
        elif v > wb:
            above += 1
        else:
            vals.append(v)
    return below, above, np.array(vals)


def test_window_exact_equals_the_bracket_by_bracket_count() -> None:
    """Windows around the middle (few brackets meet them), wide ones (many, in every block of 1,024), ones at
    a bracket's ends and empty ones, on smooth, quantized and sparse frames of more than one block."""
    rng = np.random.default_rng(1203)
    params = EdgeSurfaceParams()
    tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
    checked = 0
    for t in range(8):
        a = (_quantized_frame(rng, 70, 90, float(rng.choice([0.5, 1.0]))) if t % 2
             else np.ascontiguousarray(_fuzz_cloud(rng, 70, 90)))
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        per_px = reach_median(a, valid)
        n = valid.size
        lo, hi, at = np.empty(n), np.empty(n), np.empty(n, np.int64)
        m, _, _ = _ratio_brackets(a, valid, params.patch_radius_px, params.min_patch_px, per_px, tan,
                                  params.side_step_mm, lo, hi, at)
        if m == 0:
            continue
        lo, hi, at = lo[:m], hi[:m], at[:m]
        slo, shi = np.sort(lo), np.sort(hi)
        h = m // 2
        for wa, wb in ((slo[h], shi[h]), (slo[0], shi[-1]), (slo[m // 4], shi[3 * m // 4]), (lo[0], hi[0]),
                       (shi[-1] * 2 + 1, shi[-1] * 3 + 1), (0.0, 0.0)):
            want = _window_oracle(a, valid, params, per_px, tan, lo, hi, at, float(wa), float(wb))
            vals = np.full(m, np.nan)
            below, above, inside = _window_exact(a, valid, params.patch_radius_px, params.min_patch_px, per_px, tan,
                                                 params.side_step_mm, lo, hi, at, float(wa), float(wb), vals)
            assert (below, above) == want[:2], (t, wa, wb)
            assert inside == want[2].size and below + above + inside == m
            assert np.array_equal(vals[:inside], want[2]), (t, wa, wb)
            checked += 1
    assert checked >= 30


def _decided(s: LazySurfaces) -> tuple[np.ndarray, ...]:
    surface = s.surface  # every patch decided
    return surface, s._state.copy(), s._slot.copy(), s._planes[: int(s._count[0])].copy()


def test_listed_state_decides_as_the_patches_would() -> None:
    """With the gate's list (``gate``), the lazy surfaces' distances at a list of pixels, and then every
    patch's decision (state, slot, plane), are those of the surfaces that decide every patch when read:
    fuzzed, quantized and sparse frames, a frame where no patch is fitted, all NaN, one pixel, 0 × 0."""
    rng = np.random.default_rng(1204)
    params = EdgeSurfaceParams()
    frames = [np.ascontiguousarray(_fuzz_cloud(rng, 50, 70)) for _ in range(6)]
    frames += [_quantized_frame(rng, 60, 80, 1.0), np.full((20, 30, 3), np.nan), np.full((1, 1, 3), 600.0),
               np.zeros((0, 0, 3))]
    sparse = np.ascontiguousarray(_fuzz_cloud(rng, 40, 60))
    sparse[rng.random(sparse.shape[:2]) < 0.85] = np.nan  # few patches with enough points
    frames.append(sparse)
    for t, a in enumerate(frames):
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        ws = SorWorkspace(max_bytes=None)
        with ws.call() as w:
            gate = gate_arrays(w, valid.size)
            gate[0][:] = np.nan  # garbage before: only the gate's list is read
            gate[2][:] = -1
            listed = lazy_surfaces(a, valid, params, gate=gate)
        plain = lazy_surfaces(a, valid, params)
        assert listed.n_fitted == plain.n_fitted
        where = np.flatnonzero(valid)[:: max(1, int(valid.sum()) // 300)]
        d1, d0 = listed.distance_at(where), plain.distance_at(where)
        assert np.array_equal(d1, d0, equal_nan=True), t
        for x, y in zip(_decided(listed), _decided(plain)):
            assert np.array_equal(x, y, equal_nan=True), t


def test_whole_call_equals_the_reference() -> None:
    """``suspects`` with the labelling page's edge surfaces against ``suspects_reference``: fuzzed and quantized
    frames (in metres), one mostly unmeasured."""
    rng = np.random.default_rng(1205)
    for t in range(4):
        mm = _quantized_frame(rng, 60, 90, 1.0) if t == 3 else np.ascontiguousarray(_fuzz_cloud(rng, 60, 90))
        if t == 2:
            mm[rng.random(mm.shape[:2]) < 0.6] = np.nan
        xyz = mm / 1000.0
        h = -1000.0 * xyz[..., 2]
        zone = np.isfinite(xyz).all(axis=2)
        kw = dict(params=SuspectParams(), edge_surface=EdgeSurfaceParams())
        assert_same(suspects(xyz, h, zone, **kw), suspects_reference(xyz, h, zone, **kw))
