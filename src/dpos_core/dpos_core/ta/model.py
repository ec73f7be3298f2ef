"""The 24-state nonlinear transfer-alignment model of a sub-IMU ([Gong2018] sec. 3, eq. 11-20).

State (errors = computed - true, as in the seed; position in local ENU metres instead of
``dL, dlambda, dh`` for conditioning)::

    0:3   phi    attitude error, rotation vector in local ENU: C_est = expm(-[phi x]) C_true
    3:6   dv     velocity error, local ENU [m/s]
    6:9   dp     position error, local ENU [m]
    9:12  eps    gyro bias, sub-IMU axes [rad/s]             (random constant)
    12:15 nabla  accelerometer bias, sub-IMU axes [m/s^2]    (random constant)
    15:18 rho    rigid misalignment, sub-IMU axes [rad]       (constant)
    18:21 theta  wing flexure, sub-IMU axes [rad]             (2nd-order Markov, eq. 13)
    21:24 theta_dot

Continuous dynamics (the paper's eq. 11 with the exact attitude error ``E = expm([phi x])``
instead of the Euler-angle matrix of eq. 12, valid for any angle):

    phi_dot = J_r(phi)^-1 ((I - E^T) w_in + E^T dw_in - C_est eps)
    dv_dot  = (I - E) f^n + E C_est nabla - (2 w_ie + w_en) x dv - (2 dw_ie + dw_en) x v + dg
    dp_dot  = dv;   eps, nabla, rho constant;   theta_ddot + 2 beta theta_dot + beta^2 theta = eta

Discretization at the filter epochs: the sub-IMU strapdown integrates the nominal trajectory at
the IMU rate; over each filter interval the error dynamics use the interval integrals of the
nominal (``int f^n dt``, ``int C_est dt``) and its mid-interval rates, with the errors held at
their start value (they change by < 1e-4 of themselves per second once the first update has
taken out the large initial misalignment); position by the trapezoid rule; the flexure block is
discretized exactly (Van Loan).  Process noise: gyro/accelerometer white noise integrated over
the interval, the in-run bias instability of the sub-IMU's model as a random walk of the bias
states (``ImuErrorModel.bias_walk_variance``; zero for the seeds' units), and the exact flexure noise.

Short sub-IMU gaps (a step longer than ``GAP_FACTOR`` nominal steps, up to ``TAConfig.max_imu_gap_s``;
longer gaps split the session, :func:`.pipeline.run_segments`): the strapdown holds the sample after
the gap across it, so the interval holding the gap gets the noise of what the IMU did not measure
(:meth:`TransferAlignmentModel._gap_noise`): per gap of length ``g``, with ``dw`` and ``df`` the
changes of the angular rate and specific force across it, an attitude 1-sigma ``|dw| g`` (twice the
hold's error ``|dw| g / 2`` when the rate changes linearly across the gap; the margin covers the
curvature of aircraft and wing motions whose time constants are seconds), a velocity 1-sigma
``|df| g`` plus what that attitude error does to the velocity over the rest of the interval
(``|f| sigma_phi tau``), the position error that velocity error builds (fully correlated), and the
white noise of one sample held for ``g`` instead of averaged over ``g / dt`` samples.  Those
intervals are listed in ``bridged_intervals`` (flag :data:`.flags.BRIDGED_GAP`).

Measurement (eq. 16-20, formed from the two attitudes instead of subtracted Euler angles):

    z_att = log( C_m C_0 C_est^T )  = log( expm(-[A theta]) expm(-[A rho]) expm([phi]) ) + v
    z_vel = v_est - v_m - C_m (w_m x r0) = dv + C_m (w_m x (k [C_0 theta] x r0) + k [C_0 theta_dot] x r0) + v
    z_pos = p_est - p_m - C_m r0         = dp + C_m (k [C_0 theta] x r0) + v     (optional, ENU metres)

[Gong2018] matches attitude and velocity only; the position match ([Ye2024] and [LSFit] use the
master's position through the lever arm too) is on by default (``TAConfig.use_position``) and
bounds the position and baseline errors by the main system's position accuracy.

with ``A = C_m C_0`` (master attitude times the nominal mount), lever arm ``r0``, and the wing's
bending lever-arm factor ``k`` (the flexure turns the lever arm, design.md "Aircraft configuration").
The closed loop: after each epoch's update the estimated navigation errors are removed from the
strapdown and the error states shifted by the applied correction.

Installation states (optional, appended after the 24; :attr:`TransferAlignmentModel.extra` names
their slices): constants that enter the matches linearly, estimated where the installation is
uncertain (``Installation.lever_arm_sigma_m``, ``Installation.time_offset_sigma_s``; docs/mismatch.md):

    dr   lever-arm survey error, master axes [m]: the true arm minus the configured r0
         z_vel += C_m (w_m x dr),  z_pos += C_m dr
    tau  time offset [s]: the sub-IMU's stamps minus the main system's time of the same instant.
         The nominal then follows the truth ``tau`` earlier than its stamp, and matching it against
         the main system at the stamp adds the motion over ``tau``:
         z_att += tau w_nb^n,  z_vel -= tau a^n,  z_pos -= tau v^n
         (w_nb^n ~ C_m w_m; a^n the nominal's acceleration over the last 0.1 s before the epoch, which
         holds the wing's vibration; v^n the sub-IMU's velocity).  The output is moved to its stamps
         by the estimate (:func:`.pipeline.shift_in_time`).

    gyro_axes, accel_axes   the sub-IMU's scale factors and misalignments ``gamma`` (the gyros' 9 in
         the order of :func:`axis_matrix`; the accelerometers' 3 scale factors and 3 symmetric
         misalignments, :data:`ACCEL_SYMMETRIC`), present with ``Installation.axis_error_states`` for the triads
         whose datasheet states them (``ImuErrorModel``
         ``*_scale_ppm``, ``*_misalignment_mrad``, which are their prior 1 sigma): over interval k
         the gyros' add ``int C_est W(omega) dt gamma_g`` to the attitude error beside the bias's
         ``C_int eps``, the accelerometers' ``int C_est W(f) dt gamma_a`` to the velocity error
         (and T/2 of it to the position error).  Within the interval the gyros' attitude error
         ``K(t) gamma_g`` (K(t) = int_0^t C_est W(omega)) meets the specific force: the velocity error
         gains ``-int [f^n x] K(t) dt gamma_g``.  Without that term (the errors held at their start
         value, as for the biases) a turn at 3 deg/s leaves 0.15 mm/s per second unexplained for 1 mrad
         of misalignment, 3x the paper sub-IMU's noise.  Both triads turned together against the
         mount rho change no match: with all 18 terms estimated, the model's small discretization
         errors read that direction as observed (on sub_imu_scale_misalignment the oracle's attitude
         errors were 2-6 of its sigmas, 0 % within 2 sigma).  So the accelerometer triad defines the
         body (its rotation, the antisymmetric part of its misalignments, is not a state), and the
         output attitude's variance gains that rotation's prior (:func:`accel_axis_rotation_var`).

    master_error   the main POS's position and velocity errors (6: ENU position, then its rate,
         the velocity error), with ``TAConfig.master_error_tau_s`` > 0: a second-order Gauss-Markov
         process per axis ([Gong2018] eq. 13's, ``beta = 2.146 / tau``) whose 1 sigma is the main
         POS's reported position sigma; the matches become ``z_vel -= e_dot``, ``z_pos -= e`` and lose
         the main POS's covariance from their noise.  The output is then the sub-IMU relative to the
         main POS (``dp - e``, ``dv - e_dot``: :func:`.pipeline._apply`), what the baselines of SAR
         processing need; its absolute sigma adds the main POS's.

The lever arm and the time offset are observable through the turns: the lever arm's ENU projection turns with the aircraft
(the U-turn reverses it) while a position error does not, and the time offset's signature grows
with the rates and accelerations while the rigid misalignment's does not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincinv

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import _error_kernel, earth
from ..attitude import compose_rotvec, cross, dcm_to_rotvec, mount_dcm, rotvec_to_dcm, skew
from ..config.flexure import K_BEND, FlexureModel
from ..config.sensors import ImuErrorModel
from ..errors import RejectedInput
from ..ifa.model import gyro_axis_matrix
from ..ins_errors import Interval, IntervalIntegrals, nav_process_noise
from ..series import GAP_FACTOR, ImuSeries, NavSeries
from ..strapdown import NavState, Strapdown
from . import _vibration_kernel

N_STATES = 24
#: variance [rad^2, rad^2/s^2] of the flexure states of an axis without flexure (held at zero:
#: :meth:`TransferAlignmentModel._flex_discrete`), their prior and per-interval noise (positive
#: definite covariances; as the prior's floor of every flexure axis)
RIGID_FLEXURE_VAR = 1e-16
PHI, DV, DP, EPS, NAB, RHO, TH, THD = (slice(i, i + 3) for i in range(0, 24, 3))
NAV = slice(0, 9)


#: (9, 6): the accelerometers' axis errors from their estimated part (s_x, s_y, s_z, a_xy, a_xz, a_yz),
#: the symmetric misalignments ``m_ij = m_ji = a_ij``; their antisymmetric part, a rotation of the
#: triad, is the one thing the matches cannot tell from the gyros' and the mount rho turned together
#: (module docstring)
ACCEL_SYMMETRIC = np.zeros((9, 6))
for _r, _c in ((0, 0), (1, 1), (2, 2), (3, 3), (5, 3), (4, 4), (7, 4), (6, 5), (8, 5)):
    ACCEL_SYMMETRIC[_r, _c] = 1.0


def accel_axis_rotation_var(imu: ImuErrorModel) -> float:
    """Variance [rad^2] per axis of the accelerometer triad's rotation against the body (the
    antisymmetric part ``(m_ij - m_ji) / 2`` of its misalignments; module docstring), which no
    match observes: the output attitude's floor with ``accel_axes``."""
    return (imu.accel_misalignment_mrad * 1e-3) ** 2 / 2.0


