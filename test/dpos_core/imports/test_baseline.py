"""The lever arm between two IMUs from their specific-force differences (dpos_core.imports.baseline):
two simulated IMUs on a rigid body with a known lever arm and mounting."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.attitude import cross, mount_dcm, rotvec_to_dcm
from dpos_core.errors import MountingNotObservable
from dpos_core.imports.baseline import lever_arm_from_specific_force
from dpos_core.series import ImuSeries

R_TRUE = np.array([0.12, -0.21, 0.05])  #: IMU b from IMU a, a's axes [m]
C_AB = mount_dcm((1.0, -0.5, 2.0), (0.0, 0.0, 0.0))  #: b's axes -> a's
BIAS_B = np.array([0.03, -0.02, 0.05])  #: b's accelerometer bias [m/s^2]


def rigid_pair(seed: int, amp_radps: float = 0.6, duration_s: float = 60.0, hz: float = 120.0, f_noise: float = 0.05,
               w_noise: float = 0.005, f_noise_cov: np.ndarray | None = None, tilt: bool = False) -> tuple[np.ndarray, ...]:
    """Two IMUs on a rigid body turning by sums of sinusoids (about every axis): a at the origin, b
    at R_TRUE turned by C_AB, each with white noise (b's samples half a step later than a's):
    ``f_noise`` [m/s^2] on every axis, or ``f_noise_cov`` (3, 3) in each IMU's axes (a
    multirotor's vibration: several times larger along the thrust axis, the horizontal axes
    correlated).  ``tilt``: the specific force also carries gravity's share of the body's
    tilt (the small-angle integral of the rate about x and y), as on an aircraft that tilts to
    manoeuvre: then a rotation error between the IMUs leaks into the arm.  Returns a's and b's logs."""
    rng = np.random.default_rng(seed)
    freqs = rng.uniform(0.2, 1.5, (3, 3))
    phases = rng.uniform(0, 2 * np.pi, (3, 3))

    def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        arg = 2 * np.pi * freqs[None] * t[:, None, None] + phases[None]
        w = amp_radps / 3 * np.sin(arg).sum(axis=2)
        alpha = amp_radps / 3 * (2 * np.pi * freqs[None] * np.cos(arg)).sum(axis=2)
        # the common specific force: gravity-like plus a slow linear acceleration (a's axes)
        f = np.column_stack([0.8 * np.sin(0.7 * t), 0.5 * np.cos(0.4 * t), 9.81 + 0.3 * np.sin(1.1 * t)])
        if tilt:  # theta = integral of w (small angles); gravity's share: (g theta_y, -g theta_x, 0)
            theta = -amp_radps / 3 * (np.cos(arg) / (2 * np.pi * freqs[None])).sum(axis=2)
            f = f + 9.81 * np.column_stack([theta[:, 1], -theta[:, 0], np.zeros_like(t)])
        return w, alpha, f

    def f_err(shape: tuple[int, ...]) -> np.ndarray:
        if f_noise_cov is None:
            return f_noise * rng.standard_normal(shape)
        return rng.standard_normal(shape) @ np.linalg.cholesky(f_noise_cov).T

    t_a = np.arange(0.0, duration_s, 1 / hz)
    t_b = t_a + 0.5 / hz
    w, _, f = motion(t_a)
    f_a = f + f_err(f.shape)
    w_a = w + w_noise * rng.standard_normal(w.shape)
    w, alpha, f = motion(t_b)
    fb_a = f + cross(alpha, R_TRUE) + cross(w, cross(w, R_TRUE))
    f_b = fb_a @ C_AB + BIAS_B + f_err(f.shape)  # (C_AB^T fb_a per row)
    w_b = w @ C_AB + w_noise * rng.standard_normal(w.shape)
    return ImuSeries(t_a, w_a, f_a), ImuSeries(t_b, w_b, f_b)


def test_lever_arm_recovered_within_its_sigma() -> None:
    """Ten rigid bodies with noise: the lever arm within 3 sigma on every axis each time, within 2
    sigma on most (the sigma honest: not far too large either - below 1 cm - and the normalized
    errors' rms between 0.5 and 1.6), and the bias difference found."""
    z = []
    for seed in range(10):
        e = lever_arm_from_specific_force(*rigid_pair(seed), C_AB)
        err = e.r_m - R_TRUE
        assert np.all(np.abs(err) < 3 * e.r_sigma_m), (seed, err, e.r_sigma_m)
        assert np.all(e.r_sigma_m < 0.01), e.r_sigma_m
        assert np.all(np.abs(e.bias_diff_mps2 - C_AB @ BIAS_B) < 4 * e.bias_diff_sigma_mps2 + 1e-3), (e.bias_diff_mps2, C_AB @ BIAS_B)
        z.append(err / e.r_sigma_m)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 < rms < 1.6, rms


#: quad_mimu's residuals (path 3, DOT1-DOT2, 0.05 s): rms 0.27 / 0.12 / 0.47 m/s^2, x-y correlation -0.78;
#: here per 120 Hz sample, x-y correlation -0.8, z four times x
VIBRATION_COV = np.array([[0.5**2, -0.8 * 0.5 * 0.35, 0.0], [-0.8 * 0.5 * 0.35, 0.35**2, 0.0], [0.0, 0.0, 2.0**2]])


def test_anisotropic_vibration_covered() -> None:
    """The residuals' noise as on quad_mimu: four times larger along z, x and y correlated (-0.8).
    One variance pooled over the three axes puts the y sigma too low and the z sigma far too high
    (normalized errors' rms 1.1 / 1.5 / 0.4 on x / y / z, measured with the pooled sigma); the
    residuals' 3 x 3 covariance weighs (1) (feasible GLS): every axis within 3 sigma, the
    normalized errors' rms between 0.6 and 1.4 on each axis (1.1 / 1.0 / 0.9), the z sigma below
    the x / y ones."""
    z, sig = [], []
    for seed in range(12):
        e = lever_arm_from_specific_force(*rigid_pair(seed, f_noise_cov=VIBRATION_COV), C_AB)
        err = e.r_m - R_TRUE
        assert np.all(np.abs(err) < 3 * e.r_sigma_m), (seed, err, e.r_sigma_m)
        assert e.residual_cov_mps4[0, 1] < 0 and e.residual_cov_mps4[2, 2] > 4 * e.residual_cov_mps4[0, 0], e.residual_cov_mps4
        z.append(err / e.r_sigma_m)
        sig.append(e.r_sigma_m)
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.6) & (rms < 1.4)), rms
    s = np.median(sig, axis=0)
    assert s[2] < min(s[0], s[1]), s


