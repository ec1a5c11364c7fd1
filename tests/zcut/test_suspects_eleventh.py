"""The suspects' eleventh round (issue 32, item 5): :func:`zcut.suspects.detectors.label_medians` from a counting
sort and a stable sort per label is :func:`label_medians_reference`'s (one lexsort), bit for bit; the gate works in
arrays the caller gives (:func:`zcut.suspects.surfaces.gate_arrays`: :func:`zcut.suspects.suspects` gives the
jump's and the strength's), and both workspaces are bounded (``max_bytes``): the whole call stays
``suspects_reference``'s whatever they held or dropped."""

from __future__ import annotations

import math

import numpy as np
from kernel_cache_helpers import missed, second_process_stats
from suspects_helpers import whole_frame_gate
from test_suspects_fast import assert_same
from test_suspects_ninth import _quantized_frame

from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.sor_workspace import SorWorkspace
from zcut.suspects import suspects, suspects_reference
from zcut.suspects.detectors import label_medians, label_medians_reference
from zcut.suspects.surfaces import GATE_KEPT_BYTES, _gate_median_in, gate_arrays, gate_workspace
from zcut.suspects.union import SCRATCH_KEPT_BYTES, scratch_workspace


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and bool((a.view(np.int64) == b.view(np.int64)).all())


def test_label_medians_equals_the_lexsort() -> None:
    """Random labels (0, negative, above n: not counted) and values with many ties, -0.0 beside 0.0 (the
    order of a tie decides which zero is the middle one), NaN and ±inf (not counted); labels with no
    value, one, two, odd and even counts; int32 and int64 labels; 2-D arrays; empty input; float32
    values and unsigned labels (the reference's path)."""
    rng = np.random.default_rng(1101)
    cases = 0
    for t in range(400):
        m = int(rng.integers(0, 300))
        n = int(rng.integers(0, 40))
        labels = rng.integers(-2, n + 3, m)
        kind = t % 4
        if kind == 0:
            values = rng.normal(0.0, 1.0, m)
        elif kind == 1:  # ties and signed zeros
            values = rng.choice(np.array([-0.0, 0.0, 1.5, -1.5, 2.0]), m)
        elif kind == 2:  # NaN and inf among ties
            values = rng.choice(np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 3.0, 3.0]), m)
        else:  # quantized, many equal values
            values = np.round(rng.normal(0.0, 2.0, m)) * 0.25
        for dtype in (np.int64, np.int32):
            got = label_medians(values, labels.astype(dtype), n)
            want = label_medians_reference(values, labels.astype(dtype), n)
            assert _same_bits(got, want), (t, dtype)
            cases += 1
        if m % 6 == 0 and m > 0:  # 2-D, as the sixth round's test calls it
            v2, l2 = values.reshape(6, -1), labels.reshape(6, -1)
            assert _same_bits(label_medians(v2, l2, n), label_medians_reference(v2, l2, n)), t
    assert cases == 800
    # the reference's path: float32 values (float32 means), unsigned labels
    v32 = rng.normal(0.0, 1.0, 200).astype(np.float32)
    lab = rng.integers(0, 6, 200)
    assert _same_bits(label_medians(v32, lab, 5), label_medians_reference(v32, lab, 5))
    assert _same_bits(label_medians(v32.astype(np.float64), lab.astype(np.uint32), 5),
                      label_medians_reference(v32.astype(np.float64), lab.astype(np.uint32), 5))
    # a middle zero's sign is the stable order's: the k-th zero in the values' order
    v = np.array([0.0, -0.0, 5.0, -0.0, 0.0, -3.0, 0.0, -0.0])
    for perm in range(50):
        p = rng.permutation(v.size)
        lab = np.ones(v.size, np.int64)
        lab[: perm % 3] = 2
        assert _same_bits(label_medians(v[p], lab, 2), label_medians_reference(v[p], lab, 2)), p
    assert label_medians(np.zeros(0), np.zeros(0, np.int64), 0).shape == (0,)
    assert np.isnan(label_medians(np.zeros(0), np.zeros(0, np.int64), 3)).all()


