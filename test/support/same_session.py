"""Bit-for-bit comparison of two read sessions (the streaming readers against read_session)."""

from __future__ import annotations

import numpy as np

from dpos_core.series import ImuSeries, NavSeries
from dpos_ros.io.session import RecordedSession

_FIELDS = ("t_s", "q_nb", "vel_n_mps", "llh", "omega_eb_b_radps", "att_cov", "vel_cov", "pos_cov", "omega_radps", "f_mps2")


def same_series(a: ImuSeries | NavSeries, b: ImuSeries | NavSeries) -> None:
    """Every array of the two series present in both or neither, equal bit for bit with its dtype."""
    for name in _FIELDS:
        va, vb = getattr(a, name, None), getattr(b, name, None)
        assert (va is None) == (vb is None), name
        if va is not None:
            assert va.dtype == vb.dtype and np.array_equal(va, vb), name


def same_session(a: RecordedSession, b: RecordedSession) -> None:
    """The same series (main POS, sub-IMUs, truth), identity, metadata, warnings and datum."""
    same_series(a.master, b.master)
    assert a.sub_imus.keys() == b.sub_imus.keys() and a.truth.keys() == b.truth.keys()
    for k in a.sub_imus:
        same_series(a.sub_imus[k], b.sub_imus[k])
    for k in a.truth:
        same_series(a.truth[k], b.truth[k])
    assert (a.session_id, a.t0_ns, a.end_s, a.custom, a.master_mechanized) == (b.session_id, b.t0_ns, b.end_s, b.custom, b.master_mechanized)
    assert a.warnings == b.warnings
    assert np.array_equal(a.datum_llh, b.datum_llh)
