"""A sub-IMU's mounting rotation from the data: its angular rates against the main solution's.

With the two on one clock, the main solution's body rate over each of its intervals
(:func:`dpos_core.imports.clock.attitude_rates`) and the sub-IMU's mean rate over the same
interval (:func:`dpos_core.imports.clock.interval_means`) are related by the rigid mounting
``omega_b = C_bs (omega_s - bias)`` (``C_bs``: sub-IMU axes -> master axes, the aircraft file's
``mount_dcm(mount_rpy_deg, 0)``).  Both sets are centred (removing the gyro bias) and ``C_bs``
is Wahba's solution by SVD (Markley 1988, "Attitude determination using vector observations and
the singular value decomposition", J. Astronaut. Sci. 36(3)).

Sigma: the residuals ``r_k = omega_b,k - C_bs omega_s,k`` give the noise variance; linearized
about the solution, ``r_k = -[v_k x] phi + n_k`` (``v_k = C_bs omega_s,k``, ``phi`` a small
rotation in master axes), so ``cov(phi) = sigma^2 (sum [v_k x]^T [v_k x])^-1``, inflated by the
residuals' correlation time (``1 + 2 sum rho_j`` over their positive autocorrelations: samples
are not independent), and mapped to roll/pitch/yaw by the numerical Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..attitude import rotvec_to_dcm, skew
from ..correlation import correlation_factor
from ..errors import MountingNotObservable
from ..units import DEG, FloatArray
from .clock import attitude_rates, interval_means


@dataclass(frozen=True)
class MountingEstimate:
    """Mounting rotation of a sub-IMU (aircraft file's ``mount_rpy_deg`` convention).

    Attributes:
        rpy_deg: (3,) roll, pitch, yaw [deg] (``C_bs = Rz(yaw) Ry(pitch) Rx(roll)``).
        rpy_sigma_deg: (3,) their 1 sigma [deg].
        C_bs: (3, 3) sub-IMU axes -> master axes.
        phi_cov_rad2: (3, 3) covariance of the rotation error in master axes [rad^2].
        bias_dps: (3,) the sub-IMU's mean rate minus the mapped main rate (gyro bias) [deg/s].
        residual_dps: rms of the residual per axis [deg/s]; samples: intervals used;
        corr_factor: the sigma inflation for correlated residuals (variance factor).
    """

    rpy_deg: FloatArray
    rpy_sigma_deg: FloatArray
    C_bs: FloatArray
    phi_cov_rad2: FloatArray
    bias_dps: FloatArray
    residual_dps: float
    samples: int
    corr_factor: float


def rpy_from_dcm(C: FloatArray) -> FloatArray:
    """``C = Rz(y) Ry(p) Rx(r)`` -> (roll, pitch, yaw) [rad] (inverse of :func:`dpos_core.attitude.mount_dcm`)."""
    return np.array([np.arctan2(C[2, 1], C[2, 2]), -np.arcsin(np.clip(C[2, 0], -1.0, 1.0)), np.arctan2(C[1, 0], C[0, 0])])


def wahba(v_b: FloatArray, v_s: FloatArray) -> FloatArray:
    """Rotation ``C`` (3, 3) minimizing ``sum |v_b,k - C v_s,k|^2``; v_b, v_s (K, 3). SVD solution."""
    B = v_b.T @ v_s
    U, _, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def estimate_mounting(t_main_s: FloatArray, C_nb: FloatArray, t_sub_s: FloatArray, omega_sub: FloatArray,
                      min_rate_dps: float = 1.0, name: str = "sub-IMU") -> MountingEstimate:
    """Mounting of a sub-IMU whose stamps ``t_sub_s`` (M,) share the main solution's clock
    ``t_main_s`` (N,) (module docstring). C_nb (N, 3, 3) FLU body -> ENU; omega_sub (M, 3) [rad/s].
    Raises :class:`MountingNotObservable` when the rates do not span two directions."""
    a, b, w_b = attitude_rates(t_main_s, C_nb)
    dt = float(np.median(b - a))
    keep = (b - a) < 1.5 * dt
    w_s, inside = interval_means(t_sub_s, omega_sub, a, b)
    keep &= inside
    if keep.sum() < 20:
        raise MountingNotObservable(f"{name}: {int(keep.sum())} intervals of the main solution within the log, 20 needed")
    return rotation_from_rates(w_b[keep], w_s[keep], min_rate_dps, name, "the main solution's")


def rotation_from_rates(vb: FloatArray, vs: FloatArray, min_rate_dps: float = 1.0, name: str = "sub-IMU",
                        whose: str = "the reference's") -> MountingEstimate:
    """``C_bs`` with ``vb ~ C_bs (vs - bias)`` from paired mean rates vb, vs (K, 3) [rad/s] (module
    docstring: centred Wahba/SVD, sigma from the residuals). Raises :class:`MountingNotObservable`."""
    vb_c, vs_c = vb - vb.mean(axis=0), vs - vs.mean(axis=0)
    sv = np.linalg.svd(vb_c, compute_uv=False) / np.sqrt(vb_c.shape[0])
    if sv[1] < min_rate_dps * DEG:
        raise MountingNotObservable(f"{name}: mounting not observable: {whose} rate varies about fewer than two axes "
                                    f"(rms {sv[0] / DEG:.2f}, {sv[1] / DEG:.2f}, {sv[2] / DEG:.2f} deg/s; {min_rate_dps:g} needed on two)")
    C = wahba(vb_c, vs_c)
    v = vs_c @ C.T
    r = vb_c - v
    n = r.shape[0]
    s2 = float((r * r).sum()) / max(1, 3 * n - 6)
    info = np.zeros((3, 3))
    for vk in v:
        S = skew(vk)
        info += S.T @ S
    factor = correlation_factor(r)
    cov = s2 * factor * np.linalg.inv(info)
    rpy = rpy_from_dcm(C)
    J = np.zeros((3, 3))
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        d = rpy_from_dcm(rotvec_to_dcm(e) @ C) - rpy
        J[:, j] = (d + np.pi) % (2 * np.pi) - np.pi
    J /= h
    cov_rpy = J @ cov @ J.T
    bias = vs.mean(axis=0) - C.T @ vb.mean(axis=0)
    return MountingEstimate(rpy / DEG, np.sqrt(np.diag(cov_rpy)) / DEG, C, cov, bias / DEG,
                            float(np.sqrt((r * r).mean(axis=0)).mean() / DEG), n, factor)


def relative_rotation(t_a_s: FloatArray, omega_a: FloatArray, t_b_s: FloatArray, omega_b: FloatArray, interval_s: float = 0.05,
                      min_rate_dps: float = 1.0, name: str = "sub-IMU pair") -> MountingEstimate:
    """Rotation ``C_ab`` (axes of IMU b -> axes of IMU a) of two IMUs on one rigid body and one clock,
    from their own rates: both averaged over common intervals of ``interval_s`` (their full rate
    carries the airframe's vibration, far more rotation to match than a 10 Hz solution's), then
    :func:`rotation_from_rates`. t_a_s (N,), omega_a (N, 3), t_b_s (M,), omega_b (M, 3) [s, rad/s]."""
    lo, hi = max(t_a_s[0], t_b_s[0]), min(t_a_s[-1], t_b_s[-1])
    edges = np.arange(lo, hi, interval_s)
    if edges.size < 21:
        raise MountingNotObservable(f"{name}: the logs overlap by {max(0.0, hi - lo):.2f} s, {20 * interval_s:g} s needed")
    wa, ia = interval_means(t_a_s, omega_a, edges[:-1], edges[1:])
    wb, ib = interval_means(t_b_s, omega_b, edges[:-1], edges[1:])
    keep = ia & ib
    return rotation_from_rates(wa[keep], wb[keep], min_rate_dps, name, "the pair's")


__all__ = ["MountingEstimate", "MountingNotObservable", "estimate_mounting", "relative_rotation", "rotation_from_rates", "rpy_from_dcm", "wahba"]
