"""zcut.fit_vetting's second fact: a part never lies behind the bin or the table (issue 29, docs/labelling.md
"Fifth round: fits of ghosts beside the walls").

Closed forms first: a floor and a wall sampled as the pipeline's bin model is (points with normals turned towards
the camera), a box sunk into one by a known depth lies behind it by the share of its volume beyond k × Err; a box
touching it, or beside it, by none; the table alone the same. Then :func:`vet_fits` with the shares: a fit behind
the bin is out whatever its support and suppresses nothing; without shares (or all of them below the threshold) the
vetting is the overlap rule's, unchanged.
"""

from __future__ import annotations

import numpy as np
import pytest
from explained_helpers import box_mesh

from zcut import explained as ex
from zcut import fit_vetting as fv
from zcut.errors import InputShapeError, ParameterError

F_PX = 1000.0  # 0.6 mm footprints at 600 mm
SIGMA = 0.1
FLOOR_Z = 600.0


def _floor_and_wall() -> ex.KnownSurfaces:
    """A floor at z = 600 mm (normals to the camera: −z) and a wall x = 60 mm (the bin's inside at x < 60, normals
    −x), sampled every 0.5 mm, the bin's σ 0.1 mm."""
    g = np.arange(-80.0, 80.01, 0.5)
    X, Y = np.meshgrid(g, g)
    floor = np.stack([X.ravel(), Y.ravel(), np.full(X.size, FLOOR_Z)], axis=1)
    floor = floor[floor[:, 0] <= 60.0]
    Yw, Zw = np.meshgrid(g, np.arange(500.0, FLOOR_Z + 0.01, 0.5))
    wall = np.stack([np.full(Yw.size, 60.0), Yw.ravel(), Zw.ravel()], axis=1)
    pts = np.concatenate([floor, wall])
    nrm = np.concatenate([np.tile([0.0, 0.0, -1.0], (len(floor), 1)), np.tile([-1.0, 0.0, 0.0], (len(wall), 1))])
    return ex.KnownSurfaces(bin_points=(pts, nrm), bin_spacing_mm=0.5, bin_err_mm=SIGMA)


def _box_solid(lo, hi) -> tuple[fv.Solid, np.ndarray]:
    v, t = box_mesh(np.asarray(lo, float), np.asarray(hi, float))
    return fv.solid_of(v, t), np.eye(4)


def _at(z_mm: float) -> float:
    """k × the bin's Err at depth z."""
    c = z_mm / F_PX
    return fv.BEHIND_ERRS * float(np.sqrt(SIGMA**2 + 0.5 * c * c))


def test_a_box_sunk_into_the_floor_lies_behind_it_by_its_share_beyond_k_err():
    s = _floor_and_wall()
    solid, eye = _box_solid([-10, -10, 590], [10, 10, 610])  # half of it below the floor
    share = fv.behind_shares(solid, [eye], s, f_px=F_PX)[0]
    want = (610.0 - (FLOOR_Z + _at(FLOOR_Z))) / 20.0
    assert abs(share - want) < 0.06  # 400 samples: binomial error ±0.025
    above, _ = _box_solid([-10, -10, 580], [10, 10, 599.8])  # resting on it
    assert fv.behind_shares(above, [eye], s, f_px=F_PX)[0] == 0.0
    # within k × Err behind the floor: the bin's own noise, not behind it
    shallow, _ = _box_solid([-10, -10, 581], [10, 10, FLOOR_Z + 0.9 * _at(FLOOR_Z)])
    assert fv.behind_shares(shallow, [eye], s, f_px=F_PX)[0] == 0.0


def test_a_box_crossing_the_wall_lies_behind_it_one_beside_it_does_not():
    s = _floor_and_wall()
    solid, _ = _box_solid([-4, -10, -10], [4, 10, 10])  # 8 mm across the wall
    T = np.eye(4)
    poses = []
    for x in (66.0, 55.8, 20.0):  # crossing the wall by 10 mm, touching it, far
        P = T.copy()
        P[:3, 3] = [x, 0.0, 585.0]
        poses.append(P)
    share = fv.behind_shares(solid, poses, s, f_px=F_PX)
    # behind: beyond k Err of the wall and within k Err + the search band of its samples
    want = (min(70.0, 60.0 + _at(585.0) + fv.BEHIND_SEARCH_MM) - (60.0 + _at(585.0))) / 8.0
    assert abs(share[0] - want) < 0.06 and share[0] > fv.MAX_BEHIND
    np.testing.assert_array_equal(share[1:], [0.0, 0.0])


