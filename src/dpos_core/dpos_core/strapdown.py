"""Strapdown inertial mechanization in the local-level ENU navigation frame.

State: attitude ``q_nb`` (body -> local ENU ``n``), velocity ``vel_n_mps`` over the Earth in
``n``, geodetic position ``llh = (lat_rad, lon_rad, h_m)``.  The body frame is whatever frame the
IMU data is expressed in (FLU in this product).

Algorithm (Savage, *Strapdown Analytics* 2nd ed., ch. 7; Savage 1998 JGCD 21(1)-(2)), one step
per IMU sample over ``(t_{k-1}, t_k]``:

* attitude: ``C_nb(k) = expm(-[zeta x]) C_nb(k-1) expm([phi x])`` with the body rotation vector
  ``phi = dtheta_k + 1/12 dtheta_{k-1} x dtheta_k`` (coning compensation) and the navigation-frame
  rotation ``zeta = (omega_ie^n + omega_en^n) T`` at mid-interval;
* velocity: ``dv_sf^b = dv_k + 1/2 dtheta_k x dv_k + 1/12 (dtheta_{k-1} x dv_k + dv_{k-1} x dtheta_k)``
  (rotation + sculling compensation), ``dv_sf^n = (I - 1/2 [zeta x]) C_nb(k-1) dv_sf^b``,
  ``v(k) = v(k-1) + dv_sf^n + (g^n - (2 omega_ie^n + omega_en^n) x v) T`` with gravity and
  Coriolis at mid-interval (velocity extrapolated from the previous step);
* position: trapezoidal integration of the velocity on the ellipsoid.

With rate input (angular rate / specific force sampled at ``t_k``) the increments come from the
trapezoid rule and the coning / sculling terms from the exact integrals for rates that vary
linearly over the interval: coning ``T^2/12 w_{k-1} x w_k``, sculling
``T^2/12 (w_{k-1} x f_k + f_{k-1} x w_k)`` (derived from Savage 1998 eq. 26-29).

A caller can correct the state at any epoch (closed-loop error feedback) with
:meth:`Strapdown.correct`, whose sign convention is the papers' (errors = computed - true,
attitude error ``phi`` with ``C_nb_est = expm(-[phi x]) C_nb_true``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.errors import RejectedInput
from dpos_core.units import FloatArray

from . import _attitude_kernel as _ak
from . import _strapdown_kernel as _k
from .series import NavSeries, NavState  # NavState: imported from here by many callers


def _check_input(name: str, arr: ArrayLike, n: int | None = None) -> FloatArray:
    a = np.ascontiguousarray(arr, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {a.shape}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} has {a.shape[0]} rows but t_s has {n}")
    bad = ~np.all(np.isfinite(a), axis=1)
    if bad.any():
        raise RejectedInput(f"{name} has non-finite values at {int(bad.sum())} samples (first index {int(np.argmax(bad))})",
                            what="IMU samples", reason="nan")
    return a


@dataclass
class Strapdown:
    """Streaming strapdown integrator (see module docstring for the algorithm).

    Feed consecutive chunks of IMU data with :meth:`run_increments` or :meth:`run_rates`
    (not both in one session); correct the state between chunks with :meth:`correct`.
    """

    initial: NavState
    coning: bool = True
    sculling: bool = True
    _state: FloatArray = field(init=False, repr=False)
    _prev: FloatArray = field(init=False, repr=False)
    _t_s: float = field(init=False, repr=False)
    _mode: int | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        self.reset(self.initial)

    def reset(self, state: NavState) -> None:
        """Restart from ``state``, forgetting the previous IMU sample."""
        self._state = np.zeros(_k.STATE_SIZE)
        self._state[0:4] = state.q_nb
        self._state[4:7] = state.vel_n_mps
        self._state[7:10] = state.llh
        self._prev = np.zeros(_k.PREV_SIZE)
        self._t_s = state.t_s
        self._mode = None

    def resume(self, state: NavState, dtheta_rad: ArrayLike, dvel_mps: ArrayLike, dvel_n_mps: ArrayLike) -> None:
        """Restart from ``state`` as if the increment sample ending at ``state.t_s`` had just been
        integrated: ``dtheta_rad``, ``dvel_mps`` (3,) that sample's body increments (the coning and
        sculling memory) and ``dvel_n_mps`` (3,) the velocity change it produced (the kernel's
        previous velocity change).  Re-integrating the following samples then reproduces the
        original run exactly (used to replay stored samples after a correction)."""
        self.reset(state)
        self._prev[0:3] = np.asarray(dtheta_rad, dtype=float).reshape(3)
        self._prev[3:6] = np.asarray(dvel_mps, dtype=float).reshape(3)
        self._prev[6] = 1.0
        self._state[10:13] = np.asarray(dvel_n_mps, dtype=float).reshape(3)

    def snapshot(self) -> tuple[FloatArray, FloatArray, float, int | None]:
        """The integrator's whole state (navigation state, the previous increments of the coning and
        sculling corrections, time, mode): :meth:`restore` continues from it bit for bit."""
        return self._state.copy(), self._prev.copy(), self._t_s, self._mode

    def restore(self, snap: tuple[FloatArray, FloatArray, float, int | None]) -> None:
        """Continue from a :meth:`snapshot` (of this or another integrator with the same options)."""
        state, prev, t_s, mode = snap
        self._state, self._prev, self._t_s, self._mode = state.copy(), prev.copy(), t_s, mode

    @property
    def state(self) -> NavState:
        """Current navigation state (a copy)."""
        return NavState._from_state_vector(self._t_s, self._state)

    @property
    def llh(self) -> FloatArray:
        """The current position (3,) ``[lat_rad, lon_rad, h_m]`` (a copy; ``state.llh`` without the rest)."""
        return self._state[7:10].copy()

    def set_state(self, state: NavState) -> None:
        """Replace the navigation state at the current time, keeping the IMU-sample memory."""
        if abs(state.t_s - self._t_s) > 1e-9:
            raise ValueError(f"set_state at t={state.t_s} but the integrator is at t={self._t_s}")
        self._state[0:4] = state.q_nb
        self._state[4:7] = state.vel_n_mps
        self._state[7:10] = state.llh

    def correct(
        self,
        phi_n_rad: ArrayLike | None = None,
        dvel_n_mps: ArrayLike | None = None,
        dllh: ArrayLike | None = None,
    ) -> None:
        """Closed-loop feedback: remove estimated errors from the current state.

        Args:
            phi_n_rad: attitude error (3,), ``C_nb_est = expm(-[phi x]) C_nb_true``.
            dvel_n_mps: velocity error (3,), ``v_est - v_true``.
            dllh: position error (3,) ``[dlat_rad, dlon_rad, dh_m]``, est - true.
        """
        if phi_n_rad is not None:
            # expm(-[phi x]) removed: q <- normalized rotvec_quat(phi) * q (attitude's kernels on scalars, one call)
            _ak.rotate_normalize(self._state[0:4], np.ascontiguousarray(phi_n_rad, dtype=float).reshape(3))
        if dvel_n_mps is not None:
            dv = np.asarray(dvel_n_mps, dtype=float).reshape(3)
            self._state[4:7] -= dv
        if dllh is not None:
            self._state[7:10] -= np.asarray(dllh, dtype=float).reshape(3)

    def _times(self, t_s: ArrayLike) -> FloatArray:
        t = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
        if not np.all(np.isfinite(t)):
            raise RejectedInput("t_s has non-finite stamps", what="IMU samples", reason="nan")
        return t

    def _steps(self, t: FloatArray, t_start: float | None = None) -> FloatArray:
        """Step lengths from the current time (or ``t_start``); reject non-increasing stamps."""
        t0 = self._t_s if t_start is None else t_start
        dt = np.diff(t, prepend=t0)
        if np.any(dt <= 0.0):
            i = int(np.argmax(dt <= 0.0))
            raise RejectedInput(f"t_s must be strictly increasing after t={t0}: sample {i} at {t[i]} (step {dt[i]})",
                                what="IMU samples", reason="duplicate" if dt[i] == 0.0 else "out_of_order", t_s=float(t[i]))
        return dt

    def _check_mode(self, mode: int) -> None:
        if self._mode is not None and self._mode != mode:
            raise ValueError("cannot mix increment and rate input in one integration (call reset() first)")

    def _run(self, mode: int, t: FloatArray, dt: FloatArray, a: FloatArray, b: FloatArray) -> NavSeries:
        n = t.shape[0]
        out_q = np.empty((n, 4))
        out_v = np.empty((n, 3))
        out_llh = np.empty((n, 3))
        _k.integrate(mode, dt, a, b, self._state, self._prev, self.coning, self.sculling, out_q, out_v, out_llh)
        if n:
            self._t_s = float(t[-1])
        return NavSeries(t.copy(), out_q, out_v, out_llh)

    def run_increments(self, t_s: ArrayLike, dtheta_rad: ArrayLike, dvel_mps: ArrayLike) -> NavSeries:
        """Integrate angle / velocity increments.

        Args:
            t_s: end time of each increment's interval, shape (N,), strictly increasing and
                after the current state time.
            dtheta_rad: integrated angular rate ``omega_ib^b`` over each interval, shape (N, 3).
            dvel_mps: integrated specific force in body axes over each interval, shape (N, 3).

        Returns:
            The navigation solution at each ``t_s`` (N epochs).
        """
        self._check_mode(_k.MODE_INCREMENTS)
        t = self._times(t_s)
        a = _check_input("dtheta_rad", dtheta_rad, t.shape[0])
        b = _check_input("dvel_mps", dvel_mps, t.shape[0])
        dt = self._steps(t)
        self._mode = _k.MODE_INCREMENTS
        return self._run(_k.MODE_INCREMENTS, t, dt, a, b)

    def run_valid_increments(self, t_s: FloatArray, dt_s: FloatArray, dtheta_rad: FloatArray, dvel_mps: FloatArray) -> NavSeries:
        """:meth:`run_increments` of input its caller has validated (the same numbers, without the
        checks: a filter's model integrating, epoch after epoch, samples it checked once).

        Args:
            t_s: end times (N,), strictly increasing and after the current state time.
            dt_s: their steps (N,) from the current state time (``np.diff(t_s, prepend=t0)``).
            dtheta_rad, dvel_mps: finite increments (N, 3), as :meth:`run_increments`.
        """
        self._check_mode(_k.MODE_INCREMENTS)
        self._mode = _k.MODE_INCREMENTS
        return self._run(_k.MODE_INCREMENTS, np.ascontiguousarray(t_s, dtype=float), np.ascontiguousarray(dt_s, dtype=float),
                         np.ascontiguousarray(dtheta_rad, dtype=float), np.ascontiguousarray(dvel_mps, dtype=float))

    def run_rates(self, t_s: ArrayLike, omega_ib_b_radps: ArrayLike, f_ib_b_mps2: ArrayLike) -> NavSeries:
        """Integrate angular rate / specific force samples.

        The first sample of a fresh integrator must be at the state time (it starts the
        interpolation); later chunks continue from the last sample of the previous chunk.

        Args:
            t_s: sample times, shape (N,), strictly increasing.
            omega_ib_b_radps: angular rate of the body w.r.t. inertial space, shape (N, 3).
            f_ib_b_mps2: specific force in body axes, shape (N, 3).

        Returns:
            The navigation solution at each ``t_s`` (N epochs; for a fresh integrator the first
            one is the initial state).
        """
        self._check_mode(_k.MODE_RATES)
        t = self._times(t_s)
        a = _check_input("omega_ib_b_radps", omega_ib_b_radps, t.shape[0])
        b = _check_input("f_ib_b_mps2", f_ib_b_mps2, t.shape[0])
        starting = self._prev[6] < 0.5 and t.shape[0] > 0
        if starting:
            if abs(t[0] - self._t_s) > 1e-9:
                raise ValueError(f"first rate sample at t={t[0]} but the state is at t={self._t_s}")
            self._steps(t[1:], t[0])
        else:
            self._steps(t)
        self._mode = _k.MODE_RATES
        parts: list[NavSeries] = []
        if starting:
            self._prev[0:3], self._prev[3:6], self._prev[6] = a[0], b[0], 1.0
            s = self.state
            parts.append(NavSeries(t[:1].copy(), s.q_nb[None], s.vel_n_mps[None], s.llh[None]))
            t, a, b = t[1:], a[1:], b[1:]
        parts.append(self._run(_k.MODE_RATES, t, np.diff(t, prepend=self._t_s), a, b))
        return NavSeries.concatenate(parts) if len(parts) > 1 else parts[0]
