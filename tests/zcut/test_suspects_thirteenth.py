"""The suspects' thirteenth round (issue 32, item 5): the gate's window ends from a sample's window
(:func:`zcut.suspects.select.kth_of_both`), the zone's heights in a caller's array
(:func:`zcut.suspects.floating.floating_components`' ``hz``) and the strength classes of labels of one or two
values without a sort (:func:`zcut.suspects.grouping._label_classes`): the same values as the code they replace,
and the whole call still ``suspects_reference``'s."""

from __future__ import annotations

import math

import numpy as np
import pytest
from suspects_helpers import whole_frame_gate
from test_suspects_fast import _fuzz_cloud, assert_same
from test_suspects_fifth import _floating_case
from test_suspects_ninth import _quantized_frame

from zcut.edge_surface import EdgeSurfaceParams
from zcut.errors import InputShapeError
from zcut.params import SuspectParams
from zcut.sor_workspace import SorWorkspace
from zcut.suspects import select as sel
from zcut.suspects import suspects, suspects_reference
from zcut.suspects.floating import floating_components
from zcut.suspects.noise import noise_profile
from zcut.suspects.surfaces import _gate_median_in, gate_arrays


def _bits(v: float) -> int:
    return int(np.float64(v).view(np.int64))


def _pairs(rng: np.random.Generator):  # type: ignore[no-untyped-def]
    """(x, y) of sizes around and above the sample's threshold: brackets (y a little above x), equal arrays,
    sorted and reversed (a strided sample of a sorted array is spread evenly; one sorted in blocks is not),
    many ties, zeros (a window from zero: the whole array's order_pair), -0.0, NaN, negative values and inf."""
    for t in range(48):
        n = int(rng.integers(sel._SAMPLE_MIN - 3, 4 * sel._SAMPLE_MIN)) if t % 8 else int(rng.integers(1, 3000))
        kind = t % 6
        if kind == 0:
            x = rng.random(n)
        elif kind == 1:
            x = rng.integers(0, 50, n) * 0.125  # ties, and zeros
        elif kind == 2:
            x = np.sort(rng.exponential(size=n))
        elif kind == 3:
            x = np.sort(rng.random(n))[::-1].copy()
        elif kind == 4:  # sorted in blocks of the sample's stride: the sample holds the blocks' smallest only
            x = np.sort(rng.random(n).reshape(-1, 1) if n % sel._SAMPLE_EVERY else
                        rng.random(n).reshape(-1, sel._SAMPLE_EVERY), axis=1).ravel()
        else:
            x = np.abs(rng.normal(size=n)) * 10.0 ** rng.integers(-30, 30, n)
        y = x + np.abs(x) * rng.random(n) * float(rng.choice([0.0, 1e-12, 1e-3]))
        if t % 7 == 3:
            x[rng.integers(0, n, 3)] = -0.0
        if t % 9 == 4:
            y[rng.integers(0, n)] = np.nan
        if t % 10 == 5:
            x[rng.integers(0, n, 5)] = -rng.random(5)
            y[rng.integers(0, n)] = np.inf
        yield t, np.ascontiguousarray(x), np.ascontiguousarray(y)


def test_kth_of_both_equals_order_pair_of_each() -> None:
    """Ranks at the middle (the gate's: kx = ky or ky = kx + 1), at both ends and at random, each value's bits
    those of order_pair (np.partition's value) of the whole array."""
    rng = np.random.default_rng(1301)
    for t, x, y in _pairs(rng):
        n = x.size
        h = n // 2
        ranks = [(h, h), (max(h - 1, 0), h), (0, 0), (n - 1, n - 1), (int(rng.integers(0, n)), int(rng.integers(0, n)))]
        for kx, ky in ranks:
            got = sel.kth_of_both(x, y, kx, ky)
            want = (sel.order_pair(x, kx, kx)[0], sel.order_pair(y, ky, ky)[0])
            for g, w in zip(got, want, strict=True):
                assert (math.isnan(g) and math.isnan(w)) or _bits(g) == _bits(w), (t, n, kx, ky, got, want)


