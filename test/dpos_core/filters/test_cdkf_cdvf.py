"""The CDKF and the CDVF ([Ye2024] sec. 2.2, Algorithm 2): the Kalman filter and RTS on a linear
model, Stirling's second-order moments, and the conjugate-gradient update's cost on a nonlinear
measurement."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.filters.dd2 import dd2_predict, dd2_update
from dpos_core.filters.gaussian import cd_predict, cd_update, kf_predict, kf_update, rts_smooth, ut_predict
from dpos_core.filters.linalg import chol, solve_lower
from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.points import CentralDifferencePoints
from dpos_core.filters.runners import CentralDifferenceRule, VariationalRule, run_sigma_point_filter, smooth_gaussian
from dpos_core.filters.variational import CGSettings, cdvf_update


def _linear(n: int = 6, p: int = 3, K: int = 40, seed: int = 0):
    rng = np.random.default_rng(seed)
    F = np.linalg.qr(rng.normal(size=(n, n)))[0] * 0.98
    G = rng.normal(size=(n, n)) * 0.1
    Q = G @ G.T + 1e-3 * np.eye(n)
    H = rng.normal(size=(p, n))
    B = rng.normal(size=(p, p)) * 0.3
    R = B @ B.T + 0.05 * np.eye(p)
    x = rng.normal(size=n)
    ys = []
    for _ in range(K):
        x = F @ x + chol(Q) @ rng.normal(size=n)
        ys.append(H @ x + chol(R) @ rng.normal(size=p))
    return F, Q, H, R, np.array(ys)


def _kf_rts(F, Q, H, R, ys, x0, P0):
    x, P = x0, P0
    xf, Pf, xp, Pp, C = [], [], [], [], []
    for k, y in enumerate(ys):
        if k > 0:
            pr = kf_predict(x, P, F, Q)
            xp.append(pr.x), Pp.append(pr.P), C.append(pr.C)
            x, P = pr.x, pr.P
        up = kf_update(x, P, y, H, R)
        x, P = up.x, up.P
        xf.append(x), Pf.append(P)
    xf, Pf = np.array(xf), np.array(Pf)
    return (xf, Pf, *rts_smooth(xf, Pf, np.array(xp), np.array(Pp), np.array(C)))


@pytest.mark.parametrize("rule", [CentralDifferenceRule(), VariationalRule(settings=CGSettings(grad_tol=1e-8))])
def test_cdkf_and_cdvf_equal_the_kalman_filter_and_their_smoothers_rts(rule) -> None:
    F, Q, H, R, ys = _linear()
    n = F.shape[0]
    x0, P0 = np.zeros(n), np.eye(n) * 4.0
    ref = _kf_rts(F, Q, H, R, ys, x0, P0)
    tr = run_sigma_point_filter(LinearGaussianModel(F, Q, H, R, ys), x0, P0, rule=rule)
    got = (tr.x_f, tr.P_f, *smooth_gaussian(tr))
    for a, b in zip(ref, got, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-9)
    if isinstance(rule, VariationalRule):
        assert tr.cg is not None
        # linear CG: the minimum in at most p + 1 steps (Gamma = I + B^T B has p + 1 distinct eigenvalues;
        # p = 3 measurements, n = 6 states)
        assert tr.cg.iterations.max() <= H.shape[0] + 1 and set(tr.cg.stop) == {"gradient"}
        np.testing.assert_allclose(tr.cg.cost, tr.cg.cost_cdkf, rtol=1e-9)
    else:
        assert tr.cg is None


def test_default_stopping_rule_bounds_the_mahalanobis_distance_to_the_minimum() -> None:
    """|grad J| <= 1e-3 in whitened coordinates: the CDVF mean is within 1e-3 posterior sigma of the
    Kalman update (variational.py docstring), measured here on badly conditioned updates."""
    rng = np.random.default_rng(5)
    n, p = 8, 4
    for _ in range(20):
        A = rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-2, 2, size=n)
        P = A @ A.T + 1e-6 * np.eye(n)
        H = rng.normal(size=(p, n))
        R = np.diag(10.0 ** rng.uniform(-4, 0, size=p))
        x = rng.normal(size=n)
        y = H @ x + rng.normal(size=p) * 10.0
        kf = kf_update(x, P, y, H, R)
        up, info = cdvf_update(x, P, y, lambda X: X @ H.T, R)
        assert info.stop == "gradient" and info.grad_norm <= 1e-3
        d = up.x - kf.x
        L = chol(kf.P)
        assert float(np.linalg.norm(solve_lower(L, d[:, None]))) <= 1e-3
        np.testing.assert_allclose(up.P, kf.P, rtol=0, atol=1e-8 * np.abs(kf.P).max())  # (condition numbers up to 1e9)


def test_cdkf_is_the_square_root_dd2_and_exact_for_separable_quadratics() -> None:
    """Stirling's second-order interpolation: mean and covariance of ``x_i^2`` exact (the first-order
    term alone would miss ``2 s^4``); the covariance form equals the DD2's square-root factors."""
    m = np.array([1.0, -0.5, 0.3, 2.0])
    s = np.array([0.5, 0.8, 0.2, 0.1])
    P = np.diag(s**2)
    f = lambda X: np.stack([X[..., 0] ** 2, X[..., 1] ** 2, X[..., 0] + X[..., 1], X[..., 3]], axis=-1)  # noqa: E731
    pr = cd_predict(m, P, f, np.zeros((4, 4)))
    np.testing.assert_allclose(pr.x, [m[0] ** 2 + s[0] ** 2, m[1] ** 2 + s[1] ** 2, m[0] + m[1], m[3]], atol=1e-14)
    var = 4 * m[:2] ** 2 * s[:2] ** 2 + 2 * s[:2] ** 4
    np.testing.assert_allclose(np.diag(pr.P)[:2], var, rtol=1e-12)
    np.testing.assert_allclose(pr.P[0, 2], 2 * m[0] * s[0] ** 2, rtol=1e-12)  # Cov(x1^2, x1 + x2)
    assert abs(pr.P[0, 1]) < 1e-14  # x1^2 and x2^2 are independent
    # the unscented rule with the central-difference points and weights is not Stirling's covariance
    # (gaussian.py docstring): -s1^2 s2^2 there
    pu = ut_predict(m, P, f, np.zeros((4, 4)), CentralDifferencePoints())
    np.testing.assert_allclose(pu.P[0, 1], -s[0] ** 2 * s[1] ** 2, rtol=1e-12)
    # the same filter as the square-root DD2 (dd2.py), prediction and update
    rng = np.random.default_rng(2)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    Q = np.diag([0.1, 0.2, 0.3, 0.4])
    g = lambda X: np.stack([np.sin(X[..., 0]) + X[..., 1] ** 2, X[..., 2] * X[..., 3], np.exp(0.3 * X[..., 1]), X[..., 0]], axis=-1)  # noqa: E731
    a = cd_predict(m, P, g, Q)
    b = dd2_predict(m, chol(P), g, chol(Q))
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12)
    np.testing.assert_allclose(a.P, b.S @ b.S.T, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(a.C, b.C, rtol=1e-10, atol=1e-12)
    R = np.diag([0.05, 0.1])
    hh = lambda X: np.stack([X[..., 0] * X[..., 1], np.cos(X[..., 2])], axis=-1)  # noqa: E731
    y = np.array([0.3, 0.9])
    u = cd_update(m, P, y, hh, R)
    v = dd2_update(m, chol(P), y, hh, chol(R))
    np.testing.assert_allclose(u.x, v.x, rtol=1e-10)
    np.testing.assert_allclose(u.P, v.S @ v.S.T, rtol=1e-9, atol=1e-12)


def _range_bearing(X: np.ndarray) -> np.ndarray:
    """Range and bearing (..., 2) of planar positions X (..., 2) seen from the origin."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0])], axis=-1)


def test_cdvf_lowers_the_variational_cost_below_the_cdkf_update_on_a_nonlinear_measurement() -> None:
    """A broad prior seen by a precise range-bearing sensor: the CDKF's one-step (linear minimum
    variance) update leaves cost on the table, the CG minimizes J further and lands nearer the truth."""
    rng = np.random.default_rng(11)
    P = np.diag([4.0, 4.0])
    R = np.diag([0.01**2, 0.002**2])
    lower = closer = 0
    trials = 30
    for _ in range(trials):
        truth = np.array([10.0, 0.0]) + rng.normal(size=2) * 2.0
        x = truth + chol(P) @ rng.normal(size=2)  # the prediction, consistent with P
        y = _range_bearing(truth) + np.sqrt(np.diag(R)) * rng.normal(size=2)
        lmv = cd_update(x, P, y, _range_bearing, R)
        up, info = cdvf_update(x, P, y, _range_bearing, R)
        assert info.cost <= info.cost_cdkf * (1 + 1e-12) and info.cost < info.cost_prior
        assert info.stop == "gradient"
        lower += info.cost < 0.5 * info.cost_cdkf
        closer += np.linalg.norm(up.x - truth) < np.linalg.norm(lmv.x - truth)
        np.testing.assert_array_equal(up.P, lmv.P)  # the CDKF's covariance ([Ye2024] step 13)
    assert lower >= 0.9 * trials and closer >= 0.9 * trials


def test_bad_settings_are_named() -> None:
    for kw in ({"grad_tol": 0.0}, {"max_iter": 0}, {"jac_step": -1.0}, {"armijo": 0.7}, {"max_halvings": 0}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            CGSettings(**kw)
    with pytest.raises(ValueError, match="one state"):
        cdvf_update(np.zeros((2, 3)), np.eye(3), np.zeros(1), lambda X: X[..., :1], np.eye(1))


def test_a_guard_stopping_above_the_cdkf_cost_returns_the_cdkf_update() -> None:
    """Capped at one step the iteration stays above the CDKF update's cost: the CDKF update is returned."""
    P = np.diag([4.0, 4.0])
    R = np.diag([0.01**2, 0.002**2])
    x, truth = np.array([11.5, -1.8]), np.array([10.0, 0.5])
    y = _range_bearing(truth)
    lmv = cd_update(x, P, y, _range_bearing, R)
    up, info = cdvf_update(x, P, y, _range_bearing, R, settings=CGSettings(max_iter=1))
    assert info.stop == "max_iter" and info.iterations == 1
    np.testing.assert_array_equal(up.x, lmv.x)
    assert info.cost == info.cost_cdkf
    full, info_full = cdvf_update(x, P, y, _range_bearing, R)
    assert info_full.stop == "gradient" and info_full.cost < info.cost
