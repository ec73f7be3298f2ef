"""A simulated session generated window by window, for flights too long to hold in memory
(docs/campaign.md "Long flights").

:class:`ChunkedSession` produces the streams of a :class:`~.session.SimulatedSession` over
consecutive time windows ``(t_a, t_b]``: the deterministic parts (flight, wing, truth, ideal
increments) are functions of time and are evaluated on the window's stamps only; the random parts
are drawn by streaming recursions whose state is carried from one window to the next (each noise
term from its own generator, consumed in sample order; the in-run bias Gauss-Markov process as a
recursion).  So the same seed gives the same samples whatever the windows (tested), and memory
holds one window.

The random streams are not those of the whole-session generator (:class:`SimulatedSession`
draws a component's gyro and accelerometer noise from one generator, the gyro's first): a chunked
session has the same statistics and the same per-run draws (turn-on biases, axis errors, the
wing's flexure realization) but other white-noise and timing samples.  The wing's flexure
realization is still sampled over the whole flight at the sub-IMU rate (a few floats per sample
and mode).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import earth
from ..attitude import dcm_to_quat, quat_to_dcm
from ..config.sensors import ImuErrorModel
from ..frames import C_nb_from_hpr, hpr_from_C_nb, hpr_sigma_to_rotation_cov
from ..kinematics import increments_from_motion
from ..series import GnssSeries, ImuSeries, NavSeries
from .ar1 import ar1
from .sensors import draw_axes_errors, draw_biases
from .session import SimulatedSession


class _GaussMarkov:
    """First-order Gauss-Markov samples (k, 3), stationary start, drawn window by window."""

    def __init__(self, sigma: float, tau_s: float, dt_s: float, rng: np.random.Generator) -> None:
        self.a = float(np.exp(-dt_s / tau_s))
        self.q = sigma * np.sqrt(1.0 - self.a * self.a)
        self.rng = rng
        self.x = rng.normal(0.0, sigma, 3)

    def next(self, n: int) -> FloatArray:
        w = self.rng.normal(0.0, self.q, (n, 3))
        if n == 0:
            return w
        # x_i = a x_{i-1} + w_i from the state carried over: the same recursion whatever the windows
        out = ar1(w, self.a, self.x)
        self.x = out[-1].copy()
        return out


class _ImuStream:
    """One IMU's samples, window by window (stamps ``k / rate``, k >= 1, with the real-device timing)."""

    def __init__(self, ss: SimulatedSession, body: str, rate_hz: float, model: ImuErrorModel, component: str,
                 jitter_s: float = 0.0, drop_fraction: float = 0.0) -> None:
        self.ss, self.body, self.rate, self.model = ss, body, rate_hz, model
        self.jitter, self.drop = jitter_s, drop_fraction
        rng = ss.rng(component)  # the per-run draws: the same as the whole-session generator's
        self.biases = draw_biases(model, rng)
        self.axes = draw_axes_errors(model, rng)
        self.g_rng, self.a_rng = ss.rng(f"{component}/gyro_noise"), ss.rng(f"{component}/accel_noise")
        self.t_rng = ss.rng(f"{component}/timing") if jitter_s > 0.0 else None
        self.d_rng = ss.rng(f"{component}/drops") if drop_fraction > 0.0 else None
        dt = 1.0 / rate_hz
        self.g_gm = (_GaussMarkov(model.gyro_bias_instability_deg_h * DEG_PER_H, model.gyro_bias_tau_s, dt, ss.rng(f"{component}/gyro_gm"))
                     if model.gyro_bias_instability_deg_h else None)
        self.a_gm = (_GaussMarkov(model.accel_bias_instability_ug * UG_MPS2, model.accel_bias_tau_s, dt, ss.rng(f"{component}/accel_gm"))
                     if model.accel_bias_instability_ug else None)
        self.k = 0  # samples made
        self.t_last = 0.0  # the last (jittered) stamp: the start of the next interval
        self.n_total = int(np.floor(ss.duration_s * rate_hz + 1e-9))

    def next(self, t_end_s: float) -> ImuSeries:
        """The samples stamped (nominally) after the previous window up to ``t_end_s``."""
        k1 = min(self.n_total, int(np.floor(t_end_s * self.rate + 1e-9)))
        n = max(k1 - self.k, 0)
        t = np.arange(self.k + 1, self.k + 1 + n) / self.rate
        if self.t_rng is not None:
            t = t + self.t_rng.uniform(-self.jitter, self.jitter, n)
        edges = np.concatenate([[self.t_last], t])
        dth, dv = increments_from_motion(self.ss.motion(self.body), edges)
        dt = np.diff(edges)[:, None]
        m = self.model
        om, f = dth / dt, dv / dt
        if self.axes is not None:
            om, f = om @ self.axes[0].T, f @ self.axes[1].T
        g_sig: float | FloatArray = m.gyro_noise_deg_h * DEG_PER_H
        a_sig: float | FloatArray = m.accel_noise_ug * UG_MPS2
        if m.gyro_arw_deg_rth:
            g_sig = np.hypot(g_sig, m.gyro_arw_deg_rth * DEG / 60.0 / np.sqrt(dt))
        if m.accel_vrw_mps_rth:
            a_sig = np.hypot(a_sig, m.accel_vrw_mps_rth / 60.0 / np.sqrt(dt))
        om = om + self.biases[0] + self.g_rng.normal(0.0, 1.0, (n, 3)) * g_sig
        f = f + self.biases[1] + self.a_rng.normal(0.0, 1.0, (n, 3)) * a_sig
        if self.g_gm is not None:
            om = om + self.g_gm.next(n)
        if self.a_gm is not None:
            f = f + self.a_gm.next(n)
        self.k += n
        if n:
            self.t_last = float(t[-1])
        imu = ImuSeries(t, om, f)
        if self.d_rng is not None:
            imu = imu.select(self.d_rng.random(n) >= self.drop)
        return imu


