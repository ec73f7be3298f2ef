"""The synthetic data the warm-ups run on (:mod:`dpos_core.ta.warmup`, :mod:`dpos_core.ifa.warmup`).

A level IMU at rest beside a level main POS at rest, 4 s at 100 Hz: the IMU measures the Earth's
rate and the reaction to gravity exactly, the main POS is exact.  Shared here so that neither
estimation package imports the other's warm-up.
"""

from __future__ import annotations

import numpy as np

from . import earth
from .frames import C_nb_from_hpr
from .series import ImuSeries, NavSeries

#: the synthetic session: duration [s], IMU rate [Hz], place (lat, lon [rad], h [m])
DURATION_S, RATE_HZ = 4.0, 100.0
LLH = np.array([0.6, 1.9, 1000.0])


def resting_imu_and_master() -> tuple[ImuSeries, NavSeries]:
    """``(imu, master)``: a level IMU and a level main POS at rest (module docstring), samples at
    ``t_s = k / RATE_HZ``, k = 1 .. DURATION_S * RATE_HZ; the main POS with small covariances and a
    zero body rate."""
    t_s = np.arange(1, int(DURATION_S * RATE_HZ) + 1) / RATE_HZ
    n = t_s.size
    C_nb = np.broadcast_to(C_nb_from_hpr(0.0, 0.0, 0.0), (n, 3, 3)).copy()
    llh = np.broadcast_to(LLH, (n, 3)).copy()
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    master = NavSeries.from_C_nb(t_s, C_nb, np.zeros((n, 3)), llh, omega_eb_b_radps=np.zeros((n, 3)),
                                 att_cov=eye * 1e-10, vel_cov=eye * 1e-6, pos_cov=eye * 1e-4)
    C_bn = C_nb[0].T
    w_ib_b = C_bn @ earth.earth_rate_n(LLH[0])
    f_b = -(C_bn @ earth.gravity_n(LLH[0], LLH[2]))
    imu = ImuSeries(t_s, np.broadcast_to(w_ib_b, (n, 3)).copy(), np.broadcast_to(f_b, (n, 3)).copy())
    return imu, master
