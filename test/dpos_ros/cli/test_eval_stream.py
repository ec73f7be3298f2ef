"""dpos-eval --stream: a streamed run is simulated window by window into a temporary
recording, processed and evaluated by dpos-process --stream on's path - its metrics are those of
dpos-process --stream off on the same chunked recording (dpos-sim --window gives it: the same
seed, the same bag whatever the window) - and the temporary recording is deleted."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dpos_core.ta import metrics as M
from dpos_ros.cli import evaluate as eval_cli
from dpos_ros.cli import process as process_cli
from dpos_ros.cli import sim as sim_cli

SCEN = ["--scenario", "paper_su", "--aircraft", "paper_su_pair", "--duration", "25"]
SEED = "3"


def _close(x, y, path: str) -> None:
    if isinstance(x, dict):
        assert x.keys() == y.keys(), path
        for k in x:
            _close(x[k], y[k], f"{path}/{k}")
    elif isinstance(x, float):
        assert x == pytest.approx(y, rel=1e-12, nan_ok=True), path
    else:
        assert x == y, path


def test_streamed_run_is_dpos_process_on_the_chunked_recording(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(eval_cli, "STREAM_AUTO_S", 10.0)  # auto: this 25 s run streams
    monkeypatch.setattr(eval_cli, "STREAM_SIM_WINDOW_S", 7.0)
    ev_out = tmp_path / "eval"
    assert eval_cli.main([*SCEN, "--methods", "urtss,ups", "--particles", "10", "--runs", "1", "--seed", SEED,
                          "--out", str(ev_out)]) == 0
    assert sorted(p.name for p in ev_out.iterdir()) == ["metrics.json", "report.md"]  # the temporary recording is gone
    got = json.loads((ev_out / "metrics.json").read_text())
    assert got["evaluation"] == {"paths": ["streaming"], "seeds": [3]}
    assert "Runs of seed 3 took the streaming path" in (ev_out / "report.md").read_text()
    rec = tmp_path / "rec"
    assert sim_cli.main([*SCEN, "--seed", SEED, "--window", "10", "--out", str(rec)]) == 0
    for m in ("urtss", "ups"):
        out = tmp_path / m
        assert process_cli.main([str(rec), "--method", m, "--particles", "10", "--seed", SEED, "--workers", "1",
                                 "--stream", "off", "--out", str(out)]) == 0
        (want_path,) = out.glob("*/metrics.json")
        want = json.loads(want_path.read_text())["methods"][m]
        g = got["methods"][m]
        assert set(g["antennas"]) == {"ant_r", "ant_l"}
        for part in ("mean", "antennas", "consistency"):
            _close(g[part], want[part], f"{m}/{part}")
        assert g["mean"]["rmse"].keys() == set(M.KEYS)


def test_in_memory_below_the_threshold(tmp_path: Path) -> None:
    assert eval_cli.main([*SCEN[:-1], "5", "--methods", "urtss", "--runs", "1", "--out", str(tmp_path)]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["evaluation"] == {"paths": ["in memory"], "seeds": [1]}
    assert "streaming path" not in (tmp_path / "report.md").read_text()


def test_stream_on_refuses_the_oracles(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        eval_cli.main([*SCEN, "--methods", "urtss,oracle", "--stream", "on", "--out", str(tmp_path)])
    assert e.value.code == 2 and "oracle" in capsys.readouterr().err
