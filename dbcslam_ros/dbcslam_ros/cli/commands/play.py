"""``dbcslam play BAG``: publish a bag's messages with their recorded timing and QoS."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from dbcslam_ros.cli._common import (
    bag_qos_to_runtime,
    native_qos,
    node_session,
    positive_float,
)
from dbcslam_ros.cli.registry import Command
from dbcslam_ros.errors import BagError

__all__ = ["COMMAND", "PLAYER_NODE"]

#: Node name of the player.
PLAYER_NODE = "dbcslam_play"
#: Minimum history depth of volatile playback publishers (a fast replay must not overrun
#: reliable readers).
_MIN_DEPTH = 1000

_DESCRIPTION = """\
Publish the messages of BAG (bag directory or .mcap file; a directory holding bags plays
each in name order) on their topics, in log-time order, keeping the recorded gaps
between messages divided by --rate. Each topic is published with the QoS recorded for
it (reliable/best effort, volatile/transient local, depth), so a latched topic such as
/scenario is latched again for late subscribers.
The CDR bytes are published as recorded (no decode/re-encode).

--clock publishes rosgraph_msgs/msg/Clock on /clock with the bag time (for nodes using
use_sim_time). --delay waits before the first message so subscribers can match.
A damaged bag is an error (exit 2) unless --salvage plays what lies before the damage.
SIGINT/SIGTERM stop the playback (exit 0)."""

_EXAMPLES = """\
  dbcslam play bags/edge
  dbcslam play bags/edge --rate 2 --clock       # twice as fast, with /clock
  dbcslam play crashed_run/ --salvage --loop
  dbcslam play bags/edge --topics /scenario /object/pose /object/wrench /joint_states
"""


def _publish_clock(pub: Any, bag_time_ns: int) -> None:
    from dbcslam_ros.bag.types import jazzy_typestore

    store = jazzy_typestore()
    clock_t = store.types["rosgraph_msgs/msg/Clock"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    sec, nsec = divmod(max(0, bag_time_ns), 1_000_000_000)
    msg = clock_t(clock=time_t(sec=sec, nanosec=nsec))
    pub.publish(bytes(store.serialize_cdr(msg, "rosgraph_msgs/msg/Clock")))


def _wait_for_acks(rt: Any, pub: Any, timeout_s: float) -> None:
    """Block until reliable readers acknowledged everything (bounded)."""
    pub.wait_for_all_acked(rt.Duration(seconds=timeout_s))


def _open_bags(args: argparse.Namespace) -> list[Any]:
    """The bags named by BAG (one bag, or every bag in a directory), checked in full."""
    from dbcslam_ros.bag.reader import find_bags, open_bag

    bags = [open_bag(path, salvage=args.salvage) for path in find_bags(args.bag)]
    for bag in bags:
        bag.verify()  # a damaged chunk is reported before anything is published
        if bag.damage is not None:
            print(f"warning: {bag.damage}; playing the messages before it", file=sys.stderr)
    return bags


def _select_topics(args: argparse.Namespace, bags: list[Any]) -> dict[str, Any]:
    """Topics to play (first bag holding a topic gives its type and QoS)."""
    from dbcslam_ros.bag.types import register_schema

    topics: dict[str, Any] = {}
    counts: dict[str, int] = {}
    for bag in bags:
        for name, topic in bag.topics().items():
            topics.setdefault(name, topic)
            counts[name] = counts.get(name, 0) + topic.message_count
    if args.topics is not None:
        unknown = sorted(set(args.topics) - set(topics))
        if unknown:
            have = ", ".join(sorted(topics))
            problem = f"{args.bag}: no topic {', '.join(unknown)} in the bag (it has {have})"
            raise BagError(problem)
        topics = {name: t for name, t in topics.items() if name in args.topics}
    if sum(counts[name] for name in topics) == 0:
        problem = f"{args.bag}: the bag holds no messages to play"
        raise BagError(problem)
    for topic in topics.values():
        # Types ROS 2 Jazzy does not ship become publishable from the schema in the bag.
        if topic.schema_text:
            register_schema(topic.msgtype, topic.schema_encoding, topic.schema_text)
    return topics


def _run(args: argparse.Namespace) -> int:
    bags = _open_bags(args)
    topics = _select_topics(args, bags)
    published = 0
    with node_session(PLAYER_NODE) as (rt, node, stop):
        pubs = {
            t.name: rt.create_raw_publisher(
                node,
                t.msgtype,
                t.name,
                native_qos(rt, bag_qos_to_runtime(t.offered_qos, min_depth=_MIN_DEPTH)),
            )
            for t in topics.values()
        }
        clock_pub = None
        if args.clock is not None:
            clock_pub = rt.create_raw_publisher(
                node, "rosgraph_msgs/msg/Clock", "/clock", rt.qos_profile("clock")
            )
        if args.delay > 0:
            stop.wait(args.delay)
        clock_period = 1.0 / args.clock if args.clock else 0.0
        while not stop.stopped:
            for bag in bags:
                if stop.stopped:
                    break
                start_bag = bag.start_ns
                start_wall = time.monotonic()
                next_clock = start_wall
                for msg in bag.messages(topics):
                    target = start_wall + (msg.log_time_ns - start_bag) / 1e9 / args.rate
                    while True:
                        now = time.monotonic()
                        if clock_pub is not None and now >= next_clock:
                            bag_now = start_bag + int((now - start_wall) * args.rate * 1e9)
                            _publish_clock(clock_pub, min(bag_now, msg.log_time_ns))
                            next_clock = now + clock_period
                        wait = target - now
                        if wait <= 0 or stop.stopped:
                            break
                        if clock_pub is not None:
                            wait = min(wait, max(0.0, next_clock - now))
                        stop.wait(min(wait, 0.1))
                    if stop.stopped:
                        break
                    pubs[msg.topic].publish(msg.data)
                    published += 1
            if not args.loop:
                break
        # Give reliable readers the chance to acknowledge before the publishers go away.
        for pub in pubs.values():
            _wait_for_acks(rt, pub, 2.0)
    print(f"published {published} messages from {args.bag}", file=sys.stderr)
    return 0


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "bag",
        metavar="BAG",
        help="bag directory or .mcap file; a directory of bags plays them one after another",
    )
    parser.add_argument(
        "-r",
        "--rate",
        type=positive_float,
        default=1.0,
        metavar="R",
        help="playback speed factor (default 1.0; 2 = twice as fast)",
    )
    parser.add_argument("-l", "--loop", action="store_true", help="play again and again")
    parser.add_argument(
        "--topics",
        nargs="+",
        metavar="TOPIC",
        help="play only these topics (e.g. the inputs, to run a live filter on them)",
    )
    parser.add_argument(
        "--clock",
        type=positive_float,
        nargs="?",
        const=40.0,
        default=None,
        metavar="HZ",
        help="publish /clock with the bag time at HZ (default 40 Hz when given)",
    )
    parser.add_argument(
        "--delay",
        type=float,
        default=0.5,
        metavar="S",
        help="seconds to wait after creating publishers before playing (default 0.5)",
    )
    parser.add_argument(
        "--salvage",
        action="store_true",
        help="play the messages before a truncation or damage instead of failing",
    )


COMMAND = Command(
    name="play",
    help="publish a bag with its recorded timing and QoS",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
