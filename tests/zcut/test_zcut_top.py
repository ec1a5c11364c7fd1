"""The z-cut with its window anchored on the pile's top (zcut/cut_top.py): the fast path equals the literal
loop over nasty inputs, the paper's z-cut is the case ``top_area <= 1``, a ghost under the rim sets the
paper's window and not the anchored one, degenerate frames, bad inputs, and the method ``zcut_top``
through a replay of a real log."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from zcut.cut_top import (
    find_clusters_top,
    pile_top_level,
    pile_top_level_reference,
    window_depth,
    zcut_top_outliers,
    zcut_top_outliers_reference,
)
from zcut.cuts import find_clusters, zcut_outliers
from zcut.errors import InputShapeError, ParameterError
from zcut.params import ZCutParams, ZCutTopParams, n_levels


def _both(h, **kw):
    fast = zcut_top_outliers(h, **kw)
    ref = zcut_top_outliers_reference(h, **kw)
    assert fast.dtype == bool and fast.shape == np.shape(h)
    np.testing.assert_array_equal(fast, ref)
    return fast


def _random_height(rng, H, W, *, nan_share=0.0, quantum=None):
    h = rng.normal(size=(H, W)).cumsum(axis=0) * 2 + rng.normal(size=(H, W))
    if quantum:  # values exactly on the cuts' thresholds
        h = np.round(h / quantum) * quantum
    h[rng.random((H, W)) < nan_share] = np.nan
    return h


@pytest.mark.parametrize("seed", range(40))
def test_fast_equals_the_literal_loop_on_random_images(seed):
    rng = np.random.default_rng(seed)
    H, W = (int(x) for x in rng.integers(1, 24, 2))
    step = float(rng.choice([0.1, 0.2, 0.25, 0.5, 1.0]))
    h = _random_height(rng, H, W, nan_share=float(rng.choice([0.0, 0.1, 0.5])),
                       quantum=step * float(rng.choice([0.5, 1.0])) if seed % 2 else None)
    if seed % 3 == 0:
        h = h.astype(np.float32)
    for connectivity in (4, 8):
        for top_area in (1.0, 2.0, 7.5, float(rng.integers(1, H * W + 2)), 1e9):
            kw = dict(step=step, top_area=top_area, connectivity=connectivity)
            assert pile_top_level(h, **kw) == pile_top_level_reference(h, **kw)
            _both(h, step=step, max_depth=float(rng.choice([0.0, step, 2.0, 5.0])), max_area=float(rng.integers(1, 12)),
                  top_area=top_area, connectivity=connectivity)


def _levels_oracle(h, step, top_area, connectivity):
    """k_top from the cuts at the pixels' own levels only (the cuts change nowhere else): each pixel's
    level found by bisection with the exact test ``z~ >= z_max - k * step``."""
    from scipy import ndimage

    valid = np.isfinite(h)
    if not valid.any() or h.size < top_area:
        return 0
    z_min, z_max = float(h[valid].min()), float(h[valid].max())
    zt = np.where(valid, h, z_min)

    def level(v):
        lo, hi = 0, 1
        while not v >= z_max - hi * step:
            hi *= 2
        while lo < hi:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if v >= z_max - mid * step else (mid + 1, hi)
        return lo

    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)
    for k in sorted({level(float(v)) for v in zt.ravel()}):
        lab, n = ndimage.label(zt >= z_max - k * step, structure=structure)
        if n and np.bincount(lab.ravel())[1:].max() >= top_area:
            return k
    return 0


@pytest.mark.parametrize("seed", range(6))
def test_a_tiny_step_many_levels_apart(seed):
    """Levels too many to count (the kernel's rounds grow past a counting sort and sort instead)."""
    rng = np.random.default_rng(200 + seed)
    h = rng.normal(size=(7, 9)) * 50
    h[rng.random(h.shape) < 0.2] = np.nan
    for step in (1e-4, 1e-9):
        for top_area in (2.0, 5.0, 30.0):
            assert pile_top_level(h, step=step, top_area=top_area) == _levels_oracle(h, step, top_area, 8)
    assert pile_top_level(h, step=0.5, top_area=5.0) == pile_top_level_reference(h, step=0.5, top_area=5.0) \
        == _levels_oracle(h, 0.5, 5.0, 8)


@pytest.mark.parametrize("kind", ["all_nan", "empty", "one_pixel", "flat", "row", "column", "inf", "two_levels"])
def test_nasty_inputs(kind):
    h = {
        "all_nan": np.full((5, 6), np.nan),
        "empty": np.zeros((0, 0)),
        "one_pixel": np.array([[3.0]]),
        "flat": np.full((7, 9), 2.5),
        "row": np.array([[0.0, 5.0, 0.0, 5.2, 0.0, 0.0, 9.0]]),
        "column": np.array([[0.0], [5.0], [0.0], [5.2], [np.nan], [9.0]]),
        "inf": np.array([[np.inf, 1.0, 1.0], [-np.inf, 1.0, 4.0], [1.0, 1.0, 1.0]]),
        "two_levels": np.where(np.arange(40).reshape(5, 8) % 7 == 0, 10.0, 0.0),
    }[kind]
    for top_area in (1.0, 3.0, 1e6):
        out = _both(h, step=0.2, max_depth=3.0, max_area=4.0, top_area=top_area)
        assert not (out & ~np.isfinite(h)).any()
    if kind in ("all_nan", "empty", "one_pixel", "flat"):
        assert pile_top_level(h, step=0.2, top_area=3.0) == 0  # no part-sized top: the paper's window
        res = find_clusters_top(h, params=ZCutParams(step=0.2, max_depth=3.0, max_area=4.0), top_area=3.0)
        assert res.k_top == 0
        np.testing.assert_array_equal(res.outliers, zcut_outliers(h, step=0.2, max_depth=3.0, max_area=4.0))
        assert res.outliers.any() == (kind == "one_pixel")  # a lone pixel floats, as the paper's z-cut says
        if kind in ("all_nan", "empty"):
            assert np.isnan(res.z_top) and np.isnan(res.floor)


@settings(max_examples=60, deadline=None)
@given(h=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
                    elements=st.one_of(st.floats(-5, 5, allow_nan=False), st.just(np.nan),
                                       st.sampled_from([0.0, 0.2, 0.4, 1.0]))),
       top_area=st.floats(0.5, 60), max_area=st.floats(0.5, 20), connectivity=st.sampled_from([4, 8]))
