"""ROS 2 message schemas and fast CDR codecs for the messages zcut reads and writes.

Only four message types matter here: ``sensor_msgs/msg/PointCloud2``, ``sensor_msgs/msg/Image``,
``sensor_msgs/msg/CameraInfo`` (with their dependencies ``std_msgs/msg/Header``,
``builtin_interfaces/msg/Time``, ``sensor_msgs/msg/PointField``,
``sensor_msgs/msg/RegionOfInterest``). They are encoded and decoded by hand (XCDR1, as ROS 2's
rmw implementations write it: a 4-byte encapsulation header, then fields aligned to their size
relative to the end of that header). The big ``uint8[] data`` arrays are never copied field by
field: the decoders return a ``memoryview`` slice of the message and the numpy codecs view it
with a structured dtype built from the ``PointField`` list.

Every size is checked against the byte length before a view is made; a malformed message raises
:class:`~replay.errors.LogFormatError` whose message names the topic, the message index and the
mismatch (never a numpy or struct exception).
"""

from __future__ import annotations

import struct
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from replay.errors import LogFormatError, OverCapError
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError, ZcutError

# --------------------------------------------------------------------------------------------
# Schema texts (ros2msg, dependencies appended the way rosbag2 / mcap_ros2 expect them)
# --------------------------------------------------------------------------------------------

_SEP = "=" * 80 + "\n"

TIME_MSG = "int32 sec\nuint32 nanosec\n"
HEADER_MSG = "builtin_interfaces/Time stamp\nstring frame_id\n"
POINTFIELD_MSG = (
    "uint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\nuint8 UINT16  = 4\n"
    "uint8 INT32   = 5\nuint8 UINT32  = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n"
    "string name\nuint32 offset\nuint8  datatype\nuint32 count\n"
)
ROI_MSG = "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
POINTCLOUD2_MSG = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\n"
    "bool    is_bigendian\nuint32  point_step\nuint32  row_step\nuint8[] data\nbool is_dense\n"
)
IMAGE_MSG = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    "uint32 step\nuint8[] data\n"
)
CAMERAINFO_MSG = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
    "float64[9]  k\nfloat64[9]  r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
    "sensor_msgs/RegionOfInterest roi\n"
)


def _with_deps(main: str, deps: list[tuple[str, str]]) -> str:
    text = main
    for name, body in deps:
        text += "\n" + _SEP + f"MSG: {name}\n" + body
    return text


POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMERAINFO = "sensor_msgs/msg/CameraInfo"

#: Full ros2msg schema text (with dependency definitions) per message type.
SCHEMAS: dict[str, str] = {
    POINTCLOUD2: _with_deps(
        POINTCLOUD2_MSG,
        [
            ("std_msgs/Header", HEADER_MSG),
            ("builtin_interfaces/Time", TIME_MSG),
            ("sensor_msgs/PointField", POINTFIELD_MSG),
        ],
    ),
    IMAGE: _with_deps(
        IMAGE_MSG, [("std_msgs/Header", HEADER_MSG), ("builtin_interfaces/Time", TIME_MSG)]
    ),
    CAMERAINFO: _with_deps(
        CAMERAINFO_MSG,
        [
            ("std_msgs/Header", HEADER_MSG),
            ("builtin_interfaces/Time", TIME_MSG),
            ("sensor_msgs/RegionOfInterest", ROI_MSG),
        ],
    ),
}

# PointField datatypes -> (numpy kind+size)
_PF_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

# --------------------------------------------------------------------------------------------
# Decoded messages (headers only; the payload stays a memoryview into the message bytes)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PointField:
    name: str
    offset: int
    datatype: int
    count: int


@dataclass(frozen=True, slots=True)
class CloudMsg:
    """A decoded ``PointCloud2``; ``data`` is a view into the message bytes (not a copy)."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    fields: tuple[PointField, ...]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: memoryview
    is_dense: bool


@dataclass(frozen=True, slots=True)
class ImageMsg:
    """A decoded ``Image``; ``data`` is a view into the message bytes (not a copy)."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: bool
    step: int
    data: memoryview


@dataclass(frozen=True, slots=True)
class CameraInfoMsg:
    stamp_ns: int
    frame_id: str
    height: int
    width: int
    distortion_model: str
    d: tuple[float, ...]
    k: tuple[float, ...]
    r: tuple[float, ...]
    p: tuple[float, ...]


# --------------------------------------------------------------------------------------------
# CDR reading
# --------------------------------------------------------------------------------------------


