"""``zcut record`` with the camera model (issue 35 #24): ``--fx --fy --cx --cy`` or a ROS camera_info YAML,
written as ``/camera/camera_info``, so that ``cluster`` (areas in mm²) runs on recorded clouds."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import run_cli

from replay.logs.reader import LogReader
from replay.synth.log import write_synthetic_log

H, W = 120, 160


def _write_pcd(path, xyz) -> None:
    h, w = xyz.shape[:2]
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {w}\n"
            f"HEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {h * w}\nDATA binary\n").encode()
    path.write_bytes(head + np.ascontiguousarray(xyz, dtype="<f4").tobytes())


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A synthetic scan as an organized PCD file, and the intrinsics of the camera that made it."""
    d = tmp_path_factory.mktemp("scan")
    log = write_synthetic_log(d / "s.mcap", kind="rods", frames=1, seed=5, size=(H, W))
    r = LogReader(log)
    _write_pcd(d / "scan.pcd", next(r.frames()).xyz)
    return d / "scan.pcd", r.intrinsics


ROS_YAML = """image_width: {w}
image_height: {h}
camera_name: zivid   # a comment
camera_matrix:
  rows: 3
  cols: 3
  data: [{fx}, 0, {cx},
         0, {fy}, {cy}, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0, 0, 0, 0, 0]
"""

ECHO_YAML = """header:
  stamp:
    sec: 0
  frame_id: camera_optical_frame
height: {h}
width: {w}
distortion_model: plumb_bob
k:
- {fx}
- 0.0
- {cx}
- 0.0
- {fy}
- {cy}
- 0.0
- 0.0
- 1.0
"""


def _k(K) -> dict:
    return {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "w": W, "h": H}


@pytest.mark.parametrize("how", ["flags", "ros_yaml", "echo_yaml"])
def test_record_writes_the_camera_info_given(scan, tmp_path, capsys, how):
    pcd, K = scan
    if how == "flags":
        extra = ["--fx", K.fx, "--fy", K.fy, "--cx", K.cx, "--cy", K.cy]
    else:
        (tmp_path / "cam.yaml").write_text((ROS_YAML if how == "ros_yaml" else ECHO_YAML).format(**_k(K)))
        extra = ["--camera-info", tmp_path / "cam.yaml"]
    rc, out, err = run_cli(capsys, "record", pcd, "-o", tmp_path / "rec.mcap", *extra)
    assert rc == 0, err
    assert "and camera info (fx " in out
    got = LogReader(tmp_path / "rec.mcap").intrinsics
    assert got is not None
    assert (got.fx, got.fy, got.cx, got.cy, got.width, got.height) == pytest.approx(
        (K.fx, K.fy, K.cx, K.cy, W, H))


def test_cluster_runs_on_a_log_recorded_with_its_camera(scan, tmp_path, capsys):
    pcd, K = scan
    assert run_cli(capsys, "record", pcd, "-o", tmp_path / "bare.mcap")[0] == 0
    rc, _, err = run_cli(capsys, "replay", tmp_path / "bare.mcap", "--methods", "cluster")
    assert rc == 1 and "zcut record --camera-info FILE.yaml, or --fx --fy --cx --cy" in err, err
    assert run_cli(capsys, "record", pcd, "-o", tmp_path / "cam.mcap", "--fx", K.fx, "--fy", K.fy,
                   "--cx", K.cx, "--cy", K.cy)[0] == 0
    rc, _, err = run_cli(capsys, "replay", tmp_path / "cam.mcap", "--methods", "cluster")
    assert rc == 0, err


@pytest.mark.parametrize("extra, match", [
    (["--fx", "600", "--fy", "600", "--cx", "80"], "needs --fx, --fy, --cx and --cy together; missing --cy"),
    (["--fx", "0", "--fy", "600", "--cx", "80", "--cy", "60"], "fx must be a positive number of pixels, got 0"),
    (["--fx", "nan", "--fy", "600", "--cx", "80", "--cy", "60"], "fx must be a positive number of pixels"),
    (["--fx", "600", "--fy", "600", "--cx", "900", "--cy", "60"], "the principal point (900, 60) lies outside"),
    (["--camera-info", "{d}/cam.yaml", "--fx", "600"], "--camera-info and --fx both give the camera model"),
    (["--camera-info", "{d}/missing.yaml"], "no such file"),
    (["--camera-info", "{d}/wrong_size.yaml"], "is for 640x480 images but"),
    (["--camera-info", "{d}/no_k.yaml"], "no camera matrix (camera_matrix.data or k, 9 numbers)"),
    (["--camera-info", "{d}/skew.yaml"], "is not a pinhole K"),
    (["--camera-info", "{d}/binary.yaml"], "not UTF-8 text"),
    (["--camera-info", "{d}/open.yaml"], "a [ list is not closed"),
])
def test_bad_camera_values_are_one_line(scan, tmp_path, capsys, extra, match):
    pcd, K = scan
    d = tmp_path
    (d / "cam.yaml").write_text(ROS_YAML.format(**_k(K)))
    (d / "wrong_size.yaml").write_text(ROS_YAML.format(**{**_k(K), "w": 640, "h": 480}))
    (d / "no_k.yaml").write_text("image_width: 160\nimage_height: 120\n")
    (d / "skew.yaml").write_text(ROS_YAML.format(**_k(K)).replace(f"[{K.fx}, 0,", f"[{K.fx}, 3,"))
    (d / "binary.yaml").write_bytes(b"\xff\xfe\x00bad")
    (d / "open.yaml").write_text("k: [1, 2,\n 3\n")
    rc, _, err = run_cli(capsys, "record", pcd, "-o", d / "o.mcap", *[a.format(d=d) for a in extra])
    assert rc == 1
    lines = [ln for ln in err.splitlines() if not ln.startswith("zcut: ")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], err
    assert not (d / "o.mcap").exists()
