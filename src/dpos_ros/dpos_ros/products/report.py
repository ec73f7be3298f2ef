"""The reports of the evaluation of a session's antennas against the recorded truth
(design.md "Session products"): ``metrics.json`` (:func:`metrics_json`, :func:`combine_runs` over runs), ``report.md`` in the
papers' table layouts (:func:`report_md`: [Gong2018] Table 1, [Ye2024] Table 2) and the error
figures (:func:`plot_antenna_errors`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dpos_core.filters.variational import pool_summaries
from dpos_core.ta import metrics as M
from dpos_core.units import FloatArray
from dpos_ros.io.session import RecordedSession


def interp_llh(t: FloatArray, llh: FloatArray, tq: FloatArray) -> FloatArray:
    return np.stack([np.interp(tq, t, llh[:, i]) for i in range(3)], -1)


def combine_runs(per_method: dict[str, list[dict]], timing: dict[str, dict]) -> dict[str, tuple[dict, dict]]:
    """Per method, the mean over the runs of each antenna's RMSE / STD (and its consistency, where
    the runs have it) from the runs' :func:`dpos_ros.products.evaluate.evaluate` results, with the method's timing: the
    ``per_method`` argument of :func:`metrics_json`."""
    combined = {}
    for m, runs in per_method.items():
        names = runs[0].keys()
        ant = {n: M.average([{"rmse": run[n]["rmse"], "std": run[n]["std"]} for run in runs]) for n in names}
        cons = {n: M.average_consistency([run[n].get("consistency", {}) for run in runs]) for n in names}
        cg = {n: pool_summaries([run[n]["cg"] for run in runs if "cg" in run[n]]) for n in names}
        combined[m] = ({n: {**ant[n], **({"consistency": cons[n]} if cons[n]["n"] else {}), **({"cg": cg[n]} if cg[n]["updates"] else {})}
                        for n in names}, timing[m])
    return combined


def metrics_json(sess: RecordedSession | None, per_method: dict[str, tuple[dict, dict]], runs: int, scenario: str | None = None) -> dict:
    """design.md's metrics.json: per method the mean over antennas (and runs) and per antenna."""
    segs = list((sess.imaging_segments() if sess else {}).keys()) or ["session"]
    methods: dict[str, dict] = {}
    out = {"scenario": scenario or (sess.custom.get("dpos.scenario", "") if sess else ""), "runs": runs, "segments": segs, "methods": methods}
    for method, (ev, timing) in per_method.items():
        ants = {name: {"rmse": e["rmse"], "std": e["std"]} for name, e in ev.items()}
        methods[method] = {"mean": M.average(list(ants.values())) if ants else {}, "antennas": ants, "timing": timing}
        cons = {name: e["consistency"] for name, e in ev.items() if e.get("consistency")}
        if cons:  # the reported sigma against the errors (M.consistency), per antenna and pooled
            for name, c in cons.items():
                ants[name]["consistency"] = c
            methods[method]["consistency"] = M.average_consistency(list(cons.values()))
        cgs = {name: e["cg"] for name, e in ev.items() if e.get("cg")}
        if cgs:  # the CDVF's conjugate-gradient iterations, per antenna and pooled
            for name, c in cgs.items():
                ants[name]["cg"] = c
            methods[method]["cg"] = pool_summaries(list(cgs.values()))
    return out


PAPER_TABLE1 = {  # [Gong2018] Table 1: (URTSS RMSE, STD), (UPS RMSE, STD)
    "heading_deg": ((3.7874, 1.2914), (0.4959, 0.0217)), "pitch_deg": ((0.5166, 0.1218), (0.0766, 0.0781)),
    "roll_deg": ((0.8238, 0.0371), (0.0569, 0.0568)), "vel_e_mps": ((0.0264, 0.0245), (0.0133, 0.0134)),
    "vel_n_mps": ((0.0403, 0.0414), (0.0225, 0.0148)), "vel_u_mps": ((0.0125, 0.0124), (0.0224, 0.0211)),
    "lat_m": ((2.1444, 0.0990), (1.0077, 0.0529)), "lon_m": ((1.7280, 0.0878), (0.0510, 0.0495)),
    "h_m": ((0.1078, 0.0987), (0.1294, 0.0126)), "baseline_m": ((0.7039, 0.0532), (0.0014, 0.0008)),
}


ROWS = [("Attitude error", "Heading (°)", "heading_deg"), ("", "Pitch (°)", "pitch_deg"), ("", "Roll (°)", "roll_deg"),
        ("Velocity error", "East (m/s)", "vel_e_mps"), ("", "North (m/s)", "vel_n_mps"), ("", "Up (m/s)", "vel_u_mps"),
        ("Position error", "Latitude (m)", "lat_m"), ("", "Longitude (m)", "lon_m"), ("", "Height (m)", "h_m"),
        ("Baseline error", "(m)", "baseline_m")]