class _Cdr:
    """Bounds-checked XCDR1 reader over a bytes-like object."""

    __slots__ = ("buf", "pos", "end", "bo", "where")

    def __init__(self, data: bytes | memoryview, where: str) -> None:
        self.buf = memoryview(data).cast("B") if not isinstance(data, bytes) else memoryview(data)
        self.end = len(self.buf)
        self.where = where
        if self.end < 4:
            self.fail(f"message has {self.end} bytes, too short for a CDR header")
        kind = self.buf[1]
        if self.buf[0] != 0 or kind not in (0, 1):
            self.fail(
                f"unsupported CDR encapsulation {bytes(self.buf[:2]).hex()} "
                "(expected 0001 little-endian or 0000 big-endian CDR)"
            )
        self.bo = "<" if kind == 1 else ">"
        self.pos = 4

    def fail(self, what: str) -> None:
        raise LogFormatError(f"{self.where}: {what}")

    def _align(self, n: int) -> None:
        r = (self.pos - 4) % n
        if r:
            self.pos += n - r

    def _take(self, n: int, what: str) -> int:
        start = self.pos
        if n < 0 or start + n > self.end:
            self.fail(
                f"{what} needs {n} bytes at offset {start} but the message has only "
                f"{max(self.end - start, 0)} left"
            )
        self.pos = start + n
        return start

    def u8(self, what: str) -> int:
        return self.buf[self._take(1, what)]

    def u32(self, what: str) -> int:
        self._align(4)
        s = self._take(4, what)
        value: int = struct.unpack_from(self.bo + "I", self.buf, s)[0]
        return value

    def i32(self, what: str) -> int:
        self._align(4)
        s = self._take(4, what)
        value: int = struct.unpack_from(self.bo + "i", self.buf, s)[0]
        return value

    def f64s(self, n: int, what: str) -> tuple[float, ...]:
        if n == 0:
            return ()
        self._align(8)
        s = self._take(8 * n, what)
        return struct.unpack_from(f"{self.bo}{n}d", self.buf, s)

    def string(self, what: str) -> str:
        n = self.u32(what + " length")
        s = self._take(n, what)
        raw = bytes(self.buf[s : s + n])
        if raw.endswith(b"\x00"):
            raw = raw[:-1]
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self.fail(f"{what} is not valid UTF-8")
            raise AssertionError from None  # unreachable

    def blob(self, what: str) -> memoryview:
        n = self.u32(what + " length")
        s = self._take(n, what)
        return self.buf[s : s + n]

    def header(self) -> tuple[int, str]:
        sec = self.i32("header.stamp.sec")
        nsec = self.u32("header.stamp.nanosec")
        frame_id = self.string("header.frame_id")
        return sec * 1_000_000_000 + nsec, frame_id


def decode_cloud(data: bytes | memoryview, *, where: str = "PointCloud2") -> CloudMsg:
    """Decode a CDR ``PointCloud2`` (``data`` stays a view). Raises :class:`LogFormatError`."""
    r = _Cdr(data, where)
    stamp_ns, frame_id = r.header()
    height = r.u32("height")
    width = r.u32("width")
    n_fields = r.u32("fields length")
    if n_fields > (r.end - r.pos) // 13:  # each field takes at least 13 bytes
        r.fail(f"claims {n_fields} point fields, more than the message can hold")
    fields = []
    for i in range(n_fields):
        name = r.string(f"fields[{i}].name")
        offset = r.u32(f"fields[{i}].offset")
        datatype = r.u8(f"fields[{i}].datatype")
        count = r.u32(f"fields[{i}].count")
        fields.append(PointField(name, offset, datatype, count))
    is_bigendian = bool(r.u8("is_bigendian"))
    point_step = r.u32("point_step")
    row_step = r.u32("row_step")
    blob = r.blob("data")
    is_dense = bool(r.u8("is_dense")) if r.pos < r.end else False
    return CloudMsg(
        stamp_ns, frame_id, height, width, tuple(fields), is_bigendian, point_step, row_step, blob,
        is_dense,
    )


def decode_image(data: bytes | memoryview, *, where: str = "Image") -> ImageMsg:
    """Decode a CDR ``Image`` (``data`` stays a view). Raises :class:`LogFormatError`."""
    r = _Cdr(data, where)
    stamp_ns, frame_id = r.header()
    height = r.u32("height")
    width = r.u32("width")
    encoding = r.string("encoding")
    is_bigendian = bool(r.u8("is_bigendian"))
    step = r.u32("step")
    blob = r.blob("data")
    return ImageMsg(stamp_ns, frame_id, height, width, encoding, is_bigendian, step, blob)


def decode_camera_info(data: bytes | memoryview, *, where: str = "CameraInfo") -> CameraInfoMsg:
    """Decode a CDR ``CameraInfo``. Raises :class:`LogFormatError`."""
    r = _Cdr(data, where)
    stamp_ns, frame_id = r.header()
    height = r.u32("height")
    width = r.u32("width")
    model = r.string("distortion_model")
    n_d = r.u32("d length")
    if n_d > (r.end - r.pos) // 8:
        r.fail(f"claims {n_d} distortion coefficients, more than the message can hold")
    d = r.f64s(n_d, "d")
    k = r.f64s(9, "k")
    rr = r.f64s(9, "r")
    p = r.f64s(12, "p")
    return CameraInfoMsg(stamp_ns, frame_id, height, width, model, d, k, rr, p)


