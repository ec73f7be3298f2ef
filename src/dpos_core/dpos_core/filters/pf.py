"""Sampling-importance-resampling particle filters over a :class:`~.model.StateSpaceModel`:
the bootstrap PF, the regularized PF and [Yan2016]'s modified PF (regularization + local
resampling + Metropolis-Hastings), all vectorized over the particles.

* ``pf`` - the classical (bootstrap) PF ([Yan2016] sec. "Classical Particle Filter"; Gordon,
  Salmond, Smith 1993): particles drawn from the transition ``x_k ~ N(f(x_{k-1}), Q)``, weights
  times the likelihood ``N(y_k; h(x_k), R)`` (eq. 6), resampling (a scheme of
  :data:`~.particle.RESAMPLING`) when the effective sample size falls below a threshold.
* ``rpf`` - the regularized PF ([Yan2016] eq. 7-9; Musso, Oudjane, Le Gland 2001, the
  post-regularized form): after resampling every particle moves by ``h A eps``, ``eps ~ N(0, I)``,
  a draw from the Gaussian kernel ``K_h`` scaled by a square root ``A`` of the particles'
  weighted covariance (``S = A A^T``), bandwidth ``h_opt = (4 / (N (n + 2)))^(1 / (n + 4))``
  (eq. 9, optimal for a Gaussian density), ``h_opt / 2`` for multimodal densities.
* ``mcmc_rpf`` - [Yan2016]'s modified PF with its MH moves acting on the particles'
  *trajectories* over a window, as the paper describes them, in the form that tracks on an INS
  error model (:mod:`.trajectory_move`): every ``window`` epochs the particles are
  resampled and each trajectory's window start ``x_{k0}`` - with the constant biases, moved as
  static parameters - is moved by Metropolis-Hastings (resample-move, Gilks and Berzuini 2001),
  the window regenerated from it with the particle's own noise draws and judged by the window's
  measurements and a Gaussian of the cloud at ``k0``.  The proposals are shaped by the observable
  subspace: the window start conditioned on the window's measurements by a linearized Kalman
  update, used as an independence proposal, alternating with [Yan2016]'s regularization kernel
  as a random walk.  Between the window ends it is the bootstrap PF; at a window end the moved
  cloud's moments are reported.
* ``mcmc_rpf_literal`` - [Yan2016]'s modified PF (sec. "Metropolis-Hastings rules") read
  literally, kept for comparison: local resampling -
  after resampling, only the *children* (every copy of a parent beyond its first) are
  regenerated, the parents stay - and the regularized move of each child is accepted by the
  Metropolis-Hastings rule (eq. 10-13; Gilks and Berzuini 2001 resample-move) with the target
  ``p(x_k | x_{k-1}, y_k) ~ p(y_k | x_k) p(x_k | x_{k-1})`` of the particle's own trajectory: the
  Gaussian kernel is symmetric, so the proposal ratio cancels (eq. 13) and
  ``beta = p(y_k | x*) p(x* | x_{k-1}) / (p(y_k | x) p(x | x_{k-1}))``.  The move leaves the
  particles' posterior invariant (unlike the RPF's jitter, which widens it), but on a model whose
  transition noise is the IMU's it rejects almost every move (docs/sar.md): the window is the
  last step only (the parent ``x_{k-1}`` fixed, ``x_k`` moved).

Models with a constrained state (a unit quaternion) may define ``project(x)`` (applied after every
draw and move) and ``free`` (the indices the transition density is evaluated on, so that a state
that is a function of the others - a quaternion's scalar part - does not make ``Q`` singular), and
``loglik(k, z)``: ``log p(y_k | z)`` (M,) of states z (M, n) in one pass, equal to
``gauss_logpdf(residual(y_k, h(k, z)), R(k))`` (the weights' hot path; a compiled model has one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import FloatArray

from .linalg import gauss_logpdf, symmetrize
from .model import StateSpaceModel
from .particle import RESAMPLING, ess, log_normalize, resample_indices
from .trajectory_move import window_mh_move, window_posterior

#: the particle filters of :func:`run_sir`, in [Yan2016]'s order (classical, regularized, modified)
PF_METHODS = ("pf", "rpf", "mcmc_rpf", "mcmc_rpf_literal")
#: the windowed MCMC-RPF's defaults: window length [epochs] and MH steps per window end
MCMC_WINDOW, MCMC_MOVES = 10, 2


def bandwidth_opt(n_particles: int, n_states: int) -> float:
    """The optimal bandwidth of a Gaussian kernel for a Gaussian density ([Yan2016] eq. 9; Musso
    et al. 2001 eq. 12.9): ``h_opt = (4 / (N (n + 2)))^(1 / (n + 4))``."""
    if n_particles < 1 or n_states < 1:
        raise ValueError(f"bandwidth_opt needs N >= 1 and n >= 1, got N={n_particles}, n={n_states}")
    return float((4.0 / (n_particles * (n_states + 2.0))) ** (1.0 / (n_states + 4.0)))


def psd_sqrt(S: FloatArray) -> FloatArray:
    """A square root ``A`` (..., n, n) with ``A A^T = S`` of symmetric positive semi-definite
    matrices (..., n, n) (eigen-decomposition, negative rounding eigenvalues clipped to 0): the
    kernel's scale for a particle cloud whose covariance may be singular (identical copies, a
    state that is a function of the others)."""
    lam, V = np.linalg.eigh(symmetrize(np.asarray(S, dtype=float)))
    return V * np.sqrt(np.clip(lam, 0.0, None))[..., None, :]


def weighted_cov(x: FloatArray, logw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (n,) and covariance (n, n) of particles x (N, n) with normalized log
    weights (N,)."""
    w = np.exp(logw)
    m = w @ x
    d = x - m
    return m, symmetrize((d * w[:, None]).T @ d)


