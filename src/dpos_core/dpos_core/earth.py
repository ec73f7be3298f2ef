"""WGS-84 Earth model: geodetic <-> ECEF <-> local ENU, radii of curvature, normal gravity,
Earth rate and transport rate in the local-level (ENU) navigation frame.

Conventions
-----------
* Geodetic coordinates are ``(lat_rad, lon_rad, h_m)`` on the WGS-84 ellipsoid.
* ``n`` is the local-level East-North-Up frame at the current position; ``enu`` (the ROS world
  frame of design.md) is the Cartesian ENU frame tangent to the ellipsoid at a fixed *datum*.
* All functions accept scalars or arrays and broadcast over leading axes; vectors are in the
  last axis (shape ``(..., 3)``).

Formulas: NIMA TR8350.2 (WGS-84 constants, Somigliana normal gravity and its second-order height
expansion, eq. 4-1 and 4-3), Groves, *Principles of GNSS, Inertial, and Multisensor Integrated
Navigation Systems*, 2nd ed. (radii eq. 2.105-2.106, transport rate eq. 5.44), and Bowring's
iteration for ECEF -> geodetic (Bowring 1976), iterated to machine precision.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from . import _earth_kernel

# WGS-84 defining and derived constants (NIMA TR8350.2, 3rd ed.)
A_M: float = 6378137.0  #: semi-major axis [m]
F: float = 1.0 / 298.257223563  #: flattening
B_M: float = A_M * (1.0 - F)  #: semi-minor axis [m]
E2: float = F * (2.0 - F)  #: first eccentricity squared
EP2: float = E2 / (1.0 - E2)  #: second eccentricity squared
OMEGA_IE_RADPS: float = 7.292115e-5  #: Earth rotation rate [rad/s]
GM_M3PS2: float = 3.986004418e14  #: geocentric gravitational constant [m^3/s^2]
GAMMA_E_MPS2: float = 9.7803253359  #: normal gravity at the equator [m/s^2]
GAMMA_P_MPS2: float = 9.8321849378  #: normal gravity at the poles [m/s^2]
K_SOMIGLIANA: float = (B_M * GAMMA_P_MPS2) / (A_M * GAMMA_E_MPS2) - 1.0
M_GRAV: float = OMEGA_IE_RADPS**2 * A_M**2 * B_M / GM_M3PS2



def radii_of_curvature(lat_rad: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Meridian ``R_M`` and transverse (prime-vertical) ``R_N`` radii of curvature [m].

    Groves eq. 2.105-2.106: ``R_M = a (1-e^2) / (1 - e^2 sin^2 L)^(3/2)``,
    ``R_N = a / sqrt(1 - e^2 sin^2 L)``.
    """
    s = np.sin(np.asarray(lat_rad, dtype=float))
    w = 1.0 - E2 * s * s
    r_n = A_M / np.sqrt(w)
    r_m = r_n * (1.0 - E2) / w
    return r_m, r_n


