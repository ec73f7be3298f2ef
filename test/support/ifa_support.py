"""Helpers shared by the in-flight-alignment tests (core and nodes): a truth start with a heading
error, an approximate llh difference in metres, and a background executor for in-process nodes."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from dpos_core.ifa.mechanization import initial_state_from_truth
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState

R_EARTH_M = 6.378e6


def truth_initial(ss: SimulatedSession, heading_err_deg: float) -> NavState:
    """The truth at t = 0 with a heading error (level errors 0)."""
    tr = ss.truth("master", np.array([0.0]))
    return initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, heading_err_deg)


def llh_err_m(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Approximate position difference [m] of llh arrays (..., 3) near 40 deg latitude."""
    d = np.asarray(a) - np.asarray(b)
    return np.linalg.norm(d * np.array([R_EARTH_M, R_EARTH_M * np.cos(0.7), 1.0]), axis=-1)


class Spinner:
    """A MultiThreadedExecutor spinning the nodes in a background thread; :meth:`stop` stops their
    simulated devices (if any), the spinning, the executor once its callbacks are done, and destroys
    the nodes (that order: ros_wait.stop_and_destroy)."""

    def __init__(self, context: Any, nodes: list[Any]) -> None:
        from rclpy.executors import MultiThreadedExecutor

        self.context = context
        self.executor = MultiThreadedExecutor(num_threads=4, context=context)
        self.nodes = nodes
        for n in nodes:
            self.executor.add_node(n)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        # spin_once until stop() (not spin(): only executor.shutdown() ends that, and it must wait
        # until the callbacks handed to the pool are done)
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def stop(self) -> None:
        from ros_wait import stop_and_destroy

        for n in self.nodes:  # the devices' threads first, while the executor still serves their nodes
            if getattr(n, "device", None) is not None:
                n.device.stop()
        self._stop.set()
        self.thread.join(10.0)
        if self.thread.is_alive():
            raise AssertionError("the executor's spin thread did not stop within 10 s")
        stop_and_destroy(self.executor, self.nodes)
