"""The suspects' fourteenth round (issue 32, item 5): the frame in mm has an explicit owner.

A result's surfaces own the frame in mm they were measured on until :meth:`zcut.suspects.union.SuspectResult.release`
hands it back to the calling thread, whose next call with edge surfaces writes its frame into it; no reference
count decides it (h/sup13 read ``sys.getrefcount``: CPython's counting). The checks: ``suspects_reference``'s
results every time, a result never released intact whatever the calls after it, the frame reused only after a
release, ``surface_mm`` read before a release kept and refused after one, the bound on what a thread keeps, and
each thread's frame its own.
"""

from __future__ import annotations

import inspect
import threading

import numpy as np
import pytest
from test_suspects_fast import FIELDS, _fuzz_cloud, assert_same

from zcut.edge_surface import EdgeSurfaceParams
from zcut.errors import ZcutError
from zcut.params import SuspectParams
from zcut.suspects import suspects, suspects_reference, union

KW = dict(params=SuspectParams(), edge_surface=EdgeSurfaceParams())


def _frame(seed: int, H: int, W: int) -> np.ndarray:
    return np.ascontiguousarray(_fuzz_cloud(np.random.default_rng(seed), H, W)) / 1000.0


def _call(xyz: np.ndarray, reference: bool = False):  # type: ignore[no-untyped-def]
    h = -1000.0 * xyz[..., 2]
    zone = np.isfinite(xyz).all(axis=2)
    return (suspects_reference if reference else suspects)(xyz, h, zone, **KW)


def _same_but_surface(got, want) -> None:  # type: ignore[no-untyped-def]
    """Every field but ``surface_mm`` (which a released result may no longer measure) equal."""
    for name in FIELDS:
        if name == "surface_mm":
            continue
        a, b = getattr(got, name), getattr(want, name)
        if name == "noise_profile":
            for part in ("heights_mm", "sigma_mm", "step_mm"):
                assert np.array_equal(getattr(a, part), getattr(b, part), equal_nan=True)
            continue
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name


def _frame_of(res) -> np.ndarray:  # type: ignore[no-untyped-def]
    a = res._surfaces._xyz
    assert a is not None
    return a  # type: ignore[no-any-return]


