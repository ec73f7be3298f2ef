"""The sources of pos_master_node: where the master device's data come from, by ``device``.

``device: sim`` (:class:`SimSource`)
    publishes the simulated master device live (dpos_ros.devices.sim_device): the latched
    /dpos/datum, /master/imu, /gnss/fix, /gnss/vel, /truth/master and /truth/antenna/<antennas
    without IMU> (``publish_truth``), and /session/end after the last sample. The bytes are those of
    ``dpos-sim`` for the same scenario, aircraft, seed, duration and datum. When everything is
    published the node stays up (late subscribers of the latched datum still get it) until
    SIGINT/SIGTERM. /master/nav is the device's own stream with ``alignment: reference``; else a
    tap of /master/imu (batches of up to ``TAP_MAX_BATCH`` samples) hands the IMU to the
    navigator, which starts at the session start; with ``rate_factor`` 0, ``max_lead_s`` > 0 and
    an ifa_node publishing /ifa/correction the device thread waits while the mechanization is more
    than ``max_lead_s`` ahead of the last correction (at most ``LEAD_WAIT_S`` per wait).

``device: ros`` (:class:`RelaySource`; real drivers)
    A dpos_ros.devices.relay.DeviceRelay relays the drivers' standard topics, relative names to remap:
    ``imu_in`` (sensor_msgs/Imu) -> /master/imu (frame ``master_imu``, rotated into our FLU body
    axes by ``input_rotation_rpy_deg``), ``fix_in`` (NavSatFix) -> /gnss/fix and ``vel_in``
    (TwistWithCovarianceStamped, ENU) -> /gnss/vel (frame ``gnss``), stamps kept; bad messages
    (NaN, duplicate / out-of-order / zero stamps, NO_FIX, unknown covariance) are rejected and
    counted, gaps counted, on the DiagnosticArray ``/<node name>/status`` (``input_reliability``
    selects the input QoS). Every relayed IMU message is queued for the mechanization
    (``alignment: ifa | given``); a timer (``RELAY_TICK_S``) integrates the queue in batches of at
    most ``MAX_BATCH`` samples (``MAX_PER_TICK`` per tick, so the executor stays responsive) and
    publishes /master/nav for every IMU stamp - what the simulated device's tap does in its thread;
    /ifa/correction, /ifa/imu_bias and the UNALIGNED / ALIGNED / GIVEN flag as in simulation
    (pos_master_node.navigators, which also says how the initial state is found). No flow
    control of the device (``max_lead_s``): a real device runs in real time.

    Hold for the IFA loop: the correction of a GNSS epoch applies to the IMU samples
    after it, so /master/nav of a sample is the aligner's only if every correction before it was
    here when it was integrated. While an ifa_node is in the graph (a publisher of
    /ifa/correction, from its start on):

    * the timer integrates the queued samples only up to the oldest relayed fix (moved onto the
      IMU clock by the ifa_node's ``gnss_time_offset_s``) the ifa_node has not answered yet:
      answered = its /ifa/status says every fix up to that stamp is finished (``fixes_done_ns``:
      an epoch, a rejection or a skip) and every correction and bias estimate it published
      (``last_correction_ns``, ``last_bias_ns``: the two topics arrive in either order) has arrived
      here. The fixes waiting in the middleware are relayed first, with their velocities (the node
      may have been busy; the ifa_node pairs the two within ``pair_timeout_s`` of wall time).
      The relay itself (/master/imu, which the ifa_node needs to answer) is
      never held; /master/nav waits for the ifa_node's processing only (a few ms per fix). A hold
      unanswered for ``LEAD_WAIT_S`` (an ifa_node stopped or stuck) is released with a warning,
      counted (``hold_timeouts``);
    * in an outage, the same for the ifa_node's next time update alone (its /ifa/status
      ``predict_due_ns``) once the relayed IMU is past it: its correction carries the grown
      covariance, and the messages after it carry that;
    * a receiver delivers its fix some 50-100 ms after its stamp, so the timer also keeps
      ``nav_delay_s`` of IMU time queued: a sample is integrated once a sample that much newer has
      been relayed and it has waited ``nav_delay_s`` of wall time since it was relayed (a replay
      as fast as possible relays a backlog of IMU messages in one batch, ahead of the fixes of the
      same time), so that its fix has been relayed (and holds it) by then; when no sample came
      for ``NAV_FLUSH_S`` of wall time (the end of the data, an outage; longer than the pauses of
      a replay as fast as possible) the queue is integrated.

    Samples integrated before their fix was relayed anyway (``nav_delay_s`` 0, a fix later than
    it, no ifa_node in the graph yet) lack its correction: it is applied by re-integration and
    counted (``corrections_late``, ``late_samples``, ``last_late`` on /pos_master/status).

    ``/dpos/datum`` (latched): the ``datum`` parameter when set (stamped with the node's clock at
    start), else the first valid /gnss/fix (the antenna position, the fix's stamp). /master/nav is not
    published before the datum is known. ``/session/end`` is never published by a live device:
    the operator (or dpos-record) ends the session. ``alignment: reference`` is simulation only
    (ParameterError); the simulator parameters (scenario, seed, duration, rate_factor,
    publish_truth, min_subscribers, wait_subscribers_s, initial_heading_error_deg, max_lead_s) are
    ignored with an info line naming those that were set.

A source is built from the validated parameters and the navigator (checking what the device
needs, raising ParameterError) and :meth:`start` ed once the navigator is attached.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry
from numpy.typing import NDArray
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.ifa.mechanization import stamp_s
from dpos_core.units import DEG, FloatArray
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS
from dpos_ros.devices.relay import DeviceRelay, Route, rotation_from_rpy_deg
from dpos_ros.devices.sim_device import SimDevice, Tap
from dpos_ros.devices.sim_session import load_sim_session
from dpos_ros.devices.sim_streams import device_streams, session_id
from dpos_ros.io.flow import ArrivalAge
from dpos_ros.io.streams import TopicStream
from dpos_ros.runtime.params import ParameterError, datum_llh_rad, format_config
from pos_master_node import NODE_NAME
from pos_master_node.navigators import LEAD_WAIT_S, DriverInput, Mechanizer, Navigator
from pos_master_node.params import PosMasterConfig

__all__ = ["SimSource", "RelaySource", "Source", "IMU_INPUT", "FIX_INPUT", "VEL_INPUT", "SIM_ONLY", "RELAY_TICK_S",
           "MAX_BATCH", "MAX_PER_TICK", "TAP_MAX_BATCH", "FIX_MARKS_KEEP", "NAV_FLUSH_S"]

#: The driver topics of ``device: ros`` (relative: remap them, ``-r imu_in:=/driver/imu``).
IMU_INPUT, FIX_INPUT, VEL_INPUT = "imu_in", "fix_in", "vel_in"
#: Parameters of the simulated device only (ignored by ``device: ros``).
SIM_ONLY = ("scenario", "seed", "duration", "rate_factor", "publish_truth", "min_subscribers", "wait_subscribers_s",
            "initial_heading_error_deg", "max_lead_s")
#: ``device: ros``: period of the mechanization timer [s], samples per batch, samples per tick
RELAY_TICK_S = 0.02
MAX_BATCH = 100
MAX_PER_TICK = 1000
#: ``device: sim``: most /master/imu messages handed to the mechanization at once (SimDevice tap)
TAP_MAX_BATCH = 100
#: ``device: ros``: relayed fix stamps kept for the hold of the IFA loop
FIX_MARKS_KEEP = 10000
#: ``device: ros``: the IMU silent this long [s, wall clock] = the end of the data (or an outage): the
#: samples kept back by ``nav_delay_s`` are integrated
NAV_FLUSH_S = 2.0
#: ``device: ros`` without ``datum``: fixes that wait for the /ifa/status of an ifa_node in the graph
#: (its ``datum_deg``: the session's datum after a restart) before the first fix is the datum
DATUM_WAIT_FIXES = 5


class SimSource:
    """``device: sim``: the simulated master device (module docstring).

    Attributes:
        session: the simulated session (dpos_core.sim.session.SimulatedSession).
        device: the SimDevice publishing it (started by :meth:`start`).
        relay, nav_pub: None (``device: ros`` only).

    Raises:
        ParameterError: an unknown scenario/aircraft, a duration longer than the scenario, an
            invalid ``initial_state`` (``alignment: given``).
    """

    def __init__(self, node: Node, cfg: PosMasterConfig, navigator: Navigator) -> None:
        self.node = node
        self.config = cfg
        self.log = node.get_logger()
        self.session: Any = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
        self.relay: DeviceRelay | None = None
        self.nav_pub: Any = None
        datum = datum_llh_rad(cfg.datum)
        #: the ``datum`` parameter [lat_rad, lon_rad, h_m]; None = the session's
        self.datum_param = None if datum is None else np.asarray(datum, dtype=float)
        #: the navigator when it mechanizes the IMU, None when /master/nav is the device's (reference)
        self.mechanizer = navigator if isinstance(navigator, Mechanizer) else None
        taps = []
        if self.mechanizer is not None:
            origin_ns = int(cv.stamps_ns(self.session.scenario.start_time_s, np.array([0.0]))[0])
            datum_llh = np.asarray(self.session.datum_llh if self.datum_param is None else self.datum_param, dtype=float)
            self.mechanizer.start_simulated(self.session, origin_ns, datum_llh)
            taps.append(Tap(T.MASTER_IMU, T.MASTER_NAV, T.ODOMETRY, self._produce_nav, qos="nav", max_batch=TAP_MAX_BATCH))
        self.device = SimDevice(node, self._streams, cfg.rate_factor, min_subscribers=cfg.min_subscribers,
                                wait_subscribers_s=cfg.wait_subscribers_s, on_finished=self._finished, taps=taps)

    def topics(self) -> list[str]:
        """The topics published, in the order of the plan line."""
        cfg = self.config
        topics = [T.DATUM, T.MASTER_IMU, T.GNSS_FIX, T.GNSS_VEL]
        if self.session.scenario.sar is not None:  # a SINS/SAR scenario (its sar: block)
            topics += [T.SAR_FIX, T.BARO_PRESSURE]
        topics.append(T.MASTER_NAV)
        if cfg.publish_truth:
            topics.append(T.TRUTH_MASTER)
            topics += [T.truth_antenna(a.name) for a in self.session.scenario.aircraft.antennas if a.sub_imu is None]
        topics.append(T.SESSION_END)
        if self.mechanizer is not None:
            topics.append(T.POS_MASTER_STATUS)
        return topics

    def start(self) -> None:
        """Log the plan and start the device thread."""
        cfg = self.config
        session = self.session
        self.log.info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'scenario', 'aircraft_config', 'seed', 'duration', 'rate_factor', 'alignment', 'publish_truth'))}"
            f" datum={list(cfg.datum) if cfg.datum else 'scenario start'}: session {session_id(session)},"
            f" aircraft {session.scenario.aircraft.name}, {session.duration_s:g} s -> publishing {', '.join(self.topics())}"
        )
        if self.mechanizer is not None:
            self.mechanizer.announce_simulated()
        self.device.start()

    def stop(self) -> None:
        self.device.stop()

    def _streams(self) -> list[TopicStream]:
        """The device's streams (generated in the device thread); without /master/nav when mechanized."""
        out = device_streams(self.session, "master", truth=self.config.publish_truth, datum_llh=self.datum_param)
        return [s for s in out if self.mechanizer is None or s.topic != T.MASTER_NAV]

    def _finished(self, device: SimDevice) -> None:
        self.log.info(
            f"session {session_id(self.session)} ended ({device.published} messages published); staying up so that "
            f"late subscribers get the latched {T.DATUM} (SIGINT/SIGTERM to stop)"
        )

    def _produce_nav(self, stream: TopicStream, idx: NDArray[np.int64]) -> list[list[bytes]]:
        """SimDevice tap: /master/nav for a batch of /master/imu messages (device thread)."""
        mech = self.mechanizer
        if mech is None or stream.rows is None:  # not reached: tapped only when mechanized; the IMU stream has rows
            raise RuntimeError(f"{T.MASTER_IMU} tap without a mechanization or fixed-size messages")
        t_ns, vals = cdr.decode(cdr.layout("imu", cv.MASTER_FRAME), stream.rows[idx])
        self._wait_for_corrections(mech, float(stamp_s(t_ns[0], mech.origin_ns)))
        head, rows, keep = mech.mechanize(t_ns, vals[:, 13:16], vals[:, 25:28])
        out: list[list[bytes]] = [[] for _ in range(idx.size)]
        if head is not None:
            out[0].append(head)
        for r, k in zip(rows, np.flatnonzero(keep)):
            out[k].append(bytes(r))
        return out

    def _wait_for_corrections(self, mech: Mechanizer, t_s: float) -> None:
        """Flow control of the IFA loop (``rate_factor`` 0, ``max_lead_s``): while an ifa_node
        publishes corrections, do not run more than max_lead_s ahead of the last one."""
        cfg = self.config
        if cfg.rate_factor != 0.0 or cfg.max_lead_s <= 0.0 or self.node.count_publishers(T.IFA_CORRECTION) == 0:
            return
        mech.wait_for_corrections(t_s, cfg.max_lead_s, lambda: self.device.stopping)


class RelaySource:
    """``device: ros``: relays the real drivers and feeds the relayed IMU to the navigator (module docstring).

    Attributes:
        relay: the DeviceRelay; nav_pub: the /master/nav publisher; datum_pub: /dpos/datum's.
        input: what the navigator starts from (datum, lever arm, queued IMU, recent fixes / velocities).
        session, device: None (``device: sim`` only).

    Raises:
        ParameterError: ``alignment: reference``; ``alignment: given`` without ``initial_state``;
            an invalid ``initial_state``; an unknown ``aircraft_config``.
    """

    def __init__(self, node: Node, cfg: PosMasterConfig, navigator: Navigator) -> None:
        if not isinstance(navigator, Mechanizer):
            raise ParameterError("alignment", cfg.alignment,
                                 "simulation only (truth + main-system noise): with device:=ros use ifa or given")
        navigator.check_live()
        lever_arm_b_m = None
        if cfg.aircraft_config:
            try:
                lever_arm_b_m = np.asarray(load_aircraft(cfg.aircraft_config).gnss_lever_arm_m, dtype=float)
            except ConfigError as exc:
                raise ParameterError("aircraft_config", cfg.aircraft_config, str(exc)) from None
        self.node = node
        self.config = cfg
        self.log = node.get_logger()
        self.navigator: Mechanizer = navigator
        self.session: Any = None
        self.device: SimDevice | None = None
        datum = datum_llh_rad(cfg.datum)
        self.input = DriverInput(None if datum is None else np.asarray(datum, dtype=float), lever_arm_b_m)
        # the executor runs none of the callbacks before the node is constructed (and start()ed)
        self.datum_pub = node.create_publisher(NavSatFix, T.DATUM, DATUM_QOS)
        self.nav_pub = node.create_publisher(Odometry, T.MASTER_NAV, NAV_QOS)
        rotation = None if not any(cfg.input_rotation_rpy_deg) else rotation_from_rpy_deg(cfg.input_rotation_rpy_deg)
        routes = [Route("imu", IMU_INPUT, T.MASTER_IMU, cv.MASTER_FRAME), Route("fix", FIX_INPUT, T.GNSS_FIX, cv.GNSS_FRAME),
                  Route("vel", VEL_INPUT, T.GNSS_VEL, cv.GNSS_FRAME)]
        self.relay = DeviceRelay(node, routes, input_reliability=cfg.input_reliability, R_out_in=rotation,
                                 on_message=self._on_driver_message)
        #: stamps [ns] of the relayed fixes the hold still waits for (module docstring), oldest first
        self._fix_marks: deque[int] = deque(maxlen=FIX_MARKS_KEEP)
        self._held: tuple[int, float] | None = None  # (fix stamp [ns], monotonic time [s]) of a hold blocking the IMU
        self._imu_wall_s = time.monotonic()  # when the newest IMU sample was relayed (nav_delay_s)
        self._imu_arrival = ArrivalAge()  # the IMU stamps by relay wall time (nav_delay_s)
        self._newest_imu_ns: int | None = None
        self._datum_waits = 0  # fixes that waited for the ifa_node's datum (_choose_datum)
        self._first_fix: tuple[int, FloatArray] | None = None  # the first valid fix (stamp, llh)
        self._prediction_held: tuple[int, float] | None = None  # (stamp [ns], monotonic [s]) of an outage hold
        self._prediction_released: int | None = None  # an outage hold released after LEAD_WAIT_S
        self._tick_timer = node.create_timer(RELAY_TICK_S, self._tick)

    def start(self) -> None:
        """Name the ignored simulator parameters, publish the configured datum, log the plan."""
        cfg = self.config
        log = self.log
        defaults = PosMasterConfig()
        overridden = [f.name for f in dataclasses.fields(cfg)
                      if f.name in SIM_ONLY and getattr(cfg, f.name) != getattr(defaults, f.name)]
        if overridden:
            log.info(f"device: ros ignores the simulator parameters {format_config(cfg, tuple(overridden))}")
        datum = self.input.datum_llh
        if datum is not None:
            self.datum_pub.publish(cv.datum_msg(self.node.get_clock().now().nanoseconds, datum))
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'alignment', 'aircraft_config', 'datum', 'input_reliability', 'input_rotation_rpy_deg'))}"
            f" -> relaying {self.relay.describe()}; {T.MASTER_NAV} mechanized from {self.navigator.live_plan()}; {T.DATUM} "
            f"{'from the datum parameter' if datum is not None else 'from the first valid fix'};"
            f" relay status on {self.node.get_fully_qualified_name()}/status, nav status on {T.POS_MASTER_STATUS}"
        )

    def stop(self) -> None:
        """Nothing to stop: the relay's subscriptions and timers end with the node."""

    def _on_driver_message(self, topic: str, msg: Any) -> None:
        """DeviceRelay hook (subscription callback): queue a validated IMU sample (body axes) or
        keep a validated fix / velocity; the first fix sets the datum when none is configured."""
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        inp = self.input
        if topic == T.MASTER_IMU:
            w, f = msg.angular_velocity, msg.linear_acceleration
            inp.imu.append((t_ns, (w.x, w.y, w.z), (f.x, f.y, f.z)))
            self._imu_wall_s = time.monotonic()
            self._imu_arrival.add(t_ns, self._imu_wall_s)
            self._newest_imu_ns = t_ns if self._newest_imu_ns is None else max(self._newest_imu_ns, t_ns)
            self.navigator.note_imu(t_ns)  # the future bound of the feedback stamps (dpos_core.gates)
        elif topic == T.GNSS_FIX:
            self._fix_marks.append(t_ns)
            llh = np.array([msg.latitude * DEG, msg.longitude * DEG, msg.altitude])
            if inp.datum_llh is None:
                self._choose_datum(t_ns, llh)
            if not self.navigator.started:
                inp.fixes.append((t_ns, llh))
        elif not self.navigator.started:  # /gnss/vel (ENU)
            v = msg.twist.twist.linear
            inp.vels.append((t_ns, np.array([v.x, v.y, v.z])))

    def _choose_datum(self, t_ns: int, llh: FloatArray) -> None:
        """No ``datum`` parameter: the session's datum is the one the running ifa_node uses (its
        /ifa/status ``datum_deg``: this node was restarted mid-session, and the graph's navigation is
        in that frame), else the first valid fix. While an ifa_node is in the graph but its status
        has not come yet, up to ``DATUM_WAIT_FIXES`` fixes wait for it."""
        nav, inp = self.navigator, self.input
        graph = nav.graph_datum_llh
        if self._first_fix is None:
            self._first_fix = (t_ns, llh)
        if graph is None and nav.ifa_present() and nav.ifa_status == "none" and self._datum_waits < DATUM_WAIT_FIXES:
            self._datum_waits += 1
            return
        t_ns, llh = self._first_fix
        inp.datum_llh = llh if graph is None else graph
        self.datum_pub.publish(cv.datum_msg(t_ns, inp.datum_llh))
        d = inp.datum_llh
        where = "the first valid fix" if graph is None else f"the running ifa_node's ({T.IFA_STATUS} datum_deg: a restart)"
        self.log.info(f"{T.DATUM} = {where}: lat {d[0] / DEG:.8f} lon {d[1] / DEG:.8f} deg, h {d[2]:.3f} m (stamp {t_ns} ns)")

    def _hold_ns(self, origin_ns: int) -> int | None:
        """The stamp [ns] after which the queued IMU samples wait for the ifa_node (module docstring):
        its answer to the oldest relayed fix, or its time update alone of an outage; None when
        nothing is held."""
        holds = [h for h in (self._fix_hold_ns(origin_ns), self._prediction_hold_ns()) if h is not None]
        return min(holds) if holds else None

    def _prediction_hold_ns(self) -> int | None:
        """During an outage: the ifa_node's next time update alone (its /ifa/status ``predict_due_ns``)
        once the relayed IMU is past it (the ifa_node makes it ``outage_wait_s`` later), and every
        correction it announced until it has arrived; released after LEAD_WAIT_S with a warning."""
        nav = self.navigator
        due, newest = nav.ifa_predict_due_ns, self._newest_imu_ns
        if due is None or newest is None or not nav.ifa_present():
            self._prediction_held = None
            return None
        if not nav.feedback_received():
            hold = nav.ifa_last_correction_ns  # announced, on its way
        elif newest > due:  # the ifa_node makes it once the IMU is outage_wait_s past it (or a fix comes first)
            hold = due
        else:
            self._prediction_held = None
            return None
        if hold is None or hold == self._prediction_released:
            return None
        now = time.monotonic()
        if self._prediction_held is None or self._prediction_held[0] != hold:
            self._prediction_held = (hold, now)
        elif now - self._prediction_held[1] > LEAD_WAIT_S:
            nav.hold_timeouts += 1
            self.log.warning(f"no time update of the ifa_node at stamp {hold} ns for {LEAD_WAIT_S:g} s (outage; its next one due at "
                             f"{due} ns, last correction {nav.ifa_last_correction_ns} ns, received up to {nav.correction_seen_ns} ns): "
                             f"{T.MASTER_NAV} goes on without waiting ({nav.hold_timeouts} so far)")
            self._prediction_released = hold
            self._prediction_held = None
            return None
        return hold

    def _fix_hold_ns(self, origin_ns: int) -> int | None:
        """The oldest relayed fix the ifa_node has not answered (moved onto the IMU clock), None when
        none; releases a hold older than LEAD_WAIT_S with a warning."""
        nav = self.navigator
        marks = self._fix_marks
        while marks and marks[0] <= origin_ns:  # before the start: the ifa_node skips them
            marks.popleft()
        if not marks or not nav.ifa_present():
            self._held = None
            return None
        while marks and nav.fix_answered(marks[0]):
            marks.popleft()
        if not marks:
            self._held = None
            return None
        if self._held is not None and self._held[0] == marks[0] and time.monotonic() - self._held[1] > LEAD_WAIT_S:
            nav.hold_timeouts += 1
            self.log.warning(f"no answer of the ifa_node to the fix at stamp {marks[0]} ns for {LEAD_WAIT_S:g} s (its fixes done up "
                             f"to {nav.ifa_fixes_done_ns} ns, last correction {nav.ifa_last_correction_ns} ns, received up to "
                             f"{nav.correction_seen_ns} ns): {T.MASTER_NAV} goes on without waiting ({nav.hold_timeouts} so far)")
            marks.popleft()
            self._held = None
            return self._fix_hold_ns(origin_ns)
        if self._held is None or self._held[0] != marks[0]:
            self._held = (marks[0], time.monotonic())  # the oldest fix the ifa_node has not answered, since
        return marks[0] - nav.ifa_offset_ns

    def _tick(self) -> None:
        """Timer: start the mechanization when possible, then integrate the queued IMU samples (up to
        the hold of the IFA loop, module docstring) in batches of MAX_BATCH (at most MAX_PER_TICK per
        tick) and publish /master/nav."""
        nav = self.navigator
        if not nav.started and not nav.try_start_live(self.input):
            return
        origin_ns = nav.origin_ns
        # every fix relayed so far holds (this node may have been busy); its velocity goes with it, so that
        # the ifa_node, which pairs them, does not get the fix seconds before its velocity on a busy machine
        self.relay.take_pending(("fix", "vel"))
        pending = self.input.imu  # after the start: it replaces the queue
        hold_ns = self._hold_ns(origin_ns)
        delay_s = self.config.nav_delay_s
        limit_ns = hold_ns
        now = time.monotonic()
        aged_ns = self._imu_arrival.aged_ns(delay_s, now)
        if pending and delay_s > 0.0 and now - self._imu_wall_s < NAV_FLUSH_S and nav.ifa_present():
            # keep nav_delay_s of IMU time queued, and every sample nav_delay_s of wall time: a replay
            # as fast as possible relays the IMU in batches ahead of the fixes (module docstring)
            delayed_ns = pending[-1][0] - int(round(delay_s * 1e9))
            delayed_ns = pending[0][0] - 1 if aged_ns is None else min(delayed_ns, aged_ns)
            limit_ns = delayed_ns if limit_ns is None else min(limit_ns, delayed_ns)
        done = 0
        while pending and done < MAX_PER_TICK:
            n = 0
            while n < min(MAX_BATCH, len(pending)) and (limit_ns is None or pending[n][0] <= limit_ns):
                n += 1
            if n == 0:
                break
            batch = [pending.popleft() for _ in range(n)]
            done += len(batch)
            t_ns = np.array([b[0] for b in batch], dtype=np.int64)
            late = t_ns <= origin_ns  # arrived after the start but stamped before it
            if late.any():
                nav.imu_before_start += int(late.sum())
                batch = [b for b, k in zip(batch, late) if not k]
                t_ns = t_ns[~late]
                if not batch:
                    continue
            head, rows, _ = nav.mechanize(t_ns, np.array([b[1] for b in batch]), np.array([b[2] for b in batch]))
            if head is not None:
                self.nav_pub.publish(head)
            for r in rows:
                self.nav_pub.publish(bytes(r))


#: where the master device's data come from (chosen by ``device``)
Source = SimSource | RelaySource
