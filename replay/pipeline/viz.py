"""Every pipeline stage in Rerun. One of the two modules of zcut that import ``rerun`` (the other is
:mod:`replay.pipeline.compare_viz`, the recording of ``zcut compare``; tests/test_layout.py lists both).

An explicit :class:`rerun.RecordingStream` is passed in (no global recording). Entity paths:

====================================  ==========================================================
``image/rgb``                         the RGB image (JPEG at default detail), or a gray height
                                      image when the frame has no RGB
``image/bin_mask``                    bin footprint (1) and its bright walls (2), over the image
``image/removal``                     table (1), bin (2), easy outliers (3), zone (4)
``image/bin_check``                   the certain bin pixels (rim, upper walls) (1) and those the
                                      removal left where the filters judge (2): the bin check
``image/clusters``                    tagged z-cut clusters; each class labelled with area, level, ρ
``image/outliers``                    z-cut only (1), SOR only (2), both (3), above the rim (4)
``image/methods/NAME``                the outliers of every other filter method the config runs
                                      (``--methods``): one view each, with its count and time
``image/explained``                   the method ``explained``: each zone pixel's nearest known
                                      surface, a part fit (1), the bin (2), the table (3), the
                                      local surface (5: no part model), or unexplained (4:
                                      farther than k × Err from every one)
``image/explained_distance``          its distance to the nearest known surface (mm, colour-mapped)
``world/explained/fits``              the fitted part instances in 3D, each labelled with its
                                      residual Err and support
``world/explained/vetted_out``        the fits the vetting left out (their solid overlaps a
                                      better-supported fit's: no known surface), in red
``zcut/cuts``                         the z-cuts: scrub the ``depth_um`` timeline (see below; the
                                      viewer opens on ``frame``, where the view shows every level)
``world/cloud``                       the cloud (every 4th pixel at default detail)
``world/outliers``                    the outliers in 3D, coloured as in ``image/outliers``
``world/bin_model``                   the registered bin model (pose per frame) + fitness/RMSE
``counts/*``, ``metrics/*``,          per-frame scalars: outlier counts, α, β, stage times (ms),
``timings_ms/*``, ``registration/*``  registration fitness and RMSE (mm)
``bin_check/*``                       the bin check's figure (pixels) and threshold, the removal's
                                      tolerance (mm)
``config``                            the resolved config (TOML), static
``log``                               per-frame warnings (skipped or failed stages)
``image/verdicts/NAME``               with truth only (the log's, or ``--labels``): where method
                                      NAME is wrong, TP (1), FP (2), FN, missed (3), over the
                                      scored region (docs/compare.md, "Where each filter is wrong")
``world/verdicts/NAME``               the same pixels in 3D, coloured alike
``accuracy/NAME/*``                   with truth: per-frame ``precision``, ``recall`` of NAME
``accuracy/truth``                    with truth: what the frames are scored against, static
====================================  ==========================================================

The z-cuts cost one small image per frame: ``zcut/cuts`` holds the pixel level (the first cut a
pixel belongs to) as a segmentation image, and for every shown level k one AnnotationContext,
logged at ``depth_um`` = k·Δd in micrometres, colours the levels up to k and leaves the deeper ones
transparent: scrubbing ``depth_um`` shows the real cut Z_k (every level at full detail, at most 32
evenly spaced ones by default). Levels repeat from frame to frame, so the depth
timeline shows the last frame logged (replay one frame with ``--frames N:N+1`` to debug it).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from replay.logs.frame import Frame
from replay.pipeline.rerun_arrow import class_context, contexts_arrow, rgba32
from replay.pipeline.stages import FrameResult
from replay.pipeline.verdicts import MethodVerdict
from replay.process import interrupts_deferred
from zcut.bin_model import BinModel

if TYPE_CHECKING:
    import subprocess

    from replay.pipeline.explained import ExplainedDetail
    from zcut.fits import PartFit

#: the recording a sink logs to, for the annotations of modules that do not import Rerun themselves
RecordingStream = rr.RecordingStream

OUTLIER_CLASSES = (
    (1, "z-cut only", (255, 140, 0)),
    (2, "SOR only", (30, 144, 255)),
    (3, "both", (220, 20, 220)),
    (4, "above the rim", (255, 0, 0)),
)
REMOVAL_CLASSES = (
    (1, "table", (60, 60, 140)),
    (2, "bin", (0, 200, 200)),
    (3, "above the rim", (255, 0, 0)),
    (4, "zone", (80, 200, 80)),
)
METHOD_CLASSES = (
    (1, "outlier", (255, 60, 160)),
    (2, "above the rim", (255, 0, 0)),
)
BIN_MASK_CLASSES = (
    (1, "bin footprint", (0, 160, 255)),
    (2, "bin walls", (255, 255, 0)),
)
BIN_CHECK_CLASSES = (
    (1, "certain bin pixels (rim, upper walls)", (0, 90, 160)),
    (2, "bin left where the filters judge", (255, 0, 255)),
)
#: where a filter is wrong (replay.pipeline.verdicts: TP 1, FP 2, FN 3), the colours of zcut compare's grid
VERDICT_CLASSES = (
    (1, "TP (a true outlier it removed)", (0, 170, 0)),
    (2, "FP (a good point it removed)", (230, 30, 30)),
    (3, "FN (a true outlier it missed)", (255, 200, 0)),
)


@dataclass(frozen=True, slots=True)
class VizOptions:
    """How much to log.

    Attributes
    ----------
    full_detail : bool
        Raw images, every point, every level at full resolution.
    cloud_stride : int
        Log every n-th row and column of the cloud in 3D (or a coarser n: :attr:`max_cloud_points`).
    max_cloud_points : int
        The cloud's grid holds at most this many points: n is at least ceil(sqrt(H·W / this))
        (a 1920 x 1200 frame: every 6th row and column).
    level_stride : int
        Resolution divisor of the z-cut level image.
    jpeg_quality : int
        Quality of the RGB image (when not full detail).
    max_cluster_labels : int
        Clusters beyond this many get no label (the colour stays).
    max_scrub_levels : int
        Cut levels shown on the depth timeline per frame (full detail: all).
    overlay_stride : int
        Resolution divisor of the class images over the RGB image (:data:`OVERLAYS`, the verdicts):
        each of their pixels holds the highest class of an ``s`` x ``s`` block of the frame's
        (:func:`pool_max`), and a static ``Transform3D`` scales them by ``s`` onto the image.
    """

    full_detail: bool = False
    cloud_stride: int = 4
    level_stride: int = 2
    jpeg_quality: int = 85
    max_cluster_labels: int = 2000
    max_scrub_levels: int = 32
    overlay_stride: int = 2
    max_cloud_points: int = 80_000

    @classmethod
    def full(cls) -> VizOptions:
        return cls(full_detail=True, cloud_stride=1, level_stride=1, overlay_stride=1)

    def cloud_step(self, height: int, width: int) -> int:
        """The row and column step of the cloud logged in 3D (1 at full detail)."""
        if self.full_detail:
            return 1
        cap = int(np.ceil(np.sqrt(height * width / max(int(self.max_cloud_points), 1)) - 1e-9))
        return max(int(self.cloud_stride), cap, 1)

    @property
    def overlay_scale(self) -> int:
        """The overlays' resolution divisor (1 at full detail)."""
        return 1 if self.full_detail else max(int(self.overlay_stride), 1)


