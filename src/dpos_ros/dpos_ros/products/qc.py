"""The quality-control products of a transfer-alignment session, without truth
(docs/qc.md, design.md "Session products"): ``qc.md``, ``qc/<antenna>_qc.png`` and the ``qc``
block of ``status.json``, from the antennas' own solutions (sigmas, flags, the filter's
innovations and the forward/backward separation: :mod:`dpos_core.ta.qc`).  Written by
:func:`dpos_ros.products.write.write` for every session (dpos-process and transfer_align_node),
whether or not the recording has truth; nothing here reads it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from dpos_core.ta import flags as F
from dpos_core.ta import qc as Q
from dpos_core.units import DEG

from .antenna import AntennaSolution
from .rows import RowBlock

#: the plots show at most this many points per curve (rows decimated by striding)
MAX_PLOT_POINTS = 4000


def qc_dir(out: Path) -> Path:
    """Where the QC figures of the products in ``out`` go."""
    return out / "qc"


def json_safe(v):
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [json_safe(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _f(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    return f"{v:.{digits}g}"


def _pc(v) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"


def qc_md(summ: dict[str, dict], session_id: str, method: str) -> str:
    """The QC report (docs/qc.md explains how to read it)."""
    L = [f"# Quality control, session {session_id}", "",
         f"Method `{method}`. Computed from the solution alone (no truth): the 1-sigma, the filter's innovations "
         f"(NIS against its chi^2 bounds, {Q.PROB:.0%} two-sided; windowed over {Q.WINDOW_S:g} s), the forward/backward "
         "separation and the rows' flags. How to read it: docs/qc.md.", "",
         "## Verdicts", "", "| antenna | sub-IMU | verdict |", "|---|---|---|"]
    for name, s in summ.items():
        L.append(f"| {name} | {s.get('sub_imu', '—')} | {s['verdict']} |")
    est = {n: s for n, s in summ.items() if "sigma" in s}
    if est:
        L += ["", "## 1-sigma over the session (50th / 95th percentile / max)", "",
              "| antenna | heading [deg] | rot E [deg] | rot N [deg] | vel E [m/s] | vel N [m/s] | vel U [m/s] "
              "| east [m] | north [m] | height [m] |", "|---" * 10 + "|"]
        keys = ("heading_deg", "rot_e_deg", "rot_n_deg", "vel_e_mps", "vel_n_mps", "vel_u_mps", "east_m", "north_m", "h_m")
        for name, s in est.items():
            cells = [f"{_f(s['sigma'][k]['p50'])} / {_f(s['sigma'][k]['p95'])} / {_f(s['sigma'][k]['max'])}" for k in keys]
            L.append(f"| {name} | " + " | ".join(cells) + " |")
    nis = {n: s for n, s in est.items() if "nis" in s}
    if nis:
        L += ["", "## Innovations (NIS)", "",
              f"Per epoch NIS = nu' S^-1 nu, chi^2(dof) for a consistent filter. Outside the per-epoch bounds: "
              f"{(1 - Q.PROB) / 2:.1%} of the epochs on each side by chance. Windowed: sum NIS / sum dof over {Q.WINDOW_S:g} s "
              "against its bounds; above = sigmas optimistic (flag `inconsistent_innovations`), below = conservative. "
              "Mean nu^2/S per match: 1 when consistent.", "",
              "| antenna | epochs | dof | mean NIS/dof | epochs above / below bound | windowed above / below | mean nu^2/S per match |",
              "|---|---|---|---|---|---|---|"]
        for name, s in nis.items():
            d = s["nis"]
            pm = ", ".join(f"{k} {_f(v, 2)}" for k, v in d.get("per_match", {}).items())
            L.append(f"| {name} | {d['epochs']} | {d['dof']} | {_f(d['mean_per_dof'])} | {_pc(d['above_bound_fraction'])} / "
                     f"{_pc(d['below_bound_fraction'])} | {_pc(d['windowed_above_fraction'])} / {_pc(d['windowed_below_fraction'])} "
                     f"| {pm} |")
    sep = {n: s for n, s in nis.items() if s.get("separation")}
    if sep:
        L += ["", "## Forward/backward separation", "",
              "Filtered minus smoothed estimate per epoch: the largest difference, the largest as RMS sigmas of its "
              "covariance P_f - P_s (chi^2 per dof), and the epochs beyond its 99 % bound (1 % by chance).", "",
              "| antenna | attitude | velocity | position |", "|---|---|---|---|"]
        for name, s in sep.items():
            cells = [f"{_f(g['max_diff'])} {g['unit']} ({_f(g['max_sigmas'], 2)} sigma; {_pc(g['beyond_bound_fraction'])})"
                     for g in (s["separation"][k] for k in ("attitude", "velocity", "position"))]
            L.append(f"| {name} | " + " | ".join(cells) + " |")
    fits = {n: s for n, s in est.items() if "wing_fit" in s}
    if fits:
        L += ["", "## Wing fit (antennas without IMU)", "",
              "No innovations: the least-squares fit's own residuals. Variance factor (chi^2 / dof of the fit) and "
              "the leave-one-out cross-validation score (mean squared residual over its sigma) of the chosen degree, "
              "per component: 1 when the sub-IMUs' sigmas describe their scatter about the fit.", "",
              "| antenna | variance factor (max, component) | cross-validation score (max, component) |", "|---|---|---|"]
        for name, s in fits.items():
            w = s["wing_fit"]
            cells = []
            for key in ("variance_factor", "cv_score"):
                d = w.get(key) or {}
                if d:
                    k = max(d, key=lambda c: d[c])
                    cells.append(f"{_f(d[k])} ({k})")
                else:
                    cells.append("—")
            L.append(f"| {name} | " + " | ".join(cells) + " |")
    if est:
        names = [nm for nm in F.NAMES.values() if any(nm in s["flags"] for s in est.values())]
        if names:
            L += ["", "## Flagged time", "", "| antenna | " + " | ".join(f"`{nm}`" for nm in names) + " |", "|---" * (len(names) + 1) + "|"]
            for name, s in est.items():
                cells = [f"{s['flags'][nm]['time_s']:.0f} s ({_pc(s['flags'][nm]['fraction'])})" if nm in s["flags"] else "—" for nm in names]
                L.append(f"| {name} | " + " | ".join(cells) + " |")
        notes = {n: s["notes"] for n, s in est.items() if s.get("notes")}
        if notes:
            L += ["", "## Notes", ""] + [f"- {n}: " + "; ".join(v) for n, v in notes.items()]
    return "\n".join(L) + "\n"


_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")
_MATH_POWER = re.compile(r"^\$\\mathdefault\{(?:(\d+)\\times)?(\d+)\^\{((?:-|\\minus)?\d+)\}\}\$$")


def _plain_power(label: str) -> str:
    """A log axis's mathtext label ``$\\mathdefault{[c\\times]10^{e}}$`` as plain text ``[c×]10ᵉ``
    (superscript digits; another label as it is)."""
    m = _MATH_POWER.match(label)
    if m is None:
        return label
    c, base, e = m.groups()
    return (f"{c}×" if c else "") + base + e.replace("\\minus", "-").translate(_SUPERSCRIPT)


def _plain_log_labels(ax) -> None:
    """The log y-axis of ``ax`` labelled as matplotlib's default (``LogFormatterSciNotation``) but in
    plain text: a figure's renderer parses every mathtext label anew (its own parser: ~20 ms a label
    with pyparsing).  Over more than a decade (the minor ticks unlabelled) without its minor ticks
    (the tick objects are most of the figure's time; the major ticks and the grid stay)."""
    from matplotlib.ticker import LogFormatterSciNotation, NullLocator

    class Plain(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return _plain_power(super().__call__(x, pos))

    ax.yaxis.set_major_formatter(Plain(10.0))
    ax.yaxis.set_minor_formatter(Plain(10.0, labelOnlyBase=False))
    lo, hi = ax.get_ylim()
    if lo > 0 and hi > 0 and abs(math.log10(hi / lo)) > 1.0:
        ax.yaxis.set_minor_locator(NullLocator())


def plot_qc(path: Path, a: AntennaSolution, b: RowBlock, method: str) -> Path:
    """Antenna ``a``'s QC figure from its rows ``b`` (all, or every n-th): its 1-sigma over time per
    group, NIS per dof with its bounds (per epoch and windowed), the forward/backward separation in
    RMS sigmas, and the flags as bands."""
    from matplotlib.figure import Figure

    t, s = b.traj.t_s, b.sigma
    step = max(1, t.size // MAX_PLOT_POINTS)
    td, sd = t[::step], s[::step]
    fig = Figure(figsize=(10, 12))  # no pyplot: figures may be drawn in threads at once (thread-pool executors)
    axs = fig.subplots(6, 1, sharex=True, gridspec_kw={"height_ratios": [1, 1, 1, 1.2, 1, 0.7]})
    fig.subplots_adjust(left=0.16, right=0.98, top=0.97, bottom=0.05, hspace=0.12)  # (constrained layout: 3 s a figure)
    groups = ((0, "attitude 1-sigma [deg]", ((2, "heading"), (0, "rot E"), (1, "rot N")), 1 / DEG),
              (1, "velocity 1-sigma [m/s]", ((3, "E"), (4, "N"), (5, "U")), 1.0),
              (2, "position 1-sigma [m]", ((6, "E"), (7, "N"), (8, "U")), 1.0))
    for i, lab, comps, scale in groups:
        for c, cl in comps:
            axs[i].semilogy(td, sd[:, c] * scale, lw=0.8, label=cl)
        axs[i].set(ylabel=lab)
        axs[i].legend(loc="upper right", fontsize=7, ncol=3)
    q = a.qc
    ax = axs[3]
    if q is not None and q.epochs_s.size:
        ok = np.isfinite(q.nis) & (q.dof > 0)
        te, r = q.epochs_s[ok], q.nis[ok] / q.dof[ok]
        lo, hi = Q.chi2_bounds(q.dof[ok])
        ax.semilogy(te, np.maximum(r, 1e-6), ".", ms=2, color="0.55", label="NIS / dof per epoch")
        ax.plot(te, hi / q.dof[ok], color="0.55", lw=0.6, ls="--", label=f"per-epoch {Q.PROB:.0%} bounds")
        ax.plot(te, lo / q.dof[ok], color="0.55", lw=0.6, ls="--")
        w, wlo, whi = Q.windowed_nis(q.epochs_s, q.nis, q.dof)
        ax.plot(q.epochs_s, w, color="C0", lw=1.2, label=f"windowed ({Q.WINDOW_S:g} s)")
        ax.fill_between(q.epochs_s, wlo, whi, color="C0", alpha=0.2, label="windowed bounds")
        ax.axhline(1.0, color="k", lw=0.5)
        if te.size:  # (the first epoch's NIS is 0: the sub-IMU starts at the main POS; out of view)
            ax.set_ylim(0.3 * float(np.min(lo / q.dof[ok])), 2.0 * max(float(np.max(hi / q.dof[ok])), float(np.nanmax(r))))
        ax.legend(loc="upper right", fontsize=7, ncol=2)
    else:
        ax.text(0.5, 0.5, "no innovations (least-squares wing fit)" if a.wing_fit is not None else "no innovations",
                transform=ax.transAxes, ha="center", va="center")
    ax.set(ylabel="NIS / dof")
    ax = axs[4]
    if q is not None and q.smoothed:
        for j, (g, _) in enumerate(Q.GROUPS):
            has = q.sep_dof[:, j] > 0
            ax.plot(q.epochs_s[has], np.sqrt(q.sep[has, j] / q.sep_dof[has, j]), lw=0.8, label=g)
        bound = math.sqrt(float(Q.chi2_ppf(Q.PROB, 3)) / 3)
        ax.axhline(bound, color="k", lw=0.6, ls="--", label="99 % bound (3 dof)")
        top = np.nanmax(np.sqrt(q.sep / np.maximum(q.sep_dof, 1)), initial=0.0)
        ax.set_ylim(0.0, 1.15 * max(bound, float(top)))
        ax.legend(loc="upper right", fontsize=7, ncol=4)
    else:
        ax.text(0.5, 0.5, "no backward pass (forward-only method or wing fit)", transform=ax.transAxes, ha="center", va="center")
    ax.set(ylabel="fwd/bwd separation\n[RMS sigmas]")
    ax = axs[5]
    fl = np.asarray(b.flags, dtype=np.uint32)
    names = list(F.NAMES.items())
    for row, (bit, _) in enumerate(names):
        m = (fl[::step] & np.uint32(bit)) != 0
        if np.any(m):
            ax.fill_between(td, row - 0.4, row + 0.4, where=m, step="mid", color=f"C{row % 10}", lw=0)
    ax.set_yticks(range(len(names)), [nm for _, nm in names], fontsize=7)
    ax.set_ylim(-0.6, len(names) - 0.4)
    ax.set(xlabel="t [s]")
    for x in axs:
        x.grid(alpha=0.3)
        if x.get_yscale() == "log":
            _plain_log_labels(x)
    axs[0].set_title(f"antenna {a.name}: {method.upper()} quality control (no truth)")
    fig.savefig(path, dpi=80)
    return path
