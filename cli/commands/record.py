"""``zcut record INPUT... -o LOG.mcap``: organized PLY/PCD files (or folders of them) -> a log.

Each cloud goes to ``/camera/points`` (PointCloud2, metres) and, when there is colour, an RGB image
to ``/camera/image``: a same-named ``.png`` next to the cloud file when present, else the cloud's
own colours. Frames are stamped ``--stamp-start + i * --period``. ``--bin-model PLY`` attaches a bin
model (from ``zcut bin-model``, or a CAD PLY in zcut's bin frame) to the log as its ``bin_model.ply``
attachment (``docs/formats.md``, "Bin model attachment"): every command then replays the log with it.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replay.logs import layout

if TYPE_CHECKING:
    from zcut.cloud import Intrinsics

CLOUD_SUFFIXES = (".pcd", ".ply")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="organized .ply/.pcd files or folders of them")
    parser.add_argument("-o", "--output", required=True, metavar="LOG.mcap", help="the log to write")
    parser.add_argument("--force", action="store_true", help="replace the output if it exists")
    parser.add_argument(
        "--stamp-start", type=float, default=0.0, metavar="SECONDS",
        help="header stamp of the first frame, seconds since the epoch (default 0)",
    )
    parser.add_argument("--period", type=float, default=1.0, metavar="SECONDS", help="time between frames (default 1)")
    parser.add_argument(
        "--frame-id", default="camera_optical_frame", help="header frame_id (default camera_optical_frame)"
    )
    from cli.commands.common import SIZE_HELP, size_wxh

    grid = parser.add_mutually_exclusive_group()
    grid.add_argument(
        "--size", type=size_wxh, metavar="WxH",
        help=f"the grid of PLY files without organization info, {SIZE_HELP}, as zcut synth --size",
    )
    grid.add_argument(
        "--shape", metavar="HxW",
        help="the same grid as HEIGHTxWIDTH, rows x columns (the old spelling, e.g. 1200x1920; prefer --size)",
    )
    cam = parser.add_argument_group(
        "the camera model, written as /camera/camera_info with every frame (what `cluster` and a_max need)")
    cam.add_argument("--camera-info", metavar="FILE.yaml",
                     help="a ROS camera_info YAML (camera_calibration_parsers' image_width, image_height, "
                          "camera_matrix; or a CameraInfo echo's width, height, k)")
    for name, what in (("fx", "focal length along x"), ("fy", "focal length along y"),
                       ("cx", "principal point x (column)"), ("cy", "principal point y (row)")):
        cam.add_argument(f"--{name}", type=float, metavar="PX", help=f"{what} in pixels (give all four)")
    parser.add_argument(
        "--unit", choices=("auto", "m", "mm"), default="auto",
        help="unit of the input coordinates; auto = mm when the median |z| exceeds 20 (default auto)",
    )
    parser.add_argument(
        "--bin-model", metavar="PLY",
        help="attach this bin model (from `zcut bin-model`; metres, bin frame, up = -z) to the log: commands "
             "replay it with that model without --bin-model",
    )
    parser.add_argument("--part-model", metavar="FILE",
                        help="attach this part mesh (PLY, STL or OBJ) to the log as its part_model.ply")
    parser.add_argument("--part-model-unit", choices=("mm", "m"), help="unit of --part-model's vertices (required)")


def expand_inputs(inputs: list[str]) -> list[Path]:
    """Files as given, folders expanded to their sorted .pcd/.ply files; raises ConfigError."""
    from replay.errors import ConfigError

    out: list[Path] = []
    for raw in inputs:
        p = Path(raw)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in CLOUD_SUFFIXES)
            if not found:
                raise ConfigError(f"folder {p} holds no .pcd or .ply file")
            out += found
        elif p.is_file():
            if p.suffix.lower() not in CLOUD_SUFFIXES:
                raise ConfigError(f"{p}: not a .pcd or .ply file")
            out.append(p)
        else:
            raise ConfigError(f"no such file or folder: {p}")
    return out


def _parse_shape(text: str | None) -> tuple[int, int] | None:
    from replay.errors import ConfigError

    if text is None:
        return None
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError as e:
        raise ConfigError(f"--shape must look like 1200x1920, got {text!r}") from e
    return _organized((h, w), f"--shape {text}")


def _organized(shape: tuple[int, int], given: str) -> tuple[int, int]:
    from replay.errors import ConfigError

    h, w = shape
    if h < 2 or w < 1:
        raise ConfigError(f"{given}: the grid must be organized (at least 2 rows and 1 column)")
    return h, w


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from replay.errors import ConfigError, LogFormatError
    from replay.logs.pcd import read_pcd
    from replay.logs.ply import read_ply
    from replay.logs.ros2_msgs import MAX_STAMP_NS
    from replay.logs.writer import LogWriter
    from replay.outputs import AtomicOutput, OutputPlan

    files = expand_inputs(args.inputs)
    shape = _parse_shape(args.shape) if args.size is None else _organized(args.size, f"--size {args.size[1]}x{args.size[0]}")
    if args.shape is not None and shape is not None:
        print(f"zcut: --shape {args.shape} is HEIGHTxWIDTH: a grid {shape[1]} wide and {shape[0]} high "
              f"(--size {shape[1]}x{shape[0]} says the same, WIDTHxHEIGHT as zcut synth)", file=sys.stderr)
    max_s = MAX_STAMP_NS / 1e9
    if not (np.isfinite(args.stamp_start) and 0 <= args.stamp_start <= max_s):
        raise ConfigError(f"--stamp-start must be in 0 .. {max_s:.0f} seconds (the ROS 2 time range, "
                          f"up to 2038-01-19), got {args.stamp_start}")
    if not (np.isfinite(args.period) and 0 < args.period <= max_s):
        raise ConfigError(f"--period must be > 0 and at most {max_s:.0f} seconds, got {args.period}")
    start_ns = int(round(args.stamp_start * 1e9))
    period_ns = int(round(args.period * 1e9))
    last_ns = start_ns + (len(files) - 1) * period_ns
    if last_ns > MAX_STAMP_NS:
        raise ConfigError(f"--stamp-start {args.stamp_start:g} + {len(files) - 1} × --period {args.period:g} s "
                          "goes past the ROS 2 time range (2038-01-19)")
    camera = camera_of(args)
    out = Path(args.output)
    inputs = [str(f) for f in files] + ([args.bin_model] if args.bin_model else []) \
        + ([args.camera_info] if args.camera_info else [])
    attachments = {}
    if args.bin_model is not None:
        attachments[layout.BIN_MODEL_ATTACHMENT] = (layout.BIN_MODEL_MEDIA_TYPE, _bin_model_bytes(args.bin_model))
    if args.part_model is not None:  # the part's mesh (docs/formats.md, "Part model attachment")
        from replay.logs.part_model import PART_MODEL_ATTACHMENT, PART_MODEL_MEDIA_TYPE, load_part_mesh

        if args.part_model_unit is None:
            raise ConfigError("--part-model needs --part-model-unit mm or m (the unit of its vertices)")
        inputs.append(args.part_model)
        attachments[PART_MODEL_ATTACHMENT] = (PART_MODEL_MEDIA_TYPE,
                                              load_part_mesh(args.part_model, unit=args.part_model_unit))
    meta = {"zcut.record": {"sources": "\n".join(str(f) for f in files), "unit": args.unit}}
    with OutputPlan(inputs, force=args.force) as plan, AtomicOutput(plan.add(out, "the log")) as target:
        with LogWriter(target.temp, metadata=meta, attachments=attachments, bag_name=out.name) as w:
            for i, f in enumerate(files):
                cloud = read_pcd(f) if f.suffix.lower() == ".pcd" else read_ply(f, shape=shape)
                xyz = cloud.xyz
                unit = args.unit
                if unit == "auto":
                    z = np.abs(xyz[..., 2][np.isfinite(xyz[..., 2])].astype(np.float64))
                    unit = "mm" if z.size and float(np.median(z)) > 20.0 else "m"
                if unit == "mm":
                    xyz = (xyz.astype(np.float64) / 1000.0).astype(np.float32)
                rgb = cloud.rgb
                png = f.with_suffix(".png")
                src = "cloud colours" if rgb is not None else "no colour"
                if png.is_file():
                    size = _png_size(png)
                    if size != xyz.shape[:2]:
                        raise LogFormatError(
                            f"{png}: image is {size[0]}x{size[1]} but its cloud {f.name} is "
                            f"{xyz.shape[0]}x{xyz.shape[1]}"
                        )
                    try:
                        bgr = cv2.imread(str(png), cv2.IMREAD_COLOR)
                    except cv2.error:
                        bgr = None
                    if bgr is None:
                        raise LogFormatError(f"{png}: not a readable image")
                    if bgr.shape[:2] != xyz.shape[:2]:
                        raise LogFormatError(
                            f"{png}: image is {bgr.shape[0]}x{bgr.shape[1]} but its cloud {f.name} is "
                            f"{xyz.shape[0]}x{xyz.shape[1]}"
                        )
                    rgb = np.ascontiguousarray(bgr[..., ::-1])
                    src = png.name
                stamp = start_ns + i * period_ns
                w.write_cloud(layout.CLOUD, xyz, rgb=rgb, stamp_ns=stamp, frame_id=args.frame_id)
                if rgb is not None:
                    w.write_image(layout.IMAGE, rgb, stamp_ns=stamp, frame_id=args.frame_id)
                if camera is not None:
                    w.write_camera_info(layout.CAMERA_INFO, camera.for_grid(xyz.shape[:2], f),
                                        stamp_ns=stamp, frame_id=args.frame_id)
                n_valid = int(np.isfinite(xyz).all(axis=2).sum())
                print(
                    f"{i:4d} {f.name}: {xyz.shape[0]}x{xyz.shape[1]}, {n_valid} valid points, "
                    f"unit {unit}, image from {src}"
                )
    print(f"wrote {len(files)} frames to {out}" + (f" with the bin model {args.bin_model}" if args.bin_model else "")
          + ("" if camera is None else f" and camera info ({camera.describe()})"))
    return 0


def _bin_model_bytes(path: str) -> bytes:
    """The PLY's bytes, once it has read as a bin model (bounded PLY reader, at least one point)."""
    from replay.errors import LogFormatError
    from replay.logs.files import DEFAULT_MAX_MESSAGE_BYTES, open_input
    from replay.logs.ply import read_ply_model_bytes

    f, size = open_input(path, "a PLY file")
    with f:
        if size > DEFAULT_MAX_MESSAGE_BYTES:
            raise LogFormatError(f"{path}: PLY file of {size} bytes is more than the cap of "
                                 f"{DEFAULT_MAX_MESSAGE_BYTES}")
        data = f.read()
    if len(read_ply_model_bytes(data, name=str(path)).points) == 0:
        raise LogFormatError(f"{path}: no points in the bin model (expected a PLY point cloud or mesh)")
    return data


