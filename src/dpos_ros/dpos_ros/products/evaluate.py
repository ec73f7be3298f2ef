"""The evaluation of a session's antennas against the recorded truth (design.md "Session
products", docs/long_flights.md): :func:`evaluate`, RMSE/STD per antenna ([Gong2018] eq. 21) over
the imaging segments (the whole session when none), with memory that does not grow with the flight.

The truth topics (``/truth/master`` and ``/truth/antenna/<name>`` of the estimated antennas) are
read once, a part of the file at a time in time order (:func:`dpos_ros.io._mcap.read_batches`,
:data:`dpos_ros.io.session.STREAM_BATCH_BYTES` of messages a part; a spill of transfer_align_node,
each topic's log a block at a time, the topics advancing together), and each antenna's rows from
its :class:`~dpos_ros.products.rows.RowStore` a block at a time; each row is matched to the
truth sample at its stamp (the first truth sample at or after the row's stamp, within 1 us), and
the errors of each block accumulated (a session held in memory - dpos-eval's simulated one - gives
its truth as one part):

* per imaging segment and error key (``dpos_core.ta.metrics.KEYS``) the count, the sum of the
  squared errors (RMSE) and the mean and the sum of squared deviations from it, merged block by
  block by the parallel update of Chan et al. (STD): [Gong2018] eq. 21 exactly, to rounding;
* per antenna the consistency (``metrics.consistency``): the count, the count within 2 sigma and
  the sum of e^2/sigma^2 per component, over the rows in any segment: exact sums;
* the CDVF's conjugate-gradient summary: the solver's.

What is not a sum: the error figure (``errors_<antenna>.png``) is drawn from every n-th evaluated
row (n = the rows over :data:`PLOT_POINTS`, rounded up: every row for a flight of under 100 s at
200 Hz); the per-row normalized squared errors (``nsq``, read by ``dpos-eval --mismatch`` only)
are kept only when asked.  The baseline's main-POS positions are interpolated in the main POS held
in memory and in the truth's kept from the sample before the first row still to evaluate on: the
same numbers as the whole series'.

Bad input: an estimated antenna without its truth topic is named in a warning and not evaluated;
rows without a truth sample at their stamp (the truth has a gap) are counted in a warning and the
others evaluated; the truth's samples are cleaned as the reader cleans them (sorted within a part,
duplicate stamps and NaN rows dropped, gaps counted), a sample older than one already read in an
earlier part is dropped with a warning.
"""

from __future__ import annotations

import concurrent.futures as cf
import heapq
import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.series import GAP_FACTOR, NavSeries
from dpos_core.ta import metrics as M
from dpos_core.units import FloatArray
from dpos_ros.contract import topics as T
from dpos_ros.io import _mcap, bag
from dpos_ros.io import session as io_session
from dpos_ros.io import spill as S
from dpos_ros.io.session import RecordedSession, SessionError, _compact, _decode_rows, read_session

from . import rows as R
from .antenna import AntennaSolution
from .report import interp_llh, metrics_json, plot_antenna_errors, report_md

#: the most points of an error figure (every n-th evaluated row; module docstring)
PLOT_POINTS = 20_000
#: the truth series' columns: t_s, llh (3), vel (3), q_nb (4)
_TRUTH_COLS = 11


# ------------------------------------------------------------------------------------ the truth, a part at a time


