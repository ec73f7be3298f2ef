"""The mismatch suite (docs/mismatch.md): simulated sessions whose world differs from what the transfer
alignment's configuration says.

Every other evaluation simulates exactly the filter's model.  Here each named case of
:data:`CASES` changes the *simulator's* scenario (the truth, the sensors and so the recorded
streams) while the filter keeps the nominal aircraft and scenario the recording carries.  Each
case also says what the oracle (:mod:`dpos_core.ta.oracle`, the model linearized about the truth)
is told: the true aircraft where its model can express the difference (true flexure statistics,
true lever arm, true sensor noise model), and what it cannot express (``oracle_limits``).

How a case reaches the recording:

* flexure statistics, the modal wing, the lever arm, the sub-IMU's sensor model: the truth
  scenario's aircraft (:func:`truth_scenario`), simulated by :class:`MismatchedSession` exactly as
  a nominal scenario is (:class:`~dpos_core.sim.session.SimulatedSession`);
* a sub-IMU time offset: its samples are stamped ``t + offset`` in the main system's time (its
  clock runs late), and its truth and its antennas' truth are sampled at those stamps in the main
  system's time: the product is compared with where the antenna really was at the stamp;
* the main-system reference: first-order Gauss-Markov errors (:class:`CorrelatedNavErrors`)
  instead of white noise, with the process's marginal sigmas as the reported covariance.

The filter's side is untouched: ``dpos-eval --mismatch`` passes the nominal aircraft to the
transfer alignment and embeds the nominal aircraft file in the recording's metadata.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .. import earth
from ..attitude import dcm_to_quat, quat_to_dcm
from ..config.aircraft import AircraftConfig, load_aircraft
from ..config.flexure import FlexureModel
from ..config.sensors import ImuErrorModel, imu_model
from ..frames import C_nb_from_hpr, hpr_from_C_nb, hpr_sigma_to_rotation_cov
from ..ifa import pipeline as ifa_pipeline
from ..ifa import reference as ifa_reference
from ..ifa.mechanization import body_rate_eb
from ..ifa.smoother import smooth
from ..series import ImuSeries, NavSeries
from ..sim.ar1 import ar1
from ..sim.flexure import FlexureRealization
from ..sim.scenario import Scenario
from ..sim.session import SimulatedSession
from ..units import DEG, FloatArray
from .ifa import filter_config


@dataclass(frozen=True)
class CorrelatedNavErrors:
    """Errors of a main-system navigation (an in-flight-aligned GNSS/INS), stationary from the start,
    independent per component: attitude (heading, pitch, roll) first-order Gauss-Markov; position
    (E, N, U) second-order Gauss-Markov ([Gong2018] eq. 13's process, ``beta = 2.146 / tau``) whose
    rate is the velocity error, so that position and velocity errors are those of one trajectory
    (velocity 1 sigma ``beta pos_m``, :attr:`vel_mps`).

    Attributes: 1 sigma of heading, pitch and roll [deg] and their correlation time [s]; 1 sigma of
    each ENU position component [m] and its correlation time [s].
    """

    heading_deg: float
    pitch_deg: float
    roll_deg: float
    att_tau_s: float
    pos_m: float
    pos_tau_s: float

    @property
    def vel_mps(self) -> float:
        """1 sigma of each velocity component: the position process's rate, ``2.146 / tau * pos_m``."""
        return 2.146 / self.pos_tau_s * self.pos_m

    def draw(self, t_s: FloatArray, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Errors at the (uniform) times ``t_s`` (N,): heading/pitch/roll [rad] (N, 3), velocity
        ENU [m/s] (N, 3), position ENU [m] (N, 3)."""
        dt = float(np.median(np.diff(t_s))) if t_s.size > 1 else 1.0
        att = _gauss_markov(np.array([self.heading_deg, self.pitch_deg, self.roll_deg]) * DEG, self.att_tau_s, dt, t_s.size, rng)
        # the flexure's process in other units: its "angle" [rad] is the position error [m]
        v = (self.pos_m / DEG) ** 2
        model = FlexureModel(tau_s=(self.pos_tau_s,) * 3, variance_deg2=(v, v, v), reference_span_m=1.0, span_exponent=0.0)
        pos, vel = FlexureRealization.sample(model, float(t_s[-1] - t_s[0]), dt, rng, t0_s=float(t_s[0])).at(t_s)
        return att, vel, pos


def _gauss_markov(sigma: FloatArray, tau_s: float, dt_s: float, n: int, rng: np.random.Generator) -> FloatArray:
    """(n, 3) stationary first-order Gauss-Markov samples with steady-state 1 sigma ``sigma`` (3,)."""
    a = float(np.exp(-dt_s / tau_s))
    w = rng.normal(0.0, 1.0, (n, 3)) * sigma * np.sqrt(1.0 - a * a)
    x0 = rng.normal(0.0, 1.0, 3) * sigma
    return ar1(w, a, x0)


@dataclass(frozen=True)
class MismatchCase:
    """One case of the suite.

    Attributes:
        name: the ``--mismatch`` name.
        description: what differs from the filter's configuration (one line, for the report).
        aircraft: the true aircraft from the nominal one (None: the nominal one).
        time_offset_s: the sub-IMUs' stamps minus the main system's time of the same instant.
        master_ref: the main-system reference's errors (None: the scenario's white noise).
        master_ifa: the main-system reference is the graph's own: the main IMU mechanized with the
            in-flight alignment of this method against the simulated GNSS (:meth:`MismatchedSession.ifa_reference`).
        master_ifa_smoothed: that alignment smoothed forward-backward (:func:`dpos_core.ifa.smoother.smooth`).
        oracle_limits: what the oracle's model cannot express of the case ('' = it knows all of it).
        filters: what the filters' aircraft configuration changes for this case (None: the nominal
            one): the installation states that answer a mismatch (``<case>+<states>`` cases); the
            oracle gets the same states, about the truth.
        master_error_tau_s: the filters' (and the oracle's) ``TAConfig.master_error_tau_s``.
    """

    name: str
    description: str
    aircraft: Callable[[AircraftConfig], AircraftConfig] | None = None
    time_offset_s: float = 0.0
    master_ref: CorrelatedNavErrors | None = None
    master_ifa: str | None = None
    master_ifa_smoothed: bool = False
    oracle_limits: str = ""
    filters: Callable[[AircraftConfig], AircraftConfig] | None = None
    master_error_tau_s: float = 0.0


def _flexure(scale_tau: float = 1.0, scale_var: float = 1.0) -> Callable[[AircraftConfig], AircraftConfig]:
    def f(ac: AircraftConfig) -> AircraftConfig:
        fl = ac.flexure
        (t0, t1, t2), (v0, v1, v2) = fl.tau_s, fl.variance_deg2
        return replace(ac, flexure=replace(fl, tau_s=(t0 * scale_tau, t1 * scale_tau, t2 * scale_tau),
                                           variance_deg2=(v0 * scale_var, v1 * scale_var, v2 * scale_var)))
    return f


#: the modal wing of this aircraft (paper_su_pair_modal's: 12.5 m semi-span, bending 1.0 / 6.27 Hz,
#: torsion 4 Hz, in-plane 2 Hz, 0.15/0.01/0.01 deg^2 at 5 m, 0.3 m tip deflection per g)
MODAL_WING_AIRCRAFT = "paper_su_pair_modal"


def _modal_wing(ac: AircraftConfig) -> AircraftConfig:
    modal = load_aircraft(MODAL_WING_AIRCRAFT)
    return replace(ac, wing=modal.wing, flexure=modal.flexure)


#: direction of the lever-arm survey error (unit vector, master FLU axes): equal parts on every axis,
#: outward along the span for a right-wing sub-IMU (FLU y < 0)
LEVER_ARM_ERROR_DIRECTION = np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)


def _lever_arm(error_m: float) -> Callable[[AircraftConfig], AircraftConfig]:
    """The true sub-IMU lever arms are the surveyed (nominal) ones plus ``error_m`` along
    :data:`LEVER_ARM_ERROR_DIRECTION` (mirrored in y on the left wing: outward on both)."""
    def f(ac: AircraftConfig) -> AircraftConfig:
        subs = []
        for s in ac.sub_imus:
            d = LEVER_ARM_ERROR_DIRECTION * np.array([1.0, -1.0 if s.lever_arm_m[1] > 0 else 1.0, 1.0]) * error_m
            x, y, z = (float(v) for v in np.asarray(s.lever_arm_m) + d)
            subs.append(replace(s, lever_arm_m=(x, y, z)))
        return replace(ac, sub_imus=tuple(subs))
    return f


def _states(lever_arm_sigma_m: float = 0.0, time_offset_sigma_ms: float = 0.0, axes: bool = False,
            imu: Callable[[ImuErrorModel], ImuErrorModel] | None = None) -> Callable[[AircraftConfig], AircraftConfig]:
    """The filters' aircraft with the sub-IMUs' installation states (and datasheet ``imu``)."""
    def f(ac: AircraftConfig) -> AircraftConfig:
        return replace(ac, sub_imus=tuple(replace(s, lever_arm_sigma_m=lever_arm_sigma_m, time_offset_sigma_ms=time_offset_sigma_ms,
                                                  axis_error_states=axes, imu=imu(s.imu) if imu else s.imu) for s in ac.sub_imus))
    return f


def _sub_imu(change: Callable[[ImuErrorModel], ImuErrorModel]) -> Callable[[AircraftConfig], AircraftConfig]:
    def f(ac: AircraftConfig) -> AircraftConfig:
        return replace(ac, sub_imus=tuple(replace(s, imu=change(s.imu)) for s in ac.sub_imus))
    return f


#: scale factor and axis misalignment of a tactical unit, gyro and accelerometer alike: 300 ppm
#: and 0.05 deg (0.87 mrad) per term, between the HG1700 class (gyro scale factor 150 ppm, axis
#: alignment 0.5 mrad) and the STIM300 class (scale-factor accuracy 500 ppm, misalignment 1 mrad)
SCALE_PPM = 300.0
MISALIGNMENT_MRAD = 0.05 * DEG * 1e3


def _scale_misalignment(m: ImuErrorModel) -> ImuErrorModel:
    return replace(m, gyro_scale_ppm=SCALE_PPM, accel_scale_ppm=SCALE_PPM,
                   gyro_misalignment_mrad=MISALIGNMENT_MRAD, accel_misalignment_mrad=MISALIGNMENT_MRAD)


def _tactical(m: ImuErrorModel) -> ImuErrorModel:
    return imu_model({"preset": "tactical"}, "mismatch sub_imu_tactical")


#: the main-system reference of an in-flight-aligned navigation-grade GNSS/INS with differential
#: GNSS (docs/mismatch.md says where the figures come from): the attitude sigmas of the nominal
#: white noise ([Gong2018]'s 0.005 / 0.0025 / 0.0025 deg, a navigation-grade GNSS/INS's
#: post-processed figures) correlated over 300 s; position 0.05 m (the scenario's DGNSS) correlated
#: over 20 s, whose rate is a 5.4 mm/s velocity error (the nominal 0.005 m/s)
MASTER_REF_CORRELATED = CorrelatedNavErrors(heading_deg=0.005, pitch_deg=0.0025, roll_deg=0.0025, att_tau_s=300.0,
                                            pos_m=0.05, pos_tau_s=20.0)
#: the smoothed (forward-backward) solution: half the sigmas, the same correlation times
MASTER_REF_SMOOTHED = CorrelatedNavErrors(heading_deg=0.0025, pitch_deg=0.00125, roll_deg=0.00125, att_tau_s=300.0,
                                          pos_m=0.025, pos_tau_s=20.0)

_NO_OFFSET = "the model has no time-offset state: the oracle sees the sub-IMU data at its stamps, as the filter does"
_NO_AXES = "the model has no scale-factor or misalignment states: the oracle knows the true biases and noise only"
_ACCEL_ROTATION = ("the accelerometer triad's rotation against the body (the antisymmetric part of its misalignments) "
                   "is no state of the model, for the oracle too: no match sees it; it is in the output attitude's sigma")
_NO_REF = "the model takes the main-system errors as white: the oracle is told their true marginal sigmas, not their correlation"

CASES: dict[str, MismatchCase] = {c.name: c for c in (
    MismatchCase("nominal", "no mismatch (the reference row)"),
    MismatchCase("flexure_tau_x0.5", "true flexure correlation times half the configured ones", _flexure(scale_tau=0.5)),
    MismatchCase("flexure_tau_x2", "true flexure correlation times twice the configured ones", _flexure(scale_tau=2.0)),
    MismatchCase("flexure_var_x0.5", "true flexure variances half the configured ones", _flexure(scale_var=0.5)),
    MismatchCase("flexure_var_x2", "true flexure variances twice the configured ones", _flexure(scale_var=2.0)),
    MismatchCase("modal_wing", f"the wing bends like a wing ({MODAL_WING_AIRCRAFT}'s modes, load-dependent bending)", _modal_wing,
                 oracle_limits="the oracle's flexure is the Gauss-Markov model with the modes' variances; it knows the "
                               "true flexure angle at each epoch, not the modes"),
    MismatchCase("time_offset_1ms", "sub-IMU stamps 1 ms late against the main system", time_offset_s=0.001, oracle_limits=_NO_OFFSET),
    MismatchCase("time_offset_5ms", "sub-IMU stamps 5 ms late against the main system", time_offset_s=0.005, oracle_limits=_NO_OFFSET),
    MismatchCase("time_offset_20ms", "sub-IMU stamps 20 ms late against the main system", time_offset_s=0.020, oracle_limits=_NO_OFFSET),
    MismatchCase("lever_arm_1cm", "sub-IMU lever arm surveyed 1 cm wrong (0.58 cm per axis)", _lever_arm(0.01)),
    MismatchCase("lever_arm_2cm", "sub-IMU lever arm surveyed 2 cm wrong (1.15 cm per axis)", _lever_arm(0.02)),
    MismatchCase("sub_imu_scale_misalignment",
                 f"sub-IMU scale factors {SCALE_PPM:g} ppm and axis misalignments {MISALIGNMENT_MRAD:.2f} mrad (1 sigma, gyro and accel)",
                 _sub_imu(_scale_misalignment), oracle_limits=_NO_AXES),
    MismatchCase("sub_imu_tactical", "sub-IMUs of tactical MEMS grade (imu_presets.yaml tactical) instead of the paper's",
                 _sub_imu(_tactical), oracle_limits=_NO_AXES),
    MismatchCase("master_ref_correlated", "main-system reference with Gauss-Markov errors of a GNSS/INS (filtered)",
                 master_ref=MASTER_REF_CORRELATED, oracle_limits=_NO_REF),
    MismatchCase("master_ref_ifa", "main-system reference = the graph's own in-flight-aligned GNSS/INS (ADD2, forward filter)",
                 master_ifa="add2", oracle_limits=_NO_REF.replace("true marginal sigmas", "IFA's reported covariance")),
    MismatchCase("master_ref_ifa_smoothed", "main-system reference = the graph's own in-flight alignment (ADD2) smoothed "
                 "forward-backward (dpos-process --master-reference smoothed)", master_ifa="add2", master_ifa_smoothed=True,
                 oracle_limits=_NO_REF.replace("true marginal sigmas", "smoother's reported covariance")),
    MismatchCase("master_ref_smoothed", "main-system reference with Gauss-Markov errors of a smoothed GNSS/INS",
                 master_ref=MASTER_REF_SMOOTHED, oracle_limits=_NO_REF),
    # the installation states (dpos_core.ta.model) configured as a user who knows the uncertainty would
    MismatchCase("nominal+states", "no mismatch; filters estimate a 10 ms time offset and a 1 cm lever-arm survey error "
                 "(the cost of the states)", filters=_states(lever_arm_sigma_m=0.01, time_offset_sigma_ms=10.0)),
    MismatchCase("time_offset_5ms+state", "sub-IMU stamps 5 ms late; filters estimate the offset (prior 10 ms)",
                 time_offset_s=0.005, filters=_states(time_offset_sigma_ms=10.0)),
    MismatchCase("time_offset_20ms+state", "sub-IMU stamps 20 ms late; filters estimate the offset (prior 10 ms)",
                 time_offset_s=0.020, filters=_states(time_offset_sigma_ms=10.0)),
    MismatchCase("lever_arm_1cm+state", "lever arm surveyed 1 cm wrong; filters estimate it (prior 1 cm per axis)", _lever_arm(0.01),
                 filters=_states(lever_arm_sigma_m=0.01)),
    MismatchCase("lever_arm_2cm+state", "lever arm surveyed 2 cm wrong; filters estimate it (prior 2 cm per axis)", _lever_arm(0.02),
                 filters=_states(lever_arm_sigma_m=0.02)),
    MismatchCase("sub_imu_scale_misalignment+states", "sub-IMU axis errors as above; filters given the datasheet and its "
                 "axis-error states", _sub_imu(_scale_misalignment), filters=_states(axes=True, imu=_scale_misalignment),
                 oracle_limits=_ACCEL_ROTATION),
    MismatchCase("master_ref_correlated+states", "main-system reference with Gauss-Markov errors (filtered); filters "
                 "estimate them (correlation time 20 s) and follow the main POS", master_ref=MASTER_REF_CORRELATED,
                 master_error_tau_s=MASTER_REF_CORRELATED.pos_tau_s),
    MismatchCase("master_ref_smoothed+states", "main-system reference with Gauss-Markov errors (smoothed); filters "
                 "estimate them (correlation time 20 s) and follow the main POS", master_ref=MASTER_REF_SMOOTHED,
                 master_error_tau_s=MASTER_REF_SMOOTHED.pos_tau_s),
    MismatchCase("master_ref_ifa+states", "main-system reference = the graph's own in-flight alignment (ADD2); filters "
                 "estimate its errors (correlation time 20 s) and follow the main POS", master_ifa="add2", master_error_tau_s=20.0),
    MismatchCase("sub_imu_tactical+states", "tactical sub-IMUs; filters given the tactical datasheet and its axis-error states",
                 _sub_imu(_tactical), filters=_states(axes=True, imu=_tactical), oracle_limits=_ACCEL_ROTATION),
)}


def case_names(text: str) -> list[str]:
    """``CASE[,CASE...]`` or ``all`` -> the case names; ValueError naming the unknown ones and
    listing the valid ones."""
    if text.strip() == "all":
        return list(CASES)
    names = [c.strip() for c in text.split(",") if c.strip()]
    bad = [c for c in names if c not in CASES]
    if bad or not names:
        raise ValueError(f"unknown mismatch case(s) {bad or [text]}; valid: all, {', '.join(CASES)}")
    return names


def truth_scenario(case: MismatchCase, nominal: Scenario) -> Scenario:
    """The scenario the simulator flies for ``case`` (the filter keeps ``nominal``)."""
    return nominal if case.aircraft is None else replace(nominal, aircraft=case.aircraft(nominal.aircraft))


class MismatchedSession(SimulatedSession):
    """A simulated session of the truth scenario with a sub-IMU time offset and correlated
    main-system errors (module docstring).  The random streams are the nominal session's, so a
    case differs from the nominal run of the same seed by its mismatch alone (a sensor model
    with more terms draws more from its stream)."""

    def __init__(self, scenario: Scenario, seed: int, duration_s: float | None = None, *, time_offset_s: float = 0.0,
                 master_ref: CorrelatedNavErrors | None = None, master_ifa: str | None = None,
                 master_ifa_smoothed: bool = False) -> None:
        super().__init__(scenario, seed, duration_s)
        if not 0.0 <= time_offset_s < 0.5:
            raise ValueError(f"time_offset_s must be in [0, 0.5) s, got {time_offset_s}")
        self.time_offset_s = float(time_offset_s)
        self.master_ref = master_ref
        self.master_ifa = master_ifa
        self.master_ifa_smoothed = master_ifa_smoothed
        self._ifa_nav: NavSeries | None = None
        self._ifa_smoothed: NavSeries | None = None

    def _offset(self, t: FloatArray) -> FloatArray:
        """Stamps ``t + offset`` that stay inside the session."""
        s = t + self.time_offset_s
        return s[s <= self.duration_s + 1e-9]

    def truth(self, body: str, t_s: FloatArray | None = None) -> NavSeries:
        if t_s is None and self.time_offset_s and body.startswith(("sub_imu/", "antenna/")):
            t_s = self._offset(self.sample_times(self._rate(body), include_start=True))
        return super().truth(body, t_s)

    def sub_imu(self, name: str) -> ImuSeries:
        imu = super().sub_imu(name)
        if not self.time_offset_s:
            return imu
        t = imu.t_s + self.time_offset_s
        keep = t <= self.duration_s + 1e-9
        return ImuSeries(t[keep], imu.omega_radps[keep], imu.f_mps2[keep])

    def ifa_reference(self, smoothed: bool = False) -> NavSeries:
        """The main-system navigation as the graph makes it (pos_master_node with ``alignment: ifa``):
        the simulated main IMU and GNSS through :func:`dpos_core.ifa.pipeline.run` (method
        ``master_ifa``, the scenario's filter configuration :func:`dpos_core.evaluation.ifa.filter_config`),
        started by the real-recording rule (:func:`dpos_core.ifa.reference.initial_state`: course over
        ground, levelled from the specific force); at every IMU sample the closed-loop state, the body
        rate from the bias-compensated gyro, and the covariances of the latest filter epoch before it
        (pos_master_node's rule; before the first: 100 deg, 10 m, 1 m/s, i.e. unaligned).
        ``smoothed``: the same run smoothed forward-backward (:func:`dpos_core.ifa.smoother.smooth`,
        what ``dpos-process --master-reference smoothed`` uses), with the smoother's covariances."""
        if self._ifa_nav is not None and (not smoothed or self._ifa_smoothed is not None):
            return self._ifa_smoothed if smoothed and self._ifa_smoothed is not None else self._ifa_nav

        imu, gnss = self.master_imu(), self.gnss()
        lever = np.asarray(self.scenario.aircraft.gnss_lever_arm_m, dtype=float)
        init = ifa_reference.initial_state(imu, gnss, lever_arm_m=lever)
        res = ifa_pipeline.run(imu, gnss, lever, filter_config(self.scenario), self.master_ifa or "add2", init,
                               record_smoother=smoothed)
        if smoothed:
            self._ifa_smoothed = smooth(res, imu).nav
        t = res.t_s
        idx = np.clip(np.searchsorted(imu.t_s, t - 1e-9), 0, imu.t_s.size - 1)
        w_eb = body_rate_eb(res.q_nb, res.llh, res.vel_n_mps, imu.omega_radps[idx] - res.gyro_bias_radps)
        t_ep = np.array([x[0] for x in res.track])
        P = np.array([x[1] for x in res.track]).reshape(-1, 9, 9)
        P0 = np.diag(np.r_[np.full(3, 10.0**2), np.full(3, 1.0), np.full(3, (100.0 * DEG) ** 2)])
        blocks = np.concatenate([P0[None], P])
        k = np.searchsorted(t_ep, t - 1e-6, side="left")  # 0: before the first epoch (P0), else track k-1
        Pk = blocks[k]
        self._ifa_nav = NavSeries(t, res.q_nb, res.vel_n_mps, res.llh, omega_eb_b_radps=w_eb,
                                  att_cov=Pk[:, 6:9, 6:9].copy(), vel_cov=Pk[:, 3:6, 3:6].copy(), pos_cov=Pk[:, 0:3, 0:3].copy())
        return self._ifa_smoothed if smoothed and self._ifa_smoothed is not None else self._ifa_nav

    def master_nav_reference(self) -> NavSeries:
        if self.master_ifa is not None:
            return self.ifa_reference(self.master_ifa_smoothed)
        if self.master_ref is None:
            return super().master_nav_reference()
        g = self.master_ref
        tr = self.truth("master", self.sample_times(self.scenario.rates.master_nav_hz, include_start=True))
        d_att, d_vel, d_pos = g.draw(tr.t_s, self.rng("nav/master/correlated"))
        n = tr.t_s.shape[0]
        hpr = hpr_from_C_nb(tr.C_nb) + d_att
        q = dcm_to_quat(C_nb_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2]))
        att_sig = np.array([g.heading_deg, g.pitch_deg, g.roll_deg]) * DEG
        return NavSeries(tr.t_s, q, tr.vel_n_mps + d_vel, tr.llh + earth.enu_to_dllh(d_pos, tr.llh),
                         omega_eb_b_radps=tr.omega_eb_b_radps,
                         att_cov=hpr_sigma_to_rotation_cov(quat_to_dcm(q), att_sig),
                         vel_cov=np.broadcast_to(np.eye(3) * g.vel_mps**2, (n, 3, 3)).copy(),
                         pos_cov=np.broadcast_to(np.eye(3) * g.pos_m**2, (n, 3, 3)).copy())


def simulate(case: MismatchCase, nominal: Scenario, seed: int, duration_s: float | None = None) -> MismatchedSession:
    """The session of ``case`` for ``seed``: the truth scenario with the case's offset and reference."""
    return MismatchedSession(truth_scenario(case, nominal), seed, duration_s, time_offset_s=case.time_offset_s,
                             master_ref=case.master_ref, master_ifa=case.master_ifa, master_ifa_smoothed=case.master_ifa_smoothed)