def test_gate_in_given_arrays_equals_the_whole_frame_pass() -> None:
    """The gate in arrays the caller gives, filled with garbage before (NaN, huge values), as the jump's and
    the strength's are: the whole-frame pass's (count, median)."""
    rng = np.random.default_rng(1102)
    params = EdgeSurfaceParams()
    ws = SorWorkspace(max_bytes=None)
    for H, W, step in ((80, 120, 1.0), (40, 50, 1e-9), (1, 1, 1.0), (90, 140, 0.5)):
        a = _quantized_frame(rng, H, W, step)
        if H > 50:
            a[rng.random(a.shape[:2]) < 0.3] = np.nan
        a = np.ascontiguousarray(a)
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        m, med, per_px, tan = whole_frame_gate(a, params)
        lo, hi, at = gate_arrays(ws, H * W, ("x", "y", "z"))
        lo.fill(np.nan)
        hi.fill(1e300)
        at.fill(-1)
        got = _gate_median_in(a, valid, params, per_px, tan, lo, hi, at)
        assert got[0] == m
        assert (math.isnan(got[1]) and math.isnan(med)) or np.float64(got[1]).view(np.int64) == np.float64(
            med).view(np.int64), (H, W, got, med)


def test_suspects_with_bounded_workspaces_equals_the_reference() -> None:
    """Frames of several sizes, the scratch workspace unbounded, then bounded below one frame's images (every
    call drops them after it), then at its default: ``suspects_reference``'s results every time; the gate
    takes the scratch workspace's arrays (the gate's own workspace is left alone), and nothing returned
    shares memory with a kept array."""
    rng = np.random.default_rng(1103)
    frames = [_quantized_frame(rng, 60, 90, 1.0), _quantized_frame(rng, 30, 40, 0.5), _quantized_frame(rng, 1, 1, 1.0),
              np.full((8, 12, 3), np.nan), _quantized_frame(rng, 70, 110, 1e-9)]
    frames[0][rng.random(frames[0].shape[:2]) < 0.4] = np.nan
    params, es = SuspectParams(), EdgeSurfaceParams()
    inputs = []
    for f in frames:
        xyz = np.ascontiguousarray(f / 1000.0)
        inputs.append((xyz, -1000.0 * xyz[..., 2], np.isfinite(xyz).all(axis=2)))
    wants = [suspects_reference(x, h, z, params=params, edge_surface=es) for x, h, z in inputs]
    ws = scratch_workspace()
    assert ws.max_bytes == SCRATCH_KEPT_BYTES and gate_workspace().max_bytes == GATE_KEPT_BYTES
    gate_workspace().release()
    try:
        for bound in (None, 8 * 40 * 40, SCRATCH_KEPT_BYTES):
            ws.release()
            ws.max_bytes = bound
            for (x, h, z), want in zip(inputs + inputs[::-1], wants + wants[::-1], strict=True):
                got = suspects(x, h, z, params=params, edge_surface=es)
                assert_same(got, want)
                assert bound is None or ws.nbytes <= bound
                for name in ("mask", "groups", "detectors", "gap_mm", "residual_mm"):
                    assert not any(np.shares_memory(getattr(got, name), a) for a in ws._arrays.values()), name
            if bound is None:  # tau, the jump, the strength, the gate's pixels of the largest frame
                assert ws.nbytes == 4 * 8 * 70 * 110
            assert gate_workspace().nbytes == 0
    finally:
        ws.max_bytes = SCRATCH_KEPT_BYTES


