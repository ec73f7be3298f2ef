"""sar_nav_node — the main POS navigated with SAR scene-matching fixes and a barometer instead of GNSS
([Yan2016]; docs/sar.md): EKF, UKF, or the bootstrap, regularized and MCMC-regularized particle filters.

The core is a batch filter over a session (:func:`dpos_core.sar.navigate.navigate`: the free SINS
mechanized from the initial state over the whole IMU record, then the 16-state error filter), so the
node buffers the session and navigates it when the session ends - the way transfer_align_node
processes its sessions - and publishes the result at the filter epochs.

Inputs (design.md "Topics"): ``/master/imu`` (every sample; its covariances give the filter's
white noise), ``/master/nav`` (the first message is the initial state and its stamp the time origin:
pos_master_node publishes the state its mechanization starts from first; the subscription is closed
after it - the rest of the stream is not taken - and reopened when the session is processed),
``/sar/fix`` (PoseWithCovarianceStamped, ``enu``), ``/baro/pressure`` (FluidPressure), ``/dpos/datum``
(latched; or the ``datum`` parameter).  A session ends with ``/session/end`` (the simulated device's:
processed once ``/master/imu`` has reached its stamp, or after ``finalize_timeout_s``) or the
``~/finalize`` service (std_srvs/Trigger: what is buffered).  Messages that arrive while a session is
processed start the next one.

Outputs: ``/sar_nav/nav`` (Odometry, ``enu`` / ``master_imu``, one per filter epoch: the corrected
SINS with the filter's covariances; the twist's angular part 0, not estimated) and ``/sar_nav/status``
(DiagnosticArray, latched; 1 Hz and on every change): message ``WAITING`` (STALE: no data yet),
``BUFFERING`` (OK), ``PROCESSING`` (OK), ``DONE`` (OK) or ``FAILED: <why>`` (ERROR: the session's
data cannot be navigated - a missing stream, a barometer that misses a filter step, no noise
variance in the IMU messages); keys in design.md "Diagnostics" (for the particle filters the ESS:
``mean_ess``, ``min_ess``, ``final_ess``, and ``mean_accept``, the MH acceptance of mcmc_rpf).
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure, Imu, NavSatFix
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from dpos_core.errors import NumericalFailure
from dpos_core.units import FloatArray
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS, STATUS_QOS, STREAM_DEPTH, keep_all
from dpos_ros.io.flow import subscribe_draining, use_device_fastdds_profile
from dpos_ros.products.sar import SarInputError, odometry, run, session_inputs, summary
from dpos_ros.runtime.node_main import run_node
from dpos_ros.runtime.params import ParameterError, datum_llh_rad, declare_config, format_config
from sar_nav_node.params import SarNavConfig

NODE_NAME = "sar_nav_node"
STATUS_NAME = "sar_nav_node: SINS/SAR navigation"
#: period of the finalize check and of the status [s]
TIMER_S = 0.2
STATUS_PERIOD_S = 1.0
INPUT_QOS = keep_all(SENSOR_QOS)
#: /sar_nav/nav is published in batches of half the stream depth, each after the previous one was acknowledged
NAV_BATCH = STREAM_DEPTH // 2
ACK_WAIT_S = 30.0
_LEVELS = {"WAITING": DiagnosticStatus.STALE, "BUFFERING": DiagnosticStatus.OK, "PROCESSING": DiagnosticStatus.OK,
           "DONE": DiagnosticStatus.OK, "FAILED": DiagnosticStatus.ERROR}


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class _Session:
    """One session's buffered messages."""

    def __init__(self) -> None:
        self.imu: list[bytes] = []
        self.last_imu_ns = -1
        self.nav0: bytes | None = None
        self.fixes: list[PoseWithCovarianceStamped] = []
        self.baro: list[FluidPressure] = []

    def empty(self) -> bool:
        return not (self.imu or self.nav0 or self.fixes or self.baro)


