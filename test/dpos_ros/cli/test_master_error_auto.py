"""The main POS's error model chosen from its source (honest sigmas of the graph's own
main POS): ``--master-error-tau auto`` / transfer_align_node ``master_error_tau_s: -1``.

A GNSS/INS main POS (pos_master_node's mechanization, or the in-flight alignment re-run offline)
has errors correlated in time; the simulator's reference main POS (truth + white noise) has not.
The node-level halves are in test/nodes (test_inprocess_graph: reference -> white;
test_transfer_align_node_unaligned: a /pos_master/status publisher -> correlated)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import serialize_message
from repo_paths import REPO

from dpos_ros.cli import process as process_cli
from dpos_ros.io import bag
from dpos_ros.io.session import MASTER_SOURCE_KEY, read_session
from dpos_ros.io.spill import SpillWriter
from dpos_ros.products.master_reference import AUTO_TAU, GNSS_INS_ERROR_TAU_S, master_error_tau

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"


def test_the_rule() -> None:
    assert master_error_tau(7.5, True) == (7.5, "configured")
    assert master_error_tau(0.0, True) == (0.0, "configured")
    assert master_error_tau(AUTO_TAU, True)[0] == GNSS_INS_ERROR_TAU_S
    assert master_error_tau(AUTO_TAU, False)[0] == 0.0
    for which in ("forward", "smoothed"):  # the in-flight alignment re-run offline is a GNSS/INS whatever was recorded
        assert master_error_tau(AUTO_TAU, False, which)[0] == GNSS_INS_ERROR_TAU_S
    with pytest.raises(ValueError, match="auto"):
        master_error_tau(-0.5, False)


def test_the_source_is_read_from_the_recording(tmp_path: Path) -> None:
    """dpos-sim's recording (reference main POS) is not mechanized; the same recording with a
    /pos_master/status message (what dpos-record keeps of a graph), or as a spill whose metadata
    names the source (what transfer_align_node writes), is."""
    assert read_session(BAG).master_mechanized is False
    raw = bag.read_raw(BAG, None)
    custom = bag.custom_data(BAG)
    t0 = raw["/master/nav"][1][0]
    status = serialize_message(DiagnosticArray())
    spill = tmp_path / "spill"
    w = SpillWriter(spill, "s1", custom)
    for topic, (msgtype, stamps, blobs) in raw.items():
        for t, d in zip(stamps, blobs):
            w.write(topic, msgtype, t, bytes(d))
    w.set_custom(MASTER_SOURCE_KEY, "mechanized")
    w.close()
    assert read_session(spill).master_mechanized is True
    with_status = tmp_path / "with_status"
    from dpos_ros.io.streams import TopicStream

    streams = [TopicStream(topic, msgtype, np.asarray(stamps, dtype=np.int64), blobs=tuple(bytes(d) for d in blobs))
               for topic, (msgtype, stamps, blobs) in raw.items()]
    streams.append(TopicStream("/pos_master/status", "diagnostic_msgs/msg/DiagnosticArray", np.array([t0], dtype=np.int64),
                               blobs=(status,), qos="status"))
    bag.write_streams(with_status, streams, custom_data=custom)
    assert read_session(with_status).master_mechanized is True
    assert read_session(with_status, keep=lambda t: False).master_mechanized is True
    assert read_session(BAG, keep=lambda t: False).master_mechanized is False


@pytest.mark.parametrize("option, tau", [([], 0.0), (["--master-error-tau", "3"], 3.0)])
def test_dpos_process_says_which_model(option: list[str], tau: float, tmp_path: Path, capsys) -> None:
    b = tmp_path / "bag"
    shutil.copytree(BAG, b)
    code = process_cli.main([str(b), "--method", "ukf", "--workers", "1", "--out", str(tmp_path / "o"), *option])
    out = capsys.readouterr().out
    assert code == process_cli.EXIT_OK
    (status,) = (tmp_path / "o").glob("*/status.json")
    model = json.loads(status.read_text())["master_error_model"]
    assert model["tau_s"] == tau, model
    assert ("white noise" if tau == 0 else "configured") in model["why"] and "main POS errors" in out


def test_a_bad_value_is_refused(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        process_cli.main([str(BAG), "--master-error-tau", "-2", "--out", str(tmp_path)])
    assert "--master-error-tau" in capsys.readouterr().err
