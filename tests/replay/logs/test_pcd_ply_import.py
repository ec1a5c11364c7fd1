"""Import of organized PCD and PLY files, and ``zcut record`` / ``zcut topics`` end to end."""

from __future__ import annotations

import struct
import subprocess
import sys

import cv2
import numpy as np
import open3d as o3d
import pytest

from cli.main import main
from replay.errors import LogFormatError
from replay.logs.pcd import read_pcd
from replay.logs.ply import read_ply, read_ply_model
from replay.logs.reader import LogReader

REAL_PCDS = [
    "frame_20121214T142255.814212.pcd", "milk_cartoon_all_small_clorox.pcd", "mosd_test16.pcd",
    "mosd_test20.pcd", "mosd_test24.pcd", "mosd_test44.pcd", "mosd_test55.pcd", "mosd_test60.pcd",
    "table_scene_mug_stereo_textured.pcd",
]


# ----------------------------------------------------------------------------- writers (tests only)
def _lzf_literals(data: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (PCL's decoder accepts it too)."""
    out = bytearray()
    for i in range(0, len(data), 32):
        piece = data[i : i + 32]
        out.append(len(piece) - 1)
        out += piece
    return bytes(out)


def write_pcd(path, xyz, rgb, *, data, color="rgba", extra=True, height=None):
    h, w = xyz.shape[:2]
    fields = [("x", "F", 4), ("y", "F", 4), ("z", "F", 4)]
    cols = [xyz[..., 0].astype("<f4"), xyz[..., 1].astype("<f4"), xyz[..., 2].astype("<f4")]
    if rgb is not None:
        packed = (rgb[..., 0].astype(np.uint32) << 16) | (rgb[..., 1].astype(np.uint32) << 8) | rgb[..., 2]
        if color == "rgba":
            fields.append(("rgba", "U", 4))
            cols.append((packed | np.uint32(0xFF000000)).astype("<u4"))
        else:  # PCL's float-packed rgb
            fields.append(("rgb", "F", 4))
            cols.append(packed.astype("<u4").view("<f4"))
    if extra:
        fields.insert(0, ("label", "U", 4))
        cols.insert(0, np.arange(h * w, dtype="<u4").reshape(h, w))
    head = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(f[0] for f in fields)}\nSIZE {' '.join(str(f[2]) for f in fields)}\n"
        f"TYPE {' '.join(f[1] for f in fields)}\nCOUNT {' '.join('1' for _ in fields)}\n"
        f"WIDTH {w}\nHEIGHT {h if height is None else height}\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {h * w}\nDATA {data}\n"
    )
    if data == "ascii":
        lines = []
        flat = [c.reshape(-1) for c in cols]
        for i in range(h * w):
            vals = []
            for (_name, t, _), c in zip(fields, flat, strict=True):
                v = c[i]
                vals.append(repr(float(v)) if t == "F" else str(int(v)))
            lines.append(" ".join(vals).replace("nan", "nan"))
        body = ("\n".join(lines) + "\n").encode()
    elif data == "binary":
        rec = np.empty(h * w, dtype=[(f[0], c.dtype) for f, c in zip(fields, cols, strict=True)])
        for f, c in zip(fields, cols, strict=True):
            rec[f[0]] = c.reshape(-1)
        body = rec.tobytes()
    else:
        plain = b"".join(np.ascontiguousarray(c).tobytes() for c in cols)
        comp = _lzf_literals(plain)
        body = struct.pack("<II", len(comp), len(plain)) + comp
    path.write_bytes(head.encode() + body)


