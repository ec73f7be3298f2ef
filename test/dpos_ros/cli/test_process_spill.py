"""dpos-process --stream: the antennas' rows held in memory (``off``) or spilled to files beside
the products (``on``) give the same products, every file byte for byte but the processing time -
with the rows in many blocks, on workers or not, with the wing fit (over several windows)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from repo_paths import REPO
from same_products import same_products  # test/support/same_products.py

from dpos_ros.cli import process as process_cli
from dpos_ros.cli import sim as sim_cli
from dpos_ros.products import rows, solve

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


def _compare(on: Path, off: Path) -> None:
    """Every file of the products the same, byte for byte but the processing time."""
    (sid,) = [p.name for p in on.iterdir()]
    files = same_products(on / sid, off / sid)
    assert {"status.json", "qc.md", "antennas/antennas.mcap"} <= set(files) and any(f.endswith(".csv") for f in files)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_rows_spilled_or_in_memory_give_the_same_products(tmp_path: Path, workers: str) -> None:
    args = [str(SAMPLE), "--method", "ups", "--particles", "20", "--workers", workers]
    assert process_cli.main([*args, "--stream", "on", "--out", str(tmp_path / "on")]) == 0
    assert process_cli.main([*args, "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(tmp_path / "on", tmp_path / "off")
    assert not [p for p in (tmp_path / "on").iterdir() if p.name.startswith(".")]  # the rows' scratch directory is gone


def test_rows_in_small_blocks_with_the_per_epoch_arrays_in_files(tmp_path: Path, monkeypatch) -> None:
    """The rows a block at a time (quality bits, decimation, rates, CSV, bag, evaluation: blocks that
    do not divide the rows nor the decimation's steps; the 45 s session spans many) and the filter's
    per-epoch arrays in files: the same products in memory and spilled."""
    from dpos_core.ta import pipeline

    monkeypatch.setattr(rows, "ROW_BLOCK", 997)
    monkeypatch.setattr(pipeline, "TRACK_IN_MEMORY_BYTES", 0)
    args = [str(SAMPLE), "--method", "ups", "--particles", "20", "--workers", "1", "--output-rate", "30"]
    assert process_cli.main([*args, "--stream", "on", "--out", str(tmp_path / "on")]) == 0
    assert process_cli.main([*args, "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(tmp_path / "on", tmp_path / "off")


@pytest.fixture(scope="module")
def wing(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 10 s paper_wing recording (its fit antennas) and its products with the rows spilled, on
    one worker, the wing fit in 4 s windows (3 windows, more than FIT_IN_FLIGHT 2 on the workers)."""
    d = tmp_path_factory.mktemp("wing")
    rec = d / "wing"
    assert sim_cli.main(["--scenario", "paper_wing", "--duration", "10", "--window", "5", "--out", str(rec)]) == 0
    with pytest.MonkeyPatch.context() as mp:
        _small_fit_windows(mp)
        assert process_cli.main([*_wing_args(rec), "--workers", "1", "--stream", "on", "--out", str(d / "on_1")]) == 0
    return rec, d / "on_1"


def _small_fit_windows(mp: pytest.MonkeyPatch) -> None:
    mp.setattr(solve, "FIT_WINDOW_S", 4.0)
    mp.setattr(solve, "FIT_IN_FLIGHT", 2)


def _wing_args(rec: Path) -> list[str]:
    return [str(rec), "--method", "urtss"]


def test_spilled_rows_with_the_wing_fit(wing: tuple[Path, Path], tmp_path: Path, monkeypatch) -> None:
    rec, on = wing
    _small_fit_windows(monkeypatch)
    assert process_cli.main([*_wing_args(rec), "--workers", "1", "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(on, tmp_path / "off")


def test_wing_fit_windows_on_the_workers(wing: tuple[Path, Path], tmp_path: Path, monkeypatch) -> None:
    """The wing fit's windows fitted on the workers (a few in flight, taken in order) give the
    products of the windows fitted one after the other in this process, byte for byte."""
    rec, on_1 = wing
    _small_fit_windows(monkeypatch)
    assert process_cli.main([*_wing_args(rec), "--workers", "2", "--stream", "on", "--out", str(tmp_path / "2")]) == 0
    (sid,) = [p.name for p in on_1.iterdir()]
    a, b = on_1 / sid, tmp_path / "2" / sid
    csvs = sorted(p.name for p in a.glob("*.csv"))
    assert len(csvs) == 12 and csvs == sorted(p.name for p in b.glob("*.csv"))
    for name in csvs:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    sa, sb = json.loads((a / "status.json").read_text()), json.loads((b / "status.json").read_text())
    assert [f["windows"] for f in sa["wing_fit"].values()] == [3] * len(sa["wing_fit"])
    sa.pop("timing"), sb.pop("timing")
    assert sa == sb
