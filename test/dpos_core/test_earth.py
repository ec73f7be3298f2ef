"""WGS-84 geometry, gravity and frame rates."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import dcm_to_rotvec


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


def test_geodetic_ecef_round_trip(rng: np.random.Generator) -> None:
    n = 20000
    lat = rng.uniform(-np.pi / 2, np.pi / 2, n)
    lat[:4] = [np.pi / 2, -np.pi / 2, 0.0, 1e-12]  # poles and equator
    lon = rng.uniform(-np.pi, np.pi, n)
    h = rng.uniform(-1000.0, 100e3, n)
    p = earth.geodetic_to_ecef(lat, lon, h)
    lat2, lon2, h2 = earth.ecef_to_geodetic(p)
    p2 = earth.geodetic_to_ecef(lat2, lon2, h2)
    assert np.max(np.linalg.norm(p2 - p, axis=-1) / np.linalg.norm(p, axis=-1)) < 1e-9
    assert np.max(np.abs(lat2 - lat)) < 1e-12
    assert np.max(np.abs(h2 - h)) < 1e-6
    off_pole = np.abs(lat) < np.deg2rad(89.9)
    assert np.max(np.abs(np.angle(np.exp(1j * (lon2 - lon)))[off_pole])) < 1e-12


def test_ecef_known_points() -> None:
    np.testing.assert_allclose(earth.geodetic_to_ecef(0.0, 0.0, 0.0), [earth.A_M, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(earth.geodetic_to_ecef(np.pi / 2, 0.0, 0.0), [0.0, 0.0, earth.B_M], atol=1e-9)
    lat, lon, h = earth.ecef_to_geodetic(np.array([0.0, 0.0, earth.B_M + 100.0]))
    assert lat == pytest.approx(np.pi / 2) and h == pytest.approx(100.0, abs=1e-8)


def test_enu_round_trip_and_orientation(rng: np.random.Generator) -> None:
    datum = np.array([np.deg2rad(40.0), np.deg2rad(116.0), 500.0])
    p_enu = rng.uniform(-200e3, 200e3, (1000, 3))
    lat, lon, h = earth.enu_to_geodetic(p_enu, datum)
    back = earth.geodetic_to_enu(lat, lon, h, datum)
    assert np.max(np.abs(back - p_enu)) < 1e-9 * 200e3
    np.testing.assert_allclose(earth.geodetic_to_enu(*datum, datum), 0.0, atol=1e-8)
    # 1 km north along the meridian: +y, slightly below the tangent plane (Earth curvature)
    r_m, _ = earth.radii_of_curvature(datum[0])
    north = earth.geodetic_to_enu(datum[0] + 1000.0 / (r_m + datum[2]), datum[1], datum[2], datum)
    assert north[0] == pytest.approx(0.0, abs=1e-6)
    assert north[1] == pytest.approx(1000.0, abs=1e-3)
    assert north[2] == pytest.approx(-1000.0**2 / (2 * (r_m + datum[2])), rel=1e-3)
    # C_en columns are orthonormal and right-handed (E x N = U)
    C = earth.C_en(*datum[:2])
    np.testing.assert_allclose(C.T @ C, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(np.cross(C[:, 0], C[:, 1]), C[:, 2], atol=1e-15)


def test_radii_of_curvature() -> None:
    r_m, r_n = earth.radii_of_curvature(np.array([0.0, np.pi / 2]))
    assert r_n[0] == pytest.approx(earth.A_M, rel=1e-15)
    assert r_m[0] == pytest.approx(earth.A_M * (1 - earth.E2), rel=1e-15)
    assert r_m[1] == pytest.approx(earth.A_M**2 / earth.B_M, rel=1e-12)
    assert r_n[1] == pytest.approx(earth.A_M**2 / earth.B_M, rel=1e-12)


def test_normal_gravity() -> None:
    assert earth.normal_gravity(0.0, 0.0) == pytest.approx(earth.GAMMA_E_MPS2, rel=1e-12)
    assert earth.normal_gravity(np.pi / 2, 0.0) == pytest.approx(earth.GAMMA_P_MPS2, rel=1e-12)
    # published WGS-84 normal gravity on the ellipsoid at 45 deg latitude: 9.806199 m/s^2
    assert earth.normal_gravity(np.deg2rad(45.0), 0.0) == pytest.approx(9.806199, abs=2e-6)
    # free-air gradient ~ -3.086e-6 s^-2
    grad = (earth.normal_gravity(0.7, 1000.0) - earth.normal_gravity(0.7, 0.0)) / 1000.0
    assert grad == pytest.approx(-3.086e-6, rel=2e-3)
    np.testing.assert_allclose(earth.gravity_n(0.7, 0.0)[:2], 0.0)


def test_earth_and_transport_rate_match_frame_rotation() -> None:
    """omega_en^n equals the rotation rate of the local ENU frame along a trajectory."""
    lat0, lon0, h0 = np.deg2rad(40.0), np.deg2rad(116.0), 3000.0
    vel_n = np.array([150.0, -80.0, 5.0])
    dt = 1e-3
    rate = earth.llh_rate(lat0, h0, vel_n)
    lat1, lon1, _ = np.array([lat0, lon0, h0]) + rate * dt
    C0, C1 = earth.C_en(lat0, lon0), earth.C_en(lat1, lon1)
    # C_en(t+dt) = C_en(t) expm([w_en^n dt x])
    w_fd = dcm_to_rotvec(C0.T @ C1) / dt
    np.testing.assert_allclose(w_fd, earth.transport_rate_n(lat0, h0, vel_n), rtol=1e-5, atol=1e-12)
    w_ie = earth.earth_rate_n(lat0)
    assert np.linalg.norm(w_ie) == pytest.approx(earth.OMEGA_IE_RADPS)
    np.testing.assert_allclose(C0 @ w_ie, [0.0, 0.0, earth.OMEGA_IE_RADPS], atol=1e-20)


def test_nav_to_datum_round_trip_and_identity_at_the_datum(rng: np.random.Generator) -> None:
    from dpos_core.attitude import rotvec_to_dcm

    datum = np.array([np.deg2rad(40.0), np.deg2rad(116.0), 500.0])
    n = 200
    llh = datum + np.stack([rng.normal(0, 0.01, n), rng.normal(0, 0.01, n), rng.normal(0, 300, n)], 1)
    vel = rng.normal(0, 100, (n, 3))
    C = rotvec_to_dcm(rng.normal(0, 1, (n, 3)))
    p, v, Cw = earth.nav_to_datum(llh, vel, C, datum)
    llh2, vel2, C2 = earth.datum_to_nav(p, v, Cw, datum)
    np.testing.assert_allclose(llh2[:, :2], llh[:, :2], atol=1e-13)
    np.testing.assert_allclose(llh2[:, 2], llh[:, 2], atol=1e-7)
    np.testing.assert_allclose(vel2, vel, atol=1e-10)
    np.testing.assert_allclose(C2, C, atol=1e-12)
    # at the datum the two frames coincide; 60 km east the local vertical is tilted by ~0.54 deg about North
    np.testing.assert_allclose(earth.C_datum_n(datum[0], datum[1], datum), np.eye(3), atol=1e-15)
    _, r_n = earth.radii_of_curvature(datum[0])
    R = earth.C_datum_n(datum[0], datum[1] + 60e3 / (r_n * np.cos(datum[0])), datum)
    assert np.rad2deg(np.arccos(R[2, 2])) == pytest.approx(np.rad2deg(60e3 / r_n), rel=0.01)
