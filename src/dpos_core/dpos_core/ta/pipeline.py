"""Transfer alignment of one sub-IMU over a recorded session: forward filter, backward smoother,
and the smoothed trajectory at the IMU rate.

Methods: ``ukf`` (forward only), ``urtss`` (UKF + unscented RTS smoother), ``upf`` (forward
only), ``ups`` ([Gong2018]'s unscented particle smoother: the Rao-Blackwellized UPF - particles on
the flexure rate, every particle's UKF carrying the other 21 states - and its backward pass;
filters.runners explains the choice and what the literal variant measured).

Output at the IMU rate: the error estimates at the filter epochs are applied to the stored
nominal trajectory, linearly interpolated between epochs.  Within the interval after epoch k
the nominal was integrated from the state corrected at k, so its start error is the estimate at
k and its end error is the estimate at k + 1 before that epoch's correction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..attitude import compose_rotvec, dcm_to_quat, quat_to_dcm, rotvec_to_dcm
from ..filters.linalg import JitterRepairs
from ..filters.points import UnscentedPoints
from ..filters.runners import rb_smooth, run_sigma_point_filter, run_upf, smooth_gaussian
from ..frames import C_nb_from_hpr, hpr_from_C_nb
from ..series import ImuSeries, NavSeries
from ..strapdown import NavState
from .model import DP, DV, PHI, Installation, TAConfig, TransferAlignmentModel

METHODS = ("ukf", "urtss", "upf", "ups")
ORACLE = "oracle"  #: evaluation only (needs the simulation's truth), see .oracle


@dataclass
class TAResult:
    """Smoothed (or filtered) sub-IMU trajectory at the IMU rate and the epoch estimates.

    t_s (N,), llh (N, 3), vel_n_mps (N, 3), q_nb (N, 4); sigma (N, 9): 1-sigma of
    [phi (3, rad), dv (3, m/s), dp (3, m, ENU)]; epochs_s (K,), x (K, 24), P (K, 24, 24): the
    state estimates at the epochs (after their correction); method; particles; ess (K,) for PF;
    chol_jitter_repairs: Cholesky factors that needed a diagonal jitter (dpos_core.filters.linalg).
    """

    method: str
    t_s: FloatArray
    llh: FloatArray
    vel_n_mps: FloatArray
    q_nb: FloatArray
    sigma: FloatArray
    epochs_s: FloatArray
    x: FloatArray
    P: FloatArray
    ess: FloatArray | None = None
    chol_jitter_repairs: int = 0

    @property
    def C_nb(self) -> FloatArray:
        return quat_to_dcm(self.q_nb)


def initial_from_master(master: NavSeries, install: Installation, attitude_error_hpr_deg=(0.0, 0.0, 0.0)) -> NavState:
    """Sub-IMU start state at the first master epoch: master position + lever arm, master velocity
    + lever-arm velocity, master attitude x nominal mount, optionally rotated by an initial
    attitude error (aviation heading/pitch/roll offsets, as in [Gong2018]'s 40 deg test)."""
    C_m = master.C_nb[0]
    r = install.lever_arm_m
    C_s = C_m @ install.C_b_s0
    if np.any(np.asarray(attitude_error_hpr_deg) != 0.0):
        hpr = hpr_from_C_nb(C_s) + np.asarray(attitude_error_hpr_deg, dtype=float) * DEG
        C_s = C_nb_from_hpr(*hpr)
    (w_m,) = master.required("omega_eb_b_radps")
    v = master.vel_n_mps[0] + C_m @ np.cross(w_m[0], r)
    return NavState(master.t_s[0], dcm_to_quat(C_s), v, earth.offset_llh(master.llh[0], C_m @ r))


def run(
    imu: ImuSeries,
    master: NavSeries,
    install: Installation,
    cfg: TAConfig = TAConfig(),
    method: str = "ups",
    particles: int = 100,
    seed: int = 0,
    initial: NavState | None = None,
    points: UnscentedPoints = UnscentedPoints(alpha=0.1),
    oracle_truth=None,
    upf_engine=None,
) -> TAResult:
    """Align one sub-IMU.  ``method`` in METHODS, or ``oracle`` with ``oracle_truth =
    (truth_nav, truth_other)`` (see :class:`.oracle.LinearizedAboutTruth`).  ``upf_engine``:
    the particles' UKFs for upf/ups (filters.runners; default the shared linearization).

    Unusable data raise :class:`~dpos_core.errors.RejectedInput` (NaN samples, stamps out of
    order, no sub-IMU data after the master starts); a filter or smoother that fails beyond
    repair raises :class:`~dpos_core.errors.NumericalFailure`.  The Cholesky jitter repairs made
    on the way are counted in ``TAResult.chol_jitter_repairs``."""
    repairs = JitterRepairs()
    with repairs:
        res = _run(imu, master, install, cfg, method, particles, seed, initial, points, oracle_truth, upf_engine)
    res.chol_jitter_repairs = repairs.count
    return res


def _run(imu: ImuSeries, master: NavSeries, install: Installation, cfg: TAConfig, method: str, particles: int, seed: int,
         initial: NavState | None, points: UnscentedPoints, oracle_truth, upf_engine) -> TAResult:
    if method not in METHODS + (ORACLE,):
        raise ValueError(f"unknown method {method!r}; choose one of {METHODS}")
    if initial is None:
        initial = initial_from_master(master, install)
    model = TransferAlignmentModel(imu, master, install, cfg, initial)
    x0, P0 = model.prior()
    ess: FloatArray | None = None
    if method == ORACLE:
        from .oracle import LinearizedAboutTruth

        if oracle_truth is None:
            raise ValueError("the oracle needs the truth (evaluation of simulations only)")
        lin = LinearizedAboutTruth(model, *oracle_truth)
        tr = run_sigma_point_filter(lin, x0, P0, points)
        x, P = lin.to_model(*smooth_gaussian(tr))
        return TAResult(method, *_apply(model, x, P, tr.corrections), model.epochs_s, x, P, None)
    if method in ("ukf", "urtss"):
        tr = run_sigma_point_filter(model, x0, P0, points)
        corr = tr.corrections
        if method == "urtss":
            x, P = smooth_gaussian(tr)
        else:
            x, P = tr.x_f, tr.P_f
    else:
        ptr = run_upf(model, x0, P0, particles, np.random.default_rng(seed), points, engine=upf_engine)
        corr = ptr.corrections
        ess = ptr.ess
        if method == "ups":
            _, x, P = rb_smooth(ptr)
        else:
            x, P = ptr.mixture.x_f, ptr.mixture.P_f
    out = _apply(model, x, P, corr)
    return TAResult(method, *out, model.epochs_s, x, P, ess)


def _apply(model: TransferAlignmentModel, x: FloatArray, P: FloatArray,
           corr: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The trajectory at the IMU rate from the epoch errors (module docstring): ``(t_s, llh, vel_n_mps, q_nb, sigma)``."""
    chunks = model.nominal_chunks()
    ts: list[FloatArray] = []
    llhs: list[FloatArray] = []
    vels: list[FloatArray] = []
    qs: list[FloatArray] = []
    sigs: list[FloatArray] = []
    for k, ch in enumerate(chunks):
        e0 = x[k]
        e1 = x[k + 1].copy()
        e1[PHI] = compose_rotvec(x[k + 1, PHI], corr[k + 1, PHI])  # undo the shift of epoch k+1
        e1[DV] = x[k + 1, DV] + corr[k + 1, DV]
        e1[DP] = x[k + 1, DP] + corr[k + 1, DP]
        t0, t1 = model.epochs_s[k], model.epochs_s[k + 1]
        a = ((ch.t_s - t0) / (t1 - t0))[:, None]
        err = (1.0 - a) * e0[None, :9] + a * e1[None, :9]
        s = np.sqrt(np.maximum((1.0 - a) * np.diagonal(P[k])[None, :9] + a * np.diagonal(P[k + 1])[None, :9], 0.0))
        C = rotvec_to_dcm(err[:, PHI]) @ ch.C_nb
        v = ch.vel_n_mps - err[:, DV]
        dllh = earth.enu_to_dllh(err[:, DP], ch.llh)
        ts.append(ch.t_s)
        llhs.append(ch.llh - dllh)
        vels.append(v)
        qs.append(dcm_to_quat(C))
        sigs.append(s)
    return (np.concatenate(ts), np.concatenate(llhs), np.concatenate(vels), np.concatenate(qs), np.concatenate(sigs))
