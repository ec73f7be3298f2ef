"""Transfer-alignment inputs straight from a simulated session (evaluation without a bag)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..sim.bodies import mount_dcm
from ..sim.session import SimulatedSession
from .model import ImuData, Installation, MasterNav


def installation(session: SimulatedSession, name: str) -> Installation:
    """The installation of sub-IMU ``name`` as the aircraft configuration describes it (the rigid
    misalignment rho is unknown to the filter: only the nominal mount is used)."""
    ac = session.scenario.aircraft
    s = ac.sub_imu(name)
    scale = ac.flexure.span_scale(s.span_m)
    flex = replace(ac.flexure, variance_deg2=tuple(v * scale**2 for v in ac.flexure.variance_deg2), reference_span_m=1.0, span_exponent=0.0)
    return Installation(np.asarray(s.lever_arm_m, dtype=float), mount_dcm(s.mount_rpy_deg, (0.0, 0.0, 0.0)), flex, s.imu)


def master_nav(session: SimulatedSession) -> MasterNav:
    nav = session.master_nav_reference()
    n = nav.t_s.size
    return MasterNav(nav.t_s, nav.llh, nav.vel_n_mps, nav.C_nb, nav.omega_eb_b_radps,
                     np.broadcast_to(nav.att_sigma_rad, (n, 3)).copy(), np.broadcast_to(nav.vel_sigma_mps, (n, 3)).copy())


def sub_imu(session: SimulatedSession, name: str) -> ImuData:
    imu = session.sub_imu(name)
    return ImuData(imu.t_s, imu.omega_radps, imu.f_mps2)
