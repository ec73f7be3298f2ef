"""Private numba kernel of :meth:`dpos_core.ta.model.TransferAlignmentModel.vibration_variance`:
the detrended matching residuals' variance over one interval in one pass (scalar code, no
temporaries).  The method documents the measure; the formulas here are the same."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# WGS-84 (the values of dpos_core.earth, repeated: a kernel module imports nothing of the package)
_A_M = 6378137.0
_F = 1.0 / 298.257223563
_E2 = _F * (2.0 - _F)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def residual_variance(tm: np.ndarray, tc: np.ndarray, vc: np.ndarray, lc: np.ndarray, vm: np.ndarray, lm: np.ndarray,
                      C_m: np.ndarray, w_m: np.ndarray, r0: np.ndarray, cov_v: np.ndarray, cov_p: np.ndarray,
                      out: np.ndarray, mean_var: np.ndarray) -> None:
    """The residual variance (6,) -> ``out`` of the velocity and position matches at the main-POS
    epochs ``tm`` (n,), detrended by a straight line (n - 2 degrees of freedom), and the mean of
    the main POS's velocity and position variances (6,) -> ``mean_var``.

    Args:
        tm: main-POS stamps (n,) [s]; tc: the nominal chunk's stamps (M,), increasing.
        vc, lc: the chunk's velocity (M, 3) [m/s] and llh (M, 3), linearly interpolated at ``tm``.
        vm, lm, C_m, w_m: the main POS's velocity (n, 3), llh (n, 3), C_nb (n, 3, 3) and body
            rate (n, 3) at ``tm``; r0: the lever arm (3,) [m].
        cov_v, cov_p: the main POS's velocity and position covariances (n, 3, 3) at ``tm``.
    """
    n = tm.shape[0]
    r = np.empty((n, 6))
    nom = np.empty(6)
    for i in range(n):
        for c in range(3):
            nom[c] = np.interp(tm[i], tc, vc[:, c])
            nom[3 + c] = np.interp(tm[i], tc, lc[:, c])
        wx, wy, wz = w_m[i, 0], w_m[i, 1], w_m[i, 2]
        a0 = wy * r0[2] - wz * r0[1]  # w_m x r0
        a1 = wz * r0[0] - wx * r0[2]
        a2 = wx * r0[1] - wy * r0[0]
        s = math.sin(nom[3])
        w = 1.0 - _E2 * s * s
        r_n = _A_M / math.sqrt(w)
        r_m = r_n * (1.0 - _E2) / w
        h = nom[5]
        # the position difference in local ENU metres (llh is lat, lon, h: East from the longitude)
        d_enu = ((nom[4] - lm[i, 1]) * (r_n + h) * math.cos(nom[3]), (nom[3] - lm[i, 0]) * (r_m + h), nom[5] - lm[i, 2])
        for c in range(3):
            r[i, c] = nom[c] - vm[i, c] - (C_m[i, c, 0] * a0 + C_m[i, c, 1] * a1 + C_m[i, c, 2] * a2)
            r[i, 3 + c] = d_enu[c] - (C_m[i, c, 0] * r0[0] + C_m[i, c, 1] * r0[1] + C_m[i, c, 2] * r0[2])
    t_mean = 0.0
    for i in range(n):
        t_mean += tm[i]
    t_mean /= n
    tt = 0.0
    for i in range(n):
        tt += (tm[i] - t_mean) ** 2
    for c in range(6):
        mean = 0.0
        slope = 0.0
        for i in range(n):
            mean += r[i, c]
            slope += (tm[i] - t_mean) * r[i, c]
        mean /= n
        slope /= tt
        acc = 0.0
        for i in range(n):
            e = r[i, c] - mean - (tm[i] - t_mean) * slope
            acc += e * e
        out[c] = acc / (n - 2)
    for c in range(3):
        sv = 0.0
        sp = 0.0
        for i in range(n):
            sv += cov_v[i, c, c]
            sp += cov_p[i, c, c]
        mean_var[c] = sv / n
        mean_var[3 + c] = sp / n