# --------------------------------------------------------------------------------------------
# CDR writing (little-endian)
# --------------------------------------------------------------------------------------------

#: Largest header stamp a ROS 2 message can carry (``builtin_interfaces/Time``: int32 seconds,
#: so 2038-01-19 03:14:07.999999999 UTC); zcut writes stamps in [0, MAX_STAMP_NS].
MAX_STAMP_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999


def check_stamp(stamp_ns: int) -> None:
    """Raise :class:`~zcut.errors.ParameterError` (a ValueError; one line) unless
    ``0 <= stamp_ns <= MAX_STAMP_NS``."""
    if not 0 <= int(stamp_ns) <= MAX_STAMP_NS:
        raise ParameterError(
            f"stamp {stamp_ns} ns is outside the ROS 2 time range 0 .. {MAX_STAMP_NS} ns "
            "(int32 seconds: up to 2038-01-19 03:14:07 UTC)"
        )



class _CdrOut:
    __slots__ = ("parts", "pos")

    def __init__(self) -> None:
        self.parts: list[bytes] = [b"\x00\x01\x00\x00"]
        self.pos = 0  # position after the encapsulation header

    def _pad(self, n: int) -> None:
        r = self.pos % n
        if r:
            self.parts.append(b"\x00" * (n - r))
            self.pos += n - r

    def raw(self, b: bytes) -> None:
        self.parts.append(b)
        self.pos += len(b)

    def u8(self, v: int) -> None:
        self.raw(struct.pack("<B", v))

    def u32(self, v: int) -> None:
        self._pad(4)
        self.raw(struct.pack("<I", v))

    def i32(self, v: int) -> None:
        self._pad(4)
        self.raw(struct.pack("<i", v))

    def f64s(self, values: Iterable[float]) -> None:
        vals = list(values)
        if vals:
            self._pad(8)
            self.raw(struct.pack(f"<{len(vals)}d", *vals))

    def string(self, s: str, what: str) -> None:
        try:
            b = s.encode("utf-8") + b"\x00"
        except UnicodeEncodeError:  # e.g. undecodable bytes of a command-line argument (surrogates)
            raise ParameterError(f"{what} {s!r} is not valid UTF-8 text (a ROS 2 string must be)") from None
        self.u32(len(b))
        self.raw(b)

    def blob(self, b: bytes | memoryview) -> None:
        self.u32(len(b))
        self.raw(b)  # type: ignore[arg-type]

    def header(self, stamp_ns: int, frame_id: str) -> None:
        check_stamp(stamp_ns)
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        self.i32(sec)
        self.u32(nsec)
        self.string(frame_id, "frame_id")

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def encode_cloud(
    *,
    stamp_ns: int,
    frame_id: str,
    height: int,
    width: int,
    fields: list[PointField] | tuple[PointField, ...],
    point_step: int,
    row_step: int,
    data: bytes | memoryview,
    is_dense: bool,
    is_bigendian: bool = False,
) -> bytes:
    """CDR bytes of a ``PointCloud2``."""
    w = _CdrOut()
    w.header(stamp_ns, frame_id)
    w.u32(height)
    w.u32(width)
    w.u32(len(fields))
    for f in fields:
        w.string(f.name, "PointField name")
        w.u32(f.offset)
        w.u8(f.datatype)
        w.u32(f.count)
    w.u8(int(is_bigendian))
    w.u32(point_step)
    w.u32(row_step)
    w.blob(data)
    w.u8(int(is_dense))
    return w.bytes()


def encode_image(
    *, stamp_ns: int, frame_id: str, height: int, width: int, encoding: str, step: int,
    data: bytes | memoryview,
) -> bytes:
    """CDR bytes of an ``Image``."""
    w = _CdrOut()
    w.header(stamp_ns, frame_id)
    w.u32(height)
    w.u32(width)
    w.string(encoding, "Image encoding")
    w.u8(0)
    w.u32(step)
    w.blob(data)
    return w.bytes()


