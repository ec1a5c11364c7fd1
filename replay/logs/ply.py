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
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numba
import numpy as np

from replay.errors import LogFormatError
from replay.logs.pcd import Cloud, invalid_to_nan

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_MAX_HEADER = 64 * 1024


class _Element:
    def __init__(self, name: str, count: int) -> None:
        self.name = name
        self.count = count
        self.props: list[tuple[str, str, str | None, str | None]] = []  # name, type, list count t, list item t


def _header(raw: bytes, name: str) -> tuple[str, list[_Element], dict[str, int], int]:
    if not raw.startswith(b"ply"):
        raise LogFormatError(f"{name}: not a PLY file (no 'ply' magic)")
    end = raw.find(b"end_header", 0, _MAX_HEADER)
    if end < 0:
        raise LogFormatError(f"{name}: PLY header has no end_header")
    nl = raw.find(b"\n", end)
    if nl < 0:
        raise LogFormatError(f"{name}: PLY file ends after its header")
    text = raw[:end].decode("ascii", errors="replace")
    fmt = None
    elements: list[_Element] = []
    info: dict[str, int] = {}
    for line in text.splitlines()[1:]:
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        try:
            if key == "format":
                fmt = parts[1]
                if parts[2] != "1.0":
                    raise LogFormatError(f"{name}: PLY format version {parts[2]} (zcut reads 1.0)")
            elif key in ("comment", "obj_info"):
                m = re.match(r"\s*(?:comment|obj_info)\s+(num_rows|num_cols)\s+(\d+)", line)
                if m:
                    info[m.group(1)] = int(m.group(2))
            elif key == "element":
                elements.append(_Element(parts[1], int(parts[2])))
            elif key == "property":
                if not elements:
                    raise LogFormatError(f"{name}: PLY property before any element")
                if parts[1] == "list":
                    elements[-1].props.append((parts[4], "list", parts[2], parts[3]))
                else:
                    elements[-1].props.append((parts[2], parts[1], None, None))
        except (IndexError, ValueError) as e:
            raise LogFormatError(f"{name}: malformed PLY header line {line!r}") from e
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise LogFormatError(f"{name}: unknown PLY format {fmt!r}")
    return fmt, elements, info, nl + 1


@numba.njit(cache=True, inline="always")
def _uint_at(buf: np.ndarray, pos: int, size: int, big: bool) -> int:
    """Unsigned integer of ``size`` bytes at ``buf[pos]``, big- or little-endian."""
    v = 0
    for b in range(size):
        v = (v << 8) | np.int64(buf[pos + (b if big else size - 1 - b)])
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


def _ascii_table(lines: list[bytes], el: _Element, name: str) -> dict[str, np.ndarray]:
    """Columns of an ascii element with scalar properties, in their declared types."""
    try:
        table = np.array(b" ".join(lines).split()).astype(np.float64)
    except ValueError as e:
        raise LogFormatError(f"{name}: PLY ascii '{el.name}' data has a non-number ({e})") from e
    n = len(el.props)
    if table.size != len(lines) * n:
        raise LogFormatError(
            f"{name}: PLY ascii '{el.name}' data has {table.size} values, needs {len(lines) * n}"
        )
    table = table.reshape(len(lines), n)
    out = {}
    for i, p in enumerate(el.props):
        t = np.dtype(_TYPES[p[1]])
        col = table[:, i]
        if t.kind != "f":
            if not np.isfinite(col).all():
                raise LogFormatError(f"{name}: PLY ascii integer property '{p[0]}' has a non-number")
            col = col.astype(np.int64)
        out[p[0]] = col.astype(t)
    return out


