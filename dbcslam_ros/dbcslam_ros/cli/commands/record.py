"""``dbcslam record -o DIR [TOPIC ...]``: record live topics into a rosbag2 MCAP bag."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from dbcslam_ros.cli._common import (
    native_qos,
    node_session,
    positive_float,
    subscription_qos_for,
)
from dbcslam_ros.cli.registry import Command
from dbcslam_ros.contract import CONTRACT_TOPICS, contract_qos_profile
from dbcslam_ros.errors import BagError, UsageError
from dbcslam_ros.qos import to_bag_qos

__all__ = ["COMMAND", "RECORDER_NODE"]

#: Node name of the recorder.
RECORDER_NODE = "dbcslam_record"
#: Topics every rclpy node publishes; left out of "record everything" unless asked
#: (``--include-ros-topics``) or named, as ``ros2 bag record`` does.
ROS_INTERNAL_TOPICS = frozenset({"/rosout", "/parameter_events"})
#: Subscription history depth: generous so bursts are not dropped before they are taken.
_DEPTH = 1000
_DISCOVERY_PERIOD_S = 0.2
_FLUSH_PERIOD_S = 1.0

_DESCRIPTION = """\
Record live topics into a rosbag2 bag: directory DIR with metadata.yaml (version 9) and one
MCAP file (ros2 profile, CDR messages, the offered QoS of each topic), readable by
'ros2 bag play', rosbags and the mcap tools.

Without TOPIC arguments every topic is recorded (except /rosout and /parameter_events,
unless --include-ros-topics); topics that appear later are picked up (the graph is polled
every 0.2 s). Messages are stored as exact CDR (re-serialised through the rosbags
typestore: exact length, zeroed padding), so a recording is reproducible byte for byte.
Each topic is subscribed with a QoS compatible with what its publishers offer (reliable if
all are, transient local if all are, so latched topics
such as /scenario are recorded even when published before the recorder started).
Log time = receive time (ns since the epoch). --contract subscribes to the topics of the
interface contract at once, with their contract types and QoS, so nothing a node started
afterwards publishes is missed (`dbcslam demo` uses it); other topics are still discovered.

SIGINT (Ctrl-C) or SIGTERM, or the end of --duration, stops the recording: pending
messages are written and the bag is closed properly, its counts matching what was
received. Progress counts go to stderr once per second."""

_EXAMPLES = """\
  dbcslam record -o bags/run1                           # everything
  dbcslam record -o bags/run1 /scenario /object/pose /object/wrench /joint_states
  dbcslam record -o bags/run1 --duration 10 --overwrite
