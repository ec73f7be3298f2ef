"""A simulated session: every sensor stream and every truth of a scenario, for one seed.

Each component (master IMU, each sub-IMU, GNSS, reference navigation, each wing's flexure) draws
from its own random stream, keyed by the seed and the component's name, and is generated on
demand.  So the bag writer, the master device node and every sub-IMU device node compute
bit-identical samples for the same scenario and seed, whatever else they generate.

Sampling: an IMU sample stamped ``t_k = k / f`` (k = 1..N) carries the mean angular rate and
specific force over ``(t_{k-1}, t_k]`` (increment / T, as a high-grade IMU outputs); navigation
and truth samples are instantaneous at their stamps; GNSS fixes at ``i / f_gnss`` (i >= 1).
Times are scenario seconds from the start; ``scenario.start_time_s`` is the stamp epoch.
"""

from __future__ import annotations

import zlib
from functools import cached_property

import numpy as np

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..attitude import dcm_to_quat, mount_dcm, quat_to_dcm
from ..frames import C_nb_from_hpr, hpr_from_C_nb, hpr_sigma_to_rotation_cov
from ..kinematics import Motion, increments_from_motion, nav_from_ecef
from ..series import GnssSeries, ImuSeries, NavSeries
from .bodies import deformed_body_motion, flexed_body_motion, rigid_offset_motion
from .flexure import FlexureRealization, ModalRealization, load_factor
from .flight import Flight
from .scenario import Scenario
from .sensors import draw_axes_errors, draw_biases, measure


