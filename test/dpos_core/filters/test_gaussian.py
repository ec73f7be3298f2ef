"""Gaussian filter pieces: UKF = KF and URTSS = RTS on linear-Gaussian models."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.errors import NumericalFailure
from dpos_core.filters.gaussian import kf_predict, kf_update, rts_smooth, ut_predict, ut_update
from dpos_core.filters.linalg import chol, gauss_logpdf, householder_tria, whitener
from dpos_core.filters.points import CentralDifferencePoints, UnscentedPoints


def _linear_model(n: int = 6, p: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    F = np.linalg.qr(A)[0] * 0.98  # stable rotation-like dynamics
    G = rng.normal(size=(n, n)) * 0.1
    Q = G @ G.T + 1e-3 * np.eye(n)
    H = rng.normal(size=(p, n))
    B = rng.normal(size=(p, p)) * 0.3
    R = B @ B.T + 0.05 * np.eye(p)
    return F, Q, H, R


def _simulate(F, Q, H, R, K: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    n, p = F.shape[0], H.shape[0]
    x = rng.normal(size=n)
    ys = []
    for _ in range(K):
        x = F @ x + chol(Q) @ rng.normal(size=n)
        ys.append(H @ x + chol(R) @ rng.normal(size=p))
    return np.array(ys)


@pytest.mark.parametrize("points", [UnscentedPoints(1e-3, 2.0, 0.0), UnscentedPoints(1.0, 2.0, 0.0), UnscentedPoints(0.5, 2.0, 3.0), CentralDifferencePoints()])
def test_sigma_point_filter_and_smoother_equal_kalman_and_rts(points) -> None:
    F, Q, H, R = _linear_model()
    ys = _simulate(F, Q, H, R, 40)
    n = F.shape[0]
    out = {}
    for kind in ("kf", "ut"):
        x, P = np.zeros(n), np.eye(n) * 4.0
        xf, Pf, xp, Pp, C = [], [], [], [], []
        for k, y in enumerate(ys):
            if k > 0:
                pr = kf_predict(x, P, F, Q) if kind == "kf" else ut_predict(x, P, lambda X: X @ F.T, Q, points)
                xp.append(pr.x), Pp.append(pr.P), C.append(pr.C)
                x, P = pr.x, pr.P
            up = kf_update(x, P, y, H, R) if kind == "kf" else ut_update(x, P, y, lambda X: X @ H.T, R, points)
            x, P = up.x, up.P
            xf.append(x), Pf.append(P)
        xs, Ps = rts_smooth(np.array(xf), np.array(Pf), np.array(xp), np.array(Pp), np.array(C))
        out[kind] = (np.array(xf), np.array(Pf), xs, Ps)
    for a, b in zip(out["kf"], out["ut"]):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)
    # the smoother really smooths: its covariance is below the filter's before the last epoch
    assert np.all(np.trace(out["kf"][3][:-1], axis1=1, axis2=2) < np.trace(out["kf"][1][:-1], axis1=1, axis2=2))


def test_batched_over_particles() -> None:
    F, Q, H, R = _linear_model()
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 6))
    P = np.stack([np.eye(6) * (i + 1) for i in range(5)])
    pr = ut_predict(x, P, lambda X: X @ F.T, Q)
    for i in range(5):
        ref = kf_predict(x[i], P[i], F, Q)
        np.testing.assert_allclose(pr.x[i], ref.x, atol=1e-12)
        np.testing.assert_allclose(pr.P[i], ref.P, atol=1e-10)


def test_linalg_helpers() -> None:
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3, 4, 9))
    S = householder_tria(A)
    np.testing.assert_allclose(S @ np.swapaxes(S, 1, 2), A @ np.swapaxes(A, 1, 2), atol=1e-12)
    assert np.allclose(np.triu(S[0], 1), 0.0) and np.all(np.diagonal(S, axis1=1, axis2=2) >= 0)
    from scipy.stats import multivariate_normal

    C = A[0] @ A[0].T + np.eye(4)
    r = rng.normal(size=(7, 4))
    np.testing.assert_allclose(gauss_logpdf(r, C), multivariate_normal(np.zeros(4), C).logpdf(r), rtol=1e-12)
    W, c = whitener(C)
    np.testing.assert_allclose(c - 0.5 * np.sum((r @ W.T) ** 2, axis=1), multivariate_normal(np.zeros(4), C).logpdf(r), rtol=1e-12)
    # a PSD-by-rounding matrix gets a tiny jitter if needed (counted and warned: test/dpos_core/test_errors.py),
    # an indefinite one is refused
    v = rng.normal(size=(4, 1))
    chol(v @ v.T + 1e-15 * np.eye(4))
    with pytest.raises(NumericalFailure):
        chol(np.diag([1.0, -1.0, 1.0, 1.0]))


def _spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + scale**2 * np.eye(n)


def test_ut_moments_kernel_is_the_numpy_formula() -> None:
    """filters._ut_kernel.moments (through gaussian._ut_moments) = the weighted outer products of
    the points' deviations, symmetrized with the noise ([Gong2018] eq. 4-5), batched or not."""
    from dpos_core.filters.gaussian import _ut_moments
    from dpos_core.filters.linalg import symmetrize

    rng = np.random.default_rng(3)
    for lead in ((), (4,), (2, 3)):
        dX, dY = rng.normal(size=lead + (13, 6)), rng.normal(size=lead + (13, 5))
        wc, noise = rng.normal(size=13), rng.normal(size=(5, 5))
        cov, cross = _ut_moments(dX, dY, wc, noise)
        dYw = np.swapaxes(dY * wc[:, None], -1, -2)
        np.testing.assert_allclose(cov, symmetrize(dYw @ dY + noise), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(cross, np.swapaxes(dX * wc[:, None], -1, -2) @ dY, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))


