"""The committed sample bag is what the simulator generates for its command line (bags/README.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros import bag, cdr
from dpos_ros.sim_streams import session_streams

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "paper_su_pair_seed1_45s"


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
        np.testing.assert_array_equal(np.array(t_log), s.t_ns)
        if s.rows is None:
            assert list(blobs) == list(s.blobs), s.topic
            continue
        kind = "imu" if s.msgtype.endswith("Imu") else "odometry"
        frame, child = cdr.frame_ids(blobs[0], kind)
        _, got = cdr.decode(cdr.layout(kind, frame, child), bag.rows(blobs))
        _, want = cdr.decode(cdr.layout(kind, frame, child), s.rows)
        # identical up to the last bits of floating point (the bag may come from another BLAS/CPU)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12, err_msg=f"{s.topic}: regenerate the sample (bags/README.md)")
