"""Read organized PCL ``.pcd`` files (ascii, binary, binary_compressed) with pypcd4.

Accepted: PCD v0.5–0.7 headers with ``FIELDS`` containing ``x y z`` (``F`` 4 or 8 bytes, count 1)
and optionally ``rgb`` or ``rgba`` (``U``/``I`` 4 bytes, or ``F`` 4 bytes holding the packed
``0x00RRGGBB`` bits as PCL writes it); every other field (``label``, normals, …) is skipped.
``HEIGHT`` must be > 1 (an organized cloud, e.g. 480 × 640 from a Kinect). Invalid points are NaN
in PCL; (0, 0, 0) points are turned into NaN as well.

Division of work (see ``bench/bench_pcd_ply.py`` and the README's dependency table): pypcd4
parses the header's values and the data in all three encodings (its LZF decoder is liblzf, in
C). zcut checks the header first — organization, the x/y/z fields, the grid against
``max_pixels`` and the data against the bytes really in the file and ``max_message_bytes`` — so
pypcd4 never allocates more than the grid needs, and reads exactly the data section's bytes. Any
error becomes a one-line :class:`~replay.errors.LogFormatError` naming the file. Open3D's reader
was measured too and not used: it drops HEIGHT/WIDTH, reports errors only as printed warnings and
an empty cloud, and is slower.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replay.errors import LogFormatError
from replay.logs.files import DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PIXELS, check_caps, open_input

if TYPE_CHECKING:
    from pypcd4.pypcd4 import MetaData

_HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_MAX_HEADER = 64 * 1024
_KINDS = {"F": "f", "U": "u", "I": "i"}


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


def invalid_to_nan(xyz: np.ndarray) -> None:
    """Set points with a non-finite coordinate or exactly (0, 0, 0) to NaN, in place.

    Parameters
    ----------
    xyz : (H, W, 3) float32 ndarray
    """
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(xyz).all(axis=2) | (xyz == 0).all(axis=2)
    xyz[bad] = np.nan


def _header_lines(raw: bytes, name: str) -> tuple[list[str], int]:
    """The header's lines (comments dropped) up to DATA, and the offset of the data."""
    lines: list[str] = []
    seen: set[str] = set()
    pos = 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0:
            raise LogFormatError(f"{name}: PCD header has no DATA line in its first {len(raw)} bytes")
        try:
            line = raw[pos:nl].decode("ascii").strip()
        except UnicodeDecodeError:
            raise LogFormatError(f"{name}: not a PCD file (header line at byte {pos} is not text)") from None
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        key = line.split()[0].upper()
        if key not in _HEADER_KEYS:
            raise LogFormatError(f"{name}: not a PCD file (unexpected header line {line[:40]!r})")
        if key in seen:
            raise LogFormatError(f"{name}: PCD header has two {key} lines")
        seen.add(key)
        lines.append(line)
        if key == "DATA":
            return lines, pos


