"""The transfer alignment's divergence guard (dpos_core.ta.guard) and the rigid flexure
(dpos_core.ta.model, docs/transfer_alignment.md): a result that is no estimate raises AlignmentDiverged naming
its reason; a sub-IMU without flexure has its flexure states held at zero, so no smoother can
multiply their noise back through the flexure's contracting transition."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dpos_core.config.flexure import FlexureModel
from dpos_core.errors import AlignmentDiverged, NumericalFailure
from dpos_core.evaluation import ta as from_sim
from dpos_core.series import ImuSeries
from dpos_core.sim.flight import Segment
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import guard, pipeline
from dpos_core.ta.model import RIGID_FLEXURE_VAR, TAConfig, TransferAlignmentModel
from dpos_core.ta.pipeline import TASettings
from dpos_core.ta.qc import EpochQC

CFG = TAConfig(attitude_sigma_deg=1.0)


@pytest.fixture(scope="module")
def flight():
    """A short paper_su flight (20 s straight, a 30 deg turn over 20 s), seed 1: the session, the
    right sub-IMU's samples, the main POS and the installation."""
    sc = load_scenario("paper_su", aircraft="paper_su_pair")
    sc = replace(sc, segments=(Segment(20.0, name="lead_in"), Segment(20.0, heading_change_deg=30.0, name="turn")))
    ss = SimulatedSession(sc, 1, None)
    return ss, from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")


def _qc(nis: np.ndarray, dof: int = 9) -> EpochQC:
    K = nis.size
    return EpochQC(np.arange(K, dtype=float), nis, np.full(K, dof), np.full((K, 3), np.nan), np.zeros((K, 3), dtype=int),
                   np.full((K, 3), np.nan), False, np.full((K, dof), np.nan))


def test_nis_guard_fires_on_a_sustained_gross_excess_only() -> None:
    rng = np.random.default_rng(0)
    ok = rng.chisquare(9, 100) * 5.0  # an optimistic filter (the real logs': NIS 2-5 x dof) passes
    guard.check_nis(_qc(ok), "t")
    spike = ok.copy()
    spike[50] = 1e4  # one outlier epoch is no sustained stretch
    guard.check_nis(_qc(spike), "t")
    bad = ok.copy()
    bad[40:52] = 1e6
    with pytest.raises(AlignmentDiverged, match="grossly inconsistent") as ei:
        guard.check_nis(_qc(bad), "t")
    assert ei.value.reason == "nis" and 31.0 <= ei.value.t_s <= 40.0
    guard.check_nis(_qc(bad[45:51]), "t")  # fewer measured epochs than the window: not checked


def test_finite_guard() -> None:
    x, P = np.zeros((5, 24)), np.broadcast_to(np.eye(24), (5, 24, 24)).copy()
    guard.check_finite(x, P, np.arange(5.0), "t")
    P[3, 2, 2] = np.inf
    with pytest.raises(AlignmentDiverged, match="non-finite.*epoch 3") as ei:
        guard.check_finite(x, P, np.arange(5.0), "t")
    assert ei.value.reason == "non_finite" and ei.value.t_s == 3.0
    assert isinstance(ei.value, NumericalFailure)  # callers that catch NumericalFailure catch it


def test_position_guard_against_the_lever_arm(flight) -> None:
    _, _, master, ins = flight
    t = master.t_s[10:20]
    d_m = float(np.linalg.norm(ins.lever_arm_m)) + 5.0  # within |r0| + 10 m of the main POS
    llh = master.llh[10:20].copy()
    llh[:, 2] += d_m
    guard.check_positions(t, llh, master, ins, "t")
    llh[7, 2] += 20.0
    with pytest.raises(AlignmentDiverged, match="from the main POS") as ei:
        guard.check_positions(t, llh, master, ins, "t")
    assert ei.value.reason == "position_bound" and ei.value.t_s == t[7]
    llh[7, 2] = np.nan  # a non-finite position is outside too
    with pytest.raises(AlignmentDiverged):
        guard.check_positions(t, llh, master, ins, "t")
    guard.check_positions(t + 1e4, llh, master, ins, "t")  # outside the main POS: not checked


