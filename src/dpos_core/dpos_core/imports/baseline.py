"""The lever arm between two IMUs on one rigid body from their specific-force differences.

Rates do not see a lever arm; specific forces do.  For two IMUs a and b on a rigid body, with
``r`` the position of b relative to a in a's axes, ``omega`` the body rate and ``alpha`` its rate
of change (both in a's axes, rad/s, rad/s^2) and ``C_ab`` the rotation of b's axes to a's
(:func:`dpos_core.imports.mounting.relative_rotation`), the rigid-body kinematics give
(e.g. Titterton and Weston 2004, "Strapdown Inertial Navigation Technology", eq. 10.10)::

    C_ab f_b - f_a = ([alpha x] + [omega x][omega x]) r + d        (1)

``d`` the accelerometers' bias difference (in a's axes, constant over the log).  Both logs are
averaged over common intervals of ``interval_s`` (:func:`dpos_core.imports.clock.interval_means`:
the airframe's vibration averaged out), ``omega`` is the mean of the two IMUs' rates, ``alpha``
the central difference of the interval means over two intervals (a difference smoothed over
``2 interval_s``).  (1) stacked over the K intervals is linear in the 6 unknowns ``(r, d)`` and
solved by generalized least squares (below).

The band: (1) holds for a rigid body; two IMUs strapped to an airframe are rigid with each other
at the manoeuvres' frequencies, not at the vibration's (their mounts flex, their sensors' filters
differ).  The default ``interval_s`` of 0.1 s (the triangle smoothing of 0.2 s: about 5 Hz and
below) keeps (1) to the band where it holds; on quad_mimu a 0.025 s interval moves the estimates
by up to 5 cm, far beyond their sigmas, while 0.075-0.2 s agree (docs/real.md, "Baselines").

Observability: ``r`` is seen only where the body turns or accelerates angularly; with ``d``
estimated, the centred design matrix's smallest singular value (rms over the intervals, 1/s^2)
must reach ``min_excitation``, else :class:`MountingNotObservable` (no guess).  The smoothing
lowers the rms of ``alpha``: the same motion reads about a third less at 0.1 s than at 0.05 s
(quad_mimu's path 1: 1.85 against 2.66 1/s^2, its weakest path 4: 0.38 against 0.59), hence the
default of 0.3 (0.5 at 0.05 s before); a body that does not turn reads its gyro noise, about 0.02.

Sigma: the residuals' noise is not the same on the three axes, nor independent between them (on
a multirotor the vibration along the thrust axis is several times that across it, and the two
horizontal axes' residuals are correlated, -0.4 to -0.8 on quad_mimu); one variance pooled over
the axes understates the sigma of the arm's horizontal components and overstates the vertical
one.  So the residuals' 3 x 3 covariance ``S`` (``K - 2`` degrees of freedom per axis) weighs
(1), ``r = (sum A_k^T S^-1 A_k)^-1 sum A_k^T S^-1 d_k`` (``A_k`` the centred design of interval
k), iterated from ``S = I`` three times (Aitken's generalized least squares with the covariance
estimated: feasible GLS), with ``cov(r) = (sum A_k^T S^-1 A_k)^-1`` inflated by ``1 + 2 sum
rho_j`` of the whitened residuals' positive autocorrelations (K / that = the effective sample
count), as for the mountings (:mod:`dpos_core.imports.mounting`).  The rotation ``C_ab`` is an
estimate too: given its covariance (errors in variables), its error ``phi`` (a small rotation in
a's axes) enters (1) as ``-[C_ab f_b x] phi`` and adds ``J P J^T`` to ``cov(r)``, ``J`` the
solution's sensitivity to ``phi``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from ..attitude import skew
from ..correlation import correlation_factor
from ..errors import MountingNotObservable
from ..series import ImuSeries
from ..units import FloatArray
from .clock import interval_means, running_integral


@dataclass(frozen=True)
class LeverArmEstimate:
    """Position of IMU b relative to IMU a, in a's axes.

    Attributes:
        r_m: (3,) lever arm [m].
        r_sigma_m: (3,) its 1 sigma [m] (residuals' covariance, inflated for their correlation, plus
            the rotation's covariance when given).
        cov_m2: (3, 3) covariance of ``r_m`` [m^2].
        bias_diff_mps2: (3,) accelerometer bias difference ``d`` of (1) [m/s^2] and
        bias_diff_sigma_mps2: (3,) its 1 sigma.
        residual_mps2: rms of the residuals per axis, mean over the axes [m/s^2].
        residual_cov_mps4: (3, 3) the residuals' covariance ``S`` that weighs (1) [(m/s^2)^2].
        excitation: the centred design's singular values (3,), rms [1/s^2] (observability).
        samples: intervals used; corr_factor: the variance inflation for correlated residuals.
    """

    r_m: FloatArray
    r_sigma_m: FloatArray
    cov_m2: FloatArray
    bias_diff_mps2: FloatArray
    bias_diff_sigma_mps2: FloatArray
    residual_mps2: float
    excitation: FloatArray
    samples: int
    corr_factor: float
    residual_cov_mps4: FloatArray


def _triangle_means(t_s: FloatArray, x: FloatArray, edges: FloatArray, h: float) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Means of ``x`` (N, C) at stamps ``t_s`` (N,) under the triangle of half-width ``2 h`` centred
    on each interval ``[edges[k], edges[k + 1]]`` of length ``2 h`` (a box of ``2 h`` smoothed by a
    box of ``2 h``): the second running integral at the four points ``edges +- h``, divided by
    ``(2 h)^2``.  Returns (K - 1, C) and the mask of the intervals inside the series."""
    th1 = running_integral(t_s, x)
    dt = np.diff(t_s)[:, None]
    th2 = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(0.5 * (th1[1:] + th1[:-1]) * dt, axis=0)])

    def at(p: FloatArray) -> FloatArray:
        return np.column_stack([np.interp(p, t_s, th2[:, j]) for j in range(x.shape[1])])

    up, lo = at(edges + h), at(edges - h)
    box = up - lo  # (the running integral's box of 2h at each edge, times 2h)
    out = (box[1:] - box[:-1]) / (2 * h) ** 2
    inside = (edges[:-1] - h >= t_s[0]) & (edges[1:] + h <= t_s[-1])
    return out, inside


