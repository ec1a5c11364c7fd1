"""Options and steps that several commands share: the pipeline's inputs, outputs, the session.

Every command that runs the pipeline on a log (``replay``, ``accuracy``, ``annotate``, ``labels``,
``sweep``, ``batch``) takes the same options from :func:`add_pipeline_options`, reads them into a
:class:`replay.options.PipelineOptions` (:func:`pipeline_options`) and opens its log with it, so that
it resolves the same config (docs/accuracy.md, "Same filter everywhere"), and replays it with the bin
model :func:`replay.pipeline.bin_model.bin_model_for` chooses: the ``--bin-model`` given, else the
log's own attachment, else none, with one warning line.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from replay.presets import PART_KINDS

if TYPE_CHECKING:
    from collections.abc import Callable

    from replay.logs.reader import LogReader
    from replay.options import PipelineOptions
    from replay.pipeline.bin_model import BinModelChoice
    from replay.pipeline.session import ReplaySession


def add_pipeline_options(p: argparse.ArgumentParser, *, bin_model: bool = True, zcut: bool = True) -> None:
    """``--config``, the z-cut overrides, ``--part/--parameters/--preset``, ``--topic``, ``--bin-model``.

    ``zcut=False``: no ``--step/--max-depth/--max-area/--rho`` (a sweep takes lists there)."""
    g = p.add_argument_group("pipeline (the same options resolve the same filter in every command)")
    g.add_argument("--config", metavar="F.toml", help="pipeline config (TOML); the resolved config is written beside outputs")
    if zcut:
        g.add_argument("--step", type=float, metavar="MM", help="z-cut step Δd in mm (overrides the config)")
        g.add_argument("--max-depth", type=float, metavar="MM", help="z-cut depth d_max in mm (overrides the config)")
        g.add_argument("--max-area", type=float, metavar="PX", help="z-cut cluster area threshold μ_thr in pixels")
        g.add_argument("--rho", type=float, metavar="R", help="z-cut relative area threshold ρ_thr (μ_thr = ρ_thr·a_max)")
    g.add_argument("--part", metavar="KIND", choices=list(PART_KINDS),
                   help=f"the part kind in the bin, for a_max ({', '.join(PART_KINDS)}); synthetic logs name theirs")
    g.add_argument("--parameters", choices=("nominal", "geometry"),
                   help="z-cut Δd and d_max: the paper's nominal 0.2/30 mm (default) or its §5.4 ranges for the part")
    g.add_argument("--preset", metavar="KIND", choices=list(PART_KINDS),
                   help="shorthand for --part KIND --parameters geometry")
    g.add_argument("--methods", metavar="LIST",
                   help="the filter methods to run, report and score, comma-separated (default: the config's, "
                   "else zcut,sor): " + ", ".join(_method_names()) + "; unions as a+b (e.g. zcut+sor)")
    g.add_argument("--topic", metavar="T", help="cloud topic (when the log has several)")
    p.set_defaults(zcut_overrides=zcut)
    if bin_model:
        g.add_argument("--bin-model", metavar="PLY", help="bin model (from `zcut bin-model` or a CAD PLY); "
                       "without it the log's own bin model attachment is used, and without that the bin stages "
                       "are skipped")
    g.add_argument("--part-model", metavar="FILE", help="the part's mesh (PLY, STL or OBJ) for the method "
                   "explained; without it the log's own part_model.ply attachment")
    g.add_argument("--part-model-unit", choices=("mm", "m"), help="the unit of --part-model's vertices (default mm)")


def pipeline_options(args: argparse.Namespace) -> PipelineOptions:
    """The options :func:`add_pipeline_options` added, as the library takes them."""
    from replay.options import PipelineOptions

    z = {k: getattr(args, k, None) for k in ("step", "max_depth", "max_area", "rho")} if args.zcut_overrides else {}
    return PipelineOptions(config=args.config, **z, part=args.part, parameters=args.parameters, preset=args.preset,
                           methods=getattr(args, "methods", None), topic=getattr(args, "topic", None),
                           bin_model=getattr(args, "bin_model", None), part_model=getattr(args, "part_model", None),
                           part_model_unit=getattr(args, "part_model_unit", None))


def overrides_of(args: argparse.Namespace) -> dict[str, Any]:
    """The command line's config layer (validated: a bad value fails before the log is read)."""
    return pipeline_options(args).overrides()


def _method_names() -> list[str]:
    from replay.pipeline.methods import registry

    return list(registry())


def inputs_of(args: argparse.Namespace) -> list[str]:
    """The files the pipeline options name (for the outputs check)."""
    return pipeline_options(args).inputs()


def model_chooser(args: argparse.Namespace) -> Callable[[LogReader], BinModelChoice]:
    """:meth:`replay.options.PipelineOptions.model_chooser` of the pipeline options."""
    return pipeline_options(args).model_chooser()


def open_session(log: str | Path, args: argparse.Namespace, *, overrides: dict[str, Any] | None = None,
                 stream: IO[str] | None = None) -> ReplaySession:
    """:meth:`replay.options.PipelineOptions.open_session` of the pipeline options: ``log`` opened with them
    and the bin model they choose (its warning printed when there is none)."""
    return pipeline_options(args).open_session(log, overrides=overrides, stream=stream)


def add_force_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", action="store_true", help="replace existing outputs")


def add_truth_option(p: argparse.ArgumentParser) -> None:
    """``--truth paper|sensor`` (docs/accuracy.md, "Two truths"); default None: the paper's where a log has it."""
    p.add_argument("--truth", choices=("paper", "sensor"), default=None,
                   help="the recorded truth to score against: paper (/ground_truth/off_surface: farther than 3 Err "
                        "from every true surface) or sensor (/ground_truth/outliers); default: paper where the log "
                        "has it, else sensor (stereo logs, older synthetic logs), as the report says")


#: How ``--size`` reads, in every command that takes one (``synth``, ``record``): WIDTHxHEIGHT, columns
#: by rows, as camera data sheets give it (a Zivid 2 is 1920x1200). Arrays are (rows, columns) inside.
SIZE_HELP = "WIDTHxHEIGHT in pixels, columns x rows as cameras say it (1920x1200; 640x480 is a small landscape frame)"


def size_wxh(text: str, *, low: int = 1, high: int = 1 << 16) -> tuple[int, int]:
    """An argparse type: ``WxH`` -> (height, width), each in ``low .. high``."""
    try:
        w, h = (int(v) for v in text.lower().replace("×", "x").split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT like 1920x1200, got {text!r}") from None
    if not (low <= w <= high and low <= h <= high):
        raise argparse.ArgumentTypeError(f"width and height must be {low}..{high}, got {text!r}")
    return h, w


def portrait_note(option: str, h: int, w: int) -> str | None:
    """The note for a frame higher than wide (``--size 480x640``): WIDTHxHEIGHT may have been read the
    other way round; the frame is made as asked."""
    if h <= w:
        return None
    return (f"{option} {w}x{h} is WIDTHxHEIGHT: a portrait frame {w} wide and {h} high "
            f"({h}x{w} makes the landscape one)")
