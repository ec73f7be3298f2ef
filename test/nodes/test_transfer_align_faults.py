"""transfer_align_node under faults and bad input (issue "faults and bad input"), in-process: the
subscription callbacks are called directly with the sample bag's serialized messages (no DDS
timing) and the smoothers run in threads; every wait is bounded.

* a second session on a running node (same stamps: a replay), the datum latched only once: both
  sessions are processed, each with the datum;
* stray messages on a sub-IMU topic (another frame_id, stamp 0, covariance[0] = -1): rejected and
  counted, both wings estimated;
* messages of a closed session that arrive late: kept in ``<spill>/late``, counted in the status
  and in status.json; ``dpos-process`` on the spill uses them;
* a disk that refuses the spill: messages held in memory, status ERROR, written out when the
  disk takes them again; the spill equals what arrived;
* an output_dir that cannot be written: the node refuses to start, naming it.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from ta_inprocess import TOPICS, bag_messages, finalize, make_node, stamp_ns, status  # test/support/ta_inprocess.py

from dpos_ros.contract import topics as T
from dpos_ros.io import spill
from dpos_ros.io.session import read_session

pytestmark = pytest.mark.ros

SECONDS = 25.0


@pytest.fixture(scope="module")
def msgs() -> dict[str, tuple[str, list[bytes]]]:
    return bag_messages(SECONDS)


@pytest.fixture
def node(ros_context, tmp_path: Path, monkeypatch):
    nodes = []

    def make(**params: Any):
        nodes.append(make_node(ros_context, tmp_path / "out", monkeypatch, **params))
        return nodes[-1]

    yield make
    for n in nodes:
        n.destroy_node()


def _feed(ta, msgs, topics=TOPICS, upto_ns: int | None = None, after_ns: int | None = None) -> int:
    n = 0
    for topic in topics:
        for d in msgs[topic][1]:
            t = stamp_ns(d)
            if topic != T.DATUM and ((upto_ns is not None and t > upto_ns) or (after_ns is not None and t <= after_ns)):
                continue
            ta.cbs[topic](d)
            n += 1
    return n


def _end(msgs) -> int:
    return max(stamp_ns(d) for d in msgs[T.MASTER_NAV][1])


def test_second_session_with_the_same_stamps_and_a_datum_latched_once(node, msgs, tmp_path: Path) -> None:
    ta = node()
    _feed(ta, msgs)
    finalize(ta, _end(msgs), "first")
    _feed(ta, msgs, topics=TOPICS[1:])  # the replay: same stamps, the datum is not sent again
    with ta._lock:
        counts = {t: s.count for t, s in ta._streams.items()}
    assert counts[T.MASTER_NAV] == len(msgs[T.MASTER_NAV][1]) and counts[T.DATUM] == 1, counts
    finalize(ta, _end(msgs), "second")
    _feed(ta, msgs, topics=TOPICS[1:])  # and again, under a session id that has products already
    finalize(ta, _end(msgs), "second")
    for sid in ("first", "second", "second_2"):
        st = json.loads((tmp_path / "out" / sid / "status.json").read_text())
        assert st["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}, st
        assert len(st["warnings"]) == len(set(st["warnings"])), st["warnings"]
    a = np.loadtxt(tmp_path / "out" / "first" / "ant_r.csv", delimiter=",", skiprows=2)
    b = np.loadtxt(tmp_path / "out" / "second" / "ant_r.csv", delimiter=",", skiprows=2)
    assert a.shape == b.shape and np.allclose(a, b)  # the same data give the same poses
    s = status(ta)
    assert s["sessions_done"] == "3" and not any(k.endswith("late_after_finalize") for k in s), s


def test_mid_flight_finalize_leaves_the_rest_of_the_flight_processable(node, msgs, tmp_path: Path) -> None:
    ta = node()
    t0 = stamp_ns(msgs[T.MASTER_NAV][1][0])
    mid = t0 + 12_000_000_000
    _feed(ta, msgs, upto_ns=mid)
    finalize(ta, mid, "part1")
    _feed(ta, msgs, topics=TOPICS[1:], after_ns=mid)
    finalize(ta, _end(msgs), "part2")
    for sid, dur in (("part1", 12.0), ("part2", SECONDS - 12.0)):
        st = json.loads((tmp_path / "out" / sid / "status.json").read_text())
        assert st["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}, (sid, st)
        t = np.loadtxt(tmp_path / "out" / sid / "ant_l.csv", delimiter=",", skiprows=2, usecols=0)
        assert t[-1] - t[0] > dur - 1.5, (sid, t[0], t[-1])


def _restamp(d: bytes, t_ns: int) -> bytes:
    b = bytearray(d)
    b[4:8] = int(t_ns // 1_000_000_000).to_bytes(4, "little", signed=True)
    b[8:12] = int(t_ns % 1_000_000_000).to_bytes(4, "little")
    return bytes(b)


def _reframe(d: bytes, frame: str) -> bytes:
    """The same Imu with another frame_id (a stray device on the topic)."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu

    m = deserialize_message(d, Imu)
    m.header.frame_id = frame
    return bytes(serialize_message(m))


def _cov_unavailable(d: bytes) -> bytes:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu

    m = deserialize_message(d, Imu)
    m.angular_velocity_covariance[0] = -1.0
    return bytes(serialize_message(m))


