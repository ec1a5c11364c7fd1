"""``zcut synth -o LOG.mcap``: a synthetic bin-picking log with exact ground truth (docs/cli.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from replay.synth import SynthFrame
    from replay.synth.log import ProgressFn
    from replay.synth.raytrace.pile import Pile
    from replay.synth.raytrace.synthesize import RaytracedFrame

PART_KIND_NAMES = ("spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets")


def _size(text: str) -> tuple[int, int]:
    """``WxH`` -> (height, width), 8..8192 each (:func:`cli.commands.common.size_wxh`)."""
    from cli.commands.common import size_wxh

    return size_wxh(text, low=8, high=8192)


def check_readable(h: int, w: int) -> None:
    """Refuse a size whose log no zcut reader would read: more pixels than ``ZCUT_MAX_PIXELS`` or a
    cloud message larger than ``ZCUT_MAX_MESSAGE_BYTES`` (:mod:`replay.logs.files`), up front, not
    after minutes of writing it."""
    from replay.logs import files
    from replay.logs import ros2_msgs as rm
    from zcut.errors import ParameterError

    if h * w > files.DEFAULT_MAX_PIXELS:
        raise ParameterError(f"--size {w}x{h} is {h * w} pixels, more than the cap of {files.DEFAULT_MAX_PIXELS} "
                             "every zcut command reads (ZCUT_MAX_PIXELS): no zcut command could read the log")
    header = len(rm.encode_cloud(stamp_ns=0, frame_id="x" * 64, height=1, width=1, fields=rm.XYZRGBA_FIELDS,
                                 point_step=16, row_step=16, data=bytes(16), is_dense=True)) - 16
    cloud = header + 16 * h * w  # the largest message: the PointCloud2, 16 bytes a point
    if cloud > files.DEFAULT_MAX_MESSAGE_BYTES:
        raise ParameterError(f"--size {w}x{h} makes clouds of {cloud} bytes, more than the cap of "
                             f"{files.DEFAULT_MAX_MESSAGE_BYTES} bytes every zcut command reads "
                             "(ZCUT_MAX_MESSAGE_BYTES): no zcut command could read the log")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", metavar="LOG.mcap", required=True, help="log to write")
    p.add_argument("--force", action="store_true", help="replace the output if it exists")
    p.add_argument("--parts", default="spheres", choices=PART_KIND_NAMES,
                   help="part kind of the paper's Figure 8 (default spheres)")
    p.add_argument("--frames", type=int, default=1, metavar="N", help="number of scans (default 1)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="random seed; same seed, same bytes (default 0)")
    from cli.commands.common import SIZE_HELP

    p.add_argument("--size", type=_size, default=(1200, 1920), metavar="WxH",
                   help=f"image size, {SIZE_HELP}; default 1920x1200, the sensor's")
    finish = p.add_mutually_exclusive_group()
    finish.add_argument("--shiny", dest="shiny", action="store_const", const=True, default=None,
                        help="treat the parts as shiny (many outliers) whatever their kind")
    finish.add_argument("--matte", dest="shiny", action="store_const", const=False,
                        help="treat the parts as matte (few outliers) whatever their kind")
    p.add_argument("--empty", action="store_true",
                   help="scan the empty bin instead (the 5-position series of paper §4, repeating)")
    p.add_argument("--quantize-mm", type=float, default=0.0, metavar="MM",
                   help="quantize depth to steps of MM (a consumer stereo or ToF camera, e.g. 1); default 0: off")
    p.add_argument("--pile", choices=("floor", "walls"), default="floor",
                   help="floor (default): the parts keep off the walls; walls: they lean on one wall or a corner "
                        "of the bin, drawn per frame from the seed (both sensors)")
    p.add_argument("--sensor", choices=("handmade", "raytraced"), default="handmade",
                   help="handmade (default, fast): outliers placed by hand; raytraced: a structured-light "
                        "sensor simulated by ray tracing over a physics-dropped pile (docs/raytraced.md)")
    p.add_argument("--camera-filters", action="store_true",
                   help="raytraced sensor: apply the camera's own noise (SNR < 7), reflection and outlier (no "
                        "neighbour within 5 mm) filters to the cloud before it is written, as a real camera "
                        "delivers it; recorded in the log's metadata (docs/raytraced.md); default off")
    shape = p.add_argument_group("a bin that is not the nominal (CAD) bin (the hand-made sensor)")
    shape.add_argument("--bin-scale", type=float, default=1.0, metavar="S",
                       help="scale the whole bin by S (e.g. 1.002: 0.8 mm longer); default 1")
    shape.add_argument("--bin-bulge-mm", type=float, default=0.0, metavar="MM",
                       help="bulge every inner wall outward by MM at its middle (negative: inward); default 0")
    shape.add_argument("--bin-deform-mm", type=float, default=0.0, metavar="MM",
                       help="deform the bin anew in every scan: wall bulges and a twist of up to MM; default 0")
    shape.add_argument("--bin-cad", metavar="PLY",
                       help="also write the nominal bin as a CAD mesh (bin frame, metres, up = -z) for "
                            "`zcut bin-model --model PLY`")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from replay.synth import BinShape, write_bin_cad, write_synthetic_log
    from zcut.errors import ParameterError

    if args.frames < 1:
        raise ParameterError(f"--frames must be at least 1, got {args.frames}")
    try:
        shape = BinShape(scale=args.bin_scale, bulge_mm=args.bin_bulge_mm, deform_mm=args.bin_deform_mm)
    except ParameterError as e:  # the option's name, not the class's field
        flag = {"scale": "--bin-scale", "bulge_mm": "--bin-bulge-mm", "deform_mm": "--bin-deform-mm"}
        name = str(e).split(" ", 1)[0].partition(".")[2]
        raise ParameterError(f"{flag.get(name, name)} {str(e).split(' ', 1)[1]}") from None
    h, w = args.size
    check_readable(h, w)
    if args.pile == "walls" and args.empty:
        raise ParameterError("--pile walls needs parts to pile: it does not go with --empty")
    if args.pile == "walls" and not shape.nominal:
        raise ParameterError("--pile walls needs the nominal bin: it does not go with --bin-scale, --bin-bulge-mm "
                             "or --bin-deform-mm")
    from cli.commands.common import portrait_note

    note = portrait_note("--size", h, w)
    if note is not None:
        print(f"zcut: {note}", file=sys.stderr)
    what = "empty bin" if args.empty else args.parts

    def progress(i: int, n: int, sf: SynthFrame, seconds: float) -> None:
        n_out = int(sf.truth.sum())
        n_valid = int(np.isfinite(sf.frame.xyz[..., 2]).sum())
        print(f"frame {i + 1}/{n}: {what} {w}x{h}, {len(sf.scene.parts)} parts, {n_valid} valid points, "
              f"{n_out} true outliers, {seconds:.1f} s", file=sys.stderr, flush=True)

    from replay.outputs import AtomicOutput, OutputPlan

    with OutputPlan([], force=args.force) as plan:  # locked until the log is written
        plan.add(args.output, "the log")
        if args.sensor == "raytraced":
            if not shape.nominal or args.bin_cad is not None:
                raise ParameterError("--bin-scale, --bin-bulge-mm, --bin-deform-mm and --bin-cad belong to the "
                                     "hand-made sensor's bin")
            return _run_raytraced(args, what, progress)
        if args.camera_filters:
            raise ParameterError("--camera-filters belongs to the ray-traced sensor (--sensor raytraced)")
        if args.bin_cad is not None:
            plan.add(args.bin_cad, "the CAD bin")
        with AtomicOutput(args.output) as out:
            write_synthetic_log(out.temp, kind=args.parts, frames=args.frames, seed=args.seed, size=(h, w),
                                empty=args.empty, shiny=args.shiny, quantize_mm=args.quantize_mm, progress=progress,
                                bin_shape=shape, bag_name=Path(args.output).name, pile=args.pile)
        print(f"zcut: wrote {args.output} ({args.frames} frame(s), seed {args.seed})", file=sys.stderr)
        if args.bin_cad is not None:
            with AtomicOutput(args.bin_cad) as out:
                write_bin_cad(out.temp)
            print(f"zcut: wrote {args.bin_cad} (the nominal bin as a CAD mesh; zcut bin-model --model {args.bin_cad} "
                  "-o bin.ply makes a bin model of it)", file=sys.stderr)
    return 0


def _mujoco(text: str) -> str:
    """MuJoCo's warning as a clause of our line: its own words without its closing full stop."""
    return text.rstrip().removesuffix(".")


