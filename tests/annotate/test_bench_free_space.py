"""bench/bench_label_pageonly.py ``--free-space S:A`` (docs/labelling.md, "Twenty-third round", "Twenty-fourth round"):
one region cut S and area floor A a ``--slivers`` variant, set on the method's constants (``SLIVER_SPLIT_STEPS``,
``SLIVER_MIN_AREA_SHARE``) while the variant's fits are made, named in the variant's name, put back after; bad fields
refused in one line, the removed ``I:E:S:A`` form of the free-space reading (round of 2026-12-07g, h/dead) in its own."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType, SimpleNamespace

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def test_fields(bench) -> None:  # type: ignore[no-untyped-def]
    assert bench.parse_free("0:0,3:0.025,10:0,1.5:1") == [(0.0, 0.0), (3.0, 0.025), (10.0, 0.0), (1.5, 1.0)]


@pytest.mark.parametrize("text", ["", "2", "3:0:0", "-1:0", "x:0", "3:1.5", "3:-0.1", "3:0,", "a:b", "3:nan"])
def test_bad_fields_refused(bench, text: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=r"^--free-space takes S:A \(S >= 0, 0 <= A <= 1\), comma-separated, got "):
        bench.parse_free(text)


@pytest.mark.parametrize("text", ["0:0:3:0.025", "3:0.025,2:1:3:0.025"])
def test_the_removed_reading_is_refused_by_name(bench, text: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError) as e:
        bench.parse_free(text)
    assert str(e.value) == (f"--free-space takes S:A now: the I:E fields (the free-space reading off the rim and "
                            f"edges) were removed, got {text!r}")


def _stub(bench, monkeypatch) -> list:  # type: ignore[no-untyped-def]
    import annotate.fits
    import replay.pipeline.explained as rex

    seen: list = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(
        (rex.SLIVER_MIN_PX, rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE)))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    return seen


def test_a_cut_and_a_floor_are_named_and_put_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import replay.pipeline.explained as rex

    tree = (rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE)
    seen = _stub(bench, monkeypatch)
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers(
        "150:12:2:8,150:12:2:8,10:12:2:8,10:24:2:8"), free=bench.parse_free("0:0,10:0,3:0.025,0:0.025"))]
    assert names == ["slivers150x12x2x8_free0", "slivers150x12x2x8_free0s10", "slivers10x12x2x8_free0s3a0.025",
                     "slivers10x24x2x8_free0a0.025"]
    assert seen == [(150, 0.0, 0.0), (150, 10.0, 0.0), (10, 3.0, 0.025), (10, 0.0, 0.025)]
    assert (rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE) == tree
    # without --free-space: the tree's cut and floor, the names as before
    seen.clear()
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers("150:12:2:8"))]
    assert names == ["slivers150x12x2x8"] and seen == [(150, *tree)]


def test_one_reading_a_variant(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    _stub(bench, monkeypatch)
    with pytest.raises(ValueError, match=r"^--free-space takes one S:A a --slivers variant \(2\), got 1$"):
        list(bench.sliver_variants(None, None, None, bench.parse_slivers("150:12:2:8,150:12:2:8"),
                                   free=[(3.0, 0.0)]))
