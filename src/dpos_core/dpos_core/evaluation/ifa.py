"""Offline Monte Carlo evaluation of the in-flight alignment ([Fang2012] sec. 4.1, Table 3).

Each run simulates the scenario (:class:`~dpos_core.sim.session.SimulatedSession`, seed S + r) in
memory, starts the aligner from the truth at t0 with the initial heading (and level) error, and
compares the closed-loop navigation with the truth.  ``dpos-eval`` dispatches here for a scenario
with an ``ifa:`` block and no sub-IMUs (paper_ifa).  Experiments (all deterministic for a seed):

* ``table``: final heading / pitch / roll error per method over the runs ([Fang2012] Table 3);
* ``sweep``: initial heading errors of both signs, final heading error and convergence time;
* ``outage``: a GNSS outage ``[t0, t0 + dur)`` added to the scenario's schedule;
* ``noise_jump``: the GNSS noise scaled by ``scale`` from ``t0`` to the end (appended to the
  schedule, so it overrides it there);
* ``consistency``: started from the data as on a real recording, the datasheet filter and the
  oracle (the simulated unit's model): NEES / NIS and errors before / during / after an outage.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from dataclasses import fields as dc_fields
from typing import Any

import numpy as np

from dpos_core.units import DEG, FloatArray

from ..attitude import dcm_to_quat
from ..config.sensors import NoiseInterval
from ..frames import C_nb_from_hpr, hpr_from_C_nb
from ..ifa.model import IfaFilterConfig
from ..ifa.pipeline import METHODS, attitude_errors_deg, run
from ..ifa.reference import Reference, compare
from ..ifa.reference import consistency as nees
from ..ifa.reference import initial_state as data_initial_state
from ..series import GnssSeries
from ..sim.scenario import Scenario
from ..sim.session import SimulatedSession
from ..strapdown import NavState

KEYS = ("heading_deg", "pitch_deg", "roll_deg")
#: [Fang2012] Table 3 (its "DD2" row is the paper's ADD2)
PAPER_TABLE3 = {"add2": (0.014, 0.0016, 0.0018, 6.8505), "aekf": (0.031, 0.0019, 0.0022, 7.6235)}
CONVERGED_DEG = 0.05


def is_ifa_scenario(scenario: Scenario) -> bool:
    """An in-flight-alignment scenario: an ``ifa:`` block and no sub-IMUs."""
    return bool(scenario.ifa) and not scenario.aircraft.sub_imus


def with_gnss_interval(scenario: Scenario, interval: NoiseInterval) -> Scenario:
    """The scenario with ``interval`` appended to its GNSS schedule (later intervals override)."""
    g = scenario.gnss
    return replace(scenario, gnss=replace(g, schedule=tuple(g.schedule) + (interval,)))


def initial_state(ss: SimulatedSession, heading_err_deg: float, level_err_deg: tuple[float, float] = (0.0, 0.0)) -> NavState:
    """Truth at t = 0 with heading / pitch / roll errors [deg] added."""
    tr = ss.truth("master", np.array([0.0]))
    hpr = hpr_from_C_nb(tr.C_nb[0]) + np.array([heading_err_deg, *level_err_deg]) * DEG
    return NavState(0.0, dcm_to_quat(C_nb_from_hpr(*hpr)), tr.vel_n_mps[0], tr.llh[0])


@dataclass
class RunResult:
    """One aligner run: epochs (K,), attitude errors at the epochs (K, 3) [deg] (heading, pitch,
    roll, after feedback), final errors (3,) at the end of the data, aligned time, processing
    and data duration [s], the filter's heading 1 sigma at its last epoch [deg]."""

    method: str
    seed: int
    heading0_deg: float
    epochs_s: FloatArray
    err_deg: FloatArray
    final_deg: FloatArray
    aligned_t_s: float | None
    processing_s: float
    data_s: float
    heading_sigma_deg_final: float = float("nan")

    def convergence_t_s(self, tol_deg: float = CONVERGED_DEG) -> float | None:
        """First epoch from which |heading error| stays below ``tol_deg`` (None if never, or no epoch)."""
        if self.epochs_s.size == 0:
            return None
        bad = np.nonzero(np.abs(self.err_deg[:, 0]) >= tol_deg)[0]
        if bad.size == 0:
            return float(self.epochs_s[0])
        return float(self.epochs_s[bad[-1] + 1]) if bad[-1] + 1 < self.epochs_s.size else None

    def summary(self) -> dict:
        return {"method": self.method, "seed": self.seed, "initial_heading_error_deg": self.heading0_deg,
                "final_deg": dict(zip(KEYS, map(float, self.final_deg))), "aligned_t_s": self.aligned_t_s,
                "converged_t_s": self.convergence_t_s(), "processing_s": self.processing_s, "data_s": self.data_s}


