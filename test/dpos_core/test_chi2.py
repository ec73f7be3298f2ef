"""dpos_core.chi2 gives scipy.stats.chi2.ppf's quantiles; dpos_core.sim.ar1 gives lfilter's
first-order recursion; and no entry point imports scipy.stats or scipy.signal (about 1 s of CPU in
every node, command and worker process that starts)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import chi2

from dpos_core.chi2 import chi2_ppf, chi2_quantile
from dpos_core.sim.ar1 import ar1

#: the console scripts' modules (src/*/setup.cfg) and the transfer-alignment worker's
ENTRY_POINTS = ("dpos_core.demo", "dpos_ros.cli.sim", "dpos_ros.cli.process", "dpos_ros.cli.evaluate", "dpos_ros.cli.record",
                "dpos_ros.cli.import_", "dpos_ros.cli.sar", "dpos_ros.cli.play", "dpos_ros.cli.graph", "dpos_ros.cli.demo",
                "dpos_ros.cli.campaign", "ifa_node.node", "ifa_node.offline", "pos_master_node.node", "pos_sub_node.node",
                "sar_nav_node.node", "transfer_align_node.node", "dpos_ros.runtime.pool")


@pytest.mark.parametrize("dof", [1, 3, 9, 60, 1234])
def test_quantiles_equal_scipy_stats(dof: int) -> None:
    q = np.array([1e-9, 0.025, 0.5, 0.975, 0.99, 1.0 - 1e-9])
    np.testing.assert_allclose(chi2_ppf(q, dof), chi2.ppf(q, dof), rtol=1e-12)
    assert chi2_quantile(0.99, dof) == pytest.approx(float(chi2.ppf(0.99, dof)), rel=1e-12)


def test_a_long_dof_array_gets_each_distinct_quantile() -> None:
    d = np.array([[3, 6, 3], [9, 6, 3]])
    got = chi2_ppf(0.95, d)
    assert got.shape == d.shape
    np.testing.assert_allclose(got, chi2.ppf(0.95, d), rtol=1e-12)


@pytest.mark.parametrize(("n", "a"), [(1, 0.5), (7, 0.3), (5000, 0.999), (20000, 1.0 - 1e-6)])
def test_ar1_is_lfilters_recursion(n: int, a: float) -> None:
    rng = np.random.default_rng(n)
    w, x0 = rng.normal(size=(n, 3)), rng.normal(size=3)
    ref, _ = lfilter([1.0], [1.0, -a], w, axis=0, zi=(a * x0)[None, :])
    got = ar1(w, a, x0)
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)
    # the recursion itself, from its definition
    np.testing.assert_allclose(got[0], a * x0 + w[0], rtol=1e-15)
    np.testing.assert_allclose(got[1:], a * got[:-1] + w[1:], rtol=1e-13, atol=1e-13)


def test_no_entry_point_imports_scipy_stats_or_signal() -> None:
    code = ("import importlib, sys\n"
            f"for m in {ENTRY_POINTS!r}:\n"
            "    importlib.import_module(m)\n"
            "print(sorted(k for k in ('scipy.stats', 'scipy.signal') if k in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout
