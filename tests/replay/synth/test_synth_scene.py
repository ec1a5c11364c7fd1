"""replay.synth parts and scene: part geometry, bin height field, the dropped pile."""

from __future__ import annotations

import numpy as np
import pytest

from replay.synth import (
    BIN,
    LABEL_FLOOR,
    LABEL_PART,
    LABEL_RIM,
    LABEL_TABLE,
    LABEL_WALL,
    PART_KINDS,
    BinPose,
)
from replay.synth.parts import (
    _ALONG_X,
    _rot_axis,
    face_area_px,
    height_profile,
    part_solid,
    random_rest_rotation,
)
from replay.synth.scene import bin_height_field, drop_pile, make_grid

STEP = 0.2  # mm, fine enough for 1-2 % area accuracy


def _profile(name: str, R: np.ndarray, *, seed: int = 0):
    prims, hole = part_solid(name, np.random.default_rng(seed))
    r = PART_KINDS[name].bounding_radius_mm
    rel = np.arange(-r - 1, r + 1 + STEP / 2, STEP)
    lo, hi = height_profile(prims, hole, R, rel, rel)
    return rel, lo, hi


def test_part_kinds_are_the_papers_six():
    assert set(PART_KINDS) == {"spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets"}
    assert {k for k, p in PART_KINDS.items() if not p.shiny} == {"black_screws", "black_nuts"}
    for name, p in PART_KINDS.items():
        assert p.name == name
        assert 0 < p.p_min_mm <= 2 * p.bounding_radius_mm
        assert p.face_area_mm2 > 0


# largest face towards the camera: the footprint seen from above is that face
FACE_UP = {
    "spheres": np.eye(3),
    "zinc_nuts": np.eye(3),
    "black_nuts": np.eye(3),
    "sprockets": np.eye(3),
    "rods": np.eye(3),
    "black_screws": np.eye(3),
}


@pytest.mark.parametrize("name", sorted(PART_KINDS))
def test_face_area_matches_the_solid(name):
    rel, lo, hi = _profile(name, FACE_UP[name])
    area = np.isfinite(lo).sum() * STEP**2
    # screws: the hex head seen across flats or corners, depending on its random roll
    tol = 0.04 if name == "black_screws" else 0.02
    assert area == pytest.approx(PART_KINDS[name].face_area_mm2, rel=tol)


@pytest.mark.parametrize("name", sorted(PART_KINDS))
def test_p_min_is_the_smallest_bounding_box_edge(name):
    rel, lo, hi = _profile(name, np.eye(3))
    rows, cols = np.nonzero(np.isfinite(lo))
    edges = [np.ptp(rel[cols]) + STEP, np.ptp(rel[rows]) + STEP, np.nanmax(hi) - np.nanmin(lo)]
    if name in ("rods", "black_screws"):
        # the tightest box over rolls about the long (x) axis: the hex head across its flats
        prims, hole = part_solid(name, np.random.default_rng(0))
        line = np.array([-20.0, -18.0, 0.0, 18.0])  # through the head and the shaft
        for roll in np.radians(np.arange(0.0, 60.0, 0.5)):
            lo2, hi2 = height_profile(prims, hole, _rot_axis(np.array([1.0, 0, 0]), roll), line, np.zeros(1))
            edges.append(np.nanmax(hi2) - np.nanmin(lo2))
    assert min(edges) == pytest.approx(PART_KINDS[name].p_min_mm, abs=0.25)


def test_sphere_profile_is_exact():
    rel, lo, hi = _profile("spheres", np.eye(3))
    X, Y = np.meshgrid(rel, rel)
    r2 = 100.0 - X**2 - Y**2
    inside = r2 > 1e-9
    np.testing.assert_allclose(hi[inside], np.sqrt(r2[inside]), atol=1e-9)
    np.testing.assert_allclose(lo[inside], -np.sqrt(r2[inside]), atol=1e-9)
    assert np.isnan(hi[r2 < -1e-9]).all()