class SimulatedSession:
    """Lazily generated streams of one scenario and seed (see module docstring)."""

    def __init__(self, scenario: Scenario, seed: int, duration_s: float | None = None) -> None:
        if duration_s is not None and duration_s > scenario.duration_s:
            raise ValueError(f"duration {duration_s} s exceeds the scenario's {scenario.duration_s} s")
        self.scenario = scenario.with_duration(duration_s)
        self.seed = int(seed)
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self._flexure: dict[int, FlexureRealization | ModalRealization] = {}

    # ------------------------------------------------------------------ basics
    @property
    def duration_s(self) -> float:
        return self.scenario.duration_s

    @property
    def datum_llh(self) -> FloatArray:
        return self.scenario.datum_llh

    @cached_property
    def flight(self) -> Flight:
        return self.scenario.flight()

    def rng(self, component: str) -> np.random.Generator:
        """Independent random stream of a component (stable across processes and versions)."""
        return np.random.default_rng(np.random.SeedSequence([self.seed, zlib.crc32(component.encode())]))

    def sample_times(self, rate_hz: float, include_start: bool = False) -> FloatArray:
        n = int(np.floor(self.duration_s * rate_hz + 1e-9))
        k = np.arange(0 if include_start else 1, n + 1)
        return k / rate_hz

    # ------------------------------------------------------------------ bodies
    def flexure(self, side: int) -> FlexureRealization | ModalRealization:
        """Flexure of the right (+1) or left (-1) wing: the aircraft's modal wing (its quasi-static
        bending following this flight's load factor) if it has one, else its Gauss-Markov flexure.

        Sampled on the sub-IMU sample grid: within every IMU interval the interpolated flexure is
        then one smooth cubic, so the quadrature of the increments stays exact (a grid node inside
        an interval, where the white-noise-driven theta_ddot jumps, costs ~1e-7 rad per sample).
        """
        wing = self.scenario.aircraft.wing
        if side not in self._flexure and wing is not None:
            self._flexure[side] = ModalRealization.sample(
                wing, side, self.duration_s, 1.0 / self.scenario.rates.sub_imu_hz,
                self.rng("flexure/right" if side > 0 else "flexure/left"), load=load_factor(self.flight))
        elif side not in self._flexure:
            self._flexure[side] = FlexureRealization.sample(
                self.scenario.aircraft.flexure, self.duration_s, 1.0 / self.scenario.rates.sub_imu_hz,
                self.rng("flexure/right" if side > 0 else "flexure/left"),
            )
        return self._flexure[side]

    def _flexed_motion(self, lever_arm_m, C_b_s0, span_m: float) -> Motion:
        """A body on the wing at ``span_m``: on the modal wing, or on the Gauss-Markov flexure."""
        if self.scenario.aircraft.wing is not None and span_m != 0.0:
            fr = self.flexure(1 if span_m > 0 else -1)
            assert isinstance(fr, ModalRealization)
            return deformed_body_motion(self.flight.ecef_motion, lever_arm_m, C_b_s0, lambda t: fr.deformation(t, span_m))
        return flexed_body_motion(self.flight.ecef_motion, lever_arm_m, C_b_s0, self._flex_at(span_m))

    def _flex_at(self, span_m: float):
        if span_m == 0.0 or not np.any(np.asarray(self.scenario.aircraft.flexure.variance_deg2) > 0):
            return None
        fr = self.flexure(1 if span_m > 0 else -1)
        return lambda t: fr.at(t, span_m)

    def motion(self, body: str) -> Motion:
        """``master``, ``gnss``, ``sub_imu/<name>`` or ``antenna/<name>``."""
        ac = self.scenario.aircraft
        if body == "master":
            return self.flight.ecef_motion
        if body == "gnss":
            return rigid_offset_motion(self.flight.ecef_motion, ac.gnss_lever_arm_m)
        kind, _, name = body.partition("/")
        if kind == "sub_imu":
            s = ac.sub_imu(name)
            return self._flexed_motion(s.lever_arm_m, mount_dcm(s.mount_rpy_deg, s.rho_deg), s.span_m)
        if kind == "antenna":
            for a in ac.antennas:
                if a.name == name:
                    if a.sub_imu is not None:
                        return rigid_offset_motion(self.motion(f"sub_imu/{a.sub_imu}"), a.lever_arm_m)
                    # no IMU: a wing section at the antenna's span, flexing with the wing, no mount error
                    return self._flexed_motion(a.lever_arm_m, np.eye(3), a.span_m)
            raise KeyError(f"no antenna {name!r} in aircraft {ac.name!r}")
        raise KeyError(f"unknown body {body!r}")

    def bodies(self) -> list[str]:
        ac = self.scenario.aircraft
        return ["master"] + [f"sub_imu/{s.name}" for s in ac.sub_imus] + [f"antenna/{a.name}" for a in ac.antennas]

    # ------------------------------------------------------------------ truth
    def truth(self, body: str, t_s: FloatArray | None = None) -> NavSeries:
        """Truth navigation of a body at times t (default: its sensor rate)."""
        if t_s is None:
            t_s = self.sample_times(self._rate(body), include_start=True)
        t = np.asarray(t_s, dtype=float)
        p, v, C, w = self.motion(body)(t)
        llh, vel, C_nb = nav_from_ecef(p, v, C)
        return NavSeries(t, dcm_to_quat(C_nb), vel, llh, omega_eb_b_radps=w)

    # ------------------------------------------------------------------ sensors
    def _rate(self, body: str) -> float:
        r = self.scenario.rates
        return r.master_imu_hz if body in ("master", "gnss") else r.sub_imu_hz

    def ideal_imu(self, body: str) -> ImuSeries:
        """Error-free IMU output of a body (``master`` or ``sub_imu/<name>``) at its rate."""
        t = self.sample_times(self._rate(body), include_start=True)
        dth, dv = increments_from_motion(self.motion(body), t)
        T = np.diff(t)[:, None]
        return ImuSeries(t[1:], dth / T, dv / T)

    def _imu(self, body: str, rate_hz: float, model, component: str, jitter_s: float = 0.0, drop_fraction: float = 0.0) -> ImuSeries:
        t = self.sample_times(rate_hz, include_start=True)
        if jitter_s > 0.0:  # real timing (Rates): own generator, so the errors below are the same draws
            t = t.copy()
            t[1:] += self.rng(f"{component}/timing").uniform(-jitter_s, jitter_s, t.size - 1)
        dth, dv = increments_from_motion(self.motion(body), t)
        rng = self.rng(component)
        biases = draw_biases(model, rng)
        axes = draw_axes_errors(model, rng)
        om, f = measure(model, dth, dv, np.diff(t), biases, rng, axes)
        imu = ImuSeries(t[1:], om, f)
        if drop_fraction > 0.0:
            imu = imu.select(self.rng(f"{component}/drops").random(t.size - 1) >= drop_fraction)
        return imu

    def master_imu(self) -> ImuSeries:
        """The main IMU's samples, with the scenario's real-device timing (``Rates``): jittered
        stamps, lost samples."""
        r = self.scenario.rates
        return self._imu("master", r.master_imu_hz, self.scenario.master_imu, "imu/master", r.master_imu_jitter_s,
                         r.master_imu_drop_fraction)

    def sub_imu(self, name: str) -> ImuSeries:
        s = self.scenario.aircraft.sub_imu(name)
        return self._imu(f"sub_imu/{name}", self.scenario.rates.sub_imu_hz, s.imu, f"imu/{name}")

    def imu_biases(self, name: str) -> tuple[FloatArray, FloatArray]:
        """The constant gyro [rad/s] and accelerometer [m/s^2] biases drawn for an IMU (truth)."""
        model = self.scenario.master_imu if name == "master" else self.scenario.aircraft.sub_imu(name).imu
        return draw_biases(model, self.rng(f"imu/{name}"))

    def imu_axes(self, name: str) -> tuple[FloatArray, FloatArray] | None:
        """The axis matrices ``(M_gyro, M_accel)`` (3, 3) drawn for an IMU (truth; None when its
        model has no scale factor or misalignment): the draw after the biases on the same stream."""
        model = self.scenario.master_imu if name == "master" else self.scenario.aircraft.sub_imu(name).imu
        rng = self.rng(f"imu/{name}")
        draw_biases(model, rng)
        return draw_axes_errors(model, rng)

    def master_nav_reference(self) -> NavSeries:
        """Main-system navigation = truth + white noise (``alignment: reference``, [Gong2018]), with
        the body rate (truth) and the noise's covariances: heading, pitch and roll sigmas as a
        rotation covariance (frames.hpr_sigma_to_rotation_cov), diagonal velocity and position."""
        nz = self.scenario.master_nav_noise
        tr = self.truth("master", self.sample_times(self.scenario.rates.master_nav_hz, include_start=True))
        rng = self.rng("nav/master")
        n = tr.t_s.shape[0]
        att_sig = np.array([nz.heading_deg, nz.pitch_deg, nz.roll_deg]) * DEG
        hpr = hpr_from_C_nb(tr.C_nb) + rng.normal(0.0, 1.0, (n, 3)) * att_sig
        vel_sig = np.full(3, nz.vel_mps)
        vel = tr.vel_n_mps + rng.normal(0.0, 1.0, (n, 3)) * vel_sig
        pos_sig = np.full(3, nz.pos_m)
        llh = tr.llh + earth.enu_to_dllh(rng.normal(0.0, 1.0, (n, 3)) * pos_sig, tr.llh)
        q = dcm_to_quat(C_nb_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2]))
        return NavSeries(tr.t_s, q, vel, llh, omega_eb_b_radps=tr.omega_eb_b_radps,
                         att_cov=hpr_sigma_to_rotation_cov(quat_to_dcm(q), att_sig),
                         vel_cov=np.broadcast_to(np.diag(vel_sig**2), (n, 3, 3)).copy(),
                         pos_cov=np.broadcast_to(np.diag(pos_sig**2), (n, 3, 3)).copy())

    def gnss(self) -> GnssSeries:
        g = self.scenario.gnss
        t = self.sample_times(g.rate_hz)
        if g.phase_s:
            t = t + g.phase_s
            t = t[t <= self.duration_s]
        scale, ok = g.scale_at(t)
        tr = self.truth("gnss", t)
        rng = self.rng("gnss")
        n = t.shape[0]
        pos_sig = scale[:, None] * np.asarray(g.pos_sigma_m)
        vel_sig = scale[:, None] * np.asarray(g.vel_sigma_mps)
        llh = tr.llh + earth.enu_to_dllh(rng.normal(0.0, 1.0, (n, 3)) * pos_sig, tr.llh)
        vel = tr.vel_n_mps + rng.normal(0.0, 1.0, (n, 3)) * vel_sig
        return GnssSeries(t[ok] + g.stamp_offset_s, llh[ok], pos_sig[ok], vel[ok], vel_sig[ok])

