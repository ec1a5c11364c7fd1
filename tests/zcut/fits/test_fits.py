"""zcut.fits: instances of a known part found in clean ray-cast clouds of posed meshes."""

from __future__ import annotations

import numpy as np
import pytest
from fit_scenes import K_TEST, SIZE, hex_nut_mesh, icosphere, pose, render, rotation
from prepared_models import prepared

from zcut.errors import InputShapeError, ParameterError
from zcut.fits import FitParams, PartFit, fit_parts, pose_error, prepare_model


def _match(fits: list[PartFit], truths: list[np.ndarray], model) -> list[tuple[float, float]]:  # type: ignore[no-untyped-def]
    """For each true pose the (mm, deg) error of the nearest fit."""
    out = []
    for T in truths:
        errs = [pose_error(f.pose, T, model) for f in fits]
        out.append(min(errs, key=lambda e: e[0]))
    return out


def test_two_nuts_recovered_exactly_from_a_clean_ray_cast_cloud():
    v, t = hex_nut_mesh()
    truths = [pose(rotation((1, 0.3, 0), 160), (5, -3, 300)), pose(rotation((0.2, 1, 0), 30), (-25, 10, 310))]
    xyz, ids = render([(v, t, T) for T in truths], floor_z_mm=320)
    fits = fit_parts(xyz, ids > 0, v, t, intrinsics=K_TEST)
    assert len(fits) == 2
    model = prepared(v, t)
    for dt, da in _match(fits, truths, model):
        assert dt < 0.02 and da < 0.1
    for f in fits:
        assert f.pose.shape == (4, 4) and f.pose.dtype == np.float64
        assert f.err_mm < 0.01 and f.support > 0.95
        assert f.pixels.dtype == np.int64 and np.all(np.diff(f.pixels) > 0)
    explained = np.zeros(ids.size, bool)
    for f in fits:
        explained[f.pixels] = True
    assert explained[(ids > 0).reshape(-1)].mean() > 0.99
    assert not explained[(ids == 0).reshape(-1)].any()  # the zone is the nuts: the floor is not in it


def test_the_nut_is_found_with_its_symmetries_and_upside_down():
    """A hex nut maps onto itself by 60° turns about its axis and half-turns about its flats: the
    model finds that group, and a nut turned upside down is fitted up to it."""
    v, t = hex_nut_mesh()
    model = prepared(v, t)
    assert len(model.symmetries) == 12 and model.continuous_axis is None
    T = pose(rotation((1, 0, 0), 180) @ rotation((0, 0, 1), 17), (2, 4, 280))
    xyz, ids = render([(v, t, T)], floor_z_mm=290)
    fits = fit_parts(xyz, ids > 0, v, t, intrinsics=K_TEST)
    assert len(fits) == 1
    dt, da = pose_error(fits[0].pose, T, model)
    # seen head-on, only its silhouette holds the nut's slide and turn in its plane: pixel-limited
    # (a pixel is 0.56 mm here)
    assert dt < 0.1 and da < 0.5


def _sphere_cloud(centres: list[tuple[float, float, float]], radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The exact first hits of every pixel's ray on the spheres (closed form, no mesh)."""
    H, W = SIZE
    fx, fy, cx, cy = K_TEST
    rr, cc = np.mgrid[0:H, 0:W]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones((H, W))], axis=-1)
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    best = np.full((H, W), np.inf)
    ids = np.zeros((H, W), np.int64)
    for i, c in enumerate(centres):
        b = u @ np.asarray(c)
        disc = b * b - (np.dot(c, c) - radius**2)
        with np.errstate(invalid="ignore"):
            s = b - np.sqrt(disc)
        hit = (disc >= 0) & (s < best)
        best[hit] = s[hit]
        ids[hit] = i + 1
    xyz = u * best[..., None]
    xyz[ids == 0] = np.nan
    return xyz, ids


