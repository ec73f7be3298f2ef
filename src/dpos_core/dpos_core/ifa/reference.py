"""The in-flight alignment on real recordings: the initial state from the data, and the figures
against a reference solution (e.g. the full-rate RTK of which the aligner saw a decimated part).

The reference is not the truth: RTK fixed solutions are good to ~1-2 cm, float ones to decimetres,
so the coverage check compares the error with ``3 sqrt(sigma_filter^2 + sigma_reference^2)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..attitude import attitude_error, quat_to_dcm
from ..chi2 import chi2_ppf, chi2_quantile
from ..config.sensors import ImuErrorModel
from ..frames import hpr_from_C_nb
from ..series import GnssSeries, ImuSeries
from ..strapdown import NavState
from .mechanization import level_from_specific_force
from .pipeline import IfaResult
from .standstill import StartLevel, start_level
from .states import AlignmentState


def initial_state(imu: ImuSeries, gnss: GnssSeries, min_course_speed_mps: float = 5.0, level_window_s: float = 1.0,
                  heading_rad: float | None = None, lever_arm_m: FloatArray | None = None,
                  gnss_time_offset_s: float = 0.0) -> NavState:
    """:func:`start` with pos_master_node's raw level (its docstring); the state alone."""
    return start(imu, gnss, min_course_speed_mps, level_window_s, heading_rad, lever_arm_m, gnss_time_offset_s)[0]


def start(imu: ImuSeries, gnss: GnssSeries, min_course_speed_mps: float = 5.0, level_window_s: float = 1.0,
          heading_rad: float | None = None, lever_arm_m: FloatArray | None = None, gnss_time_offset_s: float = 0.0,
          level: str = "raw", imu_model: ImuErrorModel | None = None) -> tuple[NavState, StartLevel | None]:
    """The initial state of a recording, by pos_master_node's live rule (``device: ros``,
    ``alignment: ifa``; its module docstring): at the first fix whose ground speed is at least
    ``min_course_speed_mps`` (or any fix when ``heading_rad`` is given) and after which IMU data
    follow, stamped at the fix: velocity = the fix's; heading = the course over ground (below the
    speed: ``heading_rad``); pitch and roll levelled from the mean specific force over the
    ``level_window_s`` before the fix (0 without samples there): ``level="raw"`` as it is
    (pos_master_node's live rule; the second value returned is None), ``level="auto"`` at rest
    only, in motion with the vehicle's GNSS acceleration removed and a level sigma for what is left
    (:func:`~dpos_core.ifa.standstill.start_level` with ``imu_model``: the standstill test;
    returned as the second value); position = the fix moved from the
    antenna to the IMU by ``lever_arm_m`` with that attitude.  The fix's stamp is taken onto the
    IMU's clock first (minus ``gnss_time_offset_s``, as the filter takes it).  The bank of heading
    hypotheses covers any heading.  Raises ValueError when no fix qualifies."""
    t_imu = np.asarray(imu.t_s, dtype=float)
    for j in range(len(gnss.t_s)):
        t_fix = float(gnss.t_s[j]) - float(gnss_time_offset_s)
        if not (t_imu[0] <= t_fix < t_imu[-1]):
            continue
        v = np.asarray(gnss.vel_n_mps[j], dtype=float)
        if np.hypot(v[0], v[1]) >= min_course_speed_mps:
            heading = float(np.arctan2(v[0], v[1]))
        elif heading_rad is not None:
            heading = float(heading_rad)
        else:
            continue
        lv = None
        if level == "auto":
            lv = start_level(imu, gnss, j, t_fix, heading, level_window_s, imu_model)
            pitch, roll = lv.pitch_rad, lv.roll_rad
        elif level == "raw":
            win = (t_imu > t_fix - level_window_s) & (t_imu <= t_fix)
            pitch, roll = level_from_specific_force(np.mean(np.asarray(imu.f_mps2)[win], axis=0)) if np.any(win) else (0.0, 0.0)
        else:
            raise ValueError(f"level must be 'raw' or 'auto', got {level!r}")
        s = NavState.from_hpr(t_fix, [heading, pitch, roll], v, np.asarray(gnss.llh[j], dtype=float))
        if lever_arm_m is not None and np.any(np.asarray(lever_arm_m) != 0.0):
            llh = earth.offset_llh(s.llh, -(s.C_nb @ np.asarray(lever_arm_m, dtype=float)))
            s = NavState(t_fix, s.q_nb, v, llh)
        return s, lv
    raise ValueError(f"no GNSS fix with a ground speed of {min_course_speed_mps} m/s or more inside the IMU data "
                     "(set the heading, or lower min_course_speed_mps: the bank of heading hypotheses covers any heading)")


def track_sigmas(result: IfaResult) -> tuple[FloatArray, FloatArray]:
    """Epochs (K,) and 1 sigma (K, 9) of position E, N, U [m], velocity [m/s], attitude [rad] of a run's track."""
    t = np.array([x[0] for x in result.track])
    P = np.array([x[1] for x in result.track]).reshape(-1, 9, 9)
    return t, np.sqrt(np.diagonal(P, axis1=1, axis2=2))


