"""replay.pipeline.bin_model: a bin model from points and from empty-bin scans."""

from __future__ import annotations

import numpy as np

from replay.pipeline.bin_model import model_from_points
from zcut.params import RegistrationParams


def test_model_from_points_downsamples_with_normals():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-0.05, 0.05, (5000, 2)), np.full(5000, 0.5)]
    m = model_from_points(pts, voxel_mm=5.0)
    assert 100 <= len(m.points) <= 600
    assert np.allclose(np.abs(m.normals[:, 2]), 1.0, atol=1e-6)
    assert (m.normals[:, 2] < 0).all()  # oriented towards the camera at the origin
    assert isinstance(RegistrationParams().voxel_mm, float)


