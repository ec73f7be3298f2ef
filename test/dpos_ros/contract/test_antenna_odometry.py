"""conversions.antenna_odometry_values (the numba kernel of the antenna poses) against
the numpy formulas it replaced, and back through the decoder."""

from __future__ import annotations

import numpy as np

from dpos_core import earth
from dpos_core.attitude import dcm_to_quat, quat_to_dcm, rotvec_to_quat
from dpos_ros.contract import conversions as cv


def _reference(llh: np.ndarray, vel: np.ndarray, C_nb: np.ndarray, s: np.ndarray, datum: np.ndarray) -> np.ndarray:
    """The numpy products of the in-memory path before the kernel (products.write.antenna_stream)."""
    n = llh.shape[0]
    vals = cv.odometry_values(llh, vel, dcm_to_quat(C_nb), datum, None)
    Rw = earth.C_datum_n(llh[:, 0], llh[:, 1], datum)
    pose = np.zeros((n, 6, 6))
    pose[:, :3, :3] = Rw @ (s[:, 6:9, None] ** 2 * np.swapaxes(Rw, 1, 2))
    pose[:, 3:, 3:] = Rw @ (s[:, 0:3, None] ** 2 * np.swapaxes(Rw, 1, 2))
    twist = np.zeros((n, 6, 6))
    twist[:, :3, :3] = np.swapaxes(C_nb, 1, 2) @ (s[:, 3:6, None] ** 2 * C_nb)
    twist[:, 3:, 3:] = -np.eye(3)
    vals[:, 7:43] = pose.reshape(n, 36)
    vals[:, 49:85] = twist.reshape(n, 36)
    return vals


def test_antenna_odometry_values_equal_the_numpy_formulas() -> None:
    rng = np.random.default_rng(7)
    n = 500
    datum = np.array([np.deg2rad(34.2), np.deg2rad(108.9), 420.0])
    llh = datum + np.column_stack([rng.normal(0, 2e-3, n), rng.normal(0, 2e-3, n), rng.normal(3000, 500, n)])
    llh[0] = [np.deg2rad(-89.5), np.deg2rad(179.9), 10.0]  # far from the datum, near a pole
    vel = rng.normal(0, 80, (n, 3))
    C_nb = quat_to_dcm(rotvec_to_quat(rng.normal(0, 1.5, (n, 3))))
    s = np.abs(rng.normal(0, 1e-2, (n, 9)))
    got = cv.antenna_odometry_values(llh, vel, C_nb, s, datum)
    want = _reference(llh, vel, C_nb, s, datum)
    assert got.shape == (n, 85)
    q_sign = np.sign(got[:, 6:7] * want[:, 6:7])  # (xyzw: the same rotation either sign)
    np.testing.assert_allclose(got[:, 3:7], want[:, 3:7] * q_sign, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got[:, :3], want[:, :3], rtol=0, atol=1e-7)  # metres, positions up to 1e7 m
    np.testing.assert_allclose(got[:, 43:46], want[:, 43:46], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, 7:43], want[:, 7:43], rtol=0, atol=1e-18)
    np.testing.assert_allclose(got[:, 46:85], want[:, 46:85], rtol=0, atol=1e-18)
    # and back: the decoder gives the row's position, velocity, attitude and covariances
    back = cv.odometry_from_values(np.arange(n, dtype=np.int64), got, datum)
    np.testing.assert_allclose(back.llh[:, :2], llh[:, :2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.llh[:, 2], llh[:, 2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.vel_n_mps, vel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(quat_to_dcm(back.q_nb), C_nb, rtol=0, atol=1e-12)
    R = earth.C_datum_n(llh[:, 0], llh[:, 1], datum)
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ back.pose_cov[:, :3, :3] @ R,
                               np.apply_along_axis(np.diag, 1, s[:, 6:9] ** 2), rtol=0, atol=1e-15)
