"""The fits stopped part-way (:mod:`zcut.cancel`; docs/labelling.md, the section of the round of 2026-12-07a): inside
a :func:`zcut.cancel.stop_when` scope the fits' driver loop raises :class:`zcut.errors.Cancelled` at the first stop
point after the check says stop — between regions and candidates — and a scope whose check never says stop changes
no fit. The pins of the defaults' fits (tests/zcut/fits/fit_digests.py) hold outside a scope."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from fit_digests import degenerate_frames, digest
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation
from prepared_models import prepared

from zcut.cancel import stop_point, stop_when
from zcut.errors import Cancelled, ZcutError
from zcut.fits import fit_prepared

#: three nuts: two apart, one on its side (three regions, several candidates)
POSES = [pose(rotation((1, 0.3, 0), 160), (5, -3, 300)), pose(rotation((0.2, 1, 0), 30), (-25, 10, 310)),
         pose(rotation((1, 0, 0), 90), (28, 18, 305))]


@pytest.fixture(scope="module")
def scene():
    v, t = hex_nut_mesh()
    xyz, ids = render([(v, t, T) for T in POSES], floor_z_mm=320)
    return xyz, ids > 0, prepared(v, t)


class _Counter:
    """A check that says stop from its ``at``-th call on (never when ``at`` is None), counting its calls."""

    def __init__(self, at: int | None = None) -> None:
        self.at = at
        self.calls = 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.at is not None and self.calls >= self.at


def test_a_scope_that_never_stops_changes_no_fit(scene):
    xyz, zone, model = scene
    plain = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    check = _Counter()
    with stop_when(check):
        scoped = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    assert len(plain) == 3 and digest(scoped) == digest(plain)
    assert [f.err_mm for f in scoped] == [f.err_mm for f in plain]
    assert check.calls >= 6  # each region, and each candidate in it


def test_a_stop_at_any_stop_point_ends_the_fit_there(scene):
    xyz, zone, model = scene
    n = _Counter()
    with stop_when(n):
        full = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    for at in sorted({1, 2, n.calls // 2, n.calls}):
        check = _Counter(at)
        with stop_when(check), pytest.raises(Cancelled, match="stopped by the caller"):
            fit_prepared(xyz, zone, model, intrinsics=K_TEST)
        assert check.calls == at  # raised at the stop point that saw it, not later
    # the scope left, the same fits again (nothing of the stopped fits stayed behind)
    assert len(full) == 3 and digest(fit_prepared(xyz, zone, model, intrinsics=K_TEST)) == digest(full)


def test_with_nothing_to_fit_a_stop_changes_nothing(scene):
    """Degenerate frames (an empty zone, all NaN, one pixel, 0 × W, 1 × 1) and a frame half invalid: no region
    reaches a stop point, or the same fits."""
    xyz, zone, model = scene
    for x, z in degenerate_frames(xyz, zone):
        with stop_when(lambda: True):
            assert fit_prepared(x, z, model, intrinsics=K_TEST) == []
    half = xyz.copy()
    half[:, :160] = np.nan
    with stop_when(lambda: False):
        scoped = fit_prepared(half, zone, model, intrinsics=K_TEST)
    assert digest(scoped) == digest(fit_prepared(half, zone, model, intrinsics=K_TEST))


def test_the_scope_is_the_innermost_one_of_this_thread():
    stop_point()  # outside every scope: nothing
    seen: list[BaseException | None] = []

    def other() -> None:
        try:
            stop_point()
            seen.append(None)
        except Cancelled as e:  # pragma: no cover - the failure this test looks for
            seen.append(e)

    with stop_when(lambda: True):
        with pytest.raises(Cancelled) as got:
            stop_point()
        assert isinstance(got.value, ZcutError) and str(got.value).count("\n") == 0
        th = threading.Thread(target=other)
        th.start()
        th.join()
        assert seen == [None]  # another thread is outside this thread's scope
        with stop_when(lambda: False):
            stop_point()  # the inner scope decides
        with pytest.raises(Cancelled):
            stop_point()  # and the outer one is back
    stop_point()
