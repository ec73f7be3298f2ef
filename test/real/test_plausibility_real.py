"""The real recordings pass the plausibility checks (dpos_core.plausibility) that refuse unit and
installation mistakes, and the same recordings converted to the wrong unit are flagged: walk_0827
(handheld MEMS, tight turns), thor_flight75 (fixed-wing UAV), quad_mimu (a quadrotor; its
dpos-import runs pass the checks in test_quad_mimu.py)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core import plausibility as P
from dpos_core.imports.logs import read_imu_csv, read_pos, read_tag
from dpos_core.units import DEG, G0_MPS2

sys.path.insert(0, str(REPO / "test" / "real"))
WALK = REPO / "data" / "real" / "walk_0827"


def _walk():
    log = read_imu_csv(WALK / "imu_1730.csv", tag=read_tag(WALK / "imu_1730.csv.tag"))
    pos = read_pos(WALK / "gnss_1730_sf.pos")
    t = (log.t_ns - log.t_ns[0]) * 1e-9
    inside = (pos.t_ns >= log.t_ns[0]) & (pos.t_ns <= log.t_ns[-1])
    course = P.course_rate_radps((pos.t_ns[inside] - log.t_ns[0]) * 1e-9, pos.llh[inside])
    return t, log.omega_radps, log.f_mps2, course


def _thor():
    from test_thor_flight75 import _load

    imu, gnss, _, _ = _load()
    return imu.t_s, imu.omega_radps, imu.f_mps2, P.course_rate_radps(gnss.t_s, gnss.llh)


@pytest.fixture(scope="module", params=["walk_0827", "thor_flight75"])
def rec(request):
    return request.param, (_walk() if request.param == "walk_0827" else _thor())


def test_real_recording_passes(rec):
    name, (t, om, f, course) = rec
    assert P.check_imu(name, t, om, f) == []
    assert np.percentile(course, 90) > P.TURNING_MIN_RADPS  # the check had a turn to compare by
    assert P.check_rate_scale(name, om, course, "the GNSS course") is None


@pytest.mark.parametrize(("f_scale", "om_scale", "says"), [(G0_MPS2, 1.0, "m/s^2 read as g"), (1.0 / G0_MPS2, 1.0, "g read as m/s^2"),
                                                           (1.0, DEG, "rad/s read as deg/s"), (1.0, 1.0 / DEG, "deg/s read as rad/s")])
def test_real_recording_in_the_wrong_unit_is_flagged(rec, f_scale, om_scale, says):
    name, (t, om, f, course) = rec
    found = P.check_imu(name, t, om * om_scale, f * f_scale)
    rate = P.check_rate_scale(name, om * om_scale, course, "the GNSS course")
    assert any(says in x.mistake for x in [*found, *([rate] if rate else [])]), (found, rate)


def _track(name: str):
    """(t, omega, f, fix stamps, fix llh) of a real recording on one time scale (dpos-ifa's input)."""
    if name == "walk_0827":
        log = read_imu_csv(WALK / "imu_1730.csv", tag=read_tag(WALK / "imu_1730.csv.tag"))
        pos = read_pos(WALK / "gnss_1730_sf.pos")
        return (log.t_ns - log.t_ns[0]) * 1e-9, log.omega_radps, log.f_mps2, (pos.t_ns - log.t_ns[0]) * 1e-9, pos.llh
    from test_thor_flight75 import _load

    imu, gnss, _, _ = _load()
    return imu.t_s, imu.omega_radps, imu.f_mps2, gnss.t_s, gnss.llh


@pytest.mark.parametrize("name", ["walk_0827", "thor_flight75"])
def test_dpos_ifa_check_passes_the_real_recordings_and_flags_them_converted(name):
    """dpos-ifa's check (P.check_imu_with_track: the IMU's values, then its rates against the fixes'
    course over the IMU's span): the recordings pass; converted, each wrong unit is named."""
    t, om, f, tt, llh = _track(name)
    assert P.check_imu_with_track(name, t, om, f, tt, llh, "the fixes") == []
    for f_scale, om_scale, says in ((G0_MPS2, 1.0, "m/s^2 read as g"), (1.0, DEG, "rad/s read as deg/s"),
                                    (1.0, 1.0 / DEG, "deg/s read as rad/s")):
        found = P.check_imu_with_track(name, t, om * om_scale, f * f_scale, tt, llh, "the fixes")
        assert len(found) == 1 and says in found[0].mistake, (f_scale, om_scale, found)
