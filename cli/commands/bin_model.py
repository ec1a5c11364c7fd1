"""``zcut bin-model EMPTY.mcap -o bin.ply``: the bin model from empty-bin scans (paper §5.1).

With ``--into LOG.mcap -o NEW.mcap`` the model goes into a copy of a log instead, as its
``bin_model.ply`` attachment (``docs/formats.md``, "Bin model attachment"): every command then replays
NEW.mcap with it, without ``--bin-model``. LOG.mcap is only read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from zcut.bin_model import BinModel


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="EMPTY.mcap", nargs="?",
                   help="log of the empty bin (RGB + organized cloud), e.g. several positions on the table")
    p.add_argument("-o", "--output", metavar="bin.ply", required=True,
                   help="where to write the model (PLY), or with --into the new log (NEW.mcap)")
    p.add_argument("--into", metavar="LOG.mcap", help="write the model into a copy of LOG.mcap (its bin_model.ply "
                   "attachment) at -o NEW.mcap, which every command then replays with it; LOG.mcap is not modified")
    p.add_argument("--model", metavar="PLY", help="use this CAD/PLY model instead of building one "
                   "(metres, up = -z); it is sampled, given normals and written to -o")
    p.add_argument("--z-up", action="store_true", help="the --model has +z up (CAD convention): turn it over "
                   "into zcut's camera-like bin frame (up = -z)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="multiply the --model's coordinates by S (e.g. 0.001 for a model in millimetres)")
    p.add_argument("--config", metavar="F.toml", help="pipeline config ([bin_mask] and [registration] are used)")
    p.add_argument("--voxel", type=float, default=1.0, metavar="MM", help="downsampling voxel (default 1 mm)")
    p.add_argument("--frames", metavar="A:B", help="the empty scans to use by their 0-based index: A:B (B exclusive), A:, :B or N")
    p.add_argument("--topic", metavar="T", help="cloud topic (when the log has several)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing output; build from a log that is not marked as an empty bin, or "
                        "whose scans do not agree (low registration fitness)")

#: scans registered to the first with less fitness than this do not show the same empty bin
MIN_SCAN_FITNESS = 0.6
#: a model from fewer scans than this is built, with a warning: one scan's model left rim pixels
#: uncovered on 3 of 11 frames, two scans' none (docs/bin_robustness.md)
MIN_SCANS = 2


def run(args: argparse.Namespace) -> int:
    from replay.errors import ConfigError
    from replay.outputs import OutputPlan

    if not args.voxel > 0:
        raise ConfigError(f"--voxel must be > 0 mm, got {args.voxel!r}")
    if (args.log is None) == (args.model is None):
        raise ConfigError("give either EMPTY.mcap or --model PLY (not both)")
    if args.into is not None and not Path(args.into).is_file():
        raise FileNotFoundError(2, "no such file", str(args.into))
    inputs = [p for p in (args.log, args.model, args.config, args.into) if p]
    with OutputPlan(inputs, force=args.force) as plan:  # locked until the output is written
        plan.add(args.output, "the log with the bin model" if args.into else "the bin model")
        return _build(args)


def _build(args: argparse.Namespace) -> int:
    from replay.errors import ConfigError
    from replay.logs import layout
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import build_bin_model, load_bin_model
    from replay.pipeline.session import parse_frames

    if args.model is not None:
        import numpy as np

        from zcut.bin_model import BinModel

        if not (np.isfinite(args.scale) and args.scale > 0):
            raise ConfigError(f"--scale must be > 0, got {args.scale!r}")
        model = load_bin_model(args.model, voxel_mm=args.voxel / args.scale)
        flip = np.array([1.0, -1.0, -1.0]) if args.z_up else np.ones(3)  # 180 degrees about x
        model = BinModel(model.points * (flip * args.scale), None if model.normals is None else model.normals * flip,
                         model.spacing_m * args.scale)
        _write(args, model, f"{len(model.points)} points from {args.model}")
        return 0
    from replay.logs.reader import LogReader
    from zcut.params import BinMaskParams, RegistrationParams

    layer = cfg.load_toml(args.config) if args.config else {}
    reader = LogReader(args.log, cloud_topic=args.topic)
    kind = reader.metadata.get(layout.SYNTH_METADATA, {}).get("part_kind")
    if kind not in (None, "empty") and not args.force:
        raise ConfigError(f"{args.log} is a log of a bin filled with {kind}, not of the empty bin "
                          "(its zcut.synth metadata): a model built from it would hold the parts (--force to build anyway)")
    if layout.RESULTS_METADATA in reader.metadata and not args.force:
        raise ConfigError(f"{args.log} is a results file of zcut replay, not empty-bin scans")
    start, stop = parse_frames(args.frames)
    scans = reader.frames(start=start, stop=stop)
    model, reports = build_bin_model(scans,
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
    weak = [(r.index, r.registration.fitness) for r in reports
            if r.registration is not None and r.registration.fitness < MIN_SCAN_FITNESS]
    if weak and not args.force:
        raise ConfigError(f"scan(s) {', '.join(str(i) for i, _ in weak)} fit the first scan poorly (fitness "
                          f"{min(f for _, f in weak):.2f} < {MIN_SCAN_FITNESS}): is the bin empty "
                          "and the same in every scan? (--force to build anyway)")
    used = sum(1 for r in reports if not r.skipped)
    if used < MIN_SCANS:
        print(f"warning: the bin model is built from {used} scan: rim pixels one scan does not see stay at the "
              "zone's top and can cost a frame its z-cut (3 of 11 frames measured, docs/bin_robustness.md); "
              f"build it from {MIN_SCANS} or more empty-bin scans", file=sys.stderr)
    _write(args, model, f"{len(model.points)} points from {used} scan(s)")
    if scans.damage:
        for d in scans.damage:
            print(f"warning: data loss: {d.text}", file=sys.stderr)
        from replay.process import EXIT_DATA_LOSS

        return EXIT_DATA_LOSS
    return 0


def _write(args: argparse.Namespace, model: BinModel, what: str) -> None:
    """The model as a PLY at ``-o``, or with ``--into`` a copy of that log carrying it at ``-o``."""
    from replay.logs import layout
    from replay.logs.mcap_write import copy_with_attachment
    from replay.outputs import AtomicOutput
    from replay.pipeline.bin_model import bin_model_ply_bytes, save_bin_model

    with AtomicOutput(args.output) as out:
        if args.into is None:
            try:
                save_bin_model(model, out.temp)
            except OSError as e:  # name the output, not its temporary
                raise OSError(e.errno, e.strerror, str(args.output)) from None
        else:
            with open(out.temp, "wb") as f:
                replaced = copy_with_attachment(args.into, f, name=layout.BIN_MODEL_ATTACHMENT,
                                                media_type=layout.BIN_MODEL_MEDIA_TYPE, data=bin_model_ply_bytes(model))
    if args.into is None:
        print(f"zcut: wrote {args.output}: {what}", file=sys.stderr)
        return
    if replaced:
        print(f"zcut: the bin model {args.into} carried is replaced in the copy", file=sys.stderr)
    print(f"zcut: wrote {args.output}: a copy of {args.into} carrying its bin model ({layout.BIN_MODEL_ATTACHMENT}: "
          f"{what}); commands replay it with that model without --bin-model", file=sys.stderr)