def test_spheres_are_fitted_in_closed_form_exactly():
    centres = [(3.0, 2.0, 300.0), (-17.5, 4.0, 303.0), (20.0, -15.0, 296.0)]
    xyz, ids = _sphere_cloud(centres, 10.0)
    v, t = icosphere(10.0, 4)
    model = prepared(v, t)
    assert model.sphere_radius == pytest.approx(10.0, abs=1e-9)
    fits = fit_parts(xyz, ids > 0, v, t, intrinsics=K_TEST)
    assert len(fits) == 3
    for f in fits:
        assert f.err_mm < 1e-6
        c = f.pose[:3, :3] @ model.centroid + f.pose[:3, 3]
        assert min(np.linalg.norm(c - np.asarray(x)) for x in centres) < 1e-6
    explained = np.zeros(ids.size, bool)
    for f in fits:
        explained[f.pixels] = True
    assert explained[(ids > 0).reshape(-1)].all()


def test_intrinsics_are_estimated_from_the_organized_cloud_when_not_given():
    xyz, ids = _sphere_cloud([(0.0, 0.0, 300.0)], 10.0)
    v, t = icosphere(10.0, 4)
    fits = fit_parts(xyz, ids > 0, v, t)
    assert len(fits) == 1 and fits[0].support > 0.95


def test_empty_zone_and_all_nan_cloud_give_no_fits():
    v, t = hex_nut_mesh()
    xyz, ids = render([(v, t, pose(np.eye(3), (0, 0, 300)))])
    assert fit_parts(xyz, np.zeros(ids.shape, bool), v, t, intrinsics=K_TEST) == []
    assert fit_parts(np.full(xyz.shape, np.nan), np.ones(ids.shape, bool), v, t) == []


@pytest.mark.parametrize(
    ("vertices", "triangles", "words"),
    [
        (np.zeros((3, 3)), np.array([[0, 1, 2]]), "degenerate: 3 vertices"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]), np.array([[0, 1, 2], [1, 3, 2], [0, 2, 1], [1, 2, 3]]),
         "flat"),
        (np.ones((5, 3)), np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4], [0, 3, 4]]), "no area"),
        (np.eye(4, 3), np.array([[0, 1, 2], [1, 2, 9], [0, 1, 3], [0, 2, 3]]), "index"),
    ],
)
def test_a_degenerate_mesh_is_one_line_parameter_error(vertices, triangles, words):  # type: ignore[no-untyped-def]
    xyz = np.zeros((8, 8, 3))
    with pytest.raises(ParameterError) as e:
        fit_parts(xyz, np.ones((8, 8), bool), vertices, triangles)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_bad_arrays_and_params_say_what_is_wrong():
    v, t = hex_nut_mesh()
    with pytest.raises(InputShapeError, match="xyz_mm"):
        fit_parts(np.zeros((4, 4)), np.ones((4, 4), bool), v, t)
    with pytest.raises(InputShapeError, match="zone"):
        fit_parts(np.zeros((4, 4, 3)), np.ones((4, 5), bool), v, t)
    with pytest.raises(ParameterError, match=r"FitParams\.min_support"):
        FitParams(min_support=1.5)
    with pytest.raises(ParameterError, match=r"FitParams\.icp_iterations"):
        FitParams(icp_iterations=2.5)  # type: ignore[arg-type]


def test_a_symmetric_equivalent_pose_is_no_error():
    """The nut maps onto itself by 60° turns about its axis and half-turns about its flats: a fit
    off by one of those is exact; a 10° turn is 10° off."""
    v, t = hex_nut_mesh()
    model = prepared(v, t)
    T = pose(rotation((0.3, 1, 0.2), 37), (4, -2, 300))
    c = model.centroid
    for S in model.symmetries:
        Tf = T.copy()
        Tf[:3, :3] = T[:3, :3] @ S
        Tf[:3, 3] = T[:3, :3] @ c + T[:3, 3] - Tf[:3, :3] @ c  # the same centroid
        dt, da = pose_error(Tf, T, model)
        assert dt < 1e-6 and da < 1e-3
    assert any(abs(np.degrees(np.arccos(np.clip((np.trace(S) - 1) / 2, -1, 1))) - 60) < 1e-3 for S in model.symmetries)
    Tf = T.copy()
    Tf[:3, :3] = T[:3, :3] @ rotation((0, 0, 1), 10)
    assert pose_error(Tf, T, model)[1] == pytest.approx(10.0, abs=1e-6)


