"""The fits' own small linear algebra (zcut.fits.kernels: docs/fits.md, "The fits' bytes the same under every OpenBLAS
kernel") against NumPy / LAPACK on random and degenerate inputs (repeated eigenvalues, rank-deficient matrices,
reflections), each to a stated tolerance; the routines are plain loops (no BLAS), so their bits are the same under every
OpenBLAS kernel (the pins' subprocess test: tests/zcut/fits/test_fits_dispatch.py)."""

from __future__ import annotations

import numpy as np
import pytest

from zcut.fits.kernels import (
    covariance3,
    det3,
    facing_fronts,
    facing_mask,
    gram,
    kabsch3,
    line_fit,
    mm,
    norm3,
    polar3,
    principal_axes,
    solve_pivot,
    stack_mat_vec,
    sym_eigh,
)
from zcut.fits.sphere import algebraic_sphere


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _symmetric_cases(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Random symmetric matrices of spread scales, positive semi-definite ones of every rank, repeated eigenvalues
    (in a random basis and exactly diagonal), the zero matrix."""
    out = []
    for _ in range(150):
        a = rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-3, 3)
        out.append(a + a.T)
    for rank in range(n + 1):
        for _ in range(20):
            b = rng.normal(size=(n, rank))
            out.append(b @ b.T)
    for _ in range(40):
        q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        w = rng.choice([0.0, 1.0, 2.5], size=n)  # repeated eigenvalues
        out.append((q * w) @ q.T)
        out.append(np.diag(w))
    out.append(np.zeros((n, n)))
    return out


@pytest.mark.parametrize("n", [3, 6])
def test_sym_eigh_against_lapack(rng: np.random.Generator, n: int) -> None:
    """Eigenvalues within 1e-12 × the largest magnitude of LAPACK's; the vectors orthonormal (1e-13), A V = V diag(w)
    within 1e-12 × the scale, and each vector LAPACK's up to its sign (1e-8) where its eigenvalue is apart from the
    others by 1e-3 × the scale; the sign: the entry of largest magnitude positive."""
    for A in _symmetric_cases(rng, n):
        w, V = sym_eigh(A)
        w0, V0 = np.linalg.eigh(A)
        scale = max(float(np.abs(w0).max()), 1e-300)
        assert np.abs(w - w0).max() <= 1e-12 * scale
        assert np.all(np.diff(w) >= 0)
        assert np.abs(V.T @ V - np.eye(n)).max() <= 1e-13
        assert np.abs(A @ V - V * w).max() <= 1e-12 * scale
        for j in range(n):
            big = int(np.argmax(np.abs(V[:, j])))
            assert V[big, j] > 0
            gap = min([abs(w0[j] - w0[k]) for k in range(n) if k != j])
            if gap > 1e-3 * scale:
                s = np.sign(V0[:, j] @ V[:, j])
                assert np.abs(V[:, j] - s * V0[:, j]).max() <= 1e-8


def test_sym_eigh_reads_the_upper_triangle() -> None:
    A = np.array([[2.0, 1.0, 0.0], [99.0, 2.0, 0.0], [99.0, 99.0, 5.0]])
    w, _ = sym_eigh(A)
    np.testing.assert_allclose(w, [1.0, 3.0, 5.0], rtol=0, atol=1e-14)


@pytest.mark.parametrize("n", [3, 6])
def test_solve_pivot_against_lapack(rng: np.random.Generator, n: int) -> None:
    """Random systems, positive definite ones like the ICP's normal matrix (scales 1e-6..1e6 on the diagonal) and ones
    needing a row exchange (a zero first pivot): within 1e-12 × cond of LAPACK's solution."""
    cases = [rng.normal(size=(n, n)) for _ in range(200)]
    for _ in range(100):
        b = rng.normal(size=(3 * n, n)) * 10.0 ** rng.uniform(-3, 3, size=n)
        cases.append(b.T @ b + 1e-12 * np.eye(n))
    for _ in range(20):
        a = rng.normal(size=(n, n))
        a[0, 0] = 0.0
        cases.append(a)
    for A in cases:
        b = rng.normal(size=n)
        x, x0 = solve_pivot(A, b), np.linalg.solve(A, b)
        assert np.abs(x - x0).max() <= 1e-12 * np.linalg.cond(A) * max(1.0, float(np.abs(x0).max()))


def test_polar3_is_u_vt(rng: np.random.Generator) -> None:
    """Rotations with rounding noise (the ICP's end), general nonsingular matrices, reflections: U Vᵀ of LAPACK's SVD
    within 1e-12 × the condition number."""
    cases = [_rotation(rng) + 1e-9 * rng.normal(size=(3, 3)) for _ in range(200)]
    cases += [rng.normal(size=(3, 3)) for _ in range(200)]
    cases += [_rotation(rng) @ np.diag([1.0, 1.0, -1.0]) for _ in range(50)]
    for R in cases:
        U, s, Vt = np.linalg.svd(R)
        assert np.abs(polar3(R) - U @ Vt).max() <= 1e-12 * s[0] / s[2]


def _kabsch_lapack(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    out: np.ndarray = U @ D @ Vt
    return out


def test_kabsch3_against_lapack(rng: np.random.Generator) -> None:
    """Random M (half of them of negative determinant: the reflection case), M of rank 2, M of point sets (Σ b aᵀ,
    b a rotation of a plus noise): a rotation (det 1, orthonormal to 1e-13) within 1e-10 × σ1 / σ2 of LAPACK's
    Kabsch where the smallest two singular values are apart (the solution is then unique)."""
    cases = [rng.normal(size=(3, 3)) for _ in range(300)]
    cases += [rng.normal(size=(3, 2)) @ rng.normal(size=(2, 3)) for _ in range(100)]
    for _ in range(100):
        a = rng.normal(size=(50, 3))
        b = a @ _rotation(rng).T + 0.01 * rng.normal(size=(50, 3))
        cases.append(b.T @ a)
    for M in cases:
        R = kabsch3(M)
        assert abs(np.linalg.det(R) - 1.0) <= 1e-13
        assert np.abs(R.T @ R - np.eye(3)).max() <= 1e-13
        s = np.linalg.svd(M, compute_uv=False)
        if s[1] - s[2] > 1e-3 * s[0]:
            assert np.abs(R - _kabsch_lapack(M)).max() <= 1e-10 * s[0] / s[1]


def test_small_products_and_sums(rng: np.random.Generator) -> None:
    """mm, det3, norm3, covariance3, gram, stack_mat_vec, line_fit against NumPy (relative 1e-12)."""
    for _ in range(100):
        A, B, v = rng.normal(size=(7, 3)), rng.normal(size=(3, 3)), rng.normal(size=3)
        np.testing.assert_allclose(mm(A, B), A @ B, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(mm(B, v), B @ v, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(mm(v, B), v @ B, rtol=1e-12, atol=1e-13)
        assert abs(float(mm(v, v)) - float(v @ v)) <= 1e-12 * float(v @ v)
        assert abs(det3(B) - np.linalg.det(B)) <= 1e-12 * np.abs(B).max() ** 3
        assert abs(norm3(v) - np.linalg.norm(v)) <= 1e-15 * np.linalg.norm(v)
        P = rng.normal(size=(500, 3)) * [1.0, 10.0, 100.0] + 600.0
        np.testing.assert_allclose(covariance3(P), np.cov(P.T), rtol=1e-10)
        J, r = rng.normal(size=(40, 4)), rng.normal(size=40)
        G, h = gram(J, r)
        np.testing.assert_allclose(G, J.T @ J, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(h, J.T @ r, rtol=1e-12, atol=1e-12)
        Rs, vs = rng.normal(size=(5, 3, 3)), rng.normal(size=(5, 3))
        np.testing.assert_allclose(stack_mat_vec(Rs, vs, False), (Rs @ vs[:, :, None])[:, :, 0], rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(stack_mat_vec(Rs, vs, True), (Rs.transpose(0, 2, 1) @ vs[:, :, None])[:, :, 0],
                                   rtol=1e-12, atol=1e-13)
        x = rng.uniform(-0.5, 0.5, 300)
        y = 1200.0 * x + 960.0 + rng.normal(size=300)
        sol, *_ = np.linalg.lstsq(np.c_[x, np.ones(300)], y, rcond=None)
        np.testing.assert_allclose(line_fit(x, y), sol, rtol=1e-11)


def test_principal_axes_and_facing(rng: np.random.Generator) -> None:
    """principal_axes: LAPACK's eigenvectors of np.cov up to their signs (distinct variances); facing_mask /
    facing_fronts: the NumPy expression's samples and sums."""
    P = rng.normal(size=(2000, 3)) * [5.0, 2.0, 0.5] @ _rotation(rng).T + [10.0, -20.0, 600.0]
    ax = principal_axes(P)
    _, ax0 = np.linalg.eigh(np.cov(P.T))
    np.testing.assert_allclose(np.abs(ax), np.abs(ax0), atol=1e-10)
    n = rng.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    s = rng.normal(size=(300, 3))
    Rs = np.stack([_rotation(rng) for _ in range(4)])
    view = np.array([0.1, -0.2, 0.97])
    counts, sums = facing_fronts(n, s, Rs, view)
    for g, R in enumerate(Rs):
        want = n @ (R.T @ view) < 0
        assert np.array_equal(facing_mask(n, R, view), want)
        assert counts[g] == want.sum()
        np.testing.assert_allclose(sums[g], s[want].sum(axis=0), rtol=1e-12, atol=1e-12)


def test_algebraic_sphere_against_lstsq(rng: np.random.Generator) -> None:
    """The centred normal equations give LAPACK's least-squares sphere (a cap of a 10 mm sphere 600 mm away, noisy):
    centre within 1e-9 mm, radius within 1e-9 mm."""
    for _ in range(50):
        d = rng.normal(size=(400, 3))
        d[:, 2] = -np.abs(d[:, 2])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        c0 = np.array([30.0, -40.0, 600.0]) + rng.normal(size=3)
        p = c0 + 10.0 * d + 0.05 * rng.normal(size=(400, 3))
        A = np.c_[2.0 * p, np.ones(len(p))]
        sol, *_ = np.linalg.lstsq(A, np.einsum("ij,ij->i", p, p), rcond=None)
        c, r = algebraic_sphere(p)
        assert np.abs(c - sol[:3]).max() <= 1e-9
        assert abs(r - float(np.sqrt(sol[3] + sol[:3] @ sol[:3]))) <= 1e-9
