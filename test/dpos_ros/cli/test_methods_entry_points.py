"""Every method the core offers is accepted, and runs, at every entry point that takes a method.

The lists live in the core (:data:`dpos_core.ta.pipeline.METHODS`,
:data:`dpos_core.ifa.pipeline.METHODS`); the nodes' parameters and the CLIs' options take their
choices from there and never restate them.  A method added to the core is therefore tested here
against transfer_align_node, dpos-process, dpos-demo and dpos-eval without editing this file.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import pytest
from repo_paths import REPO

from dpos_core.ifa.pipeline import METHODS as IFA_METHODS
from dpos_core.sar.navigate import SarNavSettings
from dpos_core.sar.pipeline import METHODS as SAR_METHODS
from dpos_core.ta.pipeline import METHODS as TA_METHODS
from dpos_core.ta.pipeline import ORACLE
from dpos_ros.cli import demo, evaluate, process, sar, sar_eval
from dpos_ros.runtime.params import ParameterError, config_from_values
from ifa_node.params import IfaConfig
from sar_nav_node.params import SarNavConfig
from transfer_align_node.params import TransferAlignConfig

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"
EXE = Path(sys.executable).parent


def _choices(config: type, field: str) -> tuple[str, ...]:
    (f,) = [f for f in dataclasses.fields(config) if f.name == field]
    return next(iter(f.metadata.values())).choices


def test_node_parameters_take_the_core_lists() -> None:
    assert _choices(TransferAlignConfig, "method") == TA_METHODS
    assert _choices(IfaConfig, "method") == IFA_METHODS
    assert _choices(SarNavConfig, "method") == SAR_METHODS


@pytest.mark.parametrize("method", SAR_METHODS)
def test_sins_sar_method_is_accepted_everywhere(method: str) -> None:
    """sar_nav_node's method, dpos-sar's --method and dpos-eval's SINS/SAR --methods."""
    cfg = config_from_values(SarNavConfig, {"method": method, "particles": 20})
    assert cfg.method == method and cfg.settings() == SarNavSettings(method=method, n_particles=20)
    assert sar.parser().parse_args(["bag", "--method", method, "--out", "x"]).method == method
    assert sar_eval.sar_methods(method) == [method]


@pytest.mark.parametrize("method", TA_METHODS)
def test_transfer_alignment_method_is_accepted_everywhere(method: str) -> None:
    assert config_from_values(TransferAlignConfig, {"method": method}).method == method
    assert process.parser().parse_args(["bag", "--method", method, "--out", "x"]).method == method
    assert demo.parser().parse_args(["--method", method]).method == method
    assert evaluate.methods_of(f"{method},{ORACLE}", ifa=False) == [method, ORACLE]


@pytest.mark.parametrize("method", IFA_METHODS)
def test_ifa_method_is_accepted_everywhere(method: str) -> None:
    assert config_from_values(IfaConfig, {"method": method}).method == method
    assert evaluate.methods_of(method, ifa=True) == [method]


def test_unknown_methods_are_refused_everywhere(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ParameterError, match="method.*must be one of"):
        config_from_values(TransferAlignConfig, {"method": "nope"})
    with pytest.raises(ParameterError, match="method.*must be one of"):
        config_from_values(IfaConfig, {"method": "add2x"})
    with pytest.raises(ParameterError, match="method.*must be one of"):
        config_from_values(SarNavConfig, {"method": "add2"})  # an IFA method is not a SINS/SAR method
    for p, argv in ((process.parser(), ["bag", "--method", "nope", "--out", "x"]), (demo.parser(), ["--method", "nope"])):
        with pytest.raises(SystemExit) as e:
            p.parse_args(argv)
        assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"unknown transfer-alignment method\(s\) \['nope'\]"):
        evaluate.methods_of("ups,nope", ifa=False)
    with pytest.raises(ValueError, match=r"unknown IFA method\(s\) \['ups'\]"):
        evaluate.methods_of("ups", ifa=True)  # a TA method is not an IFA method


@pytest.mark.parametrize("method", TA_METHODS)
def test_every_method_runs_through_dpos_process(method: str, tmp_path: Path) -> None:
    """Accepted is not enough: each method processes the 45 s sample to products (dpos-process's
    main in this process, one worker: the console script itself is run by test_process.py)."""
    code = process.main([str(SAMPLE), "--method", method, "--particles", "10", "--workers", "1",
                         "--initial-attitude-error", "1", "--out", str(tmp_path)])
    assert code == process.EXIT_OK
    out = tmp_path / "paper_su_seed1"
    assert (out / "ant_r.csv").is_file() and (out / "ant_l.csv").is_file()
    assert f'"{method}"' in (out / "metrics.json").read_text()
