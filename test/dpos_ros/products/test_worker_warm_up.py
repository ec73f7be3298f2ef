"""The warm-up of the transfer-alignment workers (dpos_core.ta.warmup, run by dpos-process's and
transfer_align_node's WarmPool): after it, a worker's real task compiles no numba kernel of the
alignment that the warm-up did not - ``solve`` of a session in memory and a worker's
``align_to_store`` reading the sample bag, its rows spilled to files, UPS (the default).  Checked in a fresh interpreter (test/support/numba_probe.py);
reading the recording is set aside (dpos_ros's reader kernels, which the core's warm-up cannot
reach: a few small kernels compiled in the worker's first read on a fresh install)."""

from __future__ import annotations

import pytest
from numba_probe import new_after_warm_up  # test/support/numba_probe.py
from repo_paths import REPO

_PROBE = r"""
import tempfile
from pathlib import Path
import numpy as np
from dpos_core.config import load_aircraft
from dpos_core.ta.model import Installation
from dpos_core.ta.pipeline import TASettings
from dpos_core.ta.warmup import warm_up
from dpos_ros.io.session import read_session
from dpos_ros.products.rows import RowStore
from dpos_ros.products.solve import SubImuSource, SubImuTask, align_to_store, solve

warm_up("ups")
mark("warm_up")
bag = Path(sys.argv[2])
sess = read_session(bag)
read_session(bag, keep=lambda t: t.startswith("/sub_imu/"))
aircraft = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
mark("data")
if sys.argv[1] == "solve":
    solve(sess, aircraft, TASettings(method="ups"))
else:
    s = aircraft.sub_imus[0]
    align_to_store(SubImuTask(SubImuSource(bag=str(bag)), s.name, None, Installation.from_aircraft(aircraft, s.name), TASettings(method="ups"),
                              tuple((a.name, np.asarray(a.lever_arm_m, dtype=float)) for a in aircraft.antennas if a.sub_imu == s.name),
                              RowStore(Path(tempfile.mkdtemp()))))
mark("use")
"""


@pytest.mark.parametrize("task", ["solve", "stream"])
def test_a_worker_task_compiles_nothing_the_warm_up_did_not(task: str) -> None:
    new, warmed = new_after_warm_up(_PROBE, task, str(REPO / "bags" / "paper_su_pair_seed1_45s"))
    assert warmed, "the warm-up compiled or loaded no numba kernel"
    assert not new, f"compiled in the worker's task, not by the warm-up: {new}"
