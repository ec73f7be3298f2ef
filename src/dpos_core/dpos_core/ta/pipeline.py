"""Transfer alignment of one sub-IMU over a recorded session: forward filter, backward smoother,
and the smoothed trajectory at the IMU rate.

Methods: ``ukf`` (forward only), ``urtss`` (UKF + unscented RTS smoother), ``upf`` (forward
only), ``ups`` ([Gong2018]'s unscented particle smoother: the Rao-Blackwellized UPF - particles on
the flexure rate, every particle's UKF carrying the other 21 states - and its backward pass;
filters.runners explains the choice and what the literal variant measured); ``ups_mcmc``: the
UPS with [Yan2016]'s MCMC move after each resampling (resample-move, Gilks and Berzuini 2001:
``run_upf(move=True)``; docs/sar.md measures it on paper_su); ``cdkf`` (forward
only) and ``cdkf_rts`` (with its RTS-type smoother): [Ye2024]'s central-difference Kalman filter
(Stirling's interpolation, ``h^2 = 3``; filters.gaussian); ``cdvf`` and ``cdvf_rts``: [Ye2024]'s
central-difference variational filter (the CDKF's prediction and covariance, the state update by
the PRP conjugate gradient, Algorithm 2; filters.variational), its iterations in ``TAResult.cg``.
The ``*_rts`` smoothers are the one RTS recursion (filters.runners.smooth_gaussian) on the
filter's predictions and central-difference cross-covariances (docs/cdvf.md).

Output at the IMU rate: the error estimates at the filter epochs are applied to the stored
nominal trajectory, linearly interpolated between epochs.  Within the interval after epoch k
the nominal was integrated from the state corrected at k, so its start error is the estimate at
k and its end error is the estimate at k + 1 before that epoch's correction.

Sub-IMU gaps (:func:`run_segments`): a step longer than
:func:`.model.gap_limit_s` (``TAConfig.max_imu_gap_s``, 0.05 s by default) splits the data into
segments, each aligned on its own from the main POS at its first sample (master interpolated
there, the configured prior): the strapdown cannot know how the wing moved while it was not
measured, and after a long gap a bridged solution was off by metres and degrees with a sigma of
milli-degrees.  No row is output inside a gap; the spans without rows are returned
(``TAResult.not_estimated``), the rows of the first ``TAConfig.restart_flag_s`` of a restarted
segment flagged (:data:`.flags.RESTARTED_AFTER_GAP`).  A restart takes the configured prior of
every state, the constant ones (rho, biases) included: carrying them over would be tighter but
would rest on the mount not having moved while nothing was measured.  Shorter gaps are integrated
across with their process noise (:mod:`.model`, flag :data:`.flags.BRIDGED_GAP`).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..attitude import compose_rotvec, cross, dcm_to_quat, dcm_to_rotvec, quat_to_dcm, rotvec_to_dcm, skew
from ..errors import RejectedInput
from ..filters.linalg import JitterRepairs
from ..filters.points import UnscentedPoints
from ..filters.runners import CentralDifferenceRule, VariationalRule, rb_smooth, run_sigma_point_filter, run_upf, smooth_gaussian
from ..filters.store import EpochStore, PerEpoch, in_memory
from ..filters.variational import CGStats
from ..frames import C_nb_from_hpr, hpr_from_C_nb
from ..series import ImuSeries, NavSeries
from ..strapdown import NavState
from . import flags as F
from . import guard
from .antenna import step_roughness
from .model import DP, DV, PHI, Installation, TAConfig, TransferAlignmentModel, accel_axis_rotation_var, check_imu_stamps, gap_limit_s, master_at, nominal_dt_s
from .oracle import LinearizedAboutTruth
from .qc import EpochQC, attitude_change, epoch_qc

METHODS = ("ukf", "urtss", "upf", "ups", "ups_mcmc", "cdkf", "cdkf_rts", "cdvf", "cdvf_rts")
#: the Gaussian methods: (forward rule, smoothed) per method (the particle methods are the others)
_GAUSSIAN = {"ukf": (None, False), "urtss": (None, True), "cdkf": (CentralDifferenceRule(), False),
             "cdkf_rts": (CentralDifferenceRule(), True), "cdvf": (VariationalRule(), False), "cdvf_rts": (VariationalRule(), True)}
ORACLE = "oracle"  #: evaluation only (needs the simulation's truth), see .oracle
#: evaluation only: the oracle's forward filter (no smoother), the bound of the forward filters (ukf, upf, cdkf, cdvf)
ORACLE_FILTER = "oracle_filter"
#: evaluation only: the URTSS of a model that knows the true wing (``Installation.known_wing``:
#: the true deformed lever arm and flexure rotation in the matches, the flexure states held at zero)
ORACLE_WING = "oracle_wing"


@dataclass(frozen=True)
class TASettings:
    """One transfer-alignment run's settings, the same object from transfer_align_node's parameters
    (``TransferAlignConfig.core_config()``) or dpos-process's options to the session's solve, its
    workers (:func:`align`) and the alignment itself (:func:`run_segments`, :func:`run`), with the
    core's names.

    Attributes:
        method: one of :data:`METHODS` (or an evaluation-only oracle method).
        particles: number of particles of the particle methods (>= 1).
        seed: random seed of the particle methods (every sub-IMU uses it).
        filter_rate_hz: the filter's measurement update rate (``TAConfig.filter_rate_hz``).
        use_position: match the lever-arm-compensated main-POS position too (``TAConfig.use_position``).
        master_error_tau_s: correlation time of the main POS's position and velocity errors
            (``TAConfig.master_error_tau_s``; 0 = white).
        initial_attitude_error_deg: every sub-IMU starts from the main POS's attitude x mount rotated
            by this in heading, pitch and roll ([Gong2018]: 40 deg), its prior 1-sigma this (>= 1 deg).
        inflate_sigma: scale the output 1-sigma by the innovations' variance factor where they say
            the filter is optimistic (:func:`dpos_core.ta.qc.sigma_scale`).
        output_rate_hz: rate of the antenna rows; 0 = the sub-IMU rate.
        master_aligned_sigma_deg: the main POS counts as aligned from its first epoch with an
            attitude 1-sigma below this, and rows where it is not carry ``MASTER_UNALIGNED``.
    """

    method: str = "ups"
    particles: int = 100
    seed: int = 0
    filter_rate_hz: float = 1.0
    use_position: bool = True
    master_error_tau_s: float = 0.0
    initial_attitude_error_deg: float = 0.0
    inflate_sigma: bool = True
    output_rate_hz: float = 0.0
    master_aligned_sigma_deg: float = 0.1

    def __post_init__(self) -> None:
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if not (np.isfinite(self.output_rate_hz) and self.output_rate_hz >= 0):
            raise ValueError(f"output_rate_hz must be >= 0, got {self.output_rate_hz}")
        self.ta_config()  # (its own checks)

    def ta_config(self) -> TAConfig:
        """The filter's configuration: the prior attitude 1-sigma the initial error, at least 1 deg."""
        return TAConfig(filter_rate_hz=self.filter_rate_hz, attitude_sigma_deg=max(self.initial_attitude_error_deg, 1.0),
                        use_position=self.use_position, master_error_tau_s=self.master_error_tau_s)

    @property
    def attitude_error_hpr_deg(self) -> tuple[float, float, float]:
        """The initial attitude error (heading, pitch, roll) [deg] of :func:`run_segments`."""
        e = self.initial_attitude_error_deg
        return (e, e, e)


