"""The offline groups (``zcut labels train``, the ``learned`` method) are the page's: no patch detector where the page
fits a part model (issue 32 item 5; docs/performance.md, the suspects' round of 2026-12-07c).

:func:`annotate.assistant.frame_groups` takes the page's ``fits`` (:func:`annotate.assistant.page_fits` of the log:
the config's ``explained.part_model``, else the log's ``part_model.ply``), and its groups are then
:func:`annotate.groups.review_groups`' with the same ``fits``, to the pixel. A small hand-made frame (a plane
120 × 160 with a floating block in front and a patch behind, ~1 s warm); the sessions, stores and results are
stand-ins (no log is replayed).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from annotate import assistant
from annotate.assistant import frame_groups, learned_mask, page_fits, training_set_of_log
from annotate.groups import GCOL, review_groups
from replay.logs.part_model import PART_MODEL_ATTACHMENT
from replay.pipeline.explained import NAME
from zcut.params import SuspectParams
from zcut.suspects import PATCH

A_MAX = 1000.0
FRONT = (slice(20, 25), slice(30, 35))  # a floating block 20 mm in front of the plane
BEHIND = (slice(60, 70), slice(100, 112))  # a patch 40 mm behind it
LARGE = (slice(80, 95), slice(20, 35))  # a larger block in front: a patch


def _frame(*, hole: bool = False) -> tuple[SimpleNamespace, SimpleNamespace]:
    """(frame, result) stand-ins of one replayed frame: the plane with its blocks (heights on a 1/8 mm grid)."""
    H, W = 120, 160
    rng = np.random.default_rng(31)
    r, c = np.mgrid[0:H, 0:W]
    h = np.round((100.0 + 0.05 * r + 0.02 * c + rng.normal(0.0, 0.05, (H, W))) * 8) / 8
    h[FRONT] += 20.0
    h[BEHIND] -= 40.0
    h[LARGE] += 30.0
    if hole:  # a large invalid region
        h[:, 120:] = np.nan
    valid = np.isfinite(h)
    xyz = np.stack([c * 1e-3, r * 1e-3, -h / 1000.0], axis=2)
    frame = SimpleNamespace(xyz=xyz, rgb=None, topic="/cloud", stamp_ns=1, index=0)
    result = SimpleNamespace(valid=valid, height_mm=-1000.0 * xyz[..., 2], zone=valid,
                             easy_outliers=np.zeros((H, W), bool), outliers={"zcut": np.zeros((H, W), bool)})
    return frame, result


CONFIG = SimpleNamespace(zcut=SimpleNamespace(a_max=A_MAX))


def _session(*, part_model: str = "", attachments: tuple[str, ...] = ()) -> SimpleNamespace:
    reader = SimpleNamespace(attachments=lambda: [(a, "application/octet-stream", 1) for a in attachments])
    return SimpleNamespace(config=SimpleNamespace(bank={NAME: SimpleNamespace(part_model=part_model)}),
                           reader=reader)


@pytest.mark.parametrize(("part_model", "attachments", "expected"), [
    ("", (), False),
    ("", ("bin_model.ply",), False),
    ("", (PART_MODEL_ATTACHMENT,), True),
    ("/models/zinc_nut.ply", (), True),
    ("/models/zinc_nut.ply", (PART_MODEL_ATTACHMENT,), True),
])
def test_page_fits_is_the_pages_rule(part_model: str, attachments: tuple[str, ...], expected: bool) -> None:
    assert page_fits(_session(part_model=part_model, attachments=attachments)) is expected


@pytest.mark.parametrize("hole", [False, True])
def test_frame_groups_are_the_pages_groups_with_and_without_a_part_model(hole: bool) -> None:
    frame, result = _frame(hole=hole)
    kw = {"height_mm": result.height_mm, "valid": result.valid, "zone": result.zone,
          "above_rim": result.easy_outliers, "outliers": result.outliers, "params": SuspectParams(a_max=A_MAX)}
    for fits in (False, True):
        page = review_groups(frame.xyz, None, **kw, fits=fits)
        feats, pix, starts, ids = frame_groups(frame, result, config=CONFIG, fits=fits)
        assert np.array_equal(ids, page.ids)
        assert np.array_equal(feats, page.features, equal_nan=True)
        p_pix, p_starts = page.pixels()
        assert np.array_equal(pix, p_pix) and np.array_equal(starts, p_starts)
        patch = page.sources.index("patch")
        has_patch = bool((page.table[:, GCOL["source"]] == patch).any())
        assert has_patch is (not fits)  # the patch behind the plane is a group only without a part model
        if fits:
            assert not (page.table[:, GCOL["detectors"]].astype(np.int64) & PATCH).any()
        assert ids[FRONT].min() > 0  # the floating block is a group either way


def test_training_and_learned_read_the_pages_rule(monkeypatch: pytest.MonkeyPatch) -> None:
    frame, result = _frame()
    seen: list[bool] = []
    real = assistant.frame_groups

    def spy(frame, result, *, config, fits):  # type: ignore[no-untyped-def]
        seen.append(fits)
        return real(frame, result, config=config, fits=fits)

    monkeypatch.setattr(assistant, "frame_groups", spy)

    class _Results:
        def __iter__(self):  # type: ignore[no-untyped-def]
            return iter([(frame, result)])

        def close(self) -> None:
            pass

    store = SimpleNamespace(annotators=lambda log: ["a"], frame=lambda log, topic, stamp_ns: "rec",
                            label=lambda rec, annotator: SimpleNamespace(outliers=np.zeros(result.valid.shape, bool),
                                                                         reviewed=np.ones(result.valid.shape, bool)))
    for part_model, attachments, expected in (("", (), False), ("/models/zinc_nut.ply", (), True),
                                              ("", (PART_MODEL_ATTACHMENT,), True)):
        session = _session(part_model=part_model, attachments=attachments)
        session.config.zcut = CONFIG.zcut
        session.results = _Results
        seen.clear()
        ts = training_set_of_log(session, store, "log")  # type: ignore[arg-type]
        assert seen == [expected]
        assert ts.X.shape[0] == int(real(frame, result, config=CONFIG, fits=expected)[0].shape[0])
    model = SimpleNamespace(predict=lambda feats: np.ones(feats.shape[0]))
    seen.clear()
    mask = learned_mask(model, frame, result, config=CONFIG, fits=True)  # type: ignore[arg-type]
    assert seen == [True]
    _, _, _, ids = real(frame, result, config=CONFIG, fits=True)
    assert np.array_equal(mask, ids > 0)
