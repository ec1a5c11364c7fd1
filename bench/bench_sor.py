"""Benchmark: zcut.sor_outliers against Open3D's remove_statistical_outlier, per cloud class.

Classes (1920 x 1200, or the sensor's own size), all seeded:

  pile         a bin with slanted walls and a pile of spheres (flying pixels at depth edges, NaN holes)
  blobs5/20    a camera above a bumpy height field with steep-sided plateaus, blob-shaped invalid
               regions covering 5 % / 20 % of the image
  holes-walls  the same height field with large invalid regions (blobs covering 40 % of the image)
               and steep walls: 40 plateaus 80-300 mm tall with vertical sides (issue 32 item 7)
  walls        tall boxes on a floor 1 m away: steep side walls seen at grazing angles, 0.5 m deep
               discontinuities with flying pixels between them
  sparse       the blobs scene with 50 % of the pixels invalid, scattered
  negative-z   the pile in the OpenGL camera convention (y up, z < 0 everywhere)
  mixed-z      the pile in a tilted bin frame: z = height above the bin floor, of both signs
  distorted    the pile seen through a lens with strong radial distortion (k1 = 0.05: rows and
               columns bent by up to 25 px at the corners), as real sensors' clouds are bent
  steep        steep relief (issue 32 item 7, in the PCL convention): some 400 tall narrow parts (rods 8-24 mm across, 40-220 mm tall)
               standing on end on a floor 1 m away, seen by a camera tilted 35 deg: their sides
               run along the rays, so image neighbours are rarely 3D neighbours (flying pixels at
               the silhouettes, noise, dropouts)
  synth        the project's own synthetic structured-light scan (replay.synth), if importable
  kinect/NAME  the real Kinect clouds of the real data folder, docs/real_data.md (640 x 480, quantized depth),
               found as tests/conftest.py finds them: beside the checkout, else $ZCUT_REAL_DATA. Without
               them the run says so loudly and its minimum is not called the smallest ratio.

For every class and convention: the CPU time of all threads (time.process_time, median of
--repeat) of zcut and of Open3D's remove_statistical_outlier on the same valid points, the ratio,
and whether the result is identical: the "open3d" convention against Open3D's own mask, the "pcl"
convention against the exact KD-tree reference of tests/reference/sor_reference.py (Open3D's time
is the yardstick for both). With ``--against OLD_TREE`` (a source tree of the previous code, e.g.
``git archive COMMIT | tar -x -C OLD_TREE``; its numba kernels compile on its first run) the same
cloud also goes through the previous code in a subprocess that lives for the whole run: every
round times this code, the previous code and Open3D once each, alternately (the order of this and
the previous code flips every round), so that a shared machine's load falls on both alike; the
figures are the medians over the rounds, with the ratio previous / this, and whether the previous
code's masks are this code's bit for bit. The load average is printed before and after. Targets: issue 12, >= 5x on every class and >= 10x on the pile; issue 32 item 7,
>= 10x on every class in both conventions.

    .venv/bin/python bench/bench_sor.py [--repeat N] [--seed S] [--k K] [--std-ratio R]
                                        [--classes pile,walls,...] [--no-reference] [--against OLD_TREE]

Where the time of a call goes: ``--phases`` prints, per class and convention, the medians over --repeat
calls (after a first one) of the CPU ms of the call, of every kernel it runs on its threads and of the
steps around them (the camera fit, the tables, the fallback searches, the outlier masks), timed by
wrapping them in this process; for one thread prefix ``NUMBA_NUM_THREADS=1``. With ``--stage LOG.mcap`` (and
``--frames N``) the same for the pipeline's SOR stage on the log's frames, CPU ms a frame (for the previous code
run this file with ``PYTHONPATH=OLD_TREE``).

Page faults a call: ``--faults row`` (calls in a row) or ``--faults open3d`` (Open3D's filter
between the calls, as in the classes' rounds) prints, per class and convention, the medians over
--repeat calls (after a first one) of the CPU ms, the system ms and the minor page faults
(``resource.getrusage``) of one ``sor_outliers`` call, the caller keeping every mask; for one thread
prefix ``NUMBA_NUM_THREADS=1``, for the previous code run this file with ``PYTHONPATH=OLD_TREE``.

The SOR stage inside a replay: ``--stage LOG.mcap [--against OLD_TREE]`` runs the bin stages on
every frame of the log (its own bin model, its config) and times the pipeline's SOR stage on the
zone they leave (``replay.pipeline.zone.sor_on_zone``: the judged region, its crop, the filter;
CPU ms, median of --repeat; ``--frames N``: the first N frames), with the previous tree's in a subprocess, alternately frame by frame
and round by round as for the classes, and whether its masks are this code's bit for bit.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FULL = (1200, 1920)


def real_data_folder(root: Path = ROOT, environ=os.environ) -> tuple[Path, str | None]:
    """Where the real clouds are, as tests/conftest.py looks (docs/real_data.md): beside the checkout
    (docs/real_data.md says where), else ``$ZCUT_REAL_DATA``. (folder, None) when it holds .pcd files,
    else (the folder looked at, why no real class can run)."""
    beside = root.parent / "shared" / "data" / "real"
    folder = beside if beside.is_dir() or "ZCUT_REAL_DATA" not in environ else Path(environ["ZCUT_REAL_DATA"])
    if not folder.is_dir():
        looked = f"{beside}" + (f" nor $ZCUT_REAL_DATA={folder}" if folder != beside else "")
        return folder, (f"no real data folder: neither {looked} exists (docs/real_data.md lists the files; "
                        "put them beside the checkout or set ZCUT_REAL_DATA)")
    if not any(folder.glob("*.pcd")):
        return folder, f"the real data folder {folder} holds no .pcd file (docs/real_data.md lists them)"
    return folder, None


REAL_DATA, REAL_DATA_PROBLEM = real_data_folder()


def configure_process() -> None:
    """What the command line does (cli/main.py): numba's workqueue threads unless chosen."""
    if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
        os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = "workqueue omp tbb"
        if "numba" in sys.modules:
            import numba

            numba.config.THREADING_LAYER_PRIORITY = ["workqueue", "omp", "tbb"]


