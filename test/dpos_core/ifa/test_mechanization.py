"""The master mechanization with IFA feedback (dpos_core.ifa.mechanization).

Its navigation must equal the aligner's closed-loop strapdown (InFlightAligner, pipeline.run)
whatever the order in which IMU samples, corrections and bias compensations reach it: feedback
for a sample not integrated yet is kept pending and applied exactly there, feedback for a stored
sample re-integrates the ring; only feedback older than the ring (or at a sample the master never
integrated) is lost, and that is counted.
"""

from __future__ import annotations

import numpy as np
import pytest
from ifa_support import llh_err_m, truth_initial  # test/support/ifa_support.py
from jittered_master import jittered_master  # test/support/jittered_master.py

from dpos_core.ifa.mechanization import (
    MasterMechanization,
    level_from_specific_force,
)
from dpos_core.ifa.model import GnssFix, IfaFilterConfig
from dpos_core.ifa.pipeline import InFlightAligner, advance, fix_at, run  # advance: how run() drives the aligner
from dpos_core.series import ImuSeries, NavSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState
from dpos_core.units import DEG


def _assert_nav_equal(a: NavSeries, b: NavSeries, what: str) -> float:
    """a == b to 1e-9 m / 1e-9 m/s / 1e-12 (quaternion): returns the largest position difference [m]."""
    np.testing.assert_array_equal(a.t_s, b.t_s)
    pos = llh_err_m(a.llh, b.llh)
    assert pos.max(initial=0.0) < 1e-9, (what, pos.max(), a.t_s[np.argmax(pos)])
    assert np.abs(a.vel_n_mps - b.vel_n_mps).max(initial=0.0) < 1e-9, what
    assert np.abs(a.q_nb - b.q_nb).max(initial=0.0) < 1e-12, what
    return float(pos.max(initial=0.0))


# ----------------------------------------------------------------------------- stored samples (master ahead)


def test_master_mechanization_equals_the_aligner_closed_loop() -> None:
    """Random IMU batches, the master running ahead of delayed corrections and bias compensations:
    after each correction the re-integrated navigation equals InFlightAligner's (and run's)."""
    ss = SimulatedSession(load_scenario("paper_ifa"), 3, duration_s=40.0)
    imu, g = ss.master_imu(), ss.gnss()
    init = truth_initial(ss, 60.0)
    lever = ss.scenario.aircraft.gnss_lever_arm_m
    cfg = IfaFilterConfig(use_reported_sigma=True)
    res = run(imu, g, lever, cfg, "add2", init)
    al = InFlightAligner(init, lever, cfg, "add2", float(np.median(np.diff(imu.t_s))))
    mm = MasterMechanization(init, ring_s=5.0)
    rng = np.random.default_rng(0)
    n, i, ia = imu.t_s.size, 0, 0
    fake_bias = (np.array([1e-6, -2e-6, 3e-6]), np.array([1e-4, 2e-4, -3e-4]))
    for j in range(g.t_s.size):
        fix = GnssFix(g.t_s[j], g.llh[j], g.pos_sigma_m[j], g.vel_n_mps[j], g.vel_sigma_mps[j])
        i1 = int(np.searchsorted(imu.t_s, fix.t_s + 0.005, side="right"))
        al.propagate(imu.t_s[ia:i1], imu.omega_radps[ia:i1], imu.f_mps2[ia:i1])
        ia = i1
        al.update(fix)
        if j == 20:  # a bias compensation from here on, in the aligner and in the master
            al.model.gyro_bias_comp, al.model.accel_bias_comp = fake_bias
        target = min(n, i1 + int(rng.integers(1, 150)))
        while i < target:
            b = min(int(rng.integers(1, 40)), target - i)
            mm.add(imu.t_s[i:i + b], imu.omega_radps[i:i + b], imu.f_mps2[i:i + b])
            i += b
        if j == 20:
            assert mm.set_bias(al.nav.t_s, *fake_bias) is None
        assert mm.correct(al.nav) is None
        nav = mm.nav()
        k = np.searchsorted(nav.t_s, al.nav.t_s - 1e-9)
        assert abs(nav.t_s[k] - al.nav.t_s) < 1e-9
        assert llh_err_m(nav.llh[k], al.nav.llh) < 1e-9
        if j < 20:  # no bias yet: the stored samples up to the next epoch are run()'s too
            k1 = int(np.searchsorted(nav.t_s, g.t_s[j + 1] - 1e-9))
            assert k1 > k + 1
            r = np.searchsorted(res.t_s, nav.t_s[k:k1])
            assert np.all(llh_err_m(nav.llh[k:k1], res.llh[r]) < 1e-9)
            assert np.abs(nav.q_nb[k:k1] - res.q_nb[r]).max() < 1e-12
            assert np.abs(nav.vel_n_mps[k:k1] - res.vel_n_mps[r]).max() < 1e-9
    if i < n:
        mm.add(imu.t_s[i:], imu.omega_radps[i:], imu.f_mps2[i:])
    al.propagate(imu.t_s[ia:], imu.omega_radps[ia:], imu.f_mps2[ia:])
    s, f = mm.state, al.nav
    assert s.t_s == f.t_s and llh_err_m(s.llh, f.llh) < 1e-9
    assert np.abs(s.q_nb - f.q_nb).max() < 1e-12 and np.abs(s.vel_n_mps - f.vel_n_mps).max() < 1e-9
    # every correction but the one at the last sample came after later samples: late, none lost
    assert mm.corrections == g.t_s.size and mm.corrections_late == g.t_s.size - 1 and mm.corrections_lost == 0
    # the ring keeps ~ring_s seconds; an old correction is lost with a reason (counted), nothing changes
    warning = mm.correct(NavState(1.0, f.q_nb, f.vel_n_mps, f.llh))
    assert warning is not None and "older than the stored samples" in warning
    assert mm.corrections_lost == 1 and "t=1.000000 s" in mm.last_lost
    assert llh_err_m(mm.state.llh, f.llh) < 1e-9
    # bad IMU input: dropped with warnings, good samples kept
    t_last = mm.t_s
    _, keep, warnings = mm.add([t_last + 0.01, t_last + 0.01, t_last + 0.005, t_last + 0.02],
                               [[0, 0, 0], [0, 0, 0], [0, 0, 0], [np.nan, 0, 0]], np.zeros((4, 3)))
    assert keep.tolist() == [True, False, False, False]
    assert len(warnings) == 3 and "duplicate" in " ".join(warnings) and "out-of-order" in " ".join(warnings)
    assert "non-finite" in " ".join(warnings)


# ----------------------------------------------------------------------------- any order


