"""``explained`` vets out the fits that lie behind the registered bin or the table (zcut.fit_vetting.behind_shares;
docs/labelling.md, "Fifth round: fits of ghosts beside the walls").

A real log of a pile leaning on the walls (``zcut synth --pile walls``, hand-made zinc nuts, 320 × 200): the
registered bin model's normals face the camera, so a kept fit moved out through the nearest wall (beyond the rule's
tolerance) lies behind it and the same fit in place does not; the scene's true parts (rebuilt from the synthesis, read only to check) never
lie behind it; the method's fits and distances with the rule are those of its kept fits judged from scratch, and a
frame where the rule vets nothing out gives the same result, array for array, as the method without the rule.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from explained_helpers import handmade_true_surfaces

from cli.main import main
from zcut import explained as ex
from zcut import fit_vetting as fv

SEED = 9645


@pytest.fixture(scope="module")
def walls(tmp_path_factory):
    """(session, frame, zone, run_explained's output) of the first frame of a walls log."""
    from replay.options import PipelineOptions
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone

    log = tmp_path_factory.mktemp("walls") / "walls.mcap"
    assert main(["synth", "-o", str(log), "--parts", "zinc_nuts", "--frames", "1", "--seed", str(SEED),
                 "--size", "320x200", "--pile", "walls"]) == 0
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frames = session.located()  # the frame as read: its filter methods are run once, below, not also here
    frame, _ = next(frames)
    frames.close()
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    return session, frame, zone, run_explained(frame, zone, session.config)


def _surfaces_and_focal(frame, zone):  # type: ignore[no-untyped-def]
    from replay.pipeline.explained import bin_and_table_surfaces

    xyz = frame.xyz.astype(np.float64) * 1000.0
    assert zone.removal is not None and zone.located.registration is not None and zone.located.bin_model is not None
    s = bin_and_table_surfaces(xyz, zone.removal, zone.located.registration, zone.located.bin_model, ex.KnownSurfaces())
    K = frame.intrinsics
    assert K is not None
    return xyz, s, 0.5 * (K.fx + K.fy)


@pytest.mark.slow
def test_a_fit_pushed_through_the_wall_lies_behind_it_in_place_it_does_not(walls):
    session, frame, zone, (_, d, _) = walls
    assert d is not None and d.fits
    xyz, s, f_px = _surfaces_and_focal(frame, zone)
    from replay.pipeline.explained import part_model

    p = session.config.bank["explained"]
    _, _, prepared = part_model(p.part_model, p.part_model_unit)
    poses = np.stack([f.pose for f in d.fits])
    share = fv.behind_shares(prepared.solid, poses, s, f_px=f_px, floor_mm=p.err_floor_mm)
    assert (share <= fv.MAX_BEHIND).all()  # the kept fits
    # each fit moved out through the wall or floor along the normal of the bin sample nearest its origin, its origin
    # in the middle of the band the rule reads: k × the bin's Err behind the surface, plus half the search band
    from scipy.spatial import cKDTree

    pts, nrm = s.bin_points
    _, j = cKDTree(pts).query(poses[:, :3, 3])
    c = pts[j, 2] / f_px
    depth = fv.BEHIND_ERRS * np.maximum(p.err_floor_mm, np.sqrt(s.bin_err_mm**2 + 0.5 * c * c)) + fv.BEHIND_SEARCH_MM / 2
    pushed = poses.copy()
    pushed[:, :3, 3] = pts[j] - depth[:, None] * nrm[j]
    moved = fv.behind_shares(prepared.solid, pushed, s, f_px=f_px, floor_mm=p.err_floor_mm)
    # the band behind the walls is BEHIND_SEARCH_MM deep: a nut across it lies in it by half or more; below the floor,
    # the table's side takes the rest
    assert np.median(moved) > fv.MAX_BEHIND and (moved > 0.3).mean() > 0.9, moved


@pytest.mark.slow
def test_the_true_parts_never_lie_behind_the_registered_bin(walls):
    from replay.synth.synthesize import synthesize_frame

    session, frame, zone, _ = walls
    xyz, s, f_px = _surfaces_and_focal(frame, zone)
    sf = synthesize_frame(kind="zinc_nuts", seed=SEED, index=0, size=frame.xyz.shape[:2], pile="walls")
    assert np.array_equal(sf.frame.xyz, frame.xyz, equal_nan=True)
    parts, _ = handmade_true_surfaces(sf)
    assert parts
    floor = session.config.bank["explained"].err_floor_mm
    share = [fv.behind_shares(fv.Solid(inside=fv.inside_samples(v, t), occupancy=None, ball=None), [np.eye(4)], s,
                              f_px=f_px, floor_mm=floor)[0] for v, t in parts]
    assert max(share) <= fv.MAX_BEHIND, max(share)


@pytest.mark.slow
def test_the_method_with_the_rule_is_its_kept_fits_from_scratch_and_without_it_when_it_vets_nothing(walls, monkeypatch):
    session, frame, zone, (out, d, _) = walls
    from replay.pipeline.explained import run_explained

    assert d is not None
    for f in d.vetted_behind:
        assert any(f is g for g in d.vetted_out)
    xyz, s, _ = _surfaces_and_focal(frame, zone)
    kept = [(d.instance_mesh(i), d.triangles) for i in range(len(d.fits))]
    surfaces = dataclasses.replace(s, parts=kept, part_err_mm=[f.err_mm for f in d.fits])
    full = ex.nearest_surface(xyz, surfaces, where=zone.zone)
    # the nearest surfaces exactly; the distances to within float32 rounding: a top piece the method found is
    # measured on its own pixels (zcut.top_pieces), not in one search among all (as tests/zcut/test_explained_top_pieces.py)
    np.testing.assert_array_equal(d.surface, full.surface)
    np.testing.assert_allclose(d.dist_mm, full.dist_mm, rtol=0, atol=1e-4)
    # the rule switched off (no fit behind anything): the same fits, distances, Err and outliers when it vetted none
    monkeypatch.setattr(fv, "behind_shares", lambda solid, poses, *a, **k: np.zeros(len(poses)))
    out0, d0, _ = run_explained(frame, zone, session.config)
    assert d0 is not None and not d0.vetted_behind
    if not d.vetted_behind:
        np.testing.assert_array_equal(out, out0)
        for name in ("dist_mm", "surface", "err_mm", "unexplained"):
            np.testing.assert_array_equal(getattr(d, name), getattr(d0, name))
        assert [f.pose.tobytes() for f in d.fits] == [f.pose.tobytes() for f in d0.fits]
