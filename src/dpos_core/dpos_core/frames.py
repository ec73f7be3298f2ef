"""Body and world axis conventions, and Euler angles.

This module is the one place that knows how the product's REP 103 frames (body FLU: x forward,
y left, z up; world ENU) relate to the papers' frames (body RFU: x right, y forward, z up;
world ENU) and to the Euler angles that reports use.

Aviation angles (reports, parameters):
    heading  clockwise from north, [0, 2 pi)
    pitch    nose up positive, [-pi/2, pi/2]
    roll     right wing down positive, (-pi, pi]
    with ``C_ned_frd = Rz(heading) Ry(pitch) Rx(roll)`` (the aerospace 3-2-1 sequence).

Seed angles ([Gong2018] eq. 19, [Fang2012]): ``C_b^n = Rz(psi) Rx(theta) Ry(gamma)`` for an RFU body
in ENU.  Here ``psi`` is measured counter-clockwise from north (towards west), so
``psi = -heading``; ``theta`` = pitch, ``gamma`` = roll (same signs as aviation).

REP 103 yaw (ENU world, FLU body) is measured counter-clockwise from east: ``yaw = pi/2 - heading``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from .attitude import wrap_angle

#: Vector in RFU body axes -> FLU body axes (``v_flu = C_FLU_RFU @ v_rfu``).
C_FLU_RFU: FloatArray = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
C_RFU_FLU: FloatArray = C_FLU_RFU.T.copy()
#: NED world -> ENU world, and FRD body -> FLU body (both are their own inverse).
C_ENU_NED: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
C_FLU_FRD: FloatArray = np.diag([1.0, -1.0, -1.0])


def _rx(a: FloatArray) -> FloatArray:
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a: FloatArray) -> FloatArray:
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a: FloatArray) -> FloatArray:
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def C_nb_from_hpr(heading_rad: ArrayLike, pitch_rad: ArrayLike, roll_rad: ArrayLike) -> FloatArray:
    """Aviation heading/pitch/roll -> ``C_nb`` for an FLU body in ENU, shape ``(..., 3, 3)``."""
    h, p, r = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (heading_rad, pitch_rad, roll_rad)))
    C_ned_frd = _rz(h) @ _ry(p) @ _rx(r)
    return C_ENU_NED @ C_ned_frd @ C_FLU_FRD


def _ned_frd_from_enu_flu(C_nb: FloatArray) -> FloatArray:
    """The elements ``[0|1|2, 0]`` and ``[2, 1|2]`` of ``C_ENU_NED @ C_nb @ C_FLU_FRD`` (..., 3, 3)
    (the others unset) without the products (a stack of 3 x 3 matmuls costs ~0.1 us a matrix):
    rows 0 and 1 swapped, row 2 and columns 1, 2 negated.  The same values as the products for
    finite matrices: their zero terms make a zero ``+0`` (the ``+ 0.0``).  A matrix with a NaN or an
    infinite element is NaN throughout (the products' zero terms made NaN of some elements, and an
    infinity of others: an angle from a corrupted matrix).  (A stack of matrices, as the
    product's: the ufuncs after see the same strides, and so take the same loops.)"""
    C = np.empty(np.broadcast_shapes(C_nb.shape, (3, 3)))
    np.add(C_nb[..., 1, 0], 0.0, out=C[..., 0, 0])
    np.add(C_nb[..., 0, 0], 0.0, out=C[..., 1, 0])
    np.subtract(0.0, C_nb[..., 2, 0], out=C[..., 2, 0])  # 0 - x: -x, and +0 for a zero
    np.add(C_nb[..., 2, 1:], 0.0, out=C[..., 2, 1:])
    bad = ~np.isfinite(C_nb).all(axis=(-2, -1))  # (a sum of the elements could overflow)
    if np.any(bad):
        C[bad] = np.nan
    return C


def hpr_from_C_nb(C_nb: ArrayLike) -> FloatArray:
    """``C_nb`` (FLU body, ENU world) -> aviation ``[heading, pitch, roll]`` [rad], shape ``(..., 3)``.

    Heading in ``[0, 2 pi)``; at pitch = +-90 deg the split between heading and roll is arbitrary.
    """
    C = _ned_frd_from_enu_flu(np.asarray(C_nb, dtype=float))
    heading = np.mod(np.arctan2(C[..., 1, 0], C[..., 0, 0]), 2.0 * np.pi)
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    return np.stack([heading, pitch, roll], axis=-1)


def C_nb_flu_from_rfu(C_nb_rfu: ArrayLike) -> FloatArray:
    """Attitude of an RFU body -> attitude of the same body with FLU axes."""
    return np.asarray(C_nb_rfu, dtype=float) @ C_RFU_FLU


def C_nb_rfu_from_flu(C_nb_flu: ArrayLike) -> FloatArray:
    """Attitude of an FLU body -> attitude of the same body with RFU axes."""
    return np.asarray(C_nb_flu, dtype=float) @ C_FLU_RFU


def vec_flu_from_rfu(v_rfu: ArrayLike) -> FloatArray:
    """Body vector (rate, specific force, lever arm) in RFU axes -> FLU axes, shape ``(..., 3)``."""
    return np.asarray(v_rfu, dtype=float) @ C_FLU_RFU.T


def vec_rfu_from_flu(v_flu: ArrayLike) -> FloatArray:
    """Body vector in FLU axes -> RFU axes, shape ``(..., 3)``."""
    return np.asarray(v_flu, dtype=float) @ C_RFU_FLU.T


def C_nb_rfu_from_seed_angles(psi_rad: ArrayLike, theta_rad: ArrayLike, gamma_rad: ArrayLike) -> FloatArray:
    """[Gong2018] eq. 19: ``C_b^n = Rz(psi) Rx(theta) Ry(gamma)`` for an RFU body in ENU."""
    psi, theta, gamma = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (psi_rad, theta_rad, gamma_rad)))
    return _rz(psi) @ _rx(theta) @ _ry(gamma)