def test_fast_equals_reference_and_stays_in_the_valid_pixels(h, top_area, max_area, connectivity):
    out = _both(h, step=0.2, max_depth=1.0, max_area=max_area, top_area=top_area, connectivity=connectivity)
    assert not (out & ~np.isfinite(h)).any()


@pytest.mark.parametrize("seed", range(8))
def test_a_top_area_of_one_pixel_is_the_papers_zcut_bit_for_bit(seed):
    rng = np.random.default_rng(100 + seed)
    h = _random_height(rng, 40, 50, nan_share=0.2)
    for top_area in (0.5, 1.0):
        assert pile_top_level(h, step=0.2, top_area=top_area) == 0
        np.testing.assert_array_equal(
            zcut_top_outliers(h, step=0.2, max_depth=3.0, max_area=9.0, top_area=top_area),
            zcut_outliers(h, step=0.2, max_depth=3.0, max_area=9.0))
    # and no cut holding a component that large: the paper's window too
    np.testing.assert_array_equal(zcut_top_outliers(h, step=0.2, max_depth=3.0, max_area=9.0, top_area=1e7),
                                  zcut_outliers(h, step=0.2, max_depth=3.0, max_area=9.0))


def test_the_window_checks_exactly_k_top_plus_K_levels():
    for step in (0.1, 0.2, 0.3, 1e-3, 7.0):
        for n in (0, 1, 5, 149, 150, 151, 1000, 123457):
            assert n_levels(step, window_depth(step, n)) == n


def _ghost_scene():
    """Heights (mm) of a pile under a tall ghost: floor 0, parts of 10 × 10 px at 20–40 mm (the top part
    at 40 mm), a cluster of 2 × 2 px floating 5 mm above the 25 mm part, and a ghost of 3 × 2 px at
    110 mm at the image's edge (under the rim), 70 mm above the pile's top."""
    h = np.zeros((60, 80))
    for (r, c), z in {(5, 5): 20.0, (5, 30): 25.0, (30, 10): 32.0, (30, 40): 40.0, (40, 60): 28.0}.items():
        h[r:r + 10, c:c + 10] = z
    h[9:11, 34:36] = 30.0  # floating above the 25 mm part
    h[0:3, 77:79] = 110.0  # the ghost
    h[50:52, 0:3] = np.nan
    return h


def test_a_ghost_under_the_rim_sets_the_papers_window_not_the_anchored_one():
    h = _ghost_scene()
    ghost, floating = h >= 100, h == 30.0
    params = ZCutParams(step=0.5, max_depth=30.0, max_area=7.0, a_max=100.0)
    paper = find_clusters(h, params=params)
    assert paper.z_max == 110.0
    assert paper.outliers[ghost].all() and not paper.outliers[floating].any()  # the window holds only the ghost
    assert not (paper.outliers & ~ghost).any()
    top = find_clusters_top(h, params=params, top_area=params.a_max)
    assert top.k_top == 140 and top.z_top == 40.0 and top.floor == 10.0  # on the top part, d_max below it
    # the ghost above the pile's top is cut as the paper cuts it, and the pile's floating cluster is found
    assert top.outliers[ghost].all() and top.outliers[floating].all()
    assert not (top.outliers & ~(ghost | floating)).any()
    np.testing.assert_array_equal(top.outliers, _both(h, step=0.5, max_depth=30.0, max_area=7.0, top_area=100.0))
    assert top.cut.n_levels == 140 + params.n_levels
    # a ghost as large as a part is a top the variant cannot tell from the pile's (the documented limit)
    big = h.copy()
    big[0:10, 70:80] = 110.0
    assert pile_top_level(big, step=0.5, top_area=100.0) == 0


