"""A sub-IMU log's clock against the main navigation solution, from the data.

A logger without a time reference (a device counter only) is placed on GPS time by matching
the magnitude of its angular rate - independent of the unknown mounting - with the magnitude of
the main solution's attitude rate (:func:`attitude_rates`):

1. coarse: a normalized (Pearson) cross-correlation of the two magnitude series on a common grid
   (the main solution's sample interval), every lag of a partial or full overlap, by FFT
   (masked normalized cross-correlation, Padfield 2012, "Masked object registration in the
   Fourier domain", IEEE TIP 21(5));
2. refinement: the correlation with the sub-IMU's rates averaged over exactly the main
   solution's intervals (:func:`interval_means`) on a fine grid of offsets about the coarse
   peak, the peak located by a parabola through its neighbours, in each of several windows of
   the log; a straight line through the windows' offsets gives the offset at the log's middle
   and, for a long enough log, the drift; their sigmas are the line fit's standard errors.

The offset maps the device time to GPST: ``t_gpst = t_dev + offset + drift (t_dev - t_ref)``.
When the main solution does not turn (no manoeuvre), or the correlation has no clear peak, the
offset is not observable: :class:`ClockNotObservable` says why instead of a guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..attitude import dcm_to_rotvec
from ..errors import ClockNotObservable
from ..units import DEG, FloatArray

_NS = 1_000_000_000


@dataclass(frozen=True)
class ClockSettings:
    """Limits of the clock estimation.

    Attributes:
        min_rate_std_dps: the main solution's angular-rate magnitude must vary at least this much
            (rms about its mean over the overlap) [deg/s]; below: no manoeuvre.
        min_peak: smallest correlation coefficient accepted at the peak.
        max_second_peak: a second peak (more than ``peak_exclusion_s`` away) this close to the
            first (ratio) makes the offset ambiguous.
        min_overlap: smallest overlap of the logs as a fraction of the shorter one (coarse search).
        window_s: refinement window length [s] (at least three windows: shorter for a short log).
        drift_min_s: a log at least this long also gets a drift estimate.
        search_s: (low, high) bounds of the offset [s], or None = every overlap.
    """

    min_rate_std_dps: float = 1.0
    min_peak: float = 0.5
    max_second_peak: float = 0.9
    peak_exclusion_s: float = 1.0
    min_overlap: float = 0.8
    window_s: float = 30.0
    drift_min_s: float = 100.0
    search_s: tuple[float, float] | None = None


@dataclass(frozen=True)
class ClockEstimate:
    """Offset (and drift) of a device clock: ``t_gpst = t_dev + offset_s + drift (t_dev - t_ref_dev_s)``.

    Attributes:
        offset_s, offset_sigma_s: offset at ``t_ref_dev_s`` (the log's middle) and its 1 sigma [s].
        drift, drift_sigma: clock drift [s/s] (0 with sigma None when not estimated).
        peak: correlation coefficient at the coarse peak; second_peak: best one away from it.
        refined_peak: mean correlation of the refinement windows at their peaks.
        windows: (K, 3) per window: device time of its middle [s], offset [s], peak correlation.
        rate_std_dps: rms variation of the main solution's rate magnitude over the overlap [deg/s].
    """

    offset_s: float
    offset_sigma_s: float
    drift: float
    drift_sigma: float | None
    t_ref_dev_s: float
    peak: float
    second_peak: float
    refined_peak: float
    windows: FloatArray
    rate_std_dps: float

    def to_gpst_ns(self, t_dev_s: FloatArray, t0_dev_ns: int = 0) -> NDArray[np.int64]:
        """GPST [ns] of device times ``t_dev_s`` [s] (relative to ``t0_dev_ns``, an integer origin)."""
        t = np.asarray(t_dev_s, dtype=float)
        corr_s = self.offset_s + self.drift * (t - self.t_ref_dev_s)
        return t0_dev_ns + np.round((t + corr_s) * 1e9).astype(np.int64)


def attitude_rates(t_s: FloatArray, C_nb: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Body rate w.r.t. the navigation frame from successive attitudes.

    ``omega_k = log(C_nb[k]^T C_nb[k+1]) / (t[k+1] - t[k])`` (the mean rate over the interval, body
    axes). Returns (interval starts (N-1,), ends (N-1,), omega (N-1, 3) [rad/s]); t_s (N,), C_nb (N, 3, 3)."""
    dC = np.einsum("nji,njk->nik", C_nb[:-1], C_nb[1:])
    dt = np.diff(t_s)
    return t_s[:-1].copy(), t_s[1:].copy(), dcm_to_rotvec(dC) / dt[:, None]


def running_integral(t_s: FloatArray, omega: FloatArray) -> FloatArray:
    """Running integral (N, 3) of a rate series from its first sample (each sample the mean over the
    interval ending at its stamp)."""
    dt = np.diff(t_s)
    return np.vstack([np.zeros((1, omega.shape[1])), np.cumsum(omega[1:] * dt[:, None], axis=0)])


def interval_means(t_s: FloatArray, omega: FloatArray, a_s: FloatArray, b_s: FloatArray,
                   theta: FloatArray | None = None) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Mean of a rate series over the intervals [a, b]: the difference of its running integral
    (:func:`running_integral`, or ``theta`` precomputed) at the ends, divided by the length.
    t_s (N,), omega (N, 3); a_s, b_s (K,).  Returns (K, 3) and the mask (K,) of the intervals
    inside the series."""
    if theta is None:
        theta = running_integral(t_s, omega)
    inside = (a_s >= t_s[0]) & (b_s <= t_s[-1])
    out = np.full((a_s.size, omega.shape[1]), np.nan)
    if inside.any():
        a, b = a_s[inside], b_s[inside]
        ta = np.column_stack([np.interp(a, t_s, theta[:, j]) for j in range(omega.shape[1])])
        tb = np.column_stack([np.interp(b, t_s, theta[:, j]) for j in range(omega.shape[1])])
        out[inside] = (tb - ta) / (b - a)[:, None]
    return out, inside


def _pearson(x: FloatArray, y: FloatArray) -> float:
    if x.size < 3:
        return float("nan")
    xs, ys = x - x.mean(), y - y.mean()
    d = float(np.sqrt((xs * xs).sum() * (ys * ys).sum()))
    return float((xs * ys).sum() / d) if d > 0 else float("nan")


def masked_ncc(x: FloatArray, mx: FloatArray, y: FloatArray, my: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Pearson correlation of ``x`` (N,) and ``y`` (M,) over their overlap at every lag ``L`` (y[j]
    against x[L + j]), only where both masks (0/1, same shapes) are 1, by six FFT correlations.
    Returns (ncc, overlap counts), each (N + M - 1,) indexed by ``L + M - 1`` (L from -(M-1) to N-1);
    NaN where fewer than 3 samples overlap or either side is constant."""
    n, m = x.size, y.size
    size = int(2 ** np.ceil(np.log2(n + m)))

    def corr(a: FloatArray, b: FloatArray) -> FloatArray:
        c = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
        return np.concatenate([c[size - (m - 1):], c[:n]]) if m > 1 else c[:n]

    x0, y0 = x * mx, y * my
    cnt = np.round(corr(mx, my))
    sx, sy = corr(x0, my), corr(mx, y0)
    sxx, syy, sxy = corr(x0 * x, my), corr(mx, y0 * y), corr(x0, y0)
    with np.errstate(invalid="ignore", divide="ignore"):
        num = sxy - sx * sy / cnt
        den = np.sqrt(np.clip(sxx - sx * sx / cnt, 0, None) * np.clip(syy - sy * sy / cnt, 0, None))
        ncc = np.where((cnt >= 3) & (den > 0), num / den, np.nan)
    return ncc, cnt


def _parabola_peak(xs: FloatArray, ys: FloatArray) -> float:
    i = int(np.nanargmax(ys))
    if 0 < i < xs.size - 1 and np.all(np.isfinite(ys[i - 1:i + 2])):
        y0, y1, y2 = ys[i - 1:i + 2]
        den = y0 - 2 * y1 + y2
        if den < 0:
            return float(xs[i] + 0.5 * (y0 - y2) / den * (xs[1] - xs[0]))
    return float(xs[i])


def _no_manoeuvre(name: str, rate_std_dps: float, s: ClockSettings) -> ClockNotObservable:
    return ClockNotObservable(f"{name}: clock offset not observable: no manoeuvre (the main solution's angular rate varies by "
                              f"{rate_std_dps:.2f} deg/s rms, {s.min_rate_std_dps:g} needed); give the log's clock")


def estimate_clock(t_main_s: FloatArray, C_nb: FloatArray, t_dev_s: FloatArray, omega_dev: FloatArray,
                   settings: ClockSettings = ClockSettings(), name: str = "sub-IMU") -> ClockEstimate:
    """Offset (and drift) of a device clock against the main solution (module docstring).

    t_main_s (N,) main solution times [s, any origin shared with the result's offset], C_nb (N, 3, 3)
    its attitudes; t_dev_s (M,) device times [s], omega_dev (M, 3) its angular rates [rad/s].
    Raises :class:`ClockNotObservable` (the message names ``name``)."""
    s = settings
    a, b, w_main = attitude_rates(t_main_s, C_nb)
    dt = float(np.median(b - a))
    mag_main = np.linalg.norm(w_main, axis=1)
    # coarse: both magnitudes on grids of the main interval
    g = np.arange(t_main_s[0], t_main_s[-1] - dt + 1e-9, dt)
    mid = 0.5 * (a + b)
    xg = np.interp(g + 0.5 * dt, mid, mag_main)
    gap = np.interp(g + 0.5 * dt, mid, (b - a) > 1.5 * dt) > 0  # no rate across a gap of the solution
    mx = (~gap).astype(float)
    u = np.arange(t_dev_s[0], t_dev_s[-1] - dt + 1e-9, dt)
    if u.size < 10 or g.size < 10:
        raise ClockNotObservable(f"{name}: too short to place on the main solution ({u.size} and {g.size} intervals of {dt:.3f} s)")
    theta = running_integral(t_dev_s, omega_dev)
    wd, inside = interval_means(t_dev_s, omega_dev, u, u + dt, theta)
    yg = np.where(inside, np.linalg.norm(np.nan_to_num(wd), axis=1), 0.0)
    my = inside.astype(float)
    ncc, cnt = masked_ncc(xg, mx, yg, my)
    lags = np.arange(-(u.size - 1), g.size)
    taus = g[0] + lags * dt - u[0]  # t_gpst = t_dev + tau
    ok = cnt >= s.min_overlap * min(u.size, g.size)
    if s.search_s is not None:
        ok &= (taus >= s.search_s[0]) & (taus <= s.search_s[1])
    ncc = np.where(ok, ncc, np.nan)
    if not np.isfinite(ncc).any():
        if np.any(ok) and float(np.std(mag_main)) / DEG < s.min_rate_std_dps:
            raise _no_manoeuvre(name, float(np.std(mag_main)) / DEG, s)
        raise ClockNotObservable(f"{name}: the log does not overlap the main solution by {s.min_overlap:.0%} at any offset")
    i = int(np.nanargmax(ncc))
    tau0, peak = float(taus[i]), float(ncc[i])
    away = np.abs(taus - tau0) > s.peak_exclusion_s
    second = float(np.nanmax(ncc[away])) if np.isfinite(ncc[away]).any() else float("nan")
    # the main rate's variation over the overlap at the peak
    sel = (mid >= t_dev_s[0] + tau0) & (mid <= t_dev_s[-1] + tau0)
    rate_std = float(np.std(mag_main[sel]) / DEG) if sel.sum() > 2 else 0.0
    if rate_std < s.min_rate_std_dps:
        raise _no_manoeuvre(name, rate_std, s)
    if peak < s.min_peak:
        raise ClockNotObservable(f"{name}: clock offset not observable: best rate correlation {peak:.2f} < {s.min_peak:g}; "
                                 "give the log's clock")
    if np.isfinite(second) and second > s.max_second_peak * peak:
        raise ClockNotObservable(f"{name}: clock offset ambiguous: correlation {peak:.2f} at {tau0:+.3f} s and {second:.2f} at "
                                 f"{float(taus[away][np.nanargmax(ncc[away])]):+.3f} s; give the log's clock")
    # refinement in windows, exact interval means
    span = float(t_dev_s[-1] - t_dev_s[0])
    n_win = max(3, min(12, int(span // s.window_s)))
    edges = np.linspace(t_dev_s[0], t_dev_s[-1], n_win + 1)
    fine = np.arange(-2.0 * dt, 2.0 * dt + 1e-12, dt / 20.0)
    rows = []
    for k in range(n_win):
        rows_k = []
        for d in fine:
            tau = tau0 + d
            m = (a - tau >= edges[k]) & (b - tau <= edges[k + 1]) & ((b - a) < 1.5 * dt)
            if m.sum() < 10:
                rows_k.append(np.nan)
                continue
            wm, ins = interval_means(t_dev_s, omega_dev, a[m] - tau, b[m] - tau, theta)
            rows_k.append(_pearson(mag_main[m][ins], np.linalg.norm(wm[ins], axis=1)))
        r = np.array(rows_k)
        if np.isfinite(r).sum() >= 3 and np.nanmax(r) > 0:
            rows.append((0.5 * (edges[k] + edges[k + 1]), tau0 + _parabola_peak(fine, r), float(np.nanmax(r))))
    win = np.array(rows) if rows else np.zeros((0, 3))
    if len(win) < 3:
        raise ClockNotObservable(f"{name}: clock offset not observable: {len(win)} of {n_win} windows have a correlation peak")
    t_ref = 0.5 * float(t_dev_s[0] + t_dev_s[-1])
    x = win[:, 0] - t_ref
    wts = np.clip(win[:, 2], 1e-3, None) ** 2  # better-correlated windows weigh more
    fit_drift = span >= s.drift_min_s and len(win) >= 4
    A = np.column_stack([np.ones_like(x), x]) if fit_drift else np.ones((x.size, 1))
    W = np.sqrt(wts)[:, None]
    coef, *_ = np.linalg.lstsq(A * W, win[:, 1] * W[:, 0], rcond=None)
    res = win[:, 1] - A @ coef
    dof = max(1, x.size - A.shape[1])
    s2 = float((wts * res**2).sum() / dof)
    # floor: the refinement's resolution (a tenth of the fine step) so that a perfect fit is not exact
    s2 = max(s2, (dt / 200.0) ** 2 * float(wts.mean()))
    cov = s2 * np.linalg.inv((A * W).T @ (A * W))
    return ClockEstimate(offset_s=float(coef[0]), offset_sigma_s=float(np.sqrt(cov[0, 0])),
                         drift=float(coef[1]) if fit_drift else 0.0,
                         drift_sigma=float(np.sqrt(cov[1, 1])) if fit_drift else None,
                         t_ref_dev_s=t_ref, peak=peak, second_peak=second, refined_peak=float(win[:, 2].mean()),
                         windows=win, rate_std_dps=rate_std)


__all__ = ["ClockEstimate", "ClockNotObservable", "ClockSettings", "attitude_rates", "estimate_clock", "interval_means", "masked_ncc",
           "running_integral"]