def test_gyro_in_the_wrong_units_is_diverged_not_estimated(flight) -> None:
    """The sub-IMU's angular rates logged in deg/s but read as rad/s: the run raises
    AlignmentDiverged with its reason instead of returning rows."""
    _, imu, master, ins = flight
    wrong = ImuSeries(imu.t_s, imu.omega_radps * np.rad2deg(1.0), imu.f_mps2)
    for method in ("ukf", "ups"):
        with pytest.raises(AlignmentDiverged) as ei:
            pipeline.run(wrong, master, ins, TASettings(method=method, particles=20), cfg=CFG)
        assert ei.value.reason in ("nis", "position_bound", "non_finite"), ei.value
        assert f"({method})" in str(ei.value)
    blocks: list[np.ndarray] = []
    with pytest.raises(AlignmentDiverged):  # streamed (a row sink): no block is handed on
        pipeline.run(wrong, master, ins, TASettings(method="ukf"), cfg=CFG, sink=lambda t, *rest: blocks.append(t))
    assert blocks == []


def test_right_units_pass_the_guard(flight) -> None:
    """The same flight in the right units: the guard does not fire (a sane run, errors of cm)."""
    ss, imu, master, ins = flight
    r = pipeline.run(imu, master, ins, TASettings(method="ups", particles=20), cfg=CFG)
    tr = ss.truth("sub_imu/sub_r", r.t_s)
    assert np.abs(r.llh[:, 2] - tr.llh[:, 2]).max() < 0.5


def test_rigid_flexure_axes_are_held_at_zero(flight) -> None:
    """A flexure axis of variance 0 (span 0, a rigid mount): its transition 0, its noise and prior
    RIGID_FLEXURE_VAR; the other axes keep the exact Gauss-Markov discretization."""
    _, imu, master, ins = flight
    flex = FlexureModel(tau_s=(5.0, 2.0, 2.0), variance_deg2=(0.0, 0.5, 0.0), reference_span_m=1.0, span_exponent=0.0)
    model = TransferAlignmentModel(imu, master, replace(ins, flexure=flex), CFG, pipeline.initial_from_master(master, ins))
    Phi, Q = model._flex_discrete(1.0)
    Phi_x, Q_x = flex.discrete(1.0)
    assert list(model.rigid_flexure_axes()) == [True, False, True]
    np.testing.assert_array_equal(Phi[[0, 2]], 0.0)
    np.testing.assert_array_equal(Q[[0, 2]], np.broadcast_to(np.eye(2) * RIGID_FLEXURE_VAR, (2, 2, 2)))
    np.testing.assert_array_equal(Phi[1], Phi_x[1])
    np.testing.assert_array_equal(Q[1], Q_x[1])
    _, P0 = model.prior()
    np.testing.assert_array_equal(np.diag(P0)[[18, 20, 21, 23]], RIGID_FLEXURE_VAR)
    assert np.diag(P0)[19] > 1e-6


def test_ups_on_a_rigid_mount_agrees_with_urtss() -> None:
    """A wing without flexure (every axis variance 0, in the simulation and the model): the UPS's
    smoothed errors stay with the URTSS's (before the rigid axes were held at zero the smoother
    amplified the flexure states' noise by x2.9 per epoch on the real DOT1 log: docs/transfer_alignment.md)."""
    sc = load_scenario("paper_su", aircraft="paper_su_pair")
    ac = replace(sc.aircraft, flexure=replace(sc.aircraft.flexure, variance_deg2=(0.0, 0.0, 0.0)))
    sc = replace(sc, aircraft=ac, segments=(Segment(20.0, name="lead_in"), Segment(40.0, heading_change_deg=30.0, name="turn")))
    ss = SimulatedSession(sc, 1, None)
    imu, master, rigid = from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")
    assert rigid.flexure.variance_deg2 == (0.0, 0.0, 0.0)
    r_u = pipeline.run(imu, master, rigid, TASettings(method="ups", particles=20), cfg=CFG)
    r_s = pipeline.run(imu, master, rigid, TASettings(method="urtss"), cfg=CFG)
    assert np.abs(r_u.x[:, :9] - r_s.x[:, :9]).max() < 0.05
    assert np.abs(r_u.x[:, 18:24]).max() < 1e-6  # held at zero (their sigma 1e-8)


def test_guarded_sink_checks_each_block_before_handing_it_on(flight) -> None:
    _, _, master, ins = flight
    got: list[np.ndarray] = []
    sink = pipeline._guarded_sink(lambda t, *rest: got.append(t), master, ins, "t")
    t, llh = master.t_s[5:9], master.llh[5:9].copy()
    z3, z4 = np.zeros((4, 3)), np.zeros((4, 4))
    sink(t, llh, z3, z4, np.zeros((4, 9)))
    llh[2, 0] += 1e-3  # 6 km north
    with pytest.raises(AlignmentDiverged, match="from the main POS"):
        sink(t, llh, z3, z4, np.zeros((4, 9)))
    assert len(got) == 1
