"""The five nodes: start, log their plan, stop cleanly; reject bad parameters.

ifa_node logs what it subscribes and publishes (its behaviour: test_ifa_node.py); transfer_align_node logs what it
buffers; the device nodes run their simulated device ("-> publishing ...", see test_sim_device.py for what they publish).
"""

from __future__ import annotations

import signal

import pytest
from node_process import START_TIMEOUT_S, STOP_TIMEOUT_S  # test/support/node_process.py
from rclpy.parameter import Parameter

from dpos_ros.runtime.params import ParameterError, packaged_params_file

pytestmark = pytest.mark.ros


# console script -> extra arguments it needs to start
NODES = {
    "pos_master_node": [],
    "pos_sub_node": ["-p", "name:=sub_r"],
    "ifa_node": ["-p", "scenario:=paper_su"],
    "transfer_align_node": [],
    "sar_nav_node": [],
}

# console script -> (bad parameter, bad value as shown in the error)
# console script -> a text of the line that logs the node's plan
PLAN = {
    "pos_master_node": "-> publishing ",
    "pos_sub_node": "-> publishing ",
    "ifa_node": "-> publishing /ifa/correction",
    "transfer_align_node": "buffering /master/nav",
    "sar_nav_node": "-> publishing /sar_nav/nav",
}

BAD_PARAMETERS = {
    "pos_master_node": ("rate_factor:=-1.0", "rate_factor", "-1.0"),
    "pos_sub_node": ("name:=''", "name", "''"),
    "ifa_node": ("method:=bogus", "method", "bogus"),
    "transfer_align_node": ("particles:=0", "particles", "0"),
    "sar_nav_node": ("method:=bogus", "method", "bogus"),
}


def _assert_clean_exit(node, rc: int) -> None:
    assert rc == 0, f"exit status {rc}; output:\n{node.output}"
    assert "Traceback" not in node.output, node.output


@pytest.mark.parametrize("script", sorted(NODES))
def test_node_starts_logs_plan_and_stops_on_sigint(script, start_node):
    node = start_node(script, "--ros-args", *NODES[script])
    line = node.wait_for_line(PLAN[script], START_TIMEOUT_S)
    assert f"{script}:" in line and "[INFO]" in line
    node.send_signal(signal.SIGINT)
    _assert_clean_exit(node, node.wait(STOP_TIMEOUT_S))


@pytest.mark.parametrize("script", sorted(NODES))
def test_node_starts_with_packaged_params_file_and_stops_on_sigterm(script, start_node):
    params = packaged_params_file(script)
    node = start_node(script, "--ros-args", "--params-file", str(params), *NODES[script])
    node.wait_for_line(PLAN[script], START_TIMEOUT_S)
    node.send_signal(signal.SIGTERM)
    _assert_clean_exit(node, node.wait(STOP_TIMEOUT_S))


def test_master_log_line_shows_overrides(start_node):
    node = start_node(
        "pos_master_node", "--ros-args", "-p", "scenario:=paper_wing", "-p", "seed:=7",
        "-p", "rate_factor:=0", "-p", "alignment:=reference",
    )
    line = node.wait_for_line("-> publishing", START_TIMEOUT_S)
    for expected in ("device=sim", "scenario=paper_wing", "seed=7", "rate_factor=0.0", "alignment=reference",
                     "/master/imu", "/master/nav", "/dpos/datum"):
        assert expected in line, line
    node.send_signal(signal.SIGINT)
    _assert_clean_exit(node, node.wait(STOP_TIMEOUT_S))


@pytest.mark.parametrize("script", sorted(BAD_PARAMETERS))
def test_bad_parameter_exits_nonzero_naming_it(script, start_node):
    override, name, shown = BAD_PARAMETERS[script]
    extra = [] if script == "pos_sub_node" else NODES[script]
    node = start_node(script, "--ros-args", *extra, "-p", override)
    rc = node.wait(START_TIMEOUT_S)
    assert rc != 0, node.output
    error = node.wait_for_line("[ERROR]", 1.0)
    assert f"'{name}'" in error and shown in error, error
    assert PLAN[script] not in node.output
    assert "Traceback" not in node.output, node.output


def _node_classes():
    from ifa_node.node import IfaNode
    from ifa_node.params import IfaConfig
    from pos_master_node.node import PosMasterNode
    from pos_master_node.params import PosMasterConfig
    from pos_sub_node.node import PosSubNode
    from pos_sub_node.params import PosSubConfig
    from sar_nav_node.node import SarNavNode
    from sar_nav_node.params import SarNavConfig
    from transfer_align_node.node import TransferAlignNode
    from transfer_align_node.params import TransferAlignConfig

    return {
        "pos_master_node": (PosMasterNode, PosMasterConfig()),
        "pos_sub_node": (PosSubNode, PosSubConfig(name="sub_r")),
        "ifa_node": (IfaNode, IfaConfig(scenario="paper_su")),
        "transfer_align_node": (TransferAlignNode, TransferAlignConfig()),
        "sar_nav_node": (SarNavNode, SarNavConfig()),
    }


@pytest.mark.parametrize("script", sorted(NODES))
def test_node_in_process_has_default_config(script, ros_context, ros_executor):
    cls, expected = _node_classes()[script]
    overrides = {"pos_sub_node": [Parameter("name", value="sub_r")],
                 "ifa_node": [Parameter("scenario", value="paper_su")]}.get(script, [])
    node = cls(context=ros_context, parameter_overrides=overrides)
    try:
        assert node.get_name() == script
        assert node.config == expected
        assert node.config.datum == ()  # [] = the session's own datum
        ros_executor.add_node(node)
        ros_executor.spin_once(timeout_sec=0.1)
    finally:
        ros_executor.remove_node(node)
        node.destroy_node()


def test_node_in_process_rejects_bad_override(ros_context):
    from pos_master_node.node import PosMasterNode

    with pytest.raises(ParameterError, match="'alignment' = 'bogus'"):
        PosMasterNode(context=ros_context, parameter_overrides=[Parameter("alignment", value="bogus")])


def test_parameters_are_read_only(ros_context):
    from ifa_node.node import IfaNode

    node = IfaNode(context=ros_context, parameter_overrides=[Parameter("scenario", value="paper_su")])
    try:
        result = node.set_parameters([Parameter("window", value=20)])[0]
        assert not result.successful
        assert node.config.window == 10
    finally:
        node.destroy_node()


def test_ifa_node_needs_the_lever_arm_of_the_installation(ros_context):
    """Without an aircraft file nor a simulated scenario ifa_node does not guess a lever arm."""
    from ifa_node.node import IfaNode

    with pytest.raises(ParameterError, match="'aircraft_config' = '': required: the aircraft file of your installation"):
        IfaNode(context=ros_context)
