"""zcut.fit_vetting: fits whose solids overlap a better-supported fit's are no known surface (issue 29).

Closed forms first (boxes: a duplicate 2 mm off is vetted out, a touching neighbour is kept, an open
mesh is never vetted), then the rule of :mod:`zcut.explained` on a synthetic cloud with a fit placed
on floating points 2 mm above a part: explained before, vetted out and proposed after; then the
method on a real log (``zcut synth``) against a full recomputation without the fits it left out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from explained_helpers import box_mesh

from zcut import explained as ex
from zcut import fit_vetting as fv
from zcut.errors import InputShapeError, ParameterError

LO, HI = np.array([-20.0, -20.0, 500.0]), np.array([20.0, 20.0, 520.0])


def _shift(mesh: tuple[np.ndarray, np.ndarray], d: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    return mesh[0] + np.asarray(d), mesh[1]


def test_a_duplicate_is_vetted_out_a_touching_part_kept():
    true = box_mesh(LO, HI)
    duplicate = _shift(true, (0.0, 0.0, -2.0))  # the same part, 2 mm toward the camera
    touching = _shift(true, (40.2, 0.0, 0.0))  # the next part, 0.2 mm away
    far = _shift(true, (0.0, 100.0, 0.0))
    v = fv.vet_fits(fv.part_overlaps([true, duplicate, touching, far]), np.array([1000, 300, 500, 10]))
    np.testing.assert_array_equal(v.kept, [True, False, True, True])
    assert v.by[1] == 0 and v.overlap[1] > 0.8 and v.overlap[0] == 0.0 and v.by[0] == -1
    np.testing.assert_array_equal(v.dropped, [1])
    # the ranking decides which of the two stays; a tie keeps the lower index
    np.testing.assert_array_equal(fv.vet_fits(fv.part_overlaps([true, duplicate]), np.array([300, 1000])).kept, [False, True])
    np.testing.assert_array_equal(fv.vet_fits(fv.part_overlaps([true, duplicate]), np.array([5, 5])).kept, [True, False])
    # overlap: the share of the volume, both orders; boxes 2 mm apart along a 20 mm side share 90 %
    pairs, share = fv.part_overlaps([true, duplicate])
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 0]])
    np.testing.assert_allclose(share, 0.9, atol=0.05)
    # a threshold above the overlap keeps both
    assert fv.vet_fits(fv.part_overlaps([true, duplicate]), np.array([2, 1]), max_overlap=0.95).kept.all()


def test_touching_parts_overlap_far_below_the_threshold():
    true = box_mesh(LO, HI)
    pressed = _shift(true, (39.7, 0.0, 0.0))  # fitted 0.3 mm into its neighbour
    _, share = fv.part_overlaps([true, pressed])
    assert share.max() < 0.2 * fv.MAX_OVERLAP
    assert fv.vet_fits(fv.part_overlaps([true, pressed]), np.array([1, 1])).kept.all()


def test_an_open_mesh_has_no_inside_and_is_never_vetted_out():
    v, t = box_mesh(LO, HI)
    assert fv.is_closed(v, t) and not fv.is_closed(v, t[:-2])
    split = (v[t].reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3))  # every triangle its own vertices
    assert fv.is_closed(*split) and len(fv.inside_samples(*split)) == fv.INSIDE_SAMPLES
    opened = (v, t[:-2])
    assert fv.inside_samples(*opened).shape == (0, 3)
    assert len(fv.inside_samples(v, t)) == fv.INSIDE_SAMPLES
    assert fv.vet_fits(fv.part_overlaps([opened, _shift(opened, (0.0, 0.0, -2.0))]), np.array([2, 1])).kept.all()
    assert fv.vet_fits(fv.part_overlaps([]), np.zeros(0)).kept.shape == (0,)


@pytest.mark.parametrize("overlaps, support, kw, error, match", [
    ((np.array([[0, 1]]), np.array([0.5])), np.ones((2, 1)), {}, InputShapeError, "one value per fit"),
    ((np.array([[0, 2]]), np.array([0.5])), np.ones(2), {}, InputShapeError, "pairs of the 2 fits"),
    ((np.array([[0, 1]]), np.array([0.5, 0.1])), np.ones(2), {}, InputShapeError, "one share each"),
    ((np.array([[0, 1]]), np.array([0.5])), np.ones(2), {"max_overlap": 1.5}, ParameterError, "max_overlap"),
])
def test_bad_inputs_are_one_line(overlaps, support, kw, error, match):
    with pytest.raises(error, match=match):
        fv.vet_fits(overlaps, support, **kw)


def test_instances_of_one_mesh_overlap_as_posed_meshes_do():
    """:func:`instance_overlaps` (one model, its poses) is :func:`part_overlaps` of the posed meshes: the
    same pairs, the same shares within the sampling's error."""
    rng = np.random.default_rng(5)
    v, t = box_mesh(np.array([-10.0, -6.0, -3.0]), np.array([10.0, 6.0, 3.0]))
    poses = []
    for k in range(6):
        a = rng.uniform(-np.pi, np.pi, 3)
        Rx = np.array([[1, 0, 0], [0, np.cos(a[0]), -np.sin(a[0])], [0, np.sin(a[0]), np.cos(a[0])]])
        Rz = np.array([[np.cos(a[2]), -np.sin(a[2]), 0], [np.sin(a[2]), np.cos(a[2]), 0], [0, 0, 1]])
        T = np.eye(4)
        T[:3, :3] = Rz @ Rx
        T[:3, 3] = [6.0 * k, rng.uniform(-3, 3), 500.0 + rng.uniform(-3, 3)]
        poses.append(T)
    meshes = [(v @ T[:3, :3].T + T[:3, 3], t) for T in poses]
    pa, sa = fv.instance_overlaps(v, t, poses)
    pb, sb = fv.part_overlaps(meshes)
    got, want = dict(zip(map(tuple, pa.tolist()), sa)), dict(zip(map(tuple, pb.tolist()), sb))
    assert any(s > 0.1 for s in want.values())
    for pair, s in want.items():
        assert abs(got.get(pair, 0.0) - s) < 0.08, pair
    for pair, s in got.items():
        assert abs(want.get(pair, 0.0) - s) < 0.08, pair