@pytest.fixture
def kept_from_zero(monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """Small frames kept too (the threshold at 0), the thread's slot empty before and after."""
    monkeypatch.setattr(union, "FRAME_KEPT_MIN_BYTES", 0)
    union.release_frame_mm()
    yield
    union.release_frame_mm()


def test_no_reference_count_is_read() -> None:
    """The ownership is explicit: nothing in the module asks the interpreter how many references an array has."""
    assert "getrefcount" not in inspect.getsource(union)


def test_a_frame_is_reused_only_after_its_result_released_it(kept_from_zero: None) -> None:
    """A result not released keeps its frame intact through later calls (which take fresh ones); released, its
    frame is the next call's, whose results are the reference's; ``surface_mm`` read before the release stays."""
    f0, f1 = _frame(1401, 50, 70), _frame(1402, 50, 70)
    want0, want1 = _call(f0, reference=True), _call(f1, reference=True)

    got = _call(f0)
    assert union.kept_frame_mm_bytes() == 0  # the result owns its frame
    a0 = _frame_of(got)
    got2 = _call(f1)  # got not released: a fresh frame, got's intact
    assert _frame_of(got2) is not a0 and not np.shares_memory(_frame_of(got2), a0)
    assert np.array_equal(a0, f0.astype(np.float64) * 1000.0, equal_nan=True)
    assert_same(got, want0)  # surface_mm of the first frame, measured after the second call
    assert_same(got2, want1)

    # released after surface_mm was read: the value stays; the next call writes into the released frame
    got.release()
    assert union.kept_frame_mm_bytes() == a0.nbytes
    assert got._surfaces._xyz is None  # type: ignore[union-attr]
    assert_same(got, want0)
    got3 = _call(f1)
    assert _frame_of(got3) is a0 and union.kept_frame_mm_bytes() == 0
    assert_same(got3, want1)
    assert_same(got2, want1)  # untouched by the call that reused got's frame

    # released before surface_mm was read: every other field stays, surface_mm is refused
    got4 = _call(f0)
    got4.release()
    _same_but_surface(got4, want0)
    with pytest.raises(ZcutError, match="released"):
        got4.surface_mm  # noqa: B018  (the property measures)
    with pytest.raises(ZcutError, match="released"):
        got4._surfaces.distance_at(np.zeros(1, np.int64))  # type: ignore[union-attr]
    with pytest.raises(ZcutError, match="released"):
        got4._surfaces.surface  # type: ignore[union-attr]  # noqa: B018
    kept = union._FRAME.a_mm
    got4.release()  # twice: nothing more
    assert union._FRAME.a_mm is kept


def test_with_block_releases_and_shapes_change(kept_from_zero: None) -> None:
    """``with suspects(...) as res`` releases on leaving; a frame of another shape takes a fresh array (the kept
    one dropped), and a call without edge surfaces neither takes nor keeps one."""
    f0, f1 = _frame(1403, 40, 60), _frame(1404, 30, 44)
    with _call(f0) as res:
        a0 = _frame_of(res)
        assert_same(res, _call(f0, reference=True))
    assert union._FRAME.a_mm is a0
    got = _call(f1)  # another shape: fresh, and the slot empty (the other frame dropped)
    assert _frame_of(got) is not a0 and _frame_of(got).shape == (30, 44, 3)
    assert union.kept_frame_mm_bytes() == 0
    assert_same(got, _call(f1, reference=True))
    got.release()
    kept = union._FRAME.a_mm
    assert kept is not None and kept.shape == (30, 44, 3)
    h = -1000.0 * f1[..., 2]
    plain = suspects(f1, h, np.isfinite(f1).all(axis=2), params=SuspectParams())  # no edge surfaces
    assert plain.surface_mm is None
    plain.release()
    assert union._FRAME.a_mm is kept


def test_degenerate_frames(kept_from_zero: None) -> None:
    """All NaN, one pixel, one row: the reference's results, released or not."""
    for xyz in (np.full((6, 9, 3), np.nan), _frame(1405, 1, 1), _frame(1406, 1, 40), _frame(1407, 25, 1)):
        want = _call(xyz, reference=True)
        got = _call(xyz)
        got.release()
        _same_but_surface(got, want)
        again = _call(xyz)
        assert_same(again, want)


def test_what_a_thread_keeps_stays_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    """Below ``FRAME_KEPT_MIN_BYTES`` a released frame is not kept; kept, it and the scratch images hold at most
    ``SCRATCH_KEPT_BYTES``: a bound below them drops it at the release, and a call whose scratch images grow past
    the bound drops the one kept."""
    union.release_frame_mm()
    union.scratch_workspace().release()  # only this test's images (earlier tests' larger frames would not grow)
    f0 = _frame(1408, 40, 60)
    _call(f0).release()
    assert union.kept_frame_mm_bytes() == 0  # 57,600 bytes: below 32 MiB, from the heap anyway
    monkeypatch.setattr(union, "FRAME_KEPT_MIN_BYTES", 0)
    res = _call(f0)
    monkeypatch.setattr(union, "SCRATCH_KEPT_BYTES", union.scratch_workspace().nbytes + 100)
    res.release()
    assert union.kept_frame_mm_bytes() == 0  # would exceed the bound: dropped
    monkeypatch.setattr(union, "SCRATCH_KEPT_BYTES", 128 << 20)
    _call(f0).release()
    assert 0 < union.kept_frame_mm_bytes() and (union.kept_frame_mm_bytes() + union.scratch_workspace().nbytes
                                                 <= union.SCRATCH_KEPT_BYTES)
    # a larger frame without edge surfaces grows the scratch images past the bound: the kept frame goes
    monkeypatch.setattr(union, "SCRATCH_KEPT_BYTES", union.scratch_workspace().nbytes + union.kept_frame_mm_bytes())
    big = _frame(1409, 60, 90)
    suspects(big, -1000.0 * big[..., 2], np.isfinite(big).all(axis=2), params=SuspectParams())
    assert union.kept_frame_mm_bytes() == 0
    union.release_frame_mm()


def test_each_thread_keeps_its_own(kept_from_zero: None) -> None:
    """A result released in another thread goes to that thread; this thread's next call takes a fresh frame."""
    f0 = _frame(1410, 40, 60)
    res = _call(f0)
    a0 = _frame_of(res)
    seen: list[int] = []

    def other() -> None:
        res.release()
        seen.append(union.kept_frame_mm_bytes())

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen == [a0.nbytes] and union.kept_frame_mm_bytes() == 0
    got = _call(f0)
    assert _frame_of(got) is not a0
    assert_same(got, _call(f0, reference=True))


def test_whole_call_equals_the_reference_on_fuzzed_frames(kept_from_zero: None) -> None:
    """Calls one after the other, each result released on leaving its block (so each call writes its frame into
    the previous one's): ``suspects_reference``'s results on fuzzed frames (holes, ties, flat patches) and frames
    mostly unmeasured."""
    rng = np.random.default_rng(1412)
    for t in range(8):
        xyz = _frame(1420 + t, 48, 64)
        if t % 2:
            xyz[rng.random(xyz.shape[:2]) < 0.6] = np.nan
        with _call(xyz) as got:
            assert_same(got, _call(xyz, reference=True))