#: the class images drawn over ``image/rgb`` (and their subtrees: ``image/methods/NAME``), logged at
#: 1 / :attr:`VizOptions.overlay_stride` of the frame's resolution at default detail, their scale
#: static from the start; ``image/verdicts`` (with truth) and ``image/explained`` (when that method
#: runs) too, their scale logged with them
OVERLAYS = ("image/bin_mask", "image/removal", "image/bin_check", "image/clusters", "image/outliers",
            "image/methods")


def pool_max(img: np.ndarray, s: int) -> np.ndarray:
    """(ceil(H / s), ceil(W / s)): each pixel the highest value of its ``s`` x ``s`` block of ``img``
    (rows and columns ``s·i .. s·i + s - 1``, cut at the border): a class image at 1 / ``s`` of the
    resolution where one pixel of a class still shows (the higher class wins, as in the images'
    painting order); a bool mask: whether any pixel of the block is set. ``s`` = 1: ``img`` itself."""
    if s <= 1:
        return img
    a = img.view(np.uint8) if img.dtype == bool else img
    h, w = a.shape
    wider = _WIDER.get(a.dtype.str) if a.dtype.kind == "u" else None
    if s == 2 and not h % 2 and not w % 2 and wider is not None:
        # the rows' maxima, then each pair of columns read as one integer of twice the width: the max
        # of its two halves (no strided column pass)
        v = np.ascontiguousarray(np.maximum(a[0::2], a[1::2])).view(wider)  # (a view of a transpose: F order)
        out = (v >> np.array(8 * a.itemsize, wider)).astype(a.dtype)
        np.maximum(out, v.astype(a.dtype), out=out)  # the low half (astype keeps it)
    else:
        if h % s or w % s:  # the border blocks padded with zeros (class 0, nothing)
            a = np.pad(a, ((0, -h % s), (0, -w % s)))
        rows = a[0::s]
        for i in range(1, s):
            rows = np.maximum(rows, a[i::s])
        out = rows[:, 0::s]
        for j in range(1, s):
            out = np.maximum(out, rows[:, j::s])
        out = np.ascontiguousarray(out)
    pooled: np.ndarray = out.view(bool) if img.dtype == bool else out
    return pooled


#: the unsigned integer of twice the width of a pixel's (:func:`pool_max` pairs columns in one)
_WIDER = {np.dtype(np.uint8).str: np.uint16, np.dtype(np.uint16).str: np.uint32, np.dtype(np.uint32).str: np.uint64}


def log_overlay_scale(rec: rr.RecordingStream, entities: Iterable[str], opts: VizOptions) -> None:
    """A static ``Transform3D`` scaling each of ``entities`` by the overlays' divisor onto the
    image's pixels (nothing at full detail)."""
    s = opts.overlay_scale
    if s > 1:
        for e in entities:
            rec.log(e, rr.Transform3D(scale=float(s)), static=True)


def new_recording(*, application_id: str = "zcut", recording_id: str | None = None) -> rr.RecordingStream:
    """A recording stream that is nobody's global default.

    Made with the interruptions deferred (:func:`replay.process.interrupts_deferred`): a signal inside
    the SDK's constructor would leave a stream without its native half, whose ``__del__`` prints a
    traceback after the one-line "interrupted"."""
    with interrupts_deferred():
        rec = rr.RecordingStream(application_id, recording_id=recording_id, make_default=False,
                                 make_thread_default=False)
    return rec


#: The timeline the viewer opens on: the frames (on ``depth_um`` at 0 the z-cuts view is empty and a
#: per-frame series shows one point).
OPENING_TIMELINE = "frame"
#: The z-cuts view's name says how to scrub the cuts: the ``depth_um`` timeline, one click away.
ZCUTS_VIEW = "z-cuts (every level; timeline depth_um scrubs them)"
#: What the recording's config document and ``zcut replay`` say about the timelines.
TIMELINES_HINT = ("The viewer opens on the frame timeline. To scrub the z-cuts of the frame shown, choose "
                  "depth_um in the time panel's timeline menu (top left of the time panel) and drag its cursor "
                  "down from 0; choose frame again to step through the frames.")


#: the name of the blueprint's tab of the verdicts (with truth)
VERDICTS_TAB = "Where each filter is wrong (truth)"
#: the name of the blueprint's tab of the pipeline's stages (a tab with truth, the whole layout without)
PIPELINE_TAB = "Pipeline"


def verdicts_layout(judged: tuple[str, ...]) -> rrb.Horizontal:
    """The tab of the verdicts: a verdict image per method (TP / FP / FN over the image), the same
    pixels in 3D (one view per method, over the cloud), precision and recall per frame."""
    images = [rrb.Spatial2DView(name=f"{m}: TP / FP / FN", origin="image",
                                contents=["image/rgb", f"image/verdicts/{m}"]) for m in judged]
    clouds = [rrb.Spatial3DView(name=f"{m} in 3D: TP / FP / FN", origin="world",
                                contents=["world/cloud", f"world/verdicts/{m}"]) for m in judged]
    return rrb.Horizontal(
        rrb.Grid(*images, name="Verdicts"),
        rrb.Tabs(*clouds, name="Verdicts in 3D"),
        rrb.Vertical(
            rrb.TimeSeriesView(name="Precision per frame", contents=[f"accuracy/{m}/precision" for m in judged]),
            rrb.TimeSeriesView(name="Recall per frame", contents=[f"accuracy/{m}/recall" for m in judged]),
            rrb.TextDocumentView(name="Scored against", origin="accuracy/truth"),
            row_shares=[3, 3, 1],
        ),
        column_shares=[3, 2, 2],
        name=VERDICTS_TAB,
    )


