"""dpos_core.plausibility: each gross mistake flagged with its likely cause, the honest input not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dpos_core import plausibility as P
from dpos_core.units import DEG, G0_MPS2

RATE_HZ = 100.0


def _rotvec_dcm(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th == 0.0:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def _vehicle(seed: int = 1, roll: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """120 s of a vehicle at 100 Hz: at rest, rolled 20 deg (25-30 s), back (65-70 s), a turn
    of 10 deg/s (80-100 s); no translation, so f = gravity in the body. (t_s, omega, f)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 120.0, 1.0 / RATE_HZ)
    om = np.zeros((t.size, 3))
    if roll:
        om[(t >= 25) & (t < 30), 0] = 4.0 * DEG
        om[(t >= 65) & (t < 70), 0] = -4.0 * DEG
    om[(t >= 80) & (t < 100), 2] = 10.0 * DEG
    C = np.eye(3)  # body -> level
    f = np.empty_like(om)
    for k in range(t.size):
        f[k] = C.T @ np.array([0.0, 0.0, G0_MPS2])
        C = C @ _rotvec_dcm(om[k] / RATE_HZ)
    om_meas = om + rng.normal(0.0, 0.05 * DEG, om.shape)
    f_meas = f + rng.normal(0.0, 0.02, f.shape)
    return t, om_meas, f_meas


def test_honest_imu_has_no_finding():
    t, om, f = _vehicle()
    assert P.check_imu("imu", t, om, f) == []


@pytest.mark.parametrize(("scale", "says"), [(G0_MPS2, "m/s^2 read as g"), (1.0 / G0_MPS2, "g read as m/s^2"),
                                             (0.0, "all zero"), (5.0, "wrong accelerometer unit")])
def test_specific_force_off_g_is_flagged_with_the_likely_unit(scale, says):
    t, om, f = _vehicle()
    found = P.check_specific_force("--imu x.csv", t, f * scale)
    assert found is not None and says in found.mistake and str(found).startswith("--imu x.csv: median |f|")


def test_a_steady_2g_turn_is_not_a_unit_mistake():
    t, om, f = _vehicle()
    assert P.check_specific_force("imu", t, f * 2.0) is None


def test_rad_s_read_as_deg_s_is_flagged_by_the_tilt_the_gyros_do_not_explain():
    t, om, f = _vehicle()
    found = P.check_angular_rate("sub", t, om * DEG, f)
    assert found is not None and "rad/s read as deg/s" in found.mistake and "turned by 2" in found.statistic


def test_deg_s_read_as_rad_s_is_flagged_by_rates_no_vehicle_has():
    t, om, f = _vehicle()
    om = om.copy()
    om[(t >= 80) & (t < 100), 2] = 25.0 * DEG  # a sharper turn: x 57.3 = 1432 deg/s
    found = P.check_angular_rate("sub", t, om / DEG, f)
    assert found is not None and "deg/s read as rad/s" in found.mistake and "99th percentile" in found.statistic


def test_a_vehicle_that_only_yaws_gives_no_tilt_evidence():
    t, om, f = _vehicle(roll=False)
    assert P.check_angular_rate("car", t, om * DEG, f) is None  # nothing to tell the unit by


def test_a_tilt_inside_a_gap_is_not_taken_for_a_gyro_unit():
    t, om, f = _vehicle()
    keep = (t < 24) | (t >= 31)  # the roll happened while the log was cut
    assert P.check_angular_rate("sub", t[keep], om[keep], f[keep]) is None


@pytest.mark.parametrize(("scale", "says"), [(1.0, None), (DEG, "rad/s read as deg/s"), (1.0 / DEG, "deg/s read as rad/s")])
def test_rate_scale_against_a_reference(scale, says):
    t, om, f = _vehicle()
    ref = np.linalg.norm(om, axis=1)  # the vehicle's own rates as another system measured them
    found = P.check_rate_scale("sub-IMU s", om * scale, ref, "/master/nav")
    assert (found is None) if says is None else (found is not None and says in found.mistake)


def test_rate_scale_needs_the_vehicle_to_turn():
    rng = np.random.default_rng(3)
    om = rng.normal(0.0, 0.05 * DEG, (5000, 3))
    assert P.check_rate_scale("s", om * DEG, np.full(100, 0.5 * DEG), "ref") is None


