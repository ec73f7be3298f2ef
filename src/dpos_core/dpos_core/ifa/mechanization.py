"""The main POS's mechanization with in-flight-alignment feedback (pos_master_node, ifa_node).

:class:`MasterMechanization` integrates the master IMU at its rate with the strapdown of
:mod:`dpos_core.strapdown` (numba, batched) and applies the corrections of the ifa_node so that
its navigation is *exactly* the closed-loop strapdown of :class:`dpos_core.ifa.pipeline.InFlightAligner`
("shadow mechanization"): both integrate the same IMU samples from the same initial state, and

* a correction (``/ifa/correction``) for the epoch ``t_k`` replaces the state at the IMU sample
  ``t_k`` (the aligner's state right after its feedback, [Fang2012] sec. 3.3) and re-integrates the
  samples stored after ``t_k`` (a ring of the last ``ring_s`` seconds);
* a bias compensation (``/ifa/imu_bias`` stamped ``t_k``) is removed from the IMU samples after
  ``t_k``, as :meth:`dpos_core.ifa.model.IfaModel.propagate` does from the alignment epoch on.

Exactness needs the integrator's memory at ``t_k`` too (the coning / sculling terms use the
previous increments, the velocity extrapolation the previous velocity change; :meth:`Strapdown.correct`
keeps them): they are stored per sample and restored with :meth:`Strapdown.resume`
(test_ifa_node.py pins the equality with the aligner to 1e-9).

Times are seconds since an origin stamp (:func:`stamp_s`): ``(t_ns - origin_ns) / 1e9`` gives the
simulator's ``k / rate`` bit for bit, so the nodes integrate the very step lengths of
:func:`dpos_core.ifa.pipeline.run` on the simulated series.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dpos_core import earth
from dpos_core.attitude import dcm_to_quat, quat_to_dcm
from dpos_core.series import NavSeries
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.units import DEG, FloatArray

#: two stamps closer than this are the same sample [s]
STAMP_TOL_S = 1e-6


def stamp_s(t_ns: ArrayLike, origin_ns: int) -> FloatArray:
    """Seconds since ``origin_ns`` of stamps [ns] (exact for the simulator's grid, see module docstring)."""
    return (np.asarray(t_ns, dtype=np.int64) - np.int64(origin_ns)) / 1e9


def body_rate_eb(q_nb: FloatArray, llh: FloatArray, vel_n_mps: FloatArray, omega_ib_b_radps: FloatArray) -> FloatArray:
    """Body rate w.r.t. the Earth in body axes (N, 3): ``omega_ib^b - C_bn (omega_ie^n + omega_en^n)``."""
    w_in = earth.earth_rate_n(llh[..., 0]) + earth.transport_rate_n(llh[..., 0], llh[..., 2], vel_n_mps)
    return omega_ib_b_radps - np.einsum("...ji,...j->...i", quat_to_dcm(q_nb), w_in)


def initial_state_from_truth(truth_q_nb: FloatArray, vel_n_mps: FloatArray, llh: FloatArray, t_s: float,
                             heading_error_deg: float = 0.0) -> NavState:
    """A truth state with a heading error (level errors 0): ``C_nb_est = R_U(-dpsi) C_nb`` so that the
    aviation heading grows by ``heading_error_deg``."""
    from dpos_core.frames import C_nb_from_hpr, hpr_from_C_nb

    hpr = hpr_from_C_nb(quat_to_dcm(np.asarray(truth_q_nb, dtype=float)))
    hpr = hpr + np.array([heading_error_deg * DEG, 0.0, 0.0])
    return NavState(t_s, dcm_to_quat(C_nb_from_hpr(*hpr)), vel_n_mps, llh)


def initial_state_from_list(values: Sequence[float], t_s: float) -> NavState:
    """``[lat_deg, lon_deg, h_m, vE, vN, vU, heading_deg, pitch_deg, roll_deg]`` -> NavState."""
    v = np.asarray(values, dtype=float)
    if v.shape != (9,) or not np.all(np.isfinite(v)):
        raise ValueError("expected [lat_deg, lon_deg, h_m, vE, vN, vU, heading_deg, pitch_deg, roll_deg] (9 finite numbers)")
    return NavState.from_hpr(t_s, v[6:9] * DEG, v[3:6], [v[0] * DEG, v[1] * DEG, v[2]])


@dataclass
class _Ring:
    """Stored samples (M of them): t_s (M,), raw omega / f (M, 3), the increments integrated (M, 3)
    each, the velocity change of each step (M, 3) and the navigation after each sample."""

    t_s: FloatArray
    omega: FloatArray
    f: FloatArray
    dtheta: FloatArray
    dvel: FloatArray
    dv_step: FloatArray
    q_nb: FloatArray
    vel: FloatArray
    llh: FloatArray

    @classmethod
    def empty(cls) -> _Ring:
        z3 = np.empty((0, 3))
        return cls(np.empty(0), z3, z3, z3, z3, z3, np.empty((0, 4)), z3, z3)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def append(self, other: _Ring) -> None:
        for k in self.__dataclass_fields__:
            setattr(self, k, np.concatenate([getattr(self, k), getattr(other, k)]))

    def cut(self, start: int) -> None:
        """Keep samples ``start:``."""
        for k in self.__dataclass_fields__:
            setattr(self, k, getattr(self, k)[start:].copy())

    def replace_from(self, j: int, other: _Ring) -> None:
        """Samples ``j:`` := other (same times)."""
        for k in self.__dataclass_fields__:
            getattr(self, k)[j:] = getattr(other, k)


class MasterMechanization:
    """The master strapdown with IFA feedback (module docstring).

    Args:
        initial: the state the mechanization starts from (its ``t_s`` is before every sample).
        ring_s: how many seconds of samples are kept for re-integration after a correction.

    Not thread-safe: the nodes serialize the calls with a lock.
    """

    def __init__(self, initial: NavState, ring_s: float = 60.0) -> None:
        self.initial = initial.copy()
        self.ring_s = float(ring_s)
        self.strapdown = Strapdown(initial)
        self.ring = _Ring.empty()
        self._bias_t: list[float] = []  # stamps of the bias compensations, ascending
        self._bias: list[tuple[FloatArray, FloatArray]] = []
        self.corrections = 0
        self.last_correction_t_s: float | None = None
        self.dropped = 0  # IMU samples dropped (non-finite, duplicate / out-of-order stamps)
        self._dt_nominal: float | None = None

    # ------------------------------------------------------------------ state
    @property
    def t_s(self) -> float:
        return self.strapdown.state.t_s

    @property
    def state(self) -> NavState:
        return self.strapdown.state

    def bias_at(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        """The compensation (gyro [rad/s], accel [m/s^2]) of a sample at ``t_s`` (the last one stamped before)."""
        i = bisect.bisect_left(self._bias_t, t_s - STAMP_TOL_S) - 1
        return self._bias[i] if i >= 0 else (np.zeros(3), np.zeros(3))

    def nav(self) -> NavSeries:
        """The stored navigation (ring), as currently corrected."""
        r = self.ring
        return NavSeries(r.t_s.copy(), r.q_nb.copy(), r.vel.copy(), r.llh.copy())

    # ------------------------------------------------------------------ input
    def add(self, t_s: ArrayLike, omega_radps: ArrayLike, f_mps2: ArrayLike) -> tuple[NavSeries, NDArray[np.bool_], list[str]]:
        """Integrate new IMU samples (mean rates over ``(t_{i-1}, t_i]``: t_s (N,), (N, 3), (N, 3)).

        Returns ``(nav of the kept samples, keep mask (N,), warnings)``: samples with non-finite
        values or with a stamp not after the previous one are dropped with a warning; a gap
        (step > 1.5 x the nominal interval) is integrated and warned about.
        """
        t = np.asarray(t_s, dtype=float).reshape(-1)
        om = np.asarray(omega_radps, dtype=float).reshape(-1, 3)
        fb = np.asarray(f_mps2, dtype=float).reshape(-1, 3)
        warnings: list[str] = []
        keep = np.isfinite(t) & np.all(np.isfinite(om), axis=1) & np.all(np.isfinite(fb), axis=1)
        for i in np.flatnonzero(~keep):
            warnings.append(f"IMU sample at t={t[i]:.6f} s has non-finite values: dropped")
        last = self.t_s
        for i in np.flatnonzero(keep):
            if t[i] <= last + STAMP_TOL_S:
                kind = "duplicate" if abs(t[i] - last) <= STAMP_TOL_S else "out-of-order"
                warnings.append(f"{kind} IMU stamp t={t[i]:.6f} s (last t={last:.6f} s): dropped")
                keep[i] = False
            else:
                last = t[i]
        self.dropped += int((~keep).sum())
        t, om, fb = t[keep], om[keep], fb[keep]
        if t.size:
            steps = np.diff(np.concatenate([[self.t_s], t]))
            if self._dt_nominal is None and t.size >= 2:
                self._dt_nominal = float(np.median(steps[1:]))
            if self._dt_nominal is not None:
                for i in np.flatnonzero(steps > 1.5 * self._dt_nominal):
                    warnings.append(f"IMU gap of {steps[i]:.4f} s before t={t[i]:.6f} s (nominal {self._dt_nominal:.4f} s): integrated across")
            new = self._integrate(t, om, fb)
            self.ring.append(new)
            self._trim()
            nav = NavSeries(new.t_s, new.q_nb, new.vel, new.llh)
        else:
            nav = NavSeries(np.empty(0), np.empty((0, 4)), np.empty((0, 3)), np.empty((0, 3)))
        return nav, keep, warnings

    def _trim(self) -> None:
        r = self.ring
        if len(r) and r.t_s[-1] - r.t_s[0] > 2.0 * self.ring_s:
            self.ring.cut(int(np.searchsorted(r.t_s, r.t_s[-1] - self.ring_s)))
        while len(self._bias_t) > 1 and len(r) and self._bias_t[1] < r.t_s[0] - STAMP_TOL_S:
            del self._bias_t[0], self._bias[0]

    def _integrate(self, t: FloatArray, om: FloatArray, fb: FloatArray) -> _Ring:
        """Integrate from the strapdown's current state, bias compensation per sample (bias_at)."""
        sd = self.strapdown
        v_start = sd.state.vel_n_mps
        steps = np.diff(np.concatenate([[sd.state.t_s], t]))[:, None]
        which = np.searchsorted(np.asarray(self._bias_t), t - STAMP_TOL_S, side="left") - 1
        dth = np.empty_like(om)
        dvl = np.empty_like(fb)
        parts = []
        for lo, hi in _runs(which):
            g, a = self._bias[which[lo]] if which[lo] >= 0 else (np.zeros(3), np.zeros(3))
            # the aligner's operations, in its order: (omega - comp) * dt
            dth[lo:hi] = (om[lo:hi] - g) * steps[lo:hi]
            dvl[lo:hi] = (fb[lo:hi] - a) * steps[lo:hi]
            parts.append(sd.run_increments(t[lo:hi], dth[lo:hi], dvl[lo:hi]))
        nav = NavSeries.concatenate(parts) if len(parts) > 1 else parts[0]
        dv_step = np.diff(np.concatenate([v_start[None], nav.vel_n_mps]), axis=0)
        return _Ring(t.copy(), om.copy(), fb.copy(), dth, dvl, dv_step, nav.q_nb, nav.vel_n_mps, nav.llh)

    # ------------------------------------------------------------------ feedback
    def _index(self, t_s: float) -> int | None:
        r = self.ring
        j = int(np.searchsorted(r.t_s, t_s - STAMP_TOL_S))
        return j if j < len(r) and abs(r.t_s[j] - t_s) <= STAMP_TOL_S else None

    def _reintegrate_from(self, j: int) -> None:
        """Restart the strapdown at stored sample j (its state and memory) and re-integrate j+1:."""
        r = self.ring
        sd = self.strapdown
        sd.resume(NavState(r.t_s[j], r.q_nb[j], r.vel[j], r.llh[j]), r.dtheta[j], r.dvel[j], r.dv_step[j])
        if j + 1 < len(r):
            r.replace_from(j + 1, self._integrate(r.t_s[j + 1:], r.omega[j + 1:], r.f[j + 1:]))

    def correct(self, state: NavState) -> str | None:
        """Reset to the corrected state at the stored sample of ``state.t_s`` and re-integrate the
        samples after it. Returns a warning (nothing changed) when the stamp is not a stored sample."""
        t = state.t_s
        j = self._index(t)
        if j is None:
            r = self.ring
            span = f"[{r.t_s[0]:.3f}, {r.t_s[-1]:.3f}] s" if len(r) else "(none yet)"
            return f"correction at t={t:.6f} s is not a stored IMU sample (stored {span}): ignored"
        r = self.ring
        r.q_nb[j], r.vel[j], r.llh[j] = state.q_nb, state.vel_n_mps, state.llh
        self._reintegrate_from(j)
        self.corrections += 1
        self.last_correction_t_s = float(r.t_s[j])
        return None

    def set_bias(self, t_s: float, gyro_radps: ArrayLike, accel_mps2: ArrayLike) -> str | None:
        """Remove this compensation from the samples after ``t_s`` (re-integrating stored ones)."""
        g = np.asarray(gyro_radps, dtype=float).reshape(3)
        a = np.asarray(accel_mps2, dtype=float).reshape(3)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(a))):
            return f"IMU bias at t={t_s:.6f} s is not finite: ignored"
        i = bisect.bisect_left(self._bias_t, t_s - STAMP_TOL_S)
        if i < len(self._bias_t) and abs(self._bias_t[i] - t_s) <= STAMP_TOL_S:
            self._bias[i] = (g, a)
        else:
            self._bias_t.insert(i, float(t_s))
            self._bias.insert(i, (g, a))
        if t_s >= self.t_s - STAMP_TOL_S:
            return None  # no stored sample after it yet
        j = self._index(t_s)
        if j is None:
            j = int(np.searchsorted(self.ring.t_s, t_s)) - 1
            if j < 0:
                return f"IMU bias at t={t_s:.6f} s is older than the stored samples: applied to the samples from now on"
        self._reintegrate_from(j)
        return None


def _runs(which: NDArray[np.int64]) -> list[tuple[int, int]]:
    """[lo, hi) runs of equal values."""
    if which.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(which)) + 1
    edges = np.concatenate([[0], cuts, [which.size]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


__all__ = ["MasterMechanization", "stamp_s", "body_rate_eb", "initial_state_from_truth", "initial_state_from_list", "STAMP_TOL_S"]
