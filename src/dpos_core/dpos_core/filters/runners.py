"""Forward filters and backward smoothers over a :class:`~.model.StateSpaceModel`.

* :func:`run_sigma_point_filter` -> :class:`GaussianTrack`: a Gaussian filter with closed-loop
  feedback, its predict / update pair a rule: :class:`UnscentedRule` (the UKF, the default),
  :class:`CentralDifferenceRule` (the CDKF, [Ye2024] sec. 2.2), :class:`VariationalRule` (the CDVF,
  [Ye2024] Algorithm 2: the CDKF with the conjugate-gradient state update, :mod:`.variational`);
  :func:`smooth_gaussian` is the one RTS recursion behind URTSS, RTS and the CDKF's / CDVF's
  RTS-type smoothers (the cross-covariance of each rule's prediction).
* :func:`run_upf` -> :class:`ParticleTrack`: the unscented particle filter ([Gong2018] eq. 2-8;
  van der Merwe et al. 2000), Rao-Blackwellized: every particle carries a UKF over the whole
  state and its posterior is the particle's proposal; importance weights in logs; SIR
  resampling (a scheme of :data:`~.particle.RESAMPLING`, systematic by default) when the
  effective sample size drops below a threshold.  All particles and their
  sigma points are processed in one vectorized call.
* :func:`ffbsm` ([Gong2018] eq. 9): forward-filtering backward-smoothing reweighting,
  ``w_{k|K}^i = w_k^i sum_j w_{k+1|K}^j p(x_{k+1}^j|x_k^i) / sum_m w_k^m p(x_{k+1}^j|x_k^m)``;
  :func:`rb_smooth` (the UPS) adds, along the same backward kernel, an RTS step for the states
  each particle carries as a Gaussian.

The UPS here is [Gong2018]'s in the Rao-Blackwellized form (Chen and Liu 2000; Schon, Gustafsson
and Nordlund 2005): the particles sample only ``model.sampled`` (in the transfer-alignment model
the flexure rate, the one state driven by a noise of consequence), and each particle's UKF carries
every other state as a Gaussian conditioned on the particle's sampled path; the weights are the
UKFs' predictive likelihoods, eq. 9 reweights the sampled components, and the carried states are
smoothed by the RTS recursion on the moments of the particles' mixture.  Sampling all 24 states,
as the paper writes it, collapses on this model (the transition density is a point mass in the
noise-free directions: ESS 1.0 at every epoch).  Two engines run the particles' UKFs:
:class:`PerParticleUKF` ([Gong2018] as written) and :class:`SharedLinearizationUKF` (the
default, one shared unscented transform per step, ~2.8x faster).  docs/ups.md has the design,
the variants tried and the measurements.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import FloatArray

from . import _condition_kernel as _ck
from . import _particle_kernel as _pk
from .gaussian import Prediction, Update, _ut_moments, cd_predict, cd_update, rts_smooth, ut_predict, ut_update
from .linalg import chol, chol_unrepaired, gain, gauss_logpdf, solve_lower, symmetrize
from .model import StateSpaceModel
from .particle import RESAMPLING, ess, log_normalize, resample_indices
from .pf import children_mask
from .points import CentralDifferencePoints, UnscentedPoints
from .store import EpochStore, PerEpoch
from .variational import CGInfo, CGSettings, CGStats, cdvf_update

# ------------------------------------------------------------------------------------ Gaussian


@dataclass
class GaussianTrack:
    """Forward pass of a Gaussian filter.

    x_f (K, n), P_f (K, n, n): filtered, after the feedback shift; x_p, P_p, C (K-1, ...):
    predictions (shifted like the filtered state of their epoch) and cross-covariances; corrections (K, n) applied (zeros when none);
    nu (K, p) innovations and S (K, p, p) their covariances (NaN where no measurement).  Each is a
    numpy array, or an :class:`~.store.EpochArray` file when the runner was given an on-disk
    :class:`~.store.EpochStore` (then read a block of epochs at a time).
    """

    x_f: PerEpoch
    P_f: PerEpoch
    x_p: PerEpoch
    P_p: PerEpoch
    C: PerEpoch
    corrections: PerEpoch
    nu: PerEpoch
    S: PerEpoch
    #: the variational rule's conjugate-gradient record per epoch (None for the other rules)
    cg: CGStats | None = None


@dataclass(frozen=True)
class UnscentedRule:
    """The UKF's time and measurement updates ([Gong2018] eq. 2-5) with a point set."""

    points: UnscentedPoints | CentralDifferencePoints = UnscentedPoints()

    def predict(self, x: FloatArray, P: FloatArray, f, Q: FloatArray) -> Prediction:
        return ut_predict(x, P, f, Q, self.points)

    def update(self, x: FloatArray, P: FloatArray, y: FloatArray, h, R: FloatArray, residual) -> tuple[Update, CGInfo | None]:
        return ut_update(x, P, y, h, R, self.points, residual), None


