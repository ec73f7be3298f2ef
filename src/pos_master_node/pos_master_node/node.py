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

``device: ros`` (real drivers; issue #5)
    A dpos_ros.relay.DeviceRelay relays the drivers' standard topics, relative names to remap:
    ``imu_in`` (sensor_msgs/Imu) -> /master/imu (frame ``master_imu``, rotated into our FLU body
    axes by ``input_rotation_rpy_deg``), ``fix_in`` (NavSatFix) -> /gnss/fix and ``vel_in``
    (TwistWithCovarianceStamped, ENU) -> /gnss/vel (frame ``gnss``), stamps kept; bad messages
    (NaN, duplicate / out-of-order / zero stamps, NO_FIX, unknown covariance) are rejected and
    counted, gaps counted, on the DiagnosticArray ``/<node name>/status`` (``input_reliability``
    selects the input QoS). Every relayed IMU message is queued for the mechanization
    (``alignment: ifa | given``); a timer (``RELAY_TICK_S``) integrates the queue in batches of at
    most ``MAX_BATCH`` samples (``MAX_PER_TICK`` per tick, so the executor stays responsive) and
    publishes /master/nav for every IMU stamp - what the simulated device's tap does in its thread;
    /ifa/correction, /ifa/imu_bias and the UNALIGNED / ALIGNED / GIVEN flag as above. No flow
    control (``max_lead_s``): a real device runs in real time.

    Initial state (its stamp is the time origin; the first /master/nav carries it, then one message
    per later IMU stamp; IMU samples up to it are not integrated, counted as ``imu_before_start``):

    ``given``: ``initial_state`` (required) is the state at the first IMU sample relayed once the
    datum is known (with the ``datum`` parameter: the first IMU sample; without it: the first one
    after the first valid fix - set ``datum`` when the epoch matters).
    ``ifa``: the first valid /gnss/fix with a /gnss/vel of the same stamp (within
    ``FIX_VEL_MATCH_NS``): position = the fix, moved from the antenna to the IMU by the aircraft's
    ``gnss_lever_arm_m`` with the initial attitude when ``aircraft_config`` is set (else the
    antenna position: a lever arm of a few m is well inside the initial position sigma);
    velocity = the GNSS velocity (the antenna's; the rotation term is ignored); heading = course
    over ground ``atan2(vE, vN)`` (aviation heading, clockwise from north; a crab angle in wind
    is part of the initial heading error the IFA removes); pitch = roll = 0; covariance
    ``initial_sigma`` (heading 100 deg by default). Below ``min_course_speed_mps`` ground speed
    the course is meaningless: the ``initial_state`` heading is used when given, else the fix is
    skipped with a warning and the node waits for a faster one.

    ``/dpos/datum`` (latched): the ``datum`` parameter when set (stamped with the node's clock at
    start), else the first valid /gnss/fix (the antenna position, the fix's stamp). /master/nav is not
    published before the datum is known. ``/session/end`` is never published by a live device:
    the operator (or dpos-record) ends the session. ``alignment: reference`` is simulation only
    (ParameterError); the simulator parameters (scenario, seed, duration, rate_factor,
    publish_truth, min_subscribers, wait_subscribers_s, initial_heading_error_deg, max_lead_s) are
    ignored with an info line naming those that were set.
"""

from __future__ import annotations

from dpos_core.units import DEG

import math
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, datum_llh_rad, declare_config, format_config
from dpos_ros.relay import DeviceRelay, Route, rotation_from_rpy_deg
from dpos_ros.sim_device import SimDevice, Tap, load_sim_session, use_device_fastdds_profile
from pos_master_node.params import PosMasterConfig

NODE_NAME = "pos_master_node"
NAV_TOPIC = "/master/nav"
STATUS_TOPIC = "/pos_master/status"
#: longest wait for an /ifa/correction before the device runs on (max_lead_s) [s]
LEAD_WAIT_S = 5.0
#: The driver topics of ``device: ros`` (relative: remap them, ``-r imu_in:=/driver/imu``).
IMU_INPUT, FIX_INPUT, VEL_INPUT = "imu_in", "fix_in", "vel_in"
#: Parameters of the simulated device only (ignored by ``device: ros``).
SIM_ONLY = ("scenario", "seed", "duration", "rate_factor", "publish_truth", "min_subscribers", "wait_subscribers_s",
            "initial_heading_error_deg", "max_lead_s")
#: ``device: ros``: period of the mechanization timer [s], samples per batch, samples per tick
RELAY_TICK_S = 0.02
MAX_BATCH = 100
MAX_PER_TICK = 1000
#: ``device: ros``, ``alignment: ifa``: a /gnss/vel belongs to a /gnss/fix within this [ns]
FIX_VEL_MATCH_NS = 50_000_000
#: recent fixes / velocities kept while waiting for the initial state
GNSS_KEEP = 20
#: repeated "waiting" warnings at most this often [s]
WARN_THROTTLE_S = 5.0


class PosMasterNode(Node):
    """The main POS node; see the module docstring.

    Raises:
        ParameterError: an invalid parameter, an unknown scenario/aircraft, a duration longer than
            the scenario; with ``device: ros``: ``alignment: reference`` or ``alignment: given``
            without ``initial_state``.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.device: SimDevice | None = None
        self.relay: DeviceRelay | None = None
        self.mech = None
        try:
            self.config: PosMasterConfig = declare_config(self, PosMasterConfig)
            cfg = self.config
            if cfg.device == "ros":
                self._check_ros_config()
            else:
                self.session = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
            if cfg.alignment in ("ifa", "given"):
                self._setup_mechanization()
        except ParameterError:
            self.destroy_node()
            raise
        if cfg.device == "ros":
            self._start_relay()
        else:
            self._start_sim()

    def _check_ros_config(self) -> None:
        """``device: ros``: the alignment, the initial state and the aircraft's GNSS lever arm."""
        from dpos_ros.master_nav import initial_state_from_list

        cfg = self.config
        if cfg.alignment == "reference":
            raise ParameterError("alignment", cfg.alignment,
                                 "simulation only (truth + main-system noise): with device:=ros use ifa or given")
        if cfg.alignment == "given" and not cfg.initial_state:
            raise ParameterError("initial_state", list(cfg.initial_state),
                                 "required with device:=ros and alignment:=given: [lat_deg, lon_deg, h_m, vE, vN, vU, "
                                 "heading_deg, pitch_deg, roll_deg] at the first IMU sample")
        if cfg.initial_state:
            try:
                initial_state_from_list(cfg.initial_state, 0.0)
            except ValueError as e:
                raise ParameterError("initial_state", list(cfg.initial_state), str(e)) from None
        self.lever_arm_b_m: np.ndarray | None = None
        if cfg.aircraft_config:
            from dpos_core.config import ConfigError, load_aircraft

            try:
                self.lever_arm_b_m = np.asarray(load_aircraft(cfg.aircraft_config).gnss_lever_arm_m, dtype=float)
            except ConfigError as exc:
                raise ParameterError("aircraft_config", cfg.aircraft_config, str(exc)) from None

    # ------------------------------------------------------------------ mechanization
    def _setup_mechanization(self) -> None:
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import MasterMechanization, initial_state_from_list, initial_state_from_truth

        cfg = self.config
        datum = datum_llh_rad(cfg.datum)
        if cfg.device == "ros":  # the initial state comes with the data (_try_start)
            self.datum_llh = None if datum is None else np.asarray(datum, dtype=float)
            self.origin_ns = None
            self._setup_feedback()
            return
        sc = self.session.scenario
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
        self._setup_feedback()

    def _setup_feedback(self) -> None:
        """The nav covariance before the first correction, the /ifa/* subscriptions, the status."""
        from dpos_ros.qos import NAV_QOS, STATUS_QOS

        cfg = self.config
        s = cfg.initial_sigma
        self._nav_cov = (np.eye(3) * s[0] ** 2, np.diag([s[3], s[4], s[2]]) ** 2 * DEG**2, np.eye(3) * s[1] ** 2)
        self._lock = threading.Lock()
        self._corrected = threading.Condition(self._lock)
        self._first_nav = True
        self.nav_published = 0
        self.imu_before_start = 0
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
        from dpos_ros.master_nav import stamp_s

        t_ns, vals = cdr.decode(cdr.layout("imu", cv.MASTER_FRAME), stream.rows[idx])
        self._wait_for_corrections(float(stamp_s(t_ns[0], self.origin_ns)))
        head, rows, keep = self._mechanize(t_ns, vals[:, 13:16], vals[:, 25:28])
        out: list[list[bytes]] = [[] for _ in range(idx.size)]
        if head is not None:
            out[0].append(head)
        for r, k in zip(rows, np.flatnonzero(keep)):
            out[k].append(bytes(r))
        return out

    def _mechanize(self, t_ns: np.ndarray, om: np.ndarray, fb: np.ndarray) -> tuple[bytes | None, np.ndarray, np.ndarray]:
        """Integrate IMU samples (t_ns (N,), omega [rad/s] (N, 3), f [m/s^2] (N, 3), body axes).

        Returns ``(the initial state's /master/nav or None, the /master/nav rows of the kept
        samples (K, size), keep mask (N,))``.
        """
        from dpos_ros import conversions as cv
        from dpos_ros.master_nav import body_rate_eb, stamp_s

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
        head = None
        if first:
            s = mech.initial
            v0 = cv.odometry_values_cov(s.llh[None], s.vel_n_mps[None], s.q_nb[None], self.datum_llh, None, *cov)
            head = bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([self.origin_ns]), v0)[0])
        rows = np.empty((0, 0), dtype=np.uint8)
        if len(nav):
            w_eb = body_rate_eb(nav.q_nb, nav.llh, nav.vel_n_mps, om[keep] - gyro)
            v = cv.odometry_values_cov(nav.llh, nav.vel_n_mps, nav.q_nb, self.datum_llh, w_eb, *cov)
            rows = cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, t_ns[keep], v)
        self.nav_published += int(len(nav)) + int(first)
        return head, rows, keep

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
        if self.mech is None:
            self.get_logger().warning(f"/ifa/correction at stamp {t_ns} ns before the mechanization started: ignored")
            return
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
        if self.mech is None:
            self.get_logger().warning(f"/ifa/imu_bias at stamp {t_ns} ns before the mechanization started: ignored")
            return
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
                "device": self.config.device,
                "started": mech is not None,
                "ifa_status": self.ifa_status,
                "corrections": 0 if mech is None else mech.corrections,
                "last_correction_t_s": "none" if mech is None or mech.last_correction_t_s is None else f"{mech.last_correction_t_s:.3f}",
                "imu_dropped": 0 if mech is None else mech.dropped,
                "imu_before_start": self.imu_before_start,
                "nav_t_s": "none" if mech is None else f"{mech.t_s:.3f}",
                "heading_sigma_deg": f"{np.sqrt(self._nav_cov[1][2, 2]) / DEG:.6g}",
            }
        self.status_pub.publish(cv.diagnostic_array(self.get_clock().now().to_msg(), st_name, "master_imu", level, message, values))

    # ------------------------------------------------------------------ device: ros
    def _start_relay(self) -> None:
        import dataclasses

        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import NavSatFix

        from dpos_ros import conversions as cv
        from dpos_ros.qos import DATUM_QOS, NAV_QOS

        cfg = self.config
        log = self.get_logger()
        defaults = PosMasterConfig()
        overridden = [f.name for f in dataclasses.fields(cfg)
                      if f.name in SIM_ONLY and getattr(cfg, f.name) != getattr(defaults, f.name)]
        if overridden:
            log.info(f"device: ros ignores the simulator parameters {format_config(cfg, tuple(overridden))}")
        self._pending_imu: deque[tuple[int, tuple[float, ...], tuple[float, ...]]] = deque()
        self._gnss: dict[str, deque] = {"fix": deque(maxlen=GNSS_KEEP), "vel": deque(maxlen=GNSS_KEEP)}
        self.datum_pub = self.create_publisher(NavSatFix, "/dpos/datum", DATUM_QOS)
        if self.datum_llh is not None:
            self.datum_pub.publish(cv.datum_msg(self.get_clock().now().nanoseconds, self.datum_llh))
        self.nav_pub = self.create_publisher(Odometry, NAV_TOPIC, NAV_QOS)
        rotation = None if not any(cfg.input_rotation_rpy_deg) else rotation_from_rpy_deg(cfg.input_rotation_rpy_deg)
        routes = [Route("imu", IMU_INPUT, "/master/imu", cv.MASTER_FRAME), Route("fix", FIX_INPUT, "/gnss/fix", cv.GNSS_FRAME),
                  Route("vel", VEL_INPUT, "/gnss/vel", cv.GNSS_FRAME)]
        self.relay = DeviceRelay(self, routes, input_reliability=cfg.input_reliability, R_out_in=rotation,
                                 on_message=self._on_driver_message)
        self._tick_timer = self.create_timer(RELAY_TICK_S, self._tick)
        start = ("the given initial_state at the first IMU sample" if cfg.alignment == "given" else
                 f"the first /gnss/fix + /gnss/vel (heading = course over ground from {cfg.min_course_speed_mps:g} m/s"
                 f"{', else the initial_state heading' if cfg.initial_state else ''}), flagged UNALIGNED until /ifa/status ALIGNED")
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'alignment', 'aircraft_config', 'datum', 'input_reliability', 'input_rotation_rpy_deg'))}"
            f" -> relaying {self.relay.describe()}; {NAV_TOPIC} mechanized from {start}; /dpos/datum "
            f"{'from the datum parameter' if self.datum_llh is not None else 'from the first valid fix'};"
            f" relay status on {self.get_fully_qualified_name()}/status, nav status on {STATUS_TOPIC}"
        )

    def _on_driver_message(self, topic: str, msg: Any) -> None:
        """DeviceRelay hook (subscription callback): queue a validated IMU sample (body axes) or
        keep a validated fix / velocity; the first fix sets the datum when none is configured."""
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if topic == "/master/imu":
            w, f = msg.angular_velocity, msg.linear_acceleration
            self._pending_imu.append((t_ns, (w.x, w.y, w.z), (f.x, f.y, f.z)))
        elif topic == "/gnss/fix":
            llh = np.array([msg.latitude * DEG, msg.longitude * DEG, msg.altitude])
            if self.datum_llh is None:
                from dpos_ros import conversions as cv

                self.datum_llh = llh
                self.datum_pub.publish(cv.datum_msg(t_ns, llh))
                self.get_logger().info(
                    f"/dpos/datum = the first valid fix: lat {msg.latitude:.8f} lon {msg.longitude:.8f} deg, "
                    f"h {msg.altitude:.3f} m (stamp {t_ns} ns)")
            if self.mech is None:
                self._gnss["fix"].append((t_ns, llh))
        elif self.mech is None:  # /gnss/vel (ENU)
            v = msg.twist.twist.linear
            self._gnss["vel"].append((t_ns, np.array([v.x, v.y, v.z])))

    def _tick(self) -> None:
        """Timer: start the mechanization when possible, then integrate the queued IMU samples in
        batches of MAX_BATCH (at most MAX_PER_TICK per tick) and publish /master/nav."""
        if self.mech is None and not self._try_start():
            return
        done = 0
        while self._pending_imu and done < MAX_PER_TICK:
            batch = [self._pending_imu.popleft() for _ in range(min(MAX_BATCH, len(self._pending_imu)))]
            done += len(batch)
            t_ns = np.array([b[0] for b in batch], dtype=np.int64)
            late = t_ns <= self.origin_ns  # arrived after the start but stamped before it
            if late.any():
                self.imu_before_start += int(late.sum())
                batch = [b for b, k in zip(batch, late) if not k]
                t_ns = t_ns[~late]
                if not batch:
                    continue
            head, rows, _ = self._mechanize(t_ns, np.array([b[1] for b in batch]), np.array([b[2] for b in batch]))
            if head is not None:
                self.nav_pub.publish(head)
            for r in rows:
                self.nav_pub.publish(bytes(r))

    def _try_start(self) -> bool:
        """Create the mechanization from the initial state once it is known (module docstring)."""
        from dpos_ros.master_nav import MasterMechanization, initial_state_from_list

        cfg = self.config
        log = self.get_logger()
        if cfg.alignment == "given":
            if not self._pending_imu:
                return False
            if self.datum_llh is None:
                self.imu_before_start += len(self._pending_imu)
                self._pending_imu.clear()
                log.warning("alignment given: waiting for the first valid /gnss/fix (the datum) before starting "
                            "(set the datum parameter to start at the first IMU sample)", throttle_duration_sec=WARN_THROTTLE_S)
                return False
            t0_ns = self._pending_imu.popleft()[0]
            initial = initial_state_from_list(cfg.initial_state, 0.0)
            text = f"the given state {list(cfg.initial_state)}"
        else:
            start = self._course_start()
            if start is None:
                if self._pending_imu:  # keep at most ring_s of samples while waiting
                    t_min = self._pending_imu[-1][0] - int(cfg.ring_s * 1e9)
                    while self._pending_imu[0][0] < t_min:
                        self._pending_imu.popleft()
                        self.imu_before_start += 1
                return False
            t0_ns, initial, text = start
        before = len(self._pending_imu)
        self._pending_imu = deque(s for s in self._pending_imu if s[0] > t0_ns)
        self.imu_before_start += before - len(self._pending_imu)
        self.origin_ns = t0_ns
        with self._lock:
            self.mech = MasterMechanization(initial, cfg.ring_s)
        self._gnss["fix"].clear()
        self._gnss["vel"].clear()
        hpr = initial.hpr_rad / DEG
        log.info(f"{NODE_NAME}: {NAV_TOPIC} starts at stamp {t0_ns} ns from {text}: lat {initial.llh[0] / DEG:.8f} "
                 f"lon {initial.llh[1] / DEG:.8f} deg h {initial.llh[2]:.3f} m, vel ENU {np.round(initial.vel_n_mps, 3).tolist()} m/s, "
                 f"heading {hpr[0]:.3f} pitch {hpr[1]:.3f} roll {hpr[2]:.3f} deg"
                 f"{'' if cfg.alignment == 'given' else ' (UNALIGNED until /ifa/status ALIGNED)'}")
        self._publish_status()
        return True

    def _course_start(self) -> tuple[int, Any, str] | None:
        """``alignment: ifa``: the initial state from the oldest fix with a matching velocity, or None."""
        from dpos_core import earth
        from dpos_core.frames import C_nb_from_hpr
        from dpos_core.strapdown import NavState

        cfg = self.config
        fixes, vels = self._gnss["fix"], self._gnss["vel"]
        while fixes:
            t_fix, llh = fixes[0]
            vel = next((v for t, v in vels if abs(t - t_fix) <= FIX_VEL_MATCH_NS), None)
            if vel is None:
                if vels and vels[-1][0] > t_fix + FIX_VEL_MATCH_NS:  # its velocity will not come
                    fixes.popleft()
                    continue
                return None
            fixes.popleft()
            speed = math.hypot(vel[0], vel[1])
            if speed >= cfg.min_course_speed_mps:
                heading = math.atan2(vel[0], vel[1]) % (2.0 * math.pi)
                text = f"the fix and velocity at {t_fix} ns, heading = course over ground ({speed:.1f} m/s)"
            elif cfg.initial_state:
                heading = cfg.initial_state[6] * DEG
                text = (f"the fix and velocity at {t_fix} ns, the initial_state heading (ground speed {speed:.2f} m/s < "
                        f"min_course_speed_mps {cfg.min_course_speed_mps:g})")
            else:
                self.get_logger().warning(
                    f"alignment ifa: ground speed {speed:.2f} m/s at {t_fix} ns is below min_course_speed_mps "
                    f"{cfg.min_course_speed_mps:g}: the course is no heading; waiting for a faster fix (or set initial_state "
                    f"for its heading)", throttle_duration_sec=WARN_THROTTLE_S)
                continue
            if self.lever_arm_b_m is not None:  # antenna -> IMU with the initial attitude
                p_enu = -C_nb_from_hpr(heading, 0.0, 0.0) @ self.lever_arm_b_m
                llh = np.array(earth.enu_to_geodetic(p_enu, llh), dtype=float)
                text += f", lever arm {self.lever_arm_b_m.tolist()} m removed"
            return t_fix, NavState.from_hpr(0.0, [heading, 0.0, 0.0], vel, llh), text
        return None

    # ------------------------------------------------------------------ device: sim
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
