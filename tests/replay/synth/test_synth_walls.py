"""Piles leaning on the bin walls (``zcut synth --pile walls``, issue 31 item 2), both generators:
the parts touch the walls the frame leans on, the same seed gives the same bytes, the floor piles
are byte for byte what they were, and bad values are one line."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
from cli_helpers import run_cli

from replay.presets import BIN
from replay.synth import BinShape, synthesize_frame, write_synthetic_log
from replay.synth.scene import WALL_SETS, check_pile, lean_walls, tilt_vector, wall_distance_mm
from zcut.errors import ParameterError

SIZE = (60, 96)
#: sha256 of main's floor-pile logs before the option existed (same name, same arguments; the ray-traced one since
#: the hits are float64 Möller–Trumbore's, round of 2026-12-06e: this CPU's and an emulated Haswell's, docs/synthetic.md
#: "Exact hits"):
#: ``zcut synth -o walls_d_hm.mcap --parts zinc_nuts --size 96x60 --frames 2 --seed 5`` and
#: ``zcut synth -o walls_d_rt.mcap --parts spheres --size 96x60 --seed 5 --sensor raytraced``
FLOOR_DIGESTS = {
    "handmade": "79f8a902bba8b825c9282a507c5e69e418e8c643ad068706e8ecdbf6198f93ce",
    "raytraced": "8d581a7097e411450749152e8148c03ba5aa17d1db0618fdef85ef93544cb56d",
}


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _to_bin(xy_world: np.ndarray, pose) -> np.ndarray:
    """World (x, y) -> the bin frame's (u, v)."""
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    x = xy_world[..., 0] - pose.x_mm
    y = xy_world[..., 1] - pose.y_mm
    return np.stack([c * x + s * y, -s * x + c * y], -1)


def _wall_gap_mm(p_bin: np.ndarray, wall: str) -> np.ndarray:
    """Distance (mm) of bin-frame points to one wall's plane (positive inside the bin)."""
    axis = 0 if wall[1] == "x" else 1
    sign = 1.0 if wall[0] == "+" else -1.0
    half = BIN.floor_half[axis]
    d = math.radians(BIN.draft_deg)
    x = sign * p_bin[..., axis] - half
    return -x * math.cos(d) + (p_bin[..., 2] - BIN.floor_mm) * math.sin(d)


def _handmade_part_gaps(scene, wall: str) -> np.ndarray:
    """Per part, the smallest distance of its surface (its bottom and top on every node) to ``wall``."""
    g = scene.grid
    out = []
    for p in scene.parts:
        X, Y = np.meshgrid(g.xs[p.cols], g.ys[p.rows])
        uv = _to_bin(np.stack([X, Y], -1), scene.bin_pose)
        gaps = [_wall_gap_mm(np.concatenate([uv, z[..., None]], -1), wall) for z in (p.bottom, p.top)]
        out.append(float(np.nanmin(np.fmin(*gaps))))
    return np.array(out)


#: numpy's AVX-512 kernels (``np.sin``, ``np.exp``, ... on machines that have them) round a few last bits
#: differently from its AVX2 ones, and the logs were pinned on machines without AVX-512: the pinned logs
#: are made with numpy's dispatch capped at AVX2 (X86_V3), the same bytes on any x86-64 machine that has it.
NUMPY_AT_AVX2 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}


def test_floor_logs_are_byte_for_byte_mains(tmp_path):
    import json
    import os
    import subprocess
    import sys

    from numpy._core._multiarray_umath import __cpu_features__ as features

    if not (features.get("AVX2") and features.get("FMA3")):
        pytest.skip("the pinned logs are numpy's AVX2 kernels' bytes; this machine has no AVX2")
    code = (
        "import hashlib, json, sys\n"
        "from pathlib import Path\n"
        "from replay.synth import write_synthetic_log\n"
        "from replay.synth.raytrace import write_raytraced_log\n"
        "d = Path(sys.argv[1])\n"
        f"hm = write_synthetic_log(d / 'walls_d_hm.mcap', kind='zinc_nuts', frames=2, seed=5, size={SIZE})\n"
        f"rt = write_raytraced_log(d / 'walls_d_rt.mcap', kind='spheres', frames=1, seed=5, size={SIZE})\n"
        "print(json.dumps({k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in "
        "(('handmade', hm), ('raytraced', rt))}))\n"
    )
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=False,
                       env={**os.environ, **NUMPY_AT_AVX2})
    assert p.returncode == 0, p.stderr[-3000:]
    got = json.loads(p.stdout.strip().splitlines()[-1])
    assert got["handmade"] == FLOOR_DIGESTS["handmade"]
    assert got["raytraced"] == FLOOR_DIGESTS["raytraced"]