def n_distinct_rows(x: FloatArray) -> int:
    """The number of distinct rows of x (N, n), rows compared as bytes (one sort of N
    fixed-size keys: 5x faster than ``np.unique(x, axis=0)``, which compares column by
    column); the same count for particles, where a row differing from another only by the sign
    of a zero or a NaN's payload does not occur."""
    a = np.ascontiguousarray(x, dtype=float)
    return int(np.unique(a.view(np.dtype((np.void, a.shape[1] * a.itemsize)))).size)


def regularize(x: FloatArray, A: FloatArray, h: float, rng: np.random.Generator) -> FloatArray:
    """The regularization move ([Yan2016] eq. 7-8): ``x + h A eps``, ``eps ~ N(0, I)`` per particle
    (x (N, n), A (n, n) the kernel's square root, h the bandwidth)."""
    return x + h * rng.standard_normal(x.shape) @ A.T


def children_mask(idx: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Local resampling ([Yan2016] sec. "Metropolis-Hastings rules"): for resampled indices (N,),
    True at every copy of a parent beyond its first (the children to regenerate), False at the
    first copy (the parent, kept unchanged)."""
    order = np.argsort(idx, kind="stable")
    s = idx[order]
    first = np.ones(s.size, dtype=bool)
    first[1:] = s[1:] != s[:-1]
    out = np.empty(s.size, dtype=bool)
    out[order] = ~first
    return out


def mh_move(
    x: FloatArray,
    log_target,
    A: FloatArray,
    h: float,
    rng: np.random.Generator,
    lt_x: FloatArray | None = None,
    project=None,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """One Metropolis-Hastings step per particle with the symmetric Gaussian kernel proposal
    ``x* = x + h A eps`` ([Yan2016] eq. 10-13): accepted with probability
    ``min(1, pi(x*) / pi(x))``.

    Args:
        x: particles (N, n).
        log_target: ``log pi`` up to a constant, vectorized (M, n) -> (M,).
        A, h: the kernel's square root (n, n) and bandwidth.
        lt_x: ``log_target(x)`` if already known (N,).
        project: optional map applied to the proposals (a constraint; must commute with the
            kernel's symmetry to keep the move exact, as the normalization of a quaternion to
            first order does).

    Returns:
        The moved particles (N, n), their log targets (N,) and the accepted mask (N,).
    """
    lt0 = log_target(x) if lt_x is None else lt_x
    prop = regularize(x, A, h, rng)
    if project is not None:
        prop = project(prop)
    lt1 = log_target(prop)
    acc = np.log(rng.random(x.shape[0])) < lt1 - lt0
    acc &= np.isfinite(lt1)
    return np.where(acc[:, None], prop, x), np.where(acc, lt1, lt0), acc


def _loglik(model: StateSpaceModel, k: int, z: FloatArray) -> FloatArray:
    """``log p(y_k | z)`` (M,) of states z (M, n); zeros where epoch k has no measurement; the
    model's own ``loglik(k, z)`` where it has one (module docstring)."""
    y = model.y(k)
    if y is None:
        return np.zeros(z.shape[0])
    own = getattr(model, "loglik", None)
    if own is not None:
        return own(k, z)
    return gauss_logpdf(model.residual(y, model.h(k, z)), model.R(k))


def _window_propagator(model: StateSpaceModel, k0: int, k: int, W: FloatArray, project):
    """``propagate(s) -> (x_k, sum_{j=k0+1..k} log p(y_j | x_j))`` (from j = 0 when k0 = 0, whose anchor
    is the prior) for window starts s (N, n): the
    window regenerated with the particles' own noise draws W (>= k - k0, N, n), the same
    arithmetic as the filter's forward step (:mod:`.trajectory_move`)."""

    def propagate(s: FloatArray) -> tuple[FloatArray, FloatArray]:
        z = s
        ll = _loglik(model, 0, s) if k0 == 0 else np.zeros(s.shape[0])  # the first window: the prior is the anchor
        for j in range(k0, k):
            z = model.f(j, z) + W[j - k0]
            if project is not None:
                z = project(z)
            ll = ll + _loglik(model, j + 1, z)
        return z, ll

    return propagate


def _window_residuals(model: StateSpaceModel, k0: int, k: int, project):
    """``residuals(s) -> (r (M, m), R (m, m))``: the stacked residuals ``y_j - h_j(x_j)`` over the
    window's measured epochs (j = k0 + 1..k, from 0 when k0 = 0) of the noise-free trajectories
    from starts s (M, n), and their block-diagonal covariance (:func:`.trajectory_move.window_posterior`)."""

    def residuals(s: FloatArray) -> tuple[FloatArray, FloatArray]:
        z, rs, Rs = s, [], []
        for j in range(k0, k + 1):
            if j > k0:
                z = model.f(j - 1, z)
                if project is not None:
                    z = project(z)
            if j == k0 and k0 != 0:
                continue
            y = model.y(j)
            if y is not None:
                rs.append(model.residual(y, model.h(j, z)))
                Rs.append(model.R(j))
        m = sum(R.shape[0] for R in Rs)
        Rb = np.zeros((m, m))
        i = 0
        for R in Rs:
            Rb[i:i + R.shape[0], i:i + R.shape[0]] = R
            i += R.shape[0]
        return (np.hstack(rs) if rs else np.zeros((s.shape[0], 0))), Rb

    return residuals


@dataclass
class SirTrack:
    """Forward pass of a particle filter of :func:`run_sir`, K epochs, n states.

    mean (K, n), cov (K, n, n): the weighted particle moments after each epoch's update (before
    resampling); ess (K,): effective sample size after the update; resampled (K,) bool;
    accept (K,): the fraction of the Metropolis-Hastings moves accepted (NaN where none was
    tried); distinct (K,): the number of distinct particles carried to the next epoch (the
    distinct parents kept by resampling; N where none happened, or where the regularization
    moved every copy) - the sample impoverishment the ESS does not show (N identical particles
    have ESS N); particles (K, N, n) only when asked (``keep_particles``), else None.
    """

    mean: FloatArray
    cov: FloatArray
    ess: FloatArray
    resampled: NDArray[np.bool_]
    accept: FloatArray
    distinct: FloatArray
    particles: FloatArray | None = None


def run_sir(
    model: StateSpaceModel,
    x0: FloatArray,
    P0: FloatArray,
    n_particles: int = 1000,
    rng: np.random.Generator | None = None,
    method: str = "pf",
    ess_threshold: float = 0.5,
    resample: str = RESAMPLING[0],
    bandwidth_scale: float = 1.0,
    keep_particles: bool = False,
    window: int = MCMC_WINDOW,
    n_moves: int = MCMC_MOVES,
) -> SirTrack:
    """Run the particle filter ``method`` (one of :data:`PF_METHODS`, module docstring).

    Args:
        model: the state-space model (f, h vectorized over particles); optional ``project`` and
            ``free`` (module docstring).
        x0, P0: the prior N(x0, P0) the particles are drawn from (n,), (n, n).
        n_particles: N >= 2.
        ess_threshold: resample when ESS < ess_threshold N (1.0: every epoch, the classical SIR).
        resample: the resampling scheme (:data:`~.particle.RESAMPLING`).
        bandwidth_scale: the kernel's bandwidth is ``bandwidth_scale h_opt``; 1 for a unimodal
            density, 0.5 for a multimodal one ([Yan2016] after eq. 9).
        keep_particles: also return every epoch's particles (K, N, n) (memory: K N n doubles).
        window, n_moves: ``mcmc_rpf``'s window length in epochs (>= 1) and Metropolis-Hastings
            steps per window end (>= 1).
    """
    if method not in PF_METHODS:
        raise ValueError(f"unknown particle filter {method!r}; choose one of {PF_METHODS}")
    if resample not in RESAMPLING:
        raise ValueError(f"unknown resampling scheme {resample!r}; choose one of {RESAMPLING}")
    N = int(n_particles)
    if N < 2:
        raise ValueError(f"n_particles must be >= 2, got {n_particles}")
    if not (np.isfinite(bandwidth_scale) and bandwidth_scale > 0):
        raise ValueError(f"bandwidth_scale must be > 0, got {bandwidth_scale}")
    if int(window) < 1 or int(n_moves) < 1:
        raise ValueError(f"window and n_moves must be >= 1, got {window}, {n_moves}")
    if not 0.0 < ess_threshold <= 1.0:
        raise ValueError(f"ess_threshold must be in (0, 1], got {ess_threshold}")
    x0 = np.asarray(x0, dtype=float)
    P0 = np.asarray(P0, dtype=float)
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))):
        raise ValueError("run_sir: x0 and P0 must be finite")
    rng = np.random.default_rng() if rng is None else rng
    K, n = model.n_epochs, model.n
    project = getattr(model, "project", None)
    free = np.asarray(getattr(model, "free", np.arange(n)))
    h_bw = bandwidth_scale * bandwidth_opt(N, n)

    mean, cov = np.empty((K, n)), np.empty((K, n, n))
    ess_k, accept, distinct = np.empty(K), np.full(K, np.nan), np.full(K, float(N))
    res_k = np.zeros(K, dtype=bool)
    kept = np.empty((K, N, n)) if keep_particles else None

    x = x0 + rng.standard_normal((N, n)) @ psd_sqrt(P0).T
    if project is not None:
        x = project(x)
    fx = np.broadcast_to(x0, (N, n)).copy()  # each particle's transition mean (the prior's at k = 0)
    Qk = P0
    logw = np.full(N, -np.log(N))
    traj = method == "mcmc_rpf"
    L = int(window)
    # mcmc_rpf: each particle's window start (N, n), its noise draws over the window (L, N, n),
    # the window's summed log-likelihood (N,); the window-start epoch's Gaussian (the anchor)
    s, W, ll_win, k0 = x.copy(), np.zeros((L, N, n)), np.zeros(N), 0
    anchor: tuple[FloatArray, FloatArray] = (x0, P0)
    # the transition noise's square roots, one batched eigen-decomposition (K - 1, n, n)
    sqQ = psd_sqrt(np.stack([model.Q(j) for j in range(K - 1)])) if K > 1 else np.empty((0, n, n))
    for k in range(K):
        if k > 0:
            fx = model.f(k - 1, x)
            Qk = model.Q(k - 1)
            e = rng.standard_normal((N, n)) @ sqQ[k - 1].T
            x = fx + e
            if project is not None:
                x = project(x)
            if traj:
                W[k - 1 - k0] = e
        y = model.y(k)
        loglik = np.zeros(N)
        if y is not None:
            loglik = _loglik(model, k, x)
            logw = log_normalize(logw + loglik)
            if traj and (k > k0 or k == 0):  # the first window's anchor is the prior: y_0 is in it
                ll_win = ll_win + loglik
        mean[k], cov[k] = weighted_cov(x, logw)
        ess_k[k] = ess(logw)
        if kept is not None:
            kept[k] = x
        window_end = traj and k - k0 == L
        if k + 1 == K or (ess_k[k] >= ess_threshold * N and not window_end):
            continue
        A = psd_sqrt(cov[k])
        idx = resample_indices(logw, rng, resample)
        x, fx, loglik = x[idx], fx[idx], loglik[idx]
        if traj:
            s, W, ll_win = s[idx], W[:, idx], ll_win[idx]
        logw = np.full(N, -np.log(N))
        res_k[k] = True
        distinct[k] = float(np.count_nonzero(np.bincount(idx, minlength=N)))  # the distinct parents
        if method == "rpf":
            x = regularize(x, A, h_bw, rng)
            if project is not None:
                x = project(x)
            distinct[k] = float(N) if np.any(A) else distinct[k]
        elif traj and window_end:
            post = window_posterior(anchor, _window_residuals(model, k0, k, project), free, project)
            s, x, ll_win, accept[k] = window_mh_move(
                s, x, ll_win, _window_propagator(model, k0, k, W, project), anchor, post, h_bw, rng, free,
                n_moves=n_moves, project=project)
            distinct[k] = float(n_distinct_rows(x))
            anchor = weighted_cov(x, logw)
            mean[k], cov[k] = anchor  # the window end reports the moved cloud
            s, W, ll_win, k0 = x.copy(), np.zeros((L, N, n)), np.zeros(N), k
        elif method == "mcmc_rpf_literal":
            child = children_mask(idx)
            if not child.any():
                continue
            Qf = Qk[np.ix_(free, free)]
            fxc = fx[child]

            def log_target(z: FloatArray, fxc: FloatArray = fxc, Qf: FloatArray = Qf, y=y, k: int = k) -> FloatArray:
                lt = gauss_logpdf(z[:, free] - fxc[:, free], Qf)
                if y is not None:
                    lt = lt + _loglik(model, k, z)
                return lt

            moved, _, acc = mh_move(x[child], log_target, A, h_bw, rng, project=project)
            x[child] = moved
            accept[k] = float(np.mean(acc))
            distinct[k] += float(np.sum(acc))
    return SirTrack(mean, cov, ess_k, res_k, accept, distinct, kept)
