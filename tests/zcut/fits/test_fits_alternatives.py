"""The second pass's next-best guesses (``FitParams.seed_alternatives``, docs/fits.md "Twentieth round"): a region
whose best pose was refused for entering an accepted fit's solid tries its next-best guesses that do not.

Without them the fits are the previous tree's to the bit; with them no two fits share more volume than the claims
allow, and the choice among the guesses is the one the docstring states."""

from __future__ import annotations

import numpy as np
import pytest
from fit_digests import digest, hand_made, holed

from zcut.errors import ParameterError
from zcut.fit_vetting import pose_overlaps
from zcut.fits import FitParams, fit_prepared
from zcut.fits.fit import _alternatives

#: the fits of the hand-made frames (tests/zcut/fits/fit_digests.py) of the tree before the lever (0a99bf5):
#: (number of fits, digest), whole (False) and holed (True)
PREVIOUS = {
    ("zinc_nuts", False): (241, "3d62a8a46cb79e55"), ("zinc_nuts", True): (98, "91e10c51207c49e3"),
    ("black_nuts", False): (283, "39f35a01a616c513"), ("rods", True): (28, "0e4c6b60c2be0bf9"),
}


@pytest.mark.parametrize("key", sorted(PREVIOUS))
def test_without_alternatives_the_fits_are_the_previous_trees_to_the_bit(key: tuple[str, bool]) -> None:
    kind, hole = key
    xyz, zone, model, K = hand_made(kind)
    fits = fit_prepared(holed(xyz) if hole else xyz, zone, model, intrinsics=K,  # type: ignore[arg-type]
                        params=FitParams(seed_alternatives=0))
    assert (len(fits), digest(fits)) == PREVIOUS[key]


def test_with_alternatives_more_nuts_are_fitted_and_no_two_share_volume() -> None:
    xyz, zone, model, K = hand_made("zinc_nuts")
    p = FitParams(seed_alternatives=1)
    fits = fit_prepared(xyz, zone, model, intrinsics=K, params=p)  # type: ignore[arg-type]
    assert len(fits) > PREVIOUS[("zinc_nuts", False)][0]
    poses = np.stack([f.pose for f in fits])
    c = poses[:, :3, :3] @ model.centroid + poses[:, :3, 3]  # type: ignore[attr-defined]
    i, j = np.nonzero(np.triu(np.linalg.norm(c[:, None] - c[None], axis=2) < 2.0 * model.extent_mm, 1))  # type: ignore[attr-defined]
    share = np.maximum(pose_overlaps(model.solid, poses[i], poses[j]),  # type: ignore[attr-defined]
                       pose_overlaps(model.solid, poses[j], poses[i]))  # type: ignore[attr-defined]
    assert len(i) and float(share.max()) <= p.max_overlap
    # each fit's pixels are its own (the assignment gives a pixel to one fit)
    allpix = np.concatenate([f.pixels for f in fits])
    assert len(np.unique(allpix)) == len(allpix)


class _Avoid:
    """Claims whose solids a pose enters when its translation's x is in ``bad``."""

    def __init__(self, bad: set[float]) -> None:
        self.bad = bad

    def overlapping(self, T: np.ndarray) -> list[int]:
        return [0] if float(T[0, 3]) in self.bad else []


class _Model:
    centroid = np.zeros(3)


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_alternatives_are_the_best_scored_guesses_that_enter_no_solid_one_a_place() -> None:
    xs = np.array([0.0, 5.0, 10.0, 10.5, 20.0, 30.0])  # guess i's coarse pose lies at x = xs[i]
    scores = [0.9, 0.8, 0.7, 0.95, 0.6, 0.7]  # 3 (at 10.5) best, then 0, 1, then 2 and 5 tied, then 4
    Rs = np.repeat(np.eye(3)[None], len(xs), axis=0)
    ts = np.stack([[x, 0.0, 0.0] for x in xs])
    calls: list[float] = []

    def search(R: np.ndarray, t: np.ndarray, stop: bool) -> tuple[float, np.ndarray] | None:
        assert len(R) == 1 and not stop  # each guess alone, no early stop
        i = int(np.flatnonzero(xs == t[0, 0])[0])
        return scores[i], _pose(float(t[0, 0]))

    def refine(T0: np.ndarray) -> tuple[np.ndarray, float]:
        calls.append(float(T0[0, 3]))
        return T0, float(T0[0, 3])

    # the best (10.5) enters a solid; 0 is next; 10.0 lies within 1 mm of 10.5 (one place, already judged)
    got = _alternatives(Rs, ts, search, refine, _Model(), 2, _Avoid({10.5}))  # type: ignore[arg-type]
    assert [e for _, e in got] == [0.0, 5.0] and calls == [0.0, 5.0]
    calls.clear()
    got = _alternatives(Rs, ts, search, refine, _Model(), 3, _Avoid({10.5, 0.0}))  # type: ignore[arg-type]
    assert [e for _, e in got] == [5.0, 30.0, 20.0]  # 10.0 is 10.5's place; of 2 and 5 tied only 5 is left
    got = _alternatives(Rs, ts, search, refine, _Model(), 2, _Avoid(set(xs.tolist())))  # type: ignore[arg-type]
    assert got == []
    got = _alternatives(Rs[:0], ts[:0], search, refine, _Model(), 2, None)  # type: ignore[arg-type]
    assert got == []


def test_the_alternatives_param_says_what_is_wrong() -> None:
    with pytest.raises(ParameterError, match="seed_alternatives"):
        FitParams(seed_alternatives=-1)
    with pytest.raises(ParameterError, match="seed_alternatives"):
        FitParams(seed_alternatives=1.5)  # type: ignore[arg-type]
