"""Disk faults injected into the bag writer (dpos_ros.io._mcap.write and its Writer), for the tests of what the
commands do when the products or a recording cannot be written."""

from __future__ import annotations

import os

import pytest

from dpos_ros.io import _mcap


def fail_bag_writes_after(monkeypatch: pytest.MonkeyPatch, n: int, code: int) -> None:
    """The bag writer raises ``OSError(code)`` once more than ``n`` messages are written (as a full
    or read-only disk would; the chunks written so far stay in the file)."""
    original = _mcap.write

    def write(path, topics, order, custom_data, version, library, progress=None, qos=None):
        def fail(k: int, total: int) -> None:  # called after each chunk written
            if k > n:
                raise OSError(code, os.strerror(code), str(path / f"{path.name}.mcap"))
            if progress is not None:
                progress(k, total)

        return original(path, topics, order, custom_data, version, library, fail, qos)

    class Writer(_mcap.Writer):  # the batch-by-batch writer (dpos_ros.io.bag.write_stream_batches)
        def __init__(self, path, channels, custom_data, version, library, progress=None, qos=None):
            def fail(k: int) -> None:
                if k > n:
                    raise OSError(code, os.strerror(code), str(path / f"{path.name}.mcap"))
                if progress is not None:
                    progress(k)

            super().__init__(path, channels, custom_data, version, library, fail, qos)

    monkeypatch.setattr(_mcap, "write", write)
    monkeypatch.setattr(_mcap, "Writer", Writer)
