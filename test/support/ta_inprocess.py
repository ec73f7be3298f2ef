"""transfer_align_node in-process, for the node tests that call its subscription callbacks directly with
the sample bag's serialized messages (no DDS timing; test_transfer_align_faults.py, test_gates_datum.py).

:func:`bag_messages`: the first seconds of the sample bag's datum, main POS and sub-IMUs;
:func:`make_node`: a node whose smoothers run in threads, its status published to a :class:`StatusTap`
and its callbacks in ``node.cbs``; :func:`stamp_ns`: a serialized message's header stamp.
"""

from __future__ import annotations

import concurrent.futures as cf
from pathlib import Path
from typing import Any

import pytest
from rclpy.parameter import Parameter
from repo_paths import REPO

from dpos_ros.contract import topics as T
from dpos_ros.io import bag

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
TOPICS = [T.DATUM, T.MASTER_NAV, T.sub_imu("sub_r"), T.sub_imu("sub_l")]
#: each topic's message type
TYPES = {T.DATUM: T.NAVSATFIX, T.MASTER_NAV: T.ODOMETRY, T.sub_imu("sub_r"): T.IMU, T.sub_imu("sub_l"): T.IMU}


def bag_messages(seconds: float) -> dict[str, tuple[str, list[bytes]]]:
    """Per topic of :data:`TOPICS` (message type, serialized messages) of the sample bag's first
    ``seconds`` after its first main POS message (every datum)."""
    raw = bag.read_raw(BAG, TOPICS)
    t_first = raw[T.MASTER_NAV][1][0]
    return {topic: (mt, [d for t, d in zip(t_log, data) if topic == T.DATUM or t - t_first <= seconds * 1e9])
            for topic, (mt, t_log, data) in raw.items()}


def stamp_ns(d: bytes) -> int:
    """The header stamp [ns] of a serialized message with a std_msgs/Header first."""
    return int.from_bytes(d[4:8], "little", signed=True) * 1_000_000_000 + int.from_bytes(d[8:12], "little")


class StatusTap:
    """Stands in for the node's status publisher: keeps each status as a dict (its key values, ``message``, ``level``)."""

    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []

    def publish(self, arr: Any) -> None:
        st = arr.status[0]
        level = st.level if isinstance(st.level, int) else int.from_bytes(st.level, "little")
        self.sent.append({kv.key: kv.value for kv in st.values} | {"message": st.message, "level": level})


def make_node(context: Any, output_dir: Path, monkeypatch: pytest.MonkeyPatch, **params: Any) -> Any:
    """A TransferAlignNode (urtss on paper_su_pair, products in ``output_dir``, ``params`` over the
    defaults) whose workers are threads, its status in ``node._status_pub`` (:class:`StatusTap`) and
    its subscription callbacks in ``node.cbs`` (topic -> callback of serialized messages)."""
    import transfer_align_node.node as tan

    monkeypatch.setattr(tan, "_pool", lambda n: cf.ThreadPoolExecutor(max_workers=max(1, n)))
    over = {"method": "urtss", "aircraft_config": "paper_su_pair", "output_dir": str(output_dir),
            "finalize_timeout_s": 2.0, "output_rate_hz": 10.0} | params
    ta = tan.TransferAlignNode(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
    ta._status_pub = StatusTap()
    ta.cbs = {t: ta._make_cb(t, mt) for t, mt in TYPES.items()}
    return ta


def finalize(ta: Any, end_ns: int, sid: str = "") -> None:
    """Close ``ta``'s session at ``end_ns`` (session id ``sid``) and wait (bounded) for its products."""
    assert ta._start_finalize(end_ns, sid)
    ta._finalize_thread.join(timeout=180)
    assert not ta._finalize_thread.is_alive(), ta._progress


def status(ta: Any) -> dict[str, Any]:
    """``ta``'s status, published now (:class:`StatusTap`)."""
    ta._publish_status()
    sent: list[dict[str, Any]] = ta._status_pub.sent
    return sent[-1]
