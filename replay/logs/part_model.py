"""The part's mesh a log carries: the MCAP attachment ``part_model.ply`` (docs/formats.md, "Part model attachment").

A binary little-endian PLY triangle mesh (float64 vertices, ``vertex_indices`` faces) in the part's
own frame, its unit — ``mm`` or ``m`` — stated in a header comment ``unit: mm`` (or ``unit: m``).
Both synthetic generators attach the part they drop (``zcut synth``); ``zcut record --part-model
FILE`` attaches one read from a PLY, STL or OBJ file (:func:`load_part_mesh`). Read back with
:func:`read_part_model` (a log) or :func:`read_part_model_bytes` (the attachment's bytes), which
reuse the bin model's checked PLY reader (:func:`replay.logs.ply.read_ply_model_bytes`).
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replay.errors import LogFormatError
from replay.logs import layout
from zcut.errors import ParameterError

if TYPE_CHECKING:
    from replay.logs.reader import LogReader

PART_MODEL_ATTACHMENT = "part_model.ply"
PART_MODEL_MEDIA_TYPE = layout.BIN_MODEL_MEDIA_TYPE  # application/x-ply
#: the units a part model may be stated in, and their size in metres
UNITS = {"mm": 1e-3, "m": 1.0}
_UNIT_COMMENT = re.compile(rb"^comment\b.*\bunit:\s*(mm|m)\b", re.MULTILINE)


def carries_part_model(reader: LogReader) -> bool:
    """Whether the log ``reader`` reads carries a part model (a :data:`PART_MODEL_ATTACHMENT` attachment; its
    attachment index only, no mesh read)."""
    return any(name == PART_MODEL_ATTACHMENT for name, _, _ in reader.attachments())


@dataclass(frozen=True, slots=True)
class PartModel:
    """A part's mesh.

    Attributes
    ----------
    vertices : (n, 3) float64 ndarray
        In ``unit``, the part's own frame.
    triangles : (m, 3) int64 ndarray
    unit : str
        ``mm`` or ``m``.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    unit: str

    @property
    def vertices_m(self) -> np.ndarray:
        """The vertices in metres."""
        return self.vertices * UNITS[self.unit]


def part_model_ply_bytes(vertices: np.ndarray, triangles: np.ndarray, *, unit: str, comment: str = "") -> bytes:
    """The PLY bytes of a ``part_model.ply`` attachment: float64 vertices, int32 triangles, the unit
    in a header comment (``unit: mm``), ``comment`` (one line) in another."""
    from plyfile import PlyData, PlyElement

    if unit not in UNITS:
        raise ParameterError(f"a part model's unit must be mm or m, got {unit!r}")
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    vert = np.empty(len(v), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vert["x"], vert["y"], vert["z"] = v.T
    face = np.empty(len(t), dtype=[("vertex_indices", "<i4", (3,))])
    face["vertex_indices"] = t
    comments = [f"zcut part model, unit: {unit}"] + ([comment.replace("\n", " ")] if comment else [])
    buf = io.BytesIO()
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")], text=False, byte_order="<",
            comments=comments).write(buf)
    return buf.getvalue()


def read_part_model_bytes(data: bytes, *, name: str = PART_MODEL_ATTACHMENT) -> PartModel:
    """The :class:`PartModel` of a ``part_model.ply`` attachment's bytes (``name`` names it in errors).

    Raises
    ------
    LogFormatError
        Not a PLY mesh (the checks of :func:`~replay.logs.ply.read_ply_model_bytes`), no faces, or no
        ``unit: mm`` / ``unit: m`` header comment.
    """
    from replay.logs.ply import read_ply_model_bytes

    model = read_ply_model_bytes(data, name=name)
    if model.faces is None or len(model.faces) == 0:
        raise LogFormatError(f"{name}: a part model must be a triangle mesh; this PLY has no faces")
    end = data.find(b"end_header")
    unit = _UNIT_COMMENT.search(data[: end if end >= 0 else 0])
    if unit is None:
        raise LogFormatError(f"{name}: a part model states its unit in a header comment 'unit: mm' or 'unit: m'; "
                             "this one does not")
    return PartModel(np.asarray(model.points, np.float64), np.asarray(model.faces, np.int64), unit.group(1).decode())


def read_part_model(path: str | os.PathLike[str]) -> PartModel | None:
    """The part model a log carries (its last ``part_model.ply`` attachment), None when it has none.

    Raises
    ------
    LogFormatError
        The attachment is damaged or not a part model (:func:`read_part_model_bytes`).
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = Path(path)
    found = None
    try:
        with open(path, "rb") as f:
            for att in make_reader(f).iter_attachments():
                if att.name == PART_MODEL_ATTACHMENT:
                    found = att.data
    except (McapError, ValueError, EOFError) as e:
        raise LogFormatError(f"{path.name}: cannot read its attachments ({e})") from None
    if found is None:
        return None
    return read_part_model_bytes(bytes(found), name=f"{path.name}: attachment {PART_MODEL_ATTACHMENT}")


def load_part_mesh(path: str | os.PathLike[str], *, unit: str) -> bytes:
    """A PLY, STL or OBJ mesh file as the bytes of a ``part_model.ply`` attachment in ``unit``.

    Read with Open3D's ``read_triangle_mesh``; its vertices are kept as they are, in the unit the
    caller states (``mm`` or ``m``).

    Raises
    ------
    ParameterError
        An unknown unit, a file that is not a mesh Open3D reads, a mesh without triangles, with
        non-finite vertices or with triangles that index missing vertices; one line naming the file.
    """
    path = Path(path)
    if unit not in UNITS:
        raise ParameterError(f"--part-model-unit must be mm or m, got {unit!r}")
    if path.suffix.lower() not in (".ply", ".stl", ".obj"):
        raise ParameterError(f"{path}: a part model must be a .ply, .stl or .obj mesh")
    if not path.is_file():
        raise ParameterError(f"{path}: no such part model file")
    import open3d as o3d

    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            mesh = o3d.io.read_triangle_mesh(str(path))  # type: ignore[arg-type]  # Open3D's stub: it takes a str too
    except Exception as e:  # noqa: BLE001 - whatever the C++ reader raised, it is a bad mesh
        raise ParameterError(f"{path}: not a readable mesh ({e})") from None
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int64)
    if len(t) == 0 or len(v) == 0:
        raise ParameterError(f"{path}: not a triangle mesh (no triangles read)")
    if not np.isfinite(v).all():
        raise ParameterError(f"{path}: the mesh has non-finite vertices")
    if t.min() < 0 or t.max() >= len(v):
        raise ParameterError(f"{path}: the mesh has triangles that index missing vertices")
    return part_model_ply_bytes(v, t, unit=unit, comment=f"from {path.name}")