class _TruthCleaner:
    """:func:`dpos_ros.io.session._clean` of one truth topic a part at a time (module docstring)."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.last_ns: int | None = None
        self.unsorted = self.dup = self.older = self.nan = self.gaps = 0
        self.step_ns: float | None = None
        self.longest_ns = 0

    def __call__(self, t_ns: NDArray[np.int64], vals: FloatArray) -> tuple[NDArray[np.int64], FloatArray]:
        if t_ns.size == 0:
            return t_ns, vals
        if np.any(np.diff(t_ns) < 0):
            self.unsorted += int(np.sum(np.diff(t_ns) < 0))
            order = np.argsort(t_ns, kind="stable")
            t_ns, vals = t_ns[order], vals[order]
        if self.last_ns is not None:
            old = t_ns <= self.last_ns
            if old.any():
                same = t_ns[old] == self.last_ns
                self.dup += int(same.sum())
                self.older += int((~same).sum())
                t_ns, vals = t_ns[~old], vals[~old]
        dup = np.concatenate([[False], np.diff(t_ns) == 0])
        if dup.any():
            self.dup += int(dup.sum())
            t_ns, vals = t_ns[~dup], vals[~dup]
        prev = self.last_ns
        if t_ns.size:
            self.last_ns = int(t_ns[-1])  # (the last stamp read, NaN or not: a duplicate of it is dropped, as _clean does)
        bad = ~np.all(np.isfinite(vals), axis=1)
        if bad.any():
            self.nan += int(bad.sum())
            t_ns, vals = t_ns[~bad], vals[~bad]
        d = np.diff(np.concatenate([[prev], t_ns]) if prev is not None else t_ns)
        if self.step_ns is None and d.size >= 2:
            self.step_ns = float(np.median(d))  # the nominal step: the first part's median
        if self.step_ns is not None and d.size:
            self.gaps += int(np.sum(d > GAP_FACTOR * self.step_ns))
            self.longest_ns = max(self.longest_ns, int(d.max()))
        return t_ns, vals

    def warnings(self) -> list[str]:
        w = []
        if self.unsorted:
            w.append(f"{self.topic}: {self.unsorted} message(s) out of stamp order; sorted")
        if self.dup:
            w.append(f"{self.topic}: {self.dup} duplicate stamp(s) removed; the first of each kept")
        if self.older:
            w.append(f"{self.topic}: {self.older} message(s) older than one read before (out of order across the "
                     "file's parts); not evaluated against")
        if self.nan:
            w.append(f"{self.topic}: {self.nan} sample(s) with NaN/inf removed")
        if self.gaps and self.step_ns:
            w.append(f"{self.topic}: {self.gaps} gap(s) in the stamps, longest {self.longest_ns * 1e-9:.3f} s "
                     f"(nominal step {self.step_ns * 1e-9:.4f} s)")
        return w


def truth_parts(sess: RecordedSession, topics: list[str], warnings: list[str]) -> Iterator[dict[str, FloatArray]]:
    """The truth ``topics`` of ``sess``'s recording a part at a time, in time order: per part
    ``{topic: (n, 11)}`` rows ``[t_s, lat, lon, h, vel E N U, q_nb (4)]`` (times as ``sess``'s),
    cleaned (:class:`_TruthCleaner`; its warnings added to ``warnings`` at the end).  An MCAP
    recording is read a part of the file at a time; a spill (transfer_align_node's) a block of
    each topic's log at a time, the topic read least far first (:func:`_spill_blocks`; its late
    messages are not read, as the node's streaming finalize does not read them); a recording
    neither reads (several files) is read whole (one part)."""
    wanted = set(topics)
    if all(t.removeprefix("/truth/") in sess.truth for t in topics):  # held in memory (a simulated session): one part
        held = {t: sess.truth[t.removeprefix("/truth/")] for t in topics}
        yield {t: np.hstack([tr.t_s[:, None], tr.llh, tr.vel_n_mps, tr.q_nb]) for t, tr in held.items()}
        return
    path = Path(sess.path)
    cleaners = {t: _TruthCleaner(t) for t in topics}
    failed: set[str] = set()
    source: Iterator[list[tuple[str, str, object]]] | None  # per part: (topic, msgtype, messages)
    if S.is_spill(path):
        source = ([b] for b in _spill_blocks(path, topics, io_session.STREAM_BATCH_BYTES // max(1, len(topics)), warnings))
    else:
        file = bag._single_mcap(path) if (path / "metadata.yaml").is_file() else None
        parts = None if file is None else _mcap.read_batches(file, lambda t: t in wanted, io_session.STREAM_BATCH_BYTES)
        source = None if parts is None else ([(topic, msgtype, blobs) for topic, (msgtype, _, blobs) in part.items()] for part in parts)
    if source is None:
        whole = read_session(path, keep=lambda t: t in wanted)
        warnings.extend(w for w in whole.warnings if any(w.startswith(t) for t in topics))
        out = {}
        for topic in topics:
            tr = whole.truth.get(topic.removeprefix("/truth/"))
            if tr is not None:
                out[topic] = np.hstack([tr.t_s[:, None], tr.llh, tr.vel_n_mps, tr.q_nb])
        yield out
        return
    try:
        for items in source:
            out = {}
            for topic, msgtype, blobs in items:
                rows = _truth_rows(sess, topic, msgtype, blobs, cleaners[topic], failed, warnings)
                if rows is not None:
                    out[topic] = rows
            yield out
    finally:
        for c in cleaners.values():
            warnings.extend(c.warnings())


def _truth_rows(sess: RecordedSession, topic: str, msgtype: str, blobs, cleaner: _TruthCleaner, failed: set[str],
                warnings: list[str]) -> FloatArray | None:
    """One truth topic's messages ``blobs`` decoded and cleaned: rows (n, 11) as :func:`truth_parts`
    gives them, or None (none, not Odometry, or a topic that cannot be decoded: warned once, then ignored)."""
    if topic in failed or not len(blobs) or msgtype != T.ODOMETRY:
        return None
    try:
        t, v = _decode_rows(topic, msgtype, blobs, "odometry", warnings)
    except SessionError as e:
        warnings.append(f"{e}; the topic is ignored")
        failed.add(topic)
        return None
    t, v = cleaner(t, _compact("truth", t, v, sess.datum_llh))
    return np.hstack([((t - sess.t0_ns) * 1e-9)[:, None], v[:, 0:10]])


def _spill_blocks(path: Path, topics: list[str], block_bytes: int, warnings: list[str]) -> Iterator[tuple[str, str, object]]:
    """``(topic, msgtype, messages)`` of the spill ``path``'s ``topics`` (those it has), a block of
    each log at a time (:class:`dpos_ros.io.spill.LogBlocks`), always from the topic whose last
    block ends earliest: every topic's truth advances together, so that memory holds about a
    block per topic.  A last record cut short (a crash while writing) is warned about."""
    logs = S.spill_meta(path)[0]
    readers = {t: S.LogBlocks(logs[t][1], block_bytes) for t in topics if t in logs}
    its = {t: iter(r) for t, r in readers.items()}
    heap = [(-math.inf, i, t) for i, t in enumerate(readers)]
    while heap:
        _, i, topic = heapq.heappop(heap)
        block = next(its[topic], None)
        if block is None:
            if readers[topic].skipped:
                warnings.append(S.skipped_warning(topic, readers[topic].file, readers[topic].skipped))
            if readers[topic].cut_short:
                warnings.append(S.cut_short_warning(topic, readers[topic].file, readers[topic].cut_short))
            continue
        t_ns, msgs = block
        yield topic, logs[topic][0], msgs
        heapq.heappush(heap, (float(t_ns.max()) if t_ns.size else -math.inf, i, topic))


def _nav(rows: FloatArray) -> NavSeries:
    return NavSeries(rows[:, 0], rows[:, 7:11], rows[:, 4:7], rows[:, 1:4])


# ------------------------------------------------------------------------------------ the accumulators


class _Moments:
    """Count, sum of squares, mean and sum of squared deviations of the errors (K keys) of rows
    added a block at a time (Chan et al.'s parallel update, of the errors less the first row's: an
    error's mean may be 10^4 times its STD, the heading's on paper_su_pair): :func:`dpos_core.ta.
    metrics.rmse_std` of all the rows to ~1e-15."""

    def __init__(self, k: int) -> None:
        self.n = 0
        self.sq = np.zeros(k)
        self.shift: FloatArray | None = None
        self.mean = np.zeros(k)  # of e - shift
        self.m2 = np.zeros(k)

    def add(self, e: FloatArray) -> None:
        """Rows ``e`` (n, K)."""
        nb = e.shape[0]
        if nb == 0:
            return
        self.sq += (e * e).sum(axis=0)
        if self.shift is None:
            self.shift = e[0].copy()
        e = e - self.shift
        mb = e.mean(axis=0)
        m2b = ((e - mb) ** 2).sum(axis=0)
        if self.n == 0:
            self.mean, self.m2 = mb, m2b
        else:
            n = self.n + nb
            d = mb - self.mean
            self.mean = self.mean + d * (nb / n)
            self.m2 = self.m2 + m2b + d * d * (self.n * nb / n)
        self.n += nb

    def rmse_std(self) -> tuple[FloatArray, FloatArray]:
        if self.n == 0:
            nan = np.full(self.sq.shape, np.nan)
            return nan, nan
        return np.sqrt(self.sq / self.n), np.sqrt(self.m2 / self.n)


class _AntennaEval:
    """One antenna's evaluation, fed its rows and their truth a block at a time."""

    def __init__(self, name: str, a: AntennaSolution, segs: dict[str, tuple[float, float]], baseline: bool,
                 keep_nsq: bool = False) -> None:
        assert a.rows is not None
        self.name, self.a, self.rows = name, a, a.rows
        self.segs = segs
        self.keys = [k for k in M.KEYS if k != "baseline_m" or baseline]
        self.moments = {s: _Moments(len(self.keys)) for s in segs}
        self.c_n = 0
        self.c_within = np.zeros(9)
        self.c_nsq = np.zeros(9)
        self.step = max(1, math.ceil(self.rows.n / PLOT_POINTS))
        self.n_eval = 0  # rows evaluated (matched) so far
        self.n_unmatched = 0
        self.plot: list[tuple[FloatArray, dict[str, FloatArray]]] = []
        self.next_row = 0  # the first row not read from the store
        self.buf: dict[str, NDArray] | None = None  # rows read, not evaluated
        self.truth = np.zeros((0, _TRUTH_COLS))  # the truth samples not yet passed
        self.t_done = -math.inf  # every row at or before it is evaluated
        self.nsq: list[FloatArray] | None = [] if keep_nsq else None  # per block (n, 9), when kept

    def done(self) -> bool:
        return self.next_row >= self.rows.n and (self.buf is None or self.buf["t_s"].size == 0)

    def take(self, t_ready: float) -> dict[str, NDArray] | None:
        """The rows at or before ``t_ready`` not yet taken (read a block at a time)."""
        while self.next_row < self.rows.n and (self.buf is None or self.buf["t_s"].size == 0 or self.buf["t_s"][-1] <= t_ready):
            c = self.rows.rows(self.next_row, self.next_row + R.ROW_BLOCK)
            self.next_row += c["t_s"].size
            self.buf = c if self.buf is None else {k: np.concatenate([self.buf[k], c[k]]) for k in c}
        if self.buf is None:
            return None
        k = int(np.searchsorted(self.buf["t_s"], t_ready, side="right"))
        out = {n: v[:k] for n, v in self.buf.items()}
        self.buf = {n: v[k:] for n, v in self.buf.items()}
        self.t_done = t_ready
        return out if k else None

    def evaluate(self, rows: dict[str, NDArray], master: NavSeries, tm: FloatArray | None) -> None:
        """Rows ``rows`` (a RowStore block, in time order) against the truth samples held; ``master``
        the main POS, ``tm`` the truth master's rows held (None: no baseline)."""
        t = rows["t_s"]
        tr = self.truth
        idx = np.searchsorted(tr[:, 0], t)
        ok = (idx < tr.shape[0]) & (np.abs(tr[np.clip(idx, 0, max(tr.shape[0] - 1, 0)), 0] - t) < 1e-6) if tr.shape[0] else \
            np.zeros(t.size, dtype=bool)
        self.n_unmatched += int((~ok).sum())
        if not ok.any():
            return
        est = NavSeries(t[ok], rows["q_nb"][ok], rows["vel_n_mps"][ok], rows["llh"][ok])
        tru = _nav(tr[idx[ok]])
        m_est = m_true = None
        if tm is not None:
            m_est = interp_llh(master.t_s, master.llh, est.t_s)
            m_true = interp_llh(tm[:, 0], tm[:, 1:4], est.t_s)
        err = M.errors(est, tru, m_est, m_true)
        e = np.stack([err[k] for k in self.keys], axis=1)
        sel_any = np.zeros(est.t_s.size, dtype=bool)
        for name, (t_a, t_b) in self.segs.items():
            sel = (est.t_s >= t_a) & (est.t_s <= t_b)
            self.moments[name].add(e[sel])
            sel_any |= sel
        e9, s9 = M.state_errors(est, tru)[sel_any], rows["sigma"][ok][sel_any]
        if self.nsq is not None:
            self.nsq.append((e9 / s9) ** 2)
        good = np.all(np.isfinite(e9), axis=1) & np.all(np.isfinite(s9) & (s9 > 0), axis=1)
        z2 = (e9[good] / s9[good]) ** 2
        self.c_n += z2.shape[0]
        self.c_within += (z2 <= 4.0).sum(axis=0)
        self.c_nsq += z2.sum(axis=0)
        keep = (self.n_eval + np.arange(est.t_s.size)) % self.step == 0
        if keep.any():
            self.plot.append((est.t_s[keep], {k: v[keep] for k, v in err.items()}))
        self.n_eval += est.t_s.size

    def result(self) -> dict:
        """:func:`evaluate`'s entry of the antenna (``errors``, ``t_s``: every ``step``-th row)."""
        per: dict[str, dict[str, dict[str, float]]] = {}
        for name, mom in self.moments.items():
            r, s = mom.rmse_std()
            per[name] = {"rmse": {k: float(r[i]) for i, k in enumerate(self.keys)},
                         "std": {k: float(s[i]) for i, k in enumerate(self.keys)}}
        mean = {part: {k: float(np.mean([per[n][part][k] for n in per])) for k in self.keys} for part in ("rmse", "std")}
        t_s = np.concatenate([p[0] for p in self.plot]) if self.plot else np.zeros(0)
        errors = {k: np.concatenate([p[1][k] for p in self.plot]) if self.plot else np.zeros(0) for k in self.keys}
        out: dict = {**mean, "segments": per, "errors": errors, "t_s": t_s, "plot_step": self.step}
        out["consistency"] = ({"n": 0, "within_2sigma": {}, "nees": {}} if self.c_n == 0 else
                              {"n": self.c_n, "within_2sigma": {k: float(self.c_within[i] / self.c_n) for i, k in enumerate(M.CONS_KEYS)},
                               "nees": {k: float(self.c_nsq[i] / self.c_n) for i, k in enumerate(M.CONS_KEYS)}})
        if self.a.cg is not None:
            out["cg"] = self.a.cg.summary()
        if self.nsq is not None:
            out["nsq"] = np.concatenate(self.nsq) if self.nsq else np.zeros((0, 9))
        return out


# ------------------------------------------------------------------------------------ the evaluation


def truth_topics(topics: list[str] | set[str]) -> bool:
    """Whether a recording with these topics has truth to evaluate against."""
    return any(t.startswith("/truth/antenna/") for t in topics)


def evaluate(sess: RecordedSession, antennas: dict[str, AntennaSolution], topics: list[str] | set[str] | None = None, *,
             keep_nsq: bool = False) -> dict[str, dict]:
    """The antennas' errors against the truth (module docstring):
    ``{antenna: {"rmse", "std", "segments", "consistency", "cg", "errors", "t_s", "plot_step"}}``
    for the estimated antennas with a ``/truth/antenna/<name>`` topic among the recording's
    ``topics`` (None: the truth held in ``sess``, a session in memory); ``sess``: the recording's
    main POS and metadata.  ``keep_nsq``: each antenna's per-row normalized squared errors (n, 9)
    too, ``nsq`` (the rows in the segments; for the ANEES over runs).  Warnings (an antenna without
    its truth, rows without a truth sample, the truth's cleaning) go to ``sess.warnings``."""
    topics = {f"/truth/{k}" for k in sess.truth} if topics is None else set(topics)
    if not truth_topics(topics):
        return {}
    segs = sess.imaging_segments() or {"session": (float(sess.master.t_s[0]), float(sess.master.t_s[-1]))}
    master_topic = T.TRUTH_MASTER
    with_master = master_topic in topics
    evs: dict[str, _AntennaEval] = {}
    for name, a in antennas.items():
        if a.rows is None:
            continue
        if T.truth_antenna(name) not in topics:
            sess.warnings.append(f"evaluation: no {T.truth_antenna(name)} in the recording; antenna {name} is not evaluated")
            continue
        evs[name] = _AntennaEval(name, a, segs, with_master, keep_nsq)
    if not evs:
        return {}
    tm = np.zeros((0, _TRUTH_COLS)) if with_master else None
    last: dict[str, float] = {}  # the last truth stamp read per topic
    warnings: list[str] = []
    wanted = [T.truth_antenna(n) for n in evs] + ([master_topic] if with_master else [])

    def advance(final: bool) -> None:
        nonlocal tm
        lm = math.inf if final or tm is None else last.get(master_topic, -math.inf)
        for name, ev in evs.items():
            t_ready = math.inf if final else min(last.get(T.truth_antenna(name), -math.inf), lm)
            if t_ready <= ev.t_done:
                continue
            rows = ev.take(t_ready)
            if rows is not None:
                ev.evaluate(rows, sess.master, tm if with_master else None)
            # the truth samples no row still to come can match (those at or before t_ready)
            ev.truth = ev.truth[np.searchsorted(ev.truth[:, 0], ev.t_done, side="right"):]
        if tm is not None and tm.shape[0]:  # keep the sample before the first row still to evaluate
            t_min = min((ev.t_done for ev in evs.values() if not ev.done()), default=math.inf)
            if t_min == math.inf:  # every antenna done
                tm = tm[-1:]
            elif t_min > -math.inf:  # (-inf: an antenna not started yet - its truth not read - needs it all)
                tm = tm[max(int(np.searchsorted(tm[:, 0], t_min, side="right")) - 1, 0):]

    for part in truth_parts(sess, wanted, warnings):
        for topic, rows in part.items():
            if not rows.shape[0]:
                continue
            last[topic] = float(rows[-1, 0])
            if topic == master_topic:
                tm = np.concatenate([tm, rows]) if tm is not None else None
            else:
                ev = evs[topic.removeprefix(T.truth_antenna(""))]
                ev.truth = np.concatenate([ev.truth, rows])
        advance(final=False)
    advance(final=True)
    sess.warnings.extend(w for w in warnings if w not in sess.warnings)
    out = {}
    for name, ev in evs.items():
        if ev.n_unmatched:
            sess.warnings.append(f"evaluation: antenna {name}: {ev.n_unmatched} of {ev.rows.n} rows have no truth sample at their "
                                 "stamp (a gap in the truth); evaluated on the others")
        if ev.n_eval:
            out[name] = ev.result()
    return out


def write_evaluation(out: Path, sess: RecordedSession, evaluation: dict[str, dict], method: str, timing: dict[str, float],
                     pool: cf.Executor | None = None, *, figures: bool = True) -> None:
    """``metrics.json``, ``report.md`` and (``figures``) ``errors_<antenna>.png`` of :func:`evaluate`'s
    result into the products directory ``out`` (:func:`dpos_ros.products.write.write`); metrics.json
    also says ``"evaluation": {"path": "streaming", "plot_step": {antenna: n}}`` (:func:`evaluation_metrics`)."""
    figs = [(pool.submit(plot_antenna_errors, out / f"errors_{name}.png", name, ev, method) if pool is not None else
             plot_antenna_errors(out / f"errors_{name}.png", name, ev, method)) for name, ev in evaluation.items() if figures]
    metrics = evaluation_metrics(sess, evaluation, method, timing)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    (out / "report.md").write_text(report_md(metrics, title=f"Session {sess.session_id}"))
    for f in figs:
        if isinstance(f, cf.Future):
            f.result()


def evaluation_metrics(sess: RecordedSession, evaluation: dict[str, dict], method: str, timing: dict[str, float]) -> dict:
    """:func:`dpos_ros.products.report.metrics_json` of an evaluation, with its ``evaluation`` note
    (``path``: how the rows were evaluated, a block at a time; ``plot_step``: the error figures' n)."""
    metrics = metrics_json(sess, {method: (evaluation, timing)}, runs=1)
    metrics["evaluation"] = {"path": "streaming", "plot_step": {name: ev["plot_step"] for name, ev in evaluation.items()}}
    return metrics


def series_free(evaluation: dict[str, dict]) -> dict[str, dict]:
    """``evaluation`` without its per-row series (``errors``, ``t_s``, ``plot_step``): what
    :func:`dpos_ros.products.report.combine_runs` reads."""
    return {name: {k: v for k, v in e.items() if k not in ("errors", "t_s", "plot_step", "nsq")} for name, e in evaluation.items()}


__all__ = ["PLOT_POINTS", "evaluate", "evaluation_metrics", "series_free", "truth_parts", "truth_topics", "write_evaluation"]