class Evaluator:
    """Runs of one scenario; sessions cached per (seed, schedule)."""

    def __init__(self, scenario: Scenario, cfg: IfaFilterConfig | None = None, duration_s: float | None = None,
                 level_err_deg: tuple[float, float] = (0.0, 0.0)) -> None:
        self.scenario = scenario
        ifa = scenario.ifa
        self.cfg = cfg or IfaFilterConfig(window=int(ifa.get("window", IfaFilterConfig.window)))
        self.duration_s = duration_s
        self.level_err_deg = level_err_deg
        self._cache: dict = {}

    def _session(self, scenario: Scenario, seed: int):
        key = (seed, scenario.gnss.schedule)
        if key not in self._cache:
            ss = SimulatedSession(scenario, seed, self.duration_s)
            imu, gnss = ss.master_imu(), ss.gnss()
            truth = ss.truth("master", np.concatenate([[0.0], imu.t_s]))
            self._cache = {key: (ss, imu, gnss, truth)}  # one session at a time (memory)
        return self._cache[key]

    def run(self, method: str, seed: int, heading0_deg: float, scenario: Scenario | None = None) -> RunResult:
        if method not in METHODS:
            raise ValueError(f"unknown IFA method {method!r}; choose from {METHODS}")
        ss, imu, gnss, truth = self._session(scenario or self.scenario, seed)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run(imu, gnss, ss.scenario.aircraft.gnss_lever_arm_m, self.cfg, method,
                      initial_state(ss, heading0_deg, self.level_err_deg))
        proc = time.perf_counter() - t0
        err = attitude_errors_deg(res, truth.q_nb)
        k = np.searchsorted(res.t_s, res.epochs_s)
        sig = float(res.heading_sigma_deg[-1]) if res.epochs_s.size else float("nan")
        return RunResult(method, seed, heading0_deg, res.epochs_s, err[k], err[-1], res.aligned_t_s, proc,
                         float(res.t_s[-1] - res.t_s[0]), sig)


def filter_config(scenario: Scenario, oracle: bool = False) -> IfaFilterConfig:
    """The filter a user would configure for a scenario: the IMU model of its aircraft (vehicle)
    file when it states one (the datasheet), else the simulated unit's (the papers: the filter knew
    the sensors); the nominal GNSS sigmas of the scenario; the ``ifa`` block's keys that are
    :class:`~dpos_core.ifa.model.IfaFilterConfig` fields.  ``oracle``: the simulated unit's own
    model instead of the datasheet (the filter that knows what the truth did)."""
    names = {f.name for f in dc_fields(IfaFilterConfig)} - {"imu"}
    kw: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in scenario.ifa.items() if k in names}
    imu = scenario.master_imu if (oracle or scenario.aircraft.master_imu is None) else scenario.aircraft.master_imu
    kw.setdefault("gnss_pos_sigma_m", scenario.gnss.pos_sigma_m)
    kw.setdefault("gnss_vel_sigma_mps", scenario.gnss.vel_sigma_mps)
    return IfaFilterConfig(imu=imu, **kw)


