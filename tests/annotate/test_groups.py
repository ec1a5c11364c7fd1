"""Review groups (annotate.groups): what the page lists, one decision per group, and their features."""

from __future__ import annotations

import numpy as np
import pytest
from annotate_helpers import pipeline_result, spike_frame

from annotate.budget import METHOD_GROUPS_MAX, class_budgets, review_budget
from annotate.groups import FEATURES, GCOL, GROUP_COLUMNS, group_targets, review_groups
from annotate.payload import parse_bundle, prepare_frame
from replay.logs import layout
from replay.logs.frame import Frame
from zcut.params import SuspectParams
from zcut.suspects import DETECTORS


def _groups(frame, result, **kw):
    valid = np.asarray(result.valid, bool)
    return review_groups(frame.xyz, frame.rgb, height_mm=result.height_mm, valid=valid, zone=result.zone & valid,
                         above_rim=result.easy_outliers & valid, outliers=dict(result.outliers),
                         params=SuspectParams(**kw))


def test_groups_hold_the_spikes_and_say_why():
    frame, truth = spike_frame(0, shape=(120, 160), seed=3)
    g = _groups(frame, pipeline_result(frame), a_max=400.0)  # a part face of 400 px: spikes of 9-36 px float
    assert 1 <= g.n <= review_budget(SuspectParams(), len(g.methods))
    assert g.table.shape == (g.n, len(GROUP_COLUMNS)) and g.features.shape == (g.n, len(FEATURES))
    assert set(np.unique(g.ids)) == set(range(g.n + 1))
    # every true spike pixel is in a group, and the groups that hold them float well above the floor
    assert (g.ids[truth] > 0).all()
    held = np.unique(g.ids[truth])
    assert (g.table[held - 1, GCOL["gap_mm"]] > 40).all()
    # why: the source names a detector or a method, the sizes and boxes match the id image
    for row in g.table:
        gid = int(row[GCOL["id"]])
        assert g.sources[int(row[GCOL["source"]])] in (*DETECTORS, *g.methods)
        rr, cc = np.nonzero(g.ids == gid)
        assert row[GCOL["n"]] == rr.size
        assert (row[GCOL["x0"]], row[GCOL["y0"]], row[GCOL["x1"]], row[GCOL["y1"]]) == \
            (cc.min(), rr.min(), cc.max() + 1, rr.max() + 1)
    # the rise of a spike's pixels is its height above the floor (the wand grows over it)
    assert np.median(g.rise_mm[truth]) > 40


def test_a_frame_without_suspects_has_no_group():
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    z = np.full((h, w), 1.0)
    xyz = np.stack([(xx - w / 2) * z / 64, (yy - h / 2) * z / 64, z], axis=2).astype(np.float32)
    frame = Frame(xyz=xyz, rgb=None, stamp_ns=1, frame_id="cam", intrinsics=None, topic=layout.CLOUD, index=0,
                  masks={})
    res = pipeline_result(frame)
    g = _groups(frame, res)
    # no suspect: only what a filter flags is listed (SOR flags the plane's corners), by the filter's name
    assert g.n_suspect_px == 0
    assert all(g.sources[int(s)] in g.methods for s in g.table[:, GCOL["source"]])
    valid = np.asarray(res.valid, bool)
    none = review_groups(frame.xyz, None, height_mm=res.height_mm, valid=valid, zone=res.zone, above_rim=res.easy_outliers,
                         outliers={}, params=SuspectParams())
    assert none.n == 0 and none.table.shape == (0, len(GROUP_COLUMNS)) and not none.ids.any()
    assert none.pixels()[1].tolist() == [0]
    pf = prepare_frame(frame, res)
    header, arrays = parse_bundle(pf.served.bundle)
    assert header["n_groups"] == pf.served.n_groups == g.n and header["n_suspect_px"] == 0
    assert pf.served.decisions(np.zeros((h, w), bool), np.ones((h, w), bool)) == (g.n, 0)


