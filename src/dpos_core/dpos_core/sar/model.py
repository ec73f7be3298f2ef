"""The SINS/SAR/baro error model of [Yan2016] sec. 2 (after Zhong, Gao, Li 2012, its ref. [19]).

The SINS runs free (open loop) from the main IMU; the filters estimate its errors.  State x (16,)
([Yan2016] eq. 1, in this order):

* ``q`` (4): the attitude-error quaternion, ``C_nb_sins = C(q) C_nb_true`` (C(q) = C_n^n': true
  local-level frame -> the SINS's computed one; scalar first, ``q0 >= 0``);
* ``dv`` (3): velocity error ``v_sins - v_true``, local ENU [m/s];
* ``dp`` (3): position error ``(dL, dlambda, dh)`` of SINS - truth, expressed in metres north,
  east, up (``dL (R_M + h)``, ``dlambda (R_N + h) cos L``, ``dh``: the same state as the seed's
  radians, scaled so that the covariances stay well conditioned);
* ``eps`` (3): gyro constant drift [rad/s]; ``nab`` (3): accelerometer bias [m/s^2] (body axes).

Transition ([Yan2016] eq. 2, the nonlinear error equations written exactly for the phi-angle
quaternion, one filter step ``dt``): with ``w_in`` the true frame rate (earth + transport rate at
the true position and velocity: the SINS's minus the errors), ``w_in'`` the SINS's and
``dw = C_nb' eps``,

    dC/dt = [(dw - w_in') x] C + C [w_in x]   =>   q_{k+1} = exp((dw - w_in') dt / 2) q_k exp(w_in dt / 2)
    d(dv)/dt = (I - C^T) f' + C^T C_nb' nab - ((2 w_ie' + w_en') x v' - (2 w_ie + w_en) x v) + g' - g

where ``f' dt`` is the SINS's specific-force velocity increment in its own frame over the step
(from the mechanization), and the position error integrates the difference of the geodetic rates
of the SINS's and the true velocity.  The biases are constants; a small random walk
(``bias_walk_fraction`` of the turn-on sigma over the flight) keeps the transition density proper
for the particle filters' Metropolis-Hastings moves.  Process noise ``w`` ([Yan2016] eq. 3): gyro
and accelerometer white noise, ``Q`` from their densities (velocity noise integrated into position).

Measurements ([Yan2016] eq. 4-5): ``[psi_I - psi_S, L_I - L_S, lambda_I - lambda_S, h_I - h_B]`` -
the SINS's heading, latitude and longitude minus the SAR fix's, the SINS's height minus the
barometer's (latitude and longitude in metres, as the state); ``h(x) = [psi(C_nb') -
psi(C(q)^T C_nb'), dp_N, dp_E, dp_U]``.  Epochs without a SAR fix (the radar not imaging) have
the barometer row only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dpos_core.units import FloatArray

from .. import earth
from ..attitude import cross, dcm_to_quat, quat_conj, quat_mul, quat_normalize, quat_to_dcm, wrap_angle
from ..filters.linalg import chol
from ..frames import hpr_from_C_nb
from ..series import NavSeries
from . import _model_kernel as _mk

#: state layout
Q_ATT, DV, DP, EPS, NAB = slice(0, 4), slice(4, 7), slice(7, 10), slice(10, 13), slice(13, 16)
N_STATES = 16
#: state names, for reports
STATE_NAMES = ("q0", "q1", "q2", "q3", "dvE", "dvN", "dvU", "dpN", "dpE", "dpU", "epsx", "epsy", "epsz", "nabx", "naby", "nabz")
_NEU = [1, 0, 2]  # ENU <-> NEU component order (self-inverse)


@dataclass(frozen=True)
class SinsTrack:
    """The free SINS at the K filter epochs and over the K - 1 steps between them.

    t_s (K,); C_nb (K, 3, 3), vel_n_mps (K, 3), llh (K, 3) at the epochs; per step k -> k + 1:
    dt_s (K - 1,), C_nb_mid, vel_mid_n_mps, llh_mid at the step's middle sample, dv_sf_n_mps (K - 1, 3)
    the specific-force velocity increment ``int C_nb' f' dt`` in the SINS's local-level frame.
    """

    t_s: FloatArray
    C_nb: FloatArray
    vel_n_mps: FloatArray
    llh: FloatArray
    dt_s: FloatArray
    C_nb_mid: FloatArray
    vel_mid_n_mps: FloatArray
    llh_mid: FloatArray
    dv_sf_n_mps: FloatArray

    @classmethod
    def from_nav(cls, nav: NavSeries, t_epochs_s: FloatArray) -> SinsTrack:
        """The track of a mechanized navigation series (every IMU sample, N) at epochs that are
        among its stamps (to 1 us); ``dv_sf`` is the velocity change minus the trapezoidal
        integral of gravity and Coriolis ``g - (2 w_ie + w_en) x v`` over the samples."""
        t = np.asarray(t_epochs_s, dtype=float)
        idx = np.searchsorted(nav.t_s, t - 1e-6)
        if np.any(idx >= nav.t_s.size) or np.any(np.abs(nav.t_s[np.minimum(idx, nav.t_s.size - 1)] - t) > 1e-6):
            raise ValueError("SinsTrack.from_nav: every epoch must be a stamp of the navigation series")
        lat, h, v = nav.llh[:, 0], nav.llh[:, 2], nav.vel_n_mps
        w = 2.0 * earth.earth_rate_n(lat) + earth.transport_rate_n(lat, h, v)
        a = earth.gravity_n(lat, h) - cross(w, v)
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(nav.t_s)[:, None], axis=0)])
        i0, i1 = idx[:-1], idx[1:]
        mid = (i0 + i1) // 2
        C = nav.C_nb
        return cls(t, C[idx], v[idx], nav.llh[idx], np.diff(t), C[mid], v[mid], nav.llh[mid],
                   (v[i1] - v[i0]) - (cum[i1] - cum[i0]))


@dataclass(frozen=True)
class SarNoise:
    """The filter's noise model: white-noise densities gyro_psd [rad^2/s], accel_psd
    [m^2/s^3]; turn-on bias sigmas gyro_bias_radps, accel_bias_mps2; the bias random walk's
    size over the flight (``bias_walk_fraction`` of the turn-on sigma over ``duration_s``);
    ``pos_model_sigma_m`` per step on each position error: the discretization error of the
    one-step position propagation (measured along the truth of paper_sar at 1 Hz: 0.8 mm north,
    1.9 mm east rms, 30-70x the velocity noise integrated into position)."""

    gyro_psd: float
    accel_psd: float
    gyro_bias_radps: float
    accel_bias_mps2: float
    duration_s: float
    bias_walk_fraction: float = 0.1
    pos_model_sigma_m: float = 2e-3

    def __post_init__(self) -> None:
        for k in ("gyro_psd", "accel_psd", "gyro_bias_radps", "accel_bias_mps2", "duration_s", "bias_walk_fraction",
                  "pos_model_sigma_m"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"SarNoise.{k} must be > 0, got {v}")


@dataclass(frozen=True)
class SarMeasurements:
    """Per filter epoch (K,): ``y`` (K, 4) ``[psi_I - psi_S, dN, dE, h_I - h_B]`` [rad, m, m, m]
    (NaN in the first three where no SAR fix), ``sar`` (K,) bool, sigmas ``heading_sigma_rad``,
    ``pos_sigma_m`` (one value, or (K,) per epoch: the fixes' own) and ``baro_sigma_m`` (K,) (the
    barometer's of the epoch's averaged samples)."""

    y: FloatArray
    sar: np.ndarray
    heading_sigma_rad: float | FloatArray
    pos_sigma_m: float | FloatArray
    baro_sigma_m: FloatArray


def _dp_to_dllh(dp_neu: FloatArray, llh: FloatArray) -> FloatArray:
    return earth.enu_to_dllh(dp_neu[..., _NEU], llh)


def _dllh_to_dp(dllh: FloatArray, llh: FloatArray) -> FloatArray:
    return earth.dllh_to_enu(dllh, llh)[..., _NEU]


def _frame_rate(llh: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(w_ie, w_en) (..., 3) in local ENU."""
    return earth.earth_rate_n(llh[..., 0]), earth.transport_rate_n(llh[..., 0], llh[..., 2], v)