@dataclass
class Consistency:
    """Normalized errors of a run against the truth (simulation) at its filter epochs.

    Attributes:
        t_s: (K,) epochs (after the alignment, ``since_s``).
        nees_pos, nees_vel, nees_att: (K,) NEES of position, velocity, attitude (3 dof each).
        nis: (M,) NIS of the GNSS updates (6 dof, the model's R) in the same span.
    """

    t_s: FloatArray
    nees_pos: FloatArray
    nees_vel: FloatArray
    nees_att: FloatArray
    nis: FloatArray
    nis_dof: int

    def summary(self) -> dict[str, float]:
        """Mean NEES per block (3 when consistent), the fraction inside the two-sided 95 %
        chi-square(3) bounds per epoch (0.95 when consistent), the same for the NIS."""
        lo, hi = chi2_ppf([0.025, 0.975], 3)
        out: dict[str, float] = {}
        for k in ("pos", "vel", "att"):
            v = getattr(self, f"nees_{k}")
            out[f"nees_{k}_mean"] = float(np.mean(v))
            out[f"nees_{k}_in95"] = float(np.mean((v >= lo) & (v <= hi)))
            out[f"nees_{k}_below99"] = float(np.mean(v <= chi2_quantile(0.99, 3)))
        nlo, nhi = chi2_ppf([0.025, 0.975], self.nis_dof)
        out["nis_mean"] = float(np.mean(self.nis))
        out["nis_in95"] = float(np.mean((self.nis >= nlo) & (self.nis <= nhi)))
        out["epochs"] = float(self.t_s.size)
        return out


def consistency(result: IfaResult, truth_at, since_s: float) -> Consistency:
    """NEES of the navigation at the run's filter epochs against the truth, and its NIS.

    Args:
        result: the run (its ``track`` gives the covariance at each epoch, its navigation the state).
        truth_at: ``t_s (K,) -> NavSeries`` of the truth at the IMU.
        since_s: only epochs from this time on (e.g. the alignment time).
    """
    tt = np.array([x[0] for x in result.track])
    P = np.array([x[1] for x in result.track]).reshape(-1, 9, 9)
    keep = tt >= since_s
    tt, P = tt[keep], P[keep]
    k = np.clip(np.searchsorted(result.t_s, tt - 1e-9), 0, result.t_s.size - 1)
    tr = truth_at(result.t_s[k])
    e_pos = np.array([earth.enu_between(a, b) for a, b in zip(result.llh[k], tr.llh)])
    e_vel = result.vel_n_mps[k] - tr.vel_n_mps
    e_att = attitude_error(quat_to_dcm(result.q_nb[k]), tr.C_nb)

    def nees(e: FloatArray, blk: FloatArray) -> FloatArray:
        return np.einsum("ki,ki->k", e, np.linalg.solve(blk, e[..., None])[..., 0])

    nis = np.asarray(result.nis)[np.asarray(result.epochs_s) >= since_s]
    p = result.R_diag.shape[1] if result.R_diag.ndim == 2 else 6
    return Consistency(tt, nees(e_pos, P[:, 0:3, 0:3]), nees(e_vel, P[:, 3:6, 3:6]), nees(e_att, P[:, 6:9, 6:9]), nis, p)


@dataclass
class Reference:
    """A reference solution: t_s (M,), llh (M, 3), vel_n_mps (M, 3), pos_sigma_m (M, 3) ENU."""

    t_s: FloatArray
    llh: FloatArray
    vel_n_mps: FloatArray
    pos_sigma_m: FloatArray

    @classmethod
    def from_gnss(cls, g: GnssSeries, gnss_time_offset_s: float = 0.0) -> Reference:
        """A GNSS solution (stamped on the receiver's clock) as a reference on the IMU's clock, where
        the navigation is: each stamp minus ``gnss_time_offset_s`` (GNSS stamp minus the IMU time of
        the same instant, the filter's own convention, :func:`~dpos_core.ifa.pipeline.fix_at`).
        Scoring against the unshifted stamps would charge a correctly declared offset ``v * offset``
        of error and reward a wrong one (the navigation then follows the mis-stamped fixes)."""
        return cls(np.asarray(g.t_s, dtype=float) - float(gnss_time_offset_s), np.asarray(g.llh, dtype=float),
                   np.asarray(g.vel_n_mps, dtype=float), np.asarray(g.pos_sigma_m, dtype=float))


