"""ifa_node — in-flight alignment of the main POS against GNSS ([Fang2012]: ADD2, DD2 or AEKF).

Shadow mechanization (exact and deterministic): the node runs
:class:`dpos_core.ifa.pipeline.InFlightAligner` on the very IMU samples pos_master_node mechanizes,
from the very state it starts from, so that its closed-loop strapdown and the master's navigation
are one trajectory (dpos_core.ifa.mechanization), and its corrections equal
:func:`dpos_core.ifa.pipeline.run` on the same data.

Inputs
    ``/master/nav`` (Odometry): the first message is the initial state (pos_master_node publishes
    the state its mechanization starts from first; its stamp is the time origin of the node); the
    aligner starts once ``IMU_DT_SAMPLES`` IMU samples after it have arrived (their median
    interval is the aligner's IMU interval, of its process noise: the same whenever the node
    starts); later ones are compared with the shadow strapdown at the GNSS epochs (before the
    update) and the discrepancy goes into the status (``nav_discrepancy_m`` / ``_deg``: zero to
    rounding when the master had received every earlier correction when it computed that epoch; a
    master running ahead of the corrections with ``rate_factor`` 0 shows its lag here).
    Restart (joining a running session): pos_master_node's latched ``/pos_master/status`` says it
    runs and has applied corrections before this node started, or no /master/nav comes
    ``JOIN_WAIT_S`` of wall time after a fix that could start the node while /master/nav has a
    publisher (its start state was published before this node ran). The node then starts, unless a
    /master/nav comes first, from the oldest fix with its velocity, ``RESTART_MIN_COURSE_SPEED_MPS``
    of ground speed, half ``RESTART_LEVEL_WINDOW_S`` of IMU data before it and ``IMU_DT_SAMPLES``
    after it (:func:`dpos_core.ifa.reference.start`: pos_master_node's course start, stamped at the
    fix on the IMU's clock) with its configured prior covariance: UNALIGNED (ALIGNING), its
    corrections wide enough for pos_master_node's gates; the datum is the latched /dpos/datum.
    Pitch and roll are levelled on the IMU with the vehicle's acceleration removed (``level="auto"``,
    :func:`dpos_core.ifa.standstill.start_level`: from the velocities of the previous waiting fix,
    at most 1.5 ``RESTART_LEVEL_WINDOW_S`` older), and the prior pitch / roll sigma is widened to
    what that leaves (never narrowed): in a coordinated turn the specific force stays on the body
    z axis, so levelling it raw gives a roll of ~0 (measured: a restart at 55 s of paper_ifa, roll
    12.1 deg, started at 0.13 deg with a 1 deg sigma; /master/nav then 4-5.7 m off against a
    1.0-1.3 m sigma, 0 % inside 3 sigma over 62-70 s; compensated: roll 14.3 deg, sigma 7.5 deg,
    0.4-0.7 m, 100 %). Status keys ``start`` (``/master/nav``, ``gnss_fix``, ``none``),
    ``joined_running_session``, and after a restart ``start_level`` (``compensated``, ``raw``: no
    fix just before, ``rest``) and ``start_level_sigma_deg``. GNSS fixes for ``IMU_STARVED_S`` of wall
    time while /master/imu has a publisher but no sample of it came: warned once with the likely
    cause (a late reader refused by Fast DDS's reader resource limit, which :func:`main` lifts; a
    deployment's own Fast DDS profile must), status ``imu_starved`` (level WARN while WAITING).
    ``/master/imu`` (sensor QoS, deep reliable): buffered; non-finite samples and duplicate or
    out-of-order stamps are dropped with a warning, gaps warned about and integrated across.
    ``/gnss/fix`` + ``/gnss/vel``: paired by stamp (``pair_tolerance_s``); a fix whose velocity has
    not come is dropped with a warning (and vice versa) once the velocity stream has passed it by
    ``pair_timeout_s`` of stamps (each topic arrives in stamp order, so it will not come), or after
    ``pair_timeout_s`` of wall time (the other stream is silent). The two streams may be far apart
    on arrival (a replay as fast as possible relays each topic in batches). NavSatFix covariance: ENU [m^2]; ``COVARIANCE_TYPE_UNKNOWN`` uses the nominal
    sigmas. ``/dpos/datum`` (latched) unless the ``datum`` parameter is set. ``/session/end``
    (simulation): no IMU sample after its stamp will come, so the fixes still waiting for one are
    applied (those beyond the last sample + ``max_fix_bridge_s`` rejected, ``stale``), as run() ends.

Epochs (at the GNSS rate, driven by the IMU), exactly as :func:`dpos_core.ifa.pipeline.run` on the
same samples: a fix stamped ``t`` is at ``t - gnss_time_offset_s`` on the IMU's clock;
once an IMU sample newer than that has arrived (so every sample up to the fix is here, whatever
the jitter of the stamps or the order of arrival), the buffered samples up to the last one at or
before the fix (+ ``STAMP_TOL_S``) are propagated, with the aligner's time updates alone on the
way (:func:`dpos_core.ifa.pipeline.advance`, run()'s own loop), and the fix is applied
(:meth:`InFlightAligner.update`): its measurement bridges the fix time and that sample's with the
velocity, up to ``max_fix_bridge_s``; a fix with no sample that close (an IMU gap) is rejected by
the core (``not_at_nav_time``). Fixes stamped at or before the aligner's start (the initial state
came from that fix, or before it: the vehicle standing still) are skipped quietly and counted
(``before_start``), as are their velocities. Bad GNSS input - non-finite values, zero
covariance, no fix, a duplicate or out-of-order stamp - is rejected with a warning naming the
problem, counted (``rejected_fixes``, ``rejected/<reason>``) and leaves the filter untouched
(it is checked before any IMU is propagated for it).

Outages: a time update alone is due ``predict_interval_s`` after the last filter epoch. run()
makes it when it passes that time on its way to the next fix; this node makes it as soon as it
can tell that no fix before it will come: IMU data ``outage_wait_s`` past it has arrived, the
sample at it has been here ``outage_wait_s`` of wall time, and no fix before it is waiting here
or in the middleware (taken first). It then publishes an /ifa/correction at that sample: the
navigation, unchanged, with the grown covariance (the same as run()'s track at that time), so
/master/nav's covariance grows through the outage live as offline (counted, ``predictions``).
The checks in wall time (this one, and a fix whose velocity never comes: ``pair_timeout_s``)
run on a timer when the executor is free, after the GNSS messages waiting in the middleware are
taken, so a busy node never mistakes its own delay for silence.

Errors (:mod:`dpos_core.errors`)
    :class:`~dpos_core.errors.RejectedInput` from the core (a fix that fails its checks): a
    warning ``<input> rejected (<reason>): <what was wrong>``, counted as above.
    :class:`~dpos_core.errors.NumericalFailure` (the update failed numerically in every heading
    hypothesis; the core restored the previous state): logged at ERROR, counted
    (``numerical_failures``, ``last_failure``), and the status goes to level ERROR (message
    DEGRADED once aligned) until an epoch succeeds again.  A heading hypothesis dropped because
    its update failed is warned about and counted (``hypotheses_failed``); one pruned by
    likelihood or merged is logged at INFO.  Cholesky jitter repairs of the filters are counted
    (``chol_jitter_repairs``).  Anything else - a wrong shape, a wrong type - is a bug: it is not
    caught, the node stops with the traceback.

Outputs per accepted epoch
    ``/ifa/correction`` (Odometry, frame ``enu``, child ``master_imu``): the corrected master state
    at the IMU sample of the epoch (stamp = that sample's stamp: the last sample at or before the
    fix; the GNSS epoch itself on a common grid), pose covariance from the filter (position,
    attitude error about the local ENU axes rotated into ``enu``), twist in the body with the
    velocity covariance.
    ``/ifa/imu_bias`` (Imu, frame ``master_imu``): the gyro / accelerometer bias compensation the
    closed loop removes from the IMU samples after the stamp, with the filter's covariances.
    Published from the alignment epoch on: [Fang2012] sec. 3.3 feeds the biases back when the
    alignment ends (before, their estimates are in the status: ``gyro_bias_deg_h``,
    ``accel_bias_ug``), so pos_master_node can apply every message it gets.
    ``/ifa/status`` (DiagnosticArray, TRANSIENT_LOCAL): message WAITING (no data yet; level
    STALE), ALIGNING (WARN), ALIGNED (OK), DEGRADED (WARN: innovations inconsistent), DIVERGED
    (WARN: restarted); level ERROR after a numerical failure (above); key/values: method, epochs,
    aligned (true once the alignment was declared: a DEGRADED after it still is), heading_sigma_deg,
    att_sigma_deg, R_diag, nis, nis_window, aligned_t_s, rejected_fixes, rejected/<reason>,
    last_rejection, before_start, unpaired, imu_samples, imu_dropped, imu_gaps, imu_start_gap_s (the
    first IMU sample after the start state minus its stamp; warned when over START_GAP_WARN_S),
    numerical_failures, last_failure, hypotheses_failed, chol_jitter_repairs, nav_discrepancy_m,
    nav_discrepancy_deg, nav_discrepancy_checks and nav_discrepancy_max_m (epochs compared so far and
    the largest difference: a status message may be missed, these are not), gyro_bias_deg_h, accel_bias_ug; and for pos_master_node's hold (see its
    navigators module): fixes_done_ns (every fix stamped up to it is finished: epoch, rejected or
    skipped; published with each), last_correction_ns / last_bias_ns (the stamps of the newest
    /ifa/correction and /ifa/imu_bias), predict_due_ns (the IMU stamp of the next outage time
    update), outage_wait_s, gnss_time_offset_s; predictions (outage time updates published).
"""

