"""The seeded states the page's fitter keeps (annotate.fits.Fitter.fits_for; docs/labelling.md, "Judging fits"):
a new seed costs one refit however many came before it, past the :data:`annotate.fits.SEEDED_KEPT` states kept
too, and the fits with the seeds are the same as applying every seed in turn from the background fits.

The background fits are stand-ins with :meth:`seeded` (a Fitter only walks them): each records its seeds, so what
a walk returns says which seeds were applied, in which order, to which background fits.
"""

from __future__ import annotations

import numpy as np

from annotate import fits as af


class _Fits:
    """Stands for a frame's fits: the seeds applied so far, and a count of every refit on the frame."""

    status = "ready"

    def __init__(self, seeds: tuple = (), calls: list | None = None, root: object = None) -> None:
        self.seeds = seeds
        self.calls = [] if calls is None else calls
        self.root = self if root is None else root

    def seeded(self, x, y, xyz, config):
        assert xyz.shape == (4, 5, 3) and xyz.dtype == np.float64
        self.calls.append((x, y))
        return _Fits((*self.seeds, (x, y)), self.calls, self.root)


def _fitter(root: _Fits) -> af.Fitter:
    fitter = af.Fitter(None, None, lambda i: np.zeros((4, 5, 3), np.float32), model_name="m", model_points=[], k=3.0)
    fitter.results[0] = root  # type: ignore[assignment]
    return fitter


def test_each_new_seed_costs_one_refit_past_the_states_kept():
    root = _Fits()
    fitter = _fitter(root)
    seeds = [(i, 2 * i) for i in range(af.SEEDED_KEPT * 2 + 5)]
    for n in range(1, len(seeds) + 1):
        before = len(root.calls)
        got = fitter.fits_for(0, seeds[:n])
        assert got.seeds == tuple(seeds[:n]) and got.root is root
        assert len(root.calls) - before == 1, n
        assert len(fitter._seeded) <= af.SEEDED_KEPT
    again = len(root.calls)
    assert fitter.fits_for(0, seeds).seeds == tuple(seeds) and len(root.calls) == again  # kept: no refit


def test_a_prefix_no_longer_kept_is_walked_from_the_longest_one_kept():
    root = _Fits()
    fitter = _fitter(root)
    long = [(i, 0) for i in range(af.SEEDED_KEPT + 10)]
    for n in range(1, len(long) + 1):
        fitter.fits_for(0, long[:n])
    # the first prefixes went out; asking for one walks from the background fits again, seed by seed
    before = len(root.calls)
    got = fitter.fits_for(0, long[:3])
    assert got.seeds == tuple(long[:3]) and len(root.calls) - before == 3
    # a branch off a kept prefix refits only the new seed
    before = len(root.calls)
    got = fitter.fits_for(0, [*long[:40], (99, 99)])
    assert got.seeds == (*long[:40], (99, 99)) and len(root.calls) - before == 1


def test_new_background_fits_are_not_served_from_states_of_the_old_ones():
    old = _Fits()
    fitter = _fitter(old)
    assert fitter.fits_for(0, [(1, 1), (2, 2)]).root is old
    new = _Fits()
    fitter.results[0] = new  # type: ignore[assignment]
    got = fitter.fits_for(0, [(1, 1), (2, 2)])
    assert got.root is new and got.seeds == ((1, 1), (2, 2)) and len(new.calls) == 2


def test_no_seeds_or_no_fits_give_the_background_fits():
    root = _Fits()
    fitter = _fitter(root)
    assert fitter.fits_for(0, ()) is root and fitter.fits_for(1, [(0, 0)]) is None and not root.calls
    root.status = "error"
    assert fitter.fits_for(0, [(0, 0)]) is root and not root.calls