def encode_camera_info(intrinsics: Intrinsics, *, stamp_ns: int, frame_id: str) -> bytes:
    """CDR bytes of a ``CameraInfo`` (plumb_bob, no distortion, identity R)."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    w = _CdrOut()
    w.header(stamp_ns, frame_id)
    w.u32(intrinsics.height)
    w.u32(intrinsics.width)
    w.string("plumb_bob", "distortion_model")
    w.u32(5)
    w.f64s([0.0] * 5)
    w.f64s([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    w.f64s([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    w.f64s([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    w.u32(0)
    w.u32(0)
    for _ in range(4):
        w.u32(0)
    w.u8(0)
    return w.bytes()


# --------------------------------------------------------------------------------------------
# numpy codecs
# --------------------------------------------------------------------------------------------

#: Fields of the clouds zcut writes (like zivid-ros ``points/xyzrgba``).
XYZRGBA_FIELDS = (
    PointField("x", 0, FLOAT32, 1),
    PointField("y", 4, FLOAT32, 1),
    PointField("z", 8, FLOAT32, 1),
    PointField("rgba", 12, UINT32, 1),
)
XYZ_FIELDS = XYZRGBA_FIELDS[:3]


#: Makes an uninitialised output array from ``(shape, dtype)``: ``np.empty``, or a pool's
#: (:meth:`replay.logs.mcap_scan.BufferPool.array`: a reader decodes its frames into reused memory)
Alloc = Callable[[tuple[int, ...], Any], np.ndarray]


def check_grid(h: int, w: int, max_pixels: int | None, *, what: str, where: str) -> None:
    """Raise :class:`~replay.errors.OverCapError` (a :class:`LogFormatError`) if an ``h`` x ``w`` grid
    exceeds ``max_pixels`` (None: no cap)."""
    if max_pixels is not None and h * w > max_pixels:
        raise OverCapError(
            f"{where}: {what} of {h}x{w} = {h * w} pixels is more than the cap of {max_pixels} (max_pixels; raise it with ZCUT_MAX_PIXELS)"
        )


def _check_rows(data: memoryview, h: int, w: int, *, step: int, row: int, what: str, short: str, layout: str,
                where: str, max_pixels: int | None, **parts: object) -> int:
    """Check that ``h`` rows of ``row`` bytes each, ``step`` bytes apart, fit in ``data`` and that the
    ``h`` x ``w`` grid is within ``max_pixels``; return the bytes the rows span.

    ``short`` and ``layout`` are :meth:`str.format` templates over ``h``, ``w``, ``step``, ``row`` and ``parts``,
    formatted only when an error is raised: :class:`LogFormatError` ``"{where}: {what} {short}"`` if
    ``step < row``, ``"{where}: {layout} needs N bytes of data but has M"`` if the rows do not fit, and
    :func:`check_grid`'s error."""
    if step < row:
        raise LogFormatError(f"{where}: {what} {short.format(h=h, w=w, step=step, row=row, **parts)}")
    need = (h - 1) * step + row
    if need > len(data):
        rows = layout.format(h=h, w=w, step=step, row=row, **parts)
        raise LogFormatError(f"{where}: {rows} needs {need} bytes of data but has {len(data)}")
    check_grid(h, w, max_pixels, what=what, where=where)
    return need


def cloud_to_arrays(
    msg: CloudMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty,
) -> tuple[np.ndarray, np.ndarray | None]:
    """View a ``PointCloud2`` as arrays (:func:`cloud_to_arrays_valid` without its valid mask).

    The size is checked against the bytes present and ``max_pixels`` before the output arrays
    are allocated (by ``alloc``; every element is written).

    Parameters
    ----------
    msg : CloudMsg
    where : str
        "topic /x, message 3" style prefix for error messages.
    max_pixels : int or None
        Largest H x W accepted (None: no cap).

    Returns
    -------
    xyz : (H, W, 3) float32 ndarray
        Metres; NaN where any coordinate is non-finite or the point is exactly (0, 0, 0),
        whatever ``is_dense`` claims.
    rgb : (H, W, 3) uint8 ndarray or None
        From an ``rgb``/``rgba`` field (UINT32 or FLOAT32-packed ``0x00RRGGBB``), else None.
    """
    xyz, rgb, _ = cloud_to_arrays_valid(msg, where=where, max_pixels=max_pixels, alloc=alloc, valid=False)
    return xyz, rgb