def consistency(scenario: Scenario, seeds: list[int], method: str = "add2", duration_s: float | None = None,
                outage_s: tuple[float, float] | None = None) -> dict:
    """Honest covariance on a simulated session started as on real data (the initial state by
    pos_master_node's live rule, :func:`dpos_core.ifa.reference.initial_state`, with the ``ifa``
    block's ``min_course_speed_mps``): per seed, the datasheet filter
    (:func:`filter_config`) and the oracle (the simulated unit's model), NEES / NIS figures
    (:func:`dpos_core.ifa.reference.consistency`) after the alignment, and the horizontal error
    against the truth before / during / after ``outage_s`` with its 3-sigma coverage."""
    out: dict[str, list] = {"datasheet": [], "oracle": []}
    for seed in seeds:
        ss = SimulatedSession(scenario, seed, duration_s)
        imu, gnss = ss.master_imu(), ss.gnss()
        tr = ss.truth("master", np.arange(1.0, float(imu.t_s[-1]) - 1.0, 0.25))
        ref = Reference(tr.t_s, tr.llh, tr.vel_n_mps, np.zeros((tr.t_s.size, 3)))
        for kind in ("datasheet", "oracle"):
            cfg = filter_config(scenario, oracle=kind == "oracle")
            g = GnssSeries(gnss.t_s - cfg.gnss_time_offset_s, gnss.llh, gnss.pos_sigma_m, gnss.vel_n_mps, gnss.vel_sigma_mps)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                init = data_initial_state(imu, g, float(scenario.ifa.get("min_course_speed_mps", 5.0)),
                                          lever_arm_m=np.asarray(ss.scenario.aircraft.gnss_lever_arm_m))
                res = run(imu, gnss, ss.scenario.aircraft.gnss_lever_arm_m, cfg, method, init)
            proc = time.perf_counter() - t0
            since = res.aligned_t_s if res.aligned_t_s is not None else float(res.t_s[-1])
            rep = compare(res, ref, outage_s)
            out[kind].append({"seed": seed, "aligned_t_s": res.aligned_t_s, "restarts": res.restarts,
                              "rejected": len(res.rejected), "diverged_epochs": rep.diverged,
                              "consistency": nees(res, lambda t: ss.truth("master", t), since).summary(),
                              "horizontal_error_m": rep.horizontal_error_m, "inside_3sigma": rep.inside_3sigma,
                              "processing_s": proc, "data_s": float(res.t_s[-1] - res.t_s[0])})
    return out


def _stats(finals: FloatArray) -> dict:
    """rmse / std / mean |.| / max |.| over runs of final errors (R, 3) -> dicts keyed by KEYS."""
    f = np.asarray(finals, dtype=float).reshape(-1, 3)
    out = {"rmse": np.sqrt(np.mean(f**2, axis=0)), "std": np.std(f, axis=0), "mean_abs": np.mean(np.abs(f), axis=0),
           "max_abs": np.max(np.abs(f), axis=0)}
    return {k: dict(zip(KEYS, map(float, v))) for k, v in out.items()}


def table(ev: Evaluator, methods: list[str], seeds: list[int], heading0_deg: float) -> dict:
    """Table-3 experiment: ``{method: {mean: {rmse, std, mean_abs, max_abs}, timing, aligned_t_s,
    converged, runs: [...]}}``."""
    out = {}
    for m in methods:
        rs = [ev.run(m, s, heading0_deg) for s in seeds]
        al = [r.aligned_t_s for r in rs if r.aligned_t_s is not None]
        out[m] = {"mean": _stats(np.array([r.final_deg for r in rs])),
                  "timing": {"processing_s": float(sum(r.processing_s for r in rs)), "data_s": float(sum(r.data_s for r in rs))},
                  "aligned_fraction": len(al) / len(rs), "aligned_t_s": float(np.mean(al)) if al else None,
                  "converged_fraction": float(np.mean([abs(r.final_deg[0]) < CONVERGED_DEG for r in rs])),
                  "runs": [r.summary() for r in rs]}
    return out


def sweep(ev: Evaluator, methods: list[str], seeds: list[int], headings_deg: list[float]) -> dict:
    """Initial-heading sweep, both signs: ``{method: [{initial_heading_error_deg, max_abs_final_heading_deg,
    mean_abs_final_heading_deg, converged (count), runs, max_converged_t_s}]}``."""
    hs = sorted({float(s * h) for h in headings_deg for s in (1, -1)}, key=lambda v: (abs(v), v))
    out: dict[str, list] = {m: [] for m in methods}
    for m in methods:
        for h in hs:
            rs = [ev.run(m, s, h) for s in seeds]
            fh = np.array([abs(r.final_deg[0]) for r in rs])
            ct = [t for t in (r.convergence_t_s() for r in rs) if t is not None]  # of the runs that converged
            out[m].append({"initial_heading_error_deg": h, "mean_abs_final_heading_deg": float(fh.mean()),
                           "max_abs_final_heading_deg": float(fh.max()), "converged": int(np.sum(fh < CONVERGED_DEG)),
                           "runs": len(rs), "max_converged_t_s": None if len(ct) < len(rs) else float(max(ct)),
                           "aligned": int(sum(r.aligned_t_s is not None for r in rs))})
    return out


def _window_stats(r: RunResult, t_a: float, t_b: float) -> float:
    k = (r.epochs_s >= t_a) & (r.epochs_s < t_b)
    return float(np.max(np.abs(r.err_deg[k, 0]))) if np.any(k) else float("nan")


def outage(ev: Evaluator, methods: list[str], seeds: list[int], heading0_deg: float, t0_s: float, dur_s: float) -> dict:
    """GNSS outage ``[t0, t0 + dur)``: per method and seed the |heading| error [deg] just before,
    the max over the outage and the 30 s after it, the final error and the re-convergence time."""
    sc = with_gnss_interval(ev.scenario, NoiseInterval(t0_s, t0_s + dur_s, outage=True))
    out: dict[str, list] = {m: [] for m in methods}
    for m in methods:
        for s in seeds:
            r = ev.run(m, s, heading0_deg, sc)
            before = r.err_deg[r.epochs_s < t0_s]
            out[m].append({"seed": s, "before_deg": float(abs(before[-1, 0])) if before.size else float("nan"),
                           "max_after_outage_30s_deg": _window_stats(r, t0_s, t0_s + dur_s + 30.0),
                           "final_deg": dict(zip(KEYS, map(float, r.final_deg))),
                           "epochs_in_outage": int(np.sum((r.epochs_s >= t0_s) & (r.epochs_s < t0_s + dur_s))),
                           "converged_t_s": r.convergence_t_s()})
    return out


def noise_jump(ev: Evaluator, methods: list[str], seeds: list[int], heading0_deg: float, t0_s: float, scale: float) -> dict:
    """GNSS noise x ``scale`` from ``t0`` on: per method the final errors over seeds (stats) and the
    max |heading| error after the jump."""
    end = ev.duration_s or ev.scenario.duration_s
    sc = with_gnss_interval(ev.scenario, NoiseInterval(t0_s, end + 1.0, scale=scale))
    out = {}
    for m in methods:
        rs = [ev.run(m, s, heading0_deg, sc) for s in seeds]
        out[m] = {"mean": _stats(np.array([r.final_deg for r in rs])),
                  "max_abs_heading_after_jump_deg": float(max(_window_stats(r, t0_s, np.inf) for r in rs)),
                  "runs": [r.summary() for r in rs]}
    return out


