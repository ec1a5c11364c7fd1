"""bench/bench_label_pageonly.py ``--tail Q`` (docs/labelling.md, "Twenty-fifth round"): one profile bound a
``--slivers`` variant, set on the method's ``SLIVER_MAX_TAIL`` while the variant's fits are made, named in the
variant's name (``qQ`` where Q > 0), put back after; bad fields refused in one line."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType, SimpleNamespace

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def test_fields(bench) -> None:  # type: ignore[no-untyped-def]
    assert bench.parse_tail("0,1.645,2") == [0.0, 1.645, 2.0]


@pytest.mark.parametrize("text", ["", "x", "-1", "1.6.4", "1,", "nan"])
def test_bad_fields_refused(bench, text: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=r"^--tail takes Q \(Q >= 0\), comma-separated, got "):
        bench.parse_tail(text)


def test_a_bound_is_named_set_and_put_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import annotate.fits
    import replay.pipeline.explained as rex

    tree = rex.SLIVER_MAX_TAIL
    seen: list = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(rex.SLIVER_MAX_TAIL))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    variants = bench.parse_slivers("10:12:2:8,10:24:2:8:0.1")
    names = [n for n, *_ in bench.sliver_variants(None, None, None, variants, free=bench.parse_free("3:0.025,3:0.025"),
                                                  tail=bench.parse_tail("0,1.645"))]
    assert names == ["slivers10x12x2x8_free0s3a0.025", "slivers10x24x2x8x0.1_free0s3a0.025q1.645"]
    assert seen == [0.0, 1.645] and rex.SLIVER_MAX_TAIL == tree
    seen.clear()
    names = [n for n, *_ in bench.sliver_variants(None, None, None, variants[:1], tail=[2.0])]
    assert names == ["slivers10x12x2x8_q2"] and seen == [2.0] and rex.SLIVER_MAX_TAIL == tree
    with pytest.raises(ValueError, match=r"^--tail takes one Q a --slivers variant \(2\), got 1$"):
        list(bench.sliver_variants(None, None, None, variants, tail=[1.0]))