from __future__ import annotations

import bisect
import time
import warnings
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import replace as dc_replace
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistWithCovarianceStamped
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike
from rclpy.node import Node
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus
from std_msgs.msg import Header

from dpos_core import gates
from dpos_core.attitude import attitude_error, quat_to_dcm
from dpos_core.config import ConfigError, load_aircraft, scenario_aircraft
from dpos_core.earth import geodetic_to_enu
from dpos_core.errors import NumericalFailure, RejectedInput
from dpos_core.ifa.mechanization import STAMP_TOL_S, body_rate_eb, stamp_s
from dpos_core.ifa.model import GnssFix, IfaFilterConfig, check_fix
from dpos_core.ifa.pipeline import IMU_DT_SAMPLES, EpochRecord, InFlightAligner, nominal_imu_dt_s
from dpos_core.ifa.pipeline import advance as advance_imu  # run()'s own loop: live == offline by construction
from dpos_core.ifa.reference import start as course_start
from dpos_core.ifa.states import AlignmentState
from dpos_core.ifa.warmup import warm_up
from dpos_core.series import GAP_FACTOR, GnssSeries, ImuSeries, NavSeries
from dpos_core.strapdown import NavState
from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS, STATUS_QOS, keep_all
from dpos_ros.io.flow import ArrivalAge, subscribe_draining, take_waiting, use_device_fastdds_profile
from dpos_ros.runtime.node_main import run_node
from dpos_ros.runtime.params import ParameterError, datum_llh_rad, declare_config, format_config
from ifa_node.params import IfaConfig

NODE_NAME = "ifa_node"
STATUS_NAME = "ifa_node: in-flight alignment"
#: IMU samples kept while waiting for the first /master/nav
MAX_PRESTART_IMU = 20000
#: a first IMU sample this long after the start state (at least GAP_FACTOR IMU intervals) is warned about [s]
START_GAP_WARN_S = 0.1
#: period of the check for due outage time updates when no message comes [s]
OUTAGE_CHECK_S = 0.05
#: the graph is checked for second publishers this often [s] (dpos_core.gates.PublisherWatch)
PUBLISHER_CHECK_S = 2.0
#: topics with one publisher in a graph: a second one (a second graph on the domain, a stray
#: process) is warned about and counted (``publishers_extra/<topic>``)
SINGLE_PUBLISHER_TOPICS = (T.MASTER_NAV, T.MASTER_IMU, T.GNSS_FIX, T.GNSS_VEL, T.DATUM, T.IFA_CORRECTION, T.IFA_STATUS)
#: /master/nav messages kept for the epoch comparison
NAV_CACHE = 2000
#: restart (a running graph): the start fix's ground speed at least this [m/s] (its course is the
#: initial heading; pos_master_node's ``min_course_speed_mps`` default)
RESTART_MIN_COURSE_SPEED_MPS = 5.0
#: restart: pitch and roll levelled on the mean specific force over this long before the start fix [s]
#: (pos_master_node's LEVEL_WINDOW_S); a fix with less IMU data than half of it before it is no start
RESTART_LEVEL_WINDOW_S = 1.0
#: no /master/nav this long [s] of wall time after a fix that could start the node: a restart (IfaNode._check_join)
JOIN_WAIT_S = 3.0
#: GNSS fixes have come this long [s] of wall time while /master/imu has a publisher but no sample came:
#: warned once, status ``imu_starved`` (IfaNode._check_imu_starved)
IMU_STARVED_S = 5.0
#: the inputs: the sensor profile (RELIABLE, KEEP_LAST 5000 = 50 s of a 100 Hz IMU). Not KEEP_ALL
#: (nor a deeper KEEP_LAST): measured here, such a reader stopped acknowledging after ~5000
#: samples although the node had taken every one, and the simulated device's flow control then
#: waited forever. The node takes a sample in microseconds (raw bytes, decoded in batches) and
#: pos_master_node at rate_factor 0 keeps at most ``max_lead_s`` ahead of the corrections, so it
#: does not fall 5000 samples behind; a loss would show as an IMU gap (warned, counted).
INPUT_QOS = keep_all(SENSOR_QOS)
_LEVELS = {AlignmentState.WAITING.name: DiagnosticStatus.STALE, AlignmentState.ALIGNING.name: DiagnosticStatus.WARN,
           AlignmentState.ALIGNED.name: DiagnosticStatus.OK, AlignmentState.DEGRADED.name: DiagnosticStatus.WARN,
           AlignmentState.DIVERGED.name: DiagnosticStatus.ERROR}


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _sigma(variances: ArrayLike) -> np.ndarray:
    v = np.asarray(variances, dtype=float)
    return np.sqrt(np.where(v < 0.0, np.nan, v))