def write_ply(path, xyz, rgb, *, fmt="binary_little_endian", organized="obj_info", grid=False):
    h, w = xyz.shape[:2]
    pts = xyz.reshape(-1, 3)
    col = None if rgb is None else rgb.reshape(-1, 3)
    keep = np.arange(h * w)
    if grid:  # PCL style: only valid points as vertices, a range_grid maps cells to them
        keep = np.flatnonzero(np.isfinite(pts).all(axis=1))
    head = ["ply", f"format {fmt} 1.0", "comment written by a zcut test"]
    if organized == "obj_info":
        head += [f"obj_info num_cols {w}", f"obj_info num_rows {h}"]
    elif organized == "comment":
        head += [f"comment num_rows {h}", f"comment num_cols {w}"]
    head += [f"element vertex {len(keep)}", "property float x", "property float y", "property float z"]
    if col is not None:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    head += ["property float intensity"]
    cam_names = ["view_px", "view_py", "view_pz", "x_axisx", "x_axisy", "x_axisz", "y_axisx", "y_axisy",
                 "y_axisz", "z_axisx", "z_axisy", "z_axisz", "focal", "scalex", "scaley", "centerx",
                 "centery", "viewportx", "viewporty", "k1", "k2"]
    if organized == "camera":  # PCL's savePLYFile with its camera element
        head += ["element camera 1"] + [f"property float {n}" for n in cam_names]
    if grid:
        head += [f"element range_grid {h * w}", "property list uchar int vertex_indices"]
    head += ["end_header"]
    out = ("\n".join(head) + "\n").encode()
    bo = ">" if fmt == "binary_big_endian" else "<"
    dt = [("x", bo + "f4"), ("y", bo + "f4"), ("z", bo + "f4")]
    if col is not None:
        dt += [("r", "u1"), ("g", "u1"), ("b", "u1")]
    dt += [("i", bo + "f4")]
    rec = np.zeros(len(keep), dtype=dt)
    rec["x"], rec["y"], rec["z"] = pts[keep, 0], pts[keep, 1], pts[keep, 2]
    if col is not None:
        rec["r"], rec["g"], rec["b"] = col[keep, 0], col[keep, 1], col[keep, 2]
    rec["i"] = 0.5
    index_of = np.full(h * w, -1)
    index_of[keep] = np.arange(len(keep))
    cam = np.zeros(len(cam_names), dtype=bo + "f4")
    cam[cam_names.index("viewportx")], cam[cam_names.index("viewporty")] = w, h
    if fmt == "ascii":
        out += ("\n".join(" ".join(str(v) for v in r) for r in rec.tolist()) + "\n").encode()
        if organized == "camera":
            out += (" ".join(str(float(v)) for v in cam) + "\n").encode()
        if grid:
            out += ("\n".join(f"1 {index_of[i]}" if index_of[i] >= 0 else "0" for i in range(h * w)) + "\n").encode()
    else:
        out += rec.tobytes()
        if organized == "camera":
            out += cam.tobytes()
        if grid:
            parts = []
            for i in range(h * w):
                if index_of[i] >= 0:
                    parts.append(b"\x01" + struct.pack(bo + "i", int(index_of[i])))
                else:
                    parts.append(b"\x00")
            out += b"".join(parts)
    path.write_bytes(out)


# ----------------------------------------------------------------------------- PCD
@pytest.mark.parametrize("name", REAL_PCDS)
def test_real_pcd_matches_open3d(real_data, name):
    cloud = read_pcd(real_data / name)
    assert cloud.xyz.shape == (480, 640, 3) and cloud.xyz.dtype == np.float32
    invalid = np.isnan(cloud.xyz).any(axis=2)
    assert 0 < invalid.sum() < 480 * 640 / 2
    assert np.isnan(cloud.xyz[invalid]).all()  # all three NaN together
    z = cloud.xyz[..., 2][~invalid]
    assert 0.3 < np.median(z) < 5.0  # Kinect range, metres
    ref = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    ref_xyz = np.asarray(ref.points).reshape(480, 640, 3)
    np.testing.assert_array_equal(cloud.xyz[~invalid], ref_xyz[~invalid].astype(np.float32))
    assert not np.isfinite(ref_xyz[invalid]).all(axis=1).any()
    ref_rgb = np.round(np.asarray(ref.colors) * 255).reshape(480, 640, 3)
    np.testing.assert_array_equal(cloud.rgb[~invalid], ref_rgb[~invalid])
    mean = cloud.rgb[~invalid].mean(axis=0)
    assert ((mean > 40) & (mean < 220)).all() and cloud.rgb[~invalid].std() > 10  # a real photo


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
@pytest.mark.parametrize("color", ["rgba", "rgb"])
def test_pcd_formats_round_trip(real_data, tmp_path, data, color):
    src = read_pcd(real_data / "mosd_test55.pcd")
    xyz, rgb = src.xyz[100:140, 200:260], src.rgb[100:140, 200:260]  # a crop with NaN and colours
    assert np.isnan(xyz).any()
    p = tmp_path / f"crop_{data}.pcd"
    write_pcd(p, xyz, rgb, data=data, color=color)
    got = read_pcd(p)
    np.testing.assert_array_equal(got.xyz, xyz)
    np.testing.assert_array_equal(got.rgb, rgb)