def _cloud() -> tuple[np.ndarray, np.ndarray]:
    """A part's top face seen from the camera (z = 500 mm, 0.5 mm pixels, 0.05 mm noise) with a patch of
    floating points 2 mm above it (toward the camera): (xyz (H, W, 3) mm, floating (H, W) bool)."""
    rng = np.random.default_rng(3)
    g = np.arange(-15.0, 15.01, 0.5)
    X, Y = np.meshgrid(g, g)
    Z = 500.0 + rng.normal(0.0, 0.05, X.shape)
    floating = (np.abs(X - 5.0) < 3.0) & (np.abs(Y + 4.0) < 3.0)
    Z[floating] -= 2.0
    return np.dstack([X, Y, Z]), floating


def _judge(xyz: np.ndarray, surfaces: ex.KnownSurfaces, near: ex.Nearest, c: np.ndarray) -> tuple[ex.KnownSurfaces, np.ndarray]:
    s = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, surfaces.part_err_mm, min_pixels=5))
    err = ex.err_image(near, s, c, floor_mm=0.05)
    return s, err


def test_a_fit_on_floating_points_is_vetted_out_and_its_points_proposed():
    xyz, floating = _cloud()
    c = ex.footprint_mm(xyz, 1000.0)  # 0.5 mm footprints: 3 Err ~ 1.1 mm < 2 mm
    true = box_mesh(LO, HI)
    ghost = _shift(true, (5.0, -4.0, -2.0))  # placed on the floating points (and 2 mm off the part)
    surfaces = ex.KnownSurfaces(parts=[true, ghost], part_err_mm=[0.3, 0.3])
    near = ex.nearest_surface(xyz, surfaces)
    s, err = _judge(xyz, surfaces, near, c)
    before = ex.unexplained(near.dist_mm, err)
    assert not before[floating].any()  # the ghost fit explains them
    support = fv.explained_px(near, err, 2, k=ex.K_ERR)
    assert support[0] > 10 * support[1] > 0
    vetting = fv.vet_fits(fv.part_overlaps(surfaces.parts), support)
    np.testing.assert_array_equal(vetting.kept, [True, False])
    left, near2 = fv.without_fits(xyz, near, surfaces, vetting.kept)
    assert len(left.parts) == 1 and left.part_err_mm == [0.3]
    s2, err2 = _judge(xyz, left, near2, c)
    after = ex.unexplained(near2.dist_mm, err2)
    assert after[floating].all() and not after[~floating].any()  # proposed; the part's own points explained
    # the same as judging without the ghost fit from the start
    full = ex.nearest_surface(xyz, left)
    np.testing.assert_array_equal(near2.dist_mm, full.dist_mm)
    np.testing.assert_array_equal(near2.surface, full.surface)


def test_a_correct_fit_alone_is_kept_and_nothing_changes():
    xyz, _ = _cloud()
    surfaces = ex.KnownSurfaces(parts=[box_mesh(LO, HI), box_mesh(LO + [0, 60, 0], HI + [0, 60, 0])],
                                part_err_mm=[0.3, 0.2])
    near = ex.nearest_surface(xyz, surfaces)
    _, err = _judge(xyz, surfaces, near, ex.footprint_mm(xyz, 1000.0))
    kept = fv.vet_fits(fv.part_overlaps(surfaces.parts), fv.explained_px(near, err, 2, k=ex.K_ERR)).kept
    assert kept.all()
    left, near2 = fv.without_fits(xyz, near, surfaces, kept)
    assert near2 is near and left.part_err_mm == [0.3, 0.2]
    with pytest.raises(InputShapeError, match="one bool per part"):
        fv.without_fits(xyz, near, surfaces, kept[:1])
    with pytest.raises(InputShapeError, match="0 parts"):
        fv.explained_px(near, err, 0, k=3.0)


