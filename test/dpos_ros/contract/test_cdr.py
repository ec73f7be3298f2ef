"""The vectorized CDR encoder equals rclpy's serializer byte for byte; conversions round-trip."""

from __future__ import annotations

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu

from dpos_core.attitude import dcm_to_quat, quat_to_dcm, rotvec_to_dcm
from dpos_core.frames import hpr_sigma_to_rotation_cov
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv


def _assert_same_bytes(ours: bytes, theirs: bytes, lay: cdr.Layout) -> None:
    """Equal except at alignment padding (Fast CDR leaves it uninitialized)."""
    assert len(ours) == len(theirs) == lay.size
    a, b = bytearray(ours), bytearray(theirs)
    for p in lay.padding:
        assert a[p] == 0
        a[p] = b[p] = 0
    assert a == b


@pytest.mark.parametrize("frame", ["master_imu", "sub_imu_r", "x", "abcd", "sub_imu_sub_l"])
def test_imu_bytes_equal_rclpy(frame: str) -> None:
    rng = np.random.default_rng(1)
    t_ns = np.array([1_538_265_600_010_000_000, 5, 2_000_000_000_999_999_999 % (2**31 * 10**9)], dtype=np.int64)
    vals = rng.normal(size=(3, cdr.IMU_DOUBLES))
    rows = cdr.encode(cdr.layout("imu", frame), t_ns, vals)
    for i in range(3):
        m = Imu()
        m.header.stamp.sec = int(t_ns[i] // 10**9)
        m.header.stamp.nanosec = int(t_ns[i] % 10**9)
        m.header.frame_id = frame
        v = vals[i]
        m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = v[0:4]
        m.orientation_covariance = list(v[4:13])
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = v[13:16]
        m.angular_velocity_covariance = list(v[16:25])
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = v[25:28]
        m.linear_acceleration_covariance = list(v[28:37])
        _assert_same_bytes(bytes(rows[i]), serialize_message(m), cdr.layout("imu", frame))
        assert deserialize_message(bytes(rows[i]), Imu) == m
    t2, v2 = cdr.decode(cdr.layout("imu", frame), rows)
    np.testing.assert_array_equal(t2, t_ns)
    np.testing.assert_array_equal(v2, vals)


@pytest.mark.parametrize("frame,child", [("enu", "master_imu"), ("enu", "antenna_ant_r"), ("e", "c"), ("enu", "sub_imu_x")])
def test_odometry_bytes_equal_rclpy(frame: str, child: str) -> None:
    rng = np.random.default_rng(2)
    t_ns = np.array([1_538_265_600_010_000_000, 1_538_265_600_020_000_000], dtype=np.int64)
    vals = rng.normal(size=(2, cdr.ODOM_DOUBLES))
    rows = cdr.encode(cdr.layout("odometry", frame, child), t_ns, vals)
    for i in range(2):
        m = deserialize_message(bytes(rows[i]), Odometry)
        assert m.header.frame_id == frame and m.child_frame_id == child
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t_ns[i]
        assert m.pose.pose.position.y == vals[i, 1] and m.pose.pose.orientation.w == vals[i, 6]
        assert list(m.pose.covariance) == list(vals[i, 7:43])
        assert m.twist.twist.angular.z == vals[i, 48]
        assert list(m.twist.covariance) == list(vals[i, 49:85])
        _assert_same_bytes(bytes(rows[i]), serialize_message(m), cdr.layout("odometry", frame, child))
        assert cdr.frame_ids(bytes(rows[i]), "odometry") == (frame, child)
    # rows serialized by rclpy (garbage in the padding) decode too
    theirs = b"".join(serialize_message(deserialize_message(bytes(r), Odometry)) for r in rows)
    _, v2 = cdr.decode(cdr.layout("odometry", frame, child), np.frombuffer(theirs, dtype=np.uint8).reshape(2, -1))
    np.testing.assert_array_equal(v2, vals)


@pytest.mark.parametrize("frame", ["antenna_ant_r", "gnss", "abc"])
def test_navsatfix_rows_equal_rclpy(frame: str) -> None:
    """The antenna fixes: REP 145 content (degrees, ENU diagonal covariance) and rclpy's bytes,
    padded to 4 as Fast DDS sends them (canonical)."""
    from sensor_msgs.msg import NavSatFix, NavSatStatus

    t_ns = np.array([1_538_265_600_010_000_000, 1_538_265_600_020_000_001], dtype=np.int64)
    llh = np.array([[0.6, 1.9, 1234.5], [-0.3, -2.9, -12.25]])
    sig = np.array([[0.01, 0.02, 0.03], [1.0, 2.0, 3.0]])
    rows = cv.navsatfix_rows(frame, t_ns, llh, sig)
    lay = cdr.layout("navsatfix", frame)
    for i in range(2):
        m = NavSatFix()
        m.header.stamp.sec, m.header.stamp.nanosec = int(t_ns[i] // 10**9), int(t_ns[i] % 10**9)
        m.header.frame_id = frame
        m.status.status, m.status.service = NavSatStatus.STATUS_FIX, NavSatStatus.SERVICE_GPS
        m.latitude, m.longitude, m.altitude = float(np.rad2deg(llh[i, 0])), float(np.rad2deg(llh[i, 1])), float(llh[i, 2])
        m.position_covariance = list(np.diag(sig[i] ** 2).reshape(9))
        m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
        theirs = serialize_message(m)
        _assert_same_bytes(bytes(rows[i]), theirs + b"\x00" * (-len(theirs) % 4), lay)
        assert deserialize_message(bytes(rows[i]), NavSatFix) == m
    t2, v2 = cdr.decode(lay, rows)
    np.testing.assert_array_equal(t2, t_ns)
    np.testing.assert_array_equal(v2[:, :3], np.column_stack([np.rad2deg(llh[:, :2]), llh[:, 2]]))


def test_decode_rejects_other_frames() -> None:
    rows = cdr.encode(cdr.layout("imu", "a"), np.array([1], dtype=np.int64), np.zeros((1, cdr.IMU_DOUBLES)))
    with pytest.raises(ValueError, match="frame names"):
        cdr.decode(cdr.layout("imu", "b"), rows)


def test_imu_convention_and_round_trip() -> None:
    om = np.array([[0.1, -0.2, 0.3]])
    f = np.array([[0.5, 0.0, 9.8]])
    rows = cv.imu_rows("master_imu", np.array([7], dtype=np.int64), om, f, 1e-6, 1e-4)
    m = deserialize_message(bytes(rows[0]), Imu)
    assert m.orientation_covariance[0] == -1.0  # design.md: no orientation
    assert (m.angular_velocity.x, m.linear_acceleration.z) == (0.1, 9.8)
    assert m.angular_velocity_covariance[4] == pytest.approx(1e-12)
    blk = cv.imu_from_values(*cdr.decode(cdr.layout("imu", "master_imu"), rows))
    np.testing.assert_array_equal(blk.omega_radps, om)


def test_odometry_round_trip_and_frames() -> None:
    rng = np.random.default_rng(3)
    datum = np.array([np.deg2rad(40.0), np.deg2rad(116.0), 500.0])
    n = 50
    llh = datum + np.stack([rng.normal(0, 0.005, n), rng.normal(0, 0.005, n), rng.normal(0, 100, n)], 1)
    vel = rng.normal(0, 80, (n, 3))
    q = dcm_to_quat(rotvec_to_dcm(rng.normal(0, 1, (n, 3))))
    om = rng.normal(0, 0.1, (n, 3))
    att_cov = hpr_sigma_to_rotation_cov(quat_to_dcm(q), np.deg2rad([0.005, 0.0025, 0.0025]))
    vals = cv.odometry_values_cov(llh, vel, q, datum, om, np.diag([0.05, 0.05, 0.1]) ** 2, att_cov, np.eye(3) * 0.005**2)
    t_ns = np.arange(n, dtype=np.int64) * 10_000_000
    blk = cv.odometry_from_values(t_ns, vals, datum)
    np.testing.assert_allclose(blk.llh[:, :2], llh[:, :2], atol=1e-13)
    np.testing.assert_allclose(blk.llh[:, 2], llh[:, 2], atol=1e-7)
    np.testing.assert_allclose(blk.vel_n_mps, vel, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(blk.q_nb * q, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_array_equal(blk.omega_b_radps, om)
    # covariances are symmetric and carry the configured variances
    np.testing.assert_allclose(blk.pose_cov, np.swapaxes(blk.pose_cov, 1, 2), atol=1e-20)
    np.testing.assert_allclose(np.trace(blk.pose_cov[:, :3, :3], axis1=1, axis2=2), 0.05**2 * 2 + 0.1**2, rtol=1e-9)
    np.testing.assert_allclose(np.trace(blk.pose_cov[:, 3:, 3:], axis1=1, axis2=2), np.deg2rad(0.005) ** 2 + 2 * np.deg2rad(0.0025) ** 2, rtol=1e-9)
    # a level body at the datum heading north: heading error = rotation about -Up
    C = hpr_sigma_to_rotation_cov(np.eye(3)[None] @ np.array([[[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]]), np.array([0.1, 0.0, 0.0]))
    np.testing.assert_allclose(C[0], np.diag([0.0, 0.0, 0.01]), atol=1e-15)


def test_stamps_are_exact() -> None:
    t = cv.stamps_ns(1538265600.0, np.array([0.01, 0.1, 1299.99]))
    np.testing.assert_array_equal(t - 1538265600 * 10**9, [10_000_000, 100_000_000, 1_299_990_000_000])
