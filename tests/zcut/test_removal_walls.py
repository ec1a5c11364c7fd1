"""τ on a pile leaning on the walls (issue 31): part faces in the ring do not drive the tolerance.

On hand-made walls piles the faces of parts heaped against an upper wall lie in the frame's certain bin
pixels, a few millimetres in front of the wall and coherent with each other: on 3 of 12 hand-made walls
frames they were more than 1 % of the ring and τ, the 99th percentile of the coherent residuals + 1 mm,
rose to 3.5-5.2 mm at a correct pose (docs/bin_robustness.md, "Issue 31: τ on walls piles"). The ray-cast
scene of ``test_bin_check.py``, with blocks of its upper walls moved in front of them.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_bin_check import filled, model, on_inner_wall, pose  # noqa: F401  (fixtures)

from zcut.params import RemovalParams
from zcut.removal import frame_tolerance, prepare_removal_index, remove_table_and_bin


def leaning(xyz, ring, T, mm, share):
    """``xyz`` with patches of the inner wall faces' ring pixels moved ``mm`` towards the bin's inside (part
    faces leaning on the walls), at least ``share`` of the ring, and their flat indices."""
    wall = on_inner_wall(xyz, ring, T, 25.0)
    idx = np.argwhere(wall)
    want = int(np.ceil(share * np.count_nonzero(ring)))
    picked = np.zeros_like(wall)
    # 6 x 6 blocks of wall pixels spread along the walls, until the share is reached
    for r0, c0 in idx[:: max(1, len(idx) // 60)]:
        picked[r0:r0 + 6, c0:c0 + 6] = True
        if np.count_nonzero(picked & wall) >= want:
            break
    face = np.flatnonzero(picked & wall)
    moved = xyz.copy().reshape(-1, 3)
    x = moved[face, 0] - T[0, 3]
    moved[face, 0] -= np.sign(x) * np.float32(mm / 1000.0)
    return moved.reshape(xyz.shape), face


@pytest.mark.parametrize("dx_mm", [0.0, 2.0])
def test_part_faces_leaning_on_a_wall_do_not_raise_the_tolerance(model, filled, dx_mm):  # noqa: F811
    xyz, fp, ring = filled
    T = pose(dx_mm)
    index = prepare_removal_index(model, RemovalParams())
    clean = frame_tolerance(xyz, ring, index, T)
    moved, face = leaning(xyz, ring, pose(), 4.0, 0.03)
    assert len(face) >= 0.03 * np.count_nonzero(ring)
    tol = frame_tolerance(moved, ring, index, T)
    ref = frame_tolerance(moved, ring, index, T, reference=True)
    # the previous estimator took the parts' 4 mm (+ the 1 mm margin) at the true pose; now τ stays the
    # wall's: its noise at the true pose, the pose error's 2 mm otherwise
    assert tol.tolerance_mm == pytest.approx(clean.tolerance_mm, abs=0.05), (tol, clean)
    assert tol.tolerance_mm < dx_mm + 2.0
    # left out: the parts' faces (but their edges, off their neighbours' median: not coherent), and at a
    # pose 2 mm off a corner pixel or so whose nearest model point jumps to the other face
    assert 0.8 * len(face) <= tol.n_off_field <= 1.1 * len(face)
    assert (tol.tolerance_mm, tol.reach_mm, tol.n_off_field, tol.n_coherent) == \
        (ref.tolerance_mm, ref.reach_mm, ref.n_off_field, ref.n_coherent)
    # the clean frame at the true pose: nothing off the field (2 mm off, a few corner pixels whose nearest
    # model point is on the other face, below the percentile: the same τ as the previous estimator's)
    assert clean.n_off_field == 0 if dx_mm == 0 else clean.n_off_field < 0.01 * clean.n_pixels


def test_the_parts_leaning_on_a_wall_stay_in_the_zone(model, filled):  # noqa: F811
    xyz, fp, ring = filled
    T = pose()
    moved, face = leaning(xyz, ring, T, 4.0, 0.03)
    index = prepare_removal_index(model, RemovalParams())
    r = remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring)
    ref = remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring, reference=True)
    assert np.array_equal(r.zone, ref.zone) and r.tolerance_mm == ref.tolerance_mm
    # 4 mm in front of the wall, beyond τ + the stragglers' 2 mm: the parts' faces are not bin
    assert r.tolerance_mm < 2.0
    assert r.zone.reshape(-1)[face].mean() > 0.9
    # and the wall around them still is
    wall = on_inner_wall(xyz, ring, T, 25.0).reshape(-1)
    wall[face] = False
    assert not r.zone.reshape(-1)[wall].any()


def test_a_pose_far_off_keeps_the_previous_estimator(model, filled):  # noqa: F811
    # 30 mm off no residual field fits (its nearest model points lie on the wrong faces): nothing is left
    # out and τ is the previous one, at its cap
    xyz, _, ring = filled
    index = prepare_removal_index(model, RemovalParams())
    tol = frame_tolerance(xyz, ring, index, pose(30.0))
    assert tol.n_off_field == 0 and tol.tolerance_mm == 8.0
