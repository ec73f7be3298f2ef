"""The one place that knows message fields, frames and units (design.md "Frames, units, time").

* World frame ``enu``: Cartesian ENU at the session datum; bodies are FLU (``master_imu``,
  ``sub_imu_<name>``, ``antenna_<name>``).  The core works in the local-level ENU frame with
  geodetic positions; :func:`dpos_core.earth.nav_to_datum` maps between the two.
* Quaternions: the core is scalar-first ``[w, x, y, z]``; messages are ``x, y, z, w``.
* Stamps: ``t_ns = start_time_ns + round(t_s * 1e9)``; ``header.stamp`` is the sampling time.
* ``sensor_msgs/Imu``: angular velocity and specific force in the IMU's FLU axes (the mean over the
  sample interval ending at the stamp); no orientation (``orientation_covariance[0] = -1``).
* ``nav_msgs/Odometry``: pose of the child frame in ``enu`` with a 6x6 covariance (x, y, z, then
  rotations about the ``enu`` axes); twist in the child (body) frame: velocity over the Earth and
  body rate w.r.t. the Earth, with covariance.
* ``/gnss/fix``: ``NavSatFix`` in degrees / ellipsoidal height, ENU position covariance [m^2];
  ``/gnss/vel``: ENU velocity at the antenna (local-level axes), frame ``gnss``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from rosbags.typesys import Stores, get_typestore

from dpos_core import earth
from dpos_core.attitude import dcm_to_quat, quat_to_dcm
from dpos_core.frames import C_nb_from_hpr, hpr_from_C_nb
from dpos_core.units import FloatArray
from dpos_ros.contract import cdr

from . import _odometry_kernel as K

WORLD_FRAME = "enu"
MASTER_FRAME = "master_imu"
GNSS_FRAME = "gnss"


def sub_imu_frame(name: str) -> str:
    return f"sub_imu_{name}"


def antenna_frame(name: str) -> str:
    return f"antenna_{name}"


def stamps_ns(start_time_s: float, t_s: FloatArray) -> NDArray[np.int64]:
    """Absolute stamps [ns] of scenario times (exact integer arithmetic for the epoch)."""
    start_ns = int(round(start_time_s * 1e9))
    return start_ns + np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)


def quat_xyzw(q_wxyz: FloatArray) -> FloatArray:
    q = np.asarray(q_wxyz, dtype=float)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def quat_wxyz(q_xyzw: FloatArray) -> FloatArray:
    q = np.asarray(q_xyzw, dtype=float)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


# ------------------------------------------------------------------------------ Imu


def imu_values(omega_radps: FloatArray, f_mps2: FloatArray, gyro_sigma_radps: float, accel_sigma_mps2: float) -> FloatArray:
    """Double block (N, 37) of ``sensor_msgs/Imu`` without orientation."""
    n = omega_radps.shape[0]
    v = np.zeros((n, cdr.IMU_DOUBLES))
    v[:, 3] = 1.0  # identity orientation (ignored: covariance[0] = -1)
    v[:, 4] = -1.0
    v[:, 13:16] = omega_radps
    v[:, [16, 20, 24]] = gyro_sigma_radps**2
    v[:, 25:28] = f_mps2
    v[:, [28, 32, 36]] = accel_sigma_mps2**2
    return v


@dataclass(frozen=True)
class ImuBlock:
    """Decoded Imu samples: t_ns (N,), omega_radps (N, 3), f_mps2 (N, 3), variances (N, 3) each."""

    t_ns: NDArray[np.int64]
    omega_radps: FloatArray
    f_mps2: FloatArray
    gyro_var: FloatArray
    accel_var: FloatArray


def imu_from_values(t_ns: NDArray[np.int64], v: FloatArray) -> ImuBlock:
    return ImuBlock(t_ns, v[:, 13:16].copy(), v[:, 25:28].copy(), v[:, [16, 20, 24]].copy(), v[:, [28, 32, 36]].copy())


def imu_rows(frame_id: str, t_ns: NDArray[np.int64], omega: FloatArray, f: FloatArray, gyro_sigma: float, accel_sigma: float) -> NDArray[np.uint8]:
    return cdr.encode(cdr.layout("imu", frame_id), t_ns, imu_values(omega, f, gyro_sigma, accel_sigma))


# ------------------------------------------------------------------------------ Odometry


def odometry_values(
    llh: FloatArray,
    vel_n_mps: FloatArray,
    q_nb: FloatArray,
    datum_llh: FloatArray,
    omega_b_radps: FloatArray | None = None,
    omega_sigma_radps: float = 0.0,
) -> FloatArray:
    """Double block (N, 85) of ``nav_msgs/Odometry`` (pose in ``enu``, twist in the body) with zero
    pose and velocity covariances (:func:`odometry_values_cov` fills them)."""
    n = llh.shape[0]
    C_nb = quat_to_dcm(q_nb)
    p, v_w, C_wb = earth.nav_to_datum(llh, vel_n_mps, C_nb, datum_llh)
    out = np.zeros((n, cdr.ODOM_DOUBLES))
    out[:, 0:3] = p
    out[:, 3:7] = quat_xyzw(dcm_to_quat(C_wb))
    out[:, 43:46] = np.einsum("nji,nj->ni", C_wb, v_w)
    if omega_b_radps is not None:
        out[:, 46:49] = omega_b_radps
    twist_cov = np.zeros((n, 6, 6))
    twist_cov[:, 3:, 3:] = np.eye(3) * omega_sigma_radps**2
    out[:, 49:85] = twist_cov.reshape(n, 36)
    return out


def antenna_odometry_values(llh: FloatArray, vel_n_mps: FloatArray, C_nb: FloatArray, sigma: FloatArray,
                            datum_llh: FloatArray) -> FloatArray:
    """Double block (N, 85) of an antenna's ``nav_msgs/Odometry`` (design.md "Session products":
    pose in ``enu``, twist in the body) with its covariances from the 1-sigma ``sigma`` (N, 9) of
    ``AntennaSolution`` (attitude east/north/up [rad], velocity ENU [m/s], position ENU [m], all
    in the local ENU frame at the row): the pose's position and orientation blocks
    ``R diag(s^2) R^T`` with ``R`` the rotation local ENU -> ``enu`` (:func:`dpos_core.earth.C_datum_n`),
    the twist's linear block ``C_bn diag(s_v^2) C_nb``, the angular rate unknown (-1 on its
    diagonal); llh (N, 3), vel_n_mps (N, 3) local ENU, C_nb (N, 3, 3) body -> local ENU.  The same
    numbers as :func:`odometry_values` and those products (to rounding), one numba loop."""
    llh = np.ascontiguousarray(llh, dtype=float)
    n = llh.shape[0]
    lat0, lon0, h0 = (float(v) for v in np.asarray(datum_llh, dtype=float))
    out = np.empty((n, cdr.ODOM_DOUBLES))
    C_wb = np.empty((n, 3, 3))
    K.odometry_rows(llh, np.ascontiguousarray(vel_n_mps, dtype=float), np.ascontiguousarray(C_nb, dtype=float),
                    np.ascontiguousarray(sigma, dtype=float), np.ascontiguousarray(earth.C_en(lat0, lon0)),
                    np.asarray(earth.geodetic_to_ecef(lat0, lon0, h0), dtype=float), earth.A_M, earth.E2, out, C_wb)
    out[:, 3:7] = quat_xyzw(dcm_to_quat(C_wb))
    return out


@dataclass(frozen=True)
class OdometryBlock:
    """Decoded Odometry samples back in the core's terms.

    t_ns (N,), llh (N, 3), vel_n_mps (N, 3) local ENU, q_nb (N, 4) body -> local ENU, omega_b_radps (N, 3),
    pose_cov (N, 6, 6) and twist_cov (N, 6, 6) as on the wire.
    """

    t_ns: NDArray[np.int64]
    llh: FloatArray
    vel_n_mps: FloatArray
    q_nb: FloatArray
    omega_b_radps: FloatArray
    pose_cov: FloatArray
    twist_cov: FloatArray


def odometry_from_values(t_ns: NDArray[np.int64], v: FloatArray, datum_llh: FloatArray) -> OdometryBlock:
    n = v.shape[0]
    C_wb = quat_to_dcm(quat_wxyz(v[:, 3:7]))
    v_w = np.einsum("nij,nj->ni", C_wb, v[:, 43:46])
    llh, vel_n, C_nb = earth.datum_to_nav(v[:, 0:3], v_w, C_wb, datum_llh)
    return OdometryBlock(t_ns, llh, vel_n, dcm_to_quat(C_nb), v[:, 46:49].copy(),
                         v[:, 7:43].reshape(n, 6, 6).copy(), v[:, 49:85].reshape(n, 6, 6).copy())


def odometry_rows(frame_id: str, child_frame_id: str, t_ns: NDArray[np.int64], values: FloatArray) -> NDArray[np.uint8]:
    return cdr.encode(cdr.layout("odometry", frame_id, child_frame_id), t_ns, values)


# ------------------------------------------------------------------------------ low-rate messages (rclpy)


def _stamp(msg_header, t_ns: int, frame_id: str) -> None:
    msg_header.stamp.sec = int(t_ns // 1_000_000_000)
    msg_header.stamp.nanosec = int(t_ns % 1_000_000_000)
    msg_header.frame_id = frame_id


def navsatfix_msg(t_ns: int, frame_id: str, llh: FloatArray, pos_sigma_m: FloatArray | None, *, fix: bool = True):
    """``sensor_msgs/NavSatFix`` (degrees, ellipsoidal height, diagonal ENU covariance)."""
    from sensor_msgs.msg import NavSatFix, NavSatStatus

    m = NavSatFix()
    _stamp(m.header, t_ns, frame_id)
    m.status.status = NavSatStatus.STATUS_GBAS_FIX if fix else NavSatStatus.STATUS_NO_FIX
    m.status.service = NavSatStatus.SERVICE_GPS
    m.latitude = float(np.rad2deg(llh[0]))
    m.longitude = float(np.rad2deg(llh[1]))
    m.altitude = float(llh[2])
    if pos_sigma_m is None:
        m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_UNKNOWN
    else:
        m.position_covariance = [float(x) for x in np.diag(np.asarray(pos_sigma_m, dtype=float) ** 2).reshape(9)]
        m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
    return m


def navsatfix_rows(frame_id: str, t_ns: NDArray[np.int64], llh: FloatArray, pos_sigma_enu_m: FloatArray) -> NDArray[np.uint8]:
    """Serialized ``sensor_msgs/NavSatFix`` rows (N, size) of positions ``llh`` (N, 3) [rad, rad, m
    ellipsoidal] with ENU position sigmas (N, 3) [m] (REP 145: latitude / longitude in degrees, a
    diagonal ``position_covariance`` ENU row-major, COVARIANCE_TYPE_DIAGONAL_KNOWN, status FIX,
    service GPS): the antenna products' fixes."""
    llh = np.asarray(llh, dtype=float).reshape(-1, 3)
    s = np.asarray(pos_sigma_enu_m, dtype=float).reshape(-1, 3)
    vals = np.zeros((llh.shape[0], cdr.NAVSATFIX_DOUBLES))
    vals[:, 0], vals[:, 1], vals[:, 2] = np.rad2deg(llh[:, 0]), np.rad2deg(llh[:, 1]), llh[:, 2]
    vals[:, [3, 7, 11]] = s**2
    return cdr.encode(_layout("navsatfix", frame_id), t_ns, vals)


