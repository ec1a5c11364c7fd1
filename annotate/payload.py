"""What the labelling page shows of a frame, computed once per frame and cached in memory.

For each frame of the log the pipeline (``replay.pipeline.stages.run_frame``) proposes candidates; this
module turns a frame and its result into a :class:`PreparedFrame`: JPEGs of the RGB image and of a
height colour map, and one compact binary *bundle* with the valid mask and the candidate clusters
of the z-cut and of SOR, ready to send as is.

Bundle layout (little endian): ``uint32 n`` | ``n`` bytes of JSON header | sections. The header
lists the sections as ``{"name", "kind", "dtype", "offset", "length"}`` (offset from the first byte
after the header; ``"zlib": false`` when the section is stored without the zlib step written below). ``kind = "bits"``: ``zlib(packbits(mask.ravel()))`` (MSB first, as
:func:`annotate.store.pack_mask`); ``kind = "ids"``: ``zlib(array.ravel().tobytes())`` of an unsigned
integer array (``dtype`` ``uint8``, ``uint16`` or ``uint32``), 0 = no cluster; ``kind = "sparse"``:
the same array by its ``count`` non-zero pixels, ``zlib(deltas + values)`` where ``deltas`` are
the differences of the increasing flat pixel indices (first one from 0) as ``uint32`` and
``values`` the ids there in ``dtype`` (candidates cover a few per cent of a frame: this is
smaller and much faster to decode than the dense array); ``kind = "runs"``: a mask as
``zlib(uint32 run lengths)``, alternating runs of false and true pixels in raster order, the first
one (possibly empty) false — decoded with a few ``fill`` calls, so used for the valid mask whenever
its runs take no more bytes than its packed bits (:func:`mask_kind`).

A *view* (``GET /api/frames/{i}/view``) is everything the page needs to show a frame in one
response: ``uint32 n`` | ``n`` bytes of JSON ``{"parts": [[name, offset, length], ...]}`` | parts
(offset from the first byte after the header); the parts are the frame's bundle, the annotator's
label bundle and the JPEG of the requested image (:func:`make_view`, :func:`parse_view`).
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from annotate.store import pack_mask
from zcut.cloud import height_mm

EIGHT = np.ones((3, 3), bool)
JPEG_QUALITY = 90
INVALID_GRAY = 48


@dataclass(frozen=True, slots=True)
class ServedFrame:
    """What the server keeps of a frame: the encoded bytes and a few numbers (no dense arrays, so
    that a long log at 1920 x 1200 costs about a megabyte per frame)."""

    index: int
    stamp_ns: int
    topic: str
    frame_id: str
    height: int
    width: int
    n_zcut: int
    n_sor: int
    rgb_jpeg: bytes | None
    height_jpeg: bytes
    bundle: bytes
    warnings: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class PreparedFrame:
    """A frame as the page needs it.

    Attributes
    ----------
    index : int
    stamp_ns : int
    topic : str
    frame_id : str
    height, width : int
    valid : (H, W) bool ndarray
    zcut_clusters, sor_clusters : (H, W) uint ndarray
        Candidate cluster ids (0 = none).
    n_zcut, n_sor : int
        Number of candidate clusters.
    rgb_jpeg : bytes or None
        None when the log has no colour for the frame.
    height_jpeg : bytes
        Height colour map (turbo, 1st-99th percentile of the valid heights; invalid pixels grey).
    bundle : bytes
        See the module docstring.
    warnings : tuple of str
        The pipeline's warnings for the frame.
    """

    index: int
    stamp_ns: int
    topic: str
    frame_id: str
    height: int
    width: int
    valid: np.ndarray
    zcut_clusters: np.ndarray
    sor_clusters: np.ndarray
    n_zcut: int
    n_sor: int
    rgb_jpeg: bytes | None
    height_jpeg: bytes
    bundle: bytes
    warnings: tuple[str, ...]

    def served(self) -> ServedFrame:
        """The bytes and numbers the server keeps."""
        return ServedFrame(index=self.index, stamp_ns=self.stamp_ns, topic=self.topic, frame_id=self.frame_id,
                           height=self.height, width=self.width, n_zcut=self.n_zcut, n_sor=self.n_sor,
                           rgb_jpeg=self.rgb_jpeg, height_jpeg=self.height_jpeg, bundle=self.bundle,
                           warnings=self.warnings)


def _small_uint(ids: np.ndarray, n: int) -> np.ndarray:
    dtype = np.uint8 if n < 256 else np.uint16 if n < 65536 else np.uint32
    return ids.astype(dtype, copy=False)


def make_bundle(header: dict, sections: list[tuple[str, str, np.ndarray]], *, compress: bool = True) -> bytes:
    """Pack a header dict and ``(name, kind, array)`` sections into one bundle (module docstring).

    ``compress=False`` leaves out the zlib step of every section (marked ``"zlib": false``): the page
    then reads the sections in place, which beats inflating them when the bytes only cross the
    loopback interface.
    """
    parts: list[bytes] = []
    meta = []
    offset = 0
    for name, kind, arr in sections:
        extra: dict[str, int] = {}
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


def bundle_with_blobs(header: dict, blobs: list[tuple[str, bytes]]) -> bytes:
    """A bundle of already packed ``bits`` sections (label masks straight from the store)."""
    meta, offset = [], 0
    for name, blob in blobs:
        meta.append({"name": name, "kind": "bits", "dtype": "bool", "offset": offset, "length": len(blob)})
        offset += len(blob)
    head = json.dumps({**header, "sections": meta}).encode()
    return struct.pack("<I", len(head)) + head + b"".join(b for _, b in blobs)


def height_colormap(xyz: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR turbo colour map of the height ``-1000 z``; invalid pixels grey."""
    h = height_mm(xyz)
    out = np.full(valid.shape + (3,), INVALID_GRAY, np.uint8)
    if valid.any():
        v = h[valid]
        lo, hi = np.percentile(v, [1.0, 99.0])
        scale = 255.0 / max(hi - lo, 1e-9)
        g = np.clip((h - lo) * scale, 0, 255)
        g = np.where(valid, g, 0).astype(np.uint8)
        cm = cv2.applyColorMap(g, cv2.COLORMAP_TURBO)
        out[valid] = cm[valid]
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


