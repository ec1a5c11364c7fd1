"""A ray-traced pile keeps its parts (docs/raytraced.md, the section of the round of 2026-12-07b): a stable simulation
that lost parts (through the floor, mostly) is simulated again like an unstable one (a thicker floor, then smaller
steps: :data:`replay.synth.raytrace.pile.RETRIES`); when every simulation tried loses some, the one that lost the
fewest is kept and ``zcut synth`` warns in one line. A pile whose first simulation keeps every part is that
simulation's to the bit (the pinned ray-traced frames: tests/replay/synth/test_camera_filters.py,
test_synth_walls.py)."""

from __future__ import annotations

import numpy as np
import pytest

from replay.presets import BIN

mujoco = pytest.importorskip("mujoco")


def _drop(kind: str, seed: int, *, count: int | None = None):
    """The pile ``zcut synth --sensor raytraced`` drops for frame 0 of ``seed`` (its draws, in its order); ``count``
    instead of the drawn part count (a cheaper pile, the same draws)."""
    from replay.synth.raytrace.pile import drop_parts, part_count
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, MAX_PARTS, raytrace_rng
    from replay.synth.synthesize import bin_pose_for, frame_rng

    pose = bin_pose_for(frame_rng(seed, 0, empty=False), empty=False, index=0)
    rng = raytrace_rng(seed, 0, empty=False)
    drawn = min(part_count(kind, float(rng.uniform(*FILL_RANGE_MM))), MAX_PARTS)
    n = drawn if count is None else count
    return drop_parts(kind, pose, rng, count=n), n, rng


def test_lost_parts_are_under_the_floor_beside_or_above_the_bin():
    from replay.synth.raytrace.pile import UNDER_FLOOR_MM, lost_parts

    fx, fy = BIN.floor_half
    margin = 10 * BIN.draft_deg
    floor, r = BIN.floor_mm, 41.0
    p = np.array([
        [0.0, 0.0, floor + 8.0],                    # on the floor
        [fx - 1.0, -fy + 1.0, floor + 8.0],         # in a corner
        [0.0, 0.0, floor - UNDER_FLOOR_MM + 1e-9],  # sunk, but not through
        [0.0, 0.0, floor - UNDER_FLOOR_MM],         # under the floor, exactly at the limit
        [10.0, 5.0, -6000.0],                       # fell through the floor and on
        [fx + margin, 0.0, 50.0],                   # beside the bin, exactly at the limit
        [0.0, -fy - margin - 5.0, 50.0],            # beside the bin
        [0.0, 0.0, BIN.height_mm + 3 * r],          # above the bin, exactly at the limit
        [0.0, 0.0, BIN.height_mm + 3 * r - 1e-9],   # in the bin (high on the pile)
        [np.nan, 0.0, 50.0],                        # nowhere
    ])
    lost, under = lost_parts(p, radius_mm=r)
    assert lost.tolist() == [False, False, False, True, True, True, True, True, False, True]
    assert under == 2
    lost, under = lost_parts(np.zeros((0, 3)), radius_mm=r)
    assert lost.shape == (0,) and under == 0


def test_the_lines_of_zcut_synth_for_a_pile_that_lost_parts():
    from cli.commands.synth import pile_lines
    from replay.synth.raytrace.pile import LossyRun, Pile, UnstableRun

    R, t = np.tile(np.eye(3), (5, 1, 1)), np.zeros((5, 3))
    kept_all = Pile("rods", R, t, 1.5, False, 0, (), 0.004, 100.0, (), (LossyRun(0.004, 10.0, 3, 2),), 0)
    assert pile_lines(0, kept_all) == [
        "zcut: frame 1: the pile's simulation lost 3 of 5 part(s) (2 under the floor, 1 beside or above the bin) "
        "with a 10 mm floor at a 4 ms step; simulated again with a 100 mm floor at a 4 ms step: stable, 5 part(s) "
        "in the bin, 0 fell out"]
    lossy = (LossyRun(0.004, 10.0, 5, 5), LossyRun(0.004, 100.0, 3, 2), LossyRun(0.002, 100.0, 4, 4))
    still = Pile("sprockets", R, t, 1.5, False, 2, (), 0.001, 100.0, (), lossy, 2)
    assert pile_lines(2, still) == [
        "zcut: frame 3: the pile's simulation lost 5 of 7 part(s) (5 under the floor) with a 10 mm floor at a 4 ms "
        "step (and 2 more simulation(s) that lost parts); simulated again with a 100 mm floor at a 1 ms step: "
        "stable, 5 part(s) in the bin, 2 fell out",
        "zcut: frame 3: warning: the pile lost 2 of its 7 part(s) (2 under the floor) in the best of 4 simulations "
        "tried; the frame holds 5"]
    said = "Nan, Inf or huge value in QACC at DOF 442. The simulation is unstable. Time = 1.4800."
    both = Pile("rods", R, t, 1.5, False, 1, (), 0.002, 100.0, (UnstableRun(0.004, 10.0, 1.48, said),),
                (LossyRun(0.004, 100.0, 2, 0),), 0)
    assert pile_lines(0, both) == [
        "zcut: frame 1: the pile's simulation went unstable (MuJoCo: Nan, Inf or huge value in QACC at DOF 442. The "
        "simulation is unstable. Time = 1.4800) and lost 2 of 6 part(s) (2 beside or above the bin) with a 100 mm "
        "floor at a 4 ms step; simulated again with a 100 mm floor at a 2 ms step: stable, 5 part(s) in the bin, 1 "
        "fell out",
        "zcut: frame 1: warning: the pile lost 1 of its 6 part(s) (1 beside or above the bin) in the best of 3 "
        "simulations tried; the frame holds 5"]
    first = Pile("rods", R, t, 1.5, False, 1, (), 0.004, 10.0, (), (LossyRun(0.004, 100.0, 3, 3),), 1)
    assert pile_lines(0, first)[0].endswith("; simulated again, the first simulation kept with a 10 mm floor at a "
                                            "4 ms step: stable, 5 part(s) in the bin, 1 fell out")
    alone = Pile("rods", R, t, 1.5, False, 1, (), 0.004, 10.0, (), (), 1)
    assert pile_lines(0, alone) == ["zcut: frame 1: warning: the pile lost 1 of its 6 part(s) (1 under the floor) in "
                                    "its simulation; the frame holds 5"]
    for pile in (kept_all, still, both, first, alone):
        for text in pile_lines(0, pile):
            assert "\n" not in text and ".;" not in text and ".)" not in text and ". (" not in text


