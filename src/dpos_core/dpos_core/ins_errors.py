"""Navigation-error propagation over a filter interval, shared by the error-state models
(transfer alignment, [Gong2018] eq. 11; in-flight alignment, [Fang2012] eq. 24).

Errors are computed - true: attitude ``phi`` as a rotation vector (``C_est = expm(-[phi x]) C_true``,
exact for any angle), velocity ``dv`` and position ``dp`` in local ENU [m/s, m], gyro bias ``eps``
and accelerometer bias ``nabla`` in body axes::

    phi_dot = J_r(phi)^-1 ((I - E^T) w_in + E^T dw_in - C_est eps),       E = expm([phi x])
    dv_dot  = (I - E) f^n + E C_est nabla - (2 w_ie + w_en) x dv - (2 dw_ie + dw_en) x v + dg
    dp_dot  = dv

One step over the interval holds the errors at their start value and uses the interval integrals
of the nominal (``int f^n dt``, ``int C_est dt``) and its mid-interval rates; the position by the
trapezoid rule.  :class:`IntervalIntegrals` accumulates the integrals from the strapdown's output.

Process noise (:func:`nav_process_noise`): the gyro and accelerometer white noise integrated over
the interval (angle and velocity random walk) and, for the position, the velocity random walk
integrated once more.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dpos_core.units import FloatArray

from . import _error_kernel, earth
from .attitude import skew
from .series import NavSeries
from .strapdown import NavState


@dataclass(frozen=True)
class Interval:
    """Nominal over one filter interval: length T, ``F_n = int f^n dt`` (3,), ``C_int = int C_est dt``
    (3, 3), mid-interval Earth and transport rates (3,), velocity (3,), latitude, height, gravity."""

    T: float
    F_n: FloatArray
    C_int: FloatArray
    w_ie: FloatArray
    w_en: FloatArray
    v: FloatArray
    lat: float
    h: float
    g: float

    @property
    def w_in(self) -> FloatArray:
        return self.w_ie + self.w_en

    @cached_property
    def kernel_consts(self) -> FloatArray:
        """``[T, R_M + h, R_N + h, sin lat, cos lat, 2 g / (R_M + h)]`` (6,): the scalars of
        :func:`propagate_nav_errors` (computed once per interval)."""
        r_m, r_n = (float(r) for r in earth.radii_of_curvature(self.lat))
        return np.array([self.T, r_m + self.h, r_n + self.h, np.sin(self.lat), np.cos(self.lat), 2.0 * self.g / (r_m + self.h)])


class IntervalIntegrals:
    """Accumulates :class:`Interval` from the strapdown chunks integrated since ``start``."""

    def __init__(self, start: NavState) -> None:
        self.start = start
        self._last: NavSeries | None = None  # the last chunk added (its last epoch is the end)
        self.T = 0.0
        self.F_n = np.zeros(3)
        self.C_int = np.zeros((3, 3))

    def add(self, prev: NavState, chunk: NavSeries, f_b_mps2: FloatArray, dt_s: FloatArray) -> None:
        """A chunk integrated from ``prev`` with specific forces f_b (m, 3) over steps dt (m,)."""
        # sum_k C_mid_k f_k dt_k and sum_k C_mid_k dt_k, C_mid_k the mean of the DCMs at the step's
        # ends (the midpoint rule; numba kernel)
        dt = np.ascontiguousarray(dt_s, dtype=float).reshape(-1)
        F_n, C_int = np.empty(3), np.empty((3, 3))
        _error_kernel.interval_sums(np.ascontiguousarray(prev.q_nb, dtype=float), np.ascontiguousarray(chunk.q_nb, dtype=float),
                                    np.ascontiguousarray(f_b_mps2, dtype=float), dt, F_n, C_int)
        self.F_n = self.F_n + F_n
        self.C_int = self.C_int + C_int
        self.T += float(np.sum(dt))
        self._last = chunk

    @property
    def end(self) -> NavState | None:
        """The nominal at the end of the chunks added (None before the first)."""
        return None if self._last is None else self._last.state(-1)

    def close(self) -> Interval | None:
        """The interval's constants (None when no time passed)."""
        if self._last is None or self.T <= 0.0:
            return None
        a, b_vel, b_llh = self.start, self._last.vel_n_mps[-1], self._last.llh[-1]
        v = 0.5 * (a.vel_n_mps + b_vel)
        lat = 0.5 * (a.llh[0] + b_llh[0])
        h = 0.5 * (a.llh[2] + b_llh[2])
        return Interval(self.T, self.F_n.copy(), self.C_int.copy(), earth.earth_rate_n(lat), earth.transport_rate_n(lat, h, v),
                        v, float(lat), float(h), float(earth.normal_gravity(lat, h)))