def test_lean_walls_is_seeded_and_draws_every_set():
    drawn = [lean_walls(seed, i) for seed in range(40) for i in range(3)]
    assert drawn == [lean_walls(seed, i) for seed in range(40) for i in range(3)]
    assert set(drawn) == set(WALL_SETS)
    gu, gv = tilt_vector(("+x", "-y"), 15.0)
    assert math.hypot(gu, gv) == pytest.approx(math.tan(math.radians(15.0)))
    assert gu > 0 > gv


def test_wall_distance_on_and_beside_the_walls():
    fx, fy = BIN.floor_half
    d = math.radians(BIN.draft_deg)
    z = BIN.floor_mm + 50.0
    on_wall = fx + 50.0 * math.tan(d)  # the +x face 50 mm above the floor
    p = np.array([[on_wall, 0.0, z], [on_wall - 10.0, 0.0, z], [0.0, 0.0, z], [np.nan, 0.0, z]])
    got = wall_distance_mm(p)
    assert got[0] == pytest.approx(0.0, abs=1e-9)
    assert got[1] == pytest.approx(10.0 * math.cos(d))
    assert got[2] == pytest.approx((fy + 50.0 * math.tan(d)) * math.cos(d))  # the nearer, long walls
    assert np.isnan(got[3])
    # above the rim, beside the +x wall's top edge: the distance to that edge
    top = np.array([[BIN.inner_top_half[0], 0.0, BIN.height_mm + 7.0]])
    assert wall_distance_mm(top)[0] == pytest.approx(7.0, abs=1e-6)


@pytest.mark.parametrize("kind, seed", [("spheres", 21), ("zinc_nuts", 22)])
def test_handmade_pile_leans_on_its_walls(kind, seed):
    sf = synthesize_frame(kind=kind, seed=seed, size=SIZE, pile="walls")
    scene = sf.scene
    assert scene.walls == lean_walls(seed, 0)
    floor = synthesize_frame(kind=kind, seed=seed, size=SIZE)
    assert floor.scene.walls == ()
    assert np.array_equal(sf.T_cam_bin, floor.T_cam_bin)  # the floor pile's bin pose
    for wall in scene.walls:
        gaps = _handmade_part_gaps(scene, wall)
        touching = int(np.count_nonzero(gaps <= 2.0))
        assert touching >= 10, (wall, touching)
        assert gaps.min() >= -1e-6  # never through the wall
        # the floor pile keeps its parts' footprints over the floor: a few come near the wall's foot
        near = int(np.count_nonzero(_handmade_part_gaps(floor.scene, wall) <= 2.0))
        assert 3 * near <= touching, (wall, near, touching)
    # no part sticks out of the bin, and the pile is higher on the walls' side
    assert max(float(np.nanmax(p.top)) for p in scene.parts) <= BIN.height_mm
    gu, gv = tilt_vector(scene.walls)
    ctr = np.array([_to_bin(p.centre_mm[:2], scene.bin_pose) for p in scene.parts])
    toward = ctr @ np.array([gu, gv])
    heights = np.array([p.centre_mm[2] for p in scene.parts])
    assert heights[toward > 0].mean() > heights[toward < 0].mean() + 5.0


def test_handmade_walls_pile_is_deterministic(tmp_path):
    for d in "abc":
        (tmp_path / d).mkdir()
    a = write_synthetic_log(tmp_path / "a" / "w.mcap", kind="spheres", seed=23, size=SIZE, pile="walls")
    b = write_synthetic_log(tmp_path / "b" / "w.mcap", kind="spheres", seed=23, size=SIZE, pile="walls")
    floor = write_synthetic_log(tmp_path / "c" / "w.mcap", kind="spheres", seed=23, size=SIZE)
    assert _sha(a) == _sha(b) != _sha(floor)
    from replay.logs.reader import LogReader

    meta = LogReader(a).metadata["zcut.synth"]
    assert meta["pile"] == "walls" and meta["pile_walls"] == ",".join(lean_walls(23, 0))
    assert "pile" not in LogReader(floor).metadata["zcut.synth"]


