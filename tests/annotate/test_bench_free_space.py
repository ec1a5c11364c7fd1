"""bench/bench_label_pageonly.py ``--free-space I:E`` (docs/labelling.md, "Twenty-first round"): one free-space reading
a ``--slivers`` variant, set on the method's constants (``SLIVER_FREE_INSET_PX``, ``SLIVER_FREE_SKIP_EDGES``) while the
variant's fits are made, named in the variant's name, put back after; bad fields refused in one line."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType, SimpleNamespace

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def test_fields(bench) -> None:  # type: ignore[no-untyped-def]
    assert bench.parse_free("0:0,2:1,1:1,10:0") == [(0, False), (2, True), (1, True), (10, False)]
    assert bench.parse_free("2:1:10,0:0:3,0:0:0") == [(2, True, 10.0), (0, False, 3.0), (0, False, 0.0)]
    assert bench.parse_free("2:1:3:0.025,0:0:0:1") == [(2, True, 3.0, 0.025), (0, False, 0.0, 1.0)]


@pytest.mark.parametrize("text", ["", "2", "2:1:-1", "2:1:x", "2:1:0:1.5", "2:1:0:-0.1", "2:1:3:0.1:1", "-1:1", "2:2", "a:1",
                                  "2:1,", "1.5:0"])
def test_bad_fields_refused(bench, text: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=r"^--free-space takes I:E\[:S\[:A\]\] \(I >= 0, E 0 or 1, S >= 0, 0 <= A <= 1\)"):
        bench.parse_free(text)


def _stub(bench, monkeypatch) -> list:  # type: ignore[no-untyped-def]
    import annotate.fits
    import replay.pipeline.explained as rex

    seen: list = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(
        (rex.SLIVER_MAX_SEE_THROUGH, rex.SLIVER_FREE_INSET_PX, rex.SLIVER_FREE_SKIP_EDGES)))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    return seen


def test_variants_set_the_reading_and_put_it_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import replay.pipeline.explained as rex

    tree = (rex.SLIVER_MAX_SEE_THROUGH, rex.SLIVER_FREE_INSET_PX, rex.SLIVER_FREE_SKIP_EDGES)
    seen = _stub(bench, monkeypatch)
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers(
        "150:12:2:8,150:12:2:8,150:12:2:8:0.2"), free=bench.parse_free("0:0,2:1,1:0"))]
    assert names == ["slivers150x12x2x8_free0", "slivers150x12x2x8_free2e", "slivers150x12x2x8x0.2_free1"]
    assert seen == [(tree[0], 0, False), (tree[0], 2, True), (0.2, 1, False)]
    assert (rex.SLIVER_MAX_SEE_THROUGH, rex.SLIVER_FREE_INSET_PX, rex.SLIVER_FREE_SKIP_EDGES) == tree
    # without --free-space: the tree's reading, the names as before
    seen.clear()
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers("150:12:2:8"))]
    assert names == ["slivers150x12x2x8"] and seen == [(tree[0], tree[1], tree[2])]


def test_a_cut_names_its_footprints_and_is_put_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import annotate.fits
    import replay.pipeline.explained as rex

    tree = rex.SLIVER_SPLIT_STEPS
    seen: list = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(rex.SLIVER_SPLIT_STEPS))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers(
        "150:12:2:8,150:12:2:8,150:24:2:8"), free=bench.parse_free("0:0:0,0:0:10,2:1:3"))]
    assert names == ["slivers150x12x2x8_free0", "slivers150x12x2x8_free0s10", "slivers150x24x2x8_free2es3"]
    assert seen == [0.0, 10.0, 3.0] and rex.SLIVER_SPLIT_STEPS == tree


def test_an_area_floor_names_its_share_and_is_put_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import annotate.fits
    import replay.pipeline.explained as rex

    tree = (rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE)
    seen: list = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(
        (rex.SLIVER_MIN_PX, rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE)))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers(
        "150:12:2:8,10:12:2:8,10:24:2:8"), free=bench.parse_free("0:0:3,0:0:3:0.025,2:1:3:0.025"))]
    assert names == ["slivers150x12x2x8_free0s3", "slivers10x12x2x8_free0s3a0.025",
                     "slivers10x24x2x8_free2es3a0.025"]
    assert seen == [(150, 3.0, 0.0), (10, 3.0, 0.025), (10, 3.0, 0.025)]
    assert (rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE) == tree


def test_one_reading_a_variant(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    _stub(bench, monkeypatch)
    with pytest.raises(ValueError, match=r"^--free-space takes one I:E\[:S\[:A\]\] a --slivers variant \(2\), got 1$"):
        list(bench.sliver_variants(None, None, None, bench.parse_slivers("150:12:2:8,150:12:2:8"),
                                   free=[(2, True)]))
