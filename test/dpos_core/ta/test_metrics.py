"""dpos_core.ta.metrics against hand-computed values.

Every method is compared through these functions (dpos-eval, dpos-process, the demo), so a sign,
unit or axis error in them would cancel in any comparison between methods; here each key is
pinned to an absolute value worked out by hand:

    error = estimate - truth,   RMSE = sqrt(sum e_i^2 / n),   STD = sqrt(sum (e_i - mean e)^2 / n)

([Gong2018] eq. 21, as the module states it: the population STD, divided by n).  The expected
values use only the WGS-84 constants and the documented Euler-angle convention, written out
below, not the project's earth/frames helpers.

Tolerances: 1e-9 relative for angles, velocities and the statistics; for positions 1e-8 m
absolute on top (a longitude of 116 deg in radians carries 4e-16 rad of float64 resolution,
2 nm on the ground), and for the baseline 1e-8 m (ECEF coordinates of 6.4e6 m carry 1e-9 m).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dpos_core.series import NavSeries
from dpos_core.ta import metrics as M


def _nav(t_s: np.ndarray, llh: np.ndarray, vel_n_mps: np.ndarray, C_nb: np.ndarray) -> NavSeries:
    return NavSeries.from_C_nb(t_s, C_nb, vel_n_mps, llh)


REL = 1e-9
POS_ATOL_M = 1e-8

# WGS-84, by hand
A = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)


def radii(lat_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Meridian R_M and prime-vertical R_N radii of curvature."""
    w = 1.0 - E2 * np.sin(lat_rad) ** 2
    return A * (1.0 - E2) / w**1.5, A / np.sqrt(w)


def C_nb(heading_deg, pitch_deg, roll_deg) -> np.ndarray:
    """FLU body in ENU from aviation angles (heading clockwise from north, pitch nose up, roll
    right wing down): ``C_ned_frd = Rz(h) Ry(p) Rx(r)``, then the two axis swaps."""
    h, p, r = (np.deg2rad(np.atleast_1d(np.asarray(a, dtype=float))) for a in (heading_deg, pitch_deg, roll_deg))
    out = []
    for hh, pp, rr in zip(*np.broadcast_arrays(h, p, r)):
        Rz = np.array([[math.cos(hh), -math.sin(hh), 0.0], [math.sin(hh), math.cos(hh), 0.0], [0.0, 0.0, 1.0]])
        Ry = np.array([[math.cos(pp), 0.0, math.sin(pp)], [0.0, 1.0, 0.0], [-math.sin(pp), 0.0, math.cos(pp)]])
        Rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(rr), -math.sin(rr)], [0.0, math.sin(rr), math.cos(rr)]])
        enu_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        frd_flu = np.diag([1.0, -1.0, -1.0])
        out.append(enu_ned @ Rz @ Ry @ Rx @ frd_flu)
    return np.array(out)


def test_hand_attitude_convention() -> None:
    """The helper above is the documented convention: heading 90 deg points the nose east, pitch
    up raises the nose, roll right-wing-down raises the left (FLU +y) wing."""
    np.testing.assert_allclose(C_nb(90.0, 0.0, 0.0)[0] @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(C_nb(0.0, 0.0, 0.0)[0] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    assert (C_nb(0.0, 10.0, 0.0)[0] @ [1.0, 0.0, 0.0])[2] > 0.17
    assert (C_nb(0.0, 0.0, 10.0)[0] @ [0.0, 1.0, 0.0])[2] > 0.17


# ------------------------------------------------------------------------------------ a flight
T = np.array([0.0, 1.0, 2.0, 3.0])
LAT_DEG = np.array([40.0, 40.001, 40.002, 40.003])
LON_DEG = np.array([116.0, 116.001, 116.002, 116.003])
H_M = np.array([500.0, 510.0, 520.0, 530.0])
VEL = np.array([[64.0, 76.0, 0.5], [65.0, 75.0, -0.5], [66.0, 74.0, 0.0], [67.0, 73.0, 1.0]])
# the last two samples cross north: 359.95 deg and 0.02 deg
HEADING_DEG = np.array([40.0, 200.0, 359.95, 0.02])
PITCH_DEG = np.array([2.0, -3.0, 0.0, 1.0])
ROLL_DEG = np.array([3.0, -20.0, 30.0, 0.0])
BASELINE_M = 5.0  # the master sits 5 m straight below the antenna (along the ellipsoid normal)


def truth() -> tuple[NavSeries, np.ndarray]:
    llh = np.stack([np.deg2rad(LAT_DEG), np.deg2rad(LON_DEG), H_M], -1)
    master = llh - [0.0, 0.0, BASELINE_M]
    return _nav(T, llh, VEL.copy(), C_nb(HEADING_DEG, PITCH_DEG, ROLL_DEG)), master


def estimate(d_hpr_deg, d_vel_mps, d_enu_m, d_baseline_m) -> tuple[NavSeries, np.ndarray]:
    """The truth with errors added: attitude (N, 3) deg, velocity (N, 3) ENU m/s, position (N, 3)
    ENU m (converted with the radii at the true latitude and height), baseline (N,) m (the
    estimated master sits BASELINE_M + d_baseline below the estimated antenna)."""
    d_hpr, d_vel, d_enu = (np.broadcast_to(np.asarray(a, dtype=float), (T.size, 3)) for a in (d_hpr_deg, d_vel_mps, d_enu_m))
    lat = np.deg2rad(LAT_DEG)
    r_m, r_n = radii(lat)
    llh = np.stack([lat + d_enu[:, 1] / (r_m + H_M), np.deg2rad(LON_DEG) + d_enu[:, 0] / ((r_n + H_M) * np.cos(lat)), H_M + d_enu[:, 2]], -1)
    hpr = np.stack([HEADING_DEG, PITCH_DEG, ROLL_DEG], -1) + d_hpr
    master = llh - np.stack([np.zeros(T.size), np.zeros(T.size), BASELINE_M + np.broadcast_to(d_baseline_m, T.shape)], -1)
    return _nav(T, llh, VEL + d_vel, C_nb(hpr[:, 0] % 360.0, hpr[:, 1], hpr[:, 2])), master


def _check(err: dict, expected: dict) -> None:
    for k, e in expected.items():
        atol = POS_ATOL_M if k in ("lat_m", "lon_m", "h_m", "baseline_m") else 0.0
        np.testing.assert_allclose(err[k], e, rtol=REL, atol=atol, err_msg=k)


def test_constant_offsets_give_rmse_equal_to_the_offset_and_zero_std() -> None:
    """Estimate = truth + 1 m north, 0.5 m east, 0.2 m up, [0.01, -0.02, 0.03] m/s ENU, heading
    +0.1 deg (also across north: 359.95 -> 0.05 deg and 0.02 -> 0.12 deg), roll -0.05 deg, pitch
    +0.02 deg, baseline +0.03 m: every error series is that constant with the sign of
    estimate - truth, RMSE = |offset|, STD = 0."""
    tr, m_tr = truth()
    est, m_est = estimate([0.1, 0.02, -0.05], [0.01, -0.02, 0.03], [0.5, 1.0, 0.2], 0.03)
    err = M.errors(est, tr, m_est, m_tr)
    assert set(err) == set(M.KEYS)
    offsets = {"heading_deg": 0.1, "pitch_deg": 0.02, "roll_deg": -0.05, "vel_e_mps": 0.01, "vel_n_mps": -0.02,
               "vel_u_mps": 0.03, "lat_m": 1.0, "lon_m": 0.5, "h_m": 0.2, "baseline_m": 0.03}
    _check(err, {k: np.full(T.size, v) for k, v in offsets.items()})
    for k, v in offsets.items():
        rmse, std = M.rmse_std(err[k])
        tol = POS_ATOL_M if k.endswith("_m") else 1e-12  # rounding of the angle round trip, ~1e-13 deg
        assert rmse == pytest.approx(abs(v), rel=REL, abs=tol), k
        assert std == pytest.approx(0.0, abs=tol), k


def test_heading_wraps_across_north_both_ways() -> None:
    """359.95 deg estimated as 0.05 deg is +0.1 deg; 0.05 deg estimated as 359.95 is -0.1 deg."""
    tr = _nav(T[:2], np.zeros((2, 3)), np.zeros((2, 3)), C_nb([359.95, 0.05], [0.0, 0.0], [0.0, 0.0]))
    est = _nav(T[:2], np.zeros((2, 3)), np.zeros((2, 3)), C_nb([0.05, 359.95], [0.0, 0.0], [0.0, 0.0]))
    np.testing.assert_allclose(M.errors(est, tr)["heading_deg"], [0.1, -0.1], rtol=REL)
    # roll wraps too: 179.9 deg estimated as -179.9 deg is +0.2 deg (the short way round)
    tr = _nav(T[:1], np.zeros((1, 3)), np.zeros((1, 3)), C_nb([10.0], [0.0], [179.9]))
    est = _nav(T[:1], np.zeros((1, 3)), np.zeros((1, 3)), C_nb([10.0], [0.0], [-179.9]))
    np.testing.assert_allclose(M.errors(est, tr)["roll_deg"], [0.2], rtol=1e-8)


def test_varying_errors_rmse_and_std_by_hand() -> None:
    """Error series with a mean and a spread; RMSE^2 = STD^2 + mean^2 holds for each."""
    d_hpr = np.array([[0.1, 0.1, 0.5], [0.3, 0.2, -0.5], [-0.1, 0.3, 0.5], [0.1, 0.4, -0.5]])
    d_vel = np.array([[0.03, 0.0, 0.0], [0.01, 0.0, 0.0], [0.03, 0.0, 0.0], [0.01, 0.0, 0.0]])
    d_enu = np.array([[1.0, 0.0, -2.0], [-1.0, 0.0, -2.0], [1.0, 0.0, -2.0], [-1.0, 0.0, -2.0]])
    d_base = np.array([0.05, -0.02, 0.05, -0.02])
    tr, m_tr = truth()
    est, m_est = estimate(d_hpr, d_vel, d_enu, d_base)
    err = M.errors(est, tr, m_est, m_tr)
    _check(err, {"heading_deg": d_hpr[:, 0], "pitch_deg": d_hpr[:, 1], "roll_deg": d_hpr[:, 2], "vel_e_mps": d_vel[:, 0],
                 "vel_n_mps": d_vel[:, 1], "vel_u_mps": d_vel[:, 2], "lon_m": d_enu[:, 0], "lat_m": d_enu[:, 1],
                 "h_m": d_enu[:, 2], "baseline_m": d_base})
    expected = {  # (RMSE, STD) worked out by hand
        "heading_deg": (math.sqrt(0.12 / 4), math.sqrt(0.08 / 4)),         # mean 0.1: deviations 0, 0.2, -0.2, 0
        "pitch_deg": (math.sqrt(0.30 / 4), math.sqrt(0.05 / 4)),           # mean 0.25: +-0.15, +-0.05
        "roll_deg": (0.5, 0.5),                                            # mean 0
        "vel_e_mps": (math.sqrt(0.0020 / 4), 0.01),                        # mean 0.02: +-0.01
        "vel_n_mps": (0.0, 0.0),
        "lon_m": (1.0, 1.0),
        "lat_m": (0.0, 0.0),
        "h_m": (2.0, 0.0),
        "baseline_m": (math.sqrt(0.0058 / 4), 0.035),                      # mean 0.015: +-0.035
    }
    for k, (rmse, std) in expected.items():
        r, s = M.rmse_std(err[k])
        atol = POS_ATOL_M if k.endswith("_m") else 1e-12
        assert r == pytest.approx(rmse, rel=REL, abs=atol), k
        assert s == pytest.approx(std, rel=REL, abs=atol), k
        assert r * r == pytest.approx(s * s + np.mean(err[k]) ** 2, rel=1e-12, abs=1e-18), k


def test_rmse_std_is_the_population_form() -> None:
    """eq. 21 divides by n (not n - 1); an empty series gives NaN (no data, not zero)."""
    assert M.rmse_std([3.0, 4.0]) == pytest.approx((math.sqrt(12.5), 0.5), rel=1e-15)
    assert M.rmse_std([-2.0]) == (2.0, 0.0)
    r, s = M.rmse_std([])
    assert math.isnan(r) and math.isnan(s)


def test_baseline_is_the_ecef_distance_for_a_horizontal_baseline() -> None:
    """Master and antenna on one parallel at the same height: their ECEF distance is the chord
    2 (R_N + h) cos(lat) sin(dlon / 2).  Truth 5 m east, estimate at dlon for 5.02 m."""
    lat, h = math.radians(40.0), 500.0
    r = (radii(np.array(lat))[1] + h) * math.cos(lat)  # radius of the parallel

    def dlon(chord: float) -> float:
        return 2.0 * math.asin(chord / (2.0 * r))

    lon_m = math.radians(116.0)
    master = np.array([[lat, lon_m, h]])
    ant_true = np.array([[lat, lon_m + dlon(5.0), h]])
    ant_est = np.array([[lat, lon_m + dlon(5.02), h]])
    z = np.zeros((1, 3))
    C = C_nb([0.0], [0.0], [0.0])
    err = M.errors(_nav(T[:1], ant_est, z, C), _nav(T[:1], ant_true, z, C), master, master)
    assert err["baseline_m"][0] == pytest.approx(0.02, abs=1e-8)
    assert err["lon_m"][0] == pytest.approx(r * (dlon(5.02) - dlon(5.0)), abs=POS_ATOL_M)  # the arc along the parallel
    # without the master positions there is no baseline error
    assert "baseline_m" not in M.errors(_nav(T[:1], ant_est, z, C), _nav(T[:1], ant_true, z, C))


def test_errors_need_the_same_stamps() -> None:
    tr, _ = truth()
    est, _ = estimate(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="same stamps"):
        M.errors(_nav(T + 1e-3, est.llh, est.vel_n_mps, est.C_nb), tr)
    with pytest.raises(ValueError, match="same stamps"):
        M.errors(_nav(T[:3], est.llh[:3], est.vel_n_mps[:3], est.C_nb[:3]), tr)
    M.errors(_nav(T + 1e-7, est.llh, est.vel_n_mps, est.C_nb), tr)  # within 1 us is the same stamp


# ------------------------------------------------------------------------------------ segments
def test_segment_selection_is_inclusive_and_the_mean_is_over_segments() -> None:
    """t = 0..9 s, heading errors 0.01 t deg; segments A = [2, 4] (samples 2, 3, 4) and
    B = [6, 9] (6..9).  The reported value is the unweighted mean of the two segments' values,
    not the pooled RMSE of the 7 samples; keys follow M.KEYS, the baseline absent when absent."""
    t = np.arange(10.0)
    err = {"vel_n_mps": np.full(10, -0.5), "heading_deg": 0.01 * t}
    st = M.segment_stats(err, t, {"A": (2.0, 4.0), "B": (6.0, 9.0)})
    a_rmse, a_std = 0.01 * math.sqrt(29.0 / 3.0), 0.01 * math.sqrt(2.0 / 3.0)   # 2, 3, 4
    b_rmse, b_std = 0.01 * math.sqrt(230.0 / 4.0), 0.01 * math.sqrt(5.0 / 4.0)  # 6, 7, 8, 9
    seg = st["segments"]
    assert seg["A"]["rmse"]["heading_deg"] == pytest.approx(a_rmse, rel=REL)
    assert seg["A"]["std"]["heading_deg"] == pytest.approx(a_std, rel=REL)
    assert seg["B"]["rmse"]["heading_deg"] == pytest.approx(b_rmse, rel=REL)
    assert seg["B"]["std"]["heading_deg"] == pytest.approx(b_std, rel=REL)
    assert st["rmse"]["heading_deg"] == pytest.approx((a_rmse + b_rmse) / 2, rel=REL)
    assert st["std"]["heading_deg"] == pytest.approx((a_std + b_std) / 2, rel=REL)
    pooled = 0.01 * math.sqrt((29.0 + 230.0) / 7.0)
    assert abs(st["rmse"]["heading_deg"] - pooled) > 1e-3
    assert st["rmse"]["vel_n_mps"] == pytest.approx(0.5, rel=REL) and st["std"]["vel_n_mps"] == pytest.approx(0.0, abs=1e-16)
    assert list(st["rmse"]) == ["heading_deg", "vel_n_mps"] == list(st["std"])
    # a boundary a hair outside a sample excludes it
    st2 = M.segment_stats(err, t, {"A": (2.0 + 1e-9, 4.0 - 1e-9)})
    assert st2["rmse"]["heading_deg"] == pytest.approx(0.03, rel=REL)


def test_average_is_the_mean_over_bodies_of_the_keys_all_have() -> None:
    s1 = {"rmse": {"heading_deg": 0.1, "lat_m": 1.0, "baseline_m": 0.02}, "std": {"heading_deg": 0.05, "lat_m": 0.5, "baseline_m": 0.01}}
    s2 = {"rmse": {"heading_deg": 0.3, "lat_m": 2.0}, "std": {"heading_deg": 0.15, "lat_m": 1.5}}
    av = M.average([s1, s2])
    assert av == {"rmse": {"heading_deg": pytest.approx(0.2, rel=REL), "lat_m": pytest.approx(1.5, rel=REL)},
                  "std": {"heading_deg": pytest.approx(0.1, rel=REL), "lat_m": pytest.approx(1.0, rel=REL)}}
    assert M.average([s1]) == {"rmse": s1["rmse"], "std": s1["std"]}


def test_end_to_end_segment_stats_of_a_constant_offset() -> None:
    """errors() -> segment_stats() -> average() of the constant offsets: the offsets' magnitudes."""
    tr, m_tr = truth()
    est, m_est = estimate([0.1, 0.02, -0.05], [0.01, -0.02, 0.03], [0.5, 1.0, 0.2], 0.03)
    st = M.segment_stats(M.errors(est, tr, m_est, m_tr), T, {"X": (0.0, 1.0), "Y": (2.0, 3.0)})
    av = M.average([st, st])
    expected = {"heading_deg": 0.1, "pitch_deg": 0.02, "roll_deg": 0.05, "vel_e_mps": 0.01, "vel_n_mps": 0.02,
                "vel_u_mps": 0.03, "lat_m": 1.0, "lon_m": 0.5, "h_m": 0.2, "baseline_m": 0.03}
    assert list(av["rmse"]) == list(M.KEYS)
    for k, v in expected.items():
        assert av["rmse"][k] == pytest.approx(v, rel=REL, abs=POS_ATOL_M if k.endswith("_m") else 0.0), k
        assert av["std"][k] == pytest.approx(0.0, abs=POS_ATOL_M), k


def _honest_runs(rng: np.random.Generator, trials: int, runs: int, n: int, phi: float) -> np.ndarray:
    """Normalized errors (trials, runs, n) of an honest sigma: stationary AR(1) in time with unit
    variance and lag-one correlation ``phi`` (1: constant over the run), independent across runs."""
    from scipy.signal import lfilter

    if phi >= 1.0:
        return np.repeat(rng.standard_normal((trials, runs, 1)), n, axis=2)
    xi = rng.standard_normal((trials, runs, n))
    xi[..., 0] /= np.sqrt(1.0 - phi ** 2)  # the stationary start
    return lfilter([np.sqrt(1.0 - phi ** 2)], [1.0, -phi], xi, axis=-1)


@pytest.mark.parametrize("runs", [2, 3, 10])
def test_anees_bounds_hold_whatever_the_time_correlation(runs: int) -> None:
    """An honest sigma's ANEES pooled over the runs (M.consistency per run, M.average_consistency)
    falls outside M.nees_bounds in at most 2.5 % of experiments on each side, from white errors to
    errors constant over each run (where the bound is exact: chi^2(R) / R); 4000 experiments per
    correlation, the allowance 3 binomial sigmas (0.0074)."""
    rng = np.random.default_rng(7)
    trials, n = 4000, 200
    tol = 3.0 * np.sqrt(0.025 * 0.975 / trials)
    lo, hi = M.nees_bounds(runs)
    sig = np.full((n, 9), 2.0)
    for phi in (0.0, 0.98, 0.999, 1.0):
        z = _honest_runs(rng, trials, runs, n, phi)
        # the library's path for a few experiments: each run's consistency, pooled, judged
        for t in range(3):
            pooled = M.average_consistency([M.consistency(np.repeat(2.0 * z[t, r][:, None], 9, axis=1), sig) for r in range(runs)])
            assert pooled["nees"]["rot_e"] == pytest.approx(np.mean(z[t] ** 2), rel=1e-12)
            assert M.anees_in_bounds(pooled["nees"], runs)["rot_u"] == bool(lo <= np.mean(z[t] ** 2) <= hi)
        anees = np.mean(z ** 2, axis=(1, 2))  # (trials,)
        inside = M.anees_in_bounds({str(i): float(a) for i, a in enumerate(anees)}, runs)
        out = np.array([not inside[str(i)] for i in range(trials)])
        above, below = np.mean(out & (anees > hi)), np.mean(out & (anees < lo))
        assert above <= 0.025 + tol and below <= 0.025 + tol, (phi, above, below)
        if phi >= 1.0:  # exact there: not conservative
            assert above >= 0.025 - tol and below >= 0.025 - tol, (above, below)


def test_anees_bounds_flag_an_optimistic_sigma() -> None:
    """Errors constant over each run and 1.5x their sigma (ANEES 2.25): over 30 runs the pooled
    ANEES is outside the bounds in P(chi^2(30) > 30 * 1.566 / 2.25) = 0.89 of the experiments; over
    3 runs, where the bounds are [0.07, 3.12], in only P(chi^2(3) > 3 * 3.12 / 2.25) = 0.24."""
    rng = np.random.default_rng(8)
    for runs, expected in ((30, 0.89), (3, 0.24)):
        anees = np.mean((1.5 * _honest_runs(rng, 4000, runs, 10, 1.0)) ** 2, axis=(1, 2))
        inside = M.anees_in_bounds({str(i): float(a) for i, a in enumerate(anees)}, runs)
        flagged = 1.0 - np.mean(list(inside.values()))
        assert flagged == pytest.approx(expected, abs=0.03), runs