def test_100000_suspect_pixels_stay_in_at_most_about_40_groups():
    """A 1920 x 1200 frame with over 100,000 suspect pixels: one-pixel spikes 10-50 mm above the floor on a
    4 px grid (144,000 of them). Spikes, not blobs: a dense grid of blobs at one height is a surface of its
    own to the suspects' noise per local height (docs/filters.md, "Suspects")."""
    rng = np.random.default_rng(11)
    h, w = 1200, 1920
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.0 + 0.00005 * rng.standard_normal((h, w))
    spike = ((yy % 4) == 1) & ((xx % 4) == 1)
    z[spike] -= rng.uniform(0.01, 0.05, int(spike.sum()))
    xyz = np.stack([(xx - w / 2) * z / 1500, (yy - h / 2) * z / 1500, z], axis=2).astype(np.float32)
    frame = Frame(xyz=xyz, rgb=None, stamp_ns=1, frame_id="cam", intrinsics=None, topic=layout.CLOUD, index=0,
                  masks={})
    res = pipeline_result(frame)
    g = _groups(frame, res)
    assert g.n_suspect_px >= 100_000
    assert g.n <= review_budget(SuspectParams(), len(g.methods))
    assert np.isfinite(g.features[:, FEATURES.index("log_size")]).all()


def test_group_targets_count_a_group_decided_at_half_its_pixels():
    ids = np.array([[1, 1, 0, 2], [1, 1, 0, 2]])
    flat = ids.ravel()
    pix = np.concatenate([np.flatnonzero(flat == 1), np.flatnonzero(flat == 2)])
    starts = np.array([0, 4, 6])
    L = np.zeros(ids.shape, bool)
    R = np.zeros(ids.shape, bool)
    L[0, :2] = R[0, :2] = True  # group 1: half of it reviewed, all of that outliers
    R[0, 3] = True  # group 2: half reviewed, not outliers
    decided, share = group_targets(pix, starts, L, R)
    assert decided.tolist() == [True, True] and share.tolist() == [0.5, 0.0]
    decided, _ = group_targets(pix, starts, np.zeros_like(L), np.zeros_like(R))
    assert decided.tolist() == [False, False]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_features_of_a_frame_with_invalid_regions_are_numbers_or_nan(bad):
    frame, _ = spike_frame(1, shape=(120, 160), seed=5)
    xyz = frame.xyz.copy()
    xyz[:, :40] = bad  # a quarter of the frame unmeasured
    fr = Frame(xyz=xyz, rgb=frame.rgb, stamp_ns=frame.stamp_ns, frame_id="cam", intrinsics=frame.intrinsics,
               topic=frame.topic, index=1, masks=frame.masks)
    g = _groups(fr, pipeline_result(fr))
    assert g.n >= 1 and not np.isinf(g.features).any()
    assert (g.ids[:, :40] == 0).all()


def test_a_methods_groups_are_shared_among_its_strength_classes():
    """The pixels a filter flags that no suspect holds are grouped per strength class (one group each, the
    rest of METHOD_GROUPS_MAX in turn, largest class first), so its few pixels far off the surface are
    not decided with its thousands at the noise's edge."""
    cls = np.full((10, 10), -1, np.int8)
    cls[0, :] = 0          # 10 px at the noise's edge
    cls[1, :3] = 2         # 3 px far off the surface
    assert class_budgets(cls, 4) == [(0, 2), (2, 2)]  # the rest in turn, the class with most pixels first
    cls[2, :5] = 1
    assert class_budgets(cls, 4) == [(0, 2), (1, 1), (2, 1)]
    assert class_budgets(cls, 2) == [(0, 1), (1, 1), (2, 1)]  # every class present keeps one group
    assert class_budgets(np.full((3, 3), -1, np.int8), 4) == []


def test_the_page_budget_is_the_suspects_share_and_each_methods():
    """A frame lists at most max_groups suspect groups and METHOD_GROUPS_MAX groups per filter method."""
    assert review_budget(SuspectParams(), 0) == 40
    assert review_budget(SuspectParams(max_groups=7), 3) == 7 + 3 * METHOD_GROUPS_MAX == 19