class _Reference:
    """The aligner over a jittered session, as pipeline.run drives it (samples up to the last one at
    or before each fix): its navigation before (``pre``) and after (``post``) each epoch's feedback,
    and the feedback an ifa_node publishes: corrections (state at the epoch sample) and, from the
    alignment on, bias compensations stamped there."""

    def __init__(self, duration_s: float, seed: int) -> None:
        jm = jittered_master(duration_s, seed)
        self.jm = jm
        self.imu: ImuSeries = jm.imu(jm.start_ns)
        self.gnss = jm.gnss_from(jm.start_ns)
        self.initial = truth_initial(jm.session, 30.0)
        self.lever = jm.session.scenario.aircraft.gnss_lever_arm_m
        self.cfg = IfaFilterConfig()
        imu, cfg = self.imu, self.cfg
        al = InFlightAligner(self.initial, self.lever, cfg, "add2", float(np.median(np.diff(imu.t_s))))
        chunks: list[NavSeries] = []
        self.corrections: list[NavState] = []
        self.biases: list[tuple[float, np.ndarray, np.ndarray]] = []
        i = 0
        t, om, fb = imu.t_s, imu.omega_radps, imu.f_mps2
        for j in range(self.gnss.t_s.size):
            fix = fix_at(self.gnss.t_s[j], self.gnss, j, cfg)
            i = advance(al, t, om, fb, i, fix.t_s, chunks)  # as run(): the samples up to the fix, time updates alone
            al.update(fix)
            self.corrections.append(al.nav)
            if al.model.feed_biases:
                self.biases.append((al.nav.t_s, al.model.gyro_bias_comp.copy(), al.model.accel_bias_comp.copy()))
        advance(al, t, om, fb, i, float(t[-1]), chunks)
        self.pre = NavSeries.concatenate([NavSeries(c.t_s, c.q_nb.copy(), c.vel_n_mps.copy(), c.llh.copy()) for c in chunks])
        post = NavSeries.concatenate(chunks)
        post = NavSeries(post.t_s, post.q_nb.copy(), post.vel_n_mps.copy(), post.llh.copy())
        k = np.searchsorted(post.t_s, [c.t_s for c in self.corrections])
        for m, c in zip(k, self.corrections):
            post.q_nb[m], post.vel_n_mps[m], post.llh[m] = c.q_nb, c.vel_n_mps, c.llh
        self.post = post
        self.aligned = al.aligned


_REF: dict[int, _Reference] = {}


def _reference(seed: int) -> _Reference:
    if seed not in _REF:
        _REF[seed] = _Reference(60.0, seed)
    return _REF[seed]


def test_reference_is_the_offline_run() -> None:
    """The reference above is pipeline.run's navigation (and the session aligns, so biases are fed back)."""
    ref = _reference(1)
    res = run(ref.imu, ref.gnss, ref.lever, ref.cfg, "add2", ref.initial)
    assert not res.rejected and res.aligned and ref.aligned and len(ref.biases) > 5
    _assert_nav_equal(NavSeries(res.t_s[1:], res.q_nb[1:], res.vel_n_mps[1:], res.llh[1:]), ref.post, "run() vs the reference")


@pytest.mark.parametrize("order_seed", [0, 1, 2, 3])
def test_feedback_in_any_order_gives_the_aligner_navigation(order_seed: int) -> None:
    """IMU batches, corrections and bias compensations delivered as a random merge of the three
    streams (each in its own order; corrections and biases are separate topics, so a bias may come
    after the next epoch's correction): corrections often arrive before their sample (pending),
    often after (stored). The ring equals the aligner's closed loop to 1e-9 m, and every sample
    integrated once the feedback before it had arrived was handed out as the aligner's."""
    ref = _reference(1)
    imu = ref.imu
    rng = np.random.default_rng(order_seed)
    batches: list[tuple[int, int]] = []
    i = 0
    while i < imu.t_s.size:
        b = int(rng.integers(1, 120))
        batches.append((i, min(i + b, imu.t_s.size)))
        i += b
    streams: dict[str, list] = {"imu": batches, "corr": list(ref.corrections), "bias": list(ref.biases)}
    events = []
    pos = {k: 0 for k in streams}
    while any(pos[k] < len(v) for k, v in streams.items()):
        left = np.array([len(v) - pos[k] for k, v in streams.items()], dtype=float)  # a uniformly random merge
        k = list(streams)[int(rng.choice(len(streams), p=left / left.sum()))]
        events.append((k, streams[k][pos[k]]))
        pos[k] += 1
    mm = MasterMechanization(ref.initial, ring_s=1000.0)
    pos_c = pos_b = 0
    published: list[NavSeries] = []
    exact: list[np.ndarray] = []  # per published sample: every earlier feedback had arrived
    # the stamp of the first feedback not delivered yet (each stream arrives in its order)
    t_corr = [c.t_s for c in ref.corrections] + [np.inf]
    t_bias = [b[0] for b in ref.biases] + [np.inf]
    max_pending = 0
    for kind, item in events:
        if kind == "imu":
            lo, hi = item
            nav, keep, warnings = mm.add(imu.t_s[lo:hi], imu.omega_radps[lo:hi], imu.f_mps2[lo:hi])
            assert keep.all() and not [w for w in warnings if "gap" not in w], warnings
            published.append(nav)
            exact.append(nav.t_s <= min(t_corr[pos_c], t_bias[pos_b]) + 1e-9)
        elif kind == "corr":
            assert mm.correct(item) is None
            pos_c += 1
        else:
            assert mm.set_bias(*item) is None
            pos_b += 1
        max_pending = max(max_pending, mm.corrections_pending)
    assert mm.corrections == len(ref.corrections) and mm.corrections_lost == 0 and mm.biases_lost == 0
    assert mm.corrections_pending == 0 and mm.biases == len(ref.biases)
    assert max_pending > 0 and mm.corrections_late > 0  # both paths were taken
    d_ring = _assert_nav_equal(mm.nav(), ref.post, "ring")
    pub = NavSeries.concatenate(published)
    ok = np.concatenate(exact)
    assert ok.sum() > 0.3 * ok.size, ok.mean()
    sel = lambda s: NavSeries(s.t_s[ok], s.q_nb[ok], s.vel_n_mps[ok], s.llh[ok])  # noqa: E731
    d_pub = _assert_nav_equal(sel(pub), sel(ref.pre), "published samples")
    print(f"order {order_seed}: {len(events)} events, max pending {max_pending}, late corrections {mm.corrections_late} "
          f"({mm.late_samples} samples), ring == aligner to {d_ring:.1e} m, {ok.sum()}/{ok.size} samples published "
          f"after their feedback == aligner to {d_pub:.1e} m")


