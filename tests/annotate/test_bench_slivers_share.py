"""bench/bench_label_pageonly.py ``--slivers N:M[:C:R[:S]]`` (docs/labelling.md, "Eighteenth round"): the fifth field
is the sliver pass's free-space bound (``replay.pipeline.explained.SLIVER_MAX_SEE_THROUGH``) a variant runs with, the
four-field form as before (the tree's bound), the constants put back after the variants; bad fields refused."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType, SimpleNamespace

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def test_fields_and_names(bench) -> None:  # type: ignore[no-untyped-def]
    got = bench.parse_slivers("150:12:2:8,150:24:2:8:0.2,30:6,,0:1:0:1:1")
    assert got == [(150, 12, 2, 8), (150, 24, 2, 8, 0.2), (30, 6), (0, 1, 0, 1, 1.0)]
    assert [bench.sliver_name(v) for v in got] == ["slivers150x12x2x8", "slivers150x24x2x8x0.2", "slivers30x6",
                                                   "slivers0x1x0x1x1"]


@pytest.mark.parametrize("text", ["", "150", "150:12:2", "150:12:2:8:0.2:1", "150:0", "-1:12", "150:12:-1:8",
                                  "150:12:2:0", "150:12:2:8:1.5", "150:12:2:8:-0.1", "150:12:2:8:nan",
                                  "150:12.5", "a:b"])
def test_bad_fields_refused(bench, text: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=r"^--slivers takes N"):
        bench.parse_slivers(text)


def test_variants_set_the_bound_and_put_it_back(bench, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Each variant's fits are made with its constants (the fifth field, else the tree's bound); after the
    variants, the tree's constants again. The page's fits are stubbed to note the constants they would read."""
    import annotate.fits
    import replay.pipeline.explained as rex

    tree = (rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE,
            rex.SLIVER_MAX_SEE_THROUGH, rex._with_slivers)
    seen = []
    monkeypatch.setattr(annotate.fits, "fit_frame", lambda *a: seen.append(
        (rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE, rex.SLIVER_MAX_SEE_THROUGH)))
    session = SimpleNamespace(prepared=None, config=None)
    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=lambda log: session))
    names = [name for name, *_ in bench.sliver_variants(None, None, None, bench.parse_slivers(
        "150:12:2:8:0.2,150:24:2:8,150:12:2:8:1"))]
    assert names == ["slivers150x12x2x8x0.2", "slivers150x24x2x8", "slivers150x12x2x8x1"]
    assert seen == [(150, 12, 2, 8, 0.2), (150, 24, 2, 8, tree[4]), (150, 12, 2, 8, 1.0)]
    assert (rex.SLIVER_MIN_PX, rex.SLIVER_MAX_REGIONS, rex.SLIVER_COARSE, rex.SLIVER_REFINE,
            rex.SLIVER_MAX_SEE_THROUGH, rex._with_slivers) == tree
