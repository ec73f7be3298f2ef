"""The UPF's mixture innovations (ParticleTrack.mixture.nu / S): the measurement minus the weighted
mean prediction, with the mixture's predictive covariance (moment matched)."""

from __future__ import annotations

import numpy as np

from dpos_core.filters.runners import run_sigma_point_filter, run_upf

from .test_particle import _model


def test_mixture_innovations_approach_the_kalman_filters() -> None:
    """On a linear-Gaussian model the Rao-Blackwellized UPF's mixture is the Kalman filter's
    posterior in the limit: its innovations and their covariances approach the Kalman filter's;
    their NIS averages the measurement size."""
    m, x0, P0 = _model(K=40, bias=True)
    kf = run_sigma_point_filter(m, x0, P0)
    tr = run_upf(m, x0, P0, 500, np.random.default_rng(3), sampled=[1])
    nu, S = tr.mixture.nu, tr.mixture.S
    assert nu.shape == kf.nu.shape == (40, 2) and S.shape == kf.S.shape == (40, 2, 2)
    np.testing.assert_allclose(nu[0], kf.nu[0], atol=1e-9)  # before any sampling: the same prior
    np.testing.assert_allclose(S[0], kf.S[0], rtol=1e-9, atol=1e-12)
    sig = np.sqrt(np.diagonal(kf.S, axis1=1, axis2=2))
    assert np.max(np.abs(nu - kf.nu) / sig) < 0.15
    np.testing.assert_allclose(S, kf.S, rtol=0.15, atol=0.02)
    nis = np.einsum("ki,kij,kj->k", nu, np.linalg.inv(S), nu)
    assert 1.2 < nis.mean() < 3.0  # 2 per epoch (chi^2, 40 epochs: sd of the mean 0.3)


def test_mixture_innovations_nan_without_measurement() -> None:
    m, x0, P0 = _model(K=10)
    y = m.y
    m.y = lambda k: None if k in (0, 4) else y(k)  # type: ignore[method-assign]
    tr = run_upf(m, x0, P0, 20, np.random.default_rng(0))
    nu, S = tr.mixture.nu, tr.mixture.S
    assert nu.shape == (10, 1) and S.shape == (10, 1, 1)
    assert np.all(np.isnan(nu[[0, 4]])) and np.all(np.isnan(S[[0, 4]]))
    assert np.all(np.isfinite(np.delete(nu, [0, 4], axis=0))) and np.all(np.delete(S, [0, 4], axis=0) > 0)