@dataclass
class RealDataReport:
    """The figures of one run against a reference (``compare``)."""

    aligned_t_s: float | None  #: seconds after the start of the navigation
    diverged: int  #: epochs reported DIVERGED
    restarts: int
    heading_minus_course_deg: dict[str, float]  #: mean, std, p95 (|deviation from the mean|), n (moving epochs)
    horizontal_error_m: dict[str, dict[str, float]]  #: phase -> mean, rms, max, n
    inside_3sigma: dict[str, float]  #: axis E, N, U and all -> fraction of reference epochs
    phases: dict[str, tuple[float, float]] = field(default_factory=dict)

    def lines(self) -> list[str]:
        """The report as text lines."""
        out = [f"aligned at {self.aligned_t_s:.1f} s" if self.aligned_t_s is not None else "never aligned",
               f"DIVERGED epochs {self.diverged}, restarts {self.restarts}"]
        h = self.heading_minus_course_deg
        out.append(f"heading - course while moving: mean {h['mean']:.2f} deg, std {h['std']:.2f} deg, "
                   f"95 % within {h['p95']:.2f} deg of the mean ({int(h['n'])} epochs)")
        for k, e in self.horizontal_error_m.items():
            a, b = self.phases.get(k, (np.nan, np.nan))
            out.append(f"horizontal error {k:>6} [{a:.0f}, {b:.0f}) s: mean {e['mean']:.3f} m, rms {e['rms']:.3f} m, "
                       f"max {e['max']:.3f} m ({int(e['n'])} epochs)")
        c = self.inside_3sigma
        out.append(f"errors inside 3 sigma: E {c['E']:.3f}, N {c['N']:.3f}, U {c['U']:.3f}, all three {c['all']:.3f}")
        return out


def compare(result: IfaResult, ref: Reference, outage_s: tuple[float, float] | None, moving_mps: float = 0.5) -> RealDataReport:
    """The run's navigation against the reference at every reference epoch inside the run.

    Args:
        result: :func:`~dpos_core.ifa.pipeline.run`'s result (navigation at the IMU rate).
        ref: the reference solution on the IMU's clock (:meth:`Reference.from_gnss` with the run's
            ``gnss_time_offset_s``).
        outage_s: [start, end) of the GNSS outage the aligner had (phases before / during /
            after), None for none.
        moving_mps: heading minus course is taken where the reference speed is at least this.
    """
    t = result.t_s
    inside = (ref.t_s > t[0]) & (ref.t_s < t[-1])
    tr = ref.t_s[inside]
    idx = np.clip(np.searchsorted(t, tr), 1, t.size - 1)
    w = (tr - t[idx - 1]) / (t[idx] - t[idx - 1])
    llh = result.llh[idx - 1] + (result.llh[idx] - result.llh[idx - 1]) * w[:, None]
    err = np.array([earth.enu_between(a, b) for a, b in zip(llh, ref.llh[inside])])  # est - ref, ENU [m]
    # heading minus course while moving
    k = np.where(w < 0.5, idx - 1, idx)
    yaw = hpr_from_C_nb(quat_to_dcm(result.q_nb[k]))[:, 0]
    v = ref.vel_n_mps[inside]
    moving = np.hypot(v[:, 0], v[:, 1]) >= moving_mps
    d = np.angle(np.exp(1j * (yaw - np.arctan2(v[:, 0], v[:, 1]))))[moving]
    mean = float(np.angle(np.mean(np.exp(1j * d)))) if d.size else np.nan
    dev = np.angle(np.exp(1j * (d - mean))) if d.size else np.zeros(0)
    hc = {"mean": mean / DEG, "std": float(np.std(dev)) / DEG if d.size else np.nan,
          "p95": float(np.percentile(np.abs(dev), 95)) / DEG if d.size else np.nan, "n": float(d.size)}
    # phases
    t0, t1 = float(tr[0]), float(tr[-1])
    phases = {"all": (t0, t1 + 1e-9)}
    if outage_s is not None:
        a, b = outage_s
        phases.update({"before": (t0, a), "during": (a, b), "after": (b, t1 + 1e-9)})
    hor = np.hypot(err[:, 0], err[:, 1])
    errs = {}
    for name, (a, b) in phases.items():
        m = (tr >= a) & (tr < b)
        e = hor[m]
        errs[name] = {"mean": float(e.mean()) if e.size else np.nan, "rms": float(np.sqrt(np.mean(e**2))) if e.size else np.nan,
                      "max": float(e.max()) if e.size else np.nan, "n": float(e.size)}
    # coverage: the covariance reported with the navigation (the latest filter epoch's, result.track)
    tt, sig = track_sigmas(result)
    sig = sig[:, 0:3]
    j = np.searchsorted(tt, tr, side="right") - 1
    ok = j >= 0
    bound = 3.0 * np.sqrt(sig[np.maximum(j, 0)] ** 2 + ref.pos_sigma_m[inside] ** 2)
    within = np.abs(err) <= bound
    cov = {ax: float(within[ok, i].mean()) for i, ax in enumerate("ENU")}
    cov["all"] = float(np.all(within[ok], axis=1).mean())
    diverged = int(np.sum(result.status == AlignmentState.DIVERGED))
    aligned = None if result.aligned_t_s is None else float(result.aligned_t_s - t[0])
    return RealDataReport(aligned, diverged, result.restarts, hc, errs, cov, phases)


__all__ = ["initial_state", "start", "track_sigmas", "Consistency", "consistency", "Reference", "RealDataReport", "compare"]