class IfaNode(Node):
    """In-flight alignment node; see the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: IfaConfig = declare_config(self, IfaConfig)
            self._setup()
        except ParameterError:
            self.destroy_node()
            raise

    def _setup(self) -> None:
        cfg = self.config
        if not cfg.aircraft_config and not cfg.scenario:
            raise ParameterError("aircraft_config", "", "required: the aircraft file of your installation (its gnss_lever_arm_m "
                                 "moves the GNSS antenna to the IMU); for a simulated session set scenario instead")
        try:
            aircraft = load_aircraft(cfg.aircraft_config) if cfg.aircraft_config else scenario_aircraft(cfg.scenario)
        except ConfigError as e:
            name, value = ("aircraft_config", cfg.aircraft_config) if cfg.aircraft_config else ("scenario", cfg.scenario)
            raise ParameterError(name, value, str(e)) from None
        try:
            self.core_config = cfg.core_config(aircraft.master_imu)
        except ParameterError:
            raise  # names its parameter already
        except ValueError as e:
            raise ParameterError("window", cfg.window, str(e)) from None
        self.aircraft = aircraft
        self.lever_arm_m = np.asarray(aircraft.gnss_lever_arm_m, dtype=float)
        try:  # the filter's numba kernels compiled or loaded now, not in the data flow (dpos_core.ifa.warmup)
            self.get_logger().info(f"filter warmed up in {warm_up(self.core_config, cfg.method):.1f} s")
        except Exception as e:  # (a warm-up is never a reason not to start)
            self.get_logger().warning(f"the filter's warm-up failed ({type(e).__name__}: {e}); its first epochs may be slow")
        datum = datum_llh_rad(cfg.datum)
        self.datum_llh: FloatArray | None = None if datum is None else np.asarray(datum, dtype=float)
        self.al: InFlightAligner | None = None  # once the initial state is known (_maybe_start)
        self.origin_ns: int | None = None  # the stamp of the first /master/nav (t_s = 0), set with al
        self._first_nav: bytes | None = None
        #: a restart: pos_master_node's latched /pos_master/status says it runs and took corrections (of
        #: an earlier ifa_node) before this node started; the start is then the next GNSS fix if no
        #: /master/nav comes first (:meth:`_gnss_start`)
        self.joined_running_graph = False
        self.start_source = "none"  # "/master/nav" or "gnss_fix" once started (status key ``start``)
        #: a restart's levelling (dpos_core.ifa.standstill.start_level: ``compensated``, ``raw``, ``rest``) and the
        #: filter's prior pitch / roll sigma it started with [deg] (status ``start_level``, ``start_level_sigma_deg``)
        self.start_level = "none"
        self.start_level_sigma_deg = float("nan")
        self._no_start: set[int] = set()  # fix stamps tried as a restart's start (or unfit)
        self._join_since: float | None = None  # monotonic time a fix that could start the node was here (_check_join)
        self._first_fix_wall: float | None = None  # monotonic time the first GNSS fix came (_check_imu_starved)
        self.imu_starved = False  # fixes for IMU_STARVED_S, /master/imu published, none of it here (warned once)
        self._imu: list[tuple[int, bytes]] = []  # buffered raw samples, not yet propagated
        self._last_imu_ns: int | None = None
        self._end_ns: int | None = None  # /session/end: the stamp of the session's last sample
        self._imu_dt_s: float | None = None
        self._last_sample: tuple[int, np.ndarray] | None = None  # last propagated (t_ns, omega)
        self._fixes: dict[int, NavSatFix] = {}
        self._vels: dict[int, TwistWithCovarianceStamped] = {}
        self._imu_arrival = ArrivalAge()  # /master/imu stamps by arrival wall time (outage time updates)
        self.predictions = 0  # time updates alone published (outages)
        self._newest_fix_ns = -1  # newest stamps of each stream (pairing: module docstring)
        self._newest_vel_ns = -1
        self._arrived: dict[int, float] = {}  # fix / velocity stamp -> monotonic time of arrival
        self._navs: OrderedDict[int, bytes] = OrderedDict()
        self._pre: OrderedDict[int, Any] = OrderedDict()  # shadow state at epochs before the update
        self.epochs = 0
        self.rejected = 0
        self.rejected_by_reason: dict[str, int] = {}  # reason code -> rejected fixes
        self.before_start = 0  # fixes stamped at or before the aligner's start: skipped quietly
        self.unpaired = 0
        self.last_rejection = ""
        self.numerical_failures = 0
        self.last_failure = ""
        self._failed = False  # the last epoch failed numerically (status level ERROR until one succeeds)
        self.imu_samples = 0
        self.imu_dropped = 0
        self.imu_gaps = 0
        self.imu_start_gap_s = 0.0  # first IMU sample after the start state - its stamp [s]
        self.discrepancy = (float("nan"), float("nan"))
        self.discrepancy_checks = 0  # epochs compared with /master/nav, and the largest difference [m] of all
        self.max_discrepancy_m = 0.0
        self.last_record: EpochRecord | None = None
        self.corrections_published = 0
        #: the newest GNSS stamp [ns] up to which every fix is finished (epoch, rejected or skipped), and
        #: the stamp [ns] of the newest correction published: pos_master_node holds its IMU samples after
        #: a fix until both tell it that fix's correction (if any) is in its hands
        self.fixes_done_ns: int | None = None
        self.last_correction_ns: int | None = None
        self.last_bias_ns: int | None = None  # the stamp of the newest /ifa/imu_bias
        self._warned_unknown_cov = False
        self.gates = gates.GateCounts()  # refused inputs (dpos_core.gates): /dpos/datum changes
        self.publisher_watch = gates.PublisherWatch({t: 1 for t in SINGLE_PUBLISHER_TOPICS})
        self.imu_interleave = gates.InterleaveWatch()  # /master/imu stamps from two sources (a second graph)

        self.pub_correction = self.create_publisher(Odometry, T.IFA_CORRECTION, NAV_QOS)
        self.pub_bias = self.create_publisher(Imu, T.IFA_IMU_BIAS, NAV_QOS)
        self.pub_status = self.create_publisher(DiagnosticArray, T.IFA_STATUS, STATUS_QOS)
        # an outage time update may become due in wall time only (outage_wait_s) after the last sample came
        self.create_timer(OUTAGE_CHECK_S, self._on_timer)
        subscribe_draining(self, Imu, T.MASTER_IMU, self._on_imu, INPUT_QOS, raw=True)
        subscribe_draining(self, Odometry, T.MASTER_NAV, self._on_nav, INPUT_QOS, raw=True)
        self._gnss_subs = [(subscribe_draining(self, NavSatFix, T.GNSS_FIX, self._on_fix, INPUT_QOS), NavSatFix, self._on_fix),
                           (subscribe_draining(self, TwistWithCovarianceStamped, T.GNSS_VEL, self._on_vel, INPUT_QOS),
                            TwistWithCovarianceStamped, self._on_vel)]
        self._in_outage_check = False
        self.create_subscription(Header, T.SESSION_END, self._on_session_end, NAV_QOS)
        self._master_status_sub = self.create_subscription(DiagnosticArray, T.POS_MASTER_STATUS, self._on_master_status, STATUS_QOS)
        self._datum_from_topic = self.datum_llh is None
        if self._datum_from_topic:  # (the datum parameter wins: /dpos/datum is not read then)
            self.create_subscription(NavSatFix, T.DATUM, self._on_datum, DATUM_QOS)
        self.create_timer(PUBLISHER_CHECK_S, self._check_publishers)
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(cfg, ('method', 'window', 'use_reported_sigma', 'aligned_heading_sigma_deg'))}"
            f" aircraft={aircraft.name} lever_arm_m={list(self.lever_arm_m)}: subscribing /master/nav, /master/imu,"
            f" /gnss/fix, /gnss/vel{'' if self.datum_llh is not None else ', /dpos/datum'}"
            " -> publishing /ifa/correction, /ifa/imu_bias, /ifa/status"
        )
        self._publish_status()

    # ------------------------------------------------------------------ inputs
    def _on_datum(self, msg: NavSatFix) -> None:
        """/dpos/datum: the first valid one is kept for the node's life (its session); another one is
        refused, warned about and counted (dpos_core.gates.check_datum)."""
        refusal = gates.check_datum(self.datum_llh, cv.datum_from_msg(msg))
        if refusal is not None:
            self._refuse(f"datum/{refusal.reason}", f"{T.DATUM}: {refusal.text}")
            return
        if self.datum_llh is None:
            self.datum_llh = cv.datum_from_msg(msg)
            self._maybe_start()

    def _refuse(self, reason: str, text: str) -> None:
        """Count a refused input (``gate/<reason>``); log it (the first of its reason, then at a bounded rate)."""
        line = self.gates.refuse(reason, text, time.monotonic())
        if line is not None:
            self.get_logger().warning(line)
        self._publish_status()

    def _check_publishers(self) -> None:
        """Warn about (and count) a second publisher on a topic that should have one."""
        changed = False
        for topic in SINGLE_PUBLISHER_TOPICS:
            eps = [(bytes(i.endpoint_gid), f"{i.node_namespace.rstrip('/')}/{i.node_name}")
                   for i in self.get_publishers_info_by_topic(topic)]
            for text in self.publisher_watch.update(topic, eps):
                self.get_logger().warning(text)
                changed = True
        if changed:
            self._publish_status()

    def _on_nav(self, raw: bytes) -> None:
        if self.al is None:
            if self._first_nav is None:
                self._first_nav = bytes(raw)
                self._maybe_start()
            return
        t_ns = cv.raw_stamp_ns(raw)
        if t_ns in self._pre:
            self._compare(self._pre.pop(t_ns), raw)
        else:
            self._navs[t_ns] = bytes(raw)
            while len(self._navs) > NAV_CACHE:
                self._navs.popitem(last=False)

    def _on_imu(self, raw: bytes) -> None:
        """Buffer the raw sample (decoded in batches when propagated); stamp checks here."""
        t_ns = cv.raw_stamp_ns(raw)
        log = self.get_logger()
        last = self._last_imu_ns
        if self.imu_interleave.add(last is not None and t_ns <= last):
            log.warning(f"/master/imu: {self.imu_interleave.back_in_window} of the last {self.imu_interleave.window} stamps went "
                        "back: two sources interleave on it (a second graph on this ROS domain, a second device?); the "
                        "samples out of order are dropped (status imu_interleaved, imu_dropped)")
        if last is not None and t_ns <= last:
            self.imu_dropped += 1
            log.warning(f"{'duplicate' if t_ns == last else 'out-of-order'} /master/imu stamp {t_ns} ns (last {last} ns): dropped")
            return
        if last is not None and self._imu_dt_s is not None and (t_ns - last) * 1e-9 > GAP_FACTOR * self._imu_dt_s:
            self.imu_gaps += 1
            log.warning(f"/master/imu gap of {(t_ns - last) * 1e-9:.4f} s before stamp {t_ns} ns: integrated across")
        self._last_imu_ns = t_ns
        self.imu_samples += 1
        self._imu.append((t_ns, bytes(raw)))
        self._imu_arrival.add(t_ns)
        if self.al is None:
            if len(self._imu) > MAX_PRESTART_IMU:
                del self._imu[: len(self._imu) - MAX_PRESTART_IMU]
            self._maybe_start()
        else:
            self._process()

    def _on_fix(self, msg: NavSatFix) -> None:
        t_ns = _stamp_ns(msg.header)
        if t_ns in self._fixes:
            self._reject(t_ns, f"duplicate GNSS stamp {t_ns} ns (a fix with this stamp is already waiting): dropped", "duplicate")
            return
        self._fixes[t_ns] = msg
        self._newest_fix_ns = max(self._newest_fix_ns, t_ns)
        if self._first_fix_wall is None:
            self._first_fix_wall = time.monotonic()
        self._arrived.setdefault(t_ns, time.monotonic())
        self._process()

    def _on_session_end(self, msg: Header) -> None:
        """/session/end (simulation): no sample after its stamp will come; the fixes waiting for one are
        applied once the IMU up to it is here (run() at the end of its series)."""
        self._end_ns = _stamp_ns(msg)
        self.get_logger().info(f"/session/end at stamp {self._end_ns} ns ({msg.frame_id}): the fixes up to the last IMU sample are applied")
        self._process()

    def _on_vel(self, msg: TwistWithCovarianceStamped) -> None:
        t_ns = _stamp_ns(msg.header)
        if self.origin_ns is not None and self._before_start(t_ns):
            return  # its fix is skipped (before_start)
        if t_ns in self._vels:
            self.get_logger().warning(f"duplicate /gnss/vel stamp {t_ns} ns: the first one is kept")
            return
        self._vels[t_ns] = msg
        self._newest_vel_ns = max(self._newest_vel_ns, t_ns)
        self._arrived.setdefault(t_ns, time.monotonic())
        self._process()

    # ------------------------------------------------------------------ start
    def _on_master_status(self, msg: DiagnosticArray) -> None:
        """/pos_master/status (latched): a pos_master_node that has started and applied corrections
        before this node started runs a session whose ifa_node was restarted (this one). Its
        /master/nav start state was published long ago, so the start is the next GNSS fix
        (:meth:`_gnss_start`) unless a /master/nav message comes first."""
        if self.al is not None or self.joined_running_graph:
            return
        for st in msg.status:
            if not st.name.startswith("pos_master"):
                continue
            values = {kv.key: kv.value for kv in st.values}
            try:
                corrected = int(values.get("corrections", "0")) > 0
            except ValueError:
                corrected = False
            if values.get("started") == "True" and corrected:
                self.joined_running_graph = True
                self.get_logger().warning(
                    f"{T.POS_MASTER_STATUS}: pos_master_node runs and has applied {values.get('corrections')} corrections"
                    f" (its navigation at t={values.get('nav_t_s')} s): this ifa_node joins a running session (a restart);"
                    " it starts UNALIGNED with its prior covariance from the next GNSS fix (position, velocity, course"
                    " heading, pitch and roll levelled on the IMU) unless a /master/nav message comes first")
                self._maybe_start()
                return

    def _maybe_start(self) -> None:
        """Start the aligner from the first /master/nav once the datum and enough IMU samples are
        known; joining a running session (:meth:`_on_master_status`) from the next GNSS fix if no
        /master/nav has come."""
        if self.al is not None or self.datum_llh is None:
            return
        if self._first_nav is not None:
            self._nav_start(self._first_nav)
        elif self.joined_running_graph:
            self._gnss_start()

    def _nav_start(self, first_nav: bytes) -> None:
        """The start from the first /master/nav (the state pos_master_node's mechanization starts from)."""
        t0_ns, v = cv.decode_raw(first_nav, "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        self._imu = [s for s in self._imu if s[0] > t0_ns]
        if len(self._imu) < IMU_DT_SAMPLES:
            return
        blk = cv.odometry_from_values(np.array([t0_ns]), v[None], self._datum())
        self._start(t0_ns, NavState(0.0, blk.q_nb[0], blk.vel_n_mps[0], blk.llh[0]), "/master/nav", f"/master/nav at stamp {t0_ns} ns")

    def _start_candidates(self) -> Iterator[tuple[int, int, int, list[int]]]:
        """The waiting fixes that may start a restart (:meth:`_gnss_start`), oldest first:
        ``(fix stamp, its velocity's stamp, the fix on the IMU's clock [ns], the buffered IMU stamps)``:
        a velocity, a fix, ``RESTART_LEVEL_WINDOW_S / 2`` of IMU data before it (else it is never one)
        and ``IMU_DT_SAMPLES`` after it (else it and the later ones are not yet)."""
        if not self._imu:
            return
        offset_ns = int(round(self.core_config.gnss_time_offset_s * 1e9))
        first_imu_ns, last_imu_ns = self._imu[0][0], self._imu[-1][0]
        stamps: list[int] | None = None
        for t_ns in sorted(self._fixes):
            fix_msg, kv = self._fixes[t_ns], self._pair(t_ns)
            t0_ns = t_ns - offset_ns  # on the IMU's clock
            if t_ns in self._no_start or kv is None or fix_msg.status.status == NavSatStatus.STATUS_NO_FIX:
                continue
            if t0_ns - first_imu_ns < 0.5 * RESTART_LEVEL_WINDOW_S * 1e9:
                self._no_start.add(t_ns)  # too little IMU data before it to level on
                continue
            if last_imu_ns <= t0_ns:
                return  # the IMU after it is not here yet (the later fixes' neither)
            if stamps is None:
                stamps = [s for s, _ in self._imu]
            if len(stamps) - bisect.bisect_right(stamps, t0_ns) < IMU_DT_SAMPLES:
                return
            yield t_ns, kv, t0_ns, stamps

    def _check_join(self) -> None:
        """No /master/nav ``JOIN_WAIT_S`` of wall time after a fix that could start the node (ground
        speed, IMU around it) was here, while /master/nav has a publisher: pos_master_node runs
        and its start state was published before this node ran (a restart, also when its latched
        /pos_master/status does not reach this node): join the running session."""
        if self.al is not None or self.joined_running_graph or self._first_nav is not None or self.datum_llh is None:
            return
        now = time.monotonic()
        if self._join_since is None:
            for _, kv, _, _ in self._start_candidates():
                lin = self._vels[kv].twist.twist.linear
                if np.hypot(lin.x, lin.y) >= RESTART_MIN_COURSE_SPEED_MPS:
                    self._join_since = now
                    break
            return
        if now - self._join_since < JOIN_WAIT_S or self.count_publishers(T.MASTER_NAV) == 0:
            return
        self.joined_running_graph = True
        self.get_logger().warning(
            f"no /master/nav for {JOIN_WAIT_S:g} s while GNSS and IMU data come and pos_master_node publishes it: its start"
            " state was published before this node ran (a restart); this ifa_node joins the running session, UNALIGNED"
            " with its prior covariance, from the next GNSS fix (position, velocity, course heading, pitch and roll"
            " levelled on the IMU)")
        self._maybe_start()

    def _gnss_start(self) -> None:
        """A restart: the start from the oldest waiting fix with its velocity, a ground speed of
        ``RESTART_MIN_COURSE_SPEED_MPS`` or more, ``RESTART_LEVEL_WINDOW_S / 2`` of IMU data before
        it and ``IMU_DT_SAMPLES`` after it (:func:`dpos_core.ifa.reference.start`, pos_master_node's
        course start: velocity = the fix's, heading = course over ground, pitch and roll levelled on
        the IMU, position = the fix moved to the IMU by the lever arm), stamped at the fix on the
        IMU's clock. Fixes that are no start wait and are skipped at the start (``before_start``)."""
        for t_ns, kv, t0_ns, stamps in self._start_candidates():
            fix_msg = self._fixes[t_ns]
            fix = self._gnss_fix(t_ns, fix_msg, self._vels[kv], origin_ns=t0_ns)
            self._no_start.add(t_ns)  # (tried once: a start, or none)
            if not (np.all(np.isfinite(fix.llh)) and np.all(np.isfinite(fix.vel_n_mps))):
                continue
            lo, hi = t0_ns - int(round(RESTART_LEVEL_WINDOW_S * 1e9)), bisect.bisect_right(stamps, t0_ns) + IMU_DT_SAMPLES
            fixes = [fix]
            prev = self._previous_fix(t_ns, t0_ns)
            if prev is not None:  # its velocity gives the vehicle's acceleration over the level window
                fixes.insert(0, prev)
                lo = max(lo, int(t0_ns + round(prev.t_s * 1e9)))  # (the IMU after it: start() takes the later fix)
            batch = [r for s, r in self._imu[:hi] if s > lo]
            t_imu, vals = cv.decode_raw_batch(batch, "imu", cv.MASTER_FRAME)
            ok = np.all(np.isfinite(vals[:, 13:16]), axis=1) & np.all(np.isfinite(vals[:, 25:28]), axis=1)
            imu = ImuSeries(stamp_s(t_imu[ok], t0_ns), vals[ok, 13:16], vals[ok, 25:28])
            gnss = GnssSeries(np.array([f.t_s for f in fixes[:-1]] + [0.0]), np.array([f.llh for f in fixes]),
                              np.array([f.pos_sigma_m for f in fixes]), np.array([f.vel_n_mps for f in fixes]),
                              np.array([f.vel_sigma_mps for f in fixes]))
            try:
                initial, lv = course_start(imu, gnss, RESTART_MIN_COURSE_SPEED_MPS, RESTART_LEVEL_WINDOW_S, lever_arm_m=self.lever_arm_m,
                                           level="auto", imu_model=self.core_config.imu)
            except ValueError as e:  # too slow for a course, nothing to level on
                self.get_logger().info(f"restart: the fix at stamp {t_ns} ns is no start ({e}); waiting for the next",
                                       throttle_duration_sec=5.0)
                continue
            cfg = self.core_config
            if lv is not None and lv.sigma_rad is not None and lv.sigma_rad / DEG > cfg.level_sigma_deg:
                cfg = dc_replace(cfg, level_sigma_deg=lv.sigma_rad / DEG)  # what the motion can leave in the level
            self.start_level = "none" if lv is None else lv.how
            self.start_level_sigma_deg = cfg.level_sigma_deg
            speed = float(np.hypot(fix.vel_n_mps[0], fix.vel_n_mps[1]))
            how = {"compensated": "with the vehicle's acceleration (GNSS velocities) removed",
                   "rest": "at rest"}.get(self.start_level, "without the vehicle's acceleration (no fix just before)")
            self._start(t0_ns, NavState(0.0, initial.q_nb, initial.vel_n_mps, initial.llh), "gnss_fix",
                        f"the GNSS fix at stamp {t_ns} ns (a restart: heading = course over ground at {speed:.1f} m/s,"
                        f" pitch and roll levelled on the IMU {how}, level sigma {cfg.level_sigma_deg:.2f} deg,"
                        " lever arm removed)", cfg)
            return

    def _previous_fix(self, t_ns: int, t0_ns: int) -> GnssFix | None:
        """The waiting fix (with its velocity) just before the fix stamped ``t_ns``, when it is at most
        ``1.5 RESTART_LEVEL_WINDOW_S`` older (:func:`dpos_core.ifa.standstill.start_level`'s span for an
        acceleration), its time relative to ``t0_ns`` on the IMU's clock; else None."""
        earlier = [k for k in self._fixes if k < t_ns]
        if not earlier:
            return None
        k = max(earlier)
        kv = self._pair(k)
        if kv is None or (t_ns - k) * 1e-9 > 1.5 * RESTART_LEVEL_WINDOW_S or self._fixes[k].status.status == NavSatStatus.STATUS_NO_FIX:
            return None
        offset_ns = int(round(self.core_config.gnss_time_offset_s * 1e9))
        prev = self._gnss_fix(k, self._fixes[k], self._vels[kv], origin_ns=t0_ns + offset_ns)
        ok = np.all(np.isfinite(prev.llh)) and np.all(np.isfinite(prev.vel_n_mps)) and np.all(np.isfinite(prev.vel_sigma_mps))
        return prev if ok else None

    def _start(self, t0_ns: int, initial: NavState, source: str, what: str, cfg: IfaFilterConfig | None = None) -> None:
        """Start the aligner from ``initial`` (t_s 0) stamped ``t0_ns`` [ns] (the time origin), with the
        filter configuration ``cfg`` (default: the node's); the buffered IMU samples after it set the
        IMU interval (at least IMU_DT_SAMPLES, else later)."""
        self._imu = [s for s in self._imu if s[0] > t0_ns]
        if len(self._imu) < IMU_DT_SAMPLES:
            return
        t_imu = np.array([s[0] for s in self._imu[:IMU_DT_SAMPLES]], dtype=np.int64)  # the IMU interval: median step
        self._imu_dt_s = nominal_imu_dt_s(stamp_s(t_imu, t0_ns))  # the same rule as run()
        self.imu_start_gap_s = (self._imu[0][0] - t0_ns) * 1e-9
        if self.imu_start_gap_s > max(GAP_FACTOR * self._imu_dt_s, START_GAP_WARN_S):
            # e.g. a replay started before this node subscribed: the motion in between is not measured
            self.get_logger().warning(
                f"the first /master/imu sample after the start state ({what}) is {self.imu_start_gap_s:.3f} s "
                f"after it (IMU interval {self._imu_dt_s:.4g} s): the navigation integrates across this gap and is wrong by the "
                "motion in it until GNSS corrects it; start this node before the data (status imu_start_gap_s)")
        self.origin_ns = t0_ns
        self.al = InFlightAligner(initial, self.lever_arm_m, self.core_config if cfg is None else cfg, self.config.method,
                                  self._imu_dt_s)
        self._first_nav = None
        self.start_source = source
        hpr = initial.hpr_rad / DEG
        self.get_logger().info(
            f"started from {what}: heading {hpr[0]:.3f} pitch {hpr[1]:.3f} roll {hpr[2]:.3f} deg,"
            f" IMU interval {self._imu_dt_s:.6g} s; {self.config.method.upper()} ALIGNING"
        )
        self._publish_status()
        self._process()

    def _aligner(self) -> InFlightAligner:
        """The aligner; RuntimeError before the start (:meth:`_maybe_start`)."""
        if self.al is None:
            raise RuntimeError(f"{NODE_NAME}: the aligner is used before it started (first /master/nav, datum and IMU)")
        return self.al

    def _origin(self) -> int:
        """The time origin [ns] (the first /master/nav's stamp); RuntimeError before the start."""
        if self.origin_ns is None:
            raise RuntimeError(f"{NODE_NAME}: the time origin is used before the start (first /master/nav)")
        return self.origin_ns

    def _datum(self) -> FloatArray:
        """The ``enu`` datum [lat_rad, lon_rad, h_m]; RuntimeError while it is not known (neither the
        ``datum`` parameter nor /dpos/datum)."""
        if self.datum_llh is None:
            raise RuntimeError(f"{NODE_NAME}: the datum is used before it is known (datum parameter or /dpos/datum)")
        return self.datum_llh

    # ------------------------------------------------------------------ epochs
    def _reject(self, t_ns: int, reason: str, code: str, what: str = "GNSS fix") -> None:
        """Count and warn about a rejected fix (``code``: the short reason for ``rejected/<code>``)."""
        self.rejected += 1
        self.rejected_by_reason[code] = self.rejected_by_reason.get(code, 0) + 1
        self.last_rejection = reason
        self.get_logger().warning(f"{what} rejected ({code}) at stamp {t_ns} ns: {reason}")
        self._publish_status()

    def _rejected(self, t_ns: int, e: RejectedInput) -> None:
        self._reject(t_ns, str(e), e.reason, e.what)

    def _numerical_failure(self, t_ns: int, e: NumericalFailure) -> None:
        """The core's update failed numerically (its state is restored): ERROR, counted, status ERROR."""
        self.numerical_failures += 1
        self.last_failure = str(e)
        self._failed = True
        self.get_logger().error(f"{e.what} failed numerically at the GNSS fix of stamp {t_ns} ns, the fix is dropped: {e}")
        self._publish_status()

    def _gnss_fix(self, t_ns: int, fix: NavSatFix, vel: TwistWithCovarianceStamped | None, origin_ns: int | None = None) -> GnssFix:
        """The fix (and its velocity) as the core takes it, its time relative to ``origin_ns`` (default: the node's origin)."""
        cov = np.asarray(fix.position_covariance, dtype=float).reshape(3, 3)
        if fix.position_covariance_type == NavSatFix.COVARIANCE_TYPE_UNKNOWN:
            pos_sigma = np.asarray(self.config.gnss_pos_sigma_m, dtype=float)
            if not self._warned_unknown_cov:
                self._warned_unknown_cov = True
                self.get_logger().warning("/gnss/fix without covariance (COVARIANCE_TYPE_UNKNOWN): using gnss_pos_sigma_m")
        else:
            pos_sigma = _sigma(np.diag(cov))
        if vel is None:
            v, v_sigma = np.zeros(3), np.ones(3)
        else:
            lin = vel.twist.twist.linear
            v = np.array([lin.x, lin.y, lin.z], dtype=float)
            v_sigma = _sigma(np.diag(np.asarray(vel.twist.covariance, dtype=float).reshape(6, 6))[:3])
        llh = np.array([np.deg2rad(fix.latitude), np.deg2rad(fix.longitude), fix.altitude], dtype=float)
        return GnssFix(float(stamp_s(t_ns, self._origin() if origin_ns is None else origin_ns)), llh, pos_sigma, v, v_sigma)

    def _pair(self, t_ns: int) -> int | None:
        tol = int(round(self.config.pair_tolerance_s * 1e9))
        near = [k for k in self._vels if abs(k - t_ns) <= tol]
        return min(near, key=lambda k: abs(k - t_ns)) if near else None

    def _finish(self, t_ns: int) -> None:
        """The fix stamped ``t_ns`` leaves the queue: it is finished (epoch, rejection or skip); the
        fixes are taken in stamp order, so every fix up to ``t_ns`` is (``fixes_done_ns``)."""
        del self._fixes[t_ns]
        self.fixes_done_ns = t_ns if self.fixes_done_ns is None else max(self.fixes_done_ns, t_ns)

    def _fix_time_s(self, t_ns: int) -> float:
        """A GNSS stamp [ns] on the IMU's clock: seconds since the origin minus ``gnss_time_offset_s``
        (:func:`dpos_core.ifa.pipeline.fix_at`'s arithmetic)."""
        return float(stamp_s(t_ns, self._origin())) - self.core_config.gnss_time_offset_s

    def _before_start(self, t_ns: int) -> bool:
        """A GNSS stamp at or before the aligner's start (its initial state)."""
        return self._fix_time_s(t_ns) <= STAMP_TOL_S

    def _on_timer(self) -> None:
        """The checks in wall time, when the executor is free: first the GNSS messages waiting in the
        middleware are taken (this node may have been busy), then a fix or velocity whose partner did
        not come for ``pair_timeout_s`` is dropped, and the due outage time updates are made."""
        self._take_gnss()
        self._check_imu_starved()
        self._check_join()
        self._process(wall=True)
        self._outage_predict()

    def _check_imu_starved(self) -> None:
        """GNSS fixes have come for ``IMU_STARVED_S`` of wall time and /master/imu has a publisher,
        but no sample of it came: warn once (status ``imu_starved``, level WARN) with the likely
        cause. The node cannot start without the IMU. Measured (docs/reliability.md, G13): Fast DDS
        refuses every sample to a VOLATILE reliable reader that matched a writer after it had sent
        as many messages as the reader's ``max_samples`` (5000 by default); :func:`main` lifts the
        limit (``use_device_fastdds_profile``), a deployment's own Fast DDS profile must."""
        if self.imu_starved or self.imu_samples or self._first_fix_wall is None:
            return
        if time.monotonic() - self._first_fix_wall < IMU_STARVED_S or self.count_publishers(T.MASTER_IMU) == 0:
            return
        self.imu_starved = True
        self.get_logger().warning(
            f"{T.MASTER_IMU} has a publisher and GNSS fixes have come for {IMU_STARVED_S:g} s, but no IMU sample: this node"
            " cannot start. Likely cause: it joined the stream late (a restart) and its reader refuses every sample because"
            " the writer had sent more messages than the reader's resource limit (Fast DDS max_samples, 5000 by default)."
            " The ifa_node executable lifts the limit; with your own Fast DDS profile (FASTRTPS_DEFAULT_PROFILES_FILE) set"
            " max_samples 0 for the readers (docs/reliability.md, G13). Status imu_starved")
        self._publish_status()

    def _process(self, wall: bool = False) -> None:
        """Apply every GNSS epoch whose IMU samples are all here (stamp order; module docstring)."""
        al, origin_ns = self.al, self.origin_ns
        if al is None or origin_ns is None:  # not started (both are set by _maybe_start)
            return
        timeout_ns = int(round(self.config.pair_timeout_s * 1e9))
        bridge = self.core_config.max_fix_bridge_s
        skipped = self.before_start
        while self._fixes:
            t_ns = min(self._fixes)
            fix_msg = self._fixes[t_ns]
            t_s = self._fix_time_s(t_ns)
            if t_s <= STAMP_TOL_S:  # at or before the start: the initial state has it (or it is older)
                self._finish(t_ns)
                kv = self._pair(t_ns)
                if kv is not None:
                    del self._vels[kv]
                self.before_start += 1
                continue
            if self.before_start > skipped:  # fixes_done_ns moved on: pos_master_node's hold waits for it
                skipped = self.before_start
                self._publish_status()
            if al.last_fix_t is not None and t_s <= al.last_fix_t + 1e-9:  # no need to wait for its velocity
                self._finish(t_ns)
                kv = self._pair(t_ns)
                vel = self._vels.pop(kv) if kv is not None else None
                try:
                    check_fix(self._gnss_fix(t_ns, fix_msg, vel), al.last_fix_t)
                    self._reject(t_ns, f"GNSS fix at t={t_s} is before the navigation time", "stale")
                except RejectedInput as e:
                    self._rejected(t_ns, e)
                continue
            kv = self._pair(t_ns)
            if kv is None:
                if self._partner_gone(t_ns, self._newest_vel_ns, timeout_ns, wall):
                    self._finish(t_ns)
                    self.unpaired += 1
                    self.get_logger().warning(f"/gnss/fix at stamp {t_ns} ns has no /gnss/vel within "
                                              f"{self.config.pair_tolerance_s} s: dropped")
                    self._publish_status()  # fixes_done_ns moved on
                    continue
                break  # wait for its velocity
            ended = self._end_ns is not None and self._last_imu_ns is not None and self._last_imu_ns >= self._end_ns
            if not ended and (self._last_imu_ns is None or float(stamp_s(self._last_imu_ns, origin_ns)) <= t_s + STAMP_TOL_S):
                break  # wait for a sample after the fix: then every sample up to it is here
            self._finish(t_ns)
            vel = self._vels.pop(kv)
            t_last_s = float(stamp_s(self._last_imu_ns, origin_ns)) if self._last_imu_ns is not None else 0.0
            if ended and t_s > t_last_s + bridge:
                self._reject(t_ns, f"GNSS fix at t={t_s} is after the session's last IMU sample (t={t_last_s})", "stale")
                continue
            if fix_msg.status.status == NavSatStatus.STATUS_NO_FIX:
                self._reject(t_ns, f"GNSS message at t={t_s} reports no fix (status {fix_msg.status.status})", "no_fix")
                continue
            fix = self._gnss_fix(t_ns, fix_msg, vel)
            try:
                check_fix(fix, al.last_fix_t)
                if t_s < al.model.t_s - bridge:
                    raise RejectedInput(f"GNSS fix at t={t_s} is older than the navigation (t={al.model.t_s})", what="GNSS fix",
                                        reason="stale", t_s=t_s)
            except RejectedInput as e:
                self._rejected(t_ns, e)
                continue
            self._propagate_to(t_s)
            self._epoch(t_ns, fix)
        if self.before_start > skipped:
            self._publish_status()
        self._expire_vels(timeout_ns, wall)
        if len(self._arrived) > len(self._fixes) + len(self._vels):
            self._arrived = {k: v for k, v in self._arrived.items() if k in self._fixes or k in self._vels}

    def _outage_predict(self) -> None:
        """Outages: the time updates alone that are due (module docstring, ``outage_wait_s``), each
        published as an /ifa/correction (the navigation, unchanged, with the grown covariance) so that
        /master/nav's covariance grows through the outage as the offline run's track does."""
        al, origin_ns = self.al, self.origin_ns
        if al is None or origin_ns is None or self._end_ns is not None or self._in_outage_check:
            return  # at the end of a session the fixes' processing does the rest (as run())
        self._in_outage_check = True
        try:
            self._outage_updates(al, origin_ns)
        finally:
            self._in_outage_check = False

    def _take_gnss(self) -> bool:
        """Take the fixes and velocities already waiting in the middleware (this node may have been
        busy longer than ``outage_wait_s``): True when there were any."""
        taken = False
        for sub, cls, callback in self._gnss_subs:
            try:
                more = take_waiting(sub, cls, False)
            except RuntimeError:  # being destroyed
                continue
            for m, _ in more:
                callback(m)
                taken = True
        return taken

    def _outage_updates(self, al: InFlightAligner, origin_ns: int) -> None:
        wait_s = self.config.outage_wait_s
        while True:
            tick_s = al.next_predict_t_s
            aged_ns = self._imu_arrival.aged_ns(wait_s)
            last_ns = self._last_imu_ns
            if (last_ns is None or aged_ns is None or float(stamp_s(last_ns, origin_ns)) < tick_s + wait_s
                    or float(stamp_s(aged_ns, origin_ns)) < tick_s):
                return  # not due: IMU data outage_wait_s past it, here for outage_wait_s of wall time
            if self._take_gnss():
                return  # fixes came in the meantime: they go first (this is called again)
            if any(self._fix_time_s(t) <= tick_s + STAMP_TOL_S for t in self._fixes):
                return  # a fix before it waits (for its velocity): the fixes go first
            before = al.last_epoch_t_s
            self._propagate_to(tick_s)  # stops at the tick (advance() makes the time updates it passes)
            if al.last_epoch_t_s == before:
                if al.model.t_s <= before + STAMP_TOL_S:  # no sample up to the tick: a gap in the IMU
                    after = [t for t, _ in self._imu if float(stamp_s(t, origin_ns)) > tick_s]
                    if not after:
                        return
                    self._propagate_to(float(stamp_s(after[0], origin_ns)))  # crossed; the update at that sample
                else:
                    try:
                        al.predict()
                    except NumericalFailure as e:
                        self._numerical_failure(int(origin_ns + round(tick_s * 1e9)), e)
                        al.last_epoch_t_s = al.model.t_s
            if al.last_epoch_t_s <= before:
                return
            self.predictions += 1
            sample_ns = self._last_sample[0] if self._last_sample is not None else origin_ns
            self._publish_epoch(sample_ns, None)
            self._publish_status()

    def _expire_vels(self, timeout_ns: int, wall: bool) -> None:
        for k in [k for k in self._vels if self._partner_gone(k, self._newest_fix_ns, timeout_ns, wall) and self._pair_fix(k) is None]:
            del self._vels[k]
            if self._before_start(k):
                continue  # its fix was skipped (before_start): quietly
            self.unpaired += 1
            self.get_logger().warning(f"/gnss/vel at stamp {k} ns has no /gnss/fix: dropped")

    def _partner_gone(self, t_ns: int, newest_other_ns: int, timeout_ns: int, wall: bool) -> bool:
        """The partner of the fix / velocity stamped ``t_ns`` will not come: the other stream (newest
        stamp ``newest_other_ns``) has passed it by ``timeout_ns``, or (``wall``: from the timer,
        after taking what waits in the middleware) it has waited ``pair_timeout_s`` of wall time."""
        if newest_other_ns - t_ns > timeout_ns:
            return True
        return wall and time.monotonic() - self._arrived.get(t_ns, time.monotonic()) > self.config.pair_timeout_s

    def _pair_fix(self, k: int) -> int | None:
        tol = int(round(self.config.pair_tolerance_s * 1e9))
        return next((t for t in self._fixes if abs(t - k) <= tol), None)

    def _propagate_to(self, t_fix_s: float) -> None:
        """Propagate the buffered samples up to the last one at or before ``t_fix_s`` [s] (+ STAMP_TOL_S),
        with the aligner's time updates alone on the way, as run() does (:func:`~dpos_core.ifa.pipeline.advance`): the
        buffered samples up to the first one after the fix are decoded (one vectorized decode),
        non-finite ones dropped with a warning; the one(s) after the fix stay buffered."""
        al, origin_ns = self._aligner(), self._origin()
        n = 0
        while n < len(self._imu) and float(stamp_s(self._imu[n][0], origin_ns)) <= t_fix_s + STAMP_TOL_S:
            n += 1
        n = min(n + 1, len(self._imu))  # and the first one after the fix: run() sees the samples after it too
        if n == 0:
            return
        batch = self._imu[:n]
        t_ns, vals = cv.decode_raw_batch([r for _, r in batch], "imu", cv.MASTER_FRAME)
        om, f = vals[:, 13:16], vals[:, 25:28]
        ok = np.all(np.isfinite(om), axis=1) & np.all(np.isfinite(f), axis=1)
        for i in np.flatnonzero(~ok):
            self.imu_dropped += 1
            self.get_logger().warning(f"/master/imu at stamp {t_ns[i]} ns has non-finite values: dropped")
        t_ns, om, f = t_ns[ok], om[ok], f[ok]
        done = 0
        if t_ns.size:
            chunks: list[NavSeries] = []  # the navigation of the samples (run() keeps it; the master has its own)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                done = advance_imu(al, stamp_s(t_ns, origin_ns), om, f, 0, t_fix_s, chunks)
            for w in caught:  # a time update alone that failed numerically (the core warns and goes on)
                self.get_logger().warning(str(w.message))
        if done:
            self._last_sample = (int(t_ns[done - 1]), om[done - 1])
        last_ns = int(t_ns[done - 1]) if done else -1
        self._imu = [s for s, k in zip(batch, ok) if k and s[0] > last_ns] + self._imu[n:]

    def _epoch(self, t_fix_ns: int, fix: Any) -> None:
        al = self._aligner()
        sample_ns = self._last_sample[0] if self._last_sample is not None else self._origin()
        pre = al.nav
        try:
            rec = al.update(fix)
        except RejectedInput as e:  # bad data: skipped; anything else but a numerical failure is a bug
            self._rejected(t_fix_ns, e)
            return
        except NumericalFailure as e:
            self._numerical_failure(t_fix_ns, e)
            return
        log = self.get_logger()
        for ev in rec.events:  # what the bank of heading hypotheses did (the core returns it, we log it)
            if ev.kind == "failed":
                log.warning(f"{ev}")
            else:
                log.info(f"{ev} ({rec.hypotheses} left)")
        self._failed = False
        self.epochs += 1
        self.last_record = rec
        if sample_ns in self._navs:
            self._compare(pre, self._navs.pop(sample_ns))
        else:
            self._pre[sample_ns] = pre
            while len(self._pre) > 20:
                self._pre.popitem(last=False)
        self._publish_epoch(sample_ns, rec)
        self._publish_status()

    def _compare(self, shadow: Any, raw: bytes) -> None:
        t_ns, v = cv.decode_raw(raw, "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        blk = cv.odometry_from_values(np.array([t_ns]), v[None], self._datum())
        lat, lon, h = blk.llh[0]
        d_enu = geodetic_to_enu(lat, lon, h, shadow.llh)
        phi = attitude_error(quat_to_dcm(blk.q_nb[0]), shadow.C_nb)
        self.discrepancy = (float(np.linalg.norm(d_enu)), float(np.linalg.norm(phi) / DEG))
        self.discrepancy_checks += 1
        self.max_discrepancy_m = max(self.max_discrepancy_m, self.discrepancy[0])

    # ------------------------------------------------------------------ outputs
    def _cov15(self, P: np.ndarray) -> np.ndarray:
        """The (15, 15) navigation / bias covariance of the aligner's (13, 15 or 24 states)."""
        al = self._aligner()
        P15 = al.model.nav_cov15(P)
        if not self.core_config.vertical:  # vertical slaved to the GNSS (13 states)
            P15[2, 2] = self.config.gnss_pos_sigma_m[2] ** 2
            P15[5, 5] = self.config.gnss_vel_sigma_mps[2] ** 2
        return P15

    def _publish_epoch(self, t_ns: int, rec: Any) -> None:
        al = self._aligner()
        s = al.nav
        P = self._cov15(al.cov)
        omega = self._last_sample[1] if self._last_sample is not None else np.zeros(3)
        w_eb = body_rate_eb(s.q_nb[None], s.llh[None], s.vel_n_mps[None], (omega - al.model.gyro_bias_comp)[None])
        vals = cv.odometry_values_cov(s.llh[None], s.vel_n_mps[None], s.q_nb[None], self._datum(), w_eb,
                                      P[0:3, 0:3], P[6:9, 6:9], P[3:6, 3:6])
        stamp = np.array([t_ns], dtype=np.int64)
        self.pub_correction.publish(bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, stamp, vals)[0]))
        self.corrections_published += 1
        self.last_correction_ns = t_ns
        if al.model.feed_biases:
            bv = cv.imu_bias_values(al.model.gyro_bias_comp, al.model.accel_bias_comp, P[9:12, 9:12], P[12:15, 12:15])
            self.pub_bias.publish(bytes(cdr.encode(cdr.layout("imu", cv.MASTER_FRAME), stamp, bv)[0]))
            self.last_bias_ns = t_ns

    def state_name(self) -> str:
        al = self.al
        if al is None or self.last_record is None:
            return (AlignmentState.WAITING if al is None else AlignmentState.ALIGNING).name
        if self._failed and al.aligned:
            return AlignmentState.DEGRADED.name
        return al.status.name

    def _publish_status(self) -> None:
        name = self.state_name()
        st_name, level, message = STATUS_NAME, _LEVELS[name], name
        if self._failed:  # the last epoch failed numerically (the filter kept its previous state)
            level = DiagnosticStatus.ERROR
        elif level == DiagnosticStatus.OK and (self.gates.total or self.publisher_watch.extra or self.imu_interleave.episodes):
            level = DiagnosticStatus.WARN  # refused inputs, or a second publisher (the message still says the state)
        elif self.imu_starved and self.al is None:
            level = DiagnosticStatus.WARN  # it cannot start (the message says WAITING)
        values: dict[str, Any] = {"method": self.config.method, "epochs": self.epochs, "rejected_fixes": self.rejected}
        values.update({f"rejected/{k}": n for k, n in sorted(self.rejected_by_reason.items())})
        values.update({"fixes_done_ns": "none" if self.fixes_done_ns is None else str(self.fixes_done_ns),
                       "last_correction_ns": "none" if self.last_correction_ns is None else str(self.last_correction_ns),
                       "last_bias_ns": "none" if self.last_bias_ns is None else str(self.last_bias_ns),
                       "gnss_time_offset_s": f"{self.core_config.gnss_time_offset_s:.9g}"})
        values.update({"last_rejection": self.last_rejection, "before_start": self.before_start, "unpaired": self.unpaired,
                       "imu_samples": self.imu_samples, "imu_dropped": self.imu_dropped, "imu_gaps": self.imu_gaps,
                       "imu_start_gap_s": f"{self.imu_start_gap_s:.6g}",
                       "numerical_failures": self.numerical_failures, "last_failure": self.last_failure,
                       "start": self.start_source, "joined_running_session": "true" if self.joined_running_graph else "false"})
        if self.start_source == "gnss_fix":
            values.update({"start_level": self.start_level, "start_level_sigma_deg": f"{self.start_level_sigma_deg:.3g}"})
        if self.datum_llh is not None:  # the session's frame: a restarted pos_master_node takes it (its sources module)
            d = self.datum_llh
            values["datum_deg"] = f"{d[0] / DEG:.10f} {d[1] / DEG:.10f} {d[2]:.4f}"
        values.update(self.gates.values())
        values.update(self.publisher_watch.values())
        if self.imu_interleave.episodes:
            values["imu_interleaved"] = self.imu_interleave.episodes
        if self.imu_starved:
            values["imu_starved"] = "true"
        al, rec = self.al, self.last_record
        if al is not None:
            values.update({"hypotheses_failed": al.hypotheses_failed, "chol_jitter_repairs": al.chol_jitter_repairs,
                           "restarts": al.restarts, "states": al.model.n, "predictions": self.predictions})
            if self.origin_ns is not None and self._end_ns is None:  # the next outage time update (pos_master_node's hold)
                values.update({"predict_due_ns": str(self.origin_ns + int(round(al.next_predict_t_s * 1e9))),
                               "outage_wait_s": f"{self.config.outage_wait_s:.9g}"})

            sig = al.attitude_sigma_rad / DEG
            gb, ab = al.bias_estimates()
            values.update({
                "aligned": "true" if al.aligned else "false",
                "heading_sigma_deg": f"{sig[2]:.6g}",
                "att_sigma_deg": " ".join(f"{x:.6g}" for x in sig),
                "aligned_t_s": "none" if al.aligned_t_s is None else f"{al.aligned_t_s:.3f}",
                "gyro_bias_deg_h": " ".join(f"{x:.6g}" for x in gb / DEG_PER_H),
                "accel_bias_ug": " ".join(f"{x:.6g}" for x in ab / UG_MPS2),
            })
        if rec is not None:
            values.update({
                "t_s": f"{rec.t_s:.3f}",
                "R_diag": " ".join(f"{x:.6g}" for x in rec.R_diag),
                "nis": f"{rec.nis:.6g}",
                "nis_window": f"{rec.nis_window:.6g}",
                "nav_discrepancy_m": f"{self.discrepancy[0]:.3g}",
                "nav_discrepancy_deg": f"{self.discrepancy[1]:.3g}",
                "nav_discrepancy_checks": self.discrepancy_checks,
                "nav_discrepancy_max_m": f"{self.max_discrepancy_m:.3g}",
            })
        self.pub_status.publish(cv.diagnostic_array(self.get_clock().now().to_msg(), st_name, "master_imu", level, message, values))


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``ifa_node``."""
    use_device_fastdds_profile()  # readers without resource limits (dpos_ros.io.flow)
    return run_node(IfaNode, NODE_NAME, argv)