def _rows(x: FloatArray) -> tuple[FloatArray, tuple[int, ...]]:
    """States (..., 16) as contiguous float rows (M, 16), and their shape."""
    a = np.asarray(x, dtype=float)
    if a.shape[-1:] != (N_STATES,):
        raise ValueError(f"SarModel: expected states (..., {N_STATES}), got {a.shape}")
    return np.ascontiguousarray(a).reshape(-1, N_STATES), a.shape


#: the WGS-84 constants of :mod:`dpos_core.earth` the kernel's true-position side needs (its ``earth_c``)
_EARTH_C = np.array([earth.A_M, earth.E2, earth.OMEGA_IE_RADPS, earth.GAMMA_E_MPS2, earth.K_SOMIGLIANA, earth.F,
                     earth.M_GRAV])


def _step_table(track: SinsTrack) -> FloatArray:
    """The SINS's side of every step k -> k + 1 of :meth:`SarModel.f`, (K - 1, ``_mk.N_STEP``)
    (the columns ``_model_kernel.C_*``): dt, the middle sample's llh, velocity and C_nb, the
    specific-force increment, the radii at the epochs, the SINS's frame rate ``w_ie' + w_en'``,
    its Coriolis term ``(2 w_ie' + w_en') x v'``, gravity and llh rate at the middle - the
    per-particle kernel computes only the true-position side."""
    T = np.empty((track.dt_s.size, _mk.N_STEP))
    llh_i, v_i = track.llh_mid, track.vel_mid_n_mps
    wie_i, wen_i = _frame_rate(llh_i, v_i)
    r_m0, r_n0 = earth.radii_of_curvature(track.llh[:-1, 0])
    r_m1, r_n1 = earth.radii_of_curvature(track.llh[1:, 0])
    T[:, _mk.C_DT] = track.dt_s
    T[:, _mk.C_LLH_I:_mk.C_LLH_I + 3] = llh_i
    T[:, _mk.C_V_I:_mk.C_V_I + 3] = v_i
    T[:, _mk.C_CNB_I:_mk.C_CNB_I + 9] = track.C_nb_mid.reshape(-1, 9)
    T[:, _mk.C_DVSF:_mk.C_DVSF + 3] = track.dv_sf_n_mps
    T[:, _mk.C_DEN_N] = r_m0 + track.llh[:-1, 2]
    T[:, _mk.C_DEN_E] = (r_n0 + track.llh[:-1, 2]) * np.cos(track.llh[:-1, 0])
    T[:, _mk.C_W_IN_I:_mk.C_W_IN_I + 3] = wie_i + wen_i
    T[:, _mk.C_COR_I:_mk.C_COR_I + 3] = cross(2.0 * wie_i + wen_i, v_i)
    T[:, _mk.C_G_I] = earth.normal_gravity(llh_i[:, 0], llh_i[:, 2])
    T[:, _mk.C_RATE_I:_mk.C_RATE_I + 3] = earth.llh_rate(llh_i[:, 0], llh_i[:, 2], v_i)
    T[:, _mk.C_RMH1] = r_m1 + track.llh[1:, 2]
    T[:, _mk.C_RNH1] = r_n1 + track.llh[1:, 2]
    T[:, _mk.C_COS1] = np.cos(track.llh[1:, 0])
    T[:, _mk.C_SIN_I] = np.sin(llh_i[:, 0])
    T[:, _mk.C_COS_I] = np.cos(llh_i[:, 0])
    return T


