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