def test_pcd_zero_points_become_nan(tmp_path):
    xyz = np.ones((3, 4, 3), np.float32)
    xyz[1, 1] = 0.0
    write_pcd(tmp_path / "z.pcd", xyz, None, data="binary", extra=False)
    got = read_pcd(tmp_path / "z.pcd")
    assert got.rgb is None
    assert np.isnan(got.xyz[1, 1]).all() and np.isfinite(got.xyz).sum() == 11 * 3


_PCD_2X1 = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 2\nPOINTS 2\nDATA binary_compressed\n"


@pytest.mark.parametrize(
    "stream,match",
    [
        # literal 1.0f, then a back reference of 20 bytes to offset 4 (an overlapping copy)
        (bytes([3, 0, 0, 0x80, 0x3F, 0xE0, 0x0B, 0x03]), None),
        (bytes([0x60, 0x10]), "LZF data is corrupt"),  # a reference before the start
        (bytes([3, 0, 0, 0x80, 0x3F]), "LZF data is corrupt"),  # expands to 4 bytes, not 24
    ],
)
def test_lzf_reference_vectors(tmp_path, stream, match):
    """PCL's binary_compressed LZF, read through pypcd4 (liblzf): back references, corrupt data."""
    p = tmp_path / "lzf.pcd"
    p.write_bytes(_PCD_2X1 + struct.pack("<II", len(stream), 24) + stream)
    if match is None:
        assert (read_pcd(p).xyz == 1.0).all()
    else:
        with pytest.raises(LogFormatError, match="^lzf.pcd: PCD binary_compressed: " + match):
            read_pcd(p)


def test_pcd_corrupt_compressed_data_never_crashes(real_data, tmp_path, rng):
    raw = (real_data / "mosd_test16.pcd").read_bytes()
    start = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n") + 8
    outcomes = set()
    for k in range(40):
        bad = bytearray(raw)
        for pos in rng.integers(start, len(raw), 3):
            bad[pos] ^= 0xFF
        p = tmp_path / f"bad{k}.pcd"
        p.write_bytes(bytes(bad))
        try:
            read_pcd(p)
            outcomes.add("ok")
        except LogFormatError as e:
            assert "mosd" not in str(e) or str(e).startswith(p.name)
            outcomes.add("error")
    assert "error" in outcomes


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda s: s.replace(b"HEIGHT 480", b"HEIGHT 1").replace(b"WIDTH 640", b"WIDTH 307200"), "unorganized PCD"),
        (lambda s: s.replace(b"FIELDS label x y z", b"FIELDS label x y w"), "no 'z' field"),
        (lambda s: s.replace(b"POINTS 307200", b"POINTS 307201"), "!= POINTS 307201"),
        (lambda s: s.replace(b"DATA binary_compressed", b"DATA zip"), "unknown PCD DATA 'zip'"),
        (lambda s: s.replace(b"SIZE 4 4 4 4 4", b"SIZE 4 4 4 4"), "5 FIELDS but 4 SIZE"),
        (lambda s: s[: len(s) // 2], "claims .* compressed bytes, file has"),
        (lambda s: b"hello\nworld\n" * 3, "not a PCD file"),
    ],
)
def test_bad_pcd(real_data, tmp_path, mutate, match):
    p = tmp_path / "bad.pcd"
    p.write_bytes(mutate((real_data / "mosd_test20.pcd").read_bytes()))
    with pytest.raises(LogFormatError, match="^bad.pcd: .*" + match):
        read_pcd(p)


