"""The suspects' tenth round (issue 32, item 5): the gate's arrays come from a workspace kept per thread
(:func:`zcut.suspects.surfaces.gate_workspace`); its (count, median) stay the whole-frame pass's whatever
the workspace held before (a larger frame, a smaller one, none), on re-entry and in two threads at once
and so do :func:`zcut.suspects.suspects`' scratch images (:func:`zcut.suspects.union.scratch_workspace`: the
whole call against ``suspects_reference`` whatever the workspaces held; the other frames:
tests/zcut/test_suspects_fast.py); the row's settling
(:func:`zcut.suspects.surfaces._row_settle`, the memo written out) is :func:`_bracket_or_solve`'s."""

from __future__ import annotations

import math
import threading

import numpy as np
from suspects_helpers import patch_covariances, whole_frame_gate
from test_suspects_fast import assert_same
from test_suspects_ninth import _quantized_frame

from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.suspects import suspects, suspects_reference
from zcut.suspects.surfaces import _MEMO_BITS, _bracket_or_solve, _gate_median, _row_settle, gate_workspace
from zcut.suspects.union import scratch_workspace


def _bits(x: float) -> int:
    return int(np.float64(x).view(np.int64))


def _frames() -> list[np.ndarray]:
    """Frames of several sizes, in an order that grows and shrinks the workspace's arrays: quantized and
    smooth depth, rows mostly unmeasured, a third of the pixels gone, all NaN, one pixel, 0 × 0."""
    rng = np.random.default_rng(1001)
    out = []
    for H, W, step in ((120, 200, 1.0), (30, 40, 0.5), (150, 260, 1e-9), (1, 1, 1.0), (60, 90, 4.0)):
        out.append(_quantized_frame(rng, H, W, step))
    holes = _quantized_frame(rng, 100, 140, 1.0)
    holes[rng.random(holes.shape[:2]) < 0.33] = np.nan
    out.append(holes)
    out.append(np.full((20, 30, 3), np.nan))
    out.append(np.empty((0, 0, 3)))
    out.append(_quantized_frame(rng, 140, 230, 0.5))
    return [np.ascontiguousarray(a) for a in out]


_want = whole_frame_gate


def _check(a: np.ndarray, params: EdgeSurfaceParams, want: tuple[int, float, float, float]) -> None:
    valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
    m, med, per_px, tan = want
    got = _gate_median(a, valid, params, per_px, tan)
    assert got[0] == m, (a.shape, got, m)
    assert (math.isnan(got[1]) and math.isnan(med)) or _bits(got[1]) == _bits(med), (a.shape, got, med)


def test_gate_median_with_the_workspace_equals_the_whole_frame_pass() -> None:
    """Frame after frame in one thread (the workspace keeping the largest arrays, then grown), again after
    :meth:`release`, and on re-entry (a call while the thread's workspace is in use works in fresh
    arrays): the whole-frame pass's (count, median) every time; the workspace keeps the arrays between
    calls and drops them on release."""
    params = EdgeSurfaceParams()
    frames = _frames()
    wants = [_want(a, params) for a in frames]
    ws = gate_workspace()
    ws.release()
    for a, want in zip(frames, wants, strict=True):
        _check(a, params, want)
    big = max(a.shape[0] * a.shape[1] for a in frames)
    assert ws.nbytes >= 3 * 8 * big  # lo, hi, at of the largest frame, kept
    assert gate_workspace() is ws
    ws.release()
    assert ws.nbytes == 0
    for a, want in zip(frames[::-1], wants[::-1], strict=True):
        _check(a, params, want)
    with ws.call():  # the thread's workspace busy: the gate works in a fresh one
        for a, want in zip(frames, wants, strict=True):
            _check(a, params, want)