def _kept_ring_scan(lab: np.ndarray, keep: np.ndarray, zone: np.ndarray, valid: np.ndarray, h: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The oracle of ``_kept_ring``: every pixel in raster order (the previous kernel's scan, as a loop)."""
    H, W = lab.shape
    mask = keep[lab] & zone
    idx = np.flatnonzero(mask)
    rl, rh = [], []
    for i in range(H):
        for j in range(W):
            if mask[i, j] or not valid[i, j] or not np.isfinite(h[i, j]):
                continue
            win = (slice(max(i - 1, 0), i + 2), slice(max(j - 1, 0), j + 2))
            best = int(np.where(mask[win], lab[win], 0).max())
            if best > 0:
                rl.append(best)
                rh.append(h[i, j])
    return mask, idx, np.array(rl, np.int64), np.array(rh, np.float64)


def test_kept_ring_equals_the_scan_of_every_pixel() -> None:
    """``_kept_ring`` (the ring's candidates from the kept pixels of the rows around each row) against the scan
    of every pixel: random labels, kept or not, zone and valid holes, NaN and inf heights, kept pixels on
    every border and corner, one row, one column, one pixel, an empty frame, nothing kept, everything kept."""
    from zcut.suspects.floating import _kept_ring

    rng = np.random.default_rng(1104)
    shapes = [(1, 1), (1, 7), (9, 1), (2, 2), (0, 0), (0, 5), (30, 40), (17, 23), (64, 3)]
    for t in range(300):
        H, W = shapes[t % len(shapes)]
        n = int(rng.integers(1, 12))
        lab = rng.integers(0, n + 1, (H, W)).astype(np.int32)
        if t % 3 == 0:  # sparse components
            lab[rng.random((H, W)) < 0.8] = 0
        keep = rng.random(n + 1) < (0.0 if t % 17 == 0 else 1.0 if t % 13 == 0 else 0.5)
        keep[0] = False
        zone = rng.random((H, W)) < 0.9
        valid = rng.random((H, W)) < 0.85
        h = rng.normal(0.0, 1.0, (H, W))
        h[rng.random((H, W)) < 0.05] = np.nan
        h[rng.random((H, W)) < 0.03] = np.inf
        mask = np.empty((H, W), bool)
        idx, rl, rh = _kept_ring(lab, keep, zone, valid, h, H * W, mask)
        w_mask, w_idx, w_rl, w_rh = _kept_ring_scan(lab, keep, zone, valid, h)
        assert np.array_equal(mask, w_mask) and np.array_equal(idx, w_idx), t
        assert np.array_equal(rl, w_rl) and _same_bits(rh, w_rh), t


_CACHE_SCRIPT = r"""
import numpy as np
from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.suspects import suspects

rng = np.random.default_rng(7)
z = 1.0 + np.round(rng.normal(0.0, 0.0005, (100, 150)), 4)
H, W = z.shape
xyz = np.stack([np.tile(np.arange(W) * 1e-3, (H, 1)), np.repeat(np.arange(H)[:, None] * 1e-3, W, 1), z], axis=2)
xyz[20:23, 40:43, 2] -= 0.03  # floating pieces
xyz[60:62, 100:102, 2] -= 0.03
xyz[20:25, 30:40] = np.nan
h = -1000.0 * xyz[..., 2]
suspects(xyz, h, np.isfinite(xyz).all(axis=2), params=SuspectParams(), edge_surface=EdgeSurfaceParams())
"""


def test_the_suspects_kernels_load_from_the_cache_in_a_second_process() -> None:
    """The suspects' numba kernels (this round's ``_label_medians_kernel`` and ``_kept_ring`` among them) are not
    compiled again by a second fresh process (tests/zcut/test_kernel_cache.py's check, for ``zcut.suspects``)."""
    stats = second_process_stats(_CACHE_SCRIPT, prefix="zcut.suspects", timeout=900)
    assert {"zcut.suspects.detectors._label_medians_kernel", "zcut.suspects.floating._kept_ring"} <= set(stats), \
        sorted(stats)
    assert missed(stats) == {}, f"compiled again in a second process (cache hits, misses): {missed(stats)}"