def read_ply(path: str | os.PathLike, *, shape: tuple[int, int] | None = None) -> Cloud:
    """Read an organized PLY cloud (conventions in the module docstring).

    Parameters
    ----------
    path : str or Path
    shape : (H, W) or None
        Grid shape for files without organization info (vertex count must be H*W).

    Returns
    -------
    Cloud
        ``xyz`` (H, W, 3) float32 as stored, NaN invalid; ``rgb`` (H, W, 3) uint8 or None.
    """
    path = Path(path)
    name = path.name
    raw = path.read_bytes()
    fmt, elements, info, body_at = _header(raw, name)
    vi = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if vi is None:
        raise LogFormatError(f"{name}: PLY has no vertex element")
    if any(e.count for e in elements[:vi]):
        raise LogFormatError(f"{name}: PLY elements before 'vertex' are not supported")
    vert = elements[vi]
    if any(p[1] == "list" for p in vert.props):
        raise LogFormatError(f"{name}: PLY vertex element has a list property (not a point cloud)")
    pnames = [p[0] for p in vert.props]
    for axis in "xyz":
        if axis not in pnames:
            raise LogFormatError(f"{name}: PLY vertex has no '{axis}' property (has {' '.join(pnames)})")
    for p in vert.props:
        if p[1] not in _TYPES:
            raise LogFormatError(f"{name}: PLY property '{p[0]}' has unknown type {p[1]!r}")
    bo = ">" if fmt == "binary_big_endian" else "<"
    dt = np.dtype([(f"p{i}", bo + _TYPES[p[1]]) for i, p in enumerate(vert.props)])
    nv = vert.count
    body = memoryview(raw)[body_at:]
    # 1. the vertices
    if fmt == "ascii":
        lines = bytes(body).split(b"\n")
        if len(lines) < nv:
            raise LogFormatError(f"{name}: PLY ascii data has {len(lines)} lines, needs {nv} vertices")
        cols_of = _ascii_table(lines[:nv], vert, name)
        line_at = nv
    else:
        need = dt.itemsize * nv
        if len(body) < need:
            raise LogFormatError(f"{name}: PLY vertex data has {len(body)} bytes, needs {need} (truncated)")
        arr = np.frombuffer(body, dtype=dt, count=nv)
        cols_of = {p: arr[f"p{i}"] for i, p in enumerate(pnames)}
        byte_at = need
    # 2. the elements after them: scalar ones (PCL's 'camera') are read, then an optional range_grid
    camera: dict[str, float] = {}
    grid_el = None
    for el in elements[vi + 1 :]:
        if el.name == "range_grid":
            grid_el = el
            break
        if any(p[1] == "list" or p[1] not in _TYPES for p in el.props):
            break  # e.g. faces: nothing zcut needs comes after them
        if fmt == "ascii":
            if el.count:
                vals = _ascii_table(lines[line_at : line_at + el.count], el, name)
                if el.name == "camera":
                    camera = {k: float(v[0]) for k, v in vals.items()}
            line_at += el.count
        else:
            edt = np.dtype([(f"p{i}", bo + _TYPES[p[1]]) for i, p in enumerate(el.props)])
            if byte_at + edt.itemsize * el.count > len(body):
                raise LogFormatError(f"{name}: PLY element '{el.name}' is truncated")
            if el.name == "camera" and el.count:
                rec = np.frombuffer(body, dtype=edt, count=1, offset=byte_at)
                camera = {p[0]: float(rec[f"p{i}"][0]) for i, p in enumerate(el.props)}
            byte_at += edt.itemsize * el.count
    # 3. the grid shape
    rows, cols = info.get("num_rows"), info.get("num_cols")
    if rows is not None and cols is not None:
        gshape = (rows, cols)
    elif shape is not None:
        gshape = (int(shape[0]), int(shape[1]))
    elif camera.get("viewportx", 0) >= 1 and camera.get("viewporty", 0) >= 1:
        gshape = (int(camera["viewporty"]), int(camera["viewportx"]))
    else:
        raise LogFormatError(
            f"{name}: PLY with {nv} vertices has no organization info ('obj_info num_rows/num_cols' or "
            "a PCL camera element); pass the grid shape (zcut record --shape HxW)"
        )
    if gshape[0] <= 1 or gshape[1] < 1:
        raise LogFormatError(f"{name}: PLY grid {gshape[0]}x{gshape[1]} is not organized (need height > 1)")
    n_cells = gshape[0] * gshape[1]
    # 4. the range grid: cell -> vertex (PCL's organized writer leaves invalid cells empty)
    grid = None
    if grid_el is not None:
        lp = grid_el.props[0] if len(grid_el.props) == 1 else None
        if lp is None or lp[1] != "list" or lp[2] not in _TYPES or lp[3] not in _TYPES:
            raise LogFormatError(f"{name}: PLY range_grid must hold one list property")
        if grid_el.count != n_cells:
            raise LogFormatError(
                f"{name}: PLY range_grid has {grid_el.count} cells but the grid is {gshape[0]}x{gshape[1]}"
            )
        grid = np.full(n_cells, -1, dtype=np.int64)
        if fmt == "ascii":
            rest = lines[line_at : line_at + n_cells]
            if len(rest) < n_cells:
                raise LogFormatError(f"{name}: PLY range_grid has {len(rest)} lines, needs {n_cells}")
            try:
                for i, line in enumerate(rest):
                    t = line.split()
                    if t and int(t[0]) > 0:
                        grid[i] = int(t[1])
            except (ValueError, IndexError) as e:
                raise LogFormatError(f"{name}: PLY range_grid line {i} is malformed") from e
            if ((grid < -1) | (grid >= nv)).any():
                raise LogFormatError(f"{name}: PLY range_grid points outside the {nv} vertices")
        else:
            end = _grid_from_lists(
                np.frombuffer(body, dtype=np.uint8), byte_at, n_cells, np.dtype(_TYPES[lp[2]]).itemsize,
                np.dtype(_TYPES[lp[3]]).itemsize, bo == ">", nv, grid,
            )
            if end < 0:
                raise LogFormatError(f"{name}: PLY range_grid is truncated or points outside the vertices")
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
        xyz = np.full((n_cells, 3), np.nan, dtype=np.float32)
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
