"""Forward filters and backward smoothers over a :class:`~.model.StateSpaceModel`.

* :func:`run_sigma_point_filter` -> :class:`GaussianTrack`: UKF (unscented points) or CDKF
  (central-difference points) with closed-loop feedback; :func:`smooth_gaussian` is URTSS / RTS.
* :func:`run_upf` -> :class:`ParticleTrack`: the unscented particle filter (seed 000 eq. 2-8;
  van der Merwe et al. 2000): every particle carries a UKF whose posterior is its proposal,
  importance weights in logs, SIR resampling when the effective sample size drops below a
  threshold.  All particles and their sigma points are propagated in one vectorized call.
* :func:`ffbsm` (seed 000 eq. 9): forward-filtering backward-smoothing reweighting of the
  stored particles, ``w_{k|K}^i = w_k^i sum_j w_{k+1|K}^j p(x_{k+1}^j|x_k^i) / sum_m w_k^m p(x_{k+1}^j|x_k^m)``.

Degenerate transitions.  Bias and misalignment states have no process noise, so
``p(x_{k+1} | x_k)`` is a point mass in those directions and neither eq. 6 nor eq. 9 is defined
for particles sampled from a proposal.  We regularize the transition density: the directions
without noise get the kernel covariance of a regularized particle filter,
``h^2 Cov_particles`` with Silverman's bandwidth ``h = (4 / (N (d + 2)))^(1 / (d + 4))``
(Musso, Oudjane, Le Gland 2001), i.e. the deterministic transition is replaced by the kernel
density estimate that the particle cloud itself supports.  It keeps eq. 6 and eq. 9 well
defined, vanishes as N grows, and does not bias the noise-driven directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .gaussian import rts_smooth, ut_predict, ut_update
from .linalg import chol, symmetrize, whitener
from .model import StateSpaceModel
from .particle import ess, log_normalize, systematic_resample
from .points import UnscentedPoints

FloatArray = NDArray[np.float64]


# ------------------------------------------------------------------------------------ Gaussian


@dataclass
class GaussianTrack:
    """Forward pass of a Gaussian filter.

    x_f (K, n), P_f (K, n, n): filtered, after the feedback shift; x_p, P_p, C (K-1, ...):
    predictions (shifted like the filtered state of their epoch) and cross-covariances; corrections (K, n) applied (zeros when none);
    nu (K, p) innovations and S (K, p, p) their covariances (NaN where no measurement).
    """

    x_f: FloatArray
    P_f: FloatArray
    x_p: FloatArray
    P_p: FloatArray
    C: FloatArray
    corrections: FloatArray
    nu: FloatArray
    S: FloatArray


def run_sigma_point_filter(model: StateSpaceModel, x0: FloatArray, P0: FloatArray, points=UnscentedPoints()) -> GaussianTrack:
    K, n = model.n_epochs, model.n
    x, P = np.asarray(x0, dtype=float).copy(), np.asarray(P0, dtype=float).copy()
    x_f, P_f = np.empty((K, n)), np.empty((K, n, n))
    x_p, P_p, C = np.empty((K - 1, n)), np.empty((K - 1, n, n)), np.empty((K - 1, n, n))
    corr = np.zeros((K, n))
    nus, Ss = [], []
    for k in range(K):
        if k > 0:
            pr = ut_predict(x, P, lambda X: model.f(k - 1, X), model.Q(k - 1), points)
            x_p[k - 1], P_p[k - 1], C[k - 1] = pr.x, pr.P, pr.C
            x, P = pr.x, pr.P
        y = model.y(k)
        if y is not None:
            up = ut_update(x, P, y, lambda X: model.h(k, X), model.R(k), points, model.residual)
            x, P = up.x, up.P
            nus.append(up.nu), Ss.append(up.S)
        else:
            nus.append(None), Ss.append(None)
        c = model.feedback(k, x)
        if c is not None:
            corr[k] = c
            x = model.shift(k, x, c)
            if k > 0:  # keep x_{k|k-1} in the same (corrected) coordinates as x_{k|k} for the smoother
                x_p[k - 1] = model.shift(k, x_p[k - 1], c)
        x_f[k], P_f[k] = x, P
    p = next((v.shape[0] for v in nus if v is not None), 0)
    nu = np.array([v if v is not None else np.full(p, np.nan) for v in nus])
    S = np.array([s if s is not None else np.full((p, p), np.nan) for s in Ss])
    return GaussianTrack(x_f, P_f, x_p, P_p, C, corr, nu, S)


def smooth_gaussian(track: GaussianTrack) -> tuple[FloatArray, FloatArray]:
    """URTSS (or RTS for a linear filter): smoothed ``x_{k|K}`` (K, n) and ``P_{k|K}`` (K, n, n),
    in the coordinates of the filtered states (after each epoch's feedback)."""
    return rts_smooth(track.x_f, track.P_f, track.x_p, track.P_p, track.C)


# ------------------------------------------------------------------------------------ particles


@dataclass
class ParticleTrack:
    """Forward pass of the UPF.

    particles (K, N, n): the weighted particle set of each epoch after the feedback shift and
    before resampling; logw (K, N) its normalized log weights; proposed (K, N, n): the same
    particles in the coordinates of the transition that produced them (before the shift);
    corrections (K, n); ess (K,); resampled (K,) bool; mean (K, n) weighted filtered means.
    """

    particles: FloatArray
    proposed: FloatArray
    logw: FloatArray
    corrections: FloatArray
    ess: FloatArray
    resampled: NDArray[np.bool_]
    mean: FloatArray


def _noisy_dims(Q: FloatArray) -> NDArray[np.bool_]:
    d = np.diag(Q)
    return d > 1e-30 * max(1.0, float(d.max(initial=0.0)))


def regularized_transition_cov(Q: FloatArray, particles: FloatArray, logw: FloatArray) -> FloatArray:
    """Process noise with the kernel regularization of the noise-free directions (module docstring)."""
    det = ~_noisy_dims(Q)
    Qr = Q.copy()
    if det.any():
        N = particles.shape[0]
        d = int(det.sum())
        h = (4.0 / (N * (d + 2))) ** (1.0 / (d + 4))
        w = np.exp(logw)
        xs = particles[:, det]
        m = w @ xs
        cov = (xs - m).T @ ((xs - m) * w[:, None])
        floor = 1e-18 + 1e-12 * np.abs(m) ** 2
        Qr[np.ix_(det, det)] += h * h * symmetrize(cov) + np.diag(floor)
    return Qr


def run_upf(
    model: StateSpaceModel,
    x0: FloatArray,
    P0: FloatArray,
    n_particles: int = 100,
    rng: np.random.Generator | None = None,
    points=UnscentedPoints(),
    ess_threshold: float = 0.5,
) -> ParticleTrack:
    """Unscented particle filter (module docstring).

    Args:
        x0, P0: prior mean (n,) and covariance (n, n); the particles are drawn from it and each
            starts its UKF with ``P0`` (seed 000 step 1).
        ess_threshold: resample (systematic) when ESS < threshold * N.
    """
    rng = np.random.default_rng() if rng is None else rng
    K, n, N = model.n_epochs, model.n, int(n_particles)
    if N < 1:
        raise ValueError(f"n_particles must be >= 1, got {n_particles}")
    parts = np.empty((K, N, n))
    proposed = np.empty((K, N, n))
    logws = np.empty((K, N))
    corr = np.zeros((K, n))
    ess_k = np.empty(K)
    res_k = np.zeros(K, dtype=bool)
    means = np.empty((K, n))

    x0 = np.asarray(x0, dtype=float)
    P0 = np.asarray(P0, dtype=float)
    x = np.broadcast_to(x0, (N, n)).copy()  # particles (epoch 0: the prior mean, seed 000 step 1)
    P = np.broadcast_to(P0, (N, n, n)).copy()  # each particle's UKF covariance
    logw = np.full(N, -np.log(N))
    for k in range(K):
        if k > 0:
            Qk = model.Q(k - 1)
            pr = ut_predict(x, P, lambda X: model.f(k - 1, X), Qk, points)
            xm, Pm = pr.x, pr.P
            prior_mean = model.f(k - 1, x)
            prior_W, prior_c = whitener(regularized_transition_cov(Qk, x, logw))
        else:
            xm, Pm = x, P
            prior_mean = x
            prior_W, prior_c = whitener(P0)
        y = model.y(k)
        if y is not None:
            up = ut_update(xm, Pm, y, lambda X: model.h(k, X), model.R(k), points, model.residual)
            xm, Pm = up.x, up.P
        # importance sampling from each particle's UKF posterior q (eq. 6)
        Lq = chol(Pm)
        z = rng.standard_normal((N, n))
        x = xm + np.einsum("nij,nj->ni", Lq, z)
        P = Pm
        # log q and log p(x_k | x_{k-1}) (both without the common -n/2 log 2 pi)
        log_q = -0.5 * np.sum(z * z, axis=1) - np.sum(np.log(np.diagonal(Lq, axis1=1, axis2=2)), axis=1)
        r = (x - prior_mean) @ prior_W.T
        log_p = prior_c + 0.5 * n * np.log(2.0 * np.pi) - 0.5 * np.sum(r * r, axis=1)
        if y is not None:
            Wr, cr = whitener(model.R(k))
            ry = model.residual(y[None, :], model.h(k, x)) @ Wr.T
            log_lik = cr - 0.5 * np.sum(ry * ry, axis=1)
        else:
            log_lik = 0.0
        logw = log_normalize(logw + log_lik + log_p - log_q)
        proposed[k] = x
        mean = np.exp(logw) @ x
        c = model.feedback(k, mean)
        if c is not None:
            corr[k] = c
            x = model.shift(k, x, c)
            mean = model.shift(k, mean, c)
        parts[k] = x
        logws[k] = logw
        means[k] = mean
        ess_k[k] = ess(logw)
        if ess_k[k] < ess_threshold * N:
            idx = systematic_resample(logw, rng)
            x, P = x[idx], P[idx]
            logw = np.full(N, -np.log(N))
            res_k[k] = True
    return ParticleTrack(parts, proposed, logws, corr, ess_k, res_k, means)


def ffbsm(model: StateSpaceModel, track: ParticleTrack) -> FloatArray:
    """Backward reweighting (seed 000 eq. 9): smoothed normalized log weights (K, N) of
    ``track.particles``.  ``w_{K-1|K} = w_{K-1}``; the transition density is the regularized one
    of the forward pass."""
    K, N, n = track.particles.shape
    logws = np.empty((K, N))
    logws[-1] = track.logw[-1]
    for k in range(K - 2, -1, -1):
        xk, lwk = track.particles[k], track.logw[k]
        Qr = regularized_transition_cov(model.Q(k), xk, lwk)
        W, c0 = whitener(Qr)
        fx = model.f(k, xk)  # (N, n): means of p(. | x_k^i)
        nxt = track.proposed[k + 1]  # x_{k+1}^j in the transition's coordinates
        # L[i, j] = log p(x_{k+1}^j | x_k^i)
        R = (nxt[None, :, :] - fx[:, None, :]) @ W.T
        L = c0 - 0.5 * np.sum(R * R, axis=2)
        denom = _logsumexp(lwk[:, None] + L, axis=0)  # (N,) over m, for each j
        logws[k] = log_normalize(lwk + _logsumexp(logws[k + 1][None, :] + L - denom[None, :], axis=1))
    return logws


def weighted_moments(particles: FloatArray, logw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (K, n) and covariance (K, n, n) of particle sets (K, N, n)."""
    w = np.exp(logw)
    m = np.einsum("kn,kni->ki", w, particles)
    d = particles - m[:, None, :]
    return m, symmetrize(np.einsum("kn,kni,knj->kij", w, d, d))


def _logsumexp(a: FloatArray, axis: int) -> FloatArray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(a - m), axis=axis))