def test_bad_pcd_truncated_binary(tmp_path):
    write_pcd(tmp_path / "t.pcd", np.ones((4, 5, 3), np.float32), None, data="binary")
    raw = (tmp_path / "t.pcd").read_bytes()
    (tmp_path / "t.pcd").write_bytes(raw[:-7])
    with pytest.raises(LogFormatError, match=r"^t.pcd: PCD binary data has \d+ bytes, needs 320 \(truncated\)"):
        read_pcd(tmp_path / "t.pcd")


# ----------------------------------------------------------------------------- PLY
@pytest.fixture
def crop(real_data):
    src = read_pcd(real_data / "table_scene_mug_stereo_textured.pcd")
    xyz, rgb = src.xyz[200:230, 300:345].copy(), src.rgb[200:230, 300:345].copy()
    xyz[0, :5] = np.nan
    return xyz, rgb


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
@pytest.mark.parametrize(
    "organized,grid", [("obj_info", False), ("comment", False), ("obj_info", True), ("camera", False), ("camera", True)]
)
def test_ply_round_trip(tmp_path, crop, fmt, organized, grid):
    xyz, rgb = crop
    p = tmp_path / "c.ply"
    write_ply(p, xyz, rgb, fmt=fmt, organized=organized, grid=grid)
    got = read_ply(p)
    np.testing.assert_array_equal(got.xyz, xyz)
    valid = np.isfinite(xyz).all(axis=2)
    np.testing.assert_array_equal(got.rgb[valid], rgb[valid])


def test_ply_from_open3d_with_explicit_shape(tmp_path, crop):
    """A PLY written by a library we did not write (every point kept, row-major, no grid info)."""
    xyz, rgb = crop
    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.ascontiguousarray(xyz.reshape(-1, 3), dtype=np.float64))
    pc.colors = o3d.utility.Vector3dVector(np.ascontiguousarray(rgb.reshape(-1, 3), dtype=np.float64) / 255.0)
    p = tmp_path / "o3d.ply"
    assert o3d.io.write_point_cloud(str(p), pc, write_ascii=False)
    with pytest.raises(LogFormatError, match=r"^o3d.ply: PLY with 1350 vertices has no organization info .*--shape HxW"):
        read_ply(p)
    got = read_ply(p, shape=(30, 45))
    np.testing.assert_array_equal(got.xyz, xyz)  # open3d writes double; float32 values survive exactly
    valid = np.isfinite(xyz).all(axis=2)
    np.testing.assert_array_equal(got.rgb[valid], rgb[valid])
    with pytest.raises(LogFormatError, match="has 1350 vertices but the grid is 30x46"):
        read_ply(p, shape=(30, 46))


_PLY_XY = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"


