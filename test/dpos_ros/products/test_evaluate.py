"""The evaluation against the truth (dpos_ros.products.evaluate): the truth read a part at a
time and the rows a block at a time give the metrics of the whole series at once (:func:`_reference`,
[Gong2018] eq. 21 on every row), also with a gap in the truth or a truth topic missing, and with
the truth held in memory (a simulated session)."""

from __future__ import annotations

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core.config import load_aircraft
from dpos_core.ta import metrics as M
from dpos_core.ta.pipeline import TASettings
from dpos_ros.io import bag
from dpos_ros.io import session as S
from dpos_ros.products import evaluate as E
from dpos_ros.products import report as P
from dpos_ros.products import rows
from dpos_ros.products.antenna import AntennaSolution
from dpos_ros.products.solve import solve

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


def _reference(sess: S.RecordedSession, antennas: dict[str, AntennaSolution]) -> dict[str, dict]:
    """The metrics of every row at once against ``sess``'s truth in memory (the test's oracle):
    RMSE/STD per imaging segment ([Gong2018] eq. 21), the consistency, the error series."""
    segs = sess.imaging_segments() or {"session": (float(sess.master.t_s[0]), float(sess.master.t_s[-1]))}
    tm = sess.truth.get("master")
    out = {}
    for name, a in antennas.items():
        tr = sess.truth.get(f"antenna/{name}")
        if a.rows is None or tr is None:
            continue
        b = a.block()
        t = b.traj.t_s
        idx = np.searchsorted(tr.t_s, t)
        ok = (idx < tr.t_s.size) & (np.abs(tr.t_s[np.clip(idx, 0, tr.t_s.size - 1)] - t) < 1e-6)
        est, tru = b.traj.select(ok), tr.select(idx[ok])
        m_est = m_true = None
        if tm is not None:
            m_est, m_true = P.interp_llh(sess.master.t_s, sess.master.llh, est.t_s), P.interp_llh(tm.t_s, tm.llh, est.t_s)
        err = M.errors(est, tru, m_est, m_true)
        sel = np.zeros(est.t_s.size, dtype=bool)
        for t_a, t_b in segs.values():
            sel |= (est.t_s >= t_a) & (est.t_s <= t_b)
        out[name] = {**M.segment_stats(err, est.t_s, segs), "errors": err, "t_s": est.t_s,
                     "consistency": M.consistency(M.state_errors(est, tru)[sel], b.sigma[ok][sel])}
    return out


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """The sample read whole (its truth in memory) and aligned (URTSS), its antennas' rows also
    copied to RowStores spilled to files, in pieces of 1000 rows."""
    sess = S.read_session(SAMPLE)
    aircraft = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
    ants, _ = solve(sess, aircraft, TASettings(method="urtss"))
    d = tmp_path_factory.mktemp("rows")
    streamed = {}
    for name, a in ants.items():
        assert a.rows is not None
        st = rows.RowStore(d / name)
        for i0 in range(0, a.rows.n, 1000):
            st.append(**a.rows.rows(i0, i0 + 1000))
        streamed[name] = AntennaSolution(name, a.sub_imu, a.status, st, cg=a.cg)
    meta = bag.topics_and_duration(SAMPLE)
    assert meta is not None
    return sess, ants, streamed, set(meta[0])


def _streamed_session() -> S.RecordedSession:
    return S.read_session(SAMPLE, keep=lambda t: False)


def _assert_same(got: dict, want: dict) -> None:
    assert list(got) == list(want) and got
    for name in want:
        g, w = got[name], want[name]
        for part in ("rmse", "std"):
            assert g[part].keys() == w[part].keys()
            for k in w[part]:
                assert g[part][k] == pytest.approx(w[part][k], rel=1e-12, abs=1e-300), (name, part, k)
            for seg in w["segments"]:
                for k in w[part]:
                    assert g["segments"][seg][part][k] == pytest.approx(w["segments"][seg][part][k], rel=1e-12), (name, seg, part, k)
        assert g["consistency"]["n"] == w["consistency"]["n"] > 0
        for part in ("within_2sigma", "nees"):
            for k in M.CONS_KEYS:
                assert g["consistency"][part][k] == pytest.approx(w["consistency"][part][k], rel=1e-12), (name, part, k)


