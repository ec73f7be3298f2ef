"""dpos-process --stream (dpos_ros.products.stream): the products of the streaming path
are those of the in-memory path - the CSV files and the figures byte for byte, the antenna bag
message for message, qc.md and status.json but for the documented differences (the wing fit's window count),
metrics.json and report.md of the evaluation against the truth to 1e-12 relative (but the timing) -
on a session shorter than one wing-fit window."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from repo_paths import REPO

from dpos_ros.cli import process as process_cli
from dpos_ros.cli import sim as sim_cli
from dpos_ros.io import bag
from dpos_ros.products import rows, stream

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


def _compare(on: Path, off: Path) -> None:
    (sid,) = [p.name for p in on.iterdir()]
    a, b = on / sid, off / sid
    csvs = sorted(p.name for p in a.glob("*.csv"))
    assert csvs and csvs == sorted(p.name for p in b.glob("*.csv"))
    for name in csvs:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert (a / "qc.md").read_text() == (b / "qc.md").read_text()
    sa, sb = json.loads((a / "status.json").read_text()), json.loads((b / "status.json").read_text())
    for fit in sa.get("wing_fit", {}).values():
        assert fit.pop("windows") == 1 and fit.pop("window_s") == stream.FIT_WINDOW_S
    sa["warnings"] = [w for w in sa["warnings"] if not w.startswith("--stream")]
    for k in ("timing",):
        sa.pop(k), sb.pop(k)
    assert sa == sb
    ra, rb = bag.read_raw(a / "antennas"), bag.read_raw(b / "antennas")
    assert ra.keys() == rb.keys()
    for t in ra:
        assert ra[t][1] == rb[t][1] and [bytes(x) for x in ra[t][2]] == [bytes(x) for x in rb[t][2]], t
    figs = sorted(p.name for p in (a / "qc").iterdir())
    assert figs == sorted(p.name for p in (b / "qc").iterdir())
    for name in figs:  # the QC figures byte for byte (matplotlib's Agg PNGs embed nothing variable)
        assert (a / "qc" / name).read_bytes() == (b / "qc" / name).read_bytes(), name
    # the evaluation against the truth (products.evaluate_stream): the same metrics, the same report
    # but for the timing line, the same error figures (drawn from every n-th row: n = 1 here) byte for byte
    errs = sorted(p.name for p in a.glob("errors_*.png"))
    assert errs == sorted(p.name for p in b.glob("errors_*.png"))
    for name in errs:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    ma, mb = json.loads((a / "metrics.json").read_text()), json.loads((b / "metrics.json").read_text())
    assert ma.pop("evaluation") == {"path": "streaming", "plot_step": dict.fromkeys(ma["methods"][next(iter(ma["methods"]))]["antennas"], 1)}
    _close(ma, mb, "metrics.json")
    assert _untimed(a / "report.md") == _untimed(b / "report.md")


def _untimed(path: Path) -> list[str]:
    return [x for x in path.read_text().splitlines() if "processing time / data duration" not in x]


def _close(x, y, path: str) -> None:
    """``x`` equals ``y`` but for the timings and the floats' rounding (1e-12 relative)."""
    if isinstance(x, dict):
        assert x.keys() == y.keys(), path
        for k in x:
            if k != "timing":
                _close(x[k], y[k], f"{path}/{k}")
    elif isinstance(x, float) and isinstance(y, float):
        assert x == pytest.approx(y, rel=1e-12, nan_ok=True), path
    else:
        assert x == y, path


@pytest.mark.parametrize("workers", ["1", "2"])
def test_stream_gives_the_in_memory_products(tmp_path: Path, workers: str) -> None:
    args = [str(SAMPLE), "--method", "ups", "--particles", "20", "--workers", workers]
    assert process_cli.main([*args, "--stream", "on", "--out", str(tmp_path / "on")]) == 0
    assert process_cli.main([*args, "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(tmp_path / "on", tmp_path / "off")
    assert not [p for p in (tmp_path / "on").iterdir() if p.name.startswith(".")]  # the rows' scratch directory is gone


def test_stream_in_row_blocks_with_the_per_epoch_arrays_in_files(tmp_path: Path, monkeypatch) -> None:
    """The worker's rows a block at a time (quality bits, decimation, rates: blocks that do not divide
    the rows nor the decimation's steps) and the filter's per-epoch arrays in files: the same products."""
    from dpos_core.ta import pipeline

    monkeypatch.setattr(rows, "ROW_BLOCK", 997)
    monkeypatch.setattr(pipeline, "TRACK_IN_MEMORY_BYTES", 0)
    args = [str(SAMPLE), "--method", "ups", "--particles", "20", "--workers", "1", "--output-rate", "30"]
    assert process_cli.main([*args, "--stream", "on", "--out", str(tmp_path / "on")]) == 0
    assert process_cli.main([*args, "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(tmp_path / "on", tmp_path / "off")


def test_stream_with_the_wing_fit(tmp_path: Path) -> None:
    rec = tmp_path / "wing"
    assert sim_cli.main(["--scenario", "paper_wing", "--duration", "20", "--window", "10", "--out", str(rec)]) == 0
    args = [str(rec), "--method", "urtss", "--workers", "1"]
    assert process_cli.main([*args, "--stream", "on", "--out", str(tmp_path / "on")]) == 0
    assert process_cli.main([*args, "--stream", "off", "--out", str(tmp_path / "off")]) == 0
    _compare(tmp_path / "on", tmp_path / "off")


def test_stream_refuses_a_re_run_main_pos(tmp_path: Path, capsys) -> None:
    assert process_cli.main([str(SAMPLE), "--stream", "on", "--master-reference", "forward", "--out", str(tmp_path)]) == 2
    assert "--master-reference recorded" in capsys.readouterr().err


def test_stream_wing_fit_windows_on_the_workers(tmp_path: Path, monkeypatch) -> None:
    """The wing fit's windows fitted on the workers (a few in flight, taken in order) give the
    products of the windows fitted one after the other in this process, byte for byte."""
    rec = tmp_path / "wing"
    assert sim_cli.main(["--scenario", "paper_wing", "--duration", "20", "--window", "10", "--out", str(rec)]) == 0
    monkeypatch.setattr(stream, "FIT_WINDOW_S", 4.0)  # 5 windows, more than FIT_IN_FLIGHT
    monkeypatch.setattr(stream, "FIT_IN_FLIGHT", 2)
    for workers in ("1", "2"):
        assert process_cli.main([str(rec), "--method", "urtss", "--workers", workers, "--stream", "on", "--out", str(tmp_path / workers)]) == 0
    (sid,) = [p.name for p in (tmp_path / "1").iterdir()]
    a, b = tmp_path / "1" / sid, tmp_path / "2" / sid
    csvs = sorted(p.name for p in a.glob("*.csv"))
    assert len(csvs) == 12 and csvs == sorted(p.name for p in b.glob("*.csv"))
    for name in csvs:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    sa, sb = json.loads((a / "status.json").read_text()), json.loads((b / "status.json").read_text())
    assert [f["windows"] for f in sa["wing_fit"].values()] == [5] * len(sa["wing_fit"])
    sa.pop("timing"), sb.pop("timing")
    assert sa == sb
