"""pos_master_node — the main POS.

``device: sim`` publishes the simulated master device live (dpos_ros.sim_device): the latched
/dpos/datum, /master/imu, /gnss/fix, /gnss/vel, /truth/master and /truth/antenna/<antennas
without IMU> (``publish_truth``), and /session/end after the last sample. The bytes are those of
``dpos-sim`` for the same scenario, aircraft, seed, duration and datum. When everything is
published the node stays up (late subscribers of the latched datum still get it) until
SIGINT/SIGTERM.

/master/nav (nav_msgs/Odometry, frame ``enu``, child ``master_imu``) by ``alignment``:

``reference``
    simulation only: the device's stream, truth + the paper's main-system noise.
``ifa``
    the node mechanizes the master IMU itself (dpos_ros.master_nav.MasterMechanization, numba,
    batches of up to 100 samples handed over by the device thread as a SimDevice tap, so the
    navigation keeps up with ``rate_factor`` 0 and is flow-controlled like the device's streams).
    It starts in simulation from truth at the session start with ``initial_heading_error_deg``
    (default: the scenario's ``ifa.initial_heading_error_deg``, else 0) and level errors 0, and
    publishes that initial state first (stamp = session start: the ifa_node starts its shadow
    strapdown from the first /master/nav), then one message per IMU sample with the IMU's stamp.
    ``/ifa/correction`` for epoch ``t_k`` resets the state at the sample ``t_k`` and re-integrates
    the samples stored after it (``ring_s``); ``/ifa/imu_bias`` stamped ``t_k`` is removed from
    the samples after ``t_k``; both as the ifa_node's closed loop does, so the navigation equals
    its strapdown (dpos_core.ifa.pipeline) to rounding. Already published messages are not
    re-published: a message reflects the corrections received before it was computed.
    Unaligned flag: until ``/ifa/status`` reports ALIGNED (or DEGRADED, i.e. aligned but
    inconsistent), the covariance is the filter's (from the latest correction; before the first
    one ``initial_sigma``, heading 100 deg) and ``/pos_master/status`` (DiagnosticArray,
    TRANSIENT_LOCAL, level WARN, message UNALIGNED) says so; ALIGNED: level OK.
``given``
    the same mechanization from a configured ``initial_state`` (default in simulation: truth at
    the session start), flagged aligned (message GIVEN) from the start. Decision: corrections and
    bias estimates of an ifa_node are applied here too when one runs (the shadow loop works from
    any start state; an ifa_node then refines a given state); without an ifa_node it is
    free-inertial. /ifa/status does not change the flag.

``device: ros`` (real drivers through dpos_ros.relay) is not implemented yet: the node refuses it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, datum_llh_rad, declare_config, format_config
from dpos_ros.sim_device import SimDevice, Tap, load_sim_session, use_device_fastdds_profile
from pos_master_node.params import PosMasterConfig

NODE_NAME = "pos_master_node"
NAV_TOPIC = "/master/nav"
STATUS_TOPIC = "/pos_master/status"
DEG = np.pi / 180.0
#: longest wait for an /ifa/correction before the device runs on (max_lead_s) [s]
LEAD_WAIT_S = 5.0


class PosMasterNode(Node):
    """The main POS node; see the module docstring.

    Raises:
        ParameterError: an invalid parameter, an unknown scenario/aircraft, a duration longer than
            the scenario, or ``device: ros`` (not implemented yet).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.device: SimDevice | None = None
        self.mech = None
        try:
            self.config: PosMasterConfig = declare_config(self, PosMasterConfig)
            cfg = self.config
            if cfg.device != "sim":
                raise ParameterError(
                    "device", cfg.device, "real drivers (device: ros) are not implemented yet; use device:=sim"
                )
            self.session = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
            if cfg.alignment in ("ifa", "given"):
                self._setup_mechanization()
        except ParameterError:
            self.destroy_node()
            raise
        self._start_sim()

    # ------------------------------------------------------------------ mechanization
    def _setup_mechanization(self) -> None:
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import MasterMechanization, initial_state_from_list, initial_state_from_truth
        from dpos_ros.qos import NAV_QOS, STATUS_QOS

        cfg = self.config
        sc = self.session.scenario
        datum = datum_llh_rad(cfg.datum)
        self.datum_llh = np.asarray(datum if datum is not None else self.session.datum_llh, dtype=float)
        self.origin_ns = int(cv.stamps_ns(sc.start_time_s, np.array([0.0]))[0])
        if cfg.alignment == "ifa":
            err = cfg.initial_heading_error_deg[0] if cfg.initial_heading_error_deg else float(sc.ifa.get("initial_heading_error_deg", 0.0))
            tr = self.session.truth("master", np.array([0.0]))
            initial = initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, err)
            self._initial_text = f"truth at the session start with a heading error of {err:g} deg"
        elif cfg.initial_state:
            try:
                initial = initial_state_from_list(cfg.initial_state, 0.0)
            except ValueError as e:
                raise ParameterError("initial_state", list(cfg.initial_state), str(e)) from None
            self._initial_text = f"the given state {list(cfg.initial_state)}"
        else:
            tr = self.session.truth("master", np.array([0.0]))
            initial = initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, 0.0)
            self._initial_text = "truth at the session start"
        self.mech = MasterMechanization(initial, cfg.ring_s)
        s = cfg.initial_sigma
        self._nav_cov = (np.eye(3) * s[0] ** 2, np.diag([s[3], s[4], s[2]]) ** 2 * DEG**2, np.eye(3) * s[1] ** 2)
        self._lock = threading.Lock()
        self._corrected = threading.Condition(self._lock)
        self._first_nav = True
        self.nav_published = 0
        self.ifa_status = "none"
        self.aligned = cfg.alignment == "given"
        self.sub_correction = self.create_subscription(
            cv_msg("nav_msgs/msg/Odometry"), "/ifa/correction", self._on_correction, NAV_QOS, raw=True)
        self.sub_bias = self.create_subscription(cv_msg("sensor_msgs/msg/Imu"), "/ifa/imu_bias", self._on_bias, NAV_QOS, raw=True)
        self.sub_status = self.create_subscription(DiagnosticArray, "/ifa/status", self._on_ifa_status, STATUS_QOS)
        self.status_pub = self.create_publisher(DiagnosticArray, STATUS_TOPIC, STATUS_QOS)
        self._publish_status()

    def _produce_nav(self, stream: Any, idx: np.ndarray) -> list[list[bytes]]:
        """SimDevice tap: /master/nav for a batch of /master/imu messages (device thread)."""
        from dpos_ros import cdr
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import body_rate_eb, stamp_s

        t_ns, vals = cdr.decode(cdr.layout("imu", cv.MASTER_FRAME), stream.rows[idx])
        om, fb = vals[:, 13:16], vals[:, 25:28]
        self._wait_for_corrections(float(stamp_s(t_ns[0], self.origin_ns)))
        with self._lock:
            mech = self.mech
            first = self._first_nav
            self._first_nav = False
            nav, keep, warnings = mech.add(stamp_s(t_ns, self.origin_ns), om, fb)
            gyro = np.array([mech.bias_at(t)[0] for t in nav.t_s]).reshape(-1, 3)
            cov = self._nav_cov
        log = self.get_logger()
        for w in warnings:
            log.warning(w)
        out: list[list[bytes]] = [[] for _ in range(idx.size)]
        if first:
            s = mech.initial
            v0 = cv.odometry_values_cov(s.llh[None], s.vel_n_mps[None], s.q_nb[None], self.datum_llh, None, *cov)
            out[0].append(bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([self.origin_ns]), v0)[0]))
        if len(nav):
            w_eb = body_rate_eb(nav.q_nb, nav.llh, nav.vel_n_mps, om[keep] - gyro)
            v = cv.odometry_values_cov(nav.llh, nav.vel_n_mps, nav.q_nb, self.datum_llh, w_eb, *cov)
            rows = cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, t_ns[keep], v)
            for r, k in zip(rows, np.flatnonzero(keep)):
                out[k].append(bytes(r))
        self.nav_published += int(len(nav)) + int(first)
        return out

    def _wait_for_corrections(self, t_s: float) -> None:
        """Flow control of the IFA loop (``rate_factor`` 0, ``max_lead_s``): while an ifa_node
        publishes corrections, do not run more than max_lead_s ahead of the last one (bounded waits
        of LEAD_WAIT_S; the device thread waits on a condition, which releases the GIL)."""
        cfg = self.config
        if cfg.rate_factor != 0.0 or cfg.max_lead_s <= 0.0 or self.count_publishers("/ifa/correction") == 0:
            return
        deadline = time.monotonic() + LEAD_WAIT_S
        with self._corrected:
            while t_s - (self.mech.last_correction_t_s or 0.0) > cfg.max_lead_s:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0 or (self.device is not None and self.device.stopping):
                    self.get_logger().warning(
                        f"no /ifa/correction for {LEAD_WAIT_S:g} s (mechanization at t={t_s:.2f} s, last correction "
                        f"{self.mech.last_correction_t_s}); continuing without waiting for the IFA loop")
                    return
                self._corrected.wait(min(remaining, 0.05))

    def _on_correction(self, raw: bytes) -> None:
        from dpos_core.strapdown import NavState
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import stamp_s

        t_ns, v = cv.decode_raw(raw, "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        blk = cv.odometry_from_values(np.array([t_ns]), v[None], self.datum_llh)
        pos, att, vel = cv.odometry_cov_n(blk, self.datum_llh)
        try:
            state = NavState(float(stamp_s(t_ns, self.origin_ns)), blk.q_nb[0], blk.vel_n_mps[0], blk.llh[0])
        except ValueError as e:
            self.get_logger().warning(f"/ifa/correction at stamp {t_ns} ns: {e}: ignored")
            return
        with self._lock:
            warning = self.mech.correct(state)
            if warning is None:
                self._nav_cov = (pos[0], att[0], vel[0])
            self._corrected.notify_all()
        if warning is not None:
            self.get_logger().warning(f"/ifa/correction: {warning}")
        self._publish_status()

    def _on_bias(self, raw: bytes) -> None:
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import stamp_s

        t_ns, v = cv.decode_raw(raw, "imu", cv.MASTER_FRAME)
        g, a, _, _ = cv.imu_bias_from_values(v[None])
        with self._lock:
            warning = self.mech.set_bias(float(stamp_s(t_ns, self.origin_ns)), g[0], a[0])
        if warning is not None:
            self.get_logger().warning(f"/ifa/imu_bias: {warning}")

    def _on_ifa_status(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name.startswith("ifa_node"):
                was = self.aligned
                self.ifa_status = st.message
                if self.config.alignment == "ifa":
                    self.aligned = st.message in ("ALIGNED", "DEGRADED")
                if self.aligned != was:
                    self.get_logger().info(f"/ifa/status {st.message}: /master/nav is {'aligned' if self.aligned else 'UNALIGNED'}")
                self._publish_status()

    def _publish_status(self) -> None:
        mech = self.mech
        from dpos_ros import conversions as cv

        given = self.config.alignment == "given"
        st_name = NODE_NAME
        level = DiagnosticStatus.OK if self.aligned else DiagnosticStatus.WARN
        message = "GIVEN" if given else ("ALIGNED" if self.aligned else "UNALIGNED")
        with self._lock:
            values = {
                "alignment": self.config.alignment,
                "ifa_status": self.ifa_status,
                "corrections": mech.corrections,
                "last_correction_t_s": "none" if mech.last_correction_t_s is None else f"{mech.last_correction_t_s:.3f}",
                "imu_dropped": mech.dropped,
                "nav_t_s": f"{mech.t_s:.3f}",
                "heading_sigma_deg": f"{np.sqrt(self._nav_cov[1][2, 2]) / DEG:.6g}",
            }
        self.status_pub.publish(cv.diagnostic_array(self.get_clock().now().to_msg(), st_name, "master_imu", level, message, values))

    # ------------------------------------------------------------------ device
    def _start_sim(self) -> None:
        from dpos_ros.sim_streams import ODOMETRY, device_streams, session_id

        cfg = self.config
        session = self.session
        log = self.get_logger()
        with_nav = cfg.alignment == "reference"
        topics = ["/dpos/datum", "/master/imu", "/gnss/fix", "/gnss/vel", NAV_TOPIC]
        if cfg.publish_truth:
            topics.append("/truth/master")
            topics += [f"/truth/antenna/{a.name}" for a in session.scenario.aircraft.antennas if a.sub_imu is None]
        topics.append("/session/end")
        if not with_nav:
            topics.append(STATUS_TOPIC)
        datum = datum_llh_rad(cfg.datum)
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'scenario', 'aircraft_config', 'seed', 'duration', 'rate_factor', 'alignment', 'publish_truth'))}"
            f" datum={list(cfg.datum) if cfg.datum else 'scenario start'}: session {session_id(session)},"
            f" aircraft {session.scenario.aircraft.name}, {session.duration_s:g} s -> publishing {', '.join(topics)}"
        )
        if cfg.alignment == "ifa":
            log.warning(
                f"alignment 'ifa': {NAV_TOPIC} is mechanized from {self._initial_text} and flagged UNALIGNED "
                f"(filter covariance, {STATUS_TOPIC}) until /ifa/status reports ALIGNED; corrections come from an ifa_node"
            )
        elif cfg.alignment == "given":
            log.info(f"alignment 'given': {NAV_TOPIC} is mechanized from {self._initial_text}")

        def streams():
            out = device_streams(session, "master", truth=cfg.publish_truth, datum_llh=datum)
            return [s for s in out if with_nav or s.topic != NAV_TOPIC]

        def finished(device: SimDevice) -> None:
            log.info(
                f"session {session_id(session)} ended ({device.published} messages published); staying up so that "
                f"late subscribers get the latched /dpos/datum (SIGINT/SIGTERM to stop)"
            )

        taps = [] if with_nav else [Tap("/master/imu", NAV_TOPIC, ODOMETRY, self._produce_nav, qos="nav", max_batch=100)]
        self.device = SimDevice(
            self, streams, cfg.rate_factor, min_subscribers=cfg.min_subscribers,
            wait_subscribers_s=cfg.wait_subscribers_s, on_finished=finished, taps=taps,
        ).start()

    def destroy_node(self) -> None:
        if self.device is not None:
            self.device.stop()
        super().destroy_node()


def cv_msg(msgtype: str) -> type:
    from dpos_ros.sim_device import message_class

    return message_class(msgtype)


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_master_node``."""
    use_device_fastdds_profile()  # prompt acknowledgements for the device's flow control
    return run_node(PosMasterNode, NODE_NAME, argv)
