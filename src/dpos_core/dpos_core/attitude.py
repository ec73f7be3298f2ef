"""Attitude representations: Hamilton quaternions, direction cosine matrices, rotation vectors,
and the attitude error between two attitudes.

Conventions
-----------
* Quaternions are scalar-first ``[w, x, y, z]`` (Hamilton product).  ``q_nb`` rotates a vector
  from frame ``b`` to frame ``n``: ``v_n = q_nb * v_b * conj(q_nb)``; its DCM is ``C_nb``
  (``v_n = C_nb @ v_b``, the papers' ``C_b^n``).
* A rotation vector ``phi`` has the rotation axis as direction and the angle [rad] as norm;
  ``rotvec_to_dcm(phi) = expm([phi x])``.
* Every function broadcasts over leading axes (shape ``(..., 4)``, ``(..., 3)``, ``(..., 3, 3)``).

Euler angles live in :mod:`dpos_core.frames`, which owns the body/world axis conventions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from . import _attitude_kernel as _ak

_SMALL_ANGLE_RAD = 1e-6


def _rows(kernel, x: ArrayLike, item_in: tuple[int, ...], item_out: tuple[int, ...]) -> FloatArray:
    """Apply a row kernel of :mod:`._attitude_kernel` to ``x`` (..., *item_in): (..., *item_out)."""
    a = np.asarray(x, dtype=float)
    lead = a.shape[: a.ndim - len(item_in)]
    if a.shape[a.ndim - len(item_in):] != item_in:
        raise ValueError(f"expected shape (..., {', '.join(map(str, item_in))}), got {a.shape}")
    flat = np.ascontiguousarray(a).reshape((-1,) + item_in)
    out = np.empty((flat.shape[0],) + item_out)
    kernel(flat, out)
    return out.reshape(lead + item_out)


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix ``[v x]``, shape ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    K = np.zeros(v.shape[:-1] + (3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    K[..., 0, 1], K[..., 0, 2] = -z, y
    K[..., 1, 0], K[..., 1, 2] = z, -x
    K[..., 2, 0], K[..., 2, 1] = -y, x
    return K


def cross(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a x b`` of 3-vectors ``(..., 3)``, broadcast together (``np.cross`` without its
    per-call overhead)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def quat_mul(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p * q``, shape ``(..., 4)``."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qw - px * qx - py * qy - pz * qz
    out[..., 1] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 2] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 3] = pw * qz + px * qy - py * qx + pz * qw
    return out


def quat_conj(q: ArrayLike) -> FloatArray:
    """Conjugate (inverse of a unit quaternion), shape ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Unit quaternion with non-negative scalar part, shape ``(..., 4)``."""
    u = np.asarray(q, dtype=float)
    u = u / np.sqrt(np.sum(u * u, axis=-1, keepdims=True))
    return np.where(u[..., :1] < 0.0, -u, u)


def quat_to_dcm(q: ArrayLike) -> FloatArray:
    """Unit quaternion ``q_nb`` -> DCM ``C_nb``, shape ``(..., 3, 3)``."""
    return _rows(_ak.rows_quat_to_dcm, q, (4,), (3, 3))


def dcm_to_quat(C: ArrayLike) -> FloatArray:
    """DCM ``C_nb`` -> unit quaternion ``q_nb`` (Shepperd's method, robust for all angles).

    Each candidate row ``[1 + tr, ...]`` equals ``4 q_i * q``; the one with the largest pivot
    ``q_i`` (of ``tr, C_00, C_11, C_22``) is used, normalized, scalar part made non-negative.
    """
    return _rows(_ak.rows_dcm_to_quat, C, (3, 3), (4,))


def rotvec_to_quat(phi: ArrayLike) -> FloatArray:
    """Rotation vector -> unit quaternion, shape ``(..., 4)`` (series below 1e-6 rad)."""
    return _rows(_ak.rows_rotvec_to_quat, phi, (3,), (4,))


def quat_to_rotvec(q: ArrayLike) -> FloatArray:
    """Unit quaternion -> rotation vector with angle in ``[0, pi]``, shape ``(..., 3)`` (the
    quaternion normalized first; ``2 v / w`` below ``|v|`` = 1e-12)."""
    return _rows(_ak.rows_quat_to_rotvec, q, (4,), (3,))


def rotvec_to_dcm(phi: ArrayLike) -> FloatArray:
    """Rotation vector -> DCM ``expm([phi x])``, shape ``(..., 3, 3)``."""
    return quat_to_dcm(rotvec_to_quat(phi))


def dcm_to_rotvec(C: ArrayLike) -> FloatArray:
    """DCM -> rotation vector (``logm``), shape ``(..., 3)``; valid up to pi."""
    return _rows(_ak.rows_dcm_to_rotvec, C, (3, 3), (3,))


def attitude_error(C_nb_est: ArrayLike, C_nb_true: ArrayLike) -> FloatArray:
    """Attitude error ``phi^n`` (rotation vector, world frame) of an estimate, shape ``(..., 3)``.

    Defined exactly (no small-angle assumption) by ``C_nb_est = expm(-[phi x]) @ C_nb_true``,
    the misalignment ("phi-angle") convention of the papers' error models ([Gong2018] eq. 11:
    ``C_n^{n'} = I - [phi x]`` to first order).  Valid for any angle below pi and
    free of Euler-angle singularities and heading wrap.  The estimate is corrected by
    ``C_nb_true = expm([phi x]) @ C_nb_est``.
    """
    C_est = np.asarray(C_nb_est, dtype=float)
    C_true = np.asarray(C_nb_true, dtype=float)
    return dcm_to_rotvec(C_true @ np.swapaxes(C_est, -1, -2))


def apply_attitude_correction(C_nb_est: ArrayLike, phi_n_rad: ArrayLike) -> FloatArray:
    """Inverse of :func:`attitude_error`: ``expm([phi x]) @ C_nb_est``."""
    return rotvec_to_dcm(phi_n_rad) @ np.asarray(C_nb_est, dtype=float)


def wrap_angle(angle_rad: ArrayLike) -> FloatArray:
    """Wrap to ``(-pi, pi]``."""
    a = np.asarray(angle_rad, dtype=float)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


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


def mount_dcm(mount_rpy_deg: ArrayLike, rho_deg: ArrayLike) -> FloatArray:
    """``C_b_s0 = C_mount expm([rho x])`` from the nominal mount roll/pitch/yaw (about x, y, z of
    the master body, applied z-y-x) and the rigid misalignment rotation vector [deg]."""
    r, p, y = np.deg2rad(np.asarray(mount_rpy_deg, dtype=float))
    cz, sz, cy, sy, cx, sx = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
    Ry = np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
    Rx = np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz @ Ry @ Rx @ rotvec_to_dcm(np.deg2rad(np.asarray(rho_deg, dtype=float)))


def compose_rotvec(a: FloatArray, b: FloatArray) -> FloatArray:
    """``log(expm([a x]) expm([b x]))`` (..., 3), a and b broadcast together."""
    a_, b_ = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if b_.shape == (3,) and a_.ndim >= 1 and a_.shape[-1] == 3:  # one b for every a (a filter's correction)
        fa = np.ascontiguousarray(a_).reshape(-1, 3)
        out = np.empty_like(fa)
        _ak.rows_compose_rotvec_one(fa, np.ascontiguousarray(b_), out)
        return out.reshape(a_.shape)
    a_, b_ = np.broadcast_arrays(a_, b_)
    fa = np.ascontiguousarray(a_).reshape(-1, 3)
    out = np.empty_like(fa)
    _ak.rows_compose_rotvec(fa, np.ascontiguousarray(b_).reshape(-1, 3), out)
    return out.reshape(a_.shape)
