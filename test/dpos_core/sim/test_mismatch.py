"""The mismatch suite's truth-side perturbations (dpos_core.evaluation.mismatch): each case reaches the
simulated streams, the nominal scenario stays as it was; and the consistency metric of
dpos_core.ta.metrics on errors whose sigma is known."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.evaluation import mismatch as MM
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import metrics as M
from dpos_core.units import DEG, DEG_PER_H

DUR = 5.0


@pytest.fixture(scope="module")
def su():
    return load_scenario("paper_su")


def test_case_names(su) -> None:
    assert MM.case_names("all") == list(MM.CASES)
    assert MM.case_names("lever_arm_1cm, time_offset_5ms") == ["lever_arm_1cm", "time_offset_5ms"]
    with pytest.raises(ValueError, match=r"bogus_case.*valid: all, nominal, flexure_tau_x0.5"):
        MM.case_names("lever_arm_1cm,bogus_case")
    assert {"flexure_tau_x0.5", "flexure_tau_x2", "flexure_var_x0.5", "flexure_var_x2", "modal_wing", "time_offset_1ms",
            "time_offset_5ms", "time_offset_20ms", "lever_arm_1cm", "lever_arm_2cm", "sub_imu_scale_misalignment",
            "sub_imu_tactical", "master_ref_correlated"} <= set(MM.CASES)


def test_time_offset_in_the_stamps(su) -> None:
    nom = SimulatedSession(su, 1, DUR)
    ss = MM.simulate(MM.CASES["time_offset_5ms"], su, 1, DUR)
    a, b = nom.sub_imu("sub_r"), ss.sub_imu("sub_r")
    n = b.t_s.size
    np.testing.assert_allclose(b.t_s, a.t_s[:n] + 0.005, atol=1e-12)  # the same samples, stamped 5 ms late
    np.testing.assert_array_equal(b.omega_radps, a.omega_radps[:n])
    assert b.t_s[-1] <= DUR
    # the truth is at the stamps, in the main system's time
    tr = ss.truth("antenna/ant_r")
    np.testing.assert_allclose(tr.t_s[:3], [0.005, 0.015, 0.025], atol=1e-12)
    np.testing.assert_allclose(tr.llh, nom.truth("antenna/ant_r", tr.t_s).llh, atol=1e-12)
    # the master streams are not shifted
    np.testing.assert_array_equal(ss.master_imu().t_s, nom.master_imu().t_s)
    np.testing.assert_array_equal(ss.truth("master").t_s, nom.truth("master").t_s)


def test_lever_arm_truth_moves_nominal_stays(su) -> None:
    sc = MM.truth_scenario(MM.CASES["lever_arm_2cm"], su)
    d = np.subtract(sc.aircraft.sub_imu("sub_r").lever_arm_m, su.aircraft.sub_imu("sub_r").lever_arm_m)
    assert np.linalg.norm(d) == pytest.approx(0.02, rel=1e-9)
    assert d[1] < 0  # outward on the right wing
    assert su.aircraft.sub_imu("sub_r").lever_arm_m == (0.1, -5.0, 0.1)  # the nominal object is untouched
    nom, ss = SimulatedSession(su, 1, DUR), MM.simulate(MM.CASES["lever_arm_2cm"], su, 1, DUR)
    t = np.array([1.0, 3.0])
    a, b = nom.truth("sub_imu/sub_r", t), ss.truth("sub_imu/sub_r", t)
    shift = np.linalg.norm(earth.dllh_to_enu(b.llh - a.llh, a.llh), axis=1)
    np.testing.assert_allclose(shift, 0.02, atol=2e-4)  # the flexure moves the arm a little


def test_flexure_statistics_reach_the_wing(su) -> None:
    nom = SimulatedSession(su, 3, 60.0)
    big = MM.simulate(MM.CASES["flexure_var_x2"], su, 3, 60.0)
    t = np.linspace(0.0, 60.0, 301)
    th0, _ = nom.flexure(1).at(t, 5.0)
    th1, _ = big.flexure(1).at(t, 5.0)
    np.testing.assert_allclose(th1, np.sqrt(2.0) * th0, rtol=1e-6, atol=1e-12)  # the same draws, scaled
    slow = MM.truth_scenario(MM.CASES["flexure_tau_x2"], su)
    assert slow.aircraft.flexure.tau_s == (10.0, 4.0, 4.0) and su.aircraft.flexure.tau_s == (5.0, 2.0, 2.0)
    modal = MM.simulate(MM.CASES["modal_wing"], su, 3, DUR)
    assert modal.scenario.aircraft.wing is not None and su.aircraft.wing is None
    assert not np.allclose(modal.truth("sub_imu/sub_r").llh, nom.truth("sub_imu/sub_r", modal.truth("sub_imu/sub_r").t_s).llh)


def test_sub_imu_errors_reach_the_samples(su) -> None:
    nom = SimulatedSession(su, 1, DUR)
    ax = MM.simulate(MM.CASES["sub_imu_scale_misalignment"], su, 1, DUR)
    m = ax.scenario.aircraft.sub_imu("sub_r").imu
    assert m.gyro_scale_ppm == MM.SCALE_PPM and m.accel_misalignment_mrad == pytest.approx(0.05 * DEG * 1e3)
    assert su.aircraft.sub_imu("sub_r").imu.gyro_scale_ppm == 0.0
    # the specific force (about g on z) through scale factor and misalignment: mm/s^2, far above the 50 ug noise
    d = np.mean(ax.sub_imu("sub_r").f_mps2 - nom.sub_imu("sub_r").f_mps2, axis=0)
    assert np.max(np.abs(d)) > 1e-3
    tac = MM.simulate(MM.CASES["sub_imu_tactical"], su, 1, DUR)
    gb, ab = tac.imu_biases("sub_r")
    assert 0.05 < np.max(np.abs(gb)) / DEG_PER_H < 5.0  # 1 deg/h class, not the paper's 0.01 deg/h
    assert tac.scenario.aircraft.sub_imu("sub_r").imu.gyro_arw_deg_rth > 0


def test_master_reference_correlated_errors(su) -> None:
    nom = SimulatedSession(su, 2, 200.0)
    ss = MM.simulate(MM.CASES["master_ref_correlated"], su, 2, 200.0)
    ref, tr = ss.master_nav_reference(), ss.truth("master", ss.sample_times(100.0, include_start=True))
    e_h = np.rad2deg(hpr_error(hpr_from_C_nb(ref.C_nb), hpr_from_C_nb(tr.C_nb))[:, 0])
    e_p = earth.dllh_to_enu(ref.llh - tr.llh, tr.llh)[:, 0]
    e_w = np.rad2deg(hpr_error(hpr_from_C_nb(nom.master_nav_reference().C_nb), hpr_from_C_nb(tr.C_nb))[:, 0])

    def lag(e: np.ndarray, k: int = 100) -> float:  # 1 s lag autocorrelation
        return float(np.corrcoef(e[:-k], e[k:])[0, 1])

    assert lag(e_h) > 0.95 and lag(e_p) > 0.95 and abs(lag(e_w)) < 0.05
    assert np.max(np.abs(e_p)) > 0.01  # the position is no longer exact
    e_v = ref.vel_n_mps[:, 0] - tr.vel_n_mps[:, 0]  # the velocity error is the position error's rate
    d = np.diff(e_p) / 0.01 - 0.5 * (e_v[1:] + e_v[:-1])  # (up to the white acceleration within a step)
    assert np.std(e_v) > 2e-3 and np.sqrt(np.mean(d**2)) < 0.05 * np.std(e_v)
    g = MM.MASTER_REF_CORRELATED
    np.testing.assert_allclose(np.sqrt(ref.pos_cov[0].diagonal()), g.pos_m)  # reported: the marginal sigma
    np.testing.assert_allclose(np.sqrt(ref.vel_cov[0].diagonal()), g.vel_mps)


def test_consistency_of_a_gaussian_error() -> None:
    rng = np.random.default_rng(5)
    sigma = np.exp(rng.normal(0.0, 1.0, (20000, 9)))  # any sigma, per sample and component
    c = M.consistency(rng.normal(0.0, 1.0, (20000, 9)) * sigma, sigma)
    assert c["n"] == 20000
    for k in M.CONS_KEYS:
        assert c["within_2sigma"][k] == pytest.approx(0.954, abs=0.01)
        assert c["nees"][k] == pytest.approx(1.0, abs=0.05)
    c2 = M.consistency(rng.normal(0.0, 2.0, (20000, 9)) * sigma, sigma)  # optimistic by 2x
    assert c2["nees"]["pos_u"] == pytest.approx(4.0, rel=0.05) and c2["within_2sigma"]["pos_u"] < 0.75
    pooled = M.average_consistency([c, c2])
    assert pooled["n"] == 40000 and pooled["nees"]["rot_e"] == pytest.approx((c["nees"]["rot_e"] + c2["nees"]["rot_e"]) / 2)
    lo, hi = M.nees_bounds(50)
    assert 0.6 < lo < 1.0 < hi < 1.5
    assert M.nees_bounds(2) == pytest.approx((0.0506 / 2, 7.378 / 2), rel=2e-3)  # chi2(2) 2.5 % and 97.5 % over 2


def test_master_reference_from_the_in_flight_alignment(su) -> None:
    ss = MM.simulate(MM.CASES["master_ref_ifa"], su, 1, 12.0)
    ref = ss.master_nav_reference()
    assert ref is ss.master_nav_reference()  # computed once per session
    assert ref.t_s[0] >= 1.0 and np.all(np.diff(ref.t_s) > 0)  # from the first fix on (the recording rule)
    tr = ss.truth("master", ref.t_s)
    e = earth.dllh_to_enu(ref.llh - tr.llh, tr.llh)
    assert 0.0 < np.max(np.abs(e)) < 1.0  # a GNSS/INS's position, not the truth
    sig_att = np.sqrt(np.max(np.diagonal(ref.att_cov, axis1=1, axis2=2), axis=1))
    assert sig_att[0] > 10 * DEG  # unaligned before the first epoch (pos_master_node's flag)
    assert np.unique(sig_att).size > 3  # then each filter epoch's covariance
    assert ref.omega_eb_b_radps is not None and np.allclose(ref.omega_eb_b_radps, tr.omega_eb_b_radps, atol=1e-4)


def test_master_reference_smoothed_in_flight_alignment(su) -> None:
    ss = MM.simulate(MM.CASES["master_ref_ifa_smoothed"], su, 1, 30.0)
    sm = ss.master_nav_reference()
    fw = ss.ifa_reference()  # the same run, forward (cached with it)
    assert sm is not fw and sm.t_s.size > 0.9 * fw.t_s.size
    t = np.intersect1d(np.round(sm.t_s, 6), np.round(fw.t_s, 6))
    i, j = np.searchsorted(np.round(sm.t_s, 6), t), np.searchsorted(np.round(fw.t_s, 6), t)
    late = t > 20.0
    att = lambda n, k: np.sqrt(np.max(np.diagonal(n.att_cov[k], axis1=1, axis2=2), axis=1))  # noqa: E731
    assert np.median(att(sm, i[late])) < np.median(att(fw, j[late]))  # the smoother knows more
