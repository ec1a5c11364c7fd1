"""Build, save and load the bin model (paper §5.1), and choose the one a log is replayed with.

Each empty-bin scan is masked from its RGB image (:func:`zcut.binmask.bin_mask`); the valid 3D
points of the mask are ICP-registered into the first scan's frame; the union is voxel-downsampled,
given normals (oriented towards the camera) and saved as a PLY point cloud. A CAD model given as a
PLY mesh or cloud may be used instead (:func:`load_bin_model`); its frame must be camera-like: up is
-z (what a top-down camera's optical frame gives), metres.

A log may carry its bin model as an MCAP attachment (``docs/formats.md``, "Bin model attachment").
:func:`bin_model_for` is the one place that decides which model a command replays a log with: the
``--bin-model`` given, else the log's own attachment, else none (with one warning that names the log
and says what to do).

Loading a model costs more than reading its file: a mesh is sampled and given normals (~4.5 CPU-s
for the synthetic bin's CAD mesh), a cloud's spacing is measured (0.3 s for 365k points), and the
structures of registration and removal are built (:func:`zcut.prepared_model.prepare_bin_model`,
~0.8 s for 365k points). Both results are kept in a cache folder (:func:`model_cache_folder`: files
keyed by the SHA-256 of the model's content, the parameters and the source of the code that makes
them, so an edited model, other parameters or changed code never reuse a stale entry), and read back
bit for bit in ~0.05 s (:func:`bin_model_from_ply`, :func:`prepared_bin_model`). A cache that cannot
be written (read-only, full disk) is skipped; the newest :data:`CACHE_ENTRIES` files are kept.
"""

from __future__ import annotations

import functools
import hashlib
import os
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replay.errors import LogFormatError
from replay.logs.frame import Frame
from zcut.bin_model import BinModel
from zcut.binmask import bin_mask
from zcut.errors import InputShapeError
from zcut.params import BinMaskParams, RegistrationParams, RemovalParams
from zcut.prepared_model import PreparedBinModel, prepare_bin_model, prepared_arrays, prepared_from_arrays
from zcut.registration import RegistrationResult, prepare_icp_model, prepare_target, register_bin, voxel_down

if TYPE_CHECKING:
    import open3d as o3d

    from replay.logs.ply import PlyModel
    from replay.logs.reader import LogReader


@dataclass(frozen=True, slots=True)
class ScanReport:
    """How one empty scan went into the model."""

    index: int
    n_points: int
    registration: RegistrationResult | None  # None for the first scan (the reference) or a skipped one
    skipped: str  # why the scan was left out, else ""


def _with_normals(points: np.ndarray, voxel_m: float, what: str) -> o3d.geometry.PointCloud:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    if voxel_m > 0:
        pc = voxel_down(pc, voxel_m, what)
    radius = max(3.0 * voxel_m, 0.003)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return pc


def model_from_points(points: np.ndarray, *, voxel_mm: float = 1.0, what: str = "the bin model") -> BinModel:
    """Downsample (N, 3) metre points and estimate normals: a :class:`BinModel`."""
    pc = _with_normals(points, voxel_mm / 1000.0, what)
    return BinModel(np.asarray(pc.points, dtype=np.float64).copy(),
                    np.asarray(pc.normals, dtype=np.float64).copy(), max(voxel_mm / 1000.0, 1e-4))