def test_shifting_every_height_by_a_step_multiple_changes_nothing():
    h = _ghost_scene()
    kw = dict(step=0.5, max_depth=30.0, max_area=7.0, top_area=100.0)
    np.testing.assert_array_equal(zcut_top_outliers(h, **kw), zcut_top_outliers(h + 64.0, **kw))


@pytest.mark.parametrize("kw, match", [
    (dict(top_area=0.0), r"top_area must be a number > 0 \(pixels\), got 0.0"),
    (dict(top_area=-3), r"top_area must be a number > 0"),
    (dict(top_area=float("nan")), r"top_area must be a number > 0"),
    (dict(top_area="100"), r"top_area must be a real number, got '100'"),
    (dict(top_area=True), r"top_area must be a real number, got True"),
    (dict(step=0.0), r"step must be a finite number > 0, got 0.0"),
    (dict(max_depth=-1.0), r"max_depth must be a finite number >= 0, got -1.0"),
    (dict(connectivity=6), r"connectivity must be 4 or 8, got 6"),
])
def test_bad_parameters_are_one_line_errors(kw, match):
    args = dict(step=0.2, max_depth=3.0, max_area=5.0, top_area=10.0) | kw
    for fn in (zcut_top_outliers, zcut_top_outliers_reference):
        with pytest.raises(ParameterError, match=match):
            fn(np.zeros((3, 3)), **args)


@pytest.mark.parametrize("h, match", [
    (np.zeros(5), r"height must be an \(H, W\) real float array, got shape \(5,\) float64"),
    (np.zeros((3, 3), np.int32), r"height must be an \(H, W\) real float array"),
])
def test_bad_heights(h, match):
    for fn in (pile_top_level, pile_top_level_reference):
        with pytest.raises(InputShapeError, match=match):
            fn(h, step=0.2, top_area=3.0)


@pytest.mark.parametrize("value, match", [
    (0, r"ZCutTopParams.top_faces must be a number > 0, got 0"),
    (float("inf"), r"ZCutTopParams.top_faces must be a number > 0, got inf"),
    ("1", r"ZCutTopParams.top_faces must be a number > 0, got '1'"),
])
def test_bad_top_faces(value, match):
    with pytest.raises(ParameterError, match=match):
        ZCutTopParams(top_faces=value)
    with pytest.raises(ParameterError, match="params must be a ZCutParams"):
        find_clusters_top(np.zeros((2, 2)), params=ZCutTopParams(), top_area=3.0)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------- the method
@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    from cli_helpers import synth_with_bin_model

    d = tmp_path_factory.mktemp("zcut_top")
    return synth_with_bin_model(d, parts="spheres", seed=29, size="150x200", names=("s.mcap", "e.mcap"))


def test_the_method_through_a_replay_of_a_real_log(logs):
    from replay.logs import layout
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.methods import registry
    from replay.pipeline.session import ReplaySession

    log, _, model = logs
    assert registry()["zcut_top"].params is ZCutTopParams and "zcut_top" in cfg.section_names()
    session = ReplaySession.open(log, overrides=cfg.cli_layer(methods="zcut,zcut_top"), bin_model=load_bin_model(model))
    config = session.config
    assert config.zcut_top == ZCutTopParams() and config.zcut.a_max is not None
    zones = session.zones(frames=(0, 2))
    seen = 0
    try:
        for (frame, zone), (_, r) in zip(zones, session.results(frames=(0, 2))):
            top = find_clusters_top(zone.height_mm, params=config.zcut, top_area=config.zcut.a_max)
            np.testing.assert_array_equal(r.outliers["zcut_top"], (top.outliers & zone.zone) | zone.easy)
            paper = find_clusters(zone.height_mm, params=config.zcut)
            assert top.z_top <= paper.z_max and top.cut.n_levels == top.k_top + config.zcut.n_levels
            assert layout.TRUTH_OUTLIERS in frame.masks
            seen += 1
    finally:
        zones.close()
    assert seen == 2
    # top_faces small enough that the highest point is a part's footprint: the paper's z-cut
    tiny = config.replace(zcut_top=ZCutTopParams(top_faces=0.5 / config.zcut.a_max))
    for _, r in session.results(frames=(0, 1), config=tiny):
        np.testing.assert_array_equal(r.outliers["zcut_top"], r.outliers["zcut"])
