"""A tiny ray-cast bin scene for the pipeline tests: boxes seen by a pinhole camera looking down +z.

Table: dark plane at z = 0.60 m. Bin: bright plastic, a floor slab and four walls (rim at z = 0.50 m).
Parts: mid-gray boxes lying on the floor. Flying pixels can be added as a few floating specks.
Everything is exact geometry, so the tests know the truth of every pixel.
"""

from __future__ import annotations

import numpy as np

from replay.logs.frame import Frame
from zcut.cloud import Intrinsics

TABLE_Z = 0.60
RIM_Z = 0.50
FLOOR_Z = 0.585  # top of the floor slab
WALL = 0.008
HALF = (0.10, 0.075)  # outer half extents (x, y)

DARK, BRIGHT, PART = (40, 40, 45), (220, 220, 210), (120, 110, 100)


def intrinsics(h: int = 120, w: int = 160) -> Intrinsics:
    f = 0.9 * w  # ~ 0.3 m wide view at 0.5 m
    return Intrinsics(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)


def bin_boxes(shift=(0.0, 0.0, 0.0)) -> list[tuple[np.ndarray, np.ndarray]]:
    hx, hy = HALF
    s = np.asarray(shift, float)
    boxes = [
        ((-hx, -hy, FLOOR_Z), (hx, hy, TABLE_Z)),  # floor slab
        ((-hx, -hy, RIM_Z), (-hx + WALL, hy, TABLE_Z)),
        ((hx - WALL, -hy, RIM_Z), (hx, hy, TABLE_Z)),
        ((-hx, -hy, RIM_Z), (hx, -hy + WALL, TABLE_Z)),
        ((-hx, hy - WALL, RIM_Z), (hx, hy, TABLE_Z)),
    ]
    return [(np.array(lo) + s, np.array(hi) + s) for lo, hi in boxes]


def part_boxes(shift=(0.0, 0.0, 0.0)) -> list[tuple[np.ndarray, np.ndarray]]:
    s = np.asarray(shift, float)
    parts = [
        ((-0.05, -0.03, FLOOR_Z - 0.02), (-0.01, 0.02, FLOOR_Z)),
        ((0.01, -0.04, FLOOR_Z - 0.03), (0.06, 0.00, FLOOR_Z)),
        ((0.00, 0.02, FLOOR_Z - 0.025), (0.05, 0.05, FLOOR_Z)),
    ]
    return [(np.array(lo) + s, np.array(hi) + s) for lo, hi in parts]


def render(K: Intrinsics, boxes, colours) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast axis-aligned boxes over a table plane. Returns xyz (H, W, 3) float32 and rgb."""
    v, u = np.mgrid[0:K.height, 0:K.width].astype(np.float64)
    d = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], -1)
    best = np.full(u.shape, TABLE_Z)  # ray parameter t == z since d_z = 1
    rgb = np.empty(u.shape + (3,), np.uint8)
    rgb[:] = DARK
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        for (lo, hi), col in zip(boxes, colours):
            t1 = (lo - 0.0) * inv
            t2 = (hi - 0.0) * inv
            tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (tmax >= tmin) & (tmin > 0) & (tmin < best)
            best = np.where(hit, tmin, best)
            rgb[hit] = col
    xyz = (d * best[..., None]).astype(np.float32)
    return xyz, rgb


def scene(*, h: int = 120, w: int = 160, shift=(0.0, 0.0, 0.0), parts: bool = True,
          specks: int = 0, seed: int = 0) -> tuple[Frame, np.ndarray]:
    """A frame of the bin (shifted by ``shift`` metres) and the mask of its floating specks."""
    K = intrinsics(h, w)
    boxes = bin_boxes(shift) + (part_boxes(shift) if parts else [])
    colours = [BRIGHT] * 5 + [PART] * (len(boxes) - 5)
    xyz, rgb = render(K, boxes, colours)
    truth = np.zeros((h, w), bool)
    if specks:
        rng = np.random.default_rng(seed)
        # specks: single pixels on the parts lifted 15 mm above their neighbours
        on_part = (rgb == np.array(PART, np.uint8)).all(axis=2)
        on_part[:2] = on_part[-2:] = False
        on_part[:, :2] = on_part[:, -2:] = False
        cand = np.flatnonzero(on_part)
        picks = rng.choice(cand, size=min(specks, cand.size), replace=False) if cand.size else []
        for r, c in (divmod(int(i), w) for i in picks):
            if truth[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].any():
                continue
            xyz[r, c] *= np.float32((xyz[r, c, 2] - 0.015) / xyz[r, c, 2])
            truth[r, c] = True
    frame = Frame(xyz=xyz, rgb=rgb, stamp_ns=1_000_000_000, frame_id="camera", intrinsics=K,
                  topic="/camera/points", index=0, masks={"/ground_truth/outliers": truth})
    return frame, truth


def bin_pixels(frame: Frame) -> np.ndarray:
    """(H, W) bool: the pixels that see the bin (its bright plastic)."""
    return (frame.rgb == np.array(BRIGHT, np.uint8)).all(axis=2)


def model_from_empty(*, h: int = 120, w: int = 160) -> np.ndarray:
    """(N, 3) float64 points of the empty bin at its nominal pose (the bright pixels)."""
    frame, _ = scene(h=h, w=w, parts=False)
    return frame.xyz[bin_pixels(frame)].astype(np.float64)


#: The shift (m) of the bin in :func:`filled_bin_scene` from the pose :func:`shifted_bin_model` is built at.
SHIFT = (0.006, -0.004, 0.003)


def filled_bin_scene() -> tuple[Frame, np.ndarray]:
    """A 240 x 320 frame of the filled bin shifted by :data:`SHIFT`, with 12 flying specks (seed 3)."""
    return scene(h=240, w=320, shift=SHIFT, specks=12, seed=3)


def shifted_bin_model():
    """The bin model built from five 240 x 320 frames of the empty bin, at its pose and 2 cm off it
    along x and y (``replay.pipeline.bin_model.build_bin_model``, 1 mm voxels); every frame used."""
    import dataclasses

    from replay.pipeline.bin_model import build_bin_model
    from zcut.params import RegistrationParams

    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = scene(h=240, w=320, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    m, reports = build_bin_model(frames, registration=RegistrationParams(voxel_mm=1.0), voxel_mm=1.0)
    assert all(r.skipped == "" for r in reports)
    return m


def resolved_config(layer: dict, shape: tuple[int, int] = (240, 320)):
    """The pipeline config resolved from a config layer, for a frame of ``shape`` without metadata."""
    from replay.pipeline import config as cfg

    return cfg.resolve(cfg.LogFacts(None, None, None, shape), file_layer=layer).config


def prepared(model, config):
    """The bin model prepared for ``config`` (what a replay session builds once)."""
    from zcut.prepared_model import prepare_bin_model

    return prepare_bin_model(model, registration=config.registration, removal=config.removal)


def turned_pose(deg_xyz, t) -> np.ndarray:
    """4 x 4 rigid pose: rotations about x, then y, then z by ``deg_xyz`` degrees (R = Rz @ Ry @ Rx), then the
    translation ``t`` (the registration tests' perturbed and true poses)."""
    a, b, c = np.radians(deg_xyz)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = t
    return T
