"""Reading a recorded session (rosbag2) into the transfer alignment's inputs.

Every problem with the data is reported, and no good sample is dropped: out-of-order messages are
sorted, exact duplicates removed, samples with NaN removed, gaps (stamp steps over GAP_FACTOR = 1.75 x the
median) counted; each as a warning naming the topic.  A missing ``/master/nav`` is an error.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from dpos_core import plausibility
from dpos_core.errors import SessionError
from dpos_core.series import GAP_FACTOR, ImuSeries, NavSeries
from dpos_core.units import FloatArray
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io import _mcap, bag
from dpos_ros.io import spill as S
from dpos_ros.io.messages import Messages, RawTopic
from dpos_ros.io.outdir import safe_name

#: metadata key (rosbag2 ``custom_data``, a spill's ``custom_data``) naming the source of /master/nav:
#: ``mechanized`` = pos_master_node's GNSS/INS mechanization (transfer_align_node writes it into its
#: spill when a /pos_master/status publisher exists)
MASTER_SOURCE_KEY = "dpos.master_source"
#: :data:`MASTER_SOURCE_KEY` of a recording whose /master/nav is an imported navigation solution (dpos-import --nav)
MASTER_SOURCE_SOLUTION = "solution"


def master_is_mechanized(custom: dict[str, str], raw: dict) -> bool:
    """Whether /master/nav is pos_master_node's mechanization (a GNSS/INS): the recording's
    ``/pos_master/status`` (a message of it in ``raw``, what dpos-record keeps of a graph) or its
    :data:`MASTER_SOURCE_KEY` metadata say so.  The simulator's ``reference`` main POS (truth +
    white noise; dpos-sim, pos_master_node ``alignment: reference``) publishes no status."""
    status = raw.get(T.POS_MASTER_STATUS)
    return (status is not None and len(status[1]) > 0) or custom.get(MASTER_SOURCE_KEY) == "mechanized"


@dataclass
class RecordedSession:
    """Inputs of a session, times in seconds since ``t0_ns``.

    master: the main-system navigation with its body rate and covariances (local ENU);
    sub_imus: {name: ImuSeries}; truth: {"master" | "sub_imu/<name>" | "antenna/<name>": NavSeries};
    custom: the recording's dpos.* metadata; warnings: what was wrong with the data;
    master_mechanized: /master/nav is pos_master_node's mechanization of the main IMU aligned by GNSS
    (``alignment`` ifa or given: a GNSS/INS, whose errors are correlated in time), known from the
    recording's ``/pos_master/status`` or its ``dpos.master_source`` metadata (:data:`MASTER_SOURCE_KEY`);
    master_error_model: how the processing modelled the main POS's errors (``tau_s``, ``why``;
    :func:`dpos_ros.products.master_reference.master_error_tau`), for status.json.
    """

    path: Path
    session_id: str
    t0_ns: int
    datum_llh: FloatArray
    master: NavSeries
    sub_imus: dict[str, ImuSeries]
    truth: dict[str, NavSeries]
    custom: dict[str, str]
    end_s: float | None
    warnings: list[str] = field(default_factory=list)
    master_mechanized: bool = False
    master_error_model: dict[str, Any] = field(default_factory=dict)
    #: data of the recording that could not be read (status.json ``data_lost``): ``messages`` in
    #: skipped MCAP chunks, ``spill_bytes_skipped`` of corrupt spill records; empty when none
    data_lost: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # a session id names the products' directory: never a path (dpos_ros.io.outdir.safe_name)
        sid = safe_name(self.session_id)
        if sid != self.session_id:
            self.warnings.append(f"session id {self.session_id!r} is not a safe directory name: using {sid!r}")
            self.session_id = sid

    def imaging_segments(self) -> dict[str, tuple[float, float]]:
        segs = json.loads(self.custom.get("dpos.imaging_segments", "{}") or "{}")
        start = float(self.custom.get("dpos.start_time_s", self.t0_ns * 1e-9))
        off = start - self.t0_ns * 1e-9
        return {k: (v[0] + off, v[1] + off) for k, v in segs.items()}


def _clean(topic: str, t_ns: NDArray[np.int64], vals: FloatArray, warnings: list[str]) -> tuple[NDArray[np.int64], FloatArray]:
    """Sort, drop duplicates and NaN rows, count gaps; warn about each."""
    t_ns, (vals,) = _clean_groups(topic, t_ns, [vals], warnings)
    return t_ns, vals


def _clean_groups(topic: str, t_ns: NDArray[np.int64], groups: list[FloatArray],
                  warnings: list[str]) -> tuple[NDArray[np.int64], list[FloatArray]]:
    """:func:`_clean` of the rows whose values are the columns of ``groups`` (each (N, m_i)) side by side:
    the same rows kept and the same warnings; arrays without a problem are returned as they are."""
    if t_ns.size == 0:
        return t_ns, groups
    if np.any(np.diff(t_ns) < 0):
        n_bad = int(np.sum(np.diff(t_ns) < 0))
        warnings.append(f"{topic}: {n_bad} message(s) out of stamp order; sorted")
        order = np.argsort(t_ns, kind="stable")
        t_ns, groups = t_ns[order], [g[order] for g in groups]
    dup = np.concatenate([[False], np.diff(t_ns) == 0])
    if dup.any():
        d = dup[1:]
        same = np.all(np.stack([np.all(g[1:][d] == g[:-1][d], axis=1) for g in groups]), axis=0)
        warnings.append(f"{topic}: {int(dup.sum())} duplicate stamp(s) ({int(same.sum())} identical messages) removed; the first of each kept")
        t_ns, groups = t_ns[~dup], [g[~dup] for g in groups]
    bad = np.zeros(t_ns.size, dtype=bool)
    for g in groups:
        bad |= ~np.all(np.isfinite(g), axis=1)
    if bad.any():
        warnings.append(f"{topic}: {int(bad.sum())} sample(s) with NaN/inf removed (first at stamp {int(t_ns[bad][0])} ns)")
        t_ns, groups = t_ns[~bad], [g[~bad] for g in groups]
    if t_ns.size > 2:
        d = np.diff(t_ns)
        med = np.median(d)
        gaps = d > GAP_FACTOR * med
        if gaps.any():
            warnings.append(f"{topic}: {int(gaps.sum())} gap(s) in the stamps, longest {d.max() * 1e-9:.3f} s (nominal step {med * 1e-9:.4f} s)")
    return t_ns, groups


#: sensor_msgs/Imu doubles (cdr.IMU_DOUBLES): angular velocity and linear acceleration covariance diagonals
_IMU_W_COV_DIAG = [16, 20, 24]
_IMU_F_COV_DIAG = [28, 32, 36]


def _decode_rows(topic: str, msgtype: str, blobs: Sequence[bytes], kind: str, warnings: list[str]) -> tuple[NDArray[np.int64], FloatArray]:
    """Stamps (N,) and doubles (N, IMU_DOUBLES | ODOM_DOUBLES) of a topic's messages.

    The topic's frame names are those of most of its messages; a message with other frame names
    (another device publishing on the topic) is rejected, and so is one the relays of
    :mod:`dpos_ros.devices.relay` reject: stamp 0 (``zero_stamp``) and, for Imu, a rate or
    acceleration covariance[0] = -1 (``unavailable``) or a negative variance (``negative_cov``).
    Each kind is counted in a warning naming the topic; the other messages are kept.  A topic
    none of whose messages can be decoded raises :class:`SessionError`."""
    dec = _TopicDecoder(topic, msgtype, kind)
    out = dec.decode(blobs)
    warnings.extend(dec.warnings())
    return out


#: the reasons of :func:`reject_reasons`, in the order of their warnings
_REASONS = ("zero_stamp", "unavailable", "negative_cov")


class _TopicDecoder:
    """:func:`_decode_rows` of one topic's messages handed over a block at a time (the spill read
    in blocks, :func:`read_session`): the frame names are chosen in the first block with
    messages (as :func:`_decode_rows` chooses them in all of them: the names of most of the
    messages at its first, middle and last one) and kept for the next blocks; the rejected
    messages are counted over every block, so :meth:`warnings` are those of one
    :func:`_decode_rows` of all the messages (``sorted_first``: the messages were merged in stamp
    order afterwards, so the first of a kind is the one with the smallest stamp)."""

    def __init__(self, topic: str, msgtype: str, kind: str) -> None:
        self.topic, self.msgtype, self.kind = topic, msgtype, kind
        self.layout: cdr.Layout | None = None
        self.frames = ""
        self.n_in = self.n_keep = 0
        self.rejected: dict[str, list[int]] = {}  # reason -> [count, first stamp, smallest stamp]

    def decode(self, blobs: Sequence[bytes]) -> tuple[NDArray[np.int64], FloatArray]:
        """Stamps and doubles of the block's messages kept (:func:`_decode_rows`)."""
        kind = self.kind
        n_doubles = cdr.IMU_DOUBLES if kind == "imu" else cdr.ODOM_DOUBLES
        empty = np.zeros(0, dtype=np.int64), np.zeros((0, n_doubles))
        if not len(blobs):
            return empty
        msgs = Messages.from_list(blobs)  # (no copy when it is one already)
        sizes = msgs.sizes
        if self.layout is None:
            by_size: dict[int, tuple[NDArray[np.intp], NDArray[np.uint8]]] = {}
            best: tuple[cdr.Layout, str, NDArray[np.uint8], NDArray[np.bool_]] | None = None
            tried: set[tuple[str, str]] = set()
            for i in sorted({0, len(blobs) // 2, len(blobs) - 1}):  # candidate frame names: a stray message is rarely all three
                try:
                    frame, child = cdr.frame_ids(msgs[i], kind)
                    lay = cdr.layout(kind, frame, child)
                except (UnicodeDecodeError, ValueError):
                    continue
                if (frame, child) in tried:  # (the same candidate again: the same count)
                    continue
                tried.add((frame, child))
                if lay.size not in by_size:
                    idx = np.nonzero(sizes == lay.size)[0]
                    by_size[lay.size] = idx, msgs.rows(idx) if idx.size else np.zeros((0, lay.size), dtype=np.uint8)
                rows = by_size[lay.size][1]
                ok = cdr.matches(lay, rows) if rows.shape[0] else np.zeros(0, dtype=bool)
                if best is None or int(ok.sum()) > int(best[3].sum()):
                    best = (lay, frame if kind != "odometry" else f"{frame}' -> '{child}", rows, ok)
            if best is None or not best[3].any():
                raise SessionError(f"{self.topic} ({self.msgtype}): no message has a readable {kind} layout")
            self.layout, self.frames, rows, ok = best
        else:
            lay = self.layout
            idx = np.nonzero(sizes == lay.size)[0]
            rows = msgs.rows(idx) if idx.size else np.zeros((0, lay.size), dtype=np.uint8)
            ok = cdr.matches(lay, rows) if rows.shape[0] else np.zeros(0, dtype=bool)
        n_keep = int(ok.sum())
        self.n_in += len(blobs)
        self.n_keep += n_keep
        if not n_keep:
            return empty
        t_ns, vals = cdr.decode(self.layout, rows if n_keep == len(blobs) else rows[ok], checked=True)
        bad = np.zeros(t_ns.size, dtype=bool)
        for why, mask in reject_reasons(kind, t_ns, vals).items():
            if mask.any():
                t_bad = t_ns[mask]
                rec = self.rejected.setdefault(why, [0, int(t_bad[0]), int(t_bad[0])])
                rec[0] += int(mask.sum())
                rec[2] = min(rec[2], int(t_bad.min()))
                bad |= mask
        return (t_ns[~bad], vals[~bad]) if bad.any() else (t_ns, vals)

    def warnings(self, sorted_first: bool = False) -> list[str]:
        """The warnings of :func:`_decode_rows` about the messages decoded so far."""
        out = []
        if self.n_keep < self.n_in:
            out.append(f"{self.topic}: {self.n_in - self.n_keep} message(s) with other frame names than '{self.frames}' "
                       "(or another type) rejected; the others kept")
        for why in _REASONS:
            if why in self.rejected:
                n, first, smallest = self.rejected[why]
                out.append(f"{self.topic}: {n} message(s) rejected ({why}, first at stamp {smallest if sorted_first else first} ns)")
        return out


def reject_reasons(kind: str, t_ns: NDArray[np.int64], vals: FloatArray) -> dict[str, NDArray[np.bool_]]:
    """The relays' checks (:mod:`dpos_ros.devices.relay`) on decoded messages: ``{reason: mask (N,)}``,
    each message under its first reason only: ``zero_stamp`` and, for ``imu`` (vals (N, IMU_DOUBLES)),
    ``unavailable`` (rate or acceleration covariance[0] = -1) and ``negative_cov``.  (NaN rows are
    removed later, by the cleaning, with their own count.)"""
    reasons = {"zero_stamp": t_ns == 0}
    if kind == "imu":
        reasons["unavailable"] = (vals[:, _IMU_W_COV_DIAG[0]] == -1.0) | (vals[:, _IMU_F_COV_DIAG[0]] == -1.0)
        reasons["negative_cov"] = np.any(vals[:, _IMU_W_COV_DIAG + _IMU_F_COV_DIAG] < 0.0, axis=1)
    taken = np.zeros(t_ns.size, dtype=bool)
    for why in reasons:
        reasons[why] = reasons[why] & ~taken
        taken |= reasons[why]
    return reasons


def _read_whole(path: Path, include_late: bool = True, keep: Callable[[str], bool] | None = None) -> RecordedSession:
    """:func:`read_session` of a recording read whole, every message in memory at once: the
    recordings the part-at-a-time reader does not read (sqlite3, several files, without metadata),
    and the reference its tests compare it with.  A spill: with its late messages unless
    ``include_late`` is False (:func:`dpos_ros.io.spill.read_spill`).  ``keep``: read only the
    topics it accepts (/master/nav and /dpos/datum are always read)."""
    if keep is not None:
        only = keep
        keep = lambda t: t in (T.MASTER_NAV, T.DATUM, T.SESSION_END, T.POS_MASTER_STATUS) or only(t)  # noqa: E731
    path = Path(path)
    if S.is_spill(path):  # the crash-safe spill of transfer_align_node
        skipped: dict[str, int] = {}
        try:
            raw, custom, sid, warns = S.read_spill(path, include_late, keep, skipped)
        except (ValueError, OSError) as e:
            raise SessionError(f"{path}: cannot read the spill: {e}") from None
        custom.setdefault("dpos.session_id", sid)
        sess = session_from_raw(raw, custom, path)
        sess.warnings[:0] = warns
        _count_lost(sess, spill_bytes=sum(skipped.values()))  # as the streamed reading counts them
        return sess
    if not (path / "metadata.yaml").is_file() and not any(path.glob("*.mcap")):
        raise SessionError(f"{path}: not a rosbag2 directory (no metadata.yaml) nor a dpos spill (no spill.json)")
    notes = _mcap.Notes()
    try:
        raw = bag.read_raw(path, keep, notes=notes)  # a recording without metadata is recovered (noted)
        meta_path, _ = bag.readable_bag(path)
    except Exception as e:  # rosbags raises its own errors for truncated or broken files
        raise SessionError(f"{path}: cannot read the recording: {e}") from None
    custom = bag.custom_data(meta_path)
    sess = session_from_raw(raw, custom, path)
    sess.warnings[:0] = notes
    _count_lost(sess, notes.lost_messages + int(custom.get(bag.RECOVERY_LOST_KEY, "0") or 0))
    return sess


def _count_lost(sess: RecordedSession, messages: int = 0, spill_bytes: int = 0) -> None:
    """Add what could not be read to ``sess.data_lost`` (only what is not zero)."""
    for key, n in (("messages", messages), ("spill_bytes_skipped", spill_bytes)):
        if n:
            sess.data_lost[key] = sess.data_lost.get(key, 0) + int(n)


def session_from_streams(streams, custom: dict[str, str], name: str = "memory") -> RecordedSession:
    """The same reader over in-memory streams (dpos-eval simulates without writing a bag)."""
    raw = {s.topic: RawTopic(s.msgtype, np.asarray(s.t_ns, dtype=np.int64).tolist(),
                             Messages.from_rows(s.rows) if s.rows is not None else Messages.from_list(s.blobs or ()))
           for s in streams}
    return session_from_raw(raw, custom, Path(name))


def session_from_raw(raw: dict, custom: dict[str, str], path: Path) -> RecordedSession:
    warnings: list[str] = []
    if T.MASTER_NAV not in raw or not raw[T.MASTER_NAV][2]:
        raise SessionError(f"{path}: no /master/nav messages: the transfer alignment needs the main-system navigation")
    # datum: the latched /dpos/datum, else the first master position
    if T.DATUM in raw and raw[T.DATUM][2]:
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import NavSatFix

        datum = cv.datum_from_msg(deserialize_message(raw[T.DATUM][2][0], NavSatFix))
    else:
        raise SessionError(f"{path}: no /dpos/datum: the enu frame of /master/nav is undefined")
    t_nav, v_nav = _decode_rows(T.MASTER_NAV, raw[T.MASTER_NAV][0], raw[T.MASTER_NAV][2], "odometry", warnings)
    t_nav, v_nav = _clean(T.MASTER_NAV, t_nav, v_nav, warnings)
    if t_nav.size == 0:
        raise SessionError(f"{path}: no usable /master/nav message: the transfer alignment needs the main-system navigation")
    t0_ns = int(round(float(custom["dpos.start_time_s"]) * 1e9)) if "dpos.start_time_s" in custom else int(t_nav[0])
    od = cv.odometry_from_values(t_nav, v_nav, datum)
    # covariances: the message's are in the enu (datum) frame (pose) and the body (twist); the model wants local ENU
    pos_cov, att_cov, vel_cov = cv.odometry_cov_n(od, datum)
    ts = lambda t: (t - t0_ns) * 1e-9  # noqa: E731
    master = NavSeries(ts(t_nav), od.q_nb, od.vel_n_mps, od.llh, omega_eb_b_radps=od.omega_b_radps,
                       att_cov=att_cov, vel_cov=vel_cov, pos_cov=pos_cov)

    subs: dict[str, ImuSeries] = {}
    truth: dict[str, NavSeries] = {}
    for topic, (msgtype, _, blobs) in sorted(raw.items()):
        parts = topic.strip("/").split("/")
        is_imu = len(parts) == 3 and parts[0] == "sub_imu" and parts[2] == "imu"
        if not is_imu and not (parts[0] == "truth" and msgtype == T.ODOMETRY):
            continue
        try:  # one topic's problem costs that topic only
            t, v = _clean(topic, *_decode_rows(topic, msgtype, blobs, "imu" if is_imu else "odometry", warnings), warnings)
        except SessionError as e:
            warnings.append(f"{e}; the topic is ignored")
            continue
        if is_imu:
            blk = cv.imu_from_values(t, v)
            subs[parts[1]] = ImuSeries(ts(t), blk.omega_radps, blk.f_mps2)
        else:
            o = cv.odometry_from_values(t, v, datum)
            truth["/".join(parts[1:])] = NavSeries(ts(t), o.q_nb, o.vel_n_mps, o.llh)
    end_s = None
    if T.SESSION_END in raw and raw[T.SESSION_END][1]:
        end_s = ts(max(raw[T.SESSION_END][1]))
    sid = custom.get("dpos.session_id") or path.name
    return RecordedSession(path, sid, t0_ns, datum, master, subs, truth, custom, end_s, warnings,
                           master_mechanized=master_is_mechanized(custom, raw))


#: bytes of raw messages decoded at a time by :func:`read_session`
STREAM_BATCH_BYTES = 2**24


def read_session(path: Path, include_late: bool = True, keep: Callable[[str], bool] | None = None,
                 batch_bytes: int = STREAM_BATCH_BYTES) -> RecordedSession:
    """A recording or a spill as a :class:`RecordedSession` (:func:`_read_session`), refused with a
    SessionError in one line when its values show a unit or installation mistake
    (:func:`check_plausible`)."""
    return check_plausible(_read_session(path, include_late, keep, batch_bytes))


#: /master/nav's 90th percentile body rate that shows the aircraft turned (its rates are smooth) [rad/s]
MASTER_TURN_RADPS = 1.0 * np.pi / 180.0


def check_plausible(sess: RecordedSession) -> RecordedSession:
    """``sess``, or a SessionError naming the first gross mistake (dpos_core.plausibility): a
    sub-IMU in g or deg/s read as m/s^2 or rad/s (and the reverse), a datum far from the first
    main-system position."""
    found = [f for name, s in sess.sub_imus.items() for f in plausibility.check_imu(f"{sess.path}: sub-IMU {name}", s.t_s, s.omega_radps, s.f_mps2)]
    if sess.master.omega_eb_b_radps is not None:
        ref = np.linalg.norm(sess.master.omega_eb_b_radps, axis=1)
        for name, s in sess.sub_imus.items():
            if s.t_s.size == 0:
                continue
            span = (sess.master.t_s >= s.t_s[0]) & (sess.master.t_s <= s.t_s[-1])  # the same part of the flight
            scale = plausibility.check_rate_scale(f"{sess.path}: sub-IMU {name}", s.omega_radps, ref[span],
                                                  "/master/nav's body rates", min_turn_radps=MASTER_TURN_RADPS)
            found += [scale] if scale is not None else []
    llh = sess.master.llh
    if llh.shape[0]:
        d = plausibility.check_datum(f"{sess.path}: /dpos/datum", float(sess.datum_llh[0]), float(sess.datum_llh[1]),
                                     float(llh[0, 0]), float(llh[0, 1]))
        found += [d] if d is not None else []
    if found:
        raise SessionError(str(found[0]))
    return sess


def _read_session(path: Path, include_late: bool = True, keep: Callable[[str], bool] | None = None,
                  batch_bytes: int = STREAM_BATCH_BYTES) -> RecordedSession:
    """Read a recording made by dpos-sim, dpos-record or the graph, or a spill of
    transfer_align_node (see module docstring), with memory for one part of it: ``keep``: read
    only the topics it accepts (/master/nav and /dpos/datum are always read); ``include_late``: a
    spill's late messages too.  The file is read ``batch_bytes`` of messages at a time (MCAP:
    :func:`dpos_ros.io._mcap.read_batches`; a spill: each wanted topic's log file alone,
    :class:`dpos_ros.io.spill.LogBlocks`), each part's messages decoded and converted at once,
    and only the series kept (the sub-IMU's 7 numbers a sample instead of its ~330 bytes of CDR
    and 43 decoded doubles).  The same series as reading it whole (:func:`_read_whole`); the data
    checks are the same.  MCAP: a problem found in several parts is warned about once per part, and
    duplicates are told identical by the kept numbers.  A spill: the same warnings as reading it
    whole (the rejections counted over the parts, duplicates told identical by a hash of all their
    numbers), except that a topic's frame names are chosen in its first part
    (:class:`_TopicDecoder`).  Recordings the part-at-a-time reader does not read (sqlite3, several
    files, without metadata) are read whole (:func:`_read_whole`)."""
    path = Path(path)
    if S.is_spill(path):
        return _read_spill_streaming(path, keep, batch_bytes, include_late)
    if not (path / "metadata.yaml").is_file():
        return _read_whole(path, include_late, keep)
    file = bag._single_mcap(path)
    if file is not None and _mcap.damage(file) is not None:
        return _read_whole(path, include_late, keep)  # recovered from its start first (bag.readable_bag)
    wanted = (lambda t: t not in (T.DATUM, T.SESSION_END, T.POS_MASTER_STATUS)) if keep is None else \
        (lambda t: t == T.MASTER_NAV or (t not in (T.DATUM, T.SESSION_END, T.POS_MASTER_STATUS) and keep(t)))  # noqa: E731
    lost = _mcap.Notes()  # the chunks skipped (corrupt), said once each and counted
    parts = None if file is None else _mcap.read_batches(file, wanted, batch_bytes, lost)
    if parts is None:
        return _read_whole(path, include_late, keep)
    custom = bag.custom_data(path)
    try:
        small = bag.read_raw(path, [T.DATUM, T.SESSION_END, T.POS_MASTER_STATUS], notes=lost)  # (only the chunks that hold them)
    except (ValueError, OSError) as e:  # a file that cannot be read at all
        raise SessionError(f"{path}: cannot read the recording: {e}") from None
    if T.DATUM not in small or not small[T.DATUM][2]:
        raise SessionError(f"{path}: no /dpos/datum: the enu frame of /master/nav is undefined")
    datum = _datum(small[T.DATUM][2][0])
    warnings: list[str] = lost
    counts = message_counts(path)
    acc: dict[str, _Rows] = {}  # topic -> its stamps and numbers so far
    failed: set[str] = set()
    try:
        _read_parts(parts, acc, failed, counts, datum, warnings)
    except SessionError:
        raise
    except (ValueError, OSError) as e:  # a chunk that cannot be decompressed or parsed, a file cut short
        raise SessionError(f"{path}: cannot read the recording: {e}") from None
    for topic in failed:
        acc.pop(topic, None)
    if T.MASTER_NAV not in acc:
        raise SessionError(f"{path}: no /master/nav messages: the transfer alignment needs the main-system navigation")
    cols: dict[str, tuple[NDArray[np.int64], FloatArray | list[FloatArray]]] = {}
    for topic in sorted(acc):
        cols[topic] = _clean_groups(topic, *acc.pop(topic).arrays(), warnings)
    sess = _session_from_cols(path, custom, datum, cols, small, warnings)
    _count_lost(sess, lost.lost_messages)
    return sess



def _read_parts(parts, acc: dict[str, _Rows], failed: set[str], counts: dict[str, int], datum: FloatArray,
                warnings: list[str]) -> None:
    """:func:`read_session`'s parts of an MCAP file decoded into ``acc`` (topic -> its rows so far;
    a topic that cannot be decoded is warned about and put in ``failed``)."""
    for part in parts:
        for topic, (msgtype, _, blobs) in part.items():
            kind = _kind(topic, msgtype)
            if kind is None or topic in failed or not len(blobs):
                continue
            try:
                t, v = _decode_rows(topic, msgtype, blobs, "odometry" if kind != "imu" else "imu", warnings)
            except SessionError as e:
                if topic == T.MASTER_NAV:
                    raise
                warnings.append(f"{e}; the topic is ignored")
                failed.add(topic)
                continue
            if topic not in acc:
                acc[topic] = _Rows(_GROUPS[kind], counts.get(topic, 0))
            acc[topic].append(t, _compact(kind, t, v, datum))


def _datum(blob: bytes) -> FloatArray:
    """The datum (lat, lon [rad], h [m]) of a /dpos/datum message."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import NavSatFix

    return cv.datum_from_msg(deserialize_message(blob, NavSatFix))


def _groups(topic: str, v: FloatArray | list[FloatArray]) -> list[FloatArray]:
    """A topic's :func:`_compact` rows (N, m) as the arrays of its column groups (:data:`_GROUPS`),
    copied; groups already are returned as they are."""
    if isinstance(v, list):
        return v
    kind = "master" if topic == T.MASTER_NAV else "imu" if _kind(topic, T.IMU) == "imu" else "truth"
    edges = np.concatenate([[0], np.cumsum(_GROUPS[kind])]).astype(int)
    return [v[:, a:b].copy() for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _session_from_cols(path: Path, custom: dict[str, str], datum: FloatArray,
                       cols: dict[str, tuple[NDArray[np.int64], FloatArray | list[FloatArray]]],
                       small: dict, warnings: list[str]) -> RecordedSession:
    """The session of the cleaned compact rows ``cols`` (topic -> stamps, :func:`_compact` rows or
    the arrays of their column groups, :data:`_GROUPS`; /master/nav among them) and ``small`` (the raw
    /session/end and /pos_master/status, when recorded)."""
    t_nav, m_rows = cols.pop(T.MASTER_NAV)
    llh, vel, q, w, c_att, c_vel, c_pos, _ = _groups(T.MASTER_NAV, m_rows)
    if t_nav.size == 0:
        raise SessionError(f"{path}: no usable /master/nav message: the transfer alignment needs the main-system navigation")
    t0_ns = int(round(float(custom["dpos.start_time_s"]) * 1e9)) if "dpos.start_time_s" in custom else int(t_nav[0])
    ts_ = lambda t: (t - t0_ns) * 1e-9  # noqa: E731
    n = t_nav.size
    master = NavSeries(ts_(t_nav), q, vel, llh, omega_eb_b_radps=w, att_cov=c_att.reshape(n, 3, 3), vel_cov=c_vel.reshape(n, 3, 3),
                       pos_cov=c_pos.reshape(n, 3, 3))
    subs: dict[str, ImuSeries] = {}
    truth: dict[str, NavSeries] = {}
    for topic, (t, v) in cols.items():
        parts_ = topic.strip("/").split("/")
        g = _groups(topic, v)
        if _kind(topic, T.IMU) == "imu":
            subs[parts_[1]] = ImuSeries(ts_(t), g[0], g[1])
        else:
            truth["/".join(parts_[1:])] = NavSeries(ts_(t), g[2], g[1], g[0])
    end_s = None
    if T.SESSION_END in small and small[T.SESSION_END][1]:
        end_s = ts_(max(small[T.SESSION_END][1]))
    sid = custom.get("dpos.session_id") or path.name
    return RecordedSession(path, sid, t0_ns, datum, master, subs, truth, custom, end_s, warnings,
                           master_mechanized=master_is_mechanized(custom, small))


def _row_hash(v: FloatArray) -> FloatArray:
    """(N,) a 53-bit hash of each row of ``v`` as an exact, finite float (FNV-1a over the rows'
    doubles, -0.0 taken as 0.0): two rows equal number for number hash alike."""
    b = np.ascontiguousarray(v + 0.0).view(np.uint64)
    h = np.full(b.shape[0], 0xCBF29CE484222325, dtype=np.uint64)
    prime = np.uint64(0x100000001B3)
    for j in range(b.shape[1]):
        h = (h ^ b[:, j]) * prime
    return (h >> np.uint64(11)).astype(np.float64)


def _read_spill_streaming(path: Path, keep: Callable[[str], bool] | None, batch_bytes: int, include_late: bool) -> RecordedSession:
    """:func:`read_session` of a spill (its docstring): each wanted topic's log (and its
    late log) read a block at a time, the topics one after the other."""
    try:
        topics, custom, sid = S.spill_meta(path)
        late_dir = path / S.LATE_DIR
        late = S.spill_meta(late_dir)[0] if include_late and S.is_spill(late_dir) else {}
    except (ValueError, OSError) as e:
        raise SessionError(f"{path}: cannot read the spill: {e}") from None
    custom.setdefault("dpos.session_id", sid)
    small_topics = (T.MASTER_NAV, T.DATUM, T.SESSION_END, T.POS_MASTER_STATUS)
    wanted = [t for t in dict.fromkeys([*topics, *late]) if keep is None or t in small_topics or keep(t)]
    cut: dict[tuple[int, str, int], str] = {}  # (0 the spill | 1 late/, topic, 0 skipped | 1 cut short) -> its warning
    n_late: dict[str, int] = {}
    skipped_bytes: dict[tuple[int, str], int] = {}

    def blocks(topic: str):
        """(stamps, messages) of ``topic``'s log then its late log, a block at a time."""
        for which, (src, prefix) in enumerate(((topics, ""), (late, f"{S.LATE_DIR}/"))):
            if topic not in src:
                continue
            reader = S.LogBlocks(src[topic][1], batch_bytes)
            yield from reader
            if reader.skipped:  # (a corrupt record size: the reading resynchronized)
                skipped_bytes[(which, topic)] = sum(n for _, n in reader.skipped)
                cut[(which, topic, 0)] = prefix + S.skipped_warning(topic, src[topic][1], reader.skipped)
            if reader.cut_short:
                cut[(which, topic, 1)] = prefix + S.cut_short_warning(topic, src[topic][1], reader.cut_short)
            if which == 1 and reader.count:
                n_late[topic] = reader.count

    def msgtype(topic: str) -> str:
        return topics[topic][0] if topic in topics else late[topic][0]

    try:
        small: dict[str, RawTopic] = {}  # the datum, the session's end, the main POS's status: whole
        for topic in wanted:
            if topic in small_topics[1:]:
                parts = list(blocks(topic))
                t_all = np.concatenate([t for t, _ in parts]) if parts else np.zeros(0, dtype=np.int64)
                msgs = Messages.concat([m for _, m in parts]) if parts else Messages.from_list([])
                if n_late.get(topic) and topic in topics:  # merged in stamp order (read_spill)
                    order = np.argsort(t_all, kind="stable")
                    t_all, msgs = t_all[order], msgs.take(order)
                small[topic] = RawTopic(msgtype(topic), t_all.tolist(), msgs)
        if T.MASTER_NAV not in wanted or not any(len(m) for _, m in blocks(T.MASTER_NAV)):
            raise SessionError(f"{path}: no /master/nav messages: the transfer alignment needs the main-system navigation")
        if T.DATUM not in small or not small[T.DATUM][2]:
            raise SessionError(f"{path}: no /dpos/datum: the enu frame of /master/nav is undefined")
        datum = _datum(small[T.DATUM][2][0])
        warnings: list[str] = []
        cols: dict[str, tuple[NDArray[np.int64], FloatArray | list[FloatArray]]] = {}
        for topic in [T.MASTER_NAV, *sorted(t for t in wanted if t != T.MASTER_NAV)]:  # session_from_raw's order
            kind = _kind(topic, msgtype(topic))
            if kind is None:
                if topic not in small:
                    for _ in blocks(topic):  # (read for its checks only: a cut-short record, late messages)
                        pass
                continue
            dec = _TopicDecoder(topic, msgtype(topic), "odometry" if kind != "imu" else "imu")
            ts: list[NDArray[np.int64]] = []
            rows: list[FloatArray] = []
            try:
                for _, m_b in blocks(topic):
                    t, v = dec.decode(m_b)
                    if not t.size:
                        continue
                    ts.append(t)
                    rows.append(np.hstack([_compact(kind, t, v, datum), _row_hash(v)[:, None]]))
            except SessionError as e:
                if topic == T.MASTER_NAV:
                    raise
                warnings.append(f"{e}; the topic is ignored")
                for _ in blocks(topic):  # (its checks, as read_spill reads it whole)
                    pass
                continue
            merged = bool(n_late.get(topic)) and topic in topics
            warnings.extend(dec.warnings(sorted_first=merged))
            n_cols = (7 if kind == "imu" else 11 if kind == "truth" else 41) + 1
            t_all = np.concatenate(ts) if ts else np.zeros(0, dtype=np.int64)
            v_all = np.concatenate(rows) if rows else np.zeros((0, n_cols))
            del ts, rows
            if merged:  # the late messages merged in stamp order (read_spill)
                order = np.argsort(t_all, kind="stable")
                t_all, v_all = t_all[order], v_all[order]
            cols[topic] = _clean(topic, t_all, v_all, warnings)
    except OSError as e:
        raise SessionError(f"{path}: cannot read the spill: {e}") from None
    notes = [cut[k] for k in sorted(cut, key=lambda k: (k[0], list((topics, late)[k[0]]).index(k[1]), k[2]))]
    notes += [S.late_note(t, n_late[t]) for t in late if t in n_late]
    sess = _session_from_cols(path, custom, datum, cols, small, warnings)
    sess.warnings[:0] = notes
    _count_lost(sess, spill_bytes=sum(skipped_bytes.values()))
    return sess


#: the column groups of :func:`_compact`'s rows per kind (each group one array of the series; the
#: last, a NaN flag, is for the cleaning only)
_GROUPS = {"imu": (3, 3, 1), "truth": (3, 3, 4, 1), "master": (3, 3, 4, 3, 9, 9, 9, 1)}


class _Rows:
    """A topic's stamps and numbers read so far, one array per column group (``widths``), appended a
    part at a time into arrays of ``capacity`` rows (the recording's message count: the whole is never
    held twice nor copied to its series; grown by half when more messages come)."""

    def __init__(self, widths: tuple[int, ...], capacity: int) -> None:
        self.n = 0
        self.t = np.empty(max(capacity, 0), dtype=np.int64)
        self.groups = [np.empty((max(capacity, 0), w)) for w in widths]
        self._edges = np.concatenate([[0], np.cumsum(widths)]).astype(int)

    def append(self, t: NDArray[np.int64], rows: FloatArray) -> None:
        """Rows (m, sum of the widths) stamped t (m,)."""
        need = self.n + t.size
        if need > self.t.size:
            cap = max(need, self.t.size + self.t.size // 2)
            self.t = np.concatenate([self.t[:self.n], np.empty(cap - self.n, dtype=np.int64)])
            self.groups = [np.concatenate([g[:self.n], np.empty((cap - self.n, g.shape[1]))]) for g in self.groups]
        self.t[self.n:need] = t
        for g, a, b in zip(self.groups, self._edges[:-1], self._edges[1:], strict=True):
            g[self.n:need] = rows[:, a:b]
        self.n = need

    def arrays(self) -> tuple[NDArray[np.int64], list[FloatArray]]:
        """The stamps (n,) and the groups (n, width) read (views)."""
        return self.t[:self.n], [g[:self.n] for g in self.groups]


def message_counts(path: Path) -> dict[str, int]:
    """The message count per topic that the rosbag2 metadata of ``path`` lists ({} without one)."""
    try:
        info = bag.bag_info(path)
        return {str(t["topic_metadata"]["name"]): int(t.get("message_count") or 0) for t in info.get("topics_with_message_count") or []}
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return {}


def _kind(topic: str, msgtype: str) -> str | None:
    """``imu`` for /sub_imu/<name>/imu, ``master`` for /master/nav, ``truth`` for /truth/* odometry, else None."""
    if topic == T.MASTER_NAV:
        return "master"
    parts = topic.strip("/").split("/")
    if len(parts) == 3 and parts[0] == "sub_imu" and parts[2] == "imu":
        return "imu"
    if parts[0] == "truth" and msgtype == T.ODOMETRY:
        return "truth"
    return None


def _compact(kind: str, t: NDArray[np.int64], v: FloatArray, datum: FloatArray) -> FloatArray:
    """The numbers kept of decoded messages (N, IMU_DOUBLES | ODOM_DOUBLES), with a last column NaN
    where a message has a NaN or infinite number (so the cleaning drops it as :func:`read_session` does):
    ``imu`` omega (3), f (3); ``truth`` llh, vel, q; ``master`` those, the body rate and the
    attitude, velocity and position covariances (local ENU, as :func:`session_from_raw`)."""
    bad = np.where(np.all(np.isfinite(v), axis=1), 0.0, np.nan)[:, None]
    if kind == "imu":
        blk = cv.imu_from_values(t, v)
        return np.hstack([blk.omega_radps, blk.f_mps2, bad])
    with np.errstate(invalid="ignore"):
        od = cv.odometry_from_values(t, v, datum)
        if kind == "truth":
            return np.hstack([od.llh, od.vel_n_mps, od.q_nb, bad])
        pos_cov, att_cov, vel_cov = cv.odometry_cov_n(od, datum)
    n = t.size
    return np.hstack([od.llh, od.vel_n_mps, od.q_nb, od.omega_b_radps, att_cov.reshape(n, 9), vel_cov.reshape(n, 9),
                      pos_cov.reshape(n, 9), bad])