class SarNavNode(Node):
    """SINS/SAR navigation node; see the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # the worker thread publishes too: destroy_node() stops it from publishing before the publishers go
        self._pub_lock = threading.Lock()
        self._closing = False
        try:
            self.config: SarNavConfig = declare_config(self, SarNavConfig)
            try:
                self.settings = self.config.settings()
            except ValueError as e:
                raise ParameterError("method", self.config.method, str(e)) from None
            self._setup()
        except ParameterError:
            self.destroy_node()
            raise

    def _setup(self) -> None:
        cfg = self.config
        datum = datum_llh_rad(cfg.datum)
        self.datum_llh: FloatArray | None = None if datum is None else np.asarray(datum, dtype=float)
        self._session = _Session()
        self._end_ns: int | None = None  # /session/end's stamp, waiting for the IMU to reach it
        self._end_wall = 0.0
        self._end_id = ""
        self._worker: threading.Thread | None = None
        self._lock = threading.Lock()
        self.state = "WAITING"
        self.message = "WAITING"
        self.sessions_done = 0
        self.results: dict[str, Any] = {}
        self.last_error = ""
        self.nav_published = 0
        self._last_status = 0.0
        self.pub_nav = self.create_publisher(Odometry, T.SAR_NAV, NAV_QOS)
        self.pub_status = self.create_publisher(DiagnosticArray, T.SAR_NAV_STATUS, STATUS_QOS)
        subscribe_draining(self, Imu, T.MASTER_IMU, self._on_imu, INPUT_QOS, raw=True)
        # /master/nav stays subscribed: only the first message of a session is kept (the initial state).  The
        # subscription is never destroyed while spinning - a multi-threaded executor may be adding its QoS event
        # handlers to a wait set at that moment (rclpy raises InvalidHandle in the executor's thread).
        self.create_subscription(Odometry, T.MASTER_NAV, self._on_nav, keep_all(NAV_QOS), raw=True)
        subscribe_draining(self, PoseWithCovarianceStamped, T.SAR_FIX, self._on_fix, INPUT_QOS)
        subscribe_draining(self, FluidPressure, T.BARO_PRESSURE, self._on_baro, INPUT_QOS)
        self.create_subscription(Header, T.SESSION_END, self._on_session_end, NAV_QOS)
        if self.datum_llh is None:
            self.create_subscription(NavSatFix, T.DATUM, self._on_datum, DATUM_QOS)
        self.create_service(Trigger, "~/finalize", self._on_finalize)
        self.create_timer(TIMER_S, self._on_timer)
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(cfg, ('method', 'particles', 'seed', 'bandwidth_scale', 'filter_rate_hz'))}: subscribing "
            f"/master/imu, /master/nav (initial state), /sar/fix, /baro/pressure{'' if self.datum_llh is not None else ', /dpos/datum'}, "
            "/session/end -> publishing /sar_nav/nav, /sar_nav/status when a session ends")
        self._publish_status()

    # ------------------------------------------------------------------ inputs
    def _buffering(self) -> None:
        if self.state in ("WAITING", "DONE", "FAILED") and self._worker is None:
            self.state = self.message = "BUFFERING"

    def _on_datum(self, msg: NavSatFix) -> None:
        if self.datum_llh is None:
            self.datum_llh = cv.datum_from_msg(msg)

    def _on_imu(self, raw: bytes) -> None:
        s = self._session
        s.imu.append(bytes(raw))
        s.last_imu_ns = max(s.last_imu_ns, cv.raw_stamp_ns(raw))
        self._buffering()

    def _on_nav(self, raw: bytes) -> None:
        """The session's first /master/nav is its initial state; the rest of the stream (one message per IMU
        sample) is taken and dropped."""
        if self._session.nav0 is None:
            self._session.nav0 = bytes(raw)
            self._buffering()

    def _on_fix(self, msg: PoseWithCovarianceStamped) -> None:
        self._session.fixes.append(msg)
        self._buffering()

    def _on_baro(self, msg: FluidPressure) -> None:
        self._session.baro.append(msg)
        self._buffering()

    def _on_session_end(self, msg: Header) -> None:
        self._end_ns, self._end_wall, self._end_id = _stamp_ns(msg), time.monotonic(), msg.frame_id
        self.get_logger().info(f"/session/end at stamp {self._end_ns} ns ({msg.frame_id}): navigating once /master/imu reaches it")

    def _on_finalize(self, request: Any, response: Any) -> Any:
        if self._worker is not None:
            response.success, response.message = False, "a session is already being processed"
        elif self._session.empty():
            response.success, response.message = False, "no data buffered: nothing to navigate"
        else:
            self._start(self._end_id or "finalize")
            response.success, response.message = True, f"navigating {len(self._session_taken.imu)} IMU samples with {self.config.method}"
        return response

    def _on_timer(self) -> None:
        if self._end_ns is not None and self._worker is None:
            s = self._session
            if s.last_imu_ns >= self._end_ns or time.monotonic() - self._end_wall > self.config.finalize_timeout_s:
                if s.last_imu_ns < self._end_ns:
                    self.get_logger().warning(f"/master/imu did not reach the session's end ({self._end_ns} ns) within "
                                              f"finalize_timeout_s: navigating what came (up to {s.last_imu_ns} ns)")
                self._start(self._end_id)
        if time.monotonic() - self._last_status >= STATUS_PERIOD_S:
            self._publish_status()

    # ------------------------------------------------------------------ processing
    def _start(self, session_id: str) -> None:
        """Take the buffered session and navigate it in a worker thread (the executor stays free)."""
        self._session_taken, self._session = self._session, _Session()
        self._end_ns, self._end_id = None, ""
        self.state = self.message = "PROCESSING"
        self._publish_status()
        self._worker = threading.Thread(target=self._process, args=(self._session_taken, session_id), name="sar_nav", daemon=True)
        self._worker.start()

    def _process(self, s: _Session, session_id: str) -> None:
        log = self.get_logger()
        t_wall = time.monotonic()
        try:
            res, summ = self._navigate(s)
            t_ns, rows = odometry(res, self._origin_ns, self._datum_used)
            self._publish_flow_controlled(rows)
            with self._lock:
                self.results = summ | {"processing_s": round(time.monotonic() - t_wall, 3), "session": session_id}
                self.nav_published += len(rows)
                self.sessions_done += 1
                self.state = self.message = "DONE"
                self.last_error = ""
            log.info(f"session {session_id}: {summ['epochs']} epochs navigated with {self.config.method} in "
                     f"{time.monotonic() - t_wall:.1f} s, published on {T.SAR_NAV}"
                     + (f"; mean ESS {summ['mean_ess']:.1f} of {summ['particles']}" if "mean_ess" in summ else ""))
        except (SarInputError, NumericalFailure) as e:
            with self._lock:
                self.state, self.message, self.last_error = "FAILED", f"FAILED: {e}", str(e)
            log.error(f"session {session_id}: cannot navigate: {e}")
        except Exception as e:  # a bug: the thread cannot stop the node; say so loudly
            with self._lock:
                self.state, self.message, self.last_error = "FAILED", f"FAILED: {type(e).__name__}: {e}", traceback.format_exc()
            log.error(f"session {session_id}: navigation failed:\n{traceback.format_exc()}")
        finally:
            self._worker = None
            self._publish_status()

    def _publish_flow_controlled(self, rows: Any) -> None:
        """Publish /sar_nav/nav; before a batch would exceed half the stream's KEEP_LAST depth of unacknowledged
        messages, wait (polling: rclpy holds the GIL in the wait) until the reliable subscribers acknowledged
        the last batch (at most ``ACK_WAIT_S`` per batch: a subscriber that went away is not waited for).
        Stops when the node is being destroyed."""
        for lo in range(0, len(rows), NAV_BATCH):
            if lo:
                deadline = time.monotonic() + ACK_WAIT_S
                while not self._acked() and time.monotonic() < deadline:
                    time.sleep(0.01)
            with self._pub_lock:
                if self._closing:
                    return
                for r in rows[lo:lo + NAV_BATCH]:
                    self.pub_nav.publish(bytes(r))

    def _acked(self) -> bool:
        """Every /sar_nav/nav message acknowledged by the reliable subscribers (True once the node is being destroyed)."""
        with self._pub_lock:
            return self._closing or self.pub_nav.wait_for_all_acked(Duration(nanoseconds=0))

    def destroy_node(self) -> None:
        """Destroy the node; from now on the worker thread (a navigation may be in progress: its result
        is lost with the node) publishes nothing, so it never uses a destroyed publisher."""
        with self._pub_lock:
            self._closing = True
        super().destroy_node()

    def _navigate(self, s: _Session) -> tuple[Any, dict[str, Any]]:
        missing = [t for t, have in ((T.MASTER_IMU, s.imu), (T.MASTER_NAV, s.nav0), (T.SAR_FIX, s.fixes), (T.BARO_PRESSURE, s.baro)) if not have]
        if self.datum_llh is None:
            missing.append(f"{T.DATUM} (or the datum parameter)")
        if missing:
            raise SarInputError(f"no message on {', '.join(missing)}")
        datum = np.asarray(self.datum_llh, dtype=float)
        t_imu, v_imu = cv.decode_raw_batch(s.imu, "imu", cv.MASTER_FRAME)
        assert s.nav0 is not None
        nav0 = cv.decode_raw(s.nav0, "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        fixes = [cv.sar_fix_from_msg(m, datum) for m in s.fixes]
        baro = [cv.baro_from_msg(m) for m in s.baro]
        inputs = session_inputs(cv.imu_from_values(t_imu, v_imu), nav0, fixes, baro, datum, self.config.baro_height_offset_m)
        res = run(inputs, self.settings)
        self._origin_ns, self._datum_used = inputs.origin_ns, datum
        return res, summary(res, self.settings, inputs)

    # ------------------------------------------------------------------ status
    def _publish_status(self) -> None:
        self._last_status = time.monotonic()
        cfg = self.config
        s = self._session
        with self._lock:
            values: dict[str, Any] = {"state": self.state.lower(), "method": cfg.method,
                                      "particles": cfg.particles if cfg.method not in ("ekf", "ukf") else 0, "seed": cfg.seed,
                                      "bandwidth_scale": cfg.bandwidth_scale, "sessions_done": self.sessions_done,
                                      "buffered_imu": len(s.imu), "buffered_sar_fixes": len(s.fixes), "buffered_baro": len(s.baro),
                                      "nav_published": self.nav_published, "last_error": self.last_error.splitlines()[-1] if self.last_error else ""}
            for k, v in self.results.items():
                if isinstance(v, dict):
                    values.update({f"{k}/{kk}": vv for kk, vv in v.items()})
                elif isinstance(v, (list, tuple)):
                    values[k] = " ".join(f"{x:.6g}" for x in v)
                elif isinstance(v, float):
                    values[k] = f"{v:.6g}"
                else:
                    values[k] = v
            message, level = self.message, _LEVELS[self.state]
        with self._pub_lock:  # (also from the worker thread: not once the node is being destroyed)
            if not self._closing:
                self.pub_status.publish(cv.diagnostic_array(self.get_clock().now().to_msg(), STATUS_NAME, cv.MASTER_FRAME, level,
                                                            message, values))


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``sar_nav_node``."""
    use_device_fastdds_profile()  # reader resource limits off (design.md "QoS"), short heartbeats
    return run_node(SarNavNode, NODE_NAME, argv)


if __name__ == "__main__":
    raise SystemExit(main())
