"""Warm-ups of the live main-POS nodes: before its data flow, ifa_node runs :func:`warm_up` and
pos_master_node (``alignment: ifa | given``) :func:`warm_up_mechanization`, so that every numba
kernel of the filter or of the mechanization is compiled or loaded from its cache then, not inside
the live loop (on a fresh install the first compilation of the filters' kernels took seconds and
ifa_node's first corrections came late; the mechanization's first IMU batch took ~1 s instead of
~0.3 s with warm caches and under a millisecond after)."""

from __future__ import annotations

import time

import numpy as np

from ..series import GnssSeries
from ..strapdown import NavState
from ..warmup_data import resting_imu_and_master
from .mechanization import MasterMechanization
from .pipeline import IfaFilterConfig, run


def warm_up(cfg: IfaFilterConfig, method: str = "add2") -> float:
    """Align a main POS at rest (:func:`dpos_core.warmup_data.resting_imu_and_master`: 4 s at 100 Hz) with
    GNSS fixes for 2 s then none (the measurement update and the outage's time updates run);
    returns the seconds it took.  The result is discarded."""
    t0 = time.perf_counter()
    imu, master = resting_imu_and_master()
    t, llh = np.array([1.0, 2.0]), np.asarray(master.llh[0], dtype=float)
    gnss = GnssSeries(t, np.broadcast_to(llh, (2, 3)).copy(), np.full((2, 3), 0.02), np.zeros((2, 3)), np.full((2, 3), 0.01))
    initial = NavState(0.0, np.asarray(master.q_nb[0], dtype=float), np.zeros(3), llh.copy())
    run(imu, gnss, np.zeros(3), cfg, method, initial)
    return time.perf_counter() - t0


def warm_up_mechanization() -> float:
    """Run :class:`dpos_core.ifa.mechanization.MasterMechanization` over 0.4 s of a main IMU at rest
    (100 Hz, two batches) with a correction at an integrated sample (the ring re-integrated) and a
    bias compensation; returns the seconds it took.  The result is discarded."""
    t0 = time.perf_counter()
    imu, master = resting_imu_and_master()
    llh = np.asarray(master.llh[0], dtype=float)
    q = np.asarray(master.q_nb[0], dtype=float)
    n = min(40, imu.t_s.size)
    t = np.asarray(imu.t_s[:n], dtype=float)
    mech = MasterMechanization(NavState(float(t[0]) - 0.01, q, np.zeros(3), llh.copy()), ring_s=1.0)
    half = n // 2
    mech.add(t[:half], imu.omega_radps[:half], imu.f_mps2[:half])
    mech.correct(NavState(float(t[half // 2]), q, np.zeros(3), llh.copy()))
    mech.set_bias(float(t[half - 1]), np.zeros(3), np.zeros(3))
    mech.add(t[half:n], imu.omega_radps[half:n], imu.f_mps2[half:n])
    return time.perf_counter() - t0
