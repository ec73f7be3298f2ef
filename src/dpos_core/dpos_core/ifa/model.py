"""The large-heading-error model of the main POS's in-flight alignment ([Fang2012] sec. 3, eq. 24-25).

State (errors = computed - true, the paper's sign; level position in local ENU metres instead of
``dL, dlambda`` for conditioning, which only rescales the paper's states)::

    15-state (default, ``vertical=True``)         13-state ([Fang2012], ``vertical=False``)
    0:3   dp    position error E, N, U [m]        0:2   dp   E, N [m]
    3:6   dv    velocity error E, N, U [m/s]      2:4   dv   E, N [m/s]
    6:9   phi   attitude error (ENU rotation vector) 4:7 phi
    9:12  eps   gyro bias, IMU axes [rad/s]       7:10  eps
    12:15 nabla accelerometer bias [m/s^2]        10:13 nabla

Attitude error.  Eq. 24 writes the nonlinear terms with ``C_n^p`` built from Euler-type error
angles (eq. 26, small level errors, any heading error).  We use the exact rotation-vector error
of :mod:`dpos_core.ta.model`, ``C_nb_est = expm(-[phi x]) C_nb_true``, ``E = expm([phi x])`` (so
``C_n^p = E^T``): it reduces to eq. 26 for small ``phi_E, phi_N`` and any ``phi_U``, but stays
exact for large level errors too and has no Euler singularity.  The dynamics are eq. 24 with
``C_n^p - I = E^T - I``::

    phi_dot = J_r(phi)^-1 ((I - E^T) w_in + E^T dw_in - C_est eps)
    dv_dot  = (I - E) f^n + E C_est nabla - (2 w_ie + w_en) x dv - (2 dw_ie + dw_en) x v + dg
    dp_dot  = dv;    eps, nabla random constants

(``f^n = C_est f^b`` is the computed specific force; the paper's ``(C_n^p - I) C_b^n f^b`` with
``C_b^n`` the true attitude is the same term.)  ``F_1, F_2`` of eq. 24 are the ``dw_ie, dw_en``
terms in ENU metres.  Discretized over each filter interval exactly as the transfer-alignment
model: the strapdown integrates the nominal at the IMU rate, the errors are held at their start
value and the interval integrals ``int f^n dt``, ``int C_est dt`` of the nominal enter.

Vertical channel.  The seed's 13 states leave height and vertical velocity out.  A free-inertial
vertical channel diverges (positive gravity feedback, and 100 ug of vertical accelerometer bias
alone gives ~80 m in 400 s), and the paper_ifa track climbs and descends at 5 m/s, so by default
the filter carries ``dh, dv_U`` and matches the GNSS height and vertical velocity too
(15 states, 6 measurements): the vertical accelerometer bias becomes observable and the vertical
errors stay bounded by the GNSS.  With ``vertical=False`` (the paper's 13 states, 4 measurements)
the strapdown's height and vertical velocity are instead slaved to the lever-arm compensated GNSS
at every epoch (the usual external height damping).

Measurement (eq. 25 with the lever arm ``l`` from the IMU to the GNSS antenna, IMU axes)::

    z_pos = p_INS - p_GNSS + C_est l               = dp + (I - E) C_est l            + v
    z_vel = v_INS - v_GNSS + C_est (w_eb^b x l)    = dv + (I - E) C_est (w_eb^b x l) + v

in local ENU (metres, m/s).  ``(C_est - C_true) l = (I - E) C_est l`` is the lever-arm term the
attitude error leaves after compensation (about 1 m for this aircraft at a 180 deg heading
error).  By default it is left out, i.e. the paper's linear ``H = [I 0]``
(``IfaFilterConfig.lever_arm_coupling``): in level flight it makes the heading weakly and multimodally
observable through 1.5 m GNSS noise, and the Gaussian filters then pull a 100 deg-sigma heading
prior far off before the first turn (measured: ADD2 diverged on paper_ifa seed 2 from 30 deg with
it, converged without it); the neglected term is at most ~1 m at the start and vanishes as the
heading converges.

Closed loop ([Fang2012] sec. 3.3): position, velocity and attitude errors are fed back into the
strapdown after every update.  The biases stay in the state; while aligning they are not fed
back (poorly observable: feeding noisy estimates in would disturb the filter), and from the
epoch the alignment is declared on, the estimates are removed from the IMU samples (and from the
state) at every epoch.  The reset ``x -> shift(x, c)`` re-expresses the state after a correction
``c``; the attitude part ``log(expm([phi x]) expm(-[c x]))`` is nonlinear, so the filters apply
it to their covariance too (divided differences / Jacobian), not only to the mean.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import earth
from ..attitude import compose_rotvec, rotvec_to_dcm
from ..errors import RejectedInput
from ..ins_errors import Interval, IntervalIntegrals, nav_process_noise, propagate_nav_errors
from ..series import NavSeries
from ..strapdown import NavState, Strapdown

# indices into the full 15-state vector
DP, DV, PHI, EPS, NAB = (slice(i, i + 3) for i in range(0, 15, 3))
N_FULL = 15
#: the paper's 13 states inside the 15 (no dh, dv_U)
IDX13 = np.array([0, 1, 3, 4, 6, 7, 8, 9, 10, 11, 12, 13, 14])
#: the 15-state indices of (phi, dv, dp), the order of ins_errors.nav_process_noise
_NAV_ORDER = np.r_[PHI, DV, DP]


@dataclass(frozen=True)
class IfaFilterConfig:
    """Alignment settings.  Defaults: [Fang2012] Table 1 sensors, N = 10 (sec. 4).

    Attributes:
        vertical: 15 states with the vertical channel (True) or the paper's 13 (False).
        window: innovation window N of ADD2 / AEKF (eq. 22).
        r_floor: eigenvalue floor of the adapted R relative to the nominal R (dd2.guard_innovation_cov).
        r_ceiling: cap of the adapted R relative to the nominal R (10x the nominal sigma).
        adapt_diagonal: adapt only the variances of R (dd2.guard_innovation_cov ``diagonal``).
        adapt_debias: estimate R from each innovation minus its own state part
            (dd2.InnovationWindow.noise_cov) instead of the window covariance minus the current one
            (off: eq. 22-23 as printed; on was less robust on paper_ifa).
        lever_arm_coupling: include the attitude error's lever-arm term in h (module docstring).
        gnss_pos_sigma_m, gnss_vel_sigma_mps: nominal (E, N, U) GNSS noise of the filter's R.
        use_reported_sigma: take R from each fix's own sigmas instead of the nominal ones.
        position_sigma_m, velocity_sigma_mps, level_sigma_deg, heading_sigma_deg: prior 1 sigma.
        gyro_bias_deg_h, accel_bias_ug: prior bias sigma; gyro_noise_deg_h, accel_noise_ug:
            white noise per IMU sample (process noise).
        q_scale: multiplies the process noise (model error of the discretization).
        coarse_heading_sigma_deg: heading 1 sigma that ends a filter's coarse phase (nominal R, no
            adaptation); the fine phase restarts the attitude / bias covariance from
            ``fine_level_sigma_deg`` / ``fine_heading_sigma_deg`` and the sensor bias priors
            (the coarse transient of the first turn leaves overconfident bias estimates), and
            ADD2 / AEKF adapt R only there.  Also the heading difference under which two
            hypotheses count as the same solution.
        heading_hypotheses: filters in the bank (initial heading + k 360/M deg); 1 = a single filter.
        hypothesis_prune_log: drop a hypothesis whose accumulated innovation log-likelihood is
            this far below the best (pipeline.InFlightAligner).
        aligned_heading_sigma_deg: heading 1 sigma below which the alignment may be declared.
        nis_quantile: the windowed mean NIS must stay below this chi-square quantile.
    """

    vertical: bool = True
    window: int = 10
    r_floor: float = 1.0
    r_ceiling: float = 100.0
    adapt_diagonal: bool = True
    adapt_debias: bool = False
    lever_arm_coupling: bool = False
    coarse_heading_sigma_deg: float = 1.0
    fine_heading_sigma_deg: float = 3.0
    fine_level_sigma_deg: float = 0.2
    heading_hypotheses: int = 6
    hypothesis_prune_log: float = 20.0
    gnss_pos_sigma_m: tuple[float, float, float] = (1.5, 1.5, 1.5)
    gnss_vel_sigma_mps: tuple[float, float, float] = (0.03, 0.03, 0.03)
    use_reported_sigma: bool = False
    position_sigma_m: float = 5.0
    velocity_sigma_mps: float = 0.5
    level_sigma_deg: float = 1.0
    heading_sigma_deg: float = 100.0
    gyro_bias_deg_h: float = 0.02
    accel_bias_ug: float = 100.0
    gyro_noise_deg_h: float = 0.01
    accel_noise_ug: float = 50.0
    q_scale: float = 1.0
    aligned_heading_sigma_deg: float = 0.1
    nis_quantile: float = 0.999

    def __post_init__(self) -> None:
        if self.heading_hypotheses < 1:
            raise ValueError(f"heading_hypotheses must be >= 1, got {self.heading_hypotheses}")
        if self.window < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        pos = (self.r_floor, *self.gnss_pos_sigma_m, *self.gnss_vel_sigma_mps, self.position_sigma_m,
               self.velocity_sigma_mps, self.level_sigma_deg, self.heading_sigma_deg, self.q_scale,
               self.aligned_heading_sigma_deg)
        if not all(np.isfinite(v) and v > 0 for v in pos):
            raise ValueError("IfaFilterConfig: sigmas, r_floor, q_scale and thresholds must be finite and > 0")
        if not 0.0 < self.nis_quantile < 1.0:
            raise ValueError(f"nis_quantile must be in (0, 1), got {self.nis_quantile}")

    @property
    def n(self) -> int:
        return 15 if self.vertical else 13

    @property
    def p(self) -> int:
        return 6 if self.vertical else 4


@dataclass(frozen=True)
class GnssFix:
    """One GNSS fix at the antenna: t_s, llh (3,) [rad, rad, m], pos_sigma_m (3,) ENU,
    vel_n_mps (3,) ENU, vel_sigma_mps (3,)."""

    t_s: float
    llh: FloatArray
    pos_sigma_m: FloatArray
    vel_n_mps: FloatArray
    vel_sigma_mps: FloatArray


def check_fix(fix: GnssFix, last_t_s: float | None) -> None:
    """Raise :class:`~dpos_core.errors.RejectedInput` (``what="GNSS fix"``, ``reason`` code) if a
    fix cannot be used; nothing is modified.  A wrong array shape is a programming error (plain
    ``ValueError``), not a rejected fix."""
    t = fix.t_s
    if not np.isfinite(t):
        raise RejectedInput(f"GNSS fix stamp is not finite: {t}", what="GNSS fix", reason="nan")
    if last_t_s is not None and t <= last_t_s:
        kind = "duplicate" if t == last_t_s else "out-of-order"
        raise RejectedInput(f"{kind} GNSS stamp t={t} (last accepted fix at t={last_t_s})", what="GNSS fix",
                            reason=kind.replace("-", "_"), t_s=t)
    for name in ("llh", "pos_sigma_m", "vel_n_mps", "vel_sigma_mps"):
        a = np.asarray(getattr(fix, name), dtype=float)
        if a.shape != (3,):
            raise ValueError(f"GNSS fix {name} must have shape (3,), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise RejectedInput(f"GNSS fix at t={t}: {name} is not finite: {a}", what="GNSS fix", reason="nan", t_s=t)
    if not (np.all(np.asarray(fix.pos_sigma_m) > 0) and np.all(np.asarray(fix.vel_sigma_mps) > 0)):
        raise RejectedInput(f"GNSS fix at t={t}: zero or negative covariance (pos_sigma {fix.pos_sigma_m}, "
                            f"vel_sigma {fix.vel_sigma_mps}) is not a measurement", what="GNSS fix", reason="zero_cov", t_s=t)
    if abs(fix.llh[0]) > np.pi / 2 + 1e-9:
        raise RejectedInput(f"GNSS fix at t={t}: latitude {fix.llh[0]} rad out of range", what="GNSS fix",
                            reason="out_of_range", t_s=t)


_Linearization = Interval  # the interval constants of ``f`` (dpos_core.ins_errors)


class IfaModel:
    """Error-state model driving the master strapdown (module docstring).

    Usage per GNSS epoch: :meth:`propagate` the IMU samples up to the fix, :meth:`interval` gives
    ``f`` for the step since the last filter epoch, :meth:`measurement` gives ``y, h, R`` for a
    (checked) fix, :meth:`feedback` applies a correction and :meth:`shift` re-expresses states.
    """

    def __init__(self, initial: NavState, lever_arm_m: ArrayLike, cfg: IfaFilterConfig = IfaFilterConfig(), imu_dt_s: float = 0.01) -> None:
        self.cfg = cfg
        self.n, self.p = cfg.n, cfg.p
        self.lever_arm_m = np.asarray(lever_arm_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(self.lever_arm_m)):
            raise ValueError("lever arm is not finite")
        self.imu_dt_s = float(imu_dt_s)
        self.strapdown = Strapdown(initial)
        self.gyro_bias_comp = np.zeros(3)  #: removed from the IMU rates [rad/s]
        self.accel_bias_comp = np.zeros(3)  #: removed from the specific force [m/s^2]
        self.feed_biases = False
        self._iv = IntervalIntegrals(initial.copy())
        self._omega_last = np.zeros(3)  # last bias-compensated IMU rate (lever-arm velocity)
        self.chunks: list[NavSeries] = []

    # ------------------------------------------------------------------ embedding 13 <-> 15
    def full(self, x: FloatArray) -> FloatArray:
        """States (..., n) -> (..., 15) with zero vertical errors for the 13-state model."""
        if self.n == N_FULL:
            return x
        out = np.zeros(x.shape[:-1] + (N_FULL,))
        out[..., IDX13] = x
        return out

    def reduce(self, x: FloatArray) -> FloatArray:
        return x if self.n == N_FULL else x[..., IDX13]

    # ------------------------------------------------------------------ nominal
    @property
    def t_s(self) -> float:
        return self.strapdown.state.t_s

    def propagate(self, t_s: FloatArray, omega_radps: FloatArray, f_mps2: FloatArray) -> None:
        """Integrate IMU samples (mean rates over ``(t_{i-1}, t_i]``, (N,), (N, 3), (N, 3)),
        compensated by the current bias estimates, and accumulate the interval integrals."""
        t = np.asarray(t_s, dtype=float)
        if t.size == 0:
            return
        start = self.strapdown.state
        dt = np.diff(np.concatenate([[start.t_s], t]))[:, None]
        om = np.asarray(omega_radps, dtype=float) - self.gyro_bias_comp
        fb = np.asarray(f_mps2, dtype=float) - self.accel_bias_comp
        chunk = self.strapdown.run_increments(t, om * dt, fb * dt)
        self.chunks.append(chunk)
        self._iv.add(start, chunk, fb, dt[:, 0])
        self._omega_last = om[-1]

    def interval(self) -> _Linearization | None:
        """Constants of ``f`` for the step since the last filter epoch (None if no time passed)."""
        return self._iv.close()

    def start_interval(self) -> None:
        """A filter epoch happened: the next interval starts at the current (corrected) state."""
        self._iv = IntervalIntegrals(self.strapdown.state)

    # ------------------------------------------------------------------ f, Q
    def f(self, lin: _Linearization, x: FloatArray) -> FloatArray:
        """Transition over one interval, x (..., n) -> (..., n) (eq. 24, module docstring)."""
        X = self.full(np.asarray(x, dtype=float))
        phi_new, dv_new, dp_new = propagate_nav_errors(X[..., PHI], X[..., DV], X[..., DP], X[..., EPS], X[..., NAB], lin)
        if self.n != N_FULL:  # 13 states: the vertical channel is slaved to the GNSS, not propagated
            dv_new[..., 2] = 0.0
            dp_new[..., 2] = X[..., DP][..., 2]
        out = X.copy()
        out[..., PHI], out[..., DV], out[..., DP] = phi_new, dv_new, dp_new
        return self.reduce(out)

    def Q(self, lin: _Linearization) -> FloatArray:
        """Process noise (n, n) of one interval: gyro / accelerometer white noise per IMU sample
        integrated over T (angle / velocity random walk, :func:`~dpos_core.ins_errors.nav_process_noise`),
        times ``q_scale``."""
        cfg = self.cfg
        Q = np.zeros((N_FULL, N_FULL))
        Q[np.ix_(_NAV_ORDER, _NAV_ORDER)] = nav_process_noise(lin.T, self.imu_dt_s, cfg.gyro_noise_deg_h * DEG_PER_H,
                                                              cfg.accel_noise_ug * UG_MPS2)
        Q *= cfg.q_scale
        return Q[np.ix_(IDX13, IDX13)] if self.n != N_FULL else Q

    # ------------------------------------------------------------------ measurement
    def measurement(self, fix: GnssFix) -> tuple[FloatArray, Callable[[FloatArray], FloatArray], FloatArray]:
        """``(y (p,), h: (..., n) -> (..., p), R (p, p))`` for a fix at the current nominal time
        (the fix must have passed :func:`check_fix`; a stamp up to one IMU step before/after the
        nominal is bridged with the velocity)."""
        nom = self.strapdown.state
        C = nom.C_nb
        l = self.lever_arm_m
        a_p = C @ l
        w_eb = self._omega_last - C.T @ (earth.earth_rate_n(nom.llh[0]) + earth.transport_rate_n(nom.llh[0], nom.llh[2], nom.vel_n_mps))
        a_v = C @ np.cross(w_eb, l)
        d_pos = earth.enu_between(nom.llh, fix.llh) + a_p + nom.vel_n_mps * (fix.t_s - nom.t_s)
        d_vel = nom.vel_n_mps + a_v - np.asarray(fix.vel_n_mps, dtype=float)
        cfg = self.cfg
        sp = np.asarray(fix.pos_sigma_m if cfg.use_reported_sigma else cfg.gnss_pos_sigma_m, dtype=float)
        sv = np.asarray(fix.vel_sigma_mps if cfg.use_reported_sigma else cfg.gnss_vel_sigma_mps, dtype=float)
        y = np.concatenate([d_pos, d_vel])
        r = np.concatenate([sp, sv]) ** 2
        keep = np.arange(6) if cfg.vertical else np.array([0, 1, 3, 4])

        coupling = cfg.lever_arm_coupling

        def h(x: FloatArray) -> FloatArray:
            X = self.full(np.asarray(x, dtype=float))
            zp, zv = X[..., DP], X[..., DV]
            if coupling:
                I_E = np.eye(3) - rotvec_to_dcm(X[..., PHI])
                zp = zp + I_E @ a_p
                zv = zv + I_E @ a_v
            return np.concatenate([zp, zv], axis=-1)[..., keep]

        return y[keep], h, np.diag(r[keep])

    # ------------------------------------------------------------------ closed loop
    def feedback(self, mean: FloatArray, fix: GnssFix | None = None) -> FloatArray:
        """Remove the estimated navigation errors (and, once ``feed_biases``, the bias estimates)
        from the strapdown / IMU compensation; returns the applied correction (n,).  For the
        13-state model the height and vertical velocity are then set from the fix."""
        c = np.zeros(self.n)
        X = self.full(np.asarray(mean, dtype=float))
        C15 = np.zeros(N_FULL)
        C15[DP], C15[DV], C15[PHI] = X[DP], X[DV], X[PHI]
        if self.feed_biases:
            C15[EPS], C15[NAB] = X[EPS], X[NAB]
            self.gyro_bias_comp = self.gyro_bias_comp + X[EPS]
            self.accel_bias_comp = self.accel_bias_comp + X[NAB]
        dllh = earth.enu_to_dllh(C15[DP], self.strapdown.state.llh)
        self.strapdown.correct(phi_n_rad=C15[PHI], dvel_n_mps=C15[DV], dllh=dllh)
        if not self.cfg.vertical and fix is not None:
            s = self.strapdown.state
            a_p = s.C_nb @ self.lever_arm_m
            llh = s.llh.copy()
            llh[2] = fix.llh[2] - a_p[2] - s.vel_n_mps[2] * (fix.t_s - s.t_s)
            v = s.vel_n_mps.copy()
            v[2] = fix.vel_n_mps[2] - (s.C_nb @ np.cross(self._omega_last - s.C_nb.T @ earth.earth_rate_n(s.llh[0]), self.lever_arm_m))[2]
            self.strapdown.set_state(NavState(s.t_s, s.q_nb, v, llh))
        c[:] = self.reduce(C15)
        return c

    def shift(self, x: FloatArray, c: FloatArray) -> FloatArray:
        """States (..., n) re-expressed after the correction c (n,)."""
        X = self.full(np.asarray(x, dtype=float)).copy()
        Cf = self.full(np.asarray(c, dtype=float))
        X[..., PHI] = compose_rotvec(X[..., PHI], np.broadcast_to(-Cf[PHI], X[..., PHI].shape))
        for s in (DP, DV, EPS, NAB):
            X[..., s] = X[..., s] - Cf[s]
        return self.reduce(X)

    # ------------------------------------------------------------------ prior
    def prior(self, fine_from: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        """Prior mean (zeros) and covariance (n, n) from the configuration; with ``fine_from``
        (the current covariance (n, n)) the prior of the fine phase: position and velocity
        variances kept, attitude from ``fine_level_sigma_deg`` / ``fine_heading_sigma_deg``,
        biases from the sensor priors, no correlations (module docstring)."""
        cfg = self.cfg
        d = np.zeros(N_FULL)
        d[DP] = cfg.position_sigma_m**2
        d[DV] = cfg.velocity_sigma_mps**2
        d[PHI] = np.array([cfg.level_sigma_deg, cfg.level_sigma_deg, cfg.heading_sigma_deg]) ** 2 * DEG**2
        if fine_from is not None:
            cur = self.full(np.diag(fine_from))
            d[DP], d[DV] = cur[DP], cur[DV]
            d[PHI] = np.array([cfg.fine_level_sigma_deg, cfg.fine_level_sigma_deg, cfg.fine_heading_sigma_deg]) ** 2 * DEG**2
        d[EPS] = (max(cfg.gyro_bias_deg_h, 1e-6) * DEG_PER_H) ** 2
        d[NAB] = (max(cfg.accel_bias_ug, 1e-3) * UG_MPS2) ** 2
        return np.zeros(self.n), np.diag(self.reduce(d))

    # ------------------------------------------------------------------ indices
    @property
    def phi_index(self) -> slice:
        return slice(6, 9) if self.n == N_FULL else slice(4, 7)

    @property
    def bias_index(self) -> tuple[slice, slice]:
        o = 9 if self.n == N_FULL else 7
        return slice(o, o + 3), slice(o + 3, o + 6)
