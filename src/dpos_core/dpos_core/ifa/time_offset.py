"""The constant GNSS-IMU time offset, estimated where the data make it observable.

A fix stamped ``t`` on the receiver's clock is the antenna at ``t - offset`` on the IMU's clock
(:func:`~dpos_core.ifa.pipeline.fix_at`). A wrong offset ``e`` moves every fix along the track by
``v e`` (15 m/s, 50 ms: 0.75 m) and the velocity by ``a e``: the innovations grow with it. The
estimate is the offset whose alignment has the smallest innovations: the run is repeated for
candidate offsets with the fixed-noise filter (``dd2``: the adaptive ADD2 would absorb the misfit
into its R) and the sum of the normalized innovations squared

    J(offset) = sum_k nu_k^T S_k^-1 nu_k          (-2 log-likelihood up to the log det S terms,
                                                  which the offset barely changes)

over the epochs after the alignment is taken; a parabola through the smallest J and its two
neighbours gives the estimate and its 1 sigma, sqrt(2 / J'') (the profile likelihood's curvature),
times sqrt(s) where s = max(1, J_min / (p K)) is the reduced chi-square of the K epochs of p
measurements: a filter whose R is too small for the data (NIS above its dof) would otherwise claim
a too precise offset (a quasi-likelihood, as a least-squares fit with an unknown noise scale).
The offset is observable only when the vehicle moves and accelerates enough for the GNSS noise:
when J does not rise by ``MIN_RISE`` s (a 3 sigma likelihood ratio) within the searched span on both
sides of its minimum the result says so (``observable`` False) and the value must not be used.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dpos_core.units import FloatArray

from ..series import GnssSeries, ImuSeries
from ..strapdown import NavState
from .model import IfaFilterConfig
from .pipeline import run

#: rise of J on both sides of the minimum (within the span) for an observable offset: 9 = 3 sigma
MIN_RISE = 9.0


@dataclass(frozen=True)
class TimeOffsetEstimate:
    """offsets_s (M,) the candidates, cost (M,) J of each (epochs_used of them), offset_s the
    estimate [s] and sigma_s its 1 sigma (nan when not observable), observable, reduced_chi2: see
    the module."""

    offsets_s: FloatArray
    cost: FloatArray
    epochs_used: int
    offset_s: float
    sigma_s: float
    observable: bool
    reduced_chi2: float  #: J_min / (p K), at least 1: the scale of the sigma

    def lines(self) -> list[str]:
        curve = ", ".join(f"{o * 1e3:+.0f} ms: {c:.1f}" for o, c in zip(self.offsets_s, self.cost))
        head = (f"GNSS-IMU time offset: {self.offset_s * 1e3:+.1f} ms +- {self.sigma_s * 1e3:.1f} ms (1 sigma)"
                if self.observable else
                f"GNSS-IMU time offset: not observable on this data (J rises by less than {MIN_RISE:g} within "
                f"[{self.offsets_s[0] * 1e3:+.0f}, {self.offsets_s[-1] * 1e3:+.0f}] ms of its minimum at "
                f"{self.offset_s * 1e3:+.1f} ms): keep gnss_time_offset_s from the installation")
        if self.observable:
            head += (f"; set gnss_time_offset_s: {self.offset_s:.4f} (dpos-ifa --gnss-time-offset {self.offset_s * 1e3:.1f}), "
                     "as it is: the candidates replace the configured offset, they are not added to it")
        return [head, f"sum of NIS over {self.epochs_used} epochs by offset (reduced chi-square at the minimum "
                      f"{self.reduced_chi2:.2f}): {curve}"]


def estimate_time_offset(imu: ImuSeries, gnss: GnssSeries, lever_arm_m: FloatArray, cfg: IfaFilterConfig, initial: NavState,
                         offsets_s: FloatArray, since_s: float | None = None) -> TimeOffsetEstimate:
    """Estimate the constant GNSS-IMU time offset (module docstring).

    Args:
        imu, gnss, lever_arm_m, cfg, initial: as :func:`~dpos_core.ifa.pipeline.run` (``cfg``'s own
            ``gnss_time_offset_s`` is replaced by each candidate).
        offsets_s: (M,) candidate offsets [s], increasing, evenly spaced, M >= 3.
        since_s: epochs from this IMU time on enter J; default: the alignment time of the run at
            the middle candidate, else the second half of the data.
    """
    off = np.asarray(offsets_s, dtype=float)
    if off.ndim != 1 or off.size < 3 or np.any(np.diff(off) <= 0):
        raise ValueError(f"offsets_s must be (M,) increasing with M >= 3, got {off}")
    step = np.diff(off)
    if not np.allclose(step, step[0], rtol=1e-6, atol=1e-12):
        raise ValueError("offsets_s must be evenly spaced")
    results = [run(imu, gnss, lever_arm_m, replace(cfg, gnss_time_offset_s=float(o)), "dd2", initial) for o in off]
    if since_s is None:
        mid = results[off.size // 2]
        since_s = mid.aligned_t_s if mid.aligned_t_s is not None else float(imu.t_s[0] + 0.5 * (imu.t_s[-1] - imu.t_s[0]))
    # the same epochs (by the fixes' stamps) in every run: the fix stamps move with the offset
    used = [set(np.round(np.asarray(r.epochs_s) + o, 6)[np.asarray(r.epochs_s) >= since_s]) for r, o in zip(results, off)]
    common = set.intersection(*used)
    cost = np.array([float(np.sum(np.asarray(r.nis)[np.isin(np.round(np.asarray(r.epochs_s) + o, 6), list(common))]))
                     for r, o in zip(results, off)])
    i = int(np.argmin(cost))
    j = min(max(i, 1), off.size - 2)
    a, b, _ = np.polyfit(off[j - 1:j + 2], cost[j - 1:j + 2], 2)
    p = results[0].R_diag.shape[1] if np.ndim(results[0].R_diag) == 2 else 6
    scale = max(1.0, float(cost[i]) / max(p * len(common), 1))  # the reduced chi-square (module docstring)
    est, sigma = float(off[i]), float("nan")
    if a > 0:
        est = float(np.clip(-b / (2 * a), off[j - 1], off[j + 1]))
        sigma = float(np.sqrt(scale * 2.0 / (2.0 * a)))  # J'' = 2a; -2 log L = J / scale: var = 2 scale / J''
    observable = bool(a > 0 and 0 < i < off.size - 1 and cost[:i].max() - cost[i] >= MIN_RISE * scale
                      and cost[i + 1:].max() - cost[i] >= MIN_RISE * scale)
    return TimeOffsetEstimate(off, cost, len(common), est, sigma if observable else float("nan"), observable, scale)


__all__ = ["TimeOffsetEstimate", "estimate_time_offset", "MIN_RISE"]