def report_md(metrics: dict, title: str, paper: bool | None = None) -> str:
    """[Gong2018] Table 1 layout: means of RMSE and STD over the imaging segments (and runs)."""
    methods = list(metrics["methods"])
    paper = metrics.get("scenario") == "paper_su" if paper is None else paper
    head = ["Parameter", ""] + [f"{m.upper()} {c}" for m in methods for c in ("RMSE", "STD")]
    if paper:
        head += ["paper URTSS RMSE", "paper URTSS STD", "paper UPS RMSE", "paper UPS STD"]
    what = f"Scenario `{metrics['scenario']}`" if metrics.get("scenario") else "Live session"
    lines = [f"# {title}", "", f"{what}, {metrics['runs']} run(s), segments {', '.join(metrics['segments'])}; "
             "means of RMSE and STD ([Gong2018] eq. 21) over the segments, the runs and the antennas.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group, label, key in ROWS:
        row = [group, label]
        for m in methods:
            mean = metrics["methods"][m].get("mean", {})
            row += [_fmt(mean.get("rmse", {}).get(key)), _fmt(mean.get("std", {}).get(key))]
        if paper:
            (ur, us), (pr, ps) = PAPER_TABLE1[key]
            row += [f"{ur:.4f}", f"{us:.4f}", f"{pr:.4f}", f"{ps:.4f}"]
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    cons = {m: metrics["methods"][m]["consistency"] for m in methods if metrics["methods"][m].get("consistency", {}).get("n")}
    if cons:
        lines += ["Reported 1-sigma against the errors, pooled over the antennas and runs: fraction of errors within "
                  "2 sigma (0.95 when honest) / mean e^2/sigma^2 (1 when honest); attitude about local E, N, U.", "",
                  "| method | " + " | ".join(M.CONS_KEYS) + " |", "|---|" + "---|" * len(M.CONS_KEYS)]
        for m, c in cons.items():
            lines.append(f"| {m} | " + " | ".join(f"{c['within_2sigma'][k]:.2f} / {c['nees'][k]:.2g}" for k in M.CONS_KEYS) + " |")
        lines.append("")
    if metrics.get("scenario") == "paper_cdvf":
        lines += table2_md(metrics)
    cgs = {m: metrics["methods"][m]["cg"] for m in methods if metrics["methods"][m].get("cg", {}).get("updates")}
    if cgs:
        lines += cg_md(cgs)
    for m in methods:
        t = metrics["methods"][m].get("timing", {})
        if t.get("data_s"):
            lines.append(f"- {m}: processing {t['processing_s']:.1f} s for {t['data_s']:.0f} s of sub-IMU data "
                         f"(processing time / data duration = {t['processing_s'] / t['data_s']:.4f})")
    return "\n".join(lines) + "\n"


#: [Ye2024] Table 2 (flight test, RMSE): the traditional method (CDKF), the modified method (the
#: H-infinity CDKF of its ref. 1) and the proposed method (CDVF)
PAPER_TABLE2 = {
    "heading_deg": (0.066, 0.058, 0.050), "pitch_deg": (0.006, 0.005, 0.004), "roll_deg": (0.005, 0.004, 0.003),
    "vel_e_mps": (0.026, 0.023, 0.019), "vel_n_mps": (0.023, 0.020, 0.016), "vel_u_mps": (0.031, 0.026, 0.022),
    "lat_m": (0.748, 0.645, 0.580), "lon_m": (0.848, 0.713, 0.660), "h_m": (0.976, 0.870, 0.741),
}


#: the relative improvements [%] [Ye2024] sec. 4.2 states in its text (they are not those of its Table 2)
PAPER_TABLE2_TEXT_PCT = {"heading_deg": 22.2, "pitch_deg": 10.5, "roll_deg": 12.5, "vel_e_mps": 19.2, "vel_n_mps": 18.1,
                         "vel_u_mps": 22.5, "lat_m": 17.3, "lon_m": 19.8, "h_m": 23.9}


#: (CDKF, CDVF) pairs whose relative improvement the Table 2 layout shows
CDVF_PAIRS = (("cdkf", "cdvf"), ("cdkf_rts", "cdvf_rts"))


def _improvement(base: float | None, new: float | None) -> str:
    """``(base - new) / base`` in % (positive: ``new`` is better), or a dash."""
    if base is None or new is None or not np.isfinite(base) or not np.isfinite(new) or base <= 0:
        return "—"
    return f"{100.0 * (base - new) / base:+.2f} %"


def table2_md(metrics: dict) -> list[str]:
    """[Ye2024] Table 2 layout (attitude, velocity, position RMSE; no baseline row): every method's
    RMSE, the relative improvement of each CDVF over its CDKF (:data:`CDVF_PAIRS`), the paper's three
    columns and its improvements (from its table, traditional -> proposed, and as its text states)."""
    methods = list(metrics["methods"])
    rmse = {m: metrics["methods"][m].get("mean", {}).get("rmse", {}) for m in methods}
    pairs = [(a, b) for a, b in CDVF_PAIRS if a in methods and b in methods]
    head = ["Items", ""] + methods + [f"{b} vs {a}" for a, b in pairs] + [
        "paper CDKF", "paper modified CDKF", "paper CDVF", "paper CDVF vs CDKF (table)", "paper (text)"]
    lines = ["", f"[Ye2024] Table 2 layout: RMSE over the imaging laps ({metrics['runs']} run(s)); improvement = "
             "(CDKF - CDVF) / CDKF, positive when the CDVF is better.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group, label, key in ROWS:
        if key not in PAPER_TABLE2:
            continue
        row = [group, label] + [(f"{rmse[m][key]:.4g}" if rmse[m].get(key) is not None else "—") for m in methods]
        row += [_improvement(rmse[a].get(key), rmse[b].get(key)) for a, b in pairs]
        t, mod, prop = PAPER_TABLE2[key]
        row += [f"{t:.3f}", f"{mod:.3f}", f"{prop:.3f}", _improvement(t, prop), f"+{PAPER_TABLE2_TEXT_PCT[key]:.1f} %"]
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def cg_md(cgs: dict[str, dict]) -> list[str]:
    """The CDVF's conjugate-gradient iterations per method (:meth:`dpos_core.filters.variational.CGStats.summary`, pooled)."""
    lines = ["CDVF conjugate-gradient state updates (stopping rule |grad J| <= 1e-3 in the whitened coordinates, "
             "dpos_core.filters.variational; J: the variational cost, J0 at the prediction, J_cdkf at the CDKF's update):", "",
             "| method | updates | iterations mean / max | stopped by the gradient rule | mean (J0 - J) / J0 | J < J_cdkf | "
             "mean (J_cdkf - J) / J_cdkf | max (J - J_cdkf) | max final abs(grad J) |", "|---|---|---|---|---|---|---|---|---|"]
    for m, c in cgs.items():
        lines.append(f"| {m} | {c['updates']} | {c['iterations_mean']:.2f} / {c['iterations_max']} | {c['stopped_by_gradient']:.3f} | "
                     f"{c['relative_cost_decrease_mean']:.4f} | {c['below_cdkf']:.3f} | {c['relative_gain_over_cdkf_mean']:.2e} | "
                     f"{c['cost_minus_cdkf_max']:.2e} | {c['grad_norm_max']:.2e} |")
    return lines + [""]


def _fmt(v) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.4f}" if abs(v) >= 1e-3 else f"{v:.2e}"


def plot_antenna_errors(path: Path, name: str, ev: dict, method: str) -> Path:
    """The antenna's errors against the truth over time (``ev``: its entry of :func:`dpos_ros.products.evaluate.evaluate`)."""
    from matplotlib.figure import Figure

    e, t = ev["errors"], ev["t_s"]
    fig = Figure(figsize=(9, 7.5))  # no pyplot: figures may be drawn in threads at once (thread-pool executors)
    axs = fig.subplots(3, 1, sharex=True)
    fig.subplots_adjust(left=0.11, right=0.98, top=0.95, bottom=0.07, hspace=0.1)  # (constrained layout: ~2x the time)
    for k, lab in (("heading_deg", "heading"), ("pitch_deg", "pitch"), ("roll_deg", "roll")):
        axs[0].plot(t, e[k], lw=0.7, label=lab)
    axs[0].set(ylabel="attitude error [deg]")
    for k, lab in (("vel_e_mps", "east"), ("vel_n_mps", "north"), ("vel_u_mps", "up")):
        axs[1].plot(t, e[k], lw=0.7, label=lab)
    axs[1].set(ylabel="velocity error [m/s]")
    for k, lab in (("lat_m", "latitude"), ("lon_m", "longitude"), ("h_m", "height")):
        axs[2].plot(t, e[k], lw=0.7, label=lab)
    if "baseline_m" in e:
        axs[2].plot(t, e["baseline_m"], lw=0.7, label="baseline")
    axs[2].set(ylabel="position error [m]", xlabel="t [s]")
    for ax in axs:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axs[0].set_title(f"antenna {name}: {method.upper()} errors against truth")
    fig.savefig(path, dpi=80)
    return path
