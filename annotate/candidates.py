"""The pipeline's candidates for the labelling page, run as ``zcut replay`` runs them.

The page prepares a log's frames in log order, one at a time (``annotate.server.Catalog``).
:class:`PipelineRunner` resolves the config with :func:`replay.pipeline.config.resolve_config` at
the first frame it is given (the log's first readable frame, as a
:class:`~replay.pipeline.session.ReplaySession` does), prepares the bin model once for it, registers
that first frame as the seed of every frame's registration, and runs ``run_frame`` as the session
does: the page shows the masks ``zcut replay`` writes for the same log, config file and overrides.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


class PipelineRunner:
    """Resolve the pipeline config once (at the first frame) and run ``run_frame`` frame by frame.

    Parameters
    ----------
    metadata : dict[str, dict[str, str]]
        The log's MCAP metadata records (``LogReader.metadata``).
    config_path : path-like, optional
        Pipeline config (TOML).
    bin_model : zcut.bin_model.BinModel, optional
        Enables the bin stages.
    overrides : dict, optional
        The command line's layer (:func:`replay.pipeline.config.cli_layer`).
    intrinsics : zcut.cloud.Intrinsics, optional
        The log's camera intrinsics (``LogReader.intrinsics``) when known apart from the frames.
    """

    def __init__(self, metadata: dict[str, dict[str, str]], *, config_path: str | Path | None = None,
                 bin_model=None, overrides: dict[str, Any] | None = None, intrinsics=None) -> None:
        self.metadata = metadata
        self.config_path = config_path
        self.bin_model = bin_model
        self.overrides = overrides
        self.intrinsics = intrinsics
        self.config = None
        self.prepared = None
        self.seed = None
        self.notes: tuple[str, ...] = ()

    def _resolve(self, frame) -> None:
        from replay.pipeline import config as cfg
        from zcut.prepared_model import prepare_bin_model

        resolved = cfg.resolve_config(self.metadata, frame, config_file=self.config_path,
                                      overrides=self.overrides, intrinsics=self.intrinsics)
        self.config = resolved.config
        self.notes = resolved.notes
        if self.bin_model is not None:
            from replay.pipeline.stages import locate_bin

            self.prepared = prepare_bin_model(self.bin_model, registration=self.config.registration,
                                              removal=self.config.removal)
            if self.config.registration.seed_from_first_frame:
                self.seed = locate_bin(frame, self.config, bin_model=self.prepared).registration

    def run(self, frame):
        """``replay.pipeline.stages.run_frame`` on a frame of the log (FrameResult); the first call must
        be with the log's first readable frame."""
        from replay.pipeline.stages import run_frame

        if self.config is None:
            self._resolve(frame)
        return run_frame(frame, self.config, bin_model=self.prepared, seed=self.seed)
