"""Ideal IMU outputs and navigation states from an Earth-fixed (ECEF) trajectory.

For a body with ECEF position ``p_e``, velocity ``v_e``, acceleration ``a_e`` (derivatives in the
rotating ECEF frame), attitude ``C_eb`` and angular rate ``omega_eb^b`` relative to ECEF:

* ``omega_ib^b = omega_eb^b + C_eb^T omega_ie^e``;
* ``f^b = C_eb^T (a_e + 2 omega_ie^e x v_e - g_e)`` with ``g_e`` the normal-gravity (plumb-line)
  vector, i.e. the same gravity model the mechanization uses (:func:`dpos_core.earth.gravity_n`),
  so a perfect IMU integrates back to the truth (Groves eq. 5.28 rearranged).

Increments over sampling intervals are integrated with Gauss-Legendre quadrature of the rate
functions, which is exact to far below the mechanization's own algorithm error.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from .earth import OMEGA_IE_RADPS, C_en, ecef_to_geodetic, normal_gravity

OMEGA_IE_E: FloatArray = np.array([0.0, 0.0, OMEGA_IE_RADPS])


def imu_from_ecef_kinematics(
    p_e_m: ArrayLike,
    v_e_mps: ArrayLike,
    a_e_mps2: ArrayLike,
    C_eb: ArrayLike,
    omega_eb_b_radps: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Ideal gyro and accelerometer outputs.

    Args:
        p_e_m, v_e_mps, a_e_mps2: shape (..., 3), ECEF position and its first two derivatives.
        C_eb: shape (..., 3, 3), body -> ECEF.
        omega_eb_b_radps: shape (..., 3), body rate w.r.t. ECEF in body axes.

    Returns:
        ``(omega_ib_b_radps, f_b_mps2)``, each shape (..., 3).
    """
    p_e = np.asarray(p_e_m, dtype=float)
    v_e = np.asarray(v_e_mps, dtype=float)
    a_e = np.asarray(a_e_mps2, dtype=float)
    C = np.asarray(C_eb, dtype=float)
    C_be = np.swapaxes(C, -1, -2)
    lat, lon, h = ecef_to_geodetic(p_e)
    g_e = -normal_gravity(lat, h)[..., None] * C_en(lat, lon)[..., :, 2]
    f_e = a_e + 2.0 * np.cross(OMEGA_IE_E, v_e) - g_e
    omega_ib_b = np.asarray(omega_eb_b_radps, dtype=float) + np.einsum("...ij,j->...i", C_be, OMEGA_IE_E)
    f_b = np.einsum("...ij,...j->...i", C_be, f_e)
    return omega_ib_b, f_b


def nav_from_ecef(
    p_e_m: ArrayLike, v_e_mps: ArrayLike, C_eb: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF kinematics -> navigation truth ``(llh (..., 3), vel_n_mps (..., 3), C_nb (..., 3, 3))``."""
    lat, lon, h = ecef_to_geodetic(p_e_m)
    C_en_ = C_en(lat, lon)
    C_ne = np.swapaxes(C_en_, -1, -2)
    vel_n = np.einsum("...ij,...j->...i", C_ne, np.asarray(v_e_mps, dtype=float))
    C_nb = C_ne @ np.asarray(C_eb, dtype=float)
    return np.stack([lat, lon, h], axis=-1), vel_n, C_nb


def integrate_increments(
    rates: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
    t_edges_s: ArrayLike,
    n_points: int = 4,
) -> tuple[FloatArray, FloatArray]:
    """Angle and velocity increments over consecutive intervals by Gauss-Legendre quadrature.

    Args:
        rates: ``t (M,) -> (omega_ib_b (M, 3), f_b (M, 3))``.
        t_edges_s: interval edges, shape (N+1,).
        n_points: quadrature nodes per interval (exact for polynomials of degree ``2 n - 1``).

    Returns:
        ``(dtheta_rad (N, 3), dvel_mps (N, 3))``.
    """
    t = np.asarray(t_edges_s, dtype=float)
    x, w = np.polynomial.legendre.leggauss(n_points)
    t0, t1 = t[:-1], t[1:]
    half = 0.5 * (t1 - t0)
    nodes = (0.5 * (t0 + t1))[:, None] + half[:, None] * x[None, :]
    om, f = rates(nodes.reshape(-1))
    om = om.reshape(nodes.shape + (3,))
    f = f.reshape(nodes.shape + (3,))
    dtheta = np.einsum("nk,k,nkj->nj", np.broadcast_to(half[:, None], nodes.shape), w, om)
    dvel = np.einsum("nk,k,nkj->nj", np.broadcast_to(half[:, None], nodes.shape), w, f)
    return dtheta, dvel


Motion = Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray, FloatArray]]


def increments_from_motion(motion: Motion, t_edges_s: ArrayLike, n_points: int = 4) -> tuple[FloatArray, FloatArray]:
    """Ideal angle and velocity increments of a body from its ECEF motion, without accelerations.

    ``motion(t) -> (p_e (M,3), v_e (M,3), C_eb (M,3,3), omega_eb_b (M,3))``.  The velocity
    increment ``int C_be (a_e + 2 W x v_e - g_e) dt`` is integrated by parts,
    ``int C_be a_e dt = [C_be v_e] + int omega_eb^b x (C_be v_e) dt`` (using
    ``d/dt C_be = -[omega_eb^b x] C_be``), so only positions, velocities, attitudes and rates are
    needed: bodies on a flexing lever arm need no angular or flexure acceleration.

    Returns:
        ``(dtheta_rad (N, 3), dvel_mps (N, 3))`` over the N intervals of ``t_edges_s`` (N+1,).
    """
    t = np.asarray(t_edges_s, dtype=float)
    x, w = np.polynomial.legendre.leggauss(n_points)
    half = 0.5 * (t[1:] - t[:-1])
    nodes = (0.5 * (t[1:] + t[:-1]))[:, None] + half[:, None] * x[None, :]
    shape = nodes.shape
    p_e, v_e, C_eb, w_eb = motion(nodes.reshape(-1))
    C_be = np.swapaxes(C_eb, -1, -2)
    lat, lon, h = ecef_to_geodetic(p_e)
    g_e = -normal_gravity(lat, h)[:, None] * C_en(lat, lon)[:, :, 2]
    v_b = np.einsum("mij,mj->mi", C_be, v_e)
    w_ib = w_eb + np.einsum("mij,j->mi", C_be, OMEGA_IE_E)
    integrand_v = np.cross(w_eb, v_b) + np.einsum("mij,mj->mi", C_be, 2.0 * np.cross(OMEGA_IE_E, v_e) - g_e)
    weights = half[:, None] * w[None, :]
    dtheta = np.einsum("nk,nkj->nj", weights, w_ib.reshape(shape + (3,)))
    dvel = np.einsum("nk,nkj->nj", weights, integrand_v.reshape(shape + (3,)))
    p0, v0, C0, _ = motion(t)
    vb_edges = np.einsum("mji,mj->mi", C0, v0)
    # C_be v_e at the end of each interval minus at its start (the bracket of the by-parts formula)
    dvel += vb_edges[1:] - vb_edges[:-1]
    return dtheta, dvel
