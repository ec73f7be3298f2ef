"""The main POS smoothed offline: forward-backward (RTS) smoothing of the in-flight alignment.

The forward pass is :func:`dpos_core.ifa.pipeline.run` with ``record_smoother=True``: the final
heading hypothesis keeps, at every filter step (GNSS update or time update alone), a
:class:`~dpos_core.ifa.pipeline.SmootherStep` - its filtered mean / covariance after the
closed-loop feedback, the prediction to the step and the cross-covariance with the previous step
(the divided-difference ``C = S S_x1^T`` of DD2 / ADD2, the same Stirling cross-covariance as the
CDKF / URTSS of the transfer alignment; ``P F^T`` for AEKF), both re-expressed after the step's
feedback - and its nominal (the closed-loop strapdown at the IMU rate, before each feedback).

:func:`smooth` runs the ONE RTS recursion of the package
(:func:`dpos_core.filters.runners.smooth_gaussian` on a :class:`~dpos_core.filters.runners.GaussianTrack`)
over the steps.  The fine phase of the alignment restarts its covariance from a prior
(:mod:`.pipeline`): the chain breaks there, so the steps are smoothed in segments, the last one
(the fine phase from its restart) first; an earlier segment (the coarse phase) then ends at the
later one's smoothed estimate at the restart instead of its own filtered one there (the RTS
recursion's terminal condition: the estimate given all the data, of which the coarse filter's
own - heading sigma about 1 deg at the restart - adds next to nothing; left out, not fused).

Navigation at the IMU rate: the smoothed error states (position, velocity, attitude) are
interpolated linearly in time between consecutive steps - from the step's error after its feedback
to the next step's error before its feedback (the shift undone) - the position error as the
integral of that interpolated velocity error (``d dp / dt = dv``) with what is left of its
end-to-end change spread linearly - and removed from the nominal
(``C_nb = expm([phi x]) C_nb_nominal``, ``v - dv``, position minus ``dp``), as the transfer
alignment's ``_apply`` does; the covariances are interpolated linearly.  In an outage the steps
are the time updates alone, ``IfaFilterConfig.predict_interval_s`` (1.5 s) apart, so the outage
is bridged from both ends by the RTS recursion itself, the interpolation spanning 1.5 s at most
(on mems_vehicle the smoothed error mid-way between two steps of the 30 s outage is that at the
steps to 1 %: test/dpos_core/ifa/test_smoother.py).  After the last step
the nominal is corrected by the last step's estimate (the forward one: nothing comes after).
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import replace as dc_replace

import numpy as np

from dpos_core.units import FloatArray

from .. import earth
from ..attitude import compose_rotvec, dcm_to_quat, quat_to_dcm, rotvec_to_dcm
from ..filters.runners import GaussianTrack, smooth_gaussian
from ..series import ImuSeries, NavSeries
from .mechanization import body_rate_eb
from .model import DP, DV, N_FULL, PHI
from .pipeline import IfaResult, SmootherStep


@dataclass
class SmoothedIfa:
    """The smoothed main POS of one in-flight alignment.

    nav: the smoothed navigation at the IMU rate (the rows of the final hypothesis' nominal, with
    ``omega_eb_b_radps`` and the attitude / velocity / position covariances) - the type of a
    recorded ``/master/nav``; forward: the same rows, forward only (the closed-loop strapdown the
    node publishes, covariance interpolated between the filtered and the next predicted one);
    steps_s (K,): the filter steps; x_s (K, n), P_s (K, n, n): the smoothed error states after
    each step's feedback; segments: [(first, last)] step indices smoothed as one chain.
    """

    nav: NavSeries
    forward: NavSeries
    steps_s: FloatArray
    x_s: FloatArray
    P_s: FloatArray
    segments: list[tuple[int, int]]


def segments(steps: list[SmootherStep]) -> list[tuple[int, int]]:
    """``[(first, last)]`` step indices of the chains: a restart at step r ends one at r and starts
    the next at r."""
    cuts = [0] + [k for k, s in enumerate(steps) if s.restart is not None and 0 < k < len(steps) - 1] + [len(steps) - 1]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True)] if len(steps) > 1 else [(0, 0)]


def track_of(steps: list[SmootherStep], first: int, last: int) -> GaussianTrack:
    """The :class:`~dpos_core.filters.runners.GaussianTrack` of steps ``first..last`` (inclusive):
    the first step's filtered state is its restart (if it restarted), the others' their filtered
    state before any restart."""
    seg = steps[first:last + 1]
    K, n = len(seg), seg[0].x_f.shape[0]
    x0, P0 = seg[0].restart if (seg[0].restart is not None and K > 1) else (seg[0].x_f, seg[0].P_f)
    x_f = np.stack([x0] + [s.x_f for s in seg[1:]])
    P_f = np.stack([P0] + [s.P_f for s in seg[1:]])
    if K > 1:
        missing = [s.t_s for s in seg[1:] if s.x_p is None or s.P_p is None or s.C is None]
        if missing:
            raise ValueError(f"smoother steps without a prediction at t = {missing[:3]} s")
        x_p = np.stack([s.x_p for s in seg[1:]])  # type: ignore[misc]
        P_p = np.stack([s.P_p for s in seg[1:]])  # type: ignore[misc]
        C = np.stack([s.C for s in seg[1:]])  # type: ignore[misc]
    else:
        x_p, P_p, C = np.empty((0, n)), np.empty((0, n, n)), np.empty((0, n, n))
    corr = np.stack([s.correction for s in seg])
    return GaussianTrack(x_f, P_f, x_p, P_p, C, corr, np.full((K, 0), np.nan), np.full((K, 0, 0), np.nan))


def _unshift(x24: FloatArray, c24: FloatArray) -> FloatArray:
    """Navigation errors (..., 9) before a feedback ``c``: the inverse of the model's shift."""
    out = x24[..., :9].copy()
    out[..., PHI] = compose_rotvec(x24[..., PHI], c24[..., PHI])
    out[..., DV] = x24[..., DV] + c24[..., DV]
    out[..., DP] = x24[..., DP] + c24[..., DP]
    return out