def test_a_pile_that_lost_parts_is_simulated_again_and_keeps_them(monkeypatch):
    """Twelve sprockets (two layers of the column, seed 4's draws): the first simulation loses 3 through the 10 mm
    floor; the first retry (100 mm floor, 2 ms, contacts of 8 ms) keeps all 12, and the frame's later draws are as
    without a retry."""
    from cli.commands.synth import pile_lines
    from replay.synth.raytrace import pile as P
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, raytrace_rng

    pile, n, rng = _drop("sprockets", 4, count=12)
    (first,) = pile.lossy
    assert (first.floor_thickness_mm, first.time_step_s, first.contact_time_s) == (
        P.FLOOR_THICKNESS_MM, P.TIME_STEP_S, P.CONTACT_TIME_S)
    assert first.lost == first.under_floor > 0 and pile.unstable == ()
    floor_mm, divisor, contact_s = P.RETRIES[0]
    assert (pile.floor_thickness_mm, pile.time_step_s, pile.contact_time_s) == (
        floor_mm, P.TIME_STEP_S / divisor, contact_s)
    assert len(pile) == n and pile.escaped == pile.under_floor == 0
    assert np.isfinite(pile.t_mm).all() and (pile.t_mm[:, 2] > BIN.floor_mm).all()
    fresh = raytrace_rng(4, 0, empty=False)
    fresh.uniform(*FILL_RANGE_MM)
    fresh.uniform(-0.02, 0.02, (n, 2)), fresh.standard_normal((n, 4)), fresh.normal(0.0, 0.05, (n, 2))
    assert rng.bit_generator.state == fresh.bit_generator.state
    (line,) = pile_lines(0, pile)
    assert line.startswith(f"zcut: frame 1: the pile's simulation lost {first.lost} of 12 part(s) ({first.lost} under "
                           "the floor) with a 10 mm floor at a 4 ms step; simulated again with a 100 mm floor at a "
                           "2 ms step and contacts of 8 ms: stable, 12 part(s) in the bin, 0 fell out")

    # every retry loses as many: the later of the tie is kept, and zcut synth warns
    monkeypatch.setattr(P, "RETRIES", ((P.FLOOR_THICKNESS_MM, 1, P.CONTACT_TIME_S),))
    still, _, _ = _drop("sprockets", 4, count=12)
    assert still.lossy == (first,) and still.escaped == still.under_floor == first.lost
    assert len(still) == n - first.lost
    assert pile_lines(0, still)[-1] == (f"zcut: frame 1: warning: the pile lost {first.lost} of its 12 part(s) "
                                        f"({first.lost} under the floor) in the best of 2 simulations tried; the "
                                        f"frame holds {n - first.lost}")


def test_a_pile_that_keeps_its_parts_is_its_first_simulation(monkeypatch):
    """Twelve sprockets of seed 1 keep all their parts at once: no retry, the same pile as without any."""
    from replay.synth.raytrace import pile as P

    pile, n, _ = _drop("sprockets", 1, count=12)
    assert pile.lossy == pile.unstable == () and len(pile) == n and pile.escaped == 0
    monkeypatch.setattr(P, "RETRIES", ())
    alone, _, _ = _drop("sprockets", 1, count=12)
    assert alone.R.tobytes() == pile.R.tobytes() and alone.t_mm.tobytes() == pile.t_mm.tobytes()
