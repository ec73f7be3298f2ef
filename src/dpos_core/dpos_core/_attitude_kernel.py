"""Private numba kernels of :mod:`dpos_core.attitude`: the conversions between rotation vectors,
quaternions and DCMs row by row (scalar code, no temporaries), for batches of any size.  Use
:mod:`dpos_core.attitude`, which documents the conventions; the formulas and branch thresholds
are the same (the numpy ``error_model``: a zero quaternion gives NaN, as numpy does)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_SMALL_ANGLE_RAD = 1e-6  # attitude.rotvec_to_quat's series threshold


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rotvec_quat(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """:func:`dpos_core.attitude.rotvec_to_quat` of one rotation vector."""
    a2 = x * x + y * y + z * z
    a = math.sqrt(a2)
    if a < _SMALL_ANGLE_RAD:
        w = 1.0 - a2 / 8.0
        s = 0.5 - a2 / 48.0
    else:
        w = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return w, s * x, s * y, s * z


@nb.njit(cache=True, nogil=True, error_model="numpy")
def quat_mul(aw: float, ax: float, ay: float, az: float,
             bw: float, bx: float, by: float, bz: float) -> tuple[float, float, float, float]:
    """Hamilton product ``a * b`` (:func:`dpos_core.attitude.quat_mul`)."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@nb.njit(cache=True, nogil=True, error_model="numpy")
def quat_rotvec(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`dpos_core.attitude.quat_to_rotvec` (normalized, non-negative scalar part first)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    sn = math.sqrt(x * x + y * y + z * z)
    if sn < 1e-12:
        scale = 2.0 / w
    else:
        scale = 2.0 * math.atan2(sn, w) / sn
    return scale * x, scale * y, scale * z


@nb.njit(cache=True, nogil=True, error_model="numpy")
def quat_dcm(q: tuple[float, float, float, float], out: np.ndarray) -> None:
    """:func:`dpos_core.attitude.quat_to_dcm` of one quaternion into ``out`` (3, 3)."""
    w, x, y, z = q
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def dcm_quat(C: np.ndarray) -> tuple[float, float, float, float]:
    """:func:`dpos_core.attitude.dcm_to_quat` of one DCM (3, 3) (Shepperd, normalized, w >= 0)."""
    m00, m01, m02 = C[0, 0], C[0, 1], C[0, 2]
    m10, m11, m12 = C[1, 0], C[1, 1], C[1, 2]
    m20, m21, m22 = C[2, 0], C[2, 1], C[2, 2]
    tr = m00 + m11 + m22
    k = 0
    best = tr
    if m00 > best:
        k, best = 1, m00
    if m11 > best:
        k, best = 2, m11
    if m22 > best:
        k = 3
    if k == 0:
        w, x, y, z = 1.0 + tr, m21 - m12, m02 - m20, m10 - m01
    elif k == 1:
        w, x, y, z = m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20
    elif k == 2:
        w, x, y, z = m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21
    else:
        w, x, y, z = m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        return -w, -x, -y, -z
    return w, x, y, z


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_rotvec_to_quat(phi: np.ndarray, out: np.ndarray) -> None:
    """Rows (M, 3) -> (M, 4)."""
    for m in range(phi.shape[0]):
        out[m, 0], out[m, 1], out[m, 2], out[m, 3] = rotvec_quat(phi[m, 0], phi[m, 1], phi[m, 2])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_quat_to_rotvec(q: np.ndarray, out: np.ndarray) -> None:
    """Rows (M, 4) -> (M, 3)."""
    for m in range(q.shape[0]):
        out[m, 0], out[m, 1], out[m, 2] = quat_rotvec(q[m, 0], q[m, 1], q[m, 2], q[m, 3])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_quat_to_dcm(q: np.ndarray, out: np.ndarray) -> None:
    """Rows (M, 4) -> (M, 3, 3)."""
    for m in range(q.shape[0]):
        quat_dcm((q[m, 0], q[m, 1], q[m, 2], q[m, 3]), out[m])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_dcm_to_quat(C: np.ndarray, out: np.ndarray) -> None:
    """Rows (M, 3, 3) -> (M, 4)."""
    for m in range(C.shape[0]):
        out[m, 0], out[m, 1], out[m, 2], out[m, 3] = dcm_quat(C[m])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_dcm_to_rotvec(C: np.ndarray, out: np.ndarray) -> None:
    """Rows (M, 3, 3) -> (M, 3)."""
    for m in range(C.shape[0]):
        w, x, y, z = dcm_quat(C[m])
        out[m, 0], out[m, 1], out[m, 2] = quat_rotvec(w, x, y, z)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_compose_rotvec(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Rows ``log(expm([a x]) expm([b x]))``, a, b, out (M, 3)."""
    for m in range(a.shape[0]):
        aw, ax, ay, az = rotvec_quat(a[m, 0], a[m, 1], a[m, 2])
        bw, bx, by, bz = rotvec_quat(b[m, 0], b[m, 1], b[m, 2])
        w, x, y, z = quat_mul(aw, ax, ay, az, bw, bx, by, bz)
        out[m, 0], out[m, 1], out[m, 2] = quat_rotvec(w, x, y, z)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_compose_rotvec_one(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Rows ``log(expm([a x]) expm([b x]))`` of a, out (M, 3) with one b (3,) (:func:`rows_compose_rotvec`
    of b repeated)."""
    bw, bx, by, bz = rotvec_quat(b[0], b[1], b[2])
    for m in range(a.shape[0]):
        aw, ax, ay, az = rotvec_quat(a[m, 0], a[m, 1], a[m, 2])
        w, x, y, z = quat_mul(aw, ax, ay, az, bw, bx, by, bz)
        out[m, 0], out[m, 1], out[m, 2] = quat_rotvec(w, x, y, z)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rotate_normalize(q: np.ndarray, phi: np.ndarray) -> None:
    """``q`` (4,) in place: ``quat_normalize(rotvec_quat(phi) * q)`` (a strapdown's attitude
    correction, :meth:`dpos_core.strapdown.Strapdown.correct`; the norm summed in numpy's order)."""
    w, x, y, z = quat_mul(*rotvec_quat(phi[0], phi[1], phi[2]), q[0], q[1], q[2], q[3])
    s = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / s, x / s, y / s, z / s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    q[0], q[1], q[2], q[3] = w, x, y, z
