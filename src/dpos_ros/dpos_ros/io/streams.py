"""Serialized topic streams: what a device publishes, a bag holds and the products write.

A :class:`TopicStream` is one topic's stamps and CDR payloads; :func:`merged_order` is the
publication (and recording) order of several.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dpos_ros.contract import cdr
from dpos_ros.contract import topics as T


@dataclass(frozen=True)
class TopicStream:
    """One topic: ``t_ns`` (N,) stamps and N serialized CDR messages.

    ``rows`` holds fixed-size messages as a (N, size) uint8 array, ``blobs`` variable ones.
    ``qos`` is ``sensor``, ``nav``, ``datum`` (latched) or ``status``.
    """

    topic: str
    msgtype: str
    t_ns: NDArray[np.int64]
    rows: NDArray[np.uint8] | None = None
    blobs: tuple[bytes, ...] | None = None
    qos: str = "sensor"

    def __post_init__(self) -> None:
        if self.blobs is not None:  # reproducible bytes (see cdr.canonical)
            object.__setattr__(self, "blobs", tuple(cdr.canonical(b, self.msgtype) for b in self.blobs))

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def message(self, i: int) -> bytes:
        if self.rows is not None:
            return bytes(self.rows[i])
        assert self.blobs is not None  # one of the two is set
        return self.blobs[i]


def merged_order(streams: list[TopicStream]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Publication order of all messages by stamp: ``(t_ns, stream index, message index)``.

    Equal stamps keep the order of the streams (the datum first, /session/end last)."""
    t = np.concatenate([s.t_ns for s in streams])
    si = np.concatenate([np.full(len(s), i) for i, s in enumerate(streams)])
    mi = np.concatenate([np.arange(len(s)) for s in streams])
    end = np.array([s.topic == T.SESSION_END for s in streams])[si]
    order = np.lexsort((si, end, t))
    return t[order], si[order], mi[order]
