"""The main POS's mechanization with in-flight-alignment feedback (pos_master_node, ifa_node).

:class:`MasterMechanization` integrates the master IMU at its rate with the strapdown of
:mod:`dpos_core.strapdown` (numba, batched) and applies the corrections of the ifa_node so that
its navigation is *exactly* the closed-loop strapdown of :class:`dpos_core.ifa.pipeline.InFlightAligner`
("shadow mechanization"): both integrate the same IMU samples from the same initial state, and

* a correction (``/ifa/correction``) for the epoch ``t_k`` replaces the state at the IMU sample
  ``t_k`` (the aligner's state right after its feedback, [Fang2012] sec. 3.3); the samples after
  ``t_k`` are integrated from it;
* a bias compensation (``/ifa/imu_bias`` stamped ``t_k``) is removed from the IMU samples after
  ``t_k``, as :meth:`dpos_core.ifa.model.IfaModel.propagate` does from the alignment epoch on.

Whatever the order in which samples and feedback arrive, the result is the same (the
ifa_node may publish the correction of ``t_k`` before or after the master integrated ``t_k``):

* **pending**: feedback stamped after the last integrated sample is kept and applied exactly when
  that sample is integrated: :meth:`MasterMechanization.add` splits its batch at the pending
  stamps (integrate up to ``t_k``, reset to the corrected state at ``t_k`` keeping the
  integrator's memory, as the aligner's feedback does, continue); a bias stamped ``t_k`` applies
  to the samples after ``t_k`` whenever they are integrated;
* **stored**: feedback for a sample already integrated resets the stored sample (a ring of the
  last ``ring_s`` seconds, :attr:`MasterMechanization.ring`) and re-integrates the samples stored
  after it, re-applying the later corrections already received (a correction carries the
  aligner's absolute state, so it stays valid when an earlier bias arrives late); the navigation
  of those samples was already handed out without it: counted as ``corrections_late`` /
  ``late_samples``;
* **lost**: feedback older than the ring, or stamped where no sample was integrated (a sample the
  master dropped), cannot be applied exactly: counted (``corrections_lost`` / ``biases_lost``)
  and returned as a warning, never silent.

The navigation returned for a sample (:meth:`MasterMechanization.add`, what pos_master_node
publishes) is the integration up to it: at an epoch sample ``t_k`` the state *before* the
correction (the one the ifa_node's shadow strapdown compares, ``nav_discrepancy_m``); the ring
(:meth:`MasterMechanization.nav`) holds the corrected state there, as
:func:`dpos_core.ifa.pipeline.run` does.

Exactness needs the integrator's memory at ``t_k`` too (the coning / sculling terms use the
previous increments, the velocity extrapolation the previous velocity change; :meth:`Strapdown.correct`
keeps them): they are stored per sample and restored with :meth:`Strapdown.resume`
(test_mechanization.py and test_ifa_node.py pin the equality with the aligner to 1e-9).

Times are seconds since an origin stamp (:func:`stamp_s`): ``(t_ns - origin_ns) / 1e9`` gives the
simulator's ``k / rate`` bit for bit, so the nodes integrate the very step lengths of
:func:`dpos_core.ifa.pipeline.run` on the simulated series.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dpos_core import earth
from dpos_core.attitude import dcm_to_quat, quat_to_dcm
from dpos_core.frames import C_nb_from_hpr, hpr_from_C_nb
from dpos_core.series import GAP_FACTOR, NavSeries
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.units import DEG, FloatArray

#: two stamps closer than this are the same sample [s]
STAMP_TOL_S = 1e-6
#: standard gravity [m/s^2] (only the direction of the mean specific force is used by :func:`level_from_specific_force`)
_G0_MPS2 = 9.80665


def stamp_s(t_ns: ArrayLike, origin_ns: int) -> FloatArray:
    """Seconds since ``origin_ns`` of stamps [ns] (exact for the simulator's grid, see module docstring)."""
    return (np.asarray(t_ns, dtype=np.int64) - np.int64(origin_ns)) / 1e9


def body_rate_eb(q_nb: FloatArray, llh: FloatArray, vel_n_mps: FloatArray, omega_ib_b_radps: FloatArray) -> FloatArray:
    """Body rate w.r.t. the Earth in body axes (N, 3): ``omega_ib^b - C_bn (omega_ie^n + omega_en^n)``."""
    w_in = earth.earth_rate_n(llh[..., 0]) + earth.transport_rate_n(llh[..., 0], llh[..., 2], vel_n_mps)
    return omega_ib_b_radps - np.einsum("...ji,...j->...i", quat_to_dcm(q_nb), w_in)


def level_from_specific_force(f_b_mps2: ArrayLike) -> tuple[float, float]:
    """Pitch and roll [rad] (aviation angles: nose up +, right wing down +) of a body whose mean
    specific force is ``f_b_mps2`` (3,) [m/s^2] in its FLU axes: at rest (or unaccelerated)
    ``f = C_bn (0, 0, +g)`` (ENU), i.e. ``f = g (sin(pitch), sin(roll) cos(pitch), cos(roll) cos(pitch))``,
    so ``pitch = atan2(f_x, hypot(f_y, f_z))`` and ``roll = atan2(f_y, f_z)`` (nose up, the forward
    axis points up: +g sin(pitch) on x; an FRD formula's ``-f_x`` is for ``f = -g`` along down).

    An acceleration ``a`` over the averaging window tilts the result by about ``|a| / g`` rad
    (1 m/s^2: 5.8 deg): the in-flight alignment removes what is left.

    Raises:
        ValueError: ``f_b_mps2`` not 3 finite values, or less than 0.1 g (no gravity to level on).
    """
    f = np.asarray(f_b_mps2, dtype=float).reshape(3)
    if not np.all(np.isfinite(f)) or np.linalg.norm(f) < 0.1 * _G0_MPS2:
        raise ValueError(f"mean specific force {f.tolist()} m/s^2 is not finite or too small to level on")
    return float(np.arctan2(f[0], np.hypot(f[1], f[2]))), float(np.arctan2(f[1], f[2]))


def initial_state_from_truth(truth_q_nb: FloatArray, vel_n_mps: FloatArray, llh: FloatArray, t_s: float,
                             heading_error_deg: float = 0.0) -> NavState:
    """A truth state with a heading error (level errors 0): ``C_nb_est = R_U(-dpsi) C_nb`` so that the
    aviation heading grows by ``heading_error_deg``."""
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
class _Samples:
    """Integrated samples (M of them): t_s (M,), raw omega / f (M, 3), the increments integrated (M, 3)
    each, the velocity change of each step (M, 3) and the navigation after each sample (corrected
    at the epoch samples)."""

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
    def concatenate(cls, parts: list[_Samples]) -> _Samples:
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def set_nav(self, j: int, state: NavState) -> None:
        """The navigation of sample j := ``state`` (its time is the sample's)."""
        self.q_nb[j], self.vel[j], self.llh[j] = state.q_nb, state.vel_n_mps, state.llh


#: the columns of a sample in the ring: name -> shape of one sample
_COLUMNS: dict[str, tuple[int, ...]] = {"t_s": (), "omega": (3,), "f": (3,), "dtheta": (3,), "dvel": (3,), "dv_step": (3,),
                                        "q_nb": (4,), "vel": (3,), "llh": (3,)}


class _Ring:
    """The stored samples (:class:`_Samples`' columns), in buffers that grow by doubling: appending
    copies only the new samples (the attributes are views of the first ``len`` rows, writable)."""

    def __init__(self, capacity: int = 1024) -> None:
        self._n = 0
        self._buf = {k: np.empty((capacity, *shape)) for k, shape in _COLUMNS.items()}

    def __len__(self) -> int:
        return self._n

    def _col(self, name: str) -> FloatArray:
        return self._buf[name][: self._n]

    t_s = property(lambda self: self._col("t_s"))
    omega = property(lambda self: self._col("omega"))
    f = property(lambda self: self._col("f"))
    dtheta = property(lambda self: self._col("dtheta"))
    dvel = property(lambda self: self._col("dvel"))
    dv_step = property(lambda self: self._col("dv_step"))
    q_nb = property(lambda self: self._col("q_nb"))
    vel = property(lambda self: self._col("vel"))
    llh = property(lambda self: self._col("llh"))

    def append(self, new: _Samples) -> None:
        m = len(new)
        cap = next(iter(self._buf.values())).shape[0]
        if self._n + m > cap:
            cap = max(2 * cap, self._n + m)
            for k, b in self._buf.items():
                grown = np.empty((cap, *b.shape[1:]))
                grown[: self._n] = b[: self._n]
                self._buf[k] = grown
        for k, b in self._buf.items():
            b[self._n:self._n + m] = getattr(new, k)
        self._n += m

    def cut(self, start: int) -> None:
        """Keep samples ``start:``."""
        keep = self._n - start
        for b in self._buf.values():
            b[:keep] = b[start:self._n].copy()
        self._n = keep

    def replace_from(self, j: int, new: _Samples) -> None:
        """Samples ``j:`` := new (same times)."""
        for k, b in self._buf.items():
            b[j:self._n] = getattr(new, k)

    def set_nav(self, j: int, state: NavState) -> None:
        """The navigation of sample j := ``state`` (its time is the sample's)."""
        self.q_nb[j], self.vel[j], self.llh[j] = state.q_nb, state.vel_n_mps, state.llh


class MasterMechanization:
    """The master strapdown with IFA feedback (module docstring).

    Args:
        initial: the state the mechanization starts from (its ``t_s`` is before every sample).
        ring_s: how many seconds of samples are kept for re-integration after a correction
            (between ``ring_s`` and ``2 ring_s`` are stored).

    Counters (what pos_master_node reports on /pos_master/status):
        corrections: corrections applied (at once or when their sample was integrated);
        biases: bias compensations applied (:meth:`set_bias`);
        corrections_late: of those, applied to a sample after which samples had already been
            integrated (their navigation, already handed out, lacks it);
        late_samples: how many samples that was in all (corrections and biases); last_late: the
            latest late correction, for people;
        corrections_lost, biases_lost: feedback that could not be applied exactly (older than the
            ring, or stamped where no sample was integrated); last_lost: why, for people;
        dropped: IMU samples dropped (non-finite, duplicate / out-of-order stamps).
    :attr:`corrections_pending` is the number of corrections waiting for their sample.

    Not thread-safe: the nodes serialize the calls with a lock.
    """

    def __init__(self, initial: NavState, ring_s: float = 60.0) -> None:
        self.initial = initial.copy()
        self.ring_s = float(ring_s)
        self.strapdown = Strapdown(initial)
        self.ring = _Ring()
        #: the ring still starts at the first sample after the initial state (a correction at the
        #: initial state's stamp can then be applied by re-integrating everything)
        self._from_start = True
        self._bias_t: list[float] = []  # stamps of the bias compensations, ascending
        self._bias: list[tuple[FloatArray, FloatArray]] = []
        # corrections by stamp, ascending: applied ones within the ring (re-applied when the ring is
        # re-integrated) and pending ones after the last integrated sample
        self._reset_t: list[float] = []
        self._reset: list[NavState] = []
        self.corrections = 0
        self.corrections_late = 0
        self.corrections_lost = 0
        self.biases = 0
        self.biases_lost = 0
        self.late_samples = 0
        self.last_lost = ""
        self.last_late = ""  #: the latest feedback applied late: when, and to how many samples
        self.last_correction_t_s: float | None = None
        self.dropped = 0  # IMU samples dropped (non-finite, duplicate / out-of-order stamps)
        self._dt_nominal: float | None = None

    # ------------------------------------------------------------------ state
    @property
    def t_s(self) -> float:
        """Time [s] of the last integrated sample (the initial state's before the first)."""
        return self.strapdown.state.t_s

    @property
    def state(self) -> NavState:
        """The current navigation state (at :attr:`t_s`, corrected)."""
        return self.strapdown.state

    @property
    def corrections_pending(self) -> int:
        """Corrections received for samples not integrated yet."""
        return len(self._reset_t) - bisect.bisect_right(self._reset_t, self.t_s + STAMP_TOL_S)

    def bias_at(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        """The compensation (gyro [rad/s], accel [m/s^2]) of a sample at ``t_s`` (the last one stamped before)."""
        i = bisect.bisect_left(self._bias_t, t_s - STAMP_TOL_S) - 1
        return self._bias[i] if i >= 0 else (np.zeros(3), np.zeros(3))

    def nav(self) -> NavSeries:
        """The stored navigation (ring), as currently corrected (the corrected state at the epoch samples)."""
        r = self.ring
        return NavSeries(r.t_s.copy(), r.q_nb.copy(), r.vel.copy(), r.llh.copy())

    # ------------------------------------------------------------------ input
    def add(self, t_s: ArrayLike, omega_radps: ArrayLike, f_mps2: ArrayLike) -> tuple[NavSeries, NDArray[np.bool_], list[str]]:
        """Integrate new IMU samples (mean rates over ``(t_{i-1}, t_i]``: t_s (N,) [s], omega (N, 3)
        [rad/s], f (N, 3) [m/s^2]), applying the pending corrections at their samples.

        Returns ``(nav of the kept samples (K), keep mask (N,), warnings)``: the navigation after
        each kept sample (at an epoch sample: before its correction, module docstring); samples
        with non-finite values or with a stamp not after the previous one are dropped with a
        warning; a gap (step > GAP_FACTOR = 1.75 x the nominal interval) is integrated and warned about; a
        pending correction whose sample is not among the kept ones is lost (warning, counted).
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
        if not t.size:
            return NavSeries(np.empty(0), np.empty((0, 4)), np.empty((0, 3)), np.empty((0, 3))), keep, warnings
        steps = np.diff(np.concatenate([[self.t_s], t]))
        if self._dt_nominal is None and t.size >= 2:
            self._dt_nominal = float(np.median(steps[1:]))
        if self._dt_nominal is not None:
            for i in np.flatnonzero(steps > GAP_FACTOR * self._dt_nominal):
                warnings.append(f"IMU gap of {steps[i]:.4f} s before t={t[i]:.6f} s (nominal {self._dt_nominal:.4f} s): integrated across")
        new, published = self._integrate_with_resets(t, om, fb, warnings)
        self.ring.append(new)
        self._trim()
        return published, keep, warnings

    def _trim(self) -> None:
        r = self.ring
        if len(r) and r.t_s[-1] - r.t_s[0] > 2.0 * self.ring_s:
            self.ring.cut(int(np.searchsorted(r.t_s, r.t_s[-1] - self.ring_s)))
            self._from_start = False
        if not len(r):
            return
        while len(self._bias_t) > 1 and self._bias_t[1] < r.t_s[0] - STAMP_TOL_S:
            del self._bias_t[0], self._bias[0]
        k = bisect.bisect_left(self._reset_t, r.t_s[0] - STAMP_TOL_S)
        del self._reset_t[:k], self._reset[:k]

    def _integrate(self, t: FloatArray, om: FloatArray, fb: FloatArray) -> _Samples:
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
        return _Samples(t.copy(), om.copy(), fb.copy(), dth, dvl, dv_step, nav.q_nb, nav.vel_n_mps, nav.llh)

    def _integrate_with_resets(self, t: FloatArray, om: FloatArray, fb: FloatArray,
                               warnings: list[str] | None = None) -> tuple[_Samples, NavSeries]:
        """Integrate samples (after the strapdown's time) and apply the corrections stamped at them.

        The batch is split at the correction stamps: integrate up to ``t_k``, replace the state
        there (:meth:`Strapdown.set_state`: the integrator's memory is kept, as the aligner's
        feedback keeps it), continue. ``warnings`` given: new samples (corrections applied now
        are counted; one without a sample at its stamp is lost); None: stored samples being
        re-integrated (their corrections were counted when first applied).

        Returns ``(the samples for the ring (corrected at the epochs), their navigation before
        the corrections)``.
        """
        sd = self.strapdown
        lo_r = bisect.bisect_right(self._reset_t, sd.state.t_s + STAMP_TOL_S)
        hi_r = bisect.bisect_right(self._reset_t, t[-1] + STAMP_TOL_S)
        stamps, states = self._reset_t[lo_r:hi_r], self._reset[lo_r:hi_r]
        parts: list[_Samples] = []
        pre: list[tuple[int, FloatArray, FloatArray, FloatArray]] = []  # (index, q, v, llh) before the corrections
        lo = 0
        for tk, state in zip(stamps, states):
            m = int(np.searchsorted(t, tk - STAMP_TOL_S))
            if m >= t.size or abs(t[m] - tk) > STAMP_TOL_S:  # no sample at its stamp (new samples only)
                self._drop_reset(tk)
                if warnings is not None:
                    warnings.append(self._lose("correction", tk, "no IMU sample was integrated at its stamp "
                                                                 f"(the samples around it: {_around(t, tk)})"))
                continue
            seg = self._integrate(t[lo:m + 1], om[lo:m + 1], fb[lo:m + 1])
            pre.append((m, seg.q_nb[-1].copy(), seg.vel[-1].copy(), seg.llh[-1].copy()))
            fixed = NavState(float(t[m]), state.q_nb, state.vel_n_mps, state.llh)
            sd.set_state(fixed)
            seg.set_nav(len(seg) - 1, fixed)
            parts.append(seg)
            lo = m + 1
            if warnings is not None:
                self.corrections += 1
                self.last_correction_t_s = float(t[m])
        if lo < t.size:
            parts.append(self._integrate(t[lo:], om[lo:], fb[lo:]))
        new = _Samples.concatenate(parts) if len(parts) > 1 else parts[0]
        q, v, llh = new.q_nb.copy(), new.vel.copy(), new.llh.copy()
        for m, qm, vm, lm in pre:
            q[m], v[m], llh[m] = qm, vm, lm
        return new, NavSeries(new.t_s.copy(), q, v, llh)

    # ------------------------------------------------------------------ feedback
    def _index(self, t_s: float) -> int | None:
        r = self.ring
        j = int(np.searchsorted(r.t_s, t_s - STAMP_TOL_S))
        return j if j < len(r) and abs(r.t_s[j] - t_s) <= STAMP_TOL_S else None

    def _at_start(self, t_s: float) -> bool:
        """``t_s`` is the initial state's stamp and every sample since is stored."""
        return self._from_start and abs(t_s - self.initial.t_s) <= STAMP_TOL_S

    def _reintegrate_from(self, j: int) -> None:
        """Restart the strapdown at stored sample j (its state and memory; j = -1: the initial
        state) and re-integrate the samples j+1: (re-applying their corrections)."""
        r = self.ring
        sd = self.strapdown
        if j < 0:
            sd.reset(self.initial)
        else:
            sd.resume(NavState(r.t_s[j], r.q_nb[j], r.vel[j], r.llh[j]), r.dtheta[j], r.dvel[j], r.dv_step[j])
        if j + 1 < len(r):
            new, _ = self._integrate_with_resets(r.t_s[j + 1:], r.omega[j + 1:], r.f[j + 1:])
            r.replace_from(j + 1, new)

    def _store_reset(self, state: NavState) -> None:
        t = float(state.t_s)
        i = bisect.bisect_left(self._reset_t, t - STAMP_TOL_S)
        if i < len(self._reset_t) and abs(self._reset_t[i] - t) <= STAMP_TOL_S:
            self._reset[i] = state.copy()  # a newer correction for the same sample replaces it
        else:
            self._reset_t.insert(i, t)
            self._reset.insert(i, state.copy())

    def _drop_reset(self, t_s: float) -> None:
        i = bisect.bisect_left(self._reset_t, t_s - STAMP_TOL_S)
        if i < len(self._reset_t) and abs(self._reset_t[i] - t_s) <= STAMP_TOL_S:
            del self._reset_t[i], self._reset[i]

    def _lose(self, what: str, t_s: float, why: str) -> str:
        """Count a correction / bias that cannot be applied; the warning text."""
        if what == "correction":
            self.corrections_lost += 1
        else:
            self.biases_lost += 1
        self.last_lost = f"{what} at t={t_s:.6f} s: {why}"
        return f"{self.last_lost}: lost ({self.corrections_lost} correction(s), {self.biases_lost} bias(es) lost so far)"

    def _span(self) -> str:
        r = self.ring
        return f"[{r.t_s[0]:.6f}, {r.t_s[-1]:.6f}] s" if len(r) else "(none yet)"

    def correct(self, state: NavState) -> str | None:
        """Apply the corrected state of the sample at ``state.t_s`` (module docstring): kept pending
        when that sample is not integrated yet, else reset there and re-integrate the stored
        samples after it. Returns None, or a warning when it is lost (counted, nothing changed):
        older than the ring, or not at a stored sample."""
        t = float(state.t_s)
        if t > self.t_s + STAMP_TOL_S:
            self._store_reset(state)
            return None
        j = self._index(t)
        if j is None and not self._at_start(t):
            r = self.ring
            why = (f"older than the stored samples {self._span()} (ring_s {self.ring_s:g} s)" if not len(r) or t < r.t_s[0]
                   else f"not a stored IMU sample (the samples around it: {_around(r.t_s, t)})")
            return self._lose("correction", t, why)
        later = len(self.ring) - 1 - (-1 if j is None else j)
        if j is None:  # the initial state's stamp
            self.initial = NavState(self.initial.t_s, state.q_nb, state.vel_n_mps, state.llh)
            self._reintegrate_from(-1)
            t = self.initial.t_s
        else:
            self._store_reset(NavState(float(self.ring.t_s[j]), state.q_nb, state.vel_n_mps, state.llh))
            self.ring.set_nav(j, NavState(float(self.ring.t_s[j]), state.q_nb, state.vel_n_mps, state.llh))
            self._reintegrate_from(j)
            t = float(self.ring.t_s[j])
        self.corrections += 1
        self.last_correction_t_s = t
        if later > 0:
            self.corrections_late += 1
            self.late_samples += later
            self.last_late = f"correction at t={t:.6f} s after {later} sample(s) were integrated (last at t={float(self.ring.t_s[-1]):.6f} s)"
        return None

    def set_bias(self, t_s: float, gyro_radps: ArrayLike, accel_mps2: ArrayLike) -> str | None:
        """Remove this compensation (gyro [rad/s] (3,), accelerometer [m/s^2] (3,)) from the samples
        after ``t_s`` [s]: from those still to come; stored ones after it are re-integrated.
        Returns None, or a warning (counted) when it is not finite (ignored) or older than the
        ring (applied to the samples from now on only: lost for the stored ones)."""
        g = np.asarray(gyro_radps, dtype=float).reshape(3)
        a = np.asarray(accel_mps2, dtype=float).reshape(3)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(a))):
            return self._lose("IMU bias", t_s, "not finite: ignored")
        i = bisect.bisect_left(self._bias_t, t_s - STAMP_TOL_S)
        if i < len(self._bias_t) and abs(self._bias_t[i] - t_s) <= STAMP_TOL_S:
            self._bias[i] = (g, a)
        else:
            self._bias_t.insert(i, float(t_s))
            self._bias.insert(i, (g, a))
        if t_s >= self.t_s - STAMP_TOL_S:
            self.biases += 1
            return None  # no sample after it integrated yet: applied when they are
        j = self._index(t_s)
        if j is None:
            j = int(np.searchsorted(self.ring.t_s, t_s)) - 1
            if j < 0 and not (self._from_start and t_s >= self.initial.t_s - STAMP_TOL_S):
                return self._lose("IMU bias", t_s, f"older than the stored samples {self._span()}: applied to the samples from now on")
        self.biases += 1
        self.late_samples += len(self.ring) - 1 - j
        self._reintegrate_from(j)
        return None


def _around(t: FloatArray, t_s: float) -> str:
    """The stamps of ``t`` (sorted) on both sides of ``t_s``, for messages."""
    i = int(np.searchsorted(t, t_s))
    near = t[max(i - 1, 0):i + 1]
    return ", ".join(f"{x:.6f}" for x in near) + " s" if near.size else "none"


def _runs(which: NDArray[np.int64]) -> list[tuple[int, int]]:
    """[lo, hi) runs of equal values."""
    if which.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(which)) + 1
    edges = np.concatenate([[0], cuts, [which.size]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


__all__ = ["MasterMechanization", "stamp_s", "body_rate_eb", "level_from_specific_force", "initial_state_from_truth",
           "initial_state_from_list", "STAMP_TOL_S"]
