"""/sar/fix and /baro/pressure (design.md "Message fields"): the conversions round-trip through the
wire (rclpy and the bag reader's deserializer), and the simulated main system publishes the fixes and
heights of dpos_core.sim.sar, the same for the same seed."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import FluidPressure

from dpos_core.earth import offset_llh
from dpos_core.sim.sar import baro_heights, sar_fixes
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.devices.sim_streams import device_streams
from dpos_ros.io.gnss_ins import deserialize

DATUM = np.array([34.2 * DEG, 108.9 * DEG, 2000.0])


@pytest.mark.parametrize("heading_deg", [0.0, 37.5, 180.0, 359.9])
def test_sar_fix_round_trip_far_from_the_datum(heading_deg: float) -> None:
    """A fix 80 km north-east of the datum: latitude, longitude and heading come back exactly (the
    meridian convergence is in the orientation, as in Odometry), the sigmas too; z, roll, pitch -1."""
    llh = offset_llh(DATUM, np.array([60e3, 55e3, 900.0]))
    msg = cv.sar_fix_msg(1_700_000_000_123_456_789, llh, heading_deg * DEG, 10.0, 0.05 * DEG, DATUM)
    assert msg.header.frame_id == cv.WORLD_FRAME
    cov = np.asarray(msg.pose.covariance).reshape(6, 6)
    assert cov[0, 0] == cov[1, 1] == 100.0 and cov[2, 2] == cov[3, 3] == cov[4, 4] == -1.0
    assert cov[5, 5] == pytest.approx((0.05 * DEG) ** 2)
    for m in (deserialize_message(serialize_message(msg), PoseWithCovarianceStamped),
              deserialize([serialize_message(msg)], T.POSE_COV)[0]):  # rclpy, and the bag reader's
        f = cv.sar_fix_from_msg(m, DATUM)
        assert f.t_ns == 1_700_000_000_123_456_789
        assert f.lat_rad == pytest.approx(llh[0], abs=1e-12) and f.lon_rad == pytest.approx(llh[1], abs=1e-12)
        assert np.mod(f.heading_rad - heading_deg * DEG + np.pi, 2 * np.pi) - np.pi == pytest.approx(0.0, abs=1e-10)
        assert f.pos_sigma_m == pytest.approx(10.0) and f.heading_sigma_rad == pytest.approx(0.05 * DEG)
    # the orientation is not the local heading's yaw in enu: 80 km away the meridians converge
    o = msg.pose.pose.orientation
    yaw_enu = 2 * np.arctan2(o.z, o.w)
    assert abs(np.mod(yaw_enu - (90.0 - heading_deg) * DEG + np.pi, 2 * np.pi) - np.pi) > 0.1 * DEG


def test_baro_round_trip_and_isa() -> None:
    assert cv.isa_pressure_pa(0.0) == pytest.approx(101325.0)
    assert cv.isa_pressure_pa(11000.0) == pytest.approx(22632.0, rel=1e-3)  # ISA tropopause
    for h in (-200.0, 0.0, 2000.0, 2787.6, 9000.0):
        msg = cv.baro_msg(5_000_000_000, h, 2.0)
        assert msg.header.frame_id == cv.BARO_FRAME
        for m in (deserialize_message(serialize_message(msg), FluidPressure), deserialize([serialize_message(msg)], T.FLUID_PRESSURE)[0]):
            t, h2, s = cv.baro_from_msg(m)
            assert t == 5_000_000_000 and h2 == pytest.approx(h, abs=1e-6) and s == pytest.approx(2.0, rel=1e-6)
    assert 2.0 * 9.0 < np.sqrt(cv.baro_msg(0, 2000.0, 2.0).variance) < 2.0 * 12.0  # ~10 Pa per metre at 2 km
    with pytest.raises(ValueError, match="ISA troposphere"):
        cv.baro_msg(0, 12000.0, 2.0)


def _decoded(streams):
    by = {s.topic: s for s in streams}
    fx = [cv.sar_fix_from_msg(deserialize_message(b, PoseWithCovarianceStamped), DATUM) for b in by[T.SAR_FIX].blobs]
    baro = [cv.baro_from_msg(deserialize_message(b, FluidPressure)) for b in by[T.BARO_PRESSURE].blobs]
    return by, fx, baro


def test_simulated_master_publishes_the_sar_fixes_and_barometer() -> None:
    ss = SimulatedSession(load_scenario("paper_sar"), 3, duration_s=400.0)
    streams = device_streams(ss, "master", truth=False)
    by, fx, baro = _decoded(streams)
    ref, ref_b = sar_fixes(ss), baro_heights(ss)
    start_ns = int(round(ss.scenario.start_time_s * 1e9))
    np.testing.assert_array_equal([f.t_ns for f in fx], cv.stamps_ns(ss.scenario.start_time_s, ref.t_s))
    assert len(fx) == 360  # 1 Hz up to the end of the climb (360 s), none in turn_right (360-420 s)
    np.testing.assert_allclose([f.lat_rad for f in fx], ref.llh[:, 0], atol=1e-12)
    np.testing.assert_allclose([f.lon_rad for f in fx], ref.llh[:, 1], atol=1e-12)
    dh = np.mod(np.array([f.heading_rad for f in fx]) - ref.heading_rad + np.pi, 2 * np.pi) - np.pi
    assert np.abs(dh).max() < 1e-10
    np.testing.assert_allclose([f.pos_sigma_m for f in fx], 10.0, rtol=1e-12)
    np.testing.assert_allclose([b[1] for b in baro], ref_b.h_m, atol=1e-6)
    assert baro[0][0] == start_ns + 100_000_000 and len(baro) == 4000
    assert by[T.SAR_FIX].qos == by[T.BARO_PRESSURE].qos == "sensor"
    # same seed -> the same bytes; another seed -> other noise; a scenario without a sar block -> no topics
    again = {s.topic: s for s in device_streams(SimulatedSession(load_scenario("paper_sar"), 3, duration_s=400.0), "master", truth=False)}
    assert list(again[T.SAR_FIX].blobs) == list(by[T.SAR_FIX].blobs) and list(again[T.BARO_PRESSURE].blobs) == list(by[T.BARO_PRESSURE].blobs)
    other = {s.topic: s for s in device_streams(SimulatedSession(load_scenario("paper_sar"), 4, duration_s=400.0), "master", truth=False)}
    assert list(other[T.SAR_FIX].blobs) != list(by[T.SAR_FIX].blobs)
    su = {s.topic for s in device_streams(SimulatedSession(load_scenario("paper_su"), 1, duration_s=5.0), "master", truth=False)}
    assert T.SAR_FIX not in su and T.BARO_PRESSURE not in su


@pytest.mark.parametrize("window_s", [10.0, 7.0])
def test_windowed_simulation_carries_the_same_sar_messages(window_s: float) -> None:
    """dpos-sim --window (chunked_session_streams): every window has /sar/fix and /baro/pressure (empty where
    none), together the whole session's messages byte for byte, whatever the window."""
    from dpos_ros.devices.sim_streams import chunked_session_streams

    ss = SimulatedSession(load_scenario("paper_sar"), 2, duration_s=45.0)
    whole = {s.topic: s for s in device_streams(ss, "master", truth=False)}
    got: dict[str, list[bytes]] = {T.SAR_FIX: [], T.BARO_PRESSURE: []}
    for batch in chunked_session_streams(ss, window_s, truth=False):
        by = {s.topic: s for s in batch}
        assert T.SAR_FIX in by and T.BARO_PRESSURE in by
        for t in got:
            got[t] += [by[t].message(i) for i in range(len(by[t]))]
    for t, msgs in got.items():
        assert msgs == [whole[t].message(i) for i in range(len(whole[t]))], t