def build_bin_model(
    frames: Iterable[Frame],
    *,
    bin_mask_params: BinMaskParams | None = None,
    registration: RegistrationParams | None = None,
    voxel_mm: float = 1.0,
) -> tuple[BinModel, list[ScanReport]]:
    """Build a bin model from empty-bin scans.

    Parameters
    ----------
    frames : iterable of Frame
        Empty-bin scans with RGB images.
    bin_mask_params, registration : optional
        How each scan's bin is masked and registered to the first (default: the defaults).
    voxel_mm : float
        Downsampling voxel of the model.

    Returns
    -------
    (BinModel, list of ScanReport)
        Raises :class:`LogFormatError` when no scan gave bin points.
    """
    c = bin_mask_params or BinMaskParams()
    r = registration or RegistrationParams()
    parts: list[np.ndarray] = []
    reports: list[ScanReport] = []
    reference = None
    for frame in frames:
        if frame.rgb is None:
            reports.append(ScanReport(frame.index, 0, None, "no RGB image"))
            continue
        bm = bin_mask(frame.rgb, params=c)
        valid = np.isfinite(frame.xyz).all(axis=2)
        pts = frame.xyz[bm.mask & valid].astype(np.float64)
        if not bm.found or len(pts) == 0:
            reports.append(ScanReport(frame.index, 0, None, "no bin found in the RGB image"))
            continue
        if reference is None:
            reference = prepare_target(pts, voxel_m=r.voxel_m, intrinsics=frame.intrinsics)
            parts.append(pts)
            reports.append(ScanReport(frame.index, len(pts), None, ""))
            continue
        # register this scan (as the "model") into the reference frame (as the "target")
        scan = prepare_icp_model(BinModel(pts, None, max(r.voxel_m, 1e-4)), r)
        reg = register_bin(scan, reference)
        if not reg.converged:
            reports.append(ScanReport(frame.index, len(pts), reg, f"registration failed: {reg.reason}"))
            continue
        parts.append(pts @ reg.T_cam_bin[:3, :3].T + reg.T_cam_bin[:3, 3])
        reports.append(ScanReport(frame.index, len(pts), reg, ""))
    if not parts:
        raise LogFormatError("no empty-bin scan gave bin points (need RGB images showing the bin)")
    return model_from_points(np.concatenate(parts), voxel_mm=voxel_mm, what="the bin points of the empty scans"), reports