def test_the_model_index_matches_the_exact_distances_and_the_reference_icp():
    """The voxel index built once per model gives the exact distance to the surface near it (within
    the voxel's tangential slack), and ICP through it lands where the k-d tree ICP lands."""
    from zcut.fits.fit import _surface_distances
    from zcut.fits.icp import icp, icp_reference

    v, t = hex_nut_mesh()
    model = prepared(v, t)
    from zcut.fits.kernels import _index_dtype

    # int16 grids where the indices fit (half the memory the lookups walk), int32 beyond
    assert model.index is not None and model.index.tri_grid.dtype == np.int16 and model.index.seg_grid.dtype == np.int16
    assert _index_dtype(32767) is np.int16 and _index_dtype(32768) is np.int32
    rng = np.random.default_rng(5)
    q = model.samples[rng.choice(len(model.samples), 2000)] + rng.normal(0, 0.4, (2000, 3))
    exact = model.distance(q)
    approx = _surface_distances(model, q, np.eye(4))
    # float32 in Open3D's exact distance; the voxel's triangle is the nearest one but near a face's border
    assert np.all(np.abs(approx - exact) <= 0.87 * model.index.h + 1e-4)
    assert np.mean(np.abs(approx - exact) < 1e-4) > 0.9
    T = pose(rotation((1, 0.3, 0), 160), (5, -3, 300))
    xyz, ids = render([(v, t, T)], floor_z_mm=320)
    pts = xyz[ids > 0]
    T0 = T @ pose(rotation((0, 1, 0.4), 4), (0.8, -0.5, 0.3))
    opts = dict(iterations=30, gate_mm=4.0, k=3.0, floor_mm=0.1)
    Tk, rk, _ = icp(pts, model, T0, **opts)
    Tr, rr, _ = icp_reference(pts, model, T0, **opts)
    assert pose_error(Tk, T, model)[0] < 0.02 and pose_error(Tk, T, model)[1] < 0.1
    assert pose_error(Tk, Tr, model)[0] < 0.05 and pose_error(Tk, Tr, model)[1] < 0.2
    assert rk < 0.01


def test_touching_nuts_in_one_region_are_fitted_patch_by_patch():
    """Three nuts lying nearly flat (tilted a few degrees each way, as in a pile), flats touching: one
    candidate region holds two of them (no depth jump between them), fitted one instance at a time
    (a guess from the whole region's axes fits neither)."""
    from zcut.fits.fit import _Frame, _holds_many
    from zcut.fits.segment import segment

    v, t = hex_nut_mesh()
    model = prepared(v, t)
    truths = [pose(rotation((1, 0, 0), a) @ rotation((0, 0, 1), b), (1.0, y, 300.0))
              for y, a, b in ((-18.3, 6.0, 3.0), (0.0, -5.0, -2.0), (18.3, 7.0, 1.0))]
    xyz, ids = render([(v, t, T) for T in truths], floor_z_mm=330)
    zone = ids > 0
    regions = segment(xyz, np.flatnonzero(zone), f_px=500.0, jump_mm=1.5, jump_px=3.0, min_px=40)
    assert len(regions) == 2 and len(regions[0]) > 1.5 * len(regions[1])
    frame = _Frame(xyz=xyz, valid=np.isfinite(xyz).all(axis=2), zone=zone, K=K_TEST)
    assert _holds_many(frame, regions[0], model)
    fits = fit_parts(xyz, zone, v, t, intrinsics=K_TEST)
    assert len(fits) == 3
    for dt, da in _match(fits, truths, model):
        # near head-on the silhouette alone holds the turn (a pixel is 0.6 mm here)
        assert dt < 0.2 and da < 1.0
    explained = np.zeros(ids.size, bool)
    for f in fits:
        explained[f.pixels] = True
    assert explained[zone.reshape(-1)].mean() > 0.98


