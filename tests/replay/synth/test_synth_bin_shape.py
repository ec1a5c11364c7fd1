"""A bin that is not the nominal one (scale, bulge, per-scan deformation) and the nominal CAD bin."""

from __future__ import annotations

import numpy as np
import pytest

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.pipeline.bin_model import load_bin_model
from replay.synth import BIN, LABEL_PART, LABEL_RIM, LABEL_WALL, BinPose, BinShape
from replay.synth.scene import bin_height_field, bin_mesh_mm, make_grid
from replay.synth.synthesize import synthesize_frame
from zcut.errors import ParameterError

SIZE = (60, 96)


@pytest.fixture(scope="module")
def grid():
    return make_grid(half_x_mm=230, half_y_mm=180, step_mm=0.5)


def _inner_half_x_at(grid, height, label, z_mm):
    """Half length (mm) of the bin's opening at height ``z_mm`` along the x axis (y = 0)."""
    row = height[np.argmin(np.abs(grid.ys))]
    xs = grid.xs
    inside = (np.abs(xs) < 190) & (row < z_mm)
    return float(np.max(np.abs(xs[inside])))


def test_the_nominal_shape_is_the_nominal_bin(grid):
    h0, l0 = bin_height_field(grid, BinPose())
    h1, l1 = bin_height_field(grid, BinPose(), deformation=BinShape().realise(None))
    assert np.array_equal(h0, h1) and np.array_equal(l0, l1)
    a = synthesize_frame(kind="rods", seed=3, size=SIZE)
    b = synthesize_frame(kind="rods", seed=3, size=SIZE, bin_shape=BinShape())
    assert np.array_equal(a.frame.xyz, b.frame.xyz, equal_nan=True) and np.array_equal(a.truth, b.truth)


def test_scale_grows_the_whole_bin(grid):
    h, lab = bin_height_field(grid, BinPose(), deformation=BinShape(scale=1.01).realise(None))
    assert h[lab == LABEL_RIM].max() == pytest.approx(BIN.height_mm * 1.01)
    h0, lab0 = bin_height_field(grid, BinPose())
    mid = 0.5 * BIN.height_mm
    assert _inner_half_x_at(grid, h, lab, mid) - _inner_half_x_at(grid, h0, lab0, mid) == pytest.approx(1.8, abs=0.6)


def test_a_bulge_moves_the_middle_of_the_walls_not_the_corners_or_the_rim(grid):
    h0, lab0 = bin_height_field(grid, BinPose())
    h, lab = bin_height_field(grid, BinPose(), deformation=BinShape(bulge_mm=2.0).realise(None))
    mid = BIN.floor_mm + 0.5 * (BIN.height_mm - BIN.floor_mm)
    # halfway down the wall, halfway along it: the opening is 2 mm wider on that side
    assert _inner_half_x_at(grid, h, lab, mid) - _inner_half_x_at(grid, h0, lab0, mid) == pytest.approx(2.0, abs=0.6)
    # the rim and the floor stay; the table is untouched
    assert np.array_equal(lab == LABEL_RIM, lab0 == LABEL_RIM)
    assert np.array_equal(h[lab0 == LABEL_RIM], h0[lab0 == LABEL_RIM])
    X, Y = np.meshgrid(grid.xs, grid.ys)
    corner = (np.abs(np.abs(X) - 185) < 3) & (np.abs(np.abs(Y) - 135) < 3) & (lab0 == LABEL_WALL)
    # near the corners the wall moves by less than 0.1 mm (its height, on the 4° draft, by < 1.5 mm)
    assert np.abs(h[corner] - h0[corner]).max() * np.tan(np.radians(BIN.draft_deg)) < 0.1


def test_a_deformation_is_drawn_anew_for_every_scan_and_the_same_for_the_same_seed():
    shape = BinShape(deform_mm=1.0)
    a = synthesize_frame(kind="rods", seed=5, index=0, size=SIZE, bin_shape=shape)
    b = synthesize_frame(kind="rods", seed=5, index=0, size=SIZE, bin_shape=shape)
    c = synthesize_frame(kind="rods", seed=5, index=1, size=SIZE, bin_shape=shape)
    assert a.scene.deformation == b.scene.deformation != c.scene.deformation
    d = a.scene.deformation
    assert all(abs(x) <= 1.0 for x in d.bulges_mm) and 0 < abs(d.twist_mm) <= 1.0
    nominal = synthesize_frame(kind="rods", seed=5, index=0, size=SIZE)
    # the same pile (settled in the nominal bin), a different bin
    assert len(a.scene.parts) == len(nominal.scene.parts)
    for p, q in zip(a.scene.parts, nominal.scene.parts):
        np.testing.assert_array_equal(p.top, q.top)
    assert not np.array_equal(a.scene.bin_height, nominal.scene.bin_height)
    np.testing.assert_array_equal(a.T_cam_bin, nominal.T_cam_bin)


