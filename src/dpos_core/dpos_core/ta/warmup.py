"""Warming a fresh process for the transfer alignment.

A spawned worker pays, before its first sub-IMU, for importing the pipeline (numpy, scipy.linalg,
numba: ~1.1 s of CPU) and for loading each numba kernel of the filters from its cache at first
call.  :func:`warm_up` pays both on a few seconds of synthetic data, so that a pool started ahead
of time (transfer_align_node keeps one from its start; dpos-process starts it while the recording
is read: :func:`dpos_ros.runtime.pool.warm_pool`) spends the time after a session's end on the
session alone.
"""

from __future__ import annotations

import time

import numpy as np

from .. import earth
from ..config.flexure import FlexureModel
from ..config.sensors import ImuErrorModel
from ..frames import C_nb_from_hpr
from ..series import ImuSeries, NavSeries
from .model import Installation, TAConfig
from .pipeline import run_segments

#: the synthetic session: duration [s], IMU rate [Hz], place (lat, lon [rad], h [m])
_DURATION_S, _RATE_HZ = 4.0, 100.0
_LLH = np.array([0.6, 1.9, 1000.0])


def resting_session() -> tuple[ImuSeries, NavSeries, Installation]:
    """A level sub-IMU at rest 2 m to the right of a level main POS at rest (4 s at 100 Hz): the
    IMU measures the Earth's rate and the reaction to gravity exactly, the main POS is exact.
    Returns ``(imu, master, install)`` for :func:`~.pipeline.run_segments`."""
    t_s = np.arange(1, int(_DURATION_S * _RATE_HZ) + 1) / _RATE_HZ
    n = t_s.size
    C_nb = np.broadcast_to(C_nb_from_hpr(0.0, 0.0, 0.0), (n, 3, 3)).copy()
    llh = np.broadcast_to(_LLH, (n, 3)).copy()
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    master = NavSeries.from_C_nb(t_s, C_nb, np.zeros((n, 3)), llh, omega_eb_b_radps=np.zeros((n, 3)),
                                 att_cov=eye * 1e-10, vel_cov=eye * 1e-6, pos_cov=eye * 1e-4)
    C_bn = C_nb[0].T
    w_ib_b = C_bn @ earth.earth_rate_n(_LLH[0])
    f_b = -(C_bn @ earth.gravity_n(_LLH[0], _LLH[2]))
    imu = ImuSeries(t_s, np.broadcast_to(w_ib_b, (n, 3)).copy(), np.broadcast_to(f_b, (n, 3)).copy())
    install = Installation(np.array([0.0, -2.0, 0.0]), np.eye(3), FlexureModel((2.0, 5.0, 2.0), (0.01, 0.15, 0.01)),
                           ImuErrorModel(gyro_bias_deg_h=1.0, gyro_noise_deg_h=1.0, accel_bias_ug=100.0, accel_noise_ug=50.0))
    return imu, master, install


def warm_up(method: str = "ups", particles: int = 8) -> float:
    """Align :func:`resting_session` with ``method`` (every kernel of that method's forward pass
    and smoother runs once); returns the seconds it took.  The result is discarded: this exists
    for its side effects (imports, numba kernels loaded from their cache)."""
    t0 = time.perf_counter()
    run_segments(*resting_session(), TAConfig(attitude_sigma_deg=1.0), method, particles, 0)
    return time.perf_counter() - t0