def cloud_to_arrays_valid(
    msg: CloudMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty, valid: bool = True,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`cloud_to_arrays` and, written by the same pass, the pixels whose point is valid.

    Parameters
    ----------
    msg : CloudMsg
    where : str
        "topic /x, message 3" style prefix for error messages.
    max_pixels : int or None
        Largest H x W accepted (None: no cap).
    alloc : callable
        Allocates the output arrays (``np.empty``'s signature; every element is written).
    valid : bool
        Write the valid mask where the layout allows it (False: never).

    Returns
    -------
    xyz, rgb
        As :func:`cloud_to_arrays`.
    valid : (H, W) bool ndarray or None
        True where ``xyz`` holds three finite coordinates, the same array as
        ``zcut.removal.valid_pixels(xyz)`` computes in a pass of its own (a replay's locator did, 1.7-5.8 CPU ms
        a 1920 x 1200 frame: docs/performance.md, "The frame's valid pixels from its decoding"); None for the
        layouts whose kernel does not write it (only zcut's own 16-byte points without colour do).
    """
    h, w, step, row_step = msg.height, msg.width, msg.point_step, msg.row_step
    by_name = {f.name: f for f in msg.fields}
    for name in ("x", "y", "z"):
        if name not in by_name:
            have = ", ".join(f.name for f in msg.fields) or "none"
            raise LogFormatError(f"{where}: PointCloud2 has no '{name}' field (fields: {have})")
    if h < 1 or w < 1:
        raise LogFormatError(f"{where}: PointCloud2 is empty (height {h}, width {w})")
    if step < 1:
        raise LogFormatError(f"{where}: PointCloud2 point_step is {step}")
    _check_rows(msg.data, h, w, step=row_step, row=w * step, what="PointCloud2",
                short="row_step {step} is smaller than width {w} x point_step {point_step}",
                layout="PointCloud2 of {h}x{w} with row_step {step}, point_step {point_step}",
                where=where, max_pixels=max_pixels, point_step=step)
    bo = ">" if msg.is_bigendian else "<"
    coord_types = set()
    for name in ("x", "y", "z"):
        f = by_name[name]
        if f.datatype not in (FLOAT32, FLOAT64):
            raise LogFormatError(
                f"{where}: PointCloud2 field '{name}' has datatype {f.datatype}; "
                "zcut reads x, y, z as FLOAT32 (7) or FLOAT64 (8)"
            )
        coord_types.add(f.datatype)
        size = 4 if f.datatype == FLOAT32 else 8
        if f.offset + size > step:
            raise LogFormatError(
                f"{where}: PointCloud2 field '{name}' at offset {f.offset} does not fit in "
                f"point_step {step}"
            )
    names = ["x", "y", "z"]
    formats = [bo + _PF_TYPES[by_name[n].datatype] for n in names]
    offsets = [by_name[n].offset for n in names]
    color = by_name.get("rgba") or by_name.get("rgb")
    if color is not None:
        if color.datatype not in (UINT32, FLOAT32, INT32) or color.offset + 4 > step:
            color = None  # an unusual colour field: ignore it rather than guess
        else:
            names.append("c")
            formats.append(bo + "u4")  # FLOAT32-packed colour is the same 4 bytes
            offsets.append(color.offset)
    xyz = alloc((h, w, 3), np.float32)
    rgb = alloc((h, w, 3), np.uint8) if color is not None else None
    ok: np.ndarray | None = None
    words_ok = (
        not msg.is_bigendian and sys.byteorder == "little" and coord_types == {FLOAT32}
        and step % 4 == 0 and row_step % 4 == 0 and all(o % 4 == 0 for o in offsets)
    )
    if words_ok:
        # the common layouts (zivid-ros, PCL): the points as 32-bit words, checked bitwise
        words = np.ndarray((h, w, step // 4), dtype=np.uint32, buffer=msg.data, offset=0,
                           strides=(row_step, step, 4))
        ox, oy, oz = (o // 4 for o in offsets[:3])
        if rgb is not None:
            _unpack_words_rgb(words, ox, oy, oz, offsets[3] // 4, xyz, rgb)
        elif (ox, oy, oz) == (0, 1, 2) and step == 16 and row_step == 16 * w and xyz.flags.c_contiguous:
            # zcut's own layout (x, y, z, rgba: 16 bytes a point, rows back to back; the synthetic logs and
            # `zcut record`'s): the points as one run of 4-word groups, offsets known to the compiler
            if valid:
                ok = alloc((h, w), np.bool_)
                _unpack_words16_valid(words.reshape(-1), xyz.reshape(-1).view(np.uint32), ok.reshape(-1))
            else:
                _unpack_words16(words.reshape(-1), xyz.reshape(-1).view(np.uint32))
        else:
            _unpack_words(words, ox, oy, oz, xyz)
        return xyz, rgb, ok
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    # zero-copy view: rows row_step apart, points point_step apart (padding never touched)
    pts = np.ndarray((h, w), dtype=dt, buffer=msg.data, offset=0, strides=(row_step, step))
    px, py, pz = pts["x"], pts["y"], pts["z"]
    if msg.is_bigendian or px.dtype != py.dtype or px.dtype != pz.dtype:  # numba wants native order
        px, py, pz = (a.astype(np.float64) for a in (px, py, pz))
    if rgb is not None:
        c = pts["c"]
        if msg.is_bigendian:
            c = c.astype(np.uint32)
        _unpack_xyz_rgb(px, py, pz, c, xyz, rgb)
    else:
        _unpack_xyz(px, py, pz, xyz)
    return xyz, rgb, None


@numba.njit(cache=True, nogil=True)
def _unpack_xyz(px, py, pz, xyz):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    h, w = px.shape
    nan = np.float32(np.nan)
    for i in range(h):
        for j in range(w):
            x = np.float32(px[i, j])
            y = np.float32(py[i, j])
            z = np.float32(pz[i, j])
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)) or (x == 0 and y == 0 and z == 0):
                x = y = z = nan
            xyz[i, j, 0] = x
            xyz[i, j, 1] = y
            xyz[i, j, 2] = z


@numba.njit(cache=True, nogil=True)
def _unpack_xyz_rgb(px, py, pz, c, xyz, rgb):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # one pass: each point's bytes are read from memory once
    h, w = px.shape
    nan = np.float32(np.nan)
    for i in range(h):
        for j in range(w):
            x = np.float32(px[i, j])
            y = np.float32(py[i, j])
            z = np.float32(pz[i, j])
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)) or (x == 0 and y == 0 and z == 0):
                x = y = z = nan
            xyz[i, j, 0] = x
            xyz[i, j, 1] = y
            xyz[i, j, 2] = z
            v = np.uint32(c[i, j])
            rgb[i, j, 0] = (v >> 16) & 0xFF
            rgb[i, j, 1] = (v >> 8) & 0xFF
            rgb[i, j, 2] = v & 0xFF


_EXP = np.uint32(0x7F800000)  # float32 exponent bits: all set = inf or NaN
_ABS = np.uint32(0x7FFFFFFF)
_NAN = np.uint32(0x7FC00000)  # the bits of np.float32(np.nan)
_ALL = np.uint32(0xFFFFFFFF)
_NONE = np.uint32(0)


@numba.njit(cache=True, nogil=True)
def _unpack_words(words, ox, oy, oz, xyz):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # same result as _unpack_xyz for little-endian FLOAT32 coordinates, bitwise and branch-free
    h, w = words.shape[0], words.shape[1]
    out = xyz.view(np.uint32)
    for i in range(h):
        for j in range(w):
            x = words[i, j, ox]
            y = words[i, j, oy]
            z = words[i, j, oz]
            bad = ((x & _EXP) == _EXP) | ((y & _EXP) == _EXP) | ((z & _EXP) == _EXP) | (((x | y | z) & _ABS) == 0)
            out[i, j, 0] = _NAN if bad else x
            out[i, j, 1] = _NAN if bad else y
            out[i, j, 2] = _NAN if bad else z


@numba.njit(cache=True, nogil=True, inline="always")
def _point16(words, out, k):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # point k of 4-word points into out's words 3k..3k+2, NaN, NaN, NaN if it is bad (a coordinate with an
    # all-ones exponent, or all three zero); returns whether it was bad. Inlined into the two kernels below
    x = words[4 * k]
    y = words[4 * k + 1]
    z = words[4 * k + 2]
    bad = ((x & _EXP) == _EXP) | ((y & _EXP) == _EXP) | ((z & _EXP) == _EXP) | (((x | y | z) & _ABS) == 0)
    m = _ALL if bad else _NONE
    out[3 * k] = (x & ~m) | (_NAN & m)
    out[3 * k + 1] = (y & ~m) | (_NAN & m)
    out[3 * k + 2] = (z & ~m) | (_NAN & m)
    return bad


@numba.njit(cache=True, nogil=True)
def _unpack_words16(words, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # _unpack_words for x, y, z at words 0, 1, 2 of 4-word points, rows back to back: ``words`` the points'
    # (4 n,) words, ``out`` the (3 n,) words of xyz. With the offsets and strides constants the compiler
    # vectorizes the loop (a blend instead of a branch): ~0.7 x the time of the general kernel's pass
    # (docs/performance.md, "The replay's read and hand-offs"); the same bits
    for k in range(out.shape[0] // 3):
        _point16(words, out, k)


@numba.njit(cache=True, nogil=True)
def _unpack_words16_valid(words, out, valid):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # _unpack_words16, and ``valid`` the (n,) points' "not bad": after the unpacking a point's three coordinates
    # are finite exactly when it was not bad (a bad point is NaN, NaN, NaN; a kept one has no all-ones exponent)
    for k in range(out.shape[0] // 3):
        valid[k] = not _point16(words, out, k)


@numba.njit(cache=True, nogil=True)
def _unpack_words_rgb(words, ox, oy, oz, oc, xyz, rgb):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    h, w = words.shape[0], words.shape[1]
    out = xyz.view(np.uint32)
    for i in range(h):
        for j in range(w):
            x = words[i, j, ox]
            y = words[i, j, oy]
            z = words[i, j, oz]
            bad = ((x & _EXP) == _EXP) | ((y & _EXP) == _EXP) | ((z & _EXP) == _EXP) | (((x | y | z) & _ABS) == 0)
            out[i, j, 0] = _NAN if bad else x
            out[i, j, 1] = _NAN if bad else y
            out[i, j, 2] = _NAN if bad else z
            v = words[i, j, oc]
            rgb[i, j, 0] = (v >> 16) & 0xFF
            rgb[i, j, 1] = (v >> 8) & 0xFF
            rgb[i, j, 2] = v & 0xFF


def arrays_to_cloud_data(xyz: np.ndarray, rgb: np.ndarray | None) -> memoryview:
    """Pack (H, W, 3) xyz (+ optional (H, W, 3) uint8 rgb) as x, y, z FLOAT32 + rgba UINT32
    little-endian (16 bytes per point; the last 4 are zero padding when rgb is None)."""
    h, w = xyz.shape[:2]
    out = np.empty((h, w, 4), dtype="<f4")
    if sys.byteorder == "little":
        if rgb is None:
            _pack_xyz(xyz, out)
        else:
            _pack_xyz_rgb(xyz, rgb, out)
    else:  # pragma: no cover - big-endian hosts
        out[..., :3] = xyz
        out.view("<u4")[..., 3] = 0
        if rgb is not None:
            r = rgb.astype(np.uint32)
            out.view("<u4")[..., 3] = (0xFF << 24) | (r[..., 0] << 16) | (r[..., 1] << 8) | r[..., 2]
    return memoryview(out).cast("B")  # type: ignore[arg-type]  # an ndarray is a buffer


@numba.njit(cache=True, nogil=True)
def _pack_xyz(xyz, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    h, w = out.shape[0], out.shape[1]
    bits = out.view(np.uint32)
    for i in range(h):
        for j in range(w):
            out[i, j, 0] = xyz[i, j, 0]
            out[i, j, 1] = xyz[i, j, 1]
            out[i, j, 2] = xyz[i, j, 2]
            bits[i, j, 3] = 0


@numba.njit(cache=True, nogil=True)
def _pack_xyz_rgb(xyz, rgb, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    h, w = out.shape[0], out.shape[1]
    bits = out.view(np.uint32)
    for i in range(h):
        for j in range(w):
            out[i, j, 0] = xyz[i, j, 0]
            out[i, j, 1] = xyz[i, j, 1]
            out[i, j, 2] = xyz[i, j, 2]
            bits[i, j, 3] = (
                np.uint32(0xFF000000) | (np.uint32(rgb[i, j, 0]) << 16) | (np.uint32(rgb[i, j, 1]) << 8)
                | np.uint32(rgb[i, j, 2])
            )


_IMAGE_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8")
#: zcut's bit-packed mask ``Image`` (docs/formats.md, "Results"): one bit a pixel, each row packed into
#: ``ceil(width / 8)`` bytes, its first pixel in the most significant bit (``np.packbits(mask, axis=1)``),
#: ``step`` bytes from one row to the next; 1 = set. Not a ROS standard encoding: ``zcut replay --out``
#: writes its masks so (the previous releases wrote ``mono8``, 255 = set; both are read).
PACKED_MASK_ENCODING = "mono1"
#: the Image encodings a mask is read from
MASK_ENCODINGS = ("mono8", PACKED_MASK_ENCODING)
#: the Image row check's layout in its errors (a template for :func:`_check_rows`)
_IMAGE_LAYOUT = "Image {h}x{w} {encoding} with step {step}"


def _image_pixels(msg: ImageMsg, *, where: str, max_pixels: int | None = None) -> np.ndarray:
    ch = _IMAGE_CHANNELS.get(msg.encoding)
    if ch is None:
        raise LogFormatError(
            f"{where}: Image encoding '{msg.encoding}' is not supported "
            f"(zcut reads {', '.join(_IMAGE_CHANNELS)})"
        )
    h, w, step = msg.height, msg.width, msg.step
    if h < 1 or w < 1:
        raise LogFormatError(f"{where}: Image is empty (height {h}, width {w})")
    need = _check_rows(msg.data, h, w, step=step, row=w * ch, what="Image",
                       short="step {step} is smaller than width {w} x {ch} bytes ({encoding})", layout=_IMAGE_LAYOUT,
                       where=where, max_pixels=max_pixels, ch=ch, encoding=msg.encoding)
    buf = np.frombuffer(msg.data, dtype=np.uint8, count=need)
    return np.lib.stride_tricks.as_strided(
        buf, shape=(h, w, ch), strides=(step, ch, 1), writeable=False
    )


def image_to_rgb(msg: ImageMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty) -> np.ndarray:
    """(H, W, 3) uint8 RGB copy of an rgb8/bgr8/rgba8/bgra8/mono8 ``Image`` (step padding dropped;
    H x W checked against the bytes present and ``max_pixels`` first), written into ``alloc``'s array."""
    px = _image_pixels(msg, where=where, max_pixels=max_pixels)
    enc = msg.encoding
    out = alloc((msg.height, msg.width, 3), np.uint8)  # a copy even for rgb8: never pin the chunk buffer
    if enc == "mono8":
        np.copyto(out, px)  # the one channel repeated
    elif enc in ("bgr8", "bgra8"):
        np.copyto(out, px[..., 2::-1])
    else:
        np.copyto(out, px[..., :3])
    return out


def image_to_mask(msg: ImageMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty) -> np.ndarray:
    """(H, W) bool of a mask ``Image``: ``mono8`` (nonzero, 255 as zcut wrote it, -> True; into
    ``alloc``'s array) or zcut's bit-packed ``mono1`` (:data:`PACKED_MASK_ENCODING`; set bits -> True)."""
    return mask_decoding(msg, where=where, max_pixels=max_pixels, alloc=alloc)()


def mask_decoding(msg: ImageMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty
                  ) -> Callable[[], np.ndarray]:
    """:func:`image_to_mask` in two steps: its checks now (the same :class:`LogFormatError`), and its array
    when the returned function is called (each call decodes the message's bytes anew; the function holds
    a view of them, not a copy)."""
    if msg.encoding == PACKED_MASK_ENCODING:
        return _packed_mask(msg, where=where, max_pixels=max_pixels)
    if msg.encoding != "mono8":
        raise LogFormatError(f"{where}: a mask must be a mono8 or {PACKED_MASK_ENCODING} Image, got '{msg.encoding}'")
    px = _image_pixels(msg, where=where, max_pixels=max_pixels)[..., 0]

    def decode() -> np.ndarray:
        mask: np.ndarray = np.not_equal(px, 0, out=alloc(px.shape, np.bool_))
        return mask

    return decode


def _packed_mask(msg: ImageMsg, *, where: str, max_pixels: int | None) -> Callable[[], np.ndarray]:
    """The (H, W) bool of a ``mono1`` Image, its sizes checked against the bytes present now."""
    h, w, step = msg.height, msg.width, msg.step
    if h < 1 or w < 1:
        raise LogFormatError(f"{where}: Image is empty (height {h}, width {w})")
    row = (w + 7) // 8
    need = _check_rows(msg.data, h, w, step=step, row=row, what="Image",
                       short="step {step} is smaller than width {w} / 8 bytes, rounded up ({row}; {encoding})",
                       layout=_IMAGE_LAYOUT, where=where, max_pixels=max_pixels, encoding=PACKED_MASK_ENCODING)
    buf = np.frombuffer(msg.data, dtype=np.uint8, count=need)
    rows = np.lib.stride_tricks.as_strided(buf, shape=(h, row), strides=(step, 1), writeable=False)

    def decode() -> np.ndarray:
        mask: np.ndarray = np.unpackbits(rows, axis=1, count=w).view(np.bool_)
        return mask

    return decode


def mask_to_packed(mask: np.ndarray) -> np.ndarray:
    """(H, ceil(W / 8)) uint8: an (H, W) bool mask's rows bit-packed as :data:`PACKED_MASK_ENCODING` holds them."""
    return np.packbits(np.ascontiguousarray(mask, dtype=np.bool_), axis=1)


def image_to_codes(msg: ImageMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty) -> np.ndarray:
    """(H, W) uint8 of a mono8 ``Image`` whose values are codes (e.g. an outlier-kind image), a copy
    (into ``alloc``'s array)."""
    return codes_decoding(msg, where=where, max_pixels=max_pixels, alloc=alloc)()


def codes_decoding(msg: ImageMsg, *, where: str, max_pixels: int | None = None, alloc: Alloc = np.empty
                   ) -> Callable[[], np.ndarray]:
    """:func:`image_to_codes` in two steps, as :func:`mask_decoding`: its checks now, its copy when called."""
    if msg.encoding != "mono8":
        raise LogFormatError(f"{where}: a code image must be a mono8 Image, got '{msg.encoding}'")
    px = _image_pixels(msg, where=where, max_pixels=max_pixels)[..., 0]

    def decode() -> np.ndarray:
        out = alloc(px.shape, np.uint8)
        np.copyto(out, px)
        return out

    return decode


def camera_info_to_intrinsics(msg: CameraInfoMsg, *, where: str) -> Intrinsics:
    """:class:`zcut.cloud.Intrinsics` from ``K`` of a ``CameraInfo``."""
    k = msg.k
    try:
        return Intrinsics(
            fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]),
            width=int(msg.width), height=int(msg.height),
        )
    except ZcutError as e:
        raise LogFormatError(f"{where}: CameraInfo is unusable: {e}") from e
