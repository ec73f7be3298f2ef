"""Private numba kernel of :func:`dpos_ros.contract.conversions.antenna_odometry_values`: an
antenna pose's ``nav_msgs/Odometry`` doubles, one loop over the rows instead of ~30 numpy passes
over (N, 3, 3) stacks (8.6 M antenna poses an hour of paper_wing)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, error_model="numpy")
def odometry_rows(llh: np.ndarray, vel_n: np.ndarray, C_nb: np.ndarray, sigma: np.ndarray, C0: np.ndarray, p0: np.ndarray,
                  a_m: float, e2: float, out: np.ndarray, C_wb: np.ndarray) -> None:
    """Rows m: llh (M, 3) [rad, rad, m], vel_n (M, 3) local ENU, C_nb (M, 3, 3), sigma (M, 9) as
    ``AntennaSolution.sigma``; ``C0`` (3, 3) C_en of the datum, ``p0`` (3,) its ECEF position;
    WGS-84 ``a_m``, ``e2``.  Fills ``out`` (M, 85) but the orientation (3:7, from ``C_wb`` (M, 3, 3),
    filled here) and ``C_wb``."""
    R = np.empty((3, 3))
    Cen = np.empty((3, 3))
    for m in range(llh.shape[0]):
        lat, lon, h = llh[m, 0], llh[m, 1], llh[m, 2]
        sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
        r_n = a_m / math.sqrt(1.0 - e2 * sl * sl)
        d0 = (r_n + h) * cl * co - p0[0]
        d1 = (r_n + h) * cl * so - p0[1]
        d2 = (r_n * (1.0 - e2) + h) * sl - p0[2]
        for i in range(3):  # position in the datum's ENU: C0^T (p_e - p0)
            out[m, i] = d0 * C0[0, i] + d1 * C0[1, i] + d2 * C0[2, i]
        # C_en at the row: columns east, north, up in ECEF
        Cen[0, 0], Cen[1, 0], Cen[2, 0] = -so, co, 0.0
        Cen[0, 1], Cen[1, 1], Cen[2, 1] = -sl * co, -sl * so, cl
        Cen[0, 2], Cen[1, 2], Cen[2, 2] = cl * co, cl * so, sl
        for i in range(3):  # R = C0^T C_en: local ENU -> datum ENU
            for j in range(3):
                R[i, j] = C0[0, i] * Cen[0, j] + C0[1, i] * Cen[1, j] + C0[2, i] * Cen[2, j]
        for i in range(3):
            for j in range(3):
                C_wb[m, i, j] = R[i, 0] * C_nb[m, 0, j] + R[i, 1] * C_nb[m, 1, j] + R[i, 2] * C_nb[m, 2, j]
        for j in range(3):  # the velocity in the body: C_nb^T v_n (= C_wb^T R v_n)
            out[m, 43 + j] = C_nb[m, 0, j] * vel_n[m, 0] + C_nb[m, 1, j] * vel_n[m, 1] + C_nb[m, 2, j] * vel_n[m, 2]
        for i in range(3):  # pose covariance: R diag(s^2) R^T, position (sigma 6:9) then orientation (sigma 0:3)
            for j in range(3):
                pp = 0.0
                po = 0.0
                tw = 0.0
                for k in range(3):
                    pp += R[i, k] * sigma[m, 6 + k] ** 2 * R[j, k]
                    po += R[i, k] * sigma[m, k] ** 2 * R[j, k]
                    tw += C_nb[m, k, i] * sigma[m, 3 + k] ** 2 * C_nb[m, k, j]  # twist: C_bn diag(s^2) C_nb
                out[m, 7 + 6 * i + j] = pp
                out[m, 7 + 6 * i + j + 3] = 0.0
                out[m, 7 + 6 * (i + 3) + j] = 0.0
                out[m, 7 + 6 * (i + 3) + j + 3] = po
                out[m, 49 + 6 * i + j] = tw
                out[m, 49 + 6 * i + j + 3] = 0.0
                out[m, 49 + 6 * (i + 3) + j] = 0.0
                out[m, 49 + 6 * (i + 3) + j + 3] = -1.0 if i == j else 0.0  # angular rate not estimated
            out[m, 46 + i] = 0.0
