"""``zcut record INPUT... -o LOG.mcap``: organized PLY/PCD files (or folders of them) -> a log.

Each cloud goes to ``/camera/points`` (PointCloud2, metres) and, when there is colour, an RGB image
to ``/camera/image``: a same-named ``.png`` next to the cloud file when present, else the cloud's
own colours. Frames are stamped ``--stamp-start + i * --period``. ``--bin-model PLY`` attaches a bin
model (from ``zcut bin-model``, or a CAD PLY in zcut's bin frame) to the log as its ``bin_model.ply``
attachment (``docs/formats.md``, "Bin model attachment"): every command then replays the log with it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from replay.logs import layout

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
    parser.add_argument(
        "--shape", metavar="HxW",
        help="grid shape for PLY files without organization info (e.g. 1200x1920)",
    )
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
    if h < 2 or w < 1:
        raise ConfigError(f"--shape must be organized (height > 1), got {text!r}")
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
    shape = _parse_shape(args.shape)
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
    out = Path(args.output)
    inputs = [str(f) for f in files] + ([args.bin_model] if args.bin_model else [])
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
        with LogWriter(target.temp, metadata=meta, attachments=attachments) as w:
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
                n_valid = int(np.isfinite(xyz).all(axis=2).sum())
                print(
                    f"{i:4d} {f.name}: {xyz.shape[0]}x{xyz.shape[1]}, {n_valid} valid points, "
                    f"unit {unit}, image from {src}"
                )
    print(f"wrote {len(files)} frames to {out}" + (f" with the bin model {args.bin_model}" if args.bin_model else ""))
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
