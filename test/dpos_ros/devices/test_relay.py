"""``device: ros``: pos_sub_node relays a driver's sensor_msgs/Imu (dpos_ros.devices.relay.DeviceRelay).

A fake driver publishes on /drv/imu (best-effort or reliable); pos_sub_node with ``device:=ros`` and
``-r imu_in:=/drv/imu`` must republish every good message on /sub_imu/<name>/imu with the same
stamp and values (rotated when asked), reject NaN / duplicate / out-of-order / unavailable ones
with counts, report a gap, and lose nothing good. DeviceRelay's fix and vel routes are tested on
a test node. Every wait is bounded; nothing sleeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistWithCovarianceStamped
from node_process import START_TIMEOUT_S, STOP_TIMEOUT_S  # test/support/node_process.py
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_wait import spin_until  # test/support/ros_wait.py
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from dpos_ros.contract.qos import SENSOR_QOS, STATUS_QOS
from dpos_ros.devices.relay import DeviceRelay, Route, rotation_from_rpy_deg
from dpos_ros.runtime.params import ParameterError

pytestmark = pytest.mark.ros

TIMEOUT_S = 20.0
T0_NS = 1_700_000_000_123_000_000
PERIOD_NS = 10_000_000  # 100 Hz


def _driver_qos(reliability: str) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1000, durability=DurabilityPolicy.VOLATILE,
        reliability=ReliabilityPolicy.BEST_EFFORT if reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
    )


def _stamp(header: Any, t_ns: int) -> None:
    header.stamp.sec, header.stamp.nanosec = divmod(t_ns, 1_000_000_000)


def _t_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _imu(t_ns: int, w: np.ndarray, f: np.ndarray, w_var: np.ndarray, f_var: np.ndarray) -> Imu:
    m = Imu()
    _stamp(m.header, t_ns)
    m.header.frame_id = "vn100"
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = 0.1, 0.2, 0.3, 0.927  # driver's AHRS
    m.orientation_covariance = np.full(9, 0.01)
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in f)
    m.angular_velocity_covariance = np.diag(w_var).reshape(9)
    m.linear_acceleration_covariance = np.diag(f_var).reshape(9)
    return m


def _imu_sequence(rng: np.random.Generator) -> tuple[list[Imu], list[Imu], dict[str, int]]:
    """Messages as a driver would send them: good ones, bad ones and a gap of 5 samples.
    Returns (all messages in sending order, the good ones, the expected rejection counts)."""
    msgs: list[Imu] = []
    good: list[Imu] = []

    def add(k: int, **bad: Any) -> None:
        t = T0_NS + k * PERIOD_NS if "t" not in bad else bad["t"]
        w, f = rng.normal(0.0, 0.1, 3), rng.normal(0.0, 1.0, 3) + [0.0, 0.0, 9.8]
        m = _imu(t, w, f, rng.uniform(1e-6, 2e-6, 3), rng.uniform(1e-4, 2e-4, 3))
        if bad.get("nan"):
            m.angular_velocity.y = float("nan")
        if bad.get("unavailable"):
            m.linear_acceleration_covariance = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])
        msgs.append(m)
        if not bad:
            good.append(m)

    for k in range(30):
        add(k)
    add(30, nan=True)  # NaN gyro
    for k in range(30, 50):
        add(k)
    add(49, t=T0_NS + 49 * PERIOD_NS)  # duplicate stamp
    add(40, t=T0_NS + 40 * PERIOD_NS)  # out of order
    add(50, unavailable=True)  # linear acceleration covariance[0] = -1
    add(0, t=0)  # a driver that does not stamp
    for k in range(55, 80):  # samples 50..54 never arrive: a gap of 5
        add(k)
    rejected = {"nan": 1, "duplicate": 1, "out_of_order": 1, "unavailable": 1, "zero_stamp": 1}
    return msgs, good, rejected


def _vec(v: Any) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


CASES = {
    # driver QoS, node input_reliability, input_rotation_rpy_deg
    "best_effort_driver": ("best_effort", "best_effort", None),
    "reliable_driver_frd": ("reliable", "best_effort", [180.0, 0.0, 0.0]),
    "reliable_input_rotated": ("reliable", "reliable", [10.0, -20.0, 30.0]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_pos_sub_node_relays_driver_imu(case, ros_context, ros_executor):
    from pos_sub_node.node import PosSubNode

    driver_reliability, input_reliability, rpy = CASES[case]
    overrides = [Parameter("name", value="sub_r"), Parameter("device", value="ros"),
                 Parameter("input_reliability", value=input_reliability)]
    if rpy is not None:
        overrides.append(Parameter("input_rotation_rpy_deg", value=rpy))
    # independent of dpos_ros.devices.relay: extrinsic x-y-z = Rz(yaw) Ry(pitch) Rx(roll)
    R = np.eye(3) if rpy is None else Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()

    driver = Node("fake_imu_driver", context=ros_context)
    pub = driver.create_publisher(Imu, "/drv/imu", _driver_qos(driver_reliability))
    sink = Node("relay_sink", context=ros_context)
    got: list[Imu] = []
    sink.create_subscription(Imu, "/sub_imu/sub_r/imu", got.append, SENSOR_QOS)
    statuses: list[DiagnosticArray] = []
    sink.create_subscription(DiagnosticArray, "/sub_r/status", statuses.append, STATUS_QOS)
    node = PosSubNode(context=ros_context, cli_args=["--ros-args", "-r", "__node:=sub_r", "-r", "imu_in:=/drv/imu"],
                      parameter_overrides=overrides)
    for n in (driver, sink, node):
        ros_executor.add_node(n)
    try:
        assert node.device is None and node.relay is not None
        assert node.relay.describe() == "imu_in (/drv/imu) -> /sub_imu/sub_r/imu [sub_imu_sub_r]"
        out_pub = node.relay._states[0].publisher
        spin_until(ros_executor, lambda: pub.get_subscription_count() >= 1 and out_pub.get_subscription_count() >= 1,
                    TIMEOUT_S, "the driver -> relay -> sink matches")
        msgs, good, rejected = _imu_sequence(np.random.default_rng(5))
        # what the driver sent, copied before the relay (same process) could touch it
        by_stamp = {_t_ns(m): (_vec(m.angular_velocity), _vec(m.linear_acceleration),
                               np.array(m.angular_velocity_covariance).reshape(3, 3),
                               np.array(m.linear_acceleration_covariance).reshape(3, 3)) for m in good}
        good_t = [_t_ns(m) for m in good]
        for m in msgs:  # one at a time, so that a best-effort reader never overflows
            count = node.relay.stats["/sub_imu/sub_r/imu"].received
            pub.publish(m)
            spin_until(ros_executor, lambda c=count: node.relay.stats["/sub_imu/sub_r/imu"].received > c,
                        TIMEOUT_S, "the relay to receive the message")
        spin_until(ros_executor, lambda: len(got) >= len(good), TIMEOUT_S,
                    lambda: f"{len(good)} relayed messages (got {len(got)})")

        # every good message, in order, same stamp, values rotated into the body axes
        assert [_t_ns(m) for m in got] == good_t
        for m in got:
            w, f, w_cov, f_cov = by_stamp[_t_ns(m)]
            assert m.header.frame_id == "sub_imu_sub_r"
            np.testing.assert_allclose(_vec(m.angular_velocity), R @ w, rtol=0, atol=1e-15)
            np.testing.assert_allclose(_vec(m.linear_acceleration), R @ f, rtol=0, atol=1e-14)
            np.testing.assert_allclose(np.array(m.angular_velocity_covariance).reshape(3, 3), R @ w_cov @ R.T, atol=1e-20)
            np.testing.assert_allclose(np.array(m.linear_acceleration_covariance).reshape(3, 3), R @ f_cov @ R.T, atol=1e-18)
            assert m.orientation_covariance[0] == -1.0 and m.orientation.w == 1.0  # contract: no orientation
        if rpy == [180.0, 0.0, 0.0]:  # FRD -> FLU flips y and z
            first = by_stamp[good_t[0]][0]
            np.testing.assert_array_equal(_vec(got[0].angular_velocity), first * [1.0, -1.0, -1.0])

        st = node.relay.stats["/sub_imu/sub_r/imu"]
        assert st.received == len(msgs) and st.relayed == len(good) == 75
        assert st.rejected == rejected
        assert st.received == st.relayed + st.rejected_total  # nothing good lost
        assert (st.gaps, st.missing) == (1, 5) and st.largest_gap_s == pytest.approx(0.06)
        assert st.period_s == pytest.approx(0.01) and st.last_stamp_ns == good_t[-1]

        # the latched status reports the same counts
        def status_values() -> dict[str, str]:
            return {kv.key: kv.value for kv in statuses[-1].status[0].values} if statuses else {}

        spin_until(ros_executor, lambda: status_values().get("received") == str(len(msgs)), TIMEOUT_S,
                    lambda: f"a status with the final counts (last {status_values()})")
        values = status_values()
        assert values["relayed"] == "75" and values["gaps"] == "1" and values["missing"] == "5"
        assert values["rejected/duplicate"] == "1" and values["rejected/nan"] == "1"
        assert values["input_topic"] == "/drv/imu" and statuses[-1].status[0].level == DiagnosticStatus.WARN
    finally:
        for n in (node, sink, driver):
            ros_executor.remove_node(n)
            n.destroy_node()


def test_pos_sub_node_ros_checks_name_against_aircraft(ros_context):
    from pos_sub_node.node import PosSubNode

    overrides = [Parameter("name", value="sub_x"), Parameter("device", value="ros"),
                 Parameter("aircraft_config", value="paper_su_pair")]
    with pytest.raises(ParameterError, match="'name' = 'sub_x'.*sub_r, sub_l"):
        PosSubNode(context=ros_context, parameter_overrides=overrides)
    with pytest.raises(ParameterError, match="'input_reliability' = 'sometimes'"):
        PosSubNode(context=ros_context, parameter_overrides=[
            Parameter("name", value="sub_r"), Parameter("device", value="ros"),
            Parameter("input_reliability", value="sometimes")])


def _fix(t_ns: int, lat: float, var: list[float], status: int = NavSatStatus.STATUS_FIX) -> NavSatFix:
    m = NavSatFix()
    _stamp(m.header, t_ns)
    m.header.frame_id = "gps_link"
    m.status.status = status
    m.latitude, m.longitude, m.altitude = lat, 116.0, 500.0
    m.position_covariance = np.diag(var).reshape(9).astype(float)
    m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
    return m


def _vel(t_ns: int, v: list[float], var: list[float]) -> TwistWithCovarianceStamped:
    m = TwistWithCovarianceStamped()
    _stamp(m.header, t_ns)
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = v
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.diag(var)
    cov[3:, 3:] = -np.eye(3)  # angular part unknown: allowed
    m.twist.covariance = cov.reshape(36)
    return m


def test_device_relay_fix_and_vel_routes(ros_context, ros_executor):
    s = 1_000_000_000
    fixes = [_fix(T0_NS, 40.0, [1.0, 1.0, 4.0]),
             _fix(T0_NS + s, 40.0, [1.0, 1.0, 4.0], status=NavSatStatus.STATUS_NO_FIX),
             _fix(T0_NS + s, 40.0, [0.0, 0.0, 0.0]),          # unknown covariance
             _fix(T0_NS + s, 40.0, [1.0, -1.0, 4.0]),
             _fix(T0_NS + s, float("nan"), [1.0, 1.0, 4.0]),
             _fix(T0_NS + s, 91.0, [1.0, 1.0, 4.0]),
             _fix(T0_NS + s, 40.00001, [2.0, 2.0, 5.0])]
    vels = [_vel(T0_NS, [1.0, 2.0, 0.1], [0.01, 0.01, 0.04]),
            _vel(T0_NS + s, [1.0, 2.0, 0.1], [0.0, 0.0, 0.0]),
            _vel(T0_NS + s, [float("inf"), 2.0, 0.1], [0.01, 0.01, 0.04]),
            _vel(T0_NS + s, [1.0, 2.0, 0.1], [-1.0, 0.0, 0.0]),
            _vel(T0_NS + s, [1.1, 2.1, 0.2], [0.01, 0.01, 0.04])]
    driver = Node("fake_gnss_driver", context=ros_context)
    fix_pub = driver.create_publisher(NavSatFix, "/drv/fix", _driver_qos("reliable"))
    vel_pub = driver.create_publisher(TwistWithCovarianceStamped, "/drv/vel", _driver_qos("best_effort"))
    sink = Node("gnss_sink", context=ros_context)
    got: dict[str, list] = {"/gnss/fix": [], "/gnss/vel": []}
    sink.create_subscription(NavSatFix, "/gnss/fix", got["/gnss/fix"].append, SENSOR_QOS)
    sink.create_subscription(TwistWithCovarianceStamped, "/gnss/vel", got["/gnss/vel"].append, SENSOR_QOS)
    host = Node("relay_host", context=ros_context, cli_args=["--ros-args", "-r", "fix_in:=/drv/fix", "-r", "vel_in:=/drv/vel"])
    seen: list[tuple[str, int]] = []
    relay = DeviceRelay(host, [Route("fix", "fix_in", "/gnss/fix", "gnss"), Route("vel", "vel_in", "/gnss/vel", "gnss")],
                        on_message=lambda topic, m: seen.append((topic, _t_ns(m))), status_period_s=None)
    for n in (driver, sink, host):
        ros_executor.add_node(n)
    try:
        # status_period_s=None: no status publisher of its own
        assert "/relay_host/status" not in {t for t, _ in host.get_publisher_names_and_types_by_node("relay_host", "/")}
        spin_until(ros_executor, lambda: min(fix_pub.get_subscription_count(), vel_pub.get_subscription_count(),
                                              relay._states[0].publisher.get_subscription_count(),
                                              relay._states[1].publisher.get_subscription_count()) >= 1,
                    TIMEOUT_S, "the matches")
        for pub, msgs, topic in ((fix_pub, fixes, "/gnss/fix"), (vel_pub, vels, "/gnss/vel")):
            for m in msgs:
                n = relay.stats[topic].received
                pub.publish(m)
                spin_until(ros_executor, lambda n=n, t=topic: relay.stats[t].received > n, TIMEOUT_S, f"{topic} input")
        spin_until(ros_executor, lambda: len(got["/gnss/fix"]) >= 2 and len(got["/gnss/vel"]) >= 2, TIMEOUT_S,
                    lambda: f"the relayed fixes and velocities ({ {k: len(v) for k, v in got.items()} })")
        fix_stats, vel_stats = relay.stats["/gnss/fix"], relay.stats["/gnss/vel"]
        assert fix_stats.rejected == {"no_fix": 1, "zero_cov": 1, "negative_cov": 1, "nan": 1, "out_of_range": 1}
        assert (fix_stats.received, fix_stats.relayed) == (7, 2)
        assert vel_stats.rejected == {"zero_cov": 1, "nan": 1, "unavailable": 1}
        assert (vel_stats.received, vel_stats.relayed) == (5, 2)
        # passed through (ENU covariance / ENU velocity), stamps kept, frame gnss
        for out, src in zip(got["/gnss/fix"], (fixes[0], fixes[6])):
            assert out.header.frame_id == "gnss" and _t_ns(out) == _t_ns(src)
            assert (out.latitude, out.longitude, out.altitude) == (src.latitude, src.longitude, src.altitude)
            np.testing.assert_array_equal(out.position_covariance, src.position_covariance)
        for out, src in zip(got["/gnss/vel"], (vels[0], vels[4])):
            assert out.header.frame_id == "gnss" and _t_ns(out) == _t_ns(src)
            np.testing.assert_array_equal(_vec(out.twist.twist.linear), _vec(src.twist.twist.linear))
            np.testing.assert_array_equal(out.twist.covariance, src.twist.covariance)
        assert sorted(seen) == sorted([("/gnss/fix", T0_NS), ("/gnss/fix", T0_NS + s),
                                       ("/gnss/vel", T0_NS), ("/gnss/vel", T0_NS + s)])
        diag = relay.diagnostics()
        assert [d.name for d in diag] == ["relay_host: /drv/fix -> /gnss/fix", "relay_host: /drv/vel -> /gnss/vel"]
        assert "no_fix 1" in diag[0].message
    finally:
        for n in (host, sink, driver):
            ros_executor.remove_node(n)
            n.destroy_node()


def test_rotation_from_rpy_deg_matches_scipy():
    rng = np.random.default_rng(3)
    for rpy in rng.uniform(-180.0, 180.0, (20, 3)):
        np.testing.assert_allclose(rotation_from_rpy_deg(rpy), Rotation.from_euler("xyz", rpy, degrees=True).as_matrix(),
                                   atol=1e-14)
    np.testing.assert_array_equal(rotation_from_rpy_deg([180.0, 0.0, 0.0]), np.diag([1.0, -1.0, -1.0]))


def test_device_relay_rejects_bad_configuration(ros_context):
    node = Node("bad_relay_host", context=ros_context)
    imu = Route("imu", "imu_in", "/master/imu", "master_imu")
    try:
        with pytest.raises(ValueError, match="kind 'baro'"):
            Route("baro", "baro_in", "/baro", "baro")
        with pytest.raises(ValueError, match="duplicate output_topic"):
            DeviceRelay(node, [imu, Route("imu", "imu2_in", "/master/imu", "master_imu")])
        with pytest.raises(ValueError, match="input reliability 'lossy'"):
            DeviceRelay(node, [imu], input_reliability="lossy")
        with pytest.raises(ValueError, match="not a proper rotation"):
            DeviceRelay(node, [imu], R_out_in=np.diag([1.0, 1.0, -1.0]))  # a reflection
        with pytest.raises(ValueError, match="shape"):
            DeviceRelay(node, [imu], R_out_in=np.eye(2))
    finally:
        node.destroy_node()


def test_pos_sub_node_ros_process_logs_plan_and_stops(start_node):
    """The console script: device:=ros names the resolved input, the ignored simulator parameters, and
    stops cleanly on SIGINT."""
    import signal

    proc = start_node("pos_sub_node", "--ros-args", "-r", "__node:=sub_l", "-p", "name:=sub_l", "-p", "device:=ros",
                      "-p", "seed:=7", "-p", "rate_factor:=0", "-r", "imu_in:=/drv/imu_l")
    line = proc.wait_for_line("-> relaying", START_TIMEOUT_S)
    assert "imu_in (/drv/imu_l) -> /sub_imu/sub_l/imu [sub_imu_sub_l]" in line and "status on /sub_l/status" in line, line
    ignored = proc.wait_for_line("ignores the simulator parameters", 1.0)
    assert "seed=7" in ignored and "rate_factor=0.0" in ignored and "scenario" not in ignored, ignored
    proc.send_signal(signal.SIGINT)
    assert proc.wait(STOP_TIMEOUT_S) == 0, proc.output
    assert "Traceback" not in proc.output and "-> publishing" not in proc.output, proc.output


HOUR_NS = 3600 * 1_000_000_000
JUMP_CASES = {
    # case: (stamps in arrival order as sample indices or (index, offset ns), expected relayed indices, rejected)
    "one message +1 h": ([*range(40), (40, HOUR_NS), *range(41, 100)], [*range(40), *range(41, 100)], {"jump": 1}),
    "one message -1 h": ([*range(40), (40, -HOUR_NS), *range(41, 100)], [*range(40), *range(41, 100)], {"out_of_order": 1}),
    "two messages +1 h": ([*range(40), (40, HOUR_NS), (41, HOUR_NS), *range(42, 100)], [*range(40), *range(42, 100)], {"jump": 2}),
    "a glitch then a repeat of it": ([*range(40), (40, HOUR_NS), (40, HOUR_NS), *range(41, 100)], [*range(40), *range(41, 100)],
                                     {"jump": 1, "duplicate": 1}),
    "a real clock step +1 h": ([*range(40), *((k, HOUR_NS) for k in range(40, 100))], list(range(100)), {}),
}


@pytest.mark.parametrize("case", sorted(JUMP_CASES))
def test_one_stamp_jump_costs_one_message(case, ros_context):
    """A driver message stamped +1 h: rejected alone (``jump``), the stream goes
    on; a real clock step (the stamps go on from the new time) is relayed whole.  The relay's
    callback is called directly: no DDS delivery is involved."""
    order, relayed_idx, rejected = JUMP_CASES[case]
    host = Node("jump_host", context=ros_context)
    relay = DeviceRelay(host, [Route("imu", "imu_in", "/sub_imu/x/imu", "sub_imu_x")], status_period_s=None)
    out: list[int] = []
    st = relay._states[0]
    st.publisher = type("Pub", (), {"publish": lambda self, m: out.append(_t_ns(m))})()
    rng = np.random.default_rng(3)
    try:
        stamps = []
        for item in order:
            k, off = (item, 0) if isinstance(item, int) else item
            stamps.append(T0_NS + k * PERIOD_NS + off)
            relay._on_input(st, _imu(stamps[-1], rng.normal(0, 0.1, 3), np.array([0, 0, 9.8]), np.full(3, 1e-6), np.full(3, 1e-4)))
        step = HOUR_NS if case.startswith("a real") else 0
        assert out == [T0_NS + k * PERIOD_NS + (step if k >= 40 else 0) for k in relayed_idx]
        s = relay.stats["/sub_imu/x/imu"]
        assert s.rejected == rejected and s.relayed == len(relayed_idx) and s.held == 0
        assert s.received == s.relayed + s.rejected_total + s.held == len(order)
    finally:
        host.destroy_node()