# ------------------------------------------------------------------------------------------------
# clouds
# ------------------------------------------------------------------------------------------------
def _rays(height: int, width: int, f: float) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return (u - (width - 1) / 2.0) / f, (v - (height - 1) / 2.0) / f


def _flying_pixels(z: np.ndarray, rng: np.random.Generator, *, jump: float, frac: float) -> np.ndarray:
    # mixed pixels at depth edges: somewhere between the two depths, on the pixel's own ray
    edge = np.zeros_like(z, dtype=bool)
    j = np.abs(np.diff(z, axis=1)) > jump
    edge[:, 1:] |= j
    edge[:, :-1] |= j
    j = np.abs(np.diff(z, axis=0)) > jump
    edge[1:, :] |= j
    edge[:-1, :] |= j
    fly = edge & (rng.random(z.shape) < frac)
    zr = np.roll(z, 2, axis=1)
    return np.where(fly, z + rng.random(z.shape) * (zr - z), z)


def _blob_mask(rng: np.random.Generator, shape: tuple[int, int], frac: float) -> np.ndarray:
    # smooth random field thresholded at its (1 - frac) quantile: blob-shaped regions
    from scipy.ndimage import gaussian_filter, zoom

    small = gaussian_filter(rng.normal(size=(shape[0] // 8, shape[1] // 8)), 3.0)
    field = zoom(small, (shape[0] / small.shape[0], shape[1] / small.shape[1]), order=1)[: shape[0], : shape[1]]
    return field > np.quantile(field, 1.0 - frac)


def pile_cloud(seed: int = 0, *, height: int = FULL[0], width: int = FULL[1], k1: float = 0.0) -> np.ndarray:
    """(H, W, 3) float32 bin scene in metres, camera optical frame, NaN = invalid; ``k1``: radial
    lens distortion of the pixel grid (the ray of a pixel at normalized radius r is scaled by
    1 + k1·r², so columns and rows of points are no longer planes through the camera)."""
    rng = np.random.default_rng(seed)
    fx = fy = 1700.0
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    dx, dy = _rays(height, width, fx)
    if k1:
        scale = 1.0 + k1 * (dx * dx + dy * dy)
        dx, dy = dx * scale, dy * scale

    floor_z, rim_z, table_z = 0.50, 0.35, 0.505
    half_x, half_y, slope, rim_w = 0.22, 0.13, 0.25, 0.02

    def scene_depth(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        # distance outside the floor rectangle, walls rise with the slope up to the rim
        ex = np.maximum(np.abs(X) - half_x, 0.0)
        ey = np.maximum(np.abs(Y) - half_y, 0.0)
        e = np.maximum(ex, ey)
        wall_len = (floor_z - rim_z) * slope
        z = np.where(e <= 0, floor_z, floor_z - (floor_z - rim_z) * np.minimum(e / wall_len, 1.0))
        return np.where(e > wall_len + rim_w, table_z, z)

    z = np.full((height, width), floor_z)
    for _ in range(4):  # fixed point: the ray through each pixel meets the height field
        z = scene_depth(dx * z, dy * z)

    # a pile of spheres on the floor (ray-sphere intersection, nearest hit)
    for _ in range(260):
        r = rng.uniform(0.012, 0.035)
        C = np.array([rng.uniform(-half_x, half_x), rng.uniform(-half_y, half_y), floor_z - r - rng.uniform(0, 0.04)])
        uc, vc = C[0] / C[2] * fx + cx, C[1] / C[2] * fy + cy
        rad = r / (C[2] - r) * fx * 1.2 + 2
        r0, r1 = int(max(0, vc - rad)), int(min(height, vc + rad + 1))
        c0, c1 = int(max(0, uc - rad)), int(min(width, uc + rad + 1))
        if r0 >= r1 or c0 >= c1:
            continue
        ddx, ddy = dx[r0:r1, c0:c1], dy[r0:r1, c0:c1]
        dd = ddx * ddx + ddy * ddy + 1.0
        b = ddx * C[0] + ddy * C[1] + C[2]
        disc = b * b - dd * (C @ C - r * r)
        t = (b - np.sqrt(np.maximum(disc, 0.0))) / dd
        hit = (disc > 0) & (t < z[r0:r1, c0:c1])
        z[r0:r1, c0:c1][hit] = t[hit]

    # flying pixels at depth edges, then noise along the rays
    edge = np.zeros_like(z, dtype=bool)
    jump = np.abs(np.diff(z, axis=1)) > 0.004
    edge[:, 1:] |= jump
    edge[:, :-1] |= jump
    jump = np.abs(np.diff(z, axis=0)) > 0.004
    edge[1:, :] |= jump
    edge[:-1, :] |= jump
    fly = edge & (rng.random(z.shape) < 0.3)
    zr = np.roll(z, 3, axis=1)
    z = np.where(fly, z + rng.random(z.shape) * (zr - z), z)
    z = z * (1.0 + rng.normal(0.0, 2e-4, z.shape))

    # NaN holes: sparse dropouts, blobs, and most of the steep edge pixels
    invalid = rng.random(z.shape) < 0.01
    for _ in range(150):
        rc, cc = rng.integers(0, height), rng.integers(0, width)
        rr = rng.integers(3, 25)
        invalid[max(0, rc - rr):rc + rr, max(0, cc - rr):cc + rr] = True
    invalid |= edge & ~fly & (rng.random(z.shape) < 0.5)

    xyz = np.stack([dx * z, dy * z, z], axis=-1).astype(np.float32)
    xyz[invalid] = np.nan
    return xyz


make_cloud = pile_cloud  # the name this benchmark used before the classes


def blobs_cloud(seed: int = 0, *, invalid_frac: float = 0.1, height: int = FULL[0], width: int = FULL[1],
                plateaus: int = 12, plateau_m: tuple[float, float] = (0.03, 0.12)) -> np.ndarray:
    """A camera 0.7 m above a bumpy height field with ``plateaus`` steep-sided plateaus (heights in
    ``plateau_m``, metres); blob-shaped NaN regions covering ``invalid_frac`` of the image."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(seed)
    f = 1700.0 * width / FULL[1]
    dx, dy = _rays(height, width, f)
    base = 0.7
    # the height field on a 1 mm grid over the view, then bilinear lookups along the rays
    hx, hy = 0.45, 0.3
    gx, gy = np.meshgrid(np.arange(-hx, hx, 1e-3), np.arange(-hy, hy, 1e-3))
    hf = np.zeros_like(gx)
    for _ in range(50):
        X0, Y0 = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
        s, a = rng.uniform(0.01, 0.06), rng.uniform(0.0, 0.1)
        hf += a * np.exp(-((gx - X0) ** 2 + (gy - Y0) ** 2) / (2 * s * s))
    for _ in range(plateaus):  # plateaus with near-vertical sides (1 mm ramps)
        X0, Y0 = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
        ax, ay, a = rng.uniform(0.02, 0.1), rng.uniform(0.02, 0.1), rng.uniform(*plateau_m)
        e = np.maximum(np.abs(gx - X0) - ax, np.abs(gy - Y0) - ay)
        hf = np.maximum(hf, a * np.clip(-e / 1e-3, 0.0, 1.0) + hf * (e > 0))
    z = np.full((height, width), base)
    for _ in range(6):
        X, Y = dx * z, dy * z
        z = base - map_coordinates(hf, [(Y + hy) / 1e-3, (X + hx) / 1e-3], order=1, mode="nearest")
    z = z * (1.0 + rng.normal(0.0, 2e-4, z.shape))
    xyz = np.stack([dx * z, dy * z, z], axis=-1).astype(np.float32)
    xyz[_blob_mask(rng, (height, width), invalid_frac)] = np.nan
    xyz[rng.random((height, width)) < 0.005] = np.nan
    return xyz


def walls_cloud(seed: int = 0, *, height: int = FULL[0], width: int = FULL[1]) -> np.ndarray:
    """Tall boxes on a floor 1 m from the camera, ray-cast exactly: side walls seen at grazing
    angles, discontinuities up to 0.5 m deep with flying pixels, noise, a few dropouts."""
    rng = np.random.default_rng(seed)
    f = 1700.0 * width / FULL[1]
    dx, dy = _rays(height, width, f)
    floor = 1.0
    z = np.full((height, width), floor)
    hx, hy = 0.55 * floor, 0.35 * floor
    for _ in range(30):
        x0, y0 = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
        x1, y1 = x0 + rng.uniform(0.03, 0.15), y0 + rng.uniform(0.03, 0.15)
        top = floor - rng.uniform(0.1, 0.5)
        # pixels whose ray can meet the box (its projection between the top and the floor)
        us = [x / zz * f + (width - 1) / 2 for x in (x0, x1) for zz in (top, floor)]
        vs = [y / zz * f + (height - 1) / 2 for y in (y0, y1) for zz in (top, floor)]
        c0, c1 = max(0, int(min(us)) - 1), min(width, int(max(us)) + 2)
        r0, r1 = max(0, int(min(vs)) - 1), min(height, int(max(vs)) + 2)
        if c0 >= c1 or r0 >= r1:
            continue
        ddx, ddy = dx[r0:r1, c0:c1], dy[r0:r1, c0:c1]
        best = z[r0:r1, c0:c1].copy()
        inside = (ddx * top >= x0) & (ddx * top <= x1) & (ddy * top >= y0) & (ddy * top <= y1)
        best = np.where(inside, np.minimum(best, top), best)
        with np.errstate(divide="ignore", invalid="ignore"):
            for wall, along, lo, hi in ((x0, ddx, y0, y1), (x1, ddx, y0, y1), (y0, ddy, x0, x1), (y1, ddy, x0, x1)):
                t = wall / along
                other = (ddy if along is ddx else ddx) * t
                hit = (t >= top) & (t <= floor) & (other >= lo) & (other <= hi)
                best = np.where(hit, np.minimum(best, t), best)
        z[r0:r1, c0:c1] = best
    z = _flying_pixels(z, rng, jump=0.01, frac=0.25)
    z = z * (1.0 + rng.normal(0.0, 2e-4, z.shape))
    xyz = np.stack([dx * z, dy * z, z], axis=-1).astype(np.float32)
    xyz[rng.random((height, width)) < 0.01] = np.nan
    return xyz


def steep_cloud(seed: int = 0, *, height: int = FULL[0], width: int = FULL[1], tilt_deg: float = 5.0,
                n_parts: int = 900) -> np.ndarray:
    """Tall narrow parts standing on end (vertical cylinders with flat tops) on a floor, ray-cast
    exactly from a camera 1 m above the floor and tilted by ``tilt_deg`` from the vertical: the
    rods' sides are seen at steep angles, so the depth jumps by millimetres to centimetres between
    image neighbours along them. Flying pixels at the silhouettes, noise along the rays, dropouts."""
    rng = np.random.default_rng(seed)
    f = 1700.0 * width / FULL[1]
    dx, dy = _rays(height, width, f)
    # world: z up, floor z = 0; camera at (0, -sin(t), cos(t)) * 1 m looking at the origin
    t = np.deg2rad(tilt_deg)
    C = np.array([0.0, -np.sin(t), np.cos(t)])
    fwd = -C
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(fwd, right)
    Rwc = np.stack([right, down, fwd], axis=1)  # camera axes (x right, y down, z forward) in the world
    D = np.stack([dx, dy, np.ones_like(dx)], axis=-1) @ Rwc.T  # ray directions, camera z = 1
    tz = np.where(D[..., 2] < 0, -C[2] / np.where(D[..., 2] < 0, D[..., 2], -1.0), np.inf)  # the floor
    floor_hit = C + tz[..., None] * D
    tz = np.where((np.abs(floor_hit[..., 0]) < 0.6) & (np.abs(floor_hit[..., 1]) < 0.5), tz, np.inf)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    for _ in range(n_parts):
        R, h = rng.uniform(0.004, 0.012), rng.uniform(0.04, 0.22)
        cx, cy = rng.uniform(-0.35, 0.35), rng.uniform(-0.3, 0.3)
        corners = np.array([[cx + sx * R, cy + sy * R, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (0.0, h)])
        cam = (corners - C) @ Rwc  # world -> camera
        if (cam[:, 2] <= 0.05).any():
            continue
        uv = cam @ K.T
        us, vs = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
        c0, c1 = max(0, int(us.min()) - 1), min(width, int(us.max()) + 2)
        r0, r1 = max(0, int(vs.min()) - 1), min(height, int(vs.max()) + 2)
        if c0 >= c1 or r0 >= r1:
            continue
        d = D[r0:r1, c0:c1]
        ox, oy = C[0] - cx, C[1] - cy
        a = d[..., 0] ** 2 + d[..., 1] ** 2
        b = 2 * (ox * d[..., 0] + oy * d[..., 1])
        disc = b * b - 4 * a * (ox * ox + oy * oy - R * R)
        with np.errstate(invalid="ignore", divide="ignore"):
            ts = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)  # the side, nearest hit
            zs = C[2] + ts * d[..., 2]
            side = (disc > 0) & (zs >= 0) & (zs <= h) & (ts > 0)
            tt = (h - C[2]) / d[..., 2]  # the top disk
            top = C + tt[..., None] * d
            cap = ((top[..., 0] - cx) ** 2 + (top[..., 1] - cy) ** 2 <= R * R) & (tt > 0)
        best = tz[r0:r1, c0:c1]
        best = np.where(side, np.minimum(best, ts), best)
        best = np.where(cap, np.minimum(best, tt), best)
        tz[r0:r1, c0:c1] = best
    z = np.where(np.isfinite(tz), tz, np.nan)  # camera z = t (the rays have camera z = 1)
    z = _flying_pixels(np.where(np.isnan(z), 2.0, z), rng, jump=0.01, frac=0.25)
    z = z * (1.0 + rng.normal(0.0, 2e-4, z.shape))
    xyz = np.stack([dx * z, dy * z, z], axis=-1).astype(np.float32)
    xyz[~np.isfinite(tz) | (rng.random((height, width)) < 0.01)] = np.nan
    return xyz


def sparse_cloud(seed: int = 0) -> np.ndarray:
    """The blobs scene (5 % blobs) with half of the pixels invalid, scattered."""
    xyz = blobs_cloud(seed, invalid_frac=0.05)
    xyz[np.random.default_rng(seed + 99).random(xyz.shape[:2]) < 0.5] = np.nan
    return xyz


def negative_z_cloud(seed: int = 0) -> np.ndarray:
    """The pile in the OpenGL camera convention: y up, looking along -z (every z < 0)."""
    xyz = pile_cloud(seed)
    return np.stack([xyz[..., 0], -xyz[..., 1], -xyz[..., 2]], axis=-1)


def mixed_z_cloud(seed: int = 0) -> np.ndarray:
    """The pile in a tilted bin frame: rotated 20 deg about x and 30 deg about z, z = height above
    the bin floor (of both signs)."""
    xyz = pile_cloud(seed).astype(np.float64)
    a, b = np.deg2rad(20.0), np.deg2rad(30.0)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
    out = xyz @ (Rz @ Rx).T
    out[..., 2] = np.nanmedian(out[..., 2]) - out[..., 2]
    return out.astype(np.float32)


def synth_cloud(seed: int = 0) -> np.ndarray | str:
    """The project's synthetic structured-light scan of a bin of parts (or why it could not be made)."""
    try:
        from replay.synth import synthesize_frame

        return np.asarray(synthesize_frame(kind="spheres", seed=seed, size=FULL).frame.xyz)
    except Exception as e:  # noqa: BLE001 - an optional class: any failure only skips it
        return f"{type(e).__name__}: {e}"


def read_pcd(path: Path) -> np.ndarray:
    """(HEIGHT, WIDTH, 3) points of an organized PCD, NaN kept (Open3D's reader)."""
    import open3d as o3d

    width = height = None
    with open(path, "rb") as f:
        for line in f:
            key = line.split(maxsplit=1)[:1]
            if key == [b"WIDTH"]:
                width = int(line.split()[1])
            elif key == [b"HEIGHT"]:
                height = int(line.split()[1])
            elif key == [b"DATA"]:
                break
    cloud = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    return np.asarray(cloud.points).reshape(height, width, 3)


def cloud_classes(seed: int) -> dict[str, object]:
    """Class name -> function returning the cloud (lazily: they take seconds to make)."""
    classes: dict[str, object] = {
        "pile": lambda: pile_cloud(seed),
        "blobs5": lambda: blobs_cloud(seed, invalid_frac=0.05),
        "blobs20": lambda: blobs_cloud(seed, invalid_frac=0.20),
        "holes-walls": lambda: blobs_cloud(seed, invalid_frac=0.40, plateaus=40, plateau_m=(0.08, 0.30)),
        "walls": lambda: walls_cloud(seed),
        "sparse": lambda: sparse_cloud(seed),
        "negative-z": lambda: negative_z_cloud(seed),
        "mixed-z": lambda: mixed_z_cloud(seed),
        "distorted": lambda: pile_cloud(seed, k1=0.05),
        "steep": lambda: steep_cloud(seed),
        "synth": lambda: synth_cloud(seed),
    }
    for path in sorted(REAL_DATA.glob("*.pcd")) if REAL_DATA_PROBLEM is None else []:
        classes[f"kinect/{path.stem[:18]}"] = lambda path=path: read_pcd(path)
    return classes


# ------------------------------------------------------------------------------------------------
# measurement
# ------------------------------------------------------------------------------------------------
def cpu_best(fn, repeat: int) -> tuple[float, object]:
    """Smallest CPU time (all threads of the process) of ``repeat`` calls, and the last result
    (bench/bench_bank.py's yardstick)."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t0)
    return best, out


def cpu_median(fn, repeat: int) -> tuple[float, object]:
    """Median CPU time (all threads of the process) of ``repeat`` calls, and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return float(np.median(times)), out


def warm_up(k: int) -> None:
    """JIT compile / cache load of every path of zcut.sor (not timed)."""
    from zcut.sor import sor_outliers

    warm = np.random.default_rng(0).normal(size=(40, 40, 3))
    for convention in ("pcl", "open3d"):
        sor_outliers(warm, k=k, convention=convention)
        sor_outliers(pile_cloud(0, height=60, width=90), k=k, convention=convention)


def time_both(xyz: np.ndarray, k: int, std_ratio: float, repeat: int) -> dict[str, tuple[float, np.ndarray]]:
    """Convention -> (median CPU s, outlier mask) of zcut.sor_outliers (whichever zcut is imported)."""
    from zcut.sor import sor_outliers

    return {c: cpu_median(lambda c=c: sor_outliers(xyz, k=k, std_ratio=std_ratio, convention=c), repeat)
            for c in ("pcl", "open3d")}


class Previous:
    """The zcut of the source tree ``tree`` in a subprocess that lives for the whole run (this
    file's ``--serve`` mode), asked for one timed call at a time, so that its calls and this
    code's alternate."""

    def __init__(self, tree: Path, scratch: Path) -> None:
        import subprocess

        self.scratch = scratch
        self.proc = subprocess.Popen([sys.executable, __file__, "--serve"], env=dict(os.environ, PYTHONPATH=str(tree)),
                                     cwd=str(tree), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask(self, *words: object) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(" ".join(map(str, words)) + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        if not answer.startswith("done"):
            raise RuntimeError(f"the previous code's process failed on {words!r}: {answer!r}")
        return answer

    def cloud(self, cloud: Path, k: int, std_ratio: float) -> dict[str, tuple[float, np.ndarray]]:
        """Convention -> (CPU s, mask) of one call of the previous sor_outliers on the saved cloud."""
        out = self.scratch / "prev.npz"
        self.ask("cloud", cloud, out, k, std_ratio)
        with np.load(out) as f:
            return {c: (float(f[f"t_{c}"]), f[f"m_{c}"]) for c in ("pcl", "open3d")}

    def close(self) -> None:
        if self.proc.poll() is None:
            self.ask("quit")
            self.proc.wait()


def _serve() -> int:
    """The previous code's side of :class:`Previous`: one command a line on stdin, "done" on stdout."""
    import zcut

    assert str(Path(zcut.__file__).resolve()).startswith(os.path.realpath(os.getcwd())), zcut.__file__
    stage: list[tuple[object, ...]] = []
    warmed: set[int] = set()
    for line in sys.stdin:
        words = line.split()
        if words[0] == "quit":
            print("done", flush=True)
            return 0
        if words[0] == "cloud":
            cloud, out, k, std_ratio = words[1], words[2], int(words[3]), float(words[4])
            if k not in warmed:
                warm_up(k)
                warmed.add(k)
            res = time_both(np.load(cloud), k, std_ratio, 1)
            np.savez(out, **{f"t_{c}": t for c, (t, _) in res.items()}, **{f"m_{c}": m for c, (_, m) in res.items()})
        elif words[0] == "stage-open":
            stage = stage_zones(Path(words[1]), int(words[2]) if len(words) > 2 else 0)
            print(f"done {len(stage)}", flush=True)
            continue
        elif words[0] == "stage":
            t, mask = time_stage(stage[int(words[1])])
            np.savez(words[2], t=t, mask=mask)
        print("done", flush=True)
    return 0


def open3d_outliers(pts: np.ndarray, valid: np.ndarray, k: int, std_ratio: float, repeat: int) -> tuple[float, np.ndarray]:
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    t, (_, kept) = cpu_median(lambda: pcd.remove_statistical_outlier(nb_neighbors=k, std_ratio=std_ratio), repeat)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = ~keep
    return t, out


def stage_zones(log: Path, frames: int = 0) -> list[tuple[object, ...]]:
    """(frame, zone, config) of every frame of ``log`` (its first ``frames`` when > 0) after the bin stages (its
    own bin model, its config) and the methods the config runs before SOR (the z-cut: what it notes on the zone,
    SOR reads, as in a replay; not timed), ready for the pipeline's SOR stage."""
    from replay.pipeline import stages
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.methods import registry
    from replay.pipeline.session import ReplaySession

    warm_up(4)
    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    config = session.config
    methods = config.base_methods
    before = [registry()[m] for m in methods[:methods.index("sor")]] if "sor" in methods else []
    out: list[tuple[object, ...]] = []
    for frame in session.reader.frames(stop=frames or None):
        located = stages.locate_bin(frame, config, bin_model=session.prepared, seed=session.seed)
        zone = stages.bin_zone(frame, config, bin_model=session.prepared, located=located)
        for method in before:
            method.run(frame, zone, config)
        out.append((frame, zone, config))
    return out


def time_stage(item: tuple[object, ...]) -> tuple[float, np.ndarray]:
    """CPU s and mask of one call of the pipeline's SOR stage (``sor_on_zone``) on a prepared frame."""
    from replay.pipeline.zone import sor_on_zone

    frame, zone, config = item
    t, mask = cpu_median(lambda: sor_on_zone(frame, zone, config), 1)  # type: ignore[arg-type]  # stage_zones' items
    return t, np.asarray(mask)


def stage_main(log: Path, against: Path | None, repeat: int, frames: int = 0) -> int:
    """Print the SOR stage's CPU ms per frame of ``log`` (its first ``frames`` when > 0), this code and
    (``against``) the previous, alternately (frame by frame, the order flipping every round); medians of
    ``repeat`` rounds."""
    import tempfile

    print(f"SOR stage of {log}: CPU ms (all threads), median of {repeat} rounds; load average {load_average()}"
          + (f"; previous code: {against}, alternately" if against else ""), flush=True)
    zones = stage_zones(log, frames)
    scratch = tempfile.TemporaryDirectory(prefix="bench-sor-")
    prev = Previous(against, Path(scratch.name)) if against is not None else None
    if prev is not None:
        prev.ask("stage-open", log, frames)
    times: list[list[float]] = [[] for _ in zones]
    prev_t: list[list[float]] = [[] for _ in zones]
    masks: list[np.ndarray] = [np.zeros(0, bool)] * len(zones)
    prev_m: list[np.ndarray] = [np.zeros(0, bool)] * len(zones)
    for rnd in range(repeat):
        for i, item in enumerate(zones):
            for who in (("this", "prev") if rnd % 2 == 0 else ("prev", "this")):
                if who == "this":
                    t, masks[i] = time_stage(item)
                    times[i].append(t)
                elif prev is not None:
                    out = Path(scratch.name) / "stage.npz"
                    prev.ask("stage", i, out)
                    with np.load(out) as f:
                        prev_t[i].append(float(f["t"]))
                        prev_m[i] = f["mask"]
    if prev is not None:
        prev.close()
    scratch.cleanup()
    med = [float(np.median(t)) for t in times]
    pmed = [float(np.median(t)) for t in prev_t] if prev is not None else []
    print(f"{'frame':>5s} {'outliers':>10s} {'this ms':>8s}" + (f" {'prev ms':>8s} {'prev/this':>9s} same" if pmed else ""))
    for i, (t, m) in enumerate(zip(med, masks, strict=True)):
        line = f"{i:5d} {int(m.sum()):10d} {1000 * t:8.1f}"
        if pmed:
            line += f" {1000 * pmed[i]:8.1f} {pmed[i] / t:8.2f}x {'yes' if np.array_equal(m, prev_m[i]) else 'NO'}"
        print(line)
    line = f"{'median':>5s} {'':10s} {1000 * float(np.median(med)):8.1f}"
    if pmed:
        line += f" {1000 * float(np.median(pmed)):8.1f} {float(np.median(pmed)) / float(np.median(med)):8.2f}x"
    print(line)
    print(f"load average at the end: {load_average()}")
    return 0


def faults_main(classes: dict[str, object], k: int, std_ratio: float, repeat: int, between: str) -> int:
    """Per class and convention: medians of CPU ms, system ms and minor page faults of a call."""
    import resource

    import numba

    import zcut
    from zcut.sor import sor_outliers

    warm_up(k)
    print(f"zcut {Path(zcut.__file__).parent}, {numba.config.NUMBA_NUM_THREADS} threads, "
          f"{'Open3D between the calls' if between == 'open3d' else 'calls in a row'}, medians of {repeat} calls "
          f"after a first one; load average {load_average()}")
    print(f"{'class':26s} {'conv':6s} {'CPU ms':>8s} {'sys ms':>7s} {'faults':>8s}  (faults: min-max)")
    for name, make in classes.items():
        xyz = make()
        if isinstance(xyz, str):
            print(f"{name:26s} (skipped: {xyz})")
            continue
        valid = np.isfinite(xyz).all(axis=2)
        pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
        kept = []  # the caller keeps its masks
        for convention in ("pcl", "open3d"):
            rows = []
            for _ in range(repeat + 1):
                if between == "open3d":
                    open3d_outliers(pts, valid, k, std_ratio, 1)
                r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.process_time()
                kept.append(sor_outliers(xyz, k=k, std_ratio=std_ratio, convention=convention))
                t1, r1 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
                rows.append(((t1 - t0) * 1e3, (r1.ru_stime - r0.ru_stime) * 1e3, r1.ru_minflt - r0.ru_minflt))
            cpu, sys_ms, faults = np.median(np.array(rows[1:]), axis=0)
            lo, hi = min(r[2] for r in rows[1:]), max(r[2] for r in rows[1:])
            print(f"{name:26s} {convention:6s} {cpu:8.1f} {sys_ms:7.1f} {faults:8.0f}  ({lo}-{hi})", flush=True)
    print(f"load average at the end: {load_average()}")
    return 0


def _timed_parts(spent: dict[str, float]) -> None:
    """Wrap zcut.sor's thread runner (every kernel it runs: ``run: NAME``) and the steps around the kernels so that
    each adds its CPU seconds (all threads, ``time.process_time``) to ``spent[NAME]`` (this process only)."""
    import contextlib

    import zcut.sor as sor
    from zcut import columns, sor_camera, sor_search, sor_window

    def timed(module: object, name: str) -> None:
        fn = getattr(module, name)

        def wrapper(*args: object, **kw: object) -> object:
            t0 = time.process_time()
            try:
                return fn(*args, **kw)
            finally:
                spent[name] = spent.get(name, 0.0) + time.process_time() - t0

        setattr(module, name, wrapper)

    workers = sor._workers

    @contextlib.contextmanager
    def timed_workers(ws):
        with workers(ws) as run:
            def timed_run(kernel, n, *args):
                t0 = time.process_time()
                run(kernel, n, *args)
                key = "run: " + getattr(kernel, "__name__", repr(kernel))
                spent[key] = spent.get(key, 0.0) + time.process_time() - t0

            yield timed_run

    sor._workers = timed_workers
    masks = "_outlier_masks_spans" if hasattr(sor, "_outlier_masks_spans") else "_outlier_masks"
    for module, name in ((sor, "_prepare"), (sor, "_mean_distances"), (sor, "_fallback"), (sor, "_column_stage"),
                         (sor, masks), (sor_camera, "fit_camera"), (sor_camera, "band_tables"),
                         (sor_camera, "corner_tables"), (sor_window, "unproven_pixels"), (sor_search, "build_quadtree"),
                         (sor_search, "valid_range"), (columns, "mark_columns"), (columns, "count_columns"),
                         (columns, "fill_columns")):
        timed(module, name)


def phases_main(classes: dict[str, object], k: int, std_ratio: float, repeat: int) -> int:
    """Per class and convention: where the CPU time of a ``sor_outliers`` call goes (medians of
    --repeat calls after a first one, CPU ms of all threads): every kernel the call runs on its
    threads (``run: NAME``, see ``zcut.sor._workers``) and the steps around them, timed by wrapping
    them in this process. The steps nest (``_mean_distances`` holds the window phase and the fallback,
    ``_fallback`` the tile and column searches), so the column does not add up."""
    import numba

    import zcut
    import zcut.sor as sor

    spent: dict[str, float] = {}
    _timed_parts(spent)
    warm_up(k)
    print(f"zcut {Path(zcut.__file__).parent}, {numba.config.NUMBA_NUM_THREADS} threads, CPU ms of a sor_outliers "
          f"call and of its parts, medians of {repeat} calls after a first one; load average {load_average()}")
    for name, make in classes.items():
        xyz = make()
        if isinstance(xyz, str):
            print(f"{name:26s} (skipped: {xyz})")
            continue
        for convention in ("pcl", "open3d"):
            rows = []
            for _ in range(repeat + 1):
                spent.clear()
                t0 = time.process_time()
                sor.sor_outliers(xyz, k=k, std_ratio=std_ratio, convention=convention)
                rows.append({"call": time.process_time() - t0, **spent})
            rows = rows[1:]
            keys = sorted(set().union(*rows), key=lambda key: -float(np.median([r.get(key, 0.0) for r in rows])))
            parts = ", ".join(f"{key} {1e3 * float(np.median([r.get(key, 0.0) for r in rows])):.1f}" for key in keys)
            print(f"{name:26s} {convention:6s} {parts}", flush=True)
    print(f"load average at the end: {load_average()}")
    return 0


def stage_phases_main(log: Path, repeat: int, frames: int = 0) -> int:
    """Where the CPU time of the pipeline's SOR stage goes on the frames of ``log`` (``--stage LOG --phases``): per
    kernel and step (as :func:`phases_main`), CPU ms a frame (the sum over the frames, divided by their number),
    medians of --repeat passes over the frames after a first one."""
    import numba

    import zcut

    zones = stage_zones(log, frames)
    spent: dict[str, float] = {}
    _timed_parts(spent)
    print(f"zcut {Path(zcut.__file__).parent}, {numba.config.NUMBA_NUM_THREADS} threads; the SOR stage of {log} "
          f"({len(zones)} frames): CPU ms a frame of the stage and of its parts, medians of {repeat} passes after a "
          f"first one; load average {load_average()}")
    passes: list[dict[str, float]] = []
    for _ in range(repeat + 1):
        total: dict[str, float] = {}
        for item in zones:
            spent.clear()
            t, _mask = time_stage(item)
            for key, value in {"stage": t, **spent}.items():
                total[key] = total.get(key, 0.0) + value
        passes.append(total)
    passes = passes[1:]
    keys = sorted(set().union(*passes), key=lambda key: -float(np.median([p.get(key, 0.0) for p in passes])))
    for key in keys:
        values = [1e3 * p.get(key, 0.0) / len(zones) for p in passes]
        print(f"{key:28s} {float(np.median(values)):8.2f}   ({', '.join(f'{v:.2f}' for v in values)})")
    print(f"load average at the end: {load_average()}")
    return 0


def load_average() -> str:
    try:
        return " ".join(f"{v:.1f}" for v in os.getloadavg())
    except OSError:  # not on this platform
        return "unknown"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--std-ratio", type=float, default=1.0)
    parser.add_argument("--classes", default="", help="comma-separated class names or prefixes (default: all)")
    parser.add_argument("--no-reference", action="store_true", help="skip the exact pcl reference (KD-tree, slow)")
    parser.add_argument("--against", metavar="OLD_TREE", type=Path,
                        help="also time the previous code of this source tree on every cloud, and compare its masks")
    parser.add_argument("--stage", metavar="LOG", type=Path,
                        help="time the pipeline's SOR stage on every frame of this log instead of the classes")
    parser.add_argument("--frames", type=int, default=0,
                        help="--stage: the log's first N frames only (default 0: every frame)")
    parser.add_argument("--faults", choices=("row", "open3d"),
                        help="print CPU ms, system ms and page faults a call (calls in a row, or Open3D between them)")
    parser.add_argument("--phases", action="store_true",
                        help="print where the CPU time of a call goes, per kernel and step (no Open3D)")
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()

    configure_process()
    if args.serve:
        return _serve()
    if args.stage and args.phases:
        return stage_phases_main(args.stage, args.repeat, args.frames)
    if args.stage:
        return stage_main(args.stage, args.against, args.repeat, args.frames)
    if args.phases:
        chosen = cloud_classes(args.seed)
        wanted = [c for c in args.classes.split(",") if c]
        if wanted:
            chosen = {name: f for name, f in chosen.items() if any(name.startswith(w) for w in wanted)}
        return phases_main(chosen, args.k, args.std_ratio, args.repeat)
    if args.faults:
        chosen = cloud_classes(args.seed)
        wanted = [c for c in args.classes.split(",") if c]
        if wanted:
            chosen = {name: f for name, f in chosen.items() if any(name.startswith(w) for w in wanted)}
        return faults_main(chosen, args.k, args.std_ratio, args.repeat, args.faults)
    import tempfile

    import numba

    sys.path.insert(0, str(ROOT / "tests" / "reference"))  # not tests/: its folders mirror the packages
    from sor_reference import sor_outliers_reference

    classes = cloud_classes(args.seed)
    wanted = [c for c in args.classes.split(",") if c]
    if wanted:
        classes = {name: f for name, f in classes.items() if any(name.startswith(w) for w in wanted)}

    warm_up(args.k)
    print(f"k={args.k} std_ratio={args.std_ratio} repeat={args.repeat} seed={args.seed}, {os.cpu_count()} cores, "
          f"zcut on {numba.config.NUMBA_NUM_THREADS} threads; CPU s = process time of all threads, median of "
          f"{args.repeat} rounds; load average {load_average()}"
          + (f"; previous code: {args.against}, alternately" if args.against else ""))
    header = f"{'class':26s} {'conv':6s} {'H x W':>11s} {'n valid':>9s} {'zcut s':>8s} {'Open3D s':>9s} {'ratio':>7s}"
    if args.against:
        header += f" {'prev s':>8s} {'prev/this':>9s} {'same as prev':>12s}"
    header += "  identical"
    print(header)
    print("-" * len(header))
    worst = np.inf
    ran: list[str] = []
    skipped: dict[str, str] = {}
    if REAL_DATA_PROBLEM is not None:
        print(f"WARNING: no real-data class will run: {REAL_DATA_PROBLEM}", file=sys.stderr, flush=True)
    scratch = tempfile.TemporaryDirectory(prefix="bench-sor-")
    previous = Previous(args.against, Path(scratch.name)) if args.against else None
    for name, make in classes.items():
        xyz = make()
        if isinstance(xyz, str):
            print(f"{name:26s} (skipped: {xyz})")
            skipped[name] = xyz
            continue
        ran.append(name)
        valid = np.isfinite(xyz).all(axis=2)
        pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
        t_o3d, want_o3d, mine, prev = alternate(xyz, pts, valid, args.k, args.std_ratio, args.repeat, previous,
                                                Path(scratch.name))
        for convention in ("pcl", "open3d"):
            t, got = mine[convention]
            if convention == "open3d":
                same = "yes" if np.array_equal(got, want_o3d) else f"NO ({int((got != want_o3d).sum())} px)"
            elif args.no_reference:
                same = "(not checked)"
            else:
                want = sor_outliers_reference(xyz, k=args.k, std_ratio=args.std_ratio, convention="pcl", method="kdtree")
                same = "yes" if np.array_equal(got, want) else f"NO ({int((got != want).sum())} px)"
            worst = min(worst, t_o3d / t)
            shape = f"{xyz.shape[0]}x{xyz.shape[1]}"
            line = f"{name:26s} {convention:6s} {shape:>11s} {pts.shape[0]:9d} {t:8.3f} {t_o3d:9.3f} {t_o3d / t:6.1f}x"
            if prev is not None:
                t_prev, m_prev = prev[convention]
                as_prev = "yes" if np.array_equal(got, m_prev) else f"NO ({int((got != m_prev).sum())} px)"
                line += f" {t_prev:8.3f} {t_prev / t:8.2f}x {as_prev:>12s}"
            print(f"{line}  {same}", flush=True)
    if previous is not None:
        previous.close()
    scratch.cleanup()
    for line in summary(ran, skipped, worst, real_problem=REAL_DATA_PROBLEM):
        print(line)
    print(f"load average at the end: {load_average()}")
    return 0


def alternate(xyz: np.ndarray, pts: np.ndarray, valid: np.ndarray, k: int, std_ratio: float, rounds: int,
              previous: Previous | None, scratch: Path) -> tuple[float, np.ndarray, dict[str, tuple[float, np.ndarray]],
                                                                 dict[str, tuple[float, np.ndarray]] | None]:
    """Open3D, this code and (``previous``) the previous code once each per round, this and the
    previous in an order that flips every round; the medians over the rounds and the last masks:
    (Open3D s, Open3D's mask, this code's {convention: (s, mask)}, the previous code's or None)."""
    cloud = scratch / "cloud.npy"
    if previous is not None:
        np.save(cloud, xyz)
    t_o3d: list[float] = []
    want_o3d = np.zeros(0, bool)
    mine: dict[str, list[tuple[float, np.ndarray]]] = {"pcl": [], "open3d": []}
    prev: dict[str, list[tuple[float, np.ndarray]]] = {"pcl": [], "open3d": []}
    for rnd in range(rounds):
        t, want_o3d = open3d_outliers(pts, valid, k, std_ratio, 1)
        t_o3d.append(t)
        for who in (("this", "prev") if rnd % 2 == 0 else ("prev", "this")):
            if who == "this":
                for c, res in time_both(xyz, k, std_ratio, 1).items():
                    mine[c].append(res)
            elif previous is not None:
                for c, res in previous.cloud(cloud, k, std_ratio).items():
                    prev[c].append(res)

    def med(runs: dict[str, list[tuple[float, np.ndarray]]]) -> dict[str, tuple[float, np.ndarray]]:
        return {c: (float(np.median([t for t, _ in r])), r[-1][1]) for c, r in runs.items()}

    return float(np.median(t_o3d)), want_o3d, med(mine), med(prev) if previous is not None else None


def is_real(name: str) -> bool:
    return name.startswith("kinect/")


def summary(ran: list[str], skipped: dict[str, str], worst: float, *, real_problem: str | None) -> list[str]:
    """The closing lines: which classes ran (real ones named apart), which did not and why, and the
    minimum ratio, called the smallest only when a real class is among those it is taken over."""
    real = [c for c in ran if is_real(c)]
    lines = [f"classes run ({len(ran)}): {', '.join(ran) or 'none'}",
             f"real-data classes run ({len(real)}): {', '.join(real) or 'NONE'}"]
    lines += [f"not run: {name}: {why}" for name, why in skipped.items()]
    if not ran:
        return [*lines, "no class ran: no ratio"]
    if real:
        return [*lines, f"smallest ratio: {worst:.1f}x (over {len(ran)} classes, {len(real)} of real data)"]
    why = real_problem or "none was chosen (--classes)"
    return [*lines, f"WARNING: no real-data class ran: {why}",
            f"minimum ratio over the synthetic classes only: {worst:.1f}x (not the smallest: real clouds were "
            "not measured)"]


if __name__ == "__main__":
    raise SystemExit(main())
