"""Read organized PCL ``.pcd`` files (ascii, binary, binary_compressed).

Accepted: PCD v0.5–0.7 headers with ``FIELDS`` containing ``x y z`` (``F`` 4 or 8 bytes, count 1)
and optionally ``rgb`` or ``rgba`` (``U``/``I`` 4 bytes, or ``F`` 4 bytes holding the packed
``0x00RRGGBB`` bits as PCL writes it); every other field (``label``, normals, …) is skipped.
``HEIGHT`` must be > 1 (an organized cloud, e.g. 480 × 640 from a Kinect). Invalid points are NaN
in PCL; (0, 0, 0) points are turned into NaN as well.

``binary_compressed`` is PCL's layout: two little-endian uint32 (compressed, uncompressed size),
then LZF data that decompresses to the fields one after another (all x, then all y, …). The LZF
decoder is implemented here (numba) with bounds checks; corrupt data raises
:class:`~replay.errors.LogFormatError`.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from replay.errors import LogFormatError

_HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_MAX_HEADER = 64 * 1024


@dataclass(frozen=True, slots=True)
class Cloud:
    """An organized cloud read from a file.

    Attributes
    ----------
    xyz : (H, W, 3) float32 ndarray
        As stored (PCD: metres), NaN invalid.
    rgb : (H, W, 3) uint8 ndarray or None
    """

    xyz: np.ndarray
    rgb: np.ndarray | None


@numba.njit(cache=True, nogil=True)
def _lzf_decompress(src: np.ndarray, out: np.ndarray) -> int:
    """LZF-decompress ``src`` into ``out``; return bytes written, or -1 on corrupt input."""
    ip = 0
    op = 0
    n_in = src.shape[0]
    n_out = out.shape[0]
    while ip < n_in:
        ctrl = np.int64(src[ip])
        ip += 1
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            ln = ctrl + 1
            if ip + ln > n_in or op + ln > n_out:
                return -1
            for i in range(ln):
                out[op + i] = src[ip + i]
            ip += ln
            op += ln
        else:  # back reference
            ln = ctrl >> 5
            if ln == 7:
                if ip >= n_in:
                    return -1
                ln += np.int64(src[ip])
                ip += 1
            if ip >= n_in:
                return -1
            ref = op - ((ctrl & 0x1F) << 8) - np.int64(src[ip]) - 1
            ip += 1
            ln += 2
            if ref < 0 or op + ln > n_out:
                return -1
            for i in range(ln):  # byte by byte: the ranges may overlap
                out[op + i] = out[ref + i]
            op += ln
    return op


def lzf_decompress(data: bytes | memoryview, size: int) -> bytes:
    """Decompress LZF ``data`` that must expand to exactly ``size`` bytes.

    Raises
    ------
    LogFormatError
        On corrupt data or a size mismatch.
    """
    src = np.frombuffer(data, dtype=np.uint8)
    out = np.empty(size, dtype=np.uint8)
    n = _lzf_decompress(src, out)
    if n != size:
        raise LogFormatError(
            "LZF data is corrupt" if n < 0 else f"LZF data expands to {n} bytes, not {size}"
        )
    return out.tobytes()


def invalid_to_nan(xyz: np.ndarray) -> None:
    """Set points with a non-finite coordinate or exactly (0, 0, 0) to NaN, in place.

    Parameters
    ----------
    xyz : (H, W, 3) float32 ndarray
    """
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(xyz).all(axis=2) | (xyz == 0).all(axis=2)
    xyz[bad] = np.nan


def _parse_header(raw: bytes, name: str) -> tuple[dict[str, list[str]], int]:
    fields: dict[str, list[str]] = {}
    pos = 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0:
            raise LogFormatError(f"{name}: PCD header has no DATA line in its first {len(raw)} bytes")
        line = raw[pos:nl].decode("ascii", errors="replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        key = key.upper()
        if key not in _HEADER_KEYS:
            raise LogFormatError(f"{name}: not a PCD file (unexpected header line {line[:40]!r})")
        fields[key] = vals
        if key == "DATA":
            return fields, pos


def read_pcd(path: str | os.PathLike) -> Cloud:
    """Read an organized PCD file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Cloud
        ``xyz`` (H, W, 3) float32 (NaN invalid) and ``rgb`` (H, W, 3) uint8 or None.

    Raises
    ------
    LogFormatError
        Not a PCD, unorganized (HEIGHT 1), no x/y/z, unsupported layout, truncated or corrupt data.
    """
    path = Path(path)
    name = path.name
    raw = path.read_bytes()
    hdr, data_at = _parse_header(raw[:_MAX_HEADER], name)
    try:
        names = hdr["FIELDS"]
        sizes = [int(v) for v in hdr.get("SIZE", [])]
        types = [v.upper() for v in hdr.get("TYPE", [])]
        counts = [int(v) for v in hdr.get("COUNT", ["1"] * len(names))]
        width = int(hdr["WIDTH"][0])
        height = int(hdr.get("HEIGHT", ["1"])[0])
        points = int(hdr.get("POINTS", [str(width * height)])[0])
        data_kind = hdr["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as e:
        raise LogFormatError(f"{name}: malformed PCD header ({e!r})") from e
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise LogFormatError(
            f"{name}: PCD header lists {len(names)} FIELDS but {len(sizes)} SIZE, {len(types)} TYPE, "
            f"{len(counts)} COUNT"
        )
    if width < 1 or height < 0 or points != width * height:
        raise LogFormatError(f"{name}: PCD WIDTH {width} x HEIGHT {height} != POINTS {points}")
    if height <= 1:
        raise LogFormatError(
            f"{name}: unorganized PCD (HEIGHT {height}, WIDTH {width}); zcut needs organized clouds "
            "(HEIGHT > 1)"
        )
    kinds = {"F": "f", "U": "u", "I": "i"}
    formats = []
    for n, s, t, c in zip(names, sizes, types, counts, strict=True):
        if t not in kinds or s not in (1, 2, 4, 8) or c < 1 or (t == "F" and s < 4):
            raise LogFormatError(f"{name}: PCD field '{n}' has unsupported SIZE {s} TYPE {t} COUNT {c}")
        base = np.dtype(f"<{kinds[t]}{s}")
        formats.append(base if c == 1 else np.dtype((base, (c,))))
    for axis in "xyz":
        if axis not in names:
            raise LogFormatError(f"{name}: PCD has no '{axis}' field (fields: {' '.join(names)})")
        i = names.index(axis)
        if types[i] != "F" or counts[i] != 1:
            raise LogFormatError(f"{name}: PCD field '{axis}' must be F with COUNT 1")
    uniq = [f"{n}_{i}" for i, n in enumerate(names)]  # PCL allows repeated '_' padding fields
    rec = np.dtype({"names": uniq, "formats": formats})
    n_pts = width * height
    body = memoryview(raw)[data_at:]
    if data_kind == "ascii":
        arr = _read_ascii(bytes(body), rec, n_pts, name)
    elif data_kind == "binary":
        need = rec.itemsize * n_pts
        if len(body) < need:
            raise LogFormatError(f"{name}: PCD binary data has {len(body)} bytes, needs {need} (truncated)")
        arr = np.frombuffer(body, dtype=rec, count=n_pts)
    elif data_kind == "binary_compressed":
        if len(body) < 8:
            raise LogFormatError(f"{name}: PCD binary_compressed data is truncated")
        csize, usize = struct.unpack_from("<II", body, 0)
        need = rec.itemsize * n_pts
        if usize != need:
            raise LogFormatError(
                f"{name}: PCD binary_compressed claims {usize} uncompressed bytes, fields need {need}"
            )
        if 8 + csize > len(body):
            raise LogFormatError(
                f"{name}: PCD binary_compressed claims {csize} compressed bytes, file has {len(body) - 8}"
            )
        try:
            plain = lzf_decompress(body[8 : 8 + csize], usize)
        except LogFormatError as e:
            raise LogFormatError(f"{name}: PCD binary_compressed: {e}") from e
        arr = np.empty(n_pts, dtype=rec)
        off = 0
        for u, f in zip(uniq, formats, strict=True):
            k = f.itemsize * n_pts
            count = n_pts * (f.itemsize // f.base.itemsize)
            arr[u] = np.frombuffer(plain, dtype=f.base, count=count, offset=off).reshape(arr[u].shape)
            off += k
    else:
        raise LogFormatError(f"{name}: unknown PCD DATA '{data_kind}' (ascii, binary, binary_compressed)")
    arr = arr.reshape(height, width)
    xyz = np.empty((height, width, 3), dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaN / huge doubles in the file
        for j, axis in enumerate("xyz"):
            xyz[..., j] = arr[uniq[names.index(axis)]]
    invalid_to_nan(xyz)
    rgb = None
    for cname in ("rgba", "rgb"):
        if cname in names:
            i = names.index(cname)
            if sizes[i] == 4 and counts[i] == 1:
                c = np.ascontiguousarray(arr[uniq[i]]).view(np.uint32)
                rgb = np.empty((height, width, 3), dtype=np.uint8)
                rgb[..., 0] = (c >> 16) & 0xFF
                rgb[..., 1] = (c >> 8) & 0xFF
                rgb[..., 2] = c & 0xFF
            break
    return Cloud(xyz, rgb)


def _read_ascii(body: bytes, rec: np.dtype, n_pts: int, name: str) -> np.ndarray:
    tokens = body.split()
    per = sum(int(np.prod(rec[n].shape)) if rec[n].shape else 1 for n in rec.names)
    if len(tokens) < per * n_pts:
        raise LogFormatError(
            f"{name}: PCD ascii data has {len(tokens)} values, needs {per * n_pts} (truncated)"
        )
    try:
        table = np.array(tokens[: per * n_pts]).astype(np.float64).reshape(n_pts, per)
    except ValueError as e:
        raise LogFormatError(f"{name}: PCD ascii data has a value that is not a number ({e})") from e
    arr = np.empty(n_pts, dtype=rec)
    col = 0
    for n in rec.names:
        sub = rec[n]
        k = int(np.prod(sub.shape)) if sub.shape else 1
        vals = table[:, col : col + k]
        if sub.base.kind != "f":
            if not np.isfinite(vals).all():
                raise LogFormatError(f"{name}: PCD ascii integer field '{n.rsplit('_', 1)[0]}' has a non-number")
            vals = vals.astype(np.int64)
        arr[n] = vals.reshape(arr[n].shape).astype(sub.base)
        col += k
    return arr
