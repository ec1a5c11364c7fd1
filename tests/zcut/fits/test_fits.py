"""zcut.fits: instances of a known part found in clean ray-cast clouds of posed meshes."""

from __future__ import annotations

import numpy as np
import pytest
from fit_scenes import K_TEST, SIZE, hex_nut_mesh, icosphere, pose, render, rotation

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
    model = prepare_model(v, t)
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
    model = prepare_model(v, t)
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
    model = prepare_model(v, t)
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