def test_stray_messages_are_rejected_and_counted_and_both_wings_estimated(node, msgs, tmp_path: Path) -> None:
    ta = node()
    topic = T.sub_imu("sub_r")
    good = msgs[topic][1]
    strays = [_reframe(good[100 + 40 * i], "stray_imu") for i in range(5)]
    strays += [_restamp(good[400], 0), _cov_unavailable(good[500])]
    bad_msgs = dict(msgs)
    bad_msgs[topic] = (msgs[topic][0], good[:300] + strays + good[300:])
    _feed(ta, bad_msgs)
    s = status(ta)
    assert s[f"{topic}/rejected"] == "7" and s["level"] >= 1, s
    assert (s[f"{topic}/rejected/frame"], s[f"{topic}/rejected/zero_stamp"], s[f"{topic}/rejected/unavailable"]) == ("5", "1", "1"), s
    finalize(ta, _end(msgs), "strays")
    st = json.loads((tmp_path / "out" / "strays" / "status.json").read_text())
    assert st["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}, st
    w = " | ".join(st["warnings"])
    assert "5 message(s) with other frame names than 'sub_imu_sub_r'" in w, w
    assert "1 message(s) rejected (zero_stamp" in w and "1 message(s) rejected (unavailable" in w, w
    # no good sample lost: the reader keeps every good message of the topic
    sess = read_session(tmp_path / "out" / "spill" / next(p.name for p in (tmp_path / "out" / "spill").iterdir()))
    assert sess.sub_imus["sub_r"].t_s.size == len(good)


def test_late_messages_are_kept_counted_and_used_by_a_rerun(node, msgs, tmp_path: Path) -> None:
    ta = node()
    topic = T.sub_imu("sub_l")
    end = _end(msgs)
    cut = end - 3_000_000_000  # sub_l's device lags: its last 3 s arrive after the session closed
    _feed(ta, msgs, topics=[T.DATUM, T.MASTER_NAV, T.sub_imu("sub_r")])
    _feed(ta, msgs, topics=[topic], upto_ns=cut)
    finalize(ta, end, "lagging")
    n_late = _feed(ta, msgs, topics=[topic], after_ns=cut)
    assert n_late > 250
    s = status(ta)
    assert s[f"{topic}/late_after_finalize"] == str(n_late) and s["level"] >= 1, s
    with ta._lock:
        assert not ta._streams  # late messages do not open a new session
    spill_dir = ta._closed.spill_dir
    ta._closed.close()
    st = json.loads((tmp_path / "out" / "lagging" / "status.json").read_text())
    assert st["late_after_close"]["messages"] == {topic: n_late} and st["late_after_close"]["used"] is False, st
    full = read_session(spill_dir)
    own = read_session(spill_dir, include_late=False)
    assert full.sub_imus["sub_l"].t_s.size == own.sub_imus["sub_l"].t_s.size + n_late == len(msgs[topic][1])
    assert any(f"{n_late} message(s) arrived after the session was closed" in w for w in full.warnings), full.warnings


def test_disk_that_refuses_the_spill_holds_in_memory_and_loses_nothing(node, msgs, tmp_path: Path, monkeypatch) -> None:
    ta = node()
    real_write = spill.SpillWriter.write
    state = {"full": False, "refused": 0}

    def write(self, topic, msgtype, t_ns, data):
        if state["full"]:
            state["refused"] += 1
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, topic, msgtype, t_ns, data)

    monkeypatch.setattr(spill.SpillWriter, "write", write)
    nav = msgs[T.MASTER_NAV][1]
    _feed(ta, {T.DATUM: msgs[T.DATUM], T.MASTER_NAV: (T.ODOMETRY, nav[:500])}, topics=[T.DATUM, T.MASTER_NAV])
    state["full"] = True
    for d in nav[500:1500]:
        ta.cbs[T.MASTER_NAV](d)
    s = status(ta)
    assert s["level"] == 2 and s["held_in_memory"] == "1000" and s["lost"] == "0" and "No space" in s["disk_error"], s
    assert "disk" in s["last_error"], s
    assert state["refused"] < 20  # retried at most once a second, not once per message
    state["full"] = False
    for d in nav[1500:]:
        ta.cbs[T.MASTER_NAV](d)
    s = status(ta)
    assert s["level"] == 0 and "held_in_memory" not in s, s
    sp = ta._spill
    sp.writer.close()
    raw, _, _, warns = spill.read_spill(sp.writer.dir)
    assert raw[T.MASTER_NAV][2] == nav and not warns  # every message, in order, byte for byte


def test_disk_bound_counts_what_is_lost(node, msgs, monkeypatch) -> None:
    ta = node(disk_full_buffer_mb=0.1, finalize_timeout_s=0.5)  # (the shutdown gives the disk 0.5 s)
    monkeypatch.setattr(spill.SpillWriter, "write", lambda *a: (_ for _ in ()).throw(OSError(errno.EROFS, "Read-only file system")))
    nav = msgs[T.MASTER_NAV][1]
    for d in nav[:1000]:
        ta.cbs[T.MASTER_NAV](d)
    s = status(ta)
    held = int(s["held_in_memory"])
    assert s["level"] == 2 and held + int(s["lost"]) == 1000 and held * len(nav[0]) <= 100_000 < (held + 1) * len(nav[0]), s
    assert "Read-only" in s["disk_error"] and "lost past disk_full_buffer_mb" in s["last_error"], s


def test_unwritable_output_dir_is_refused_at_start(ros_context, tmp_path: Path) -> None:
    from dpos_ros.runtime.params import ParameterError
    from transfer_align_node.node import TransferAlignNode

    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    with pytest.raises(ParameterError, match=r"output_dir.*not writable"):
        TransferAlignNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(blocker / "out"))])
