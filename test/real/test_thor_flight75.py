"""The main POS on a real fixed-wing UAV it was not developed on: thor_flight75 (University of
Minnesota "Thor", 50 Hz MEMS IMU, 1 Hz GPS, the onboard 15-state EKF as a comparison - not a
truth; MIT licence, data/real/thor_flight75/README.md and LICENSE).

The run as #31 sets it (the peer's settings): the IMU samples with the onboard biases added back, every new GPS fix from the first at 22 s, sigmas
3 / 6 m and 0.5 / 1.0 m/s, no lever arm, the ``automotive_mems`` preset (no datasheet) and the
defaults - the settings of walk_0827, only the installation differs - the start
at the first fix on the ground (``start(level="auto")``); attitude scored 271-577 s against the
onboard EKF; three 30 s outages 200, 350 and 500 s after the first fix, scored against the
withheld fixes.  Figures (docs/ifa.md, beside the peer's) are printed with ``-s``."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core import earth
from dpos_core.config.sensors import imu_model
from dpos_core.frames import hpr_from_C_nb
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.ifa.pipeline import run
from dpos_core.ifa.reference import start
from dpos_core.ifa.smoother import as_result, smooth
from dpos_core.ifa.standstill import detect_standstill
from dpos_core.series import GnssSeries, ImuSeries

MAT = REPO / "data" / "real" / "thor_flight75" / "thor_flight75_WaypointTracker_150squareWaypointNew_2012_10_10.mat"


def _load():
    import scipy.io

    d = scipy.io.loadmat(MAT, squeeze_me=True, struct_as_record=False)["flight_data"]
    t = np.asarray(d.time, dtype=float)
    # the logged rates and specific forces have the onboard EKF's bias estimates removed: added back
    # (as the peer's loader does), so that nothing of the onboard solution enters; body FRD -> FLU
    raw = {k: np.asarray(getattr(d, k), dtype=float) + np.asarray(getattr(d, k + "_bias"), dtype=float)
           for k in ("p", "q", "r", "ax", "ay", "az")}
    om = np.column_stack([raw["p"], -raw["q"], -raw["r"]])
    f = np.column_stack([raw["ax"], -raw["ay"], -raw["az"]])
    k = np.flatnonzero(np.r_[False, np.diff(np.asarray(d.GPS_TOW, dtype=float)) > 0] & (t > 22.0))  # each new fix
    llh = np.column_stack([np.radians(d.lat[k]), np.radians(d.lon[k]), np.asarray(d.alt, dtype=float)[k]])
    vel = np.column_stack([d.ve[k], d.vn[k], -np.asarray(d.vd, dtype=float)[k]])
    n = k.size
    gnss = GnssSeries(t[k], llh, np.tile([3.0, 3.0, 6.0], (n, 1)), vel, np.tile([0.5, 0.5, 1.0], (n, 1)))
    onboard = np.degrees(np.column_stack([d.psi, d.theta, d.phi]).astype(float))  # heading, pitch, roll
    return ImuSeries(t, om, f), gnss, t, onboard


def _sel(g: GnssSeries, m: np.ndarray) -> GnssSeries:
    return GnssSeries(g.t_s[m], g.llh[m], g.pos_sigma_m[m], g.vel_n_mps[m], g.vel_sigma_mps[m])


def _config(**kw) -> IfaFilterConfig:
    """The filter settings of every real automotive MEMS recording (data/real/walk_0827/ifa_node.yaml):
    the ``automotive_mems`` preset and the defaults, with this receiver's sigmas."""
    return IfaFilterConfig(imu=imu_model({"preset": "automotive_mems"}, "thor_flight75"), gnss_pos_sigma_m=(3.0, 3.0, 6.0),
                           gnss_vel_sigma_mps=(0.5, 0.5, 1.0), **kw)