def test_kalman_correction_kernel_is_the_numpy_formula() -> None:
    """filters._ut_kernel.correct (through gaussian._correct) = ``K = Pxz S^-1`` by
    :func:`~dpos_core.filters.linalg.gain`, ``x + K nu``, ``sym(P - K S K^T)``, batched and broadcast;
    an S that is not positive definite goes to gain (which raises)."""
    from dpos_core.filters.gaussian import _correct
    from dpos_core.filters.linalg import gain, symmetrize

    rng = np.random.default_rng(4)
    n, p = 7, 4
    for lead_x, lead_P in (((), ()), ((5,), ()), ((5,), (5,)), ((), (3,))):
        x, nu = rng.normal(size=lead_x + (n,)), rng.normal(size=lead_x + (p,))
        P = _spd(rng, n) if not lead_P else np.stack([_spd(rng, n) for _ in range(lead_P[0])])
        Pxz, S = rng.normal(size=(n, p)), _spd(rng, p)
        if lead_x == lead_P:  # the shapes of ut_update (one lead: the kernel)
            Pxz, S = np.broadcast_to(Pxz, lead_x + (n, p)), np.broadcast_to(S, lead_x + (p, p))
        up = _correct(x, P, Pxz, S, nu)
        K = gain(Pxz, S)
        np.testing.assert_allclose(up.K, K, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(up.x, x + np.einsum("...ij,...j->...i", K, nu), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(up.P, symmetrize(P - K @ S @ np.swapaxes(K, -1, -2)), rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(up.P, np.swapaxes(up.P, -1, -2))
    with pytest.raises(NumericalFailure):
        _correct(np.zeros(n), np.eye(n), np.ones((n, p)), -np.eye(p), np.zeros(p))


def test_gauss_logpdf_kernel_shared_covariance() -> None:
    """filters._logpdf_kernel.gauss_logpdf_rows (gauss_logpdf of many residuals (N, p) under one
    covariance (p, p)) = the batched solve's formula."""
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(5)
    C = _spd(rng, 9, 0.3)
    r = rng.normal(size=(100, 9)) * 0.3
    np.testing.assert_allclose(gauss_logpdf(r, C), multivariate_normal(np.zeros(9), C).logpdf(r), rtol=1e-12)
    np.testing.assert_allclose(gauss_logpdf(r, C), gauss_logpdf(r, np.broadcast_to(C, (100, 9, 9))), rtol=1e-12)


def test_symmetric_points_kernel_is_the_numpy_formula() -> None:
    """points.symmetric_points (numba kernel filters._points_kernel for one square root per mean) =
    ``[x, x + scale s_j, x - scale s_j]``, bit for bit, batched or not; a square root shared by
    several means goes through numpy."""
    from dpos_core.filters.points import symmetric_points

    rng = np.random.default_rng(9)
    for lead in ((), (3,), (2, 4)):
        x, S = rng.normal(size=lead + (5,)), rng.normal(size=lead + (5, 5))
        d = 1.7 * np.swapaxes(S, -1, -2)
        ref = np.concatenate([x[..., None, :], x[..., None, :] + d, x[..., None, :] - d], axis=-2)
        np.testing.assert_array_equal(symmetric_points(x, S, 1.7), ref)
    x, S = rng.normal(size=(3, 5)), rng.normal(size=(5, 5))
    d = 1.7 * S.T
    np.testing.assert_array_equal(symmetric_points(x, S, 1.7), np.concatenate([x[:, None], x[:, None] + d, x[:, None] - d], axis=-2))
