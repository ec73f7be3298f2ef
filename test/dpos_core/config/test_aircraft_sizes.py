"""Lever arms and spans of an aircraft file within the aircraft's size (dpos_core.plausibility):
1000 m or millimetres given as metres is a ConfigError in one line naming the file and the entry;
the shipped files and the real data's vehicle files load."""

from __future__ import annotations

import pytest
from repo_paths import REPO

from dpos_core.config import ConfigError, load_aircraft

HEAD = "name: t\nflexure: {tau_s: [5, 2, 2], variance_deg2: [0.15, 0.01, 0.01]}\n"
SUB = "sub_imus:\n  - {name: sub_r, span_m: %s, lever_arm_m: %s}\nantennas:\n  - {name: ant_r, span_m: 5, sub_imu: sub_r, lever_arm_m: %s}\n"


def _load(tmp_path, gnss: str = "[0, 0, 1.5]", span: str = "5", arm: str = "[0.1, -5.0, 0.1]", ant: str = "[0, 0, -0.2]"):
    p = tmp_path / "ac.yaml"
    p.write_text(HEAD + f"gnss_lever_arm_m: {gnss}\n" + SUB % (span, arm, ant))
    return p, load_aircraft(p)


def test_honest_file_loads(tmp_path):
    assert _load(tmp_path)[1].sub_imus[0].lever_arm_m == (0.1, -5.0, 0.1)


def test_the_real_vehicle_file_loads():
    load_aircraft(REPO / "data" / "real" / "walk_0827" / "handheld.yaml")


@pytest.mark.parametrize(("kw", "where", "says"), [
    ({"gnss": "[0, 0, 1000]"}, "gnss_lever_arm_m", "millimetres"),
    ({"gnss": "[0, 0, 150000]"}, "gnss_lever_arm_m", "a typing or unit mistake"),
    ({"arm": "[100, -5000, 100]", "span": "5"}, "sub-IMU 'sub_r' lever_arm_m", "millimetres"),
    ({"ant": "[0, 0, -200]"}, "antenna 'ant_r' lever_arm_m", "millimetres"),
    ({"span": "5000", "arm": "[100, -5000, 100]"}, "sub-IMU 'sub_r' span_m", "millimetres"),
])
def test_lever_arm_beyond_the_aircraft_is_refused_in_one_line(tmp_path, kw, where, says):
    with pytest.raises(ConfigError) as e:
        _load(tmp_path, **kw)
    msg = str(e.value)
    assert msg.startswith(f"{tmp_path / 'ac.yaml'}: {where}: length ") and says in msg and "\n" not in msg, msg
