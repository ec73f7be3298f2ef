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

Sub-IMU on a modal wing (:func:`deformed_body_motion`, :class:`~dpos_core.sim.flexure.ModalRealization`):
the flexure gives, in master axes, the rotation ``theta_b`` of the wing section and the
displacement ``d`` of its elastic axis (deflection ``w`` up, in-plane ``u`` forward), so

* attitude ``C_bs = expm([theta_b x]) C_s0 = C_s0 expm([theta_s x])`` with ``theta_s = C_s0^T theta_b``;
* lever arm ``r = r0 + d + (R(theta_b) - I) r_off``: the section moves with the elastic axis and
  turns the body's offset ``r_off`` from it (``r0`` without its along-wing y component);
* ``r_dot = d_dot + R(theta_b) (J_r(theta_b) theta_b_dot x r_off)``, and the rates as above: the
  gyro sees the flexure rate, the accelerometer the deflection acceleration ``d2w/dt2``.

Antennas are rigid on their carrier (a sub-IMU, or a wing section for antennas without IMU).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from ..attitude import right_jacobian, rotvec_to_dcm
from ..config.flexure import K_BEND
from ..kinematics import Motion


def flexed_body_motion(
    carrier: Motion,
    lever_arm_b_m: ArrayLike,
    C_b_s0: ArrayLike,
    flexure: Callable[[FloatArray], tuple[FloatArray, FloatArray]] | None,
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


def deformed_body_motion(
    carrier: Motion,
    lever_arm_b_m: ArrayLike,
    C_b_s0: ArrayLike,
    deformation: Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray, FloatArray]],
) -> Motion:
    """Motion of a body on a modal wing (module docstring).

    Args:
        carrier: the master body's motion.
        lever_arm_b_m: ``r0`` (3,) undeformed, from the master IMU, master axes (wing along y).
        C_b_s0: (3, 3) body axes -> master axes without flexure (mount and rigid misalignment).
        deformation: ``t -> (theta_b, theta_b_dot, d, d_dot)`` each (M, 3) in master axes
            (:meth:`~dpos_core.sim.flexure.ModalRealization.deformation` at the body's span).
    """
    r0 = np.asarray(lever_arm_b_m, dtype=float).reshape(3)
    C_s0 = np.asarray(C_b_s0, dtype=float).reshape(3, 3)
    r_off = r0 * np.array([1.0, 0.0, 1.0])

    def motion(t: FloatArray):
        p_m, v_m, C_eb, w_eb = carrier(t)
        thb, thbd, d, dd = deformation(t)
        th, thd = thb @ C_s0, thbd @ C_s0  # sub-IMU axes: C_s0^T theta_b
        C_bs = C_s0 @ rotvec_to_dcm(th)
        R = rotvec_to_dcm(thb)
        r = r0 + d + R @ r_off - r_off
        r_dot = dd + np.einsum("mij,mj->mi", R, np.cross(np.einsum("mij,mj->mi", right_jacobian(thb), thbd), r_off))
        p = p_m + np.einsum("mij,mj->mi", C_eb, r)
        v = v_m + np.einsum("mij,mj->mi", C_eb, np.cross(w_eb, r) + r_dot)
        w = np.einsum("mji,mj->mi", C_bs, w_eb) + np.einsum("mij,mj->mi", right_jacobian(th), thd)
        return p, v, C_eb @ C_bs, w

    return motion