@dataclass(frozen=True)
class CentralDifferenceRule:
    """The CDKF's time and measurement updates ([Ye2024] eq. 14-28; :func:`~.gaussian.cd_predict`)."""

    points: CentralDifferencePoints = CentralDifferencePoints()

    def predict(self, x: FloatArray, P: FloatArray, f, Q: FloatArray) -> Prediction:
        return cd_predict(x, P, f, Q, self.points)

    def update(self, x: FloatArray, P: FloatArray, y: FloatArray, h, R: FloatArray, residual) -> tuple[Update, CGInfo | None]:
        return cd_update(x, P, y, h, R, self.points, residual), None


@dataclass(frozen=True)
class VariationalRule(CentralDifferenceRule):
    """The CDVF ([Ye2024] Algorithm 2): the CDKF's prediction and covariance, the state update by
    the PRP conjugate gradient on the variational cost (:func:`~.variational.cdvf_update`)."""

    settings: CGSettings = CGSettings()

    def update(self, x: FloatArray, P: FloatArray, y: FloatArray, h, R: FloatArray, residual) -> tuple[Update, CGInfo | None]:
        return cdvf_update(x, P, y, h, R, self.points, residual, self.settings)


GaussianRule = UnscentedRule | CentralDifferenceRule | VariationalRule


class _Innovations:
    """A forward pass's innovations ``nu`` (K, p) and their covariances ``S`` (K, p, p) in ``store``,
    NaN at the epochs without a measurement; p is the first measurement's size (0 without any)."""

    def __init__(self, store: EpochStore, n_epochs: int) -> None:
        self.store, self.K = store, n_epochs
        self.nu: PerEpoch | None = None
        self.S: PerEpoch | None = None

    def put(self, k: int, nu: FloatArray | None, S: FloatArray | None) -> None:
        """Epoch k's innovation (p,) and covariance (p, p), or None (none measured)."""
        if nu is None or S is None:
            return
        if self.nu is None:
            p = nu.shape[0]
            self.nu = self.store.array("nu", self.K, (p,), fill=np.nan)
            self.S = self.store.array("S", self.K, (p, p), fill=np.nan)
        assert self.S is not None
        self.nu[k], self.S[k] = nu, S

    def arrays(self) -> tuple[PerEpoch, PerEpoch]:
        if self.nu is None or self.S is None:
            return np.zeros((self.K, 0)), np.zeros((self.K, 0, 0))
        return self.nu, self.S


def run_sigma_point_filter(model: StateSpaceModel, x0: FloatArray, P0: FloatArray, points=UnscentedPoints(),
                           rule: GaussianRule | None = None, store: EpochStore | None = None) -> GaussianTrack:
    """The forward pass of a Gaussian filter over ``model`` from the prior ``x0`` (n,), ``P0``
    (n, n): ``rule``'s predict and update at every epoch (default the UKF with ``points``), then the
    model's feedback and shift.  ``store``: where the per-epoch arrays go (default in memory; the
    same numbers either way)."""
    rule = UnscentedRule(points) if rule is None else rule
    st = EpochStore() if store is None else store
    K, n = model.n_epochs, model.n
    x, P = np.asarray(x0, dtype=float).copy(), np.asarray(P0, dtype=float).copy()
    x_f, P_f = st.array("x_f", K, (n,)), st.array("P_f", K, (n, n))
    x_p, P_p, C = st.array("x_p", K - 1, (n,)), st.array("P_p", K - 1, (n, n)), st.array("C", K - 1, (n, n))
    corr = st.array("corrections", K, (n,), fill=0.0)
    inn = _Innovations(st, K)
    infos: list[CGInfo | None] = []
    xp_k = np.zeros(n)  # x_{k|k-1}, stored once shifted by epoch k's correction
    for k in range(K):
        if k > 0:
            pr = rule.predict(x, P, lambda X: model.f(k - 1, X), model.Q(k - 1))
            xp_k = pr.x
            P_p[k - 1], C[k - 1] = pr.P, pr.C
            x, P = pr.x, pr.P
        y = model.y(k)
        info: CGInfo | None = None
        if y is not None:
            up, info = rule.update(x, P, y, lambda X: model.h(k, X), model.R(k), model.residual)
            x, P = up.x, up.P
            inn.put(k, up.nu, up.S)
        if isinstance(rule, VariationalRule):
            infos.append(info)
        c = model.feedback(k, x)
        if c is not None:
            corr[k] = c
            x = model.shift(k, x, c)
            if k > 0:  # keep x_{k|k-1} in the same (corrected) coordinates as x_{k|k} for the smoother
                xp_k = model.shift(k, xp_k, c)
        if k > 0:
            x_p[k - 1] = xp_k
        x_f[k], P_f[k] = x, P
    cg = CGStats.from_infos(infos) if isinstance(rule, VariationalRule) else None
    return GaussianTrack(x_f, P_f, x_p, P_p, C, corr, *inn.arrays(), cg)