def axis_matrix(u: FloatArray) -> FloatArray:
    """``W(u)`` (..., 3, 9) with ``Gamma u = W(u) gamma`` for a sensor triad's axis errors
    ``gamma = (s_x, s_y, s_z, m_xy, m_xz, m_yx, m_yz, m_zx, m_zy)``: ``Gamma = diag(s) + offdiag(m)``,
    ``m_ij`` the input along axis j seen by sensor i, the measured ``(I + Gamma) u``
    (dpos_core.sim.sensors; the in-flight alignment's gyro axis errors use the same order)."""
    return gyro_axis_matrix(u)


#: master epochs further apart than this [s] are a gap of the main-system navigation (no
#: measurement in between)
MASTER_GAP_S = 0.5


def check_imu_stamps(t_s: FloatArray) -> None:
    """Sub-IMU stamps (N,) usable for alignment: ValueError for a wrong shape, RejectedInput
    (``too_short`` / ``out_of_order``) for fewer than 2 or not strictly increasing."""
    if t_s.ndim != 1:
        raise ValueError(f"sub-IMU stamps must have shape (N,), got {t_s.shape}")
    if t_s.size < 2:
        raise RejectedInput(f"{t_s.size} sub-IMU sample(s): at least 2 are needed", what="sub-IMU samples", reason="too_short")
    if np.any(np.diff(t_s) <= 0):
        raise RejectedInput("sub-IMU stamps must be strictly increasing", what="sub-IMU samples", reason="out_of_order")


