"""Motion of bodies carried by the aircraft: sub-IMUs on the flexing wing and antennas.

A motion is a function ``t (M,) -> (p_e (M,3), v_e (M,3), C_eb (M,3,3), omega_eb_b (M,3))``
(ECEF position, velocity, attitude and body rate w.r.t. ECEF) that
:func:`dpos_core.kinematics.increments_from_motion` turns into ideal IMU increments.

Sub-IMU on the wing (all vectors of the lever arm in master body axes ``b``):

* attitude ``C_bs(t) = C_mount expm([rho x]) expm([theta(t) x])``: nominal mount, rigid
  misalignment ``rho`` and flexure ``theta`` ([Gong2018] sec. 3.2; theta in sub-IMU axes);
* body rate ``omega_es^s = C_bs^T omega_eb^b + J_r(theta) theta_dot`` (right Jacobian of SO(3));
* position ``p_s = p_m + C_eb r(t)`` with the bending lever arm
  ``r(t) = r0 + k_bend (C_s0 theta) x r0``: a uniformly curved wing whose section at ``r0`` has
  turned by ``theta`` has moved by half the arc, ``k_bend = 1/2``;
* velocity ``v_s = v_m + C_eb (omega_eb^b x r + r_dot)``: the rigid lever-arm velocity plus the
  motion of the flexing wing, so the sub-IMU's specific force contains
  ``omega x (omega x r) + omega_dot x r`` and the flexure acceleration consistently.

Antennas are rigid on their carrier (a sub-IMU, or a wing section for antennas without IMU).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..attitude import rotvec_to_dcm, skew
from ..kinematics import Motion

FloatArray = NDArray[np.float64]
K_BEND = 0.5


def right_jacobian(theta: ArrayLike) -> FloatArray:
    """Right Jacobian of SO(3): ``expm([theta x])^T d/dt expm([theta x]) = [J_r(theta) theta_dot x]``.

    ``J_r = I - (1 - cos a)/a^2 [theta x] + (a - sin a)/a^3 [theta x]^2`` (series below 1e-4 rad).
    """
    th = np.asarray(theta, dtype=float)
    a2 = np.sum(th * th, axis=-1)[..., None, None]
    a = np.sqrt(a2)
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    c2 = np.where(small, 1.0 / 6.0 - a2 / 120.0, (safe - np.sin(safe)) / safe**3)
    K = skew(th)
    return np.eye(3) - c1 * K + c2 * (K @ K)


def flexed_body_motion(
    carrier: Motion,
    lever_arm_b_m: ArrayLike,
    C_b_s0: ArrayLike,
    flexure: "callable[[FloatArray], tuple[FloatArray, FloatArray]] | None",
    k_bend: float = K_BEND,
) -> Motion:
    """Motion of a body on the (flexing) wing of ``carrier`` (see module docstring).

    Args:
        carrier: the master body's motion.
        lever_arm_b_m: ``r0`` (3,) from the master IMU to the body, master axes.
        C_b_s0: (3, 3) body axes -> master axes without flexure (mount and rigid misalignment).
        flexure: ``t -> (theta (M,3), theta_dot (M,3))`` in body axes, or None (rigid).
    """
    r0 = np.asarray(lever_arm_b_m, dtype=float).reshape(3)
    C_s0 = np.asarray(C_b_s0, dtype=float).reshape(3, 3)

    def motion(t: FloatArray):
        p_m, v_m, C_eb, w_eb = carrier(t)
        m = p_m.shape[0]
        if flexure is None:
            th = thd = np.zeros((m, 3))
        else:
            th, thd = flexure(t)
        C_bs = C_s0 @ rotvec_to_dcm(th)
        r = r0 + k_bend * np.cross(th @ C_s0.T, r0)
        r_dot = k_bend * np.cross(thd @ C_s0.T, r0)
        p = p_m + np.einsum("mij,mj->mi", C_eb, r)
        v = v_m + np.einsum("mij,mj->mi", C_eb, np.cross(w_eb, r) + r_dot)
        w = np.einsum("mji,mj->mi", C_bs, w_eb) + np.einsum("mij,mj->mi", right_jacobian(th), thd)
        return p, v, C_eb @ C_bs, w

    return motion


def rigid_offset_motion(carrier: Motion, offset_m: ArrayLike) -> Motion:
    """A point rigidly attached to ``carrier`` at ``offset_m`` (3,) in the carrier's axes (same axes)."""
    d = np.asarray(offset_m, dtype=float).reshape(3)

    def motion(t: FloatArray):
        p, v, C, w = carrier(t)
        return p + C @ d, v + np.einsum("mij,mj->mi", C, np.cross(w, d)), C, w

    return motion


def mount_dcm(mount_rpy_deg: ArrayLike, rho_deg: ArrayLike) -> FloatArray:
    """``C_b_s0 = C_mount expm([rho x])`` from the nominal mount roll/pitch/yaw (about x, y, z of
    the master body, applied z-y-x) and the rigid misalignment rotation vector [deg]."""
    r, p, y = np.deg2rad(np.asarray(mount_rpy_deg, dtype=float))
    cz, sz, cy, sy, cx, sx = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
    Ry = np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
    Rx = np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz @ Ry @ Rx @ rotvec_to_dcm(np.deg2rad(np.asarray(rho_deg, dtype=float)))
