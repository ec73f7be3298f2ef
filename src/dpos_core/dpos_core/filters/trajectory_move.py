"""The trajectory Metropolis-Hastings move of the windowed MCMC-regularized PF (``mcmc_rpf``
of :func:`~.pf.run_sir`), vectorized over the particles.

[Yan2016] moves the particles' *trajectories* over a window of L steps by Metropolis-Hastings
(eq. 10-13) after resampling, the resample-move of Gilks and Berzuini (2001).  On a model whose
transition noise is tiny (an INS error model: IMU white noise, constant biases) a move of the last
state alone is judged by the transition density ``p(x_k | x_{k-1})`` and is rejected whenever it
leaves the width of the IMU noise, so the copies never spread (docs/sar.md).  Here the move acts
on the trajectory's *window start* ``s = x_{k0}`` and regenerates the whole window from it with
the particle's own process-noise draws ``w_{k0..k-1}`` (a reparametrization of the trajectory by
``(s, w)``: ``x_{j+1} = project(f_j(x_j) + w_j)``).  The move of ``s`` with the ``w`` kept is a
block Metropolis-Hastings step on the joint density of ``(s, w_{k0..k-1})`` given
``y_{k0+1..k}``, whose ``w`` factors cancel in the ratio, so the target of ``s`` is

    pi(s) = p(s | y_{..k0}) * prod_{j = k0+1..k} p(y_j | x_j(s))

(Gilks and Berzuini 2001).  The window-start density
``p(s | y_{..k0})`` of a particle filter has no closed form; it is the Gaussian of the particle
cloud at ``k0`` (its mean and covariance, the *anchor*): exact for a Gaussian filtering density,
an approximation otherwise (the nonlinearity inside the window is kept exactly).  The constant
biases are part of ``s``: they are moved as static parameters with the whole window's
likelihood, Gilks and Berzuini's own use of the move.

The proposals are shaped by the observable subspace: :func:`window_posterior` linearizes the
window (the noise-free trajectories from the anchor's mean, central differences) and conditions
the anchor on the window's measurements by the Kalman update - the Gaussian ``N(m, P)`` of ``s``
given ``y_{..k}``, narrow along the directions the window's data observe and as wide as the
anchor along the others.  The moves alternate

* an independence Metropolis-Hastings step (Tierney 1994) with the proposal ``N(m, c^2 P)``
  (``c`` = 1.05, slightly above 1 for heavier tails than the target's), acceptance
  ``min(1, pi(s*) q(s) / (pi(s) q(s*)))`` - the linearized proposal of Doucet, Godsill and
  Andrieu (2000) used as an MH proposal, so its error is corrected, not inherited;
* a random-walk step ``s* = s + h A eps``, ``A A^T = P``, [Yan2016]'s regularization kernel
  (eq. 8) with the bandwidth ``h`` (``h_opt = 0.66`` for N = 1000, n = 16, near the
  ``2.38 / sqrt(n)`` of Roberts, Gelman and Gilks 1997) and the symmetric acceptance of eq. 13.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import FloatArray

from .linalg import gauss_logpdf, symmetrize

#: ``propagate(s) -> (x_k (M, n), sum of log p(y_j | x_j) over the window (M,))`` for starts s (M, n)
Propagate = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
#: ``residuals(s) -> (r (M, m), R (m, m))``: the window's stacked measurement residuals
#: ``y_j - h_j(x_j(s))`` of noise-free trajectories from starts s (M, n) and their covariance
Residuals = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
#: the independence proposal's scale ``c`` on the window posterior's sigma: a little above 1 for
#: tails heavier than the target's; in 15 dimensions every 1 % costs acceptance (paper_sar, N =
#: 1000: c = 1.2 accepts 0.5 and the cloud's covariance shrinks, NEES 90-400; c = 1.05 accepts 0.85,
#: NEES 15-16; c = 1 accepts 0.99, NEES 23)
PROPOSAL_INFLATION = 1.05


def _regularized(S: FloatArray) -> FloatArray:
    d = np.diag(S)
    return symmetrize(S) + np.diag(1e-9 * d + 1e-300)


def anchor_logpdf(s: FloatArray, mean: FloatArray, cov: FloatArray, free: NDArray[np.intp]) -> FloatArray:
    """``log N(s; mean, cov)`` (M,) of window starts s (M, n) on the ``free`` components (a
    quaternion's scalar part, a function of the others, left out); a relative ``1e-9`` of the
    diagonal is added so that a covariance singular in a direction still has a density."""
    return gauss_logpdf(s[:, free] - mean[free], _regularized(cov[np.ix_(free, free)]))


def window_posterior(
    anchor: tuple[FloatArray, FloatArray], residuals: Residuals, free: NDArray[np.intp],
    project: Callable[[FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The Gaussian ``N(m, P)`` of the window start given the window's measurements (module
    docstring): the anchor ``(mean (n,), cov (n, n))`` updated by the Kalman rule with the
    window's residuals at the anchor's mean and their Jacobian by central differences (steps of
    1e-3 of the anchor's sigma per free component; 1 + 2 n_free noise-free trajectories in one
    batch).  Returns m (n,) and P (n, n) (zero outside the free components)."""
    m_a, P_a = anchor
    n = m_a.size
    sd = np.sqrt(np.clip(np.diag(P_a)[free], 0.0, None))
    step = np.where(sd > 0, 1e-3 * sd, 1e-12)
    pts = np.repeat(m_a[None, :], 1 + 2 * free.size, axis=0)
    pts[1 + np.arange(free.size), free] += step
    pts[1 + free.size + np.arange(free.size), free] -= step
    if project is not None:
        pts = project(pts)
    r, R = residuals(pts)
    if r.shape[1] == 0:
        return m_a.copy(), P_a.copy()
    G = -(r[1:1 + free.size] - r[1 + free.size:]).T / (2.0 * step)  # d h / d s_free (m, n_free)
    Pf = P_a[np.ix_(free, free)]
    S = symmetrize(G @ Pf @ G.T + R)
    K = np.linalg.solve(S, G @ Pf).T  # Pf G^T S^-1 (n_free, m)
    m = m_a.copy()
    m[free] += K @ r[0]
    P = np.zeros((n, n))
    P[np.ix_(free, free)] = symmetrize(Pf - K @ G @ Pf)
    return m, P


def window_mh_move(
    s: FloatArray,
    x_end: FloatArray,
    loglik_window: FloatArray,
    propagate: Propagate,
    anchor: tuple[FloatArray, FloatArray],
    post: tuple[FloatArray, FloatArray],
    h: float,
    rng: np.random.Generator,
    free: NDArray[np.intp],
    n_moves: int = 2,
    project: Callable[[FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """``n_moves`` Metropolis-Hastings steps of every particle's window start (module docstring):
    the odd ones independence proposals from ``N(post)`` (inflated by
    :data:`PROPOSAL_INFLATION`), the even ones the random walk ``h A eps`` with ``A A^T = P_post``.

    Args:
        s: window starts ``x_{k0}`` (N, n); x_end: the particles' current states ``x_k`` (N, n)
            (the window propagated from s); loglik_window: ``sum_j log p(y_j | x_j)`` of their
            windows (N,).
        propagate: regenerates the window from starts (M, n) (the particles' own noise draws).
        anchor: the window-start density's mean (n,) and covariance (n, n).
        post: the window posterior's mean (n,) and covariance (n, n) (:func:`window_posterior`).
        h: the random walk's bandwidth.
        free: the components the densities are evaluated on.
        project: optional constraint applied to proposed starts (a unit quaternion: its change of
            the vector part is second order in the attitude error, 1e-8 here, and neglected in q).

    Returns:
        ``(s, x_end, loglik_window, acceptance)``: the moved starts (N, n), states (N, n), window
        log-likelihoods (N,) and the fraction of proposals accepted (over all steps).
    """
    m_a, P_a = anchor
    m_p, P_p = post
    c = PROPOSAL_INFLATION
    Pq = _regularized(c * c * P_p[np.ix_(free, free)])
    Lq = np.linalg.cholesky(Pq)
    lt = anchor_logpdf(s, m_a, P_a, free) + loglik_window
    N, n_acc = s.shape[0], 0
    for i in range(int(n_moves)):
        independent = i % 2 == 0
        if independent:
            prop = np.repeat(m_p[None, :], N, axis=0)
            prop[:, free] += rng.standard_normal((N, free.size)) @ Lq.T
        else:
            prop = s.copy()
            prop[:, free] += (h / c) * rng.standard_normal((N, free.size)) @ Lq.T
        if project is not None:
            prop = project(prop)
        x1, ll1 = propagate(prop)
        lt1 = anchor_logpdf(prop, m_a, P_a, free) + ll1
        log_ratio = lt1 - lt
        if independent:
            log_ratio += gauss_logpdf(s[:, free] - m_p[free], Pq) - gauss_logpdf(prop[:, free] - m_p[free], Pq)
        acc = (np.log(rng.random(N)) < log_ratio) & np.isfinite(lt1)
        s = np.where(acc[:, None], prop, s)
        x_end = np.where(acc[:, None], x1, x_end)
        loglik_window = np.where(acc, ll1, loglik_window)
        lt = np.where(acc, lt1, lt)
        n_acc += int(np.sum(acc))
    return s, x_end, loglik_window, n_acc / max(1, int(n_moves) * N)
