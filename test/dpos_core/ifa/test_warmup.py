"""The warm-ups of the live main-POS nodes (dpos_core.ifa.warmup): after the warm-up, real use
compiles no numba kernel that the warm-up did not (ifa_node: the chosen filter on a simulated
flight with a GNSS outage; pos_master_node: the mechanization with corrections and a bias).
Each check runs in a fresh interpreter, where no kernel has been compiled or loaded yet; its data
are simulated here and handed over in a file (the simulator's own kernels would hide the node's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba_probe import new_after_warm_up  # test/support/numba_probe.py

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession

#: the warm-up, then the real use, in a fresh interpreter (numba_probe's ``mark``)
_PROBE = r"""
import numpy as np

WHAT = sys.argv[1]
from dpos_core.ifa import warmup
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.strapdown import NavState
if WHAT == "mechanization":
    warmup.warm_up_mechanization()
else:
    warmup.warm_up(IfaFilterConfig(), WHAT)
mark("warm_up")

from dpos_core.series import GnssSeries, ImuSeries
z = np.load(sys.argv[2])
imu = ImuSeries(z["t_s"], z["omega_radps"], z["f_mps2"])
class tr:
    q_nb, vel_n_mps, llh = z["q_nb"][None], z["vel_n_mps"][None], z["llh"][None]
initial = NavState(0.0, tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0])
if WHAT == "mechanization":
    from dpos_core.ifa.mechanization import MasterMechanization
    m = MasterMechanization(initial, ring_s=5.0)
    for i0 in range(0, imu.t_s.size, 37):  # batches of a live relay, a correction and a bias after some
        sl = slice(i0, i0 + 37)
        m.add(imu.t_s[sl], imu.omega_radps[sl], imu.f_mps2[sl])
        if i0 and i0 % 370 == 0:
            m.correct(NavState(float(imu.t_s[i0 - 5]), tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0]))
            m.set_bias(float(imu.t_s[i0 - 3]), np.full(3, 1e-6), np.full(3, 1e-4))
    m.nav()
else:
    from dpos_core.ifa.pipeline import run
    gnss = GnssSeries(*(z[f"gnss_{k}"] for k in ("t_s", "llh", "pos_sigma_m", "vel_n_mps", "vel_sigma_mps")))
    run(imu, gnss, z["lever_arm_m"], IfaFilterConfig(), WHAT, initial)
mark("use")
"""


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 s of paper_ifa's main IMU, its GNSS with an outage from 15 to 30 s, the true start."""
    ss = SimulatedSession(load_scenario("paper_ifa"), 1)
    imu = ss.master_imu()
    imu = imu.select(imu.t_s <= 40.0)
    gnss = ss.gnss()
    keep = (gnss.t_s <= 15.0) | ((gnss.t_s >= 30.0) & (gnss.t_s <= imu.t_s[-1]))
    tr = ss.truth("master", np.array([0.0]))
    path = tmp_path_factory.mktemp("warmup") / "flight.npz"
    np.savez(path, t_s=imu.t_s, omega_radps=imu.omega_radps, f_mps2=imu.f_mps2, q_nb=tr.q_nb[0], vel_n_mps=tr.vel_n_mps[0],
             llh=tr.llh[0], lever_arm_m=np.asarray(ss.scenario.aircraft.gnss_lever_arm_m, dtype=float),
             **{f"gnss_{k}": getattr(gnss, k)[keep] for k in ("t_s", "llh", "pos_sigma_m", "vel_n_mps", "vel_sigma_mps")})
    return path


@pytest.mark.parametrize("what", ["mechanization", "add2", "dd2", "aekf"])
def test_real_use_compiles_nothing_the_warm_up_did_not(what: str, flight: Path) -> None:
    new, warmed = new_after_warm_up(_PROBE, what, str(flight))
    assert warmed, "the warm-up compiled or loaded no numba kernel"
    assert not new, f"compiled in real use, not by the warm-up: {new}"
