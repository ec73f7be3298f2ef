"""dpos_core.ta.antenna: the lever-arm kinematics from a sub-IMU to its antenna, checked by hand."""

from __future__ import annotations

import numpy as np

from dpos_core import earth
from dpos_core.ta.antenna import antenna_motion
from dpos_core.units import DEG


def test_antenna_one_metre_east_of_a_turning_imu() -> None:
    lat, h = 40.0 * DEG, 500.0
    llh = np.array([[lat, 116.0 * DEG, h]] * 2)
    C_nb = np.stack([np.eye(3)] * 2)  # body axes = E, N, U
    w_ie_n = earth.earth_rate_n(llh[:, 0])
    omega_ib = w_ie_n + np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]])  # at rest; then yawing at 0.1 rad/s
    vel = np.zeros((2, 3))
    llh_a, vel_a = antenna_motion(C_nb, vel, llh, omega_ib, [1.0, 0.0, 0.0])
    # 1 m east: longitude grows by 1 / ((N + h) cos lat), to the second order in 1 m / 6.4e6 m
    a, e2 = 6378137.0, 6.69437999014e-3
    N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    np.testing.assert_allclose(llh_a[:, 1] - llh[:, 1], 1.0 / ((N + h) * np.cos(lat)), rtol=1e-6)
    np.testing.assert_allclose(llh_a[:, 0], lat, atol=1e-12)  # 1e-12 rad = 6 um north
    np.testing.assert_allclose(llh_a[:, 2], h, atol=1e-6)  # the curvature drop over 1 m: 8e-8 m
    # velocity: the Earth's rate cancels at rest; a 0.1 rad/s yaw moves the tip north at 0.1 m/s
    np.testing.assert_allclose(vel_a[0], [0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(vel_a[1], [0.0, 0.1, 0.0], atol=1e-15)
