"""Sensor models in datasheet units (dpos_core.config.sensors): presets, the aircraft file's
``master_imu``, the white-noise conversion, and what the simulator draws from each term."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.config.sensors import IMU_PRESETS, ImuErrorModel, imu_model
from dpos_core.sim.sensors import draw_axes_errors, draw_biases, measure
from dpos_core.units import DEG, DEG_PER_H, UG_MPS2


def test_presets_load_and_keys_beside_override():
    assert {"navigation_fog", "tactical", "automotive_mems", "consumer_mems"} <= set(IMU_PRESETS)
    m = imu_model({"preset": "automotive_mems", "gyro_scale_ppm": 8000.0}, "x")
    assert m.gyro_bias_deg_h == IMU_PRESETS["automotive_mems"]["gyro_bias_deg_h"] and m.gyro_scale_ppm == 8000.0
    grades = [imu_model({"preset": p}, "x").gyro_bias_deg_h for p in ("navigation_fog", "tactical", "automotive_mems", "consumer_mems")]
    assert grades == sorted(grades)  # the grades are in order


def test_unknown_preset_and_key_are_errors_naming_them():
    with pytest.raises(ConfigError, match="unknown IMU preset 'mems'.*automotive_mems"):
        imu_model({"preset": "mems"}, "aircraft x: master_imu")
    with pytest.raises(ConfigError, match=r"master_imu: unknown key\(s\) \['gyro_bias'\]"):
        imu_model({"gyro_bias": 1.0}, "aircraft x: master_imu")
    with pytest.raises(ConfigError, match="gyro_bias_tau_s must be > 0"):
        imu_model({"gyro_bias_tau_s": 0.0}, "x")


def test_aircraft_file_states_the_main_imu(tmp_path: Path):
    p = tmp_path / "car.yaml"
    p.write_text("name: car\ngnss_lever_arm_m: [0, 0, 1]\nmaster_imu: {preset: tactical, gyro_bias_deg_h: 2.0}\n")
    ac = load_aircraft(p)
    assert ac.master_imu is not None and ac.master_imu.gyro_bias_deg_h == 2.0 and ac.master_imu.accel_bias_ug == 1000.0
    assert load_aircraft("paper_ifa").master_imu is None  # the seeds' aircraft state none: the scenario's sensor is used


def test_white_sigma_adds_the_papers_noise_and_the_datasheets_density():
    m = ImuErrorModel(gyro_noise_deg_h=3.0, gyro_arw_deg_rth=0.3, accel_noise_ug=40.0, accel_vrw_mps_rth=0.06)
    g, a = m.white_sigma(0.01)
    arw = 0.3 * DEG / 60.0 / np.sqrt(0.01)  # 0.3 deg/sqrt(h) = 0.005 deg/sqrt(s)
    np.testing.assert_allclose(g, np.hypot(3.0 * DEG_PER_H, arw), rtol=1e-12)
    np.testing.assert_allclose(a, np.hypot(40.0 * UG_MPS2, 0.06 / 60.0 / np.sqrt(0.01)), rtol=1e-12)


def test_simulator_draws_each_datasheet_term():
    """Stationary unit (no motion), 100 Hz: the sample std follows the ARW; the in-run bias wanders
    with its sigma and correlation; scale factor and misalignment act on the rate only under motion."""
    m = ImuErrorModel(gyro_arw_deg_rth=0.3, gyro_bias_instability_deg_h=20.0, gyro_bias_tau_s=50.0,
                      gyro_scale_ppm=5000.0, gyro_misalignment_mrad=5.0)
    rng = np.random.default_rng(4)
    n, dt = 200_000, 0.01
    axes = draw_axes_errors(m, rng)
    assert axes is not None
    om, _ = measure(m, np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, dt), (np.zeros(3), np.zeros(3)), rng, axes)
    # the in-run part: a 1 s moving mean removes most of the white noise (0.05 deg/s -> 0.005 deg/s)
    k = 100
    slow = np.convolve(om[:, 0], np.ones(k) / k, mode="valid")
    assert 0.5 * 20.0 * DEG_PER_H < slow.std() < 1.6 * 20.0 * DEG_PER_H
    white = np.diff(om[:, 0]).std() / np.sqrt(2.0)
    np.testing.assert_allclose(white, 0.3 * DEG / 60.0 / np.sqrt(dt), rtol=0.02)
    # constant rotation about z at 10 deg/s: x and y see the misalignment, z the scale factor
    w = np.array([0.0, 0.0, 10.0 * DEG])
    quiet = ImuErrorModel(gyro_scale_ppm=5000.0, gyro_misalignment_mrad=5.0)
    om2, _ = measure(quiet, np.tile(w * dt, (10, 1)), np.zeros((10, 3)), np.full(10, dt), (np.zeros(3), np.zeros(3)), rng, axes)
    np.testing.assert_allclose(om2[0], axes[0] @ w, rtol=1e-12)
    assert abs(om2[0, 2] / w[2] - 1.0) < 0.03 and np.all(np.abs(om2[0, :2]) < 0.03 * w[2])


def test_zero_terms_draw_nothing():
    """A paper's model (bias + white noise only) makes the same draws as before the new terms existed."""
    m = ImuErrorModel(gyro_bias_deg_h=0.01, gyro_noise_deg_h=0.01, accel_bias_ug=50.0, accel_noise_ug=50.0)
    assert draw_axes_errors(m, np.random.default_rng(0)) is None
    r1, r2 = np.random.default_rng(7), np.random.default_rng(7)
    b = draw_biases(m, r1)
    om, f = measure(m, np.zeros((5, 3)), np.zeros((5, 3)), np.full(5, 0.01), b, r1)
    b2 = (r2.normal(0.0, 0.01 * DEG_PER_H, 3), r2.normal(0.0, 50 * UG_MPS2, 3))
    np.testing.assert_array_equal(b[0], b2[0])
    np.testing.assert_allclose(om, b2[0] + r2.normal(0.0, 0.01 * DEG_PER_H, (5, 3)), rtol=1e-15, atol=1e-20)


def test_filters_bias_walk_matches_the_simulated_gauss_markov_drift():
    """The process noise the filters give their constant-bias states (ImuErrorModel.bias_walk_variance,
    used by the IFA and the transfer alignment) is the variance of the simulator's Gauss-Markov bias
    change over an interval: 1 s with tau 100 s, 2000 s of samples, within 10 % (sampling ~2 %)."""
    m = ImuErrorModel(gyro_bias_instability_deg_h=20.0, gyro_bias_tau_s=100.0, accel_bias_instability_ug=400.0, accel_bias_tau_s=100.0)
    n, dt = 200_000, 0.01
    zero = np.zeros((n, 3))
    om, f = measure(m, zero, zero, np.full(n, dt), (np.zeros(3), np.zeros(3)), np.random.default_rng(7))
    lag = 100  # 1 s
    q_g, q_a = m.bias_walk_variance(lag * dt)
    for x, q in ((om, q_g), (f, q_a)):
        d = x[lag::lag] - x[:-lag:lag]
        assert np.var(d) == pytest.approx(q, rel=0.10)