def _whiten(L: FloatArray, M: FloatArray) -> FloatArray:
    """``L^-1 M_k`` for each of the K matrices (K, 3, m) or vectors (K, 3), ``L`` (3, 3) lower triangular."""
    return solve_triangular(L, np.moveaxis(M, 0, 1).reshape(3, -1), lower=True).reshape((3, M.shape[0], *M.shape[2:])).swapaxes(0, 1)


def _gls(Kc: FloatArray, dc: FloatArray, S: FloatArray) -> tuple[FloatArray, tuple[FloatArray, bool], FloatArray, FloatArray]:
    """(1) by generalized least squares with the residuals' covariance ``S`` (3, 3): ``Kc`` (K, 3, 3)
    and ``dc`` (K, 3) whitened by the Cholesky factor ``L`` of ``S``.  Returns ``L``, the Cholesky
    factor of the information ``sum K_k^T S^-1 K_k`` (:func:`scipy.linalg.cho_factor`), ``r`` (3,)
    and the residuals (K, 3) (not whitened)."""
    L = np.asarray(np.linalg.cholesky(S), dtype=np.float64)
    Kw, dw = _whiten(L, Kc), _whiten(L, dc)
    info_f = cho_factor(np.einsum("kji,kjm->im", Kw, Kw))
    r = cho_solve(info_f, np.einsum("kji,kj->i", Kw, dw))
    return L, info_f, r, dc - np.einsum("kij,j->ki", Kc, r)


