"""The particle filters of [Yan2016] (filters/pf.py): bootstrap PF, regularized PF, MCMC-regularized PF."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.filters.gaussian import kf_predict, kf_update
from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.particle import ess
from dpos_core.filters.pf import PF_METHODS, bandwidth_opt, children_mask, mh_move, n_distinct_rows, psd_sqrt, regularize, run_sir, weighted_cov
from dpos_core.filters.points import UnscentedPoints


def _linear(K: int = 25, seed: int = 3) -> tuple[LinearGaussianModel, np.ndarray, np.ndarray]:
    """Constant-velocity target observed in position (process noise on both states)."""
    rng = np.random.default_rng(seed)
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]) * 0.1
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.4]])
    x = np.array([0.0, 1.0])
    ys = []
    for _ in range(K):
        x = F @ x + np.linalg.cholesky(Q) @ rng.normal(size=2)
        ys.append(H @ x + np.sqrt(R[0, 0]) * rng.normal(size=1))
    return LinearGaussianModel(F, Q, H, R, np.array(ys)), np.zeros(2), np.eye(2)


def _kalman(m: LinearGaussianModel, x0: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xs, Ps = [], []
    x, P = x0, P0
    for k in range(m.n_epochs):
        if k:
            pr = kf_predict(x, P, m.F, m.Q(k))
            x, P = pr.x, pr.P
        up = kf_update(x, P, m.ys[k], m.H, m.R(k))
        x, P = up.x, up.P
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)


@pytest.mark.parametrize("method", PF_METHODS)
def test_particle_filters_converge_to_the_kalman_filter(method: str) -> None:
    """With many particles every PF's mean is the Kalman filter's to a fraction of its sigma
    (the regularized ones widen the posterior a little: the mean stays)."""
    m, x0, P0 = _linear()
    xk, Pk = _kalman(m, x0, P0)
    tr = run_sir(m, x0, P0, n_particles=20000, rng=np.random.default_rng(1), method=method)
    sig = np.sqrt(np.diagonal(Pk, axis1=1, axis2=2))
    z = np.abs(tr.mean - xk) / sig
    assert np.max(z) < 0.12, (method, float(np.max(z)))
    ratio = np.sqrt(np.diagonal(tr.cov, axis1=1, axis2=2)) / sig
    lo, hi = (0.9, 1.1) if method != "rpf" else (0.9, 1.25)
    assert lo < np.median(ratio) < hi, (method, float(np.median(ratio)))
    assert tr.resampled.any()
    if method.startswith("mcmc_rpf"):
        assert np.nanmean(tr.accept) > 0.2  # the move does something on this model


def test_bootstrap_pf_with_few_particles_is_worse() -> None:
    """The test above can fail: 30 particles are visibly off the Kalman filter."""
    m, x0, P0 = _linear()
    xk, Pk = _kalman(m, x0, P0)
    tr = run_sir(m, x0, P0, n_particles=30, rng=np.random.default_rng(1), method="pf")
    z = np.abs(tr.mean - xk) / np.sqrt(np.diagonal(Pk, axis1=1, axis2=2))
    assert np.max(z) > 0.12


def test_bandwidth_formula_and_kernel_covariance() -> None:
    """h_opt = (4 / (N (n + 2)))^(1 / (n + 4)); jittered equal-weight particles have covariance
    (1 + h^2) S (the kernel adds h^2 S)."""
    assert bandwidth_opt(1000, 16) == pytest.approx((4.0 / (1000 * 18)) ** (1.0 / 20))
    assert bandwidth_opt(100, 1) == pytest.approx((4.0 / 300) ** 0.2)
    rng = np.random.default_rng(2)
    S = np.array([[4.0, 1.2, 0.0], [1.2, 1.0, -0.3], [0.0, -0.3, 0.5]])
    x = rng.multivariate_normal(np.zeros(3), S, size=200000)
    logw = np.full(x.shape[0], -np.log(x.shape[0]))
    _, C = weighted_cov(x, logw)
    A = psd_sqrt(C)
    np.testing.assert_allclose(A @ A.T, C, atol=1e-12)
    h = 0.5
    _, C2 = weighted_cov(regularize(x, A, h, rng), logw)
    np.testing.assert_allclose(C2, (1 + h * h) * C, atol=0.03)


def test_mh_move_leaves_the_target_invariant() -> None:
    """Exact draws of a 1-D Gaussian moved by 20 MH steps with a wide kernel keep its mean and
    variance; a wrong acceptance (always accept) would widen them."""
    rng = np.random.default_rng(4)
    mu, sd = 2.0, 0.5

    def lt(z: np.ndarray) -> np.ndarray:
        return -0.5 * ((z[:, 0] - mu) / sd) ** 2

    x = rng.normal(mu, sd, (100000, 1))
    A = np.array([[1.5 * sd]])
    rates = []
    for _ in range(20):
        x, _, acc = mh_move(x, lt, A, 1.0, rng)
        rates.append(acc.mean())
    assert abs(x.mean() - mu) < 0.01
    assert abs(x.std() - sd) < 0.01
    assert 0.2 < np.mean(rates) < 0.8
    y = x.copy()  # the same kernel without the acceptance step random-walks away
    for _ in range(5):
        y = regularize(y, A, 1.0, rng)
    assert y.std() > 2 * sd


def _window_problem(L: int = 6, seed: int = 11):
    """A linear-Gaussian window: start s (3,) ~ N(m_a, P_a), noise-free x_{j+1} = F x_j, y_j = H x_j
    + v_j (j = 1..L); the exact posterior of s given the y_j (information form) and the window's
    propagate / residuals functions of trajectory_move."""
    rng = np.random.default_rng(seed)
    F = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    R = np.array([[0.5]])
    m_a, P_a = np.array([0.3, -0.2, 0.1]), np.diag([2.0, 0.5, 0.05])
    s_true = m_a + np.sqrt(np.diag(P_a)) * rng.normal(size=3)
    Phi = [np.linalg.matrix_power(F, j) for j in range(1, L + 1)]
    ys = np.array([H @ P @ s_true + np.sqrt(R[0, 0]) * rng.normal(size=1) for P in Phi])
    G = np.vstack([H @ P for P in Phi])
    info = np.linalg.inv(P_a) + G.T @ G / R[0, 0]
    P_post = np.linalg.inv(info)
    m_post = P_post @ (np.linalg.solve(P_a, m_a) + G.T @ ys[:, 0] / R[0, 0])

    def propagate(s):
        ll = np.zeros(s.shape[0])
        z = s
        for j in range(L):
            z = z @ F.T
            ll += -0.5 * ((ys[j, 0] - z[:, 0]) ** 2) / R[0, 0]
        return z, ll

    def residuals(s):
        z, rs = s, []
        for j in range(L):
            z = z @ F.T
            rs.append(ys[j] - z[:, :1])
        return np.hstack(rs), R[0, 0] * np.eye(L)

    return m_a, P_a, m_post, P_post, propagate, residuals, np.linalg.matrix_power(F, L)


def test_window_posterior_is_the_kalman_update() -> None:
    """trajectory_move.window_posterior on a linear window = the exact Gaussian posterior of the start."""
    from dpos_core.filters.trajectory_move import window_posterior

    m_a, P_a, m_post, P_post, _, residuals, _ = _window_problem()
    m, P = window_posterior((m_a, P_a), residuals, np.arange(3))
    np.testing.assert_allclose(m, m_post, atol=1e-6)
    np.testing.assert_allclose(P, P_post, atol=1e-8)


def test_trajectory_move_keeps_the_window_posterior() -> None:
    """Exact draws of a linear-Gaussian window posterior moved by 6 trajectory MH steps (independence
    proposals from a deliberately wrong Gaussian - 0.6 sigma off along each whitened axis, 1.2 times
    too wide - alternating with random walks) keep the posterior (the Kalman filter's): whitened,
    mean within 0.03 and covariance within 0.05 of the identity (Monte Carlo error of 40000
    correlated draws: about 0.01).  Dropping the independence proposal's ratio q(s) / q(s*) from
    the acceptance shifts the mean by 0.14 and shrinks the variance to 0.8 (checked by hand), so
    the test can fail; the states at the window end and the window's log-likelihoods follow the starts."""
    from dpos_core.filters.trajectory_move import window_mh_move

    m_a, P_a, m_post, P_post, propagate, _, FL = _window_problem()
    rng = np.random.default_rng(12)
    N = 40000
    s = rng.multivariate_normal(m_post, P_post, size=N)
    x, ll = propagate(s)
    Lp = np.linalg.cholesky(P_post)
    wrong = (m_post + Lp @ np.full(3, 0.6), 1.2**2 * P_post)
    s2, x2, ll2, acc = window_mh_move(s, x, ll, propagate, (m_a, P_a), wrong, 0.8, rng, np.arange(3), n_moves=6)
    assert 0.2 < acc < 0.8
    assert np.mean(np.any(s2 != s, axis=1)) > 0.8  # most particles moved
    z = np.linalg.solve(Lp, (s2 - m_post).T).T
    np.testing.assert_array_less(np.abs(z.mean(axis=0)), 0.03)
    np.testing.assert_allclose(np.cov(z.T), np.eye(3), atol=0.05)
    np.testing.assert_allclose(x2, s2 @ FL.T, atol=1e-9)
    np.testing.assert_allclose(ll2, propagate(s2)[1], atol=1e-9)


def test_children_mask_and_ess() -> None:
    idx = np.array([0, 0, 3, 3, 3, 5])
    np.testing.assert_array_equal(children_mask(idx), [False, True, False, True, True, False])
    np.testing.assert_array_equal(children_mask(np.array([4, 1, 4, 1])), [False, False, True, True])
    assert ess(np.full(50, -np.log(50))) == pytest.approx(50.0)
    lw = np.full(4, -np.inf)
    lw[2] = 0.0
    assert ess(lw) == pytest.approx(1.0)
    w = np.array([0.5, 0.25, 0.25])
    assert ess(np.log(w)) == pytest.approx(1.0 / np.sum(w**2))


def test_distinct_rows_count_as_np_unique() -> None:
    rng = np.random.default_rng(5)
    x = rng.standard_normal((300, 7))[rng.integers(0, 300, 300)]  # resampled copies
    x[::7, 3] += 1e-12  # copies that moved by a hair are distinct
    assert n_distinct_rows(x) == np.unique(x, axis=0).shape[0] < 300
    assert n_distinct_rows(x[:, ::2]) == np.unique(x[:, ::2], axis=0).shape[0]  # a non-contiguous view
    assert n_distinct_rows(np.ones((5, 3))) == 1


def test_bad_arguments_are_named() -> None:
    m, x0, P0 = _linear(K=3)
    with pytest.raises(ValueError, match="unknown particle filter 'bpf'"):
        run_sir(m, x0, P0, method="bpf")
    with pytest.raises(ValueError, match="n_particles"):
        run_sir(m, x0, P0, n_particles=1)
    with pytest.raises(ValueError, match="bandwidth_scale"):
        run_sir(m, x0, P0, bandwidth_scale=0.0)
    with pytest.raises(ValueError, match="finite"):
        run_sir(m, np.array([np.nan, 0.0]), P0)
    with pytest.raises(ValueError, match="window and n_moves"):
        run_sir(m, x0, P0, method="mcmc_rpf", window=0)
    with pytest.raises(ValueError, match="window and n_moves"):
        run_sir(m, x0, P0, method="mcmc_rpf", n_moves=0)


def test_ups_resample_move_keeps_the_kalman_filter() -> None:
    """run_upf(move=True) (resample-move inside the UPF; velocity sampled, position carried) still
    converges to the Kalman filter; the move replaces only the children's rows, each by a fresh
    draw (no two children of one parent equal), the parents' rows unchanged."""
    from dpos_core.filters.runners import SharedLinearizationUKF, _resample_move, run_upf

    m, x0, P0 = _linear()
    xk, Pk = _kalman(m, x0, P0)
    sig = np.sqrt(np.diagonal(Pk, axis1=1, axis2=2))
    for move in (False, True):
        tr = run_upf(m, x0, P0, n_particles=2000, rng=np.random.default_rng(5), sampled=[1], ess_threshold=0.9, move=move)
        assert tr.resampled.sum() > 5
        assert np.max(np.abs(tr.mean - xk) / sig) < 0.15, move
    rng = np.random.default_rng(6)
    N = 6
    m_u = rng.normal(size=(N, 2))
    P_u = np.array([[0.5, 0.1], [0.1, 0.3]])
    idx = np.array([0, 0, 0, 2, 4, 4])
    m_pred = m.f(0, m_u[idx])
    out, P = _resample_move(m, 0, SharedLinearizationUKF(), UnscentedPoints(), np.array([1]), idx, m_u, P_u, m_pred.copy(), P_u,
                            None, rng)
    same = np.all(out == m_pred, axis=1)
    np.testing.assert_array_equal(same, children_mask(idx) == 0)
    assert len({round(v, 12) for v in out[[1, 2], 0]}) == 2


def test_condition_kernel_is_the_numpy_formula() -> None:
    """runners._condition with the factor of the sampled block given (numba kernel
    filters._condition_kernel) = the numpy path (gain, conditional mean, symmetrized covariance with
    the sampled rows and columns zeroed), for one shared covariance and one per particle."""
    from dpos_core.filters.linalg import chol
    from dpos_core.filters.runners import _condition

    rng = np.random.default_rng(8)
    N, n = 6, 7
    for S in (np.array([4, 5, 6]), np.array([0, 3])):
        for shared in (True, False):
            A = rng.normal(size=(n, n)) if shared else rng.normal(size=(N, n, n))
            P = A @ np.swapaxes(A, -1, -2) + np.eye(n)
            m, xs = rng.normal(size=(N, n)), rng.normal(size=(N, S.size))
            L = chol(P[..., S[:, None], S[None, :]])
            m_k, P_k = _condition(m, P, S, xs, L)
            m_n, P_n = _condition(m, P, S, xs)
            np.testing.assert_allclose(m_k, m_n, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(P_k, P_n, rtol=1e-12, atol=1e-12)
            np.testing.assert_array_equal(P_k, np.swapaxes(P_k, -1, -2))
            np.testing.assert_allclose(m_k[:, S], xs, rtol=1e-12, atol=1e-12)