def geodetic_to_ecef(lat_rad: ArrayLike, lon_rad: ArrayLike, h_m: ArrayLike) -> FloatArray:
    """Geodetic -> ECEF position, shape ``(..., 3)`` [m]."""
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    h = np.asarray(h_m, dtype=float)
    _, r_n = radii_of_curvature(lat)
    cl = np.cos(lat)
    x = (r_n + h) * cl * np.cos(lon)
    y = (r_n + h) * cl * np.sin(lon)
    z = (r_n * (1.0 - E2) + h) * np.sin(lat)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(p_e_m: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF position ``(..., 3)`` -> ``(lat_rad, lon_rad, h_m)``.

    Bowring's parametric-latitude iteration; four passes reach machine precision for any
    point outside a few km of the Earth's centre (the error shrinks by ~e^4 per pass).  The
    height uses the form that stays well conditioned at the poles.
    """
    p_e = np.asarray(p_e_m, dtype=float)
    x, y, z = p_e[..., 0], p_e[..., 1], p_e[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z, (1.0 - F) * p)
    lat = beta
    for _ in range(4):
        sb, cb = np.sin(beta), np.cos(beta)
        lat = np.arctan2(z + EP2 * B_M * sb**3, p - E2 * A_M * cb**3)
        beta = np.arctan2((1.0 - F) * np.sin(lat), np.cos(lat))
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - A_M * np.sqrt(1.0 - E2 * sl * sl)
    return lat, lon, h


def C_en(lat_rad: ArrayLike, lon_rad: ArrayLike) -> FloatArray:
    """DCM from the local ENU frame at (lat, lon) to ECEF, shape ``(..., 3, 3)``.

    Columns are the East, North and Up unit vectors expressed in ECEF.
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    east = np.stack(np.broadcast_arrays(-so, co, zero), axis=-1)
    north = np.stack(np.broadcast_arrays(-sl * co, -sl * so, cl), axis=-1)
    up = np.stack(np.broadcast_arrays(cl * co, cl * so, sl), axis=-1)
    return np.stack([east, north, up], axis=-1)


def ecef_to_enu(p_e_m: ArrayLike, datum_llh: ArrayLike) -> FloatArray:
    """ECEF position ``(..., 3)`` -> Cartesian ENU ``(..., 3)`` at the datum ``(lat_rad, lon_rad, h_m)``."""
    lat0, lon0, h0 = (float(v) for v in np.asarray(datum_llh, dtype=float))
    p0 = geodetic_to_ecef(lat0, lon0, h0)
    return (np.asarray(p_e_m, dtype=float) - p0) @ C_en(lat0, lon0)


def enu_to_ecef(p_enu_m: ArrayLike, datum_llh: ArrayLike) -> FloatArray:
    """Cartesian ENU ``(..., 3)`` at the datum -> ECEF ``(..., 3)``."""
    lat0, lon0, h0 = (float(v) for v in np.asarray(datum_llh, dtype=float))
    p0 = geodetic_to_ecef(lat0, lon0, h0)
    return p0 + np.asarray(p_enu_m, dtype=float) @ C_en(lat0, lon0).T


def geodetic_to_enu(lat_rad: ArrayLike, lon_rad: ArrayLike, h_m: ArrayLike, datum_llh: ArrayLike) -> FloatArray:
    """Geodetic -> Cartesian ENU at the datum, shape ``(..., 3)`` [m]."""
    return ecef_to_enu(geodetic_to_ecef(lat_rad, lon_rad, h_m), datum_llh)


def enu_to_geodetic(p_enu_m: ArrayLike, datum_llh: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Cartesian ENU at the datum -> ``(lat_rad, lon_rad, h_m)``."""
    return ecef_to_geodetic(enu_to_ecef(p_enu_m, datum_llh))


def normal_gravity(lat_rad: ArrayLike, h_m: ArrayLike) -> FloatArray:
    """Magnitude of WGS-84 normal gravity (gravitation + centrifugal) at height ``h_m`` [m/s^2].

    Somigliana's closed formula on the ellipsoid with the second-order height expansion of
    NIMA TR8350.2 eq. 4-3.  The small north component of the normal-gravity vector above the
    ellipsoid (< 1e-5 m/s^2 at 1 km) is neglected consistently by the simulator and the
    mechanization: both use ``g_n = [0, 0, -normal_gravity]``.
    """
    lat = np.asarray(lat_rad, dtype=float)
    h = np.asarray(h_m, dtype=float)
    s2 = np.sin(lat) ** 2
    g0 = GAMMA_E_MPS2 * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_GRAV - 2.0 * F * s2) * h + 3.0 / A_M**2 * h * h)


def gravity_n(lat_rad: ArrayLike, h_m: ArrayLike) -> FloatArray:
    """Normal-gravity vector in the local ENU frame, shape ``(..., 3)`` [m/s^2]."""
    g = normal_gravity(lat_rad, h_m)
    z = np.zeros_like(g)
    return np.stack([z, z, -g], axis=-1)


def earth_rate_n(lat_rad: ArrayLike) -> FloatArray:
    """Earth rotation rate ``omega_ie^n`` in the local ENU frame, shape ``(..., 3)`` [rad/s]."""
    lat = np.asarray(lat_rad, dtype=float)
    if lat.ndim == 0:  # one place (a filter interval's): the same values without the stack
        return np.array([0.0, OMEGA_IE_RADPS * np.cos(lat), OMEGA_IE_RADPS * np.sin(lat)])
    z = np.zeros_like(lat)
    return np.stack([z, OMEGA_IE_RADPS * np.cos(lat), OMEGA_IE_RADPS * np.sin(lat)], axis=-1)


def transport_rate_n(lat_rad: ArrayLike, h_m: ArrayLike, vel_n_mps: ArrayLike) -> FloatArray:
    """Transport rate ``omega_en^n`` of the ENU frame over the ellipsoid, shape ``(..., 3)`` [rad/s].

    ``[-v_N / (R_M + h), v_E / (R_N + h), v_E tan(L) / (R_N + h)]`` (Groves eq. 5.44 in ENU).
    """
    lat = np.asarray(lat_rad, dtype=float)
    h = np.asarray(h_m, dtype=float)
    v = np.asarray(vel_n_mps, dtype=float)
    r_m, r_n = radii_of_curvature(lat)
    ve, vn = v[..., 0], v[..., 1]
    if lat.ndim == 0 and h.ndim == 0 and v.ndim == 1:  # one place: the same values without the stack
        return np.array([-vn / (r_m + h), ve / (r_n + h), ve * np.tan(lat) / (r_n + h)])
    return np.stack([-vn / (r_m + h), ve / (r_n + h), ve * np.tan(lat) / (r_n + h)], axis=-1)


def _enu_to_dllh(d_enu: FloatArray, lat: FloatArray, h: FloatArray) -> FloatArray:
    """``[d_N / (R_M + h), d_E / ((R_N + h) cos L), d_U]`` (the body of :func:`enu_to_dllh`)."""
    r_m, r_n = radii_of_curvature(lat)
    if d_enu.ndim == 1 and np.ndim(lat) == 0 and np.ndim(h) == 0:  # one displacement: the same values without the stack
        return np.array([d_enu[1] / (r_m + h), d_enu[0] / ((r_n + h) * np.cos(lat)), d_enu[2]])
    return np.stack([d_enu[..., 1] / (r_m + h), d_enu[..., 0] / ((r_n + h) * np.cos(lat)), d_enu[..., 2]], axis=-1)


def enu_to_dllh(d_enu_m: ArrayLike, llh: ArrayLike) -> FloatArray:
    """Small local-ENU displacement -> geodetic difference, to first order.

    Args:
        d_enu_m: displacement (..., 3) [m] East, North, Up in the local-level frame at ``llh``.
        llh: position (..., 3) ``[lat_rad, lon_rad, h_m]`` where the radii are taken.

    Returns:
        ``(dlat_rad, dlon_rad, dh_m)`` (..., 3): ``[d_N / (R_M + h), d_E / ((R_N + h) cos L), d_U]``
        with the radii of :func:`radii_of_curvature` (Groves 2013 eq. 2.105-2.106).  The
        neglected terms are of order ``|d| / R`` relative (1.6e-7 for 1 m, 1.6e-5 for 100 m); for
        a large offset (a lever arm of metres) that must be exact use :func:`offset_llh`.
    """
    p = np.asarray(llh, dtype=float)
    return _enu_to_dllh(np.asarray(d_enu_m, dtype=float), p[..., 0], p[..., 2])


def dllh_to_enu(dllh: ArrayLike, llh: ArrayLike) -> FloatArray:
    """Inverse of :func:`enu_to_dllh`: geodetic difference ``(dlat_rad, dlon_rad, dh_m)`` (..., 3)
    -> local-ENU displacement (..., 3) [m] ``[dlon (R_N + h) cos L, dlat (R_M + h), dh]``, radii at
    ``llh`` (..., 3).  E.g. a position error ``est - true`` in metres with ``llh`` the truth."""
    d = np.asarray(dllh, dtype=float)
    p = np.asarray(llh, dtype=float)
    lat, h = p[..., 0], p[..., 2]
    r_m, r_n = radii_of_curvature(lat)
    return np.stack([d[..., 1] * (r_n + h) * np.cos(lat), d[..., 0] * (r_m + h), d[..., 2]], axis=-1)


def offset_llh(llh: ArrayLike, d_n_m: ArrayLike) -> FloatArray:
    """Position ``llh`` (..., 3) ``[lat_rad, lon_rad, h_m]`` moved by ``d_n_m`` (..., 3) [m] given
    in the local ENU frame at ``llh``, exactly (through ECEF): ``llh`` (..., 3) of
    ``p_e(llh) + C_en(llh) d_n``, each point with its own local frame (for one fixed origin this is
    :func:`enu_to_geodetic`).  For lever arms; small errors use :func:`enu_to_dllh`."""
    p = np.asarray(llh, dtype=float)
    d = np.asarray(d_n_m, dtype=float)
    shape = np.broadcast_shapes(p.shape, d.shape)
    if shape[-1:] != (3,):
        raise ValueError(f"offset_llh: expected (..., 3) arrays, got {p.shape} and {d.shape}")
    rows = np.ascontiguousarray(np.broadcast_to(p, shape)).reshape(-1, 3)
    out = np.empty_like(rows)
    _earth_kernel.rows_offset_llh(rows, np.ascontiguousarray(np.broadcast_to(d, shape)).reshape(-1, 3), out)
    return out.reshape(shape)


def enu_between(llh: ArrayLike, llh_ref: ArrayLike) -> FloatArray:
    """The vector (3,) [m] from ``llh_ref`` to ``llh`` (each (3,) ``[lat_rad, lon_rad, h_m]``) in
    the local ENU frame at ``llh``, exactly: ``C_en(llh)^T (p_e(llh) - p_e(llh_ref))``, so that
    ``offset_llh(llh, -enu_between(llh, llh_ref))`` is ``llh_ref``."""
    lat, lon, h = (float(v) for v in np.asarray(llh, dtype=float).reshape(3))
    lat_r, lon_r, h_r = (float(v) for v in np.asarray(llh_ref, dtype=float).reshape(3))
    # scalar arithmetic (called once per filter epoch: array calls would cost more than the formulas)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    slr, clr = math.sin(lat_r), math.cos(lat_r)
    r_n = A_M / math.sqrt(1.0 - E2 * sl * sl)
    r_nr = A_M / math.sqrt(1.0 - E2 * slr * slr)
    dx = (r_n + h) * cl * co - (r_nr + h_r) * clr * math.cos(lon_r)
    dy = (r_n + h) * cl * so - (r_nr + h_r) * clr * math.sin(lon_r)
    dz = (r_n * (1.0 - E2) + h) * sl - (r_nr * (1.0 - E2) + h_r) * slr
    return np.array([-so * dx + co * dy, -sl * co * dx - sl * so * dy + cl * dz, cl * co * dx + cl * so * dy + sl * dz])


def llh_rate(lat_rad: ArrayLike, h_m: ArrayLike, vel_n_mps: ArrayLike) -> FloatArray:
    """Time derivative of ``(lat, lon, h)`` for an ENU velocity, shape ``(..., 3)`` [rad/s, rad/s, m/s]
    (:func:`enu_to_dllh` of the velocity)."""
    return _enu_to_dllh(np.asarray(vel_n_mps, dtype=float), np.asarray(lat_rad, dtype=float), np.asarray(h_m, dtype=float))


def C_datum_n(lat_rad: ArrayLike, lon_rad: ArrayLike, datum_llh: ArrayLike) -> FloatArray:
    """Rotation from the local ENU frame at (lat, lon) to the datum's Cartesian ENU frame ``enu``,
    shape ``(..., 3, 3)``: ``C_en(datum)^T C_en(lat, lon)``."""
    lat0, lon0 = (float(v) for v in np.asarray(datum_llh, dtype=float)[:2])
    return C_en(lat0, lon0).T @ C_en(lat_rad, lon_rad)


def nav_to_datum(
    llh: ArrayLike, vel_n_mps: ArrayLike, C_nb: ArrayLike, datum_llh: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Local-level navigation -> the ROS world frame ``enu`` at the datum.

    Args:
        llh (N, 3), vel_n_mps (N, 3) local ENU, C_nb (N, 3, 3) body -> local ENU.

    Returns:
        ``(p_enu_m (N, 3), vel_enu_mps (N, 3), C_enu_b (N, 3, 3))``.
    """
    llh = np.asarray(llh, dtype=float)
    R = C_datum_n(llh[..., 0], llh[..., 1], datum_llh)
    p = geodetic_to_enu(llh[..., 0], llh[..., 1], llh[..., 2], datum_llh)
    return p, np.einsum("...ij,...j->...i", R, np.asarray(vel_n_mps, dtype=float)), R @ np.asarray(C_nb, dtype=float)


def datum_to_nav(
    p_enu_m: ArrayLike, vel_enu_mps: ArrayLike, C_enu_b: ArrayLike, datum_llh: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of :func:`nav_to_datum`: ``(llh (N, 3), vel_n_mps (N, 3), C_nb (N, 3, 3))``."""
    lat, lon, h = enu_to_geodetic(p_enu_m, datum_llh)
    R_T = np.swapaxes(C_datum_n(lat, lon, datum_llh), -1, -2)
    return (
        np.stack([lat, lon, h], axis=-1),
        np.einsum("...ij,...j->...i", R_T, np.asarray(vel_enu_mps, dtype=float)),
        R_T @ np.asarray(C_enu_b, dtype=float),
    )