def read_pcd(
    path: str | os.PathLike[str], *, max_pixels: int = DEFAULT_MAX_PIXELS,
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> Cloud:
    """Read an organized PCD file.

    Parameters
    ----------
    path : str or Path
    max_pixels : int
        Largest grid (WIDTH x HEIGHT) accepted; default 2**24.
    max_message_bytes : int
        Largest data section (uncompressed) accepted; default 256 MiB.

    Returns
    -------
    Cloud
        ``xyz`` (H, W, 3) float32 (NaN invalid) and ``rgb`` (H, W, 3) uint8 or None.

    Raises
    ------
    LogFormatError
        Not a regular file, not a PCD, unorganized (HEIGHT 1), no x/y/z, unsupported layout, over a
        cap, truncated or corrupt data.
    """
    from pypcd4.pypcd4 import MetaData, PointCloud

    check_caps(max_pixels, max_message_bytes)
    path = Path(path)
    name = path.name
    f, size = open_input(path, "a PCD file")
    with f:
        lines, data_at = _header_lines(f.read(_MAX_HEADER), name)
        keys = {ln.split()[0].upper(): ln.split()[1:] for ln in lines}
        names = keys.get("FIELDS", [])
        data_kind = (keys["DATA"] or ["?"])[0].lower()
        if data_kind not in ("ascii", "binary", "binary_compressed"):
            raise LogFormatError(f"{name}: unknown PCD DATA '{data_kind}' (ascii, binary, binary_compressed)")
        lens = {k: len(keys.get(k, [])) for k in ("SIZE", "TYPE", "COUNT")}
        if "COUNT" not in keys:
            lines.insert(-1, "COUNT " + " ".join("1" for _ in names))
            lens["COUNT"] = len(names)
        if len(set(lens.values()) | {len(names)}) != 1:
            raise LogFormatError(
                f"{name}: PCD header lists {len(names)} FIELDS but {lens['SIZE']} SIZE, "
                f"{lens['TYPE']} TYPE, {lens['COUNT']} COUNT"
            )
        if "POINTS" not in keys:  # v0.5/0.6: WIDTH x HEIGHT
            try:
                lines.insert(-1, f"POINTS {int(keys['WIDTH'][0]) * int(keys.get('HEIGHT', ['1'])[0])}")
            except (KeyError, IndexError, ValueError):
                pass  # pydantic names what is missing
        lines = [ln for ln in lines if not ln.upper().startswith("VERSION")]  # pypcd4 knows 0.7 only
        try:
            meta = MetaData.parse_header(lines)
        except ValueError as e:  # pydantic's ValidationError is a ValueError
            first = str(e).splitlines()
            raise LogFormatError(f"{name}: malformed PCD header ({' '.join(first[:3])[:200]})") from None
        width, height, points = meta.width, meta.height, meta.points
        if width < 1 or points != width * height:
            raise LogFormatError(f"{name}: PCD WIDTH {width} x HEIGHT {height} != POINTS {points}")
        if height <= 1:
            raise LogFormatError(
                f"{name}: unorganized PCD (HEIGHT {height}, WIDTH {width}); zcut needs organized clouds "
                "(HEIGHT > 1)"
            )
        for n, s, t, c in zip(meta.fields, meta.size, meta.type, meta.count, strict=True):
            if s not in (1, 2, 4, 8) or (t == "F" and s < 4):
                raise LogFormatError(f"{name}: PCD field '{n}' has unsupported SIZE {s} TYPE {t} COUNT {c}")
        for axis in "xyz":
            if axis not in meta.fields:
                raise LogFormatError(f"{name}: PCD has no '{axis}' field (fields: {' '.join(names)})")
            i = meta.fields.index(axis)
            if meta.type[i] != "F" or meta.count[i] != 1:
                raise LogFormatError(f"{name}: PCD field '{axis}' must be F with COUNT 1")
        if points > max_pixels:
            raise LogFormatError(
                f"{name}: PCD grid {height}x{width} = {points} points is more than the cap of {max_pixels} "
                "(max_pixels; raise it with ZCUT_MAX_PIXELS)"
            )
        need = points * sum(s * c for s, c in zip(meta.size, meta.count, strict=True))
        body = size - data_at
        if need > max_message_bytes or (data_kind == "ascii" and body > 64 * max_message_bytes):
            raise LogFormatError(
                f"{name}: PCD data of {max(need, body)} bytes is more than the cap of {max_message_bytes} "
                "(max_message_bytes; raise it with ZCUT_MAX_MESSAGE_BYTES)"
            )
        if data_kind == "binary" and body < need:
            raise LogFormatError(f"{name}: PCD binary data has {body} bytes, needs {need} (truncated)")
        n_read = need if data_kind == "binary" else body
        if data_kind == "binary_compressed":
            f.seek(data_at)
            head = f.read(8)
            if len(head) < 8:
                raise LogFormatError(f"{name}: PCD binary_compressed data is truncated")
            csize, usize = struct.unpack("<II", head)
            if usize != need:
                raise LogFormatError(
                    f"{name}: PCD binary_compressed claims {usize} uncompressed bytes, fields need {need}"
                )
            if 8 + csize > body:
                raise LogFormatError(
                    f"{name}: PCD binary_compressed claims {csize} compressed bytes, file has {body - 8}"
                )
            n_read = 8 + csize
        f.seek(data_at)
        data = f.read(n_read)  # exactly the data section's bytes, behind the checked header
        try:
            arr = PointCloud.from_fileobj(io.BytesIO(("\n".join(lines) + "\n").encode() + data)).pc_data  # type: ignore[arg-type]  # pypcd4 reads any binary file object
        except (ValueError, TypeError, RuntimeError, struct.error, IndexError) as e:
            what = "LZF data is corrupt" if data_kind == "binary_compressed" else "data does not parse"
            raise LogFormatError(f"{name}: PCD {data_kind}: {what} ({str(e).splitlines()[0][:120]})") from None
    if arr.shape != (points,):
        raise LogFormatError(f"{name}: PCD {data_kind} data holds {arr.size} points, needs {points} (truncated)")
    return _to_cloud(arr, meta, height, width)


def _to_cloud(arr: np.ndarray, meta: MetaData, height: int, width: int) -> Cloud:
    arr = arr.reshape(height, width)
    cols = arr.dtype.names
    xyz = np.empty((height, width, 3), dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaN / huge doubles in the file
        for j, axis in enumerate("xyz"):
            xyz[..., j] = arr[cols[_column(meta, axis)]]  # type: ignore[index]  # a structured array has names
    invalid_to_nan(xyz)
    rgb = None
    for cname in ("rgba", "rgb"):
        if cname in meta.fields:
            i = meta.fields.index(cname)
            if meta.size[i] == 4 and meta.count[i] == 1:
                c = np.ascontiguousarray(arr[cols[_column(meta, cname)]]).view(np.uint32)  # type: ignore[index]  # a structured array has names
                rgb = np.empty((height, width, 3), dtype=np.uint8)
                rgb[..., 0] = (c >> 16) & 0xFF
                rgb[..., 1] = (c >> 8) & 0xFF
                rgb[..., 2] = c & 0xFF
            break
    return Cloud(xyz, rgb)


def _column(meta: MetaData, field: str) -> int:
    """Column of ``field`` in pypcd4's structured array (a COUNT n field takes n columns)."""
    i = meta.fields.index(field)
    return sum(meta.count[:i])
