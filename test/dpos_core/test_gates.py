"""dpos_core.gates: the pure checks of the contract topics' inputs."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth, gates
from dpos_core.attitude import dcm_to_quat, rotvec_to_dcm
from dpos_core.units import DEG

LLH = np.array([40.0 * DEG, 116.0 * DEG, 3000.0])
Q0 = np.array([1.0, 0.0, 0.0, 0.0])


def _cov(pos_m: float, vel_mps: float, att_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.eye(3) * pos_m**2, np.eye(3) * vel_mps**2, np.eye(3) * (att_deg * DEG) ** 2


# ---------------------------------------------------------------------------------------------- stamps
def test_stamp_in_the_future_is_refused_beyond_the_tolerance() -> None:
    assert gates.check_stamp(10_000_000_000, None, 9_000_000_000, future_tol_s=2.0) is None
    r = gates.check_stamp(12_000_000_001, None, 10_000_000_000, future_tol_s=2.0)
    assert r is not None and r.reason == "future"
    r = gates.check_stamp(10_000_000_000 + 3600 * 10**9, 9_000_000_000, 10_000_000_000)  # +1 h
    assert r is not None and r.reason == "future" and "3600" in r.text


def test_stamp_before_the_last_accepted_is_refused_equal_is_not() -> None:
    assert gates.check_stamp(5, 5, None) is None
    r = gates.check_stamp(4, 5, None)
    assert r is not None and r.reason == "before_last"
    assert gates.check_stamp(6, 5, 100) is None
    assert gates.check_stamp(6, None, None) is None  # nothing known: passes


# ---------------------------------------------------------------------------------------------- corrections
def test_correction_difference_has_the_position_velocity_and_attitude_offsets() -> None:
    moved = earth.offset_llh(LLH, np.array([3.0, -4.0, 1.0]))
    q = dcm_to_quat(rotvec_to_dcm(np.array([0.0, 0.0, 2.0 * DEG])))
    d = gates.correction_difference(moved, np.array([1.0, 0.0, 0.0]), q, LLH, np.zeros(3), Q0)
    np.testing.assert_allclose(d[:3], [3.0, -4.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(d[3:6], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(d[6:], [0.0, 0.0, 2.0 * DEG], atol=1e-12)


def test_a_1000_m_correction_with_a_tiny_covariance_is_refused_against_a_0p4_m_node() -> None:
    d = np.zeros(9)
    d[0] = 1000.0
    r = gates.check_correction(d, _cov(0.4, 0.05, 0.1), _cov(1e-5, 1e-5, 1e-5))
    assert r is not None and r.reason == "size" and "1000" in r.text
    # other sizes of the same class: 100 m, 30 m/s, 45 deg of heading
    for i, x in ((1, 100.0), (4, 30.0), (8, 45.0 * DEG)):
        d = np.zeros(9)
        d[i] = x
        r = gates.check_correction(d, _cov(0.4, 0.05, 0.1), _cov(0.3, 0.03, 0.05))
        assert r is not None and r.reason == "size", i


def test_consistent_corrections_pass_the_gate() -> None:
    rng = np.random.default_rng(1)
    own, corr = _cov(0.4, 0.05, 0.1), _cov(0.3, 0.03, 0.05)
    P = np.diag([0.4**2 + 0.3**2 + 9.0] * 3 + [0.05**2 + 0.03**2 + 1.0] * 3 + [((0.1**2 + 0.05**2) + 4.0) * DEG**2] * 3)
    d = rng.multivariate_normal(np.zeros(9), P, size=2000)
    refused = sum(gates.check_correction(x, own, corr) is not None for x in d)
    assert refused == 0
    # during the alignment the own covariance is large (heading 100 deg): a big heading change passes
    d = np.zeros(9)
    d[0], d[8] = 8.0, 60.0 * DEG
    assert gates.check_correction(d, _cov(5.0, 0.5, 100.0), _cov(1.0, 0.1, 10.0)) is None


def test_a_correction_with_a_broken_covariance_or_state_is_refused() -> None:
    d = np.zeros(9)
    bad_nan = (np.eye(3) * np.nan, np.eye(3), np.eye(3))
    neg = (-np.eye(3), np.eye(3), np.eye(3))
    asym = (np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), np.eye(3), np.eye(3))
    for cov in (bad_nan, neg, asym):
        r = gates.check_correction(d, _cov(1, 1, 1), cov)
        assert r is not None and r.reason == "covariance"
    d[2] = np.inf
    r = gates.check_correction(d, _cov(1, 1, 1), _cov(1, 1, 1))
    assert r is not None and r.reason == "nonfinite"


def test_extrapolation_widens_the_gate_for_a_stamp_ahead() -> None:
    d = np.zeros(9)
    d[0] = 40.0
    own, corr = _cov(0.4, 0.05, 0.1), _cov(0.3, 0.03, 0.05)
    assert gates.check_correction(d, own, corr) is not None
    assert gates.check_correction(d, own, corr, extra_var=gates.extrapolation_var(2.0)) is None
    np.testing.assert_allclose(gates.extrapolation_var(0.0), 0.0)


# ---------------------------------------------------------------------------------------------- biases
def test_gross_or_nonfinite_bias_estimates_are_refused() -> None:
    assert gates.check_bias(np.full(3, 0.01 * DEG / 3600.0), np.full(3, 1e-3)) is None
    r = gates.check_bias(np.array([0.0, 0.0, 1.0]), np.zeros(3))  # 1 rad/s = 57 deg/s
    assert r is not None and r.reason == "size"
    r = gates.check_bias(np.zeros(3), np.array([9.81, 0.0, 0.0]))  # 1 g
    assert r is not None and r.reason == "size"
    r = gates.check_bias(np.array([np.nan, 0.0, 0.0]), np.zeros(3))
    assert r is not None and r.reason == "nonfinite"


# ---------------------------------------------------------------------------------------------- aligned
@pytest.mark.parametrize("sigma", [100.0, "100", 1.5, "nan", "none", None, "-1", "inf"])
def test_an_aligned_claim_without_a_supporting_heading_sigma_is_refused(sigma: object) -> None:
    r = gates.check_aligned(True, sigma, 1.0)  # type: ignore[arg-type]
    assert r is not None and r.reason == "unsupported"


def test_a_supported_or_no_aligned_claim_passes() -> None:
    assert gates.check_aligned(True, "0.08", 1.0) is None
    assert gates.check_aligned(False, "100", 1.0) is None


# ---------------------------------------------------------------------------------------------- datum
def test_a_datum_that_changes_is_refused_the_same_one_passes() -> None:
    assert gates.check_datum(None, LLH) is None
    assert gates.check_datum(LLH, LLH + np.array([1e-12, 0.0, 0.001])) is None
    r = gates.check_datum(LLH, LLH + np.array([10.0 * DEG, 0.0, 0.0]))
    assert r is not None and r.reason == "changed" and "km" not in r.text
    r = gates.check_datum(LLH, LLH + np.array([0.0, 0.0, 5.0]))  # 5 m up
    assert r is not None and r.reason == "changed"
    r = gates.check_datum(None, np.array([np.nan, 0.0, 0.0]))
    assert r is not None and r.reason == "nonfinite"
    r = gates.check_datum(None, np.array([3.0, 0.0, 0.0]))  # 172 deg latitude: degrees read as radians
    assert r is not None and r.reason == "nonfinite"


# ---------------------------------------------------------------------------------------------- counts
def test_refusals_are_counted_and_logged_once_then_at_a_bounded_rate() -> None:
    g = gates.GateCounts(interval_s=10.0)
    lines = [g.refuse("ifa_correction/size", "x", t) for t in np.arange(0.0, 30.0, 0.5)]  # 60 in 30 s
    logged = [x for x in lines if x is not None]
    assert g.by_reason == {"ifa_correction/size": 60} and g.total == 60
    assert len(logged) == 3  # t = 0, 10, 20
    assert "20 refused since the last report" in logged[1]
    assert g.refuse("ifa_status/unsupported", "y", 30.0) is not None  # another reason: logged at once
    v = g.values()
    assert v["gate_refused"] == 61 and v["gate/ifa_status/unsupported"] == 1 and str(v["last_gate"]).startswith("ifa_status")


def test_a_second_publisher_is_reported_once_a_restarted_one_is_not() -> None:
    w = gates.PublisherWatch({"/master/nav": 1})
    assert w.update("/master/nav", [(b"a", "/pos_master_node")]) == []
    assert w.update("/master/nav", [(b"b", "/pos_master_node")]) == []  # restarted: a new GID alone
    assert w.replaced == {"/master/nav": 1} and w.extra == {}
    lines = w.update("/master/nav", [(b"b", "/pos_master_node"), (b"c", "/graph_b/pos_master_node")])
    assert len(lines) == 1 and "2 publishers on /master/nav" in lines[0] and "/graph_b/pos_master_node" in lines[0]
    assert w.update("/master/nav", [(b"b", "/pos_master_node"), (b"c", "/graph_b/pos_master_node")]) == []  # once
    assert w.values() == {"publishers_extra/master/nav": 1, "publishers_replaced/master/nav": 1}
    assert w.update("/other", [(b"x", "n"), (b"y", "m")]) != []  # unknown topics: one expected
    assert w.update("/other", [(b"x", "n"), (b"y", "m"), (b"z", "o")]) != []  # a third one: reported
    assert w.extra["/other"] == 2  # the most beyond the one expected at once


def test_two_interleaving_sources_are_detected_an_isolated_glitch_is_not() -> None:
    w = gates.InterleaveWatch(window=200, min_back=10)
    assert not any(w.add(k in (50, 51)) for k in range(1000))  # two glitches
    assert w.episodes == 0
    # two graphs: every other sample goes back (a second device's stamps, offset)
    starts = [w.add(k % 2 == 1) for k in range(400)]
    assert starts.count(True) == 1 and w.episodes == 1 and starts.index(True) == 19
    assert not any(w.add(False) for _ in range(200))  # it ends ...
    assert any(w.add(True) for _ in range(10)) and w.episodes == 2  # ... and a new episode is reported
