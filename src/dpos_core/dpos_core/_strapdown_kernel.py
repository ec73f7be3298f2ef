"""Private numba kernel of the local-level (ENU) strapdown mechanization.

Use :class:`dpos_core.strapdown.Strapdown`; this module only holds the hot loop, written with
scalars so that numba keeps everything in registers (no per-sample allocation).  The algorithm
is documented in :mod:`dpos_core.strapdown`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .earth import A_M, E2, GAMMA_E_MPS2, K_SOMIGLIANA, M_GRAV, OMEGA_IE_RADPS, F

MODE_INCREMENTS = 0
MODE_RATES = 1

# state vector layout: q_nb (4), vel_n (3), lat, lon, h (3), previous velocity change (3)
STATE_SIZE = 13
# previous-sample memory: a_prev (3), b_prev (3), has_prev (1)
PREV_SIZE = 7

_SMALL2 = 1e-12  # squared angle below which the rotation-vector series is used


@nb.njit(cache=True, nogil=True)
def _gravity(lat: float, h: float) -> float:
    s2 = math.sin(lat) ** 2
    g0 = GAMMA_E_MPS2 * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_GRAV - 2.0 * F * s2) * h + 3.0 / (A_M * A_M) * h * h)


@nb.njit(cache=True, nogil=True)
def _radii(lat: float) -> tuple[float, float]:
    s = math.sin(lat)
    w = 1.0 - E2 * s * s
    rn = A_M / math.sqrt(w)
    return rn * (1.0 - E2) / w, rn


@nb.njit(cache=True, nogil=True)
def _rv2q(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    a2 = x * x + y * y + z * z
    if a2 < _SMALL2:
        w = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        a = math.sqrt(a2)
        w = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return w, s * x, s * y, s * z


@nb.njit(cache=True, nogil=True)
def _qmul(
    aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float, bz: float
) -> tuple[float, float, float, float]:
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@nb.njit(cache=True, nogil=True)
def integrate(
    mode: int,
    dt: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    state: np.ndarray,
    prev: np.ndarray,
    coning: bool,
    sculling: bool,
    out_q: np.ndarray,
    out_v: np.ndarray,
    out_llh: np.ndarray,
) -> None:
    """Integrate ``len(dt)`` IMU steps in place.

    mode 0: ``a``, ``b`` = angle and velocity increments over ``(t_{k-1}, t_k]``;
    mode 1: ``a``, ``b`` = angular rate and specific force sampled at ``t_k`` (``prev`` holds
    the sample at ``t_{k-1}`` and must be set).  ``state`` / ``prev`` are updated in place.
    """
    qw, qx, qy, qz = state[0], state[1], state[2], state[3]
    vx, vy, vz = state[4], state[5], state[6]
    lat, lon, h = state[7], state[8], state[9]
    dpx, dpy, dpz = state[10], state[11], state[12]
    pax, pay, paz = prev[0], prev[1], prev[2]
    pbx, pby, pbz = prev[3], prev[4], prev[5]
    has_prev = prev[6] > 0.5

    for k in range(dt.shape[0]):
        T = dt[k]
        ax, ay, az = a[k, 0], a[k, 1], a[k, 2]
        bx, by, bz = b[k, 0], b[k, 1], b[k, 2]
        if mode == MODE_INCREMENTS:
            thx, thy, thz = ax, ay, az
            dvx, dvy, dvz = bx, by, bz
            c12 = 1.0 / 12.0
        else:
            thx, thy, thz = 0.5 * (pax + ax) * T, 0.5 * (pay + ay) * T, 0.5 * (paz + az) * T
            dvx, dvy, dvz = 0.5 * (pbx + bx) * T, 0.5 * (pby + by) * T, 0.5 * (pbz + bz) * T
            c12 = T * T / 12.0
        # coning (Savage: 1/12 a_{k-1} x a_k) and sculling (1/12 (a_{k-1} x b_k + b_{k-1} x a_k))
        cx = cy = cz = 0.0
        sx = sy = sz = 0.0
        if has_prev:
            if coning:
                cx = c12 * (pay * az - paz * ay)
                cy = c12 * (paz * ax - pax * az)
                cz = c12 * (pax * ay - pay * ax)
            if sculling:
                sx = c12 * ((pay * bz - paz * by) + (pby * az - pbz * ay))
                sy = c12 * ((paz * bx - pax * bz) + (pbz * ax - pbx * az))
                sz = c12 * ((pax * by - pay * bx) + (pbx * ay - pby * ax))
        pax, pay, paz, pbx, pby, pbz = ax, ay, az, bx, by, bz
        has_prev = True

        # --- navigation quantities at mid-interval, extrapolated from the last velocity change
        vmx, vmy, vmz = vx + 0.5 * dpx, vy + 0.5 * dpy, vz + 0.5 * dpz
        rm, rn = _radii(lat)
        lat_m = lat + 0.5 * vmy * T / (rm + h)
        h_m = h + 0.5 * vmz * T
        rm, rn = _radii(lat_m)
        cl, sl = math.cos(lat_m), math.sin(lat_m)
        wie_y, wie_z = OMEGA_IE_RADPS * cl, OMEGA_IE_RADPS * sl
        wen_x = -vmy / (rm + h_m)
        wen_y = vmx / (rn + h_m)
        wen_z = vmx * sl / cl / (rn + h_m)
        zx, zy, zz = wen_x * T, (wie_y + wen_y) * T, (wie_z + wen_z) * T
        g = _gravity(lat_m, h_m)

        # --- velocity: specific-force increment with rotation + sculling compensation
        ux = dvx + 0.5 * (thy * dvz - thz * dvy) + sx
        uy = dvy + 0.5 * (thz * dvx - thx * dvz) + sy
        uz = dvz + 0.5 * (thx * dvy - thy * dvx) + sz
        # to the n frame at t_{k-1}: C_nb u
        c00 = 1.0 - 2.0 * (qy * qy + qz * qz)
        c01 = 2.0 * (qx * qy - qw * qz)
        c02 = 2.0 * (qx * qz + qw * qy)
        c10 = 2.0 * (qx * qy + qw * qz)
        c11 = 1.0 - 2.0 * (qx * qx + qz * qz)
        c12n = 2.0 * (qy * qz - qw * qx)
        c20 = 2.0 * (qx * qz - qw * qy)
        c21 = 2.0 * (qy * qz + qw * qx)
        c22 = 1.0 - 2.0 * (qx * qx + qy * qy)
        nx = c00 * ux + c01 * uy + c02 * uz
        ny = c10 * ux + c11 * uy + c12n * uz
        nz = c20 * ux + c21 * uy + c22 * uz
        # n-frame rotation over the interval: (I - 1/2 [zeta x])
        nx2 = nx - 0.5 * (zy * nz - zz * ny)
        ny2 = ny - 0.5 * (zz * nx - zx * nz)
        nz2 = nz - 0.5 * (zx * ny - zy * nx)
        # Coriolis + transport: (2 w_ie + w_en) x v_mid ; gravity
        ox, oy, oz = wen_x, 2.0 * wie_y + wen_y, 2.0 * wie_z + wen_z
        corx = oy * vmz - oz * vmy
        cory = oz * vmx - ox * vmz
        corz = ox * vmy - oy * vmx
        vx1 = vx + nx2 - corx * T
        vy1 = vy + ny2 - cory * T
        vz1 = vz + nz2 + (-g - corz) * T

        # --- position: trapezoidal velocity
        h1 = h + 0.5 * (vz + vz1) * T
        h_a = 0.5 * (h + h1)
        lat1 = lat + 0.5 * (vy + vy1) * T / (rm + h_a)
        lat_a = 0.5 * (lat + lat1)
        rm_a, rn_a = _radii(lat_a)
        lon1 = lon + 0.5 * (vx + vx1) * T / ((rn_a + h_a) * math.cos(lat_a))

        # --- attitude: n-frame rotation from the mean velocity / position over the interval
        vax, vay = 0.5 * (vx + vx1), 0.5 * (vy + vy1)
        cla, sla = math.cos(lat_a), math.sin(lat_a)
        zx = -vay / (rm_a + h_a) * T
        zy = (OMEGA_IE_RADPS * cla + vax / (rn_a + h_a)) * T
        zz = (OMEGA_IE_RADPS * sla + vax * sla / cla / (rn_a + h_a)) * T
        bw, bqx, bqy, bqz = _rv2q(thx + cx, thy + cy, thz + cz)
        nw, nqx, nqy, nqz = _rv2q(zx, zy, zz)
        qw, qx, qy, qz = _qmul(qw, qx, qy, qz, bw, bqx, bqy, bqz)
        qw, qx, qy, qz = _qmul(nw, -nqx, -nqy, -nqz, qw, qx, qy, qz)
        inv = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw * inv, qx * inv, qy * inv, qz * inv

        dpx, dpy, dpz = vx1 - vx, vy1 - vy, vz1 - vz
        vx, vy, vz = vx1, vy1, vz1
        lat, lon, h = lat1, lon1, h1

        out_q[k, 0] = qw
        out_q[k, 1] = qx
        out_q[k, 2] = qy
        out_q[k, 3] = qz
        out_v[k, 0] = vx
        out_v[k, 1] = vy
        out_v[k, 2] = vz
        out_llh[k, 0] = lat
        out_llh[k, 1] = lon
        out_llh[k, 2] = h

    state[0], state[1], state[2], state[3] = qw, qx, qy, qz
    state[4], state[5], state[6] = vx, vy, vz
    state[7], state[8], state[9] = lat, lon, h
    state[10], state[11], state[12] = dpx, dpy, dpz
    prev[0], prev[1], prev[2] = pax, pay, paz
    prev[3], prev[4], prev[5] = pbx, pby, pbz
    prev[6] = 1.0 if has_prev else 0.0


@nb.njit(cache=True, nogil=True)
def rk4_llh(v_nodes: np.ndarray, v_mid: np.ndarray, h: float, llh0: np.ndarray) -> np.ndarray:
    """RK4 of ``d(lat, lon, h)/dt`` for a known ENU velocity at the grid nodes and mid-points.

    ``v_nodes`` (N+1, 3), ``v_mid`` (N, 3) -> llh (N+1, 3).  Used by the flight simulator.
    """
    n = v_mid.shape[0]
    out = np.empty((n + 1, 3))
    out[0, 0], out[0, 1], out[0, 2] = llh0[0], llh0[1], llh0[2]
    for k in range(n):
        lat, lon, hh = out[k, 0], out[k, 1], out[k, 2]
        acc_lat = 0.0
        acc_lon = 0.0
        acc_h = 0.0
        dl, dn, dh = 0.0, 0.0, 0.0
        for stage in range(4):
            if stage == 0:
                ve, vn, vu = v_nodes[k, 0], v_nodes[k, 1], v_nodes[k, 2]
                la, ha, wgt = lat, hh, 1.0
            elif stage == 3:
                ve, vn, vu = v_nodes[k + 1, 0], v_nodes[k + 1, 1], v_nodes[k + 1, 2]
                la, ha, wgt = lat + h * dl, hh + h * dh, 1.0
            else:
                ve, vn, vu = v_mid[k, 0], v_mid[k, 1], v_mid[k, 2]
                la, ha, wgt = lat + 0.5 * h * dl, hh + 0.5 * h * dh, 2.0
            rm, rn = _radii(la)
            dl = vn / (rm + ha)
            dn = ve / ((rn + ha) * math.cos(la))
            dh = vu
            acc_lat += wgt * dl
            acc_lon += wgt * dn
            acc_h += wgt * dh
        out[k + 1, 0] = lat + h / 6.0 * acc_lat
        out[k + 1, 1] = lon + h / 6.0 * acc_lon
        out[k + 1, 2] = hh + h / 6.0 * acc_h
    return out


@nb.njit(cache=True, nogil=True)
def linear_recursion(Phi: np.ndarray, L: np.ndarray, x0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``x_{k+1} = Phi x_k + L w_k`` for a small state: Phi, L (n, n), x0 (n,), w (N, n) -> x (N+1, n)."""
    n_steps, n = w.shape
    out = np.empty((n_steps + 1, n))
    out[0] = x0
    for k in range(n_steps):
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += Phi[i, j] * out[k, j] + L[i, j] * w[k, j]
            out[k + 1, i] = acc
    return out
