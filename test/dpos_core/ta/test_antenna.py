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


def test_rate_at_the_rows_from_step_means_has_no_half_step_lag() -> None:
    """A 4 Hz rotation sampled at 100 Hz as step means: the rate at a stamp taken as that sample's
    mean lags by half a step (2 pi f dt / 2 = 12.6 % of the amplitude); attributed to the steps'
    middles and interpolated, it is right to the curvature, (2 pi f dt)^2 / 8 = 0.8 % (1.5 %)."""
    from dpos_core.ta.antenna import rate_at

    f, A, dt = 4.0, 0.05, 0.01
    t = np.arange(1, 1001) * dt
    w = 2 * np.pi * f
    mean = A * (np.cos(w * (t - dt)) - np.cos(w * t)) / (w * dt)  # the mean of A sin(w t) over each step
    true = A * np.sin(w * t)
    held = np.max(np.abs(mean - true))
    interp = np.max(np.abs(rate_at(t, np.stack([mean] * 3, axis=1), t)[1:-1, 0] - true[1:-1]))
    assert held > 0.1 * A
    assert interp < 0.015 * A


def test_rate_interpolation_variance_matches_a_rough_rate() -> None:
    """A rate whose steps are independent (broadband vibration at the sample scale): the predicted
    variance of the interpolated rate at the stamps equals the actual squared error on average, and
    through a 0.2 m lever it is the antenna velocity's variance."""
    from dpos_core.ta.antenna import lever_velocity_var, rate_at, rate_interpolation_var

    rng = np.random.default_rng(5)
    dt, n, sub = 0.01, 20_000, 20
    fine = np.cumsum(rng.normal(0.0, 0.003, (n * sub, 3)), axis=0)  # a random-walk rate [rad/s]
    means = fine.reshape(n, sub, 3).mean(axis=1)  # the samples: step means
    t = np.arange(1, n + 1) * dt
    true = fine[sub - 1::sub]  # the rate at each stamp (the end of its step)
    err = rate_at(t, means, t) - true
    pred = rate_interpolation_var(t, means, t)
    ratio = np.mean(err[100:-100] ** 2, axis=0) / np.mean(pred[100:-100], axis=0)
    assert np.all((ratio > 0.7) & (ratio < 1.5)), ratio
    C = np.broadcast_to(np.eye(3), (n, 3, 3))
    v = lever_velocity_var(C, pred, [0.0, 0.0, -0.2])
    assert np.allclose(v[:, 2], 0.0) and np.allclose(v[:, 0], pred[:, 1] * 0.04) and np.allclose(v[:, 1], pred[:, 0] * 0.04)