def test_order_pair_large_equals_order_pair() -> None:
    """The same arrays, adjacent and equal ranks at the middle, both ends and at random: order_pair's values, bit
    for bit (NaN left to it: the arrays with one are skipped, as order_pair's callers check them first)."""
    rng = np.random.default_rng(1306)
    for t, x, _ in _pairs(rng):
        n = x.size
        if np.isnan(x).any():
            continue
        h = n // 2
        for k0, k1 in ((h, h), (max(h - 1, 0), h), (0, min(1, n - 1)), (n - 1, n - 1),
                       (k := int(rng.integers(0, n)), min(k + 1, n - 1))):
            got = sel.order_pair_large(x, k0, k1)
            want = sel.order_pair(x, k0, k1)
            assert [_bits(g) for g in got] == [_bits(w) for w in want], (t, n, k0, k1, got, want)
    with pytest.raises(ValueError):
        sel.order_pair_large(np.arange(5.0), 3, 2)


def test_kth_of_both_checks_its_arguments() -> None:
    x = np.arange(10.0)
    with pytest.raises(ValueError):
        sel.kth_of_both(x, x[:9], 0, 0)
    with pytest.raises(ValueError):
        sel.kth_of_both(x, x, 10, 0)
    with pytest.raises(ValueError):
        sel.kth_of_both(x, x, 0, -1)


def test_window_passes_count_and_gather_as_numpy() -> None:
    """The counting pass and the gathering pass against numpy's masks, windows at the middle, from the
    smallest value and to +inf; values below the window of every sign (-0.0 and negatives wrap around)."""
    rng = np.random.default_rng(1302)
    for t in range(40):
        n = int(rng.integers(1, 5000))
        x = rng.random(n) * 4.0
        x[rng.random(n) < 0.1] = -0.0
        x[rng.random(n) < 0.05] *= -1.0
        y = x + 1e-9
        s = np.sort(x[x > 0]) if (x > 0).any() else np.array([1.0])
        a = float(s[int(rng.integers(0, s.size))])
        b = float(np.inf) if t % 4 == 0 else float(max(a, s[int(rng.integers(0, s.size))]))
        cx, cy, nan = sel._window_counts(x, y, a)
        assert sel._window_count_one(x, a) == (cx, 0)
        assert (cx, cy, nan) == (int((x < a).sum()), int((y < a).sum()), 0)
        bx, by = np.empty(n), np.empty(n)
        nx, ny = sel._window_values(x, y, a, b, bx, by)
        assert np.array_equal(bx[:nx], x[(x >= a) & (x <= b)]) and np.array_equal(by[:ny], y[(y >= a) & (y <= b)])
        assert sel._window_values_one(x, a, b, bx) == nx and np.array_equal(bx[:nx], x[(x >= a) & (x <= b)])
    x = np.array([1.0, np.nan, 2.0])
    assert sel._window_counts(x, x.copy(), 0.5)[2] == 1 and sel._window_count_one(x, 0.5) == (0, 1)


def test_gate_of_large_frames_equals_the_whole_frame_pass() -> None:
    """Frames with more fitted patches than the sample's threshold (the window from the sample), smooth,
    quantized (many equal ratios) and with a third unmeasured: the whole-frame pass's (count, median)."""
    rng = np.random.default_rng(1303)
    params = EdgeSurfaceParams()
    ws = SorWorkspace(max_bytes=None)
    n_large = 0
    for H, W, step in ((300, 320, 1.0), (300, 320, 1e-9), (360, 400, 0.25)):
        a = _quantized_frame(rng, H, W, step) if step != 1e-9 else np.ascontiguousarray(_fuzz_cloud(rng, H, W))
        if step == 0.25:
            a[rng.random(a.shape[:2]) < 0.3] = np.nan
        a = np.ascontiguousarray(a)
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        m, med, per_px, tan = whole_frame_gate(a, params)
        n_large += m >= sel._SAMPLE_MIN
        lo, hi, at = gate_arrays(ws, H * W, ("x", "y", "z"))
        lo.fill(np.nan)
        hi.fill(1e300)
        got = _gate_median_in(a, valid, params, per_px, tan, lo, hi, at)
        assert got[0] == m
        assert (math.isnan(got[1]) and math.isnan(med)) or _bits(got[1]) == _bits(med), (H, W, got, med)
    assert n_large >= 2, n_large


