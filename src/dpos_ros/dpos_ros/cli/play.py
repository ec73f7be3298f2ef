"""``dpos-play``: replay a rosbag2 on DDS, message bytes unchanged, with /clock.

    dpos-play bags/paper_su_pair_seed1_45s                       # real time, publishes /clock
    dpos-play /tmp/rec --rate 0 --min-subscribers 1              # as fast as the subscribers keep up
    dpos-play /tmp/rec --rate 10 --topics /master/imu /master/nav --no-clock

--rate 1.0 replays with the recorded timing (log times), 10 ten times faster, 0 as fast as the
reliable subscribers acknowledge (flow control: nothing is lost). /clock (rosgraph_msgs/Clock)
carries the bag's log time so that nodes with use_sim_time follow the bag. /dpos/datum and
*/status are latched (TRANSIENT_LOCAL). Exits 0 once everything is published and acknowledged;
1 when interrupted; 2 on bad arguments or an unreadable bag.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from dpos_ros.cli.options import one_line_errors
from dpos_ros.io.flow import use_device_fastdds_profile
from dpos_ros.io.play import BagError, BagPlayer, PlayOptions
from dpos_ros.runtime.node_main import install_stop_handlers, restore_handlers

EXIT_OK = 0
EXIT_INTERRUPTED = 1
EXIT_ERROR = 2


def _parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="dpos-play", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="rosbag2 directory (MCAP or SQLite)")
    ap.add_argument("--rate", "-r", type=float, default=1.0, help="1 = recorded timing, 0 = as fast as subscribers keep up (default 1)")
    ap.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics")
    clock = ap.add_mutually_exclusive_group()
    clock.add_argument("--clock", dest="clock", action="store_true", default=True, help="publish /clock with the bag's log time (default)")
    clock.add_argument("--no-clock", dest="clock", action="store_false", help="do not publish /clock")
    ap.add_argument("--clock-hz", type=float, default=100.0, help="most /clock messages per wall second (default 100)")
    ap.add_argument("--min-subscribers", type=int, default=0, help="wait for this many subscribers on every non-latched topic (default 0)")
    ap.add_argument("--wait-subscribers", type=float, default=30.0, metavar="S", help="longest wait for --min-subscribers [s] (default 30)")
    ap.add_argument("--flow-window", type=int, default=None, metavar="N",
                    help="unacknowledged messages over all topics (default 1000, see dpos_ros.io.play)")
    args = ap.parse_args(argv)
    if not (args.rate >= 0 and math.isfinite(args.rate)):
        ap.error("--rate must be >= 0 (and finite)")
    if not (args.clock_hz > 0 and math.isfinite(args.clock_hz)):
        ap.error("--clock-hz must be > 0 (and finite)")
    if args.min_subscribers < 0 or not (args.wait_subscribers >= 0 and math.isfinite(args.wait_subscribers)):
        ap.error("--min-subscribers and --wait-subscribers must be >= 0 (and finite)")
    if args.flow_window is not None and args.flow_window < 1:
        ap.error(f"--flow-window must be >= 1, got {args.flow_window}")
    return args


@one_line_errors("dpos-play")
def main(argv: list[str] | None = None) -> int:
    full = list(sys.argv if argv is None else ["dpos-play", *argv])
    args = _parse(remove_ros_args(full)[1:])
    if not args.bag.exists():
        print(f"dpos-play: error: {args.bag}: no such bag (a rosbag2 directory)", file=sys.stderr)
        return EXIT_ERROR

    player = None
    previous = install_stop_handlers(lambda: player.stop() if player is not None else None)
    use_device_fastdds_profile()  # prompt acknowledgements for the flow control
    node = None
    status = EXIT_OK
    done = False
    try:
        rclpy.init(args=full, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("dpos_play")

        def log(text: str) -> None:
            print(f"dpos-play: {text}", flush=True)

        try:
            options = PlayOptions(rate=args.rate, topics=None if args.topics is None else tuple(args.topics), clock=args.clock,
                                  clock_hz=args.clock_hz, min_subscribers=args.min_subscribers,
                                  wait_subscribers_s=args.wait_subscribers,
                                  **({} if args.flow_window is None else {"flow_window": args.flow_window}))
            player = BagPlayer(node, args.bag, options, log=log)
        except BagError as exc:
            print(f"dpos-play: error: {exc}", file=sys.stderr)
            return EXIT_ERROR
        t0 = time.monotonic()
        try:
            done = player.run()
        except BagError as exc:
            print(f"dpos-play: error: {exc}", file=sys.stderr)
            status = EXIT_ERROR
        finally:
            player.close()
        wall = time.monotonic() - t0
        span = (player.last_ns - player.first_ns) * 1e-9
        rate = player.published / player.elapsed_s if done and player.elapsed_s > 0 else 0.0
        state = "played" if done else ("stopped" if status == EXIT_OK else "failed")
        print(f"dpos-play: {state}: {player.published} of {player.total} messages on {len(player.topics)} topics, "
              f"{span:.1f} s of log time in {player.elapsed_s if done else wall:.2f} s"
              + (f" ({rate:.0f} messages/s)" if done else "")
              + (f", {player.clock_published} /clock" if args.clock else ""), flush=True)
        for t in player.topics:
            print(f"  {t.topic:<32} {t.msgtype:<46} {player.per_topic[t.topic]:>8}")
        if not done and status == EXIT_OK:
            status = EXIT_INTERRUPTED
    except (KeyboardInterrupt, ExternalShutdownException):
        status = EXIT_INTERRUPTED
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        restore_handlers(previous)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