def test_beyond_the_search_radius_the_bin_says_nothing_the_table_does():
    s = _floor_and_wall()
    solid, eye = _box_solid([-10, -10, 640], [10, 10, 660])  # 40-60 mm below the floor: beyond the search band
    assert fv.behind_shares(solid, [eye], s, f_px=F_PX)[0] == 0.0
    table = ex.Plane(np.array([0.0, 0.0, 1.0]), 650.0, residual_mm=0.2)
    with_table = ex.KnownSurfaces(bin_points=s.bin_points, bin_err_mm=SIGMA, table=table)
    c = 655.0 / F_PX
    want = (660.0 - (650.0 + fv.BEHIND_ERRS * np.sqrt(0.04 + 0.5 * c * c))) / 20.0
    assert abs(fv.behind_shares(solid, [eye], with_table, f_px=F_PX)[0] - want) < 0.06
    # the plane's orientation does not matter: the camera's side is the origin's
    flipped = ex.KnownSurfaces(table=ex.Plane(np.array([0.0, 0.0, -1.0]), -650.0, residual_mm=0.2))
    assert abs(fv.behind_shares(solid, [eye], flipped, f_px=F_PX)[0] - want) < 0.06


def test_nothing_to_be_behind_gives_zero_shares_and_bad_focal_lengths_are_one_line():
    solid, eye = _box_solid([-10, -10, 590], [10, 10, 610])
    np.testing.assert_array_equal(fv.behind_shares(solid, [eye, eye], ex.KnownSurfaces(), f_px=F_PX), [0.0, 0.0])
    assert fv.behind_shares(solid, np.zeros((0, 4, 4)), _floor_and_wall(), f_px=F_PX).shape == (0,)
    v, t = box_mesh(np.array([-10.0, -10.0, 590.0]), np.array([10.0, 10.0, 610.0]))
    opened = fv.solid_of(v, t[:-2])  # no inside: never behind
    assert fv.behind_shares(opened, [eye], _floor_and_wall(), f_px=F_PX)[0] == 0.0
    with pytest.raises(ParameterError, match="focal length"):
        fv.behind_shares(solid, [eye], _floor_and_wall(), f_px=float("nan"))


def test_a_fit_behind_the_bin_is_out_whatever_its_support_and_suppresses_nothing():
    true = box_mesh(np.array([-20.0, -20.0, 500.0]), np.array([20.0, 20.0, 520.0]))
    ghost = (true[0] + np.array([0.0, 0.0, -2.0]), true[1])  # overlaps the part by 90 %
    overlaps = fv.part_overlaps([true, ghost])
    support = np.array([300, 1000])  # the ghost explains more: alone, the vetting keeps it
    np.testing.assert_array_equal(fv.vet_fits(overlaps, support).kept, [False, True])
    v = fv.vet_fits(overlaps, support, behind=np.array([0.0, 0.7]))
    np.testing.assert_array_equal(v.kept, [True, False])
    assert v.by[1] == -1 and v.overlap[1] == 0.0 and v.by[0] == -1
    np.testing.assert_array_equal(v.behind, [0.0, 0.7])
    # shares at or below the threshold change nothing: the overlap rule's result, field for field
    for behind in (None, np.zeros(2), np.array([fv.MAX_BEHIND, 0.01])):
        a, b = fv.vet_fits(overlaps, support), fv.vet_fits(overlaps, support, behind=behind)
        for f in ("kept", "overlap", "by"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert fv.vet_fits(overlaps, support, behind=np.array([0.2, 0.2]), max_behind=0.25).kept.tolist() == [False, True]


@pytest.mark.parametrize("kw, error, match", [
    ({"behind": np.zeros(3)}, InputShapeError, "one share per fit"),
    ({"behind": np.zeros((2, 1))}, InputShapeError, "one share per fit"),
    ({"max_behind": 1.0}, ParameterError, "max_behind"),
    ({"max_behind": float("nan")}, ParameterError, "max_behind"),
])
def test_bad_behind_inputs_are_one_line(kw, error, match):
    with pytest.raises(error, match=match):
        fv.vet_fits((np.zeros((0, 2), np.int64), np.zeros(0)), np.ones(2), **kw)