def test_course_rate_of_a_circle():
    t = np.arange(0.0, 100.0, 0.25)
    r = 100.0  # m, 10 m/s: 0.1 rad/s
    ang = 0.1 * t
    llh = np.column_stack([0.7 + r * np.sin(ang) / 6_371_000.0, 0.2 + r * np.cos(ang) / (6_371_000.0 * math.cos(0.7)), np.zeros_like(t)])
    cr = P.course_rate_radps(t, llh)
    assert cr.size > 90 and abs(float(np.median(cr)) - 0.1) < 0.005


@pytest.mark.parametrize(("arm", "says"), [((1000.0, 0.0, 0.0), "longer than the aircraft"), ((0.0, -5000.0, 300.0), "millimetres"),
                                           ((0.0, -12.0, -0.3), None), ((float("nan"), 0, 0), None)])
def test_lever_arm_within_the_aircraft(arm, says):
    bound = P.size_bound_m([12.0], 12.5)
    found = P.check_lever_arm("sub-IMU 'imu11' lever_arm_m", arm, bound)
    assert (found is None) if says is None else (found is not None and says in found.mistake)


def test_size_bound():
    assert P.size_bound_m([]) == P.DEFAULT_SIZE_M
    assert P.size_bound_m([-45.0], 40.0) == 75.0


def test_datum_near_the_first_fix():
    lat, lon = 40.0 * DEG, 116.0 * DEG
    assert P.check_datum("datum", lat, lon, lat + 0.5 * DEG, lon) is None  # 56 km
    far = P.check_datum("/dpos/datum", lat + 10.0 * DEG, lon, lat, lon)
    assert far is not None and "1112 km" in far.statistic


@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan"), float("inf")])
def test_sigma_must_be_positive_and_finite(sigma):
    assert P.check_sigma("initial_sigma[2]", sigma) is not None


def test_sigma_positive_passes():
    assert P.check_sigma("s", 1e-3) is None


@pytest.mark.parametrize(("offset", "ok"), [(0.0, True), (-0.12, True), (59.0, True), (1e300, False), (120.0, False),
                                            (float("nan"), False), (-3600.0, False)])
def test_time_offset_bound(offset, ok):
    assert (P.check_time_offset("gnss_time_offset_s", offset) is None) == ok


def test_records_of_another_day_do_not_overlap():
    assert P.check_overlap("imu and pos", (1000.0, 1200.0), (1100.0, 1300.0)) is None
    day = P.check_overlap("imu and pos", (1000.0, 1200.0), (1000.0 + 86400.0, 1200.0 + 86400.0))
    assert day is not None and "whole days" in day.statistic
    hour = P.check_overlap("imu and pos", (0.0, 100.0), (7300.0, 7400.0))
    assert hour is not None and "whole days" not in hour.statistic


def test_fix_sigmas_all_zero_are_flagged_one_positive_fix_is_not():
    s = np.zeros((20, 3))
    f = P.check_fix_sigmas("/fix", s)
    assert f is not None and "position sigma" in f.statistic and "> 0" in f.mistake
    s[5] = (0.02, 0.02, 0.05)  # a driver that fills its covariance only sometimes: the filter rejects the others
    assert P.check_fix_sigmas("/fix", s) is None
    assert P.check_fix_sigmas("/fix", np.full((3, 3), np.nan)) is not None
    assert P.check_fix_sigmas("/fix", np.zeros((0, 3))) is None


def test_imu_with_track_compares_rates_with_the_course_within_the_imu_span():
    """A vehicle on a circle at 0.1 rad/s: its gyros in rad/s pass, read as deg/s (x DEG: no tilt, the
    record's own values cannot tell) are flagged against the track's course; the course outside the
    IMU's span is not used."""
    t = np.arange(0.0, 200.0, 0.01)
    om = np.zeros((t.size, 3))
    om[:, 2] = 0.1
    f = np.tile([0.0, 0.0, G0_MPS2], (t.size, 1))
    tt = np.arange(-100.0, 200.0, 0.25)
    ang = 0.1 * np.maximum(tt, 0.0)  # (straight before the IMU starts)
    llh = np.column_stack([0.7 + 100.0 * np.sin(ang) / 6_371_000.0, 0.2 + 100.0 * np.cos(ang) / (6_371_000.0 * math.cos(0.7)),
                           np.zeros_like(tt)])
    assert P.check_imu_with_track("imu", t, om, f, tt, llh, "/fix") == []
    found = P.check_imu_with_track("imu", t, om * DEG, f, tt, llh, "/fix")
    assert len(found) == 1 and "rad/s read as deg/s" in found[0].mistake and "the course of /fix" in found[0].statistic
    found = P.check_imu_with_track("imu", t, om, f * G0_MPS2, tt, llh, "/fix")
    assert len(found) == 1 and "m/s^2 read as g" in found[0].mistake
