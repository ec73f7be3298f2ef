"""In-flight alignment of the main POS against GNSS ([Fang2012]): ADD2, DD2 or AEKF on the
large-heading-error model of :mod:`.model`, the master strapdown in closed loop at the IMU rate.

* :class:`InFlightAligner` is the online engine (the node's core): :meth:`~InFlightAligner.propagate`
  IMU samples, :meth:`~InFlightAligner.update` with a GNSS fix.  A fix that cannot be used
  (non-finite values, zero covariance, duplicate or out-of-order stamp, stamp not at the
  navigation time) raises :class:`~dpos_core.errors.RejectedInput` before anything changes; an
  update that fails numerically in every hypothesis raises
  :class:`~dpos_core.errors.NumericalFailure` with the state restored.  Anything else (a wrong
  shape, a wrong type) is a bug and propagates as it is.
* :func:`run` drives it over recorded series; unusable fixes are skipped with a warning and listed
  in the result.

Errors are returned, not logged: the core has no logger.  What the bank of hypotheses does at an
epoch (a hypothesis dropped because its update failed numerically, pruned by likelihood, merged
into a likelier one) is returned as :class:`HypothesisEvent` s in the epoch's record (and kept in
:attr:`InFlightAligner.events`), so that the caller logs them with its own logger (ifa_node:
the ROS logger, so they reach ``/rosout``; :func:`run`: ``warnings``) and counts them
(``hypotheses_failed``); Cholesky jitter repairs are counted in
:attr:`InFlightAligner.chol_jitter_repairs` (:mod:`dpos_core.filters.linalg`).

Alignment decision (not a timer): at each epoch the heading 1-sigma of the filter and the
innovation consistency over the last N epochs are checked.  The normalized innovation squared
``NIS_k = nu_k^T P_y,k^-1 nu_k`` uses the filter's *model* innovation covariance (nominal R), so
it detects GNSS noise the model does not explain; its window mean over N epochs is
``chi^2(N p) / N`` when consistent.  The alignment is declared (and latched) at the first epoch
with ``sigma_heading < cfg.aligned_heading_threshold_rad`` (the larger of
``aligned_heading_sigma_deg`` and the heading sigma the IMU's grade can reach) and window-mean NIS below the
``cfg.nis_quantile`` quantile (window full).  Status per epoch (:class:`~.states.AlignmentState`):
ALIGNING (0), ALIGNED (1), DEGRADED (2: aligned, but the current window is inconsistent).

Large heading errors: :class:`InFlightAligner` is a bank of ``cfg.heading_hypotheses`` filters
(class docstring) pruned by their accumulated innovation likelihood; each filter has a coarse and
a fine phase (``IfaFilterConfig.coarse_heading_sigma_deg``).  The alignment is declared only once one
hypothesis is left.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dpos_core.units import DEG, FloatArray

from .. import earth
from ..attitude import dcm_to_quat, quat_to_dcm
from ..chi2 import chi2_quantile
from ..errors import NumericalFailure, RejectedInput
from ..filters.dd2 import (
    ChangePointWindow,
    InnovationWindow,
    NoiseWindow,
    add2_update,
    aekf_predict,
    aekf_update,
    dd2_predict,
    dd2_update,
    divided_differences,
)
from ..filters.jacobian import central_difference_jacobian, steps_from_cov
from ..filters.linalg import JitterRepairs, chol, householder_tria, solve_spd, symmetrize
from ..frames import C_nb_from_hpr, hpr_error, hpr_from_C_nb
from ..series import GnssSeries, ImuSeries, NavSeries
from ..strapdown import NavState
from . import constraints
from .model import GnssFix, IfaFilterConfig, IfaModel, check_fix
from .standstill import detect_standstill
from .states import AlignmentState

#: two stamps closer than this are the same instant [s] (as dpos_core.ifa.mechanization.STAMP_TOL_S)
STAMP_TOL_S = 1e-6

METHODS = ("add2", "dd2", "aekf")


def noise_window(cfg: IfaFilterConfig) -> NoiseWindow:
    """The innovation window of ADD2 / AEKF's R estimate (``cfg.r_estimator``): ``window``, eq. 22's
    moving window of ``cfg.window`` epochs (:class:`~dpos_core.filters.dd2.InnovationWindow`), or
    ``changepoint``, up to ``cfg.r_window_max`` epochs per channel, restarted at detected noise
    changes (:class:`~dpos_core.filters.dd2.ChangePointWindow`, one scale per channel)."""
    if cfg.r_estimator == "window":
        return InnovationWindow(cfg.window)
    return ChangePointWindow(cfg.r_window_max, cfg.r_min_epochs, None, cfg.r_change_quantile)


@dataclass(frozen=True)
class HypothesisEvent:
    """Something the bank of heading hypotheses did at an epoch (module docstring).

    Attributes:
        t_s: the epoch (GNSS fix time) [s].
        offset_deg: the hypothesis' initial heading offset from the given heading [deg].
        kind: ``failed`` (its update failed numerically: dropped), ``pruned`` (its accumulated
            log-likelihood fell too far below the best), ``merged`` (it converged to the heading of
            a likelier one), ``diverged`` (the innovations left every bound: the alignment
            restarts, offset 0).
        reason: what happened, for people.
    """

    t_s: float
    offset_deg: float
    kind: str
    reason: str

    def __str__(self) -> str:
        return f"heading hypothesis {self.offset_deg:+.0f} deg {self.kind} at t={self.t_s:.3f} s: {self.reason}"


@dataclass
class EpochRecord:
    t_s: float
    x: FloatArray  # estimate before feedback (n,)
    P: FloatArray  # covariance (n, n)
    correction: FloatArray
    nu: FloatArray
    nis: float
    nis_window: float
    R_diag: FloatArray  # diagonal of the R the gain used
    status: AlignmentState
    loglik: float = 0.0  #: log-likelihood of this epoch's innovation (model covariance)
    hypotheses: int = 1  #: heading hypotheses still alive after this epoch
    events: list[HypothesisEvent] = field(default_factory=list)  #: what the bank did at this epoch
    #: the standstill test of the epoch's IMU window (None: not made, too few samples)
    at_rest: bool | None = None
    #: the constraint updates applied after the fix's: ``zupt``, ``zaru``, ``nhc`` (:mod:`.constraints`)
    constraints: tuple[str, ...] = ()
    #: normalized innovation squared of the constraint updates (nan without), chi-square with their dimension when consistent
    constraint_nis: float = float("nan")


@dataclass
class SmootherStep:
    """What the RTS smoother (:mod:`.smoother`) needs of one filter step (a GNSS update or a time
    update alone), recorded by an engine built with ``record_smoother``.  All in the coordinates of
    the step's filtered state after its closed-loop feedback (``shift``): x_p (n,), P_p (n, n) the
    prediction to this step, C (n, n) its cross-covariance with the previous step's filtered state
    (the divided-difference ``S S_x1^T`` of :func:`~dpos_core.filters.dd2.dd2_predict`, ``P F^T`` for
    AEKF), both re-expressed after this step's feedback by the statistical linearization of the
    shift; x_f, P_f the filtered state; correction (n,) the feedback (zeros for a time update alone);
    restart: the state (x, P) the fine phase restarted from at this step, else None (the chain of
    the smoother breaks there: the next step's C is relative to it).  The first step (the prior at
    the start) has no prediction (x_p, P_p, C None)."""

    t_s: float  #: navigation time of the step [s]
    x_f: FloatArray
    P_f: FloatArray
    correction: FloatArray
    x_p: FloatArray | None = None
    P_p: FloatArray | None = None
    C: FloatArray | None = None
    restart: tuple[FloatArray, FloatArray] | None = None


class _Engine:
    """One hypothesis of the online in-flight alignment (module docstring).

    Args:
        initial: navigation state at the start (t_s, attitude with the heading error, ...).
        lever_arm_m: IMU -> GNSS antenna in IMU (FLU) axes (3,).
        cfg: :class:`~.model.IfaFilterConfig`.
        method: ``add2``, ``dd2`` or ``aekf``.
        imu_dt_s: IMU sample interval (process noise per sample, stamp tolerance).
    """

    def __init__(self, initial: NavState, lever_arm_m: ArrayLike, cfg: IfaFilterConfig = IfaFilterConfig(),
                 method: str = "add2", imu_dt_s: float = 0.01, record_smoother: bool = False) -> None:
        if method not in METHODS:
            raise ValueError(f"unknown IFA method {method!r}; choose one of {METHODS}")
        self.method = method
        self.cfg = cfg
        self.model = IfaModel(initial, lever_arm_m, cfg, imu_dt_s)
        self.model.feed_biases = cfg.feeds_biases_while_aligning
        x0, P0 = self.model.prior()
        self.x = x0
        self.S = chol(P0)  # square-root form (DD2 / ADD2)
        self.P = P0  # covariance form (AEKF)
        self.window = noise_window(cfg)  # adaptation (ADD2 / AEKF)
        self.nis_hist: list[float] = []
        self.sig_h_hist: list[float] = []  #: heading 1 sigma [rad] of the last ``window`` epochs (ALIGNED)
        self.nis_used_hist: list[float] = []  #: NIS with r_ceiling x R (divergence), last ``window`` epochs
        self.last_fix_t: float | None = None
        self.status = AlignmentState.ALIGNING
        self.aligned_t_s: float | None = None
        self.may_align = True  #: False while other heading hypotheses are alive
        self.fine = False  #: coarse (False) / fine (True) phase
        self.fine_t_s: float | None = None
        #: (t_s, gyro-bias covariance block (3, 3)) after the last applied standstill update: what the
        #: rest told about the vertical gyro bias, which the fine-phase restart keeps (:meth:`_epoch`)
        self.rest_gyro: tuple[float, FloatArray] | None = None
        self.records: list[EpochRecord] = []
        self._nis_limit = chi2_quantile(cfg.nis_quantile, cfg.window * cfg.p) / cfg.window
        #: the smoother's record of every filter step (:class:`SmootherStep`), None unless ``record_smoother``
        self.smoother_steps: list[SmootherStep] | None = None
        self.initial = initial
        if record_smoother:
            self.smoother_steps = [SmootherStep(initial.t_s, x0.copy(), P0.copy(), np.zeros(self.model.n))]

    # ------------------------------------------------------------------ accessors
    @property
    def cov(self) -> FloatArray:
        return self.P if self.method == "aekf" else symmetrize(self.S @ self.S.T)

    @property
    def attitude_sigma_rad(self) -> FloatArray:
        """1-sigma of the attitude error about E, N, U (3,) [rad] (U ~ heading)."""
        return np.sqrt(np.diag(self.cov)[self.model.phi_index])

    @property
    def nav(self) -> NavState:
        return self.model.strapdown.state

    @property
    def aligned(self) -> bool:
        """The alignment has been declared (latched until a restart)."""
        return self.aligned_t_s is not None

    def bias_estimates(self) -> tuple[FloatArray, FloatArray]:
        """Total gyro [rad/s] and accelerometer [m/s^2] bias estimates (compensation + state)."""
        ie, ia = self.model.bias_index
        X = self.x
        return self.model.gyro_bias_comp + X[ie], self.model.accel_bias_comp + X[ia]

    # ------------------------------------------------------------------ online API
    def propagate(self, t_s: ArrayLike, omega_radps: ArrayLike, f_mps2: ArrayLike) -> None:
        """Integrate IMU samples (strictly after the navigation time)."""
        self.model.propagate(np.asarray(t_s, dtype=float), np.asarray(omega_radps, dtype=float),
                             np.asarray(f_mps2, dtype=float))

    def check(self, fix: GnssFix) -> None:
        """Raise :class:`~dpos_core.errors.RejectedInput` if ``fix`` cannot be used now (nothing changes)."""
        check_fix(fix, self.last_fix_t)
        t_nav = self.model.t_s
        if abs(fix.t_s - t_nav) > self.cfg.max_fix_bridge_s + 1e-9:
            raise RejectedInput(f"GNSS fix at t={fix.t_s} but the navigation is at t={t_nav} (more than max_fix_bridge_s "
                                f"= {self.cfg.max_fix_bridge_s} s apart): propagate the IMU to the fix first", what="GNSS fix",
                                reason="not_at_nav_time", t_s=fix.t_s)

    def update(self, fix: GnssFix) -> EpochRecord:
        """One filter epoch at a GNSS fix: time update since the last epoch, measurement update
        (method), closed-loop feedback, alignment decision.  Raises
        :class:`~dpos_core.errors.RejectedInput` (state untouched) for an unusable fix, and
        :class:`~dpos_core.errors.NumericalFailure` (previous state restored) when the update
        fails numerically (a covariance beyond repair, a singular matrix, a non-finite state)."""
        self.check(fix)
        saved = (self.x.copy(), self.S.copy(), self.P.copy(), self.window.copy(), list(self.nis_hist), list(self.nis_used_hist),
                 list(self.sig_h_hist))
        try:
            return self._epoch(fix)
        except (NumericalFailure, np.linalg.LinAlgError, FloatingPointError) as e:
            self.x, self.S, self.P, self.window, self.nis_hist, self.nis_used_hist, self.sig_h_hist = saved
            raise NumericalFailure(f"GNSS fix at t={fix.t_s}: the {self.method.upper()} update failed numerically "
                                   f"({type(e).__name__}: {e}); the previous state is restored", what="IFA filter", t_s=fix.t_s) from e

    def predict(self) -> None:
        """Time update alone to the navigation time (no fix: an outage); the covariance grows
        with the process noise, the next interval starts here.  Raises
        :class:`~dpos_core.errors.NumericalFailure` (state restored) when it fails numerically."""
        m = self.model
        lin = m.interval()
        if lin is None:
            return
        saved = (self.x.copy(), self.S.copy(), self.P.copy())
        try:
            f = lambda X: m.f(lin, X)  # noqa: E731
            Q = m.Q(lin)
            if self.method == "aekf":
                P_prev = self.P
                self.x, self.P, F = aekf_predict(self.x, self.P, f, Q)
                C = P_prev @ F.T
            else:
                pr = dd2_predict(self.x, self.S, f, chol(Q + 1e-30 * np.eye(m.n)))
                self.x, self.S, C = pr.x, pr.S, pr.C
            if self.smoother_steps is not None:
                P_now = self.cov
                self.smoother_steps.append(SmootherStep(m.t_s, self.x.copy(), P_now, np.zeros(m.n), self.x.copy(), P_now, C))
        except (NumericalFailure, np.linalg.LinAlgError, FloatingPointError) as e:
            self.x, self.S, self.P = saved
            raise NumericalFailure(f"time update at t={m.t_s} failed numerically ({type(e).__name__}: {e})",
                                   what="IFA filter", t_s=m.t_s) from e
        m.start_interval()

    # ------------------------------------------------------------------ one epoch
    def _epoch(self, fix: GnssFix) -> EpochRecord:
        m, cfg = self.model, self.cfg
        lin = m.interval()
        x, S, P = self.x, self.S, self.P
        C_pred = symmetrize(P) if self.method == "aekf" else symmetrize(S @ S.T)  # no time passed: x_{k+1} = x_k
        if lin is not None:
            f = lambda X: m.f(lin, X)  # noqa: E731
            Q = m.Q(lin)
            if self.method == "aekf":
                P_prev = P
                x, P, F = aekf_predict(x, P, f, Q)
                C_pred = P_prev @ F.T
            else:
                pr = dd2_predict(x, S, f, chol(Q + 1e-30 * np.eye(m.n)))
                x, S, C_pred = pr.x, pr.S, pr.C
        pred = (x.copy(), S.copy(), P.copy())
        y, h, R = m.measurement(fix)
        SR = chol(R)
        # adaptation gate of eq. 22's window: while the predicted heading sigma is large the innovations
        # are dominated by the nonlinear heading error, which the window minus the *current* state part
        # takes for GNSS noise; the change-point window subtracts each innovation's own state part and
        # adapts from the first epoch (module docstring)
        adapt = (self.fine or cfg.r_estimator == "changepoint") and cfg.adaptive
        window = self.window.copy() if adapt else noise_window(cfg)
        if self.method == "aekf":
            Hs = _jac(h, x, P)
            Py_model = symmetrize(Hs @ P @ Hs.T + R)  # model innovation covariance (nominal R) for the NIS
            x, P, nu, _, _, R_used = aekf_update(x, P, y, h, R, window, r_floor=cfg.r_floor, diagonal=cfg.adapt_diagonal,
                                                 debias=cfg.adapt_debias, r_ceiling=cfg.r_ceiling, adapt=adapt)
        elif self.method == "add2":
            fac = divided_differences(x, S, h)
            Py_model = symmetrize(fac.S1 @ fac.S1.T + fac.S2 @ fac.S2.T + R)
            up, R_used = add2_update(x, S, y, h, SR, window, r_floor=cfg.r_floor, diagonal=cfg.adapt_diagonal, debias=cfg.adapt_debias,
                                      r_ceiling=cfg.r_ceiling, adapt=adapt)
            x, S, nu = up.x, up.S, up.nu
        else:
            up = dd2_update(x, S, y, h, SR)
            x, S, nu = up.x, up.S, up.nu
            Py_model = symmetrize(up.S_y @ up.S_y.T)
            R_used = R
        at_rest, applied, cons = self._constraints(fix)
        c_nis = float("nan")
        if cons:  # sequential updates with their nominal R (no adaptation): after the fix's, before the feedback
            ys, hs, Rs = zip(*cons)
            y_c = np.concatenate(ys)
            R_c = np.zeros((y_c.size, y_c.size))
            o = 0
            for Ri in Rs:
                R_c[o:o + Ri.shape[0], o:o + Ri.shape[0]] = Ri
                o += Ri.shape[0]
            h_c = lambda X: np.concatenate([hi(X) for hi in hs], axis=-1)  # noqa: E731
            if self.method == "aekf":
                H = _jac(h_c, x, P)
                Sy = symmetrize(H @ P @ H.T + R_c)
                K = np.linalg.solve(Sy, H @ P).T
                nu_c = y_c - h_c(x[None])[0]
                c_nis = float(nu_c @ solve_spd(Sy, nu_c[:, None])[:, 0])
                if c_nis <= chi2_quantile(cfg.nis_quantile, y_c.size):
                    x = x + K @ nu_c
                    IKH = np.eye(m.n) - K @ H
                    P = symmetrize(IKH @ P @ IKH.T + K @ R_c @ K.T)
            else:
                up_c = dd2_update(x, S, y_c, h_c, chol(R_c))
                c_nis = float(np.sum(np.linalg.solve(up_c.S_y, up_c.nu) ** 2))
                if c_nis <= chi2_quantile(cfg.nis_quantile, y_c.size):
                    x, S = up_c.x, up_c.S
            if c_nis > chi2_quantile(cfg.nis_quantile, y_c.size):  # gated: not at rest after all (a start within the window)
                applied = ()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(S)) and np.all(np.isfinite(P))):
            raise NumericalFailure("non-finite state after the update", what="IFA filter", t_s=fix.t_s)
        nis = float(nu @ solve_spd(Py_model, nu[:, None])[:, 0])
        # divergence is judged against the largest R the adaptation may reach (r_ceiling x nominal): a
        # GNSS noisier than modelled (up to 10x the sigma) is DEGRADED, innovations beyond even that are not noise
        nis_used = float(nu @ solve_spd(symmetrize(Py_model + (cfg.r_ceiling - 1.0) * R), nu[:, None])[:, 0])
        self.nis_used_hist = (self.nis_used_hist + [nis_used])[-cfg.window:]
        loglik = -0.5 * (nis + float(np.linalg.slogdet(2.0 * np.pi * Py_model)[1]))
        self.nis_hist = (self.nis_hist + [nis])[-cfg.window:]
        nis_w = float(np.mean(self.nis_hist))
        x_hat = x.copy()
        P_hat = symmetrize(P) if self.method == "aekf" else symmetrize(S @ S.T)
        # alignment decision (latched) and consistency (every epoch, before and after it)
        sig_h = float(np.sqrt(P_hat[m.phi_index][:, m.phi_index][2, 2]))
        full = len(self.nis_hist) >= cfg.window
        consistent = full and nis_w < self._nis_limit
        self.sig_h_hist = (self.sig_h_hist + [sig_h])[-cfg.window:]
        settled = len(self.sig_h_hist) >= cfg.window and max(self.sig_h_hist) < cfg.aligned_heading_threshold_rad
        if not self.aligned and self.may_align and consistent and settled:
            self.aligned_t_s = fix.t_s
            m.feed_biases = True
        if full and not consistent:
            self.status = AlignmentState.DEGRADED
        else:
            self.status = AlignmentState.ALIGNED if self.aligned else AlignmentState.ALIGNING
        # closed loop (eq. 24 reset): feedback, then re-express the state and its covariance
        c = m.feedback(x, fix)
        shift = lambda X: m.shift(X, c)  # noqa: E731
        if self.method == "aekf":
            Hs = _jac(shift, x, P)
            P = symmetrize(Hs @ P @ Hs.T)
            x = shift(x[None])[0]
        else:
            fac = divided_differences(x, S, shift)
            x = fac.y
            S = householder_tria(np.concatenate([fac.S1, fac.S2], axis=-1))
        ie, _ = m.bias_index
        if "zaru" in applied:
            P_now = P if self.method == "aekf" else symmetrize(S @ S.T)
            self.rest_gyro = (fix.t_s, P_now[ie, ie].copy())
        step = None
        if self.smoother_steps is not None:
            step = self._smoother_step(fix.t_s, m.t_s, pred, C_pred, shift, x, P if self.method == "aekf" else symmetrize(S @ S.T), c)
        if not self.fine and sig_h < cfg.coarse_heading_sigma_deg * DEG:
            # end of the coarse phase: restart from the coarse estimate (already fed back)
            self.fine = True
            self.fine_t_s = fix.t_s
            x_fine, P_fine = m.prior(fine_from=P_hat)
            gi = m.gam_index
            if gi.size:  # the gyro axis errors are not fed back: keep their estimate and covariance
                P_cur = P if self.method == "aekf" else symmetrize(S @ S.T)
                x_fine[gi] = x[gi]
                P_fine[np.ix_(gi, gi)] = P_cur[np.ix_(gi, gi)]
            if self.rest_gyro is not None:
                # the gyro bias about the vertical seen at rest (ZARU) is not the coarse transient's: keep
                # its estimate and the rest's variance along Up, grown by the bias walk since; the other
                # directions restart from the prior (docs/ifa.md, "ZUPT and ZARU": without this the fine
                # phase's heading error leaked into the vertical bias, with all three axes kept the level
                # axes, tied at rest to the level and the accelerometer biases, made the attitude overconfident)
                t_rest, B = self.rest_gyro
                q_g, _ = cfg.imu.bias_walk_variance(max(fix.t_s - t_rest, 0.0))
                u = m.strapdown.state.C_nb[2]  # Up in IMU axes
                U = np.outer(u, u)
                x_fine[ie] = U @ x[ie]
                P_fine[ie, ie] = (np.eye(3) - U) @ P_fine[ie, ie] @ (np.eye(3) - U) + (float(u @ B @ u) + q_g) * U
            x, P = x_fine, P_fine
            S = chol(P)
            if step is not None:
                step.restart = (x.copy(), P.copy())
            if cfg.r_estimator == "window":
                window = noise_window(cfg)
        m.start_interval()
        self.x, self.S, self.P, self.window = x, S, P, window
        self.last_fix_t = fix.t_s
        if step is not None and self.smoother_steps is not None:
            self.smoother_steps.append(step)
        rec = EpochRecord(fix.t_s, x_hat, P_hat, c, nu, nis, nis_w, np.diag(R_used).copy(), self.status, loglik,
                          at_rest=at_rest, constraints=applied, constraint_nis=c_nis)
        self.records.append(rec)
        return rec

    def _constraints(self, fix: GnssFix) -> tuple[bool | None, tuple[str, ...], list[constraints.Measurement]]:
        """The standstill test of the IMU window before the epoch (``cfg.standstill_window_s``, the
        IMU model's noise, ``cfg.standstill_noise_factor``, the fix's speed) and the constraint
        measurements it calls for (:mod:`.constraints`): ZUPT and ZARU at rest
        (``cfg.standstill_updates``, ``cfg.zupt``, ``cfg.zaru``), NHC in motion in the fine phase (``cfg.nhc``).  Returns
        ``(at_rest or None without a window, names, [(y, h, R)])``.  The caller gates them: an
        update whose NIS (their innovation covariance) is beyond the ``cfg.nis_quantile`` chi-square
        quantile is not applied (the vehicle started within the window; ``EpochRecord.constraints``
        is then empty, ``constraint_nis`` says why)."""
        m, cfg = self.model, self.cfg
        t, om, fb = m.recent_samples()
        at_rest: bool | None = None
        dt = float(np.median(np.diff(t))) if t.size >= 2 else 0.0
        if t.size >= 3 and t[-1] - t[0] >= 0.5 * cfg.standstill_window_s:
            test = detect_standstill(om - m.gyro_bias_comp, fb - m.accel_bias_comp, cfg.imu, dt, np.asarray(fix.vel_n_mps, dtype=float),
                                     noise_factor=cfg.standstill_noise_factor)
            at_rest = test.at_rest
        nom = m.strapdown.state
        C = nom.C_nb
        if at_rest and cfg.standstill_updates and (cfg.zupt or cfg.zaru):
            g_sig, _ = cfg.imu.white_sigma(dt)
            names = ("zupt",) * cfg.zupt + ("zaru",) * cfg.zaru
            ms = [constraints.zupt(nom.vel_n_mps, cfg.zupt_sigma_mps, m.full, fb, dt, C)] if cfg.zupt else []
            if cfg.zaru:
                ms.append(constraints.zaru(om, m.gyro_bias_comp, C, earth.earth_rate_n(nom.llh[0]), g_sig, m.full))
            return at_rest, names, ms
        if cfg.nhc and self.fine and at_rest is not None and not at_rest:
            return at_rest, ("nhc",), [constraints.nhc(nom.vel_n_mps, C, cfg.nhc_sigma_mps, m.full)]
        return at_rest, (), []


    def _smoother_step(self, t_fix_s: float, t_nav_s: float, pred: tuple[FloatArray, FloatArray, FloatArray], C: FloatArray,
                       shift, x_f: FloatArray, P_f: FloatArray, c: FloatArray) -> SmootherStep:
        """The :class:`SmootherStep` of an update epoch: the prediction ``pred = (x, S, P)`` and its
        cross-covariance ``C`` re-expressed after the feedback ``shift`` by its statistical
        linearization ``J`` (divided differences over the prediction's factor; the Jacobian for AEKF):
        ``x_p = E[shift(x)]``, ``P_p = J P J^T`` (+ the second-order part), ``C J^T``."""
        x, S, P = pred
        if self.method == "aekf":
            J = _jac(shift, x, P)
            x_p, P_p = shift(x[None])[0], symmetrize(J @ P @ J.T)
        else:
            fac = divided_differences(x, S, shift)
            x_p = fac.y
            P_p = symmetrize(fac.S1 @ fac.S1.T + fac.S2 @ fac.S2.T)
            J = np.asarray(np.linalg.solve(S.T, fac.S1.T), dtype=float).T  # S1 = J S
        return SmootherStep(t_nav_s, x_f.copy(), symmetrize(P_f), np.asarray(c, dtype=float).copy(), x_p, P_p, C @ J.T)


class InFlightAligner:
    """Online in-flight alignment (module docstring): a bank of heading hypotheses.

    Args:
        initial: navigation state at the start (t_s, attitude with the heading error, ...).
        lever_arm_m: IMU -> GNSS antenna in IMU (FLU) axes (3,).
        cfg: :class:`~.model.IfaFilterConfig` (``heading_hypotheses``, ``hypothesis_prune_log``).
        method: ``add2``, ``dd2`` or ``aekf``.
        imu_dt_s: IMU sample interval (process noise per sample, stamp tolerance).

    With ``cfg.heading_hypotheses = M > 1`` the engine runs M filters whose initial headings are
    the given one plus ``k 360/M`` deg, each with a heading prior sigma of ``min(heading_sigma_deg,
    180/M)`` deg, and accumulates the log-likelihood of each one's innovations.  A hypothesis whose
    accumulated log-likelihood falls more than ``hypothesis_prune_log`` below the best is dropped;
    the reported one (``.nav``, ``.x``, records, ...) is the given heading until it is dropped, then
    the best survivor.  Two hypotheses whose headings agree within ``coarse_heading_sigma_deg``
    converged to the same solution: the less likely one is dropped.  No hypothesis may declare the
    alignment while others are alive.  A hypothesis whose update fails numerically is dropped
    while others remain.  Each epoch's record lists these events (:class:`HypothesisEvent`);
    :attr:`events` keeps them all, :attr:`hypotheses_failed` counts the numerical failures and
    :attr:`chol_jitter_repairs` the Cholesky jitter repairs made by the bank.
    """

    def __init__(self, initial: NavState, lever_arm_m: ArrayLike, cfg: IfaFilterConfig = IfaFilterConfig(),
                 method: str = "add2", imu_dt_s: float = 0.01, record_smoother: bool = False) -> None:
        if method not in METHODS:
            raise ValueError(f"unknown IFA method {method!r}; choose one of {METHODS}")
        self.method, self.cfg = method, cfg
        self.record_smoother = record_smoother  #: every engine keeps its SmootherStep s (:mod:`.smoother`)
        #: Cholesky jitter repairs made by this bank (dpos_core.filters.linalg)
        self.jitter = JitterRepairs()
        #: every hypothesis event so far (module docstring), oldest first
        self.events: list[HypothesisEvent] = []
        #: hypotheses dropped because their update failed numerically
        self.hypotheses_failed = 0
        self._lever_arm_m, self._imu_dt_s = lever_arm_m, imu_dt_s
        #: restarts after a divergence (class docstring)
        self.restarts = 0
        self._diverging = 0  # consecutive epochs beyond the divergence limit
        self._diverged_now = False
        self._limit = chi2_quantile(cfg.nis_quantile, cfg.window * cfg.p) / cfg.window * cfg.diverged_nis_factor
        self.records: list[EpochRecord] = []
        #: (t_s, covariance (9, 9) of the navigation errors: position E, N, U [m], velocity E, N, U [m/s],
        #: attitude about E, N, U [rad]) after every filter epoch (updates and time updates alone), oldest first
        self.track: list[tuple[float, FloatArray]] = []
        self._build_bank(initial)
        self.last_epoch_t_s = initial.t_s  #: time of the last filter epoch (update or time update alone)

    def _build_bank(self, initial: NavState, keep_from: _Engine | None = None) -> None:
        """The bank of heading hypotheses around ``initial`` (``keep_from``: carry its bias
        compensation and last fix over, as after a restart)."""
        cfg, method, lever_arm_m, imu_dt_s = self.cfg, self.method, self._lever_arm_m, self._imu_dt_s
        M = cfg.heading_hypotheses
        with self.jitter:
            if M == 1:
                self.hyps = [_Engine(initial, lever_arm_m, cfg, method, imu_dt_s, self.record_smoother)]
            else:
                sub = replace(cfg, heading_sigma_deg=min(cfg.heading_sigma_deg, 180.0 / M))
                self.hyps = [_Engine(_rotate_heading(initial, k * 2.0 * np.pi / M), lever_arm_m, sub, method, imu_dt_s, self.record_smoother)
                             for k in range(M)]
        if keep_from is not None:
            for h in self.hyps:
                h.model.gyro_bias_comp = keep_from.model.gyro_bias_comp.copy()
                h.model.accel_bias_comp = keep_from.model.accel_bias_comp.copy()
                h.last_fix_t = keep_from.last_fix_t
        self.loglik = np.zeros(M)
        self.offsets_deg = [k * 360.0 / M for k in range(M)]
        self._cur = 0
        self._sync()

    @property
    def status(self) -> AlignmentState:
        """DIVERGED at the epoch a divergence was detected, else the reported hypothesis' status."""
        return AlignmentState.DIVERGED if self._diverged_now else self.engine.status

    @property
    def next_predict_t_s(self) -> float:
        """IMU time at which a time update alone is due when no fix came (``cfg.predict_interval_s``)."""
        return self.last_epoch_t_s + self.cfg.predict_interval_s

    def predict(self) -> None:
        """Time update alone in every hypothesis, at the navigation time (no fix since
        ``predict_interval_s``).  A hypothesis whose time update fails numerically is dropped
        while others remain; :class:`~dpos_core.errors.NumericalFailure` when all fail."""
        failed: list[int] = []
        with self.jitter:
            for i, h in enumerate(self.hyps):
                try:
                    h.predict()
                except NumericalFailure:
                    failed.append(i)
        if len(failed) == len(self.hyps):
            raise NumericalFailure(f"time update at t={self.engine.model.t_s} failed in every heading hypothesis", what="IFA filter",
                                   t_s=self.engine.model.t_s)
        if failed:
            keep = [i for i in range(len(self.hyps)) if i not in failed]
            cur = self._cur if self._cur in keep else keep[0]
            self.events += [HypothesisEvent(self.engine.model.t_s, self.offsets_deg[i], "failed", "time update failed numerically")
                            for i in failed]
            self.hypotheses_failed += len(failed)
            self.hyps = [self.hyps[i] for i in keep]
            self.offsets_deg = [self.offsets_deg[i] for i in keep]
            self.loglik = self.loglik[keep]
            self._cur = keep.index(cur)
            self._sync()
        self.last_epoch_t_s = self.engine.model.t_s
        self._log_track()

    def _log_track(self) -> None:
        e = self.engine
        self.track.append((e.model.t_s, symmetrize(e.model.nav_cov15(e.cov)[:9, :9])))

    def _sync(self) -> None:
        for h in self.hyps:
            h.may_align = len(self.hyps) == 1

    @property
    def engine(self) -> _Engine:
        """The reported hypothesis."""
        return self.hyps[self._cur]

    @property
    def hypotheses(self) -> int:
        return len(self.hyps)

    @property
    def chol_jitter_repairs(self) -> int:
        """Cholesky jitter repairs made by this bank so far (counted, not silent)."""
        return self.jitter.count

    def __getattr__(self, name: str):
        """``status``, ``aligned``, ``aligned_t_s``, ``nav``, ``cov``, ``attitude_sigma_rad``,
        ``bias_estimates()``, ``x``, ``S``, ``P``, ``window``, ``model``, ``last_fix_t``, ``fine``:
        those of the reported hypothesis (:attr:`engine`)."""
        if name in ("hyps", "_cur"):
            raise AttributeError(name)
        return getattr(self.hyps[self._cur], name)

    def propagate(self, t_s: ArrayLike, omega_radps: ArrayLike, f_mps2: ArrayLike) -> None:
        """Integrate IMU samples (strictly after the navigation time) in every hypothesis."""
        for h in self.hyps:
            h.propagate(t_s, omega_radps, f_mps2)

    def check(self, fix: GnssFix) -> None:
        """Raise :class:`~dpos_core.errors.RejectedInput` if ``fix`` cannot be used now (nothing changes)."""
        self.engine.check(fix)

    def update(self, fix: GnssFix) -> EpochRecord:
        """One filter epoch in every hypothesis, then pruning (class docstring).

        Raises :class:`~dpos_core.errors.RejectedInput` (nothing changed) for an unusable fix and
        :class:`~dpos_core.errors.NumericalFailure` (every hypothesis restored) when the update
        fails numerically in every hypothesis.  A hypothesis whose update fails while others
        succeed is dropped; the returned record's ``events`` say so (and what was pruned)."""
        self.check(fix)
        recs: dict[int, EpochRecord] = {}
        failed: dict[int, NumericalFailure] = {}
        with self.jitter:
            for i, h in enumerate(self.hyps):
                try:
                    recs[i] = h.update(fix)
                except NumericalFailure as e:
                    failed[i] = e
        if not recs:
            first = next(iter(failed.values()))
            raise NumericalFailure(f"GNSS fix at t={fix.t_s}: the update failed numerically in every heading hypothesis "
                                   f"({len(failed)}), the previous state is kept: {first}", what="IFA filter", t_s=fix.t_s) from first
        events = [HypothesisEvent(fix.t_s, self.offsets_deg[i], "failed", f"dropped: {e}") for i, e in failed.items()]
        keep = sorted(recs)
        ll = np.array([self.loglik[i] + recs[i].loglik for i in keep])
        limit = self.cfg.hypothesis_prune_log
        alive = [k for k, i in enumerate(keep) if ll[k] >= ll.max() - limit]
        events += [HypothesisEvent(fix.t_s, self.offsets_deg[keep[k]], "pruned",
                                   f"log-likelihood {ll[k] - ll.max():.1f} below the best (limit -{limit:g})")
                   for k in range(len(keep)) if k not in alive]
        if len(alive) > 1:  # hypotheses that converged to the same heading: keep the likelier one
            yaw = np.array([hpr_from_C_nb(quat_to_dcm(self.hyps[keep[k]].nav.q_nb))[0] for k in alive])
            order = sorted(range(len(alive)), key=lambda j: -ll[alive[j]])
            kept: list[int] = []
            for j in order:
                if all(abs(np.angle(np.exp(1j * (yaw[j] - yaw[q])))) >= self.cfg.coarse_heading_sigma_deg * DEG for q in kept):
                    kept.append(j)
            events += [HypothesisEvent(fix.t_s, self.offsets_deg[keep[alive[j]]], "merged",
                                       f"converged to the heading of a likelier hypothesis (within {self.cfg.coarse_heading_sigma_deg:g} deg)")
                       for j in range(len(alive)) if j not in kept]
            alive = [alive[j] for j in sorted(kept)]
        cur = self._cur if self._cur in [keep[k] for k in alive] else keep[alive[int(np.argmax(ll[alive]))]]
        rec = recs[cur]
        self.hyps = [self.hyps[keep[k]] for k in alive]
        self.offsets_deg = [self.offsets_deg[keep[k]] for k in alive]
        self.loglik = ll[alive] - ll[alive].max()
        self._cur = [keep[k] for k in alive].index(cur)
        self._sync()
        rec.hypotheses = len(self.hyps)
        # divergence: the reported hypothesis' window far beyond its consistency limit, several epochs
        rep = self.engine
        self._diverged_now = False
        nis_used_w = float(np.mean(rep.nis_used_hist)) if rep.nis_used_hist else 0.0
        if len(rep.nis_used_hist) >= self.cfg.window and nis_used_w > self._limit:
            self._diverging += 1
        else:
            self._diverging = 0
        if self._diverging >= self.cfg.diverged_epochs:
            self._diverged_now = True
            self._diverging = 0
            rec.status = AlignmentState.DIVERGED
            what = (f"window-mean NIS (with r_ceiling x R) {nis_used_w:.3g} above {self._limit:.3g} for {self.cfg.diverged_epochs} epochs")
            if self.cfg.restart_on_divergence:
                nav = rep.nav
                self.restarts += 1
                self._build_bank(NavState(nav.t_s, nav.q_nb, np.asarray(fix.vel_n_mps, dtype=float).copy(),
                                          np.asarray(fix.llh, dtype=float).copy()), keep_from=rep)
                what += ": the alignment restarts from the fix and the current attitude"
            events.append(HypothesisEvent(fix.t_s, 0.0, "diverged", what))
        rec.events = events
        self.last_epoch_t_s = self.engine.model.t_s
        self._log_track()
        self.events += events
        self.hypotheses_failed += len(failed)
        self.records.append(rec)
        return rec


def _rotate_heading(s: NavState, dpsi_rad: float) -> NavState:
    """The state with its heading increased by ``dpsi_rad`` (pitch, roll kept)."""
    hpr = hpr_from_C_nb(quat_to_dcm(s.q_nb))
    return NavState(s.t_s, dcm_to_quat(C_nb_from_hpr(hpr[0] + dpsi_rad, hpr[1], hpr[2])), s.vel_n_mps.copy(), s.llh.copy())


def _jac(fn, x: FloatArray, P: FloatArray) -> FloatArray:
    return central_difference_jacobian(fn, x, steps_from_cov(P))


# ---------------------------------------------------------------------------------- batch


@dataclass
class IfaResult:
    """Alignment over a recording.

    Navigation at the IMU rate: t_s (N,), llh (N, 3), vel_n_mps (N, 3), q_nb (N, 4) (the closed-loop
    strapdown; the sample at each epoch is the corrected state).  Epochs (K filter updates):
    epochs_s (K,), x (K, n) estimates before feedback, att_sigma_rad (K, 3) 1-sigma of the
    attitude error about E, N, U, heading_sigma_deg (K,), nis (K,), nis_window (K,),
    R_diag (K, p), status (K,) (:class:`~.states.AlignmentState` values).  aligned / aligned_t_s: the decision; gyro_bias_radps (3,),
    accel_bias_mps2 (3,): final bias estimates; rejected: [(t_s, reason)] (rejected fixes and
    epochs that failed numerically in every hypothesis); runtime_s; events: the bank's
    :class:`HypothesisEvent` s; hypotheses_failed, chol_jitter_repairs, restarts: counters; track:
    the covariance after every filter epoch (:attr:`InFlightAligner.track`).
    """

    method: str
    t_s: FloatArray
    llh: FloatArray
    vel_n_mps: FloatArray
    q_nb: FloatArray
    epochs_s: FloatArray
    x: FloatArray
    att_sigma_rad: FloatArray
    nis: FloatArray
    nis_window: FloatArray
    R_diag: FloatArray
    status: NDArray[np.int_]
    aligned: bool
    aligned_t_s: float | None
    gyro_bias_radps: FloatArray
    accel_bias_mps2: FloatArray
    final: NavState
    rejected: list[tuple[float, str]] = field(default_factory=list)
    runtime_s: float = 0.0
    events: list[HypothesisEvent] = field(default_factory=list)
    hypotheses_failed: int = 0
    chol_jitter_repairs: int = 0
    restarts: int = 0
    #: InFlightAligner.track: (t_s, navigation error covariance (9, 9)) after every filter epoch
    track: list[tuple[float, FloatArray]] = field(default_factory=list)
    #: fixes stamped before the initial state (skipped, not rejected)
    before_start: int = 0
    #: with ``run(..., record_smoother=True)``: the final hypothesis (its model's nominal chunks and
    #: :attr:`_Engine.smoother_steps`), what :func:`dpos_core.ifa.smoother.smooth` needs
    engine: _Engine | None = None
    #: per epoch (K,): the standstill test of its IMU window (1 at rest, 0 in motion, nan not made)
    at_rest: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: per epoch (K,): the constraint updates applied (``EpochRecord.constraints``)
    constraints: list[tuple[str, ...]] = field(default_factory=list)
    #: per epoch (K,): EpochRecord.constraint_nis
    constraint_nis: FloatArray = field(default_factory=lambda: np.zeros(0))

    @property
    def heading_sigma_deg(self) -> FloatArray:
        return self.att_sigma_rad[:, 2] / DEG

    @property
    def C_nb(self) -> FloatArray:
        return quat_to_dcm(self.q_nb)


def run(imu: ImuSeries, gnss: GnssSeries, lever_arm: ArrayLike, cfg: IfaFilterConfig = IfaFilterConfig(), method: str = "add2",
        initial: NavState | None = None, record_smoother: bool = False) -> IfaResult:
    """Align the main POS over recorded series.

    Args:
        imu: the main IMU's samples (:class:`~dpos_core.series.ImuSeries`: t_s (N,), omega_radps
            (N, 3), f_mps2 (N, 3), mean rates over ``(t_{i-1}, t_i]``), strictly increasing stamps.
        gnss: the fixes at the antenna (:class:`~dpos_core.series.GnssSeries`: t_s (M,), llh (M, 3),
            pos_sigma_m (M, 3), vel_n_mps (M, 3), vel_sigma_mps (M, 3)).
        lever_arm: IMU -> antenna (3,) in IMU axes.
        method: ``add2`` (default), ``dd2`` or ``aekf``.
        initial: the navigation state at the start (required: position, velocity and an attitude
            whose heading may be far off).
        record_smoother: keep what the RTS smoother needs (``IfaResult.engine``;
            :func:`dpos_core.ifa.smoother.smooth`).

    Raises :class:`~dpos_core.errors.RejectedInput` for unusable IMU series (fewer than two
    samples, non-finite values, stamps not strictly increasing); bad fixes and failed epochs are
    skipped with a warning (``IfaResult.rejected``), a dropped hypothesis is warned about.
    """
    if initial is None:
        raise ValueError("run() needs the initial navigation state")
    t_imu = np.asarray(imu.t_s, dtype=float)
    if t_imu.ndim != 1:
        raise ValueError(f"IMU stamps must have shape (N,), got {t_imu.shape}")
    if t_imu.size < 2:
        raise RejectedInput(f"IMU series of {t_imu.size} sample(s): at least 2 are needed", what="IMU samples", reason="too_short")
    if not np.all(np.isfinite(t_imu)) or np.any(np.diff(t_imu) <= 0):
        raise RejectedInput("IMU stamps must be finite and strictly increasing", what="IMU samples", reason="out_of_order")
    om, fb = np.asarray(imu.omega_radps, dtype=float), np.asarray(imu.f_mps2, dtype=float)
    if not (np.all(np.isfinite(om)) and np.all(np.isfinite(fb))):
        raise RejectedInput("IMU samples contain non-finite values", what="IMU samples", reason="nan")
    first = int(np.searchsorted(t_imu, initial.t_s + STAMP_TOL_S))  # samples after the initial state
    dt = nominal_imu_dt_s(t_imu[first:])
    t0 = time.perf_counter()
    al = InFlightAligner(initial, lever_arm, cfg, method, dt, record_smoother)
    i = first
    rejected: list[tuple[float, str]] = []
    out: list[NavSeries] = []  # navigation of the hypothesis reported at each interval (as a node follows it)
    g_t = np.asarray(gnss.t_s, dtype=float)
    bridge = cfg.max_fix_bridge_s
    before_start = 0
    for j in range(g_t.size):
        fix = fix_at(g_t[j], gnss, j, cfg)
        if np.isfinite(fix.t_s) and fix.t_s <= initial.t_s + STAMP_TOL_S:
            before_start += 1  # not bad data: at or before the start (ifa_node skips it the same way)
            continue
        try:
            check_fix(fix, al.last_fix_t)
            if fix.t_s > t_imu[-1] + bridge or fix.t_s < al.model.t_s - bridge:
                raise RejectedInput(f"GNSS fix at t={fix.t_s} is outside the IMU data still to come", what="GNSS fix",
                                    reason="stale", t_s=fix.t_s)
        except RejectedInput as e:
            rejected.append((fix.t_s, str(e)))
            warnings.warn(f"IFA: skipping GNSS fix: {e}", stacklevel=2)
            continue
        # the samples up to the fix (the last one at or before it; the measurement bridges the rest),
        # with a time update alone every predict_interval_s without a fix
        i = advance(al, t_imu, om, fb, i, fix.t_s, out)
        try:
            rec = al.update(fix)
        except (RejectedInput, NumericalFailure) as e:
            rejected.append((fix.t_s, str(e)))
            warnings.warn(f"IFA: skipping GNSS fix: {e}", stacklevel=2)
            continue
        for ev in rec.events:
            if ev.kind == "failed":
                warnings.warn(f"IFA: {ev}", stacklevel=2)
        # the epoch sample of the output is the corrected state (of the hypothesis reported now)
        ch = out[-1] if out else None
        if ch is not None and abs(ch.t_s[-1] - al.model.t_s) < 1e-12:
            # a copy: the hypothesis' own chunk stays its nominal before the feedback (the smoother's)
            ch = out[-1] = replace(ch, q_nb=ch.q_nb.copy(), vel_n_mps=ch.vel_n_mps.copy(), llh=ch.llh.copy())
            s = al.nav
            ch.q_nb[-1], ch.vel_n_mps[-1], ch.llh[-1] = s.q_nb, s.vel_n_mps, s.llh
    if i < t_imu.size:
        i = advance(al, t_imu, om, fb, i, float(t_imu[-1]), out)
    runtime = time.perf_counter() - t0
    chunks = [NavSeries(np.array([initial.t_s]), initial.q_nb[None], initial.vel_n_mps[None], initial.llh[None])]
    nav = NavSeries.concatenate(chunks + out)
    recs = al.records
    n, p = al.model.n, al.model.p
    gb, ab = al.bias_estimates()
    return IfaResult(
        method, nav.t_s, nav.llh, nav.vel_n_mps, nav.q_nb,
        np.array([r.t_s for r in recs]), np.array([r.x for r in recs]).reshape(-1, n),
        np.array([np.sqrt(np.diag(r.P)[al.model.phi_index]) for r in recs]).reshape(-1, 3),
        np.array([r.nis for r in recs]), np.array([r.nis_window for r in recs]),
        np.array([r.R_diag for r in recs]).reshape(-1, p), np.array([r.status for r in recs], dtype=int),
        al.aligned, al.aligned_t_s, gb, ab, al.nav, rejected, runtime, list(al.events), al.hypotheses_failed,
        al.chol_jitter_repairs, al.restarts, list(al.track), before_start, al.engine if record_smoother else None,
        np.array([np.nan if r.at_rest is None else float(r.at_rest) for r in recs]), [r.constraints for r in recs],
        np.array([r.constraint_nis for r in recs]),
    )


#: IMU samples after the start whose median interval is the nominal one (ifa_node waits for as many)
IMU_DT_SAMPLES = 51


def nominal_imu_dt_s(t_after_start_s: FloatArray) -> float:
    """The IMU interval the process noise is scaled with [s]: the median step of the first
    :data:`IMU_DT_SAMPLES` samples after the start (the same rule live and offline: ifa_node has no more
    when it starts)."""
    t = np.asarray(t_after_start_s, dtype=float)[:IMU_DT_SAMPLES]
    if t.size < 2:
        raise RejectedInput(f"{t.size} IMU sample(s) after the start: at least 2 are needed", what="IMU samples", reason="too_short")
    return float(np.median(np.diff(t)))


def advance(al: InFlightAligner, t_imu: FloatArray, om: FloatArray, fb: FloatArray, i: int, t_end_s: float,
             out: list[NavSeries]) -> int:
    """Propagate samples ``i:`` up to the last one at or before ``t_end_s``, with a time update
    alone (``al.predict``) each time ``al.next_predict_t_s`` is passed; the reported hypothesis'
    navigation chunks go to ``out``.  Returns the next sample index.

    A gap in the IMU longer than ``predict_interval_s`` (no sample up to a due time update) is
    integrated across to the first sample after it, where the time update is made: the
    process noise of that interval covers the gap's duration, and the loop always moves on."""
    n = t_imu.size
    while True:
        tick = al.next_predict_t_s
        last = min(tick, t_end_s)
        i1 = int(np.searchsorted(t_imu, last + STAMP_TOL_S, side="right"))
        if i1 == i and tick < t_end_s:  # no sample up to the due time update: a gap in the IMU
            if i >= n or t_imu[i] > t_end_s + STAMP_TOL_S:
                return i  # nothing more before t_end_s: the fix (if any) is judged against the navigation time
            i1 = i + 1
        if i1 > i:
            al.propagate(t_imu[i:i1], om[i:i1], fb[i:i1])
            out.append(al.engine.model.chunks[-1])  # the reported hypothesis' navigation
            i = i1
        if tick >= t_end_s or i >= n:
            return i
        try:
            al.predict()
        except NumericalFailure as e:
            warnings.warn(f"IFA: {e}", stacklevel=3)
            al.last_epoch_t_s = al.model.t_s


def fix_at(t_stamp_s: float, gnss: GnssSeries, j: int, cfg: IfaFilterConfig) -> GnssFix:
    """Fix ``j`` of a series as the filter takes it: its stamp ``t_stamp_s`` [s] moved onto the IMU's
    clock (minus ``cfg.gnss_time_offset_s``)."""
    return GnssFix(float(t_stamp_s) - cfg.gnss_time_offset_s, np.asarray(gnss.llh[j], dtype=float),
                   np.asarray(gnss.pos_sigma_m[j], dtype=float), np.asarray(gnss.vel_n_mps[j], dtype=float),
                   np.asarray(gnss.vel_sigma_mps[j], dtype=float))


def attitude_errors_deg(result: IfaResult, truth_q_nb: FloatArray) -> FloatArray:
    """Heading, pitch, roll errors (est - true, wrapped) [deg] (N, 3) of the result's navigation
    against truth attitudes (N, 4) at the same stamps."""
    return hpr_error(hpr_from_C_nb(result.C_nb), hpr_from_C_nb(quat_to_dcm(truth_q_nb))) / DEG


__all__ = ["METHODS", "SmootherStep", "InFlightAligner", "IfaResult", "HypothesisEvent", "run", "fix_at", "attitude_errors_deg", "STAMP_TOL_S", "advance", "nominal_imu_dt_s", "IMU_DT_SAMPLES"]