def test_floating_components_in_a_given_array() -> None:
    """The zone's heights written into a caller's array filled with garbage: the same mask, pixels and gaps as
    in a fresh one, nothing returned shares its memory; an array of the wrong shape, type or layout refused."""
    rng = np.random.default_rng(1304)
    for t in range(30):
        H, W = (int(rng.integers(1, 8)), int(rng.integers(1, 8))) if t % 6 == 0 else (int(rng.integers(20, 80)),
                                                                                    int(rng.integers(20, 90)))
        h, zone, valid, rough = _floating_case(rng, H, W)
        profile = noise_profile(np.where(zone, h, np.nan), zone)
        params = SuspectParams()
        args = (np.ascontiguousarray(h), zone, valid, rough, params, 0.01 * H * W, 0.5, profile)
        want = floating_components(*args)
        hz = np.full((H, W), 1e300)
        hz.ravel()[:: 3] = np.nan
        got = floating_components(*args, hz=hz)
        for g, w in zip(got, want, strict=True):
            assert np.array_equal(g, w, equal_nan=True) and g.dtype == w.dtype
            assert not np.shares_memory(g, hz)
    h, zone, valid, rough = _floating_case(rng, 10, 12)
    profile = noise_profile(np.where(zone, h, np.nan), zone)
    args = (np.ascontiguousarray(h), zone, valid, rough, SuspectParams(), 1.2, 0.5, profile)
    for bad in (np.empty((10, 11)), np.empty((10, 12), np.float32), np.empty((12, 10)).T):
        with pytest.raises(InputShapeError):
            floating_components(*args, hz=bad)


def test_whole_call_equals_the_reference() -> None:
    """``suspects`` with the labelling page's edge surfaces against ``suspects_reference``, on frames with more
    fitted patches than the sample's threshold (smooth, quantized, a third unmeasured) and a small one."""
    rng = np.random.default_rng(1305)
    for t in range(4):
        if t == 3:
            mm = np.ascontiguousarray(_fuzz_cloud(rng, 40, 60))
        else:
            mm = _quantized_frame(rng, 280, 300, 1.0) if t == 1 else np.ascontiguousarray(_fuzz_cloud(rng, 280, 300))
        if t == 2:
            mm[rng.random(mm.shape[:2]) < 0.3] = np.nan
        xyz = mm / 1000.0
        h = -1000.0 * xyz[..., 2]
        zone = np.isfinite(xyz).all(axis=2)
        kw = dict(params=SuspectParams(), edge_surface=EdgeSurfaceParams())
        assert_same(suspects(xyz, h, zone, **kw), suspects_reference(xyz, h, zone, **kw))


def test_local_height_in_a_given_array() -> None:
    """The local heights written into a caller's array filled with garbage: the fresh array's values, bit for
    bit (NaN, ±0 and ties among them); arrays of the wrong shape, type or layout, or the heights' own, refused."""
    from zcut.suspects.noise import local_height

    rng = np.random.default_rng(1307)
    for t in range(30):
        H, W = (int(rng.integers(1, 4)), int(rng.integers(1, 6))) if t % 5 == 0 else (int(rng.integers(5, 60)),
                                                                                    int(rng.integers(5, 60)))
        h = np.round(rng.normal(0.0, 2.0, (H, W)) * 2.0) / 2.0
        h[rng.random((H, W)) < 0.2] = np.nan
        h[rng.random((H, W)) < 0.05] = -0.0
        want = local_height(h)
        out = np.full((H, W), 1e300)
        got = local_height(h, out=out)
        assert got is out and np.array_equal(got.view(np.int64), want.view(np.int64))
    h = rng.random((6, 7))
    for bad in (np.empty((6, 8)), np.empty((6, 7), np.float32), np.empty((7, 6)).T, h):
        with pytest.raises(InputShapeError):
            local_height(h, out=bad)


def test_in_zone_equals_boolean_indexing() -> None:
    """σ̂ in the zone gathered into a longer array filled with garbage: ``a[zone]``, in order (NaN, -0.0 kept)."""
    from zcut.suspects.union import _in_zone

    rng = np.random.default_rng(1309)
    for t in range(40):
        H, W = (int(rng.integers(0, 3)), int(rng.integers(0, 4))) if t % 8 == 0 else (int(rng.integers(1, 80)),
                                                                                    int(rng.integers(1, 90)))
        a = rng.random((H, W))
        a[rng.random((H, W)) < 0.1] = np.nan
        a[rng.random((H, W)) < 0.1] = -0.0
        zone = rng.random((H, W)) < float(rng.choice([0.0, 0.5, 1.0]))
        out = np.full(H * W, 1e300)
        n = int(_in_zone(a, zone, out))
        assert np.array_equal(out[:n].view(np.int64), a[zone].view(np.int64))
