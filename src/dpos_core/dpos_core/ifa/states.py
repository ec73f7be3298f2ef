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
    (aligned, but the current innovation window is inconsistent)."""

    WAITING = -1
    ALIGNING = 0
    ALIGNED = 1
    DEGRADED = 2

    @property
    def aligned(self) -> bool:
        """The alignment has been declared (ALIGNED or DEGRADED): the navigation may be used."""
        return self in (AlignmentState.ALIGNED, AlignmentState.DEGRADED)

    @classmethod
    def from_message(cls, message: str) -> AlignmentState | None:
        """The state named by an ``/ifa/status`` message, None for any other text."""
        return cls.__members__.get(message)

    @classmethod
    def message_is_aligned(cls, message: str) -> bool:
        """An ``/ifa/status`` message says the main POS is aligned (``ALIGNED`` or ``DEGRADED``)."""
        state = cls.from_message(message)
        return state is not None and state.aligned
