"""SOR's top region with the z-cut's z_max (``replay.pipeline.zone.known_z_max``: the z-cut noted it on the zone
while it read the heights): the same region as when ``sor_region`` scans the heights for it, on height images with
NaN, +-inf, signed zeros and values exactly on the threshold, degenerate images (one pixel, one row, one column,
none finite), the real organized clouds' heights and through the pipeline; another height image is not given it.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from replay.pipeline.zone import Zone, known_z_max, note_z_max, sor_region
from zcut.cuts import find_clusters
from zcut.params import ZCutParams

PARAMS = ZCutParams(step=0.5, max_depth=3.0, max_area=40.0)


def _heights(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(-20.0, 20.0, (h, w))
    pick = rng.random((h, w))
    z[pick < 0.15] = np.nan
    z[(pick >= 0.15) & (pick < 0.18)] = np.inf
    z[(pick >= 0.18) & (pick < 0.20)] = -np.inf
    z[(pick >= 0.20) & (pick < 0.23)] = -0.0
    z[(pick >= 0.23) & (pick < 0.26)] = 0.0
    fin = np.isfinite(z)
    if fin.any():  # values exactly on the lowest cut
        top = float(np.max(z, where=fin, initial=-np.inf))
        z[(pick >= 0.26) & (pick < 0.30)] = top - PARAMS.n_levels * PARAMS.step
    return z


def _same_region(z: np.ndarray, zone: np.ndarray) -> None:
    cut = find_clusters(z, params=PARAMS)
    fin = np.isfinite(z)
    if fin.any():
        assert cut.z_max == float(np.max(z, where=fin, initial=-np.inf))
    else:
        assert np.isnan(cut.z_max)
    assert np.array_equal(sor_region(z, zone, PARAMS, z_max=cut.z_max), sor_region(z, zone, PARAMS))


@pytest.mark.parametrize("shape", [(1, 1), (1, 17), (13, 1), (40, 60), (121, 97)])
def test_random_heights(shape):
    for seed in range(4):
        z = _heights(*shape, seed=seed)
        zone = np.random.default_rng(seed + 50).random(shape) < 0.7
        _same_region(z, zone)


@pytest.mark.parametrize("fill", [np.nan, np.inf, -np.inf])
def test_no_finite_height(fill):
    z = np.full((6, 8), fill)
    zone = np.ones((6, 8), bool)
    _same_region(z, zone)
    assert not sor_region(z, zone, PARAMS, z_max=float("nan")).any()


def test_one_finite_height_among_signed_zeros():
    z = np.full((5, 5), np.nan)
    z[2, 2] = -0.0
    z[0, 0] = 0.0
    _same_region(z, np.ones((5, 5), bool))


def test_real_clouds_heights():
    from replay.logs.pcd import read_pcd

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    for path in clouds:
        z = -1000.0 * read_pcd(path).xyz[..., 2].astype(np.float64)
        fin = np.isfinite(z)
        _same_region(z, fin)
        _same_region(np.where(np.arange(z.shape[0])[:, None] < z.shape[0] // 2, np.nan, z), fin)  # half invalid


def test_noted_only_for_the_zones_own_heights():
    z = _heights(20, 30, seed=9)
    zone = Zone(None, None, np.isfinite(z), z, np.zeros(z.shape, bool), {}, ())  # type: ignore[arg-type]
    assert known_z_max(zone) is None
    note_z_max(zone, z.copy(), 1.0)  # another array: not noted
    assert known_z_max(zone) is None
    note_z_max(zone, z, 3.5)
    assert known_z_max(zone) == 3.5
    assert known_z_max(dataclasses.replace(zone, height_mm=z.copy())) is None


def test_through_the_pipeline(tmp_path):
    """A synthetic frame's methods: the z-cut notes its z_max on the zone, SOR's region with it is the region
    without it, and so are SOR's outliers."""
    from replay.logs.reader import LogReader
    from replay.pipeline import config as cfg
    from replay.pipeline.stages import bin_zone, run_methods
    from replay.pipeline.zone import sor_judged, sor_on_zone
    from replay.synth.log import write_synthetic_log

    path = write_synthetic_log(tmp_path / "one.mcap", kind="zinc_nuts", frames=1, seed=29, size=(90, 120))
    frame = next(iter(LogReader(path).frames()))
    config = cfg.resolve(cfg.log_facts({}, frame)).config  # the default methods: the z-cut, then SOR
    zone = bin_zone(frame, config)  # no bin model: the whole frame's heights
    assert "sor" in config.base_methods and config.sor.region == "top"
    run_methods(frame, zone, config, timings={}, warnings=[])
    assert known_z_max(zone) is not None
    bare = dataclasses.replace(zone, found={})
    assert known_z_max(bare) is None
    assert np.array_equal(sor_judged(zone, config), sor_judged(bare, config))
    assert np.array_equal(sor_on_zone(frame, zone, config), sor_on_zone(frame, bare, config))
