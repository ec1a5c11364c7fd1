"""Clean organized clouds of posed meshes, ray cast with Open3D's RaycastingScene (test helper)."""

from __future__ import annotations

import numpy as np

#: (fx, fy, cx, cy) of a small test camera
K_TEST = (500.0, 500.0, 159.5, 119.5)
SIZE = (240, 320)


def rotation(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    t = np.radians(deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * (K @ K)
    return R


def pose(R: np.ndarray, t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def render(meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]], *, K: tuple[float, float, float, float] = K_TEST,
           size: tuple[int, int] = SIZE, floor_z_mm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (H, W, 3) mm, id (H, W) int: 0 floor / nothing, i + 1 the i-th mesh) of ``meshes``
    given as (vertices, triangles, pose model -> camera), with an optional floor plane z = const.

    Open3D's ray casting (Embree) says which mesh and triangle each pixel's ray hits; the depth is Möller–Trumbore's
    in float64 on that triangle's float64 corners (:func:`zcut.ray_hits.mesh_hit_t`), so that the scene's bytes do not
    depend on the CPU (Embree's float32 ``t_hit`` does in its last bits: docs/fits.md, "The fits' ray casts exact")."""
    import open3d as o3d

    from zcut.ray_hits import mesh_hit_t

    scene = o3d.t.geometry.RaycastingScene()
    posed: list[tuple[np.ndarray, np.ndarray]] = []
    for v, t, T in meshes:
        posed.append((np.asarray(v, np.float64) @ T[:3, :3].T + T[:3, 3], np.asarray(t, np.int64)))
    if floor_z_mm is not None:
        s = 5000.0
        posed.append((np.array([[-s, -s, floor_z_mm], [s, -s, floor_z_mm], [s, s, floor_z_mm], [-s, s, floor_z_mm]]),
                      np.array([[0, 1, 2], [0, 2, 3]], np.int64)))
    for vc, t in posed:
        scene.add_triangles(o3d.core.Tensor(vc.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    # every geometry's triangles in one table: geometry g's triangle p is row first[g] + p
    vertices = np.concatenate([vc for vc, _ in posed])
    first_vertex = np.cumsum([0] + [len(vc) for vc, _ in posed])
    triangles = np.concatenate([t + first_vertex[g] for g, (_, t) in enumerate(posed)])
    first = np.cumsum([0] + [len(t) for _, t in posed])
    H, W = size
    fx, fy, cx, cy = K
    rr, cc = np.mgrid[0:H, 0:W]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones((H, W))], axis=-1)
    rays = np.concatenate([np.zeros((H, W, 3)), d], axis=-1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t32 = ans["t_hit"].numpy().reshape(-1)
    hit = np.isfinite(t32)
    gid = ans["geometry_ids"].numpy().astype(np.int64).reshape(-1)
    prim = np.zeros(t32.shape, np.int64)
    prim[hit] = first[gid[hit]] + ans["primitive_ids"].numpy().astype(np.int64).reshape(-1)[hit]
    t_hit = np.empty(t32.shape)
    mesh_hit_t(t32, prim, np.zeros((1, 3)), np.ascontiguousarray(d.reshape(-1, 3)), vertices, triangles, t_hit)
    t_hit = t_hit.reshape(H, W)
    xyz = d * t_hit[..., None]  # d has z = 1: t_hit is the depth
    xyz[~np.isfinite(t_hit)] = np.nan
    ids = np.where(np.isfinite(t_hit) & (gid.reshape(H, W) < len(meshes)), gid.reshape(H, W) + 1, 0)
    return xyz, ids


def hex_nut_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The hand-made generator's zinc nut (M12: 18 mm across flats, 10.8 mm high, 10.5 mm bore)."""
    from replay.synth.surfaces import kind_model_mesh

    return kind_model_mesh("zinc_nuts")


def icosphere(radius: float, level: int = 3) -> tuple[np.ndarray, np.ndarray]:
    from replay.synth.raytrace.meshes import _icosphere

    m = _icosphere(radius, level)
    return np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int64)


def hand_made_nut_frame() -> tuple[np.ndarray, np.ndarray, object, tuple[float, float, float, float]]:
    """A hand-made zinc-nut frame (seed 5, 300 × 480) in mm, its zone (the parts and the truths), the prepared nut
    model and the intrinsics (:func:`fit_digests.hand_made`)."""
    from fit_digests import hand_made

    xyz, zone, model, K = hand_made("zinc_nuts")
    assert K is not None
    return xyz, zone, model, K


def segment_cloud(rng: np.random.Generator, H: int, W: int, nan_share: float) -> np.ndarray:
    """(H, W, 3) a random-walk cloud with 4 mm steps in depth and a share of NaN pixels: the segmentation tests' input."""
    xyz = np.stack([rng.normal(0, 1, (H, W)).cumsum(axis=1), rng.normal(0, 1, (H, W)).cumsum(axis=0),
                    300 + rng.choice([0.0, 0.0, 0.0, 4.0], size=(H, W)) + rng.normal(0, 0.3, (H, W))], axis=-1)
    xyz[rng.random((H, W)) < nan_share] = np.nan
    return xyz


def same_regions(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    """Two segmentations' regions equal, in order, dtype included."""
    return len(a) == len(b) and all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(a, b))
