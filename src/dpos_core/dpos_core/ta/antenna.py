"""From a sub-IMU's navigation to its antenna phase centre: rigid lever-arm kinematics.

The antenna sits at ``l_a`` (sub-IMU body axes) on its carrier sub-IMU.  Its position is the IMU's
moved by ``C_nb l_a`` (exactly, through ECEF), its velocity adds ``C_nb (omega_eb^b x l_a)`` with
the body rate relative to the Earth ``omega_eb^b = omega_ib^b - C_nb^T omega_ie^n``
([Gong2018] eq. 18, the lever-arm velocity of the master/slave measurement, applied here to the
antenna), and its attitude is the IMU's (rigidly mounted).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import earth
from ..units import FloatArray


def antenna_motion(
    C_nb: FloatArray,
    vel_n_mps: FloatArray,
    llh: FloatArray,
    omega_ib_b_radps: FloatArray,
    lever_arm_b_m: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Position ``llh`` (N, 3) [rad, rad, m] and ENU velocity (N, 3) [m/s] of a point at
    ``lever_arm_b_m`` (3,) in the body axes of an IMU with attitude ``C_nb`` (N, 3, 3), velocity
    ``vel_n_mps`` (N, 3), position ``llh`` (N, 3) and measured angular rate ``omega_ib_b_radps`` (N, 3)."""
    l_a = np.asarray(lever_arm_b_m, dtype=float)
    w_eb = omega_ib_b_radps - np.einsum("nji,nj->ni", C_nb, earth.earth_rate_n(llh[:, 0]))
    vel = vel_n_mps + np.einsum("nij,nj->ni", C_nb, np.cross(w_eb, l_a))
    return earth.offset_llh(llh, C_nb @ l_a), vel


def rate_at(t_imu_s: FloatArray, omega_radps: FloatArray, t_s: FloatArray) -> FloatArray:
    """The angular rate (N, 3) at times ``t_s`` (N,) from IMU samples stamped ``t_imu_s`` (M,) with
    rates ``omega_radps`` (M, 3), each the mean over the step ending at its stamp: attributed to the
    step's middle and interpolated linearly between middles (held beyond the first and last).

    Taking a sample's rate as the rate at its stamp lags it by half a step: on the modal wing of
    docs/mismatch.md (torsion at 4 Hz, 100 Hz samples) that put 1 mm/s of error into the velocity
    of an antenna 0.2 m from its sub-IMU, ten times the sub-IMU's own."""
    t_imu = np.asarray(t_imu_s, dtype=float)
    w = np.asarray(omega_radps, dtype=float)
    if t_imu.size < 2:
        return np.broadcast_to(w[:1], (np.size(t_s), 3)).copy()
    dt = np.diff(t_imu)
    mid = t_imu - 0.5 * np.concatenate([dt[:1], dt])
    return np.stack([np.interp(t_s, mid, w[:, i]) for i in range(3)], axis=1)


#: rows over which :func:`step_roughness` averages
ROUGHNESS_WINDOW = 101


