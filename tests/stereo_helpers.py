"""Stereo scenes for the tests, made at test time from scikit-image's Motorcycle (no data in the
repository), and an independent computation of their truth (numpy only, written apart from
zcut/stereo.py: loops where the module vectorises)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

MIDDLEBURY = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
if not MIDDLEBURY.is_dir():  # a checkout elsewhere may point at the data explicitly
    MIDDLEBURY = Path(os.environ.get("ZCUT_MIDDLEBURY", MIDDLEBURY))

#: skimage.data.stereo_motorcycle()'s calibration (its docstring), for the full 500 x 741 images.
MOTORCYCLE = {"focal": 994.978, "cx": 311.193, "cy": 254.877, "doffs": 31.086, "baseline": 193.001}


def middlebury() -> Path:
    """The shared Middlebury scenes (docs/real_data.md): skip when absent, fail under CI."""
    if not MIDDLEBURY.is_dir():
        why = (f"Middlebury scenes not found: {MIDDLEBURY}; docs/real_data.md (\"Stereo scenes\") says what they "
               "are and where the tests look for them (or set ZCUT_MIDDLEBURY=/path/to/them)")
        if os.environ.get("CI"):
            pytest.fail(why)
        pytest.skip(why)
    return MIDDLEBURY


def write_pfm(path: Path, disp: np.ndarray) -> None:
    """A one-channel little-endian PFM, rows bottom-up."""
    h, w = disp.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        f.write(np.ascontiguousarray(disp[::-1], dtype="<f4").tobytes())


def motorcycle(factor: int = 4) -> dict:
    """Motorcycle downsampled ``factor`` times: left, right (RGB), gt (float32, inf unknown), an
    occlusion mask (Middlebury's codes: two bands marked 128 and 0) and the calibration."""
    import cv2

    skd = pytest.importorskip("skimage.data")
    left, right, gt = skd.stereo_motorcycle()
    h, w = left.shape[0] // factor, left.shape[1] // factor
    size = (w, h)
    lt = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
    rt = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
    g = gt[factor // 2::factor, factor // 2::factor][:h, :w].astype(np.float32) / np.float32(factor)
    g[~np.isfinite(g)] = np.inf
    mask = np.full((h, w), 255, np.uint8)
    mask[h // 3: h // 3 + 4, :] = 128
    mask[:, w // 2: w // 2 + 3] = 0
    cal = {"focal": MOTORCYCLE["focal"] / factor, "cx": (MOTORCYCLE["cx"] + 0.5) / factor - 0.5,
           "cy": (MOTORCYCLE["cy"] + 0.5) / factor - 0.5, "doffs": MOTORCYCLE["doffs"] / factor,
           "baseline": MOTORCYCLE["baseline"]}
    return {"left": lt, "right": rt, "gt": g, "mask": mask, "calib": cal, "ndisp": 64 // factor}


def write_scene(folder: Path, scene: dict) -> Path:
    """A Middlebury-layout folder of ``scene``."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "im0.png"), scene["left"][..., ::-1])
    cv2.imwrite(str(folder / "im1.png"), scene["right"][..., ::-1])
    c = scene["calib"]
    h, w = scene["gt"].shape
    (folder / "calib.txt").write_text(
        f"cam0=[{c['focal']} 0 {c['cx']}; 0 {c['focal']} {c['cy']}; 0 0 1]\n"
        f"cam1=[{c['focal']} 0 {c['cx'] + c['doffs']}; 0 {c['focal']} {c['cy']}; 0 0 1]\n"
        f"doffs={c['doffs']}\nbaseline={c['baseline']}\nwidth={w}\nheight={h}\nndisp={scene['ndisp']}\n"
        "isint=0\nvmin=1\nvmax=15\n")
    write_pfm(folder / "disp0GT.pfm", scene["gt"])
    cv2.imwrite(str(folder / "mask0nocc.png"), scene["mask"])
    return folder


def independent_truth(z_m: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, calib: dict,
                      tau_px: float = 1.0) -> dict[str, np.ndarray]:
    """outliers, unknown, detectable from the cloud's z (metres), the ground-truth disparity and the
    calibration, pixel by pixel: Z_GT = B f / (d + doffs); outlier iff |Z - Z_GT| > tau Z_GT^2 / (f B);
    detectable iff |Z - median of the valid 8-neighbours' Z| > that tolerance, or no valid neighbour."""
    h, w = z_m.shape
    f, b, doffs = calib["focal"], calib["baseline"], calib["doffs"]
    out = np.zeros((h, w), bool)
    unknown = np.zeros((h, w), bool)
    det = np.zeros((h, w), bool)
    tol = np.full((h, w), np.nan)
    zmm = z_m.astype(np.float64) * 1000.0
    for v in range(h):
        for u in range(w):
            d = float(gt[v, u])
            if not np.isfinite(d) or d + doffs <= 0 or (mask is not None and mask[v, u] != 255):
                unknown[v, u] = True
                continue
            zg = b * f / (d + doffs)
            tol[v, u] = tau_px * zg * zg / (f * b)
            z = zmm[v, u]
            if np.isfinite(z) and abs(z - zg) > tol[v, u]:
                out[v, u] = True
    for v, u in zip(*np.nonzero(out)):
        nb = [zmm[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)
              if (dv or du) and 0 <= v + dv < h and 0 <= u + du < w and np.isfinite(zmm[v + dv, u + du])]
        det[v, u] = not nb or abs(zmm[v, u] - float(np.median(nb))) > tol[v, u]
    return {"outliers": out, "unknown": unknown, "detectable": det}
