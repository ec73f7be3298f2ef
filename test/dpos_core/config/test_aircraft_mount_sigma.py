"""A sub-IMU's ``mount_sigma_deg``: the 1 sigma of its given mounting (the transfer alignment's
misalignment prior); optional, absent or null = not stated, else a finite number > 0 [deg]."""

from __future__ import annotations

import re

import pytest

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.config.aircraft import SubImuConfig

HEAD = "name: t\ngnss_lever_arm_m: [0, 0, 1]\nflexure: {tau_s: [5, 2, 2], variance_deg2: [0.01, 0.01, 0.01]}\nantennas: []\n"


def _sub(extra: str) -> str:
    return HEAD + "sub_imus:\n  - {name: r, span_m: 5.0, lever_arm_m: [0, -5, 0], mount_rpy_deg: [0.5, 1.5, -1.0]" + extra + "}\n"


def test_absent_or_null_is_not_stated() -> None:
    assert load_aircraft("t", text=_sub("")).sub_imu("r").mount_sigma_deg is None
    assert load_aircraft("t", text=_sub(", mount_sigma_deg: null")).sub_imu("r").mount_sigma_deg is None


@pytest.mark.parametrize("value, want", [("0.25", 0.25), ("1", 1.0), ("3.0e-1", 0.3)])
def test_a_positive_sigma_is_read(value: str, want: float) -> None:
    s = load_aircraft("t", text=_sub(f", mount_sigma_deg: {value}")).sub_imu("r")
    assert s.mount_sigma_deg == pytest.approx(want) and s.mount_rpy_deg == (0.5, 1.5, -1.0)


@pytest.mark.parametrize("value", ["0", "-0.2", ".nan", ".inf", "true", "estimate", "[0.1, 0.2, 0.3]"])
def test_a_bad_sigma_is_a_config_error_naming_it(value: str) -> None:
    with pytest.raises(ConfigError, match=re.escape("t: sub_imus[0]: ") + ".*mount_sigma_deg"):
        load_aircraft("t", text=_sub(f", mount_sigma_deg: {value}"))


def test_the_dataclass_refuses_it_too() -> None:
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="mount_sigma_deg"):
            SubImuConfig("r", 5.0, (0.0, -5.0, 0.0), mount_sigma_deg=bad)
    assert SubImuConfig("r", 5.0, (0.0, -5.0, 0.0), mount_sigma_deg=0.1).mount_sigma_deg == 0.1
