"""zcut.fits without duplicates (``FitParams.claim``, docs/fits.md "Sixth round"): a part whose pixels fall
into two candidate regions gets one fit, not one per region; ``claim=False`` gives the fifth round's
fits to the bit (literal digests of the previous tree's fits, 04e9ee3)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from fit_scenes import K_TEST, hex_nut_mesh, icosphere, pose, render, rotation

from zcut.errors import ParameterError
from zcut.fits import FitParams, PartFit, fit_parts, fit_prepared, pose_error, prepare_model


def _bar() -> tuple[np.ndarray, np.ndarray]:
    """A box 2.4 mm wide, 80 mm long, 10 mm deep: a rod lying across a part, in front of it."""
    v = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-40.0, 40.0) for z in (-5.0, 5.0)])
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, t


def _split_scene(part: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(xyz, zone, vertices, triangles, true pose): one part with a bar across its middle 20 mm in front
    of it; the zone is the part's pixels, in two regions (the bar's shadow splits them)."""
    v, t = hex_nut_mesh() if part == "nut" else icosphere(10.0, 4)
    T = pose(rotation((1, 0.2, 0), 35) @ rotation((0, 0, 1), 10), (0, 0, 300)) if part == "nut" else \
        pose(np.eye(3), (0, 0, 300))
    bv, bt = _bar()
    xyz, ids = render([(v, t, T), (bv, bt, pose(np.eye(3), (0, 0, 280)))], floor_z_mm=320)
    return xyz, ids == 1, v, t, T


@pytest.mark.parametrize("part", ["nut", "sphere"])
def test_a_part_split_into_two_regions_gets_one_fit(part):  # type: ignore[no-untyped-def]
    """The old fits fitted each region of the part, the same pose twice (two fits 0.01 mm apart, each
    explaining the other's band); the fit of the second region now overlaps the first's solid and
    explains no more pixels: it is refused, and the one fit explains both regions."""
    from zcut.fits.segment import segment

    xyz, zone, v, t, T = _split_scene(part)
    regions = segment(xyz, np.flatnonzero(zone), f_px=500.0, jump_mm=1.5, jump_px=3.0, min_px=40)
    assert len(regions) == 2  # the cause: one part, two candidate regions
    old = fit_parts(xyz, zone, v, t, intrinsics=K_TEST, params=FitParams(claim=False))
    assert len(old) == 2
    fits = fit_parts(xyz, zone, v, t, intrinsics=K_TEST)
    assert len(fits) == 1
    dt, da = pose_error(fits[0].pose, T, prepare_model(v, t))
    assert dt < 0.05 and da < 0.5
    explained = np.zeros(zone.size, bool)
    explained[fits[0].pixels] = True
    assert explained[zone.reshape(-1)].mean() > 0.99


def test_a_better_fit_replaces_an_accepted_one_it_overlaps():
    """Of two fits of one part the one that explains more pixels within the smaller Err's band stays,
    whichever came first: a nut posed 2 mm off accepted first is replaced by the true one."""
    from zcut.fits.fit import _Claims, _Frame, _model_distance, _window_flat

    xyz, zone, v, t, T = _split_scene("nut")
    model = prepare_model(v, t)
    params = FitParams()
    frame = _Frame(xyz=xyz, valid=np.isfinite(xyz).all(axis=2), zone=zone, K=K_TEST)
    off = T.copy()
    off[:3, 3] += (2.0, 0.0, 0.0)
    claims = _Claims(model, params, zone.size)

    def known(P: np.ndarray, err: float) -> tuple[np.ndarray, np.ndarray]:
        flat = _window_flat(frame, P, model)
        return flat, _model_distance(frame, P, model, flat, params.k * max(err, params.err_floor_mm))

    claims.add(off, 0.8, known(off, 0.8))
    assert claims.overlapping(T) == [0]
    assert claims.better(0.01, known(T, 0.01), 0)
    claims.add(T, 0.01, known(T, 0.01))
    assert not claims.better(0.8, known(off, 0.8), 1)  # and not the other way round
    claims.kill(0)
    assert claims.alive == [False, True] and claims.overlapping(off) == [1]
    far = T.copy()
    far[:3, 3] += (30.0, 0.0, 0.0)  # a nut 30 mm away shares no volume
    assert claims.overlapping(far) == []


