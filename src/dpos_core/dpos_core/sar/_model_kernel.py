"""Private numba kernels of :class:`dpos_core.sar.model.SarModel`: the transition ``f``, the
measurement ``h`` and the quaternion projection over a batch of states row by row (scalar code, no
temporaries).  Use :class:`~dpos_core.sar.model.SarModel`, which documents the model ([Yan2016]
eq. 2 and 4-5); the formulas and their order of operations are those of its numpy form, so the
results agree to rounding.

The per-step quantities of the SINS track (its frame rate, Coriolis and gravity terms, the radii
at the epochs) are computed once per model, by the numpy functions of :mod:`dpos_core.earth`,
into a table (K - 1, :data:`N_STEP`) of the columns ``C_*``; the WGS-84 constants the per-particle
(true-position) side needs come in ``earth_c`` (:data:`N_EARTH`: ``A_M, E2, OMEGA_IE, GAMMA_E,
K_SOMIGLIANA, F, M_GRAV``), so this module imports nothing of the package.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._attitude_kernel import quat_mul

# columns of the per-step table (one row per step k -> k + 1)
C_DT = 0  # dt [s]
C_LLH_I = 1  # the SINS's llh at the step's middle (3)
C_V_I = 4  # the SINS's ENU velocity at the middle (3)
C_CNB_I = 7  # its C_nb at the middle (3, 3) row major (9)
C_DVSF = 16  # specific-force velocity increment (3)
C_DEN_N = 19  # R_M + h at epoch k (metres north -> dlat)
C_DEN_E = 20  # (R_N + h) cos L at epoch k (metres east -> dlon)
C_W_IN_I = 21  # w_ie' + w_en' at the middle (3)
C_COR_I = 24  # (2 w_ie' + w_en') x v' at the middle (3)
C_G_I = 27  # normal gravity at the middle
C_RATE_I = 28  # llh rate of the SINS at the middle (3)
C_RMH1 = 31  # R_M + h at epoch k + 1
C_RNH1 = 32  # R_N + h at epoch k + 1
C_COS1 = 33  # cos L at epoch k + 1
C_SIN_I = 34  # sin L at the middle
C_COS_I = 35  # cos L at the middle
N_STEP = 36
N_EARTH = 7


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _rotvec_quat(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """:func:`dpos_core.attitude.rotvec_to_quat` of one rotation vector; below 1e-3 rad (a filter
    step's frame rotation: 1e-4 rad) ``cos(a / 2)`` and ``sin(a / 2) / a`` by their series to
    ``a^4``, whose first neglected terms (``a^6 / 46080``, ``a^6 / 645120``) are below 1e-22, far
    under the rounding of 1."""
    a2 = x * x + y * y + z * z
    if a2 < 1e-6:
        w = 1.0 - a2 / 8.0 * (1.0 - a2 / 48.0)
        s = 0.5 - a2 / 48.0 * (1.0 - a2 / 80.0)
    else:
        a = math.sqrt(a2)
        w = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return w, s * x, s * y, s * z


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _normalize(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """:func:`dpos_core.attitude.quat_normalize`: unit norm, scalar part >= 0."""
    n = math.sqrt(((w * w + x * x) + y * y) + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        return -w, -x, -y, -z
    return w, x, y, z


_TWO_PI = 2.0 * math.pi


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _mod_two_pi(a: float) -> float:
    """``a % 2 pi`` as numpy's ``np.mod`` and Python's float ``%`` (fmod, then the divisor's sign;
    a zero is +0), without the fmod on (-2 pi, 4 pi), where it is exact: ``a``, ``a + 2 pi`` (the
    same rounded sum) or ``a - 2 pi`` (exact, Sterbenz)."""
    if 0.0 < a < _TWO_PI:
        return a
    if -_TWO_PI < a < 0.0:
        return a + _TWO_PI
    if _TWO_PI <= a < 2.0 * _TWO_PI:
        return a - _TWO_PI
    return a % _TWO_PI


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _gravity(s2: float, h: float, ec: np.ndarray) -> float:
    """:func:`dpos_core.earth.normal_gravity` of ``sin^2`` of the latitude and the height."""
    a_m, e2, gamma_e, k_s, f, m_g = ec[0], ec[1], ec[3], ec[4], ec[5], ec[6]
    g0 = gamma_e * (1.0 + k_s * s2) / math.sqrt(1.0 - e2 * s2)
    return g0 * (1.0 - 2.0 / a_m * (1.0 + f + m_g - 2.0 * f * s2) * h + 3.0 / a_m**2 * h * h)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_f(x: np.ndarray, c: np.ndarray, ec: np.ndarray, out: np.ndarray) -> None:
    """One step of :meth:`SarModel.f <dpos_core.sar.model.SarModel.f>` for states x (M, 16) into
    out (M, 16); c (:data:`N_STEP`,) the step's row of the table, ec the earth constants."""
    dt = c[C_DT]
    lat_i, h_i = c[C_LLH_I], c[C_LLH_I + 2]
    ve_i, vn_i, vu_i = c[C_V_I], c[C_V_I + 1], c[C_V_I + 2]
    a_m, e2, om = ec[0], ec[1], ec[2]
    for m in range(x.shape[0]):
        qw, qx, qy, qz = x[m, 0], x[m, 1], x[m, 2], x[m, 3]
        dve, dvn, dvu = x[m, 4], x[m, 5], x[m, 6]
        ex, ey, ez = x[m, 10], x[m, 11], x[m, 12]
        nx, ny, nz = x[m, 13], x[m, 14], x[m, 15]
        # the position error in llh (radii at epoch k), the true position and velocity
        d0 = x[m, 7] / c[C_DEN_N]
        d1 = x[m, 8] / c[C_DEN_E]
        d2 = x[m, 9]
        lat_t = lat_i - d0
        h_t = h_i - d2
        vte, vtn, vtu = ve_i - dve, vn_i - dvn, vu_i - dvu
        if -1e-3 < d0 < 1e-3:  # sin, cos of lat_i - d0 from the middle's, d0's by series (to d0^5: < 1e-22)
            d02 = d0 * d0
            sd = d0 * (1.0 - d02 / 6.0 * (1.0 - d02 / 20.0))
            cd = 1.0 - d02 / 2.0 * (1.0 - d02 / 12.0)
            sl = c[C_SIN_I] * cd - c[C_COS_I] * sd
            cl = c[C_COS_I] * cd + c[C_SIN_I] * sd
        else:
            sl, cl = math.sin(lat_t), math.cos(lat_t)
        w_ = 1.0 - e2 * sl * sl
        rn = a_m / math.sqrt(w_)
        rm = rn * (1.0 - e2) / w_
        wie1, wie2 = om * cl, om * sl
        rmh, rnh = rm + h_t, rn + h_t
        wen0, wen1, wen2 = -vtn / rmh, vte / rnh, vte * (sl / cl) / rnh
        # attitude: q1 = exp((dw - w_in') dt / 2) q exp(w_in dt / 2), dw = C_nb' eps
        dw0 = ex * c[C_CNB_I] + ey * c[C_CNB_I + 1] + ez * c[C_CNB_I + 2]
        dw1 = ex * c[C_CNB_I + 3] + ey * c[C_CNB_I + 4] + ez * c[C_CNB_I + 5]
        dw2 = ex * c[C_CNB_I + 6] + ey * c[C_CNB_I + 7] + ez * c[C_CNB_I + 8]
        aw, ax, ay, az = _rotvec_quat((dw0 - c[C_W_IN_I]) * dt, (dw1 - c[C_W_IN_I + 1]) * dt,
                                      (dw2 - c[C_W_IN_I + 2]) * dt)
        bw, bx, by, bz = _rotvec_quat((0.0 + wen0) * dt, (wie1 + wen1) * dt, (wie2 + wen2) * dt)
        pw, px, py, pz = quat_mul(aw, ax, ay, az, qw, qx, qy, qz)
        q1w, q1x, q1y, q1z = quat_mul(pw, px, py, pz, bw, bx, by, bz)
        # C = C(q) (the step's start attitude error), its transpose applied to f' and to C_nb' nab
        uw, ux, uy, uz = _normalize(qw, qx, qy, qz)
        c00 = 1 - 2 * (uy * uy + uz * uz)
        c01 = 2 * (ux * uy - uw * uz)
        c02 = 2 * (ux * uz + uw * uy)
        c10 = 2 * (ux * uy + uw * uz)
        c11 = 1 - 2 * (ux * ux + uz * uz)
        c12 = 2 * (uy * uz - uw * ux)
        c20 = 2 * (ux * uz - uw * uy)
        c21 = 2 * (uy * uz + uw * ux)
        c22 = 1 - 2 * (ux * ux + uy * uy)
        f0, f1, f2 = c[C_DVSF], c[C_DVSF + 1], c[C_DVSF + 2]
        t0 = c00 * f0 + c10 * f1 + c20 * f2
        t1 = c01 * f0 + c11 * f1 + c21 * f2
        t2 = c02 * f0 + c12 * f1 + c22 * f2
        b0 = nx * c[C_CNB_I] + ny * c[C_CNB_I + 1] + nz * c[C_CNB_I + 2]
        b1 = nx * c[C_CNB_I + 3] + ny * c[C_CNB_I + 4] + nz * c[C_CNB_I + 5]
        b2 = nx * c[C_CNB_I + 6] + ny * c[C_CNB_I + 7] + nz * c[C_CNB_I + 8]
        n0 = c00 * b0 + c10 * b1 + c20 * b2
        n1 = c01 * b0 + c11 * b1 + c21 * b2
        n2 = c02 * b0 + c12 * b1 + c22 * b2
        # Coriolis and gravity differences at the true position
        a0, a1, a2 = 2.0 * 0.0 + wen0, 2.0 * wie1 + wen1, 2.0 * wie2 + wen2
        cor0 = c[C_COR_I] - (a1 * vtu - a2 * vtn)
        cor1 = c[C_COR_I + 1] - (a2 * vte - a0 * vtu)
        cor2 = c[C_COR_I + 2] - (a0 * vtn - a1 * vte)
        dg2 = -c[C_G_I] - -_gravity(sl * sl, h_t, ec)
        dv1e = dve + (f0 - t0) + n0 * dt - cor0 * dt + 0.0 * dt
        dv1n = dvn + (f1 - t1) + n1 * dt - cor1 * dt + 0.0 * dt
        dv1u = dvu + (f2 - t2) + n2 * dt - cor2 * dt + dg2 * dt
        # position: the difference of the geodetic rates of the SINS's and the true velocity
        vme = ve_i - 0.5 * (dve + dv1e)
        vmn = vn_i - 0.5 * (dvn + dv1n)
        vmu = vu_i - 0.5 * (dvu + dv1u)
        r0 = c[C_RATE_I] - vmn / rmh
        r1 = c[C_RATE_I + 1] - vme / (rnh * cl)
        r2 = c[C_RATE_I + 2] - vmu
        out[m, 0], out[m, 1], out[m, 2], out[m, 3] = _normalize(q1w, q1x, q1y, q1z)
        out[m, 4], out[m, 5], out[m, 6] = dv1e, dv1n, dv1u
        out[m, 7] = (d0 + r0 * dt) * c[C_RMH1]
        out[m, 8] = (d1 + r1 * dt) * c[C_RNH1] * c[C_COS1]
        out[m, 9] = d2 + r2 * dt
        for i in range(10, 16):
            out[m, i] = x[m, i]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _heading_row(qw: float, qx: float, qy: float, qz: float, C_nb: np.ndarray, psi: float) -> float:
    """h's first row ``wrap(psi - heading(C(q)^T C_nb))`` of one state's quaternion (NaN for a
    non-finite one)."""
    uw, ux, uy, uz = _normalize(qw, qx, qy, qz)
    if not (math.isfinite(uw) and math.isfinite(ux) and math.isfinite(uy) and math.isfinite(uz)):
        return math.nan
    # column 0 of C(q)^T C_nb: its rows 0 and 1 give the heading (ENU world, FLU body)
    c00 = 1 - 2 * (uy * uy + uz * uz)
    c01 = 2 * (ux * uy - uw * uz)
    c10 = 2 * (ux * uy + uw * uz)
    c11 = 1 - 2 * (ux * ux + uz * uz)
    c20 = 2 * (ux * uz - uw * uy)
    c21 = 2 * (uy * uz + uw * ux)
    e0 = c00 * C_nb[0, 0] + c10 * C_nb[1, 0] + c20 * C_nb[2, 0]
    e1 = c01 * C_nb[0, 0] + c11 * C_nb[1, 0] + c21 * C_nb[2, 0]
    # frames.hpr_from_C_nb's heading in [0, 2 pi) and attitude.wrap_angle's wrap
    hd = _mod_two_pi(math.atan2(e0 + 0.0, e1 + 0.0))
    w = _mod_two_pi(psi - hd + math.pi) - math.pi
    return math.pi if w == -math.pi else w


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _wrap(a: float) -> float:
    """:func:`dpos_core.attitude.wrap_angle` of one angle."""
    w = _mod_two_pi(a + math.pi) - math.pi
    return math.pi if w == -math.pi else w


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_heading_residual(x: np.ndarray, C_nb: np.ndarray, psi: float, out: np.ndarray) -> None:
    """The SAR rows of :meth:`SarModel.h <dpos_core.sar.model.SarModel.h>` for states x (M, 16)
    into out (M, 4): ``wrap(psi - heading(C(q)^T C_nb))`` and the position error (NaN heading for
    a non-finite attitude, as :func:`dpos_core.frames.hpr_from_C_nb`)."""
    for m in range(x.shape[0]):
        out[m, 0] = _heading_row(x[m, 0], x[m, 1], x[m, 2], x[m, 3], C_nb, psi)
        out[m, 1], out[m, 2], out[m, 3] = x[m, 7], x[m, 8], x[m, 9]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_loglik(x: np.ndarray, C_nb: np.ndarray, psi: float, y: np.ndarray, L: np.ndarray, out: np.ndarray) -> None:
    """``log N(y - h(x_m); 0, L L^T)`` into out (M,) for states x (M, 16): the residual of
    :meth:`SarModel.residual <dpos_core.sar.model.SarModel.residual>` (heading wrapped) and the
    density of :func:`dpos_core.filters.linalg.gauss_logpdf` (its kernel's arithmetic) in one pass;
    y (4,) and L (4, 4) at a SAR epoch (h's four rows), y (1,) and L (1, 1) without a fix (the
    barometer row: the height error)."""
    p = y.shape[0]
    half_logdet = 0.0
    for j in range(p):
        half_logdet += math.log(L[j, j])
    c = half_logdet + 0.5 * p * math.log(2.0 * math.pi)
    r = np.empty(p)
    z = np.empty(p)
    for m in range(x.shape[0]):
        if p == 4:
            r[0] = _wrap(y[0] - _heading_row(x[m, 0], x[m, 1], x[m, 2], x[m, 3], C_nb, psi))
            r[1], r[2], r[3] = y[1] - x[m, 7], y[2] - x[m, 8], y[3] - x[m, 9]
        else:
            r[0] = y[0] - x[m, 9]
        q = 0.0
        for a in range(p):
            e = r[a]
            for b in range(a):
                e -= L[a, b] * z[b]
            z[a] = e / L[a, a]
            q += z[a] * z[a]
        out[m] = -0.5 * q - c


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_project(x: np.ndarray, out: np.ndarray) -> None:
    """:meth:`SarModel.project <dpos_core.sar.model.SarModel.project>`: x (M, 16) with the
    quaternion normalized into out (M, 16)."""
    for m in range(x.shape[0]):
        out[m, 0], out[m, 1], out[m, 2], out[m, 3] = _normalize(x[m, 0], x[m, 1], x[m, 2], x[m, 3])
        for i in range(4, 16):
            out[m, i] = x[m, i]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_wrap_heading(d: np.ndarray) -> None:
    """The heading column of residuals d (M, 4) wrapped to (-pi, pi] in place
    (:func:`dpos_core.attitude.wrap_angle`)."""
    for m in range(d.shape[0]):
        d[m, 0] = _wrap(d[m, 0])
