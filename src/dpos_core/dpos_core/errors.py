"""What went wrong, in terms a caller can act on: the errors the core raises on purpose.

Hierarchy (every exception class of the workspace is defined here, test/dpos_core/test_errors.py)::

    DposError                                         base of every error below
    +-- RejectedInput(DposError, ValueError)          bad data the caller may skip
    +-- NumericalFailure(DposError, ArithmeticError)  a filter that cannot go on from here
    |   +-- AlignmentDiverged                          a transfer alignment whose result is not an estimate
    +-- ConfigError(DposError, ValueError)            a scenario / aircraft file is invalid
    +-- ParameterError(DposError, ValueError)         a node's or a command's parameter is invalid
    +-- InputError(DposError, ValueError)             a recording or an option cannot be used
    +-- SarInputError(DposError, ValueError)          a session cannot be SAR-navigated
    +-- SessionError(DposError, ValueError)           a recording cannot be made into a session
    +-- LogFormatError(DposError, ValueError)         a flight log cannot be read at all
    +-- BagError(DposError)                           a bag cannot be read
    +-- BagDamaged(DposError, ValueError)             a bag's layout cannot be trusted: read it from its start
    +-- OutputError(DposError)                        an output location cannot be used
    +-- ProductsExistError(DposError, FileExistsError)  products of an earlier run are in the way
    +-- GraphError(DposError, RuntimeError)           a node graph did not start or become ready
    +-- ImportFailure(DposError)                      a log import cannot go on
    +-- CampaignError(DposError)                      unusable campaign input
    +-- TaskFailed(DposError)                         a campaign task failed (the engine retries it)

    NumericalRepairWarning(RuntimeWarning)            a silent numerical repair was made (counted)

Each error keeps the builtin base it had before it joined the hierarchy, so an ``except
ValueError`` / ``except FileExistsError`` that caught it keeps catching it.  The classes carry
no ROS type: the ROS-side modules that raise them (``dpos_ros.runtime.params``,
``dpos_ros.io.play``, ...) import them from here and still export them under their old names.

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

from typing import Any

__all__ = ["DposError", "RejectedInput", "NumericalFailure", "AlignmentDiverged", "NumericalRepairWarning", "ConfigError", "ParameterError",
           "InputError", "SarInputError", "SessionError", "LogFormatError", "ClockNotObservable",
           "MountingNotObservable", "BagError", "BagDamaged", "OutputError", "ProductsExistError",
           "GraphError", "ImportFailure", "CampaignError", "TaskFailed"]


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


class AlignmentDiverged(NumericalFailure):
    """A transfer alignment that ran to its end but whose result is no estimate
    (:mod:`dpos_core.ta.guard`): its rows must not be used, the sub-IMU's antennas are not estimated.

    Args:
        message: what diverged and by how much, for people.
        reason: a short code: ``non_finite`` (a state or covariance not finite), ``nis`` (the
            innovations grossly beyond their covariance over a sustained stretch), ``position_bound``
            (a position outside the lever arm's reach from the main POS).
        what: the estimator, e.g. ``"transfer alignment (ups)"``.
        t_s: the first epoch or row where it showed [s], when known.
    """

    def __init__(self, message: str, *, reason: str = "diverged", what: str = "transfer alignment", t_s: float | None = None) -> None:
        super().__init__(message, what=what, t_s=t_s)
        self.reason = reason


class NumericalRepairWarning(RuntimeWarning):
    """A numerical repair was made silently (e.g. a Cholesky factor with diagonal jitter); the
    first one per call site is warned, every one is counted
    (:class:`dpos_core.filters.linalg.JitterRepairs`)."""


# ----------------------------------------------------------------------------- inputs and settings


class ConfigError(DposError, ValueError):
    """A scenario or aircraft file is invalid (the message names the file and the key)."""


class ParameterError(DposError, ValueError):
    """An invalid parameter value of a node or a command; the message names the parameter and the value.

    Args:
        name: the parameter's name.
        value: the value that was given.
        reason: why it is invalid, for people.
    """

    def __init__(self, name: str, value: Any, reason: str) -> None:
        self.name = name
        self.value = value
        self.reason = reason
        super().__init__(f"invalid parameter '{name}' = {value!r}: {reason}")

    def __reduce__(self) -> tuple[type[ParameterError], tuple[str, Any, str]]:
        return type(self), (self.name, self.value, self.reason)  # survives pickling (worker processes)


class InputError(DposError, ValueError):
    """A recording or an option cannot be used (the message says which and why)."""


class SarInputError(DposError, ValueError):
    """A session's data cannot be navigated with SAR fixes (the message says what is missing or wrong)."""


class SessionError(DposError, ValueError):
    """A recording cannot be processed into a session (the message says why)."""


class LogFormatError(DposError, ValueError):
    """A log cannot be read at all (wrong format, no usable line); the message names the file and what is wrong."""


class ClockNotObservable(DposError, ValueError):
    """A sub-IMU log's clock offset cannot be told from the data (no manoeuvre, a weak or ambiguous
    correlation peak); the message names the log and why."""


class MountingNotObservable(DposError, ValueError):
    """Too little rotation to tell a sub-IMU's mounting (the message says why)."""


class BagError(DposError):
    """A bag that cannot be read (the message names the path)."""


class BagDamaged(DposError, ValueError):
    """An MCAP file whose layout cannot be trusted (no footer, a summary or chunk index pointing
    past the end of the file): read it record by record from its start instead
    (``dpos_ros.io._mcap_recover.scan``)."""


# ----------------------------------------------------------------------------- outputs


class OutputError(DposError):
    """An output location that cannot be used (the message names the path and why)."""


class ProductsExistError(DposError, FileExistsError):
    """A session's product directory exists (from an earlier run) and ``overwrite`` is False."""


# ----------------------------------------------------------------------------- running


class GraphError(DposError, RuntimeError):
    """A node graph could not be started or did not become ready (the message names the nodes)."""


class ImportFailure(DposError):
    """A problem that ends a log import with ``dpos-import: error: <message>`` and status 2."""


class CampaignError(DposError):
    """Unusable campaign input (the message names what): exit status 2 before anything runs."""


class TaskFailed(DposError):
    """A campaign task that failed: ``message`` (dpos-process's error, one line) and the ``attempt``
    it failed at (1 = the first).  Raised in the worker, so that the engine retries the task."""

    def __init__(self, message: str, attempt: int) -> None:
        super().__init__(message, attempt)
        self.message = message
        self.attempt = attempt

    def __str__(self) -> str:
        return self.message