def _png_size(path: Path) -> tuple[int, int]:
    """(height, width) from a PNG's IHDR, read before anything is decoded (a 100-byte file can claim
    2**31 x 2**31 pixels)."""
    from replay.errors import LogFormatError

    with open(path, "rb") as f:
        head = f.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise LogFormatError(f"{path}: not a PNG image")
    return int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")


#: Largest camera_info YAML read (a calibration file is ~1 kB).
CAMERA_INFO_MAX_BYTES = 1 << 20


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics given to ``zcut record`` (flags or a camera_info YAML); ``size`` (H, W) when
    the YAML names one, which every cloud must then have."""

    fx: float
    fy: float
    cx: float
    cy: float
    source: str
    size: tuple[int, int] | None = None

    def for_grid(self, shape: tuple[int, int], cloud: Path) -> Intrinsics:
        from replay.errors import ConfigError
        from zcut.cloud import Intrinsics

        h, w = shape
        if self.size is not None and self.size != (h, w):
            raise ConfigError(f"{self.source} is for {self.size[1]}x{self.size[0]} images but {cloud} is a "
                              f"{w}x{h} grid (WIDTHxHEIGHT)")
        if not (0.0 <= self.cx <= w and 0.0 <= self.cy <= h):
            raise ConfigError(f"{self.source}: the principal point ({self.cx:g}, {self.cy:g}) lies outside the "
                              f"{w}x{h} grid of {cloud}")
        return Intrinsics(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=w, height=h)

    def describe(self) -> str:
        return f"fx {self.fx:g}, fy {self.fy:g}, cx {self.cx:g}, cy {self.cy:g} px, from {self.source}"


def camera_of(args: argparse.Namespace) -> Camera | None:
    """The camera model of ``--camera-info`` or ``--fx --fy --cx --cy`` (checked before any cloud is read)."""
    from replay.errors import ConfigError

    flags = {n: getattr(args, n) for n in ("fx", "fy", "cx", "cy")}
    given = [n for n, v in flags.items() if v is not None]
    if args.camera_info is not None and given:
        raise ConfigError(f"--camera-info and --{' --'.join(given)} both give the camera model: give one of them")
    if args.camera_info is not None:
        return read_camera_info_yaml(args.camera_info)
    if not given:
        return None
    if len(given) != 4:
        missing = [n for n in flags if n not in given]
        raise ConfigError(f"the camera model needs --fx, --fy, --cx and --cy together; missing --{', --'.join(missing)}")
    return _checked_camera(flags, source="--fx --fy --cx --cy", size=None)


def _checked_camera(v: dict[str, float], *, source: str, size: tuple[int, int] | None) -> Camera:
    import math

    from replay.errors import ConfigError

    for name in ("fx", "fy"):
        if not (math.isfinite(v[name]) and v[name] > 0):
            raise ConfigError(f"{source}: {name} must be a positive number of pixels, got {v[name]:g}")
    for name in ("cx", "cy"):
        if not (math.isfinite(v[name]) and v[name] >= 0):
            raise ConfigError(f"{source}: {name} must be a pixel position (0 or more), got {v[name]:g}")
    return Camera(v["fx"], v["fy"], v["cx"], v["cy"], source=source, size=size)


def read_camera_info_yaml(path: str) -> Camera:
    """The pinhole intrinsics of a ROS camera_info YAML: camera_calibration_parsers' layout
    (``image_width``, ``image_height``, ``camera_matrix: {rows, cols, data: [9 numbers]}``) or a
    ``ros2 topic echo`` of a CameraInfo (``width``, ``height``, ``k``). Only that subset of YAML is
    read (``key: value``, one level of nesting, ``[a, b]`` and ``- a`` lists); anything else is one line."""
    from replay.errors import ConfigError
    from replay.logs.files import open_input

    f, size = open_input(path, "a camera_info YAML file")
    with f:
        if size > CAMERA_INFO_MAX_BYTES:
            raise ConfigError(f"{path}: {size} bytes is too large for a camera_info YAML file")
        raw = f.read()
    try:
        doc = _small_yaml(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a camera_info YAML file (not UTF-8 text)") from None
    except ValueError as e:
        raise ConfigError(f"{path}: not a camera_info YAML file this reader knows ({e})") from None

    def number(key: str, value: Any) -> float:
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: {key} must be a number, got {value!r}") from None

    matrix = doc.get("camera_matrix")
    k = matrix.get("data") if isinstance(matrix, dict) else doc.get("k", doc.get("K"))
    if not isinstance(k, list) or len(k) != 9:
        raise ConfigError(f"{path}: no camera matrix (camera_matrix.data or k, 9 numbers)")
    k = [number("the camera matrix", x) for x in k]
    width = doc.get("image_width", doc.get("width"))
    height = doc.get("image_height", doc.get("height"))
    grid = None
    if width is not None or height is not None:
        w, h = number("image_width", width), number("image_height", height)
        if not (w.is_integer() and h.is_integer() and w >= 1 and h >= 1):
            raise ConfigError(f"{path}: image_width and image_height must be positive integers, got {width!r}, {height!r}")
        grid = (int(h), int(w))
    if k[1] != 0.0 or k[3] != 0.0 or k[6:] != [0.0, 0.0, 1.0]:
        raise ConfigError(f"{path}: the camera matrix {k} is not a pinhole K [fx 0 cx; 0 fy cy; 0 0 1]")
    return _checked_camera({"fx": k[0], "fy": k[4], "cx": k[2], "cy": k[5]}, source=str(path), size=grid)


def _scalar(text: str) -> str | float | int:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    try:
        return float(text) if any(c in text for c in ".eE") or text.lower() in ("nan", "inf", "-inf") \
            else int(text)
    except ValueError:
        return text


def _small_yaml(text: str) -> dict[str, Any]:
    """The subset of YAML a camera_info file is written in (see :func:`read_camera_info_yaml`)."""
    lines: list[str] = []
    pending = ""
    for line in text.splitlines():
        line = line.split("#", 1)[0].rstrip()
        if pending:
            pending += " " + line.strip()
            if "]" in line:
                lines.append(pending)
                pending = ""
            continue
        if "[" in line and "]" not in line:
            pending = line
            continue
        if line.strip() and line.strip() != "---":
            lines.append(line)
    if pending:
        raise ValueError("a [ list is not closed")
    doc: dict[str, Any] = {}
    parent: str | None = None  # the top-level key indented lines belong to
    last: tuple[dict[str, Any], str] | None = None  # the key a "- item" line appends to
    for line in lines:
        indent = len(line) - len(line.lstrip(" "))
        body = line.strip()
        if body.startswith("- ") or body == "-":
            if last is None or not isinstance(last[0][last[1]], list):
                raise ValueError(f"a list item where no list is open: {body!r}")
            last[0][last[1]].append(_scalar(body[1:]))
            continue
        key, colon, value = body.partition(":")
        if not colon or not key.strip():
            raise ValueError(f"not a key: value line: {body!r}")
        key, value = key.strip(), value.strip()
        parsed: list[str | float | int] | str | float | int
        if value.startswith("[") and value.endswith("]"):
            parsed = [_scalar(x) for x in value[1:-1].split(",") if x.strip()]
        elif value.startswith("{"):
            raise ValueError(f"inline mappings are not read: {body!r}")
        elif value == "":
            parsed = []  # a block list or a mapping follows
        else:
            parsed = _scalar(value)
        if indent == 0:
            doc[key], parent, last = parsed, key, (doc, key)
            continue
        if parent is None:
            raise ValueError(f"an indented line under nothing: {body!r}")
        if not isinstance(doc[parent], dict):
            if doc[parent] != []:
                raise ValueError(f"{parent} is both a value and a mapping")
            doc[parent] = {}
        doc[parent][key] = parsed
        last = (doc[parent], key)
    return doc