@pytest.fixture(scope="module")
def thor():
    imu, gnss, t, onboard = _load()
    cfg = _config()
    t0 = float(gnss.t_s[0])
    outages = [(t0 + s, t0 + s + 30.0) for s in (200.0, 350.0, 500.0)]
    keep = np.ones(gnss.t_s.size, dtype=bool)
    for a, b in outages:
        keep &= ~((gnss.t_s >= a) & (gnss.t_s < b))
    out, smoothed = {}, {}
    for name, g in (("all", gnss), ("outages", _sel(gnss, keep))):
        init, lv = start(imu, g, 0.0, heading_rad=0.0, level="auto", imu_model=cfg.imu)
        c = cfg if lv is None or lv.sigma_rad is None else replace(cfg, level_sigma_deg=max(cfg.level_sigma_deg, np.degrees(lv.sigma_rad)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run(imu, g, np.zeros(3), c, "add2", init, record_smoother=True)
        out[name] = res
        smoothed[name] = as_result(res, smooth(res, imu).nav)
    return imu, gnss, t, onboard, outages, out, smoothed


def _attitude_minus_onboard(res, t, onboard):
    m = (res.t_s >= 271.0) & (res.t_s <= 577.0)
    d = np.degrees(hpr_from_C_nb(res.C_nb[m])) - onboard[np.searchsorted(t, res.t_s[m])]
    d[:, 0] = (d[:, 0] + 180.0) % 360.0 - 180.0
    return d


def test_attitude_against_the_onboard_ekf(thor):
    _, _, t, onboard, _, out, _ = thor
    for name, res in out.items():
        assert res.aligned_t_s is not None and res.restarts == 0 and not res.rejected
        d = _attitude_minus_onboard(res, t, onboard)
        p95 = np.percentile(np.abs(d), 95, axis=0)
        print(f"{name}: aligned at {res.aligned_t_s:.1f} s; heading, pitch, roll minus onboard: mean "
              f"{np.round(d.mean(axis=0), 2)}, std {np.round(d.std(axis=0), 2)}, p95 |.| {np.round(p95, 2)} deg")
        # the peer (NavEKF15, default): heading +11.74 / 1.63 / 14.33, pitch 0.00 / 0.47 / 0.93, roll -1.22 / 0.92 / 2.62;
        # measured p95 1.52 / 0.52 / 1.37 (all GPS), 1.41 / 0.67 / 1.44 deg (with the outages), ALIGNED at 220.8 s
        assert p95[0] < 2.2 and p95[1] < 1.0 and p95[2] < 2.0, p95


def _outage_figures(res, gnss, outages, label: str) -> list[tuple[float, float, float, float]]:
    """Per outage: horizontal error against the withheld fix at its end, max in it, 10 s after [m],
    and the fraction of the withheld fixes inside 3 sigma (E, N, U; the fixes' own 3 / 6 m with)."""
    tt_, P = np.array([x for x, _ in res.track]), np.array([p for _, p in res.track])
    figs = []
    for a, b in outages:
        w = (gnss.t_s >= a) & (gnss.t_s < b + 10.5)
        tt = gnss.t_s[w]
        q = np.clip(np.searchsorted(res.t_s, tt), 0, res.t_s.size - 1)
        enu = np.array([earth.enu_between(x, y) for x, y in zip(res.llh[q], gnss.llh[w])])
        e = np.hypot(enu[:, 0], enu[:, 1])
        j = np.clip(np.searchsorted(tt_, tt, side="right") - 1, 0, tt_.size - 1)
        sig = np.sqrt(np.diagonal(P[j], axis1=1, axis2=2))[:, :3]
        inside = np.all(np.abs(enu) <= 3.0 * np.sqrt(sig**2 + gnss.pos_sigma_m[w] ** 2), axis=1)[tt < b]
        end, after = e[tt < b][-1], e[np.flatnonzero(tt >= b + 9.5)[0]]
        print(f"{label} outage {a:.0f}-{b:.0f} s: at its end {end:.1f} m, max in it {e[tt < b].max():.1f} m, 10 s after {after:.2f} m; "
              f"in 3 sigma {inside.mean():.2f}")
        figs.append((end, float(e[tt < b].max()), after, float(inside.mean())))
    return figs


def test_outages_in_flight_against_the_withheld_fixes(thor):
    _, gnss, _, _, outages, out, _ = thor
    figs = _outage_figures(out["outages"], gnss, outages, "forward")
    ends, afters = [f[0] for f in figs], [f[2] for f in figs]
    # the peer (default): 242.9 / 0.67, 90.1 / 3.47, 127.2 / 1.53 m (docs/ifa.md has ours beside);
    # measured 89.9 / 0.18, 52.3 / 3.53, 25.2 / 0.50 m, every withheld fix inside 3 sigma; the bounds are
    # the figures with the standstill updates off (95.0 / 57.9 / 33.2 m): the default must not be worse
    assert ends[0] < 95.0 and ends[1] < 57.9 and ends[2] < 33.2, ends
    assert max(afters) < 5.0, afters
    assert min(f[3] for f in figs) >= 0.95, figs


def test_the_outage_drift_is_the_level_not_the_heading(thor):
    """Outage 372-402 s (ours 52.3 m, the peer's fixed-wing configuration 35.0 m; docs/ifa.md): the
    velocity error against the withheld fixes, over 296 deg of turns, is a constant acceleration
    error in the navigation frame (a tilt: ``g phi``), not a heading error (``a_h psi``, which turns
    with the specific force) nor body-fixed accelerometer biases.  Measured: +0.093 m/s^2 north
    (0.55 deg of tilt; the filter's level sigma there 0.36 / 0.39 deg), residual 0.17 m/s rms of a
    1.33 m/s change with all five terms, 0.24 m/s with the two constants alone, 1.14 m/s with the
    heading alone, 0.38 m/s with the body biases alone."""
    imu, gnss, _, _, outages, out, _ = thor
    res = out["outages"]
    a, b = outages[1]
    w = (gnss.t_s >= a) & (gnss.t_s < b)
    tt = gnss.t_s[w]
    t_last = float(res.epochs_s[res.epochs_s < a][-1])  # the last update before the outage
    q = np.searchsorted(res.t_s, np.r_[t_last, tt])
    fix_last = int(np.searchsorted(gnss.t_s, t_last))
    dv = res.vel_n_mps[q, :2] - np.vstack([gnss.vel_n_mps[fix_last, :2], gnss.vel_n_mps[w, :2]])
    y = (dv[1:] - dv[0]).T.ravel()  # (E..., N...)
    k = (res.t_s > t_last) & (res.t_s <= tt[-1] + 1e-6)
    C = res.C_nb[k]
    fn = np.einsum("kij,kj->ki", C, imu.f_mps2[np.searchsorted(imu.t_s, res.t_s[k])] - res.accel_bias_mps2)
    dt = np.diff(np.r_[t_last, res.t_s[k]])[:, None]
    one = np.ones(dt.shape[0])
    terms = {"E": np.c_[one, 0 * one], "N": np.c_[0 * one, one], "heading": np.c_[fn[:, 1], -fn[:, 0]],
             "bias x": C[:, :2, 0], "bias y": C[:, :2, 1]}
    j = np.searchsorted(res.t_s[k], tt - 1e-6)
    A = {n: np.cumsum(v * dt, axis=0)[j].T.ravel() for n, v in terms.items()}

    def fit(names: list[str]) -> tuple[np.ndarray, float]:
        M = np.column_stack([A[n] for n in names])
        x = np.linalg.lstsq(M, y, rcond=None)[0]
        return x, float(np.sqrt(np.mean((M @ x - y) ** 2)))

    x_all, r_all = fit(list(terms))
    _, r_const = fit(["E", "N"])
    _, r_head = fit(["heading"])
    _, r_bias = fit(["bias x", "bias y"])
    print(f"outage {a:.0f}-{b:.0f} s: velocity error change rms {np.sqrt(np.mean(y ** 2)):.2f} m/s; constant acceleration "
          f"E / N {x_all[0]:+.3f} / {x_all[1]:+.3f} m/s^2, heading {np.degrees(x_all[2]):+.2f} deg, body biases {np.round(x_all[3:], 3)} "
          f"m/s^2; residual rms: all {r_all:.2f}, constants alone {r_const:.2f}, heading alone {r_head:.2f}, biases alone {r_bias:.2f} m/s")
    assert r_const < 0.3 < 1.0 < r_head and r_const < 0.8 * r_bias
    assert abs(np.degrees(x_all[2])) < 1.0 and abs(x_all[1]) > 0.06


def _started_in_flight(thor, t_start_s: float):
    """The run started at the first fix after ``t_start_s`` (flying) with the onboard heading + 30 deg,
    the IMU cut at 577 s (landing; the scored span).  Returns the result, the start's level, the time
    after the start [s] of each navigation sample and its heading minus the onboard EKF's and minus
    the all-GPS run started on the ground (``thor``'s ``all``: this filter's own steady state) [deg]."""
    imu, gnss, t, onboard, _, out, _ = thor
    g = _sel(gnss, (gnss.t_s >= t_start_s) & (gnss.t_s <= 577.0))
    k = imu.t_s <= 577.0
    I = ImuSeries(imu.t_s[k], imu.omega_radps[k], imu.f_mps2[k])
    j = int(np.searchsorted(t, g.t_s[0]))
    cfg = _config()
    init, lv = start(I, g, 1e9, heading_rad=float(np.radians(onboard[j, 0] + 30.0)), level="auto", imu_model=cfg.imu)
    # a level from flight: its sigma is what the motion can leave in it (as dpos-ifa takes it)
    c = cfg if lv is None or lv.sigma_rad is None else replace(cfg, level_sigma_deg=max(cfg.level_sigma_deg, np.degrees(lv.sigma_rad)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run(I, g, np.zeros(3), c, "add2", init)
    h = np.degrees(hpr_from_C_nb(res.C_nb))[:, 0]
    ground = out["all"]
    wrap = lambda x: (x + 180.0) % 360.0 - 180.0  # noqa: E731
    d_on = wrap(h - onboard[np.searchsorted(t, res.t_s), 0])
    d_gr = wrap(h - np.degrees(hpr_from_C_nb(ground.C_nb[np.searchsorted(ground.t_s, res.t_s)]))[:, 0])
    return res, init, lv, res.t_s - init.t_s, d_on, d_gr


def _stays(tt: np.ndarray, d: np.ndarray, lim: float) -> float:
    """The time from which ``|d|`` stays below ``lim`` (to the end)."""
    out_of = np.flatnonzero(np.abs(d) >= lim)
    return float(tt[out_of[-1] + 1]) if out_of.size and out_of[-1] + 1 < tt.size else float(tt[0])


def test_started_in_flight_with_a_30_deg_heading_error(thor):
    """Started at the first fix after 300 s (flying, 20-26 m/s) with the onboard heading + 30 deg:
    the heading comes within 2 deg of the onboard EKF's and stays there (the peer: after 4 s,
    staying from 9 s; [12 s with its fixed-wing configuration]).  Beside, the heading minus this
    filter's own all-GPS run started on the ground (docs/ifa.md: the in-flight start's transient of
    -1.5 to -2 deg at 20-60 s is the accelerometer biases, 37 / 48 mg on this unit, learned in flight;
    with them known it stays within 0.9 deg of the ground run from 20 s)."""
    res, init, _, tt, d, d_gr = _started_in_flight(thor, 300.0)
    first = float(tt[np.flatnonzero(np.abs(d) < 2.0)[0]])
    win = [float(np.abs(d_gr[(tt >= a) & (tt < a + 10.0)]).max()) for a in (10.0, 20.0, 30.0, 40.0, 50.0, 60.0)]
    print(f"30 deg start at {init.t_s:.1f} s: within 2 deg of onboard after {first:.1f} s, stays within 2 deg from "
          f"{_stays(tt, d, 2.0):.1f} s, within 5 deg from {_stays(tt, d, 5.0):.1f} s; aligned "
          f"{None if res.aligned_t_s is None else round(res.aligned_t_s - init.t_s, 1)} s after the start; minus the "
          f"ground-started run: stays within 2 deg from {_stays(tt, d_gr, 2.0):.1f} s, max |.| per 10 s from 10 s "
          f"{np.round(win, 2).tolist()} deg")
    # measured: 7.0 s, staying within 5 deg from 7.0 s and within 2 deg of a comparison that is itself
    # no truth from 48.2 s; aligned 27.0 s after the start; within 2 deg of the ground run from 48.0 s
    assert res.aligned_t_s is not None and first < 15.0 and _stays(tt, d, 5.0) < 60.0 and _stays(tt, d, 2.0) < 120.0
    assert max(win[1:]) < 3.0, win


def test_started_in_flight_in_a_banked_turn(thor):
    """Started at the first fix after 450 s, in a 41 deg bank (the onboard EKF's roll; a coordinated
    turn at 16 m/s), with the onboard heading + 30 deg.  The specific force of a coordinated turn is
    along the body's vertical: the raw level is wings-level; its sigma covers the bank through the
    centripetal bound ``|w| |v| / g`` (dpos_core.ifa.standstill.start_level; the former 5.8 deg sigma
    left the filter's heading 20-40 deg off for 20 s and ALIGNED 6 deg off at 2.2 deg sigma, 3.8
    sigma later).  Measured: level sigma 40.3 deg; within 2 deg of the ground-started run from 17 s,
    ALIGNED 34 s after the start 0.1 deg from it, within 2 deg of the onboard EKF from 52 s."""
    res, init, lv, tt, d, d_gr = _started_in_flight(thor, 450.0)
    _, _, t, onboard, _, _, _ = thor
    roll_onboard = float(onboard[np.searchsorted(t, init.t_s), 2])
    print(f"30 deg start at {init.t_s:.1f} s in a {roll_onboard:.1f} deg bank: level ({lv.how}) roll {np.degrees(lv.roll_rad):.1f} deg, "
          f"sigma {np.degrees(lv.sigma_rad):.1f} deg; minus the ground-started run: stays within 2 deg from {_stays(tt, d_gr, 2.0):.1f} s; "
          f"minus onboard: from {_stays(tt, d, 2.0):.1f} s; aligned "
          f"{None if res.aligned_t_s is None else round(res.aligned_t_s - init.t_s, 1)} s after the start")
    assert lv.how == "raw" and abs(np.degrees(lv.roll_rad) - roll_onboard) < 2.0 * np.degrees(lv.sigma_rad)  # the former sigma: 7 sigma
    assert res.aligned_t_s is not None and res.restarts == 0
    assert _stays(tt, d_gr, 2.0) < 30.0 and _stays(tt, d, 2.0) < 70.0
    at = int(np.searchsorted(res.t_s, res.aligned_t_s))
    assert abs(d_gr[at]) < 2.0


def test_smoothed_bridges_the_outages_and_follows_the_onboard_attitude(thor):
    """The forward-backward (RTS) main POS (dpos-ifa --smooth) of the same runs.  Measured: at the
    outages' ends 0.7 / 2.2 / 0.7 m, max in them 10.4 / 2.2 / 1.8 m, 10 s after 0.50 / 3.01 / 0.09 m
    (forward 95.0 / 57.9 / 33.2 m at the ends; the peer's forward 242.9 / 90.1 / 127.2 m, 10 s after
    0.67 / 3.47 / 1.53 m: within the fixes' 3 m sigma), every withheld fix inside 3 sigma.  Attitude
    minus onboard, p95 of |.|, all GPS 1.19 / 0.83 / 1.57 deg (heading, pitch, roll; forward
    1.52 / 0.52 / 1.37)."""
    imu, gnss, t, onboard, outages, out, smoothed = thor
    for name, srs in smoothed.items():
        d = _attitude_minus_onboard(srs, t, onboard)
        p95 = np.percentile(np.abs(d), 95, axis=0)
        print(f"smoothed {name}: heading, pitch, roll minus onboard: mean {np.round(d.mean(axis=0), 2)}, std "
              f"{np.round(d.std(axis=0), 2)}, p95 |.| {np.round(p95, 2)} deg")
        assert p95[0] < 1.8 and p95[1] < 1.0 and p95[2] < 2.0, p95
        if name == "outages":
            figs = _outage_figures(srs, gnss, outages, "smoothed")
            assert all(f[0] < 5.0 and f[1] < 20.0 and f[2] < 4.0 for f in figs), figs
            assert min(f[3] for f in figs) >= 0.95, figs


def _inside_3sigma(res, gnss, a: float, b: float) -> float:
    """Fraction of the fixes in [a, b) (withheld in an outage) whose error (E, N, U) is inside 3 sigma
    of the run's reported covariance (its track) and the fix's own sigma."""
    w = (gnss.t_s >= a) & (gnss.t_s < b)
    tt = gnss.t_s[w]
    q = np.clip(np.searchsorted(res.t_s, tt), 0, res.t_s.size - 1)
    enu = np.array([earth.enu_between(x, y) for x, y in zip(res.llh[q], gnss.llh[w])])
    tt_, P = np.array([x for x, _ in res.track]), np.array([p for _, p in res.track])
    j = np.clip(np.searchsorted(tt_, tt, side="right") - 1, 0, tt_.size - 1)
    sig = np.sqrt(np.diagonal(P[j], axis1=1, axis2=2))[:, :3]
    return float(np.all(np.abs(enu) <= 3.0 * np.sqrt(sig**2 + gnss.pos_sigma_m[w] ** 2), axis=1).mean())


def test_honest_covariance_before_during_after_each_outage(thor):
    """#31 part 6: at least 0.95 of the errors inside 3 sigma in the 30 s before, the 30 s of and the
    30 s after each outage, forward and smoothed, with the preset alone.  Measured: 1.00 in every
    window, both (before the preset's in-motion accelerometer instability, 2 mg / 30 s: smoothed 0.31
    in the first outage, which falls in the alignment's coarse phase; docs/ifa.md)."""
    _, gnss, _, _, outages, out, smoothed = thor
    for label, res in (("forward", out["outages"]), ("smoothed", smoothed["outages"])):
        fr = [[_inside_3sigma(res, gnss, a - 30.0, a), _inside_3sigma(res, gnss, a, b), _inside_3sigma(res, gnss, b, b + 30.0)]
              for a, b in outages]
        print(f"{label} inside 3 sigma before / during / after each outage: {np.round(fr, 2).tolist()}, flight "
              f"{_inside_3sigma(res, gnss, 211.0, 577.0):.3f}")
        assert np.min(fr) >= 0.95, (label, fr)


def test_standstill_on_the_ground_before_take_off(thor):
    """#31 part 2's figures (docs/ifa.md): one-second windows from the first fix (22 s) to take-off
    (211 s).  With the ``automotive_mems`` white noise none is at rest (this unit standing is
    noisier than the class: median T 67 against the threshold 11.5); with ``consumer_mems``'s 58 of
    189 are, and their mean rate, the gyro bias from the rest, is (-1.179, +0.016, -0.017) deg/s
    FLU, the onboard EKF's mean over the ground phase (-1.189, +0.015, -0.310): the level axes agree
    to 0.01 deg/s, the heading axis (unobservable at rest for the EKF too) does not."""
    imu, gnss, t, _, _, _, _ = thor
    import scipy.io

    d = scipy.io.loadmat(MAT, squeeze_me=True, struct_as_record=False)["flight_data"]
    onboard_bias = np.degrees(np.column_stack([d.p_bias, -np.asarray(d.q_bias), -np.asarray(d.r_bias)]).astype(float))
    onboard_bias = onboard_bias[(t > 22.0) & (t < 211.0)].mean(axis=0)
    dt = float(np.median(np.diff(imu.t_s)))
    found = {}
    for preset in ("automotive_mems", "consumer_mems"):
        model = imu_model({"preset": preset}, "thor_flight75")
        rest, rates = [], []
        for a in np.arange(22.0, 211.0, 1.0):
            w = (imu.t_s > a) & (imu.t_s <= a + 1.0)
            k = max(int(np.searchsorted(gnss.t_s, a + 1.0)) - 1, 0)
            rest.append(detect_standstill(imu.omega_radps[w], imu.f_mps2[w], model, dt, gnss.vel_n_mps[k]).at_rest)
            rates.append(imu.omega_radps[w].mean(axis=0))
        found[preset] = (np.array(rest), np.degrees(np.array(rates)))
    assert not found["automotive_mems"][0].any()
    rest, rates = found["consumer_mems"]
    bias = rates[rest].mean(axis=0)
    print(f"at rest (consumer_mems noise) {rest.sum()} of {rest.size} windows; gyro bias from the rest {np.round(bias, 3)} deg/s, "
          f"onboard EKF {np.round(onboard_bias, 3)}")
    assert rest.sum() >= 30
    assert np.all(np.abs(bias[:2] - onboard_bias[:2]) < 0.03), (bias, onboard_bias)


def test_standstill_updates_on_the_ground(thor):
    """#31 part 2, the standstill updates as by default (``standstill_updates``: ZARU about the
    vertical at the GNSS epochs found at rest; docs/ifa.md) and off: run to take-off (211 s).
    The epochs at rest are the ground's stops (the detector at 10x the preset's noise: T 15-300 at
    rest, 3e3-1e5 taxiing); the gyro bias at take-off is the rest's mean rate on every axis, the
    heading axis's too (without ZARU it is 0.05 deg/s off); the level at take-off is the onboard
    EKF's within what the accelerometer bias allows; the constraint innovations are consistent."""
    imu, gnss, t, onboard, _, _, _ = thor
    m = imu.t_s <= 211.0
    I = ImuSeries(imu.t_s[m], imu.omega_radps[m], imu.f_mps2[m])
    g = _sel(gnss, gnss.t_s <= 211.0)
    found = {}
    for on in (True, False):
        cfg = _config(standstill_updates=on)
        init, lv = start(I, g, 0.0, heading_rad=0.0, level="auto", imu_model=cfg.imu)
        c = cfg if lv is None or lv.sigma_rad is None else replace(cfg, level_sigma_deg=max(cfg.level_sigma_deg, np.degrees(lv.sigma_rad)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            found[on] = run(I, g, np.zeros(3), c, "add2", init)
    res = found[True]
    rest = res.at_rest == 1.0
    # the rest's mean rate over the windows found at rest, earth rate removed (0.003 deg/s at most)
    wins = [(imu.t_s > e - 1.0) & (imu.t_s <= e) for e in res.epochs_s[rest]]
    b_rest = np.degrees(np.mean([imu.omega_radps[w].mean(axis=0) for w in wins], axis=0))
    b_on, b_off = np.degrees(res.gyro_bias_radps), np.degrees(found[False].gyro_bias_radps)
    k = int(np.searchsorted(t, res.t_s[-1]))
    lvl = np.degrees(hpr_from_C_nb(res.C_nb[-1]))[1:]
    cn = res.constraint_nis[np.isfinite(res.constraint_nis)]
    dim = (3 if c.zupt else 0) + (1 if c.zaru else 0)  # rows of the update (c: the last run's, off: the same rows)
    print(f"standstill updates on the ground: {rest.sum()} of {rest.size} epochs at rest, {sum(bool(c) for c in res.constraints)} "
          f"updated, constraint NIS mean {cn.mean():.2f} (dimension {dim}); gyro bias at take-off {np.round(b_on, 3)} deg/s (off: "
          f"{np.round(b_off, 3)}), the rest's mean rate {np.round(b_rest, 3)}; level at take-off {np.round(lvl, 2)} deg (off: "
          f"{np.round(np.degrees(hpr_from_C_nb(found[False].C_nb[-1]))[1:], 2)}), onboard {np.round(onboard[k, 1:], 2)}")
    assert rest.sum() >= 60 and not np.any(found[False].constraint_nis == found[False].constraint_nis)  # off: none applied
    assert np.all(np.abs(b_on - b_rest) < 0.01), (b_on, b_rest)
    assert abs(b_off[2] - b_rest[2]) > 0.03, (b_off, b_rest)
    assert np.all(np.abs(lvl - onboard[k, 1:]) < 2.3), (lvl, onboard[k, 1:])  # 2 asin(b / g) of the preset's 20 mg
    assert 0.5 * dim < cn.mean() < 2.0 * dim, (cn.mean(), dim)
