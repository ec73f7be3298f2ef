"""``dpos-record``: record DDS topics into a rosbag2 (MCAP, zstd chunks), message bytes unchanged.

    dpos-record --out /tmp/rec --until-session-end /master/imu /master/nav /session/end
    dpos-record --out /tmp/rec --all --duration 60 --meta operator=alice
    dpos-record --out /tmp/rec /master/imu --ros-args -r __node:=my_recorder

Topics are subscribed as soon as a publisher appears (QoS of docs/design.md: RELIABLE, KEEP_ALL;
TRANSIENT_LOCAL for /dpos/datum and */status). Log time = receive time (like ros2 bag).
Stops on Ctrl-C / SIGTERM, after --duration seconds, or with --until-session-end when
/session/end arrives (after a bounded drain of what is still in flight). Prints the messages
recorded per topic. Exit status: 0; 1 when a requested topic never appeared (listed as missing,
the bag is still written); 2 on bad arguments or when the bag cannot be written.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from dpos_ros.cli.options import one_line_errors
from dpos_ros.io.record import BagRecorder
from dpos_ros.runtime.node_main import install_stop_handlers, restore_handlers

EXIT_OK = 0
EXIT_MISSING = 1
EXIT_ERROR = 2


def _parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="dpos-record", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("topics", nargs="*", help="topics to record")
    ap.add_argument("--out", "-o", type=Path, required=True, help="new rosbag2 directory to write")
    ap.add_argument("--all", "-a", action="store_true", dest="all_topics",
                    help="record every topic discovered (but /rosout, /parameter_events, /clock unless named)")
    ap.add_argument("--duration", type=float, help="stop after this many seconds (wall time)")
    ap.add_argument("--until-session-end", action="store_true", help="stop when /session/end arrives (after a drain)")
    ap.add_argument("--drain", type=float, default=10.0,
                    help="after /session/end: longest time to keep receiving what is in flight [s] (default 10)")
    ap.add_argument("--drain-idle", type=float, default=0.3,
                    help="after /session/end: stop once nothing arrived for this long [s] (default 0.3)")
    ap.add_argument("--wait-topics", type=float, default=10.0,
                    help="warn about requested topics without a publisher after this many seconds (default 10); "
                    "they are still looked for, and reported as missing at the end")
    ap.add_argument("--meta", action="append", default=[], metavar="KEY=VALUE", help="custom_data of the bag metadata (repeatable)")
    args = ap.parse_args(argv)
    if not args.topics and not args.all_topics:
        ap.error("name the topics to record, or --all")
    bad = [t for t in args.topics if not t.startswith("/")]
    if bad:
        ap.error(f"topic names must be absolute (start with '/'): {', '.join(bad)}")
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        ap.error("--duration must be > 0 (and finite)")
    if args.drain < 0 or args.drain_idle < 0 or args.wait_topics < 0:
        ap.error("--drain, --drain-idle and --wait-topics must be >= 0")
    meta = {}
    for kv in args.meta:
        key, sep, value = kv.partition("=")
        if not sep or not key:
            ap.error(f"--meta {kv!r}: expected KEY=VALUE")
        meta[key] = value
    args.meta = meta
    if args.out.exists():
        ap.error(f"--out {args.out} exists; rosbag2 writes a new directory")
    return args


@one_line_errors("dpos-record")
def main(argv: list[str] | None = None) -> int:
    full = list(sys.argv if argv is None else ["dpos-record", *argv])
    args = _parse(remove_ros_args(full)[1:])

    stop = threading.Event()
    reason = ["interrupted"]
    previous = install_stop_handlers(stop.set)
    node = executor = recorder = None
    status = EXIT_OK
    t0 = time.monotonic()
    try:
        rclpy.init(args=full, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("dpos_record")
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            recorder = BagRecorder(node, args.out, args.topics, all_topics=args.all_topics,
                                   custom_data=args.meta, watch_session_end=args.until_session_end)
        except (OSError, ValueError) as exc:
            print(f"dpos-record: cannot write {args.out}: {exc}", file=sys.stderr)
            return EXIT_ERROR
        what = "every topic" if args.all_topics and not args.topics else ", ".join(args.topics) + (" and every topic" if args.all_topics else "")
        print(f"dpos-record: recording {what} -> {args.out}", flush=True)
        warned = False
        t0 = time.monotonic()
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if args.duration is not None and now - t0 >= args.duration:
                reason[0] = f"duration {args.duration:g} s reached"
                break
            if recorder.session_end_at is not None:
                if now - recorder.session_end_at >= args.drain or now - recorder.last_receive >= args.drain_idle:
                    reason[0] = "/session/end received"
                    break
            if not warned and now - t0 >= args.wait_topics and recorder.missing():
                warned = True
                node.get_logger().warning(
                    f"no publisher after {args.wait_topics:g} s for {', '.join(recorder.missing())} (still looking)")
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        close_error = None
        if recorder is not None:
            try:
                recorder.close()
            except Exception as exc:  # noqa: BLE001 - reported below
                close_error = exc
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        restore_handlers(previous)
    if recorder is None:
        return EXIT_ERROR
    elapsed = time.monotonic() - t0
    total = sum(recorder.counts.values())
    print(f"dpos-record: stopped ({reason[0]}) after {elapsed:.1f} s: {total} messages on "
          f"{len(recorder.counts)} topics -> {args.out}")
    for topic, n in recorder.counts.items():
        print(f"  {topic:<32} {recorder.types[topic]:<46} {n:>8}")
    if close_error is not None:
        print(f"dpos-record: error: {close_error}", file=sys.stderr)
        status = EXIT_ERROR
    for kind, n in sorted(recorder.problems.items()):
        print(f"dpos-record: warning: {n} x {kind} (see the warnings above)", file=sys.stderr)
    missing = recorder.missing()
    if missing:
        for topic in missing:
            why = recorder.failed.get(topic, "no publisher discovered")
            print(f"dpos-record: missing {topic}: {why}", file=sys.stderr)
        print(f"dpos-record: {len(missing)} requested topic(s) missing: {', '.join(missing)}")
        status = max(status, EXIT_MISSING)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