def prepare_frame(frame, *, zcut_outliers: np.ndarray, sor_outliers: np.ndarray,
                  cut_clusters: np.ndarray | None, warnings: tuple[str, ...] = ()) -> PreparedFrame:
    """Build the page's view of a frame from the frame and the pipeline's masks.

    Parameters
    ----------
    frame : replay.logs.frame.Frame
    zcut_outliers, sor_outliers : (H, W) bool ndarray
        Candidates of the two filters.
    cut_clusters : (H, W) int ndarray or None
        The z-cut's cluster labels (``CutResult.clusters``).
    warnings : tuple of str
    """
    valid = np.isfinite(frame.xyz).all(axis=2)
    zc = np.asarray(zcut_outliers, bool) & valid
    sc = np.asarray(sor_outliers, bool) & valid
    z_ids, n_z, s_ids, n_s = candidate_clusters(zc, cut_clusters, sc)
    hbgr = height_colormap(frame.xyz, valid)
    rgb_jpeg = None if frame.rgb is None else _jpeg(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
    H, W = valid.shape
    header = {"index": frame.index, "stamp_ns": frame.stamp_ns, "topic": frame.topic, "height": H, "width": W,
              "n_zcut": n_z, "n_sor": n_s, "has_rgb": frame.rgb is not None, "warnings": list(warnings)}
    bundle = make_bundle(header, [("valid", mask_kind(valid), valid), ("zcut", "sparse", z_ids), ("sor", "sparse", s_ids)],
                         compress=False)
    return PreparedFrame(
        index=frame.index, stamp_ns=frame.stamp_ns, topic=frame.topic, frame_id=frame.frame_id, height=H, width=W,
        valid=valid, zcut_clusters=z_ids, sor_clusters=s_ids, n_zcut=n_z, n_sor=n_s, rgb_jpeg=rgb_jpeg,
        height_jpeg=_jpeg(hbgr), bundle=bundle, warnings=tuple(warnings),
    )


def parse_bundle(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
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
            lengths = np.frombuffer(raw, "<u4").astype(np.int64)
            if int(lengths.sum()) != shape[0] * shape[1]:
                raise ValueError(f"bundle section {s['name']!r}: runs cover {int(lengths.sum())} pixels, not {shape}")
            flat = np.repeat(np.arange(lengths.size) % 2 == 1, lengths)
            out[s["name"]] = flat.reshape(shape)
        elif s["kind"] == "bits":
            out[s["name"]] = np.unpackbits(np.frombuffer(raw, np.uint8), count=shape[0] * shape[1]).view(bool).reshape(shape)
        elif s["kind"] == "sparse":
            n = s["count"]
            idx = np.cumsum(np.frombuffer(raw, "<u4", count=n).astype(np.int64))
            a = np.zeros(shape[0] * shape[1], np.dtype(s["dtype"]))
            a[idx] = np.frombuffer(raw, np.dtype(s["dtype"]).newbyteorder("<"), count=n, offset=4 * n)
            out[s["name"]] = a.reshape(shape)
        else:
            out[s["name"]] = np.frombuffer(raw, np.dtype(s["dtype"]).newbyteorder("<")).reshape(shape)
    return header, out