def smooth_gaussian(track: GaussianTrack, store: EpochStore | None = None) -> tuple[PerEpoch, PerEpoch]:
    """URTSS (or RTS for a linear filter): smoothed ``x_{k|K}`` (K, n) and ``P_{k|K}`` (K, n, n),
    in the coordinates of the filtered states (after each epoch's feedback); in ``store`` (default
    in memory), the track read and the result written a block of epochs at a time
    (:func:`~.gaussian.rts_smooth`)."""
    return rts_smooth(track.x_f, track.P_f, track.x_p, track.P_p, track.C, store=store)


# ------------------------------------------------------------------------------------ particles


@dataclass
class ParticleTrack:
    """Forward pass of the (Rao-Blackwellized) UPF, K epochs, N particles, n states.

    particles (K, N, n): each particle's state after the epoch's sampling and feedback shift
    (sampled components exact, the others the particle's conditional mean); logw (K, N): normalized log
    weights before resampling; proposed (K, N, n): the particles before the shift (the coordinates
    of the transition that produced them); pred_mean (K - 1, N, s), pred_cov (K - 1, N, s, s): each
    particle's predicted density of the sampled components at the next epoch (the transition
    density of the backward pass); sampled (s,) indices; corrections (K, n); ess (K,); resampled
    (K,) bool; mixture: the moments of the weighted mixture
    of the particles' Gaussians - filtered, predicted (in the corrected coordinates of the
    next epoch) and their cross-covariances - as a :class:`GaussianTrack` for the RTS recursion,
    with the mixture's innovations: ``nu = sum_i w_i nu^i`` (the measurement minus the weighted mean
    of the particles' predictions, weights before the update) and
    ``S = sum_i w_i (S^i + (nu^i - nu)(nu^i - nu)^T)``, the predictive covariance of the mixture
    (moment matched; NaN where no measurement).  ``run_upf(full_track=False)`` keeps of the particles
    only what FFBSm reads: particles and proposed None, proposed_sampled (K, N, s) the proposed
    particles' sampled components.
    """

    particles: PerEpoch | None
    proposed: PerEpoch | None
    logw: PerEpoch
    pred_mean: PerEpoch
    pred_cov: PerEpoch
    sampled: NDArray[np.intp]
    corrections: PerEpoch
    ess: FloatArray
    resampled: NDArray[np.bool_]
    mixture: GaussianTrack
    #: where the per-epoch arrays are (``run_upf(store=...)``)
    store: EpochStore | None = None
    #: (K, N, s): the proposed particles' sampled components (``run_upf(full_track=False)``), else None
    proposed_sampled: PerEpoch | None = None

    @property
    def mean(self) -> PerEpoch:
        """Weighted filtered means (K, n) (the mixture's)."""
        return self.mixture.x_f

    def close(self) -> None:
        """Remove the files of the per-epoch arrays kept on disk (``run_upf(store=...)``; the
        smoother's results in the same store too)."""
        if self.store is not None:  # (every array of the track is the store's)
            self.store.close()


def sampled_indices(model: StateSpaceModel, n: int, sampled=None) -> NDArray[np.intp]:
    """The sampled state components: ``sampled`` if given, else ``model.sampled`` if the model
    has it, else all n."""
    sel = sampled if sampled is not None else getattr(model, "sampled", None)
    idx = np.arange(n)[sel] if sel is not None else np.arange(n)
    if idx.size == 0:
        raise ValueError("at least one state component must be sampled")
    return idx


