"""SAR scene-matching fixes and barometric heights of a simulated session ([Yan2016] sec. 2.2).

The fix model (the scenario's ``sar:`` block, :class:`~.scenario.SarAidingConfig`; docs/sar.md):

* SAR: one fix every ``1 / rate_hz`` s (at ``i / rate_hz``, i >= 1) while the radar images - inside
  one of the scenario's ``imaging_segments`` (the whole flight when it lists none; no fix in the
  turns of paper_sar, where a side-looking SAR does not image).  A fix is the main body's true
  latitude and longitude plus white north/east noise of ``pos_sigma_m`` and its true heading plus
  white noise of ``heading_sigma_deg`` (scene matching against a geo-referenced map: no drift).
* Barometer: every ``1 / baro_rate_hz`` s over the whole flight, the true height plus white noise
  of ``baro_sigma_m``.

Each stream draws from its own random stream of the session (``sar``, ``baro``).  The series types
(:class:`~dpos_core.series.SarFixes`, :class:`~dpos_core.series.BaroSeries`) are the
navigation's inputs, whatever their source.
"""

from __future__ import annotations

import numpy as np

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..series import BaroSeries, SarFixes
from .scenario import SarAidingConfig
from .session import SimulatedSession

__all__ = ["BaroSeries", "SarFixes", "baro_heights", "imaging_mask", "sar_config", "sar_fixes"]


def sar_config(ss: SimulatedSession) -> SarAidingConfig:
    """The session scenario's ``sar:`` block; ValueError if it has none."""
    cfg = ss.scenario.sar
    if cfg is None:
        raise ValueError(f"scenario {ss.scenario.name!r} has no sar: block (SAR/baro aiding)")
    return cfg


def imaging_mask(ss: SimulatedSession, t_s: FloatArray) -> np.ndarray:
    """True where the radar images at t_s (inside an imaging segment; everywhere if none)."""
    names = [n for n in ss.scenario.imaging_segments if n in {s.name for s in ss.scenario.segments}]
    if not names:
        return np.ones(t_s.shape, dtype=bool)
    ok = np.zeros(t_s.shape, dtype=bool)
    for n in names:
        a, b = ss.flight.segment_bounds(n)
        ok |= (t_s >= a) & (t_s <= b)
    return ok


def sar_fixes(ss: SimulatedSession) -> SarFixes:
    """The SAR fixes of the session (module docstring)."""
    cfg = sar_config(ss)
    t = ss.sample_times(cfg.rate_hz)
    t = t[imaging_mask(ss, t)]
    tr = ss.truth("master", t)
    rng = ss.rng("sar")
    n = t.shape[0]
    d_enu = np.zeros((n, 3))
    d_enu[:, :2] = rng.normal(0.0, cfg.pos_sigma_m, (n, 2))
    llh = tr.llh + earth.enu_to_dllh(d_enu, tr.llh)
    hdg = tr.hpr_rad[:, 0] + rng.normal(0.0, cfg.heading_sigma_deg * DEG, n)
    return SarFixes(t, llh, np.mod(hdg, 2.0 * np.pi), cfg.pos_sigma_m, cfg.heading_sigma_deg * DEG)


def baro_heights(ss: SimulatedSession) -> BaroSeries:
    """The barometric heights of the session (module docstring)."""
    cfg = sar_config(ss)
    t = ss.sample_times(cfg.baro_rate_hz)
    tr = ss.truth("master", t)
    h = tr.llh[:, 2] + ss.rng("baro").normal(0.0, cfg.baro_sigma_m, t.shape[0])
    return BaroSeries(t, h, cfg.baro_sigma_m)
