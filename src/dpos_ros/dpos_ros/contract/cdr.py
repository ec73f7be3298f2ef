"""Vectorized CDR (XCDR1, little endian) encoding and decoding of the high-rate streams.

``sensor_msgs/Imu`` and ``nav_msgs/Odometry`` carry a header (stamp + frame strings) followed by
a block of float64 values with no gaps, so for fixed frame names every message has the same
layout: a constant prefix, the stamp, the strings, padding, then ``N`` doubles.  Encoding a whole
series is then a few numpy copies instead of one Python message object per sample, and the bag
writer and the live devices emit the very same bytes.  ``test/dpos_ros/contract/test_cdr.py`` checks that the
bytes equal ``rclpy.serialization.serialize_message`` of the same content (except alignment
padding, which Fast CDR leaves uninitialized and we write as zeros).

Alignment in CDR is relative to the payload after the 4-byte encapsulation header.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore

from dpos_core.units import FloatArray

CDR_LE_HEADER = b"\x00\x01\x00\x00"

#: doubles after the header: orientation xyzw (4) + cov (9) + angular velocity (3) + cov (9) + linear acceleration (3) + cov (9)
IMU_DOUBLES = 37
#: pose position (3) + orientation xyzw (4) + cov (36) + twist linear (3) + angular (3) + cov (36)
ODOM_DOUBLES = 85
#: latitude, longitude [deg], altitude [m] (3) + position covariance ENU (9)
NAVSATFIX_DOUBLES = 12
#: the NavSatFix layout's constants (sensor_msgs/NavSatStatus, NavSatFix): a fix of the GPS service
#: with a diagonal covariance (the antenna products' fixes: position sigmas per ENU axis)
NAVSATFIX_STATUS, NAVSATFIX_SERVICE, NAVSATFIX_COVARIANCE_TYPE = 0, 1, 2


def _align(payload: bytearray, n: int, pads: list[int]) -> None:
    while len(payload) % n:
        pads.append(4 + len(payload))
        payload.append(0)


def _string(payload: bytearray, s: str, pads: list[int]) -> None:
    """Append a CDR string (uint32 length incl. NUL, bytes, NUL) at 4-byte alignment."""
    _align(payload, 4, pads)
    b = s.encode("utf-8") + b"\x00"
    payload += len(b).to_bytes(4, "little") + b


@dataclass(frozen=True)
class Layout:
    """Layout of a message kind for given frame names: stamp at payload offset 0, doubles at ``offset``."""

    prefix: bytes  # payload bytes after the stamp up to the doubles (strings + padding)
    n_doubles: int
    padding: tuple[int, ...] = ()  # offsets (in the serialized message) of alignment padding bytes
    suffix: bytes = b""  # constant bytes after the doubles (NavSatFix: the covariance type, padded to 4)

    @property
    def offset(self) -> int:
        return 8 + len(self.prefix)

    @property
    def size(self) -> int:
        return 4 + self.offset + 8 * self.n_doubles + len(self.suffix)


def layout(kind: str, frame_id: str, child_frame_id: str = "") -> Layout:
    """``kind``: ``imu``, ``odometry`` or ``navsatfix`` (status, service and covariance type the
    module's ``NAVSATFIX_*`` constants; the payload padded to 4 bytes as Fast DDS sends it)."""
    payload = bytearray(8)  # stamp sec, nanosec
    pads: list[int] = []
    _string(payload, frame_id, pads)
    suffix = b""
    if kind == "odometry":
        _string(payload, child_frame_id, pads)
        n = ODOM_DOUBLES
    elif kind == "imu":
        n = IMU_DOUBLES
    elif kind == "navsatfix":
        payload += NAVSATFIX_STATUS.to_bytes(1, "little", signed=True)  # int8 status
        _align(payload, 2, pads)
        payload += NAVSATFIX_SERVICE.to_bytes(2, "little")  # uint16 service
        n = NAVSATFIX_DOUBLES
        suffix = bytes([NAVSATFIX_COVARIANCE_TYPE, 0, 0, 0])  # uint8 position_covariance_type, then padding to 4
    else:
        raise ValueError(f"unknown CDR layout {kind!r}")
    _align(payload, 8, pads)
    if suffix:
        end = 4 + len(payload) + 8 * n
        pads += [end + 1, end + 2, end + 3]
    return Layout(bytes(payload[8:]), n, tuple(pads), suffix)


def split_stamp(t_ns: NDArray[np.int64]) -> tuple[NDArray[np.int32], NDArray[np.uint32]]:
    t = np.asarray(t_ns, dtype=np.int64)
    sec = np.floor_divide(t, 1_000_000_000)
    return sec.astype(np.int32), (t - sec * 1_000_000_000).astype(np.uint32)


def encode(lay: Layout, t_ns: NDArray[np.int64], values: FloatArray) -> NDArray[np.uint8]:
    """Rows of serialized messages (N, size) from stamps (N,) and the double block (N, n_doubles)."""
    v = np.ascontiguousarray(values, dtype="<f8")
    n = v.shape[0]
    if v.shape != (n, lay.n_doubles):
        raise ValueError(f"expected values of shape (N, {lay.n_doubles}), got {v.shape}")
    out = np.empty((n, lay.size), dtype=np.uint8)
    out[:, :4] = np.frombuffer(CDR_LE_HEADER, dtype=np.uint8)
    sec, nsec = split_stamp(t_ns)
    out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    out[:, 8:12] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
    out[:, 12 : 4 + lay.offset] = np.frombuffer(lay.prefix, dtype=np.uint8)
    end = 4 + lay.offset + 8 * lay.n_doubles
    out[:, 4 + lay.offset : end] = v.view(np.uint8).reshape(n, 8 * lay.n_doubles)
    out[:, end:] = np.frombuffer(lay.suffix, dtype=np.uint8)
    return out


def matches(lay: Layout, rows: NDArray[np.uint8]) -> NDArray[np.bool_]:
    """(N,) True for the rows (N, lay.size) that have this layout's frame names (padding ignored)."""
    r = np.asarray(rows, dtype=np.uint8)
    if r.ndim != 2 or r.shape[1] != lay.size:
        raise ValueError(f"expected serialized rows of {lay.size} bytes, got shape {r.shape}")
    keep = np.ones(lay.offset - 8, dtype=bool)
    keep[[p - 12 for p in lay.padding if p < 4 + lay.offset]] = False  # padding bytes may hold anything
    return np.all(r[:, 12 : 4 + lay.offset][:, keep] == np.frombuffer(lay.prefix, dtype=np.uint8)[keep], axis=1)


def decode(lay: Layout, rows: NDArray[np.uint8], checked: bool = False) -> tuple[NDArray[np.int64], FloatArray]:
    """Inverse of :func:`encode` for rows of this layout: ``(t_ns (N,), values (N, n_doubles))``.
    ``checked``: the caller has already found every row to :func:`matches` the layout."""
    r = np.ascontiguousarray(rows, dtype=np.uint8)
    if r.ndim != 2 or r.shape[1] != lay.size:
        raise ValueError(f"expected serialized rows of {lay.size} bytes, got shape {r.shape}")
    if not checked and not np.all(matches(lay, r)):
        raise ValueError("serialized messages do not have the expected frame names")
    sec = r[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
    nsec = r[:, 8:12].copy().view("<u4")[:, 0].astype(np.int64)
    vals = r[:, 4 + lay.offset : 4 + lay.offset + 8 * lay.n_doubles].copy().view("<f8")
    return sec * 1_000_000_000 + nsec, vals


def frame_ids(data: bytes, kind: str) -> tuple[str, str]:
    """Frame names of one serialized message (``child`` is '' for Imu)."""
    n = int.from_bytes(data[12:16], "little")
    frame = data[16 : 16 + n - 1].decode("utf-8")
    if kind != "odometry":
        return frame, ""
    o = 16 + n
    o += (-(o - 4)) % 4
    m = int.from_bytes(data[o : o + 4], "little")
    return frame, data[o + 4 : o + 4 + m - 1].decode("utf-8")


_TYPESTORE = None


def canonical(raw: bytes, msgtype: str) -> bytes:
    """Re-serialize CDR with zeroed alignment padding (rosbags' serializer) and pad the payload to a
    multiple of 4 bytes, so that messages serialized by rclpy (Fast CDR leaves padding
    uninitialized) are reproducible byte for byte."""
    global _TYPESTORE
    if _TYPESTORE is None:
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    out = bytes(_TYPESTORE.serialize_cdr(_TYPESTORE.deserialize_cdr(raw, msgtype), msgtype))
    # Fast DDS pads serialized payloads to a multiple of 4 bytes on the wire: do the same, so a
    # recording of the live graph and a dpos-sim bag carry identical bytes
    return out + b"\x00" * (-len(out) % 4)