def seed_angles_from_C_nb_rfu(C_nb_rfu: ArrayLike) -> FloatArray:
    """Inverse of [Gong2018] eq. 19 -> ``[psi, theta, gamma]`` (psi counter-clockwise from north, wrapped)."""
    C = np.asarray(C_nb_rfu, dtype=float)
    psi = np.arctan2(-C[..., 0, 1], C[..., 1, 1])
    theta = np.arcsin(np.clip(C[..., 2, 1], -1.0, 1.0))
    gamma = np.arctan2(-C[..., 2, 0], C[..., 2, 2])
    return np.stack([psi, theta, gamma], axis=-1)


def seed_psi_from_heading(heading_rad: ArrayLike) -> FloatArray:
    """Aviation heading (clockwise from north) -> seed heading ``psi`` (counter-clockwise), wrapped."""
    return wrap_angle(-np.asarray(heading_rad, dtype=float))


def heading_from_seed_psi(psi_rad: ArrayLike) -> FloatArray:
    """Seed heading ``psi`` -> aviation heading in ``[0, 2 pi)``."""
    return np.mod(-np.asarray(psi_rad, dtype=float), 2.0 * np.pi)


def yaw_from_heading(heading_rad: ArrayLike) -> FloatArray:
    """Aviation heading -> REP 103 yaw (ENU, counter-clockwise from east), wrapped to ``(-pi, pi]``."""
    return wrap_angle(0.5 * np.pi - np.asarray(heading_rad, dtype=float))


def heading_from_yaw(yaw_rad: ArrayLike) -> FloatArray:
    """REP 103 yaw -> aviation heading in ``[0, 2 pi)``."""
    return np.mod(0.5 * np.pi - np.asarray(yaw_rad, dtype=float), 2.0 * np.pi)


def hpr_error(hpr_est_rad: ArrayLike, hpr_true_rad: ArrayLike) -> FloatArray:
    """Element-wise Euler-angle error ``est - true``, each wrapped to ``(-pi, pi]`` (reports)."""
    return wrap_angle(np.asarray(hpr_est_rad, dtype=float) - np.asarray(hpr_true_rad, dtype=float))


def hpr_sigma_to_rotation_cov(C_nb: ArrayLike, sigma_hpr_rad: ArrayLike) -> FloatArray:
    """Covariance (..., 3, 3) of an attitude error expressed as a rotation about the world (ENU)
    axes, from independent heading / pitch / roll errors of an FLU body.

    The heading axis is -Up, the pitch axis the horizontal axis turned by the heading
    ``[cos h, -sin h, 0]``, the roll axis the body's forward axis; ``M diag(sigma^2) M^T``.
    """
    hpr = hpr_from_C_nb(C_nb)
    h, p = hpr[..., 0], hpr[..., 1]
    z = np.zeros_like(h)
    a_h = np.stack([z, z, -np.ones_like(h)], -1)
    a_p = np.stack([np.cos(h), -np.sin(h), z], -1)
    a_r = np.stack([np.sin(h) * np.cos(p), np.cos(h) * np.cos(p), np.sin(p)], -1)
    M = np.stack([a_h, a_p, a_r], -1)
    return M @ ((np.asarray(sigma_hpr_rad, dtype=float) ** 2)[:, None] * np.swapaxes(M, -1, -2))