def lever_arm_from_specific_force(a: ImuSeries, b: ImuSeries, C_ab: FloatArray, interval_s: float = 0.1,
                                  min_excitation: float = 0.3, name: str = "IMU pair",
                                  C_ab_cov_rad2: FloatArray | None = None) -> LeverArmEstimate:
    """Lever arm of IMU b from IMU a by (1) (module docstring).  Both logs on one clock, each in its
    own axes: ``a`` (N samples), ``b`` (M samples); C_ab (3, 3) b's axes -> a's, ``C_ab_cov_rad2``
    (3, 3) its covariance as a small rotation in a's axes (``MountingEstimate.phi_cov_rad2`` of
    :func:`dpos_core.imports.mounting.relative_rotation`), None = exact.
    ``min_excitation`` [1/s^2]: the smallest rms singular value of the centred design for ``r`` to
    count as observable.  Raises :class:`MountingNotObservable`."""
    t_a_s, f_a, omega_a = a.t_s, a.f_mps2, a.omega_radps
    t_b_s, f_b, omega_b = b.t_s, b.f_mps2, b.omega_radps
    lo, hi = max(t_a_s[0], t_b_s[0]), min(t_a_s[-1], t_b_s[-1])
    h = 0.5 * interval_s
    edges = np.arange(lo + h, hi - h + 1e-9, interval_s)
    if edges.size < 21:
        raise MountingNotObservable(f"{name}: the logs overlap by {max(0.0, hi - lo):.2f} s, {20 * interval_s + 2 * h:g} s needed")
    # b's samples in a's axes: specific force, rate, and [omega x]^2 (9) per sample
    xa = np.hstack([f_a, omega_a, (skew(omega_a) @ skew(omega_a)).reshape(-1, 9)])
    wb = omega_b @ C_ab.T
    xb = np.hstack([f_b @ C_ab.T, wb, (skew(wb) @ skew(wb)).reshape(-1, 9)])
    ta, ia = _triangle_means(t_a_s, xa, edges, h)
    tb, ib = _triangle_means(t_b_s, xb, edges, h)
    ma, _ = interval_means(t_a_s, omega_a, edges - h, edges + h)
    mb, _ = interval_means(t_b_s, wb, edges - h, edges + h)
    m = 0.5 * (ma + mb)  # the rate's box means centred at the edges
    alpha = np.diff(m, axis=0) / interval_s  # the triangle mean of alpha over each interval (exact)
    keep = ia & ib
    if keep.sum() < 20:
        raise MountingNotObservable(f"{name}: {int(keep.sum())} common intervals, 20 needed")
    d = tb[keep, 0:3] - ta[keep, 0:3]  # (K, 3)
    W2 = 0.5 * (ta[keep, 6:15] + tb[keep, 6:15]).reshape(-1, 3, 3)
    K = np.asarray(skew(alpha[keep]) + W2, dtype=np.float64)  # (K, 3, 3)
    n = d.shape[0]
    # centred design: r against the bias difference (the means of (1) over the intervals)
    Kc = K - K.mean(axis=0)
    dc = d - d.mean(axis=0)
    exc = np.linalg.svd(Kc.reshape(3 * n, 3), compute_uv=False) / np.sqrt(n)
    if exc[-1] < min_excitation:
        raise MountingNotObservable(f"{name}: lever arm not observable: the angular motion excites (1) by rms {exc[0]:.3g}, "
                                    f"{exc[1]:.3g}, {exc[2]:.3g} 1/s^2 ({min_excitation:g} needed on all three)")
    S = np.eye(3)
    for _ in range(3):  # feasible GLS: the residuals' covariance weighs (1)
        _, _, _, res = _gls(Kc, dc, S)
        S = res.T @ res / max(1, n - 2)
    L, info_f, r, res = _gls(Kc, dc, S)
    factor = correlation_factor(solve_triangular(L, res.T, lower=True).T)  # whitened residuals
    cov = factor * cho_solve(info_f, np.eye(3))
    if C_ab_cov_rad2 is not None:  # errors in variables: the rotation's error through -[g x] phi
        G = -np.asarray(skew(tb[keep, 0:3]), dtype=np.float64)
        J = cho_solve(info_f, np.einsum("kji,kjm->im", _whiten(L, Kc), _whiten(L, G - G.mean(axis=0))))
        cov = cov + J @ np.asarray(C_ab_cov_rad2, dtype=np.float64) @ J.T
    Km = K.mean(axis=0)
    bias = d.mean(axis=0) - Km @ r
    # the bias difference's variance: the mean's noise plus what r's error does to it
    cov_d = S * factor / n + Km @ cov @ Km.T
    return LeverArmEstimate(r, np.sqrt(np.diag(cov)), cov, bias, np.sqrt(np.diag(cov_d)),
                            float(np.sqrt((res * res).mean(axis=0)).mean()), exc, n, factor, S)


__all__ = ["LeverArmEstimate", "lever_arm_from_specific_force"]
