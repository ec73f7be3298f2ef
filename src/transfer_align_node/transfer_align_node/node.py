"""transfer_align_node — buffers the session, runs the transfer alignment when it ends, publishes
and writes a smoothed pose for every antenna (design.md "Nodes").

Buffering
    Every message of ``/master/nav``, ``/dpos/datum``, each configured ``/sub_imu/<name>/imu`` and,
    when present, the ``/truth/*`` topics of the aircraft is appended to a crash-safe spill
    (:mod:`dpos_ros.io.spill`) as it arrives: memory stays bounded, a killed process loses nothing,
    and ``dpos-process <spill dir>`` gives the same products.  Stamps, gaps and counts per topic
    are reported on ``/transfer_align/status`` (DiagnosticArray, latched, 1 Hz).

Sessions
    A session is what arrives between two finalizes.  The latched ``/dpos/datum`` is kept and
    written into every session's spill (a publisher that latched it once serves every session);
    without one the ``datum`` parameter is used.  A datum may not change within a session: the
    first accepted since the last session closed is kept, another one (more than
    ``dpos_core.gates.DATUM_TOL_M`` away; or not a position) is refused with a warning (the first,
    then at most every ``gates.WARN_INTERVAL_S``) and counted (status ``gate_refused``,
    ``gate/datum/changed``, ``last_gate``; level WARN).  After a session is closed, a message that
    continues its topic's stream of that session (stamp after the topic's last one there, at or
    before the session's end) is late: it goes into ``<spill>/late/`` (counted in the status as
    ``<topic>/late_after_finalize`` and in the session's ``status.json``; ``dpos-process
    <spill>`` uses it, the node's own products do not).  Every other message - a stamp after the
    end, or a topic that starts again (a replay, a restarted device) - belongs to the next
    session, and once a topic started again all its messages do.

Bad messages
    Messages the session reader (:func:`dpos_ros.io.session.read_session`) will reject - other
    frame names than the topic's first message (``frame``), stamp 0, and for Imu the relays'
    ``unavailable`` / ``negative_cov`` - are counted as they arrive (status ``<topic>/rejected``
    and ``<topic>/rejected/<reason>``, level WARN) and kept out of the stream statistics; they
    are spilled as they came.

Disk faults
    ``output_dir`` must be writable at start (else exit 2 naming it).  When the disk refuses a
    write (full, read-only, I/O error) the messages are held in memory in arrival order, up to
    ``disk_full_buffer_mb``, and written out as soon as the disk takes them again (tried every
    second); the status is ERROR meanwhile, naming the error, what is held and what was lost past
    the bound.  Finalizing waits until everything held is on disk.  Products that cannot be
    written are reported at ERROR with the command that makes them from the spill.

Finalizing (``/session/end``, the ``~/finalize`` service, or shutdown)
    Waits until every stream has reached the end stamp (the truth streams too, unless they
    stopped arriving for ``STALL_S``): at most ``finalize_timeout_s`` after the wait began or after
    the latest message of a stream still short of the end (a loaded machine drains its queues
    slowly), 10x ``finalize_timeout_s`` in all; reports what is missing; then runs
    the smoother for each sub-IMU in worker processes (in parallel on the available cores; the
    workers are started when the node starts and load the filters then, so the time after the
    session's end goes to the session: ~1.5 s of CPU per worker; a pool broken by a dead worker is
    replaced for the next session) while the executor keeps serving callbacks and the status reports progress; publishes ``/antenna/<name>/odom`` (flow-controlled, no loss) and writes the
    session products under ``output_dir/<session id>/``; then starts a new session.

Long sessions
    Every session is finalized by ``dpos-process``'s code (:func:`dpos_ros.products.solve.solve`,
    :mod:`dpos_ros.products.write`, :mod:`dpos_ros.products.evaluate`) on the spill
    (:meth:`TransferAlignNode._process`): the workers read their sub-IMU's log and the main POS's a
    block of records at a time (:func:`dpos_ros.io.session.read_session`, without the
    late messages), the poses are published :data:`~dpos_ros.products.write.BAG_BATCH_S` at a time
    (:class:`~dpos_ros.devices.sim_device.StreamBatches`: flow-controlled), and the products are
    written a block of rows at a time.  A session whose streams span more than ``stream_above_s``
    has its rows in files beside the products instead of in memory (memory that does not grow with
    it); the products are the same either way.

Errors
    A sub-IMU whose smoother fails - bad data (:class:`~dpos_core.errors.RejectedInput`), a
    numerical failure (:class:`~dpos_core.errors.NumericalFailure`), a bug or a dead worker -
    costs that sub-IMU only: the failure is logged at ERROR with the exception (with the
    traceback unless it is a rejected input), its antennas get the status ``failed: <reason>``
    in the products (and a warning in ``status.json``), the other antennas are processed,
    published and written as usual, and ``/transfer_align/status`` goes to level ERROR naming
    the sub-IMU (keys ``failed``, ``last_error``) until the next session is finalized.  A
    failure of the finalize itself is logged with its traceback and reported the same way.
    Cholesky jitter repairs of the smoothers are counted (``chol_jitter_repairs`` in the status
    and in ``status.json``).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from dpos_core import gates
from dpos_core.config import ConfigError, config_text, load_aircraft
from dpos_core.errors import RejectedInput
from dpos_core.ta.warmup import warm_up
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS, STATUS_QOS, keep_all
from dpos_ros.devices.sim_device import SimDevice, StreamBatches, StreamInfo
from dpos_ros.io.session import MASTER_SOURCE_KEY, RecordedSession, read_session, reject_reasons
from dpos_ros.io.spill import LATE_DIR, BufferedSpill, SpillWriter, spill_meta
from dpos_ros.products import solve as products_solve
from dpos_ros.products.antenna import AntennaSolution
from dpos_ros.products.evaluate import evaluate
from dpos_ros.products.master_reference import master_error_tau
from dpos_ros.products.rows import scratch_dir
from dpos_ros.products.solve import SubImuSource, solve
from dpos_ros.products.write import antenna_stream_batches, write
from dpos_ros.runtime.node_main import run_node
from dpos_ros.runtime.params import ParameterError, declare_config, format_config
from dpos_ros.runtime.pool import WarmPool, process_pool, worker_count
from transfer_align_node.params import TransferAlignConfig

NODE_NAME = "transfer_align_node"
#: at finalize, a stream that the smoother does not need (truth) and that has received nothing
#: for this long is not waited for (it may simply have ended before the session)
STALL_S = 2.0
#: at finalize, a stream that reached the end stamp (within 20 ms) is closed once it received
#: nothing for this long: its last samples may still be in flight
SETTLE_S = 0.3


def _stamp_ns(data: bytes) -> int:
    """header.stamp of a serialized message (every buffered type starts with a std_msgs/Header)."""
    sec = int.from_bytes(data[4:8], "little", signed=True)
    nsec = int.from_bytes(data[8:12], "little")
    return sec * 1_000_000_000 + nsec


def _frame_bytes(data: bytes) -> bytes:
    """The header.frame_id of a serialized message as its CDR bytes (length + string)."""
    n = int.from_bytes(data[12:16], "little")
    return bytes(data[12 : 16 + n])


def _check_writable(directory: Path) -> None:
    """Create ``directory`` if needed and write a file there; OSError when it cannot be written."""
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=directory, prefix=".writable_"):
        pass


def _pool(n_workers: int) -> cf.Executor:
    """The executor of the smoothers: spawned worker processes (one sub-IMU each).  A module
    function so that tests can run the smoothers in-process (and inject failures)."""
    return process_pool(n_workers)


def _warm_worker(method: str) -> float:
    """Run in each worker when the pool starts (:meth:`TransferAlignNode._new_pool`): imports this
    module and the filters and runs ``method`` once on synthetic data (dpos_core.ta.warmup)."""
    return warm_up(method)


def _describe(e: BaseException) -> str:
    """``<type>: <message>`` of an exception (a KeyError's message alone says little)."""
    return f"{type(e).__name__}: {e}"


def _pose_batches(sess: RecordedSession, est: dict[str, AntennaSolution],
                  batch_s: float | None = None) -> Iterator[list[Any]]:
    """The ``/antenna/<name>/odom`` streams (:func:`dpos_ros.products.write.antenna_stream_batches`)
    of the rows of ``est`` (every antenna with rows), ``batch_s`` seconds of poses at a time
    (default :data:`dpos_ros.products.write.BAG_BATCH_S`): each batch a stream per antenna in
    ``est``'s order (empty where it has no row then), the batches in time order."""
    yield from antenna_stream_batches(sess, est, batch_s)


class _SubImuTasks(cf.Executor):
    """The executor :func:`dpos_ros.products.solve.solve` gets in the node: its sub-IMU
    tasks (:func:`~dpos_ros.products.solve.align_to_store`) that fail - a numerical failure, a
    bug, a dead worker, an unreadable log - cost that sub-IMU only (module docstring, "Errors"): the
    exception is kept in :attr:`failed` and the task's result says that its antennas are not
    estimated; every other task goes to ``pool`` as it is, or runs in this process once the pool
    is broken (a worker died: the sub-IMUs that finished still get their wing fit and products)."""

    def __init__(self, pool: cf.Executor, method: str) -> None:
        self.pool = pool
        self.method = method
        self.failed: dict[str, BaseException] = {}  # sub-IMU -> what its task raised

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        out: cf.Future = cf.Future()
        try:
            fut = self.pool.submit(fn, *args, **kwargs)
        except cf.BrokenExecutor as e:  # a worker died (a sub-IMU's task): the session goes on without the pool
            if fn is products_solve.align_to_store:
                self._failed(args[0].sub, e, out)
            else:  # the wing fit's windows, the products' files: in this process
                try:
                    out.set_result(fn(*args, **kwargs))
                except BaseException as ex:  # noqa: BLE001 - the caller's result() raises it
                    out.set_exception(ex)
            return out
        if fn is not products_solve.align_to_store:
            return fut
        sub = args[0].sub

        def done(f: cf.Future) -> None:
            try:
                out.set_result(f.result())
            except BaseException as e:  # noqa: BLE001 - this sub-IMU only (the node reports it)
                self._failed(sub, e, out)

        fut.add_done_callback(done)
        return out

    def _failed(self, sub: str, e: BaseException, out: cf.Future) -> None:
        self.failed[sub] = e
        out.set_result({"rejected": f"the {self.method} smoother failed ({_describe(e)})", "warnings": []})

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """(The pool is the node's: it stays up.)"""


class _Stream:
    """What arrived on one topic: created with its first message (stamp ``t`` [ns])."""

    __slots__ = ("count", "first_ns", "last_ns", "min_dt", "gaps", "arrived")

    def __init__(self, t: int) -> None:
        self.count = 1
        self.first_ns: int = t  # the oldest stamp
        self.last_ns: int = t  # the newest stamp
        self.min_dt: int | None = None
        self.gaps = 0
        self.arrived = time.monotonic()  # wall time of the last message

    def add(self, t: int) -> None:
        self.arrived = time.monotonic()
        dt = t - self.last_ns
        if dt > 0:
            if self.min_dt is None or dt < self.min_dt:
                self.min_dt = dt
            elif dt > 2 * self.min_dt:
                self.gaps += 1
        self.count += 1
        self.first_ns = min(self.first_ns, t)
        self.last_ns = max(self.last_ns, t)


class _Closed:
    """The last closed session: where late messages of it go (module docstring, "Sessions")."""

    def __init__(self, end_ns: int, spill_dir: Path, session_id: str, last_ns: dict[str, int], max_bytes: int) -> None:
        self.end_ns = end_ns
        self.spill_dir = spill_dir
        self.session_id = session_id
        self.last_ns = last_ns  # topic -> newest stamp spilled in the session
        self.restarted: set[str] = set()  # topics whose messages now belong to the next session
        self.late: dict[str, int] = {}
        self.products: Path | None = None
        self._max_bytes = max_bytes
        self._writer: BufferedSpill | None = None

    def is_late(self, topic: str, t: int) -> bool:
        last = self.last_ns.get(topic)
        if topic in self.restarted or last is None or not last < t <= self.end_ns:
            self.restarted.add(topic)
            return False
        return True

    def write(self, topic: str, msgtype: str, t: int, data: bytes) -> int:
        if self._writer is None:
            self._writer = BufferedSpill(lambda: SpillWriter(self.spill_dir / LATE_DIR, self.session_id), self._max_bytes)
        self._writer.write(topic, msgtype, t, data)
        self.late[topic] = self.late.get(topic, 0) + 1
        return self.late[topic]

    def close(self) -> None:
        """Close the late spill and write the final late counts into the session's products."""
        if self._writer is not None:
            self._writer.flush()
            self._writer.close()
        if self.products is not None and self.late:
            _note_late(self.products, self.spill_dir, self.late)


def _note_late(products: Path, spill_dir: Path, late: dict[str, int]) -> None:
    """Record in ``products/status.json`` what arrived after the session closed (not in these
    products; ``dpos-process <spill>`` uses it)."""
    f = products / "status.json"
    try:
        st = json.loads(f.read_text())
        st["late_after_close"] = {"messages": dict(sorted(late.items())), "spill": str(spill_dir / LATE_DIR),
                                  "used": False, "rerun": f"dpos-process {spill_dir} --out <dir> uses them"}
        tmp = f.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(st, indent=1))
        os.replace(tmp, f)
    except (OSError, ValueError):
        pass  # the counts are in the node's log and status; the spill holds the messages


