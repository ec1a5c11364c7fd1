"""The suspects' ninth round (issue 32, item 5): the gate's covariances for r = 1 with the nine points
unrolled are the general kernel's; the closed form's values taken from the memo are the closed form's;
the gate's median on frames of quantized depth (flat patches repeating a covariance at the rounding
level) is the whole-frame pass's (the whole call against ``suspects_reference``:
tests/zcut/test_suspects_fast.py; the noise samples of the folded streams: test_suspects_eighth.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from suspects_helpers import patch_covariances, whole_frame_gate
from test_suspects_fast import _fuzz_cloud

from zcut.edge_surface import (
    EdgeSurfaceParams,
    _patch_moments,
    _smallest_eigvec,
)
from zcut.suspects.surfaces import (
    _MEMO_BITS,
    _bracket_or_solve,
    _gate_median,
    _lambda_bracket,
    _planar_row,
    _ratio_brackets,
    _row_moments,
    _row_moments_r1,
)


def _bits(x: float) -> int:
    return int(np.float64(x).view(np.int64))


def test_row_moments_r1_equal_the_general_kernel() -> None:
    """:func:`_row_moments_r1` gives :func:`_row_moments`' count, centroid depth and covariance for r = 1 bit
    for bit, signs of zero included, and :func:`zcut.edge_surface._patch_moments`' where a patch has a
    point: random fields with holes, ties, flat regions, -0.0 coordinates, pixels finite but not valid,
    NaN and infinities under pixels not valid, reaches of 0 and on the boundary."""
    rng = np.random.default_rng(901)
    compared = 0
    for t in range(80):
        H, W = int(rng.integers(3, 30)), int(rng.integers(3, 70))
        a = _fuzz_cloud(rng, H, W)
        if t % 3 == 0:
            a[..., 0][a[..., 0] == 0.0] = -0.0
            a[rng.random((H, W)) < 0.1, int(rng.integers(0, 3))] = -0.0
        valid = np.isfinite(a).all(axis=2)
        if t % 4 == 1:
            valid &= rng.random((H, W)) < 0.8  # finite points left out
        if t % 5 == 2:  # junk under pixels not valid
            junk = ~valid & (rng.random((H, W)) < 0.5)
            a[junk, int(rng.integers(0, 3))] = float(rng.choice([np.inf, -np.inf, np.nan]))
        valid = np.ascontiguousarray(valid)
        a = np.ascontiguousarray(a)
        per_px = float(rng.choice([0.0, 1e-3, 2e-3]))
        tan = math.tan(math.radians(float(rng.choice([45, 80, 89.9]))))
        floor = float(rng.choice([0.0, 0.5, 1.0]))
        X, Y, Z, V = np.empty((3, W)), np.empty((3, W)), np.empty((3, W)), np.zeros((3, W), bool)
        sel = np.empty((9, W), bool)
        general = [np.empty(W) for _ in range(12)]  # zq, reach, then nn, mx, my, mz, c0 .. c5
        mine = [np.empty(W) for _ in range(8)]  # nn, mz, c0 .. c5
        for i0 in range(2):
            _planar_row(a, valid, i0, i0 % 3, X, Y, Z, V)
        px, py, pz = np.empty(9), np.empty(9), np.empty(9)
        for i in range(1, H - 1):
            _planar_row(a, valid, i + 1, (i + 1) % 3, X, Y, Z, V)
            _row_moments(i, 1, per_px, tan, floor, W, X, Y, Z, V, *general[:2], sel, *general[2:])
            _row_moments_r1(i, per_px, tan, floor, W, X, Y, Z, V, *mine)
            want = np.stack([general[2], general[5]] + general[6:])[:, :W - 2]
            got = np.stack(mine)[:, :W - 2]
            assert np.array_equal(got.view(np.int64), want.view(np.int64)), (t, i)
            for j in range(1, W - 1):
                exp = _patch_moments(a, valid, i, j, 1, 1, per_px, tan, floor, px, py, pz)
                assert mine[0][j - 1] == exp[0], (t, i, j)
                if exp[0]:
                    row = np.array([mine[1][j - 1]] + [c[j - 1] for c in mine[2:]])
                    assert np.array_equal(row.view(np.int64), np.array([exp[3], *exp[4:]]).view(np.int64))
                    compared += 1
    assert compared > 10000


def _covariances(rng: np.random.Generator, n: int) -> np.ndarray:
    """Covariances (n, 6) as the gate computes them: 3 × 3 patches of random, flat, quantized, tilted
    to grazing, on a line, of one point, at every scale, with -0.0 entries now and then."""
    return np.array(list(patch_covariances(rng, n, tilts=(0.0, 0.1, 1.0, 100.0), noises=(0.0, 0.0, 1e-6, 1e-3, 1.0),
                                           quantized_every=3, decades=3, negative_zero_every=7)),
                    dtype=np.float64).reshape(n, 6)


def test_memo_gives_the_closed_form() -> None:
    """:func:`_bracket_or_solve` is :func:`_lambda_bracket`'s bracket where it gives one, else the closed
    form's λ_min and whether its normal is determined, bit for bit, whether the memo holds the
    covariance or not: repeated covariances, more distinct ones than slots (slots overwritten), the same
    covariance with +0.0 and -0.0 entries (distinct keys), NaN and infinite entries."""
    rng = np.random.default_rng(902)
    base = _covariances(rng, 3000)
    flips = base.copy()
    flips[flips == 0.0] = -0.0  # the same values, other bits where zero
    odd = base[:50].copy()
    odd[::2, int(rng.integers(0, 6))] = np.nan
    odd[1::2, int(rng.integers(0, 6))] = np.inf
    many = np.concatenate([base, flips, odd, _covariances(rng, 2 * (1 << _MEMO_BITS))])
    # each covariance several times, in an order that revisits them after slots changed hands
    order = np.concatenate([np.arange(many.shape[0]), rng.integers(0, many.shape[0], 4 * many.shape[0]),
                            np.repeat(np.arange(0, many.shape[0], 97), 5)])
    key = np.empty(6)
    memo = (np.zeros((1 << _MEMO_BITS, 7), np.uint64), np.empty((1 << _MEMO_BITS, 2)), key, key.view(np.uint64))
    solved = repeated = 0
    seen: set[bytes] = set()
    for q in order:
        c = [float(v) for v in many[q]]
        got = _bracket_or_solve(*c, memo)
        want = _lambda_bracket(*c)
        assert got[0] == want[0], q
        if want[0]:
            assert got[1:4] == want[1:], q
            continue
        lam, nx, _, _ = _smallest_eigvec(*c)
        assert _bits(got[4]) == _bits(lam) and got[5] == bool(np.isfinite(nx)), (q, got, lam, nx)
        solved += 1
        repeated += many[q].tobytes() in seen
        seen.add(many[q].tobytes())
    assert solved > 5000 and repeated > 3000  # (the closed form's way on both first and repeated calls)


def _quantized_frame(rng: np.random.Generator, H: int, W: int, step: float) -> np.ndarray:
    """A bin floor of quantized depth (steps of ``step`` mm) on a pixel grid, with a few quantized spheres
    and rows mostly unmeasured: flat patches repeat their covariance at the rounding level."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = np.full((H, W), 600.0)
    for _ in range(4):
        ci, cj, rad = rng.uniform(0, H), rng.uniform(0, W), rng.uniform(5, 25)
        d2 = (yy - ci) ** 2 + (xx - cj) ** 2
        z = np.where(d2 < rad ** 2, np.minimum(z, 600.0 - np.sqrt(np.maximum(rad ** 2 - d2, 0.0))), z)
    z = np.round(z / step) * step
    f = 600.0
    a = np.stack([(xx - W / 2) * z / f, (yy - H / 2) * z / f, z], axis=2)
    gone = rng.random((H, W)) < 0.02
    gone[rng.integers(0, H, 3)] |= rng.random((3, W)) < 0.8  # rows mostly unmeasured
    a[gone] = np.nan
    return a