def default_blueprint(methods: tuple[str, ...] = ("zcut", "sor"), judged: tuple[str, ...] = ()) -> rrb.Blueprint:
    """Image stages on the left, 3D and the z-cuts in the middle, scalars and config on the right;
    ``methods``: the base methods the replay runs (a view for each other than the z-cut and SOR).
    ``judged``: the methods judged against truth; when there are some, the layout above is the tab
    :data:`PIPELINE_TAB` and :func:`verdicts_layout` the tab :data:`VERDICTS_TAB`, which the viewer
    opens on."""
    others = [m for m in methods if m not in ("zcut", "sor")]
    image_views: list[rrb.Spatial2DView | rrb.Tabs] = [
        rrb.Spatial2DView(name="RGB + bin mask", origin="image", contents=["image/rgb", "image/bin_mask"]),
        rrb.Spatial2DView(name="Removal", origin="image", contents=["image/rgb", "image/removal", "image/bin_check"]),
        rrb.Spatial2DView(name="Outliers (z-cut / SOR / both)", origin="image",
                          contents=["image/rgb", "image/outliers"]),
    ]
    if others:
        method_views = [rrb.Spatial2DView(name=f"Outliers: {m}", origin="image",
                                          contents=["image/rgb", f"image/methods/{m}"]) for m in others]
        if "explained" in others:  # its nearest known surface per pixel (classes) and the distance to it
            method_views += [
                rrb.Spatial2DView(name="Explained: nearest surface", origin="image",
                                  contents=["image/rgb", "image/explained"]),
                rrb.Spatial2DView(name="Explained: distance (mm)", origin="image",
                                  contents=["image/explained_distance"]),
            ]
        image_views.append(rrb.Tabs(*method_views))
    pipeline = rrb.Horizontal(
        rrb.Vertical(*image_views),
        rrb.Vertical(
            # with truth the verdicts' points stay in their own tab
            rrb.Spatial3DView(name="3D: cloud, outliers, bin model", origin="world",
                              contents=["$origin/**", "- /world/verdicts/**"])
            if judged else rrb.Spatial3DView(name="3D: cloud, outliers, bin model", origin="world"),
            rrb.Horizontal(
                rrb.Spatial2DView(name="Clusters", origin="image", contents=["image/rgb", "image/clusters"]),
                rrb.Spatial2DView(name=ZCUTS_VIEW, origin="zcut/cuts"),
            ),
        ),
        rrb.Vertical(
            rrb.TimeSeriesView(name="Outlier counts", origin="counts"),
            rrb.TimeSeriesView(name="α, β", origin="metrics"),
            rrb.TimeSeriesView(name="Stage times (ms)", origin="timings_ms"),
            rrb.TimeSeriesView(name="Registration", origin="registration"),
            rrb.TimeSeriesView(name="Bin check", origin="bin_check"),
            rrb.Tabs(rrb.TextDocumentView(name="Config", origin="config"),
                     rrb.TextLogView(name="Warnings", origin="log")),
        ),
        column_shares=[2, 3, 2],
        name=PIPELINE_TAB if judged else None,
    )
    root: rrb.Horizontal | rrb.Tabs = pipeline
    if judged:
        tab = verdicts_layout(judged)
        root = rrb.Tabs(pipeline, tab, active_tab=1)  # the verdicts (a name finds views only)
    return rrb.Blueprint(
        root,
        # the viewer opens on the frame timeline: every stage of a frame, the per-frame series over every
        # frame; picking depth_um in the time panel's timeline menu scrubs the z-cuts of the frame shown
        rrb.TimePanel(timeline=OPENING_TIMELINE, state="expanded", play_state="paused"),
        collapse_panels=False,
    )


#: the address of the viewers zcut starts and of the ``rerun`` commands it prints: this machine only
#: (Rerun's own default, and ``rr.spawn``'s, is every interface, 0.0.0.0)
VIEWER_BIND = "127.0.0.1"
#: Rerun's default viewer port
VIEWER_PORT = 9876
#: seconds a spawned viewer may take to listen
VIEWER_START_S = 20.0


def _listening(port: int) -> bool:
    import socket

    try:
        with socket.create_connection((VIEWER_BIND, port), timeout=1.0):
            return True
    except OSError:
        return False


def viewer_args(port: int = VIEWER_PORT) -> list[str]:
    """The arguments of a viewer that listens on 127.0.0.1:``port`` only (after the executable)."""
    return ["--bind", VIEWER_BIND, "--port", str(port), "--memory-limit", "75%"]


def spawn_viewer(*, port: int = VIEWER_PORT, executable: str = "rerun",
                 timeout_s: float = VIEWER_START_S) -> subprocess.Popen[bytes] | None:
    """Start a Rerun viewer listening on 127.0.0.1:``port`` only, detached from this process (it
    stays open after the replay, as ``rr.spawn``'s does; ``rr.spawn`` cannot bind an address).

    Returns the viewer's ``subprocess.Popen``, or None when something listens on the port already (a
    viewer started before: the replay streams to it, as ``rr.spawn`` does).

    Raises
    ------
    ConfigError
        No ``rerun`` executable, or the viewer exited or did not listen within ``timeout_s``.
    """
    import os
    import shutil
    import subprocess
    import time

    from replay.errors import ConfigError

    if _listening(port):
        return None
    beside = os.path.join(os.path.dirname(sys.executable), executable)  # a venv that is not activated
    exe = beside if os.path.isfile(beside) else shutil.which(executable)
    if exe is None:
        raise ConfigError(f"--spawn: no {executable!r} on PATH (the viewer ships with rerun-sdk)")
    proc = subprocess.Popen([exe, *viewer_args(port)], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True,
                            env={**os.environ, "RERUN_APP_ONLY": "true"})
    deadline = time.monotonic() + timeout_s
    while not _listening(port):
        if proc.poll() is not None:
            raise ConfigError(f"--spawn: the Rerun viewer exited as it started (status {proc.returncode}); "
                              "a machine without a display can write --rrd OUT.rrd and open it with "
                              f"`rerun --bind {VIEWER_BIND} --web-viewer OUT.rrd`")
        if time.monotonic() > deadline:
            proc.kill()
            raise ConfigError(f"--spawn: the Rerun viewer did not listen on {VIEWER_BIND}:{port} within {timeout_s:g} s")
        time.sleep(0.05)
    return proc