def test_gate_median_in_two_threads_at_once() -> None:
    """Two threads calling the gate over the frames at once, each with its own workspace: the whole-frame
    pass's (count, median) in both."""
    params = EdgeSurfaceParams()
    frames = _frames()
    wants = [_want(a, params) for a in frames]
    errors: list[BaseException] = []
    spaces: list[object] = []
    start = threading.Barrier(2)

    def run(order: list[int]) -> None:
        try:
            start.wait()
            for _ in range(3):
                for q in order:
                    _check(frames[q], params, wants[q])
            spaces.append(gate_workspace())
        except BaseException as e:  # noqa: BLE001  (re-raised in the test's thread)
            errors.append(e)

    idx = list(range(len(frames)))
    threads = [threading.Thread(target=run, args=(o,)) for o in (idx, idx[::-1])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert len(spaces) == 2 and spaces[0] is not spaces[1] and spaces[0] is not gate_workspace()


def _memo() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    key = np.empty(6)
    return np.zeros((1 << _MEMO_BITS, 7), np.uint64), np.empty((1 << _MEMO_BITS, 2)), key, key.view(np.uint64)


def _ratio(lam: float, zz: float) -> float:
    """sqrt(max(λ, 0)) / z² with IEEE division (z² = 0: ±inf or NaN), as the kernels compute it."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.float64(math.sqrt(max(lam, 0.0))) / np.float64(zz))


def test_row_settle_equals_bracket_or_solve() -> None:
    """:func:`_row_settle` gives, patch by patch, what :func:`_bracket_or_solve` gives (its bracket, else the
    closed form's value, from the memo or not) turned into the ratio's bracket as :func:`_keep_patch` turns
    it, bit for bit; the counts of solved patches and the NaN flag likewise; and it leaves the memo as
    :func:`_bracket_or_solve` leaves it. Rows of covariances drawn with repeats (memo hits), more distinct
    ones than slots, +0.0 / -0.0 entries, NaN and infinite entries, z² of 0 and NaN; the row's other
    entries untouched."""
    rng = np.random.default_rng(1002)
    base = np.array(list(patch_covariances(rng, 6000, tilts=(0.0, 0.1, 1.0, 100.0), noises=(0.0, 0.0, 1e-6, 1e-3, 1.0),
                                           quantized_every=2, decades=3, negative_zero_every=7)))
    odd = base[:60].copy()
    odd[::2, 2] = np.nan
    odd[1::2, 4] = np.inf
    pool = np.concatenate([base, odd])
    mine, theirs = _memo(), _memo()
    settled = solved_total = 0
    for row in range(300):
        W = int(rng.integers(1, 200))
        cov = pool[rng.integers(0, pool.shape[0] if row % 3 else 200, W)]  # every third row: few distinct ones
        mz = rng.choice([1.0, 0.5, 600.0, 0.0, np.nan], W, p=[0.3, 0.3, 0.36, 0.02, 0.02])
        k = int(rng.integers(0, W + 1))
        idx = np.sort(rng.choice(W, k, replace=False)).astype(np.int64)
        c = [np.ascontiguousarray(cov[:, q]) for q in range(6)]
        good, fitted = np.zeros(W, bool), rng.random(W) < 0.5
        rlo, rhi = rng.random(W), rng.random(W)
        before = (good.copy(), fitted.copy(), rlo.copy(), rhi.copy())
        solved, nan = _row_settle(k, idx, *c, mz, good, rlo, rhi, fitted, mine)
        want_solved, want_nan = 0, False
        for q in idx:
            zz = mz[q] ** 2
            ok, l0, l1, fit, lam, det = _bracket_or_solve(*(float(v) for v in cov[q]), theirs)
            if ok:
                want = (fit, _ratio(l0, zz), _ratio(l1, zz))
            else:
                want_solved += 1
                v = _ratio(lam, zz)
                want = (det, v, v)
                want_nan = want_nan or (det and zz > 0 and math.isnan(v))
            assert good[q] and fitted[q] == want[0], (row, q)
            assert _bits(rlo[q]) == _bits(want[1]) and _bits(rhi[q]) == _bits(want[2]), (row, q, rlo[q], want)
        rest = np.ones(W, bool)
        rest[idx] = False
        for got, was in zip((good, fitted, rlo, rhi), before, strict=True):
            assert np.array_equal(got[rest], was[rest]), row
        assert (solved, nan) == (want_solved, want_nan), row
        filled = theirs[0][:, 6] == 1
        assert np.array_equal(mine[0], theirs[0])
        assert np.array_equal(mine[1][filled].view(np.int64), theirs[1][filled].view(np.int64))
        settled += k
        solved_total += solved
    assert settled > 12000 and solved_total > 3000, (settled, solved_total)


def test_suspects_with_kept_workspaces_equal_the_reference() -> None:
    """The whole call, frame after frame in one thread (the scratch and gate workspaces grown and kept
    across sizes, then released), on re-entry, and in two threads at once: every field equal to
    ``suspects_reference``'s; nothing the call returns shares memory with a kept image."""
    rng = np.random.default_rng(1003)
    frames = [_quantized_frame(rng, 60, 90, 1.0), _quantized_frame(rng, 20, 30, 0.5), _quantized_frame(rng, 1, 1, 1.0),
              np.full((8, 12, 3), np.nan), _quantized_frame(rng, 70, 110, 1e-9)]
    frames[1][rng.random(frames[1].shape[:2]) < 0.4] = np.nan
    inputs = []
    for f in frames:
        xyz = np.ascontiguousarray(f / 1000.0)
        h = -1000.0 * xyz[..., 2]
        inputs.append((xyz, h, np.isfinite(xyz).all(axis=2)))
    params, es = SuspectParams(), EdgeSurfaceParams()
    wants = [suspects_reference(x, h, z, params=params, edge_surface=es) for x, h, z in inputs]

    def run_all(order: list[int]) -> None:
        for q in order:
            x, h, z = inputs[q]
            got = suspects(x, h, z, params=params, edge_surface=es)
            assert_same(got, wants[q])
            kept = [a for a in scratch_workspace()._arrays.values()] + [a for a in gate_workspace()._arrays.values()]
            for name in ("mask", "groups", "detectors", "gap_mm", "residual_mm"):
                assert not any(np.shares_memory(getattr(got, name), a) for a in kept), name

    order = list(range(len(inputs)))
    run_all(order + order[::-1])
    assert scratch_workspace().nbytes >= 3 * 8 * 70 * 110
    scratch_workspace().release()
    with scratch_workspace().call(), gate_workspace().call():  # both busy: fresh arrays
        run_all(order)
    errors: list[BaseException] = []

    def thread(o: list[int]) -> None:
        try:
            run_all(o)
        except BaseException as e:  # noqa: BLE001  (re-raised in the test's thread)
            errors.append(e)

    threads = [threading.Thread(target=thread, args=(o,)) for o in (order * 2, order[::-1] * 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