def test_pending_correction_is_applied_inside_a_batch() -> None:
    """Every correction arrives before its sample (the ifa_node ahead of the master): the batches
    are split at the epochs, the navigation handed out is the aligner's for every sample (before
    the correction at the epoch sample), nothing is late or lost."""
    ref = _reference(1)
    imu = ref.imu
    mm = MasterMechanization(ref.initial, ring_s=1000.0)
    for c in ref.corrections:
        assert mm.correct(c) is None
    for t, g, a in ref.biases:
        assert mm.set_bias(t, g, a) is None
    assert mm.corrections_pending == len(ref.corrections) and mm.corrections == 0
    out = []
    for lo in range(0, imu.t_s.size, 250):  # 2.4 s per batch: several epochs inside each
        nav, _, _ = mm.add(imu.t_s[lo:lo + 250], imu.omega_radps[lo:lo + 250], imu.f_mps2[lo:lo + 250])
        out.append(nav)
    assert mm.corrections == len(ref.corrections) and mm.corrections_pending == 0
    assert mm.corrections_late == 0 and mm.late_samples == 0 and mm.corrections_lost == 0
    _assert_nav_equal(NavSeries.concatenate(out), ref.pre, "handed out")
    _assert_nav_equal(mm.nav(), ref.post, "ring")
    assert mm.last_correction_t_s == pytest.approx(ref.corrections[-1].t_s, abs=1e-12)


