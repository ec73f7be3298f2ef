"""Two products directories compared file for file, byte for byte but the processing time (the
one thing that differs between runs): dpos-process and transfer_align_node with the rows in
memory and spilled to files."""

from __future__ import annotations

import re
from pathlib import Path


def masked(p: Path) -> bytes:
    """A product file's bytes, its processing time masked (status.json / metrics.json
    ``processing_s``, report.md's processing line)."""
    b = p.read_bytes()
    if p.name in ("status.json", "metrics.json"):
        b = re.sub(rb'"processing_s": [0-9.e+-]+', b'"processing_s": X', b)
    if p.name == "report.md":
        b = re.sub(rb"processing [0-9.]+ s for [0-9]+ s of sub-IMU data \(processing time / data duration = [0-9.]+\)",
                   b"processing X", b)
    return b


def same_products(a: Path, b: Path) -> list[str]:
    """Every file of the products ``a`` and ``b`` the same (:func:`masked`); their names, relative."""
    files = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert files == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    for f in files:
        assert masked(a / f) == masked(b / f), f
    return files