class TransferAlignNode(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: TransferAlignConfig = declare_config(self, TransferAlignConfig)
            self._setup()
        except ParameterError:
            self.destroy_node()
            raise

    # ------------------------------------------------------------------ setup
    def _setup(self) -> None:
        cfg = self.config
        ref = cfg.aircraft_config or "paper_su"
        try:
            self.aircraft_yaml = config_text("aircraft", ref)
            self.aircraft = load_aircraft(ref, text=self.aircraft_yaml)
        except ConfigError as e:
            raise ParameterError("aircraft_config", cfg.aircraft_config, str(e)) from None
        known = [s.name for s in self.aircraft.sub_imus]
        unknown = [n for n in cfg.sub_imus if n not in known]
        if unknown:
            raise ParameterError("sub_imus", list(cfg.sub_imus), f"{unknown} not in aircraft {self.aircraft.name!r} (has {known})")
        self.sub_names = list(cfg.sub_imus) or known
        self.output_dir = Path(cfg.output_dir)
        try:
            _check_writable(self.output_dir)
        except OSError as e:
            raise ParameterError("output_dir", cfg.output_dir, f"not writable: {e.strerror or e}") from None
        self._max_held = int(cfg.disk_full_buffer_mb * 1_000_000)
        self._lock = threading.Lock()
        self._spill: BufferedSpill | None = None
        self._spill_dir: Path | None = None
        self._streams: dict[str, _Stream] = {}
        self._end: tuple[int, str] | None = None
        self._finalizing = False
        self._finalize_thread: threading.Thread | None = None
        self._progress = "waiting for data"
        self._errors: dict[str, str] = {}  # sub-IMU (or "finalize") -> what failed, for the session being / last finalized
        self._chol_jitter_repairs = 0  # in the smoothers of the last finalized session
        self._sessions_done = 0
        self._closed: _Closed | None = None  # the last closed session (late messages)
        self._end_on_shutdown = False
        self._datum: tuple[int, bytes] | None = None  # the latest /dpos/datum (stamp, CDR): spilled into every session
        # the datum accepted since the last session closed [lat_rad, lon_rad, h_m]: another one is refused until
        # that session is finalized (dpos_core.gates.check_datum), counted in the status (gate/datum/<reason>)
        self._session_datum: np.ndarray | None = None
        self._gates = gates.GateCounts()
        self._frames: dict[str, tuple[bytes, cdr.Layout | None]] = {}  # topic -> frame_id bytes of its first message (Imu: layout)
        self._rejected: dict[str, dict[str, int]] = {}  # topic -> reason -> messages the session reader rejects
        self._disk: BufferedSpill | None = None  # a closing spill waiting for the disk (finalize)
        self._saw_master_status = False  # a /pos_master/status publisher seen during the session (_publish_status)
        self._stopping_at: float | None = None  # time.monotonic() of the shutdown (bounds the wait for the disk)
        self._device: SimDevice | None = None  # publishing the antenna poses of the last session
        self._n_workers = worker_count(cfg.workers, len(self.sub_names))
        self._executor: cf.Executor | None = self._new_pool()  # started now: warm when the session ends
        topics = {T.MASTER_NAV: (T.ODOMETRY, NAV_QOS), T.DATUM: (T.NAVSATFIX, DATUM_QOS),
                  T.TRUTH_MASTER: (T.ODOMETRY, NAV_QOS)}
        for n in self.sub_names:
            topics[T.sub_imu(n)] = (T.IMU, SENSOR_QOS)
            topics[T.truth_sub_imu(n)] = (T.ODOMETRY, NAV_QOS)
        for a in self.aircraft.antennas:
            if a.sub_imu is None or a.sub_imu in self.sub_names:
                topics[T.truth_antenna(a.name)] = (T.ODOMETRY, NAV_QOS)

        types = {T.ODOMETRY: Odometry, T.IMU: Imu, T.NAVSATFIX: NavSatFix}
        # KEEP_ALL (design.md allows it): a reader that falls behind makes reliable writers wait
        # instead of losing the oldest samples, as a deep KEEP_LAST queue would
        self._subs = [self.create_subscription(types[mt], topic, self._make_cb(topic, mt), keep_all(qos), raw=True)
                      for topic, (mt, qos) in topics.items()]
        self._subs.append(self.create_subscription(Header, T.SESSION_END, self._on_end, NAV_QOS))
        self.create_service(Trigger, "~/finalize", self._on_finalize)
        self._status_pub = self.create_publisher(DiagnosticArray, T.TRANSFER_ALIGN_STATUS, STATUS_QOS)
        self.create_timer(1.0, self._publish_status)
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(cfg, ('method', 'particles', 'output_dir', 'sub_imus'))} aircraft={self.aircraft.name} "
            f"sub-IMUs {self.sub_names}: buffering /master/nav, {', '.join(f'/sub_imu/{n}/imu' for n in self.sub_names)}; "
            f"finalize on /session/end or /{NODE_NAME}/finalize")

    # ------------------------------------------------------------------ buffering
    def _make_cb(self, topic: str, msgtype: str):
        def cb(data: bytes) -> None:
            t = _stamp_ns(data)
            data = bytes(data)
            with self._lock:
                if topic == T.DATUM:  # latched once, valid for every session until a new one comes
                    llh = cv.datum_from_msg(deserialize_message(data, NavSatFix))
                    refusal = gates.check_datum(self._session_datum, llh)
                    if refusal is not None:
                        line = self._gates.refuse(f"datum/{refusal.reason}", f"{T.DATUM} stamped {t} ns: {refusal.text}",
                                                  time.monotonic())
                        if line is not None:
                            self.get_logger().warning(line)
                        return
                    self._session_datum = llh
                    self._datum = (t, data)
                    if self._spill is not None:
                        self._spill.write(topic, msgtype, t, data)
                        self._streams.setdefault(topic, _Stream(t))
                    return
                closed = self._closed
                if closed is not None and closed.is_late(topic, t):
                    n = closed.write(topic, msgtype, t, data)
                    if n == 1:
                        self.get_logger().warning(
                            f"{topic}: message stamped {t} ns arrived after its session {closed.session_id} (ending "
                            f"{closed.end_ns} ns) was closed; kept in {closed.spill_dir / LATE_DIR} (dpos-process on the "
                            "spill uses it; counted in the status as late_after_finalize)")
                    return
                sp = self._ensure_spill()
                sp.write(topic, msgtype, t, data)
                why = self._reject_reason(topic, msgtype, t, data)
                if why is not None:
                    counts = self._rejected.setdefault(topic, {})
                    counts[why] = counts.get(why, 0) + 1
                    if counts[why] == 1:
                        self.get_logger().warning(
                            f"{topic}: message stamped {t} ns rejected ({why}); spilled as it came, the session reader rejects "
                            "it too (counted in the status as rejected)")
                    return
                st = self._streams.get(topic)
                if st is None:
                    self._streams[topic] = _Stream(t)
                else:
                    st.add(t)
        return cb

    def _reject_reason(self, topic: str, msgtype: str, t: int, data: bytes) -> str | None:
        """Why the session reader will reject this message (:func:`dpos_ros.io.session.reject_reasons`,
        ``frame``: another frame_id than the topic's first message in this session), or None."""
        frame = _frame_bytes(data)
        first = self._frames.get(topic)
        if first is None:
            first = self._frames[topic] = (frame, cdr.layout("imu", cdr.frame_ids(data, "imu")[0]) if msgtype == T.IMU else None)
        if frame != first[0]:
            return "frame"
        lay = first[1]
        if lay is None or len(data) != lay.size:
            return "zero_stamp" if t == 0 else None
        t_v, vals = cdr.decode(lay, np.frombuffer(data, dtype=np.uint8)[None])
        return next((why for why, m in reject_reasons("imu", t_v, vals).items() if m[0]), None)

    def _ensure_spill(self) -> BufferedSpill:
        sp = self._spill
        if sp is None:
            sid = time.strftime("session_%Y%m%d_%H%M%S")
            d = self._spill_dir = self.output_dir / "spill" / f"{sid}_{os.getpid()}"
            custom = {"dpos.session_id": sid, "dpos.aircraft_yaml": self.aircraft_yaml}
            sp = self._spill = BufferedSpill(lambda: SpillWriter(d, sid, custom), self._max_held)
            self._frames = {}
            self._saw_master_status = False
            self.get_logger().info(f"new session: spilling to {self._spill_dir}")
            if self._datum is not None:
                sp.write(T.DATUM, T.NAVSATFIX, *self._datum)
                self._streams[T.DATUM] = _Stream(self._datum[0])
        return sp

    def _on_end(self, msg) -> None:
        t = msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec
        self.get_logger().info(f"/session/end: session {msg.frame_id!r}, last sample at {t} ns")
        self._start_finalize(t, msg.frame_id)

    def _on_finalize(self, _req, resp):
        with self._lock:
            has_data = self._spill is not None
            last = max((s.last_ns for s in self._streams.values()), default=None)
        if not has_data or last is None:
            resp.success = False
            resp.message = "no data buffered: nothing to finalize"
            return resp
        started = self._start_finalize(last, "")
        resp.success = started
        resp.message = f"finalizing session up to {last} ns" if started else "a session is already being finalized"
        return resp

    def _start_finalize(self, end_ns: int, session_id: str, shutdown: bool = False) -> bool:
        with self._lock:
            if self._finalizing:
                return False
            self._finalizing = True
            self._end = (end_ns, session_id)
            self._end_on_shutdown = shutdown
            self._errors = {}
        self._finalize_thread = threading.Thread(target=self._finalize, name="finalize", daemon=True)
        self._finalize_thread.start()
        return True

    # ------------------------------------------------------------------ finalizing
    def _finalize(self) -> None:
        log = self.get_logger()
        cfg = self.config
        try:
            if self._end is None:
                raise RuntimeError("finalize started without the session's end (_start_finalize sets it)")
            end_ns, sid = self._end
            needed = [T.MASTER_NAV] + [T.sub_imu(n) for n in self.sub_names]
            deadline = time.monotonic() + cfg.finalize_timeout_s
            hard_deadline = time.monotonic() + 10 * cfg.finalize_timeout_s
            while True:
                # the streams the smoother needs, and every other stream of the session (truth,
                # datum) that is still arriving: none may be cut off by closing the spill
                now = time.monotonic()
                with self._lock:
                    # at shutdown the devices may be gone already: a stalled stream is not waited for either
                    stalled = (lambda st: now - st.arrived >= STALL_S) if self._end_on_shutdown else (lambda st: False)
                    behind = [t for t in needed if (self._streams.get(t) is None and not self._end_on_shutdown)
                              or (t in self._streams and self._streams[t].last_ns < end_ns - 20_000_000
                                  and not stalled(self._streams[t]))]
                    behind += [t for t, st in self._streams.items() if t not in needed and t != T.DATUM
                               and st.last_ns < end_ns - 20_000_000 and now - st.arrived < STALL_S]
                    # a stream within 20 ms of the end may still have its last samples in flight:
                    # close once nothing stamped up to the end arrived for SETTLE_S
                    behind += [t for t, st in self._streams.items() if t != T.DATUM and t not in behind
                               and st.last_ns <= end_ns and now - st.arrived < SETTLE_S]
                    # data up to the end still coming in (a loaded machine drains its queues slowly):
                    # the bound counts from the latest such arrival, up to 10x finalize_timeout_s
                    arriving = max((self._streams[t].arrived for t in behind if t in self._streams), default=0.0)
                if not behind or now > min(max(deadline, arriving + cfg.finalize_timeout_s), hard_deadline):
                    break
                self._progress = f"waiting for data up to the end: {behind}"
                time.sleep(0.1)
            with self._lock:
                sp, spill_dir = self._spill, self._spill_dir
                saw_status = self._saw_master_status
                missing = [t for t in needed if t not in self._streams]
                if sp is not None and T.DATUM not in self._streams and cfg.datum:
                    self._spill_datum(sp)
                self._spill = None  # new messages (stamped after the end) start the next session
                self._session_datum = None  # the next session may have another datum (the latest is kept for it)
                self._spill_dir = None
                streams = self._streams
                self._streams = {}
                rejected = self._rejected
                self._rejected = {}
                previous = self._closed
                if sp is not None and spill_dir is not None:
                    self._closed = _Closed(end_ns, spill_dir, sid or spill_dir.name, {k: v.last_ns for k, v in streams.items()},
                                           self._max_held)
            if previous is not None:
                previous.close()
            if rejected:
                log.warning(f"finalize: messages the session reader rejects, per topic and reason: {rejected}")
            short = [t for t, st in streams.items() if t in needed and st.last_ns < end_ns - 20_000_000]
            if behind:
                log.warning(f"finalize: after {cfg.finalize_timeout_s:g} s still short of the end stamp: {behind}")
            elif short:
                log.warning(f"finalize at shutdown: {short} stopped short of the last stamp of the session "
                            f"({end_ns} ns); processing what arrived")
            if missing:
                log.warning(f"finalize: no data at all on {missing}")
            if sp is None or spill_dir is None:  # (both are set together by _ensure_spill)
                log.error("finalize: nothing buffered")
                return
            # /master/nav is pos_master_node's GNSS/INS mechanization when its status is published
            # (also kept in the spill's metadata, for dpos-process on the spill)
            mechanized = saw_status or self.count_publishers(T.POS_MASTER_STATUS) > 0
            self._close_spill(sp, sid, mechanized)
            timed = [st for t, st in streams.items() if t != T.DATUM]  # (the latched datum's stamp may be old)
            span_s = (max(st.last_ns for st in timed) - min(st.first_ns for st in timed)) * 1e-9 if timed else 0.0
            self._process(spill_dir, mechanized, span_s)
        except Exception as e:  # noqa: BLE001 - logged with its traceback, status ERROR; the node stays up for the next session
            log.error(f"finalize failed: {_describe(e)}\n{''.join(traceback.format_exception(e)).rstrip()}")
            with self._lock:
                self._errors["finalize"] = _describe(e)
            self._progress = f"failed: {_describe(e)}"
        finally:
            with self._lock:
                self._finalizing = False

    def _close_spill(self, sp: BufferedSpill, sid: str, mechanized: bool = False) -> None:
        """Write out what is held in memory (waiting, with the status at ERROR, while the disk
        refuses it: nothing held is dropped), name the session and close the spill.  At shutdown
        the wait is bounded by ``finalize_timeout_s``: what the disk still refuses then is lost
        with the process, and the error says how much."""
        log = self.get_logger()
        waited = False
        if self._end_on_shutdown:
            self._stopping_at = self._stopping_at or time.monotonic()
        while True:
            give_up = None if self._stopping_at is None else self._stopping_at + self.config.finalize_timeout_s
            if give_up is not None and time.monotonic() > give_up:
                log.error(f"shutdown: the disk still refuses the spill ({sp.error}); {sp.held} message(s) held in memory "
                          "are lost with the process; processing what is on disk")
                sp.close()
                break
            try:
                if sp.flush():
                    if sid and sp.writer is not None:
                        sp.writer.session_id = sid
                        sp.writer.set_custom("dpos.session_id", sid)
                    if mechanized and sp.writer is not None:
                        sp.writer.set_custom(MASTER_SOURCE_KEY, "mechanized")
                    sp.close()
                    break
            except OSError as e:  # naming the session (spill.json) failed: the disk still refuses
                sp.error = e
            self._progress = (f"finalize waits for the disk: {sp.held} message(s) held in memory "
                              f"({sp.error.strerror if sp.error else 'error'}); free space on {self.output_dir}")
            with self._lock:
                self._disk = sp
            if not waited:
                log.error(self._progress)
                waited = True
            time.sleep(1.0)
        if waited:
            with self._lock:
                self._disk = None
            log.info("finalize: the disk took the held messages; the spill is complete")

    def _spill_datum(self, sp) -> None:
        lat, lon, h = self.config.datum
        msg = cv.datum_msg(0, np.array([np.deg2rad(lat), np.deg2rad(lon), h]))
        sp.write(T.DATUM, T.NAVSATFIX, 0, serialize_message(msg))
        self.get_logger().warning("no /dpos/datum received: using the datum parameter")

    def _new_pool(self) -> cf.Executor:
        """The smoothers' workers, started now, each loading the filters (:func:`_warm_worker`)."""
        return WarmPool(self._n_workers, partial(_warm_worker, self.config.method), make=_pool)

    def _publish_poses(self, streams: Sequence[Any] | StreamBatches, n: int) -> None:
        """Publish the antenna poses (``n`` messages; whole streams or :class:`StreamBatches`) without
        loss (:class:`SimDevice`, as fast as the subscribers take them) and wait until they are."""
        if self._device is not None:
            self._device.stop()
            self._device = None
        if not n:
            self.get_logger().warning("no antenna estimated in this session: nothing to publish on /antenna/*/odom")
            return
        self._progress = f"publishing {n} antenna poses"
        device = self._device = SimDevice(self, streams, 0.0).start()
        device.finished.wait()
        device.stop()  # every pose is published: do not hold the session's poses until the next one
        self._device = None

    def _process(self, spill_dir: Path, mechanized: bool = False, span_s: float = 0.0) -> None:
        """The session's products (module docstring): :func:`dpos_ros.products.solve.solve` on the
        spill (each worker reads its sub-IMU's log and the main POS's), the poses published from the
        rows :data:`~dpos_ros.products.write.BAG_BATCH_S` at a time,
        :func:`~dpos_ros.products.write.write`.  A session longer than ``stream_above_s`` has its
        rows in files beside the products ("Long sessions"), a shorter one in memory."""
        cfg = self.config
        log = self.get_logger()
        t0 = time.perf_counter()
        tau, why = master_error_tau(cfg.master_error_tau_s, mechanized)
        log.info(f"main POS errors: {'white noise' if tau == 0 else f'correlated, {tau:g} s, estimated as states'} ({why})")
        settings = cfg.core_config(tau)
        spill = span_s > cfg.stream_above_s
        self._progress = (f"processing {len(self.sub_names)} sub-IMU(s) with {cfg.method} on {self._n_workers} worker(s)"
                          + (f", rows spilled to disk ({span_s:.0f} s of session > stream_above_s {cfg.stream_above_s:g} s)" if spill else ""))
        log.info(self._progress)
        sess = read_session(spill_dir, keep=lambda t: False, include_late=False)  # the main POS alone
        sess.master_error_model = {"tau_s": settings.master_error_tau_s, "why": why}
        topics = spill_meta(spill_dir)[0]
        subs = [n for n in self.sub_names if T.sub_imu(n) in topics]
        ex = self._executor if self._executor is not None else self._new_pool()
        try:
            ex.submit(int).result()  # (a pool broken since the last session - a worker died - refuses work)
        except cf.BrokenExecutor:
            log.warning("the smoothers' worker pool is broken (a worker died since the node started): starting new workers")
            ex.shutdown(wait=False, cancel_futures=True)
            ex = self._new_pool()
        self._executor = ex
        tasks = _SubImuTasks(ex, cfg.method)
        with scratch_dir(self.output_dir) as tmp:
            antennas, timing = solve(sess, self.aircraft, settings, source=SubImuSource(bag=str(spill_dir), include_late=False),
                                     store_dir=Path(tmp) if spill else None, pool=tasks, sub_imus=subs)
            # the antennas of the sub-IMUs not configured (sub_imus) are not the session's (as _process)
            other = [s.name for s in self.aircraft.sub_imus if s.name not in self.sub_names]
            antennas = {k: a for k, a in antennas.items() if a.sub_imu is None or a.sub_imu in self.sub_names}
            sess.warnings = [w for w in sess.warnings if not any(w.startswith(f"sub-IMU {n}: no /sub_imu/{n}/imu ") for n in other)]
            failed = {sub: _describe(e) for sub, e in tasks.failed.items()}
            for sub, e in tasks.failed.items():
                tb = "" if isinstance(e, RejectedInput) else "\n" + "".join(traceback.format_exception(e)).rstrip()
                log.error(f"sub-IMU {sub}: the {cfg.method} smoother failed: {_describe(e)}; its antennas are not estimated{tb}")
                for a in antennas.values():
                    if a.sub_imu == sub:
                        a.status = f"failed: {failed[sub]}"
            with self._lock:
                self._errors.update(failed)
            per_sub: dict[str, int] = {}
            for a in antennas.values():
                if a.sub_imu is not None:
                    per_sub[a.sub_imu] = max(per_sub.get(a.sub_imu, 0), a.chol_jitter_repairs)
            self._chol_jitter_repairs = sum(per_sub.values())
            if self._chol_jitter_repairs:
                log.warning(f"the smoothers repaired {self._chol_jitter_repairs} covariance(s) with a diagonal jitter (chol_jitter_repairs)")
            if any(isinstance(e, cf.BrokenExecutor) for e in tasks.failed.values()):  # a dead worker breaks the pool: new workers
                ex.shutdown(wait=False, cancel_futures=True)
                self._executor = None
                self._executor = self._new_pool()
            est = {name: a for name, a in antennas.items() if a.rows is not None and a.rows.n}
            info = [StreamInfo(T.antenna_odom(name), T.ODOMETRY, "nav", a.rows.n) for name, a in est.items() if a.rows is not None]
            self._publish_poses(StreamBatches(info, lambda: _pose_batches(sess, est)), sum(i.count for i in info))
            self._unique_session_id(sess)
            timing["processing_s"] = time.perf_counter() - t0
            try:  # against the truth when the session has it, a part at a time (dpos_ros.products.evaluate)
                ev = evaluate(sess, antennas, list(topics))
                out = write(self.output_dir, sess, antennas, cfg.method, timing, ev or None, pool=self._executor)
            except OSError as e:
                self._products_failed(sess, e, spill_dir)
                return
        self._session_done(spill_dir, sess, out, {name: a.status for name, a in antennas.items()}, failed, timing)

    def _unique_session_id(self, sess: RecordedSession) -> None:
        """A repeated session id (the same bag replayed) gets a suffix: never overwrite a flight's products."""
        sid = sess.session_id
        k = 2
        while (self.output_dir / sess.session_id).exists():
            sess.session_id = f"{sid}_{k}"
            k += 1
        if sess.session_id != sid:
            self.get_logger().warning(f"products of a session {sid!r} exist in {self.output_dir}: this session's go to {sess.session_id!r}")

    def _products_failed(self, sess: RecordedSession, e: OSError, spill_dir: Path) -> None:
        """The products could not be written: ERROR naming the spill to run dpos-process on."""
        why = f"the products of session {sess.session_id} could not be written ({e.strerror or e}: {e.filename or self.output_dir})"
        with self._lock:
            self._errors["products"] = why
        self._progress = f"{why}; the spill is kept: dpos-process {spill_dir} --out <dir> makes them"
        self.get_logger().error(self._progress)
        self._sessions_done += 1

    def _session_done(self, spill_dir: Path, sess: RecordedSession, out: Path, statuses: dict[str, str], failed: dict[str, str],
                      timing: dict[str, float]) -> None:
        """The session's products are written in ``out``: its late messages noted, the outcome logged."""
        log = self.get_logger()
        with self._lock:
            closed = self._closed
            if closed is not None and closed.spill_dir == spill_dir:
                closed.products = out
                late = dict(closed.late)
            else:
                late = {}
        if late:
            _note_late(out, spill_dir, late)
        self._sessions_done += 1
        for name, status in statuses.items():
            log.info(f"antenna {name}: {status}")
        errors = ", ".join(f"{sub} ({' '.join(a.name for a in self.aircraft.antennas if a.sub_imu == sub)})" for sub in sorted(failed))
        errors = f" with failed sub-IMU(s) {errors}" if failed else ""
        self._progress = f"session {sess.session_id} done{errors}: products in {out}; ready for the next session"
        (log.error if failed else log.info)(f"{self._progress} (processing {timing['processing_s']:.1f} s for {timing['data_s']:.0f} s of sub-IMU data)")

    # ------------------------------------------------------------------ status
    def _retry_disk(self) -> None:
        """Write out what the disk refused before, when nothing else comes to retry it (1 Hz)."""
        with self._lock:
            sp = self._spill
            if sp is not None and sp.held:
                sp.flush()

    def _publish_status(self) -> None:
        self._retry_disk()
        if self._spill is not None and not self._saw_master_status and self.count_publishers(T.POS_MASTER_STATUS) > 0:
            self._saw_master_status = True
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus()
        st.name = f"{NODE_NAME}: session"
        st.hardware_id = self.get_name()
        with self._lock:
            streams = {k: (v.count, v.gaps, v.last_ns) for k, v in self._streams.items()}
            finalizing = self._finalizing
        st.level = DiagnosticStatus.OK
        st.message = self._progress if (finalizing or not streams) else f"buffering {sum(c for c, _, _ in streams.values())} messages"
        st.values = [KeyValue(key="state", value="finalizing" if finalizing else ("buffering" if streams else "idle")),
                     KeyValue(key="sessions_done", value=str(self._sessions_done))]
        with self._lock:
            late = dict(self._closed.late) if self._closed is not None else {}
            errors = dict(self._errors)
            rejected = {k: dict(v) for k, v in self._rejected.items()}
            disk = self._spill if self._spill is not None and (self._spill.held or self._spill.lost) else self._disk
        if disk is not None and (disk.held or disk.lost):
            st.level = DiagnosticStatus.ERROR
            err = disk.error.strerror if disk.error is not None and disk.error.strerror else str(disk.error or "")
            st.values += [KeyValue(key="disk_error", value=err), KeyValue(key="held_in_memory", value=str(disk.held)),
                          KeyValue(key="held_bytes", value=str(disk.held_bytes)), KeyValue(key="lost", value=str(disk.lost))]
            errors["disk"] = (f"the disk refuses the spill ({err}): {disk.held} message(s) held in memory"
                              + (f", {disk.lost} lost past disk_full_buffer_mb" if disk.lost else ""))
        st.values.append(KeyValue(key="chol_jitter_repairs", value=str(self._chol_jitter_repairs)))
        if errors:  # a sub-IMU's smoother (or the finalize) failed in the session being / last finalized
            st.level = DiagnosticStatus.ERROR
            names = " ".join(sorted(errors))
            st.values += [KeyValue(key="failed", value=names), KeyValue(key="last_error", value="; ".join(f"{k}: {v}" for k, v in sorted(errors.items())))]
            if not st.message.startswith(("failed", "session")):  # those name the failures already
                st.message = f"{st.message} ({'' if finalizing else 'last session: '}failed {names})"
        for topic, n in sorted(late.items()):
            st.values.append(KeyValue(key=f"{topic}/late_after_finalize", value=str(n)))
            st.level = max(st.level, DiagnosticStatus.WARN)
        for topic, by_reason in sorted(rejected.items()):
            st.values.append(KeyValue(key=f"{topic}/rejected", value=str(sum(by_reason.values()))))
            st.values += [KeyValue(key=f"{topic}/rejected/{why}", value=str(n)) for why, n in sorted(by_reason.items())]
            st.level = max(st.level, DiagnosticStatus.WARN)
        with self._lock:
            gate_values = self._gates.values()
        st.values += [KeyValue(key=k, value=str(v)) for k, v in gate_values.items()]
        if self._gates.total:
            st.level = max(st.level, DiagnosticStatus.WARN)
        for topic, (c, g, _last) in sorted(streams.items()):
            st.values.append(KeyValue(key=f"{topic}/count", value=str(c)))
            st.values.append(KeyValue(key=f"{topic}/gaps", value=str(g)))
            if g:
                st.level = max(st.level, DiagnosticStatus.WARN)
        arr.status = [st]
        self._status_pub.publish(arr)

    def destroy_node(self) -> None:
        # shutdown finalizes a session that has data and was not finalized yet
        try:
            lock = getattr(self, "_lock", None)
            if lock is None:  # construction failed (bad parameter): nothing to finalize
                return
            self._stopping_at = time.monotonic()
            with lock:
                pending = self._spill is not None and not self._finalizing
                last = max((s.last_ns for s in self._streams.values()), default=None)
            if pending and last is not None:
                self.get_logger().info("shutdown: finalizing the buffered session")
                self._start_finalize(last, "", shutdown=True)
            t = getattr(self, "_finalize_thread", None)
            if t is not None and t.is_alive():
                t.join()
            device = getattr(self, "_device", None)
            if device is not None:
                device.stop()
            ex = getattr(self, "_executor", None)
            if ex is not None:
                self._executor = None
                ex.shutdown(wait=True, cancel_futures=True)
            closed = getattr(self, "_closed", None)
            if closed is not None:  # the late messages of the last session: final counts into its products
                closed.close()
        finally:
            super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``transfer_align_node``."""
    return run_node(TransferAlignNode, NODE_NAME, argv)