def master_at(master: NavSeries, t_s: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """The master's llh (3,), velocity (3,), C_nb (3, 3) and body rate (3,) at ``t_s``: an epoch's
    own values, or interpolated between the two around it (attitude along the geodesic); None
    outside the data or between epochs more than ``MASTER_GAP_S`` apart."""
    (w,) = master.required("omega_eb_b_radps")
    m = master
    j = int(np.searchsorted(m.t_s, t_s))
    if j < m.t_s.size and abs(m.t_s[j] - t_s) < 1e-6:
        return m.llh[j], m.vel_n_mps[j], m.C_nb[j], w[j]
    if j == 0 or j >= m.t_s.size or m.t_s[j] - m.t_s[j - 1] > MASTER_GAP_S:
        return None
    a = (t_s - m.t_s[j - 1]) / (m.t_s[j] - m.t_s[j - 1])
    C = m.C_nb[j - 1] @ rotvec_to_dcm(a * dcm_to_rotvec(m.C_nb[j - 1].T @ m.C_nb[j]))
    return ((1 - a) * m.llh[j - 1] + a * m.llh[j], (1 - a) * m.vel_n_mps[j - 1] + a * m.vel_n_mps[j], C,
            (1 - a) * w[j - 1] + a * w[j])


@dataclass(frozen=True)
class Installation:
    """Where and how the sub-IMU sits: lever arm r0 (3,) in master axes, nominal mount C_0 (3, 3)
    (sub-IMU axes -> master axes), flexure statistics at its span, sensor errors, bending factor."""

    lever_arm_m: FloatArray
    C_b_s0: FloatArray
    flexure: FlexureModel
    imu: ImuErrorModel
    k_bend: float = K_BEND
    #: evaluation only (the oracle that knows the true wing): ``t -> (theta_b (3,) [rad], r_b (3,) [m],
    #: r_dot_b (3,) [m/s])``, the true flexure rotation of the sub-IMU's section and its true lever arm
    #: and lever-arm rate, master axes.  The matches then use the true deformed installation and the
    #: flexure states are held at zero (:class:`TransferAlignmentModel`)
    known_wing: Callable[[float], tuple[FloatArray, FloatArray, FloatArray]] | None = None
    #: prior 1 sigma [m] per axis of the lever arm's survey error; > 0 estimates it (3 constant
    #: states, module docstring), 0 takes the configured arm as exact
    lever_arm_sigma_m: float = 0.0
    #: prior 1 sigma [s] of the sub-IMU's time offset against the main system; > 0 estimates it (one
    #: constant state, module docstring), 0 takes the stamps as synchronized
    time_offset_sigma_s: float = 0.0
    #: estimate the sub-IMU's scale factors and misalignments that its datasheet (``imu``) states
    axis_error_states: bool = False
    #: prior 1 sigma [deg] per axis of the rigid misalignment rho: what the nominal mount
    #: (``C_b_s0``) is worth (the aircraft file's ``mount_sigma_deg``); None: ``TAConfig.rho_sigma_deg``
    rho_sigma_deg: float | None = None

    def __post_init__(self) -> None:
        for name in ("lever_arm_sigma_m", "time_offset_sigma_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0.0):
                raise ValueError(f"Installation.{name} must be finite and >= 0, got {v}")
        if self.rho_sigma_deg is not None and not (np.isfinite(self.rho_sigma_deg) and self.rho_sigma_deg > 0.0):
            raise ValueError(f"Installation.rho_sigma_deg must be finite and > 0 (or None), got {self.rho_sigma_deg}")

    @classmethod
    def from_aircraft(cls, aircraft, name: str) -> Installation:
        """Sub-IMU ``name`` as the aircraft configuration describes it: the flexure scaled to its
        span; the rigid misalignment rho is what the filter estimates, so only the nominal mount
        enters, and its ``mount_sigma_deg`` (when stated) as rho's prior 1 sigma."""

        s = aircraft.sub_imu(name)
        scale = aircraft.flexure.span_scale(s.span_m)
        flex = replace(aircraft.flexure, variance_deg2=tuple(v * scale**2 for v in aircraft.flexure.variance_deg2),
                       reference_span_m=1.0, span_exponent=0.0)
        return cls(np.asarray(s.lever_arm_m, dtype=float), mount_dcm(s.mount_rpy_deg, (0.0, 0.0, 0.0)), flex, s.imu,
                   lever_arm_sigma_m=s.lever_arm_sigma_m, time_offset_sigma_s=s.time_offset_sigma_ms * 1e-3,
                   axis_error_states=s.axis_error_states, rho_sigma_deg=s.mount_sigma_deg)


@dataclass(frozen=True)
class TAConfig:
    """Filter settings ([Gong2018] sec. 4.1.3 defaults)."""

    filter_rate_hz: float = 1.0
    attitude_sigma_deg: float = 40.0  #: prior 1 sigma of each attitude-error axis
    velocity_sigma_mps: float = 0.1
    position_sigma_m: float = 0.1
    rho_sigma_deg: float = 1.0  #: prior 1 sigma of rho per axis where the installation states none (``Installation.rho_sigma_deg``)
    bias_sigma_scale: float = 1.0  #: prior bias sigma = scale x the IMU's configured constant bias
    att_noise_floor_deg: float = 1e-4
    vel_noise_floor_mps: float = 1e-4
    use_position: bool = True  #: match the lever-arm-compensated master position too
    pos_noise_floor_m: float = 0.01  #: floor of the master position noise (lever-arm survey, antenna phase)
    #: the floor when the lever arm's survey error is a state (``Installation.lever_arm_sigma_m``): the
    #: survey no longer stands in it as white noise, the antenna phase centre and the wing's motion
    #: the model lacks remain (on paper_su, seed 2, 2 cm survey error: the arm's estimate 2.9-4.3 mm
    #: 1-sigma instead of 4.6-7.3 mm, the position error 1.3-5.4 mm instead of 4.3-9.4 mm with 1 cm)
    pos_noise_floor_estimated_arm_m: float = 0.003
    #: a sub-IMU step longer than this [s] (and than ``MIN_GAP_STEPS`` nominal steps) splits the data:
    #: each part is aligned anew from the main POS (:func:`.pipeline.run_segments`); shorter gaps are
    #: integrated across with their process noise (module docstring).  0.05 s = 5 steps at 100 Hz:
    #: the hold across a gap errs by ``alpha g^2 / 2`` for an angular acceleration ``alpha``, below the
    #: main POS's attitude noise (0.005 deg) up to alpha = 4 deg/s^2 at 0.05 s; the linear-rate model of
    #: the bridging noise holds over 0.05 s for motions with time constants of seconds (turn entries,
    #: wing flexure); a longer gap leaves the strapdown to guess the motion
    max_imu_gap_s: float = 0.05
    #: rows within this time [s] after a restart (a gap above) carry :data:`.flags.RESTARTED_AFTER_GAP`
    restart_flag_s: float = 10.0
    #: add the wing vibration the filter epochs cannot follow to the velocity and position noise
    #: (:meth:`TransferAlignmentModel.vibration_variance`)
    vibration_noise: bool = True
    #: correlation time [s] of the main POS's position and velocity errors; > 0 models them as
    #: states (second-order Gauss-Markov per ENU axis, module docstring) instead of white noise, and
    #: the output follows the main POS (its position and velocity relative to the main POS's are the
    #: estimate); 0 takes them as white
    master_error_tau_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.filter_rate_hz > 0:
            raise ValueError(f"filter_rate_hz must be > 0, got {self.filter_rate_hz}")
        if not self.max_imu_gap_s > 0:
            raise ValueError(f"max_imu_gap_s must be > 0, got {self.max_imu_gap_s}")
        if not self.restart_flag_s >= 0:
            raise ValueError(f"restart_flag_s must be >= 0, got {self.restart_flag_s}")
        if not (np.isfinite(self.master_error_tau_s) and self.master_error_tau_s >= 0):
            raise ValueError(f"master_error_tau_s must be finite and >= 0, got {self.master_error_tau_s}")


#: a gap is never shorter than this many nominal sub-IMU steps (a slow IMU's regular step is no gap)
MIN_GAP_STEPS = 3.0


def nominal_dt_s(t_s: FloatArray) -> float:
    """The nominal step [s] of stamps ``t_s`` (N,), N >= 2: the median step."""
    return float(np.median(np.diff(t_s)))


def gap_limit_s(t_s: FloatArray, cfg: TAConfig) -> float:
    """The longest sub-IMU step [s] of stamps ``t_s`` (N,) that is integrated across rather than
    splitting the data: ``max(cfg.max_imu_gap_s, MIN_GAP_STEPS x nominal step)``."""
    return max(cfg.max_imu_gap_s, MIN_GAP_STEPS * nominal_dt_s(t_s)) if t_s.size >= 2 else cfg.max_imu_gap_s


@dataclass
class _Epoch:
    y: FloatArray | None
    R: FloatArray
    A: FloatArray  # C_m C_0
    C_m: FloatArray
    w_m: FloatArray
    He: FloatArray | None = None  # (p, n - 24): the installation states' part of the matches


@dataclass
class TransferAlignmentModel:
    """The state-space model (see module docstring), driving the sub-IMU strapdown.

    One forward filter run drives it epoch by epoch (``y``/``h`` at epoch k, then ``feedback(k)``
    integrates the nominal to the next epoch); afterwards ``f(k)`` and the stored nominal are
    available for the backward pass and the output.
    """

    imu: ImuSeries  #: the sub-IMU's samples
    master: NavSeries  #: main-system navigation with omega_eb_b_radps, att_cov, vel_cov and pos_cov
    install: Installation
    cfg: TAConfig
    initial: NavState
    n: int = N_STATES
    #: the components the particle filters sample (the flexure rate, the one state driven by a noise
    #: of consequence; filters.runners); the others are carried by each particle's UKF
    sampled = THD
    epochs_s: FloatArray = field(init=False)
    n_epochs: int = field(init=False)
    #: the installation states after the 24 (module docstring): name -> slice of the state
    extra: dict[str, slice] = field(init=False)
    #: keep the nominal at the IMU rate (:meth:`nominal_chunks`); False: only the integrator's state at
    #: each epoch, the interval re-integrated from it by :meth:`nominal_chunk` (the same numbers)
    keep_nominal: bool = True
    #: keep every epoch's measurement data and every interval's transition data (False: each is dropped
    #: once the forward filter has passed it - ``feedback(k)`` drops those of epoch k - 1 and interval
    #: k - 1 -, and ``y``, ``h``, ``R``, ``f``, ``Q`` of them raise: a model for one forward pass,
    #: its memory flat with the session's length)
    keep_epoch_data: bool = True

    def __post_init__(self) -> None:
        # the master's body rate and covariances (ValueError without them)
        self._w_m, self._cov_att, self._cov_vel, self._cov_pos = self.master.required("omega_eb_b_radps", "att_cov", "vel_cov", "pos_cov")
        self.extra = {}
        i = N_STATES
        if self.install.lever_arm_sigma_m > 0:
            self.extra["lever_arm"], i = slice(i, i + 3), i + 3
        if self.install.time_offset_sigma_s > 0:
            self.extra["time_offset"], i = slice(i, i + 1), i + 1
        imu = self.install.imu
        if self.install.axis_error_states and (imu.gyro_scale_ppm > 0 or imu.gyro_misalignment_mrad > 0):
            self.extra["gyro_axes"], i = slice(i, i + 9), i + 9
        if self.install.axis_error_states and (imu.accel_scale_ppm > 0 or imu.accel_misalignment_mrad > 0):
            self.extra["accel_axes"], i = slice(i, i + 6), i + 6
        if self.cfg.master_error_tau_s > 0:
            self.extra["master_error"], i = slice(i, i + 6), i + 6
            # its 1 sigma per ENU axis: the main POS's reported position sigma (median over the session)
            sig = np.sqrt(np.median(np.diagonal(self._cov_pos, axis1=1, axis2=2), axis=0))
            v0, v1, v2 = (float(v) for v in (np.maximum(sig, 1e-4) / DEG) ** 2)  # the same process as the flexure, in metres
            self._master_gm = FlexureModel(tau_s=(self.cfg.master_error_tau_s,) * 3, variance_deg2=(v0, v1, v2),
                                           reference_span_m=1.0, span_exponent=0.0)
        self.n = i
        self._pos_floor_m = self.cfg.pos_noise_floor_estimated_arm_m if "lever_arm" in self.extra else self.cfg.pos_noise_floor_m
        self._K_axes: list[tuple[FloatArray, FloatArray, FloatArray] | None] = []  # per interval (3, 9) each: int C_est W(omega) dt, int C_est W(f) dt, L
        t_imu = self.imu.t_s
        check_imu_stamps(t_imu)
        if not np.all(np.isfinite(self.imu.omega_radps)) or not np.all(np.isfinite(self.imu.f_mps2)):
            raise RejectedInput("sub-IMU samples contain NaN or infinite values", what="sub-IMU samples", reason="nan")
        after = t_imu > self.initial.t_s + 1e-9  # samples before the first master epoch cannot be aligned
        if not after.all():
            self.imu = self.imu.select(after)
            t_imu = self.imu.t_s
            if t_imu.size < 2:
                raise RejectedInput("the sub-IMU data ends before the main-system navigation starts", what="sub-IMU samples",
                                    reason="too_short")
        if np.any(np.diff(self.master.t_s) <= 0):
            raise RejectedInput("master navigation stamps must be strictly increasing", what="master navigation", reason="out_of_order")
        t0 = self.initial.t_s
        t_end = min(t_imu[-1], self.master.t_s[-1])
        step = 1.0 / self.cfg.filter_rate_hz
        grid = t0 + step * np.arange(int(np.floor((t_end - t0) / step + 1e-9)) + 1)
        # epochs on sub-IMU sample times (the nominal exists there exactly)
        idx = np.clip(np.searchsorted(t_imu, grid - 1e-9), 0, t_imu.size - 1)
        self._epoch_idx = np.unique(np.concatenate([[-1], idx[1:]]))  # -1 = the initial state
        self.epochs_s = np.concatenate([[t0], t_imu[self._epoch_idx[1:]]])
        self.n_epochs = int(self.epochs_s.size)
        self.strapdown = Strapdown(self.initial)
        self._intervals: list[Interval | None] = []
        self._epochs: list[_Epoch | None] = [None] * self.n_epochs
        self._chunks: list[NavSeries] = []
        self._last_chunk: NavSeries | None = None  # the nominal of the last interval integrated
        self._starts: list[tuple] = []  # the integrator's state at the start of each interval (Strapdown.snapshot)
        self._nominal_at: list[NavState | None] = [self.initial.copy()]  # nominal at each epoch, before its correction
        self._flex = self.install.flexure
        self._flex_cache: dict[float, tuple[FloatArray, FloatArray]] = {}
        self._q_cache: dict[float, FloatArray] = {}
        self._imu_dt_s = nominal_dt_s(t_imu)
        self._gap_q: dict[int, FloatArray] = {}  # interval -> extra (9, 9) noise of its bridged gaps
        self._vib_gate: dict[int, float] = {}  # vibration_variance's chi^2 gate per number of main-POS epochs
        #: the intervals k (epoch k to k + 1) that contained a short gap integrated across
        self.bridged_intervals: list[int] = []
        self._forgotten = -1  # the last epoch dropped (keep_epoch_data=False)
        self._build_epoch(0)

    # ------------------------------------------------------------------ nominal / epochs
    def _master_at(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | None:
        """Master llh, velocity, C_nb, body rate (:func:`master_at`) and the attitude / velocity /
        position covariance of the epoch at or after t; None where :func:`master_at` has none."""
        at = master_at(self.master, t)
        if at is None:
            return None  # outside the master data or inside a gap: no measurement
        j = int(np.searchsorted(self.master.t_s, t))  # the epoch itself, or the one after t (as master_at)
        return (*at, self._cov_att[j], self._cov_vel[j], self._cov_pos[j])

    def _build_epoch(self, k: int) -> None:
        nom = self._nominal_at[k]
        assert nom is not None
        ms = self._master_at(float(self.epochs_s[k]))
        ins = self.install
        p = 9 if self.cfg.use_position else 6
        if ms is None:
            self._epochs[k] = _Epoch(None, np.eye(p), np.eye(3), np.eye(3), np.zeros(3), np.zeros((p, self.n - N_STATES)))
            return
        llh_m, v_m, C_m, w_m, cov_att, cov_v, cov_p = ms
        r_b, r_dot_b = ins.lever_arm_m, np.zeros(3)
        A = C_m @ ins.C_b_s0
        if ins.known_wing is not None:  # the oracle that knows the wing: the true deformed installation
            th_b, r_b, r_dot_b = ins.known_wing(float(self.epochs_s[k]))
            A = C_m @ rotvec_to_dcm(th_b) @ ins.C_b_s0
        C_est = nom.C_nb
        z_att = dcm_to_rotvec(A @ C_est.T)
        z_vel = nom.vel_n_mps - v_m - C_m @ (cross(w_m, r_b) + r_dot_b)
        # R: the main POS's covariances (its position and velocity errors are states, not noise, with
        # master_error), plus on the diagonal the noise floors, then the vibration's variance
        R = np.zeros((p, p))
        gm = "master_error" in self.extra
        R[:3, :3] = cov_att
        if not gm:
            R[3:6, 3:6] = cov_v
        vib = self.cfg.vibration_noise and ins.known_wing is None
        vib_v, vib_p = self.vibration_variance(k) if vib else (np.zeros(3), np.zeros(3))
        floor = np.empty(p)
        floor[:3] = (self.cfg.att_noise_floor_deg * DEG) ** 2
        floor[3:6] = self.cfg.vel_noise_floor_mps**2
        extra = np.zeros(p)
        extra[3:6] = vib_v
        z = [z_att, z_vel]
        if self.cfg.use_position:
            # p_est - p_m - C_m r0 in local ENU metres at the sub-IMU
            z.append(earth.enu_between(nom.llh, llh_m) - C_m @ r_b)
            if not gm:
                R[6:, 6:] = cov_p
            floor[6:] = self._pos_floor_m**2
            extra[6:] = vib_p
        d = np.arange(p)
        R[d, d] = (R[d, d] + floor) + extra
        self._epochs[k] = _Epoch(np.concatenate(z), R, A, C_m, w_m, self._installation_rows(k, p, C_m, w_m, nom.vel_n_mps))

    def _installation_rows(self, k: int, p: int, C_m: FloatArray, w_m: FloatArray, v_n: FloatArray) -> FloatArray:
        """The matches' linear part (p, n - 24) in the installation states at epoch k (module docstring)."""
        He = np.zeros((p, self.n - N_STATES))
        la = self.extra.get("lever_arm")
        if la is not None:
            j = slice(la.start - N_STATES, la.stop - N_STATES)
            He[3:6, j] = C_m @ skew(w_m)
            if p == 9:
                He[6:9, j] = C_m
        me = self.extra.get("master_error")
        if me is not None:  # the main POS reports truth + error: the matches lose it
            j0 = me.start - N_STATES
            He[3:6, j0 + 3:j0 + 6] = -np.eye(3)
            if p == 9:
                He[6:9, j0:j0 + 3] = -np.eye(3)
        to = self.extra.get("time_offset")
        if to is not None:
            j0 = to.start - N_STATES
            He[0:3, j0] = C_m @ w_m
            He[3:6, j0] = -self._nominal_accel(k)
            if p == 9:
                He[6:9, j0] = -v_n
        return He

    def _nominal_accel(self, k: int) -> FloatArray:
        """The nominal's ENU acceleration (3,) over the last 0.1 s before epoch k (zeros at epoch 0)."""
        ch = self._chunk_before(k)
        if ch is None:
            return np.zeros(3)
        t, v = ch.t_s, ch.vel_n_mps
        if t.size < 2:
            prev = self._nominal_at[k - 1]
            assert prev is not None  # (built as epoch k: k - 1 is kept until then)
            return (v[-1] - prev.vel_n_mps) / max(float(t[-1] - prev.t_s), 1e-9)
        j = max(0, min(int(np.searchsorted(t, t[-1] - 0.1)), t.size - 2))
        return (v[-1] - v[j]) / float(t[-1] - t[j])

    def _chunk_before(self, k: int) -> NavSeries | None:
        """The nominal over interval k - 1 (the one ending at epoch k), None at k = 0 or before it is
        integrated: kept, the last one integrated (as the filter builds epoch k), or re-integrated."""
        if k == 0 or k - 1 >= len(self._starts):
            return None
        if self.keep_nominal:
            return self._chunks[k - 1]
        if k == len(self._starts) and self._last_chunk is not None:
            return self._last_chunk
        return self.nominal_chunk(k - 1)

    def vibration_variance(self, k: int) -> tuple[FloatArray, FloatArray]:
        """Variance (3,) + (3,) of the velocity and position match at epoch k that the wing's
        vibration adds and the model cannot represent (ENU; zeros when none is detected).

        The model's flexure (eq. 13, a 2nd-order Gauss-Markov process with correlation times of
        seconds) has almost no power above the filter rate; a real wing's bending modes (1-6 Hz)
        move a tip IMU by centimetres at tenths of a m/s, and a match sampled once per epoch takes
        a random phase of that motion, which the filter would read as navigation error (on
        paper_wing's modal wing with the datasheet noise the rho_x estimate of the tip IMU erred by
        4.6 sigmas).  Over the interval before epoch k, at each main-POS epoch, the matching
        residuals ``v_nom - v_m - C_m (w_m x r0)`` and ``p_nom - p_m - C_m r0`` are detrended
        (a straight line: the filter's states follow that); their residual variance ``s^2``
        (N - 2 degrees of freedom) is compared with the main POS's reported noise ``sigma^2``
        (mean of its covariance diagonal, plus the noise floor): where ``s^2 / sigma^2`` exceeds the 99 % point of
        ``chi^2_{N-2} / (N - 2)`` (the main POS alone would exceed it once in 100 intervals) the
        excess ``s^2 - sigma^2`` is added to the epoch's noise.  A rigid or slowly flexing wing adds
        nothing; fewer than 6 main-POS epochs in the interval add nothing."""
        zero = (np.zeros(3), np.zeros(3))
        ch = self._chunk_before(k)
        if ch is None:
            return zero
        t0, t1 = float(self.epochs_s[k - 1]), float(self.epochs_s[k])
        m = self.master
        # the main-POS epochs in (t0, t1] (with 1e-9 s slack) covered by the chunk (stamps increasing)
        lo = max(int(np.searchsorted(m.t_s, t0 + 1e-9, side="right")), int(np.searchsorted(m.t_s, ch.t_s[0], side="left")))
        hi = min(int(np.searchsorted(m.t_s, t1 + 1e-9, side="right")), int(np.searchsorted(m.t_s, ch.t_s[-1], side="right")))
        n = hi - lo
        if n < 6:
            return zero
        j = slice(lo, hi)
        tm = m.t_s[j]
        gate = self._vib_gate.get(n)
        if gate is None:
            gate = self._vib_gate[n] = float(2.0 * gammaincinv((n - 2) / 2, 0.99)) / (n - 2)  # chi^2_{n-2} 99 % point / (n - 2)
        # the velocity and position residuals, then their variance about the straight-line fit
        # [1, t - mean t] (orthogonal columns: mean and slope), in a numba kernel
        s2, sig2 = np.empty(6), np.empty(6)  # and the main POS's mean variances
        _vibration_kernel.residual_variance(tm, ch.t_s, ch.vel_n_mps, ch.llh, m.vel_n_mps[j], m.llh[j], m.C_nb[j], self._w_m[j],
                                            np.asarray(self.install.lever_arm_m, dtype=float), self._cov_vel[j], self._cov_pos[j], s2, sig2)
        sig2[:3] += self.cfg.vel_noise_floor_mps**2
        sig2[3:] += self._pos_floor_m**2
        ex = np.where(s2 > gate * sig2, s2 - sig2, 0.0)
        return ex[:3], ex[3:]

    def _propagate(self, k: int) -> None:
        """Integrate the (corrected) nominal from epoch k to k + 1 and store the interval data."""
        i0 = self._epoch_idx[k] + 1
        i1 = self._epoch_idx[k + 1] + 1
        t = self.imu.t_s[i0:i1]
        dt = np.diff(np.concatenate([[self.epochs_s[k]], t]))[:, None]
        om, f = self.imu.omega_radps[i0:i1], self.imu.f_mps2[i0:i1]
        start = self.strapdown.state
        self._starts.append(self.strapdown.snapshot())
        chunk = self.strapdown.run_valid_increments(t, dt[:, 0], om * dt, f * dt)  # (checked in __post_init__)
        self._last_chunk = chunk
        if self.keep_nominal:
            self._chunks.append(chunk)
        acc = IntervalIntegrals(start)
        acc.add(start, chunk, f, dt[:, 0])
        interval = acc.close()
        if interval is None:  # the epochs are distinct sub-IMU sample times: some time always passes
            raise RuntimeError(f"no time passed between epochs {k} and {k + 1} (t = {self.epochs_s[k]:.6f} s)")
        self._intervals.append(interval)
        if "gyro_axes" in self.extra or "accel_axes" in self.extra:
            C = np.concatenate([start.C_nb[None], chunk.C_nb])
            C_dt = 0.5 * (C[1:] + C[:-1]) * dt[:, :, None]  # the interval integrals' midpoint rule
            dK = np.einsum("kij,kjl->kil", C_dt, axis_matrix(om))  # (m, 3, 9)
            K_mid = np.cumsum(dK, axis=0) - 0.5 * dK  # the gyro axis errors' attitude error at each step's middle
            # ... which the specific force turns into velocity within the interval (the base kernel holds the
            # attitude error at its start value): dv += -int [f^n x] K(t) dt gamma_g
            L = np.einsum("kij,kjl->il", skew(np.einsum("kij,kj->ki", C_dt, f)), K_mid)
            self._K_axes.append((dK.sum(axis=0), np.einsum("kij,kjl->il", C_dt, axis_matrix(f)) @ ACCEL_SYMMETRIC, L))
        gaps = np.nonzero(dt[:, 0] > GAP_FACTOR * self._imu_dt_s)[0]
        if gaps.size:
            self._gap_q[k] = sum((self._gap_noise(i0 + j, float(dt[j, 0]), float(self.epochs_s[k + 1] - t[j])) for j in gaps),
                                 np.zeros((9, 9)))
            self.bridged_intervals.append(k)
        self._nominal_at.append(self.strapdown.state)
        self._build_epoch(k + 1)

    # ------------------------------------------------------------------ StateSpaceModel
    def f(self, k: int, x: FloatArray) -> FloatArray:
        """The transition over interval k of states x (..., n) (numba kernel, module docstring; the
        installation states are constants)."""
        it = self._interval(k)
        rows = np.ascontiguousarray(x, dtype=float).reshape(-1, self.n)
        out = np.empty_like(rows)
        base = rows if self.n == N_STATES else np.ascontiguousarray(rows[:, :N_STATES])
        core = out if self.n == N_STATES else np.empty_like(base)
        ga, aa = self.extra.get("gyro_axes"), self.extra.get("accel_axes")
        K_axes = self._K_axes[k] if ga is not None or aa is not None else None
        gx = rows[:, ga] @ K_axes[0].T if ga is not None and K_axes is not None else np.zeros((rows.shape[0], 3))
        _error_kernel.ta_transition(base, it.kernel_consts, it.F_n, it.C_int, it.w_ie, it.w_en, it.v, self._flex_discrete(it.T)[0],
                                    np.ascontiguousarray(gx), core)
        if ga is not None or aa is not None:  # the axis errors' velocity, and the position it builds over the interval
            dv = np.zeros((rows.shape[0], 3))
            assert K_axes is not None  # (dropped with the interval)
            if ga is not None:
                dv -= rows[:, ga] @ K_axes[2].T
            if aa is not None:
                dv += rows[:, aa] @ K_axes[1].T
            core[:, DV] += dv
            core[:, DP] += 0.5 * it.T * dv
        if self.n != N_STATES:
            out[:, :N_STATES] = core
            out[:, N_STATES:] = rows[:, N_STATES:]
            me = self.extra.get("master_error")
            if me is not None:
                Phi = self._master_gm_discrete(it.T)[0]
                e, ed = rows[:, me.start:me.start + 3], rows[:, me.start + 3:me.stop]
                out[:, me.start:me.start + 3] = e * Phi[:, 0, 0] + ed * Phi[:, 0, 1]
                out[:, me.start + 3:me.stop] = e * Phi[:, 1, 0] + ed * Phi[:, 1, 1]
        return out.reshape(np.shape(x))

    def master_error_stationary_var(self) -> FloatArray:
        """The main POS's error process's stationary variance (6,): ENU position [m^2], velocity [m^2/s^2]."""
        C = self._master_gm.stationary_cov()
        return np.concatenate([C[:, 0, 0], C[:, 1, 1]])

    def _master_gm_discrete(self, T: float) -> tuple[FloatArray, FloatArray]:
        """The main POS's error process over T: transition and noise (3, 2, 2) per ENU axis, cached."""
        key = -round(T, 9) - 1.0  # beside the flexure's keys
        if key not in self._flex_cache:
            self._flex_cache[key] = self._master_gm.discrete(T)
        return self._flex_cache[key]

    def _flex_discrete(self, T: float) -> tuple[FloatArray, FloatArray]:
        """Exact flexure transition and noise (3, 2, 2) each over T, cached per interval length.

        An axis without flexure (variance 0: a sub-IMU at span 0, a rigid mount) has its two states
        held at zero: transition 0 and noise :data:`RIGID_FLEXURE_VAR` (:meth:`rigid_flexure_axes`).
        Its exact transition (a damped oscillator, ``|eig Phi| = exp(-beta T)``: 0.34 at tau = 2 s,
        T = 1 s) would leave a noise-free contracting pair of states, and every smoother's gain is
        ``Phi^-1`` there (x2.9 per epoch backwards): the rounding and Cholesky-repair noise the
        forward pass leaves in them (the UPS's particles draw the flexure rate from it) came back
        multiplied by ``2.9^K`` - 1e69 m after 150 epochs on the quad_mimu raw DOT1 log
        (docs/transfer_alignment.md)."""
        key = round(T, 9)
        if key not in self._flex_cache:
            Phi, Q = self._flex.discrete(T)
            rigid = self.rigid_flexure_axes()
            if rigid.any():
                Phi, Q = Phi.copy(), Q.copy()
                Phi[rigid] = 0.0
                Q[rigid] = np.eye(2) * RIGID_FLEXURE_VAR
            self._flex_cache[key] = (Phi, Q)
        return self._flex_cache[key]

    def rigid_flexure_axes(self) -> NDArray[np.bool_]:
        """The flexure axes (3,) without flexure (variance 0 after the span scaling): their states are
        held at zero (:meth:`_flex_discrete`)."""
        return np.asarray(self._flex.variance_deg2, dtype=float) == 0.0

    def Q(self, k: int) -> FloatArray:
        T = self._interval(k).T
        key = round(T, 9)
        if key not in self._q_cache:
            self._q_cache[key] = self._process_noise(T)
        extra = self._gap_q.get(k)
        if extra is None:
            return self._q_cache[key]
        Q = self._q_cache[key].copy()
        Q[NAV, NAV] += extra
        return Q

    def _gap_noise(self, i: int, g: float, tau: float) -> FloatArray:
        """Extra process noise (9, 9) of ``(phi, dv, dp)`` for the sub-IMU gap of ``g`` [s] ending at
        sample ``i``, held across by that sample, ``tau`` [s] before the interval's end (module docstring)."""
        imu = self.imu
        j = i - 1 if i > 0 else min(i + 1, imu.t_s.size - 1)  # the sample on the other side of the gap
        dw = float(np.linalg.norm(imu.omega_radps[i] - imu.omega_radps[j]))
        df = float(np.linalg.norm(imu.f_mps2[i] - imu.f_mps2[j]))
        sg, sa = self.install.imu.white_sigma(self._imu_dt_s)
        held = max(g * g - self._imu_dt_s * g, 0.0)  # one sample's noise held for g, not averaged over g / dt
        var_phi = (dw * g) ** 2 + sg**2 * held
        var_v = (df * g) ** 2 + sa**2 * held + (float(np.linalg.norm(imu.f_mps2[i])) * np.sqrt(var_phi) * tau) ** 2
        lever = tau + 0.5 * g  # the velocity error integrates into position over the rest of the interval
        Q = np.zeros((9, 9))
        Q[PHI, PHI] = np.eye(3) * var_phi
        Q[DV, DV] = np.eye(3) * var_v
        Q[DP, DP] = np.eye(3) * var_v * lever**2
        Q[DV, DP] = Q[DP, DV] = np.eye(3) * var_v * lever
        return Q

    def _process_noise(self, T: float) -> FloatArray:
        """Process noise (n, n) of an interval of length T (module docstring; none on the installation states)."""
        imu = self.install.imu
        Q = np.zeros((self.n, self.n))
        Q[NAV, NAV] = nav_process_noise(T, self._imu_dt_s, *imu.white_sigma(self._imu_dt_s))  # PHI, DV, DP
        q_g, q_a = imu.bias_walk_variance(T)  # the sub-IMU's in-run bias instability (0 for the seeds' units)
        Q[EPS, EPS] += np.eye(3) * q_g
        Q[NAB, NAB] += np.eye(3) * q_a
        Qf = self._flex_discrete(T)[1]
        if self.install.known_wing is not None:  # the flexure is known: its states stay at zero
            Qf = np.broadcast_to(np.eye(2) * 1e-16, Qf.shape)
        for i in range(3):
            ii = [18 + i, 21 + i]
            Q[np.ix_(ii, ii)] = Qf[i]
        me = self.extra.get("master_error")
        if me is not None:
            Qm = self._master_gm_discrete(T)[1]
            for i in range(3):
                ii = [me.start + i, me.start + 3 + i]
                Q[np.ix_(ii, ii)] = Qm[i]
        return Q

    def _interval(self, k: int) -> Interval:
        """The nominal's integrals over interval k (RuntimeError once dropped: :attr:`keep_epoch_data`)."""
        it = self._intervals[k]
        if it is None:
            raise RuntimeError(f"interval {k} is dropped: the model keeps the intervals the forward filter has passed "
                               "only with keep_epoch_data=True")
        return it

    def _forget(self, k: int) -> None:
        """Drop what the forward filter alone needs of epoch k and interval k (:attr:`keep_epoch_data`)."""
        if k < 0:
            return
        self._epochs[k] = None
        self._forgotten = max(self._forgotten, k)
        if k < len(self._intervals):
            self._intervals[k] = None
        if k < len(self._K_axes):
            self._K_axes[k] = None
        if k < len(self._nominal_at):
            self._nominal_at[k] = None

    def _epoch(self, k: int) -> _Epoch:
        """The measurement data of epoch k (built when the nominal reaches it: by the feedback of epoch k - 1)."""
        ep = self._epochs[k]
        if ep is None:
            if k <= self._forgotten:
                raise RuntimeError(f"epoch {k} is dropped: the model keeps the epochs the forward filter has passed "
                                   "only with keep_epoch_data=True")
            raise RuntimeError(f"epoch {k} is not built yet: the filter has not fed back epoch {k - 1}")
        return ep

    def y(self, k: int) -> FloatArray | None:
        return self._epoch(k).y

    def R(self, k: int) -> FloatArray:
        return self._epoch(k).R

    def h(self, k: int, x: FloatArray) -> FloatArray:
        """The matches (..., 6) or (..., 9) of epoch k for states x (..., n) (numba kernel, module docstring)."""
        ep = self._epoch(k)
        ins = self.install
        rows = np.ascontiguousarray(x, dtype=float).reshape(-1, self.n)
        p = 9 if self.cfg.use_position else 6
        out = np.empty((rows.shape[0], p))
        base = rows if self.n == N_STATES else np.ascontiguousarray(rows[:, :N_STATES])
        _error_kernel.ta_measurement(base, ep.A, ep.C_m, ep.w_m, ins.C_b_s0, ins.lever_arm_m, float(ins.k_bend), out)
        if self.n != N_STATES and ep.He is not None:
            out += rows[:, N_STATES:] @ ep.He.T
        return out.reshape(np.shape(x)[:-1] + (p,))

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        return a - b

    def feedback(self, k: int, mean: FloatArray) -> FloatArray:
        c = np.zeros(self.n)
        c[NAV] = mean[..., NAV]
        dllh = earth.enu_to_dllh(c[DP], self.strapdown.llh)
        self.strapdown.correct(phi_n_rad=c[PHI], dvel_n_mps=c[DV], dllh=dllh)
        if k + 1 < self.n_epochs:
            self._propagate(k)
        if not self.keep_epoch_data:
            self._forget(k - 1)
        return c

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        out = np.array(x, dtype=float, copy=True)
        out[..., PHI] = compose_rotvec(x[..., PHI], -c[PHI])
        out[..., DV] = x[..., DV] - c[DV]
        out[..., DP] = x[..., DP] - c[DP]
        return out

    # ------------------------------------------------------------------ priors and output
    def prior(self) -> tuple[FloatArray, FloatArray]:
        """Prior mean (zeros) and covariance (n, n) from the configuration."""
        cfg, ins = self.cfg, self.install
        d = np.zeros(self.n)
        d[PHI] = (cfg.attitude_sigma_deg * DEG) ** 2
        d[DV] = cfg.velocity_sigma_mps**2
        d[DP] = cfg.position_sigma_m**2
        d[EPS] = (max(ins.imu.gyro_bias_deg_h, 1e-6) * cfg.bias_sigma_scale * DEG_PER_H) ** 2
        d[NAB] = (max(ins.imu.accel_bias_ug, 1e-3) * cfg.bias_sigma_scale * UG_MPS2) ** 2
        d[RHO] = ((cfg.rho_sigma_deg if ins.rho_sigma_deg is None else ins.rho_sigma_deg) * DEG) ** 2
        if "lever_arm" in self.extra:
            d[self.extra["lever_arm"]] = ins.lever_arm_sigma_m**2
        if "time_offset" in self.extra:
            d[self.extra["time_offset"]] = ins.time_offset_sigma_s**2
        for name, scale_ppm, mis_mrad in (("gyro_axes", ins.imu.gyro_scale_ppm, ins.imu.gyro_misalignment_mrad),
                                          ("accel_axes", ins.imu.accel_scale_ppm, ins.imu.accel_misalignment_mrad)):
            if name in self.extra:  # the datasheet's 1 sigma; a term it leaves at 0 gets a tiny prior (it stays at 0)
                sl = self.extra[name]
                d[sl.start:sl.start + 3] = max(scale_ppm * 1e-6, 1e-9) ** 2
                # the accelerometers' symmetric parts (m_ij + m_ji) / 2 of independent m_ij: half the variance
                d[sl.start + 3:sl.stop] = max(mis_mrad * 1e-3, 1e-9) ** 2 * (0.5 if name == "accel_axes" else 1.0)
        P = np.diag(d)
        me = self.extra.get("master_error")
        if me is not None:
            Pm = self._master_gm.stationary_cov()
            for i in range(3):
                ii = [me.start + i, me.start + 3 + i]
                P[np.ix_(ii, ii)] = Pm[i]
        Pf = self._flex.stationary_cov()
        if ins.known_wing is not None:
            Pf = np.zeros_like(Pf)
        for i in range(3):  # (a rigid axis, variance 0: RIGID_FLEXURE_VAR, its noise)
            ii = [18 + i, 21 + i]
            P[np.ix_(ii, ii)] = Pf[i] + np.diag([RIGID_FLEXURE_VAR, RIGID_FLEXURE_VAR])
        return np.zeros(self.n), P

    def nominal_chunks(self) -> list[NavSeries]:
        """The nominal of every interval integrated so far (re-integrated when not kept: :attr:`keep_nominal`)."""
        return self._chunks if self.keep_nominal else [self.nominal_chunk(k) for k in range(len(self._starts))]

    def nominal_chunk(self, k: int) -> NavSeries:
        """The nominal over interval k (the rows after epoch k up to epoch k + 1): the stored one, or
        re-integrated from the integrator's state at its start with the same samples (bit for bit)."""
        if self.keep_nominal:
            return self._chunks[k]
        i0, i1 = self._epoch_idx[k] + 1, self._epoch_idx[k + 1] + 1
        t = self.imu.t_s[i0:i1]
        dt = np.diff(np.concatenate([[self.epochs_s[k]], t]))[:, None]
        sd = Strapdown(self.initial)
        sd.restore(self._starts[k])
        return sd.run_valid_increments(t, dt[:, 0], self.imu.omega_radps[i0:i1] * dt, self.imu.f_mps2[i0:i1] * dt)

    def interval_sizes(self) -> NDArray[np.intp]:
        """The rows (sub-IMU samples) of each interval integrated so far (those of :meth:`nominal_chunk`)."""
        return np.diff(self._epoch_idx)[: len(self._starts)]

    def nominal_at_epochs(self) -> list[NavState]:
        """The nominal at each epoch before its correction (index k); RuntimeError without
        :attr:`keep_epoch_data` (those the filter has passed are dropped)."""
        if not self.keep_epoch_data:
            raise RuntimeError("the nominal at the epochs is kept only with keep_epoch_data=True")
        return cast(list[NavState], self._nominal_at)