def heading_of(C_nb: FloatArray) -> FloatArray:
    """Aviation heading [rad] of C_nb (..., 3, 3)."""
    return hpr_from_C_nb(C_nb)[..., 0]


class SarModel:
    """The 16-state SINS/SAR/baro error model (module docstring) as a
    :class:`~dpos_core.filters.model.StateSpaceModel` over the K epochs of ``track``; f and h are
    vectorized over leading axes (particles, sigma points).  ``free`` (the 15 components but
    ``q0``) and ``project`` (unit quaternion, ``q0 >= 0``) are for the particle filters.

    f, h, ``project``, ``residual`` and ``loglik`` run as compiled loops over the rows
    (:mod:`._model_kernel`, the formulas of the numpy form in its order of operations: equal to
    it to rounding, test/dpos_core/sar/test_model_kernel.py); the SINS's side of every step is
    tabulated once here (:func:`_step_table`)."""

    n = N_STATES
    free = np.arange(1, N_STATES)

    def __init__(self, track: SinsTrack, meas: SarMeasurements, noise: SarNoise) -> None:
        self.track, self.meas, self.noise = track, meas, noise
        self.n_epochs = int(track.t_s.size)
        if meas.y.shape != (self.n_epochs, 4):
            raise ValueError(f"SarModel: measurements {meas.y.shape} do not match {self.n_epochs} epochs")
        self._Q = [self._make_Q(float(dt)) for dt in track.dt_s]
        hs = np.broadcast_to(np.asarray(meas.heading_sigma_rad, dtype=float), (self.n_epochs,))
        ps = np.broadcast_to(np.asarray(meas.pos_sigma_m, dtype=float), (self.n_epochs,))
        self._R4 = [np.diag([h**2, p**2, p**2, float(b) ** 2]) for h, p, b in zip(hs, ps, meas.baro_sigma_m, strict=True)]
        self._psi = heading_of(track.C_nb)
        self._steps = _step_table(track)
        self._C_nb = np.ascontiguousarray(track.C_nb)
        # the Cholesky factors of R(k) (gauss_logpdf's), for loglik
        self._L = [chol(self.R(k)) for k in range(self.n_epochs)]

    def _make_Q(self, dt: float) -> FloatArray:
        nz = self.noise
        Q = np.zeros((N_STATES, N_STATES))
        qa = 0.25 * nz.gyro_psd * dt
        Q[1:4, 1:4] = qa * np.eye(3)
        Q[0, 0] = 1e-6 * qa  # q0 follows from the unit norm: a token variance keeps Q positive definite
        Sa = nz.accel_psd
        for i_v, i_p in zip(range(4, 7), (8, 7, 9), strict=True):  # E, N, U velocity -> N, E, U position
            Q[i_v, i_v] = Sa * dt
            Q[i_p, i_p] = Sa * dt**3 / 3.0 + nz.pos_model_sigma_m**2
            Q[i_v, i_p] = Q[i_p, i_v] = Sa * dt**2 / 2.0
        f = nz.bias_walk_fraction**2 * dt / nz.duration_s
        Q[EPS, EPS] = f * nz.gyro_bias_radps**2 * np.eye(3)
        Q[NAB, NAB] = f * nz.accel_bias_mps2**2 * np.eye(3)
        return Q

    # ------------------------------------------------------------------ transition
    def f(self, k: int, x: FloatArray) -> FloatArray:
        """One step k -> k + 1 of the error equations (module docstring), x (..., 16): the
        compiled kernel :func:`~._model_kernel.rows_f` over the rows, with the step's SINS
        quantities computed once per model (:func:`_step_table`)."""
        rows, shape = _rows(x)
        out = np.empty(rows.shape)
        _mk.rows_f(rows, self._steps[k], _EARTH_C, out)
        return out.reshape(shape)

    def Q(self, k: int) -> FloatArray:
        return self._Q[k]

    def project(self, x: FloatArray) -> FloatArray:
        """The states with a unit attitude quaternion (scalar part >= 0), x (..., 16)."""
        rows, shape = _rows(x)
        out = np.empty(rows.shape)
        _mk.rows_project(rows, out)
        return out.reshape(shape)

    # ------------------------------------------------------------------ measurements
    def y(self, k: int) -> FloatArray | None:
        row = self.meas.y[k]
        return row if self.meas.sar[k] else row[3:4]

    def h(self, k: int, x: FloatArray) -> FloatArray:
        """``[psi_I - psi_true(q), dp_N, dp_E, dp_U]`` (..., 4), or ``[dp_U]`` without a SAR fix."""
        if not self.meas.sar[k]:
            return x[..., 9:10]
        rows, shape = _rows(x)
        out = np.empty((rows.shape[0], 4))
        _mk.rows_heading_residual(rows, self._C_nb[k], float(self._psi[k]), out)
        return out.reshape(shape[:-1] + (4,))

    def loglik(self, k: int, x: FloatArray) -> FloatArray:
        """``log p(y_k | x)`` (M,) of states x (M, 16): ``gauss_logpdf(residual(y(k), h(k, x)), R(k))``
        in one compiled pass (:func:`~._model_kernel.rows_loglik`; the particle filters' weights)."""
        rows, shape = _rows(x)
        if len(shape) != 2:
            raise ValueError(f"SarModel.loglik: expected states (M, {N_STATES}), got {shape}")
        out = np.empty(rows.shape[0])
        y = np.ascontiguousarray(self.y(k), dtype=float)
        _mk.rows_loglik(rows, self._C_nb[k], float(self._psi[k]), y, self._L[k], out)
        return out

    def R(self, k: int) -> FloatArray:
        return self._R4[k] if self.meas.sar[k] else self._R4[k][3:4, 3:4]

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        d = np.asarray(a - b, dtype=float)
        if d.shape[-1] == 4:  # the heading row wrapped (attitude.wrap_angle), in place in the new array
            rows = np.ascontiguousarray(d).reshape(-1, 4)
            _mk.rows_wrap_heading(rows)
            d = rows.reshape(d.shape)
        return d

    def feedback(self, k: int, mean: FloatArray) -> FloatArray | None:
        return None

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        return x