def step_roughness(d: FloatArray) -> FloatArray:
    """Per-step variance (N - 1, m) of the increments ``d`` (N - 1, m) between output rows about a
    straight line: half the running mean (:data:`ROUGHNESS_WINDOW` rows) of their squared first
    differences.  A quantity whose increments are independent from step to step (a wing flexing
    under turbulence, sampled at the IMU rate) interpolated at a fraction a of a step errs by
    ``a (1 - a)`` times that (the Brownian bridge): on paper_su's simulated wing the true velocity
    halfway between 100 Hz rows is 0.3-0.4 mm/s from the straight line, twice the output's own
    error.  The IMU's noise adds to the differences, so the estimate errs on the safe side."""
    n = d.shape[0]
    if n < 2:
        return np.zeros_like(d)
    dd = np.diff(d, axis=0) ** 2
    k = min(ROUGHNESS_WINDOW, dd.shape[0])
    c = np.cumsum(np.concatenate([np.zeros((1, d.shape[1])), dd]), axis=0)
    lo = np.clip(np.arange(n) - k // 2, 0, dd.shape[0] - k)
    return 0.5 * (c[lo + k] - c[lo]) / k


def rate_interpolation_var(t_imu_s: FloatArray, omega_radps: FloatArray, t_s: FloatArray) -> FloatArray:
    """Variance (N, 3) [rad^2/s^2] of :func:`rate_at`'s rates at ``t_s`` (N,): what the linear
    interpolation between the samples' middles cannot know of a rate that changes from step to step
    (a vibrating wing): the Brownian bridge ``a (1 - a) q`` on the samples' own roughness q
    (:func:`step_roughness`), a the time's fraction between the two middles around it."""
    t_imu = np.asarray(t_imu_s, dtype=float)
    if t_imu.size < 3:
        return np.zeros((np.size(t_s), 3))
    w = np.asarray(omega_radps, dtype=float)
    dt = np.diff(t_imu)
    mid = t_imu - 0.5 * np.concatenate([dt[:1], dt])
    q = step_roughness(np.diff(w, axis=0))  # (M - 1, 3): per step between middles
    j = np.clip(np.searchsorted(mid, t_s, side="right") - 1, 0, mid.size - 2)
    a = np.clip((np.asarray(t_s, dtype=float) - mid[j]) / (mid[j + 1] - mid[j]), 0.0, 1.0)[:, None]
    return a * (1.0 - a) * q[j]


def lever_velocity_var(C_nb: FloatArray, omega_var: FloatArray, lever_arm_b_m: ArrayLike) -> FloatArray:
    """ENU variance (N, 3) of ``C_nb (d_omega x r)`` for a rate error of per-axis variance ``omega_var``
    (N, 3) (independent axes) at a lever arm r (3,) in body axes: the antenna velocity's share of the
    rate's uncertainty (:func:`antenna_motion`)."""
    r = np.asarray(lever_arm_b_m, dtype=float)
    Rx = np.array([[0.0, r[2], -r[1]], [-r[2], 0.0, r[0]], [r[1], -r[0], 0.0]])  # d_omega x r = Rx d_omega
    M = np.einsum("nij,jk->nik", C_nb, Rx)  # (N, 3, 3)
    return np.einsum("nik,nk->ni", M**2, omega_var)



class ImuRates:
    """:func:`rate_at` and :func:`rate_interpolation_var` of one IMU's samples, ``t_imu_s`` (M,) and
    ``omega_radps`` (M, 3), for times given a block at a time in increasing order: each
    block computes the samples' middles and roughness over the samples around it only (no array of
    the flight's length; the running sum of :func:`step_roughness` is carried from block to block),
    the same numbers as the functions on every time at once.  Blocks out of order are right too,
    the running sum then restarting from the first sample."""

    #: samples beyond a block's on either side whose middles it computes
    MARGIN = 3

    def __init__(self, t_imu_s: FloatArray, omega_radps: FloatArray) -> None:
        self.t = np.asarray(t_imu_s, dtype=float)
        self.w = np.asarray(omega_radps, dtype=float)
        M = self.t.size
        self._k = min(ROUGHNESS_WINDOW, M - 2) if M >= 3 else 0  # step_roughness's window
        self._ic = 0  # the running sum c[i] = sum of the squared second differences before i, at i = _ic
        self._c = np.zeros((1, 3))

    def _window(self, t_s: FloatArray) -> tuple[int, FloatArray]:
        """The first index i0 and the middles (m,) of the samples around times t_s (N,) (increasing)."""
        t, M = self.t, self.t.size
        i0 = max(int(np.searchsorted(t, t_s[0], side="right")) - self.MARGIN, 0)
        i1 = min(int(np.searchsorted(t, t_s[-1], side="right")) + self.MARGIN, M)
        if i0 == 0:
            dt = np.diff(t[:i1])
            dt = np.concatenate([dt[:1], dt])
        else:
            dt = np.diff(t[i0 - 1:i1])
        return i0, t[i0:i1] - 0.5 * dt

    def rate_at(self, t_s: FloatArray) -> FloatArray:
        """:func:`rate_at` (N, 3) at the times t_s (N,)."""
        t_s = np.asarray(t_s, dtype=float)
        if self.t.size < 2 or t_s.size == 0:
            return rate_at(self.t, self.w, t_s)
        i0, mid = self._window(t_s)
        w = self.w[i0:i0 + mid.size]
        return np.stack([np.interp(t_s, mid, w[:, i]) for i in range(3)], axis=1)

    def interpolation_var(self, t_s: FloatArray) -> FloatArray:
        """:func:`rate_interpolation_var` (N, 3) at the times t_s (N,)."""
        t_s = np.asarray(t_s, dtype=float)
        M = self.t.size
        if M < 3 or t_s.size == 0:
            return rate_interpolation_var(self.t, self.w, t_s)
        i0, mid = self._window(t_s)
        j = np.clip(i0 + np.searchsorted(mid, t_s, side="right") - 1, 0, M - 2)
        a = np.clip((t_s - mid[j - i0]) / (mid[j + 1 - i0] - mid[j - i0]), 0.0, 1.0)[:, None]
        k = self._k
        lo = np.clip(j - k // 2, 0, (M - 2) - k)
        lo0, hi = int(lo.min()), int(lo.max()) + k
        if lo0 < self._ic:  # (times before the last block's: the running sum from the start again)
            self._ic, self._c = 0, np.zeros((1, 3))
        ic = self._ic
        d = np.diff(self.w[ic:hi + 2], axis=0)
        dd = np.diff(d, axis=0) ** 2  # the squared second differences ic .. hi - 1
        c = np.cumsum(np.concatenate([self._c, dd[:hi - ic]]), axis=0)  # c[ic .. hi]
        self._ic, self._c = lo0, c[lo0 - ic:lo0 - ic + 1]
        q = 0.5 * (c[lo + k - ic] - c[lo - ic]) / k
        return a * (1.0 - a) * q