def test_the_second_pass_still_finds_the_partly_hidden_nut_and_the_first_pass_is_unchanged():
    """The scene of test_fits.py's second-pass test (a plate hides most of nut B): with the claims the
    same two fits, A's pose identical to the first pass alone."""
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    A = pose(rotation((1, 0.3, 0), 20), (45, -20, 300))
    B = pose(rotation((-0.736, -0.163, -0.482), 42.67), (15, 10, 305))
    plate = (np.array([[19.0, -300, 0], [-281, -300, 0], [-281, 300, 0], [19.0, 300, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    xyz, ids = render([(v, t, A), (v, t, B), (*plate, pose(np.eye(3), (0, 0, 285)))], floor_z_mm=330)
    zone = (ids == 1) | (ids == 2)
    first = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=FitParams(seed_shifts=0))
    fits = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    assert len(first) == 1 and len(fits) == 2 and np.array_equal(first[0].pose, fits[0].pose)
    dt, da = pose_error(fits[1].pose, B, model)
    assert dt < 0.05 and da < 0.5


def _digest(fits: list[PartFit]) -> list[tuple[str, str, int, str]]:
    return [(repr(f.err_mm), repr(f.support), len(f.pixels),
             hashlib.sha256(f.pose.tobytes() + f.pixels.tobytes()).hexdigest()[:16]) for f in fits]


#: the previous tree's fits (04e9ee3, before the claims) of the scenes below: (Err, support, pixels, sha256 of the
#: pose's and the pixels' bytes), with the exact ray casts (docs/fits.md "The fits' ray casts exact"). One set for every
#: CPU since the test nut's mesh no longer takes numpy's ``np.arctan2`` (whose AVX-512 kernel rounds differently:
#: docs/fits.md "The part meshes built the same on every CPU"): the nut's scenes moved to the set made at the merge
#: of h/fitray with numpy kept to AVX2, which every CPU now gives (the spheres' scene has no nut and did not move)
OLD = {
    "nut_bar": [("0.0033551694925739394", "1.0", 703, "6a87e271ab8b7054"),
                ("0.011729625347018957", "1.0", 141, "e1bf1c2721eba5b5")],
    "sphere_bar": [("0.002460114693896882", "1.0", 368, "fdcd4698d24c0576"),
                   ("0.0024601146938968777", "1.0", 368, "6560f47c12f6bafc")],
    "three_nuts": [("0.03900134112868317", "0.9965694682675815", 571, "6671c319e6352f04"),
                   ("0.04193715973589023", "0.988835725677831", 609, "9345c7754c03af22"),
                   ("0.002374508250429824", "0.9970972423802612", 687, "b321d2bc70bea929")],
    "occluded": [("0.0005805336332660733", "1.0", 782, "fd01b1bb0431aed0"),
                 ("0.0012055788643325165", "1.0", 175, "290b6714228e99c8")],
}


def test_claim_false_gives_the_previous_fits_to_the_bit():
    off = FitParams(claim=False, fine_points=0)  # the eighth round's last refinement off too
    v, t = hex_nut_mesh()
    for part in ("nut", "sphere"):
        xyz, zone, pv, pt, _ = _split_scene(part)
        assert _digest(fit_parts(xyz, zone, pv, pt, intrinsics=K_TEST, params=off)) == OLD[f"{part}_bar"]
    truths = [pose(rotation((1, 0, 0), a) @ rotation((0, 0, 1), b), (1.0, y, 300.0))
              for y, a, b in ((-18.3, 6.0, 3.0), (0.0, -5.0, -2.0), (18.3, 7.0, 1.0))]
    xyz, ids = render([(v, t, T) for T in truths], floor_z_mm=330)
    assert _digest(fit_parts(xyz, ids > 0, v, t, intrinsics=K_TEST, params=off)) == OLD["three_nuts"]
    A = pose(rotation((1, 0.3, 0), 20), (45, -20, 300))
    B = pose(rotation((-0.736, -0.163, -0.482), 42.67), (15, 10, 305))
    plate = (np.array([[19.0, -300, 0], [-281, -300, 0], [-281, 300, 0], [19.0, 300, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    xyz, ids = render([(v, t, A), (v, t, B), (*plate, pose(np.eye(3), (0, 0, 285)))], floor_z_mm=330)
    fits = fit_parts(xyz, (ids == 1) | (ids == 2), v, t, intrinsics=K_TEST, params=off)
    assert _digest(fits) == OLD["occluded"]


def test_the_claim_params_say_what_is_wrong():
    with pytest.raises(ParameterError, match="claim"):
        FitParams(claim=1)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="max_overlap"):
        FitParams(max_overlap=1.5)


def test_the_model_knows_its_inside():
    v, t = hex_nut_mesh()
    m = prepare_model(v, t)
    assert len(m.inside) == 400 and m.contains(m.inside).mean() > 0.97  # the voxels: a 64th of the box
    assert not m.contains(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]])).any()  # the bore, far away
    s = prepare_model(*icosphere(10.0, 4))
    assert s.contains(s.centroid[None]).all() and not s.contains(s.centroid[None] + 10.5).any()


def test_the_fitting_and_the_vetting_measure_overlap_by_one_rule():
    """The fitting's overlap test (``_Claims.overlapping``) and the vetting's (``instance_overlaps``) are
    one function on one solid (the prepared model's is the vetting's: the same samples and grid), so a pair
    is refused by one exactly when the other vets it out; and the fits made with claims leave the vetting
    nothing to drop."""
    from zcut import fit_vetting as fv
    from zcut.fits.fit import _Claims

    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    built = fv.solid_of(v, t)
    assert model.occupancy is not None and built.occupancy is not None and built.ball is None
    np.testing.assert_array_equal(built.inside, model.inside)
    np.testing.assert_array_equal(built.occupancy[2], model.occupancy[2])
    rng = np.random.default_rng(11)
    base = pose(rotation((1, 0.2, 0), 30), (0, 0, 300))
    poses = [base]
    for _ in range(40):
        T = base.copy()
        ax = rng.normal(size=3)
        T[:3, :3] = rotation((float(ax[0]), float(ax[1]), float(ax[2])), float(rng.uniform(0, 60))) @ base[:3, :3]
        T[:3, 3] = base[:3, 3] + rng.uniform(-14, 14, 3)
        poses.append(T)
    pairs, share = fv.instance_overlaps(v, t, poses, solid=model.solid)
    assert np.array_equal(fv.instance_overlaps(v, t, poses)[1], share)  # the mesh's own solid: the same
    worst = np.zeros(len(poses))
    for (a, b), s in zip(pairs.tolist(), share.tolist()):
        if 0 in (a, b):
            worst[b if a == 0 else a] = max(worst[b if a == 0 else a], s)
    claims = _Claims(model, FitParams(), 1)
    claims.add(base, 0.1, (np.zeros(0, np.int64), np.zeros(0)))
    refused = np.array([bool(claims.overlapping(T)) for T in poses[1:]])
    assert refused.any() and (~refused).any()
    np.testing.assert_array_equal(refused, worst[1:] > FitParams().max_overlap)
    truths = [pose(rotation((1, 0, 0), a) @ rotation((0, 0, 1), b), (1.0, y, 300.0))
              for y, a, b in ((-18.3, 6.0, 3.0), (0.0, -5.0, -2.0), (18.3, 7.0, 1.0))]
    xyz, ids = render([(v, t, T) for T in truths], floor_z_mm=330)
    fits = fit_prepared(xyz, ids > 0, model, intrinsics=K_TEST)
    _, share = fv.instance_overlaps(v, t, [f.pose for f in fits])
    assert len(fits) == 3 and (share.size == 0 or share.max() <= fv.MAX_OVERLAP)