def _overlapping_fits(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The fits as before docs/fits.md's sixth round (``FitParams.claim=False``: duplicates, which the
    fitting itself no longer makes), so the method has overlapping fits to vet."""
    import functools

    import zcut.fits

    monkeypatch.setattr(zcut.fits, "FitParams", functools.partial(zcut.fits.FitParams, claim=False))


@pytest.fixture(scope="module")
def overlapping(tmp_path_factory):  # type: ignore[no-untyped-def]
    """(session, frame, zone, ``run_explained``'s output) of a real log (``zcut synth``, hand-made spheres,
    320 × 200) with :func:`_overlapping_fits`: made once for the tests of the method's vetting."""
    from cli_helpers import synth_log

    from replay.options import PipelineOptions
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone

    with pytest.MonkeyPatch.context() as mp:
        _overlapping_fits(mp)
        log = synth_log(tmp_path_factory.mktemp("vetting") / "spheres.mcap", parts="spheres", frames=1, seed=9634,
                        size="320x200")
        session = PipelineOptions(methods="zcut,explained").open_session(log)
        frames = session.located()  # the frame as read: the method runs on it below, not also here
        frame, _ = next(frames)
        frames.close()
        zone = bin_zone(frame, session.config, bin_model=session.prepared)
        return session, frame, zone, run_explained(frame, zone, session.config)


@pytest.mark.slow
def test_the_method_leaves_out_overlapping_fits_and_judges_their_pixels_again(overlapping):
    """``explained`` on a real log (hand-made spheres, 320 × 200): no two fits it keeps share more than
    the threshold of their volume, each fit it left out overlaps a kept one, and its distances are those
    of the kept fits, the bin and the table computed from scratch."""
    from replay.pipeline.explained import bin_and_table_surfaces

    session, frame, zone, (out, d, _) = overlapping
    assert d is not None and d.fits and d.vetted_out
    poses = [f.pose for f in d.fits]
    _, share = fv.instance_overlaps(d.vertices_mm, d.triangles, poses)
    assert share.size == 0 or share.max() <= fv.MAX_OVERLAP
    for f in d.vetted_out:
        pairs, share = fv.instance_overlaps(d.vertices_mm, d.triangles, [f.pose, *poses])
        assert share[(pairs == 0).any(axis=1)].max() > fv.MAX_OVERLAP  # its share in a kept fit, or that fit's in it
    kept = [(d.instance_mesh(i), d.triangles) for i in range(len(d.fits))]
    xyz = frame.xyz.astype(np.float64) * 1000.0
    surfaces = ex.KnownSurfaces(parts=kept, part_err_mm=[f.err_mm for f in d.fits])
    assert zone.removal is not None and zone.located.registration is not None and zone.located.bin_model is not None
    surfaces = bin_and_table_surfaces(xyz, zone.removal, zone.located.registration, zone.located.bin_model, surfaces)
    full = ex.nearest_surface(xyz, surfaces, where=zone.zone)
    np.testing.assert_array_equal(d.dist_mm, full.dist_mm)
    np.testing.assert_array_equal(d.surface, full.surface)
    # Err and the outliers (the method computes the whole Err image once, after the vetting) are those of
    # the kept fits, the bin and the table judged from scratch
    p = session.config.bank["explained"]
    scratch = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(full, surfaces.part_err_mm, where=zone.zone))
    K = frame.intrinsics
    assert K is not None
    err = ex.err_image(full, scratch, ex.footprint_mm(xyz, 0.5 * (K.fx + K.fy)), floor_mm=p.err_floor_mm)
    np.testing.assert_array_equal(d.err_mm, err)
    np.testing.assert_array_equal(out, ex.unexplained(full.dist_mm, err, p.k) & zone.zone)


@pytest.mark.slow
def test_a_max_overlap_of_one_keeps_every_fit(overlapping, monkeypatch):
    """``[explained] fit_max_overlap = 1`` switches the vetting off: every fit stays a known surface and
    the method's outliers are those of the same fits judged without it (one frame where the default
    vets fits out)."""
    import dataclasses

    from replay.pipeline.explained import run_explained

    _overlapping_fits(monkeypatch)
    session, frame, zone, (on, d_on, _) = overlapping
    assert d_on is not None and d_on.vetted_out
    p = dataclasses.replace(session.config.bank["explained"], fit_max_overlap=1.0)
    config = dataclasses.replace(session.config, bank={**session.config.bank, "explained": p})
    off, d_off, _ = run_explained(frame, zone, config)
    assert d_off is not None and not d_off.vetted_out
    # the fits' own (the sliver pass's, appended after them, pose on what the fits leave unexplained: with the
    # vetting off it sees other regions, and since the cut at depth steps it may pose another there)
    assert len(d_off.fits) - d_off.slivers == len(d_on.fits) - d_on.slivers + len(d_on.vetted_out)
    assert off.sum() < on.sum()  # the duplicates' bands explain points the vetting proposes