def open_sink(rec: rr.RecordingStream, *, rrd: str | None = None, spawn: bool = False,
              connect: str | None = None, methods: tuple[str, ...] = ("zcut", "sor"),
              judged: tuple[str, ...] = ()) -> str | None:
    """Send ``rec`` to a file, a spawned viewer (listening on 127.0.0.1 only, :func:`spawn_viewer`)
    or a running viewer, with the default blueprint for the base ``methods`` the replay runs (and
    the ``judged`` methods' verdicts, with truth).

    Returns the line to tell the user for ``spawn``: a viewer was started, or one listens on the port
    already and the recording streams into it (``rr.spawn``'s behaviour, which it does silently)."""
    bp = default_blueprint(methods, judged)
    note = None
    if rrd is not None:
        rec.save(rrd, default_blueprint=bp)
    elif spawn:
        port = VIEWER_PORT
        proc = spawn_viewer(port=port)
        if proc is None:
            note = (f"--spawn: something already listens on {VIEWER_BIND}:{port} (a Rerun viewer started before?): "
                    "streaming into it, no new viewer started")
        else:
            note = f"--spawn: started a Rerun viewer on {VIEWER_BIND}:{port} (pid {proc.pid}); it stays open after the replay"
        rec.connect_grpc(f"rerun+http://{VIEWER_BIND}:{port}/proxy", default_blueprint=bp)
    elif connect is not None:
        rec.connect_grpc(connect, default_blueprint=bp)
    return note


def abandon(rec: rr.RecordingStream) -> None:
    """Give up a recording whose file writer failed (a full disk) without ever waiting for it.

    Rerun 0.41 waits for ever on such a writer wherever it flushes the recording: at
    ``disconnect()``, in the recording's ``__del__`` (which also sweeps every orphaned recording),
    and in its shutdown at exit. So the recording object is kept alive for the rest of the process
    (one reference that is never released: its ``__del__`` never runs, and no other recording's
    sweep finds it orphaned), and Rerun's shutdown at exit is not run (zcut's sinks flush and close
    every recording they keep themselves). The process then exits normally; the failed writer's
    threads end with it.
    """
    import ctypes

    ctypes.pythonapi.Py_IncRef(ctypes.py_object(rec))
    rr.unregister_shutdown()


def rrd_problem(path: str) -> str | None:
    """Why the .rrd at ``path`` is not a complete recording (read back with Rerun's own reader:
    its footer, the manifest of its recording), or None when it is complete.

    A writer that met a full disk may leave a file without footer (Rerun logs the write error and
    goes on), so a recording is checked before it takes its final name.
    """
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # "RRD file has no footer/manifest": a truncated file
            reader = rr.chunk.RrdReader(path)
            if not reader.recordings():
                return "no recording in it"
            reader.store()  # the manifest, checked against the file
    except Warning as w:
        return str(w).split(":")[0]
    except Exception as e:  # noqa: BLE001 - rerun raises RuntimeError/ValueError with the reason
        lines = [line for line in str(e).splitlines() if line.strip()]
        return lines[0] if lines else type(e).__name__
    return None


def log_static(rec: rr.RecordingStream, *, config_toml: str, notes: tuple[str, ...] = (),
               bin_model: BinModel | None = None, source: str = "", opts: VizOptions = VizOptions()) -> None:
    """Things that do not change per frame: annotation contexts, the overlays' scale (``opts``: those
    of :func:`log_frame`), axes, the config, the bin model."""
    rec.log("image/outliers", class_context(OUTLIER_CLASSES), static=True)
    rec.log("image/removal", class_context(REMOVAL_CLASSES), static=True)
    rec.log("image/bin_mask", class_context(BIN_MASK_CLASSES), static=True)
    rec.log("image/bin_check", class_context(BIN_CHECK_CLASSES), static=True)
    rec.log("world/outliers", class_context(OUTLIER_CLASSES), static=True)
    rec.log("image/methods", class_context(METHOD_CLASSES), static=True)
    log_overlay_scale(rec, OVERLAYS, opts)
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    head = f"# zcut replay\n\n{source}\n\n{TIMELINES_HINT}\n\n" if source else f"# zcut replay\n\n{TIMELINES_HINT}\n\n"
    body = "".join(f"- {n}\n" for n in notes)
    text = f"{head}{body}\n## Resolved config\n\n```toml\n{config_toml}```\n"
    rec.log("config", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    if bin_model is not None:
        pts = bin_model.points
        if len(pts) > 200_000:
            pts = pts[:: int(np.ceil(len(pts) / 200_000))]
        rec.log("world/bin_model/points", rr.Points3D(pts.astype(np.float32), colors=(0, 120, 255),
                                                      radii=rr.Radius.ui_points(1.5)), static=True)


#: the Arrow type of a Rerun blob (an image's bytes)
_BLOB_TYPE = rr.components.BlobBatch._ARROW_DATATYPE


def _blob(data: np.ndarray) -> pa.Array:
    """One Rerun blob: the bytes of ``data`` in C order, without a copy (the SDK's converter copies
    them twice and takes ~0.3 ms an image on the Python side)."""
    flat = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    return pa.ListArray.from_arrays(pa.array(np.array([0, flat.size], np.int32)), pa.array(flat), type=_BLOB_TYPE)


@functools.lru_cache(maxsize=64)
def _image_format(height: int, width: int, dtype: str) -> pa.Array:
    """The ``ImageFormat`` component of a one-channel image (built once per size and pixel type)."""
    fmt = rr.components.ImageFormat(width=width, height=height,
                                    channel_datatype=rr.encodings.ChannelDatatype.from_np_dtype(np.dtype(dtype)))
    return rr.components.ImageFormatBatch(fmt).as_arrow_array()


def _segmentation(img: np.ndarray, opacity: float | None = None) -> rr.SegmentationImage:
    """``rr.SegmentationImage(img, opacity=opacity)`` with its components built directly: the same
    Arrow arrays (tests/replay/pipeline/test_viz_overlays.py), the pixels not copied."""
    h, w = img.shape
    return rr.SegmentationImage.from_fields(buffer=_blob(img), format=_image_format(h, w, img.dtype.str),
                                            opacity=opacity)


def set_frame_time(rec: rr.RecordingStream, frame: Frame) -> None:
    """The frame's timelines: ``frame`` (index), ``stamp`` (the cloud's header stamp), and
    ``depth_um`` = 0, so that on the depth timeline (which the viewer opens on, to scrub the z-cuts)
    every stage of the last frame replayed shows too."""
    rec.set_time("frame", sequence=int(frame.index))
    rec.set_time("stamp", timestamp=np.datetime64(int(frame.stamp_ns), "ns"))
    rec.set_time("depth_um", sequence=0)


def _image(rgb: np.ndarray, opts: VizOptions) -> rr.Image | rr.EncodedImage:
    """Raw at full detail; else JPEG-encoded once with OpenCV (faster than ``rr.Image.compress``)."""
    if opts.full_detail:
        return rr.Image(np.ascontiguousarray(rgb), color_model="RGB")
    bgr = rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(opts.jpeg_quality)])
    if not ok:  # pragma: no cover - OpenCV encodes every uint8 image
        return rr.Image(np.ascontiguousarray(rgb), color_model="RGB").compress(jpeg_quality=opts.jpeg_quality)
    return rr.EncodedImage.from_fields(blob=_blob(buf), media_type="image/jpeg")  # the encoder's buffer, not a copy