def save_bin_model(model: BinModel, path: str | Path) -> None:
    """Write the model as a PLY point cloud with normals."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model.points))
    if model.normals is not None:
        pc.normals = o3d.utility.Vector3dVector(model.normals)
    import errno
    import shutil

    need = 1024 + len(model.points) * 8 * (6 if model.normals is not None else 3)  # float64 x y z (nx ny nz)
    free = shutil.disk_usage(Path(path).resolve().parent).free
    if free < need:  # Open3D's writer would print a line per failed block and report success
        raise OSError(errno.ENOSPC, f"no space left on the device ({free} bytes free, the bin model needs "
                                    f"about {need})", str(path))
    if not o3d.io.write_point_cloud(str(path), pc, write_ascii=False):  # type: ignore[arg-type]  # Open3D's stub: it takes a str too
        raise LogFormatError(f"{path}: could not write the bin model")
    _check_complete_ply(path)


#: bytes of each PLY property type
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_complete_ply(path: str | Path) -> None:
    """Raise OSError (ENOSPC) when the binary PLY Open3D wrote at ``path`` is shorter than its header
    says: Open3D reports success on a full disk, leaving a truncated file."""
    import errno
    import os

    with open(path, "rb") as f:
        head = f.read(4096)
    end = head.find(b"end_header\n")
    n = size = 0
    if end >= 0:
        for line in head[:end].decode("ascii", "replace").splitlines():
            parts = line.split()
            if parts[:2] == ["element", "vertex"]:
                n = int(parts[2])
            elif parts[:1] == ["property"] and len(parts) == 3:
                size += _PLY_SIZES.get(parts[1], 0)
    want = end + len(b"end_header\n") + n * size
    got = os.path.getsize(path)
    if end < 0 or got < want:
        raise OSError(errno.ENOSPC, f"no space left on the device: the bin model was cut short ({got} of "
                                    f"{want if end >= 0 else 'more'} bytes written)", str(path))


def _median_spacing(pts: np.ndarray, *, sample: int = 4096) -> float:
    """Median distance of a point to its nearest neighbour, from a fixed sample of the points (the
    whole cloud's query costs ~1 s for a 200k-point model, every time a worker loads it)."""
    from scipy.spatial import cKDTree

    idx = np.linspace(0, len(pts) - 1, min(sample, len(pts))).astype(np.int64)
    d, _ = cKDTree(pts).query(pts[idx], k=2)
    return float(np.median(d[:, 1]))


def load_bin_model(path: str | Path, *, voxel_mm: float = 1.0) -> BinModel:
    """Read a bin model PLY: a point cloud (as saved here) or a mesh (a CAD model, sampled).

    Points are metres in a frame whose up is -z. Normals are estimated when the file has none.
    The file is read by :func:`replay.logs.ply.read_ply_model` (counts checked against the bytes
    present and the caps, coordinates finite).
    """
    from replay.logs.ply import read_ply_model

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(2, "No such file", str(p))
    return bin_model_from_ply(read_ply_model(p), what=str(p), voxel_mm=voxel_mm)


def bin_model_from_ply(ply: PlyModel, *, what: str, voxel_mm: float = 1.0) -> BinModel:
    """The :class:`BinModel` of a PLY read by :func:`replay.logs.ply.read_ply_model` (a cloud with or
    without normals, or a mesh, sampled); ``what`` names it in errors (:class:`LogFormatError`)."""
    if len(ply.points) == 0:
        raise LogFormatError(f"{what}: no points in the bin model (expected a PLY point cloud or mesh)")
    key = _cache_key("model", ply.points, ply.normals, ply.faces, repr(float(voxel_mm)))
    cached = _cache_read(key)
    if cached is not None:
        try:
            return BinModel(cached["points"], cached.get("normals"), float(cached["spacing"][0]))
        except (KeyError, IndexError, ValueError, InputShapeError):  # not what this code writes: made again
            pass
    try:
        model = _model_of(ply, voxel_mm)
    except InputShapeError as e:  # coordinates no voxel grid can hold
        raise LogFormatError(f"{what}: {e}") from None
    arrays = {"points": model.points, "spacing": np.array([model.spacing_m])}
    if model.normals is not None:
        arrays["normals"] = np.asarray(model.normals)
    _cache_write(key, arrays)
    return model


def prepared_bin_model(model: BinModel, *, registration: RegistrationParams,
                       removal: RemovalParams) -> PreparedBinModel:
    """:func:`zcut.prepared_model.prepare_bin_model`, kept in the cache folder by the model's content
    and the parameters (read back bit for bit by :func:`zcut.prepared_model.prepared_from_arrays`)."""
    key = _cache_key("prepared", model.points, model.normals, repr(float(model.spacing_m)), repr(registration),
                     repr(removal))
    cached = _cache_read(key)
    if cached is not None:
        try:
            return prepared_from_arrays(cached, registration=registration, removal=removal)
        except (KeyError, IndexError, ValueError, TypeError, InputShapeError):  # not what this code writes
            pass
    prepared = prepare_bin_model(model, registration=registration, removal=removal)
    arrays = prepared_arrays(prepared)
    if arrays is not None:
        _cache_write(key, arrays)
    return prepared


#: how many files the cache folder keeps (the newest used; a 365k-point model's two files take ~90 MB)
CACHE_ENTRIES = 8


def model_cache_folder() -> Path:
    """Where loaded and prepared bin models are kept: ``$ZCUT_CACHE/bin_models`` (else
    ``$XDG_CACHE_HOME/zcut`` or ``~/.cache/zcut``, the demo sample's folder)."""
    root = os.environ.get("ZCUT_CACHE")
    base = Path(root) if root else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "zcut"
    return base / "bin_models"


@functools.lru_cache(maxsize=1)
def _code_digest() -> bytes:
    """The source of every module that makes a cached result, and the libraries' versions."""
    import importlib
    import sys

    import scipy

    h = hashlib.sha256(f"{sys.version}|{np.__version__}|{scipy.__version__}".encode())
    for name in ("zcut.bin_model", "zcut.prepared_model", "zcut.registration", "zcut.removal",
                 "replay.pipeline.bin_model"):
        path = importlib.import_module(name).__file__
        assert path is not None  # a source module
        h.update(Path(path).read_bytes())
    from importlib.metadata import PackageNotFoundError, version

    try:
        h.update(version("open3d").encode())
    except PackageNotFoundError:  # pragma: no cover - a source build without metadata
        h.update(b"open3d ?")
    return h.digest()


def _cache_key(kind: str, *parts: np.ndarray | str | None) -> str:
    h = hashlib.sha256(_code_digest() + kind.encode())
    for p in parts:
        if p is None:
            h.update(b"|none")
        elif isinstance(p, str):
            h.update(b"|s" + p.encode())
        else:
            a = np.ascontiguousarray(p)
            h.update(f"|a{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes() if a.dtype.hasobject else a.data.cast("B"))
    return f"{kind}-{h.hexdigest()[:40]}.npz"


def _cache_read(name: str) -> dict[str, np.ndarray] | None:
    path = model_cache_folder() / name
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # absent, or damaged: made again
        return None
    try:
        os.utime(path)  # the newest used are kept
    except OSError:  # a read-only cache: used as it is
        pass
    return arrays


def _cache_write(name: str, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to the cache atomically (a private file renamed into place); an OSError (a
    read-only folder, a full disk) leaves the cache as it was."""
    folder = model_cache_folder()
    tmp = folder / f".{name}.{os.getpid()}.{os.urandom(4).hex()}.tmp"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)  # type: ignore[arg-type]  # numpy's stub: named arrays are accepted
        os.replace(tmp, folder / name)
        entries = sorted(folder.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in entries[CACHE_ENTRIES:]:
            old.unlink(missing_ok=True)
    except OSError:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # no folder to hold it
            pass


def bin_model_ply_bytes(model: BinModel) -> bytes:
    """The model as the PLY bytes of a log's ``bin_model.ply`` attachment (float32 points and normals)."""
    from replay.logs.ply import ply_model_bytes

    return ply_model_bytes(model.points, model.normals)


@dataclass(frozen=True, slots=True)
class BinModelChoice:
    """Which bin model a log is replayed with (:func:`bin_model_for`).

    Attributes
    ----------
    model : BinModel or None
        None: the bin stages are skipped.
    source : str
        ``"explicit"`` (``--bin-model``), ``"log"`` (the log's attachment) or ``"none"``.
    warning : str or None
        The one line to show when there is no model (names the log and what to do), else None.
    """

    model: BinModel | None
    source: str
    warning: str | None = None


def bin_model_source(reader: LogReader, explicit_path: str | Path | None) -> tuple[str, str | None]:
    """Which bin model ``reader``'s log gets, without loading it: (``"explicit"`` | ``"log"`` |
    ``"none"``, the warning when ``"none"``). The log's attachment is read and checked here."""
    if explicit_path is not None:
        return "explicit", None
    if reader.attached_bin_model is not None:
        return "log", None
    from replay.logs import layout

    log = reader.path
    why = (f"{log}: {reader.bin_model_problem}" if reader.bin_model_problem else
           f"{log} carries no bin model (no {layout.BIN_MODEL_ATTACHMENT} attachment)")
    return "none", (f"{why} and no --bin-model was given: the bin stages are skipped and the z-cut runs on the "
                    f"whole frame; attach one with `zcut bin-model EMPTY.mcap --into {log} -o NEW.mcap` "
                    "or give --bin-model PLY")


def bin_model_for(reader: LogReader, explicit_path: str | Path | None, *,
                  load: Callable[[str | Path], BinModel] | None = None) -> BinModelChoice:
    """The bin model to replay ``reader``'s log with: ``explicit_path`` (``--bin-model``) when given,
    else the log's own ``bin_model.ply`` attachment, else none with a warning.

    Parameters
    ----------
    reader : replay.logs.reader.LogReader
    explicit_path : path or None
    load : callable, optional
        Loads ``explicit_path`` (default :func:`load_bin_model`; a study's worker passes its cached one).

    Raises
    ------
    FileNotFoundError, LogFormatError
        ``explicit_path`` cannot be read as a bin model (a damaged attachment is a warning instead).
    """
    source, warning = bin_model_source(reader, explicit_path)
    if source == "explicit":
        assert explicit_path is not None  # what "explicit" means
        return BinModelChoice((load or load_bin_model)(explicit_path), source)
    if source == "log":
        from replay.logs import layout

        attached = reader.attached_bin_model
        assert attached is not None  # what "log" means (read once, cached)
        try:
            model = bin_model_from_ply(attached,
                                       what=f"{reader.path.name}: attachment {layout.BIN_MODEL_ATTACHMENT}")
        except LogFormatError as e:
            return BinModelChoice(None, "none", f"{reader.path}: its bin model attachment is not usable ({e}); the "
                                  "bin stages are skipped: give --bin-model PLY")
        return BinModelChoice(model, source)
    return BinModelChoice(None, source, warning)


def _model_of(ply: PlyModel, voxel_mm: float) -> BinModel:
    pts = ply.points
    voxel_m = voxel_mm / 1000.0
    if ply.faces is not None and len(ply.faces):
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(pts),
                                         o3d.utility.Vector3iVector(np.ascontiguousarray(ply.faces, np.int32)))
        area = mesh.get_surface_area()
        n = int(min(max(area / (voxel_m * voxel_m), 1000), 2_000_000))
        pc = mesh.sample_points_uniformly(number_of_points=n)
        return model_from_points(np.asarray(pc.points), voxel_mm=voxel_mm)
    if ply.normals is not None:
        spacing = _median_spacing(pts) if len(pts) > 1 else voxel_m
        return BinModel(pts.copy(), ply.normals.copy(), max(spacing, 1e-4))
    return model_from_points(pts, voxel_mm=voxel_mm)