def _sampled_block(P: FloatArray, S: NDArray[np.intp]) -> FloatArray:
    """``P[..., S, S]`` (..., s, s) of covariances P (..., n, n): a view when S is contiguous."""
    Si = _index_of(tuple(S.tolist()))
    return P[..., Si, Si] if isinstance(Si, slice) else P[..., S[:, None], S[None, :]]


def _condition(m: FloatArray, P: FloatArray, S: NDArray[np.intp], xs: FloatArray,
               L_SS: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Condition Gaussians N(m_i, P) (m (N, n); P (N, n, n) or one shared (n, n)) on their
    components S taking the values xs (N, s): conditional means and covariances (exact).
    ``L_SS``: the Cholesky factor of ``P[..., S, S]`` when the caller has it (:func:`~.linalg.chol`)."""
    shared = P.ndim == 2
    Pb = P[None] if shared else P
    if L_SS is not None:  # G = P_xS P_SS^-1 by the factor's two solves, m + G (xs - m_S), sym(P - G P_xS^T), S zeroed (numba kernel)
        m_c, P_c = np.empty(m.shape), np.empty(Pb.shape)
        _ck.condition(np.ascontiguousarray(m, dtype=float), np.ascontiguousarray(Pb, dtype=float), np.ascontiguousarray(S, dtype=np.intp),
                      np.ascontiguousarray(L_SS[None] if shared else L_SS, dtype=float), np.ascontiguousarray(xs, dtype=float), m_c, P_c)
        return m_c, (P_c[0] if shared else P_c)
    Si = _index_of(tuple(S.tolist()))
    P_xS = Pb[:, :, Si]  # (., n, s)
    G = gain(P_xS, _sampled_block(Pb, S))  # P_xS P_SS^-1
    d = xs - m[:, Si]
    m_c = m + (np.einsum("ij,nj->ni", G[0], d) if shared else np.einsum("nij,nj->ni", G, d))
    P_c = symmetrize(Pb - G @ np.swapaxes(P_xS, -1, -2))
    P_c[:, S, :] = 0.0
    P_c[:, :, S] = 0.0
    return m_c, (P_c[0] if shared else P_c)


def _mixture(w: FloatArray, m: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean (n,) and covariance (n, n) of the mixture sum_i w_i N(m_i, P_i), w (N,), m (N, n),
    P (N, n, n) or one shared (n, n)."""
    mean = w @ m
    d = m - mean
    Pw = P if P.ndim == 2 else np.einsum("n,nij->ij", w, P)
    return mean, symmetrize(Pw + (d * w[:, None]).T @ d)


class PerParticleUKF:
    """Each particle's own unscented transforms (covariances (N, n, n)): [Gong2018] as written."""

    def init(self, P0: FloatArray, N: int) -> FloatArray:
        return np.broadcast_to(P0, (N,) + P0.shape).copy()

    def update(self, model: StateSpaceModel, k: int, m, P, w, y, points):
        up = ut_update(m, P, y, lambda X: model.h(k, X), model.R(k), points, model.residual)
        return up.x, up.P, up.nu, up.S

    def predict(self, model: StateSpaceModel, k: int, m, P, w, S, points):
        return _predict_given_sampled(m, P, S, lambda X: model.f(k, X), model.Q(k), points)

    def take(self, P: FloatArray, idx: NDArray[np.intp]) -> FloatArray:
        return P[idx]


class SharedLinearizationUKF:
    """One unscented transform per step, at the weighted mean of the particles, shared by every
    particle's filter: one covariance (n, n), gain and innovation covariance for all, each
    particle's own mean through the model at its mean plus the transform's second-order term
    (``y_hat^i = h(m^i) + (E_UT[h] - h(m_bar))``, likewise for f).  Exact when the particles'
    means differ only along directions in which the model is linear (a linear-Gaussian model;
    the flexure rate the TA model samples enters f and h linearly), and N times cheaper in
    sigma-point evaluations than :class:`PerParticleUKF`."""

    def init(self, P0: FloatArray, N: int) -> FloatArray:
        return np.array(P0, dtype=float)

    def update(self, model: StateSpaceModel, k: int, m, P, w, y, points):
        m_bar = w @ m
        h_m, h = _with_means(lambda X: model.h(k, X), m, m_bar)
        up = ut_update(m_bar, P, y, h, model.R(k), points, model.residual)
        Zm = h_m()  # h(m^i) (N, p) and h(m_bar) (1, p), from the sigma points' call
        nu = up.nu[None, :] - model.residual(Zm[:-1], Zm[-1:])
        return m + nu @ up.K.T, up.P, nu, up.S

    def predict(self, model: StateSpaceModel, k: int, m, P, w, S, points):
        m_bar = w @ m
        f_m, f = _with_means(lambda X: model.f(k, X), m, m_bar)
        x_bar, Pp, C = _predict_given_sampled(m_bar[None], P[None], S, f, model.Q(k), points)
        Ym = f_m()  # f(m^i) (N, n) and f(m_bar) (1, n)
        return x_bar + Ym[:-1] - Ym[-1:], Pp[0], C[0]

    def take(self, P: FloatArray, idx: NDArray[np.intp]) -> FloatArray:
        return P


def _with_means(fn: Callable[[FloatArray], FloatArray], m: FloatArray,
                m_bar: FloatArray) -> tuple[Callable[[], FloatArray], Callable[[FloatArray], FloatArray]]:
    """``fn`` (a model's f or h at one epoch, rows (..., n) -> (..., q)) wrapped to evaluate, in the
    same call as the points it is given, the particles' means m (N, n) and their mean m_bar (n,)
    too (one model call instead of three: a row's value does not depend on the others').
    Returns ``(at_means, wrapped)``: ``at_means()`` gives ``fn`` of ``[m; m_bar]`` (N + 1, q) after
    ``wrapped`` has been called once."""
    n = m.shape[-1]
    means = np.concatenate([m, m_bar[None]])
    out: list[FloatArray] = []

    def wrapped(X: FloatArray) -> FloatArray:
        rows = X.reshape(-1, n)
        Y = fn(np.concatenate([rows, means]))
        out.append(Y[rows.shape[0]:])
        return Y[: rows.shape[0]].reshape(X.shape[:-1] + Y.shape[-1:])

    def at_means() -> FloatArray:
        return out[-1] if out else fn(means)

    return at_means, wrapped


def _index(idx: NDArray[np.intp]) -> slice | NDArray[np.intp]:
    """A slice for contiguous indices (cheaper views than fancy indexing), else the indices."""
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


@lru_cache(maxsize=64)
def _index_of(idx: tuple[int, ...]) -> slice | NDArray[np.intp]:
    """:func:`_index` of the indices idx, computed once per idx (read-only)."""
    a = np.asarray(idx, dtype=np.intp)
    a.flags.writeable = False
    return _index(a)


@lru_cache(maxsize=64)
def _carried(n: int, S: tuple[int, ...]) -> tuple[NDArray[np.intp], slice | NDArray[np.intp]]:
    """The components (r,) of n that are not in S and their :func:`_index` (computed once per (n, S))."""
    keep = np.ones(n, dtype=bool)
    keep[list(S)] = False
    rest_idx = np.flatnonzero(keep)
    rest_idx.flags.writeable = False
    return rest_idx, _index(rest_idx)


def _predict_given_sampled(m: FloatArray, P: FloatArray, S: NDArray[np.intp], f, Q: FloatArray, points) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unscented time update (eq. 4) of Gaussians N(m, P) (N, n), (N, n, n) whose components S
    are known exactly (zero rows/columns of P): sigma points span only the other components.
    Returns the predicted means (N, n), covariances and cross-covariances Cov(x_k, x_k+1) (N, n, n)."""
    N, n = m.shape
    rest_idx, r = _carried(n, tuple(S.tolist()))
    if rest_idx.size == 0:
        return f(m), np.broadcast_to(Q, (N, n, n)).copy(), np.zeros((N, n, n))
    wm, wc = points.weights(rest_idx.size)
    P_rr = P[:, r, :][:, :, r] if isinstance(r, np.ndarray) else P[:, r, r]
    Xr = points.points(m[:, r], P_rr)  # (N, 2r + 1, r)
    X = np.repeat(m[:, None, :], Xr.shape[1], axis=1)
    X[:, :, r] = Xr
    Y = f(X)
    xp = wm @ Y
    dY = Y - xp[:, None, :]
    Pp, C_r = _ut_moments(Xr - m[:, None, r], dY, wc, Q)
    C = np.zeros((N, n, n))
    C[:, r, :] = C_r
    return xp, Pp, C


def run_upf(
    model: StateSpaceModel,
    x0: FloatArray,
    P0: FloatArray,
    n_particles: int = 100,
    rng: np.random.Generator | None = None,
    points=UnscentedPoints(),
    ess_threshold: float = 0.5,
    sampled=None,
    engine: PerParticleUKF | SharedLinearizationUKF | None = None,
    resample: str = RESAMPLING[0],
    move: bool = False,
    store: Path | EpochStore | None = None,
    full_track: bool = True,
) -> ParticleTrack:
    """Rao-Blackwellized unscented particle filter (module docstring).

    Every particle carries a UKF over the whole state (eq. 2-5).  At each epoch its UKF makes
    the proposal (eq. 6): the sampled components are drawn from the UKF posterior, the particle's
    Gaussian is conditioned on them, and the weight is multiplied by the particle's predictive
    likelihood ``N(y_k; y_hat^i, S^i)`` (eq. 7-8 with this proposal: ``p(y|x) p(x|x_prev) / q``
    integrates to it).  SIR resampling when ESS < ``ess_threshold`` N.

    Args:
        x0, P0: prior mean (n,) and covariance (n, n) of every particle's UKF ([Gong2018] step 1).
        sampled: indices or slice of the sampled components; default ``model.sampled`` or all.
        engine: :class:`SharedLinearizationUKF` (default) or :class:`PerParticleUKF`.
        resample: the resampling scheme, one of :data:`~.particle.RESAMPLING` (default systematic).
        move: resample-move (Gilks and Berzuini 2001; [Yan2016]'s local resampling): after each
            resampling every child (a copy of a parent beyond its first, :func:`~.pf.children_mask`)
            redraws its sampled components of the epoch from the parent's UKF posterior and is
            conditioned and predicted again.  That posterior is the components' exact conditional
            target given the particle's path, so the Metropolis-Hastings move with it as proposal
            is accepted with probability 1 (a Gibbs move): the copies stop sharing the epoch's
            draw.  Off by default (docs/sar.md: on paper_su it moves the errors by 3 % at most).
        store: where the per-epoch arrays of the track go (particles, proposed, predicted
            densities, weights, the mixture's moments and innovations): an
            :class:`~.store.EpochStore` or a directory for one (:class:`~.store.EpochArray` files,
            removed by :meth:`ParticleTrack.close`); default in memory.  The same numbers either way.
        full_track: keep every particle's state (``particles``, ``proposed``: 2 N n numbers an
            epoch); False keeps only the proposed particles' sampled components FFBSm reads
            (``proposed_sampled``, N s: a third of the bytes of the UPS's track on the
            transfer-alignment model), the smoother's numbers unchanged.
    """
    rng = np.random.default_rng() if rng is None else rng
    engine = SharedLinearizationUKF() if engine is None else engine
    K, n, N = model.n_epochs, model.n, int(n_particles)
    if N < 1:
        raise ValueError(f"n_particles must be >= 1, got {n_particles}")
    if resample not in RESAMPLING:
        raise ValueError(f"unknown resampling scheme {resample!r}; choose one of {RESAMPLING}")
    S = sampled_indices(model, n, sampled)
    s = S.size
    Si = _index_of(tuple(S.tolist()))  # a slice when contiguous (views)
    st = store if isinstance(store, EpochStore) else EpochStore(None if store is None else Path(store))
    K1 = max(K - 1, 0)
    parts = st.array("particles", K, (N, n)) if full_track else None
    proposed = st.array("proposed", K, (N, n)) if full_track else None
    proposed_s = None if full_track else st.array("proposed_sampled", K, (N, s))
    logws = st.array("logw", K, (N,))
    pred_mean = st.array("pred_mean", K1, (N, s))
    pred_cov = st.array("pred_cov", K1, (N, s, s))
    mix_x_f, mix_P_f = st.array("x_f", K, (n,)), st.array("P_f", K, (n, n))
    mix_x_p, mix_P_p, mix_C = st.array("x_p", K1, (n,)), st.array("P_p", K1, (n, n)), st.array("C", K1, (n, n))
    corr = st.array("corrections", K, (n,), fill=0.0)
    ess_k = np.empty(K)
    res_k = np.zeros(K, dtype=bool)

    m = np.broadcast_to(np.asarray(x0, dtype=float), (N, n)).copy()  # each particle's UKF (predicted)
    P = engine.init(np.asarray(P0, dtype=float), N)
    logw = np.full(N, -np.log(N))
    inn = _Innovations(st, K)  # the mixture's innovations and their covariances
    xp_k = np.zeros(n)  # the mixture's prediction of epoch k, stored once shifted by its correction
    for k in range(K):
        y = model.y(k)
        if y is not None:
            w_pred = np.exp(logw)
            m, P, nu, S_y = engine.update(model, k, m, P, w_pred, y, points)
            inn.put(k, *_mixture(w_pred, nu, S_y))
            logw = log_normalize(logw + gauss_logpdf(nu, S_y))
        # sample the components S from each particle's UKF posterior (eq. 6), condition the rest
        L_SS = chol(_sampled_block(P, S))
        z = rng.standard_normal((N, s))
        xs = m[:, Si] + (z @ L_SS.T if L_SS.ndim == 2 else np.einsum("nij,nj->ni", L_SS, z))
        m_u, P_u = m, P  # the UKF posterior before the draw (the resample-move's target)
        m, P = _condition(m, P, S, xs, L_SS)
        if proposed is not None:
            proposed[k] = m
        if proposed_s is not None:
            proposed_s[k] = m[:, Si]
        w = np.exp(logw)
        mean = w @ m
        c = model.feedback(k, mean)
        if c is not None:
            corr[k] = c
            m = model.shift(k, m, c)  # exact for P: the shifted components are linear or sampled
            if k > 0:  # the mixture's prediction of k in the corrected coordinates of k (for the smoother)
                xp_k = model.shift(k, xp_k, c)
        if k > 0:
            mix_x_p[k - 1] = xp_k
        if parts is not None:
            parts[k] = m
        logws[k] = logw
        ess_k[k] = ess(logw)
        # moments of the mixture (the carried Gaussians and the spread of their means)
        xf_k, Pf_k = _mixture(w, m, P)
        mix_x_f[k], mix_P_f[k] = xf_k, Pf_k
        if k + 1 == K:
            break
        m_k = m
        m, P, C = engine.predict(model, k, m, P, w, S, points)
        pred_mean[k] = m[:, Si]
        pred_cov[k] = _sampled_block(P, S)
        xp_k, Pp_k = _mixture(w, m, P)
        mix_P_p[k] = Pp_k
        dm, dp = m_k - xf_k, m - xp_k
        mix_C[k] = (C if C.ndim == 2 else np.einsum("n,nij->ij", w, C)) + (dm * w[:, None]).T @ dp
        if ess_k[k] < ess_threshold * N:
            idx = resample_indices(logw, rng, resample)
            m, P = m[idx], engine.take(P, idx)
            logw = np.full(N, -np.log(N))
            res_k[k] = True
            if move:
                m, P = _resample_move(model, k, engine, points, S, idx, m_u, P_u, m, P, c, rng)
    mixture = GaussianTrack(mix_x_f, mix_P_f, mix_x_p, mix_P_p, mix_C, corr, *inn.arrays())
    return ParticleTrack(parts, proposed, logws, pred_mean, pred_cov, S, corr, ess_k, res_k, mixture, st, proposed_s)


def _resample_move(model: StateSpaceModel, k: int, engine, points, S: NDArray[np.intp], idx: NDArray[np.intp], m_u: FloatArray,
                   P_u: FloatArray, m: FloatArray, P: FloatArray, c: FloatArray | None,
                   rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """The move of ``run_upf(move=True)``: the children of the resampled indices idx (N,) redraw
    their sampled components from their parent's UKF posterior (m_u (N, n), P_u) at epoch k,
    are conditioned, shifted by the epoch's correction c and predicted; returns the predicted
    means (N, n) and covariances with the children's rows replaced (a shared covariance stays:
    it does not depend on the sampled values in the models it is exact for)."""
    child = children_mask(idx)
    if not child.any():
        return m, P
    mu, Pu = m_u[idx], engine.take(P_u, idx)
    L = chol(Pu[..., S[:, None], S[None, :]])
    z = rng.standard_normal((idx.size, S.size))
    xs = mu[:, S] + (z @ L.T if L.ndim == 2 else np.einsum("nij,nj->ni", L, z))
    mc, Pc = _condition(mu, Pu, S, xs)
    if c is not None:
        mc = model.shift(k, mc, c)
    mp, Pp, _ = engine.predict(model, k, mc, Pc, np.full(idx.size, 1.0 / idx.size), S, points)
    m = np.where(child[:, None], mp, m)
    if P.ndim == 3:
        P = np.where(child[:, None, None], Pp, P)
    return m, P


#: epochs of the particle track read and factorized at once by :func:`ffbsm`
FFBSM_BLOCK = 256


def ffbsm(track: ParticleTrack) -> PerEpoch:
    """Backward reweighting ([Gong2018] eq. 9) of the sampled components: smoothed normalized log
    weights (K, N) of ``track.particles`` (in the track's store: :func:`run_upf`).  ``w_{K-1|K} =
    w_{K-1}``; the transition density ``p(x_{k+1}^j | x_{0:k}^i)`` is particle i's predicted
    Gaussian of the sampled components (the carried states marginalized).  :func:`rb_smooth` also
    smooths the carried states."""
    K, N = track.logw.shape
    S = track.sampled
    logws = (EpochStore() if track.store is None else track.store).array("logw_s", K, (N,))
    lw_next = np.array(track.logw[K - 1])  # logw_{k+1|K}
    logws[K - 1] = lw_next
    # a block of epochs' factors at once when none needs a repair (else epoch by epoch, repaired as chol does);
    # blocks of FFBSM_BLOCK epochs, read from disk when the track is there (run_upf(store=...))
    for b1 in range(K - 1, 0, -FFBSM_BLOCK):
        b0 = max(0, b1 - FFBSM_BLOCK)
        pred_cov, pred_mean = track.pred_cov[b0:b1], track.pred_mean[b0:b1]
        lw_blk, lws_blk = track.logw[b0:b1], np.empty((b1 - b0, N))
        L_blk = chol_unrepaired(pred_cov)
        W_blk = solve_lower(L_blk, np.eye(S.size)) if L_blk is not None else None
        for k in range(b1 - 1, b0 - 1, -1):
            lwk = lw_blk[k - b0]
            # x_{k+1}^j (N, s) in the transition's coordinates
            nxt = track.proposed_sampled[k + 1] if track.proposed_sampled is not None else _proposed(track)[k + 1][:, S]
            if L_blk is not None and W_blk is not None:
                Li, Wi = L_blk[k - b0], W_blk[k - b0]
            else:
                Li = chol(pred_cov[k - b0])  # (N, s, s)
                Wi = solve_lower(Li, np.eye(S.size))  # L_i^-1
            half_logdet = np.sum(np.log(np.diagonal(Li, axis1=1, axis2=2)), axis=1)
            # L[i, j] = log p(x_{k+1}^j | i) + const = -|W_i (x_{k+1}^j - mean_i)|^2 / 2 - log det L_i;
            # logw_{k|K}^i = logw_k^i + lse_j(logw_{k+1|K}^j + L[i, j] - lse_m(logw_k^m + L[m, j]))  (numba kernel)
            lw = np.empty(N)
            _pk.backward_step(np.ascontiguousarray(lwk), np.ascontiguousarray(lw_next), np.ascontiguousarray(nxt),
                              np.ascontiguousarray(pred_mean[k - b0]), np.ascontiguousarray(Wi), half_logdet, lw)
            lws_blk[k - b0] = lw_next = log_normalize(lw)
        logws[b0:b1] = lws_blk
    return logws


def _proposed(track: ParticleTrack) -> PerEpoch:
    if track.proposed is None:
        raise ValueError("the track keeps neither the proposed particles nor their sampled components")
    return track.proposed


def rb_smooth(track: ParticleTrack) -> tuple[PerEpoch, PerEpoch, PerEpoch]:
    """The unscented particle smoother (module docstring).  Returns the FFBSm log weights (K, N)
    (eq. 9) and the smoothed mean (K, n) and covariance (K, n, n): the FFBSm moments when every
    component is sampled, else the RTS recursion on the moments of the particles' mixture.  In the
    track's store (:func:`run_upf`; the smoothed moments read and written a block of epochs at a time
    when it is on disk)."""
    lw = ffbsm(track)
    x: PerEpoch
    P: PerEpoch
    if track.sampled.size == track.mixture.x_f.shape[1]:
        if track.particles is None:
            raise ValueError("the smoother of a particle filter sampling every component needs run_upf(full_track=True)")
        x, P = weighted_moments(np.asarray(track.particles), np.asarray(lw))
    else:
        x, P = smooth_gaussian(track.mixture, track.store)
    return lw, x, P


def weighted_moments(particles: FloatArray, logw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (K, n) and covariance (K, n, n) of particle sets (K, N, n)."""
    w = np.exp(logw)
    m = np.einsum("kn,kni->ki", w, particles)
    d = particles - m[:, None, :]
    return m, symmetrize(np.einsum("kn,kni,knj->kij", w, d, d))
