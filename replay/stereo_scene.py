"""Read a stereo scene from files (``zcut record-stereo``, docs/real_data.md, "Stereo scenes").

A scene is a rectified pair, its calibration, and optionally a ground-truth disparity of the left
view and a mask of the pixels whose truth is occluded. Middlebury 2014's folder layout is the
default (``im0.png``, ``im1.png``, ``calib.txt``, ``disp0GT.pfm``, ``mask0nocc.png``); every file
and calibration value can be given instead (:class:`SceneOverrides`). Every problem is one
:class:`~replay.errors.LogFormatError` (or ``ConfigError``) line naming the file.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from replay.errors import ConfigError, LogFormatError
from replay.logs.files import DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PIXELS, open_input
from zcut.errors import ParameterError
from zcut.stereo import StereoCalibration

#: Middlebury 2014's file names inside a scene folder.
LEFT, RIGHT, CALIB, GT_PFM, OCCLUSION = "im0.png", "im1.png", "calib.txt", "disp0GT.pfm", "mask0nocc.png"
#: Suffixes of the ground-truth disparity formats (PNG needs a scale: disparity = value / scale).
GT_SUFFIXES = (".pfm", ".png", ".npy")


@dataclass(frozen=True, slots=True)
class SceneOverrides:
    """Files and calibration values that replace a scene folder's own (None: the folder's).

    Attributes
    ----------
    left, right, calib, gt, occlusion : str or None
        File names, relative to the scene folder or absolute. ``occlusion``: a mask image, 255
        where the truth is to be judged (Middlebury's 128 occluded and 0 unknown are not).
    gt_scale : float or None
        For a PNG ground truth: disparity = value / ``gt_scale`` (0 = unknown).
    focal, baseline, doffs, cx, cy : float or None
        Calibration values (px, mm, px, px, px); with all of focal, baseline, cx, cy given no
        calibration file is read.
    """

    left: str | None = None
    right: str | None = None
    calib: str | None = None
    gt: str | None = None
    occlusion: str | None = None
    gt_scale: float | None = None
    focal: float | None = None
    baseline: float | None = None
    doffs: float | None = None
    cx: float | None = None
    cy: float | None = None


@dataclass(frozen=True, slots=True)
class StereoScene:
    """One scene read from its files.

    Attributes
    ----------
    name : str
        The folder's name.
    left, right : (H, W, 3) uint8 ndarray
        RGB.
    calib : StereoCalibration
    gt_disparity : (H, W) float32 ndarray or None
        ``inf`` where unknown.
    occluded : (H, W) bool ndarray or None
        True where the truth is not to be judged (occluded or unknown in the mask).
    sources : dict[str, str]
        What was read from where (for the log's metadata).
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    calib: StereoCalibration
    gt_disparity: np.ndarray | None
    occluded: np.ndarray | None
    sources: dict[str, str]


def _read_bytes(path: Path, what: str) -> bytes:
    f, size = open_input(path, what)
    with f:
        if size > DEFAULT_MAX_MESSAGE_BYTES:
            raise LogFormatError(f"{path}: {size} bytes is more than the cap of {DEFAULT_MAX_MESSAGE_BYTES} "
                                 "(raise it with ZCUT_MAX_MESSAGE_BYTES)")
        return f.read()


def _check_pixels(path: Path, h: int, w: int) -> None:
    if h < 2 or w < 2:
        raise LogFormatError(f"{path}: image of {h}x{w} pixels (a scene needs at least 2x2)")
    if h * w > DEFAULT_MAX_PIXELS:
        raise LogFormatError(f"{path}: {h}x{w} = {h * w} pixels is more than the cap of {DEFAULT_MAX_PIXELS} "
                             "(raise it with ZCUT_MAX_PIXELS)")


def _decode_png(path: Path, flags: int) -> np.ndarray:
    """A PNG's pixels, its header checked against the pixel cap before it is decoded."""
    import cv2

    data = _read_bytes(path, "a PNG image")
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        raise LogFormatError(f"{path}: not a PNG image")
    _check_pixels(path, int.from_bytes(data[20:24], "big"), int.from_bytes(data[16:20], "big"))
    try:
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:
        img = None
    if img is None:
        raise LogFormatError(f"{path}: not a readable PNG image")
    return img


def read_rgb(path: str | os.PathLike[str]) -> np.ndarray:
    """An 8-bit image as (H, W, 3) uint8 RGB (a gray image is repeated in the three channels)."""
    import cv2

    p = Path(path)
    img = _decode_png(p, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise LogFormatError(f"{p}: a {img.dtype} image; the stereo pair must be 8-bit")
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2)
    if img.shape[2] == 4:
        img = img[..., :3]
    return np.ascontiguousarray(img[..., ::-1])


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """A one-channel PFM (``Pf``) as (H, W) float32, top row first (the file stores rows bottom-up;
    a negative scale means little-endian)."""
    p = Path(path)
    data = _read_bytes(p, "a PFM file")
    m = re.match(rb"(P[fF])\s+(\d+)\s+(\d+)\s+(\S+)\s", data)
    if m is None:
        raise LogFormatError(f"{p}: not a PFM file (expected 'Pf', width, height, scale)")
    if m.group(1) != b"Pf":
        raise LogFormatError(f"{p}: a 3-channel PFM ('PF'); a disparity needs one channel ('Pf')")
    w, h = int(m.group(2)), int(m.group(3))
    try:
        scale = float(m.group(4))
    except ValueError:
        raise LogFormatError(f"{p}: PFM scale {m.group(4)!r} is not a number") from None
    if scale == 0 or not np.isfinite(scale):
        raise LogFormatError(f"{p}: PFM scale must be a nonzero number, got {scale}")
    _check_pixels(p, h, w)
    body = data[m.end():]
    if len(body) != 4 * w * h:
        raise LogFormatError(f"{p}: {len(body)} bytes of pixels, a {w}x{h} PFM needs {4 * w * h}")
    a = np.frombuffer(body, dtype="<f4" if scale < 0 else ">f4").reshape(h, w)
    return np.ascontiguousarray(a[::-1]).astype(np.float32)


def read_gt(path: str | os.PathLike[str], *, scale: float | None = None) -> np.ndarray:
    """A ground-truth disparity (H, W) float32, ``inf`` where unknown: PFM; PNG (8 or 16 bit, value /
    ``scale``, 0 unknown); NPY (float, or integer / ``scale``; not finite or <= 0 unknown)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in GT_SUFFIXES:
        raise ConfigError(f"{p}: ground truth must be a {', '.join(GT_SUFFIXES)} file")
    if suffix == ".pfm":
        return read_pfm(p)
    if suffix == ".png":
        import cv2

        if scale is None:
            raise ConfigError(f"{p}: a PNG ground truth needs --gt-scale (disparity = value / scale)")
        img = _decode_png(p, cv2.IMREAD_UNCHANGED)
        if img.ndim != 2:
            raise LogFormatError(f"{p}: a ground-truth PNG must have one channel, got {img.shape[2]}")
        d = img.astype(np.float32) / np.float32(scale)
        d[img == 0] = np.inf
        return d
    data = _read_bytes(p, "a NPY file")
    import io

    try:
        a = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise LogFormatError(f"{p}: not a readable NPY array ({e})") from None
    if not isinstance(a, np.ndarray) or a.ndim != 2 or not (np.issubdtype(a.dtype, np.floating)
                                                           or np.issubdtype(a.dtype, np.integer)):
        raise LogFormatError(f"{p}: a ground-truth NPY must be a 2-D number array, got {getattr(a, 'shape', a)}")
    _check_pixels(p, *a.shape)
    d = a.astype(np.float32)
    if np.issubdtype(a.dtype, np.integer):
        d = d / np.float32(scale if scale is not None else 1.0)
    d[~np.isfinite(d) | (d <= 0)] = np.inf
    return d


def read_occlusion(path: str | os.PathLike[str]) -> np.ndarray:
    """(H, W) bool, True where the truth is not judged: a mask image whose value is not 255
    (Middlebury's ``mask0nocc.png``: 255 non-occluded, 128 occluded, 0 unknown)."""
    import cv2

    p = Path(path)
    img = _decode_png(p, cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise LogFormatError(f"{p}: an occlusion mask must be a one-channel 8-bit image")
    unjudged: np.ndarray = img != 255
    return unjudged


_CAM = re.compile(r"^\s*cam0\s*=\s*\[([^\]]*)\]\s*$")
_VALUE = re.compile(r"^\s*(\w+)\s*=\s*(\S+)\s*$")


def parse_calib(text: str, *, name: str) -> dict[str, float]:
    """Middlebury's ``calib.txt``: ``{"focal", "cx", "cy", "doffs", "baseline", "width", "height",
    "ndisp"}`` as present (``cam0 = [f 0 cx; 0 f cy; 0 0 1]``, one ``key=value`` a line)."""
    out: dict[str, float] = {}
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _CAM.match(line)
        if m:
            try:
                k = [float(v) for v in m.group(1).replace(";", " ").split()]
            except ValueError:
                raise LogFormatError(f"{name}: line {n}: cam0 is not a 3x3 matrix of numbers") from None
            if len(k) != 9:
                raise LogFormatError(f"{name}: line {n}: cam0 has {len(k)} numbers, a 3x3 matrix has 9")
            out.update(focal=k[0], cx=k[2], cy=k[5])
            continue
        if line.strip().startswith("cam"):
            continue
        m = _VALUE.match(line)
        if m is None:
            raise LogFormatError(f"{name}: line {n} is not 'key=value': {line.strip()[:60]!r}")
        if m.group(1) in ("doffs", "baseline", "width", "height", "ndisp"):
            try:
                out[m.group(1)] = float(m.group(2))
            except ValueError:
                raise LogFormatError(f"{name}: line {n}: {m.group(1)} = {m.group(2)[:40]!r} is not a number") from None
    return out


def _resolve(folder: Path, given: str | None, default: str) -> Path:
    if given is None:
        return folder / default
    p = Path(given)
    return p if p.is_absolute() else folder / p


def load_scene(folder: str | os.PathLike[str], over: SceneOverrides = SceneOverrides()) -> StereoScene:
    """Read one scene (module docstring); the ground truth and occlusion mask are optional unless named."""
    d = Path(folder)
    if not d.is_dir():
        raise FileNotFoundError(2, "no such folder", str(d))
    sources: dict[str, str] = {}
    left_p, right_p = _resolve(d, over.left, LEFT), _resolve(d, over.right, RIGHT)
    left, right = read_rgb(left_p), read_rgb(right_p)
    sources.update(left=str(left_p), right=str(right_p))
    shape = left.shape[:2]
    if right.shape[:2] != shape:
        raise LogFormatError(f"{right_p}: image is {right.shape[0]}x{right.shape[1]} but the left image "
                             f"{left_p.name} is {shape[0]}x{shape[1]}")
    given = {"focal": over.focal, "baseline": over.baseline, "doffs": over.doffs, "cx": over.cx, "cy": over.cy}
    values: dict[str, float] = {}
    calib_p = _resolve(d, over.calib, CALIB)
    need_file = any(given[k] is None for k in ("focal", "baseline", "cx", "cy"))
    if need_file or over.calib is not None:
        raw = _read_bytes(calib_p, "a calibration file")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise LogFormatError(f"{calib_p}: not a text file") from None
        values = parse_calib(text, name=str(calib_p))
        sources["calib"] = str(calib_p)
        for key in ("width", "height"):
            want = shape[1] if key == "width" else shape[0]
            if key in values and int(values[key]) != want:
                raise LogFormatError(f"{calib_p}: {key} {values[key]:g} but the image {left_p.name} is "
                                     f"{shape[0]}x{shape[1]}")
    values.update({k: float(v) for k, v in given.items() if v is not None})
    missing = [k for k in ("focal", "baseline", "cx", "cy") if k not in values]
    if missing:
        raise LogFormatError(f"{calib_p}: no {', '.join(missing)} (give cam0 and baseline, or --{' --'.join(missing)})")
    ndisp = values.get("ndisp")
    try:
        calib = StereoCalibration(focal_px=values["focal"], cx=values["cx"], cy=values["cy"],
                                  baseline_mm=values["baseline"], doffs_px=values.get("doffs", 0.0),
                                  ndisp=int(ndisp) if ndisp is not None and ndisp >= 1 and ndisp == int(ndisp) else None)
    except ParameterError as e:
        raise LogFormatError(f"{sources.get('calib', 'calibration')}: {e}") from None
    gt = occluded = None
    gt_p = _resolve(d, over.gt, GT_PFM)
    if over.gt is not None or gt_p.exists():
        gt = read_gt(gt_p, scale=over.gt_scale)
        if gt.shape != shape:
            raise LogFormatError(f"{gt_p}: ground truth is {gt.shape[0]}x{gt.shape[1]} but the image "
                                 f"{left_p.name} is {shape[0]}x{shape[1]}")
        sources["gt"] = str(gt_p)
    occ_p = _resolve(d, over.occlusion, OCCLUSION)
    if over.occlusion is not None or (gt is not None and occ_p.exists()):
        occluded = read_occlusion(occ_p)
        if occluded.shape != shape:
            raise LogFormatError(f"{occ_p}: mask is {occluded.shape[0]}x{occluded.shape[1]} but the image "
                                 f"{left_p.name} is {shape[0]}x{shape[1]}")
        sources["occlusion"] = str(occ_p)
    return StereoScene(name=d.resolve().name, left=left, right=right, calib=calib, gt_disparity=gt,
                       occluded=occluded, sources=sources)
