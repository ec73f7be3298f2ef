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

from ..config.flexure import FlexureModel
from ..config.sensors import ImuErrorModel
from ..series import ImuSeries, NavSeries
from ..warmup_data import resting_imu_and_master
from .model import Installation, TAConfig
from .pipeline import TASettings, run_segments


def resting_session() -> tuple[ImuSeries, NavSeries, Installation]:
    """A level sub-IMU at rest 2 m to the right of a level main POS at rest (4 s at 100 Hz,
    :func:`dpos_core.warmup_data.resting_imu_and_master`).
    Returns ``(imu, master, install)`` for :func:`~.pipeline.run_segments`."""
    imu, master = resting_imu_and_master()
    install = Installation(np.array([0.0, -2.0, 0.0]), np.eye(3), FlexureModel((2.0, 5.0, 2.0), (0.01, 0.15, 0.01)),
                           ImuErrorModel(gyro_bias_deg_h=1.0, gyro_noise_deg_h=1.0, accel_bias_ug=100.0, accel_noise_ug=50.0))
    return imu, master, install


def warm_up(method: str = "ups", particles: int = 8) -> float:
    """Align :func:`resting_session` with ``method`` (every kernel of that method's forward pass
    and smoother runs once); returns the seconds it took.  The result is discarded: this exists
    for its side effects (imports, numba kernels loaded from their cache)."""
    t0 = time.perf_counter()
    run_segments(*resting_session(), TASettings(method=method, particles=particles), cfg=TAConfig(attitude_sigma_deg=1.0))
    return time.perf_counter() - t0