def _where(lost: int, under_floor: int) -> str:
    """Where ``lost`` parts went, ``under_floor`` of them through the floor."""
    rest = lost - under_floor
    return ", ".join(x for x in (f"{under_floor} under the floor" if under_floor else "",
                                 f"{rest} beside or above the bin" if rest else "") if x)


def pile_lines(i: int, pile: Pile) -> list[str]:
    """What ``zcut synth --sensor raytraced`` says of frame ``i``'s (0-based) pile on stderr: the simulations thrown
    away (unstable, or stable but losing parts) and what settled it (:data:`replay.synth.raytrace.pile.RETRIES`), a
    warning when the pile kept still lost parts, and MuJoCo's warnings of the simulation kept (its own words, not its
    ``MUJOCO_LOG.TXT`` in the working directory)."""
    out = []
    asked = len(pile) + pile.escaped
    if pile.unstable or pile.lossy:
        why = []
        if pile.unstable:
            first = pile.unstable[0]
            more = f" (and {len(pile.unstable) - 1} retry(ies) after it)" if len(pile.unstable) > 1 else ""
            why.append(f"went unstable (MuJoCo: {_mujoco(first.warning)}){more}")
        if pile.lossy:
            lossy = pile.lossy[0]
            more = f" (and {len(pile.lossy) - 1} more simulation(s) that lost parts)" if len(pile.lossy) > 1 else ""
            why.append(f"lost {lossy.lost} of {asked} part(s) ({_where(lossy.lost, lossy.under_floor)}) with a "
                       f"{lossy.floor_thickness_mm:g} mm floor at a {lossy.time_step_s * 1000:g} ms step{more}")
        from replay.synth.raytrace.pile import CONTACT_TIME_S, FLOOR_THICKNESS_MM, TIME_STEP_S

        # the first simulation is kept only when every retry lost more parts than it did
        first_kept = not pile.unstable and (pile.floor_thickness_mm, pile.time_step_s, pile.contact_time_s) == (
            FLOOR_THICKNESS_MM, TIME_STEP_S, CONTACT_TIME_S)
        kept = "simulated again, the first simulation kept" if first_kept else "simulated again"
        stiff = (f" and contacts of {pile.contact_time_s * 1000:g} ms" if pile.contact_time_s != CONTACT_TIME_S
                 else "")
        out.append(f"zcut: frame {i + 1}: the pile's simulation {' and '.join(why)}; {kept} with a "
                   f"{pile.floor_thickness_mm:g} mm floor at a {pile.time_step_s * 1000:g} ms step{stiff}: stable, "
                   f"{len(pile)} part(s) in the bin, {pile.escaped} fell out")
    if pile.escaped:
        tried = 1 + len(pile.unstable) + len(pile.lossy)
        best = f"the best of {tried} simulations tried" if tried > 1 else "its simulation"
        out.append(f"zcut: frame {i + 1}: warning: the pile lost {pile.escaped} of its {asked} part(s) "
                   f"({_where(pile.escaped, pile.under_floor)}) in {best}; the frame holds {len(pile)}")
    if pile.warnings:
        more = f" (and {len(pile.warnings) - 1} more)" if len(pile.warnings) > 1 else ""
        out.append(f"zcut: frame {i + 1}: the pile's simulation warned: {_mujoco(pile.warnings[0])}{more}; "
                   f"{pile.escaped} part(s) fell out of the bin")
    return out


