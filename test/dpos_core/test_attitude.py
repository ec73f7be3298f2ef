"""Attitude representations and conventions, cross-checked against scipy.spatial.transform."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dpos_core import attitude as att
from dpos_core import frames
from dpos_core.units import DEG


@pytest.fixture
def rots() -> Rotation:
    return Rotation.random(2000, random_state=7)


def test_quaternion_dcm_rotvec_agree_with_scipy(rots: Rotation) -> None:
    q_sp = rots.as_quat()  # scalar last
    q = np.concatenate([q_sp[:, 3:], q_sp[:, :3]], axis=1)
    np.testing.assert_allclose(att.quat_to_dcm(q), rots.as_matrix(), atol=1e-14)
    q_back = att.dcm_to_quat(rots.as_matrix())
    np.testing.assert_allclose(np.abs(np.sum(q_back * q, axis=1)), 1.0, atol=1e-14)
    np.testing.assert_allclose(att.rotvec_to_dcm(rots.as_rotvec()), rots.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(att.dcm_to_rotvec(rots.as_matrix()), rots.as_rotvec(), atol=1e-12)
    np.testing.assert_allclose(att.quat_to_rotvec(att.rotvec_to_quat(rots.as_rotvec())), rots.as_rotvec(), atol=1e-12)


def test_quaternion_product_composes_rotations(rots: Rotation) -> None:
    a, b = rots[:1000], rots[1000:]
    qa = att.dcm_to_quat(a.as_matrix())
    qb = att.dcm_to_quat(b.as_matrix())
    np.testing.assert_allclose(att.quat_to_dcm(att.quat_mul(qa, qb)), (a * b).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(att.quat_mul(qa, att.quat_conj(qa)), np.tile([1.0, 0, 0, 0], (1000, 1)), atol=1e-15)


def test_small_rotation_vectors_are_accurate() -> None:
    phi = np.array([[1e-9, -2e-9, 3e-10], [3e-7, 1e-7, -2e-7], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(att.rotvec_to_dcm(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-18)
    np.testing.assert_allclose(att.dcm_to_rotvec(att.rotvec_to_dcm(phi)), phi, atol=1e-18, rtol=1e-9)


def test_skew_is_cross_product() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", att.skew(a), b), np.cross(a, b), atol=1e-14)


def test_attitude_error_large_angles_and_heading_wrap(rots: Rotation) -> None:
    rng = np.random.default_rng(3)
    axis = rng.normal(size=(2000, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    phi = axis * rng.uniform(0.0, 3.0, (2000, 1))  # up to 172 deg
    C_true = rots.as_matrix()
    C_est = att.rotvec_to_dcm(-phi) @ C_true
    np.testing.assert_allclose(att.attitude_error(C_est, C_true), phi, atol=1e-11)
    np.testing.assert_allclose(att.apply_attitude_correction(C_est, phi), C_true, atol=1e-14)
    # heading 359 deg estimated, 1 deg true: the estimate's nose is turned 2 deg counter-clockwise
    # (+2 deg about Up), C_est = Rz(+2 deg) C_true = expm(-[phi x]) C_true -> phi_U = -2 deg,
    # i.e. phi_U = heading_est - heading_true (wrapped), not 358 deg
    C_est = frames.C_nb_from_hpr(359 * DEG, 3 * DEG, -2 * DEG)
    C_true = frames.C_nb_from_hpr(1 * DEG, 3 * DEG, -2 * DEG)
    phi = att.attitude_error(C_est, C_true)
    np.testing.assert_allclose(phi, [0.0, 0.0, -2 * DEG], atol=1e-12)
    assert frames.hpr_error([359 * DEG, 0, 0], [1 * DEG, 0, 0])[0] == pytest.approx(-2 * DEG)


def test_aviation_euler_matches_scipy_and_round_trips() -> None:
    rng = np.random.default_rng(5)
    hpr = np.stack([rng.uniform(0, 2 * np.pi, 5000), rng.uniform(-1.5, 1.5, 5000), rng.uniform(-np.pi, np.pi, 5000)], 1)
    C = frames.C_nb_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2])
    # scipy intrinsic ZYX = Rz(h) Ry(p) Rx(r) for an FRD body in NED
    C_ned_frd = Rotation.from_euler("ZYX", hpr).as_matrix()
    np.testing.assert_allclose(frames.C_ENU_NED @ C_ned_frd @ frames.C_FLU_FRD, C, atol=1e-14)
    np.testing.assert_allclose(frames.hpr_from_C_nb(C), hpr, atol=1e-10)


def test_named_attitude_cases() -> None:
    # level, nose north: heading 0, forward axis = north
    C = frames.C_nb_from_hpr(0.0, 0.0, 0.0)
    np.testing.assert_allclose(C[:, 0], [0, 1, 0], atol=1e-15)  # x forward -> north
    np.testing.assert_allclose(C[:, 1], [-1, 0, 0], atol=1e-15)  # y left -> west
    np.testing.assert_allclose(frames.hpr_from_C_nb(C), [0, 0, 0], atol=1e-15)
    # nose east: heading 90 deg
    C = frames.C_nb_from_hpr(90 * DEG, 0.0, 0.0)
    np.testing.assert_allclose(C[:, 0], [1, 0, 0], atol=1e-15)
    assert frames.hpr_from_C_nb(C)[0] == pytest.approx(90 * DEG)
    # nose up: positive pitch lifts the forward axis
    assert frames.C_nb_from_hpr(0.0, 10 * DEG, 0.0)[2, 0] == pytest.approx(np.sin(10 * DEG))
    # right wing down: positive roll; the right wing is -y (FLU), its Up component is negative
    C = frames.C_nb_from_hpr(0.0, 0.0, 20 * DEG)
    assert (C @ [0.0, -1.0, 0.0])[2] == pytest.approx(-np.sin(20 * DEG))
    # REP 103 yaw (ENU, CCW from east) vs aviation heading (CW from north)
    assert frames.yaw_from_heading(0.0) == pytest.approx(90 * DEG)
    assert frames.yaw_from_heading(90 * DEG) == pytest.approx(0.0)
    assert frames.yaw_from_heading(270 * DEG) == pytest.approx(180 * DEG)
    assert frames.heading_from_yaw(-90 * DEG) == pytest.approx(180 * DEG)
    # the yaw of a level FLU body in ENU is the rotation about z of Rz(yaw)
    yaw = frames.yaw_from_heading(30 * DEG)
    np.testing.assert_allclose(frames.C_nb_from_hpr(30 * DEG, 0, 0), Rotation.from_euler("z", yaw).as_matrix(), atol=1e-15)


def test_seed_rfu_convention() -> None:
    """[Gong2018] eq. 19: C_b^n(RFU, ENU) with psi counter-clockwise; same body as our FLU attitude."""
    rng = np.random.default_rng(9)
    h, p, r = rng.uniform(0, 2 * np.pi, 500), rng.uniform(-1.4, 1.4, 500), rng.uniform(-3, 3, 500)
    psi = frames.seed_psi_from_heading(h)
    C_rfu = frames.C_nb_rfu_from_seed_angles(psi, p, r)
    # literal elements of eq. 19 (phi_m = psi, theta_m = pitch, gamma_m = roll)
    np.testing.assert_allclose(C_rfu[:, 0, 1], -np.cos(p) * np.sin(psi), atol=1e-14)
    np.testing.assert_allclose(C_rfu[:, 1, 1], np.cos(p) * np.cos(psi), atol=1e-14)
    np.testing.assert_allclose(C_rfu[:, 2, 0], -np.sin(r) * np.cos(p), atol=1e-14)
    np.testing.assert_allclose(
        C_rfu[:, 0, 0], np.cos(r) * np.cos(psi) - np.sin(r) * np.sin(p) * np.sin(psi), atol=1e-14
    )
    # the same physical body attitude as the aviation angles of an FLU body
    C_flu = frames.C_nb_from_hpr(h, p, r)
    np.testing.assert_allclose(frames.C_nb_rfu_from_flu(C_flu), C_rfu, atol=1e-14)
    np.testing.assert_allclose(frames.C_nb_flu_from_rfu(C_rfu), C_flu, atol=1e-14)
    np.testing.assert_allclose(frames.seed_angles_from_C_nb_rfu(C_rfu), np.stack([psi, p, r], 1), atol=1e-10)
    np.testing.assert_allclose(frames.heading_from_seed_psi(psi), h, atol=1e-12)
    # body vectors: RFU forward (y) is FLU x; RFU right (x) is FLU -y
    np.testing.assert_allclose(frames.vec_flu_from_rfu([0.0, 1.0, 0.0]), [1, 0, 0])
    np.testing.assert_allclose(frames.vec_flu_from_rfu([1.0, 0.0, 0.0]), [0, -1, 0])
    v = rng.normal(size=(10, 3))
    np.testing.assert_allclose(frames.vec_rfu_from_flu(frames.vec_flu_from_rfu(v)), v)
    # [Gong2018] lever arm [5, 0.1, 0.1] m RFU = 5 m out on the right wing
    np.testing.assert_allclose(frames.vec_flu_from_rfu([5.0, 0.1, 0.1]), [0.1, -5.0, 0.1])


def test_hpr_from_C_nb_is_the_products_angles_bit_for_bit() -> None:
    """``hpr_from_C_nb`` without the 3 x 3 products: the same bits as through ``C_ENU_NED @ C @
    C_FLU_FRD`` (the antenna CSV's attitude), for random DCMs, DCMs of exact zeros of either sign
    and rows with NaN."""
    from dpos_core.attitude import quat_to_dcm
    from dpos_core.frames import C_ENU_NED, C_FLU_FRD, C_nb_from_hpr, hpr_from_C_nb

    def by_products(C_nb: np.ndarray) -> np.ndarray:
        C = C_ENU_NED @ C_nb @ C_FLU_FRD
        return np.stack([np.mod(np.arctan2(C[..., 1, 0], C[..., 0, 0]), 2.0 * np.pi), -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0)),
                         np.arctan2(C[..., 2, 1], C[..., 2, 2])], axis=-1)

    rng = np.random.default_rng(5)
    q = rng.normal(size=(5000, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    right = rng.choice([0.0, -0.0, np.pi / 2, -np.pi / 2, np.pi, 0.3], (3, 2000))
    signed = rng.choice([0.0, -0.0, 1.0, -1.0, 0.5, np.nan], (2000, 3, 3))
    with np.errstate(invalid="ignore"):
        for C in (quat_to_dcm(q), C_nb_from_hpr(*right), signed, quat_to_dcm(q)[0], signed[:4]):
            a, b = by_products(C), hpr_from_C_nb(C)
            assert a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def test_compose_rotvec_with_one_right_factor_is_the_broadcast() -> None:
    """compose_rotvec(a (..., 3), b (3,)) (kernel rows_compose_rotvec_one) = b repeated for every row, bit for bit."""
    from dpos_core import _attitude_kernel as _ak
    from dpos_core.attitude import compose_rotvec

    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(4, 5, 3)), rng.normal(size=3) * 0.1
    rows = a.reshape(-1, 3)
    out = np.empty_like(rows)
    _ak.rows_compose_rotvec(rows, np.ascontiguousarray(np.broadcast_to(b, rows.shape)), out)
    np.testing.assert_array_equal(compose_rotvec(a, b), out.reshape(a.shape))
    np.testing.assert_array_equal(compose_rotvec(a[0, 0], b), out[0])


def test_rotate_normalize_kernel_is_the_numpy_formula() -> None:
    """_attitude_kernel.rotate_normalize (Strapdown.correct's attitude) = quat_normalize(rotvec_to_quat(phi) * q), bit for bit."""
    from dpos_core import _attitude_kernel as _ak

    rng = np.random.default_rng(13)
    for _ in range(50):
        q = att.quat_normalize(rng.normal(size=4))
        phi = rng.normal(size=3) * rng.choice([1e-9, 1e-4, 0.3, 2.0])
        ref = att.quat_normalize(np.array(_ak.quat_mul(*_ak.rotvec_quat(*phi), *q)))
        out = q.copy()
        _ak.rotate_normalize(out, phi)
        np.testing.assert_array_equal(out, ref)


def test_hpr_of_a_corrupted_matrix_is_nan_and_of_large_finite_ones_finite() -> None:
    """An infinite element makes the three angles NaN (not a pitch of 90 deg from a clipped
    infinity); huge finite elements are not taken for non-finite ones (no sum that overflows)."""
    C = np.stack([np.eye(3)] * 3)
    C[0, 2, 0] = np.inf
    C[1, 0, :] = 1e308
    hpr = frames.hpr_from_C_nb(C)
    assert np.all(np.isnan(hpr[0])) and np.all(np.isfinite(hpr[1]))
    np.testing.assert_array_equal(hpr[2], frames.hpr_from_C_nb(np.eye(3)))