def test_lost_feedback_is_counted_never_silent() -> None:
    """A correction older than the ring, one within the ring but between samples, and a pending one
    whose sample never comes (dropped) are lost: a warning each, counted; nothing else changes."""
    ss = SimulatedSession(load_scenario("paper_ifa"), 1, duration_s=10.0)
    imu = ss.master_imu()
    init = truth_initial(ss, 0.0)
    mm = MasterMechanization(init, ring_s=2.0)
    mm.add(imu.t_s[:600], imu.omega_radps[:600], imu.f_mps2[:600])  # 6 s: the ring keeps >= 2 s
    s = mm.state
    w = mm.correct(NavState(0.5, s.q_nb, s.vel_n_mps, s.llh))
    assert w is not None and "older than the stored samples" in w and mm.corrections_lost == 1
    w = mm.correct(NavState(5.0055, s.q_nb, s.vel_n_mps, s.llh))
    assert w is not None and "not a stored IMU sample" in w and "5.000000, 5.010000" in w and mm.corrections_lost == 2
    w = mm.set_bias(0.5, np.zeros(3), np.zeros(3))
    assert w is not None and "older than the stored samples" in w and mm.biases_lost == 1
    assert mm.set_bias(7.0, [np.nan, 0, 0], np.zeros(3)) is not None and mm.biases_lost == 2
    # pending at 6.5 s, but the sample at 6.5 s is dropped by the driver: lost when the master passes it
    assert mm.correct(NavState(6.5, s.q_nb, s.vel_n_mps, s.llh)) is None and mm.corrections_pending == 1
    keep = np.ones(imu.t_s.size, dtype=bool)
    keep[649] = False
    assert imu.t_s[649] == pytest.approx(6.5)
    nav, _, warnings = mm.add(imu.t_s[600:800][keep[600:800]], imu.omega_radps[600:800][keep[600:800]], imu.f_mps2[600:800][keep[600:800]])
    assert mm.corrections_lost == 3 and mm.corrections_pending == 0 and mm.corrections == 0
    assert any("no IMU sample was integrated at its stamp" in x for x in warnings), warnings
    assert "t=6.500000 s" in mm.last_lost
    # ... and the navigation is the uncorrected one
    free = MasterMechanization(init, ring_s=2.0)
    free.add(imu.t_s[:800][keep[:800]], imu.omega_radps[:800][keep[:800]], imu.f_mps2[:800][keep[:800]])
    assert llh_err_m(mm.state.llh, free.state.llh) == 0.0


def test_correction_at_the_initial_state() -> None:
    """A fix between the start and the first sample gives an epoch at the initial state's stamp: its
    correction restarts the mechanization from the corrected initial state (before or after the
    first samples are integrated); the same as correcting before integrating anything."""
    ss = SimulatedSession(load_scenario("paper_ifa"), 1, duration_s=3.0)
    imu = ss.master_imu()
    init = truth_initial(ss, 20.0)
    fixed = truth_initial(ss, 0.0)
    a = MasterMechanization(init)
    assert a.correct(fixed) is None
    nav_a, _, _ = a.add(imu.t_s, imu.omega_radps, imu.f_mps2)
    b = MasterMechanization(init)
    b.add(imu.t_s[:50], imu.omega_radps[:50], imu.f_mps2[:50])
    assert b.correct(fixed) is None and b.corrections_late == 1 and b.late_samples == 50
    b.add(imu.t_s[50:], imu.omega_radps[50:], imu.f_mps2[50:])
    assert a.corrections == b.corrections == 1 and a.corrections_late == 0
    _assert_nav_equal(a.nav(), b.nav(), "initial correction before / after")
    ref = MasterMechanization(fixed)
    ref_nav, _, _ = ref.add(imu.t_s, imu.omega_radps, imu.f_mps2)
    _assert_nav_equal(nav_a, ref_nav, "corrected start")


def test_level_from_specific_force() -> None:
    """Pitch and roll of a tilted body at rest from its specific force (FLU, +g up)."""
    from dpos_core.frames import C_nb_from_hpr

    for hpr_deg in ([30.0, 8.0, -5.0], [200.0, -10.0, 10.0], [0.0, 0.0, 0.0]):
        C_nb = C_nb_from_hpr(*(np.asarray(hpr_deg) * DEG))
        f_b = C_nb.T @ np.array([0.0, 0.0, 9.81])
        pitch, roll = level_from_specific_force(f_b)
        assert pitch / DEG == pytest.approx(hpr_deg[1], abs=1e-9) and roll / DEG == pytest.approx(hpr_deg[2], abs=1e-9)
    with pytest.raises(ValueError, match="too small"):
        level_from_specific_force([0.0, 0.0, 0.1])