def _run_raytraced(args: argparse.Namespace, what: str, progress: ProgressFn) -> int:
    """``--sensor raytraced``: the same log layout from the ray-traced sensor."""
    from replay.outputs import AtomicOutput
    from replay.synth.raytrace import write_raytraced_log
    from replay.synth.raytrace.camera_filters import CameraFilters
    from zcut.errors import ParameterError

    if args.shiny is not None or args.quantize_mm != 0.0:
        raise ParameterError("--shiny, --matte and --quantize-mm belong to the hand-made sensor; the ray-traced "
                             "one takes the finish from the part's material")

    def rt_progress(i: int, n: int, rf: RaytracedFrame, seconds: float) -> None:
        h, w = args.size
        n_parts = len(rf.pile) if rf.pile is not None else 0
        n_valid = int(np.isfinite(rf.frame.xyz[..., 2]).sum())
        print(f"frame {i + 1}/{n}: {what} {w}x{h} (ray-traced), {n_parts} parts, {n_valid} valid points, "
              f"{int(rf.truth.sum())} true outliers, {seconds:.1f} s", file=sys.stderr, flush=True)
        if rf.pile is not None:
            for line in pile_lines(i, rf.pile):
                print(line, file=sys.stderr, flush=True)

    import numpy as np

    with AtomicOutput(args.output) as out:
        write_raytraced_log(out.temp, kind=args.parts, frames=args.frames, seed=args.seed, size=args.size,
                            empty=args.empty, progress=rt_progress, bag_name=Path(args.output).name,
                            pile=args.pile, camera_filters=CameraFilters() if args.camera_filters else None)
    print(f"zcut: wrote {args.output} ({args.frames} frame(s), seed {args.seed}, ray-traced"
          + (", camera filters" if args.camera_filters else "") + ")", file=sys.stderr)
    return 0
