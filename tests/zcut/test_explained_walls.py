"""``explained`` judges the pixels the removal labelled bin (``run_explained(judge_removed_bin=True)``):
a point in front of a wall farther than k × Err from the bin model is an outlier by the paper's
definition even when the removal's tolerance (τ plus the straggler pass's margin) took it as bin
(issue 31; docs/bin_robustness.md, "Issue 31: piles leaning on the walls — `explained`").

A real log (``zcut synth --pile walls``, hand-made spheres at 480 × 300, where 3 × the bin's Err is
below τ plus the straggler margin) with one wall pixel moved along the wall's inward normal, the whole
pipeline run on the moved frame: a removal whose tolerance reaches τ plus the straggler margin (fixed: with
issue 31 item 2's bound on, ``straggler_bound``, the straggler pass itself stops at 3 of the bin's Err and leaves
such a point in the zone) labels it bin; ``explained`` flags it only when it judges the removal's bin pixels, and only when
it lies beyond k × Err (not at half of it).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zcut import explained as ex

SIZE = "480x300"


@pytest.fixture(scope="module")
def walls(tmp_path_factory):
    from cli.main import main
    from replay.options import PipelineOptions
    from replay.pipeline.stages import bin_zone

    log = tmp_path_factory.mktemp("walls") / "spheres_walls.mcap"
    assert main(["synth", "-o", str(log), "--parts", "spheres", "--frames", "1", "--seed", "9643", "--size", SIZE,
                 "--pile", "walls"]) == 0
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frames = session.located()  # the frame as read: the methods run on it below, not also here
    frame, _ = next(frames)
    frames.close()
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    return session, frame, zone


@pytest.fixture(scope="module")
def judged_run(walls):
    """``run_explained(judge_removed_bin=True)`` of the walls frame, and the ``zone_err`` each call of the missed
    instances on top was given (the vetting's Err image of the zone, or None): computed once, for the tests
    that read it (the wrapper that records ``zone_err`` passes every argument on)."""
    from replay.pipeline import explained as pe

    session, frame, zone = walls
    real = pe._with_top_pieces
    given = []

    def reuse(*args, zone_err=None, **kw):
        given.append(zone_err)
        return real(*args, zone_err=zone_err, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pe, "_with_top_pieces", reuse)
        out = pe.run_explained(frame, zone, session.config, judge_removed_bin=True)
    return out, given


def _wall_pixel(frame, zone, session):
    """A wall pixel the removal labelled bin with its 8 neighbours, away from the ring and the rim: its
    (row, col), its inward unit normal (camera frame) and its Err against the bin (mm)."""
    from replay.pipeline.explained import bin_and_table_surfaces

    rem, reg, model = zone.removal, zone.located.registration, zone.located.bin_model
    assert rem is not None and reg is not None and model is not None and model.normals is not None
    xyz = frame.xyz.astype(np.float64) * 1000.0
    s = bin_and_table_surfaces(xyz, rem, reg, model, ex.KnownSurfaces())
    T = np.asarray(reg.T_cam_bin, np.float64)
    pts = 1000.0 * (model.points @ T[:3, :3].T) + 1000.0 * T[:3, 3]
    nrm = model.normals @ T[:3, :3].T
    centre = pts.mean(axis=0)
    b = rem.bin_points
    inner = b.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            inner[1:-1, 1:-1] &= b[1 + dr:b.shape[0] - 1 + dr, 1 + dc:b.shape[1] - 1 + dc]
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    if zone.located.ring is not None:
        inner &= ~zone.located.ring
    from scipy.spatial import cKDTree

    rows, cols = np.nonzero(inner)
    _, j = cKDTree(pts).query(xyz[rows, cols], k=1)
    n = nrm[j]
    on_wall = np.abs(n @ (T[:3, :3] @ np.array([0.0, 0.0, 1.0]))) < 0.2  # the normal across the bin's axis
    assert on_wall.sum() > 100
    i = np.flatnonzero(on_wall)[on_wall.sum() // 2]
    r, c = int(rows[i]), int(cols[i])
    n_in = n[i] * np.sign(np.dot(centre - xyz[r, c], n[i]))
    K = frame.intrinsics
    assert K is not None
    foot = abs(xyz[r, c, 2]) / (0.5 * (K.fx + K.fy))
    p = session.config.bank["explained"]
    err = max(p.err_floor_mm, float(np.sqrt(s.bin_err_mm ** 2 + 0.5 * foot ** 2)))
    return (r, c), n_in, err


def _moved(frame, rc, n_in, d_mm):
    xyz = frame.xyz.copy()
    xyz[rc] = xyz[rc] + (d_mm / 1000.0) * n_in.astype(np.float32)
    return dataclasses.replace(frame, xyz=xyz)


@pytest.mark.slow
def test_a_point_the_removal_took_beyond_k_err_of_the_wall_is_unexplained(walls):
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone
    from zcut.prepared_model import prepare_bin_model

    session, frame, zone = walls
    rc, n_in, err = _wall_pixel(frame, zone, session)
    p = session.config.bank["explained"]
    assert zone.removal is not None
    reach = zone.removal.tolerance_mm + session.config.removal.straggler_mm
    assert p.k * err + 0.3 < reach, f"3 Err {p.k * err:.2f} mm is not below the removal's reach {reach:.2f} mm"
    # with the bound on, the straggler pass stops at 3 of the bin's Err: the point beyond stays in the zone
    far = _moved(frame, rc, n_in, 0.5 * (p.k * err + reach))
    for which, kept in (("global", True), ("below_rim", True), ("off", False)):  # the pixel lies below the rim band
        rp = dataclasses.replace(session.config.removal, straggler_bound=which)
        z0 = bin_zone(far, dataclasses.replace(session.config, removal=rp),
                      bin_model=prepare_bin_model(session.bin_model, registration=session.config.registration,
                                                  removal=rp))
        assert z0.removal is not None and z0.zone[rc] == kept, which
    # a removal whose tolerance reaches τ + straggler_mm (fixed) takes it
    config = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal, tolerance_mm=reach))
    prepared = prepare_bin_model(session.bin_model, registration=config.registration, removal=config.removal)
    for d_mm, beyond in ((0.5 * (p.k * err + reach), True), (0.5 * p.k * err, False)):
        moved = _moved(frame, rc, n_in, d_mm)
        z = bin_zone(moved, config, bin_model=prepared)
        assert z.removal is not None and z.removal.bin_points[rc], "the removal no longer labels the point bin"
        plain, _, _ = run_explained(moved, z, config)
        judged, d, _ = run_explained(moved, z, config, judge_removed_bin=True)
        assert not plain[rc]  # the removal took it: never judged
        assert judged[rc] == beyond, (d_mm, err)
        # the zone's outliers are the same; what it adds is the removal's bin pixels beyond k × Err
        np.testing.assert_array_equal(judged & z.zone, plain)
        added = judged & ~z.zone
        assert not (added & ~z.removal.bin_points).any()
        assert d is not None
        assert (d.dist_mm[added] > p.k * d.err_mm[added]).all()
        assert np.array_equal(d.unexplained, judged)
        # the point's distance is the one to the bin model
        assert d.surface[rc] == ex.SURFACE_BIN and abs(d.dist_mm[rc] - d_mm) < 0.1


@pytest.mark.slow
def test_without_a_part_model_the_removals_bin_pixels_are_not_judged(walls):
    """The local surface (no part model) is measured in the zone only: the flag changes nothing."""
    from replay.pipeline.explained import run_explained

    session, frame, zone = walls
    p = dataclasses.replace(session.config.bank["explained"], part_model="")
    config = dataclasses.replace(session.config, bank={**session.config.bank, "explained": p})
    plain, _, _ = run_explained(frame, zone, config)
    judged, _, _ = run_explained(frame, zone, config, judge_removed_bin=True)
    np.testing.assert_array_equal(judged, plain)


@pytest.mark.slow
def test_one_search_judges_the_removals_bin_pixels_as_the_merge_did(walls, judged_run, monkeypatch):
    """The removal's bin pixels are judged in the zone's own search (the judged set widened, the outliers
    masked with the zone and those pixels): the same outliers, distances, surfaces and Err as the previous
    implementation, a second search over them with the final surfaces merged into the zone's images (its
    body transcribed here as the oracle)."""
    from replay.pipeline.explained import run_explained

    session, frame, zone = walls
    config = session.config
    p = config.bank["explained"]
    assert zone.removal is not None
    real = ex.err_image
    calls = []

    def spy(nearest, surfaces, footprint, **kw):
        calls.append((nearest, surfaces, footprint, kw))
        return real(nearest, surfaces, footprint, **kw)

    monkeypatch.setattr(ex, "err_image", spy)
    plain, d0, _ = run_explained(frame, zone, config)
    near, surfaces, foot, kw = calls[-1]  # the final Err image: the final nearest surfaces and known surfaces
    assert kw.get("where") is None and np.array_equal(near.dist_mm, d0.dist_mm, equal_nan=True)
    monkeypatch.setattr(ex, "err_image", real)
    (judged, d, _), _ = judged_run  # run_explained(frame, zone, config, judge_removed_bin=True)
    # the previous removed_bin_judged
    xyz = frame.xyz.astype(np.float64) * 1000.0
    where = zone.removal.bin_points & ~zone.zone
    nb = ex.nearest_surface(xyz, surfaces, where=where)
    eb = real(nb, surfaces, foot, floor_mm=p.err_floor_mm)
    w = ~np.isnan(nb.dist_mm)
    assert w.sum() > 10_000
    assert d is not None
    np.testing.assert_array_equal(d.dist_mm, np.where(w, nb.dist_mm, near.dist_mm))
    np.testing.assert_array_equal(d.surface, np.where(w, nb.surface, near.surface))
    np.testing.assert_array_equal(d.err_mm, np.where(w, eb, d0.err_mm))
    np.testing.assert_array_equal(judged, plain | ex.unexplained(nb.dist_mm, eb, p.k))
    assert (judged & ~zone.zone).any() or not ex.unexplained(nb.dist_mm, eb, p.k).any()


@pytest.mark.slow
def test_the_missed_instances_on_top_reuse_the_vettings_err(walls, judged_run, monkeypatch):
    """When the vetting leaves every fit in, the missed instances on top read its Err image of the zone
    instead of computing it again: the same outputs as with it computed again."""
    from replay.pipeline import explained as pe

    session, frame, zone = walls
    real = pe._with_top_pieces
    reused, given = judged_run  # the method as it is: the image it was given passed on

    def again(*args, zone_err=None, **kw):  # the image computed again, as before
        return real(*args, **kw)

    monkeypatch.setattr(pe, "_with_top_pieces", again)
    outs = [reused, pe.run_explained(frame, zone, session.config, judge_removed_bin=True)]
    assert given[0] is not None  # no fit vetted out on this frame: the vetting's image was passed in
    (o1, d1, _), (o2, d2, _) = outs
    assert d1 is not None and d2 is not None and len(d1.fits) > 0
    np.testing.assert_array_equal(o1, o2)
    for a, b in ((d1.dist_mm, d2.dist_mm), (d1.surface, d2.surface), (d1.err_mm, d2.err_mm)):
        np.testing.assert_array_equal(a, b)
    assert d1.top_pieces == d2.top_pieces and len(d1.fits) == len(d2.fits)