def smooth(result: IfaResult, imu: ImuSeries) -> SmoothedIfa:
    """Smooth a forward run (``run(..., record_smoother=True)``; module docstring) and apply it to
    the navigation at the IMU rate.  ``imu``: the series the run used (body rates of the output)."""
    eng = result.engine
    if eng is None or eng.smoother_steps is None:
        raise ValueError("the in-flight alignment was run without record_smoother=True: nothing to smooth")
    steps = eng.smoother_steps
    model = eng.model
    K, n = len(steps), model.n
    segs = segments(steps)
    x_s, P_s = np.empty((K, n)), np.empty((K, n, n))
    x_end, P_end = np.empty((K, n)), np.empty((K, n, n))  # the estimate closing the interval before each step
    Pp_end = np.empty((K, n, n))  # forward: the prediction to each step
    for first, last in reversed(segs):  # the later chain first: its smoothed estimate at the restart closes the earlier one
        tr = track_of(steps, first, last)
        if last < K - 1:
            tr.x_f[-1], tr.P_f[-1] = x_s[last], P_s[last]
        xs, Ps = smooth_gaussian(tr)
        x_end[first + 1:last + 1], P_end[first + 1:last + 1] = xs[1:], Ps[1:]
        if first == 0:
            x_end[0], P_end[0] = xs[0], Ps[0]
        x_s[first:last + 1], P_s[first:last + 1] = xs, Ps
    for j, st in enumerate(steps):
        Pp_end[j] = st.P_p if st.P_p is not None else st.P_f
    Pf_start = np.stack([s.restart[1] if s.restart is not None else s.P_f for s in steps])
    T = np.array([s.t_s for s in steps])
    corr = model.full(np.stack([s.correction for s in steps]))
    E = model.full(np.eye(n))[:, :N_FULL]  # (n, 15): the navigation part of a covariance
    nav9 = lambda P: (E.T @ P @ E)[..., :9, :9]  # noqa: E731

    # the nominal rows (the final hypothesis' closed-loop strapdown, before each feedback)
    init = eng.initial
    chunks = [NavSeries(np.array([init.t_s]), init.q_nb[None], init.vel_n_mps[None], init.llh[None])] + list(model.chunks)
    nom = NavSeries.concatenate(chunks)
    t = nom.t_s
    k = np.clip(np.searchsorted(T, t, side="left") - 1, 0, K - 1)  # T_k < t <= T_k+1
    k1 = np.minimum(k + 1, K - 1)
    span = T[k1] - T[k]
    a = np.where(span > 0.0, (t - T[k]) / np.where(span > 0.0, span, 1.0), 0.0)
    a = np.clip(a, 0.0, 1.0)[:, None]
    a[t <= T[0]] = 0.0
    a[k == K - 1] = 0.0

    gb = result.gyro_bias_radps
    ti = np.asarray(imu.t_s, dtype=float)
    w_ib = np.asarray(imu.omega_radps, dtype=float)[np.clip(np.searchsorted(ti, t - 1e-9), 0, ti.size - 1)] - gb
    av = a[:, :, None]

    def cov9(P_start: FloatArray, P_close: FloatArray) -> FloatArray:
        return (1.0 - av) * nav9(P_start)[k] + av * nav9(P_close)[k1]

    e0 = model.full(x_s)[:, :9]
    e1 = _unshift(model.full(x_end), corr)
    err = (1.0 - a) * e0[k] + a * e1[k1]
    # position: the integral of the interpolated velocity error (d dp / dt = dv), what is left of the
    # end-to-end change spread linearly; the linear interpolation above plus -(dv1 - dv0) tau (T - tau) / 2T
    tau = a[:, 0] * span
    err[:, DP] -= (e1[k1][:, DV] - e0[k][:, DV]) * (tau * (span - tau) / (2.0 * np.where(span > 0.0, span, 1.0)))[:, None]
    q = dcm_to_quat(rotvec_to_dcm(err[:, PHI]) @ quat_to_dcm(nom.q_nb))
    llh = nom.llh - earth.enu_to_dllh(err[:, DP], nom.llh)
    vel = nom.vel_n_mps - err[:, DV]
    P9 = cov9(P_s, P_end)
    smoothed = NavSeries(t.copy(), q, vel, llh, omega_eb_b_radps=body_rate_eb(q, llh, vel, w_ib), att_cov=P9[:, 6:9, 6:9].copy(),
                         vel_cov=P9[:, 3:6, 3:6].copy(), pos_cov=P9[:, 0:3, 0:3].copy())
    # forward: the nominal, corrected at each step by its feedback (the filtered navigation errors
    # after it are zero), with the filter's covariance from each step's filtered one to the next
    # step's prediction
    F9 = cov9(Pf_start, Pp_end)
    at_step = (a[:, 0] == 1.0) & (np.abs(t - T[k1]) < 1e-9)  # the row of a step: the corrected state (as run() outputs)
    c9 = np.where(at_step[:, None], corr[k1, :9], 0.0)
    qf = dcm_to_quat(rotvec_to_dcm(c9[:, PHI]) @ quat_to_dcm(nom.q_nb))
    llhf = nom.llh - earth.enu_to_dllh(c9[:, DP], nom.llh)
    velf = nom.vel_n_mps - c9[:, DV]
    fwd = NavSeries(t.copy(), qf, velf, llhf, omega_eb_b_radps=body_rate_eb(qf, llhf, velf, w_ib), att_cov=F9[:, 6:9, 6:9].copy(),
                    vel_cov=F9[:, 3:6, 3:6].copy(), pos_cov=F9[:, 0:3, 0:3].copy())
    return SmoothedIfa(smoothed, fwd, T, x_s, P_s, segs)


