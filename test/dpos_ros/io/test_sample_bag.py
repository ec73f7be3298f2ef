"""The committed sample bag is what the simulator generates for its command line (bags/README.md).

The bag was written on another machine.  Floating point is not bit-identical across CPUs, libm
and BLAS builds (a last-bit difference in one GNSS latitude failed this test on a fresh machine),
so every message is decoded and its float fields are compared with a tolerance; stamps, integers
and strings (frame ids, status) must be identical.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from repo_paths import REPO

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.contract import cdr
from dpos_ros.devices.sim_streams import session_streams
from dpos_ros.io import bag

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"

# Relative tolerance for floats of the sample against a fresh simulation.  Round-off differs
# between machines by a few ulp per operation (2.2e-16 relative) and accumulates over the 4500
# steps of the 45 s integration to ~1e-12; 1e-9 leaves a 1000x margin.  A deliberate change of
# the simulator moves the values by far more (the smallest simulated noise, 0.01 deg/h of gyro
# bias, is 5e-8 rad/s against rates of 1e-3 rad/s and more: 5e-5 relative).
RTOL = 1e-9
# Absolute floor: positions in metres of the ``enu`` frame are differences of ECEF coordinates of
# 6.4e6 m, whose last bit is 0.9 nm (measured: 3 nm between this machine and the sample's); 10 nm
# is far below anything the simulator models (the smallest position noise is millimetres).
ATOL = 1e-8


def _flatten(msg: Any, prefix: str = "") -> tuple[dict[str, Any], dict[str, float]]:
    """Split a deserialized rosbags message into exact fields (ints, strings) and float fields."""
    exact: dict[str, Any] = {}
    floats: dict[str, float] = {}
    for name in msg.__dataclass_fields__:
        if name == "__msgtype__":
            continue
        v = getattr(msg, name)
        key = f"{prefix}{name}"
        if hasattr(v, "__dataclass_fields__"):
            e, f = _flatten(v, key + ".")
            exact.update(e)
            floats.update(f)
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f":
            floats.update({f"{key}[{i}]": float(x) for i, x in enumerate(v)})
        elif isinstance(v, float):
            floats[key] = v
        elif isinstance(v, np.ndarray):
            exact[key] = v.tolist()
        else:
            exact[key] = v
    return exact, floats


def _assert_same_message(got: bytes, want: bytes, msgtype: str, where: str) -> None:
    ts = bag.typestore()
    e_got, f_got = _flatten(ts.deserialize_cdr(got, msgtype))
    e_want, f_want = _flatten(ts.deserialize_cdr(want, msgtype))
    assert e_got == e_want, where
    assert f_got.keys() == f_want.keys(), where
    keys = sorted(f_want)
    np.testing.assert_allclose([f_got[k] for k in keys], [f_want[k] for k in keys], rtol=RTOL, atol=ATOL,
                               err_msg=f"{where}: regenerate the sample (bags/README.md)")


def test_sample_bag_is_small_and_current() -> None:
    size = sum(f.stat().st_size for f in SAMPLE.iterdir())
    assert size < 5e6, f"{SAMPLE} is {size / 1e6:.1f} MB"
    raw = bag.read_raw(SAMPLE)
    streams = session_streams(SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 1, 45.0))
    assert set(raw) == {s.topic for s in streams}
    meta = bag.custom_data(SAMPLE)
    assert meta["dpos.session_id"] == "paper_su_seed1" and meta["dpos.scenario"] == "paper_su"
    assert "sub_l" in meta["dpos.aircraft_yaml"]
    for s in streams:
        mt, t_log, blobs = raw[s.topic]
        assert mt == s.msgtype and len(blobs) == len(s), s.topic
        np.testing.assert_array_equal(np.array(t_log), s.t_ns)  # integers: exact
        if s.rows is None:  # variable-size messages (fix, velocity, datum, session end)
            for i, b in enumerate(blobs):
                _assert_same_message(b, s.message(i), s.msgtype, f"{s.topic}[{i}]")
            continue
        kind = "imu" if s.msgtype.endswith("Imu") else "odometry"
        frame, child = cdr.frame_ids(blobs[0], kind)
        assert all(cdr.frame_ids(b, kind) == (frame, child) for b in blobs), s.topic
        t_got, got = cdr.decode(cdr.layout(kind, frame, child), bag.rows(blobs))
        t_want, want = cdr.decode(cdr.layout(kind, frame, child), s.rows)
        np.testing.assert_array_equal(t_got, t_want)
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL, err_msg=f"{s.topic}: regenerate the sample (bags/README.md)")