def test_nut_has_a_through_hole_and_its_thickness():
    rel, lo, hi = _profile("zinc_nuts", np.eye(3))
    c = len(rel) // 2
    assert np.isnan(lo[c, c])  # the bore
    ring = np.isfinite(lo)
    np.testing.assert_allclose(hi[ring] - lo[ring], 10.8, atol=1e-9)


def test_rod_axis_lies_along_x_and_tilted_parts_keep_their_volume():
    rel, lo, hi = _profile("rods", np.eye(3))
    rows, cols = np.nonzero(np.isfinite(lo))
    assert np.ptp(rel[cols]) == pytest.approx(80.0, abs=2 * STEP)
    assert np.allclose(_ALONG_X @ [0, 0, 1.0], [1, 0, 0])
    vol_flat = np.nansum(hi - lo) * STEP**2
    R = random_rest_rotation("rods", np.random.default_rng(3))
    _, lo2, hi2 = _profile("rods", R)
    vol_tilted = np.nansum(hi2 - lo2) * STEP**2
    assert vol_tilted == pytest.approx(vol_flat, rel=0.02)
    assert vol_flat == pytest.approx(np.pi * 64 * 80, rel=0.02)


def test_face_area_px_scales_with_distance():
    p = PART_KINDS["spheres"]
    a = face_area_px(p, fx=1600.0, fy=1600.0, distance_m=0.5)
    assert a == pytest.approx(np.pi * 100 / (0.5 * 0.5 / 1600**2 * 1e6))
    assert face_area_px(p, fx=1600.0, fy=1600.0, distance_m=1.0) == pytest.approx(a / 4)


def test_bin_height_field_labels_and_heights():
    grid = make_grid(half_x_mm=260, half_y_mm=200, step_mm=1.0)
    h, lab = bin_height_field(grid, BinPose())
    X, Y = np.meshgrid(grid.xs, grid.ys)
    assert (h[lab == LABEL_TABLE] == 0).all()
    assert (h[lab == LABEL_RIM] == BIN.height_mm).all()
    assert (h[lab == LABEL_FLOOR] == BIN.floor_mm).all()
    wall = lab == LABEL_WALL
    assert (h[wall] > BIN.floor_mm).all() and (h[wall] <= BIN.height_mm).all()
    assert lab[np.abs(X) > 201].max() == LABEL_TABLE  # outside the 400 mm outer length
    assert (lab[(np.abs(X) < 100) & (np.abs(Y) < 80)] == LABEL_FLOOR).all()
    # a yawed bin: the rim corner moves
    h2, lab2 = bin_height_field(grid, BinPose(yaw_rad=np.radians(10), x_mm=20.0))
    assert (lab2 != lab).any()


@pytest.mark.parametrize("name", sorted(PART_KINDS))
def test_pile_rests_without_interpenetration(name):
    grid = make_grid(half_x_mm=230, half_y_mm=180, step_mm=1.0)
    pose = BinPose(yaw_rad=np.radians(2.0), x_mm=5.0, y_mm=-4.0)
    scene = drop_pile(grid, pose, name, np.random.default_rng(11), fill_mm=25.0)
    assert len(scene.parts) > 5
    H = scene.bin_height.copy()
    floor = BIN.floor_mm
    for p in scene.parts:
        win = H[p.rows, p.cols]
        hit = np.isfinite(p.bottom)
        assert hit.any()
        assert (p.top[hit] >= p.bottom[hit] - 1e-4).all()
        gap = p.bottom[hit].astype(np.float64) - win[hit]
        assert gap.min() >= -1e-3  # never below what was there: no interpenetration
        assert gap.min() <= 1e-3  # touches its support
        assert p.bottom[hit].min() >= floor - 1e-3
        win[hit] = np.maximum(win[hit], p.top[hit])
    # the scene's height field is exactly the bin plus the stacked parts
    np.testing.assert_allclose(H, scene.height, atol=1e-3)
    assert ((scene.label == LABEL_PART) == (scene.part_id > 0)).all()
    assert (scene.height[scene.label == LABEL_PART] > floor).all()
    # parts stay inside the bin, on the floor region
    assert not (scene.label[scene.bin_height >= BIN.height_mm] == LABEL_PART).any()