def test_relative_rotation_error_covered() -> None:
    """The rotation between the IMUs is an estimate: on a body that tilts to manoeuvre (gravity's
    share of the tilt varies with the angular acceleration), a 1 deg rotation error per axis
    moves the arm by several of its noise sigmas; with the rotation's covariance given (errors in
    variables) the sigma covers it (normalized errors' rms 1.0, none beyond 2.5), without it the
    errors are outside (rms 2.6, up to 5.4)."""
    P = np.deg2rad(1.0) ** 2 * np.eye(3)
    rng = np.random.default_rng(7)
    z_with, z_without = [], []
    for seed in range(12):
        C_est = rotvec_to_dcm(rng.multivariate_normal(np.zeros(3), P)) @ C_AB
        a, b = rigid_pair(seed, tilt=True)
        e = lever_arm_from_specific_force(a, b, C_est, C_ab_cov_rad2=P)
        e0 = lever_arm_from_specific_force(a, b, C_est)
        z_with.append((e.r_m - R_TRUE) / e.r_sigma_m)
        z_without.append((e0.r_m - R_TRUE) / e0.r_sigma_m)
    assert np.abs(z_with).max() < 3.5, np.round(z_with, 2)
    assert float(np.sqrt(np.mean(np.square(z_with)))) < 1.5, np.round(z_with, 2)
    assert float(np.sqrt(np.mean(np.square(z_without)))) > 2.0, np.round(z_without, 2)


def test_wrong_lever_arm_is_outside_the_sigma() -> None:
    """The estimate tells lever arms apart: b moved by 5 cm along x is found 5 cm away, many sigmas
    off the first arm."""
    global R_TRUE
    keep = R_TRUE
    try:
        R_TRUE = keep + np.array([0.05, 0.0, 0.0])
        e = lever_arm_from_specific_force(*rigid_pair(3), C_AB)
    finally:
        R_TRUE = keep
    assert abs(e.r_m[0] - keep[0] - 0.05) < 3 * e.r_sigma_m[0]
    assert abs(e.r_m[0] - keep[0]) > 10 * e.r_sigma_m[0]


def test_no_rotation_is_refused() -> None:
    """A body that does not turn: the lever arm is not observable, refused (no guess)."""
    with pytest.raises(MountingNotObservable, match="not observable"):
        lever_arm_from_specific_force(*rigid_pair(0, amp_radps=0.0), C_AB)


def test_too_short_overlap_is_refused() -> None:
    a, b = rigid_pair(0, duration_s=0.5)
    with pytest.raises(MountingNotObservable, match="overlap"):
        lever_arm_from_specific_force(a, b, C_AB)
