"""Transfer-alignment inputs straight from a simulated session (evaluation without a bag)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import earth
from ..attitude import dcm_to_rotvec, mount_dcm
from ..series import ImuSeries, NavSeries
from ..sim.session import SimulatedSession
from ..ta.model import Installation
from ..units import DEG, FloatArray


def installation(session: SimulatedSession, name: str) -> Installation:
    return Installation.from_aircraft(session.scenario.aircraft, name)


def master_nav(session: SimulatedSession) -> NavSeries:
    """The main-system navigation with its body rate and covariances (``alignment: reference``)."""
    return session.master_nav_reference()


def sub_imu(session: SimulatedSession, name: str) -> ImuSeries:
    return session.sub_imu(name)


def oracle_truth(
    session: SimulatedSession, name: str
) -> tuple[Callable[[float], tuple[FloatArray, FloatArray, FloatArray]], Callable[[float], FloatArray], dict]:
    """What the oracle ([Gong2018]'s model linearized about the truth) needs of a simulated sub-IMU:
    ``nav(t) -> (C_nb (3, 3), vel_n_mps (3,), llh (3,))`` at the main system's time t,
    ``other(t) -> (15,)`` = gyro bias [rad/s], accelerometer bias [m/s^2], misalignment rho [rad],
    flexure angle [rad] and rate [rad/s], and the true installation states
    (:class:`.oracle.LinearizedAboutTruth`): the session's sub-IMU time offset (a mismatch case's;
    0 otherwise) and the sub-IMU's drawn axis errors; the lever arm's is 0 (the oracle is given the
    true aircraft)."""
    s = session.scenario.aircraft.sub_imu(name)
    gb, ab = session.imu_biases(name)
    rho = np.asarray(s.rho_deg) * DEG
    flexing = np.any(np.asarray(session.scenario.aircraft.flexure.variance_deg2) > 0)
    fr = session.flexure(1 if s.span_m > 0 else -1) if flexing else None

    def nav(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        tr = session.truth(f"sub_imu/{name}", np.array([t]))
        return tr.C_nb[0], tr.vel_n_mps[0], tr.llh[0]

    def other(t: float) -> FloatArray:
        th, thd = fr.at(np.array([t]), s.span_m) if fr is not None else (np.zeros((1, 3)), np.zeros((1, 3)))
        return np.concatenate([gb, ab, rho, th[0], thd[0]])

    inst: dict = {"time_offset": float(getattr(session, "time_offset_s", 0.0)), "master_error": _master_error(session)}
    axes = session.imu_axes(name)
    if axes is not None:
        inst["gyro_axes"] = axis_errors(axes[0])
        g = axis_errors(axes[1])  # the accelerometers' estimated part: scale factors, symmetric misalignments
        inst["accel_axes"] = np.r_[g[:3], 0.5 * (g[3] + g[5]), 0.5 * (g[4] + g[7]), 0.5 * (g[6] + g[8])]
    return nav, other, inst


def _master_error(session: SimulatedSession) -> Callable[[float], FloatArray]:
    """``t -> (6,)``: the main-system reference's ENU position [m] and velocity [m/s] errors at t
    (its epoch at or before t), computed on first use."""
    cache: list = []

    def at(t: float) -> FloatArray:
        if not cache:
            ref = session.master_nav_reference()
            tr = session.truth("master", ref.t_s)
            cache.append((ref.t_s, np.concatenate([earth.dllh_to_enu(ref.llh - tr.llh, tr.llh), ref.vel_n_mps - tr.vel_n_mps], axis=1)))
        ts, e = cache[0]
        return e[int(np.clip(np.searchsorted(ts, t + 1e-9) - 1, 0, ts.size - 1))]

    return at


def axis_errors(M: FloatArray) -> FloatArray:
    """The axis errors ``gamma`` (9,) (:func:`.model.axis_matrix`'s order) of an axis matrix M (3, 3) = I + Gamma."""
    G = np.asarray(M, dtype=float) - np.eye(3)
    return np.array([G[0, 0], G[1, 1], G[2, 2], G[0, 1], G[0, 2], G[1, 0], G[1, 2], G[2, 0], G[2, 1]])


def known_wing(session: SimulatedSession, name: str) -> Callable[[float], tuple[FloatArray, FloatArray, FloatArray]]:
    """The true wing at sub-IMU ``name`` (``Installation.known_wing``, the oracle that knows the
    wing): ``t -> (theta_b (3,) [rad], r_b (3,) [m], r_dot_b (3,) [m/s])``, the flexure rotation of its
    section and its true lever arm and lever-arm rate from the main IMU, master axes (from the
    simulated truth of both bodies, so any wing model: Gauss-Markov or modal)."""
    s = session.scenario.aircraft.sub_imu(name)
    C_s0 = mount_dcm(s.mount_rpy_deg, s.rho_deg)  # sub-IMU axes -> master axes, no flexure

    def at(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        tt = np.array([t])
        m, b = session.truth("master", tt), session.truth(f"sub_imu/{name}", tt)
        C_bn = m.C_nb[0].T
        th_b = dcm_to_rotvec((C_bn @ b.C_nb[0] @ C_s0.T)[None])[0]
        p_m, p_b = earth.geodetic_to_ecef(*m.llh[0]), earth.geodetic_to_ecef(*b.llh[0])
        C_en = earth.C_en(m.llh[0, 0], m.llh[0, 1])
        r_b = C_bn @ (C_en.T @ (p_b - p_m))
        w = m.omega_eb_b_radps[0] if m.omega_eb_b_radps is not None else np.zeros(3)
        r_dot_b = C_bn @ (b.vel_n_mps[0] - m.vel_n_mps[0]) - np.cross(w, r_b)
        return th_b, r_b, r_dot_b

    return at
