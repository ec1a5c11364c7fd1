"""PointCloud2 / Image / CameraInfo codecs: every layout docs/formats.md allows, and malformed messages."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic

from replay.errors import LogFormatError
from replay.logs import ros2_msgs as rm
from zcut.cloud import Intrinsics

H, W = 5, 7


def _cloud_bytes(xyz, rgb, *, ftype, order, point_step, row_pad, big, color, color_type,
                 is_dense=False, extra_field=True):
    """Build a PointCloud2 CDR message with an arbitrary layout, independently of the decoder."""
    bo = ">" if big else "<"
    size = 4 if ftype == rm.FLOAT32 else 8
    offsets = {}
    pos = 0
    for name in order:  # coordinates in the given order, 2 bytes of padding between them
        offsets[name] = pos
        pos += size + 2
    fields = [rm.PointField(n, offsets[n], ftype, 1) for n in "xyz"]
    if color:
        offsets["c"] = pos
        fields.append(rm.PointField(color, pos, color_type, 1))
        pos += 4
    if extra_field:
        fields.append(rm.PointField("intensity", pos, rm.UINT16, 1))
        pos += 2
    assert point_step >= pos
    row_step = W * point_step + row_pad
    buf = np.zeros(H * row_step, dtype=np.uint8)
    fmt = bo + ("f4" if size == 4 else "f8")
    for i, j in itertools.product(range(H), range(W)):
        base = i * row_step + j * point_step
        for k, n in enumerate("xyz"):
            buf[base + offsets[n] : base + offsets[n] + size] = np.frombuffer(
                np.array(xyz[i, j, k], dtype=fmt).tobytes(), np.uint8)
        if color:
            packed = (0xFF << 24) | (int(rgb[i, j, 0]) << 16) | (int(rgb[i, j, 1]) << 8) | int(rgb[i, j, 2])
            buf[base + offsets["c"] : base + offsets["c"] + 4] = np.frombuffer(
                np.array(packed, dtype=bo + "u4").tobytes(), np.uint8)
        buf[base + pos - 2 : base + pos] = 0xAB  # intensity garbage
    if row_pad:
        for i in range(H):
            buf[i * row_step + W * point_step : (i + 1) * row_step] = 0xEE
    return rm.encode_cloud(
        stamp_ns=123_456_789_012, frame_id="cam", height=H, width=W, fields=fields,
        point_step=point_step, row_step=row_step, data=buf.tobytes(), is_dense=is_dense,
        is_bigendian=big,
    )


@pytest.fixture
def scene(rng):
    xyz = rng.normal(size=(H, W, 3))
    xyz[1, 2] = np.nan
    xyz[2, 3] = (0.0, 0.0, 0.0)  # invalid the Ouster way
    xyz[3, 4, 1] = np.inf
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    expect = xyz.astype(np.float32)
    expect[1, 2] = expect[2, 3] = expect[3, 4] = np.nan
    return xyz, rgb, expect


@pytest.mark.parametrize("ftype", [rm.FLOAT32, rm.FLOAT64])
@pytest.mark.parametrize("big", [False, True])
@pytest.mark.parametrize(
    "order,point_step,row_pad",
    [("xyz", 48, 0), ("zyx", 40, 13), ("yxz", 64, 1)],
)
@pytest.mark.parametrize(
    "color,color_type", [(None, None), ("rgba", rm.UINT32), ("rgb", rm.FLOAT32), ("rgb", rm.UINT32)]
)
@pytest.mark.parametrize("is_dense", [False, True])
def test_cloud_layouts(scene, ftype, big, order, point_step, row_pad, color, color_type, is_dense):
    xyz, rgb, expect = scene
    raw = _cloud_bytes(xyz, rgb, ftype=ftype, order=order, point_step=point_step, row_pad=row_pad,
                       big=big, color=color, color_type=color_type, is_dense=is_dense)
    msg = rm.decode_cloud(raw, where="t")
    assert (msg.height, msg.width, msg.stamp_ns, msg.frame_id) == (H, W, 123_456_789_012, "cam")
    got_xyz, got_rgb = rm.cloud_to_arrays(msg, where="t")
    assert got_xyz.dtype == np.float32 and got_xyz.shape == (H, W, 3)
    np.testing.assert_array_equal(got_xyz, expect)
    if color is None:
        assert got_rgb is None
    else:
        np.testing.assert_array_equal(got_rgb, rgb)


def test_cloud_decoder_agrees_with_mcap_ros2(scene):
    """Our hand decoder and mcap_ros2's generic one read the same header fields."""
    xyz, rgb, _ = scene
    raw = _cloud_bytes(xyz, rgb, ftype=rm.FLOAT32, order="xyz", point_step=32, row_pad=3, big=False,
                       color="rgba", color_type=rm.UINT32)
    ref = generate_dynamic(rm.POINTCLOUD2, rm.SCHEMAS[rm.POINTCLOUD2])[rm.POINTCLOUD2](raw)
    ours = rm.decode_cloud(raw, where="t")
    assert (ref.height, ref.width, ref.point_step, ref.row_step, ref.is_dense) == (
        ours.height, ours.width, ours.point_step, ours.row_step, ours.is_dense)
    assert [(f.name, f.offset, f.datatype, f.count) for f in ref.fields] == [
        (f.name, f.offset, f.datatype, f.count) for f in ours.fields]
    assert bytes(ref.data) == bytes(ours.data)