def align(imu: ImuSeries, master: NavSeries, install: Installation, settings: TASettings, *, oracle_truth=None,
          sink: RowSink | None = None) -> TAResult:
    """:func:`run_segments` of one sub-IMU with ``settings`` (a module function: the products'
    workers are sent it by name with their sub-IMU's data, the main POS, its installation and the
    settings, nothing else)."""
    return run_segments(imu, master, install, settings, oracle_truth=oracle_truth, sink=sink)


@dataclass
class TAResult:
    """Smoothed (or filtered) sub-IMU trajectory at the IMU rate and the epoch estimates.

    t_s (N,), llh (N, 3), vel_n_mps (N, 3), q_nb (N, 4); sigma (N, 9): 1-sigma of
    [phi (3, rad), dv (3, m/s), dp (3, m, ENU)]; epochs_s (K,), x (K, 24), P (K, 24, 24): the
    state estimates at the epochs (after their correction); method; particles; ess (K,) for PF;
    chol_jitter_repairs: Cholesky factors that needed a diagonal jitter (dpos_core.filters.linalg);
    flags (N,): the rows' quality bits (:mod:`.flags`); not_estimated: the spans ``(t_from_s,
    t_to_s, reason)`` between output rows that :func:`run_segments` left without rows (sub-IMU
    gaps, data too short to align); the rows at ``t_from_s`` and ``t_to_s`` themselves exist when
    data do on that side.  qc: the consistency measures at the epochs (:class:`.qc.EpochQC`: NIS of
    the forward filter's innovations - the UPF's mixture's -, the filtered-minus-smoothed
    separation of the smoothers), for the quality control without truth.  cg: the CDVF's
    conjugate-gradient record per epoch (iterations, costs: :class:`~dpos_core.filters.variational.CGStats`),
    None for the other methods.  installation: the installation states' estimates at the last epoch
    (.model docstring), ``name -> {"value": [...], "sigma": [...]}`` in state units (``lever_arm`` m,
    the true arm minus the configured one, master axes; ``time_offset`` s; ``gyro_axes`` /
    ``accel_axes`` dimensionless scale factors and misalignments); empty without them.  After gaps
    (several parts aligned anew) the longest part's.
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
    flags: F.FlagArray = field(default_factory=lambda: F.none(0))
    not_estimated: list[tuple[float, float, str]] = field(default_factory=list)
    qc: EpochQC | None = None
    cg: CGStats | None = None
    installation: dict[str, dict[str, list[float]]] = field(default_factory=dict)

    @property
    def C_nb(self) -> FloatArray:
        return quat_to_dcm(self.q_nb)


def initial_from_master(master: NavSeries, install: Installation, attitude_error_hpr_deg=(0.0, 0.0, 0.0),
                        t_s: float | None = None) -> NavState:
    """Sub-IMU start state at the first master epoch (or at ``t_s``, the master interpolated there:
    :func:`master_at`): master position + lever arm, master velocity + lever-arm velocity, master
    attitude x nominal mount, optionally rotated by an initial attitude error (aviation
    heading/pitch/roll offsets, as in [Gong2018]'s 40 deg test).  ValueError when ``t_s`` is outside
    the master data or inside a gap of it."""
    (w,) = master.required("omega_eb_b_radps")
    if t_s is None:
        t, llh_m, v_m, C_m, w_m = float(master.t_s[0]), master.llh[0], master.vel_n_mps[0], master.C_nb[0], w[0]
    else:
        at = master_at(master, t_s)
        if at is None:
            raise ValueError(f"no main-system navigation at t = {t_s:.3f} s (outside the data or in a gap)")
        t, (llh_m, v_m, C_m, w_m) = float(t_s), at
    r = install.lever_arm_m
    C_s = C_m @ install.C_b_s0
    if np.any(np.asarray(attitude_error_hpr_deg) != 0.0):
        hpr = hpr_from_C_nb(C_s) + np.asarray(attitude_error_hpr_deg, dtype=float) * DEG
        C_s = C_nb_from_hpr(*hpr)
    v = v_m + C_m @ np.cross(w_m, r)
    return NavState(t, dcm_to_quat(C_s), v, earth.offset_llh(llh_m, C_m @ r))


def split_at_gaps(t_s: FloatArray, limit_s: float) -> list[slice]:
    """The runs of stamps ``t_s`` (N,) without a step longer than ``limit_s`` [s], as slices (in order)."""
    cuts = np.nonzero(np.diff(t_s) > limit_s)[0] + 1
    edges = np.concatenate([[0], cuts, [t_s.size]]).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def run_segments(
    imu: ImuSeries,
    master: NavSeries,
    install: Installation,
    settings: TASettings = TASettings(),
    *,
    cfg: TAConfig | None = None,
    oracle_truth=None,
    upf_engine=None,
    sink: RowSink | None = None,
) -> TAResult:
    """Align one sub-IMU whose stream may have gaps (module docstring): split it at steps longer
    than :func:`.model.gap_limit_s`, align every segment from the main POS at its start (the
    start of its first sample's interval - a sample is the mean over the nominal step before its
    stamp - with the master interpolated there, or the first master epoch for data that start
    before it; ``settings.attitude_error_hpr_deg`` as :func:`initial_from_master`, on every
    segment), and concatenate the results (rows, epochs, states, covariances, flags; the jitter
    repairs summed).  Data without such a gap give :func:`run`'s result.  ``settings``: the
    method, particles, seed and initial attitude error (:class:`TASettings`); ``cfg``: the
    filter's configuration, default ``settings.ta_config()``; the others as :func:`run`.

    A segment shorter than one filter interval (after the master starts and before it ends), or
    starting inside a master gap with no master epoch after it, is not estimated: it adds to
    ``TAResult.not_estimated`` instead of raising.  RejectedInput when no segment can be aligned
    (or as :func:`run` for NaN samples, stamps out of order); NumericalFailure as :func:`run`."""
    cfg = settings.ta_config() if cfg is None else cfg
    t = imu.t_s
    check_imu_stamps(t)
    step = 1.0 / cfg.filter_rate_hz
    parts: list[TAResult] = []
    spans: list[tuple[float, float, str]] = []
    pending: list[str] = []  # why there are no rows since the last output row
    last_row: float | None = None
    t_master_end = float(master.t_s[-1])
    dt = nominal_dt_s(t)
    for i, seg in enumerate(split_at_gaps(t, gap_limit_s(t, cfg))):
        if i > 0:
            pending.append(f"sub-IMU gap of {t[seg.start] - t[seg.start - 1]:.3f} s")
        start, why = _segment_start(master, float(t[seg.start]) - dt, float(t[seg.stop - 1]))
        end = min(float(t[seg.stop - 1]), t_master_end)
        if why is None and end - start < step - 1e-9:
            why = f"{max(end - start, 0.0):.3f} s of sub-IMU data, too short to align (one filter interval is {step:g} s)"
        if why is not None:
            pending.append(why)
            continue
        init = initial_from_master(master, install, settings.attitude_error_hpr_deg, None if start == float(master.t_s[0]) else start)
        r = run(imu.select(seg), master, install, settings, cfg=cfg, initial=init, oracle_truth=oracle_truth, upf_engine=upf_engine, sink=sink)
        if i > 0:
            r.flags[r.t_s <= start + cfg.restart_flag_s] |= F.RESTARTED_AFTER_GAP
        if pending:
            spans.append((float(t[0]) if last_row is None else last_row, float(r.t_s[0]), "; ".join(pending)))
            pending = []
        last_row = float(r.t_s[-1])
        parts.append(r)
    if not parts:
        raise RejectedInput(f"no sub-IMU segment can be aligned: {'; '.join(pending)}", what="sub-IMU samples", reason="too_short")
    if pending:
        assert last_row is not None
        spans.append((last_row, float(t[-1]), "; ".join(pending)))
    if len(parts) == 1:
        parts[0].not_estimated = spans
        return parts[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    ess = None if any(p.ess is None for p in parts) else cat("ess")
    qcs = [p.qc for p in parts if p.qc is not None]
    cgs = [p.cg for p in parts if p.cg is not None]
    return TAResult(settings.method, cat("t_s"), cat("llh"), cat("vel_n_mps"), cat("q_nb"), cat("sigma"), cat("epochs_s"), cat("x"), cat("P"),
                    ess, sum(p.chol_jitter_repairs for p in parts), cat("flags"), spans,
                    EpochQC.concat(qcs) if len(qcs) == len(parts) else None, CGStats.concat(cgs) if len(cgs) == len(parts) else None,
                    max(parts, key=lambda p: p.t_s.size).installation)


def _segment_start(master: NavSeries, t_first: float, t_last: float) -> tuple[float, str | None]:
    """Where a segment of sub-IMU data covering ``t_first`` to ``t_last`` [s] starts its alignment: the
    first master epoch if the data start before it, else ``t_first`` if the master can be
    interpolated there, else the next master epoch; and why it cannot start, or None."""
    m0 = float(master.t_s[0])
    if t_first <= m0 + 1e-6:  # (master_at's tolerance for an epoch's own time)
        return m0, None
    if master_at(master, t_first) is not None:
        return t_first, None
    j = int(np.searchsorted(master.t_s, t_first))
    if j >= master.t_s.size or master.t_s[j] >= t_last:
        return t_first, "no main-system navigation over the sub-IMU data"
    return float(master.t_s[j]), None


def run(
    imu: ImuSeries,
    master: NavSeries,
    install: Installation,
    settings: TASettings = TASettings(),
    *,
    cfg: TAConfig | None = None,
    initial: NavState | None = None,
    oracle_truth=None,
    upf_engine=None,
    sink: RowSink | None = None,
) -> TAResult:
    """Align one sub-IMU.  ``settings.method`` in METHODS, or ``oracle`` (``oracle_filter``: its forward
    filter only) with ``oracle_truth = (truth_nav, truth_other)`` (see :class:`.oracle.LinearizedAboutTruth`);
    ``settings.particles`` and ``settings.seed`` for the particle methods; ``cfg``: the filter's
    configuration, default ``settings.ta_config()``; ``initial``: the starting state, default the
    main POS's at its first epoch (:func:`initial_from_master`, without the settings' initial
    error: :func:`run_segments` applies it).  ``upf_engine``: the particles' UKFs for upf/ups
    (filters.runners; default the shared linearization).  The unscented points: :data:`POINTS`.

    Unusable data raise :class:`~dpos_core.errors.RejectedInput` (NaN samples, stamps out of
    order, no sub-IMU data after the master starts); a filter or smoother that fails beyond
    repair raises :class:`~dpos_core.errors.NumericalFailure`, a run whose result is no estimate
    (non-finite, innovations grossly inconsistent, positions beyond the lever arm's reach from the
    main POS: :mod:`.guard`) its subclass :class:`~dpos_core.errors.AlignmentDiverged` (``reason``
    says which), before a row is returned (with ``sink``: before the block holding it is handed on).  The Cholesky jitter repairs made
    on the way are counted in ``TAResult.chol_jitter_repairs``.

    ``sink``: the output rows are handed to it a block at a time (:data:`RowSink`, in
    time order, across the segments of :func:`run_segments` too) instead of being kept; the
    result then holds their stamps ``t_s`` and ``flags`` only (``llh``, ``vel_n_mps``, ``q_nb``
    and ``sigma`` are empty)."""
    repairs = JitterRepairs()
    with repairs:
        res = _run(imu, master, install, settings, settings.ta_config() if cfg is None else cfg, initial, oracle_truth, upf_engine, sink)
    res.chol_jitter_repairs = repairs.count
    return res


def _installation(model: TransferAlignmentModel, x: FloatArray, P: FloatArray) -> dict[str, dict[str, list[float]]]:
    """TAResult.installation from the estimates at the last epoch x (n,) and P (n, n)."""
    sd = np.sqrt(np.maximum(np.diagonal(P), 0.0))
    return {name: {"value": [float(v) for v in x[sl]], "sigma": [float(v) for v in sd[sl]]} for name, sl in model.extra.items()}


def _bridged_flags(model: TransferAlignmentModel) -> F.FlagArray:
    """:data:`.flags.BRIDGED_GAP` on the output rows (those of :func:`_apply`) of the intervals
    that contained a short gap."""
    sizes = model.interval_sizes()
    out = F.none(int(sum(sizes)))
    ends = np.cumsum(sizes)
    for k in model.bridged_intervals:
        out[ends[k] - sizes[k]:ends[k]] |= F.BRIDGED_GAP
    return out


#: the unscented points of the sigma-point filters and the particles' UKFs
POINTS = UnscentedPoints(alpha=0.1)


def _run(imu: ImuSeries, master: NavSeries, install: Installation, settings: TASettings, cfg: TAConfig, initial: NavState | None,
         oracle_truth, upf_engine, sink: RowSink | None = None) -> TAResult:
    method, particles, seed, points = settings.method, settings.particles, settings.seed, POINTS
    if method == ORACLE_WING:
        if install.known_wing is None:
            raise ValueError("the oracle with the true wing needs Installation.known_wing (evaluation of simulations only)")
        method = "urtss"
    if method not in METHODS + (ORACLE, ORACLE_FILTER):
        raise ValueError(f"unknown method {method!r}; choose one of {METHODS}")
    if initial is None:
        initial = initial_from_master(master, install)
    # (the oracle's linearization reads the model's epochs after the forward pass: it keeps them)
    model = TransferAlignmentModel(imu, master, install, cfg, initial, keep_nominal=KEEP_NOMINAL,
                                   keep_epoch_data=method in (ORACLE, ORACLE_FILTER))
    x0, P0 = model.prior()
    ess: FloatArray | None = None
    if method in (ORACLE, ORACLE_FILTER):
        if oracle_truth is None:
            raise ValueError("the oracle needs the truth (evaluation of simulations only)")
        lin = LinearizedAboutTruth(model, *oracle_truth)
        tr = run_sigma_point_filter(lin, x0, P0, points)
        x_f, P_f = in_memory(tr.x_f), in_memory(tr.P_f)  # (a store in memory)
        if method == ORACLE:
            xo, Po = lin.to_model(*(in_memory(a) for a in smooth_gaussian(tr)))
            qc = epoch_qc(model.epochs_s, tr.nu, tr.S, *lin.to_model(x_f, P_f), xo, Po)
        else:
            xo, Po = lin.to_model(x_f, P_f)
            qc = epoch_qc(model.epochs_s, tr.nu, tr.S, xo, Po)
        qc.att_change = attitude_change(master.t_s, master.q_nb, model.epochs_s)
        return TAResult(method, *_apply(model, xo, Po, tr.corrections), model.epochs_s, xo, Po, None, flags=_bridged_flags(model), qc=qc,
                        installation=_installation(model, xo[-1], Po[-1]))
    cg: CGStats | None = None
    particle = method not in _GAUSSIAN
    with tempfile.TemporaryDirectory(prefix="dpos_ta_") as tmp:
        # the per-epoch arrays of the filter and the smoother (~20 kB an epoch, and the UPS's track ~13 kB at
        # 100 particles) in files when large (filters.store), read back a block of epochs at a time
        big = model.n_epochs * per_epoch_bytes(model.n, particles if particle else 0, _sampled_size(model)) > TRACK_IN_MEMORY_BYTES
        store = EpochStore(Path(tmp) if big else None)
        try:
            if not particle:
                rule, smoothed = _GAUSSIAN[method]
                tr = run_sigma_point_filter(model, x0, P0, points, rule=rule, store=store)
                cg = tr.cg
            else:
                # (the track of what FFBSm reads: the model samples some components only)
                ptr = run_upf(model, x0, P0, particles, np.random.default_rng(seed), points, engine=upf_engine, move=method == "ups_mcmc",
                              store=store, full_track=_sampled_size(model) == model.n)
                ess = ptr.ess
                smoothed = method in ("ups", "ups_mcmc")
                tr = ptr.mixture
            xs: PerEpoch
            Ps: PerEpoch
            if smoothed:
                xs, Ps = rb_smooth(ptr)[1:] if particle else smooth_gaussian(tr, store)
            else:
                xs, Ps = tr.x_f, tr.P_f
            qc = epoch_qc(model.epochs_s, tr.nu, tr.S, tr.x_f, tr.P_f, *((xs, Ps) if smoothed else (None, None)))
            qc.att_change = attitude_change(master.t_s, master.q_nb, model.epochs_s)
            corr = tr.corrections
            # the divergence guard (.guard): AlignmentDiverged before any row is used
            what = f"transfer alignment ({method})"
            guard.check_finite(xs, Ps, model.epochs_s, what)
            guard.check_nis(qc, what)
            if sink is None:
                out = _apply(model, xs, Ps, corr)
                guard.check_positions(out[0], out[1], master, install, what)
            else:
                out = _to_sink(model, xs, Ps, corr, _guarded_sink(sink, master, install, what))
            installation = _installation(model, np.asarray(xs[-1]), np.asarray(Ps[-1]))
            # the estimates at the epochs: kept in memory, or (the rows handed to a sink) not kept
            x, P = (in_memory(xs), in_memory(Ps)) if sink is None else (np.zeros((0, model.n)), np.zeros((0, model.n, model.n)))
        finally:
            store.close()
    return TAResult(method, *out, model.epochs_s, x, P, ess, flags=_bridged_flags(model), qc=qc, cg=cg, installation=installation)


def _guarded_sink(sink: RowSink, master: NavSeries, install: Installation, what: str) -> RowSink:
    """``sink`` behind :func:`.guard.check_positions`: a block with a row out of the bound raises
    before it is handed on."""

    def checked(t: FloatArray, llh: FloatArray, vel: FloatArray, q: FloatArray, sigma: FloatArray) -> None:
        guard.check_positions(t, llh, master, install, what)
        sink(t, llh, vel, q, sigma)

    return checked


def per_epoch_bytes(n: int, particles: int = 0, sampled: int = 0) -> int:
    """Bytes a filter and its smoother keep per epoch for the backward pass and the output (n
    states; a particle filter's ``particles`` with ``sampled`` sampled components): the filtered,
    predicted, cross- and smoothed covariances and the means, and the particle track (the weights,
    the proposed particles' sampled components and their predicted densities: ``run_upf(full_track=False)``)."""
    N, s = particles, sampled
    return 8 * (4 * n * n + 5 * n + 100 + (2 * N + 2 * N * s + N * s * s if N else 0))


def _sampled_size(model: TransferAlignmentModel) -> int:
    """The number of components the particle filters sample (``model.sampled``)."""
    return int(np.arange(model.n)[model.sampled].size)


def shift_in_time(model: TransferAlignmentModel, x: FloatArray, P: FloatArray, t: FloatArray, llh: FloatArray, vel: FloatArray,
                  q: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The output rows (t (N,), llh (N, 3), vel_n_mps (N, 3), q_nb (N, 4), 1-sigma s (N, 9)) moved to
    their stamps by the estimated time offset (the model's ``time_offset`` state; x (K, n), P (K, n, n)).

    With an offset tau the nominal at stamp t follows the truth at t - tau (.model docstring), so the
    pose at t is the output at t + tau: interpolated between the rows around it (the attitude along
    the geodesic; before the first and after the last row the first and last intervals' rates carry
    it on).  tau at a row is interpolated between the epochs (the smoothed estimate is one constant;
    a forward filter's grows more certain).  The output's error is then the navigation estimate's
    (sign reversed) plus J times the offset estimate's, J the rate of each component (ENU attitude
    rate, acceleration, velocity), so the variance gains ``J^2 var(tau) - 2 J cov(nav, tau)`` (the
    two estimates are correlated through the matches: a position match fixes ``dp - tau v``), and the
    attitude and velocity the interpolation cannot know between rows (:func:`.antenna.step_roughness`).
    Returns ``(llh, vel_n_mps, q_nb, s)``."""
    i = model.extra["time_offset"].start
    if t.size < 2:
        return llh, vel, q, s
    tau = np.interp(t, model.epochs_s, x[:, i])
    var_tau = np.interp(t, model.epochs_s, P[:, i, i])
    j = np.clip(np.searchsorted(t, t + tau, side="right") - 1, 0, t.size - 2)
    dt = t[j + 1] - t[j]
    a = ((t + tau - t[j]) / dt)[:, None]
    C0 = quat_to_dcm(q[j])
    rv = dcm_to_rotvec(quat_to_dcm(q[j + 1]) @ np.swapaxes(C0, 1, 2))  # ENU rotation from row j to j + 1
    dv = vel[j + 1] - vel[j]
    q2 = dcm_to_quat(rotvec_to_dcm(a * rv) @ C0)
    vel2 = vel[j] + a * dv
    llh2 = llh[j] + a * (llh[j + 1] - llh[j])
    J = np.concatenate([rv / dt[:, None], dv / dt[:, None], vel2], axis=1)  # d(output)/d(time) (N, 9)
    cross_tau = np.stack([np.interp(t, model.epochs_s, P[:, c, i]) for c in range(9)], axis=1)  # cov(nav error, tau)
    # output error = -(navigation estimate's error) + J (tau estimate's error)
    var = s**2 + var_tau[:, None] * J**2 - 2.0 * J * cross_tau
    var[:, :6] += np.abs(a * (1.0 - a)) * step_roughness(np.concatenate([rv, dv], axis=1))[j]
    return llh2, vel2, q2, np.sqrt(np.maximum(var, 0.0))




#: keep the nominal at the IMU rate through the filter (True), or re-integrate it interval by interval
#: in the output pass (False, the default: the same numbers without the trajectory in memory)
KEEP_NOMINAL = False
#: per-epoch arrays of a filter and its smoother (:func:`per_epoch_bytes`) larger than this go to files in a
#: temporary directory for the backward pass, the quality measures and the output pass, which read them a
#: block of epochs at a time (:class:`dpos_core.filters.store.EpochStore`): 64 MB is ~20 min of the UPS at
#: 100 particles, ~1 h of the URTSS (24 states, 1 Hz)
TRACK_IN_MEMORY_BYTES = 64 * 2**20
#: intervals (filter epochs) whose rows the output pass builds at once (:func:`iter_rows`)
APPLY_BLOCK = 64


def _apply(model: TransferAlignmentModel, x: PerEpoch, P: PerEpoch,
           corr: PerEpoch) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The trajectory at the IMU rate from the epoch errors (module docstring): ``(t_s, llh, vel_n_mps, q_nb, sigma)``,
    the blocks of :func:`iter_rows` concatenated."""
    parts = list(iter_rows(model, x, P, corr))
    return tuple(np.concatenate(c) for c in zip(*parts, strict=True))  # type: ignore[return-value]


#: ``sink(t_s, llh, vel_n_mps, q_nb, sigma)``: takes a block of output rows (``run(..., sink=...)``)
RowSink = Callable[[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray], None]


def _to_sink(model: TransferAlignmentModel, x: PerEpoch, P: PerEpoch, corr: PerEpoch,
             sink: RowSink) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The rows of :func:`_apply` handed to ``sink`` block by block; returns their stamps and
    empty (0, m) arrays in place of the other columns (the trajectory is not kept)."""
    t = np.empty(int(np.sum(model.interval_sizes())))  # (the stamps filled in place: no list of blocks concatenated)
    i = 0
    for blk in iter_rows(model, x, P, corr):
        sink(*blk)
        t[i:i + blk[0].size] = blk[0]
        i += blk[0].size
    assert i == t.size
    return t, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 9))


def iter_rows(model: TransferAlignmentModel, x: PerEpoch, P: PerEpoch, corr: PerEpoch,
              block: int | None = None):
    """:func:`_apply`'s rows, ``block`` intervals at a time (the nominal of each re-integrated when the
    model does not keep it, :attr:`.model.TransferAlignmentModel.keep_nominal`): ``(t_s, llh,
    vel_n_mps, q_nb, sigma)`` per block (default :data:`APPLY_BLOCK`), the same numbers as at once
    (row by row arithmetic).  The epoch estimates x (K, n), P (K, n, n) and the corrections (K, n)
    (numpy arrays or :class:`~dpos_core.filters.store.EpochArray` files) are read a block at a time.
    With the ``time_offset`` state the rows are shifted in time across rows (:func:`shift_in_time`):
    one block of every row then (not streamed)."""
    n = int(model.interval_sizes().size)
    block = APPLY_BLOCK if block is None else block
    if "time_offset" in model.extra:  # shift_in_time moves each row by the offset between its neighbours: every row at once
        block = max(n, 1)
    for k0 in range(0, max(n, 1), block):
        k1 = min(k0 + block, n)
        xb, Pb = np.asarray(x[k0:k1 + 1]), np.asarray(P[k0:k1 + 1])  # the epochs k0 .. k1
        cb = np.asarray(corr[k0 + 1:k1 + 1])
        e1 = xb[1:].copy()  # the errors at the interval ends, before the end epoch's correction (undo its shift)
        e1[:, PHI] = compose_rotvec(xb[1:, PHI], cb[:, PHI])
        e1[:, DV] = xb[1:, DV] + cb[:, DV]
        e1[:, DP] = xb[1:, DP] + cb[:, DP]
        yield _apply_block(model, xb, Pb, e1, k0, [model.nominal_chunk(k) for k in range(k0, k1)])


def _apply_block(model: TransferAlignmentModel, x: FloatArray, P: FloatArray, e1: FloatArray, k0: int,
                 chunks: list[NavSeries]) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The rows of the intervals k0, k0 + 1, .. (their nominal ``chunks``) at once: the interval of each
    row, the errors at its two epochs (x (B + 1, n), P (B + 1, n, n): those of the epochs k0 .. k0 + B,
    B = len(chunks); ``e1`` (B, n): the errors at the interval ends before the end epoch's correction)
    interpolated to the rows.  With the ``time_offset`` state (one block of every row) x and P are
    every epoch's."""
    sizes = np.array([ch.t_s.size for ch in chunks], dtype=int)
    kk = np.repeat(np.arange(len(chunks)), sizes)  # the interval of each row, in the block (k0 + kk in the session)
    t = np.concatenate([ch.t_s for ch in chunks])
    vel = np.concatenate([ch.vel_n_mps for ch in chunks])
    llh = np.concatenate([ch.llh for ch in chunks])
    q = np.concatenate([ch.q_nb for ch in chunks])
    t0, t1 = model.epochs_s[:-1][k0 + kk], model.epochs_s[1:][k0 + kk]
    a = ((t - t0) / (t1 - t0))[:, None]
    err = (1.0 - a) * x[kk, :9] + a * e1[kk, :9]
    dP = np.diagonal(P, axis1=1, axis2=2)[:, :9]
    me = model.extra.get("master_error")
    if me is not None:  # the output follows the main POS: its position and velocity relative to the main POS's (.model)
        m0 = me.start
        e = (1.0 - a) * x[kk, m0:m0 + 6] + a * x[kk + 1, m0:m0 + 6]
        err[:, DV] -= e[:, 3:]
        err[:, DP] -= e[:, :3]
        i_nav = np.r_[DP.start:DP.stop, DV.start:DV.stop]
        i_e = np.r_[m0:m0 + 6]
        # var(nav - e) = P_nav + P_e - 2 P_nav,e per component, and the main POS's own error (absolute sigma)
        dP = dP.copy()
        dP[:, i_nav] += np.diagonal(P[:, i_e][:, :, i_e], axis1=1, axis2=2) - 2.0 * np.diagonal(P[:, i_nav][:, :, i_e], axis1=1, axis2=2)
        st = model.master_error_stationary_var()
        dP[:, DP] += st[:3]
        dP[:, DV] += st[3:]
    var = (1.0 - a) * dP[kk] + a * dP[kk + 1]
    # the velocity the IMU gains within the interval beyond a straight line (the wing's vibration):
    # an attitude error turns it, dv_dot = f x phi (model docstring), which no linear interpolation
    # of the epoch errors holds: on paper_wing a 0.1 deg heading error turns the 2 Hz in-plane
    # vibration (0.4 m/s at 9 m) into mm/s across the span, twice the error at the epochs
    ends = np.cumsum(sizes)
    first, last = ends - sizes, ends - 1
    vib = np.flatnonzero(sizes[kk] > 2)  # rows of intervals with more than 2 rows
    if vib.size:
        kv = kk[vib]
        f, la = first[kk[vib]], last[kk[vib]]
        b = ((t[vib] - t[f]) / (t[la] - t[f]))[:, None]
        D = vel[vib] - vel[f] - b * (vel[la] - vel[f])
        err[vib, DV] += cross(D, err[vib, PHI])
        Sk = skew(D)  # D x phi = [D x] phi
        av = a[vib][:, :, None]
        Pp = P[:, PHI, PHI]
        P_phi = (1.0 - av) * Pp[kv] + av * Pp[kv + 1]
        var[vib, DV] += np.einsum("tij,tjk,tik->ti", Sk, P_phi, Sk)
    if "accel_axes" in model.extra:  # the accelerometer triad's rotation against the body: no match sees it (.model)
        var[:, PHI] += accel_axis_rotation_var(model.install.imu)
    s = np.sqrt(np.maximum(var, 0.0))
    C = rotvec_to_dcm(err[:, PHI]) @ quat_to_dcm(q)
    llh_o, vel_o, q_o = llh - earth.enu_to_dllh(err[:, DP], llh), vel - err[:, DV], dcm_to_quat(C)
    if "time_offset" in model.extra:
        llh_o, vel_o, q_o, s = shift_in_time(model, x, P, t, llh_o, vel_o, q_o, s)
    return t, llh_o, vel_o, q_o, s