def consistency_md(c: dict, outage_s: tuple[float, float] | None) -> list[str]:
    """Markdown lines of :func:`consistency`."""
    L = ["Honest covariance (start from the data: levelled at the first fix, any heading). NEES per 3-dof block "
         "after the alignment (mean, 3 when consistent; fraction inside the two-sided 95 % chi-square bounds), NIS of "
         "the 6 GNSS measurements (mean, 6 when consistent), horizontal error against the truth, errors inside the "
         "reported 3 sigma (E, N, U).", "",
         "| filter | seed | aligned (s) | NEES pos | NEES vel | NEES att | NIS | error before (m rms) | during (m max) | "
         "after (m rms) | inside 3 sigma E/N/U |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind, rows in c.items():
        for r in rows:
            s, e, i = r["consistency"], r["horizontal_error_m"], r["inside_3sigma"]
            ph = ("before", "during", "after") if outage_s else ("all", "all", "all")
            L.append(f"| {kind} | {r['seed']} | {_f(r['aligned_t_s'], '.0f')} | {s['nees_pos_mean']:.2f} ({s['nees_pos_in95']:.2f}) | "
                     f"{s['nees_vel_mean']:.2f} ({s['nees_vel_in95']:.2f}) | {s['nees_att_mean']:.2f} ({s['nees_att_in95']:.2f}) | "
                     f"{s['nis_mean']:.2f} ({s['nis_in95']:.2f}) | {e[ph[0]]['rms']:.3f} | {e[ph[1]]['max']:.3f} | {e[ph[2]]['rms']:.3f} | "
                     f"{i['E']:.3f}/{i['N']:.3f}/{i['U']:.3f} |")
    L.append("")
    return L


def _f(v: float | None, fmt: str = ".4f") -> str:
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def report_md(metrics: dict) -> str:
    """Markdown report: Table 3 layout (mean |final error| and RMSE over runs), then the optional
    sweep, outage and noise-jump tables."""
    L = [f"# In-flight alignment: {metrics['scenario']} ({metrics['runs']} runs, seeds {metrics['seeds'][0]}.."
         f"{metrics['seeds'][-1]}, initial heading error {metrics['initial_heading_error_deg']} deg)", ""]
    if "methods" in metrics:
        L += ["Final attitude error ([Fang2012] Table 3 layout): mean |error| over runs, RMSE in brackets; time used = "
              "processing time per run (ours: Python; the paper's: MATLAB, for reference).", "",
              "| filter | heading (deg) | pitch (deg) | roll (deg) | time used (s) | aligned at (s) | converged |",
              "|---|---|---|---|---|---|---|"]
        for m, d in metrics["methods"].items():
            a, r = d["mean"]["mean_abs"], d["mean"]["rmse"]
            tu = d["timing"]["processing_s"] / metrics["runs"]
            L.append(f"| {m.upper()} (ours) | " + " | ".join(f"{a[k]:.4f} ({r[k]:.4f})" for k in KEYS)
                     + f" | {tu:.2f} | {_f(d['aligned_t_s'], '.0f')} | {d['converged_fraction'] * 100:.0f}% |")
            if m in PAPER_TABLE3:
                p = PAPER_TABLE3[m]
                L.append(f"| {m.upper()} ([Fang2012]) | {p[0]} | {p[1]} | {p[2]} | {p[3]} | — | — |")
        L.append("")
    if "heading_sweep" in metrics:
        L += [f"Initial-heading sweep: final |heading error| (deg) over {metrics['runs']} seeds, converged = final "
              f"|heading| < {CONVERGED_DEG} deg, t_conv = latest time from which |heading| stays below it.", "",
              "| method | initial heading error (deg) | mean | max | converged | aligned | t_conv max (s) |", "|---|---|---|---|---|---|---|"]
        for m, rows in metrics["heading_sweep"].items():
            for row in rows:
                L.append(f"| {m} | {row['initial_heading_error_deg']:+.0f} | {row['mean_abs_final_heading_deg']:.4f} | "
                         f"{row['max_abs_final_heading_deg']:.4f} | {row['converged']}/{row['runs']} | {row['aligned']}/{row['runs']} | "
                         f"{_f(row['max_converged_t_s'], '.0f')} |")
        L.append("")
    if "outage" in metrics:
        o = metrics["outage"]
        L += [f"GNSS outage {o['t0_s']:.0f}-{o['t0_s'] + o['duration_s']:.0f} s: |heading error| (deg).", "",
              "| method | seed | before | max in outage + 30 s | final heading | final pitch | final roll | t_conv (s) |",
              "|---|---|---|---|---|---|---|---|"]
        for m, rows in o["methods"].items():
            for row in rows:
                f = row["final_deg"]
                L.append(f"| {m} | {row['seed']} | {row['before_deg']:.4f} | {row['max_after_outage_30s_deg']:.4f} | "
                         f"{f['heading_deg']:+.4f} | {f['pitch_deg']:+.5f} | {f['roll_deg']:+.5f} | {_f(row['converged_t_s'], '.0f')} |")
        L.append("")
    if "consistency" in metrics:
        o = metrics["consistency"]
        L += consistency_md(o["filters"], o.get("outage_s"))
    if "noise_jump" in metrics:
        o = metrics["noise_jump"]
        L += [f"GNSS noise x{o['scale']:g} from {o['t0_s']:.0f} s to the end: final error, mean |.| (max |.|) over seeds, deg.", "",
              "| method | heading | pitch | roll | max |heading| after the jump |", "|---|---|---|---|---|"]
        for m, d in o["methods"].items():
            a, x = d["mean"]["mean_abs"], d["mean"]["max_abs"]
            L.append(f"| {m} | " + " | ".join(f"{a[k]:.4f} ({x[k]:.4f})" for k in KEYS)
                     + f" | {d['max_abs_heading_after_jump_deg']:.4f} |")
        L.append("")
    return "\n".join(L)


def metrics_json(scenario: str, seeds: list[int], heading0_deg: float, cfg: IfaFilterConfig, parts: dict) -> dict:
    """design.md ``metrics.json`` shape with the IFA keys: ``methods.<m>.mean.{rmse,std}``
    (final heading / pitch / roll [deg]) and ``timing``, plus the experiments run."""
    out = {"scenario": scenario, "runs": len(seeds), "seeds": seeds, "initial_heading_error_deg": heading0_deg,
           "config": {"window": cfg.window, "heading_hypotheses": cfg.heading_hypotheses}}
    out.update(parts)
    return out


__all__ = ["Evaluator", "RunResult", "is_ifa_scenario", "with_gnss_interval", "initial_state", "table", "sweep",
           "outage", "noise_jump", "report_md", "metrics_json", "PAPER_TABLE3", "filter_config", "consistency", "consistency_md"]
