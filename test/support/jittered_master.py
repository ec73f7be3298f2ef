"""A real master device's data, simulated: IMU stamps that jitter, dropped samples, GNSS
fixes stamped between IMU samples.

The samples are physically consistent (the simulator's motion and master IMU model, integrated
over the jittered intervals), so the in-flight alignment behaves as on a flight. Stamps are
integer nanoseconds (what a driver publishes); seconds are :func:`dpos_core.ifa.mechanization.stamp_s`
of them, the very floats the nodes compute.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dpos_core import earth
from dpos_core.ifa.mechanization import stamp_s
from dpos_core.kinematics import increments_from_motion
from dpos_core.series import GnssSeries, ImuSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.sensors import draw_axes_errors, draw_biases, measure
from dpos_core.sim.session import SimulatedSession

#: IMU intervals [ns]: uniform over 8 ... 11 ms on a 0.5 ms grid (symmetric about 9.5 ms, so the
#: median interval of any long stretch is 9.5 ms: the aligner's process noise per sample is then
#: the same live (ifa_node: the median of its first 50 intervals) and offline (run(): of all)
STEPS_NS = np.arange(8_000_000, 11_000_001, 500_000, dtype=np.int64)


@dataclass
class JitteredMaster:
    """One session: ``imu_ns`` (N,) stamps [ns], ``omega`` / ``f`` (N, 3) [rad/s, m/s^2] (FLU),
    ``fix_ns`` (M,) GNSS stamps [ns], ``gnss`` (stamps in s since ``start_ns``), ``session`` (the
    simulated flight), ``start_ns`` (the simulator's t = 0), ``dropped`` (indices of the samples
    removed, into the undropped series)."""

    imu_ns: np.ndarray
    omega: np.ndarray
    f: np.ndarray
    fix_ns: np.ndarray
    gnss: GnssSeries
    session: SimulatedSession
    start_ns: int
    dropped: np.ndarray

    def imu(self, origin_ns: int, after: bool = True) -> ImuSeries:
        """The IMU in seconds since ``origin_ns`` (only the samples after it when ``after``)."""
        k = self.imu_ns > origin_ns if after else np.ones(self.imu_ns.size, dtype=bool)
        return ImuSeries(stamp_s(self.imu_ns[k], origin_ns), self.omega[k], self.f[k])

    def gnss_from(self, origin_ns: int, after: bool = True) -> GnssSeries:
        """The fixes in seconds since ``origin_ns`` (only those after it when ``after``)."""
        g = self.gnss
        k = self.fix_ns > origin_ns if after else np.ones(self.fix_ns.size, dtype=bool)
        return GnssSeries(stamp_s(self.fix_ns[k], origin_ns), g.llh[k], g.pos_sigma_m[k], g.vel_n_mps[k], g.vel_sigma_mps[k])


def jittered_master(duration_s: float, seed: int = 1, n_dropped: int = 5, fix_phase_s: float = 0.0037,
                    scenario: str = "paper_ifa") -> JitteredMaster:
    """Simulate ``duration_s`` of the master device of ``scenario`` with jittered IMU stamps
    (:data:`STEPS_NS`), ``n_dropped`` samples dropped at random (after the first second) and 1 Hz
    GNSS fixes at ``k + fix_phase_s`` s, k >= 1 (between IMU samples: the grid is 0.5 ms, the
    phase is not on it). GNSS noise: the scenario's sigmas."""
    ss = SimulatedSession(load_scenario(scenario), seed, duration_s=duration_s)
    rng = np.random.default_rng(1000 + seed)
    n = int(duration_s / 8e-3) + 2
    edges_ns = np.concatenate([[0], np.cumsum(rng.choice(STEPS_NS, size=n))])
    edges_ns = edges_ns[edges_ns <= int(round(duration_s * 1e9))]
    edges_s = edges_ns / 1e9
    model = ss.scenario.master_imu
    dth, dv = increments_from_motion(ss.motion("master"), edges_s)
    omega, f = measure(model, dth, dv, np.diff(edges_s), draw_biases(model, rng), rng, draw_axes_errors(model, rng))
    start_ns = int(round(ss.scenario.start_time_s * 1e9))
    imu_ns = start_ns + edges_ns[1:]
    first = int(np.searchsorted(edges_s[1:], 1.0))
    dropped = np.sort(rng.choice(np.arange(first, imu_ns.size - 1), size=n_dropped, replace=False))
    keep = np.ones(imu_ns.size, dtype=bool)
    keep[dropped] = False
    t_fix = np.arange(1.0, duration_s - 0.5) + fix_phase_s
    g = ss.scenario.gnss
    tr = ss.truth("gnss", t_fix)
    pos_sig = np.broadcast_to(np.asarray(g.pos_sigma_m, dtype=float), (t_fix.size, 3)).copy()
    vel_sig = np.broadcast_to(np.asarray(g.vel_sigma_mps, dtype=float), (t_fix.size, 3)).copy()
    llh = tr.llh + earth.enu_to_dllh(rng.normal(0.0, 1.0, (t_fix.size, 3)) * pos_sig, tr.llh)
    vel = tr.vel_n_mps + rng.normal(0.0, 1.0, (t_fix.size, 3)) * vel_sig
    fix_ns = start_ns + np.round(t_fix * 1e9).astype(np.int64)
    return JitteredMaster(imu_ns[keep], omega[keep], f[keep], fix_ns, GnssSeries(t_fix, llh, pos_sig, vel, vel_sig), ss,
                          start_ns, dropped)


def with_outage(jm: JitteredMaster, t0_s: float, t1_s: float) -> JitteredMaster:
    """The session without the fixes stamped in [t0_s, t1_s) seconds after its first fix (an outage)."""
    t = (jm.fix_ns - jm.fix_ns[0]) * 1e-9
    keep = ~((t >= t0_s) & (t < t1_s))
    g = jm.gnss
    return replace(jm, fix_ns=jm.fix_ns[keep],
                   gnss=GnssSeries(g.t_s[keep], g.llh[keep], g.pos_sigma_m[keep], g.vel_n_mps[keep], g.vel_sigma_mps[keep]))
