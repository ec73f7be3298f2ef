"""Paths of the repository for the tests (test/support is on sys.path: pytest.ini ``pythonpath``)."""

from __future__ import annotations

from pathlib import Path

#: the repository root (the folder with the Makefile)
REPO = Path(__file__).resolve().parents[2]
