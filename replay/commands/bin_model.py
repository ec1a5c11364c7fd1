"""``zcut bin-model EMPTY.mcap -o bin.ply``: the bin model from empty-bin scans (paper §5.1)."""

from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="EMPTY.mcap", nargs="?",
                   help="log of the empty bin (RGB + organized cloud), e.g. several positions on the table")
    p.add_argument("-o", "--output", metavar="bin.ply", required=True, help="where to write the model (PLY)")
    p.add_argument("--model", metavar="PLY", help="use this CAD/PLY model instead of building one "
                   "(metres, up = -z); it is sampled, given normals and written to -o")
    p.add_argument("--z-up", action="store_true", help="the --model has +z up (CAD convention): turn it over "
                   "into zcut's camera-like bin frame (up = -z)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="multiply the --model's coordinates by S (e.g. 0.001 for a model in millimetres)")
    p.add_argument("--config", metavar="F.toml", help="pipeline config ([bin_mask] and [registration] are used)")
    p.add_argument("--voxel", type=float, default=1.0, metavar="MM", help="downsampling voxel (default 1 mm)")
    p.add_argument("--frames", metavar="A:B", help="frame index range of the empty scans")
    p.add_argument("--topic", metavar="T", help="cloud topic (when the log has several)")


def run(args: argparse.Namespace) -> int:
    from replay.errors import ConfigError
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import (
        build_bin_model,
        load_bin_model,
        save_bin_model,
    )
    from replay.pipeline.session import parse_frames

    if not args.voxel > 0:
        raise ConfigError(f"--voxel must be > 0 mm, got {args.voxel!r}")
    if (args.log is None) == (args.model is None):
        raise ConfigError("give either EMPTY.mcap or --model PLY (not both)")
    if args.model is not None:
        import numpy as np

        from zcut.bin_model import BinModel

        if not (np.isfinite(args.scale) and args.scale > 0):
            raise ConfigError(f"--scale must be > 0, got {args.scale!r}")
        model = load_bin_model(args.model, voxel_mm=args.voxel / args.scale)
        flip = np.array([1.0, -1.0, -1.0]) if args.z_up else np.ones(3)  # 180 degrees about x
        model = BinModel(model.points * (flip * args.scale), None if model.normals is None else model.normals * flip,
                         model.spacing_m * args.scale)
        save_bin_model(model, args.output)
        print(f"zcut: wrote {args.output}: {len(model.points)} points from {args.model}", file=sys.stderr)
        return 0
    from replay.logs.reader import LogReader

    from zcut.params import BinMaskParams, RegistrationParams

    layer = cfg.load_toml(args.config) if args.config else {}
    reader = LogReader(args.log, cloud_topic=args.topic)
    start, stop = parse_frames(args.frames)
    model, reports = build_bin_model(reader.frames(start=start, stop=stop),
                                     bin_mask_params=BinMaskParams(**layer.get("bin_mask", {})),
                                     registration=RegistrationParams(**layer.get("registration", {})),
                                     voxel_mm=args.voxel)
    for r in reports:
        if r.skipped:
            print(f"warning: scan {r.index} left out: {r.skipped}", file=sys.stderr)
        elif r.registration is None:
            print(f"scan {r.index}: {r.n_points} bin points (reference frame)")
        else:
            print(f"scan {r.index}: {r.n_points} bin points, fitness {r.registration.fitness:.3f}, "
                  f"RMSE {r.registration.inlier_rmse * 1000:.2f} mm")
    save_bin_model(model, args.output)
    used = sum(1 for r in reports if not r.skipped)
    print(f"zcut: wrote {args.output}: {len(model.points)} points from {used} scan(s)", file=sys.stderr)
    if reader.damage:
        for d in reader.damage:
            print(f"warning: data loss: {d}", file=sys.stderr)
        from replay.cli import EXIT_DATA_LOSS

        return EXIT_DATA_LOSS
    return 0
