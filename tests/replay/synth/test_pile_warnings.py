"""MuJoCo's warnings while a pile settles are the pile's and the user's, not a ``MUJOCO_LOG.TXT``
written into the working directory (it was once committed to the repository by accident)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")


def test_the_warnings_are_collected_and_the_handler_restored(tmp_path, monkeypatch):
    from replay.synth.raytrace.pile import mujoco_warnings

    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size="0.1"/></body></worldbody></mujoco>')
    data = mujoco.MjData(model)
    data.qvel[0] = np.nan
    before = mujoco.get_mju_user_warning()
    with mujoco_warnings() as warned:
        mujoco.mj_step(model, data)
    assert len(warned) == 1 and "QVEL" in warned[0] and "unstable" in warned[0]
    assert mujoco.get_mju_user_warning() is before
    assert list(tmp_path.iterdir()) == []


def test_an_unstable_pile_says_so_in_the_pile_and_on_stderr_and_writes_no_file(tmp_path, monkeypatch, capsys):
    """Seed 913, rods, frame 0 (docs/raytraced.md): the simulation goes unstable and is simulated again
    (tests/replay/synth/test_pile_unstable.py); the line carries MuJoCo's words without a doubled full stop."""
    from cli.main import main

    monkeypatch.chdir(tmp_path)
    assert main(["synth", "--sensor", "raytraced", "--parts", "rods", "--seed", "913", "--frames", "1",
                 "--size", "160x100", "-o", "rods.mcap"]) == 0
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "the pile's simulation went unstable" in x)
    assert line.startswith("zcut: frame 1: ") and "The simulation is unstable" in line and "simulated again with" in line
    assert ".)" not in line and ".;" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rods.mcap"]


def test_a_stable_pile_warns_of_nothing(tmp_path, monkeypatch):
    from replay.synth.raytrace.pile import drop_parts
    from replay.synth.scene import BinPose

    monkeypatch.chdir(tmp_path)
    pile = drop_parts("spheres", BinPose(0.0, 0.0, 0.0), np.random.default_rng(3), count=20)
    assert pile.warnings == () and len(pile) == 20
    assert list(tmp_path.iterdir()) == []
