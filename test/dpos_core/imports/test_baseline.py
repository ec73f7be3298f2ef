"""The lever arm between two IMUs from their specific-force differences (dpos_core.imports.baseline):
two simulated IMUs on a rigid body with a known lever arm and mounting."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.attitude import cross, mount_dcm
from dpos_core.errors import MountingNotObservable
from dpos_core.imports.baseline import lever_arm_from_specific_force
from dpos_core.series import ImuSeries

R_TRUE = np.array([0.12, -0.21, 0.05])  #: IMU b from IMU a, a's axes [m]
C_AB = mount_dcm((1.0, -0.5, 2.0), (0.0, 0.0, 0.0))  #: b's axes -> a's
BIAS_B = np.array([0.03, -0.02, 0.05])  #: b's accelerometer bias [m/s^2]


def rigid_pair(seed: int, amp_radps: float = 0.6, duration_s: float = 60.0, hz: float = 120.0, f_noise: float = 0.05,
               w_noise: float = 0.005) -> tuple[np.ndarray, ...]:
    """Two IMUs on a rigid body turning by sums of sinusoids (about every axis): a at the origin, b
    at R_TRUE turned by C_AB, each with white noise (b's samples half a step later than a's).
    Returns a's and b's logs."""
    rng = np.random.default_rng(seed)
    freqs = rng.uniform(0.2, 1.5, (3, 3))
    phases = rng.uniform(0, 2 * np.pi, (3, 3))

    def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        arg = 2 * np.pi * freqs[None] * t[:, None, None] + phases[None]
        w = amp_radps / 3 * np.sin(arg).sum(axis=2)
        alpha = amp_radps / 3 * (2 * np.pi * freqs[None] * np.cos(arg)).sum(axis=2)
        # the common specific force: gravity-like plus a slow linear acceleration (a's axes)
        f = np.column_stack([0.8 * np.sin(0.7 * t), 0.5 * np.cos(0.4 * t), 9.81 + 0.3 * np.sin(1.1 * t)])
        return w, alpha, f

    t_a = np.arange(0.0, duration_s, 1 / hz)
    t_b = t_a + 0.5 / hz
    w, _, f = motion(t_a)
    f_a = f + f_noise * rng.standard_normal(f.shape)
    w_a = w + w_noise * rng.standard_normal(w.shape)
    w, alpha, f = motion(t_b)
    fb_a = f + cross(alpha, R_TRUE) + cross(w, cross(w, R_TRUE))
    f_b = fb_a @ C_AB + BIAS_B + f_noise * rng.standard_normal(f.shape)  # (C_AB^T fb_a per row)
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
