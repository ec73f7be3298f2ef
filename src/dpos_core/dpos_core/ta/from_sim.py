"""Transfer-alignment inputs straight from a simulated session (evaluation without a bag)."""

from __future__ import annotations

import numpy as np

from ..frames import hpr_sigma_to_rotation_cov
from ..sim.session import SimulatedSession
from .model import ImuData, Installation, MasterNav


def installation(session: SimulatedSession, name: str) -> Installation:
    return Installation.from_aircraft(session.scenario.aircraft, name)


def master_nav(session: SimulatedSession) -> MasterNav:
    nav = session.master_nav_reference()
    n = nav.t_s.size
    C = nav.C_nb
    return MasterNav(nav.t_s, nav.llh, nav.vel_n_mps, C, nav.omega_eb_b_radps,
                     hpr_sigma_to_rotation_cov(C, nav.att_sigma_rad), np.broadcast_to(np.diag(nav.vel_sigma_mps**2), (n, 3, 3)).copy(),
                     np.broadcast_to(np.diag(nav.pos_sigma_m**2), (n, 3, 3)).copy())


def sub_imu(session: SimulatedSession, name: str) -> ImuData:
    imu = session.sub_imu(name)
    return ImuData(imu.t_s, imu.omega_radps, imu.f_mps2)
