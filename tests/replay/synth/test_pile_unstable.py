"""A ray-traced pile whose simulation went unstable is simulated again with a smaller time step (docs/raytraced.md, the
section of the round of 2026-12-07a): MuJoCo resets an unstable state to the start and warns "The simulation is
unstable"; such a simulation is thrown away (``Pile.unstable``), the same start simulated again with a thicker floor,
then smaller steps (:data:`replay.synth.raytrace.pile.RETRIES`), and refused in one line when none is stable. A pile whose first simulation is stable is that simulation's to the bit
(the ray-traced logs' pinned digests: tests/replay/synth/test_synth_walls.py, test_camera_filters.py). And ``zcut
synth`` says it in one line each, MuJoCo's words without their full stop (cli/commands/synth.py)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")


def _drop(kind: str, seed: int, index: int = 0):
    """The pile ``zcut synth --sensor raytraced`` drops for frame ``index`` of ``seed`` (its draws, in its order)."""
    from replay.synth.raytrace.pile import drop_parts, part_count
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, MAX_PARTS, raytrace_rng
    from replay.synth.synthesize import bin_pose_for, frame_rng

    pose = bin_pose_for(frame_rng(seed, index, empty=False), empty=False, index=index)
    rng = raytrace_rng(seed, index, empty=False)
    count = min(part_count(kind, float(rng.uniform(*FILL_RANGE_MM))), MAX_PARTS)
    return drop_parts(kind, pose, rng, count=count), count, rng


def test_an_unstable_simulation_is_simulated_again_and_keeps_its_parts(tmp_path, monkeypatch):
    """Seed 913, rods, frame 0: unstable at 4 ms (52 of 76 parts fell out before); stable with a thicker floor."""
    from replay.synth.raytrace.pile import FLOOR_THICKNESS_MM, TIME_STEP_S
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, raytrace_rng

    monkeypatch.chdir(tmp_path)
    pile, count, rng = _drop("rods", 913)
    (first,) = pile.unstable
    assert (first.time_step_s, first.floor_thickness_mm) == (TIME_STEP_S, FLOOR_THICKNESS_MM)
    assert "The simulation is unstable" in first.warning and 0 < first.at_s <= 1.5
    assert pile.floor_thickness_mm > FLOOR_THICKNESS_MM and not any("unstable" in w for w in pile.warnings)
    assert len(pile) + pile.escaped == count and pile.escaped <= 2
    assert np.isfinite(pile.t_mm).all() and (pile.t_mm[:, 2] > 0).all()
    # the frame's later draws (the ray tracer's) are as without a retry: drop_parts drew its start once
    fresh = raytrace_rng(913, 0, empty=False)
    fresh.uniform(*FILL_RANGE_MM)
    fresh.uniform(-0.02, 0.02, (count, 2)), fresh.standard_normal((count, 4)), fresh.normal(0.0, 0.05, (count, 2))
    assert rng.bit_generator.state == fresh.bit_generator.state
    assert list(tmp_path.iterdir()) == []


def test_unstable_at_every_step_is_refused_in_one_line(monkeypatch):
    from replay.synth.raytrace import pile as P
    from zcut.errors import ParameterError

    monkeypatch.setattr(P, "RETRIES", ((10.0, 1, P.CONTACT_TIME_S),))  # the first simulation again: unstable again
    with pytest.raises(P.UnstablePile) as got:
        _drop("rods", 913)
    e = got.value
    assert isinstance(e, ParameterError) and "\n" not in str(e) and len(e.runs) == 2
    assert str(e).startswith("the pile's simulation (76 rods) went unstable in every way tried (10 mm floor at 4 ms, "
                             "10 mm floor at 4 ms; MuJoCo: Nan, Inf or huge value in QACC")
    assert str(e).endswith("); try another seed") and ".)" not in str(e)


def test_the_lines_of_zcut_synth_carry_mujocos_words_without_a_doubled_full_stop():
    from cli.commands.synth import pile_lines
    from replay.synth.raytrace.pile import Pile, UnstableRun

    said = "Nan, Inf or huge value in QACC at DOF 442. The simulation is unstable. Time = 1.4800."
    R, t = np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 3))
    pile = Pile("rods", R, t, 1.2, True, 1, (), 0.002, 100.0, (UnstableRun(0.004, 10.0, 1.48, said),
                                                              UnstableRun(0.004, 100.0, 0.9, said)))
    line, lost = pile_lines(0, pile)  # the part still lost: a warning of its own (tests/replay/synth/test_pile_kept.py)
    assert lost.startswith("zcut: frame 1: warning: the pile lost 1 of its 4 part(s)")
    assert line == ("zcut: frame 1: the pile's simulation went unstable (MuJoCo: Nan, Inf or huge value in QACC at DOF "
                    "442. The simulation is unstable. Time = 1.4800) (and 1 retry(ies) after it); simulated again "
                    "with a 100 mm floor at a 2 ms step: stable, 3 part(s) in the bin, 1 fell out")
    warned = Pile("rods", R, t, 1.5, False, 0, ("Too many contacts. Time = 0.5000.", "again."))
    (line,) = pile_lines(4, warned)
    assert line == ("zcut: frame 5: the pile's simulation warned: Too many contacts. Time = 0.5000 (and 1 more); "
                    "0 part(s) fell out of the bin")
    assert pile_lines(0, Pile("rods", R, t, 0.4, True, 0)) == []
    for text in (*pile_lines(0, pile), *pile_lines(4, warned)):
        assert ".;" not in text and ".)" not in text and ". (" not in text
