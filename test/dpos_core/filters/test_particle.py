"""Unscented particle filter and FFBSm smoother on linear-Gaussian models."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.errors import NumericalFailure
from dpos_core.filters.linalg import chol
from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.particle import RESAMPLING, ess, log_normalize, resample_indices
from dpos_core.filters.runners import ffbsm, run_sigma_point_filter, run_upf, smooth_gaussian, weighted_moments


def _model(K: int = 30, seed: int = 0, bias: bool = False) -> tuple[LinearGaussianModel, np.ndarray, np.ndarray]:
    """Position/velocity random walk observed in position (+ a constant, noise-free bias state)."""
    rng = np.random.default_rng(seed)
    dt = 1.0
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]) * 0.05
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.5]])
    if bias:  # y = pos + b, b constant (no process noise), and an extra velocity-only measurement
        F = np.block([[F, np.zeros((2, 1))], [np.zeros((1, 2)), np.eye(1)]])
        Q = np.block([[Q, np.zeros((2, 1))], [np.zeros((1, 3))]])
        H = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
        R = np.diag([0.5, 0.2])
    n = F.shape[0]
    x = rng.normal(size=n)
    ys = []
    for _ in range(K):
        x = F @ x + (chol(Q + 1e-300 * np.eye(n)) @ rng.normal(size=n) if not bias else np.r_[chol(Q[:2, :2]) @ rng.normal(size=2), 0.0])
        ys.append(H @ x + chol(R) @ rng.normal(size=H.shape[0]))
    m = LinearGaussianModel(F, Q, H, R, np.array(ys))
    return m, np.zeros(n), np.eye(n) * 2.0


def _kalman(m: LinearGaussianModel, x0, P0):
    tr = run_sigma_point_filter(m, x0, P0)
    return tr.x_f, smooth_gaussian(tr)[0]


@pytest.mark.parametrize("scheme", RESAMPLING)
def test_resampling_scheme_draws_index_i_n_w_i_times_in_expectation(scheme: str) -> None:
    """N = 5 weights, one of them zero; over M = 4000 draws the mean count of index i is N w_i
    within 5 standard errors of the mean (the multinomial variance N w_i (1 - w_i) per draw, which
    bounds the stratified and systematic ones); every draw has N indices; a zero weight is never
    drawn; systematic counts are floor(N w_i) or ceil(N w_i)."""
    rng = np.random.default_rng(0)
    w = np.array([0.0, 0.45, 0.3, 0.15, 0.1])
    with np.errstate(divide="ignore"):
        logw = log_normalize(np.log(w))
    N, M = w.size, 4000
    counts = np.array([np.bincount(resample_indices(logw, rng, scheme), minlength=N) for _ in range(M)])
    assert counts.shape == (M, N) and np.all(counts.sum(axis=1) == N)
    se = np.sqrt(N * w * (1.0 - w) / M)
    assert np.all(np.abs(counts.mean(axis=0) - N * w) <= 5.0 * se), (counts.mean(axis=0), N * w, se)
    assert np.all(counts[:, 0] == 0)
    if scheme == "systematic":
        assert np.all((counts == np.floor(N * w)) | (counts == np.ceil(N * w)))


def test_upf_resampling_scheme_is_a_choice() -> None:
    """run_upf(resample=...) takes every scheme of RESAMPLING (each resamples and tracks the
    Kalman mean: measured rms 0.05-0.1 with 200 particles, the position's posterior std ~0.6), the
    default is systematic (same draws, same result), anything else is refused."""
    m, x0, P0 = _model()
    kf, _ = _kalman(m, x0, P0)
    for scheme in RESAMPLING:
        tr = run_upf(m, x0, P0, 200, np.random.default_rng(1), resample=scheme)
        assert tr.resampled.any(), scheme
        assert np.sqrt(np.mean((tr.mean - kf) ** 2)) < 0.2, scheme
    a = run_upf(m, x0, P0, 50, np.random.default_rng(2))
    b = run_upf(m, x0, P0, 50, np.random.default_rng(2), resample=RESAMPLING[0])
    np.testing.assert_array_equal(a.mean, b.mean)
    assert RESAMPLING[0] == "systematic"
    with pytest.raises(ValueError, match="unknown resampling scheme"):
        run_upf(m, x0, P0, 10, np.random.default_rng(0), resample="residual")
    with pytest.raises(ValueError, match="unknown resampling scheme"):
        resample_indices(np.log(np.full(3, 1 / 3)), np.random.default_rng(0), "residual")


def test_log_weights_and_ess() -> None:
    logw = log_normalize(np.log(np.array([0.5, 0.25, 0.125, 0.125])))
    np.testing.assert_allclose(np.exp(logw).sum(), 1.0, rtol=1e-15)
    assert ess(logw) == pytest.approx(1.0 / np.sum(np.exp(logw) ** 2))
    with pytest.raises(NumericalFailure, match="weights are zero"):
        log_normalize(np.full(3, -np.inf))


def test_upf_mean_approaches_kalman_mean_as_particles_grow() -> None:
    m, x0, P0 = _model()
    kf, _ = _kalman(m, x0, P0)
    errs = {}
    for N in (10, 100, 1000):
        e = []
        for seed in range(4):
            tr = run_upf(m, x0, P0, N, np.random.default_rng(seed))
            e.append(np.sqrt(np.mean((tr.mean - kf) ** 2)))
        errs[N] = np.mean(e)
    # Monte Carlo error ~ c / sqrt(N): tenfold particles cut it by ~3 (require 2 for 100 -> 1000)
    assert errs[1000] < errs[100] / 2 and errs[100] < errs[10], errs
    assert errs[1000] < 0.2  # posterior std of the position is ~0.6


def test_ffbsm_approaches_rts_and_weights_are_consistent() -> None:
    m, x0, P0 = _model()
    _, rts = _kalman(m, x0, P0)
    err_s, err_f = [], []
    for seed in range(3):
        tr = run_upf(m, x0, P0, 400, np.random.default_rng(seed))
        lw = ffbsm(tr)
        np.testing.assert_allclose(np.exp(lw).sum(axis=1), 1.0, atol=1e-12)
        np.testing.assert_array_equal(lw[-1], tr.logw[-1])
        xs, _ = weighted_moments(tr.particles, lw)
        err_s.append(np.sqrt(np.mean((xs - rts) ** 2)))
        err_f.append(np.sqrt(np.mean((tr.mean - rts) ** 2)))
    # the backward pass moves the particle estimate towards the RTS smoother
    assert np.mean(err_s) < 0.75 * np.mean(err_f), (err_s, err_f)


def test_rao_blackwellized_ups_equals_rts_with_a_noise_free_state() -> None:
    """A constant bias state (no process noise) is carried by each particle's Kalman filter, not
    sampled (module docstring): the weights stay well defined (healthy ESS), the filter mean
    approaches the Kalman filter's and the smoother (FFBSm weights + the carried states' RTS
    step) the RTS smoother's, closer with more particles."""
    from dpos_core.filters.runners import rb_smooth

    m, x0, P0 = _model(K=40, bias=True)
    kf, rts = _kalman(m, x0, P0)
    err_f, err_s = {}, {}
    for N in (20, 500):
        ef, es = [], []
        for seed in range(3):
            tr = run_upf(m, x0, P0, N, np.random.default_rng(seed), sampled=[1])  # the noise-driven velocity
            assert np.all(np.isfinite(tr.logw)) and np.median(tr.ess) > 0.3 * N
            lw, xs, Ps = rb_smooth(tr)
            np.testing.assert_allclose(np.exp(lw).sum(axis=1), 1.0, atol=1e-12)
            np.testing.assert_array_equal(lw[-1], tr.logw[-1])
            assert np.all(np.linalg.eigvalsh(Ps) > -1e-12)
            ef.append(np.sqrt(np.mean((tr.mean - kf) ** 2)))
            es.append(np.sqrt(np.mean((xs - rts) ** 2)))
        err_f[N], err_s[N] = np.mean(ef), np.mean(es)
    assert err_f[500] < err_f[20] / 2 and err_s[500] < err_s[20] / 2, (err_f, err_s)
    assert err_s[500] < 0.05 and err_f[500] < 0.05, (err_f, err_s)  # posterior std of the bias ~0.4


