"""Warm-up of the in-flight alignment (ifa_node): before its data flow, the node runs :func:`warm_up`
so that every numba kernel of its filter is compiled or loaded from its cache then, not inside the
live loop (on a fresh install the first compilation of the filters' kernels took seconds and its
first corrections came late)."""

from __future__ import annotations

import time

import numpy as np

from ..series import GnssSeries
from ..strapdown import NavState
from ..ta.warmup import resting_session
from .pipeline import IfaFilterConfig, run


def warm_up(cfg: IfaFilterConfig, method: str = "add2") -> float:
    """Align a main POS at rest (:func:`dpos_core.ta.warmup.resting_session`'s 4 s at 100 Hz) with
    GNSS fixes for 2 s then none (the measurement update and the outage's time updates run);
    returns the seconds it took.  The result is discarded."""
    t0 = time.perf_counter()
    imu, master, _ = resting_session()
    t, llh = np.array([1.0, 2.0]), np.asarray(master.llh[0], dtype=float)
    gnss = GnssSeries(t, np.broadcast_to(llh, (2, 3)).copy(), np.full((2, 3), 0.02), np.zeros((2, 3)), np.full((2, 3), 0.01))
    initial = NavState(0.0, np.asarray(master.q_nb[0], dtype=float), np.zeros(3), llh.copy())
    run(imu, gnss, np.zeros(3), cfg, method, initial)
    return time.perf_counter() - t0