def gnss_vel_msg(t_ns: int, vel_n_mps: FloatArray, vel_sigma_mps: FloatArray):
    """``geometry_msgs/TwistWithCovarianceStamped``: ENU velocity at the antenna."""
    from geometry_msgs.msg import TwistWithCovarianceStamped

    m = TwistWithCovarianceStamped()
    _stamp(m.header, t_ns, GNSS_FRAME)
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = (float(x) for x in vel_n_mps)
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.diag(np.asarray(vel_sigma_mps, dtype=float) ** 2)
    cov[3:, 3:] = -1.0 * np.eye(3)  # angular part unknown
    m.twist.covariance = [float(x) for x in cov.reshape(36)]
    return m


def datum_msg(t_ns: int, datum_llh: FloatArray):
    """``/dpos/datum``: the session datum as a NavSatFix (frame ``enu``, no covariance)."""
    return navsatfix_msg(t_ns, WORLD_FRAME, datum_llh, None)


_TYPESTORE: Any = None


def datum_blob(t_ns: int, datum_llh: FloatArray) -> bytes:
    """``/dpos/datum`` serialized without the ROS client library (the offline paths load no rclpy):
    the fields of :func:`datum_msg` - frame ``enu``, status GBAS_FIX, service GPS, degrees and
    ellipsoidal height, covariance unknown - through rosbags' typestore (test_cdr compares the
    bytes with the rclpy message's)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    ts = _TYPESTORE
    NavSatFix, NavSatStatus = ts.types["sensor_msgs/msg/NavSatFix"], ts.types["sensor_msgs/msg/NavSatStatus"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    msg = NavSatFix(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=WORLD_FRAME),
                    status=NavSatStatus(status=NavSatStatus.STATUS_GBAS_FIX, service=NavSatStatus.SERVICE_GPS),
                    latitude=float(np.rad2deg(datum_llh[0])), longitude=float(np.rad2deg(datum_llh[1])), altitude=float(datum_llh[2]),
                    position_covariance=np.zeros(9), position_covariance_type=NavSatFix.COVARIANCE_TYPE_UNKNOWN)
    return bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/NavSatFix"))


def datum_from_msg(msg) -> FloatArray:
    return np.array([np.deg2rad(msg.latitude), np.deg2rad(msg.longitude), msg.altitude])


def session_end_msg(t_ns: int, session_id: str):
    from std_msgs.msg import Header

    m = Header()
    _stamp(m, t_ns, session_id)
    return m


# ------------------------------------------------------------------------------ full covariances (master nav, IFA)


def odometry_values_cov(
    llh: FloatArray,
    vel_n_mps: FloatArray,
    q_nb: FloatArray,
    datum_llh: FloatArray,
    omega_b_radps: FloatArray | None,
    pos_cov_n: FloatArray,
    att_cov_n: FloatArray,
    vel_cov_n: FloatArray,
) -> FloatArray:
    """As :func:`odometry_values` (N, 85), with full covariances in local-level ENU terms.

    ``pos_cov_n`` [m^2], ``att_cov_n`` (attitude error as a rotation about the local ENU axes, the
    seeds' ``phi`` [rad^2]) and ``vel_cov_n`` [m^2/s^2]: (3, 3) for every sample or (N, 3, 3).
    The pose covariance is rotated into ``enu``, the velocity covariance into the body.
    """
    out = odometry_values(llh, vel_n_mps, q_nb, datum_llh, omega_b_radps)
    n = out.shape[0]
    R = earth.C_datum_n(llh[:, 0], llh[:, 1], datum_llh)
    C_nb = quat_to_dcm(q_nb)
    Rt = np.swapaxes(R, 1, 2)
    pose = np.zeros((n, 6, 6))
    pose[:, :3, :3] = R @ np.asarray(pos_cov_n, dtype=float) @ Rt
    pose[:, 3:, 3:] = R @ np.asarray(att_cov_n, dtype=float) @ Rt
    out[:, 7:43] = pose.reshape(n, 36)
    twist = out[:, 49:85].reshape(n, 6, 6).copy()
    twist[:, :3, :3] = np.swapaxes(C_nb, 1, 2) @ np.asarray(vel_cov_n, dtype=float) @ C_nb
    out[:, 49:85] = twist.reshape(n, 36)
    return out


def odometry_cov_n(block: OdometryBlock, datum_llh: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of the covariance part of :func:`odometry_values_cov`: (pos, att, vel) covariances
    (N, 3, 3) each in local-level ENU terms."""
    R = earth.C_datum_n(block.llh[:, 0], block.llh[:, 1], datum_llh)
    Rt = np.swapaxes(R, 1, 2)
    C_nb = quat_to_dcm(block.q_nb)
    pos = Rt @ block.pose_cov[:, :3, :3] @ R
    att = Rt @ block.pose_cov[:, 3:, 3:] @ R
    vel = C_nb @ block.twist_cov[:, :3, :3] @ np.swapaxes(C_nb, 1, 2)
    return pos, att, vel


def imu_bias_values(gyro_radps: FloatArray, accel_mps2: FloatArray, gyro_cov: FloatArray, accel_cov: FloatArray) -> FloatArray:
    """Double block (N, 37) of ``/ifa/imu_bias`` (``sensor_msgs/Imu`` in the IMU frame): gyro bias
    [rad/s] in angular_velocity, accelerometer bias [m/s^2] in linear_acceleration, their (N, 3, 3)
    covariances; no orientation (``orientation_covariance[0] = -1``)."""
    g = np.atleast_2d(np.asarray(gyro_radps, dtype=float))
    n = g.shape[0]
    v = np.zeros((n, cdr.IMU_DOUBLES))
    v[:, 3] = 1.0
    v[:, 4] = -1.0
    v[:, 13:16] = g
    v[:, 16:25] = np.broadcast_to(np.asarray(gyro_cov, dtype=float), (n, 3, 3)).reshape(n, 9)
    v[:, 25:28] = np.atleast_2d(np.asarray(accel_mps2, dtype=float))
    v[:, 28:37] = np.broadcast_to(np.asarray(accel_cov, dtype=float), (n, 3, 3)).reshape(n, 9)
    return v


def imu_bias_from_values(v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Inverse of :func:`imu_bias_values`: gyro (N, 3), accel (N, 3), gyro_cov (N, 3, 3), accel_cov (N, 3, 3)."""
    n = v.shape[0]
    return v[:, 13:16].copy(), v[:, 25:28].copy(), v[:, 16:25].reshape(n, 3, 3).copy(), v[:, 28:37].reshape(n, 3, 3).copy()


def decode_raw(raw: bytes, kind: str, frame_id: str, child_frame_id: str = "") -> tuple[int, FloatArray]:
    """One serialized Imu / Odometry message -> ``(t_ns, values (n_doubles,))``.

    Fast path for the frame names of this product (:func:`cdr.decode`); other frame names go
    through rclpy's deserializer.
    """
    lay = _layout(kind, frame_id, child_frame_id)
    if len(raw) >= lay.size:
        try:
            t, v = cdr.decode(lay, np.frombuffer(raw, dtype=np.uint8)[None, : lay.size])
            return int(t[0]), v[0]
        except ValueError:
            pass
    return _decode_slow(raw, kind)


def _decode_slow(raw: bytes, kind: str) -> tuple[int, FloatArray]:
    from rclpy.serialization import deserialize_message

    if kind == "imu":
        from sensor_msgs.msg import Imu

        m = deserialize_message(raw, Imu)
        o, w, a = m.orientation, m.angular_velocity, m.linear_acceleration
        vals = [o.x, o.y, o.z, o.w, *m.orientation_covariance, w.x, w.y, w.z, *m.angular_velocity_covariance,
                a.x, a.y, a.z, *m.linear_acceleration_covariance]
    else:
        from nav_msgs.msg import Odometry

        m = deserialize_message(raw, Odometry)
        p, o = m.pose.pose.position, m.pose.pose.orientation
        lin, ang = m.twist.twist.linear, m.twist.twist.angular
        vals = [p.x, p.y, p.z, o.x, o.y, o.z, o.w, *m.pose.covariance, lin.x, lin.y, lin.z, ang.x, ang.y, ang.z, *m.twist.covariance]
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, np.asarray(vals, dtype=float)


_LAYOUTS: dict[tuple[str, str, str], cdr.Layout] = {}


def _layout(kind: str, frame_id: str, child_frame_id: str = "") -> cdr.Layout:
    key = (kind, frame_id, child_frame_id)
    if key not in _LAYOUTS:
        _LAYOUTS[key] = cdr.layout(kind, frame_id, child_frame_id)
    return _LAYOUTS[key]


def raw_stamp_ns(raw: bytes) -> int:
    """``header.stamp`` [ns] of a serialized (little-endian CDR) message with a header first."""
    return int.from_bytes(raw[4:8], "little", signed=True) * 1_000_000_000 + int.from_bytes(raw[8:12], "little")


def decode_raw_batch(raws: Sequence[bytes], kind: str, frame_id: str, child_frame_id: str = "") -> tuple[NDArray[np.int64], FloatArray]:
    """Serialized Imu / Odometry messages -> ``(t_ns (N,), values (N, n_doubles))`` (vectorized
    when all have this product's frame names, else one by one like :func:`decode_raw`)."""
    lay = _layout(kind, frame_id, child_frame_id)
    if all(len(r) >= lay.size for r in raws):
        try:
            rows = np.frombuffer(b"".join(bytes(r[: lay.size]) for r in raws), dtype=np.uint8).reshape(len(raws), lay.size)
            return cdr.decode(lay, rows)
        except ValueError:
            pass
    out = [decode_raw(r, kind, frame_id, child_frame_id) for r in raws]
    return np.array([t for t, _ in out], dtype=np.int64), np.stack([v for _, v in out])


def diagnostic_array(stamp_msg, name: str, hardware_id: str, level: bytes | int, message: str, values: dict):
    """``diagnostic_msgs/DiagnosticArray`` with one status (values stringified) - the node statuses."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    st = DiagnosticStatus(name=name, hardware_id=hardware_id, level=level if isinstance(level, bytes) else bytes([level]), message=message)
    st.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    arr = DiagnosticArray()
    arr.header.stamp = stamp_msg
    arr.status = [st]
    return arr


# ------------------------------------------------------------------------------ SAR fixes and the barometer

#: frame of /baro/pressure (the barometer's static port; no lever arm is modelled)
BARO_FRAME = "baro"
#: ICAO standard atmosphere, troposphere (ISO 2533): sea-level pressure [Pa] and temperature [K],
#: lapse rate [K/m], and the exponent g0 M / (R L) of p = p0 (1 - L h / T0)^n
ISA_P0_PA = 101325.0
ISA_T0_K = 288.15
ISA_LAPSE_K_PER_M = 0.0065
ISA_EXPONENT = 9.80665 * 0.0289644 / (8.3144598 * 0.0065)
#: the ISA troposphere's top [m]: pressure altitudes above it are refused
ISA_TROPOPAUSE_M = 11000.0


def isa_pressure_pa(h_m: ArrayLike) -> FloatArray:
    """ISA static pressure [Pa] at pressure altitude ``h_m`` (troposphere)."""
    return ISA_P0_PA * (1.0 - ISA_LAPSE_K_PER_M * np.asarray(h_m, dtype=float) / ISA_T0_K) ** ISA_EXPONENT


def isa_pressure_altitude_m(p_pa: ArrayLike) -> FloatArray:
    """Inverse of :func:`isa_pressure_pa`: the pressure altitude [m] of a static pressure [Pa]."""
    return ISA_T0_K / ISA_LAPSE_K_PER_M * (1.0 - (np.asarray(p_pa, dtype=float) / ISA_P0_PA) ** (1.0 / ISA_EXPONENT))


def _isa_dp_dh(h_m: ArrayLike) -> FloatArray:
    h = np.asarray(h_m, dtype=float)
    return -ISA_P0_PA * ISA_EXPONENT * ISA_LAPSE_K_PER_M / ISA_T0_K * (1.0 - ISA_LAPSE_K_PER_M * h / ISA_T0_K) ** (ISA_EXPONENT - 1.0)


def baro_msg(t_ns: int, h_m: float, sigma_m: float):
    """``/baro/pressure``: ``sensor_msgs/FluidPressure`` [Pa] of a barometric height ``h_m`` (the ISA
    pressure altitude, taken as the ellipsoidal height: design.md "Message fields"), ``variance``
    [Pa^2] = (dp/dh sigma_m)^2 at that height; frame ``baro``."""
    from sensor_msgs.msg import FluidPressure

    if not -1000.0 <= h_m < ISA_TROPOPAUSE_M:
        raise ValueError(f"barometric height {h_m} m is outside the ISA troposphere [-1000, {ISA_TROPOPAUSE_M:g}) m")
    m = FluidPressure()
    _stamp(m.header, t_ns, BARO_FRAME)
    m.fluid_pressure = float(isa_pressure_pa(h_m))
    m.variance = float((_isa_dp_dh(h_m) * sigma_m) ** 2)
    return m


def baro_from_msg(msg) -> tuple[int, float, float]:
    """``(t_ns, h_m, sigma_m)`` of a ``/baro/pressure`` message (inverse of :func:`baro_msg`);
    ``sigma_m`` is NaN when the variance is 0 (unknown) or negative."""
    h = float(isa_pressure_altitude_m(msg.fluid_pressure))
    var = float(msg.variance)
    sigma = float(np.sqrt(var) / abs(float(_isa_dp_dh(h)))) if var > 0 else float("nan")
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec), h, sigma


def sar_fix_msg(t_ns: int, llh: FloatArray, heading_rad: float, pos_sigma_m: float, heading_sigma_rad: float, datum_llh: FloatArray):
    """``/sar/fix``: ``geometry_msgs/PoseWithCovarianceStamped`` in ``enu`` of one SAR scene-matching fix.

    ``pose.position``: the point at the fix's latitude and longitude and the **datum's height** in
    ``enu`` (SAR measures no height: the point's z is a convention, its variance -1);
    ``pose.orientation``: the heading as a level attitude (pitch = roll = 0 in the local level at the
    fix) rotated into ``enu`` as Odometry poses are (with the meridian convergence);
    ``pose.covariance``: x, y variance ``pos_sigma_m^2`` (north/east, isotropic: unchanged by the
    rotation about the vertical into ``enu``), rotation about z ``heading_sigma_rad^2``; the
    unmeasured z, rotations about x and y: -1 on the diagonal, off-diagonals 0.
    """
    from geometry_msgs.msg import PoseWithCovarianceStamped

    llh = np.asarray(llh, dtype=float)
    datum = np.asarray(datum_llh, dtype=float)
    p, _, C_wb = earth.nav_to_datum(np.array([llh[0], llh[1], datum[2]])[None], np.zeros((1, 3)),
                                    C_nb_from_hpr(heading_rad, 0.0, 0.0)[None], datum)
    m = PoseWithCovarianceStamped()
    _stamp(m.header, t_ns, WORLD_FRAME)
    m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = (float(x) for x in p[0])
    q = quat_xyzw(dcm_to_quat(C_wb[0]))
    m.pose.pose.orientation.x, m.pose.pose.orientation.y, m.pose.pose.orientation.z, m.pose.pose.orientation.w = (float(x) for x in q)
    cov = np.diag([pos_sigma_m**2, pos_sigma_m**2, -1.0, -1.0, -1.0, heading_sigma_rad**2])
    m.pose.covariance = [float(x) for x in cov.reshape(36)]
    return m


@dataclass(frozen=True)
class SarFix:
    """A decoded ``/sar/fix``: t_ns, lat_rad, lon_rad, heading_rad (aviation, local level),
    pos_sigma_m (north/east), heading_sigma_rad (NaN where the variance is not > 0)."""

    t_ns: int
    lat_rad: float
    lon_rad: float
    heading_rad: float
    pos_sigma_m: float
    heading_sigma_rad: float


def sar_fix_from_msg(msg, datum_llh: FloatArray) -> SarFix:
    """Inverse of :func:`sar_fix_msg` (``datum_llh``: the session's ``enu`` datum)."""
    p = msg.pose.pose.position
    o = msg.pose.pose.orientation
    C_wb = quat_to_dcm(quat_wxyz(np.array([o.x, o.y, o.z, o.w], dtype=float)))
    llh, _, C_nb = earth.datum_to_nav(np.array([[p.x, p.y, p.z]]), np.zeros((1, 3)), C_wb[None], np.asarray(datum_llh, dtype=float))
    cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    pv = 0.5 * (cov[0, 0] + cov[1, 1])
    t_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    return SarFix(t_ns, float(llh[0, 0]), float(llh[0, 1]), float(hpr_from_C_nb(C_nb[0])[0]),
                  float(np.sqrt(pv)) if pv > 0 else float("nan"), float(np.sqrt(cov[5, 5])) if cov[5, 5] > 0 else float("nan"))
