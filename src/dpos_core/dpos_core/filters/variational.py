"""The central-difference variational filter (CDVF; [Ye2024] sec. 3, Algorithm 2).

Prediction and covariance are the CDKF's (:func:`~.gaussian.cd_predict`, the covariance of
:func:`~.gaussian.cd_update`: "the state estimation covariance matrix update progresses in
parallel with the state update by the original CDKF", [Ye2024] sec. 3 step 3(2)).  The state
update minimizes the variational cost ([Ye2024] eq. 29-33) in the coordinates whitened by the
predicted covariance, ``x = x_pred + M z`` with ``M M^T = P_pred`` (lower Cholesky factor)::

    J(z) = 1/2 z^T z + 1/2 e(z)^T e(z),   e(z) = W (y - h(x_pred + M z)),   W R W^T = I

with the Polak-Ribiere-Polyak conjugate gradient from ``z = 0`` (the prediction; [Ye2024]
Algorithm 2 steps 7-12; Algorithm 1, Shi and Shen 2007)::

    g = grad J(z) = z + B^T e,   B = de/dz   (a (p, n) Jacobian by central differences along the
                                              columns of M, step JAC_STEP in whitened units)
    Gamma = I + B^T B            ([Ye2024] eq. 33: I + M^T H^T R^-1 H M)
    alpha = -g^T d / (d^T Gamma d),   z <- z + alpha d
    beta  = max(0, g_new^T (g_new - g) / g^T g),   d <- -g_new + beta d

The paper's measurement is linear (``H x``): ``J`` is then quadratic, ``alpha`` is the exact line
minimum and the iteration is linear CG, whose minimum is the Kalman (= CDKF) update, reached in
at most ``n`` steps.  The transfer alignment's attitude match is not linear (model.py), so here
``h`` is the model's own, the Jacobian is re-evaluated at every iterate (Gauss-Newton ``Gamma``),
the step is accepted only with a sufficient decrease of the true ``J`` (Armijo, ``c1 = 1e-4``,
halving ``alpha`` otherwise: the paper's step is the line minimum of the local quadratic, which a
nonlinear ``J`` need not honour), ``beta`` is clipped at 0 (PRP+, Gilbert and Nocedal 1992: a
restart along the steepest descent instead of a direction that need not descend) and a direction
that does not descend is replaced by ``-g``.

Stopping rule (:class:`CGSettings`): stop when ``|g| <= grad_tol`` (1e-3).  For the quadratic
(the local Gauss-Newton model) ``g = Gamma (z - z*)`` and ``Gamma >= I``, so
``(z - z*)^T Gamma (z - z*) = g^T Gamma^-1 g <= |g|^2``: the iterate is within ``grad_tol`` of the
minimizer in the Mahalanobis distance of the posterior (``Gamma`` is the posterior information in
whitened coordinates), and its cost within ``grad_tol^2 / 2`` of the minimum - a thousandth of the
estimate's own uncertainty, whatever the scale of the states.  A relative gradient rule
(``|g| / |g_0|``) would not mean that: ``g_0`` grows with the innovation.  Also stop after
``max_iter`` steps or when the line search finds no decrease (the cost is flat to rounding):
guards, not the rule: if one stops the iteration at a cost above the CDKF update's, the CDKF
update is returned (the variational update is never worse in the cost it minimizes).  The cap
defaults to ``max(4 n, 100)``: linear CG needs at most ``p + 1``
steps here (``Gamma - I`` has rank ``p``), but on the transfer alignment an update whose
prediction is hundreds of sigmas off (the turn that makes the heading observable) took up to 74
(docs/cdvf.md has the measured counts).  Every update's iterations, costs
and gradient norms are kept (:class:`CGInfo`, :class:`CGStats`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import FloatArray

from .gaussian import Update, cd_update
from .linalg import chol, solve_lower, whitener
from .points import CENTRAL_DIFFERENCE_POINTS, CentralDifferencePoints, symmetric_points

Fn = Callable[[FloatArray], FloatArray]
Residual = Callable[[FloatArray, FloatArray], FloatArray]

#: why the iteration stopped (:attr:`CGInfo.stop`)
STOP_REASONS = ("gradient", "max_iter", "line_search")


@dataclass(frozen=True)
class CGSettings:
    """The PRP iteration's stopping rule and safeguards (module docstring).

    grad_tol: stop when the whitened gradient norm ``|g|`` is at most this (the Mahalanobis
    distance to the minimizer of the local quadratic is then at most ``grad_tol``).
    max_iter: at most this many steps (None: ``max(4 n, 100)``).
    jac_step: central-difference step of the Jacobian ``B`` in whitened units (prior sigmas).
    armijo: sufficient-decrease constant ``c1``; max_halvings: step halvings before giving up.
    """

    grad_tol: float = 1e-3
    max_iter: int | None = None
    jac_step: float = 1e-5
    armijo: float = 1e-4
    max_halvings: int = 40

    def __post_init__(self) -> None:
        if not self.grad_tol > 0:
            raise ValueError(f"grad_tol must be > 0, got {self.grad_tol}")
        if self.max_iter is not None and self.max_iter < 1:
            raise ValueError(f"max_iter must be >= 1 (or None for max(4 n, 100)), got {self.max_iter}")
        if not self.jac_step > 0:
            raise ValueError(f"jac_step must be > 0, got {self.jac_step}")
        if not 0 < self.armijo < 0.5:
            raise ValueError(f"armijo must be in (0, 0.5), got {self.armijo}")
        if self.max_halvings < 1:
            raise ValueError(f"max_halvings must be >= 1, got {self.max_halvings}")


@dataclass(frozen=True)
class CGInfo:
    """One update's iteration: steps taken; the cost at the prediction (``z = 0``), at the result
    and at the CDKF's (linear minimum variance) update; the gradient norm at the start and at the
    last iterate; why it stopped (:data:`STOP_REASONS`; the result is the CDKF update when a guard
    stopped the iteration above its cost)."""

    iterations: int
    cost_prior: float
    cost: float
    cost_cdkf: float
    grad_norm0: float
    grad_norm: float
    stop: str


@dataclass(frozen=True)
class CGStats:
    """The :class:`CGInfo` of every epoch of a run as arrays (K,) (NaN / -1 / "" where no update)."""

    iterations: NDArray[np.int_]
    cost_prior: FloatArray
    cost: FloatArray
    cost_cdkf: FloatArray
    grad_norm0: FloatArray
    grad_norm: FloatArray
    stop: NDArray[np.str_]

    @classmethod
    def from_infos(cls, infos: list[CGInfo | None]) -> CGStats:
        f = lambda name: np.array([np.nan if i is None else getattr(i, name) for i in infos], dtype=float)  # noqa: E731
        return cls(np.array([-1 if i is None else i.iterations for i in infos], dtype=int), f("cost_prior"), f("cost"),
                   f("cost_cdkf"), f("grad_norm0"), f("grad_norm"), np.array(["" if i is None else i.stop for i in infos]))

    @classmethod
    def concat(cls, parts: list[CGStats]) -> CGStats:
        return cls(*(np.concatenate([getattr(p, k) for p in parts]) for k in
                     ("iterations", "cost_prior", "cost", "cost_cdkf", "grad_norm0", "grad_norm", "stop")))

    @property
    def updated(self) -> NDArray[np.bool_]:
        """The epochs (K,) that had a measurement update."""
        return self.iterations >= 0

    def summary(self) -> dict[str, float]:
        """Over the updates: their number; mean and max iterations; the fraction stopped by the
        gradient rule; the mean relative cost decrease from the prediction ``(J_0 - J) / J_0``; the
        fraction with the cost below the CDKF update's, the mean relative gain ``(J_cdkf - J) / J_cdkf``
        and the largest ``J - J_cdkf`` (<= 0: never above the CDKF's); the largest final ``|g|``.
        (:func:`pool_summaries` combines them.)"""
        u = self.updated
        if not np.any(u):
            return {"updates": 0}
        tiny = np.finfo(float).tiny
        it = self.iterations[u]
        J, J0, Jc = self.cost[u], self.cost_prior[u], self.cost_cdkf[u]
        return {"updates": int(u.sum()), "iterations_mean": float(it.mean()), "iterations_max": int(it.max()),
                "stopped_by_gradient": float(np.mean(self.stop[u] == "gradient")),
                "relative_cost_decrease_mean": float(np.mean((J0 - J) / np.maximum(J0, tiny))),
                "below_cdkf": float(np.mean(J < Jc)), "relative_gain_over_cdkf_mean": float(np.mean((Jc - J) / np.maximum(Jc, tiny))),
                "cost_minus_cdkf_max": float(np.max(J - Jc)), "grad_norm_max": float(self.grad_norm[u].max())}


#: the :meth:`CGStats.summary` entries that are maxima (the others are means over the updates)
_MAX_KEYS = ("iterations_max", "cost_minus_cdkf_max", "grad_norm_max")


def pool_summaries(items: list[dict[str, float]]) -> dict[str, float]:
    """:meth:`CGStats.summary` of several runs (or antennas) as one: means weighted by the updates, maxima of the maxima."""
    items = [s for s in items if s.get("updates")]
    n = sum(s["updates"] for s in items)
    if not n:
        return {"updates": 0}
    out: dict[str, float] = {"updates": n}
    for k in items[0]:
        if k == "updates":
            continue
        out[k] = max(s[k] for s in items) if k in _MAX_KEYS else sum(s[k] * s["updates"] for s in items) / n
    return out


def cdvf_update(
    x: FloatArray,
    P: FloatArray,
    y: FloatArray,
    h: Fn,
    R: FloatArray,
    points: CentralDifferencePoints = CENTRAL_DIFFERENCE_POINTS,
    residual: Residual | None = None,
    settings: CGSettings | None = None,
) -> tuple[Update, CGInfo]:
    """CDVF measurement update ([Ye2024] Algorithm 2 steps 7-13; module docstring) of one state.

    Args:
        x (n,), P (n, n): the prediction; y (p,); h: (..., n) -> (..., p); R (p, p).
        residual: measurement difference ``a - b`` (default subtraction).
        settings: the stopping rule and safeguards (default :class:`CGSettings`).
    Returns:
        The :class:`~.gaussian.Update` with the variational mean, the CDKF's covariance,
        innovation ``y - y_pred``, its covariance and gain; and the iteration's :class:`CGInfo`.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"cdvf_update takes one state (n,), got shape {x.shape}")
    settings = CGSettings() if settings is None else settings
    lmv = cd_update(x, P, y, h, R, points, residual)
    n = x.size
    M = chol(P)
    W, _ = whitener(np.asarray(R, dtype=float))
    res = residual or (lambda a, b: a - b)
    yv = np.asarray(y, dtype=float)
    d_jac = settings.jac_step
    max_iter = max(4 * n, 100) if settings.max_iter is None else settings.max_iter

    def white(X: FloatArray) -> FloatArray:
        """Whitened residuals e (..., p) of states X (..., n)."""
        return res(yv, h(X)) @ W.T

    def cost(z: FloatArray, e: FloatArray) -> float:
        return 0.5 * float(z @ z + e @ e)

    def at(z: FloatArray, extra: FloatArray | None = None) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """e (p,) and B = de/dz (p, n) at z (one batched call of h), and e at ``extra`` states (m, n)."""
        X = symmetric_points(x + M @ z, M, d_jac)
        E = white(X if extra is None else np.concatenate([X, extra]))
        B = (E[1:n + 1] - E[n + 1:2 * n + 1]).T / (2.0 * d_jac)
        return E[0], B, (None if extra is None else E[2 * n + 1:])

    z = np.zeros(n)
    e, B, e_lmv = at(z, lmv.x[None, :])
    assert e_lmv is not None
    z_lmv = solve_lower(M, (lmv.x - x)[:, None])[:, 0]
    J = J0 = cost(z, e)
    J_lmv = cost(z_lmv, e_lmv[0])
    g = z + B.T @ e
    g0 = gn = float(np.linalg.norm(g))
    d = -g
    it = 0
    stop = "max_iter"
    while True:
        if gn <= settings.grad_tol:
            stop = "gradient"
            break
        if it >= max_iter:
            break
        gd = float(g @ d)
        if gd >= 0.0:  # not a descent direction: restart along -g
            d, gd = -g, -float(g @ g)
        Bd = B @ d
        alpha = -gd / float(d @ d + Bd @ Bd)  # the line minimum of the local quadratic ([Ye2024] step 7)
        for _ in range(settings.max_halvings):
            z_new = z + alpha * d
            J_new = cost(z_new, white(x + M @ z_new))
            if J_new <= J + settings.armijo * alpha * gd:
                break
            alpha *= 0.5
        else:
            stop = "line_search"
            break
        z = z_new
        e, B, _ = at(z)
        J = cost(z, e)
        g_new = z + B.T @ e
        beta = max(0.0, float(g_new @ (g_new - g)) / float(g @ g))  # PRP+ ([Ye2024] step 11)
        d = -g_new + beta * d
        g = g_new
        gn = float(np.linalg.norm(g))
        it += 1
    x_new = x + M @ z
    if stop != "gradient" and J_lmv < J:  # a guard stopped it above the CDKF update's cost: keep that one
        x_new, J = lmv.x, J_lmv
    up = Update(x_new, lmv.P, lmv.nu, lmv.S, lmv.K)
    return up, CGInfo(it, J0, J, J_lmv, g0, gn, stop)
