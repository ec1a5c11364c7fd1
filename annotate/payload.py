"""What the labelling page shows of a frame, computed once per frame.

For each frame of the log the pipeline (``replay.pipeline.stages.run_frame``) proposes candidates;
:func:`prepare_frame` turns the frame and its :class:`~replay.pipeline.stages.FrameResult` into a
:class:`PreparedFrame`: JPEGs of the RGB image (:func:`rgb_picture`: a fill colour of the unmeasured
pixels shown grey) and of a height colour map, one compact binary
*bundle* with the valid mask, the candidate clusters of the z-cut and of SOR and the *candidate
table*, and the frame's points (``geometry``) that the server spills to disk and serves by
rectangles (:func:`make_geometry`) for the exact views: height and xyz under the cursor, the
profile and the 3D view. The JPEG is only a picture; every number the page shows comes from the
float32 points.

Bundle layout (little endian): ``uint32 n`` | ``n`` bytes of JSON header | sections. The header
lists the sections as ``{"name", "kind", "dtype", "offset", "length"}`` (offset from the first byte
after the header; ``"zlib": false`` when the section is stored without the zlib step written
below). ``kind = "bits"``: ``zlib(packbits(mask.ravel()))`` (MSB first, as
:func:`annotate.store.pack_mask`); ``kind = "ids"``: ``zlib(array.ravel().tobytes())`` of an
unsigned integer array (``dtype`` ``uint8``, ``uint16`` or ``uint32``), 0 = no cluster;
``kind = "sparse"``: the same array by its ``count`` non-zero pixels, ``zlib(deltas + values)``
where ``deltas`` are the differences of the increasing flat pixel indices (first one from 0) as
``uint32`` and ``values`` the ids there in ``dtype`` (candidates cover a few per cent of a frame:
this is smaller and much faster to decode than the dense array); ``kind = "runs"``: a mask as
``zlib(uint32 run lengths)``, alternating runs of false and true pixels in raster order, the first
one (possibly empty) false — decoded with a few ``fill`` calls, so used for the valid mask whenever
its runs take no more bytes than its packed bits (:func:`mask_kind`); ``kind = "table"``: a
``(rows, cols)`` float32 array in row-major order, ``zlib``'ed, with ``"rows"`` and ``"cols"`` in
the section's entry.

The frame's bundle holds ``valid``, ``zcut`` and ``sor`` (sparse ids), ``zone`` (only when the bin
stages ran: the pixels the filters judge) and ``candidates``, the table of :data:`CANDIDATE_COLUMNS`
(named in the header's ``candidate_columns``; one row per z-cut cluster and per SOR cluster of at
least :data:`SOR_LIST_MIN_PX` pixels, at most :data:`SOR_LIST_MAX` of them, the largest). Its
header also carries ``height_lo_mm`` and ``height_hi_mm``, the heights that the colour map's first
and last colours stand for. The review groups (:mod:`annotate.groups`: what the page lists, one
decision each) are ``groups`` (sparse ids), ``group_table`` (:data:`annotate.groups.GROUP_COLUMNS`,
named in ``group_columns``; ``group_sources``, ``methods`` and ``detectors`` name what its
``source``, ``methods`` and ``detectors`` columns index) and ``rise`` (sparse uint8: how far a pixel
stands above the surface around it, in :data:`RISE_STEP_MM` steps — what the wand and the residual
brush select by). ``bin_stages`` says whether the bin stages ran (the frame's ``warnings`` say why
not).

A *view* (``GET /api/frames/{i}/view``) is everything the page needs to show a frame in one
response: ``uint32 n`` | ``n`` bytes of JSON ``{"parts": [[name, offset, length], ...]}`` | parts
(offset from the first byte after the header); the parts are the frame's bundle, the annotator's
label bundle and the JPEG of the requested image (:func:`make_view`, :func:`parse_view`).

A *geometry* rectangle (``GET /api/frames/{i}/geometry``): ``uint32 n`` | ``n`` bytes of JSON
``{"x0", "y0", "width", "height", "channels": ["x_m", "y_m", "z_m"], "dtype": "float32"}`` |
``float32`` planes, one per channel, each ``height x width`` in raster order (NaN = no point).
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from scipy import ndimage

from annotate.groups import GROUP_COLUMNS, group_targets, review_groups
from annotate.store import pack_mask
from zcut.cloud import height_mm
from zcut.params import SuspectParams
from zcut.suspects import DETECTORS

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.stages import FrameResult

EIGHT = np.ones((3, 3), bool)
JPEG_QUALITY = 90
INVALID_GRAY = 48
#: Unmeasured pixels that all share one colour, at least this many, are a cloud file's fill value,
#: shown grey in the RGB picture (:func:`rgb_picture`).
FILL_MIN_PX = 16
#: The share of its own colour an unmeasured pixel keeps in the RGB picture when it shows the camera's
#: picture (the rest is :data:`INVALID_GRAY`): what the depth sensor missed stays recognisable, and
#: reads as not measured (:func:`rgb_picture`).
UNMEASURED_SHADE = 0.4
#: Columns of the candidate table (float32). ``source``: 0 = z-cut, 1 = SOR; ``id``: the cluster's id
#: in that source's id image; ``x0, y0, x1, y1``: bounding box (end exclusive); ``cx, cy``: centroid;
#: ``h_min_mm, h_max_mm``: its heights; ``below_mm``: the highest valid pixel within
#: :data:`RING_PX` pixels around it (NaN if none); ``gap_mm = h_min_mm - below_mm`` (> 0: it floats
#: above everything around it); ``both``: its pixels the other filter flags too; ``level``: the
#: z-cut level that tagged it (-1 for SOR and for z-cut outliers outside a cluster).
CANDIDATE_COLUMNS = ("source", "id", "n", "x0", "y0", "x1", "y1", "cx", "cy", "h_min_mm", "h_max_mm",
                     "below_mm", "gap_mm", "both", "level")
COLUMN = {name: i for i, name in enumerate(CANDIDATE_COLUMNS)}
SOURCE_ZCUT, SOURCE_SOR = 0, 1
RING_PX = 2
SOR_LIST_MIN_PX = 2
SOR_LIST_MAX = 4000
#: The page's default SOR size filter; also what a frame's disagreement count uses.
SOR_DEFAULT_MIN_PX = 5
GEOMETRY_CHANNELS = ("x_m", "y_m", "z_m")
#: The ``rise`` section's unit: how far a pixel stands above the surface continued from around it,
#: in steps of this many mm (uint8, 255 = 25.5 mm or more), for pixels above half the suspects' τ.
RISE_STEP_MM = 0.1


@dataclass(frozen=True, slots=True)
class ServedFrame:
    """What the server keeps of a frame in memory: the encoded bytes and a few numbers.

    Attributes
    ----------
    index, stamp_ns : int
    topic, frame_id : str
    height, width : int
    n_zcut, n_sor : int
        Candidate clusters of each filter (all of them, listed or not).
    n_sor_listed : int
        SOR clusters of at least :data:`SOR_DEFAULT_MIN_PX` pixels.
    n_valid : int
        Valid pixels: a label whose reviewed mask has that many pixels reviews the whole frame.
    disagreement : int
        Candidates (z-cut, and SOR of at least :data:`SOR_DEFAULT_MIN_PX` pixels) that the other
        filter flags on fewer than half of their pixels.
    rgb_jpeg : bytes or None
    height_jpeg, bundle : bytes
    warnings : tuple of str
    cand_pixels : (k,) int64 ndarray
        Flat pixel indices of the review groups (:mod:`annotate.groups`), grouped by group: what the
        page lists and what "decided" counts, in the frame list as in the page's panel.
    cand_starts : (n_groups + 1,) int64 ndarray
        Group ``g`` (1-based) owns ``cand_pixels[cand_starts[g - 1]:cand_starts[g]]``.
    n_groups : int
        Review groups of the frame.
    group_features : (n_groups, len(annotate.groups.FEATURES)) float32 ndarray
        The assistant's features of each group.
    part : str or None
        The part kind the config names (the assistant's models are per part kind).
    bin_stages : bool
        Whether the bin stages ran (without them the zone is every valid pixel, and the frame's
        ``warnings`` say why).
    """

    index: int
    stamp_ns: int
    topic: str
    frame_id: str
    height: int
    width: int
    n_zcut: int
    n_sor: int
    n_sor_listed: int
    n_valid: int
    disagreement: int
    rgb_jpeg: bytes | None
    height_jpeg: bytes
    bundle: bytes
    warnings: tuple[str, ...]
    cand_pixels: np.ndarray
    cand_starts: np.ndarray
    n_groups: int = 0
    group_features: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    part: str | None = None
    bin_stages: bool = True

    def group_targets(self, outliers: np.ndarray, reviewed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per group: (decided, share of its pixels labelled outliers) under a label
        (:func:`annotate.groups.group_targets`)."""
        return group_targets(self.cand_pixels, self.cand_starts, outliers, reviewed)

    def decisions(self, outliers: np.ndarray, reviewed: np.ndarray) -> tuple[int, int]:
        """(decided, accepted): candidates with at least half of their pixels reviewed / outliers.

        Parameters
        ----------
        outliers, reviewed : (H, W) bool ndarray
            A label's L and R.
        """
        n = self.cand_starts.size - 1
        if n == 0:
            return 0, 0
        seg = np.repeat(np.arange(n), np.diff(self.cand_starts))
        size = np.diff(self.cand_starts)
        in_r = np.bincount(seg, weights=reviewed.ravel()[self.cand_pixels], minlength=n)
        in_l = np.bincount(seg, weights=outliers.ravel()[self.cand_pixels], minlength=n)
        return int((2 * in_r >= size).sum()), int((2 * in_l >= size).sum())


@dataclass(frozen=True, slots=True)
class PreparedFrame:
    """A frame as the page needs it.

    Attributes
    ----------
    served : ServedFrame
        What the server keeps in memory (see there).
    valid : (H, W) bool ndarray
    zcut_clusters, sor_clusters : (H, W) uint ndarray
        Candidate cluster ids (0 = none).
    candidates : (n, len(CANDIDATE_COLUMNS)) float32 ndarray
        The candidate table (:data:`CANDIDATE_COLUMNS`).
    geometry : (H, W, 3) float32 ndarray
        The frame's points (x, y, z in metres, camera frame; NaN where invalid), for the server to
        spill to disk and serve by rectangles.
    """

    served: ServedFrame
    valid: np.ndarray
    zcut_clusters: np.ndarray
    sor_clusters: np.ndarray
    candidates: np.ndarray
    geometry: np.ndarray


def _small_uint(ids: np.ndarray, n: int) -> np.ndarray:
    dtype = np.uint8 if n < 256 else np.uint16 if n < 65536 else np.uint32
    return ids.astype(dtype, copy=False)


def make_bundle(header: dict[str, Any], sections: list[tuple[str, str, np.ndarray]], *, compress: bool = True) -> bytes:
    """Pack a header dict and ``(name, kind, array)`` sections into one bundle (module docstring).

    ``compress=False`` leaves out the zlib step of every section (marked ``"zlib": false``): the page
    then reads the sections in place, which beats inflating them when the bytes only cross the
    loopback interface.
    """
    parts: list[bytes] = []
    meta = []
    offset = 0
    for name, kind, arr in sections:
        extra: dict[str, object] = {}
        if kind == "bits":
            blob = pack_mask(arr)
            dtype = "bool"
        elif kind == "runs":
            blob = zlib.compress(mask_runs(arr).astype("<u4").tobytes(), 6)
            dtype = "bool"
        elif kind == "ids":
            a = np.ascontiguousarray(arr)
            blob = zlib.compress(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes(), 1)
            dtype = a.dtype.name
        elif kind == "sparse":
            flat = np.ascontiguousarray(arr).ravel()
            idx = np.flatnonzero(flat)
            deltas = np.diff(idx, prepend=0).astype("<u4")
            blob = zlib.compress(deltas.tobytes() + flat[idx].astype(flat.dtype.newbyteorder("<")).tobytes(), 6)
            dtype = flat.dtype.name
            extra["count"] = int(idx.size)
        elif kind == "table":
            t = np.ascontiguousarray(arr, dtype="<f4")
            blob = zlib.compress(t.tobytes(), 1)
            dtype = "float32"
            extra["rows"], extra["cols"] = int(t.shape[0]), int(t.shape[1])
        else:  # pragma: no cover - internal
            raise AssertionError(kind)
        if not compress:
            blob = zlib.decompress(blob)
            extra["zlib"] = False
        meta.append({"name": name, "kind": kind, "dtype": dtype, "offset": offset, "length": len(blob), **extra})
        parts.append(blob)
        offset += len(blob)
    head = json.dumps({**header, "sections": meta}).encode()
    return struct.pack("<I", len(head)) + head + b"".join(parts)


def mask_runs(mask: np.ndarray) -> np.ndarray:
    """(n,) int64 run lengths of a mask in raster order: false, true, false, ... (the first may be 0)."""
    flat = np.ascontiguousarray(mask, dtype=bool).ravel()
    if flat.size == 0:
        return np.zeros(0, np.int64)
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    lengths = np.diff(np.concatenate(([0], change, [flat.size])))
    return np.concatenate(([0], lengths)) if flat[0] else lengths


def runs_to_mask(runs: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`mask_runs`: an (H, W) bool mask from its run lengths.

    Raises
    ------
    ValueError
        If a run is negative or the runs do not cover ``H * W`` pixels exactly.
    """
    r = np.asarray(runs, dtype=np.int64)
    if r.ndim != 1 or (r < 0).any():
        raise ValueError("run lengths must be a 1-D array of non-negative integers")
    total = int(r.sum())
    if total != shape[0] * shape[1]:
        raise ValueError(f"runs cover {total} pixels, the frame has {shape[0] * shape[1]}")
    return np.repeat(np.arange(r.size) % 2 == 1, r).reshape(shape)


def mask_kind(mask: np.ndarray) -> str:
    """``"runs"`` when the mask's uint32 run lengths take no more bytes than its packed bits, else ``"bits"``."""
    flat = np.ascontiguousarray(mask, dtype=bool).ravel()
    n_runs = 1 + int(np.count_nonzero(flat[1:] != flat[:-1])) if flat.size else 0
    return "runs" if 4 * n_runs <= (flat.size + 7) // 8 else "bits"


def make_view(parts: list[tuple[str, bytes]]) -> bytes:
    """Concatenate named byte strings into one view (module docstring)."""
    meta, offset = [], 0
    for name, blob in parts:
        meta.append([name, offset, len(blob)])
        offset += len(blob)
    head = json.dumps({"parts": meta}).encode()
    return struct.pack("<I", len(head)) + head + b"".join(b for _, b in parts)


def parse_view(data: bytes) -> dict[str, bytes]:
    """Split a view back into name -> bytes."""
    (n,) = struct.unpack_from("<I", data, 0)
    base = 4 + n
    return {name: data[base + off:base + off + length] for name, off, length in json.loads(data[4:base])["parts"]}


def make_geometry(points: np.ndarray, *, x0: int, y0: int) -> bytes:
    """Encode a rectangle of the frame's points (module docstring).

    Parameters
    ----------
    points : (h, w, 3) float ndarray
        x, y, z in metres of the pixels ``[y0:y0+h, x0:x0+w]``.
    x0, y0 : int
        The rectangle's top-left pixel (column, row).
    """
    h, w = points.shape[:2]
    head = json.dumps({"x0": int(x0), "y0": int(y0), "width": int(w), "height": int(h),
                       "channels": list(GEOMETRY_CHANNELS), "dtype": "float32"}).encode()
    planes = np.ascontiguousarray(np.moveaxis(np.asarray(points, dtype="<f4"), 2, 0))
    return struct.pack("<I", len(head)) + head + planes.tobytes()


def parse_geometry(data: bytes) -> tuple[dict[str, Any], np.ndarray]:
    """(header, (h, w, 3) float32 points) of a geometry rectangle."""
    (n,) = struct.unpack_from("<I", data, 0)
    header = json.loads(data[4:4 + n])
    h, w = header["height"], header["width"]
    planes = np.frombuffer(data, "<f4", offset=4 + n, count=len(header["channels"]) * h * w)
    return header, np.moveaxis(planes.reshape(len(header["channels"]), h, w), 0, 2)


def bundle_with_blobs(header: dict[str, Any], blobs: list[tuple[str, bytes]]) -> bytes:
    """A bundle of already packed ``bits`` sections (label masks straight from the store)."""
    meta, offset = [], 0
    for name, blob in blobs:
        meta.append({"name": name, "kind": "bits", "dtype": "bool", "offset": offset, "length": len(blob)})
        offset += len(blob)
    head = json.dumps({**header, "sections": meta}).encode()
    return struct.pack("<I", len(head)) + head + b"".join(b for _, b in blobs)


def height_limits(heights: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """(lo, hi): the 1st and 99th percentile of the valid heights (mm) — the colour map's range.

    (0, 1) without valid pixels; ``hi > lo`` always.
    """
    if not valid.any():
        return 0.0, 1.0
    lo, hi = np.percentile(heights[valid], [1.0, 99.0])
    return float(lo), float(max(hi, lo + 1e-6))


def height_colormap(xyz: np.ndarray, valid: np.ndarray, *, limits: tuple[float, float] | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR turbo colour map of the height ``-1000 z``; invalid pixels grey.

    ``limits`` (mm) are the heights of the first and the last colour (default :func:`height_limits`).
    """
    h = height_mm(xyz)
    out = np.full(valid.shape + (3,), INVALID_GRAY, np.uint8)
    if valid.any():
        lo, hi = height_limits(h, valid) if limits is None else limits
        scale = 255.0 / max(hi - lo, 1e-9)
        g = np.clip((h - lo) * scale, 0, 255)
        g = np.where(valid, g, 0).astype(np.uint8)
        cm = cv2.applyColorMap(g, cv2.COLORMAP_TURBO)
        out[valid] = cm[valid]
    return out


def turbo_lut() -> list[list[int]]:
    """The 256 RGB colours of the height colour map (OpenCV's turbo), for the page's legend."""
    bgr = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(1, 256), cv2.COLORMAP_TURBO)[0]
    rgb: list[list[int]] = bgr[:, ::-1].astype(int).tolist()
    return rgb


def rgb_picture(rgb: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The RGB picture the page shows of a frame: its colours, with the unmeasured pixels grey
    (:data:`INVALID_GRAY`, as in the height colour map) when they all carry one and the same colour,
    and shaded toward that grey (:data:`UNMEASURED_SHADE` of their colour kept) when they carry the
    camera's picture.

    A cloud file stores a colour for every pixel; where its points are unmeasured that colour is
    either the camera's (a real picture of what the depth sensor missed) or one fill value that
    means nothing (a stereo cloud stores dark red for every unmatched pixel): shown as it is, a fill
    of red reads as labelled outliers and a fill of any colour as a surface, and the camera's picture
    of a chair the depth sensor missed reads as measured. At least :data:`FILL_MIN_PX` unmeasured
    pixels of one colour are taken for a fill.

    Parameters
    ----------
    rgb : (H, W, 3) uint8 ndarray
    valid : (H, W) bool ndarray

    Returns
    -------
    (H, W, 3) uint8 ndarray
        ``rgb`` itself when every pixel is measured (or the image is not the cloud's size), else a copy.
    """
    if rgb.shape[:2] != valid.shape or valid.all():  # an image of another size is no picture of the cloud's pixels
        return rgb
    unmeasured = rgb[~valid]
    out = rgb.copy()
    if unmeasured.shape[0] >= FILL_MIN_PX and (unmeasured == unmeasured[0]).all():
        out[~valid] = INVALID_GRAY
    else:
        grey = np.asarray(INVALID_GRAY, np.float64)
        out[~valid] = np.round(UNMEASURED_SHADE * unmeasured + (1.0 - UNMEASURED_SHADE) * grey).astype(np.uint8)
    return out


def _jpeg(bgr: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    assert ok
    return buf.tobytes()


def candidate_clusters(zcut_outliers: np.ndarray, cut_clusters: np.ndarray | None, sor_outliers: np.ndarray
                       ) -> tuple[np.ndarray, int, np.ndarray, int]:
    """Clickable clusters: the z-cut's own clusters (other z-cut outliers, e.g. above the rim, as their
    8-connected components) and the 8-connected components of the SOR outliers.

    Returns
    -------
    zcut_ids : (H, W) uint ndarray, n_zcut : int, sor_ids : (H, W) uint ndarray, n_sor : int
    """
    z = np.zeros(zcut_outliers.shape, np.int64)
    n_z = 0
    if cut_clusters is not None and cut_clusters.shape == zcut_outliers.shape:
        # renumber the z-cut's clusters that hold outliers 1..n, in order
        ids = np.where(zcut_outliers, cut_clusters, 0)
        used = np.unique(ids[ids > 0])
        if used.size:
            lut = np.zeros(int(used.max()) + 1, np.int64)
            lut[used] = np.arange(1, used.size + 1)
            z = lut[ids]
            n_z = int(used.size)
    rest = zcut_outliers & (z == 0)
    if rest.any():
        extra, n_extra = ndimage.label(rest, structure=EIGHT)
        z = np.where(extra > 0, extra + n_z, z)
        n_z += int(n_extra)
    s, n_s = ndimage.label(sor_outliers, structure=EIGHT)
    return _small_uint(z, n_z), n_z, _small_uint(s, int(n_s)), int(n_s)


def _cluster_stats(ids: np.ndarray, n: int, heights: np.ndarray, valid: np.ndarray, other: np.ndarray
                   ) -> dict[str, np.ndarray]:
    """Per-cluster numbers of an id image (ids 1..n): size, box, centroid, heights, gap, overlap."""
    H, W = ids.shape
    flat = ids.ravel()
    pix = np.flatnonzero(flat)
    lab = flat[pix].astype(np.int64)
    ys, xs = np.divmod(pix, W)
    hf = heights.ravel()
    cnt = np.bincount(lab, minlength=n + 1)[1:]
    safe = np.maximum(cnt, 1)
    big = np.iinfo(np.int64).max
    x0 = np.full(n + 1, big)
    y0 = np.full(n + 1, big)
    x1 = np.full(n + 1, -1)
    y1 = np.full(n + 1, -1)
    np.minimum.at(x0, lab, xs)
    np.minimum.at(y0, lab, ys)
    np.maximum.at(x1, lab, xs)
    np.maximum.at(y1, lab, ys)
    hv = hf[pix]
    h_min = np.full(n + 1, np.inf)
    h_max = np.full(n + 1, -np.inf)
    np.minimum.at(h_min, lab, hv)
    np.maximum.at(h_max, lab, hv)
    below = np.full(n + 1, -np.inf)
    vflat = valid.ravel()
    for dy in range(-RING_PX, RING_PX + 1):
        for dx in range(-RING_PX, RING_PX + 1):
            if dy == 0 and dx == 0:
                continue
            yy, xx = ys + dy, xs + dx
            ok = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
            f = yy[ok] * W + xx[ok]
            ll = lab[ok]
            keep = vflat[f] & (flat[f] != ll)
            np.maximum.at(below, ll[keep], hf[f[keep]])
    below = below[1:]
    below[~np.isfinite(below)] = np.nan
    h_min, h_max = h_min[1:], h_max[1:]
    return {
        "n": cnt, "x0": x0[1:], "y0": y0[1:], "x1": x1[1:] + 1, "y1": y1[1:] + 1,
        "cx": np.bincount(lab, weights=xs + 0.5, minlength=n + 1)[1:] / safe,
        "cy": np.bincount(lab, weights=ys + 0.5, minlength=n + 1)[1:] / safe,
        "h_min_mm": h_min, "h_max_mm": h_max, "below_mm": below, "gap_mm": h_min - below,
        "both": np.bincount(lab, weights=other.ravel()[pix], minlength=n + 1)[1:],
    }


def candidate_table(z_ids: np.ndarray, n_z: int, s_ids: np.ndarray, n_s: int, *, heights: np.ndarray,
                    valid: np.ndarray, z_levels: np.ndarray | None = None) -> np.ndarray:
    """The candidate table (:data:`CANDIDATE_COLUMNS`): every z-cut cluster, then the SOR clusters of at
    least :data:`SOR_LIST_MIN_PX` pixels (the :data:`SOR_LIST_MAX` largest), in id order.

    Parameters
    ----------
    z_ids, s_ids : (H, W) uint ndarray
        Cluster ids of the two filters (0 = none), from :func:`candidate_clusters`.
    n_z, n_s : int
        Number of clusters of each.
    heights : (H, W) float ndarray
        Heights in mm (larger = higher; NaN where invalid).
    valid : (H, W) bool ndarray
    z_levels : (n_z,) int ndarray, optional
        The z-cut level of each z-cut cluster (-1 where none).

    Returns
    -------
    (n, len(CANDIDATE_COLUMNS)) float32 ndarray
    """
    rows = []
    for src, ids, n, other, levels in ((SOURCE_ZCUT, z_ids, n_z, s_ids > 0, z_levels),
                                       (SOURCE_SOR, s_ids, n_s, z_ids > 0, None)):
        if n == 0:
            continue
        st = _cluster_stats(ids, n, heights, valid, other)
        keep = np.arange(n)
        if src == SOURCE_SOR:
            keep = keep[st["n"] >= SOR_LIST_MIN_PX]
            if keep.size > SOR_LIST_MAX:
                keep = np.sort(keep[np.argsort(-st["n"][keep], kind="stable")[:SOR_LIST_MAX]])
        lev = np.full(n, -1.0) if levels is None else np.asarray(levels, np.float64)
        cols = {"source": np.full(n, float(src)), "id": np.arange(1, n + 1, dtype=np.float64), "level": lev, **st}
        rows.append(np.stack([np.asarray(cols[c], np.float64)[keep] for c in CANDIDATE_COLUMNS], axis=1))
    if not rows:
        return np.zeros((0, len(CANDIDATE_COLUMNS)), np.float32)
    return np.concatenate(rows).astype(np.float32)


def _z_levels(z_ids: np.ndarray, n_z: int, cut: object) -> np.ndarray:
    """The z-cut level of each renumbered z-cut cluster (-1 for outliers outside the cut's clusters)."""
    out = np.full(n_z, -1, np.int64)
    clusters = getattr(cut, "clusters", None)
    levels = getattr(cut, "levels", None)
    if n_z == 0 or clusters is None or levels is None or clusters.shape != z_ids.shape:
        return out
    pix = np.flatnonzero(z_ids.ravel())
    orig = clusters.ravel()[pix].astype(np.int64)
    new = z_ids.ravel()[pix].astype(np.int64)
    ok = (orig > 0) & (orig <= len(levels))
    out[new[ok] - 1] = np.asarray(levels, np.int64)[orig[ok] - 1]
    return out


def prepare_frame(frame: Frame, result: FrameResult, *, suspect_params: SuspectParams | None = None, part: str | None = None,
                  focus: np.ndarray | None = None, fits: bool = False) -> PreparedFrame:
    """Build the page's view of a frame from the frame and the pipeline's result for it.

    Parameters
    ----------
    frame : replay.logs.frame.Frame
    result : replay.pipeline.stages.FrameResult
        Uses ``valid``, ``zone``, ``easy_outliers``, ``height_mm``, ``cut`` (clusters and levels),
        ``outliers`` (every method's) and ``warnings``.
    suspect_params : SuspectParams, optional
        The suspect detectors' parameters (default: ``SuspectParams()``; the catalogue passes the
        config's a_max).
    part : str, optional
        The part kind of the log's config (kept for the assistant).
    focus : (H, W) uint8 ndarray, optional
        The only pixels to list as review groups (``zcut annotate --disagreement``: where two filters
        disagree, :func:`annotate.groups.review_groups`); the header's ``focus`` is then true.
    fits : bool
        The page fits a part model to the frame (:func:`annotate.groups.review_groups`' ``fits``).

    Returns
    -------
    PreparedFrame
    """
    valid = np.asarray(result.valid, bool)
    zc = np.asarray(result.zcut_outliers, bool) & valid
    sc = np.asarray(result.sor_outliers, bool) & valid
    z_ids, n_z, s_ids, n_s = candidate_clusters(zc, result.cut.clusters, sc)
    heights = height_mm(frame.xyz)
    lo, hi = height_limits(heights, valid)
    table = candidate_table(z_ids, n_z, s_ids, n_s, heights=heights, valid=valid,
                            z_levels=_z_levels(z_ids, n_z, result.cut))
    src, n_px, both = table[:, COLUMN["source"]], table[:, COLUMN["n"]], table[:, COLUMN["both"]]
    counted = (src == SOURCE_ZCUT) | (n_px >= SOR_DEFAULT_MIN_PX)
    disagreement = int((counted & (2 * both < n_px)).sum())
    n_sor_listed = int(((src == SOURCE_SOR) & (n_px >= SOR_DEFAULT_MIN_PX)).sum())
    hbgr = height_colormap(frame.xyz, valid, limits=(lo, hi))
    rgb_jpeg = None if frame.rgb is None else _jpeg(cv2.cvtColor(rgb_picture(frame.rgb, valid), cv2.COLOR_RGB2BGR))
    H, W = valid.shape
    warnings = tuple(result.warnings)
    header = {"index": frame.index, "stamp_ns": frame.stamp_ns, "topic": frame.topic, "height": H, "width": W,
              "n_zcut": n_z, "n_sor": n_s, "n_sor_listed": n_sor_listed, "n_valid": int(valid.sum()),
              "disagreement": disagreement, "has_rgb": frame.rgb is not None, "warnings": list(warnings),
              "height_lo_mm": lo, "height_hi_mm": hi, "sor_default_min_px": SOR_DEFAULT_MIN_PX,
              "candidate_columns": list(CANDIDATE_COLUMNS)}
    sections = [("valid", mask_kind(valid), valid), ("zcut", "sparse", z_ids), ("sor", "sparse", s_ids),
                ("candidates", "table", table)]
    easy = np.asarray(result.easy_outliers, bool) & valid
    # the zone the labels are scored on (docs/accuracy.md): the pixels the filters judge plus the points
    # above the rim, which the pipeline reports as outliers itself (the removal's zone leaves them out)
    zone = (np.asarray(result.zone, bool) | easy) & valid
    if not np.array_equal(zone, valid):
        sections.append(("zone", mask_kind(zone), zone))
    groups = review_groups(frame.xyz, frame.rgb, height_mm=np.asarray(result.height_mm, np.float64), valid=valid,
                           zone=zone & valid, above_rim=easy,
                           outliers={k: np.asarray(v, bool) & valid for k, v in result.outliers.items()},
                           params=suspect_params if suspect_params is not None else SuspectParams(), focus=focus,
                           fits=fits)
    bin_stages = result.removal is not None
    header.update({
        "n_groups": groups.n, "group_columns": list(GROUP_COLUMNS), "group_sources": list(groups.sources),
        "methods": list(groups.methods), "detectors": list(DETECTORS), "noise_mm": groups.noise_mm,
        "threshold_mm": groups.threshold_mm, "n_suspect_px": groups.n_suspect_px, "bin_stages": bin_stages,
        "rise_step_mm": RISE_STEP_MM, "part": part, "focus": focus is not None,
    })
    rise_q = np.minimum(np.round(groups.rise_mm / RISE_STEP_MM), 255).astype(np.uint8)
    rise_q[groups.rise_mm < 0.5 * max(groups.threshold_mm, 0.0)] = 0
    sections += [("groups", "sparse", _small_uint(groups.ids, groups.n)), ("group_table", "table", groups.table),
                 ("rise", "sparse", rise_q)]
    bundle = make_bundle(header, sections, compress=False)
    pixels, starts = groups.pixels()
    served = ServedFrame(
        index=frame.index, stamp_ns=frame.stamp_ns, topic=frame.topic, frame_id=frame.frame_id, height=H, width=W,
        n_zcut=n_z, n_sor=n_s, n_sor_listed=n_sor_listed, n_valid=int(valid.sum()), disagreement=disagreement,
        rgb_jpeg=rgb_jpeg, height_jpeg=_jpeg(hbgr), bundle=bundle, warnings=warnings,
        cand_pixels=pixels, cand_starts=starts, n_groups=groups.n, group_features=groups.features, part=part,
        bin_stages=bin_stages,
    )
    return PreparedFrame(served=served, valid=valid, zcut_clusters=z_ids, sor_clusters=s_ids, candidates=table,
                         geometry=np.asarray(frame.xyz, np.float32))


def parse_bundle(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Decode a bundle back into (header, name -> array) — what the page does, in Python (for tests)."""
    (n,) = struct.unpack_from("<I", data, 0)
    header = json.loads(data[4:4 + n])
    body = data[4 + n:]
    shape = (header["height"], header["width"])
    out = {}
    for s in header["sections"]:
        raw = body[s["offset"]:s["offset"] + s["length"]]
        if s.get("zlib", True):
            raw = zlib.decompress(raw)
        if s["kind"] == "runs":
            out[s["name"]] = runs_to_mask(np.frombuffer(raw, "<u4"), shape)
        elif s["kind"] == "bits":
            bits = np.unpackbits(np.frombuffer(raw, np.uint8), count=shape[0] * shape[1])
            out[s["name"]] = bits.view(bool).reshape(shape)
        elif s["kind"] == "sparse":
            n = s["count"]
            idx = np.cumsum(np.frombuffer(raw, "<u4", count=n).astype(np.int64))
            a = np.zeros(shape[0] * shape[1], np.dtype(s["dtype"]))
            a[idx] = np.frombuffer(raw, np.dtype(s["dtype"]).newbyteorder("<"), count=n, offset=4 * n)
            out[s["name"]] = a.reshape(shape)
        elif s["kind"] == "table":
            out[s["name"]] = np.frombuffer(raw, "<f4").reshape(s["rows"], s["cols"])
        else:
            out[s["name"]] = np.frombuffer(raw, np.dtype(s["dtype"]).newbyteorder("<")).reshape(shape)
    return header, out
