"""Time series of the navigation core: IMU samples, navigation solutions, GNSS fixes, SAR fixes and
barometric heights, and the navigation state at one epoch (:class:`NavState`, also exported by
:mod:`dpos_core.strapdown`).

One type per kind of data, used by the simulator (:mod:`dpos_core.sim.session`), the strapdown
(:mod:`dpos_core.strapdown`), the alignments (:mod:`dpos_core.ifa`, :mod:`dpos_core.ta`), the
metrics and the ROS readers and writers (dpos_ros).

Conventions (design.md "Frames, units, time"): times ``t_s`` in seconds of session time (any origin), strictly
increasing; ``llh = [lat_rad, lon_rad, h_m]`` on WGS-84; velocities and covariances of position
and velocity in the local-level ENU frame ``n`` at each sample; attitude ``q_nb`` (scalar first)
/ ``C_nb`` from the body (FLU for this product's IMUs) to ``n``; the attitude covariance is that
of the error ``phi`` as a rotation about the local ENU axes (``C_nb_est = expm(-[phi x]) C_nb``,
as in the error-state models).  The series are frozen; their arrays are not modified in place
(``NavSeries.C_nb`` is cached).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dpos_core.errors import RejectedInput
from dpos_core.units import FloatArray

from .attitude import dcm_to_quat, quat_normalize, quat_to_dcm
from .frames import C_nb_from_hpr, hpr_from_C_nb

#: which samples to take: a boolean mask (N,), an index array or a slice
Selection = NDArray[Any] | slice


#: a stamp step longer than this many nominal intervals is a gap (warned about, integrated across):
#: real stamps jitter (a 100 Hz sensor read by a ~150 Hz logger gives 6 and 9 ms steps: 1.5x), one
#: lost sample at a steady rate makes 2x
GAP_FACTOR = 1.75



@dataclass
class NavState:
    """Navigation state at time ``t_s``.

    Attributes:
        t_s: time [s] (session time; any origin).
        q_nb: attitude quaternion body -> local ENU, shape (4,), scalar first.
        vel_n_mps: velocity over the Earth in local ENU, shape (3,).
        llh: ``[lat_rad, lon_rad, h_m]``, shape (3,).
    """

    t_s: float
    q_nb: FloatArray
    vel_n_mps: FloatArray
    llh: FloatArray

    def __post_init__(self) -> None:
        self.t_s = float(self.t_s)
        self.q_nb = quat_normalize(np.asarray(self.q_nb, dtype=float).reshape(4))
        self.vel_n_mps = np.asarray(self.vel_n_mps, dtype=float).reshape(3).copy()
        self.llh = np.asarray(self.llh, dtype=float).reshape(3).copy()
        for name in ("q_nb", "vel_n_mps", "llh"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise RejectedInput(f"NavState.{name} is not finite: {getattr(self, name)}", what="navigation state", reason="nan",
                                    t_s=self.t_s)

    @classmethod
    def from_hpr(
        cls, t_s: float, hpr_rad: ArrayLike, vel_n_mps: ArrayLike, llh: ArrayLike
    ) -> NavState:
        """Build from aviation heading/pitch/roll [rad] of an FLU body."""
        h, p, r = np.asarray(hpr_rad, dtype=float)
        vel = np.asarray(vel_n_mps, dtype=float)
        llh_arr = np.asarray(llh, dtype=float)
        return cls(t_s, dcm_to_quat(C_nb_from_hpr(h, p, r)), vel, llh_arr)

    @property
    def C_nb(self) -> FloatArray:
        """DCM body -> local ENU, shape (3, 3)."""
        return quat_to_dcm(self.q_nb)

    @property
    def hpr_rad(self) -> FloatArray:
        """Aviation heading, pitch, roll [rad], shape (3,)."""
        return hpr_from_C_nb(self.C_nb)

    def copy(self) -> NavState:
        return NavState(self.t_s, self.q_nb.copy(), self.vel_n_mps.copy(), self.llh.copy())

    @classmethod
    def _from_state_vector(cls, t_s: float, x: FloatArray) -> NavState:
        """The state of an integrator's vector ``x`` (>= 10,) ``[q_nb (4), vel_n_mps (3), llh (3)]``
        (fresh arrays): what the constructor makes of it (the quaternion normalized with a
        non-negative scalar part, the values checked finite), without its general conversions."""
        v = x[:10]
        if not np.isfinite(v).all():
            return cls(t_s, v[0:4], v[4:7], v[7:10])  # the constructor names what is not finite
        q = v[0:4]
        q = q / math.sqrt(float(q @ q))
        if q[0] < 0.0:
            q = -q
        st = cls.__new__(cls)
        st.t_s, st.q_nb, st.vel_n_mps, st.llh = float(t_s), q, v[4:7].copy(), v[7:10].copy()
        return st


@dataclass(frozen=True)
class ImuSeries:
    """IMU samples, each the mean over ``(t_{k-1}, t_k]`` (increment / T, as a high-grade IMU
    outputs), in the IMU's axes.

    Attributes:
        t_s: sample stamps (N,) [s], the end of each interval.
        omega_radps: angular rate w.r.t. inertial space (N, 3) [rad/s].
        f_mps2: specific force (N, 3) [m/s^2].
    """

    t_s: FloatArray
    omega_radps: FloatArray
    f_mps2: FloatArray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def select(self, keep: Selection) -> ImuSeries:
        """The samples selected by ``keep`` (a boolean mask (N,), an index array or a slice)."""
        return ImuSeries(self.t_s[keep], self.omega_radps[keep], self.f_mps2[keep])


@dataclass(frozen=True)
class NavSeries:
    """Navigation at N epochs, optionally with its body rate and uncertainty.

    Attributes:
        t_s: epochs (N,) [s].
        q_nb: attitude quaternions body -> local ENU (N, 4), scalar first.
        vel_n_mps: velocity over the Earth (N, 3) [m/s], local ENU.
        llh: position (N, 3) ``[lat_rad, lon_rad, h_m]``.
        omega_eb_b_radps: body rate w.r.t. the Earth (N, 3) [rad/s] in body axes, when known
            (lever-arm velocities, [Gong2018] eq. 18).
        att_cov: covariance (N, 3, 3) [rad^2] of the attitude error as a rotation about the
            local ENU axes, when known.
        vel_cov: velocity covariance (N, 3, 3) [m^2/s^2], local ENU, when known.
        pos_cov: position covariance (N, 3, 3) [m^2], local ENU metres, when known.
    """

    t_s: FloatArray
    q_nb: FloatArray
    vel_n_mps: FloatArray
    llh: FloatArray
    omega_eb_b_radps: FloatArray | None = None
    att_cov: FloatArray | None = None
    vel_cov: FloatArray | None = None
    pos_cov: FloatArray | None = None

    @classmethod
    def from_C_nb(cls, t_s: FloatArray, C_nb: FloatArray, vel_n_mps: FloatArray, llh: FloatArray, *,
                  omega_eb_b_radps: FloatArray | None = None, att_cov: FloatArray | None = None, vel_cov: FloatArray | None = None,
                  pos_cov: FloatArray | None = None) -> NavSeries:
        """The series of attitude DCMs ``C_nb`` (N, 3, 3) (body -> local ENU); ``C_nb`` is then
        exactly the given matrices, ``q_nb`` their quaternions."""
        out = cls(t_s, dcm_to_quat(C_nb), vel_n_mps, llh, omega_eb_b_radps=omega_eb_b_radps, att_cov=att_cov, vel_cov=vel_cov,
                  pos_cov=pos_cov)
        out.__dict__["C_nb"] = np.asarray(C_nb, dtype=float)  # the cached_property's slot
        return out

    def required(self, *names: str) -> tuple[FloatArray, ...]:
        """The optional fields ``names`` (e.g. ``"att_cov", "vel_cov"``), in that order; ValueError
        naming those the series lacks."""
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            raise ValueError(f"the navigation series lacks {', '.join(missing)}")
        return tuple(getattr(self, n) for n in names)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @cached_property
    def C_nb(self) -> FloatArray:
        """Attitude DCMs body -> local ENU (N, 3, 3) (computed once)."""
        return quat_to_dcm(self.q_nb)

    @property
    def hpr_rad(self) -> FloatArray:
        """Aviation heading, pitch, roll (N, 3) [rad]."""
        return hpr_from_C_nb(self.C_nb)

    def select(self, keep: Selection) -> NavSeries:
        """The epochs selected by ``keep`` (a boolean mask (N,), an index array or a slice), with
        every optional field that is present."""
        def take(v: FloatArray | None) -> FloatArray | None:
            return None if v is None else v[keep]

        return NavSeries(self.t_s[keep], self.q_nb[keep], self.vel_n_mps[keep], self.llh[keep],
                         omega_eb_b_radps=take(self.omega_eb_b_radps), att_cov=take(self.att_cov), vel_cov=take(self.vel_cov),
                         pos_cov=take(self.pos_cov))

    def state(self, i: int) -> NavState:
        """Epoch ``i`` as a :class:`NavState`."""
        return NavState(self.t_s[i], self.q_nb[i], self.vel_n_mps[i], self.llh[i])

    @staticmethod
    def concatenate(parts: list[NavSeries]) -> NavSeries:
        """The parts one after the other; an optional field is kept only if every part has it."""
        def cat(name: str) -> FloatArray | None:
            vals = [getattr(p, name) for p in parts]
            return None if any(v is None for v in vals) else np.concatenate(vals)

        return NavSeries(np.concatenate([p.t_s for p in parts]), np.concatenate([p.q_nb for p in parts]),
                         np.concatenate([p.vel_n_mps for p in parts]), np.concatenate([p.llh for p in parts]),
                         omega_eb_b_radps=cat("omega_eb_b_radps"), att_cov=cat("att_cov"), vel_cov=cat("vel_cov"), pos_cov=cat("pos_cov"))


@dataclass(frozen=True)
class GnssSeries:
    """GNSS fixes at the antenna.

    Attributes:
        t_s: fix stamps (N,) [s].
        llh: antenna position (N, 3) ``[lat_rad, lon_rad, h_m]``.
        pos_sigma_m: 1 sigma of the position (N, 3) [m], East, North, Up.
        vel_n_mps: antenna velocity (N, 3) [m/s], local ENU.
        vel_sigma_mps: 1 sigma of the velocity (N, 3) [m/s], East, North, Up.
    """

    t_s: FloatArray
    llh: FloatArray
    pos_sigma_m: FloatArray
    vel_n_mps: FloatArray
    vel_sigma_mps: FloatArray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class SarFixes:
    """SAR fixes: t_s (M,), llh (M, 3) (latitude and longitude of the matched position; the height
    is not measured: it only scales their differences into metres, any height near the flight's
    will do), heading_rad (M,), and their 1 sigmas: pos_sigma_m (north and east, one value or (M,)),
    heading_sigma_rad (one value or (M,))."""

    t_s: FloatArray
    llh: FloatArray
    heading_rad: FloatArray
    pos_sigma_m: float | FloatArray
    heading_sigma_rad: float | FloatArray


@dataclass(frozen=True)
class BaroSeries:
    """Barometric heights h_m (M,) at t_s (M,), 1 sigma sigma_m (one value or (M,))."""

    t_s: FloatArray
    h_m: FloatArray
    sigma_m: float | FloatArray
