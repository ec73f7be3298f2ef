"""The navigators of pos_master_node: /master/nav by ``alignment``.

/master/nav is nav_msgs/Odometry, frame ``enu``, child ``master_imu``:

``reference`` (:class:`ReferenceNavigator`)
    simulation only: the device's stream, truth + the paper's main-system noise.
``ifa`` (:class:`IfaNavigator`)
    the node mechanizes the master IMU itself (dpos_core.ifa.mechanization.MasterMechanization, numba,
    batches of up to 100 samples handed over by the device thread as a SimDevice tap, so the
    navigation keeps up with ``rate_factor`` 0 and is flow-controlled like the device's streams).
    It starts in simulation from truth at the session start with ``initial_heading_error_deg``
    (default: the scenario's ``ifa.initial_heading_error_deg``, else 0) and level errors 0, and
    publishes that initial state first (stamp = session start: the ifa_node starts its shadow
    strapdown from the first /master/nav), then one message per IMU sample with the IMU's stamp.
    ``/ifa/correction`` for epoch ``t_k`` resets the state at the sample ``t_k``;
    ``/ifa/imu_bias`` stamped ``t_k`` is removed from the samples after ``t_k``; both as the
    ifa_node's closed loop does, so the navigation equals its strapdown (dpos_core.ifa.pipeline)
    to rounding, whatever the order of arrival (dpos_core.ifa.mechanization): feedback
    for a sample not integrated yet is kept pending and applied when that sample is integrated
    (the batch is split there); feedback for an integrated sample resets it in the ring of the
    last ``ring_s`` seconds and re-integrates the samples after it. Already published messages are
    not re-published: a message reflects the corrections received before it was computed (those
    published before a correction came are counted, ``corrections_late`` / ``late_samples``); the
    message at an epoch sample is the state before its correction (what the ifa_node's
    ``nav_discrepancy_m`` compares). Feedback older than the ring (or stamped where the master
    integrated no sample) is lost: a warning each, counted (``corrections_lost``, ``biases_lost``,
    ``last_lost``).
    Unaligned flag: until ``/ifa/status`` reports ALIGNED (or DEGRADED, i.e. aligned but
    inconsistent), the covariance is the filter's (that of the latest correction stamped before the
    message's sample, whatever the order of arrival; before the first one ``initial_sigma``,
    heading 100 deg) and ``/pos_master/status`` (DiagnosticArray,
    TRANSIENT_LOCAL, level WARN, message UNALIGNED) says so; ALIGNED: level OK.
``given`` (:class:`GivenNavigator`)
    the same mechanization from a configured ``initial_state`` (default in simulation: truth at
    the session start), flagged aligned (message GIVEN) from the start. Decision: corrections and
    bias estimates of an ifa_node are applied here too when one runs (the shadow loop works from
    any start state; an ifa_node then refines a given state); without an ifa_node it is
    free-inertial. /ifa/status does not change the flag.

``ifa`` and ``given`` share :class:`Mechanizer` (the mechanization, the feedback subscriptions,
the encoding of /master/nav and the status); they differ in their initial state and their flag.
The source hands a mechanizer the IMU samples (:meth:`Mechanizer.mechanize`) and starts it: in
simulation at once from the session (:meth:`Mechanizer.start_simulated`); with ``device: ros``
once the drivers' data give the initial state (:meth:`Mechanizer.try_start_live`, from the
:class:`DriverInput` the relay fills):

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
    is part of the initial heading error the IFA removes); pitch and roll levelled from the
    accelerometers: the mean specific force of the relayed IMU samples over the last
    ``LEVEL_WINDOW_S`` before the fix (dpos_core.ifa.mechanization.level_from_specific_force;
    real mounts are tilted by up to ~10 deg; an acceleration ``a`` over that second tilts it by
    ``a / g`` rad, the IFA removes the rest), 0 when no sample was relayed in that window (the
    start log line says which); the node starts once a sample newer than the fix has been
    relayed, so the window is complete. Covariance ``initial_sigma`` (heading 100 deg by
    default). Below ``min_course_speed_mps`` ground speed the course is meaningless: the
    ``initial_state`` heading is used when given, else the fix is skipped with a warning and the
    node waits for a faster one.

Threading: :meth:`Mechanizer.mechanize` runs in the simulated device's thread (or the relay's
timer), the feedback callbacks in the executor; a lock serializes their use of the mechanization.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from numpy.typing import NDArray
from rclpy.node import Node

from dpos_core import earth, gates
from dpos_core.errors import RejectedInput
from dpos_core.frames import C_nb_from_hpr
from dpos_core.ifa.mechanization import (
    STAMP_TOL_S,
    MasterMechanization,
    body_rate_eb,
    initial_state_from_list,
    initial_state_from_truth,
    level_from_specific_force,
    stamp_s,
)
from dpos_core.ifa.states import AlignmentState
from dpos_core.ifa.warmup import warm_up_mechanization
from dpos_core.strapdown import NavState
from dpos_core.units import DEG, FloatArray
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import NAV_QOS, STATUS_QOS, keep_all
from dpos_ros.io.flow import subscribe_draining
from dpos_ros.runtime.params import ParameterError
from pos_master_node import NODE_NAME
from pos_master_node.params import PosMasterConfig

__all__ = ["Navigator", "ReferenceNavigator", "Mechanizer", "GivenNavigator", "IfaNavigator", "DriverInput", "NavRows",
           "LEAD_WAIT_S", "FIX_VEL_MATCH_NS", "GNSS_KEEP", "WARN_THROTTLE_S", "LEVEL_WINDOW_S"]

#: longest wait for an /ifa/correction before the device runs on (max_lead_s) [s]
LEAD_WAIT_S = 5.0
#: ``device: ros``, ``alignment: ifa``: a /gnss/vel belongs to a /gnss/fix within this [ns]
FIX_VEL_MATCH_NS = 50_000_000
#: recent fixes / velocities kept while waiting for the initial state
GNSS_KEEP = 20
#: repeated "waiting" warnings at most this often [s]
WARN_THROTTLE_S = 5.0
#: ``device: ros``, ``alignment: ifa``: pitch and roll from the mean specific force of the IMU
#: samples relayed over this long before the start fix [s]
LEVEL_WINDOW_S = 1.0
#: ``hardware_id`` of the /pos_master/status entry
STATUS_HARDWARE_ID = "master_imu"
#: the graph is checked for second publishers this often [s] (dpos_core.gates.PublisherWatch)
PUBLISHER_CHECK_S = 2.0
#: topics this node expects one publisher on (the ifa_node's; its own): a second one is warned
#: about and counted (``publishers_extra/<topic>``)
SINGLE_PUBLISHER_TOPICS = (T.IFA_CORRECTION, T.IFA_IMU_BIAS, T.IFA_STATUS, T.MASTER_IMU, T.MASTER_NAV, T.DATUM)

#: a relayed IMU sample: (stamp [ns], omega [rad/s] (3), f [m/s^2] (3)), body axes
ImuSample = tuple[int, tuple[float, ...], tuple[float, ...]]
#: /master/nav covariances (3, 3) each: position [m^2], attitude [rad^2] (ENU axes), velocity [m^2/s^2]
NavCov = tuple[FloatArray, FloatArray, FloatArray]
#: what :meth:`Mechanizer.mechanize` returns: (the initial state's /master/nav or None, the
#: /master/nav rows of the kept samples (K, size), keep mask (N,))
NavRows = tuple[bytes | None, NDArray[np.uint8], NDArray[np.bool_]]


@dataclass
class DriverInput:
    """``device: ros``: what the relay has received towards the start (sources.RelaySource fills it).

    Attributes:
        datum_llh: [lat_rad, lon_rad, h_m] of /dpos/datum once known (the ``datum`` parameter or the
            first valid fix), else None.
        lever_arm_b_m: the aircraft's GNSS lever arm [m] (body axes) when ``aircraft_config`` is set.
        imu: relayed IMU samples not integrated yet, in arrival order.
        fixes, vels: (stamp [ns], llh [rad, rad, m] / ENU velocity [m/s]) of the recent valid fixes and
            velocities, kept until the mechanization starts.
    """

    datum_llh: FloatArray | None
    lever_arm_b_m: FloatArray | None
    imu: deque[ImuSample] = field(default_factory=deque)
    fixes: deque[tuple[int, FloatArray]] = field(default_factory=lambda: deque(maxlen=GNSS_KEEP))
    vels: deque[tuple[int, FloatArray]] = field(default_factory=lambda: deque(maxlen=GNSS_KEEP))


@dataclass
class _Started:
    """A started mechanization: its time origin [ns], the datum of /master/nav and how it started."""

    mech: MasterMechanization
    origin_ns: int
    datum_llh: FloatArray
    initial_text: str
    #: the initial state's /master/nav is still to be published (with the first batch)
    head_due: bool = True


class ReferenceNavigator:
    """``alignment: reference`` (simulation only): /master/nav is the simulated device's own stream.

    Nothing to mechanize: no feedback subscriptions, no /pos_master/status; the source publishes
    the stream (sources.SimSource) or refuses the alignment (sources.RelaySource).
    """

    alignment: ClassVar[str] = "reference"

    def __init__(self, node: Node, cfg: PosMasterConfig) -> None:
        self.config = cfg
        #: always 0 (no mechanization; the attribute mirrors :class:`Mechanizer`)
        self.imu_before_start = 0

    @property
    def mech(self) -> MasterMechanization | None:
        """None: the reference is not mechanized."""
        return None

    @property
    def aligned(self) -> bool:
        """True: truth + the main-system noise."""
        return True

    def attach(self) -> None:
        """Nothing to subscribe to or publish."""


class Mechanizer(ABC):
    """``alignment: ifa | given``: the master IMU mechanized with the ifa_node's feedback.

    Construction reads the parameters only; :meth:`attach` creates the /ifa/* subscriptions and the
    /pos_master/status publisher and publishes the first status; a source starts the mechanization
    (:meth:`start_simulated` or :meth:`try_start_live`) and feeds it (:meth:`mechanize`).
    """

    alignment: ClassVar[str]
    #: /master/nav is flagged aligned before any /ifa/status
    initially_aligned: ClassVar[bool]
    #: the end of the ``device: ros`` start log line
    live_start_note: ClassVar[str]

    def __init__(self, node: Node, cfg: PosMasterConfig) -> None:
        self.node = node
        self.config = cfg
        self.log = node.get_logger()
        s = cfg.initial_sigma
        #: the /master/nav covariance: ``initial_sigma`` until the first correction, then the filter's
        self.nav_cov: NavCov = (np.eye(3) * s[0] ** 2, np.diag([s[3], s[4], s[2]]) ** 2 * DEG**2, np.eye(3) * s[1] ** 2)
        #: the corrections' covariances by the time [s] of their sample, oldest first: a message carries
        #: the one of the latest correction strictly before its sample (:meth:`_covs_at`), whatever the
        #: order in which correction and sample arrived; ``nav_cov`` is the newest
        self._cov_track: list[tuple[float, NavCov]] = []
        self._cov0: NavCov = self.nav_cov
        self._lock = threading.Lock()
        self._corrected = threading.Condition(self._lock)
        self._started: _Started | None = None
        #: /master/nav messages produced
        self.nav_published = 0
        #: relayed IMU samples not integrated: stamped up to the start, or dropped while waiting for it
        self.imu_before_start = 0
        #: the ifa_node's last status message ("none" before the first)
        self.ifa_status = "none"
        #: the flag of /master/nav (/pos_master/status)
        self.aligned = self.initially_aligned
        self._status_pub: Any = None  # attach()
        #: the ifa_node's progress, from its /ifa/status: every fix stamped up to ``ifa_fixes_done_ns``
        #: is finished (epoch, rejected or skipped) and its newest correction is stamped
        #: ``ifa_last_correction_ns``; its GNSS time offset [ns] (``device: ros`` holds, :meth:`fix_answered`)
        self.ifa_fixes_done_ns: int | None = None
        self.ifa_last_correction_ns: int | None = None
        self.ifa_last_bias_ns: int | None = None
        #: the ifa_node's next time update alone (an outage) [ns, IMU clock]: ``device: ros`` holds
        #: /master/nav for it too
        self.ifa_predict_due_ns: int | None = None
        self.ifa_offset_ns = 0
        #: the newest /ifa/correction and /ifa/imu_bias stamps received [ns]
        self.correction_seen_ns: int | None = None
        self.bias_seen_ns: int | None = None
        #: ``device: ros``: holds of the IMU after a fix released after LEAD_WAIT_S without the ifa_node's answer
        self.hold_timeouts = 0
        #: the gates (dpos_core.gates): refusals by reason, the last accepted /ifa/correction stamp
        #: [ns], the newest IMU stamp seen [ns] (integrated, or relayed: :meth:`note_imu`), the
        #: second publishers seen
        self.gates = gates.GateCounts()
        self.correction_accepted_ns: int | None = None
        self.bias_accepted_ns: int | None = None
        self.newest_imu_ns: int | None = None
        self.publisher_watch = gates.PublisherWatch({t: 1 for t in SINGLE_PUBLISHER_TOPICS})
        #: the last /ifa/status claims the alignment (and passed its gate)
        self.ifa_claims_aligned = False
        #: the datum [lat_rad, lon_rad, h_m] the ifa_node uses (its /ifa/status ``datum_deg``), once known:
        #: ``device: ros`` without ``datum`` takes it (sources.RelaySource: a restart keeps the session's frame)
        self.graph_datum_llh: FloatArray | None = None

    # ------------------------------------------------------------------ state
    @property
    def mech(self) -> MasterMechanization | None:
        """The mechanization, None before the start."""
        return None if self._started is None else self._started.mech

    @property
    def started(self) -> bool:
        return self._started is not None

    @property
    def origin_ns(self) -> int:
        """The stamp of the initial state [ns] (time origin of the mechanization); after the start only."""
        return self._run().origin_ns

    def ifa_present(self) -> bool:
        """An ifa_node is in the graph (a publisher of /ifa/correction), whatever its state: while it
        starts (no /ifa/status yet, or WAITING) it will answer the fixes after our first /master/nav,
        so the hold applies from the start (a replay as fast as possible otherwise runs seconds
        ahead of its first corrections)."""
        return self.node.count_publishers(T.IFA_CORRECTION) > 0

    def fix_answered(self, t_fix_ns: int) -> bool:
        """The ifa_node has finished the fix stamped ``t_fix_ns`` [ns] and its correction, if it made
        one, has arrived here (its /ifa/status: ``fixes_done_ns`` >= the fix, and every correction up to
        its ``last_correction_ns`` received, and its bias estimate up to ``last_bias_ns``: the two
        topics may arrive in either order)."""
        done = self.ifa_fixes_done_ns
        return done is not None and done >= t_fix_ns and self.feedback_received()

    def feedback_received(self) -> bool:
        """Every /ifa/correction and /ifa/imu_bias the ifa_node's last /ifa/status announces
        (``last_correction_ns``, ``last_bias_ns``) has arrived here."""
        last, seen = self.ifa_last_correction_ns, self.correction_seen_ns
        bias, bias_seen = self.ifa_last_bias_ns, self.bias_seen_ns
        return ((last is None or (seen is not None and seen >= last))
                and (bias is None or (bias_seen is not None and bias_seen >= bias)))

    def _run(self) -> _Started:
        if self._started is None:
            raise RuntimeError(f"alignment {self.alignment}: the mechanization has not started")
        return self._started

    # ------------------------------------------------------------------ wiring
    def attach(self) -> None:
        """Warm the mechanization up (:func:`dpos_core.ifa.warmup.warm_up_mechanization`: its numba
        kernels compiled or loaded now, not on the first IMU batch); subscribe to /ifa/correction,
        /ifa/imu_bias and /ifa/status; publish /pos_master/status."""
        node = self.node
        try:
            node.get_logger().info(f"mechanization warmed up in {warm_up_mechanization():.1f} s")
        except Exception as e:  # (a warm-up is never a reason not to start)
            node.get_logger().warning(f"the mechanization's warm-up failed ({type(e).__name__}: {e}); its first IMU batch may be slow")
        # draining subscriptions: the relay serves its inputs in batches (dpos_ros.io.flow.subscribe_draining)
        subscribe_draining(node, T.message_class(T.ODOMETRY), T.IFA_CORRECTION, self.on_correction, keep_all(NAV_QOS), raw=True)
        subscribe_draining(node, T.message_class(T.IMU), T.IFA_IMU_BIAS, self.on_bias, keep_all(NAV_QOS), raw=True)
        subscribe_draining(node, DiagnosticArray, T.IFA_STATUS, self.on_ifa_status, STATUS_QOS)
        self._status_pub = node.create_publisher(DiagnosticArray, T.POS_MASTER_STATUS, STATUS_QOS)
        node.create_timer(PUBLISHER_CHECK_S, self.check_publishers)
        self.publish_status()

    def check_publishers(self) -> None:
        """Warn about (and count) a second publisher on a topic that should have one (a second graph
        on the domain, a stray process: dpos_core.gates.PublisherWatch)."""
        changed = False
        for topic in SINGLE_PUBLISHER_TOPICS:
            eps = [(bytes(i.endpoint_gid), f"{i.node_namespace.rstrip('/')}/{i.node_name}")
                   for i in self.node.get_publishers_info_by_topic(topic)]
            for text in self.publisher_watch.update(topic, eps):
                self.log.warning(text)
                changed = True
        if changed:
            self.publish_status()

    def refuse(self, reason: str, text: str) -> None:
        """Count a refused input (``gate/<reason>``), log it (the first of its reason, then at a bounded rate)."""
        line = self.gates.refuse(reason, text, time.monotonic())
        if line is not None:
            self.log.warning(line)
        self.publish_status()

    def note_imu(self, t_ns: int) -> None:
        """An IMU sample stamped ``t_ns`` [ns] was relayed (the future bound of the feedback's stamps)."""
        self.newest_imu_ns = t_ns if self.newest_imu_ns is None else max(self.newest_imu_ns, int(t_ns))

    # ------------------------------------------------------------------ start
    def start(self, initial: NavState, origin_ns: int, datum_llh: FloatArray, initial_text: str) -> None:
        """Start the mechanization from ``initial`` (stamped ``origin_ns``) in the ``enu`` frame of ``datum_llh``."""
        mech = MasterMechanization(initial, self.config.ring_s)
        with self._lock:
            self._started = _Started(mech, origin_ns, datum_llh, initial_text)

    def start_simulated(self, session: Any, origin_ns: int, datum_llh: FloatArray) -> None:
        """``device: sim``: start at the session start (``origin_ns``) from :meth:`initial_in_simulation`.

        Raises:
            ParameterError: an invalid ``initial_state``.
        """
        initial, text = self.initial_in_simulation(session)
        self.start(initial, origin_ns, datum_llh, text)

    @abstractmethod
    def initial_in_simulation(self, session: Any) -> tuple[NavState, str]:
        """The initial state at the session start (t_s 0) and how it was chosen (log text)."""

    @abstractmethod
    def announce_simulated(self) -> None:
        """Log how /master/nav is made in simulation (after the device's plan line)."""

    def check_live(self) -> None:
        """``device: ros``: the parameters the live start needs.

        Raises:
            ParameterError: an invalid ``initial_state``.
        """
        cfg = self.config
        if cfg.initial_state:
            try:
                initial_state_from_list(cfg.initial_state, 0.0)
            except ValueError as e:
                raise ParameterError("initial_state", list(cfg.initial_state), str(e)) from None

    @abstractmethod
    def live_plan(self) -> str:
        """``device: ros``: what /master/nav is mechanized from (for the node's plan line)."""

    @abstractmethod
    def live_initial(self, inp: DriverInput) -> tuple[int, NavState, str] | None:
        """``device: ros``: ``(stamp [ns], initial state, log text)`` once ``inp`` gives it, else None
        (dropping, and counting, what will not be integrated while waiting)."""

    def try_start_live(self, inp: DriverInput) -> bool:
        """``device: ros``: start the mechanization once the initial state is known (module docstring).

        The IMU samples stamped up to the start are dropped from ``inp.imu`` (``imu_before_start``),
        the kept fixes and velocities are cleared.
        """
        start = self.live_initial(inp)
        if start is None:
            return False
        t0_ns, initial, text = start
        datum = inp.datum_llh
        if datum is None:  # not reached: both live starts wait for the datum
            raise RuntimeError(f"alignment {self.alignment}: a live start without a datum")
        before = len(inp.imu)
        inp.imu = deque(s for s in inp.imu if s[0] > t0_ns)
        self.imu_before_start += before - len(inp.imu)
        self.start(initial, t0_ns, datum, text)
        inp.fixes.clear()
        inp.vels.clear()
        hpr = initial.hpr_rad / DEG
        self.log.info(f"{NODE_NAME}: {T.MASTER_NAV} starts at stamp {t0_ns} ns from {text}: lat {initial.llh[0] / DEG:.8f} "
                      f"lon {initial.llh[1] / DEG:.8f} deg h {initial.llh[2]:.3f} m, vel ENU {np.round(initial.vel_n_mps, 3).tolist()} m/s, "
                      f"heading {hpr[0]:.3f} pitch {hpr[1]:.3f} roll {hpr[2]:.3f} deg{self.live_start_note}")
        self.publish_status()
        return True

    # ------------------------------------------------------------------ mechanization
    def mechanize(self, t_ns: NDArray[np.int64], om: FloatArray, fb: FloatArray) -> NavRows:
        """Integrate IMU samples (t_ns (N,), omega [rad/s] (N, 3), f [m/s^2] (N, 3), body axes).

        Returns ``(the initial state's /master/nav or None, the /master/nav rows of the kept
        samples (K, size), keep mask (N,))``.
        """
        with self._lock:
            run = self._run()
            mech = run.mech
            first = run.head_due
            run.head_due = False
            counts = (mech.corrections, mech.corrections_lost)
            if len(t_ns):
                newest = int(np.max(t_ns))
                self.newest_imu_ns = newest if self.newest_imu_ns is None else max(self.newest_imu_ns, newest)
            nav, keep, warnings = mech.add(stamp_s(t_ns, run.origin_ns), om, fb)
            changed = counts != (mech.corrections, mech.corrections_lost)  # pending corrections applied (or lost)
            gyro = np.array([mech.bias_at(t)[0] for t in nav.t_s]).reshape(-1, 3)
            cov = self._covs_at(nav.t_s)
            head_cov = self._covs_at(np.array([mech.initial.t_s]))
        for w in warnings:
            self.log.warning(w)
        if changed:
            self.publish_status()
        head = None
        if first:
            s = mech.initial
            v0 = cv.odometry_values_cov(s.llh[None], s.vel_n_mps[None], s.q_nb[None], run.datum_llh, None, *head_cov)
            head = bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([run.origin_ns]), v0)[0])
        rows = np.empty((0, 0), dtype=np.uint8)
        if len(nav):
            w_eb = body_rate_eb(nav.q_nb, nav.llh, nav.vel_n_mps, om[keep] - gyro)
            v = cv.odometry_values_cov(nav.llh, nav.vel_n_mps, nav.q_nb, run.datum_llh, w_eb, *cov)
            rows = cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, t_ns[keep], v)
        self.nav_published += int(len(nav)) + int(first)
        return head, rows, keep

    def _covs_at(self, t_s: FloatArray) -> NavCov:
        """The covariances ((N, 3, 3) position, attitude, velocity) of /master/nav messages at ``t_s``
        (N,) [s], increasing: the latest correction's strictly before each sample (the message at an
        epoch's sample carries the state before that epoch, and its covariance), ``initial_sigma``'s
        before the first. Entries older than the latest one used are dropped (the samples come in
        time order). Under the lock."""
        track = self._cov_track
        t = np.asarray(t_s, dtype=float)
        k = np.searchsorted(np.array([x[0] for x in track]), t - STAMP_TOL_S, side="left") - 1
        if not k.size:
            return (np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
        blocks = [self._cov0] + [c for _, c in track]
        out = tuple(np.stack([blocks[j + 1][i] for j in k]).reshape(-1, 3, 3) for i in range(3))
        if k.max() > 0:
            del track[: int(k.max())]
        return out  # type: ignore[return-value]

    def wait_for_corrections(self, t_s: float, max_lead_s: float, stopping: Callable[[], bool]) -> None:
        """Flow control of the IFA loop: wait while the mechanization at ``t_s`` is more than
        ``max_lead_s`` ahead of the last correction (bounded waits of LEAD_WAIT_S, or until
        ``stopping()``; the caller's thread waits on a condition, which releases the GIL)."""
        mech = self._run().mech
        deadline = time.monotonic() + LEAD_WAIT_S
        with self._corrected:
            while t_s - (mech.last_correction_t_s or 0.0) > max_lead_s:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0 or stopping():
                    self.log.warning(
                        f"no {T.IFA_CORRECTION} for {LEAD_WAIT_S:g} s (mechanization at t={t_s:.2f} s, last correction "
                        f"{mech.last_correction_t_s}); continuing without waiting for the IFA loop")
                    return
                self._corrected.wait(min(remaining, 0.05))

    # ------------------------------------------------------------------ feedback
    def on_correction(self, raw: bytes) -> None:
        """/ifa/correction: reset the state at its stamp and re-integrate; its covariance is the nav's from now on."""
        t_ns, v = cv.decode_raw(raw, "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        refusal = gates.check_stamp(t_ns, self.correction_accepted_ns, self.newest_imu_ns)
        if refusal is None or refusal.reason != "future":  # (a stamp from the future would release the holds)
            self.correction_seen_ns = t_ns if self.correction_seen_ns is None else max(self.correction_seen_ns, t_ns)
        run = self._started
        if run is None:
            self.log.warning(f"{T.IFA_CORRECTION} at stamp {t_ns} ns before the mechanization started: ignored")
            return
        if refusal is not None:
            self.refuse(f"ifa_correction/{refusal.reason}", f"{T.IFA_CORRECTION}: {refusal.text}")
            return
        blk = cv.odometry_from_values(np.array([t_ns]), v[None], run.datum_llh)
        pos, att, vel = cv.odometry_cov_n(blk, run.datum_llh)
        try:
            state = NavState(float(stamp_s(t_ns, run.origin_ns)), blk.q_nb[0], blk.vel_n_mps[0], blk.llh[0])
        except RejectedInput as e:
            self.refuse("ifa_correction/nonfinite", f"{T.IFA_CORRECTION} at stamp {t_ns} ns: {e}")
            return
        with self._lock:
            own = self._own_at(run.mech, state.t_s)
            own_cov = self.nav_cov
        if own is not None:
            (o_llh, o_vel, o_q), extra = own
            diff = gates.correction_difference(state.llh, state.vel_n_mps, state.q_nb, o_llh, o_vel, o_q)
            refusal = gates.check_correction(diff, (own_cov[0], own_cov[2], own_cov[1]), (pos[0], vel[0], att[0]),
                                             extra_var=extra)
            if refusal is not None:
                self.refuse(f"ifa_correction/{refusal.reason}", f"{T.IFA_CORRECTION} at stamp {t_ns} ns: {refusal.text}")
                return
        self.correction_accepted_ns = t_ns
        with self._lock:
            warning = run.mech.correct(state)  # pending until its sample is integrated, or applied now, or lost
            if warning is None:
                c = (pos[0], att[0], vel[0])
                k = bisect.bisect_right([x[0] for x in self._cov_track], state.t_s)
                self._cov_track.insert(k, (state.t_s, c))
                self.nav_cov = self._cov_track[-1][1]
            self._corrected.notify_all()
        if warning is not None:
            self.log.warning(f"{T.IFA_CORRECTION} at stamp {t_ns} ns: {warning}")
        self.update_flag()
        self.publish_status()

    @staticmethod
    def _own_at(mech: MasterMechanization, t_s: float) -> tuple[tuple[FloatArray, FloatArray, FloatArray], FloatArray] | None:
        """The node's own state at ``t_s`` [s] for the correction gate: ``((llh, vel ENU, q_nb), extra
        variances (9,))``: the stored sample at or before it (carried to ``t_s`` at constant velocity,
        with dpos_core.gates.extrapolation_var), the current state for a stamp after it, the initial
        state at its stamp; None when older than what is stored (the mechanization loses it anyway).
        Under the lock."""
        r = mech.ring
        if len(r) and t_s >= r.t_s[0] - STAMP_TOL_S:
            j = int(np.searchsorted(r.t_s, t_s + STAMP_TOL_S, side="right")) - 1
            j = max(j, 0)
            t0, llh, vel, q = float(r.t_s[j]), r.llh[j], r.vel[j], r.q_nb[j]
        elif abs(t_s - mech.initial.t_s) <= STAMP_TOL_S or (not len(r) and t_s >= mech.initial.t_s):
            s = mech.initial
            t0, llh, vel, q = float(s.t_s), s.llh, s.vel_n_mps, s.q_nb
        else:
            return None
        dt = t_s - t0
        if abs(dt) > STAMP_TOL_S:
            llh = earth.offset_llh(llh, np.asarray(vel, dtype=float) * dt)
        return (np.asarray(llh, dtype=float), np.asarray(vel, dtype=float), np.asarray(q, dtype=float)), gates.extrapolation_var(dt)

    def update_flag(self) -> None:
        """Set the flag from the last /ifa/status claim and the own covariance (:meth:`aligned_by`), logging a change."""
        was = self.aligned
        self.aligned = self.aligned_by(self.ifa_status, "true" if self.ifa_claims_aligned else "false")
        if self.aligned != was:
            self.log.info(f"{T.IFA_STATUS} {self.ifa_status}: {T.MASTER_NAV} is {'aligned' if self.aligned else 'UNALIGNED'}")

    def on_bias(self, raw: bytes) -> None:
        """/ifa/imu_bias: remove the estimate from the samples after its stamp."""
        t_ns, v = cv.decode_raw(raw, "imu", cv.MASTER_FRAME)
        refusal = gates.check_stamp(t_ns, self.bias_accepted_ns, self.newest_imu_ns)
        if refusal is None or refusal.reason != "future":
            self.bias_seen_ns = t_ns if self.bias_seen_ns is None else max(self.bias_seen_ns, t_ns)
        run = self._started
        if run is None:
            self.log.warning(f"{T.IFA_IMU_BIAS} at stamp {t_ns} ns before the mechanization started: ignored")
            return
        g, a, _, _ = cv.imu_bias_from_values(v[None])
        refusal = refusal or gates.check_bias(g[0], a[0])
        if refusal is not None:
            self.refuse(f"ifa_imu_bias/{refusal.reason}", f"{T.IFA_IMU_BIAS} at stamp {t_ns} ns: {refusal.text}")
            return
        self.bias_accepted_ns = t_ns
        with self._lock:
            warning = run.mech.set_bias(float(stamp_s(t_ns, run.origin_ns)), g[0], a[0])
        if warning is not None:
            self.log.warning(f"{T.IFA_IMU_BIAS} at stamp {t_ns} ns: {warning}")
            self.publish_status()

    def on_ifa_status(self, msg: DiagnosticArray) -> None:
        """/ifa/status: the ifa_node's state; :meth:`aligned_by` sets the flag."""
        for st in msg.status:
            if st.name.startswith("ifa_node"):
                self.ifa_status = st.message
                values = {kv.key: kv.value for kv in st.values}
                claims = AlignmentState.message_is_aligned(st.message, values.get("aligned"))
                refusal = self.aligned_gate(claims, values.get("heading_sigma_deg"))
                if refusal is not None:
                    self.refuse(f"ifa_status/{refusal.reason}", f"{T.IFA_STATUS} {st.message}: {refusal.text}")
                    claims = False
                self.ifa_claims_aligned = claims
                self.update_flag()
                datum = _datum_or_none(values.get("datum_deg"))
                if datum is not None:
                    self.graph_datum_llh = datum
                self.ifa_fixes_done_ns = _int_or_none(values.get("fixes_done_ns"))
                self.ifa_last_correction_ns = _int_or_none(values.get("last_correction_ns"))
                self.ifa_last_bias_ns = _int_or_none(values.get("last_bias_ns"))
                self.ifa_predict_due_ns = _int_or_none(values.get("predict_due_ns"))
                offset_s = _float_or_none(values.get("gnss_time_offset_s"))
                self.ifa_offset_ns = 0 if offset_s is None else int(round(offset_s * 1e9))
                self.publish_status()

    def aligned_gate(self, claims: bool, heading_sigma_deg: str | None) -> gates.Refusal | None:
        """The gate of an /ifa/status aligned claim (``alignment: given`` ignores the flag: no gate)."""
        return None

    @abstractmethod
    def aligned_by(self, ifa_message: str, aligned_key: str | None = None) -> bool:
        """The flag after an /ifa/status with this message (and its ``aligned`` value, if any)."""

    @abstractmethod
    def status_message(self) -> str:
        """The message of /pos_master/status."""

    def publish_status(self) -> None:
        """/pos_master/status: the flag (level OK when aligned, else WARN; WARN too once feedback was
        lost) and the mechanization's counts (pending / applied / late / lost feedback)."""
        if self._status_pub is None:  # before attach(): not wired yet
            return
        lost = self.mech is not None and (self.mech.corrections_lost > 0 or self.mech.biases_lost > 0)
        foreign = self.gates.total > 0 or bool(self.publisher_watch.extra)
        level = DiagnosticStatus.OK if self.aligned and not lost and not foreign else DiagnosticStatus.WARN
        message = self.status_message()
        with self._lock:
            mech = self.mech
            values = {
                "alignment": self.config.alignment,
                "device": self.config.device,
                "started": mech is not None,
                "ifa_status": self.ifa_status,
                "corrections": 0 if mech is None else mech.corrections,
                "corrections_pending": 0 if mech is None else mech.corrections_pending,
                "corrections_late": 0 if mech is None else mech.corrections_late,
                "late_samples": 0 if mech is None else mech.late_samples,
                "corrections_lost": 0 if mech is None else mech.corrections_lost,
                "biases": 0 if mech is None else mech.biases,
                "biases_lost": 0 if mech is None else mech.biases_lost,
                "hold_timeouts": self.hold_timeouts,
                "last_lost": "" if mech is None else mech.last_lost,
                "last_late": "" if mech is None else mech.last_late,
                "last_correction_t_s": "none" if mech is None or mech.last_correction_t_s is None else f"{mech.last_correction_t_s:.3f}",
                "imu_dropped": 0 if mech is None else mech.dropped,
                "imu_before_start": self.imu_before_start,
                "nav_t_s": "none" if mech is None else f"{mech.t_s:.3f}",
                "heading_sigma_deg": f"{np.sqrt(self.nav_cov[1][2, 2]) / DEG:.6g}",
                **self.gates.values(),
                **self.publisher_watch.values(),
            }
        self._status_pub.publish(cv.diagnostic_array(self.node.get_clock().now().to_msg(), NODE_NAME, STATUS_HARDWARE_ID,
                                                      level, message, values))


class GivenNavigator(Mechanizer):
    """``alignment: given``: mechanized from the configured ``initial_state``, flagged aligned (GIVEN)."""

    alignment: ClassVar[str] = "given"
    initially_aligned: ClassVar[bool] = True
    live_start_note: ClassVar[str] = ""

    def initial_in_simulation(self, session: Any) -> tuple[NavState, str]:
        cfg = self.config
        if cfg.initial_state:
            try:
                initial = initial_state_from_list(cfg.initial_state, 0.0)
            except ValueError as e:
                raise ParameterError("initial_state", list(cfg.initial_state), str(e)) from None
            return initial, f"the given state {list(cfg.initial_state)}"
        tr = session.truth("master", np.array([0.0]))
        return initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, 0.0), "truth at the session start"

    def announce_simulated(self) -> None:
        self.log.info(f"alignment 'given': {T.MASTER_NAV} is mechanized from {self._run().initial_text}")

    def check_live(self) -> None:
        """``initial_state`` is required (and valid).

        Raises:
            ParameterError: ``initial_state`` missing or invalid.
        """
        cfg = self.config
        if not cfg.initial_state:
            raise ParameterError("initial_state", list(cfg.initial_state),
                                 "required with device:=ros and alignment:=given: [lat_deg, lon_deg, h_m, vE, vN, vU, "
                                 "heading_deg, pitch_deg, roll_deg] at the first IMU sample")
        super().check_live()

    def live_plan(self) -> str:
        return "the given initial_state at the first IMU sample"

    def live_initial(self, inp: DriverInput) -> tuple[int, NavState, str] | None:
        """The first IMU sample relayed once the datum is known; before, the samples are dropped."""
        cfg = self.config
        if not inp.imu:
            return None
        if inp.datum_llh is None:
            self.imu_before_start += len(inp.imu)
            inp.imu.clear()
            self.log.warning(f"alignment given: waiting for the first valid {T.GNSS_FIX} (the datum) before starting "
                             "(set the datum parameter to start at the first IMU sample)", throttle_duration_sec=WARN_THROTTLE_S)
            return None
        t0_ns = inp.imu.popleft()[0]
        return t0_ns, initial_state_from_list(cfg.initial_state, 0.0), f"the given state {list(cfg.initial_state)}"

    def aligned_by(self, ifa_message: str, aligned_key: str | None = None) -> bool:
        return self.aligned  # /ifa/status does not change the flag

    def status_message(self) -> str:
        return "GIVEN"


class IfaNavigator(Mechanizer):
    """``alignment: ifa``: mechanized from a coarse initial state, flagged UNALIGNED until /ifa/status ALIGNED."""

    alignment: ClassVar[str] = "ifa"
    initially_aligned: ClassVar[bool] = False
    live_start_note: ClassVar[str] = f" (UNALIGNED until {T.IFA_STATUS} ALIGNED)"

    def initial_in_simulation(self, session: Any) -> tuple[NavState, str]:
        cfg = self.config
        sc = session.scenario
        err = cfg.initial_heading_error_deg[0] if cfg.initial_heading_error_deg else float(sc.ifa.get("initial_heading_error_deg", 0.0))
        tr = session.truth("master", np.array([0.0]))
        initial = initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, err)
        return initial, f"truth at the session start with a heading error of {err:g} deg"

    def announce_simulated(self) -> None:
        self.log.warning(
            f"alignment 'ifa': {T.MASTER_NAV} is mechanized from {self._run().initial_text} and flagged UNALIGNED "
            f"(filter covariance, {T.POS_MASTER_STATUS}) until {T.IFA_STATUS} reports ALIGNED; corrections come from an ifa_node"
        )

    def live_plan(self) -> str:
        cfg = self.config
        return (f"the first {T.GNSS_FIX} + {T.GNSS_VEL} (heading = course over ground from {cfg.min_course_speed_mps:g} m/s"
                f"{', else the initial_state heading' if cfg.initial_state else ''}), flagged UNALIGNED until {T.IFA_STATUS} ALIGNED")

    def live_initial(self, inp: DriverInput) -> tuple[int, NavState, str] | None:
        """The course start (:meth:`course_start`); while waiting, at most ``ring_s`` of IMU samples are kept.

        No start is taken while the datum is unknown (the source waits up to ``DATUM_WAIT_FIXES`` fixes
        for a running ifa_node's ``datum_deg``): the waiting fixes stay queued, so the oldest of them
        is still the start once the datum comes."""
        start = None if inp.datum_llh is None else self.course_start(inp)
        if start is None and inp.imu:  # keep at most ring_s of samples while waiting
            t_min = inp.imu[-1][0] - int(self.config.ring_s * 1e9)
            while inp.imu[0][0] < t_min:
                inp.imu.popleft()
                self.imu_before_start += 1
        return start

    _first_imu_ns: int | None = None  #: the first relayed IMU stamp course_start saw

    def course_start(self, inp: DriverInput) -> tuple[int, NavState, str] | None:
        """The initial state from the oldest fix with a matching velocity (module docstring), or None
        (also while no IMU sample newer than that fix has been relayed: the levelling window is
        then complete).  A fix older than the first relayed IMU sample is not a start (the same rule
        as dpos_core.ifa.reference.initial_state offline)."""
        cfg = self.config
        fixes, vels = inp.fixes, inp.vels
        while fixes:
            t_fix, llh = fixes[0]
            vel = next((v for t, v in vels if abs(t - t_fix) <= FIX_VEL_MATCH_NS), None)
            if vel is None:
                if vels and vels[-1][0] > t_fix + FIX_VEL_MATCH_NS:  # its velocity will not come
                    fixes.popleft()
                    continue
                return None
            if not inp.imu or inp.imu[-1][0] <= t_fix:
                return None  # the IMU up to the fix is not all here yet
            if self._first_imu_ns is None:
                self._first_imu_ns = int(inp.imu[0][0])
            fixes.popleft()
            if t_fix < self._first_imu_ns:  # no IMU data at or before it: nothing to level on, nothing to start from
                self.log.info(f"alignment ifa: the fix at {t_fix} ns precedes the first IMU sample ({self._first_imu_ns} ns): "
                              "not a start", throttle_duration_sec=WARN_THROTTLE_S)
                continue
            speed = math.hypot(vel[0], vel[1])
            if speed >= cfg.min_course_speed_mps:
                heading = math.atan2(vel[0], vel[1]) % (2.0 * math.pi)
                text = f"the fix and velocity at {t_fix} ns, heading = course over ground ({speed:.1f} m/s)"
            elif cfg.initial_state:
                heading = cfg.initial_state[6] * DEG
                text = (f"the fix and velocity at {t_fix} ns, the initial_state heading (ground speed {speed:.2f} m/s < "
                        f"min_course_speed_mps {cfg.min_course_speed_mps:g})")
            else:
                self.log.warning(
                    f"alignment ifa: ground speed {speed:.2f} m/s at {t_fix} ns is below min_course_speed_mps "
                    f"{cfg.min_course_speed_mps:g}: the course is no heading; waiting for a faster fix (or set initial_state "
                    f"for its heading)", throttle_duration_sec=WARN_THROTTLE_S)
                continue
            pitch, roll, level_text = self.level(inp, t_fix)
            text += f", {level_text}"
            if inp.lever_arm_b_m is not None:  # antenna -> IMU with the initial attitude
                p_enu = -C_nb_from_hpr(heading, pitch, roll) @ inp.lever_arm_b_m
                llh = np.array(earth.enu_to_geodetic(p_enu, llh), dtype=float)
                text += f", lever arm {inp.lever_arm_b_m.tolist()} m removed"
            return t_fix, NavState.from_hpr(0.0, [heading, pitch, roll], vel, llh), text
        return None

    @staticmethod
    def level(inp: DriverInput, t_fix_ns: int) -> tuple[float, float, str]:
        """``(pitch [rad], roll [rad], log text)`` from the mean specific force of the queued IMU
        samples stamped in ``(t_fix - LEVEL_WINDOW_S, t_fix]`` (0, 0 when there are none)."""
        lo = t_fix_ns - int(round(LEVEL_WINDOW_S * 1e9))
        f = np.array([s[2] for s in inp.imu if lo < s[0] <= t_fix_ns], dtype=float).reshape(-1, 3)
        if not f.shape[0]:
            return 0.0, 0.0, f"pitch = roll = 0 (no IMU sample in the {LEVEL_WINDOW_S:g} s before the fix to level on)"
        mean = f.mean(axis=0)
        try:
            pitch, roll = level_from_specific_force(mean)
        except ValueError as e:
            return 0.0, 0.0, f"pitch = roll = 0 ({e})"
        return pitch, roll, (f"pitch and roll levelled on the mean specific force {np.round(mean, 3).tolist()} m/s^2 "
                             f"of {f.shape[0]} IMU samples over the {LEVEL_WINDOW_S:g} s before the fix")

    def aligned_by(self, ifa_message: str, aligned_key: str | None = None) -> bool:
        """Aligned while the ifa_node claims it (past its gate) and the own covariance supports it:
        the heading sigma of the accepted corrections at most ``aligned_max_heading_sigma_deg`` (a
        restarted node, whose covariance is ``initial_sigma``, is not aligned by a latched ALIGNED)."""
        own_deg = float(np.sqrt(max(self.nav_cov[1][2, 2], 0.0))) / DEG
        return self.ifa_claims_aligned and own_deg <= self.config.aligned_max_heading_sigma_deg

    def aligned_gate(self, claims: bool, heading_sigma_deg: str | None) -> gates.Refusal | None:
        return gates.check_aligned(claims, heading_sigma_deg, self.config.aligned_max_heading_sigma_deg)

    def status_message(self) -> str:
        return "ALIGNED" if self.aligned else "UNALIGNED"


#: what makes /master/nav (chosen by ``alignment``)
Navigator = ReferenceNavigator | GivenNavigator | IfaNavigator


def _int_or_none(text: str | None) -> int | None:
    """A status value as an integer (None when missing or not one, e.g. ``none``)."""
    try:
        return None if text is None else int(text)
    except ValueError:
        return None


def _datum_or_none(text: str | None) -> FloatArray | None:
    """A ``datum_deg`` status value ("lat_deg lon_deg h_m") as [lat_rad, lon_rad, h_m] (None when
    missing or not a position: dpos_core.gates.check_datum)."""
    try:
        v = np.array([float(x) for x in (text or "").split()], dtype=float)
    except ValueError:
        return None
    if v.size != 3:
        return None
    llh = np.array([v[0] * DEG, v[1] * DEG, v[2]])
    return None if gates.check_datum(None, llh) is not None else llh


def _float_or_none(text: str | None) -> float | None:
    """A status value as a float (None when missing or not one)."""
    try:
        return None if text is None else float(text)
    except ValueError:
        return None
