"""The main POS as an RTKLIB .pos file (dpos_core.ifa.pos_file): written, read back by dpos-import's reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_core.ifa.pos_file import Q_AIDED, Q_BRIDGED, GnssSupport, gnss_support, write_pos
from dpos_core.imports.logs import read_pos
from dpos_core.units import DEG


def _solution(rng: np.random.Generator, n: int = 400):
    t_ns = 1_756_402_240_999_000_064 + np.cumsum(rng.integers(1_000, 20_000_000, n)).astype(np.int64)  # 1 us to 20 ms apart
    llh = np.column_stack([40.0967 * DEG + 1e-6 * rng.standard_normal(n), -105.1472 * DEG + 1e-6 * rng.standard_normal(n),
                           1601.4 + rng.standard_normal(n)])
    A = rng.standard_normal((n, 3, 3)) * 0.05
    P = A @ A.transpose(0, 2, 1) + 1e-4 * np.eye(3)
    B = rng.standard_normal((n, 3, 3)) * 0.02
    V = B @ B.transpose(0, 2, 1) + 1e-5 * np.eye(3)
    v = rng.standard_normal((n, 3))
    return t_ns, llh, P, v, V


def test_written_pos_reads_back_with_the_import_reader(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t_ns, llh, P, v, V = _solution(rng)
    q = np.where(rng.random(t_ns.size) < 0.5, Q_AIDED, Q_BRIDGED)
    ns = rng.integers(0, 3, t_ns.size)
    write_pos(tmp_path / "s.pos", t_ns, llh, P, v, V, GnssSupport(q, ns, rng.random(t_ns.size)), comments=["a test"])
    text = (tmp_path / "s.pos").read_text()
    assert text.startswith("% a test\n")
    back = read_pos(tmp_path / "s.pos")
    assert not back.skipped and len(back) == t_ns.size
    assert np.all(np.abs(back.t_ns - t_ns) <= 500)  # microseconds
    np.testing.assert_allclose(back.llh[:, :2], llh[:, :2], atol=0.6e-9 * DEG, rtol=0)  # 9 decimals of a degree
    np.testing.assert_allclose(back.llh[:, 2], llh[:, 2], atol=0.6e-4, rtol=0)
    np.testing.assert_array_equal(back.quality, q)
    np.testing.assert_array_equal(back.n_sat, ns)
    # covariances through RTKLIB's signed square roots, 4 / 5 decimals
    np.testing.assert_allclose(back.pos_cov_enu_m2, P, atol=2e-5, rtol=2e-3)
    np.testing.assert_allclose(back.vel_n_mps, v, atol=0.6e-5, rtol=0)
    np.testing.assert_allclose(back.vel_cov_enu, V, atol=2e-6, rtol=2e-3)
    # the order of the columns: North before East in the file, East first in ENU
    first = text.splitlines()[3].split()
    assert float(first[2]) == pytest.approx(llh[0, 0] / DEG, abs=1e-9) and float(first[7]) == pytest.approx(np.sqrt(P[0, 1, 1]), abs=1e-4)
    assert float(first[15]) == pytest.approx(v[0, 1], abs=1e-5)  # vn


def test_stamps_must_be_increasing(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    t_ns, llh, P, v, V = _solution(rng, 3)
    t_ns[2] = t_ns[1] + 999
    with pytest.raises(ValueError, match="1 us"):
        write_pos(tmp_path / "s.pos", t_ns, llh, P, v, V, GnssSupport(np.ones(3, int), np.ones(3, int), np.zeros(3)))


def test_quality_flags_an_outage_bridged_from_both_ends() -> None:
    upd = np.array([0.0, 1.0, 2.0, 20.0, 21.0])
    t = np.array([0.5, 1.5, 2.5, 4.0, 11.0, 19.0, 20.5, 22.0, 23.0])
    q, ns, age = gnss_support(t, upd, 1.5, smoothed=True)
    np.testing.assert_array_equal(q, [1, 1, 5, 5, 5, 5, 1, 5, 5])
    np.testing.assert_array_equal(ns, [2, 2, 1, 0, 0, 1, 2, 1, 0])
    np.testing.assert_allclose(age, [0.5, 0.5, 0.5, 2.0, 9.0, 1.0, 0.5, 1.0, 2.0])
    qf, nsf, agef = gnss_support(t, upd, 1.5, smoothed=False)
    np.testing.assert_array_equal(qf, [1, 1, 1, 5, 5, 5, 1, 1, 5])
    np.testing.assert_allclose(agef, [0.5, 0.5, 0.5, 2.0, 9.0, 17.0, 0.5, 1.0, 2.0])
