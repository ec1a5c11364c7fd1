"""The pipeline's options as a library value: what resolves the filter a command, a study or a program runs.

Every caller that runs the pipeline on a log (``zcut replay``, ``accuracy``, ``annotate``, ``sweep``,
``batch``, and :func:`studies.sweep.run`, :func:`studies.batch.run`, :func:`annotate.accuracy.run`)
takes one :class:`PipelineOptions` and opens its log with :meth:`PipelineOptions.open_session`, so that
the same options resolve the same config (docs/accuracy.md, "Same filter everywhere") and choose the
bin model :func:`replay.pipeline.bin_model.bin_model_for` chooses: the one given, else the log's own
attachment, else none, with one warning line. The command line's spelling of these options is
``cli/commands/common.py``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable

    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import BinModelChoice
    from replay.pipeline.session import ReplaySession


@dataclass(frozen=True, slots=True, kw_only=True)
class PipelineOptions:
    """The config file, its overrides, the cloud topic and the bin model (each None: not given).

    Attributes
    ----------
    config : str or None
        A pipeline config (TOML).
    step, max_depth, max_area, rho : float or None
        The z-cut overrides (``--step`` mm, ``--max-depth`` mm, ``--max-area`` px, ``--rho``).
    part, parameters, preset, methods : str or None
        ``--part KIND``, ``--parameters nominal|geometry``, ``--preset KIND``, ``--methods LIST``.
    topic : str or None
        The cloud topic (when the log has several).
    bin_model : str or None
        A bin model PLY; without it the log's own attachment, else no bin stages.
    part_model, part_model_unit : str or None
        The part's mesh (PLY, STL or OBJ, or a log carrying a ``part_model.ply``) and the unit of a
        mesh file's vertices (``mm``, default, or ``m``): the method ``explained``'s
        ``explained.part_model`` and ``explained.part_model_unit``; without it the log's own
        attachment.
    """

    config: str | None = None
    step: float | None = None
    max_depth: float | None = None
    max_area: float | None = None
    rho: float | None = None
    part: str | None = None
    parameters: str | None = None
    preset: str | None = None
    methods: str | None = None
    topic: str | None = None
    bin_model: str | None = None
    part_model: str | None = None
    part_model_unit: str | None = None

    def overrides(self) -> dict[str, Any]:
        """The config layer of these options (validated: a bad value fails before the log is read)."""
        from replay.pipeline import config as cfg

        layer = cfg.cli_layer(step=self.step, max_depth=self.max_depth, max_area=self.max_area, rho=self.rho,
                              part=self.part, parameters=self.parameters, preset=self.preset, methods=self.methods)
        if self.part_model:
            layer["explained"] = {"part_model": str(Path(self.part_model).resolve()),
                                  "part_model_unit": self.part_model_unit or "mm"}
        return layer

    def inputs(self) -> list[str]:
        """The files these options name (for the outputs check)."""
        return [p for p in (self.config, self.bin_model, self.part_model) if p]

    def check_inputs(self) -> None:
        """Refuse a config, bin model or part model that is not a file (as a missing file: ``error: no
        such file``), and a part model that is not a mesh (one line, :func:`replay.pipeline.explained.part_model`)."""
        for path in (self.config, self.bin_model, self.part_model):
            if path and not Path(path).is_file():
                raise FileNotFoundError(2, "no such file", str(path))
        if self.part_model:
            from replay.pipeline.explained import part_model

            part_model(self.part_model, self.part_model_unit or "mm")

    def model_chooser(self) -> Callable[[LogReader], BinModelChoice]:
        """What :meth:`ReplaySession.open <replay.pipeline.session.ReplaySession.open>` calls with the opened
        reader to choose the bin model: :func:`replay.pipeline.bin_model.bin_model_for` with ``bin_model``
        (given: that model; else the log's own attachment; else none, with a warning)."""
        from replay.pipeline.bin_model import bin_model_for

        self.check_inputs()
        explicit = self.bin_model
        return lambda reader: bin_model_for(reader, explicit)

    def open_session(self, log: str | Path, *, overrides: dict[str, Any] | None = None,
                     stream: IO[str] | None = None) -> ReplaySession:
        """Open ``log`` as a :class:`~replay.pipeline.session.ReplaySession` with these options and the bin
        model :meth:`model_chooser` chooses (its warning printed to ``stream``, stderr by default, when
        there is none)."""
        from replay.pipeline.session import ReplaySession

        choose = self.model_chooser()
        session = ReplaySession.open(log, config_file=self.config,
                                     overrides=self.overrides() if overrides is None else overrides,
                                     topic=self.topic, choose_bin_model=choose)
        warn_bin_model(session, stream=stream)
        return session


def warn_bin_model(session: ReplaySession, *, stream: IO[str] | None = None) -> None:
    """Print the one warning line of a session opened without a bin model (names the log, says what to do)."""
    choice = session.bin_model_choice
    if choice is not None and choice.warning:
        print(f"warning: {choice.warning}", file=sys.stderr if stream is None else stream, flush=True)
