"""Transfer-alignment inputs straight from a simulated session (evaluation without a bag)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..series import ImuSeries, NavSeries
from ..sim.session import SimulatedSession
from ..units import DEG, FloatArray
from .model import Installation


def installation(session: SimulatedSession, name: str) -> Installation:
    return Installation.from_aircraft(session.scenario.aircraft, name)


def master_nav(session: SimulatedSession) -> NavSeries:
    """The main-system navigation with its body rate and covariances (``alignment: reference``)."""
    return session.master_nav_reference()


def sub_imu(session: SimulatedSession, name: str) -> ImuSeries:
    return session.sub_imu(name)


def oracle_truth(
    session: SimulatedSession, name: str
) -> tuple[Callable[[float], tuple[FloatArray, FloatArray, FloatArray]], Callable[[float], FloatArray]]:
    """What the oracle ([Gong2018]'s model linearized about the truth) needs of a simulated sub-IMU:
    ``nav(t) -> (C_nb (3, 3), vel_n_mps (3,), llh (3,))`` and ``other(t) -> (15,)`` = gyro bias [rad/s],
    accelerometer bias [m/s^2], misalignment rho [rad], flexure angle [rad] and rate [rad/s]."""
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

    return nav, other
