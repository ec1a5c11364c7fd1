"""The edge-aware surface model (``zcut.edge_surface``) and the suspects' gaps it gives the labelling page."""

from __future__ import annotations

import numpy as np
import pytest

from zcut import InputShapeError, ParameterError, SuspectParams, suspects
from zcut.edge_surface import (
    EdgeSurfaceParams,
    edge_aware_distance,
    signed_edge_distance,
    signed_edge_distance_reference,
)

F = 600.0  # focal length (px) of the test camera


def cloud(z_mm: np.ndarray) -> np.ndarray:
    """The organized cloud (mm, camera frame) whose pixels see depths ``z_mm`` through a pinhole."""
    H, W = z_mm.shape
    v, u = np.mgrid[0:H, 0:W]
    return np.stack([(u - W / 2) * z_mm / F, (v - H / 2) * z_mm / F, z_mm], axis=2)


def step_scene(rng: np.random.Generator, H: int = 40, W: int = 60, noise: float = 0.05):
    """A floor 550 mm away and, on its left half, a part's flat top 20 mm nearer; noise in z."""
    z = np.full((H, W), 550.0) + rng.normal(0.0, noise, (H, W))
    z[:, : W // 2] -= 20.0
    return z


def random_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    H, W = (int(v) for v in rng.integers(3, 30, 2))
    z = 500.0 + rng.normal(0, 0.1, (H, W)) + rng.choice([0.0, 5.0, -12.0], size=(H, W), p=[0.8, 0.1, 0.1]).cumsum(
        axis=1) * (rng.random() < 0.5)
    v, u = np.mgrid[0:H, 0:W]
    z = z + rng.normal(0, 0.5) * u + rng.normal(0, 0.5) * v
    xyz = cloud(z)
    holes = rng.random((H, W)) < rng.choice([0.0, 0.1, 0.5])
    xyz[holes] = np.nan
    return xyz, ~holes


@pytest.mark.parametrize("seed", range(12))
def test_kernels_equal_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xyz, valid = random_scene(rng)
    params = EdgeSurfaceParams(search_radius_px=int(rng.integers(2, 4)), max_search_radius_px=8,
                               max_incidence_deg=float(rng.choice([80.0, 90.0])))
    fast = signed_edge_distance(xyz, valid, params=params)
    ref = signed_edge_distance_reference(xyz, valid, params=params)
    assert np.array_equal(np.isnan(fast), ~valid) and np.array_equal(np.isnan(ref), ~valid)
    assert np.array_equal(np.isinf(fast), np.isinf(ref))
    finite = np.isfinite(ref)
    np.testing.assert_allclose(fast[finite], ref[finite], atol=1e-7)


@pytest.mark.parametrize("case", ["empty", "one row", "one column", "all invalid", "one valid", "float32"])
def test_nasty_inputs(case: str) -> None:
    rng = np.random.default_rng(1)
    shapes = {"empty": (0, 0), "one row": (1, 25), "one column": (25, 1)}
    z = 500.0 + rng.normal(0, 0.1, shapes.get(case, (9, 11)))
    xyz = cloud(z)
    valid = np.ones(z.shape, bool)
    if case == "all invalid":
        valid[:] = False
        xyz[:] = np.nan
    if case == "one valid":
        valid[:] = False
        valid[4, 5] = True
        xyz[~valid] = np.nan
    if case == "float32":
        xyz = xyz.astype(np.float32)
    d = edge_aware_distance(xyz, valid)
    assert d.shape == z.shape and d.dtype == np.float64
    assert np.isnan(d[~valid]).all()
    if case in ("one row", "one column", "one valid"):  # no plane fits a line or a point: no surface
        assert np.isinf(d[valid]).all()
    if case == "float32":
        np.testing.assert_allclose(d, edge_aware_distance(xyz.astype(np.float64), valid), atol=1e-3)


def test_a_part_edge_lies_on_its_own_surface() -> None:
    """The last pixels of a part's top and the first of the floor are explained by their own side's
    planes; a window continued across the edge (its median) puts them 10 mm off."""
    rng = np.random.default_rng(2)
    z = step_scene(rng)
    d = edge_aware_distance(cloud(z), np.ones(z.shape, bool))
    edge = d[:, 28:32]
    assert np.nanmax(edge) < 0.3  # 6 σ of the noise
    median_across = np.abs(z[:, 29] - np.median(z[:, 28:33], axis=1))  # a window continued across the edge
    assert np.median(median_across) > 10.0


def test_flying_pixels_and_spikes_are_off_every_side() -> None:
    rng = np.random.default_rng(3)
    z = step_scene(rng)
    z[5:35:3, 30] = 540.0  # mixed pixels halfway between the part's top (530) and the floor (550)
    z[20, 10] -= 3.0  # a spike 3 mm toward the camera on the part's top
    z[20, 45] += 2.0  # a spike 2 mm away from the camera on the floor
    d = signed_edge_distance(cloud(z), np.ones(z.shape, bool))
    assert np.all(np.abs(d[5:35:3, 30]) > 8.0)
    # positive: toward the camera; a little less than planted, the nearest of ~40 noisy planes
    assert d[20, 10] == pytest.approx(3.0, abs=0.3)
    assert d[20, 45] == pytest.approx(-2.0, abs=0.3)
    others = np.ones(z.shape, bool)
    others[5:35:3, 28:33] = False
    others[20, 10] = others[20, 45] = False
    assert np.abs(d[others]).max() < 0.5


def test_the_pixel_is_left_out_of_the_planes_that_judge_it() -> None:
    """A spike in the middle of a plane is judged by patches that do not hold it: its full height."""
    z = np.full((15, 15), 500.0)
    z[7, 7] = 495.0
    d = signed_edge_distance(cloud(z), np.ones(z.shape, bool))
    assert d[7, 7] == pytest.approx(5.0, abs=1e-6)


def test_the_search_radius_grows_until_a_surface_is_found() -> None:
    """A pixel alone in a hole 11 px wide: the planes 6 px away still judge it."""
    rng = np.random.default_rng(4)
    z = np.full((31, 31), 500.0) + rng.normal(0, 0.01, (31, 31))
    valid = np.ones(z.shape, bool)
    valid[10:21, 10:21] = False
    valid[15, 15] = True
    xyz = cloud(z)
    xyz[~valid] = np.nan
    near = EdgeSurfaceParams(search_radius_px=3, max_search_radius_px=3)
    far = EdgeSurfaceParams(search_radius_px=3, max_search_radius_px=12)
    assert np.isinf(edge_aware_distance(xyz, valid, params=near)[15, 15])
    assert edge_aware_distance(xyz, valid, params=far)[15, 15] < 0.1


def test_a_grazing_ramp_is_no_surface() -> None:
    """Mixed pixels that fall on a steep ramp between two surfaces fit a plane of their own; seen
    nearly edge-on it is not a surface."""
    z = np.full((20, 30), 550.0)
    z[:, :15] = 530.0
    z[:, 15] = 540.0  # one column of mixed pixels, at the same depth on every row
    valid = np.ones(z.shape, bool)
    d = edge_aware_distance(cloud(z), valid)
    assert np.all(d[3:17, 15] > 8.0)


@pytest.mark.parametrize("seed", range(3))
def test_the_gate_follows_the_frames_noise(seed: int) -> None:
    """At a Kinect-like noise (10 × the step scene's) the edge's pixels stay on their sides and a
    spike of 12 σ stands out (the nearest of many noisy planes reads it at about half its height)."""
    rng = np.random.default_rng(5 + seed)
    z = step_scene(rng, noise=0.5)
    z[20, 10] -= 6.0
    d = edge_aware_distance(cloud(z), np.ones(z.shape, bool))
    others = np.ones(z.shape, bool)
    others[20, 10] = False
    assert d[20, 10] > 2.0 * d[others].max()
    assert np.median(d[:, 28:32]) < 0.2


def test_the_gate_grows_with_the_square_of_the_depth() -> None:
    """A wall 2.8 × as far as the table, with 8 × its noise (a depth sensor's noise grows as z²):
    the wall's patches are surfaces too, not 'off the surface' for being rougher than the table."""
    rng = np.random.default_rng(8)
    z = np.full((60, 60), 500.0) + rng.normal(0, 0.1, (60, 60))
    z[:20] = 1400.0 + rng.normal(0, 0.8, (20, 60))
    d = edge_aware_distance(cloud(z), np.ones(z.shape, bool))
    assert np.isfinite(d).all()
    assert np.percentile(d[2:18], 99) < 2.0 and np.percentile(d[22:], 99) < 0.3


BAD_PARAMS = [
    ({"patch_radius_px": 0}, "EdgeSurfaceParams.patch_radius_px"),
    ({"patch_radius_px": 1.5}, "EdgeSurfaceParams.patch_radius_px"),
    ({"min_patch_px": 2}, "EdgeSurfaceParams.min_patch_px"),
    ({"min_patch_px": 10}, "EdgeSurfaceParams.min_patch_px"),
    ({"search_radius_px": 1}, "EdgeSurfaceParams.search_radius_px"),
    ({"max_search_radius_px": 2}, "EdgeSurfaceParams.max_search_radius_px"),
    ({"fit_k": 0.0}, "EdgeSurfaceParams.fit_k"),
    ({"fit_k": float("nan")}, "EdgeSurfaceParams.fit_k"),
    ({"min_fit_mm": -1.0}, "EdgeSurfaceParams.min_fit_mm"),
    ({"max_incidence_deg": 0.0}, "EdgeSurfaceParams.max_incidence_deg"),
    ({"max_incidence_deg": 91.0}, "EdgeSurfaceParams.max_incidence_deg"),
    ({"side_step_mm": -0.5}, "EdgeSurfaceParams.side_step_mm"),
    ({"search_radius_px": True}, "EdgeSurfaceParams.search_radius_px"),
    ({"fit_k": "3"}, "EdgeSurfaceParams.fit_k"),
]


@pytest.mark.parametrize(("changes", "match"), BAD_PARAMS)
def test_bad_params(changes: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        EdgeSurfaceParams(**changes)


def test_params_are_frozen_and_typed() -> None:
    p = EdgeSurfaceParams(patch_radius_px=2.0, min_patch_px=15.0, search_radius_px=4, fit_k=3)
    assert isinstance(p.patch_radius_px, int) and isinstance(p.fit_k, float)
    with pytest.raises(AttributeError):
        p.fit_k = 4.0  # type: ignore[misc]


def test_bad_inputs() -> None:
    xyz = cloud(np.full((5, 6), 500.0))
    valid = np.ones((5, 6), bool)
    with pytest.raises(InputShapeError, match="xyz_mm"):
        edge_aware_distance(xyz[..., :2], valid)
    with pytest.raises(InputShapeError, match="valid"):
        edge_aware_distance(xyz, valid[:, :5])
    with pytest.raises(InputShapeError, match="valid"):
        edge_aware_distance(xyz, valid.astype(np.uint8))
    nan = xyz.copy()
    nan[2, 2, 1] = np.nan
    with pytest.raises(InputShapeError, match="finite"):
        edge_aware_distance(nan, valid)
    with pytest.raises(ParameterError, match="EdgeSurfaceParams"):
        edge_aware_distance(xyz, valid, params=SuspectParams())  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------- the suspects' gaps

def part_on_floor(rng: np.random.Generator):
    """A floor 550 mm away (metres, camera frame) with a part 12 mm high on it whose top is a ring
    2 px wide (a nut seen from above), mixed pixels along its right side and one spike."""
    H, W = 60, 80
    z = np.full((H, W), 550.0) + rng.normal(0, 0.03, (H, W))
    top = np.zeros((H, W), bool)
    top[15:45, 20:50] = True
    top[17:43, 22:48] = False  # the bore: the floor shows through
    z[top] -= 12.0
    truth = np.zeros((H, W), bool)
    z[18:42:2, 50] = 544.0
    truth[18:42:2, 50] = True
    z[50, 10] -= 4.0
    truth[50, 10] = True
    xyz = cloud(z) / 1000.0
    return xyz, -z, top, truth


@pytest.mark.parametrize("a_max", [200.0, 2000.0])
def test_the_suspects_gap_is_the_edge_aware_distance(a_max: float) -> None:
    """With ``edge_surface`` the residual detectors' suspects (here the mixed pixels) take the
    edge-aware gap; the suspects, their detectors and a floating component's gap (its height over
    the points around it: a flat component 4 px wide would be a surface of its own) do not change.
    With a_max = 2000 the ring floats (a component of 224 px), with 200 it does not."""
    rng = np.random.default_rng(6)
    xyz, height, top, truth = part_on_floor(rng)
    zone = np.ones(height.shape, bool)
    params = SuspectParams(a_max=a_max)
    old = suspects(xyz, height, zone, params=params)
    new = suspects(xyz, height, zone, params=params, edge_surface=EdgeSurfaceParams())
    assert old.surface_mm is None
    assert np.array_equal(old.mask, new.mask) and np.array_equal(old.detectors, new.detectors)
    expected = signed_edge_distance(np.asarray(xyz, np.float64) * 1000.0, np.isfinite(xyz).all(axis=2))
    np.testing.assert_array_equal(new.surface_mm, expected)
    floating = new.detector_mask("floating")
    np.testing.assert_array_equal(new.gap_mm[floating], old.gap_mm[floating])
    assert (floating & top).any() == (a_max == 2000.0)
    mixed = new.detector_mask("mixed") & ~floating
    assert mixed.any() == (a_max == 200.0)
    np.testing.assert_array_equal(new.gap_mm[mixed], expected[mixed])
    assert np.all(np.abs(new.gap_mm[truth]) > 3.0)  # the planted outliers stay off the surface
    assert new.group(int(new.groups[50, 10])).gap_mm == pytest.approx(4.0, abs=0.3)


def test_bad_edge_surface_argument() -> None:
    rng = np.random.default_rng(7)
    xyz, height, _, _ = part_on_floor(rng)
    with pytest.raises(ParameterError, match="edge_surface"):
        suspects(xyz, height, np.ones(height.shape, bool), params=SuspectParams(),
                 edge_surface=SuspectParams())  # type: ignore[arg-type]