@dataclass
class Window:
    """The streams of one window ``(t_a, t_b]`` (``t_a = 0`` includes the instantaneous samples at 0)."""

    t_a: float
    t_b: float
    master_imu: ImuSeries
    sub_imus: dict[str, ImuSeries]
    master_nav: NavSeries
    gnss: GnssSeries
    truth: dict[str, NavSeries]


class ChunkedSession:
    """The streams of ``session`` window by window (module docstring)."""

    def __init__(self, session: SimulatedSession, truth: bool = True) -> None:
        self.ss = session
        self.truth = truth
        sc = session.scenario
        r = sc.rates
        self._master = _ImuStream(session, "master", r.master_imu_hz, sc.master_imu, "imu/master", r.master_imu_jitter_s,
                                  r.master_imu_drop_fraction)
        self._subs = {s.name: _ImuStream(session, f"sub_imu/{s.name}", r.sub_imu_hz, s.imu, f"imu/{s.name}")
                      for s in sc.aircraft.sub_imus}
        self._nav_rngs = [session.rng(f"nav/master/{x}") for x in ("att", "vel", "pos")]
        self._gnss_rngs = [session.rng(f"gnss/{x}") for x in ("pos", "vel")]

    @property
    def duration_s(self) -> float:
        return self.ss.duration_s

    def truth_bodies(self) -> list[str]:
        """The bodies whose truth the recording carries (those of dpos-sim's /truth/* topics)."""
        ac = self.ss.scenario.aircraft
        return (["master"] + [f"sub_imu/{s.name}" for s in ac.sub_imus] + [f"antenna/{a.name}" for a in ac.antennas])

    def _times(self, rate_hz: float, t_a: float, t_b: float, include_start: bool) -> FloatArray:
        """Stamps ``k / rate`` in ``(t_a, t_b]`` (and 0 in the first window when ``include_start``)."""
        n_total = int(np.floor(self.duration_s * rate_hz + 1e-9))
        k0 = int(np.floor(t_a * rate_hz + 1e-9)) + 1 if t_a > 0 else (0 if include_start else 1)
        k1 = min(n_total, int(np.floor(t_b * rate_hz + 1e-9)))
        return np.arange(k0, k1 + 1) / rate_hz

    def _master_nav(self, t: FloatArray) -> NavSeries:
        """As :meth:`SimulatedSession.master_nav_reference` at stamps t, each noise from its own stream."""
        nz = self.ss.scenario.master_nav_noise
        tr = self.ss.truth("master", t)
        n = t.size
        ra, rv, rp = self._nav_rngs
        att_sig = np.array([nz.heading_deg, nz.pitch_deg, nz.roll_deg]) * DEG
        hpr = hpr_from_C_nb(tr.C_nb) + ra.normal(0.0, 1.0, (n, 3)) * att_sig
        vel_sig = np.full(3, nz.vel_mps)
        vel = tr.vel_n_mps + rv.normal(0.0, 1.0, (n, 3)) * vel_sig
        pos_sig = np.full(3, nz.pos_m)
        llh = tr.llh + earth.enu_to_dllh(rp.normal(0.0, 1.0, (n, 3)) * pos_sig, tr.llh)
        q = dcm_to_quat(C_nb_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2]))
        return NavSeries(tr.t_s, q, vel, llh, omega_eb_b_radps=tr.omega_eb_b_radps,
                         att_cov=hpr_sigma_to_rotation_cov(quat_to_dcm(q), att_sig),
                         vel_cov=np.broadcast_to(np.diag(vel_sig**2), (n, 3, 3)).copy(),
                         pos_cov=np.broadcast_to(np.diag(pos_sig**2), (n, 3, 3)).copy())

    def _gnss(self, t_a: float, t_b: float) -> GnssSeries:
        g = self.ss.scenario.gnss
        n_total = int(np.floor(self.duration_s * g.rate_hz + 1e-9))
        k0 = max(1, int(np.floor((t_a - g.phase_s) * g.rate_hz)) - 1)
        k1 = min(n_total, int(np.floor((t_b - g.phase_s) * g.rate_hz)) + 1)
        t = np.arange(k0, k1 + 1) / g.rate_hz + g.phase_s  # (as sample_times(rate) + phase)
        t = t[(t > t_a if t_a > 0 else t >= 0) & (t <= min(t_b, self.duration_s))]
        scale, ok = g.scale_at(t)
        tr = self.ss.truth("gnss", t)
        n = t.size
        rp, rv = self._gnss_rngs
        pos_sig = scale[:, None] * np.asarray(g.pos_sigma_m)
        vel_sig = scale[:, None] * np.asarray(g.vel_sigma_mps)
        llh = tr.llh + earth.enu_to_dllh(rp.normal(0.0, 1.0, (n, 3)) * pos_sig, tr.llh)
        vel = tr.vel_n_mps + rv.normal(0.0, 1.0, (n, 3)) * vel_sig
        return GnssSeries(t[ok] + g.stamp_offset_s, llh[ok], pos_sig[ok], vel[ok], vel_sig[ok])

    def window(self, t_a: float, t_b: float) -> Window:
        """The next window ``(t_a, t_b]``: windows must be asked for in order, back to back from 0."""
        r = self.ss.scenario.rates
        truth = {}
        if self.truth:
            for body in self.truth_bodies():
                rate = r.master_imu_hz if body == "master" else r.sub_imu_hz
                truth[body] = self.ss.truth(body, self._times(rate, t_a, t_b, include_start=True))
        return Window(t_a, t_b, self._master.next(t_b), {n: s.next(t_b) for n, s in self._subs.items()},
                      self._master_nav(self._times(r.master_nav_hz, t_a, t_b, include_start=True)), self._gnss(t_a, t_b), truth)

    def windows(self, window_s: float) -> Iterator[Window]:
        """The whole session in windows of ``window_s`` seconds (the last one shorter)."""
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        n = int(np.ceil(self.duration_s / window_s - 1e-9))
        for i in range(n):
            yield self.window(i * window_s, min((i + 1) * window_s, self.duration_s))