def _height_gray(height_mm: np.ndarray) -> np.ndarray:
    """(H, W) uint8 rendering of a height image (high = bright; invalid = black); the 1 % and 99 %
    percentiles that stretch it come from every 4th row and column."""
    ok = np.isfinite(height_mm)
    out = np.zeros(height_mm.shape, np.uint8)
    sub = height_mm[::4, ::4]
    sub = sub[np.isfinite(sub)]
    if ok.any():
        lo, hi = np.percentile(sub if sub.size else height_mm[ok], [1, 99])
        span = max(hi - lo, 1e-9)
        out[ok] = (np.clip((height_mm[ok] - lo) / span, 0, 1) * 230 + 25).astype(np.uint8)
    return out


def log_image(rec: rr.RecordingStream, frame: Frame, result: FrameResult, opts: VizOptions) -> None:
    """The RGB image, or a gray rendering of the height when the frame has none."""
    if frame.rgb is not None:
        rec.log("image/rgb", _image(frame.rgb, opts))
        return
    gray = _height_gray(frame.xyz[..., 2] * np.float32(-1000.0))  # float32: only a rendering
    if opts.full_detail:
        rec.log("image/rgb", rr.Image(gray, color_model="L"))
    else:
        rec.log("image/rgb", _image(gray, opts))


