"""Sub-IMUs on the flexing wing and sensor error models."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import attitude_error, dcm_to_quat, mount_dcm, right_jacobian, rotvec_to_dcm
from dpos_core.config.flexure import FlexureModel
from dpos_core.config.sensors import GnssModel, ImuErrorModel, NoiseInterval
from dpos_core.kinematics import increments_from_motion, nav_from_ecef
from dpos_core.sim.bodies import flexed_body_motion, rigid_offset_motion
from dpos_core.sim.flexure import FlexureRealization
from dpos_core.sim.flight import Flight, FlightStart, Segment
from dpos_core.sim.sensors import draw_biases, measure
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.units import DEG_PER_H, UG_MPS2


def test_right_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(0)
    for th in (rng.normal(size=3) * 0.3, rng.normal(size=3) * 1e-6):
        thd = rng.normal(size=3)
        h = 1e-6
        R0, R1 = rotvec_to_dcm(th - h * thd), rotvec_to_dcm(th + h * thd)
        Rdot = (R1 - R0) / (2 * h)
        W = rotvec_to_dcm(th).T @ Rdot
        np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], right_jacobian(th) @ thd, atol=1e-8)


def test_flexing_sub_imu_integrates_back_to_its_truth() -> None:
    """paper_su geometry: sub-IMU 5 m out on the right wing (FLU [0.1, -5, 0.1]), rho = 0.5 deg per
    axis, flexure tau 2/5/2 s, variance 0.01/0.15/0.01 deg^2, 1300 s at 100 Hz.  The gyro sees
    theta_dot, the accelerometer the flexing lever arm; integrated with our strapdown the ideal
    increments must return the sub-IMU truth (issue bound: 0.5 m, 1e-5 rad; measured 3 cm,
    4e-9 rad; the flexure's rough rate makes the trapezoid error larger than for the master)."""
    segs = [Segment(200), Segment(100, 60), Segment(100, -60), Segment(400), Segment(100, 180), Segment(400)]
    fl = Flight(FlightStart(40, 116, 500, 100, 40), segs)
    fr = FlexureRealization.sample(FlexureModel((2.0, 5.0, 2.0), (0.01, 0.15, 0.01)), fl.duration_s, 0.01, np.random.default_rng(3))
    sub = flexed_body_motion(fl.ecef_motion, [0.1, -5.0, 0.1], mount_dcm([0, 0, 0], [0.5, 0.5, 0.5]), lambda t: fr.at(t, 5.0))
    fs = 100.0
    t = np.arange(0.0, fl.duration_s + 0.5 / fs, 1.0 / fs)
    dth, dv = increments_from_motion(sub, t)
    p, v, C, _ = sub(t)
    llh, vn, Cnb = nav_from_ecef(p, v, C)
    out = Strapdown(NavState(0.0, dcm_to_quat(Cnb[0]), vn[0], llh[0])).run_increments(t[1:], dth, dv)
    r_m, r_n = earth.radii_of_curvature(llh[1:, 0])
    d = out.llh - llh[1:]
    pos = np.abs(np.stack([d[:, 0] * r_m, d[:, 1] * r_n * np.cos(llh[1:, 0]), d[:, 2]], 1)).max(0)
    assert pos.max() < 0.5, pos
    assert np.abs(attitude_error(out.C_nb, Cnb[1:])).max() < 1e-5
    # the flexure really acts: the sub-IMU attitude departs from master * rho by the flexure angle
    _, _, C_m, _ = fl.ecef_motion(t)
    rel = attitude_error(C, C_m @ mount_dcm([0, 0, 0], [0.5, 0.5, 0.5]))
    assert np.rad2deg(np.abs(rel).max(axis=0)).min() > 0.1


def test_rigid_offset_velocity_is_omega_cross_r() -> None:
    fl = Flight(FlightStart(40, 116, 500, 100, 0), [Segment(60.0, 90.0)])
    ant = rigid_offset_motion(fl.ecef_motion, [0.0, -10.0, 0.0])
    t = np.array([30.0])
    p_m, v_m, C, w = fl.ecef_motion(t)
    p_a, v_a, _, _ = ant(t)
    np.testing.assert_allclose(np.linalg.norm(p_a - p_m), 10.0, atol=1e-8)  # ECEF ~6.4e6 m: ~1e-10 m rounding
    np.testing.assert_allclose(v_a[0] - v_m[0], C[0] @ np.cross(w[0], [0.0, -10.0, 0.0]), atol=1e-12)
    # a right turn (yaw rate < 0 in FLU) moves the right-wing tip (-y) backwards relative to the master
    assert (C[0].T @ (v_a[0] - v_m[0]))[0] < 0.0


def test_imu_noise_matches_its_configuration() -> None:
    """Sample std of 200,000 samples: relative standard error 1/sqrt(2N) = 0.16 %; tolerance 1 %."""
    m = ImuErrorModel(gyro_bias_deg_h=0.01, gyro_noise_deg_h=0.01, accel_bias_ug=50.0, accel_noise_ug=50.0)
    rng = np.random.default_rng(11)
    n, dt = 200_000, 0.01
    biases = draw_biases(m, rng)
    om, f = measure(m, np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, dt), biases, rng)
    np.testing.assert_allclose(om.std(axis=0), 0.01 * DEG_PER_H, rtol=0.01)
    np.testing.assert_allclose(f.std(axis=0), 50 * UG_MPS2, rtol=0.01)
    np.testing.assert_allclose(om.mean(axis=0), biases[0], atol=5 * 0.01 * DEG_PER_H / np.sqrt(n))
    with pytest.raises(ValueError, match="gyro_noise_deg_h"):
        ImuErrorModel(gyro_noise_deg_h=-1.0)


def test_gnss_schedule() -> None:
    g = GnssModel(schedule=(NoiseInterval(20, 40, scale=3.0), NoiseInterval(50, 80, outage=True)))
    scale, ok = g.scale_at(np.array([10.0, 20.0, 39.9, 40.0, 60.0, 80.0]))
    np.testing.assert_allclose(scale, [1, 3, 3, 1, 1, 1])
    np.testing.assert_array_equal(ok, [True, True, True, True, False, True])
    with pytest.raises(ValueError, match="zero covariance"):
        GnssModel(pos_sigma_m=(0.0, 1.0, 1.0))
