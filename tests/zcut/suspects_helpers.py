"""Random patch covariances for the suspects' gate tests (tests/zcut/test_suspects_fast.py,
tests/zcut/test_suspects_ninth.py): one generator, each test's rates and scales as arguments; and the gate's
whole-frame pass, the oracle of its median (test_suspects_ninth.py, test_suspects_tenth.py)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from zcut.edge_surface import EdgeSurfaceParams


def patch_covariances(rng: np.random.Generator, n: int, *, tilts: Sequence[float], noises: Sequence[float],
                      quantized_every: int, decades: float, line_every: int = 13, point_every: int = 17,
                      negative_zero_every: int | None = None) -> Iterator[list[float]]:
    """``n`` covariances (c00, c01, c02, c11, c12, c22) of 3 × 3 patches as the gate computes them (the
    points' products about their centroid, divided by their count): 3 to 9 points of the patch's grid,
    a plane tilted by one of ``tilts`` plus noise of one of ``noises``; patch t has its depth rounded
    when t % ``quantized_every`` == 0, lies on a line when t % ``line_every`` == 0 and is one point when
    t % ``point_every`` == 0; then scaled by 10^U(-decades, decades) and shifted by 0 or 1e3. With
    ``negative_zero_every``, patch t's zero entries are -0.0 when t % it == 0.

    A generator, one covariance at a time: a caller drawing from ``rng`` between two covariances draws
    where it did when each test made its own."""
    for t in range(n):
        k = int(rng.integers(3, 10))
        g = np.stack([rng.integers(-1, 2, k), rng.integers(-1, 2, k)], 1).astype(np.float64)
        tilt = rng.normal(size=2) * float(rng.choice(tilts))
        p = np.column_stack([g, g @ tilt + rng.normal(size=k) * float(rng.choice(noises))])
        if t % quantized_every == 0:
            p[:, 2] = np.round(p[:, 2])  # quantized depth
        if t % line_every == 0:
            p[:, 1] = p[:, 0]  # a line
        if t % point_every == 0:
            p[:] = p[0]  # one point
        p = p * 10.0 ** rng.uniform(-decades, decades) + rng.normal(size=3) * float(rng.choice([0.0, 1e3]))
        d = p - p.mean(axis=0)
        c = [float(d[:, a] @ d[:, b]) / k for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
        if negative_zero_every is not None and t % negative_zero_every == 0:
            c = [-0.0 if v == 0.0 else v for v in c]
        yield c


def whole_frame_gate(a: np.ndarray, params: EdgeSurfaceParams) -> tuple[int, float, float, float]:
    """(count, median, per_px, tan) of the gate's whole-frame pass (``_patch_gate_kernel``,
    ``_median_of_temporary``): the oracle of ``_gate_median`` (test_suspects_ninth, test_suspects_tenth)."""
    import math

    from zcut.edge_surface import _median_of_temporary, _patch_gate_kernel, _reach_samples

    H, W = a.shape[:2]
    valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
    samples = _reach_samples(a, valid)
    per_px = _median_of_temporary(samples) if samples.size else 0.0
    tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
    rms, z2, steep, ratios = np.empty((H, W)), np.empty((H, W)), np.empty((H, W), bool), np.empty(H * W)
    m = _patch_gate_kernel(a, valid, params.patch_radius_px, params.min_patch_px, per_px, tan, params.side_step_mm,
                           math.cos(math.radians(params.max_incidence_deg)), rms, z2, steep, ratios)
    return m, (_median_of_temporary(ratios[:m]) if m else float("nan")), per_px, tan