def _good_cloud(**over):
    kw = dict(stamp_ns=0, frame_id="f", height=2, width=3, fields=rm.XYZRGBA_FIELDS, point_step=16,
              row_step=48, data=bytes(96), is_dense=False)
    kw.update(over)
    return rm.encode_cloud(**kw)


@pytest.mark.parametrize(
    "over,match",
    [
        ({"fields": rm.XYZRGBA_FIELDS[:2]}, "no 'z' field"),
        ({"fields": (rm.PointField("x", 0, rm.INT32, 1),) + rm.XYZRGBA_FIELDS[1:]}, "datatype 5"),
        ({"row_step": 40}, "row_step 40 is smaller than width 3 x point_step 16"),
        ({"height": 3}, "needs 144 bytes of data but has 96"),
        ({"width": 2**31, "row_step": 2**35 % 2**32}, "row_step .* smaller|needs .* bytes"),
        ({"width": 2**31 - 1, "row_step": 2**32 - 1, "point_step": 1,
          "fields": rm.XYZ_FIELDS}, "needs 6442450942 bytes of data but has 96"),
        ({"row_step": 3, "point_step": 1, "fields": rm.XYZ_FIELDS}, "'x' at offset 0 does not fit in point_step 1"),
        ({"height": 2**32 - 1, "row_step": 2**32 - 1}, "needs .* bytes of data but has 96"),
        ({"point_step": 0, "row_step": 0}, "point_step is 0"),
        ({"fields": (rm.PointField("x", 14, rm.FLOAT32, 1),) + rm.XYZRGBA_FIELDS[1:]}, "at offset 14 does not fit"),
        ({"height": 0}, "is empty"),
    ],
)
def test_bad_clouds(over, match):
    msg = rm.decode_cloud(_good_cloud(**over), where="topic /p, message 4")
    with pytest.raises(LogFormatError, match="^topic /p, message 4: .*" + match):
        rm.cloud_to_arrays(msg, where="topic /p, message 4")


def test_truncated_cdr_always_logformaterror():
    raw = _good_cloud()
    for n in range(len(raw) - 96 + 4):  # every cut before the data blob is complete
        with pytest.raises(LogFormatError, match="topic /p"):
            msg = rm.decode_cloud(raw[:n], where="topic /p")
            rm.cloud_to_arrays(msg, where="topic /p")


def test_absurd_field_count_and_encapsulation():
    raw = bytearray(_good_cloud())
    # fields length sits after header (4 + 8 + 4 + 2 = 18 -> aligned 20), height, width
    off = 4 + 8 + 4 + len(b"f\x00")
    off += (-(off - 4)) % 4
    off += 8
    raw[off : off + 4] = (2**31).to_bytes(4, "little")
    with pytest.raises(LogFormatError, match="claims 2147483648 point fields"):
        rm.decode_cloud(bytes(raw), where="x")
    with pytest.raises(LogFormatError, match="unsupported CDR encapsulation"):
        rm.decode_cloud(b"\x01\x07\x00\x00" + bytes(raw[4:]), where="x")
    with pytest.raises(LogFormatError, match="too short"):
        rm.decode_cloud(b"\x00", where="x")


