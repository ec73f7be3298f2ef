"""The alignment state of the main POS's in-flight alignment: one enum for the pipeline
(``InFlightAligner.status``, ``IfaResult.status``), ifa_node's ``/ifa/status`` message and
pos_master_node's reading of it.

The member's name is the ``/ifa/status`` message (design.md "Diagnostics"); its integer value is
what the pipeline stores per epoch (``IfaResult.status``, an int array).
"""

from __future__ import annotations

from enum import IntEnum


class AlignmentState(IntEnum):
    """``WAITING`` (ifa_node only: no initial state yet), ``ALIGNING``, ``ALIGNED``, ``DEGRADED``
    (the innovations of the current window are inconsistent with the filter's covariance: before
    or after the alignment), ``DIVERGED`` (far beyond that for several epochs: the alignment is
    restarted)."""

    WAITING = -1
    ALIGNING = 0
    ALIGNED = 1
    DEGRADED = 2
    DIVERGED = 3

    @classmethod
    def from_message(cls, message: str) -> AlignmentState | None:
        """The state named by an ``/ifa/status`` message, None for any other text."""
        return cls.__members__.get(message)

    @classmethod
    def message_is_aligned(cls, message: str, aligned_key: str | None = None) -> bool:
        """An ``/ifa/status`` says the main POS is aligned: ``ALIGNED``, or ``DEGRADED`` after the
        alignment (its ``aligned`` key/value is ``true``; a DEGRADED without the key counts as
        aligned, as ifa_node published before it had the key)."""
        state = cls.from_message(message)
        if state == AlignmentState.ALIGNED:
            return True
        if state == AlignmentState.DEGRADED:
            return aligned_key is None or aligned_key.lower() == "true"
        return False