def as_result(result: IfaResult, nav: NavSeries) -> IfaResult:
    """``result`` with its navigation replaced by ``nav`` (:attr:`SmoothedIfa.nav` or ``.forward``)
    and its ``track`` the covariance ``nav`` carries at every row ((9, 9): position, velocity,
    attitude blocks, no cross terms): what :func:`~dpos_core.ifa.reference.compare` and
    :func:`~dpos_core.ifa.reference.track_sigmas` score (the smoothed sigma of each row, where the
    forward run's track holds the filter epochs' only)."""
    if nav.pos_cov is None or nav.vel_cov is None or nav.att_cov is None:
        raise ValueError("as_result needs a navigation with its position, velocity and attitude covariances")
    P = np.zeros((nav.t_s.size, 9, 9))
    P[:, 0:3, 0:3], P[:, 3:6, 3:6], P[:, 6:9, 6:9] = nav.pos_cov, nav.vel_cov, nav.att_cov
    return dc_replace(result, t_s=nav.t_s, llh=nav.llh, vel_n_mps=nav.vel_n_mps, q_nb=nav.q_nb,
                      track=[(float(t), p) for t, p in zip(nav.t_s, P, strict=True)])


__all__ = ["SmoothedIfa", "as_result", "smooth", "segments", "track_of"]