def test_raytraced_pile_leans_on_its_walls():
    from replay.synth.raytrace.meshes import part_mesh
    from replay.synth.raytrace.pile import drop_parts
    from replay.synth.scene import BinPose

    pose = BinPose(math.radians(2.0), 5.0, -3.0)
    local = part_mesh("zinc_nuts")  # nuts stay where they slid; balls roll back off the wall once it is upright

    def drop(walls):
        pile = drop_parts("zinc_nuts", pose, np.random.default_rng(7), count=60, walls=walls)
        gaps, centres = [], []
        for i in range(len(pile)):
            v = local.vertices @ pile.R[i].T + pile.t_mm[i]
            p = np.concatenate([_to_bin(v[:, :2], pose), v[:, 2:]], -1)
            gaps.append(float(_wall_gap_mm(p, "+x").min()))
            centres.append(_to_bin(pile.t_mm[i, :2], pose))
        return pile, np.array(gaps), np.array(centres)

    pile, gaps, centres = drop(("+x",))
    again, _, _ = drop(("+x",))
    assert np.array_equal(pile.t_mm, again.t_mm) and np.array_equal(pile.R, again.R)
    assert len(pile) == 60 and pile.escaped == 0
    assert np.count_nonzero(gaps <= 2.0) >= 10
    assert gaps.min() >= -1.0  # the solver lets contacts sink by a fraction of a millimetre
    _, _, floor_centres = drop(())
    assert centres[:, 0].mean() > floor_centres[:, 0].mean() + 100.0


def test_raytraced_walls_log(tmp_path):
    from replay.logs.reader import LogReader
    from replay.synth.raytrace import write_raytraced_log

    log = write_raytraced_log(tmp_path / "rt.mcap", kind="spheres", seed=24, size=(30, 48), pile="walls")
    meta = LogReader(log).metadata["zcut.synth"]
    assert meta["pile_walls"] == ",".join(lean_walls(24, 0))
    assert meta["pile_tilt_deg"] == "30" and "against the walls" in meta["pile"]


def test_bad_piles_are_refused():
    with pytest.raises(ParameterError, match="pile must be one of floor, walls, got 'wall'"):
        check_pile("wall")
    with pytest.raises(ParameterError, match="not an empty bin"):
        synthesize_frame(empty=True, size=SIZE, pile="walls")
    with pytest.raises(ParameterError, match="nominal bin"):
        synthesize_frame(size=SIZE, pile="walls", bin_shape=BinShape(bulge_mm=1.0))
    with pytest.raises(ParameterError, match="opposite walls"):
        tilt_vector(("+x", "-x"))


@pytest.mark.parametrize("argv, what", [
    (["--pile", "wall"], "argument --pile: invalid choice: 'wall'"),
    (["--pile", "walls", "--empty"], "--pile walls needs parts to pile"),
    (["--pile", "walls", "--bin-bulge-mm", "1"], "--pile walls needs the nominal bin"),
    (["--pile", "walls", "--empty", "--sensor", "raytraced"], "--pile walls needs parts to pile"),
])
def test_cli_refuses_in_one_line(capsys, tmp_path, argv, what):
    out = tmp_path / "x.mcap"
    rc, stdout, err = run_cli(capsys, "synth", "-o", out, "--size", "96x60", *argv)
    assert rc == 1 and stdout == ""
    lines = [ln for ln in err.splitlines() if not ln.startswith("zcut: compiling")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and what in lines[0], err
    assert not out.exists()


def test_cli_writes_a_walls_pile(capsys, tmp_path):
    out = tmp_path / "w.mcap"
    rc, _, err = run_cli(capsys, "synth", "-o", out, "--size", "96x60", "--seed", "23", "--pile", "walls")
    assert rc == 0, err
    (tmp_path / "ref").mkdir()
    ref = write_synthetic_log(tmp_path / "ref" / "w.mcap", kind="spheres", seed=23, size=SIZE, pile="walls")
    assert _sha(out) == _sha(ref)