@pytest.mark.parametrize("batch_bytes, row_block", [(2**24, 2**16), (2**15, 333)])
def test_evaluation_a_part_at_a_time_is_the_whole_series(solved, monkeypatch, batch_bytes: int, row_block: int) -> None:
    sess, ants, streamed, topics = solved
    monkeypatch.setattr(S, "STREAM_BATCH_BYTES", batch_bytes)  # many parts of the truth
    monkeypatch.setattr(rows, "ROW_BLOCK", row_block)  # the rows in many blocks
    monkeypatch.setattr(E, "PLOT_POINTS", 700)
    seen = []
    real = E.truth_parts

    def counting(*a, **k):
        for p in real(*a, **k):
            seen.append(p)
            yield p

    monkeypatch.setattr(E, "truth_parts", counting)
    want = _reference(sess, ants)
    s2 = _streamed_session()
    got = E.evaluate(s2, streamed, topics)
    assert (len(seen) > 5) == (batch_bytes < 2**20)
    _assert_same(got, want)
    assert "baseline_m" in got["ant_r"]["rmse"]
    assert not [w for w in s2.warnings if w.startswith("evaluation")]
    for name, g in got.items():  # the figure's series: every step-th row
        step = g["plot_step"]
        assert step == -(-streamed[name].rows.n // 700) > 1
        assert np.array_equal(g["t_s"], want[name]["t_s"][::step])
        assert np.array_equal(g["errors"]["heading_deg"], want[name]["errors"]["heading_deg"][::step])
    metrics = E.evaluation_metrics(s2, got, "urtss", {"processing_s": 1.0, "data_s": 2.0})
    assert metrics["evaluation"]["path"] == "streaming"
    ref = P.metrics_json(sess, {"urtss": (want, {"processing_s": 1.0, "data_s": 2.0})}, runs=1)
    for k in M.KEYS:
        assert metrics["methods"]["urtss"]["mean"]["rmse"][k] == pytest.approx(ref["methods"]["urtss"]["mean"]["rmse"][k], rel=1e-12)


def test_parts_of_one_topic_each_the_main_truth_first(solved, monkeypatch) -> None:
    """A spill's truth comes a topic's block at a time (evaluate_stream._spill_blocks): parts of one
    topic each, here the main POS's truth before the antennas' - the baseline of the rows then
    needs the main truth read before any antenna started (it was cut to its last sample: metres)."""
    sess, ants, streamed, topics = solved
    monkeypatch.setattr(S, "STREAM_BATCH_BYTES", 2**15)
    real = E.truth_parts

    def one_topic_each(*a, **k):
        for p in real(*a, **k):
            for topic in sorted(p, key=lambda t: t != "/truth/master"):
                yield {topic: p[topic]}

    monkeypatch.setattr(E, "truth_parts", one_topic_each)
    want = _reference(sess, ants)
    s2 = _streamed_session()
    got = E.evaluate(s2, streamed, topics)
    _assert_same(got, want)
    assert 0 < got["ant_r"]["rmse"]["baseline_m"] < 0.01


def test_a_gap_in_the_truth(solved, monkeypatch) -> None:
    """Rows without a truth sample are left out (counted in a warning), the others evaluated as the whole series."""
    sess, ants, streamed, topics = solved
    monkeypatch.setattr(S, "STREAM_BATCH_BYTES", 2**15)
    real = E.truth_parts
    cut = (10.0, 17.5)

    def gapped(*a, **k):
        for p in real(*a, **k):
            r = p.get("/truth/antenna/ant_r")
            if r is not None:
                p["/truth/antenna/ant_r"] = r[(r[:, 0] < cut[0]) | (r[:, 0] > cut[1])]
            yield p

    monkeypatch.setattr(E, "truth_parts", gapped)
    tr = sess.truth["antenna/ant_r"]
    sess_cut = S.RecordedSession(**{**sess.__dict__, "truth": {**sess.truth, "antenna/ant_r": tr.select((tr.t_s < cut[0]) | (tr.t_s > cut[1]))}})
    want = _reference(sess_cut, ants)
    s2 = _streamed_session()
    got = E.evaluate(s2, streamed, topics)
    _assert_same(got, want)
    assert got["ant_r"]["consistency"]["n"] < got["ant_l"]["consistency"]["n"]
    (w,) = [w for w in s2.warnings if w.startswith("evaluation")]
    t = streamed["ant_r"].rows.read("t_s")
    assert f"antenna ant_r: {int(np.sum((t >= cut[0]) & (t <= cut[1])))} of {t.size} rows have no truth sample" in w


def test_missing_truth_topics(solved) -> None:
    """An antenna without its truth is named and not evaluated; without /truth/master no baseline."""
    sess, ants, streamed, topics = solved
    s2 = _streamed_session()
    got = E.evaluate(s2, streamed, topics - {"/truth/antenna/ant_l", "/truth/master"})
    assert list(got) == ["ant_r"] and "baseline_m" not in got["ant_r"]["rmse"]
    assert any("no /truth/antenna/ant_l in the recording" in w for w in s2.warnings)
    no_master = S.RecordedSession(**{**sess.__dict__, "truth": {k: v for k, v in sess.truth.items() if k != "master"}})
    _assert_same(got, {"ant_r": _reference(no_master, ants)["ant_r"]})
    assert E.evaluate(_streamed_session(), streamed, {t for t in topics if not t.startswith("/truth/")}) == {}


def test_truth_held_in_memory_is_the_recordings(solved, monkeypatch) -> None:
    """A session whose truth is in memory (dpos-eval's simulated one: ``topics`` None) gives the
    metrics of the truth read from the recording a part at a time, and the per-row normalized
    squared errors when asked (dpos-eval --mismatch's ANEES over runs)."""
    sess, ants, streamed, topics = solved
    monkeypatch.setattr(S, "STREAM_BATCH_BYTES", 2**15)
    s1 = S.RecordedSession(**{**sess.__dict__, "warnings": []})
    held = E.evaluate(s1, ants, keep_nsq=True)
    from_file = E.evaluate(_streamed_session(), streamed, topics)
    _assert_same(held, from_file)
    want = _reference(sess, ants)
    for name, g in held.items():
        assert g["nsq"].shape == (g["consistency"]["n"], 9)
        assert np.mean(g["nsq"][:, 2]) == pytest.approx(want[name]["consistency"]["nees"]["rot_u"], rel=1e-12)
    assert "nsq" not in from_file["ant_r"]


def test_moments_are_rmse_std() -> None:
    rng = np.random.default_rng(5)
    e = 3.0 + 1e-4 * rng.standard_normal((1000, 2))  # a mean 10^4 times the STD: STD from the merged deviations
    m = E._Moments(2)
    for a, b in ((0, 1), (1, 400), (400, 400), (400, 1000)):
        m.add(e[a:b])
    r, s = m.rmse_std()
    for j in range(2):
        want = M.rmse_std(e[:, j])
        assert r[j] == pytest.approx(want[0], rel=1e-13) and s[j] == pytest.approx(want[1], rel=1e-12)
    assert np.all(np.isnan(E._Moments(3).rmse_std()[0]))


def test_truth_cleaner_is_the_readers_cleaning() -> None:
    """Part by part, the cleaning of io.session._clean of the whole series (out of order within a
    part, duplicates within and across parts, NaN rows); a sample older than an earlier part's is dropped."""
    t = np.array([5, 1, 2, 2, 3, 4, 4, 6, 7, 9, 8, 10], dtype=np.int64) * 10
    v = np.arange(t.size, dtype=float)[:, None].repeat(2, 1)
    v[8, 1] = np.nan
    parts = [(0, 5), (5, 7), (7, 12)]
    want_t, want_v = S._clean("x", t[np.argsort(t, kind="stable")], v[np.argsort(t, kind="stable")], [])
    c = E._TruthCleaner("x")
    got = [c(t[a:b], v[a:b]) for a, b in parts]
    gt = np.concatenate([g[0] for g in got])
    # part 0 holds 5 (and 1, 2, 2, 3): sorted in it; part 1's 4, 4 come after 5 was read: older, dropped
    assert np.array_equal(gt, [10, 20, 30, 50, 60, 80, 90, 100])
    assert c.unsorted == 2 and c.dup == 1 and c.older == 2 and c.nan == 1
    assert set(gt) <= set(want_t.tolist())
    assert any("older than one read before" in w for w in c.warnings())
    c2 = E._TruthCleaner("y")  # in order across parts: exactly _clean's
    ts = np.sort(t)
    vs = v[np.argsort(t, kind="stable")]
    got2 = [c2(ts[a:b], vs[a:b]) for a, b in ((0, 2), (2, 5), (5, 12))]  # duplicates across parts
    assert np.array_equal(np.concatenate([g[0] for g in got2]), want_t)
    assert np.array_equal(np.concatenate([g[1] for g in got2]), want_v)
