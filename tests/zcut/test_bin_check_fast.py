"""The bin check's fast pieces against what they replace (round of 2026-12-05c, h/rem5).

- :func:`zcut.bin_check._rays_within` (a grid of the model's rays) against the KD-tree the check built per frame;
- :func:`zcut.bin_check._pixel_pitch` (one kernel) against :func:`zcut.bin_check._pixel_pitch_numpy`;
- :func:`zcut.removal.fit_residual_field` (kernels) against ``reference=True`` (numpy, as first written);
- :func:`zcut.removal.surface_nearest` (the removal's query reused) against the tree's query;
- :func:`zcut.bin_check._clumps` (a union-find over the pixels) against ``ndimage.label`` of the whole image;
- :attr:`zcut.removal.RemovalResult.zone_top` against :func:`zcut.bin_check._zone_top`;
- the whole check against the previous one: the same pieces swapped back for the literal ones, the removal's
  measured surface dropped, on frames with parts leaning on a wall, a model with a gap, large invalid regions
  and degenerate frames.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree
from test_bin_check import BAND_MM, filled, model, on_inner_wall, pose, rim_block  # noqa: F401  # fixtures

import zcut.bin_check as bc
from replay.logs.pcd import read_pcd
from zcut.bin_model import BinModel
from zcut.params import RemovalParams
from zcut.removal import (
    fit_residual_field,
    prepare_removal_index,
    remove_table_and_bin,
    surface_nearest,
)


def _tree_within(rays: np.ndarray, mine: np.ndarray, ub: float) -> np.ndarray:
    """What the check did before: a KD-tree of the rays, a nearest query bounded by ``ub``."""
    return np.isfinite(cKDTree(rays).query(mine, k=1, distance_upper_bound=ub)[0])


def _ndimage_clumps(flat: np.ndarray, h: int, w: int) -> np.ndarray:
    """What the check did before: ``ndimage.label`` of the whole image, read at the pixels."""
    img = np.zeros(h * w, bool)
    img[flat] = True
    return ndimage.label(img.reshape(h, w), structure=np.ones((3, 3), bool))[0].reshape(-1)[flat]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_rays_within_equals_the_tree():
    rng = np.random.default_rng(5301)
    n_true = 0
    for trial in range(240):
        n, m = int(rng.integers(1, 4000)), int(rng.integers(1, 400))
        c = rng.normal(size=(n, 3)) * rng.choice([0.01, 0.3, 1.0]) + [0.0, 0.0, 1.0]
        if trial % 5 == 0:
            c = np.round(c, 2)  # many rays on a lattice: ties
        rays = _unit(c)
        near = rays[rng.integers(0, n, m // 2)] + rng.normal(size=(m // 2, 3)) * 1e-3
        mine = _unit(np.concatenate([near, rng.normal(size=(m - m // 2, 3)) * 0.1 + [0.0, 0.0, 1.0]]))
        ub = float(rng.choice([1e-5, 1e-3, 3e-3, 0.05, 0.5, 3.0]))
        if trial % 7 == 0:  # queries at exactly the bound from a ray
            k = min(m, n)
            mine = rays[:k].copy()
            mine[:, 0] += ub
            ub = float(np.sqrt(((mine - rays[:k]) ** 2).sum(axis=1)).max())
        want = _tree_within(rays, mine, ub)
        got = bc._rays_within(rays, mine, ub)
        assert got.dtype == np.bool_ and np.array_equal(got, want), trial
        n_true += int(want.sum())
    assert n_true > 1000


@pytest.mark.parametrize("case", ["empty queries", "no ray", "inf bound", "zero bound", "nan ray", "nan query",
                                  "one ray", "behind the camera"])
def test_rays_within_degenerate(case):
    rng = np.random.default_rng(7)
    rays = _unit(rng.normal(size=(300, 3)) * 0.2 + [0.0, 0.0, 1.0])
    mine = _unit(rng.normal(size=(50, 3)) * 0.2 + [0.0, 0.0, 1.0])
    ub = 0.05
    if case == "empty queries":
        mine = mine[:0]
    elif case == "no ray":
        rays = rays[:0]
    elif case == "inf bound":
        ub = float("inf")
    elif case == "zero bound":
        ub = 0.0
    elif case == "nan ray":
        rays[3] = np.nan
    elif case == "nan query":
        mine[4] = np.nan
    elif case == "one ray":
        rays = rays[:1]
        mine[0] = rays[0]
    elif case == "behind the camera":
        rays[::2, 2] *= -1.0
        mine[::3, 2] *= -1.0
    def outcome(f):  # the answer, or the error (the tree takes no NaN ray)
        try:
            with np.errstate(invalid="ignore"):
                return f(rays, mine, ub).tolist()
        except ValueError as e:
            return str(e)

    want = outcome(_tree_within) if len(rays) else [False] * len(mine)
    assert outcome(bc._rays_within) == want


def _clouds(real_data=None):
    rng = np.random.default_rng(11)
    for t in range(60):
        h, w = int(rng.integers(1, 200)), int(rng.integers(1, 200))
        a = rng.normal(size=(h, w, 3)) * float(rng.choice([1e-3, 1.0, 1e3]))
        if t % 3 == 0:
            a = a.astype(np.float32)
        if t % 4 == 0:  # large invalid regions
            a[:, : w // 2] = np.nan
            a[::7] = np.nan
        if t % 9 == 0:
            a[:] = np.nan
        if t % 11 == 0:
            a[0, :2] = 0.0  # a zero point: 0 / 0 in both
        yield f"random {t}", a
    yield "one pixel", np.ones((1, 1, 3))
    yield "empty", np.zeros((0, 5, 3))


@pytest.mark.parametrize("name, a", list(_clouds()), ids=[n for n, _ in _clouds()])
def test_pixel_pitch_equals_numpy(name, a):
    with np.errstate(invalid="ignore", divide="ignore"):
        want = bc._pixel_pitch_numpy(a)
    got = bc._pixel_pitch(a)
    assert got == want or (np.isnan(got) and np.isnan(want)), name


def test_pixel_pitch_and_rays_on_the_real_clouds(real_data):
    for path in sorted(real_data.glob("*.pcd")):
        xyz = read_pcd(path).xyz
        with np.errstate(invalid="ignore", divide="ignore"):
            want = bc._pixel_pitch_numpy(xyz)
        assert bc._pixel_pitch(xyz) == want, path.name
        # the cloud's own rays as a model, its pixels as queries, bound two pitches
        pts = xyz.reshape(-1, 3).astype(np.float64)
        pts = pts[np.isfinite(pts).all(axis=1) & (np.linalg.norm(pts, axis=1) > 0)]
        rays = _unit(pts[::3])
        mine = _unit(pts[1::5])
        assert np.array_equal(bc._rays_within(rays, mine, 2.0 * want), _tree_within(rays, mine, 2.0 * want)), path.name


def test_unit_rows_equal_numpy(real_data):
    rng = np.random.default_rng(31)
    clouds = [rng.normal(size=(n, 3)) * s for n in (0, 1, 7, 100_000) for s in (1e-3, 1.0, 1e3)]
    clouds.append(np.array([[0.0, 0.0, 0.0], [1e-200, 0.0, 0.0], [1e200, 1e200, 1.0], [-0.0, 3.0, 4.0]]))
    clouds += [read_pcd(p).xyz.reshape(-1, 3).astype(np.float64) for p in sorted(real_data.glob("*.pcd"))[:3]]
    for v in clouds:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
            want = v / np.linalg.norm(v, axis=1, keepdims=True)
        got = bc._unit_rows(np.ascontiguousarray(v))
        assert got.tobytes() == want.tobytes() or np.array_equal(got, want, equal_nan=True), v.shape


def test_fit_residual_field_equals_numpy():
    rng = np.random.default_rng(9)
    fitted = 0
    for trial in range(60):
        m = int(rng.choice([10, 49, 50, 60, 500, 5000, 20_000]))
        p = rng.uniform(-0.2, 0.2, (m, 3)) + [0.0, 0.0, 0.5]
        n = _unit(rng.normal(size=(m, 3)))
        if trial % 6 == 0:
            n[:] = [0.0, 0.0, 1.0]  # one face: a degenerate design
        coef = rng.normal(size=7) * 1e-3
        q = p - p.mean(axis=0)
        r = n @ coef[:3] + np.einsum("ij,ij->i", np.cross(q, n), np.tile(coef[3:6], (m, 1))) + coef[6] * (n * q).sum(1)
        r += rng.normal(size=m) * float(rng.choice([1e-5, 2e-4, 1e-3]))
        out = rng.random(m) < 0.1
        r[out] += rng.uniform(-0.01, 0.01, out.sum())  # parts in front of the wall
        r[rng.random(m) < 0.05] = np.nan  # no model point within reach
        for normal_equations in (False, True):
            got = fit_residual_field(r, p, n, normal_equations=normal_equations)
            want = fit_residual_field(r, p, n, normal_equations=normal_equations, reference=True)
            assert (got is None) == (want is None), trial
            if got is not None and want is not None:
                fitted += 1
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]), trial
                assert got[2:] == want[2:], trial
    assert fitted > 20


def test_surface_nearest_is_the_trees_query(model, filled):  # noqa: F811  # the fixtures
    xyz, fp, ring = filled
    T = pose(dx_mm=1.0)
    index = prepare_removal_index(model, RemovalParams())
    rem = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
    assert rem.surface is not None and rem.surface.queried is not None
    flat = np.flatnonzero(ring)
    flat = flat[np.isfinite(xyz.reshape(-1, 3)[flat]).all(axis=1)]
    p = (xyz.reshape(-1, 3)[flat].astype(np.float64) - T[:3, 3]) @ T[:3, :3]
    p[::5] += 1e-9  # not the points queried: asked again
    others = np.flatnonzero(~ring & np.isfinite(xyz).all(axis=2))[:500]  # pixels it did not query
    flat = np.concatenate([flat, others])
    p = np.concatenate([p, (xyz.reshape(-1, 3)[others].astype(np.float64) - T[:3, 3]) @ T[:3, :3]])
    got = surface_nearest(rem, index, flat, p)
    assert index.tree is not None and got is not None
    d, j = index.tree.query(p, k=1, distance_upper_bound=index.params.max_tolerance_mm / 1000.0)
    assert np.array_equal(got, np.where(np.isfinite(d), j, -1))
    assert (got >= 0).sum() > len(flat) // 2
    assert surface_nearest(rem, prepare_removal_index(model, RemovalParams()), flat, p) is None  # another index
    assert surface_nearest(dataclasses.replace(rem, surface=None), index, flat, p) is None


def test_clumps_are_ndimage_labels():
    rng = np.random.default_rng(23)
    for t in range(300):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 70))
        img = rng.random((h, w)) < float(rng.choice([0.0, 0.01, 0.1, 0.3, 0.5, 0.7, 1.0]))
        if t % 10 == 0:  # a diagonal line: 8-connected, one clump
            img[:] = False
            k = np.arange(min(h, w))
            img[k, k] = True
        flat = np.flatnonzero(img)
        want = ndimage.label(img, structure=np.ones((3, 3), bool))[0].reshape(-1)[flat]
        assert np.array_equal(bc._clumps(flat, h, w), want), t


def test_the_removals_zone_top_is_the_checks(model, filled):  # noqa: F811  # the fixtures
    xyz, fp, ring = filled
    index = prepare_removal_index(model, RemovalParams())
    holes = xyz.copy()
    holes[:, : xyz.shape[1] // 2] = np.nan
    holes[::7] = np.nan
    for a in (xyz, holes, np.full_like(xyz, np.nan), xyz[:1, :1], xyz[:0]):
        f, g = fp[: a.shape[0], : a.shape[1]], ring[: a.shape[0], : a.shape[1]]
        rem = remove_table_and_bin(a, f, index=index, T_cam_bin=pose(), ring=g)
        seen, top = bc._zone_top(rem.zone, rem.height_mm)
        assert rem.zone_top is not None and rem.zone_top.seen == bool(seen)
        assert np.array_equal(rem.zone_top.top, top, equal_nan=True) and np.signbit(rem.zone_top.top) == np.signbit(top)
        assert remove_table_and_bin(a, f, index=index, T_cam_bin=pose(), ring=g, reference=True).zone_top is None
    # a result rebuilt with another zone or height image is measured again: a zone pixel raised to the top
    rem = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=pose(), ring=ring)
    height = rem.height_mm.copy()
    height[rem.zone] += 5.0
    p = RemovalParams()
    again = bc.check_bin_removal(dataclasses.replace(rem, height_mm=height, zone_top=None), ring, params=p,
                                 band_mm=BAND_MM)
    rebuilt = bc.check_bin_removal(dataclasses.replace(rem, height_mm=height), ring, params=p, band_mm=BAND_MM)
    assert (rebuilt.value, rebuilt.reason) == (again.value, again.reason)
    assert np.array_equal(rebuilt.offending, again.offending)


@pytest.fixture
def previous_check(monkeypatch):
    """``check_bin_removal`` as the previous tree ran it: the literal pieces, every residual queried again."""
    def check(rem, *args, **kw):
        with monkeypatch.context() as m:
            m.setattr(bc, "_rays_within", _tree_within)
            m.setattr(bc, "_pixel_pitch", bc._pixel_pitch_numpy)
            m.setattr(bc, "fit_residual_field", functools.partial(fit_residual_field, reference=True))
            m.setattr(bc, "surface_nearest", lambda *a: None)
            m.setattr(bc, "_clumps", _ndimage_clumps)
            return bc.check_bin_removal(dataclasses.replace(rem, surface=None, zone_top=None), *args, **kw)
    return check


def _frames(model, filled):  # noqa: F811  # the fixtures
    """(name, xyz, model) of frames whose check fits its residual field and asks the model's rays."""
    xyz, fp, ring = filled
    T = pose()
    wall = on_inner_wall(xyz, ring, T, 25.0)
    r0, c0 = np.argwhere(wall)[np.count_nonzero(wall) // 2]
    face = rim_block(wall, r0 - 3, c0 - 3, 7)
    rows, cols = np.divmod(face, ring.shape[1])
    rank = rows - rows.min() if np.ptp(rows) >= np.ptp(cols) else cols - cols.min()
    x = xyz.reshape(-1, 3)[face, 0] - T[0, 3]
    leaning = xyz.copy().reshape(-1, 3)
    leaning[face, 0] -= np.sign(x) * np.float32(0.0045)
    curving = xyz.copy().reshape(-1, 3)
    curving[face, 0] -= (np.sign(x) * (0.0045 + 0.0015 * rank)).astype(np.float32)
    holes = leaning.reshape(xyz.shape).copy()
    holes[:, : holes.shape[1] // 3] = np.nan
    holes[::7] = np.nan
    seen = np.einsum("ij,ij->i", -T[:3, :3].T @ T[:3, 3] - model.points, model.normals) > 0
    gappy = BinModel(model.points[seen][::2], model.normals[seen][::2], model.spacing_m)
    return [("a part leaning on a wall", leaning.reshape(xyz.shape), model),
            ("a face curving away from a wall", curving.reshape(xyz.shape), model),
            ("leaning, large invalid regions", holes, model),
            ("the filled bin", xyz, model),
            ("a model of every other seen point", leaning.reshape(xyz.shape), gappy),
            ("all invalid", np.full_like(xyz, np.nan), model)]


@pytest.mark.parametrize("k", range(6))
@pytest.mark.parametrize("dx_mm", [0.0, 2.0])
def test_the_check_equals_the_previous_one(model, filled, previous_check, monkeypatch, k, dx_mm):  # noqa: F811  # the fixtures
    _, fp, ring = filled
    name, xyz, m = _frames(model, filled)[k]
    p = RemovalParams()
    index = prepare_removal_index(m, p)
    T = pose(dx_mm=dx_mm)
    rem = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
    calls = {"field": 0, "rays": 0}

    def counted(name, f):
        def g(*a, **kw):
            calls[name] += 1
            return f(*a, **kw)
        return g

    monkeypatch.setattr(bc, "residual_field", counted("field", bc.residual_field))
    monkeypatch.setattr(bc, "_rays_within", counted("rays", bc._rays_within))
    for r in (rem, dataclasses.replace(rem, zone=rem.zone | ring)):  # and every ring pixel a candidate
        new = bc.check_bin_removal(r, ring, params=p, band_mm=BAND_MM, xyz=xyz, index=index, T_cam_bin=T)
        old = previous_check(r, ring, params=p, band_mm=BAND_MM, xyz=xyz, index=index, T_cam_bin=T)
        assert (new.value, new.flagged, new.reason, new.ghosts, new.off_surface) == \
            (old.value, old.flagged, old.reason, old.ghosts, old.off_surface), name
        assert np.array_equal(new.offending, old.offending), name
    if k in (0, 1, 2, 4):  # these fit the residual field and ask the model's rays
        assert calls["field"] > 0 and calls["rays"] > 0, (name, calls)