def right_jacobian_inv(phi: FloatArray) -> FloatArray:
    """``J_r(phi)^-1 = I + 1/2 [phi x] + (1/a^2 - (1 + cos a) / (2 a sin a)) [phi x]^2`` (..., 3, 3)."""
    a2 = np.sum(phi * phi, axis=-1)[..., None, None]
    a = np.sqrt(a2)
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    c = np.where(small, 1.0 / 12.0 + a2 / 720.0, 1.0 / safe**2 - (1.0 + np.cos(safe)) / (2.0 * safe * np.sin(safe)))
    K = skew(phi)
    return np.eye(3) + 0.5 * K + c * (K @ K)


def propagate_nav_errors(
    phi: FloatArray, dv: FloatArray, dp: FloatArray, eps: FloatArray, nabla: FloatArray, it: Interval,
    gyro_extra: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One interval of the error dynamics (module docstring); every input (..., 3), vectorized.
    ``gyro_extra`` (..., 3): a further integrated gyro error in ENU, ``int C_est delta_omega dt``
    over the interval, beside the bias's ``C_int eps`` (the gyro axis errors of dpos_core.ifa.model)."""
    ins = (phi, dv, dp, eps, nabla) if gyro_extra is None else (phi, dv, dp, eps, nabla, gyro_extra)
    arrs = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in ins))
    shape = arrs[0].shape
    rows = [np.ascontiguousarray(a).reshape(-1, 3) for a in arrs]
    if gyro_extra is None:
        rows.append(np.zeros_like(rows[0]))
    out = np.empty((3,) + rows[0].shape)
    _error_kernel.nav_errors(*rows, it.kernel_consts, it.F_n, it.C_int, it.w_ie, it.w_en, it.v, out[0], out[1], out[2])
    phi_new, dv_new, dp_new = (o.reshape(shape) for o in out)
    return phi_new, dv_new, dp_new


def nav_process_noise(T_s: float, imu_dt_s: float, gyro_noise_radps: float, accel_noise_mps2: float) -> FloatArray:
    """Process-noise covariance (9, 9) of ``(phi, dv, dp)`` over an interval of ``T_s`` [s].

    Args:
        T_s: interval length [s].
        imu_dt_s: IMU sample interval [s]; the noise sigmas are those of one sample.
        gyro_noise_radps: 1 sigma [rad/s] of the white noise on one angular-rate sample.
        accel_noise_mps2: 1 sigma [m/s^2] of the white noise on one specific-force sample.

    Returns:
        With ``q_g = sigma_g^2 dt T`` [rad^2] and ``q_a = sigma_a^2 dt T`` [m^2/s^2] (white noise of
        spectral density ``sigma^2 dt`` integrated over T): ``phi`` block ``q_g I``, ``dv`` block
        ``q_a I``, ``dp`` block ``q_a T^2/3 I`` [m^2] and ``dv``-``dp`` cross block
        ``q_a T/2 I`` [m^2/s]; attitude uncorrelated with the others.  Rows/columns 0:3 phi
        (local ENU [rad]), 3:6 dv (local ENU [m/s]), 6:9 dp (local ENU [m]).
    """
    qg = gyro_noise_radps**2 * imu_dt_s * T_s
    qa = accel_noise_mps2**2 * imu_dt_s * T_s
    Q = np.zeros((9, 9))
    Q[0:3, 0:3] = np.eye(3) * qg
    Q[3:6, 3:6] = np.eye(3) * qa
    Q[6:9, 6:9] = np.eye(3) * qa * T_s * T_s / 3.0
    Q[3:6, 6:9] = Q[6:9, 3:6] = np.eye(3) * qa * T_s / 2.0
    return Q