# ---------------------------------------------------------------------------- truth and corrections


def error_state(track: SinsTrack, truth: NavSeries, gyro_bias_radps: FloatArray, accel_bias_mps2: FloatArray) -> FloatArray:
    """The true error state (K, 16) of the SINS at the track's epochs against the truth (at the
    same epochs) and the IMU's true biases (3,) each."""
    x = np.empty((track.t_s.size, N_STATES))
    x[:, Q_ATT] = quat_normalize(quat_mul(track_quat(track), quat_conj(truth.q_nb)))
    x[:, DV] = track.vel_n_mps - truth.vel_n_mps
    x[:, DP] = _dllh_to_dp(track.llh - truth.llh, truth.llh)
    x[:, EPS] = gyro_bias_radps
    x[:, NAB] = accel_bias_mps2
    return x


def track_quat(track: SinsTrack) -> FloatArray:
    """The SINS's attitude quaternions q_nb (K, 4)."""
    return dcm_to_quat(track.C_nb)


def corrected(track: SinsTrack, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The SINS corrected by estimated errors x (K, 16): ``C_nb`` (K, 3, 3), ``vel_n_mps`` (K, 3),
    ``llh`` (K, 3)."""
    C = np.swapaxes(quat_to_dcm(quat_normalize(x[:, Q_ATT])), -1, -2) @ track.C_nb
    return C, track.vel_n_mps - x[:, DV], track.llh - _dp_to_dllh(x[:, DP], track.llh)


def navigation_errors(track: SinsTrack, x: FloatArray, truth: NavSeries) -> tuple[FloatArray, FloatArray]:
    """Errors of the corrected SINS against the truth at the epochs: attitude ``[pitch, roll,
    yaw]`` (K, 3) [rad] (heading wrapped) and position ``[longitude (east), latitude (north),
    altitude]`` (K, 3) [m] - [Yan2016] Figures 2-3's components."""
    C, _, llh = corrected(track, x)
    hpr_e = hpr_from_C_nb(C) - truth.hpr_rad
    att = np.stack([hpr_e[:, 1], wrap_angle(hpr_e[:, 2]), wrap_angle(hpr_e[:, 0])], axis=1)
    pos = earth.dllh_to_enu(llh - truth.llh, truth.llh)
    return att, pos