@pytest.mark.parametrize("shape", [BinShape(scale=1.002), BinShape(bulge_mm=1.0)])
def test_a_scaled_or_bulging_bin_holds_the_very_same_pile(shape):
    a = synthesize_frame(kind="spheres", seed=6, size=SIZE, bin_shape=shape)
    b = synthesize_frame(kind="spheres", seed=6, size=SIZE)
    assert np.array_equal(a.scene.part_id, b.scene.part_id)
    on = a.scene.label == LABEL_PART
    assert np.array_equal(on, b.scene.label == LABEL_PART)
    np.testing.assert_allclose(a.scene.height[on], b.scene.height[on], atol=1e-4)  # float32 part tops


@pytest.mark.parametrize("kw, match", [
    ({"scale": 1.2}, r"BinShape\.scale must be a number within 0\.05 of 1, got 1\.2"),
    ({"scale": float("nan")}, r"BinShape\.scale"),
    ({"bulge_mm": 30.0}, r"BinShape\.bulge_mm must be a number within ±20 mm"),
    ({"deform_mm": -1.0}, r"BinShape\.deform_mm must be a number in \[0, 20\] mm"),
    ({"deform_mm": True}, r"BinShape\.deform_mm"),
])
def test_bad_shapes(kw, match):
    with pytest.raises(ParameterError, match=match):
        BinShape(**kw)


def test_the_cad_mesh_is_the_nominal_bin():
    v, f = bin_mesh_mm()
    assert v.shape == (16, 3) and f.shape == (26, 3) and f.min() == 0 and f.max() == 15
    assert v[:, 2].max() == BIN.height_mm and v[:, 0].max() == BIN.outer_length_mm / 2


def test_a_cad_model_fits_a_synthetic_frame_at_its_true_pose(tmp_path):
    """``zcut synth --bin-cad`` -> ``zcut bin-model --model``: the model lies on the frame's bin at the pose
    the log carries (the nominal bin's frame)."""
    from scipy.spatial import cKDTree

    log, cad, ply = tmp_path / "l.mcap", tmp_path / "cad.ply", tmp_path / "bin.ply"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--size", "240x150", "--seed", "4",
                 "--bin-cad", str(cad)]) == 0
    assert main(["bin-model", "--model", str(cad), "-o", str(ply)]) == 0
    model = load_bin_model(ply)
    sf = synthesize_frame(kind="rods", seed=4, size=(150, 240))
    T = sf.T_cam_bin
    rim = sf.surface == LABEL_RIM
    pts = sf.frame.xyz[rim & np.isfinite(sf.frame.xyz).all(axis=2)].astype(np.float64)
    d, _ = cKDTree(model.points @ T[:3, :3].T + T[:3, 3]).query(pts)
    assert np.percentile(d, 95) < 0.0015  # within the model's 1 mm sampling and the noise


def test_cli_synth_bin_shape(tmp_path, capsys):
    out = tmp_path / "b.mcap"
    assert main(["synth", "-o", str(out), "--size", "96x60", "--bin-scale", "1.002", "--bin-bulge-mm", "1",
                 "--bin-deform-mm", "0.5"]) == 0
    meta = LogReader(out).metadata[layout.SYNTH_METADATA]
    assert (meta["bin_scale"], meta["bin_bulge_mm"], meta["bin_deform_mm"]) == ("1.002", "1", "0.5")
    plain = tmp_path / "p.mcap"
    assert main(["synth", "-o", str(plain), "--size", "96x60"]) == 0
    assert "bin_scale" not in LogReader(plain).metadata[layout.SYNTH_METADATA]
    capsys.readouterr()
    assert main(["synth", "-o", str(tmp_path / "x.mcap"), "--bin-bulge-mm", "50"]) == 1
    assert "--bin-bulge-mm must be a number within ±20 mm, got 50.0" in capsys.readouterr().err
    assert main(["synth", "-o", str(tmp_path / "y.mcap"), "--bin-cad", str(out)]) == 1  # exists: --force
