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
from numpy.typing import ArrayLike, NDArray

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import earth
from ..attitude import compose_rotvec, rotvec_to_dcm
from ..config.sensors import GYRO_AXIS_ERRORS, ImuErrorModel
from ..errors import RejectedInput
from ..ins_errors import Interval, IntervalIntegrals, nav_process_noise, propagate_nav_errors
from ..series import NavSeries
from ..strapdown import NavState, Strapdown

# indices into the full 15-state vector (and the 24 of the extended layout)
DP, DV, PHI, EPS, NAB = (slice(i, i + 3) for i in range(0, 15, 3))
N_FULL = 15
#: gyro scale factors (x, y, z) and misalignments (xy, xz, yx, yz, zx, zy) of the extended model
GAM = slice(15, 24)
N_EXT = 24
#: the paper's 13 states inside the 15 (no dh, dv_U)
IDX13 = np.array([0, 1, 3, 4, 6, 7, 8, 9, 10, 11, 12, 13, 14])


def gyro_axis_matrix(omega_radps: FloatArray) -> FloatArray:
    """``W(omega)`` (..., 3, 9) with ``Gamma omega = W(omega) gamma`` for the gyro axis errors
    ``gamma = (s_x, s_y, s_z, m_xy, m_xz, m_yx, m_yz, m_zx, m_zy)`` (``Gamma = diag(s) + offdiag(m)``,
    ``m_ij`` the rate of axis j seen by gyro i)."""
    w = np.asarray(omega_radps, dtype=float)
    W = np.zeros(w.shape[:-1] + (3, 9))
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    W[..., 0, 0], W[..., 1, 1], W[..., 2, 2] = x, y, z
    W[..., 0, 3], W[..., 0, 4] = y, z
    W[..., 1, 5], W[..., 1, 6] = x, z
    W[..., 2, 7], W[..., 2, 8] = x, y
    return W
#: the 15-state indices of (phi, dv, dp), the order of ins_errors.nav_process_noise
_NAV_ORDER = np.r_[PHI, DV, DP]


#: when the bias estimates are fed back (IfaFilterConfig.bias_feedback)
BIAS_FEEDBACK = ("auto", "aligned", "always")

