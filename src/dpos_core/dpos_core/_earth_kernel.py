"""Private numba kernels of :mod:`dpos_core.earth`: the exact lever-arm offset through ECEF row by
row (scalar code, no temporaries).  Use :func:`dpos_core.earth.offset_llh`, which documents the
conventions; the formulas (WGS-84, Bowring's iteration with four passes) are the same."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# WGS-84 (the values of dpos_core.earth, repeated: a kernel module imports nothing of the package)
_A_M = 6378137.0
_F = 1.0 / 298.257223563
_B_M = _A_M * (1.0 - _F)
_E2 = _F * (2.0 - _F)
_EP2 = _E2 / (1.0 - _E2)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def rows_offset_llh(llh: np.ndarray, d_n: np.ndarray, out: np.ndarray) -> None:
    """Rows: ``llh`` (M, 3) moved by ``d_n`` (M, 3) [m] in its local ENU frame -> ``out`` (M, 3)
    (:func:`dpos_core.earth.offset_llh`: geodetic -> ECEF, plus ``C_en d_n``, Bowring back)."""
    for m in range(llh.shape[0]):
        lat, lon, h = llh[m, 0], llh[m, 1], llh[m, 2]
        sl, cl = math.sin(lat), math.cos(lat)
        so, co = math.sin(lon), math.cos(lon)
        r_n = _A_M / math.sqrt(1.0 - _E2 * sl * sl)
        de, dn, du = d_n[m, 0], d_n[m, 1], d_n[m, 2]
        x = (r_n + h) * cl * co + (-so * de - sl * co * dn + cl * co * du)
        y = (r_n + h) * cl * so + (co * de - sl * so * dn + cl * so * du)
        z = (r_n * (1.0 - _E2) + h) * sl + (cl * dn + sl * du)
        p = math.hypot(x, y)
        # Bowring's passes with the sines and cosines of the angles from their tangents' terms
        # (sin(atan2(u, v)) = u / hypot(u, v), ...): the same iteration without the trigonometry
        r = math.hypot(z, (1.0 - _F) * p)
        sb, cb = z / r, (1.0 - _F) * p / r
        num, den = z, p
        for _ in range(4):
            num = z + _EP2 * _B_M * sb**3
            den = p - _E2 * _A_M * cb**3
            r = math.hypot(num, den)
            s2, c2 = num / r, den / r
            r = math.hypot((1.0 - _F) * s2, c2)
            sb, cb = (1.0 - _F) * s2 / r, c2 / r
        r = math.hypot(num, den)
        s2, c2 = num / r, den / r
        out[m, 0] = math.atan2(num, den)
        out[m, 1] = math.atan2(y, x)
        out[m, 2] = p * c2 + z * s2 - _A_M * math.sqrt(1.0 - _E2 * s2 * s2)
