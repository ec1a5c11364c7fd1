"""Read organized point clouds stored as PLY.

PLY has no standard way to say "this is an H × W grid", so zcut accepts these conventions, in
this order, and fails with a one-line error naming the file otherwise:

1. ``obj_info num_rows H`` / ``obj_info num_cols W`` (or the same words after ``comment``), as PCL
   and Zivid write them for ordered clouds, with either
   - ``element vertex H*W`` (every grid cell has a vertex, invalid ones NaN or (0, 0, 0)), or
   - ``element range_grid H*W`` after the vertices with ``property list <uint> <int>
     vertex_indices`` (PCL's organized writer: a cell lists 0 or 1 vertex; empty cells are NaN).
2. an explicit ``shape=(H, W)`` from the caller (``zcut record --shape HxW``) when the file has
   ``element vertex H*W`` and no organization info (e.g. a Zivid or MATLAB export that kept every
   point in row-major order);
3. PCL's ``element camera`` (written by ``pcl::io::savePLYFile`` with its camera on): its
   ``viewportx`` / ``viewporty`` are W / H, again with every cell a vertex or a range_grid.

Elements after the vertices with scalar properties only (like ``camera``) are read or skipped;
reading stops at the first element with a list property other than ``range_grid``. MATLAB's
``pcwrite`` cannot be used: it drops NaN points from PLY files (save PCD from MATLAB instead).

Formats: ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` 1.0. The vertex element
must come first (elements before it must be empty); it needs ``x y z`` (float/double), and may
have ``red green blue`` (uchar) — every other scalar property is skipped. A vertex element with a
list property is refused. Coordinates are returned as stored (the caller chooses the unit).

Division of work (``bench/bench_pcd_ply.py``, README dependency table): plyfile parses the header
(elements, properties, comments, obj_info) and the ascii data; binary elements are read with
plyfile's dtypes straight from the file, only the bytes the grid needs. Kept here: the
organisation conventions above, the size checks (the grid against ``max_pixels``, every element
against the bytes in the file and ``max_message_bytes``, before anything is allocated) and the
binary ``range_grid`` reader (numba): plyfile reads variable-length lists one row at a time in
Python, ~20x slower on PCL's range_grid. Models (:func:`read_ply_model`, a log's bin model) in
binary are read element by element with ``np.frombuffer`` and plyfile's dtypes, faces as one
(M, k) array when every face has k vertices (7 ms for a 65k-point bin model; plyfile reads a file
held in memory row by row, 0.8-5 s); lists of varying length fall back to plyfile.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numba
import numpy as np

from replay.errors import LogFormatError
from replay.logs.files import DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PIXELS, check_caps, open_input
from replay.logs.pcd import Cloud, invalid_to_nan

if TYPE_CHECKING:
    from plyfile import PlyData, PlyElement

_MAX_HEADER = 64 * 1024
_ORG = re.compile(r"\s*(num_rows|num_cols)\s+(\d+)")


@numba.njit(cache=True, inline="always")
def _uint_at(buf: np.ndarray, pos: int, size: int, big: bool) -> int:
    """Unsigned integer of ``size`` bytes at ``buf[pos]``, big- or little-endian."""
    v = 0
    for b in range(size):
        v = (v << 8) | np.int64(buf[pos + (b if big else size - 1 - b)])  # type: ignore[assignment]  # numba kernel: an int64 local
    return v


@numba.njit(cache=True)
def _grid_from_lists(buf: np.ndarray, start: int, n_cells: int, cnt_size: int, idx_size: int,
                     big: bool, n_vertex: int, out: np.ndarray) -> int:
    """Parse binary range_grid lists; out[i] = vertex index or -1. Returns end offset or -1."""
    pos = start
    n = buf.shape[0]
    for i in range(n_cells):
        if pos + cnt_size > n:
            return -1
        c = _uint_at(buf, pos, cnt_size, big)
        pos += cnt_size
        out[i] = -1
        for j in range(c):
            if pos + idx_size > n:
                return -1
            v = _uint_at(buf, pos, idx_size, big)
            pos += idx_size
            if j == 0:
                if v < 0 or v >= n_vertex:
                    return -1
                out[i] = v
    return pos


def _header(f: BinaryIO, size: int, name: str) -> tuple[PlyData, int]:
    """plyfile's parse of the header (at most :data:`_MAX_HEADER` bytes), and the data offset."""
    from plyfile import PlyData, PlyParseError

    raw = f.read(_MAX_HEADER)
    if not raw.startswith(b"ply"):
        raise LogFormatError(f"{name}: not a PLY file (no 'ply' magic)")
    end = raw.find(b"end_header")
    nl = raw.find(b"\n", end) if end >= 0 else -1
    if nl < 0:
        raise LogFormatError(f"{name}: PLY header has no end_header in its first {len(raw)} bytes")
    m = re.search(rb"^format\s+(\S+)\s+(\S+)", raw[:end], re.M)
    if m and m.group(2) != b"1.0":
        raise LogFormatError(f"{name}: PLY format version {m.group(2).decode('ascii', 'replace')} (zcut reads 1.0)")
    try:
        ply = PlyData._parse_header(io.BytesIO(raw[: nl + 1]))
    except (PlyParseError, UnicodeDecodeError, ValueError) as e:
        raise LogFormatError(f"{name}: malformed PLY header ({str(e)[:120]})") from None
    return ply, nl + 1


