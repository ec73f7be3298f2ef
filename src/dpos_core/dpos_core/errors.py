"""What went wrong, in terms a caller can act on: the errors the core raises on purpose.

Hierarchy::

    DposError                                      base of every error below
    +-- RejectedInput(DposError, ValueError)       bad data the caller may skip
    +-- NumericalFailure(DposError, ArithmeticError)  a filter that cannot go on from here
    +-- ConfigError(DposError, ValueError)         a scenario / aircraft file is invalid
                                                   (:mod:`dpos_core.config.files`)

    NumericalRepairWarning(RuntimeWarning)         a silent numerical repair was made (counted)

:class:`RejectedInput` is a datum that fails its checks: a GNSS fix with non-finite values or a
zero covariance, a duplicate or out-of-order stamp, NaN IMU samples.  Nothing was changed by the
call that raised it; the caller may drop that datum (counting it) and carry on.  It carries
``what`` was rejected, a short ``reason`` code and, when known, the stamp ``t_s``.  It is a
``ValueError`` so that code which caught ``ValueError`` for bad data keeps working.

:class:`NumericalFailure` is a filter that lost positive definiteness beyond repair, a
hypothesis or a smoother that diverged (non-finite state, all particle weights zero).  The data
may be fine; the estimate is not.  A caller reports it as an error (it is not a bad input) and
may restart, drop that filter or give up on that product.

Programming errors are *not* in this hierarchy and must propagate: wrong array shapes, wrong
types, calls out of sequence, unknown method names and invalid configuration arguments stay
``TypeError`` / ``IndexError`` / ``ValueError``.  A caller that catches :class:`RejectedInput`
to skip bad data therefore never hides a bug (a shape ``ValueError`` is not a ``RejectedInput``).
"""

from __future__ import annotations

__all__ = ["DposError", "RejectedInput", "NumericalFailure", "NumericalRepairWarning"]


class DposError(Exception):
    """Base of the errors the dpos core raises on purpose (module docstring)."""


class RejectedInput(DposError, ValueError):
    """Bad input data that the caller may skip; nothing was changed by the rejecting call.

    Args:
        message: what was wrong, for people (the ``str()`` of the exception).
        what: the input that was rejected, e.g. ``"GNSS fix"``, ``"sub-IMU samples"``.
        reason: a short code for counters (the relay's vocabulary where it applies): ``nan``
            (non-finite values), ``duplicate``, ``out_of_order``, ``zero_cov``, ``out_of_range``,
            ``stale`` (older than the navigation), ``not_at_nav_time``, ``no_fix``, ``too_short``.
        t_s: stamp of the rejected datum [s], when it has one.

    The keyword arguments have defaults so that the exception survives pickling (worker
    processes): ``BaseException.__reduce__`` rebuilds it from ``args`` and restores the attributes.
    """

    def __init__(self, message: str, *, what: str = "input", reason: str = "invalid", t_s: float | None = None) -> None:
        super().__init__(message)
        self.what = what
        self.reason = reason
        self.t_s = t_s


class NumericalFailure(DposError, ArithmeticError):
    """A filter or smoother failed numerically beyond repair (module docstring).

    Args:
        message: what failed, for people.
        what: the estimator that failed, e.g. ``"covariance"``, ``"IFA filter"``,
            ``"heading hypothesis +60 deg"``, ``"particle filter"``.
        t_s: the epoch of the failure [s], when known.
    """

    def __init__(self, message: str, *, what: str = "filter", t_s: float | None = None) -> None:
        super().__init__(message)
        self.what = what
        self.t_s = t_s


class NumericalRepairWarning(RuntimeWarning):
    """A numerical repair was made silently (e.g. a Cholesky factor with diagonal jitter); the
    first one per call site is warned, every one is counted
    (:class:`dpos_core.filters.linalg.JitterRepairs`)."""
