"""The recording of ``zcut compare`` (docs/compare.md): two filters on one timeline, in one .rrd.

The second module of zcut that imports ``rerun`` (tests/test_layout.py lists both); it takes plain
arrays, so it knows nothing of the comparison's bookkeeping (``studies/compare.py``). Entity paths:

==============================  ================================================================
``diff/config``                 the config difference (only the parameters that differ, A and B
                                values), a Markdown document, static
``image/rgb``                   the frame's RGB image, JPEG (a gray height image without one)
``a/verdict``, ``b/verdict``    each side's primary method per pixel: with truth TP (1), FP (2),
                                FN (3); without, removed (4)
``diff/consequence``            with truth: B fixes (1), B breaks (2), both wrong (3); without:
                                removed only by A (4), only by B (5)
``diff/points``                 the disagreement alone in 3D (the pixels only one side removed,
                                coloured as ``diff/consequence``), camera coordinates (RDF)
``a/scalars/*``, ``b/scalars/*``,  per-frame precision, recall, F1 of each side; ΔF1 and the
``diff/scalars/*``              pixels only A / only B removed
==============================  ================================================================

Timelines: ``frame`` (the comparison's frame number, over every log in order) and ``stamp``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from replay.pipeline.rerun_arrow import class_context
from replay.process import interrupts_deferred

if TYPE_CHECKING:
    from replay.pipeline.sinks import RrdFile

VERDICT_CLASSES = ((1, "TP", (0, 170, 0)), (2, "FP", (230, 30, 30)), (3, "FN (missed)", (255, 200, 0)),
                   (4, "removed", (220, 20, 220)))
DIFF_CLASSES = ((1, "B fixes", (0, 200, 0)), (2, "B breaks", (230, 0, 0)), (3, "both wrong", (150, 150, 150)),
                (4, "removed only by A", (255, 140, 0)), (5, "removed only by B", (30, 144, 255)))


def compare_blueprint(label_a: str, label_b: str) -> rrb.Blueprint:
    """The config difference first, then the verdict grid A | B | Δ (same image, same bounds), then
    the disagreement in 3D and the per-frame scalars."""
    def view(name: str, layer: str) -> rrb.Spatial2DView:
        return rrb.Spatial2DView(name=name, origin="/", contents=["image/rgb", layer])

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.TextDocumentView(name="Config difference (A vs B)", origin="diff/config"),
            rrb.Horizontal(view(f"A: {label_a}", "a/verdict"), view(f"B: {label_b}", "b/verdict"),
                           view("Δ: consequence of B", "diff/consequence")),
            rrb.Horizontal(
                rrb.Spatial3DView(name="Disagreement in 3D", origin="diff/points"),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="F1 per frame (A, B)", contents=["a/scalars/f1", "b/scalars/f1"]),
                    rrb.TimeSeriesView(name="ΔF1 = B − A", contents=["diff/scalars/delta_f1"]),
                ),
                rrb.TimeSeriesView(name="Pixels removed by one side only",
                                   contents=["diff/scalars/only_a_px", "diff/scalars/only_b_px"]),
            ),
            row_shares=[2, 5, 3],
        ),
        rrb.TimePanel(timeline="frame", expanded=True),
        collapse_panels=True,
    )


class CompareRecording:
    """One .rrd of a comparison, written through ``rrd`` (a :class:`replay.pipeline.sinks.RrdFile`: it
    opens the file bounded, and the caller has it check, close and name the recording).

    Parameters
    ----------
    rrd : RrdFile
    label_a, label_b : str
        What A and B are (view titles).
    config_markdown : str
        The config difference as a Markdown document.
    """

    def __init__(self, rrd: RrdFile, *, label_a: str, label_b: str, config_markdown: str) -> None:
        with interrupts_deferred():  # (see replay.pipeline.viz.new_recording)
            self.rec = rr.RecordingStream("zcut-compare", make_default=False, make_thread_default=False)
        rrd.save(self.rec, compare_blueprint(label_a, label_b))
        self.rec.log("diff/config", rr.TextDocument(config_markdown, media_type=rr.MediaType.MARKDOWN), static=True)
        for p in ("a/verdict", "b/verdict"):
            self.rec.log(p, class_context(VERDICT_CLASSES), static=True)
        for p in ("diff/consequence", "diff/points"):
            self.rec.log(p, class_context(DIFF_CLASSES), static=True)
        self.rec.log("diff/points", rr.ViewCoordinates.RDF, static=True)
        for path, name, colour in (("a/scalars", "A", (0, 114, 178)), ("b/scalars", "B", (213, 94, 0))):
            for k in ("precision", "recall", "f1"):
                self.rec.log(f"{path}/{k}", rr.SeriesLines(colors=[colour], names=f"{name} {k}"), static=True)
        for path, name, colour in (("diff/scalars/delta_f1", "ΔF1", (0, 0, 0)),
                                   ("diff/scalars/only_a_px", "only A", (255, 140, 0)),
                                   ("diff/scalars/only_b_px", "only B", (30, 144, 255))):
            self.rec.log(path, rr.SeriesLines(colors=[colour], names=name), static=True)

    def frame(self, seq: int, stamp_ns: int, *, jpeg: bytes | None, image: np.ndarray | None, points: np.ndarray,
              point_ids: np.ndarray, verdict_a: np.ndarray, verdict_b: np.ndarray, diff: np.ndarray,
              scalars: dict[str, float]) -> None:
        """Log one frame: ``jpeg`` the frame's RGB image JPEG-encoded, else ``image`` ((H, W) gray or
        (H, W, 3) RGB uint8); ``points`` (N, 3) the disagreement in 3D with ``point_ids`` their codes
        of ``diff``; ``verdict_a``/``verdict_b``/``diff`` (H, W) uint8 class images, ``scalars`` by
        entity path (NaN values are left out)."""
        rec = self.rec
        rec.set_time("frame", sequence=int(seq))
        rec.set_time("stamp", timestamp=np.datetime64(int(stamp_ns), "ns"))
        if jpeg is not None:
            rec.log("image/rgb", rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))
        elif image is not None:
            rec.log("image/rgb", rr.Image(image, color_model="L" if image.ndim == 2 else "RGB"))
        rec.log("a/verdict", rr.SegmentationImage(verdict_a))
        rec.log("b/verdict", rr.SegmentationImage(verdict_b))
        rec.log("diff/consequence", rr.SegmentationImage(diff))
        rec.log("diff/points", rr.Points3D(points, class_ids=point_ids.astype(np.uint16), radii=0.0015))
        for path, v in scalars.items():
            if v is not None and np.isfinite(v):
                rec.log(path, rr.Scalars(float(v)))