@pytest.mark.parametrize("enc", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"])
@pytest.mark.parametrize("pad", [0, 5])
def test_images(rng, enc, pad):
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    ch = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}[enc]
    px = np.zeros((H, W, ch), np.uint8)
    if enc == "mono8":
        px[..., 0] = rgb[..., 0]
        want = np.repeat(rgb[..., :1], 3, axis=2)
    else:
        src = rgb[..., ::-1] if enc.startswith("bgr") else rgb
        px[..., :3] = src
        if ch == 4:
            px[..., 3] = 77
        want = rgb
    step = W * ch + pad
    buf = np.full((H, step), 0xCD, np.uint8)
    buf[:, : W * ch] = px.reshape(H, W * ch)
    raw = rm.encode_image(stamp_ns=5, frame_id="c", height=H, width=W, encoding=enc, step=step,
                          data=buf.tobytes())
    msg = rm.decode_image(raw, where="t")
    np.testing.assert_array_equal(rm.image_to_rgb(msg, where="t"), want)
    if enc == "mono8":
        np.testing.assert_array_equal(rm.image_to_mask(msg, where="t"), rgb[..., 0] != 0)


@pytest.mark.parametrize(
    "enc,step,n,match",
    [
        ("16UC1", 14, 70, "encoding '16UC1' is not supported"),
        ("rgb8", 20, 200, "step 20 is smaller than width 7 x 3"),
        ("rgb8", 21, 100, "needs 105 bytes of data but has 100"),
        ("mono8", 2**32 - 1, 100, "needs .* bytes of data but has 100"),
    ],
)
def test_bad_images(enc, step, n, match):
    raw = rm.encode_image(stamp_ns=0, frame_id="c", height=H, width=W, encoding=enc, step=step, data=bytes(n))
    with pytest.raises(LogFormatError, match="^img: .*" + match):
        rm.image_to_rgb(rm.decode_image(raw, where="img"), where="img")


def test_mask_must_be_mono8():
    raw = rm.encode_image(stamp_ns=0, frame_id="c", height=2, width=2, encoding="rgb8", step=6, data=bytes(12))
    with pytest.raises(LogFormatError, match="mask must be a mono8 or mono1 Image, got 'rgb8'"):
        rm.image_to_mask(rm.decode_image(raw, where="m"), where="m")


def test_camera_info_round_trip_and_reference_decoder():
    k = Intrinsics(fx=1800.5, fy=1799.25, cx=960.1, cy=600.2, width=1920, height=1200)
    raw = rm.encode_camera_info(k, stamp_ns=3_000_000_007, frame_id="cam")
    msg = rm.decode_camera_info(raw, where="t")
    assert msg.stamp_ns == 3_000_000_007 and msg.frame_id == "cam"
    assert rm.camera_info_to_intrinsics(msg, where="t") == k
    ref = generate_dynamic(rm.CAMERAINFO, rm.SCHEMAS[rm.CAMERAINFO])[rm.CAMERAINFO](raw)
    assert list(ref.k) == list(msg.k) and list(ref.p) == list(msg.p) and ref.distortion_model == "plumb_bob"
    assert ref.header.stamp.sec == 3 and ref.header.stamp.nanosec == 7


def test_camera_info_bad_k():
    zero = rm.CameraInfoMsg(0, "c", 10, 10, "", (), (0.0,) * 9, (0.0,) * 9, (0.0,) * 12)
    with pytest.raises(LogFormatError, match="^ci: CameraInfo is unusable: Intrinsics.fx must be"):
        rm.camera_info_to_intrinsics(zero, where="ci")


def test_schema_texts_parse_with_mcap_ros2():
    for name, text in rm.SCHEMAS.items():
        classes = generate_dynamic(name, text)
        assert name in classes
    assert "MSG: std_msgs/Header" in rm.SCHEMAS[rm.IMAGE]
    assert "MSG: sensor_msgs/RegionOfInterest" in rm.SCHEMAS[rm.CAMERAINFO]


