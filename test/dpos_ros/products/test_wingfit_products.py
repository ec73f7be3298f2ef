"""dpos-process on a simulated paper_wing session: the `fit` antennas ([LSFit] sec. 2, the
least-squares wing fit) are estimated and as accurate as their IMU-carrying neighbours."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

FIT = ["ant02", "ant04", "ant06", "ant08", "ant10", "ant12"]
DURATION_S = 20.0


@pytest.fixture(scope="module")
def products(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("wing")
    bin_dir = Path(sys.executable).parent
    r = subprocess.run([str(bin_dir / "dpos-sim"), "--scenario", "paper_wing", "--seed", "2", "--duration", str(DURATION_S),
                        "--out", str(tmp / "w")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([str(bin_dir / "dpos-process"), str(tmp / "w"), "--method", "urtss", "--out", str(tmp / "p")],
                       capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stdout + r.stderr
    (out,) = (tmp / "p").iterdir()
    return out


def test_every_fit_antenna_is_estimated_with_its_products(products: Path) -> None:
    status = json.loads((products / "status.json").read_text())
    for name in FIT:
        assert status["antennas"][name].startswith("estimated (least-squares wing fit, polynomial in span"), status["antennas"][name]
        rows = list(csv.DictReader(ln for ln in (products / f"{name}.csv").open() if not ln.startswith('#')))
        ref = list(csv.DictReader(ln for ln in (products / "ant01.csv").open() if not ln.startswith('#')))
        assert len(rows) == len(ref)
        assert all(float(r["sigma_h_m"]) > 0 for r in rows)
    meta = (products / "antennas" / "metadata.yaml").read_text()
    assert all(f"/antenna/{n}/odom" in meta for n in FIT)
    fit = status["wing_fit"]["right"]
    assert fit["sub_imus"] == ["imu01", "imu03", "imu05", "imu07", "imu09", "imu11"]
    for comp, k in fit["degree"].items():  # the chosen degree is the CV minimum among the reported candidates
        cv = fit["cv"][comp]
        assert set(cv) >= {"0", "2", "3"}  # every candidate with a redundant sub-IMU (p <= 6 - 2; the common term counts)
        assert min(cv, key=lambda c: cv[c]["score"]) == str(k)
    # the antenna outside the outermost sub-IMU has the largest attitude sigma
    sig = {n: np.median([float(r["sigma_rot_e_deg"]) for r in csv.DictReader(ln for ln in (products / f"{n}.csv").open() if not ln.startswith('#'))]) for n in FIT}
    assert sig["ant12"] == max(sig.values()), sig


def test_fit_antennas_are_as_accurate_as_their_neighbours(products: Path) -> None:
    ants = json.loads((products / "metrics.json").read_text())["methods"]["urtss"]["antennas"]
    assert set(FIT) <= set(ants)

    def pos(a: str) -> float:
        r = ants[a]["rmse"]
        return float(np.sqrt(r["lat_m"] ** 2 + r["lon_m"] ** 2 + r["h_m"] ** 2))

    for name in FIT:
        k = int(name[3:])
        nb = [f"ant{j:02d}" for j in (k - 1, k + 1) if f"ant{j:02d}" in ants]
        heading = np.mean([ants[n]["rmse"]["heading_deg"] for n in nb])
        assert ants[name]["rmse"]["heading_deg"] <= 1.5 * heading, (name, ants[name]["rmse"], nb)
        assert pos(name) <= 1.5 * np.mean([pos(n) for n in nb]), (name, pos(name), [pos(n) for n in nb])
