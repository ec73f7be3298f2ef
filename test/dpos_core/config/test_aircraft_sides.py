"""The aircraft file's signed spans agree with the side their lever arm puts them on:
span_m is + on the right wing (FLU y < 0), - on the left (y > 0); a contradiction is a ConfigError
naming the file, the entry and the field."""

from __future__ import annotations

import re

import pytest

from dpos_core.config import ConfigError, builtin_names, load_aircraft

HEAD = "name: t\ngnss_lever_arm_m: [0, 0, 1.5]\nflexure: {tau_s: [5, 2, 2], variance_deg2: [0.15, 0.01, 0.01]}\n"


def _write(tmp_path, body: str):
    p = tmp_path / "ac.yaml"
    p.write_text(HEAD + body)
    return p


@pytest.mark.parametrize("name", builtin_names("aircraft"))
def test_builtin_aircraft_are_consistent(name):
    load_aircraft(name)


def test_right_wing_sub_imu_with_negative_span_is_refused(tmp_path):
    p = _write(tmp_path, "sub_imus:\n  - {name: sub_r, span_m: -5, lever_arm_m: [0.1, -5.0, 0.1]}\nantennas: []\n")
    with pytest.raises(ConfigError) as e:
        load_aircraft(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: sub_imus[0].span_m:"), msg
    assert "'sub_r'" in msg and "left wing" in msg and "right wing" in msg and "\n" not in msg


def test_left_wing_sub_imu_with_positive_span_is_refused(tmp_path):
    p = _write(tmp_path, "sub_imus:\n  - {name: sub_l, span_m: 5, lever_arm_m: [0.1, 5.0, 0.1]}\nantennas: []\n")
    with pytest.raises(ConfigError, match=re.escape(f"{p}: sub_imus[0].span_m: sub-IMU 'sub_l'")):
        load_aircraft(p)


def test_antenna_span_must_be_on_its_sub_imus_side(tmp_path):
    p = _write(tmp_path, "sub_imus:\n  - {name: sub_r, span_m: 5, lever_arm_m: [0.1, -5.0, 0.1]}\n"
                         "antennas:\n  - {name: ant_ok, span_m: 5, sub_imu: sub_r}\n  - {name: ant_r, span_m: -5, sub_imu: sub_r}\n")
    with pytest.raises(ConfigError, match=re.escape(f"{p}: antennas[1].span_m: antenna 'ant_r'") + ".*sub-IMU 'sub_r'"):
        load_aircraft(p)


def test_fit_antenna_span_must_match_its_lever_arm(tmp_path):
    p = _write(tmp_path, "sub_imus: []\nantennas:\n  - {name: ant02, span_m: 2, sub_imu: fit, lever_arm_m: [0, 2.0, -0.4]}\n")
    with pytest.raises(ConfigError, match=re.escape(f"{p}: antennas[0].span_m: antenna 'ant02'")):
        load_aircraft(p)


def test_consistent_and_fuselage_entries_load(tmp_path):
    p = _write(tmp_path, "sub_imus:\n  - {name: sub_r, span_m: 5, lever_arm_m: [0.1, -5.0, 0.1]}\n"
                         "  - {name: sub_l, span_m: -5, lever_arm_m: [0.1, 5.0, 0.1]}\n"
                         "  - {name: sub_c, span_m: 0, lever_arm_m: [2.0, 0.0, 0.1]}\n"
                         "antennas:\n  - {name: ant_r, span_m: 5, sub_imu: sub_r}\n  - {name: ant_l, span_m: -5, sub_imu: sub_l}\n"
                         "  - {name: ant_c, span_m: 0, sub_imu: fit, lever_arm_m: [1, 0, 0]}\n")
    ac = load_aircraft(p)
    assert [s.span_m for s in ac.sub_imus] == [5.0, -5.0, 0.0]
    assert [a.span_m for a in ac.antennas] == [5.0, -5.0, 0.0]
