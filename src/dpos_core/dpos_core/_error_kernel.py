"""Private numba kernels of the error-state models: the navigation-error propagation of
:mod:`dpos_core.ins_errors` and the transition / measurement functions of the transfer-alignment
model (:mod:`dpos_core.ta.model`).

Use those modules; this one only holds their per-row loops, written with scalars so that numba
keeps them in registers (the filters evaluate the models on batches of a few dozen to a few
hundred rows, where numpy's per-call overhead dominated).  The formulas, branch thresholds and
conventions are those documented in :mod:`dpos_core.attitude`, :mod:`dpos_core.ins_errors` and
:mod:`dpos_core.ta.model` (same order of operations where it matters for rounding).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._attitude_kernel import quat_dcm, quat_mul, quat_rotvec, rotvec_quat
from .earth import OMEGA_IE_RADPS

_SMALL_JR_RAD = 1e-4  # ins_errors.right_jacobian_inv's series threshold


@nb.njit(cache=True, nogil=True)
def _nav_row(phi: np.ndarray, dv: np.ndarray, dp: np.ndarray, eps: np.ndarray, nab: np.ndarray, extra: np.ndarray,
             consts: np.ndarray, F_n: np.ndarray, C_int: np.ndarray, w_ie: np.ndarray, w_en: np.ndarray, v: np.ndarray,
             E: np.ndarray, u: np.ndarray, out_phi: np.ndarray, out_dv: np.ndarray, out_dp: np.ndarray) -> None:
    """One row of :func:`dpos_core.ins_errors.propagate_nav_errors` (each vector (3,); ``consts`` =
    ``[T, Rm, Rn, sin lat, cos lat, 2 g / (r_m + h)]``; ``E`` (3, 3) and ``u`` (3,) scratch)."""
    T, Rm, Rn, sl, cl, g2 = consts[0], consts[1], consts[2], consts[3], consts[4], consts[5]
    ve, vn = v[0], v[1]
    quat_dcm(rotvec_quat(phi[0], phi[1], phi[2]), E)
    dL = dp[1] / Rm
    dh = dp[2]
    om = OMEGA_IE_RADPS
    dwie0, dwie1, dwie2 = 0.0, -om * sl * dL, om * cl * dL
    dwen0 = -dv[1] / Rm + vn * dh / Rm**2
    dwen1 = dv[0] / Rn - ve * dh / Rn**2
    dwen2 = dv[0] * sl / cl / Rn + ve / (cl * cl) * dL / Rn - ve * sl / cl * dh / Rn**2
    d0, d1, d2 = dwie0 + dwen0, dwie1 + dwen1, dwie2 + dwen2
    wi0, wi1, wi2 = w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]
    # rate = (w_in - E^T w_in) + E^T (dw_ie + dw_en); u = rate T - (C_int eps + extra)
    for i in range(3):
        etw = E[0, i] * wi0 + E[1, i] * wi1 + E[2, i] * wi2
        etd = E[0, i] * d0 + E[1, i] * d1 + E[2, i] * d2
        wi = wi0 if i == 0 else (wi1 if i == 1 else wi2)
        gyro = C_int[i, 0] * eps[0] + C_int[i, 1] * eps[1] + C_int[i, 2] * eps[2] + extra[i]
        u[i] = ((wi - etw) + etd) * T - gyro
    # J_r(phi)^-1 u = u + 1/2 phi x u + c phi x (phi x u)
    p0, p1, p2 = phi[0], phi[1], phi[2]
    a2 = p0 * p0 + p1 * p1 + p2 * p2
    a = math.sqrt(a2)
    if a < _SMALL_JR_RAD:
        c = 1.0 / 12.0 + a2 / 720.0
    else:
        c = 1.0 / a**2 - (1.0 + math.cos(a)) / (2.0 * a * math.sin(a))
    k0 = p1 * u[2] - p2 * u[1]
    k1 = p2 * u[0] - p0 * u[2]
    k2 = p0 * u[1] - p1 * u[0]
    kk0 = p1 * k2 - p2 * k1
    kk1 = p2 * k0 - p0 * k2
    kk2 = p0 * k1 - p1 * k0
    out_phi[0] = p0 + (u[0] + 0.5 * k0 + c * kk0)
    out_phi[1] = p1 + (u[1] + 0.5 * k1 + c * kk1)
    out_phi[2] = p2 + (u[2] + 0.5 * k2 + c * kk2)
    # cor = (2 w_ie + w_en) x dv + (2 dw_ie + dw_en) x v;  dg = [0, 0, 2 g / (r_m + h) dh]
    a0, a1, a2_ = 2.0 * w_ie[0] + w_en[0], 2.0 * w_ie[1] + w_en[1], 2.0 * w_ie[2] + w_en[2]
    b0, b1, b2 = 2.0 * dwie0 + dwen0, 2.0 * dwie1 + dwen1, 2.0 * dwie2 + dwen2
    cor0 = (a1 * dv[2] - a2_ * dv[1]) + (b1 * v[2] - b2 * v[1])
    cor1 = (a2_ * dv[0] - a0 * dv[2]) + (b2 * v[0] - b0 * v[2])
    cor2 = (a0 * dv[1] - a1 * dv[0]) + (b0 * v[1] - b1 * v[0])
    dg2 = g2 * dh
    n0 = C_int[0, 0] * nab[0] + C_int[0, 1] * nab[1] + C_int[0, 2] * nab[2]
    n1 = C_int[1, 0] * nab[0] + C_int[1, 1] * nab[1] + C_int[1, 2] * nab[2]
    n2 = C_int[2, 0] * nab[0] + C_int[2, 1] * nab[1] + C_int[2, 2] * nab[2]
    for i in range(3):
        imf = F_n[i] - (E[i, 0] * F_n[0] + E[i, 1] * F_n[1] + E[i, 2] * F_n[2])
        en = E[i, 0] * n0 + E[i, 1] * n1 + E[i, 2] * n2
        cor = cor0 if i == 0 else (cor1 if i == 1 else cor2)
        dg = dg2 if i == 2 else 0.0
        out_dv[i] = dv[i] + imf + en - (cor - dg) * T
        out_dp[i] = dp[i] + 0.5 * (dv[i] + out_dv[i]) * T


@nb.njit(cache=True, nogil=True)
def nav_errors(phi: np.ndarray, dv: np.ndarray, dp: np.ndarray, eps: np.ndarray, nab: np.ndarray, extra: np.ndarray,
               consts: np.ndarray, F_n: np.ndarray, C_int: np.ndarray, w_ie: np.ndarray, w_en: np.ndarray, v: np.ndarray,
               out_phi: np.ndarray, out_dv: np.ndarray, out_dp: np.ndarray) -> None:
    """:func:`dpos_core.ins_errors.propagate_nav_errors` over rows: every error (M, 3), outputs (M, 3)."""
    E = np.empty((3, 3))
    u = np.empty(3)
    for m in range(phi.shape[0]):
        _nav_row(phi[m], dv[m], dp[m], eps[m], nab[m], extra[m], consts, F_n, C_int, w_ie, w_en, v, E, u,
                 out_phi[m], out_dv[m], out_dp[m])


@nb.njit(cache=True, nogil=True)
def ta_transition(x: np.ndarray, consts: np.ndarray, F_n: np.ndarray, C_int: np.ndarray, w_ie: np.ndarray, w_en: np.ndarray,
                  v: np.ndarray, Phi: np.ndarray, gyro_extra: np.ndarray, out: np.ndarray) -> None:
    """:meth:`dpos_core.ta.model.TransferAlignmentModel.f` over rows ``x`` (M, 24) into ``out`` (M, 24):
    the navigation errors (0:9) as :func:`nav_errors` with the rows' further integrated gyro error
    ``gyro_extra`` (M, 3) (the gyro axis errors; zeros without them), the flexure (18:24) by its
    transition ``Phi`` (3, 2, 2), the constant states copied."""
    E = np.empty((3, 3))
    u = np.empty(3)
    for m in range(x.shape[0]):
        r = x[m]
        o = out[m]
        for i in range(9, 18):
            o[i] = r[i]
        _nav_row(r[0:3], r[3:6], r[6:9], r[9:12], r[12:15], gyro_extra[m], consts, F_n, C_int, w_ie, w_en, v, E, u,
                 o[0:3], o[3:6], o[6:9])
        for i in range(3):
            th, thd = r[18 + i], r[21 + i]
            o[18 + i] = Phi[i, 0, 0] * th + Phi[i, 0, 1] * thd
            o[21 + i] = Phi[i, 1, 0] * th + Phi[i, 1, 1] * thd


@nb.njit(cache=True, nogil=True)
def ta_measurement(x: np.ndarray, A: np.ndarray, C_m: np.ndarray, w_m: np.ndarray, C0: np.ndarray, r0: np.ndarray,
                   k_bend: float, out: np.ndarray) -> None:
    """:meth:`dpos_core.ta.model.TransferAlignmentModel.h` over rows ``x`` (M, 24) into ``out`` (M, 6)
    or (M, 9) (with the position match)."""
    use_pos = out.shape[1] == 9
    at = np.empty(3)
    ar = np.empty(3)
    for m in range(x.shape[0]):
        r = x[m]
        o = out[m]
        # log(expm(-[A theta]) expm(-[A rho]) expm([phi]))
        for i in range(3):
            at[i] = A[i, 0] * r[18] + A[i, 1] * r[19] + A[i, 2] * r[20]
            ar[i] = A[i, 0] * r[15] + A[i, 1] * r[16] + A[i, 2] * r[17]
        tw, tx, ty, tz = rotvec_quat(at[0], at[1], at[2])
        rw, rx, ry, rz = rotvec_quat(ar[0], ar[1], ar[2])
        pw, px, py, pz = rotvec_quat(r[0], r[1], r[2])
        iw, ix, iy, iz = quat_mul(rw, -rx, -ry, -rz, pw, px, py, pz)
        qw, qx, qy, qz = quat_mul(tw, -tx, -ty, -tz, iw, ix, iy, iz)
        o[0], o[1], o[2] = quat_rotvec(qw, qx, qy, qz)
        # r_flex = k (C0 theta) x r0, r_dot = k (C0 theta_dot) x r0
        c0 = C0[0, 0] * r[18] + C0[0, 1] * r[19] + C0[0, 2] * r[20]
        c1 = C0[1, 0] * r[18] + C0[1, 1] * r[19] + C0[1, 2] * r[20]
        c2 = C0[2, 0] * r[18] + C0[2, 1] * r[19] + C0[2, 2] * r[20]
        d0 = C0[0, 0] * r[21] + C0[0, 1] * r[22] + C0[0, 2] * r[23]
        d1 = C0[1, 0] * r[21] + C0[1, 1] * r[22] + C0[1, 2] * r[23]
        d2 = C0[2, 0] * r[21] + C0[2, 1] * r[22] + C0[2, 2] * r[23]
        f0 = k_bend * (c1 * r0[2] - c2 * r0[1])
        f1 = k_bend * (c2 * r0[0] - c0 * r0[2])
        f2 = k_bend * (c0 * r0[1] - c1 * r0[0])
        g0 = k_bend * (d1 * r0[2] - d2 * r0[1])
        g1 = k_bend * (d2 * r0[0] - d0 * r0[2])
        g2 = k_bend * (d0 * r0[1] - d1 * r0[0])
        # w_m x r_flex + r_dot
        s0 = (w_m[1] * f2 - w_m[2] * f1) + g0
        s1 = (w_m[2] * f0 - w_m[0] * f2) + g1
        s2 = (w_m[0] * f1 - w_m[1] * f0) + g2
        for i in range(3):
            o[3 + i] = r[3 + i] + (C_m[i, 0] * s0 + C_m[i, 1] * s1 + C_m[i, 2] * s2)
            if use_pos:
                o[6 + i] = r[6 + i] + (C_m[i, 0] * f0 + C_m[i, 1] * f1 + C_m[i, 2] * f2)


@nb.njit(cache=True, nogil=True)
def interval_sums(q0: np.ndarray, q: np.ndarray, f: np.ndarray, dt: np.ndarray, F_n: np.ndarray, C_int: np.ndarray) -> None:
    """The midpoint-rule integrals of :meth:`dpos_core.ins_errors.IntervalIntegrals.add` over the
    steps dt (m,): ``F_n = sum_k C_mid_k f_k dt_k`` (3,) and ``C_int = sum_k C_mid_k dt_k`` (3, 3)
    written to F_n, C_int, with ``C_mid_k = (C_k + C_{k-1}) / 2`` the mean of the DCMs of the
    quaternions q (m, 4) at the step's end and start (``C_{-1}`` that of q0 (4,)); f (m, 3)."""
    Ca = np.empty((3, 3))
    Cb = np.empty((3, 3))
    quat_dcm((q0[0], q0[1], q0[2], q0[3]), Ca)
    for i in range(3):
        F_n[i] = 0.0
        for j in range(3):
            C_int[i, j] = 0.0
    for k in range(q.shape[0]):
        quat_dcm((q[k, 0], q[k, 1], q[k, 2], q[k, 3]), Cb)
        t = dt[k]
        for i in range(3):
            for j in range(3):
                c = 0.5 * (Cb[i, j] + Ca[i, j])
                F_n[i] += c * (f[k, j] * t)
                C_int[i, j] += c * t
        for i in range(3):
            for j in range(3):
                Ca[i, j] = Cb[i, j]