# ---------------------------------------------------------------------------- properties
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra.numpy import arrays  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(
    xyz=arrays(np.float32, st.tuples(st.integers(2, 6), st.integers(1, 6), st.just(3)),
               elements=st.sampled_from([0.0, -0.0, 1.5, -2.25, np.nan, np.inf, -np.inf, 1e-30, 3e38])),
    with_rgb=st.booleans(),
)
def test_pack_unpack_law(xyz, with_rgb):
    """Written then read: valid points unchanged; any non-finite or (0, 0, 0) point -> all NaN."""
    h, w = xyz.shape[:2]
    rgb = (np.arange(h * w * 3, dtype=np.uint8).reshape(h, w, 3) * 7) if with_rgb else None
    raw = rm.encode_cloud(stamp_ns=1, frame_id="f", height=h, width=w,
                          fields=rm.XYZRGBA_FIELDS if with_rgb else rm.XYZ_FIELDS, point_step=16,
                          row_step=16 * w, data=rm.arrays_to_cloud_data(xyz, rgb), is_dense=True)
    got, got_rgb = rm.cloud_to_arrays(rm.decode_cloud(raw), where="t")
    invalid = ~np.isfinite(xyz).all(axis=2) | (xyz == 0).all(axis=2)
    assert np.isnan(got[invalid]).all()
    np.testing.assert_array_equal(got[~invalid], xyz[~invalid])
    if with_rgb:
        np.testing.assert_array_equal(got_rgb, rgb)
    else:
        assert got_rgb is None


@pytest.mark.parametrize("offsets,point_step,row_pad", [
    ((0, 4, 8, 12), 16, 0),  # zivid-ros points/xyzrgba
    ((0, 4, 8, 16), 32, 0),  # PCL PointXYZRGB (padding after z)
    ((8, 0, 4, 20), 24, 4),  # any order, padded rows
    ((0, 4, 8, 12), 16, 2),  # rows not 4-byte aligned: the field-view path
    ((0, 4, 8, None), 12, 0),  # no colour
])
def test_cloud_word_layouts_match_a_numpy_reference(rng, offsets, point_step, row_pad):
    """Little-endian FLOAT32 layouts on 4-byte boundaries are unpacked bitwise: same result as
    the definition (NaN where a coordinate is not finite or the point is (0, 0, 0), -0.0 too)."""
    h, w = 9, 11
    row_step = w * point_step + row_pad
    buf = rng.integers(0, 256, h * row_step, dtype=np.uint8)
    specials = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-40, -2.5, 3.0e38], np.float32)
    coords = rng.choice(specials, (h, w, 3)).astype(np.float32)
    coords[rng.random((h, w)) < 0.3] = rng.normal(size=3).astype(np.float32)
    coords[0, 0] = (0.0, -0.0, 0.0)
    coords[0, 1] = (0.0, 0.0, 1e-40)  # a denormal is a valid point
    colour = rng.integers(0, 2**32, (h, w), dtype=np.uint32)
    for i in range(h):
        for j in range(w):
            base = i * row_step + j * point_step
            for k in range(3):
                buf[base + offsets[k] : base + offsets[k] + 4] = np.frombuffer(coords[i, j, k].astype("<f4").tobytes(), np.uint8)
            if offsets[3] is not None:
                buf[base + offsets[3] : base + offsets[3] + 4] = np.frombuffer(colour[i, j].astype("<u4").tobytes(), np.uint8)
    fields = [rm.PointField(n, o, rm.FLOAT32, 1) for n, o in zip("xyz", offsets)]
    if offsets[3] is not None:
        fields.append(rm.PointField("rgba", offsets[3], rm.UINT32, 1))
    raw = rm.encode_cloud(stamp_ns=1, frame_id="f", height=h, width=w, fields=fields, point_step=point_step,
                          row_step=row_step, data=buf.tobytes(), is_dense=False)
    xyz, rgb = rm.cloud_to_arrays(rm.decode_cloud(raw), where="t")
    expect = coords.copy()
    bad = ~np.isfinite(expect).all(axis=2) | (expect == 0).all(axis=2)
    expect[bad] = np.nan
    assert bad[0, 0] and not bad[0, 1]
    np.testing.assert_array_equal(xyz, expect)
    assert np.array_equal(xyz.view(np.uint32)[~bad], coords.view(np.uint32)[~bad])  # bits kept
    if offsets[3] is None:
        assert rgb is None
    else:
        np.testing.assert_array_equal(rgb, np.stack([(colour >> 16) & 255, (colour >> 8) & 255, colour & 255], -1))