def _PLY_GRID(rows: int, cols: int) -> bytes:  # noqa: N802 - reads like a constant in the table
    return (
        f"ply\nformat binary_little_endian 1.0\nobj_info num_cols {cols}\nobj_info num_rows {rows}\n"
        "element vertex 4\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    ).encode()


@pytest.mark.parametrize(
    "text,match",
    [
        (_PLY_XY + b"end_header\n" + bytes(32), "no 'z' property"),
        (b"ply\nformat ascii 2.0\nend_header\n", "format version 2.0"),
        (b"solid cube\n", "not a PLY file"),
        (_PLY_GRID(2, 2) + bytes(20), "needs 48 \\(truncated\\)"),
        (_PLY_GRID(1, 4) + bytes(48), "not organized"),
        (_PLY_XY + b"property float z\nproperty list uchar int idx\nend_header\n", "list property"),
        (_PLY_GRID(2, 2).replace(b"vertex 4", b"vertex -1") + bytes(48), "element 'vertex' has a negative count \\(-1\\)"),
    ],
)
def test_bad_ply(tmp_path, text, match):
    p = tmp_path / "bad.ply"
    p.write_bytes(text)
    with pytest.raises(LogFormatError, match="^bad.ply: .*" + match):
        read_ply(p)


# ----------------------------------------------------------------------------- zcut record / topics
def test_record_real_pcds_round_trip(real_data, tmp_path, capsys):
    out = tmp_path / "kinect.mcap"
    assert main(["record", str(real_data), "-o", str(out), "--stamp-start", "1700000000.5", "--period", "0.1"]) == 0
    printed = capsys.readouterr().out
    assert "wrote 9 frames" in printed and "unit m" in printed
    r = LogReader(out)
    assert (r.cloud_topic, r.image_topic, r.n_frames) == ("/camera/points", "/camera/image", 9)
    assert r.metadata["zcut.record"]["sources"].splitlines()[0].endswith(REAL_PCDS[0])
    stream = r.frames()
    frames = list(stream)
    assert stream.damage == ()
    for f, name in zip(frames, REAL_PCDS, strict=True):  # folder expanded in sorted order
        src = read_pcd(real_data / name)
        np.testing.assert_array_equal(f.xyz, src.xyz)
        np.testing.assert_array_equal(f.rgb, src.rgb)
        assert f.stamp_ns == 1_700_000_000_500_000_000 + f.index * 100_000_000


def test_record_png_and_mm_ply(tmp_path, crop, capsys):
    xyz, rgb = crop
    write_ply(tmp_path / "a.ply", xyz * 1000.0, None)  # millimetres, no colour in the cloud
    photo = np.zeros_like(rgb)
    photo[..., 1] = 200
    cv2.imwrite(str(tmp_path / "a.png"), photo[..., ::-1])
    write_ply(tmp_path / "b.ply", xyz, rgb)
    out = tmp_path / "o.mcap"
    assert main(["record", str(tmp_path / "a.ply"), str(tmp_path / "b.ply"), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "a.ply: 30x45" in printed and "unit mm, image from a.png" in printed
    f0, f1 = LogReader(out).frames()
    np.testing.assert_allclose(f0.xyz, xyz, rtol=1e-6, atol=0)
    np.testing.assert_array_equal(f0.rgb, photo)
    np.testing.assert_array_equal(f1.xyz, xyz)


@pytest.mark.parametrize(
    "setup,args,match",
    [
        (lambda d: (d / "empty").mkdir(), ["{d}/empty"], "folder .*empty holds no .pcd or .ply file"),
        (lambda d: (d / "x.txt").write_text("hi"), ["{d}/x.txt"], "x.txt: not a .pcd or .ply file"),
        (lambda d: None, ["{d}/missing.pcd"], "no such file or folder: .*missing.pcd"),
        (lambda d: (d / "flat.pcd").write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n4 5 6\n"),
         ["{d}/flat.pcd"], "flat.pcd: unorganized PCD"),
        (lambda d: None, ["{d}/x.pcd", "--shape", "12"], "--shape must look like 1200x1920"),
    ],
)
def test_record_errors_one_line(tmp_path, capsys, setup, args, match):
    setup(tmp_path)
    if "x.pcd" in args[0]:
        write_pcd(tmp_path / "x.pcd", np.ones((3, 3, 3), np.float32), None, data="binary")
    code = main(["record", *[a.format(d=tmp_path) for a in args], "-o", str(tmp_path / "o.mcap")])
    err = capsys.readouterr().err
    assert code == 1
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert __import__("re").search(match, err), err
    assert not (tmp_path / "o.mcap").exists() and not (tmp_path / "o.mcap.partial").exists()


def test_record_png_size_mismatch(tmp_path, crop, capsys):
    xyz, rgb = crop
    write_ply(tmp_path / "a.ply", xyz, rgb)
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((10, 10, 3), np.uint8))
    assert main(["record", str(tmp_path / "a.ply"), "-o", str(tmp_path / "o.mcap")]) == 1
    assert "a.png: image is 10x10 but its cloud a.ply is 30x45" in capsys.readouterr().err


def test_record_png_sidecar_is_sized_from_its_header_before_decoding(tmp_path, crop, capsys):
    """A PNG whose IHDR claims 100000 x 100000 pixels (fuzz: OpenCV asserted CV_IO_MAX_IMAGE_PIXELS
    with a traceback) and a .png that is no PNG are one-line errors."""
    import struct
    import zlib

    xyz, rgb = crop
    write_ply(tmp_path / "a.ply", xyz, rgb)
    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    (tmp_path / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk)
    assert main(["record", str(tmp_path / "a.ply"), "-o", str(tmp_path / "o.mcap")]) == 1
    assert "a.png: image is 100000x100000 but its cloud a.ply is 30x45" in capsys.readouterr().err
    (tmp_path / "a.png").write_bytes(b"GIF89a" + bytes(100))
    assert main(["record", str(tmp_path / "a.ply"), "-o", str(tmp_path / "o.mcap")]) == 1
    assert "a.png: not a PNG image" in capsys.readouterr().err
    assert not (tmp_path / "o.mcap").exists()


def test_topics_command(real_data, tmp_path):
    run = [sys.executable, "-m", "cli", "topics"]
    ok = subprocess.run([*run, str(real_data / "ouster_os1_64_ros2_reencoded.mcap")], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert "/os1_cloud_node/points" in ok.stdout and "64x2048" in ok.stdout and "mono8" in ok.stdout
    assert "cloud:       /os1_cloud_node/points  (2 frames)" in ok.stdout
    bad = subprocess.run([*run, str(real_data / "ouster_os1_64_ros1_original.mcap")], capture_output=True, text=True)
    assert bad.returncode == 1
    assert "/os1_node/lidar_packets" in bad.stdout  # still lists what is there
    assert bad.stderr.startswith("error: ouster_os1_64_ros1_original.mcap is a ROS 1 log")
    assert bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr


@pytest.mark.timeout(60)
def test_import_mutants_only_raise_logformaterror(tmp_path, crop, rng):
    """Seeded mutants (flips, truncations, absurd sizes, inserted/zeroed runs) of PCD and PLY files
    in every format: a cloud or a one-line LogFormatError, never another exception or a warning."""
    from log_helpers import mutations

    xyz, rgb = crop
    xyz = xyz[:12, :16]
    rgb = rgb[:12, :16]
    files = []
    for data in ("ascii", "binary", "binary_compressed"):
        p = tmp_path / f"c_{data}.pcd"
        write_pcd(p, xyz, rgb, data=data)
        files.append((p, read_pcd))
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        for organized, grid in (("obj_info", False), ("camera", True)):
            p = tmp_path / f"c_{fmt}_{organized}.ply"
            write_ply(p, xyz, rgb, fmt=fmt, organized=organized, grid=grid)
            files.append((p, read_ply))
    outcomes = {"ok": 0, "error": 0}
    for path, reader in files:
        for _, data in mutations(path.read_bytes(), rng, 40):
            q = tmp_path / ("mutant" + path.suffix)
            q.write_bytes(data)
            try:
                cloud = reader(q)
                assert cloud.xyz.dtype == np.float32 and cloud.xyz.shape[0] > 1
                outcomes["ok"] += 1
            except LogFormatError as e:
                assert "\n" not in str(e)
                outcomes["error"] += 1
    assert outcomes["ok"] > 20 and outcomes["error"] > 20, outcomes



# ----------------------------------------------------------------------------- PLY models (bin models, CAD parts)
def test_ply_model_round_trip_open3d(tmp_path):
    """Open3D's own files (a cloud with normals, a box mesh; ascii and binary) read back exactly."""
    rng = np.random.default_rng(3)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.normal(size=(50, 3))))
    pc.normals = o3d.utility.Vector3dVector(rng.normal(size=(50, 3)))
    mesh = o3d.geometry.TriangleMesh.create_box(0.4, 0.3, 0.12)
    for ascii_ in (True, False):
        o3d.io.write_point_cloud(str(tmp_path / "pc.ply"), pc, write_ascii=ascii_)
        m = read_ply_model(tmp_path / "pc.ply")
        tol = 1e-5 if ascii_ else 0  # Open3D writes ascii with 6 digits
        np.testing.assert_allclose(m.points, np.asarray(pc.points), rtol=tol, atol=tol)
        np.testing.assert_allclose(m.normals, np.asarray(pc.normals), rtol=tol, atol=tol)
        assert m.faces is None
        o3d.io.write_triangle_mesh(str(tmp_path / "box.ply"), mesh, write_ascii=ascii_)
        m = read_ply_model(tmp_path / "box.ply")
        np.testing.assert_allclose(m.points, np.asarray(mesh.vertices))
        np.testing.assert_array_equal(m.faces, np.asarray(mesh.triangles))


_MODEL = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"


@pytest.mark.parametrize(
    "text,match",
    [
        (_MODEL.replace(b"vertex 3", b"vertex 8589934592") + b"end_header\n0 0 0\n", "8589934592 items, more than the cap"),
        (_MODEL.replace(b"vertex 3", b"vertex -1") + b"end_header\n", "negative count"),
        (_MODEL + b"end_header\n0 0 0\n", "needs at least 18 \\(truncated\\)"),
        (_MODEL + b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
         "face 0 refers to a vertex outside the 3 vertices"),
        (_MODEL + b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n",
         "face 0 has 2 vertices"),
        (_MODEL + b"end_header\n0 0 0\ninf 0 0\n0 nan 0\n", "2 vertices with a non-finite coordinate"),
        (_MODEL + b"end_header\n0 0 0\n1 x 0\n0 1 0\n", "data does not parse"),
        (b"ply\nformat ascii 1.0\nelement face 3\nproperty list uchar int vertex_indices\n" + _MODEL[19:]
         + b"comment " + b"c" * 70000 + b"\nend_header\n", "no end_header in its first 65536 bytes"),
    ],
)
def test_bad_ply_model(tmp_path, text, match):
    """Inputs that crashed Open3D's PLY reader (a face element first, a 70 KB comment) or asked it for
    74 GB are one-line errors here."""
    p = tmp_path / "bad.ply"
    p.write_bytes(text)
    with pytest.raises(LogFormatError, match="^bad.ply: .*" + match):
        read_ply_model(p)


def test_ply_model_mutants_only_raise_logformaterror(tmp_path, rng):
    from log_helpers import mutations

    mesh = o3d.geometry.TriangleMesh.create_box(0.4, 0.3, 0.12)
    mesh.compute_vertex_normals()
    outcomes = {"ok": 0, "error": 0}
    for ascii_ in (True, False):
        o3d.io.write_triangle_mesh(str(tmp_path / "box.ply"), mesh, write_ascii=ascii_)
        for _, data in mutations((tmp_path / "box.ply").read_bytes(), rng, 60):
            q = tmp_path / "mutant.ply"
            q.write_bytes(data)
            try:
                m = read_ply_model(q)
                assert np.isfinite(m.points).all() and (m.faces is None or m.faces.max() < len(m.points))
                outcomes["ok"] += 1
            except LogFormatError as e:
                assert "\n" not in str(e)
                outcomes["error"] += 1
    assert outcomes["ok"] > 5 and outcomes["error"] > 20, outcomes
