"""QoS profiles of the dpos topics (docs/design.md, "Topics" / QoS).

- Sensor and navigation streams (``/master/imu``, ``/sub_imu/*/imu``, ``/gnss/*``,
  ``/master/nav``, ``/ifa/*`` corrections, ``/antenna/*/odom``, ``/truth/*``, ``/session/end``):
  RELIABLE, KEEP_LAST with a deep queue, VOLATILE. Nothing the transfer-alignment node needs
  may be dropped under the rated load; 5000 samples are 50 s of a 100 Hz IMU or 25 s at 200 Hz.
- Datum and status (``/dpos/datum``, ``/ifa/status``, ``/transfer_align/status``):
  TRANSIENT_LOCAL + RELIABLE, so that a late joiner gets the last message.

Publishers and subscribers of one topic must use the same profile (a VOLATILE subscriber
matches a TRANSIENT_LOCAL publisher, but only a TRANSIENT_LOCAL subscriber gets the latched
message).
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from dpos_ros.contract.topics import QOS_KINDS, STREAM_DEPTH

_HISTORY = {"keep_last": HistoryPolicy.KEEP_LAST, "keep_all": HistoryPolicy.KEEP_ALL}
_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


def _profile(kind: str) -> QoSProfile:
    history, depth, reliability, durability = QOS_KINDS[kind]
    return QoSProfile(history=_HISTORY[history], depth=depth, reliability=_RELIABILITY[reliability], durability=_DURABILITY[durability])


#: Sensor streams: IMU, GNSS fix/velocity, truth (RELIABLE, KEEP_LAST STREAM_DEPTH, VOLATILE).
SENSOR_QOS = _profile("sensor")

#: Navigation streams: /master/nav, /ifa/correction, /ifa/imu_bias, /antenna/*/odom, /session/end.
NAV_QOS = _profile("nav")

#: Latched datum (/dpos/datum): the last message is kept for late joiners.
DATUM_QOS = _profile("datum")

#: Status (/ifa/status, /transfer_align/status): latched, a short history.
STATUS_QOS = _profile("status")


def keep_all(qos: QoSProfile) -> QoSProfile:
    """The subscriber side of a stream that must not lose a message however late its node takes
    them (a JIT compile, a long epoch, a replay as fast as possible): KEEP_ALL history with the
    stream's reliability and durability. A KEEP_LAST reader overwrites what its node has not taken
    yet once ``depth`` messages wait, although they were delivered and acknowledged, so the
    publisher's flow control cannot see it (a KEEP_LAST relay lost 1800 IMU samples of
    ``dpos-play --rate 0`` while the mechanization compiled). Latched profiles are returned as they are."""
    if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        return qos
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=qos.reliability, durability=qos.durability)


__all__ = ["STREAM_DEPTH", "SENSOR_QOS", "NAV_QOS", "DATUM_QOS", "STATUS_QOS", "keep_all"]

_QOS = {
    "sensor": SENSOR_QOS,
    "nav": NAV_QOS,
    "datum": DATUM_QOS,
    "status": STATUS_QOS,
}


def qos_profile(kind: str) -> QoSProfile:
    """The QoS profile of a stream's ``qos`` kind (``sensor``, ``nav``, ``datum``, ``status``)."""
    try:
        return _QOS[kind]
    except KeyError:
        raise ValueError(f"unknown stream QoS kind {kind!r}; known: {sorted(_QOS)}") from None
