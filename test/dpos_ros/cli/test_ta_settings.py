"""One settings object from transfer_align_node's parameters and from dpos-process's options to the
transfer alignment's core (dpos_core.ta.pipeline.TASettings): the node's
``TransferAlignConfig.core_config()`` and dpos-process's ``settings()`` make the same object for the
same choices, every parameter reaches it, and the filter configuration is derived from it once."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

from dpos_core.ta.model import TAConfig
from dpos_core.ta.pipeline import TASettings
from dpos_ros.cli import process as process_cli
from transfer_align_node.params import TransferAlignConfig

#: node parameters, each away from its default, and the dpos-process options that say the same
NODE = dict(method="urtss", particles=7, seed=3, filter_rate_hz=2.0, position_matching=False, sigma_inflation=False,
            output_rate_hz=50.0, initial_attitude_error_deg=2.5)
CLI = ["--method", "urtss", "--particles", "7", "--seed", "3", "--filter-rate", "2", "--no-position-matching",
       "--no-sigma-inflation", "--output-rate", "50", "--initial-attitude-error", "2.5"]


def test_the_node_and_dpos_process_make_the_same_settings() -> None:
    node = TransferAlignConfig(**NODE).core_config(20.0)
    args = process_cli.parser().parse_args(["bag", "--out", "o", *CLI])
    cli = process_cli.settings(args, SimpleNamespace(custom={}), 20.0)
    assert node == cli
    assert node == TASettings(method="urtss", particles=7, seed=3, filter_rate_hz=2.0, use_position=False, master_error_tau_s=20.0,
                              initial_attitude_error_deg=2.5, inflate_sigma=False, output_rate_hz=50.0)


def test_every_node_parameter_of_the_alignment_reaches_the_settings() -> None:
    """A parameter changed away from its default changes the settings (none is dropped on the way)."""
    base = TransferAlignConfig().core_config(0.0)
    for name, value in NODE.items():
        changed = dataclasses.replace(TransferAlignConfig(), **{name: value}).core_config(0.0)
        assert changed != base, name
    assert TransferAlignConfig().core_config(7.0).master_error_tau_s == 7.0


def test_dpos_process_takes_the_recorded_initial_error_unless_given() -> None:
    sess = SimpleNamespace(custom={"dpos.transfer_alignment": '{"initial_attitude_error_deg": 40.0}'})
    args = process_cli.parser().parse_args(["bag", "--out", "o"])
    assert process_cli.settings(args, sess, 0.0).initial_attitude_error_deg == 40.0
    args = process_cli.parser().parse_args(["bag", "--out", "o", "--initial-attitude-error", "0"])
    assert process_cli.settings(args, sess, 0.0).initial_attitude_error_deg == 0.0


def test_the_filter_configuration_of_the_settings() -> None:
    s = TASettings(filter_rate_hz=2.0, use_position=False, master_error_tau_s=5.0, initial_attitude_error_deg=40.0)
    assert s.ta_config() == TAConfig(filter_rate_hz=2.0, attitude_sigma_deg=40.0, use_position=False, master_error_tau_s=5.0)
    assert s.attitude_error_hpr_deg == (40.0, 40.0, 40.0)
    assert TASettings(initial_attitude_error_deg=0.0).ta_config().attitude_sigma_deg == 1.0  # the prior: at least 1 deg
    with pytest.raises(ValueError, match="filter_rate_hz"):
        TASettings(filter_rate_hz=0.0)
    with pytest.raises(ValueError, match="particles"):
        TASettings(particles=0)