def test_pixels_without_a_measurement_do_not_count_against_a_fit():
    """A projector's shadow over most of a nut: the pixels left still find it (the shadowed ones are
    no evidence either way, not missing support)."""
    v, t = hex_nut_mesh()
    T = pose(rotation((1, 0.2, 0), 25), (2, 1, 300))
    xyz, ids = render([(v, t, T)], floor_z_mm=320)
    rows = np.flatnonzero((ids > 0).any(axis=1))
    cut = rows[0] + int(0.6 * (rows[-1] - rows[0]))
    xyz[:cut] = np.nan  # the upper 60 % of the nut's rows unmeasured
    zone = (ids > 0) & np.isfinite(xyz).all(axis=2)
    assert zone.sum() < 0.5 * (ids > 0).sum()
    fits = fit_parts(xyz, zone, v, t, intrinsics=K_TEST)
    assert len(fits) == 1 and fits[0].support > 0.9
    dt, da = pose_error(fits[0].pose, T, prepared(v, t))
    assert dt < 0.1 and da < 1.5  # 40 % of a nut seen: its turn less held


@pytest.mark.parametrize("axis, deg", [((-0.736, -0.163, -0.482), 42.67), ((-0.514, -1.648, 0.167), 52.07)])
def test_the_second_pass_finds_a_partly_occluded_nut_the_first_pass_misses(axis, deg):  # type: ignore[no-untyped-def]
    """A nut of which a plate in front (not in the zone, like the bin) hides its larger part: its
    visible piece's centroid is not its facing side's, so the first pass's guesses miss it; the
    second pass, seeded on the pixels no fit explains with guesses that put other points of the
    facing side there, finds it. ``seed_shifts=0`` is the first pass alone."""
    v, t = hex_nut_mesh()
    model = prepared(v, t)
    A = pose(rotation((1, 0.3, 0), 20), (45, -20, 300))  # a whole nut: the first pass's noise level
    B = pose(rotation(axis, deg), (15, 10, 305))
    plate = (np.array([[19.0, -300, 0], [-281, -300, 0], [-281, 300, 0], [19.0, 300, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    xyz, ids = render([(v, t, A), (v, t, B), (*plate, pose(np.eye(3), (0, 0, 285)))], floor_z_mm=330)
    zone = (ids == 1) | (ids == 2)
    seen = (ids == 2).sum()
    alone = (render([(v, t, B)])[1] > 0).sum()
    assert 0.15 * alone < seen < 0.45 * alone
    from zcut.fits import fit_prepared

    first = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=FitParams(seed_shifts=0))
    assert len(first) == 1 and pose_error(first[0].pose, A, model)[0] < 0.05
    fits = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    assert len(fits) == 2
    assert all(np.array_equal(a.pose, b.pose) for a, b in zip(first, fits))  # the first pass unchanged
    dt, da = _match(fits, [B], model)[0]
    assert dt < 0.05 and da < 0.5
    explained = np.zeros(ids.size, bool)
    for f in fits:
        explained[f.pixels] = True
    assert explained[(ids == 2).reshape(-1)].mean() > 0.95
    assert not explained[(ids == 3).reshape(-1)].any()


def test_the_second_pass_params_say_what_is_wrong():
    with pytest.raises(ParameterError, match="seed_shifts"):
        FitParams(seed_shifts=-1)
    with pytest.raises(ParameterError, match="seed_min_share"):
        FitParams(seed_min_share=1.5)
    with pytest.raises(ParameterError, match="seed_err_ratio"):
        FitParams(seed_err_ratio=0)


def _box(a: float, b: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed box a × b × c (mm) about the origin, 8 vertices, 12 outward triangles."""
    v = np.array([[x, y, z] for x in (-a / 2, a / 2) for y in (-b / 2, b / 2) for z in (-c / 2, c / 2)], np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    t = np.array([tri for q in quads for tri in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.int64)
    return v, t


def test_a_box_is_no_sphere_though_its_corners_lie_at_one_radius():
    """A cube's 8 corners lie at one radius from its centre: the fitting classified it as a sphere and fitted
    its instances as balls. A sphere's faces' centres lie at that radius too; the fitting and the vetting's
    solid (the one overlap rule) now say the same."""
    cube = _box(20.0, 20.0, 20.0)
    model = prepare_model(*cube)
    assert model.sphere_radius is None and model.solid.ball is None
    ball = icosphere(10.0, 3)
    model = prepare_model(*ball)
    assert model.sphere_radius == pytest.approx(10.0, rel=1e-6) and model.solid.ball is not None
    nut = hex_nut_mesh()
    model = prepare_model(*nut)
    assert model.sphere_radius is None and model.solid.ball is None
