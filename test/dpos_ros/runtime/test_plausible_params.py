"""Node parameters that claim the impossible are refused in one line (dpos_core.plausibility):
a zero ``initial_sigma`` (an exact start the filter never corrects), ``gnss_time_offset_s`` far
beyond any clock offset (1e300, an hour)."""

from __future__ import annotations

import pytest

from dpos_ros.runtime.params import ParameterError, config_from_values


@pytest.mark.parametrize("sigma", [[5.0, 0.5, 0.0, 1.0, 1.0], [0.0, 0.5, 100.0, 1.0, 1.0]])
def test_zero_initial_sigma_is_refused(sigma):
    from pos_master_node.params import PosMasterConfig

    with pytest.raises(ParameterError, match=r"invalid parameter 'initial_sigma' .*must be > 0"):
        config_from_values(PosMasterConfig, {"initial_sigma": sigma})
    assert config_from_values(PosMasterConfig, {"initial_sigma": [5.0, 0.5, 1.0, 1.0, 1.0]}).initial_sigma[2] == 1.0


@pytest.mark.parametrize(("offset", "ok"), [(0.0, True), (-0.25, True), (1e300, False), (3600.0, False), (-61.0, False)])
def test_gnss_time_offset_beyond_a_minute_is_refused(offset, ok):
    from ifa_node.params import IfaConfig

    if ok:
        assert config_from_values(IfaConfig, {"gnss_time_offset_s": offset}).gnss_time_offset_s == offset
        return
    with pytest.raises(ParameterError) as e:
        config_from_values(IfaConfig, {"gnss_time_offset_s": offset})
    msg = str(e.value)
    assert "gnss_time_offset_s" in msg and "beyond +-60 s" in msg and "\n" not in msg, msg