def read_ply(
    path: str | os.PathLike[str], *, shape: tuple[int, int] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS, max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> Cloud:
    """Read an organized PLY cloud (conventions in the module docstring).

    Parameters
    ----------
    path : str or Path
    shape : (H, W) or None
        Grid shape for files without organization info (vertex count must be H*W).
    max_pixels : int
        Largest grid (and vertex count) accepted; default 2**24.
    max_message_bytes : int
        Largest data section read; default 256 MiB.

    Returns
    -------
    Cloud
        ``xyz`` (H, W, 3) float32 as stored, NaN invalid; ``rgb`` (H, W, 3) uint8 or None.

    Raises
    ------
    LogFormatError
        Not a regular file, not a PLY, no organization, a size over a cap or past the end of the
        file, malformed data; the message names the file.
    """
    check_caps(max_pixels, max_message_bytes)
    path = Path(path)
    name = path.name
    f, size = open_input(path, "a PLY file")
    with f:
        ply, body_at = _header(f, size, name)
        return _read(f, size, ply, body_at, name, shape, max_pixels, max_message_bytes)


def _read(f: BinaryIO, size: int, ply: PlyData, body_at: int, name: str, shape: tuple[int, int] | None,
          max_pixels: int, max_message_bytes: int) -> Cloud:
    from plyfile import PlyData, PlyListProperty, PlyParseError

    elements = list(ply.elements)
    for e in elements:
        if e.count < 0:
            raise LogFormatError(f"{name}: PLY element '{e.name}' has a negative count ({e.count})")
    vi = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if vi is None:
        raise LogFormatError(f"{name}: PLY has no vertex element")
    if any(e.count for e in elements[:vi]):
        raise LogFormatError(f"{name}: PLY elements before 'vertex' are not supported")
    vert = elements[vi]
    if any(isinstance(p, PlyListProperty) for p in vert.properties):
        raise LogFormatError(f"{name}: PLY vertex element has a list property (not a point cloud)")
    pnames = [p.name for p in vert.properties]
    for axis in "xyz":
        if axis not in pnames:
            raise LogFormatError(f"{name}: PLY vertex has no '{axis}' property (has {' '.join(pnames)})")
    nv = vert.count
    # the grid shape, before any data is read
    info: dict[str, int] = {}
    for line in [*ply.obj_info, *ply.comments]:
        m = _ORG.match(line)
        if m:
            info.setdefault(m.group(1), int(m.group(2)))
    rows, cols = info.get("num_rows"), info.get("num_cols")
    if nv > max_pixels:
        raise LogFormatError(f"{name}: PLY has {nv} vertices, more than the cap of {max_pixels} "
                             "(max_pixels; raise it with ZCUT_MAX_PIXELS)")
    rest = size - body_at
    if rest > max_message_bytes and ply.text:
        raise LogFormatError(
            f"{name}: PLY ascii data of {rest} bytes is more than the cap of {max_message_bytes} "
            "(max_message_bytes; raise it with ZCUT_MAX_MESSAGE_BYTES)"
        )
    later = []  # the scalar elements after the vertices, then an optional range_grid
    for el in elements[vi + 1 :]:
        if el.name == "range_grid" or any(isinstance(p, PlyListProperty) for p in el.properties):
            later.append(el)
            break  # nothing zcut needs comes after a list element other than range_grid
        later.append(el)
    grid_el = later[-1] if later and later[-1].name == "range_grid" else None
    need = 0  # bytes the elements take at least (ascii: two characters a value)
    for el in [vert, *later]:
        if el.count > max_pixels:
            raise LogFormatError(f"{name}: PLY element '{el.name}' has {el.count} items, more than the cap of {max_pixels}")
        per = 2 * len(el.properties) if ply.text else (0 if el is grid_el else el.dtype(ply.byte_order).itemsize)
        need += el.count * (per + (1 if el is grid_el else 0))
        if need > rest:
            raise LogFormatError(
                f"{name}: PLY {el.name} data has {rest} bytes after the header, needs {need} (truncated)"
            )
    camera: dict[str, float] = {}
    grid = None
    if ply.text:  # plyfile reads ascii data (bounded above by the file size)
        f.seek(0)
        try:
            with warnings.catch_warnings():  # plyfile reads an empty ascii list with np.loadtxt
                warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
                data = PlyData.read(io.BytesIO(f.read()))
        except (PlyParseError, ValueError, ArithmeticError, UnicodeDecodeError, LookupError, StopIteration) as e:
            raise LogFormatError(f"{name}: PLY ascii data does not parse ({str(e)[:120]})") from None
        cols_of = {p: data["vertex"].data[p] for p in pnames}
        if any(e.name == "camera" and e.count for e in later):
            camera = {k: float(data["camera"].data[k][0]) for k in data["camera"].data.dtype.names}
        gshape = _grid_shape(name, nv, rows, cols, shape, camera)
        if grid_el is not None:
            lists = data["range_grid"].data[grid_el.properties[0].name]
            grid = np.full(len(lists), -1, dtype=np.int64)
            for i, lst in enumerate(lists):
                if len(lst):
                    grid[i] = int(lst[0])
            if ((grid < -1) | (grid >= nv)).any():
                raise LogFormatError(f"{name}: PLY range_grid points outside the {nv} vertices")
    else:  # binary: plyfile's dtypes, only the bytes the grid needs
        bo = ply.byte_order
        dt = vert.dtype(bo)
        f.seek(body_at)
        arr = np.frombuffer(f.read(dt.itemsize * nv), dtype=dt, count=nv)
        cols_of = {p: arr[p] for p in pnames}
        byte_at = body_at + dt.itemsize * nv
        for el in later:
            if el is grid_el:
                break
            edt = el.dtype(bo)
            if el.name == "camera" and el.count:
                f.seek(byte_at)
                rec = np.frombuffer(f.read(edt.itemsize), dtype=edt, count=1)
                camera = {p: float(rec[p][0]) for p in edt.names}
            byte_at += edt.itemsize * el.count
        gshape = _grid_shape(name, nv, rows, cols, shape, camera)
        if grid_el is not None:
            lp = grid_el.properties[0]
            n_cells = gshape[0] * gshape[1]
            _check_grid_el(name, grid_el, gshape)
            cnt, idx = np.dtype(lp.len_dtype).itemsize, np.dtype(lp.val_dtype).itemsize
            f.seek(byte_at)
            buf = np.frombuffer(f.read(min(size - byte_at, n_cells * (cnt + idx))), dtype=np.uint8)
            grid = np.full(n_cells, -1, dtype=np.int64)
            end = _grid_from_lists(buf, 0, n_cells, cnt, idx, bo == ">", nv, grid)
            if end < 0:
                raise LogFormatError(f"{name}: PLY range_grid is truncated or points outside the vertices")
    if grid_el is not None:
        _check_grid_el(name, grid_el, gshape)
    n_cells = gshape[0] * gshape[1]
    if grid is None and nv != n_cells:
        raise LogFormatError(
            f"{name}: PLY has {nv} vertices but the grid is {gshape[0]}x{gshape[1]} = {n_cells} "
            "(an unorganized export dropped invalid points?)"
        )
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaN / huge doubles in the file
        xyz_v = np.stack([np.asarray(cols_of[a], dtype=np.float32) for a in "xyz"], axis=-1)
    rgb_v = None
    if all(c in cols_of for c in ("red", "green", "blue")):
        rgb_v = np.stack([np.asarray(cols_of[c]) for c in ("red", "green", "blue")], axis=-1)
        if rgb_v.dtype.kind == "f":  # float colours in [0, 1]
            with np.errstate(invalid="ignore", over="ignore"):
                rgb_v = np.clip(np.round(np.nan_to_num(rgb_v.astype(np.float64)) * 255.0), 0, 255)
        rgb_v = rgb_v.astype(np.uint8)
    if grid is not None:
        xyz: np.ndarray = np.full((n_cells, 3), np.nan, dtype=np.float32)
        have = grid >= 0
        xyz[have] = xyz_v[grid[have]]
        rgb = None
        if rgb_v is not None:
            rgb = np.zeros((n_cells, 3), dtype=np.uint8)
            rgb[have] = rgb_v[grid[have]]
    else:
        xyz, rgb = xyz_v, rgb_v
    xyz = xyz.reshape(gshape[0], gshape[1], 3)
    invalid_to_nan(xyz)
    if rgb is not None:
        rgb = np.ascontiguousarray(rgb.reshape(gshape[0], gshape[1], 3))
    return Cloud(np.ascontiguousarray(xyz), rgb)


def _check_grid_el(name: str, el: PlyElement, gshape: tuple[int, int]) -> None:
    from plyfile import PlyListProperty

    if len(el.properties) != 1 or not isinstance(el.properties[0], PlyListProperty):
        raise LogFormatError(f"{name}: PLY range_grid must hold one list property")
    if el.count != gshape[0] * gshape[1]:
        raise LogFormatError(
            f"{name}: PLY range_grid has {el.count} cells but the grid is {gshape[0]}x{gshape[1]}"
        )


def _grid_shape(name: str, nv: int, rows: int | None, cols: int | None, shape: tuple[int, int] | None,
                camera: dict[str, float]) -> tuple[int, int]:
    """(H, W) from obj_info/comment, the caller's shape, or PCL's camera viewport."""
    vx, vy = camera.get("viewportx", 0.0), camera.get("viewporty", 0.0)
    if rows is not None and cols is not None:
        gshape = (rows, cols)
    elif shape is not None:
        gshape = (int(shape[0]), int(shape[1]))
    elif np.isfinite(vx) and np.isfinite(vy) and 1 <= vx < 2**31 and 1 <= vy < 2**31:
        gshape = (int(vy), int(vx))
    else:
        raise LogFormatError(
            f"{name}: PLY with {nv} vertices has no organization info ('obj_info num_rows/num_cols' or "
            "a PCL camera element); pass the grid shape (zcut record --shape HxW)"
        )
    if gshape[0] <= 1 or gshape[1] < 1:
        raise LogFormatError(f"{name}: PLY grid {gshape[0]}x{gshape[1]} is not organized (need height > 1)")
    return gshape


# ------------------------------------------------------------------------------------------ models
@dataclass(frozen=True, slots=True)
class PlyModel:
    """A PLY point cloud or triangle mesh, e.g. a bin model (unorganized; metres as stored).

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        The vertices, all finite.
    normals : (N, 3) float64 ndarray or None
        From ``nx ny nz`` vertex properties.
    faces : (M, 3) int64 ndarray or None
        Triangles (polygons fan-triangulated), indices into ``points``; None without a face element.
    """

    points: np.ndarray
    normals: np.ndarray | None
    faces: np.ndarray | None


_FACE_LISTS = ("vertex_indices", "vertex_index")


def read_ply_model(
    path: str | os.PathLike[str], *, max_points: int = DEFAULT_MAX_PIXELS,
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> PlyModel:
    """Read a PLY point cloud or mesh (a bin model, a CAD part) with the size checks of :func:`read_ply`.

    Every element's count is checked against the bytes in the file and the caps before plyfile reads
    it (a header asking for 74 GB is a one-line error, not an allocation), the data is parsed by
    numpy (binary) or plyfile (ascii, faces of varying length), never by a C reader that trusts the
    header; face indices must lie within the vertices
    and coordinates must be finite.

    Parameters
    ----------
    path : str or Path
    max_points : int
        Largest vertex count (and face count) accepted; default 2**24.
    max_message_bytes : int
        Largest file accepted; default 256 MiB.

    Returns
    -------
    PlyModel

    Raises
    ------
    LogFormatError
        Not a regular file, not a PLY, no x/y/z, a count over a cap or past the end of the file,
        malformed data, face indices out of range, non-finite coordinates; the message names the file.
    """
    check_caps(max_points, max_message_bytes)
    path = Path(path)
    f, size = open_input(path, "a PLY file")
    with f:
        return _read_model(f, size, path.name, max_points, max_message_bytes)


def ply_model_bytes(points: np.ndarray, normals: np.ndarray | None = None) -> bytes:
    """A binary little-endian PLY point cloud of ``points`` (N, 3) and ``normals`` (N, 3), float32 (the
    form of a log's bin model attachment; :func:`read_ply_model_bytes` reads it back)."""
    from plyfile import PlyData, PlyElement

    pts = np.asarray(points, dtype=np.float32)
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    v = np.empty(len(pts), dtype=[(n, "<f4") for n in names])
    v["x"], v["y"], v["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float32)
        v["nx"], v["ny"], v["nz"] = nrm[:, 0], nrm[:, 1], nrm[:, 2]
    buf = io.BytesIO()
    PlyData([PlyElement.describe(v, "vertex")], text=False, byte_order="<").write(buf)
    return buf.getvalue()


def read_ply_model_bytes(
    data: bytes, *, name: str, max_points: int = DEFAULT_MAX_PIXELS, max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> PlyModel:
    """:func:`read_ply_model` of a PLY held in memory (e.g. a log's ``bin_model.ply`` attachment), with the
    same checks; ``name`` names it in the messages."""
    check_caps(max_points, max_message_bytes)
    return _read_model(io.BytesIO(data), len(data), name, max_points, max_message_bytes)


def _read_model(f: BinaryIO, size: int, name: str, max_points: int, max_message_bytes: int) -> PlyModel:
    from plyfile import PlyData, PlyListProperty, PlyParseError

    ply, body_at = _header(f, size, name)
    rest = size - body_at
    if size > max_message_bytes:
        raise LogFormatError(f"{name}: PLY file of {size} bytes is more than the cap of {max_message_bytes} "
                             "(max_message_bytes)")
    elements = {e.name: e for e in ply.elements}
    vert = elements.get("vertex")
    if vert is None:
        raise LogFormatError(f"{name}: PLY has no vertex element")
    need = 0
    for el in ply.elements:
        if el.count < 0:
            raise LogFormatError(f"{name}: PLY element '{el.name}' has a negative count ({el.count})")
        if el.count > max_points:
            raise LogFormatError(
                f"{name}: PLY element '{el.name}' has {el.count} items, more than the cap of {max_points}")
        if ply.text:  # at least one character and a separator a value
            per = 2 * len(el.properties)
        else:  # fixed-size properties, and at least the length field of a list
            per = sum(np.dtype(p.len_dtype if isinstance(p, PlyListProperty) else p.val_dtype).itemsize
                      for p in el.properties)
        need += el.count * per
        if need > rest:
            raise LogFormatError(
                f"{name}: PLY {el.name} data has {rest} bytes after the header, needs at least {need} (truncated)")
    pnames = [p.name for p in vert.properties]
    for axis in "xyz":
        if axis not in pnames:
            raise LogFormatError(f"{name}: PLY vertex has no '{axis}' property (has {' '.join(pnames)})")
    f.seek(0)
    raw = f.read()
    columns = None if ply.text else _binary_elements(ply, raw, body_at)
    if columns is None:  # ascii, or lists of varying length: plyfile (one row at a time)
        try:
            with warnings.catch_warnings():  # plyfile reads an empty ascii list with np.loadtxt
                warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
                data = PlyData.read(io.BytesIO(raw))
        except (PlyParseError, ValueError, ArithmeticError, UnicodeDecodeError, LookupError, StopIteration,
                TypeError, MemoryError) as e:
            raise LogFormatError(f"{name}: PLY data does not parse ({str(e)[:120]})") from None
        columns = {e.name: e.data for e in data.elements}
    v = columns["vertex"]
    for axis in "xyz":
        if v.dtype[axis].kind not in "fiu":
            raise LogFormatError(f"{name}: PLY vertex property '{axis}' is not a number")
    with np.errstate(invalid="ignore", over="ignore"):
        points = np.stack([np.asarray(v[a], dtype=np.float64) for a in "xyz"], axis=-1)
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise LogFormatError(f"{name}: PLY has {int(bad.sum())} vertices with a non-finite coordinate "
                             f"(the first is vertex {int(np.argmax(bad))})")
    normals = None
    if all(n in pnames for n in ("nx", "ny", "nz")):
        with np.errstate(invalid="ignore", over="ignore"):
            normals = np.stack([np.asarray(v[n], dtype=np.float64) for n in ("nx", "ny", "nz")], axis=-1)
        if not np.isfinite(normals).all():
            normals = None  # unusable normals are estimated again by the caller
    faces = None
    if "face" in elements and elements["face"].count:
        lists = next((p.name for p in elements["face"].properties
                      if isinstance(p, PlyListProperty) and p.name in _FACE_LISTS), None)
        if lists is None:
            raise LogFormatError(f"{name}: PLY face element has no vertex_indices list")
        n = len(points)
        polys = columns["face"][lists]
        if polys.dtype != object:  # (M, k): every face has k vertices (the binary reader's fast path)
            return PlyModel(points, normals, _fan(polys, n, name))
        tris = []
        for i, poly in enumerate(polys):
            poly = np.asarray(poly, dtype=np.int64)
            if len(poly) < 3:
                raise LogFormatError(f"{name}: PLY face {i} has {len(poly)} vertices (a face needs at least 3)")
            if poly.min() < 0 or poly.max() >= n:
                raise LogFormatError(f"{name}: PLY face {i} refers to a vertex outside the {n} vertices")
            tris.append(np.stack([np.full(len(poly) - 2, poly[0]), poly[1:-1], poly[2:]], axis=-1))
        faces = np.concatenate(tris).astype(np.int64)
    return PlyModel(points, normals, faces)


def _fan(polys: np.ndarray, n: int, name: str) -> np.ndarray:
    """Triangles of (M, k) polygons fanned from their first vertex (face-major, as the loop over
    plyfile's rows makes them), with the same checks and messages."""
    m, k = polys.shape
    if m and k < 3:
        raise LogFormatError(f"{name}: PLY face 0 has {k} vertices (a face needs at least 3)")
    polys = polys.astype(np.int64)
    bad = ((polys < 0) | (polys >= n)).any(axis=1)
    if bad.any():
        raise LogFormatError(f"{name}: PLY face {int(np.argmax(bad))} refers to a vertex outside the {n} vertices")
    tris = np.empty((m, k - 2, 3), dtype=np.int64)
    tris[:, :, 0] = polys[:, :1]
    tris[:, :, 1] = polys[:, 1:-1]
    tris[:, :, 2] = polys[:, 2:]
    return tris.reshape(-1, 3)


def _binary_elements(ply: PlyData, raw: bytes, body_at: int) -> dict[str, np.ndarray] | None:
    """Every element of a binary PLY as a structured array read with ``np.frombuffer`` (not plyfile's
    row-by-row read of a file held in memory: 4-5 s for a 65k-point bin model, here ~1 ms).

    A list property is read as a (count, k) field when every row's list has the length k of the
    first row's (triangle meshes); otherwise, or when the data are short, None: the caller reads the
    file with plyfile, which gives the same values (or its error)."""
    from plyfile import PlyListProperty

    bo = ply.byte_order
    out: dict[str, np.ndarray] = {}
    at = body_at
    for el in ply.elements:
        fields: list[tuple[str, str] | tuple[str, str, tuple[int]]] = []
        lens: list[str] = []
        pos = at  # where the first row's next property starts (for list lengths)
        for p in el.properties:
            if isinstance(p, PlyListProperty):
                ldt, vdt = np.dtype(bo + p.len_dtype), np.dtype(bo + p.val_dtype)
                if el.count == 0:
                    k = 0
                else:
                    if pos + ldt.itemsize > len(raw):
                        return None
                    k = int(np.frombuffer(raw, ldt, 1, pos)[0])
                    if k <= 0:
                        return None
                lens.append(f"len {len(lens)}")  # no PLY property name has a space
                fields += [(lens[-1], ldt), (p.name, vdt, (k,))]
                pos += ldt.itemsize + k * vdt.itemsize
            else:
                dt = np.dtype(bo + p.val_dtype)
                fields.append((p.name, dt))
                pos += dt.itemsize
        if lens and el.count == 0:
            return None  # plyfile gives an object column; keep its form
        dt = np.dtype(fields)
        if at + dt.itemsize * el.count > len(raw):
            return None
        arr = np.frombuffer(raw, dt, el.count, at)
        for ln, (_, _, (k,)) in zip(lens, (f for f in fields if len(f) == 3)):
            if (arr[ln] != k).any():
                return None
        out[el.name] = arr
        at += dt.itemsize * el.count
    return out