def _u8(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool -> the same memory as uint8 0/1 (no copy)."""
    return np.ascontiguousarray(mask, dtype=bool).view(np.uint8)


def log_bin_stages(rec: rr.RecordingStream, frame: Frame, result: FrameResult,
                   opts: VizOptions = VizOptions()) -> None:
    """Bin mask, removal classes, registered bin model with fitness/RMSE (or a Clear when skipped)."""
    s = opts.overlay_scale
    if result.bin_mask is None:
        rec.log("image/bin_mask", rr.Clear(recursive=False))
    else:
        m = np.maximum(_u8(result.bin_mask.mask), _u8(result.bin_mask.walls) * np.uint8(2))  # walls win
        rec.log("image/bin_mask", _segmentation(pool_max(m, s), opacity=0.35))
    rem = result.removal
    if rem is None:
        rec.log("image/removal", rr.Clear(recursive=False))
    else:
        # the higher class wins, as if table, bin, easy outliers and zone were painted in that order
        c = np.maximum(_u8(rem.table), _u8(rem.bin_points) * np.uint8(2))
        np.maximum(c, _u8(rem.easy_outliers) * np.uint8(3), out=c)
        np.maximum(c, _u8(rem.zone) * np.uint8(4), out=c)
        rec.log("image/removal", _segmentation(pool_max(c, s), opacity=0.4))
    reg = result.registration
    if reg is None:  # the model keeps its last pose; the label says this frame did not register it
        why = result.warnings[0] if result.warnings else "bin stages skipped"
        rec.log("world/bin_model/status", rr.Points3D([[0.0, 0.0, 0.0]], labels=[f"not registered: {why}"],
                                                      colors=[(255, 0, 0)], show_labels=True))
        return
    T = reg.T_cam_bin
    rec.log("world/bin_model", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    status = (f"fitness {reg.fitness:.3f}, RMSE {reg.inlier_rmse * 1000:.2f} mm" if reg.converged
              else f"registration FAILED: {reg.reason}")
    colour = (0, 120, 255) if reg.converged else (255, 0, 0)
    rec.log("world/bin_model/status", rr.Points3D([[0.0, 0.0, 0.0]], labels=[status], colors=[colour],
                                                  show_labels=True))
    rec.log("registration/fitness", rr.Scalars(reg.fitness))
    rec.log("registration/icp_fitness", rr.Scalars(reg.icp_fitness))
    rec.log("registration/rmse_mm", rr.Scalars(reg.inlier_rmse * 1000.0))


def log_bin_check(rec: rr.RecordingStream, result: FrameResult, opts: VizOptions = VizOptions()) -> None:
    """The bin check: its figure, threshold and the removal's tolerance as scalars, the certain bin
    pixels and the offending ones as an image, the reason as a warning (a Clear when not checked)."""
    check = result.bin_check
    if check is None or check.offending is None:
        rec.log("image/bin_check", rr.Clear(recursive=False))
    else:
        c = _u8(check.offending) * np.uint8(2)
        if check.ring is not None:
            np.maximum(c, _u8(check.ring), out=c)
        rec.log("image/bin_check", _segmentation(pool_max(c, opts.overlay_scale), opacity=0.6))
    if check is not None:
        if np.isfinite(check.value):
            rec.log("bin_check/pixels", rr.Scalars(float(check.value)))
        rec.log("bin_check/threshold", rr.Scalars(float(check.threshold)))
        rec.log("bin_check/flagged", rr.Scalars(1.0 if check.flagged else 0.0))
        if check.flagged:
            rec.log("log", rr.TextLog(f"frame {result.index}: bin check: {check.reason}", level=rr.TextLogLevel.WARN))
    if result.removal is not None and np.isfinite(result.removal.tolerance_mm):
        rec.log("bin_check/tolerance_mm", rr.Scalars(float(result.removal.tolerance_mm)))


def _level_colours(n: int) -> np.ndarray:
    """(n, 3) uint8: a blue -> yellow gradient for levels 0 .. n-1 (shallow = warm)."""
    t = np.linspace(0.0, 1.0, max(n, 1))
    r = (255 * (1 - t) + 40 * t).astype(np.uint8)
    g = (220 * (1 - t) + 90 * t).astype(np.uint8)
    b = (40 * (1 - t) + 200 * t).astype(np.uint8)
    return np.stack([r, g, b], axis=1)[:n]


def scrub_levels(n_levels: int, opts: VizOptions) -> tuple[int, list[int]]:
    """(m, levels): the cut levels shown on the depth timeline, every m-th of 0 .. K + 1 and K + 1.

    Full detail shows every level; by default at most ``opts.max_scrub_levels`` (an
    AnnotationContext per shown level is the cost of scrubbing).
    """
    top = n_levels + 1
    m = 1 if opts.full_detail else max(1, -(-(top + 1) // max(int(opts.max_scrub_levels), 2)))
    levels = list(range(0, top + 1, m))
    if levels[-1] != top:
        levels.append(top)
    return m, levels


def log_cuts(rec: rr.RecordingStream, frame: Frame, result: FrameResult, opts: VizOptions, *,
             step_mm: float) -> None:
    """The z-cuts, scrubbable on the ``depth_um`` timeline (see the module docstring).

    The level image holds class ``ceil(level / m) + 1`` (0: deeper than K + 1 or invalid); the
    context logged at ``depth_um`` = k·Δd for each shown level k = q·m colours the classes 1 .. q + 1
    and hides the rest, so the cut shown at k is exactly Z_k. The contexts of all shown levels go
    out in one ``send_columns`` call, on the frame's ``frame`` and ``stamp`` timelines too.
    """
    cut = result.cut
    s = 1 if opts.full_detail else max(int(opts.level_stride), 1)
    m, levels = scrub_levels(cut.n_levels, opts)
    seg = cut_classes(cut.pixel_level, s, m, small=not opts.full_detail)
    rec.log("zcut/cuts", _segmentation(seg))  # at depth_um 0 (set_frame_time)
    depths = np.array([round(k * step_mm * 1000.0) for k in levels], np.int64)
    n = len(levels)
    rec.send_columns("zcut/cuts", indexes=[
        rr.TimeColumn("frame", sequence=np.full(n, int(frame.index), np.int64)),
        rr.TimeColumn("stamp", timestamp=np.full(n, int(frame.stamp_ns), np.int64).astype("datetime64[ns]")),
        rr.TimeColumn("depth_um", sequence=depths)],
        columns=rr.AnnotationContext.columns(context=_cut_contexts(cut.n_levels, m, tuple(levels))))


def cut_classes(pixel_level: np.ndarray, s: int, m: int, *, small: bool = False) -> np.ndarray:
    """The level image of :func:`log_cuts`: every ``s``-th row and column's class
    ``ceil(level / m) + 1`` (0: no level, -1), uint16; ``small``: uint8 when every class fits."""
    pl = pixel_level
    if (small and s == 2 and pl.dtype == np.int16 and pl.ndim == 2 and pl.size and not pl.shape[1] % 2
            and pl.strides[1] == 2 and sys.byteorder == "little"):
        # the even columns of the even rows without a strided pass: each pair of columns read as one
        # int32 whose low half is the even column's; + 1 and the low 16 bits: level + 1 for levels
        # -1 .. 32766 (others would read >= 32768: the general formula below takes them)
        x = (pl[0::2].view(np.int32) + np.int32(1)) & np.int32(0xFFFF)
        top = int(x.max())
        if top <= 32767:
            v = np.arange(top + 1) - 1  # the level of each x
            lut = np.where(v >= 0, (v + m - 1) // m + 1, 0)
            if top < 256 and lut[-1] < 256:
                lut8 = np.zeros(256, np.uint8)  # OpenCV's table: 256 entries
                lut8[: top + 1] = lut
                classes: np.ndarray = cv2.LUT(x.astype(np.uint8), lut8)
                return classes
            return np.take(lut.astype(np.uint8 if lut[-1] < 256 else np.uint16), x)
    lvl = pl[::s, ::s].astype(np.int32)
    seg = np.where(lvl >= 0, (lvl + m - 1) // m + 1, 0)
    return seg.astype(np.uint8 if small and (seg.size == 0 or seg.max() < 256) else np.uint16)


@functools.lru_cache(maxsize=64)
def _cut_contexts(n_levels: int, m: int, levels: tuple[int, ...]) -> pa.Array:
    """One context per shown level k (classes 1 .. q + 1 coloured, the rest hidden), built in Arrow
    in one go and reused by every frame with the same K."""
    n_cls = (n_levels + 1 + m - 1) // m + 1  # classes 1 .. n_cls
    colours = np.concatenate([[0], rgba32(_level_colours(n_cls))])  # class id -> colour (0 hidden)
    names = [None] + [f"levels <= {min(c * m, n_levels + 1)}" for c in range(n_cls)]
    q = np.array([(k + m - 1) // m for k in levels])
    ids = np.tile(np.arange(n_cls + 1), len(levels))
    shown = (ids >= 1) & (ids <= np.repeat(q, n_cls + 1) + 1)
    labels = [names[i] if v else None for i, v in zip(ids.tolist(), shown.tolist())]
    return contexts_arrow(ids, labels, np.where(shown, colours[ids], 0).astype(np.uint32),
                           np.arange(len(levels) + 1) * (n_cls + 1))


@functools.lru_cache(maxsize=1)
def _cluster_palette(n: int) -> np.ndarray:
    """(n,) uint32: random bright colours for cluster ids 1 .. n (fixed seed: stable across frames)."""
    return rgba32(np.random.default_rng(7).integers(60, 256, size=(n, 3)))


def log_clusters(rec: rr.RecordingStream, result: FrameResult, opts: VizOptions) -> None:
    """Tagged clusters as a segmentation image; each class labelled with its area, level and ρ."""
    cut = result.cut
    n = cut.n_clusters
    k = min(n, opts.max_cluster_labels)
    areas, levels, rho = cut.areas[:k].tolist(), cut.levels[:k].tolist(), cut.rho[:k].tolist()
    labels = [None] + [f"cluster {i + 1}: {a} px, level {lv}" + (f", ρ {r:.3f}" if np.isfinite(r) else "")
                       for i, (a, lv, r) in enumerate(zip(areas, levels, rho))]
    colours = np.concatenate([[0], _cluster_palette(max(int(opts.max_cluster_labels), 1))[:k]]).astype(np.uint32)
    ctx = contexts_arrow(np.arange(k + 1), labels, colours, np.array([0, k + 1]))
    rec.log("image/clusters", rr.AnnotationContext(ctx))
    dtype = np.uint8 if n < 256 else np.uint16 if n < 65536 else np.uint32  # the smallest that holds every id
    # a block: the highest id in it; a pixel has an id > 0 only where the z-cut flags it (``outliers ==
    # clusters > 0``, zcut.cuts.CutResult), so the image is built from those pixels alone (no pass over
    # the frame's int32 ids: log_clusters 1.7 -> 1.0 ms a 1920 x 1200 frame)
    idx = np.flatnonzero(cut.outliers)
    ids = scatter_pool_max(cut.clusters.shape, idx, cut.clusters.ravel()[idx].astype(dtype), opts.overlay_scale)
    rec.log("image/clusters", _segmentation(ids))


def _pixels_xyz(xyz: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(n, 3): the points of the flat pixel indices ``idx`` of the (H, W, 3) cloud (``xyz[rows, cols]``)."""
    if xyz.flags.c_contiguous:
        return np.take(xyz.reshape(-1, 3), idx, axis=0)
    rows, cols = np.divmod(idx, xyz.shape[1])
    pts: np.ndarray = xyz[rows, cols]
    return pts


@dataclass(frozen=True, slots=True)
class OutlierPixels:
    """The frame's outlier pixels (z-cut, SOR, above the rim), read once for the image, the points and
    the counts of a frame: a frame's outliers are a few thousand of its millions of pixels, so the
    rest of the logging works on them, not on whole-frame masks.

    Attributes
    ----------
    idx : (n,) intp ndarray
        Their flat pixel indices, ascending.
    classes : (n,) uint8 ndarray
        Each one's class: z-cut only 1, SOR only 2, both 3, above the rim 4 (wins).
    zcut, sor, above_rim : (n,) bool ndarray
        Whether the z-cut, SOR, the removal's above-the-rim test flagged it.
    """

    idx: np.ndarray
    classes: np.ndarray
    zcut: np.ndarray
    sor: np.ndarray
    above_rim: np.ndarray


def outlier_pixels(result: FrameResult) -> OutlierPixels:
    """:class:`OutlierPixels` of ``result``: one pass over the three masks finds the pixels, the rest
    reads those pixels alone."""
    z, s, e = (np.ascontiguousarray(m, dtype=bool).reshape(-1)
               for m in (result.zcut_outliers, result.sor_outliers, result.easy_outliers))
    union = z | s
    union |= e
    idx = np.flatnonzero(union)  # bool: fast
    zi, si, ei = z[idx], s[idx], e[idx]
    c = zi.view(np.uint8) + si.view(np.uint8)
    c += si.view(np.uint8)
    classes: np.ndarray = np.maximum(c, ei.view(np.uint8) * np.uint8(4), out=c)
    return OutlierPixels(idx, classes, zi, si, ei)


def scatter_pool_max(shape: tuple[int, int], idx: np.ndarray, values: np.ndarray, s: int) -> np.ndarray:
    """:func:`pool_max` of the (H, W) image that holds ``values`` at the flat indices ``idx`` and 0
    elsewhere, built from those pixels alone (no whole-frame image): (ceil(H / s), ceil(W / s)) of
    ``values``' type. ``idx`` must not repeat (a pixel has one value)."""
    h, w = shape
    if s <= 1:
        out = np.zeros(h * w, values.dtype)
        out[idx] = values
        return out.reshape(h, w)
    out = np.zeros((-(-h // s), -(-w // s)), values.dtype)
    rows, cols = np.divmod(idx, w)
    rows //= s
    cols //= s
    np.maximum.at(out, (rows, cols), values)  # several pixels of a block: the highest
    return out


def log_outliers(rec: rr.RecordingStream, frame: Frame, px: OutlierPixels, opts: VizOptions = VizOptions()) -> None:
    """Outliers of the z-cut, SOR and both, in 2D (segmentation) and 3D (points), same colours."""
    img = scatter_pool_max(frame.xyz.shape[:2], px.idx, px.classes, opts.overlay_scale)
    rec.log("image/outliers", _segmentation(img, opacity=0.8))
    rec.log("world/outliers", rr.Points3D(_pixels_xyz(frame.xyz, px.idx), class_ids=px.classes,
                                          radii=rr.Radius.ui_points(3.0)))


def log_methods(rec: rr.RecordingStream, result: FrameResult, opts: VizOptions = VizOptions()) -> None:
    """The outliers of every base method other than the z-cut and SOR (one segmentation image each:
    its outliers 1, the above-the-rim points 2) and their counts."""
    easy = _u8(result.easy_outliers) * np.uint8(2)
    for name, mask in result.outliers.items():
        if name in ("zcut", "sor"):
            continue
        rec.log(f"image/methods/{name}", _segmentation(pool_max(np.maximum(_u8(mask), easy), opts.overlay_scale),
                                                              opacity=0.8))
        rec.log(f"counts/{name}", rr.Scalars(float(np.count_nonzero(mask))))


#: the classes of ``image/explained``
EXPLAINED_CLASSES = ((1, "part fit", (60, 180, 75)), (2, "bin", (0, 120, 255)), (3, "table", (150, 150, 150)),
                     (4, "unexplained", (230, 25, 75)), (5, "local surface", (255, 200, 40)))


def log_explained(rec: rr.RecordingStream, result: FrameResult, opts: VizOptions = VizOptions()) -> None:
    """The method ``explained``'s stage (when it ran): the nearest known surface of each zone pixel
    and the unexplained ones, the distance image, the fitted instances in 3D (metres, as the cloud)."""
    d = result.details.get("explained")
    if d is None:  # the method did not run: its modules are not loaded for nothing
        return
    from replay.pipeline.explained import ExplainedDetail
    from zcut.explained import SURFACE_BIN, SURFACE_LOCAL, SURFACE_TABLE

    if not isinstance(d, ExplainedDetail):
        return
    cls = np.zeros(d.surface.shape, np.uint8)
    judged = np.isfinite(d.dist_mm)
    cls[judged & (d.surface >= 0)] = 1
    cls[judged & (d.surface == SURFACE_BIN)] = 2
    cls[judged & (d.surface == SURFACE_TABLE)] = 3
    cls[judged & (d.surface == SURFACE_LOCAL)] = 5  # no part model: the edge-aware local surface
    cls[d.unexplained] = 4
    rec.log("image/explained", class_context(EXPLAINED_CLASSES))
    log_overlay_scale(rec, ("image/explained",), opts)
    rec.log("image/explained", _segmentation(pool_max(cls, opts.overlay_scale), opacity=0.6))
    dist = np.where(judged & np.isfinite(d.dist_mm), d.dist_mm, 0.0).astype(np.float32)
    rec.log("image/explained_distance", rr.DepthImage(dist, meter=1000.0, colormap="turbo"))
    rec.log("counts/explained_fits", rr.Scalars(float(len(d.fits))))
    rec.log("counts/explained_vetted_out", rr.Scalars(float(len(d.vetted_out))))
    _log_instances(rec, d, d.fits, "fits", "labels", (60, 180, 75, 160), "fit")
    _log_instances(rec, d, d.vetted_out, "vetted_out", "vetted_out_labels", (230, 25, 75, 110), "vetted out")


def _log_instances(rec: rr.RecordingStream, d: ExplainedDetail, fits: tuple[PartFit, ...], mesh: str, labels: str,
                   colour: tuple[int, int, int, int], what: str) -> None:
    """Fitted instances as one mesh ``world/explained/{mesh}`` (metres) with a label at each centre; cleared
    when there are none, so a frame without them shows none of the previous frame's."""
    if not fits:
        rec.log(f"world/explained/{mesh}", rr.Clear(recursive=False))
        rec.log(f"world/explained/{labels}", rr.Clear(recursive=False))
        return
    n = len(d.vertices_mm)
    verts = np.concatenate([d.vertices_mm @ f.pose[:3, :3].T + f.pose[:3, 3] for f in fits]) / 1000.0
    tris = np.concatenate([d.triangles + i * n for i in range(len(fits))])
    rec.log(f"world/explained/{mesh}", rr.Mesh3D(vertex_positions=verts.astype(np.float32),
                                                 triangle_indices=tris.astype(np.uint32), albedo_factor=colour))
    centres = np.array([f.pose[:3, 3] for f in fits]) / 1000.0
    text = [f"{what} {i}: Err {f.err_mm:.2f} mm, support {f.support:.2f}" for i, f in enumerate(fits)]
    rec.log(f"world/explained/{labels}", rr.Points3D(centres.astype(np.float32), labels=text,
                                                     radii=rr.Radius.ui_points(2.0)))


def log_cloud(rec: rr.RecordingStream, frame: Frame, opts: VizOptions) -> None:
    """The cloud in 3D (strided at default detail), in its RGB colours when there are some."""
    s = opts.cloud_step(*frame.xyz.shape[:2])
    ok = np.isfinite(frame.xyz[::s, ::s, 2])  # z first (one strided pass), then x and y of those only
    idx = np.flatnonzero(ok)
    flat = (idx // ok.shape[1]) * (s * frame.xyz.shape[1]) + (idx % ok.shape[1]) * s  # into the full grid
    xyz = np.take(frame.xyz.reshape(-1, 3), flat, axis=0)
    colours = None if frame.rgb is None else np.take(frame.rgb.reshape(-1, 3), flat, axis=0)
    good = np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1])
    if not good.all():
        xyz = xyz[good]
        colours = None if colours is None else colours[good]
    rec.log("world/cloud", rr.Points3D(xyz, colors=None if colours is None else rgba32(colours),
                                       radii=rr.Radius.ui_points(1.0)))


def log_scalars(rec: rr.RecordingStream, result: FrameResult, px: OutlierPixels) -> None:
    """Counts (of the outlier pixels ``px``: every pixel a mask flags is one of them), α, β and stage
    times of the frame."""
    rec.log("counts/zcut", rr.Scalars(float(np.count_nonzero(px.zcut))))
    rec.log("counts/sor", rr.Scalars(float(np.count_nonzero(px.sor))))
    rec.log("counts/both", rr.Scalars(float(np.count_nonzero(px.zcut & px.sor))))
    rec.log("counts/above_rim", rr.Scalars(float(np.count_nonzero(px.above_rim))))
    rec.log("counts/clusters", rr.Scalars(float(result.cut.n_clusters)))
    m = result.metrics
    rec.log("metrics/alpha", rr.Scalars(float(m.alpha)))
    rec.log("metrics/beta_sor", rr.Scalars(float(m.beta1)))
    rec.log("metrics/beta_zcut", rr.Scalars(float(m.beta2)))
    for stage, sec in result.timings.items():
        rec.log(f"timings_ms/{stage}", rr.Scalars(sec * 1000.0))


def log_frame(rec: rr.RecordingStream, frame: Frame, result: FrameResult, *,
              step_mm: float, opts: VizOptions = VizOptions()) -> None:
    """Log every stage of one frame."""
    set_frame_time(rec, frame)
    log_image(rec, frame, result, opts)
    log_bin_stages(rec, frame, result, opts)
    log_bin_check(rec, result, opts)
    log_cuts(rec, frame, result, opts, step_mm=step_mm)
    log_clusters(rec, result, opts)
    px = outlier_pixels(result)
    log_outliers(rec, frame, px, opts)
    log_methods(rec, result, opts)
    log_explained(rec, result, opts)
    log_cloud(rec, frame, opts)
    log_scalars(rec, result, px)
    for w in result.warnings:
        rec.log("log", rr.TextLog(f"frame {frame.index}: {w}", level=rr.TextLogLevel.WARN))


def log_verdicts_static(rec: rr.RecordingStream, judged: Iterable[str], *, source: str,
                        opts: VizOptions = VizOptions()) -> None:
    """The verdicts' classes (one context for the images, one for the points), the images' scale
    (``opts``: those of :func:`log_verdicts`), their series' names and colours, and what the frames
    are scored against."""
    rec.log("image/verdicts", class_context(VERDICT_CLASSES), static=True)
    log_overlay_scale(rec, ("image/verdicts",), opts)
    rec.log("world/verdicts", class_context(VERDICT_CLASSES), static=True)
    for m in judged:
        rec.log(f"accuracy/{m}/precision", rr.SeriesLines(names=f"{m} precision"), static=True)
        rec.log(f"accuracy/{m}/recall", rr.SeriesLines(names=f"{m} recall"), static=True)
    text = (f"Scored against: **{source}**, over the scored region (docs/accuracy.md).\n\n"
            "TP: a true outlier the method removed; FP: a good point it removed; FN: a true outlier it missed. "
            "A frame without truth shows no verdict.\n")
    rec.log("accuracy/truth", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)


def log_verdicts(rec: rr.RecordingStream, frame: Frame, verdicts: Mapping[str, MethodVerdict] | str,
                 judged: Iterable[str], opts: VizOptions = VizOptions()) -> None:
    """Each judged method's verdict on the frame: its image (TP 1, FP 2, FN 3), the same pixels in 3D
    and its precision and recall (left out when undefined); a frame without truth (``verdicts`` is
    why) clears them and says so in the warnings log."""
    if isinstance(verdicts, str):
        for m in judged:
            rec.log(f"image/verdicts/{m}", rr.Clear(recursive=False))
            rec.log(f"world/verdicts/{m}", rr.Clear(recursive=False))
        rec.log("log", rr.TextLog(f"frame {frame.index}: not scored: {verdicts}", level=rr.TextLogLevel.INFO))
        return
    for m, v in verdicts.items():
        idx = np.flatnonzero(v.classes.astype(bool))  # bool: ~14 x faster than on the uint8 classes
        cls = v.classes.ravel()[idx]  # the image and the points from these pixels alone
        img = scatter_pool_max(v.classes.shape, idx, cls, opts.overlay_scale)
        rec.log(f"image/verdicts/{m}", _segmentation(img, opacity=0.8))
        rec.log(f"world/verdicts/{m}", rr.Points3D(_pixels_xyz(frame.xyz, idx), class_ids=cls,
                                                   radii=rr.Radius.ui_points(3.0)))
        for name, value in (("precision", v.precision), ("recall", v.recall)):
            if np.isfinite(value):
                rec.log(f"accuracy/{m}/{name}", rr.Scalars(float(value)))
