"""read_session refuses a recording whose values show a unit or installation mistake, in one
SessionError line (dpos_ros.io.session.check_plausible, dpos_core.plausibility); the committed
sample bag passes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core.errors import SessionError
from dpos_core.series import ImuSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG, G0_MPS2
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io.session import check_plausible, read_session, session_from_streams

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


@pytest.fixture(scope="module")
def sample():
    return read_session(SAMPLE)  # the honest recording passes read_session's checks


def _with_sub(sess, name: str, omega_scale: float = 1.0, f_scale: float = 1.0):
    s = sess.sub_imus[name]
    subs = dict(sess.sub_imus)
    subs[name] = ImuSeries(s.t_s, s.omega_radps * omega_scale, s.f_mps2 * f_scale)
    return dataclasses.replace(sess, sub_imus=subs, warnings=list(sess.warnings))


def test_sample_bag_passes(sample):
    assert check_plausible(sample) is sample


@pytest.mark.parametrize(("omega", "f", "says"), [
    (1.0, G0_MPS2, "looks like m/s^2 read as g"),
    (1.0, 1.0 / G0_MPS2, "looks like g read as m/s^2"),
])
def test_sub_imu_accelerometer_in_the_wrong_unit_is_refused(sample, omega, f, says):
    name = sorted(sample.sub_imus)[0]
    with pytest.raises(SessionError) as e:
        check_plausible(_with_sub(sample, name, omega, f))
    msg = str(e.value)
    assert msg.startswith(f"{SAMPLE}: sub-IMU {name}: ") and says in msg and "\n" not in msg, msg


@pytest.fixture(scope="module")
def turning():
    """330 s of paper_cdvf: straight, then part of a 180 deg turn in 100 s (1.8 deg/s)."""
    ss = SimulatedSession(load_scenario("paper_cdvf"), 1, 330.0)
    return session_from_streams(session_streams(ss), session_custom_data(ss, ""), "cdvf")


@pytest.mark.parametrize(("omega", "says"), [(1.0, None), (1.0 / DEG, "looks like deg/s read as rad/s"),
                                             (DEG, "looks like rad/s read as deg/s")])
def test_sub_imu_gyro_unit_against_the_main_systems_rates(turning, omega, says):
    sess = _with_sub(turning, "slave", omega)
    if says is None:
        assert check_plausible(sess) is sess
        return
    with pytest.raises(SessionError) as e:
        check_plausible(sess)
    msg = str(e.value)
    assert msg.startswith("cdvf: sub-IMU slave: 90th percentile of |omega|") and "/master/nav" in msg and says in msg, msg


def test_a_straight_flight_cannot_tell_the_gyro_unit(sample):
    """The sample bag flies 45 s straight and level: no turn to compare the rates by, no finding."""
    name = sorted(sample.sub_imus)[0]
    assert check_plausible(_with_sub(sample, name, DEG)) is not None


@pytest.mark.parametrize("how", ["lat +10 deg", "lon +10 deg", "lat and lon swapped"])
def test_datum_far_from_the_first_fix_is_refused(sample, how):
    d = np.asarray(sample.datum_llh, dtype=float).copy()
    if how == "lat and lon swapped":
        d[[0, 1]] = d[[1, 0]]
    else:
        d[0 if how.startswith("lat") else 1] += 10.0 * DEG
    far = dataclasses.replace(sample, datum_llh=d, warnings=list(sample.warnings))
    with pytest.raises(SessionError, match=r"/dpos/datum: [\d.]+ km from the first fix .*: the datum of another place"):
        check_plausible(far)
