"""Run the replay pipeline over a log's frames for the candidates (page) and predictions (accuracy)."""

from __future__ import annotations

from pathlib import Path

from annotate.payload import PreparedFrame, prepare_frame


class PipelineRunner:
    """Resolve the pipeline config once (at the first frame) and run ``run_frame`` frame by frame.

    The config is resolved as ``zcut replay`` resolves it: the TOML file if given, else the preset of a
    synthetic log's part kind (``zcut.synth`` metadata), else defaults derived from the image size.
    Without a bin model the bin stages are skipped (with a warning) and the z-cut judges the frame.

    Parameters
    ----------
    metadata : dict[str, dict[str, str]]
        The log's MCAP metadata records (``LogReader.metadata``).
    config_path : path-like, optional
        Pipeline config (TOML).
    bin_model : replay.pipeline.bin_model.BinModel, optional
        Enables the bin stages.
    """

    def __init__(self, metadata: dict[str, dict[str, str]], *, config_path: str | Path | None = None,
                 bin_model=None) -> None:
        self.metadata = metadata
        self.config_path = config_path
        self.bin_model = bin_model
        self.config = None
        self.previous = None
        self.notes: tuple[str, ...] = ()

    def _resolve(self, frame) -> None:
        from replay.pipeline import config as rc
        from replay.pipeline.session import synth_info

        part_kind, dist = synth_info(self.metadata)
        intr = frame.intrinsics
        resolved = rc.resolve(
            file_layer=rc.load_toml(self.config_path) if self.config_path else None,
            part_kind=part_kind,
            camera_distance_mm=dist,
            fx=None if intr is None else intr.fx,
            fy=None if intr is None else intr.fy,
            image_shape=frame.shape,
        )
        self.config = resolved.config
        self.notes = resolved.notes

    def run(self, frame):
        """``replay.pipeline.stages.run_frame`` on the frame (FrameResult)."""
        from replay.pipeline.stages import run_frame

        if self.config is None:
            self._resolve(frame)
        result = run_frame(frame, self.config, bin_model=self.bin_model, previous=self.previous)
        self.previous = result
        return result

    def prepare_for_page(self, frame) -> PreparedFrame:
        """The page's view of the frame with the pipeline's candidates."""
        result = self.run(frame)
        return prepare_frame(frame, zcut_outliers=result.zcut_outliers, sor_outliers=result.sor_outliers,
                             cut_clusters=result.cut.clusters, warnings=tuple(result.warnings))