"""


class _Recorder:
    """Subscribes to discovered topics and writes what arrives into the bag."""

    def __init__(
        self, rt: Any, node: Any, writer: Any, topics: list[str], *, internal: bool = False
    ) -> None:
        self.rt = rt
        self.internal = internal
        self.bad: dict[str, int] = {}
        self.node = node
        self.writer = writer
        self.wanted = set(topics)
        self.all_topics = not topics
        self.subscribed: dict[str, Any] = {}
        self.skipped: set[str] = set()
        self.added: set[str] = set()

    def discover(self) -> None:
        from dbcslam_ros.bag.types import message_definition

        for topic, types in self.rt.get_topic_names_and_types(self.node):
            if topic in self.subscribed or topic in self.skipped:
                continue
            if not self.all_topics and topic not in self.wanted:
                continue
            if self.all_topics and not self.internal and topic in ROS_INTERNAL_TOPICS:
                continue
            infos = self.rt.get_publishers_info(self.node, topic)
            if not infos:
                continue  # only subscribers so far: wait for a publisher to learn the QoS
            pub_types = sorted({i.topic_type for i in infos}) or types
            type_name = pub_types[0]
            if len(pub_types) > 1:
                warn = f"warning: {topic} has several types {pub_types}; recording {type_name}"
                print(warn, file=sys.stderr)
            try:
                message_definition(type_name)
            except BagError as err:
                print(f"warning: not recording {topic}: {err}", file=sys.stderr)
                self.skipped.add(topic)
                continue
            offered = [i.qos_profile for i in infos if i.topic_type == type_name]
            self.writer.add_topic(topic, type_name, [to_bag_qos(q) for q in offered])
            qos = subscription_qos_for(offered, depth=_DEPTH)

            def on_message(data: bytes, topic: str = topic, type_name: str = type_name) -> None:
                self.write(topic, type_name, data)

            self.subscribed[topic] = self.rt.create_raw_subscription(
                self.node, type_name, topic, on_message, native_qos(self.rt, qos)
            )
            print(f"recording {topic} [{type_name}]", file=sys.stderr, flush=True)

    def write(self, topic: str, type_name: str, data: bytes) -> None:
        """Write one received message as exact CDR (the middleware may hand over trailing
        alignment bytes); a message that does not parse is counted and left out."""
        from dbcslam_ros.errors import MessageTypeError

        try:
            cdr = self.rt.canonical_cdr(data, type_name)
        except MessageTypeError as err:
            self.bad[topic] = self.bad.get(topic, 0) + 1
            if self.bad[topic] == 1:
                print(f"warning: dropping unreadable message on {topic}: {err}", file=sys.stderr)
            return
        self.writer.write(topic, cdr, time.time_ns())

    def subscribe_contract(self) -> None:
        """Subscribe now to every contract topic with its contract type and QoS (before any
        publisher exists, so the first messages of a node started next are not missed).
        A topic enters the bag with its first message."""
        for topic, type_name in CONTRACT_TOPICS.items():
            if not self.all_topics and topic not in self.wanted:
                continue
            offered = contract_qos_profile(topic)
            bag_qos = to_bag_qos(offered)
            qos = subscription_qos_for([offered], depth=_DEPTH)

            def on_message(
                data: bytes, topic: str = topic, type_name: str = type_name, bag_qos: Any = bag_qos
            ) -> None:
                if topic not in self.added:
                    self.writer.add_topic(topic, type_name, [bag_qos])
                    self.added.add(topic)
                self.write(topic, type_name, data)

            self.subscribed[topic] = self.rt.create_raw_subscription(
                self.node, type_name, topic, on_message, native_qos(self.rt, qos)
            )
            print(f"recording {topic} [{type_name}]", file=sys.stderr, flush=True)


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.bag.writer import BagWriter

    for topic in args.topics:
        if not topic.startswith("/"):
            msg = f"topic {topic!r}: expected an absolute name such as /object/pose"
            raise UsageError(msg)
    writer = BagWriter(args.output, overwrite=args.overwrite)
    writer.open()  # fails before any DDS work if the bag exists
    try:
        with node_session(RECORDER_NODE) as (rt, node, stop):
            rec = _Recorder(rt, node, writer, list(args.topics), internal=args.include_ros_topics)
            if args.contract:
                rec.subscribe_contract()
            start = time.monotonic()
            end = None if args.duration is None else start + args.duration
            next_discovery = start
            next_report = start + _FLUSH_PERIOD_S
            last_count = 0
            while not stop.stopped:
                now = time.monotonic()
                if end is not None and now >= end:
                    break
                if now >= next_discovery:
                    rec.discover()
                    next_discovery = now + _DISCOVERY_PERIOD_S
                if now >= next_report:
                    next_report = now + _FLUSH_PERIOD_S
                    writer.flush()
                    count = writer.message_count
                    if not args.quiet and count != last_count:
                        last_count = count
                        per = ", ".join(f"{t} {n}" for t, n in writer.counts().items())
                        print(f"recorded {count} messages ({per})", file=sys.stderr, flush=True)
                rt.spin_once(node, timeout_sec=0.05)
            # Drain what already arrived before closing.
            for _ in range(100):
                before = writer.message_count
                rt.spin_once(node, timeout_sec=0.0)
                if writer.message_count == before:
                    break
    finally:
        meta = writer.close()
    print(
        f"wrote {args.output}: {meta.message_count} messages on {len(meta.topics)} topics",
        file=sys.stderr,
    )
    return 0


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="bag directory")
    parser.add_argument("topics", nargs="*", metavar="TOPIC", help="topics (default: all)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing bag at DIR")
    parser.add_argument(
        "--duration", type=positive_float, metavar="S", help="stop after S seconds"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress counts")
    parser.add_argument(
        "--include-ros-topics",
        action="store_true",
        help="when recording everything, also record /rosout and /parameter_events "
        "(left out by default, like 'ros2 bag record'; a topic named as TOPIC is recorded)",
    )
    parser.add_argument(
        "--contract",
        action="store_true",
        help="subscribe to the contract topics at once (contract types and QoS), before "
        "their publishers appear",
    )


COMMAND = Command(
    name="record",
    help="record live topics into a rosbag2 MCAP bag",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