R_ESTIMATORS = ("window", "changepoint")
#: [Fang2012] Table 1: the main IMU of the seed's simulation
PAPER_IFA_IMU = ImuErrorModel(gyro_bias_deg_h=0.02, gyro_noise_deg_h=0.01, accel_bias_ug=100.0, accel_noise_ug=50.0)


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
        r_estimator: ADD2 / AEKF's estimate of the GNSS noise: ``changepoint`` (default,
            :class:`~dpos_core.filters.dd2.ChangePointWindow`: each channel's variance from its
            debiased innovations since the last detected noise change, at most ``r_window_max``
            epochs, used from the first epoch on, through the fine-phase restart) or ``window``
            (eq. 22's window of ``window`` epochs, adapting only in the fine phase).  paper_ifa,
            seeds 11-16 (docs/ifa.md): final level errors 1.12-1.16x and
            heading 1.25x those of DD2 with the true GNSS sigmas (``window``: 1.6-6.7x).
        adaptive: ADD2 / AEKF adapt R from the innovations (eq. 21-23); ``False`` runs them with the
            nominal R (ADD2 is then DD2, AEKF the EKF): the controlled comparison of the two filters'
            cores with the same Q and R (docs/ifa.md, "ADD2 against AEKF").
        r_window_max, r_min_epochs, r_change_quantile: the change-point window's longest window,
            the epochs before its estimate is used (also the change-test length) and the
            two-sided chi-square quantile of its change test.
        lever_arm_coupling: include the attitude error's lever-arm term in h (module docstring).
        gnss_pos_sigma_m, gnss_vel_sigma_mps: nominal (E, N, U) GNSS noise of the filter's R.
        use_reported_sigma: take R from each fix's own sigmas instead of the nominal ones.
        position_sigma_m, velocity_sigma_mps, level_sigma_deg, heading_sigma_deg: prior 1 sigma (the
            level's at least the accelerometer bias's tilt, :attr:`level_sigma_rad`).
        imu: the main IMU's datasheet model (:class:`~dpos_core.config.sensors.ImuErrorModel`;
            default: [Fang2012] Table 1, 0.02 deg/h + 0.01 deg/h, 100 ug + 50 ug).  Turn-on biases
            are the prior sigma of the bias states; white noise (``*_noise_*`` and ARW / VRW) the
            process noise of attitude and velocity; the in-run bias instability a random walk of the
            bias states (``2 sigma^2 T / tau`` per interval, the Gauss-Markov process for ``T << tau``);
            gyro scale-factor and misalignment errors, which no state carries, attitude process
            noise proportional to the rotation of the interval (:meth:`IfaModel.Q`), so that tight
            turns of a MEMS unit widen the covariance instead of leaving it overconfident.
        q_scale: multiplies the process noise (model error of the discretization).
        coarse_heading_sigma_deg: heading 1 sigma that ends a filter's coarse phase (nominal R, no
            adaptation); the fine phase restarts the attitude / bias covariance from
            ``fine_level_sigma_deg`` (at least :attr:`fine_level_sigma_rad`) / ``fine_heading_sigma_deg`` and the sensor bias priors
            (the coarse transient of the first turn leaves overconfident bias estimates), and
            ADD2 / AEKF adapt R only there.  Also the heading difference under which two
            hypotheses count as the same solution.
        heading_hypotheses: filters in the bank (initial heading + k 360/M deg); 1 = a single filter.
        hypothesis_prune_log: drop a hypothesis whose accumulated innovation log-likelihood is
            this far below the best (pipeline.InFlightAligner).
        aligned_heading_sigma_deg: the heading 1 sigma required for ALIGNED (a floor: the
            criterion uses the larger of it and what the unit's grade can reach,
            :attr:`aligned_heading_threshold_rad`).
        nis_quantile: the windowed mean NIS must stay below this chi-square quantile.
        max_fix_bridge_s: a fix may lie this far [s] from the navigation time (before or after):
            real GNSS fixes fall anywhere between IMU samples (and samples get dropped), the
            measurement bridges the difference with the velocity (:meth:`IfaModel.measurement`);
            the error of that is ``|a| dt^2 / 2`` (4 mm at 3 m/s^2 over 50 ms).
        gnss_time_offset_s: GNSS stamps minus the IMU's time of the same instant [s] (a constant
            offset between the receiver's and the IMU's clock; subtracted from every fix stamp).
        predict_interval_s: without a fix for this long [s] of IMU data (an outage, a fix rate
            below 1 Hz), the filter makes a time update alone, so that its covariance (published
            with the navigation) grows with what the IMU alone can do.
        diverged_nis_factor, diverged_epochs: DIVERGED when the window-mean NIS, computed with the
            GNSS noise at its ceiling (``r_ceiling`` x R: a receiver noisier than modelled is only
            DEGRADED), stays above ``diverged_nis_factor`` times its consistency limit for
            ``diverged_epochs`` epochs in a row: the estimate is farther from the GNSS than its
            covariance and any plausible GNSS noise allow.
        bias_feedback: ``aligned`` ([Fang2012] sec. 3.3: the bias estimates are removed from the IMU
            samples from the alignment epoch on), ``always`` (from the first epoch: a MEMS unit's
            turn-on bias of ~0.1 m/s^2 and ~0.2 deg/s, left in the samples while aligning, makes the
            navigation drift ~5 cm and ~0.2 deg between 1 Hz fixes) or ``auto`` (the default:
            ``always`` for an IMU whose turn-on gyro bias is 1 deg/h or more or accelerometer bias
            1 mg or more (tactical grade and below), ``aligned`` for a navigation-grade one).
        gyro_axis_errors: how the gyro scale factors and misalignments enter: ``states`` (9 more
            states, 24 in all; estimated through the turns, not fed back), ``noise`` (attitude
            process noise proportional to each interval's rotation only, :meth:`IfaModel.Q`) or
            ``auto`` (the default: the IMU model's own ``gyro_axis_errors``, the grade's choice in
            its preset - ``noise`` for the MEMS presets, factory-calibrated real units, docs/sensors.md;
            with none, ``states`` when its ``gyro_scale_ppm`` or ``gyro_misalignment_mrad`` is above
            100 ppm / 0.1 mrad: 5000 ppm is 0.9 deg of heading per half turn, which white process
            noise cannot represent: it is coherent).  The rotation-proportional noise is there in
            both cases (with states: what they do not explain).
        restart_on_divergence: restart the alignment after a divergence (the bank of heading
            hypotheses again, from the latest fix's position and velocity and the current attitude).
        standstill_updates: at every GNSS epoch whose ``standstill_window_s`` of IMU samples before
            it pass the standstill test (:func:`~dpos_core.ifa.standstill.detect_standstill` with
            the IMU model's noise, ``standstill_noise_factor`` and the fix's speed), apply a
            zero-angular-rate update (ZARU about the vertical: the heading axis's gyro bias, if
            ``zaru``) and a zero-velocity one (ZUPT, ``zupt_sigma_mps``, if ``zupt``) after the fix's
            (:mod:`dpos_core.ifa.constraints`), gated by their NIS; the fine phase's restart keeps
            the vertical gyro bias the rest gave.  On by default with ZARU alone: on thor_flight75,
            walk_0827 and mems_vehicle it is no worse than off anywhere and better on the real
            recordings; ZUPT (off by default) made thor_flight75's first outage 18 % worse
            (docs/ifa.md, "ZUPT and ZARU").
        nhc: the non-holonomic constraint of a ground vehicle (lateral and vertical body velocity
            zero within ``nhc_sigma_mps``) at every GNSS epoch in motion, in the fine phase; off by
            default (aircraft, handheld): the IMU's axes must be the vehicle's.
    """

    vertical: bool = True
    window: int = 10
    r_floor: float = 1.0
    r_ceiling: float = 100.0
    adapt_diagonal: bool = True
    adapt_debias: bool = False
    r_estimator: str = "changepoint"
    adaptive: bool = True
    r_window_max: int = 30
    r_min_epochs: int = 3
    r_change_quantile: float = 0.999
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
    imu: ImuErrorModel = PAPER_IFA_IMU
    q_scale: float = 1.0
    aligned_heading_sigma_deg: float = 0.1
    nis_quantile: float = 0.999
    max_fix_bridge_s: float = 0.05
    gnss_time_offset_s: float = 0.0
    predict_interval_s: float = 1.5
    diverged_nis_factor: float = 10.0
    diverged_epochs: int = 3
    restart_on_divergence: bool = True
    bias_feedback: str = "auto"
    gyro_axis_errors: str = "auto"
    standstill_updates: bool = True
    zupt: bool = False
    zaru: bool = True
    zupt_sigma_mps: float = 0.005
    standstill_window_s: float = 1.0
    standstill_noise_factor: float = 10.0
    nhc: bool = False
    nhc_sigma_mps: float = 0.1

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
        if not (np.isfinite(self.max_fix_bridge_s) and self.max_fix_bridge_s > 0):
            raise ValueError(f"max_fix_bridge_s must be finite and > 0, got {self.max_fix_bridge_s}")
        if not (self.predict_interval_s > 0 and self.diverged_nis_factor > 1 and self.diverged_epochs >= 1):
            raise ValueError("predict_interval_s must be > 0, diverged_nis_factor > 1 and diverged_epochs >= 1")
        if self.gyro_axis_errors not in GYRO_AXIS_ERRORS:
            raise ValueError(f"gyro_axis_errors must be one of {GYRO_AXIS_ERRORS}, got {self.gyro_axis_errors!r}")
        if self.r_estimator not in R_ESTIMATORS:
            raise ValueError(f"r_estimator must be one of {R_ESTIMATORS}, got {self.r_estimator!r}")
        if not 1 <= self.r_min_epochs <= self.r_window_max:
            raise ValueError(f"need 1 <= r_min_epochs <= r_window_max, got {self.r_min_epochs} and {self.r_window_max}")
        if not 0.5 < self.r_change_quantile < 1.0:
            raise ValueError(f"r_change_quantile must be in (0.5, 1), got {self.r_change_quantile}")
        if self.bias_feedback not in BIAS_FEEDBACK:
            raise ValueError(f"bias_feedback must be one of {BIAS_FEEDBACK}, got {self.bias_feedback!r}")
        if not np.isfinite(self.gnss_time_offset_s):
            raise ValueError(f"gnss_time_offset_s must be finite, got {self.gnss_time_offset_s}")
        if not 0.0 < self.nis_quantile < 1.0:
            raise ValueError(f"nis_quantile must be in (0, 1), got {self.nis_quantile}")
        rest = (self.zupt_sigma_mps, self.standstill_window_s, self.standstill_noise_factor, self.nhc_sigma_mps)
        if not all(np.isfinite(v) and v > 0 for v in rest):
            raise ValueError("IfaFilterConfig: zupt_sigma_mps, standstill_window_s, standstill_noise_factor and nhc_sigma_mps must be finite and > 0")

    @property
    def feeds_biases_while_aligning(self) -> bool:
        """``bias_feedback`` resolved (``auto`` by the IMU's grade)."""
        if self.bias_feedback == "auto":
            return self.imu.gyro_bias_deg_h >= 1.0 or self.imu.accel_bias_ug >= 1000.0
        return self.bias_feedback == "always"

    @property
    def fine_level_sigma_rad(self) -> float:
        """Level prior of the fine phase: ``fine_level_sigma_deg``, at least twice the tilt the
        accelerometer turn-on bias alone leaves (``2 asin(b / g)``: 2.3 deg for a 20 mg MEMS unit;
        the coarse phase's level estimate is not better than that, and a tighter restart made the
        MEMS filter overconfident: attitude NEES 20-80 instead of 3 on scenario mems_vehicle)."""
        tilt = 2.0 * float(np.arcsin(min(self.imu.accel_bias_ug * 1e-6, 0.5)))
        return max(self.fine_level_sigma_deg * DEG, tilt)

    @property
    def level_sigma_rad(self) -> float:
        """The prior level 1 sigma [rad]: ``level_sigma_deg``, at least the tilt the accelerometer
        turn-on bias leaves in any levelling from specific force (``2 asin(b / g)``, 2.3 deg for a
        20 mg MEMS unit, as :attr:`fine_level_sigma_rad`): a level from accelerations is not better
        than that at rest, and a tighter prior is a per-recording guess (walk_0827 needed 3 deg
        with the former 1 deg default, #31)."""
        tilt = 2.0 * float(np.arcsin(min(self.imu.accel_bias_ug * 1e-6, 0.5)))
        return max(self.level_sigma_deg * DEG, tilt)

    @property
    def reachable_heading_sigma_rad(self) -> float:
        """The heading 1 sigma the unit's grade can reach [rad]: the heading is seen through the
        horizontal accelerations, where a heading error ``psi`` is a specific-force error ``a_h psi``
        that the accelerometer bias ``b`` (turn-on, datasheet) can mimic until manoeuvres separate
        them; with manoeuvres of ``a_h = g / 2`` (turns and accelerations of vehicles and aircraft
        are 0.1-0.5 g) ``psi = b / a_h``, i.e. ``2 asin(b / g)``: 2.3 deg for a 20 mg automotive
        MEMS unit, 0.11 deg for a 1 mg tactical one, 0.003 deg for a 25 ug navigation-grade one."""
        return 2.0 * float(np.arcsin(min(self.imu.accel_bias_ug * 1e-6, 0.5)))

    @property
    def aligned_heading_threshold_rad(self) -> float:
        """ALIGNED's heading-sigma threshold [rad]: ``max(aligned_heading_sigma_deg,
        reachable_heading_sigma_rad)`` (a MEMS unit's heading sigma never reaches the 0.1 deg a
        navigation-grade unit does: with the fixed 0.1 deg a real MEMS run never aligned, #31)."""
        return max(self.aligned_heading_sigma_deg * DEG, self.reachable_heading_sigma_rad)

    @property
    def axis_states(self) -> bool:
        """``gyro_axis_errors`` resolved."""
        if self.gyro_axis_errors == "auto":
            if self.imu.gyro_axis_errors != "auto":  # the IMU grade's choice (imu_presets.yaml)
                return self.imu.gyro_axis_errors == "states"
            return self.imu.gyro_scale_ppm > 100.0 or self.imu.gyro_misalignment_mrad > 0.1
        return self.gyro_axis_errors == "states"

    @property
    def layout(self) -> NDArray[np.intp]:
        """Indices (n,) of this model's states in the extended 24-state layout."""
        base = np.arange(N_FULL) if self.vertical else IDX13
        return np.concatenate([base, np.arange(N_FULL, N_EXT)]) if self.axis_states else base

    @property
    def n(self) -> int:
        return int(self.layout.size)

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
        self._rot_abs = np.zeros(3)  # sum of |rotation increment| per IMU axis over the interval [rad]
        self._layout = cfg.layout
        self._axis = cfg.axis_states
        self._K_gam = np.zeros((3, 9))  # int C_est W(omega) dt over the interval (gyro axis errors -> attitude)
        self.chunks: list[NavSeries] = []
        # the raw IMU samples of the last standstill_window_s (the standstill test and ZARU at an epoch)
        self._recent = (np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))

    # ------------------------------------------------------------------ embedding n <-> 24
    def full(self, x: FloatArray) -> FloatArray:
        """States (..., n) -> (..., 24) of the extended layout (zeros for the states the model
        does not carry: the vertical ones of the 13-state model, the gyro axis errors)."""
        out = np.zeros(x.shape[:-1] + (N_EXT,))
        out[..., self._layout] = x
        return out

    def reduce(self, x: FloatArray) -> FloatArray:
        """(..., 24) -> (..., n)."""
        return x[..., self._layout]

    def nav_cov15(self, P: FloatArray) -> FloatArray:
        """The (15, 15) covariance of position, velocity, attitude and biases of a covariance (n, n)
        (zero rows / columns for states the model does not carry)."""
        E = self.full(np.eye(self.n))[:, :N_FULL]  # (n, 15)
        return E.T @ P @ E

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
        rt, rw, rf = self._recent
        rt = np.r_[rt, t]
        rw = np.concatenate([rw, np.asarray(omega_radps, dtype=float).reshape(-1, 3)])
        rf = np.concatenate([rf, np.asarray(f_mps2, dtype=float).reshape(-1, 3)])
        k = rt > t[-1] - self.cfg.standstill_window_s  # (t - W, t], as standstill.start_level
        self._recent = (rt[k], rw[k], rf[k])
        start = self.strapdown.state
        dt = np.diff(np.concatenate([[start.t_s], t]))[:, None]
        om = np.asarray(omega_radps, dtype=float) - self.gyro_bias_comp
        fb = np.asarray(f_mps2, dtype=float) - self.accel_bias_comp
        chunk = self.strapdown.run_increments(t, om * dt, fb * dt)
        self.chunks.append(chunk)
        self._iv.add(start, chunk, fb, dt[:, 0])
        if self._axis:
            C = np.concatenate([start.C_nb[None], chunk.C_nb])
            C_mid = 0.5 * (C[1:] + C[:-1])
            self._K_gam = self._K_gam + np.einsum("kij,kjl->il", C_mid, gyro_axis_matrix(om) * dt[:, :, None])
        self._omega_last = om[-1]
        self._rot_abs = self._rot_abs + np.abs(om * dt).sum(axis=0)

    def recent_samples(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The raw (not bias-compensated) IMU samples of the last ``cfg.standstill_window_s``:
        t_s (W,), omega_radps (W, 3), f_mps2 (W, 3)."""
        return self._recent

    def interval(self) -> _Linearization | None:
        """Constants of ``f`` for the step since the last filter epoch (None if no time passed)."""
        return self._iv.close()

    def start_interval(self) -> None:
        """A filter epoch happened: the next interval starts at the current (corrected) state."""
        self._iv = IntervalIntegrals(self.strapdown.state)
        self._rot_abs = np.zeros(3)
        self._K_gam = np.zeros((3, 9))

    # ------------------------------------------------------------------ f, Q
    def f(self, lin: _Linearization, x: FloatArray) -> FloatArray:
        """Transition over one interval, x (..., n) -> (..., n) (eq. 24, module docstring)."""
        X = self.full(np.asarray(x, dtype=float))
        extra = X[..., GAM] @ self._K_gam.T if self._axis else None  # gyro axis errors: int C Gamma omega dt
        phi_new, dv_new, dp_new = propagate_nav_errors(X[..., PHI], X[..., DV], X[..., DP], X[..., EPS], X[..., NAB], lin, extra)
        if not self.cfg.vertical:  # 13 states: the vertical channel is slaved to the GNSS, not propagated
            dv_new[..., 2] = 0.0
            dp_new[..., 2] = X[..., DP][..., 2]
        out = X.copy()
        out[..., PHI], out[..., DV], out[..., DP] = phi_new, dv_new, dp_new
        return self.reduce(out)

    def Q(self, lin: _Linearization) -> FloatArray:
        """Process noise (n, n) of one interval, times ``q_scale``:

        * gyro / accelerometer white noise per IMU sample integrated over T (angle / velocity
          random walk, :func:`~dpos_core.ins_errors.nav_process_noise`; ``ImuErrorModel.white_sigma``);
        * bias random walk ``2 sigma_BI^2 T / tau`` on the bias states (in-run instability);
        * gyro scale factor ``s`` and misalignment ``m``: an attitude error ``s r_i`` about IMU
          axis ``i`` and ``m r_j`` from each other axis, for the rotations ``r`` (3,) [rad] the
          axes made over the interval (sum of the absolute increments): variance
          ``C diag(s^2 r_i^2 + m^2 (|r|^2 - r_i^2)) C^T`` in ENU.  Treating a per-session constant
          as white over the intervals understates its correlation but bounds the filter's
          confidence by what the unit can do in a turn.
        """
        cfg, imu = self.cfg, self.cfg.imu
        g_sig, a_sig = imu.white_sigma(self.imu_dt_s)
        Q = np.zeros((N_EXT, N_EXT))
        Q[np.ix_(_NAV_ORDER, _NAV_ORDER)] = nav_process_noise(lin.T, self.imu_dt_s, g_sig, a_sig)
        q_g, q_a = imu.bias_walk_variance(lin.T)
        Q[EPS, EPS] += np.eye(3) * q_g
        Q[NAB, NAB] += np.eye(3) * q_a
        if (imu.gyro_scale_ppm or imu.gyro_misalignment_mrad):
            r2 = self._rot_abs**2
            v = (imu.gyro_scale_ppm * 1e-6) ** 2 * r2 + (imu.gyro_misalignment_mrad * 1e-3) ** 2 * (r2.sum() - r2)
            C = self.strapdown.state.C_nb
            Q[PHI, PHI] += (C * v) @ C.T
        Q *= cfg.q_scale
        L = self._layout
        return Q[np.ix_(L, L)]

    # ------------------------------------------------------------------ measurement
    def measurement(self, fix: GnssFix) -> tuple[FloatArray, Callable[[FloatArray], FloatArray], FloatArray]:
        """``(y (p,), h: (..., n) -> (..., p), R (p, p))`` for a fix at the current nominal time
        (the fix must have passed :func:`check_fix`; a stamp up to ``cfg.max_fix_bridge_s``
        before/after the nominal is bridged with the velocity)."""
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
        C15 = np.zeros(N_EXT)  # the gyro axis errors are not fed back (0)
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
        biases from the sensor priors, no correlations (module docstring; the caller keeps the gyro
        axis errors, which are not fed back)."""
        cfg = self.cfg
        d = np.zeros(N_EXT)
        d[DP] = cfg.position_sigma_m**2
        d[DV] = cfg.velocity_sigma_mps**2
        d[PHI] = np.array([cfg.level_sigma_rad, cfg.level_sigma_rad, cfg.heading_sigma_deg * DEG]) ** 2
        if fine_from is not None:
            cur = self.full(np.diag(fine_from))
            d[DP], d[DV] = cur[DP], cur[DV]
            lvl = cfg.fine_level_sigma_rad
            d[PHI] = np.array([lvl, lvl, cfg.fine_heading_sigma_deg * DEG]) ** 2
        d[EPS] = (max(cfg.imu.gyro_bias_deg_h, 1e-6) * DEG_PER_H) ** 2
        d[NAB] = (max(cfg.imu.accel_bias_ug, 1e-3) * UG_MPS2) ** 2
        d[GAM] = np.r_[np.full(3, max(cfg.imu.gyro_scale_ppm, 1.0) * 1e-6), np.full(6, max(cfg.imu.gyro_misalignment_mrad, 1e-3) * 1e-3)] ** 2
        return np.zeros(self.n), np.diag(self.reduce(d))

    # ------------------------------------------------------------------ indices
    @property
    def phi_index(self) -> slice:
        return slice(6, 9) if self.cfg.vertical else slice(4, 7)

    @property
    def gam_index(self) -> NDArray[np.intp]:
        """Indices of the gyro axis-error states in this model's state vector (empty without them)."""
        return np.flatnonzero(self._layout >= N_FULL)

    @property
    def bias_index(self) -> tuple[slice, slice]:
        o = 9 if self.cfg.vertical else 7
        return slice(o, o + 3), slice(o + 3, o + 6)
