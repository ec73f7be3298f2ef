"""The SINS/SAR filters ([Yan2016]) on a :class:`~.model.SarModel`: the Gaussian baselines, the
three particle filters of :mod:`dpos_core.filters.pf` and the oracle.

* ``ekf``: extended Kalman filter - the model's f and h linearized at the estimate by central
  differences (filters/jacobian.py), covariance and update by the linear KF pieces of
  filters/gaussian.py (the update's innovation is the nonlinear ``y - h(x)``).
* ``ukf``: unscented Kalman filter (filters/gaussian.py ``ut_predict`` / ``ut_update``).
* ``pf``, ``rpf``, ``mcmc_rpf``, ``mcmc_rpf_literal``: :func:`dpos_core.filters.pf.run_sir` -
  [Yan2016]'s classical PF, regularized PF and modified PF: ``mcmc_rpf`` with Metropolis-Hastings
  moves of the trajectories over a window (the one that tracks, docs/sar.md),
  ``mcmc_rpf_literal`` with local resampling and eq. 10-13's move of the last state.
* ``oracle``: the EKF linearized about the true error state (simulations only) with the model's
  exact noise statistics.  Its covariance recursion ``P_{k+1} = F P F^T + Q``, ``P^-1 += H^T R^-1 H``
  with the Jacobians at the truth is the posterior Cramer-Rao bound of the model (Tichavsky,
  Muravchik, Nehorai 1998, additive Gaussian noise) evaluated along the one simulated truth: no
  filter of this model can have a smaller error covariance, and its estimate is the best linear
  one about the truth.  The attitude quaternion's estimate is normalized after every update.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from dpos_core.units import FloatArray

from ..filters.gaussian import kf_predict, kf_update, ut_predict, ut_update
from ..filters.jacobian import central_difference_jacobian
from ..filters.pf import PF_METHODS, run_sir
from .model import N_STATES, SarModel

#: the selectable SINS/SAR methods (dpos-eval --methods), [Yan2016]'s three particle filters last
METHODS = ("ekf", "ukf") + PF_METHODS
#: the oracle (simulations only: needs the true error state)
ORACLE = "oracle"

#: central-difference steps of the EKF's Jacobians per state (quaternion, m/s, m, rad/s, m/s^2)
JACOBIAN_STEPS = np.r_[np.full(4, 1e-7), np.full(3, 1e-4), np.full(3, 1e-2), np.full(3, 1e-10), np.full(3, 1e-7)]


@dataclass
class SarEstimate:
    """A method's filtered error states x (K, 16) and covariances P (K, 16, 16); for the particle
    filters also ess (K,), resampled (K,) (0/1), the Metropolis-Hastings acceptance (K,) and the
    distinct particles carried on (K,) (:class:`~dpos_core.filters.pf.SirTrack`)."""

    x: FloatArray
    P: FloatArray
    extra: dict[str, FloatArray] = field(default_factory=dict)


def _project(model: SarModel, x: FloatArray) -> FloatArray:
    return model.project(x)


def run_gaussian(model: SarModel, x0: FloatArray, P0: FloatArray, kind: str, truth_x: FloatArray | None = None) -> SarEstimate:
    """EKF (``kind='ekf'``; with ``truth_x`` (K, 16) linearized about the truth: the oracle) or
    UKF (``kind='ukf'``) over the model's epochs (module docstring)."""
    if kind not in ("ekf", "ukf"):
        raise ValueError(f"unknown Gaussian filter {kind!r}; choose ekf or ukf")
    K, n = model.n_epochs, N_STATES
    x, P = _project(model, np.asarray(x0, dtype=float)), np.asarray(P0, dtype=float).copy()
    xs, Ps = np.empty((K, n)), np.empty((K, n, n))
    for k in range(K):
        if k > 0:
            if kind == "ukf":
                pr = ut_predict(x, P, partial(model.f, k - 1), model.Q(k - 1))
                x, P = pr.x, pr.P
            else:
                lin = x if truth_x is None else truth_x[k - 1]
                F = central_difference_jacobian(partial(model.f, k - 1), lin, JACOBIAN_STEPS)
                f_lin = model.f(k - 1, lin)
                pr = kf_predict(x - lin, P, F, model.Q(k - 1))
                x, P = f_lin + pr.x, pr.P
            x = _project(model, x)
        y = model.y(k)
        if y is not None:
            if kind == "ukf":
                up = ut_update(x, P, y, partial(model.h, k), model.R(k), residual=model.residual)
                x, P = up.x, up.P
            else:
                lin = x if truth_x is None else truth_x[k]
                H = central_difference_jacobian(partial(model.h, k), lin, JACOBIAN_STEPS)
                nu = model.residual(y, model.h(k, lin) + H @ (x - lin))
                up = kf_update(x, P, nu + H @ x, H, model.R(k))  # the linear update with the nonlinear innovation
                x, P = up.x, up.P
            x = _project(model, x)
        xs[k], Ps[k] = x, P
    return SarEstimate(xs, Ps)


def run(method: str, model: SarModel, x0: FloatArray, P0: FloatArray, *, n_particles: int = 1000,
        rng: np.random.Generator | None = None, truth_x: FloatArray | None = None, bandwidth_scale: float = 1.0) -> SarEstimate:
    """Run one method of :data:`METHODS` (or :data:`ORACLE`, which needs ``truth_x`` (K, 16))."""
    if method == ORACLE:
        if truth_x is None:
            raise ValueError("the oracle needs the true error states (truth_x)")
        return run_gaussian(model, x0, P0, "ekf", truth_x)
    if method in ("ekf", "ukf"):
        return run_gaussian(model, x0, P0, method)
    if method in PF_METHODS:
        tr = run_sir(model, x0, P0, n_particles=n_particles, rng=rng, method=method, bandwidth_scale=bandwidth_scale)
        mean = model.project(tr.mean)
        return SarEstimate(mean, tr.cov, {"ess": tr.ess, "resampled": tr.resampled.astype(float), "accept": tr.accept,
                                             "distinct": tr.distinct})
    raise ValueError(f"unknown SINS/SAR method {method!r}; choose from {METHODS + (ORACLE,)}")