@pytest.mark.parametrize("step", [0.5, 1.0, 4.0])
def test_gate_median_on_quantized_frames_equals_the_whole_frame_pass(step: float) -> None:
    """(count, median) of :func:`_gate_median` are the whole-frame pass's (``_patch_gate_kernel`` and
    ``_median_of_temporary``) on frames of quantized depth, where the median ratio is itself a closed
    form's value at the rounding level taken from the memo; and every closed-form value in
    :func:`_ratio_brackets`' list is the closed form's for that patch."""
    rng = np.random.default_rng(int(step * 10))
    for t in range(3):
        a = np.ascontiguousarray(_quantized_frame(rng, 90 + 30 * t, 160 + 40 * t, step))
        H, W = a.shape[:2]
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        params = EdgeSurfaceParams()
        m, want, per_px, tan = whole_frame_gate(a, params)
        got = _gate_median(a, valid, params, per_px, tan)
        assert got[0] == m and _bits(got[1]) == _bits(want), (t, got, m, want)
        lo, hi, at = np.empty(H * W), np.empty(H * W), np.empty(H * W, np.int64)
        k, solved, _ = _ratio_brackets(a, valid, 1, params.min_patch_px, per_px, tan, params.side_step_mm, lo, hi, at)
        assert k == m and solved > m // 4  # most patches solved in closed form: the memo's case
        px, py, pz = np.empty(9), np.empty(9), np.empty(9)
        for q in np.flatnonzero(lo[:k] == hi[:k]):
            i, j = divmod(int(at[q]), W)
            mom = _patch_moments(a, valid, i, j, 1, params.min_patch_px, per_px, tan, params.side_step_mm, px, py, pz)
            lam = _smallest_eigvec(*mom[4:])[0]
            assert _bits(lo[q]) == _bits(math.sqrt(max(lam, 0.0)) / mom[3] ** 2), (t, i, j)
