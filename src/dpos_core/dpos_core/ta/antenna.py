"""From a sub-IMU's navigation to its antenna phase centre: rigid lever-arm kinematics.

The antenna sits at ``l_a`` (sub-IMU body axes) on its carrier sub-IMU.  Its position is the IMU's
moved by ``C_nb l_a`` (exactly, through ECEF), its velocity adds ``C_nb (omega_eb^b x l_a)`` with
the body rate relative to the Earth ``omega_eb^b = omega_ib^b - C_nb^T omega_ie^n``
([Gong2018] eq. 18, the lever-arm velocity of the master/slave measurement, applied here to the
antenna), and its attitude is the IMU's (rigidly mounted).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import earth
from ..units import FloatArray


def antenna_motion(
    C_nb: FloatArray,
    vel_n_mps: FloatArray,
    llh: FloatArray,
    omega_ib_b_radps: FloatArray,
    lever_arm_b_m: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Position ``llh`` (N, 3) [rad, rad, m] and ENU velocity (N, 3) [m/s] of a point at
    ``lever_arm_b_m`` (3,) in the body axes of an IMU with attitude ``C_nb`` (N, 3, 3), velocity
    ``vel_n_mps`` (N, 3), position ``llh`` (N, 3) and measured angular rate ``omega_ib_b_radps`` (N, 3)."""
    l_a = np.asarray(lever_arm_b_m, dtype=float)
    w_eb = omega_ib_b_radps - np.einsum("nji,nj->ni", C_nb, earth.earth_rate_n(llh[:, 0]))
    vel = vel_n_mps + np.einsum("nij,nj->ni", C_nb, np.cross(w_eb, l_a))
    return earth.offset_llh(llh, C_nb @ l_a), vel
