"""zcut.explained.nearest_surface's bounded search of the bin model's samples gives what the unbounded
search gave (the previous code, kept here as the oracle): the same distance and the same nearest
surface at every pixel, on a sampled bin (floor and walls) with part boxes, a table plane, points on
every surface, flying between them and far above them, with and without parts and table."""

from __future__ import annotations

import numpy as np
import pytest
from explained_helpers import box_mesh as _box

from zcut import explained as ex
from zcut.errors import InputShapeError


def _bin(spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """A bin's samples with normals (toward the camera at the origin): a floor at z = 800 mm over
    ±150 mm and two walls at x = ±150 up to z = 700."""
    g = np.arange(-150.0, 150.0 + 1e-9, spacing)
    X, Y = np.meshgrid(g, g)
    floor = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 800.0)])
    h = np.arange(700.0, 800.0 + 1e-9, spacing)
    Yw, Zw = np.meshgrid(g, h)
    walls = [np.column_stack([np.full(Yw.size, s * 150.0), Yw.ravel(), Zw.ravel()]) for s in (-1, 1)]
    pts = np.concatenate([floor, *walls])
    nrm = np.concatenate([np.tile([0.0, 0.0, -1.0], (len(floor), 1)),
                          np.tile([1.0, 0.0, 0.0], (len(walls[0]), 1)), np.tile([-1.0, 0.0, 0.0], (len(walls[1]), 1))])
    return pts, nrm


def _oracle(xyz: np.ndarray, surfaces: ex.KnownSurfaces) -> ex.Nearest:
    """The previous nearest_surface (commit c9a5f5c), verbatim but for its checks: the meshes, then the
    bin's samples searched unbounded, then the table, each nearer surface replacing the one before."""
    import open3d as o3d

    valid = np.isfinite(xyz).all(axis=2)
    p = xyz[valid].astype(np.float64)
    dist = np.full(len(p), np.inf)
    code = np.full(len(p), ex.SURFACE_NONE, np.int32)

    def better(d, c):
        b = d < dist
        dist[b] = d[b]
        code[b] = c[b] if isinstance(c, np.ndarray) else c

    meshes = [(v, t, i) for i, (v, t) in enumerate(surfaces.parts)]
    if meshes:
        scene = o3d.t.geometry.RaycastingScene()
        codes = {}
        for v, t, c in meshes:
            gid = scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                                      o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))
            codes[int(gid)] = c
        ans = scene.compute_closest_points(o3d.core.Tensor(p.astype(np.float32)))
        q = ans["points"].numpy().astype(np.float64)
        gids = ans["geometry_ids"].numpy().astype(np.int64)
        lut = np.full(max(codes) + 1, ex.SURFACE_NONE, np.int32)
        for g, c in codes.items():
            lut[g] = c
        ok = (gids >= 0) & (gids < len(lut))
        d = np.where(ok, np.linalg.norm(p - q, axis=1), np.inf)
        better(d, np.where(ok, lut[np.clip(gids, 0, len(lut) - 1)], ex.SURFACE_NONE).astype(np.int32))
    if surfaces.bin_points is not None:
        better(ex._point_model_distance(p, *surfaces.bin_points, spacing_mm=surfaces.bin_spacing_mm), ex.SURFACE_BIN)
    if surfaces.table is not None:
        better(surfaces.table.distance(p), ex.SURFACE_TABLE)
    d_img = np.full(valid.shape, np.nan, np.float32)
    d_img[valid] = dist
    c_img = np.full(valid.shape, ex.SURFACE_NONE, np.int32)
    c_img[valid] = code
    return ex.Nearest(d_img, c_img)


@pytest.mark.parametrize("spacing", [1.0, 2.0, 4.0])
@pytest.mark.parametrize("with_parts", [True, False])
@pytest.mark.parametrize("with_table", [True, False])
def test_the_bounded_bin_search_gives_the_unbounded_searchs_nearest_surface(spacing, with_parts, with_table):
    rng = np.random.default_rng(int(spacing * 10) + 2 * with_parts + with_table)
    pts, nrm = _bin(spacing)
    parts = [_box(np.array([-60.0, -40, 760]), np.array([-20.0, 0, 800])),
             _box(np.array([10.0, 10, 700]), np.array([60.0, 50, 795]))] if with_parts else []
    table = ex.Plane(np.array([0.0, 0.0, 1.0]), 830.0, 0.2) if with_table else None
    surfaces = ex.KnownSurfaces(parts=parts, part_err_mm=[0.2] * len(parts), bin_points=(pts, nrm),
                                bin_spacing_mm=spacing, bin_err_mm=0.3, table=table)
    n = 6000
    q = np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-200, 200, n), np.empty(n)])
    kind = rng.integers(0, 5, n)
    q[:, 2] = np.select([kind == 0, kind == 1, kind == 2, kind == 3],
                        [800 + rng.normal(0, 0.3, n),            # on the floor
                         rng.uniform(690, 800, n),               # anywhere in the bin's height
                         rng.uniform(780, 800, n),               # just above the floor (within the bound)
                         830 + rng.normal(0, 0.3, n)],           # on the table
                        rng.uniform(400, 690, n))                # far above everything
    q[:50, 0] = 150.0 + rng.normal(0, 0.3, 50)                   # on a wall
    q[50:60, 0] = 150.0 + ex.BIN_SEARCH_MM + rng.uniform(-0.5, 0.5, 10)  # about the bound from a wall
    xyz = q.reshape(60, 100, 3)
    xyz[0, 70] = np.nan
    got = ex.nearest_surface(xyz, surfaces)
    want = _oracle(xyz, surfaces)
    np.testing.assert_array_equal(got.surface, want.surface)
    np.testing.assert_array_equal(got.dist_mm, want.dist_mm)
    assert (want.surface == ex.SURFACE_BIN).sum() > 500


def test_a_surface_combined_afterwards_stops_the_bin_search_early_with_the_same_result():
    """``within_mm`` (the local surface of explained without a part model): the combined nearest
    surface is the previous one's, though fewer pixels search the bin unbounded."""
    rng = np.random.default_rng(7)
    pts, nrm = _bin(2.0)
    surfaces = ex.KnownSurfaces(bin_points=(pts, nrm), bin_spacing_mm=2.0, bin_err_mm=0.3,
                                table=ex.Plane(np.array([0.0, 0.0, 1.0]), 830.0, 0.2))
    n = 6000
    q = np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-200, 200, n), rng.uniform(600, 835, n)])
    xyz = q.reshape(60, 100, 3)
    local = np.abs(rng.normal(0.0, 3.0, (60, 100)))
    local[rng.random((60, 100)) < 0.2] = np.inf  # no local surface within reach
    local[rng.random((60, 100)) < 0.1] = np.nan  # not judged by it
    local[0, :5] = 15.0  # farther than the bound
    got = ex.with_local_surface(ex.nearest_surface(xyz, surfaces, within_mm=local), local)
    want = ex.with_local_surface(_oracle(xyz, surfaces), local)
    np.testing.assert_array_equal(got.surface, want.surface)
    np.testing.assert_array_equal(got.dist_mm, want.dist_mm)
    assert {ex.SURFACE_BIN, ex.SURFACE_TABLE, ex.SURFACE_LOCAL} <= set(np.unique(want.surface))
    with pytest.raises(InputShapeError, match="within_mm"):
        ex.nearest_surface(xyz, surfaces, within_mm=local[:, :3])