def test_sampled_components_are_validated() -> None:
    m, x0, P0 = _model()
    with pytest.raises(ValueError, match="at least one"):
        run_upf(m, x0, P0, 10, np.random.default_rng(0), sampled=[])


@pytest.mark.parametrize("sampled", [None, [1]])
def test_shared_linearization_equals_per_particle_ukfs_on_a_linear_model(sampled) -> None:
    """On a linear-Gaussian model every particle's UKF has the same covariance and gain, so the
    shared-linearization engine must reproduce the per-particle one (same random draws)."""
    from dpos_core.filters.runners import PerParticleUKF, SharedLinearizationUKF, rb_smooth

    m, x0, P0 = _model(K=25, bias=True)
    a = run_upf(m, x0, P0, 50, np.random.default_rng(7), sampled=sampled, engine=PerParticleUKF())
    b = run_upf(m, x0, P0, 50, np.random.default_rng(7), sampled=sampled, engine=SharedLinearizationUKF())
    np.testing.assert_array_equal(a.resampled, b.resampled)
    np.testing.assert_allclose(b.particles, a.particles, atol=1e-9)
    np.testing.assert_allclose(b.logw, a.logw, atol=1e-9)
    for xa, xb in zip(rb_smooth(a)[1:], rb_smooth(b)[1:]):
        np.testing.assert_allclose(xb, xa, atol=1e-9)
