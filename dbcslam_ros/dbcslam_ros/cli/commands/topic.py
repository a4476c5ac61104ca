"""``dbcslam topic list | echo | hz``: inspect live topics (like ``ros2 topic``)."""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import textwrap
import time
from collections import deque
from typing import Any

from dbcslam_ros.cli._common import (
    add_qos_arguments,
    native_qos,
    node_session,
    positive_float,
    qos_from_arguments,
    unique_node_name,
)
from dbcslam_ros.cli.registry import Command
from dbcslam_ros.errors import UsageError

__all__ = ["COMMAND"]

_LIST_EXAMPLES = """\
examples:
  dbcslam topic list
  dbcslam topic list -t                 # with types: /object/pose [geometry_msgs/msg/PoseStamped]
  dbcslam topic list --spin-time 3      # wait longer for discovery
"""
_ECHO_EXAMPLES = """\
examples:
  dbcslam topic echo /object/pose
  dbcslam topic echo /scenario --once                       # the latched scenario YAML
  dbcslam topic echo /dbcslam/pose --field pose.pose.position
  dbcslam topic echo /object/pose --qos sensor_data --timeout 5
"""
_HZ_EXAMPLES = """\
examples:
  dbcslam topic hz /object/pose
  dbcslam topic hz /dbcslam/pose --window 50
"""


SETTLE_S = 0.5
"""Discovery has settled when the topic set did not change for this long (s)."""


def _discover(rt: Any, node: Any, stop: Any, spin_time: float) -> list[tuple[str, list[str]]]:
    """Topics after at least ``spin_time`` s of discovery and until the set has been stable
    for :data:`SETTLE_S` (at most ``spin_time + 2`` s): Fast DDS discovery of a peer can take
    about a second, and topics trickle in one endpoint at a time."""
    start = time.monotonic()
    last: list[tuple[str, list[str]]] = []
    changed = start
    while not stop.stopped:
        now = time.monotonic()
        current = sorted(rt.get_topic_names_and_types(node))
        if current != last:
            last, changed = current, now
        if now - start >= spin_time and now - changed >= SETTLE_S:
            break
        if now - start >= spin_time + 2.0:
            break
        rt.spin_once(node, timeout_sec=0.05)
    return last


def _run_list(args: argparse.Namespace) -> int:
    with node_session(unique_node_name("dbcslam_topic_list")) as (rt, node, stop):
        topics = _discover(rt, node, stop, args.spin_time)
    for name, types in sorted(topics):
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def _wait_for_topic(
    rt: Any, node: Any, stop: Any, topic: str, *, type_name: str | None, timeout: float | None
) -> tuple[str, list[Any]] | None:
    """Type of ``topic`` and its publishers' offered QoS, once a publisher is seen."""
    deadline = None if timeout is None else time.monotonic() + timeout
    print(f"waiting for a publisher of {topic} ...", file=sys.stderr, flush=True)
    while not stop.stopped:
        infos = rt.get_publishers_info(node, topic)
        types = sorted({i.topic_type for i in infos})
        if types:
            chosen = type_name or types[0]
            if len(types) > 1 and type_name is None:
                print(
                    f"warning: {topic} has several types {types}; using {chosen}", file=sys.stderr
                )
            offered = [i.qos_profile for i in infos if i.topic_type == chosen]
            return chosen, offered or [i.qos_profile for i in infos]
        if deadline is not None and time.monotonic() >= deadline:
            return None
        rt.spin_once(node, timeout_sec=0.05)
    return None


def _run_echo(args: argparse.Namespace) -> int:
    from dbcslam_ros.bag.types import deserialize
    from dbcslam_ros.cli._format import message_to_yaml

    if args.type is not None:
        from dbcslam_ros.runtime.typestore import normalize_type_name

        args.type = normalize_type_name(args.type)
    count = 0
    with node_session(unique_node_name("dbcslam_topic_echo")) as (rt, node, stop):
        found = _wait_for_topic(
            rt, node, stop, args.topic, type_name=args.type, timeout=args.timeout
        )
        if found is None:
            if stop.stopped:
                return 0
            msg = f"no publisher of {args.topic} appeared within {args.timeout:g} s"
            raise UsageError(msg)
        type_name, offered = found
        qos = qos_from_arguments(args, offered)
        pending: deque[bytes] = deque()

        def on_message(data: bytes) -> None:  # a real function: rclpy inspects its signature
            pending.append(data)

        rt.create_raw_subscription(node, type_name, args.topic, on_message, native_qos(rt, qos))
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        while not stop.stopped:
            rt.spin_once(node, timeout_sec=0.05)
            while pending:
                data = pending.popleft()
                text = message_to_yaml(deserialize(data, type_name), args.field)
                sys.stdout.write(text + "---\n")
                sys.stdout.flush()
                count += 1
                if args.once:
                    return 0
            if count == 0 and deadline is not None and time.monotonic() >= deadline:
                msg = f"no message on {args.topic} within {args.timeout:g} s"
                raise UsageError(msg)
    return 0


def _run_hz(args: argparse.Namespace) -> int:
    times: deque[int] = deque(maxlen=args.window + 1)
    with node_session(unique_node_name("dbcslam_topic_hz")) as (rt, node, stop):
        found = _wait_for_topic(rt, node, stop, args.topic, type_name=None, timeout=args.timeout)
        if found is None:
            if stop.stopped:
                return 0
            msg = f"no publisher of {args.topic} appeared within {args.timeout:g} s"
            raise UsageError(msg)
        type_name, offered = found
        qos = qos_from_arguments(args, offered)

        def on_message(_data: bytes) -> None:
            times.append(time.monotonic_ns())

        rt.create_raw_subscription(node, type_name, args.topic, on_message, native_qos(rt, qos))
        next_report = time.monotonic() + 1.0
        seen = 0
        while not stop.stopped:
            rt.spin_once(node, timeout_sec=0.05)
            if time.monotonic() < next_report:
                continue
            next_report += 1.0
            if len(times) < 2 or times[-1] == seen:
                print("no new messages", flush=True)
                continue
            seen = times[-1]
            stamps = list(times)
            gaps = [(b - a) / 1e9 for a, b in itertools.pairwise(stamps)]
            mean = sum(gaps) / len(gaps)
            std = math.sqrt(sum((g - mean) ** 2 for g in gaps) / len(gaps))
            print(
                f"average rate: {1.0 / mean:.3f}\n"
                f"\tmin: {min(gaps):.6f}s max: {max(gaps):.6f}s std dev: {std:.5f}s "
                f"window: {len(gaps)}",
                flush=True,
            )
    return 0


def _configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="topic_command", metavar="SUBCOMMAND", required=True)
    fmt = argparse.RawDescriptionHelpFormatter

    p_list = sub.add_parser(
        "list",
        help="print the topics seen on the domain",
        description=textwrap.fill(
            "Print the topics seen on the DDS domain (ROS_DOMAIN_ID), one per line, after "
            "waiting at least --spin-time seconds for discovery and until the list has not "
            "changed for 0.5 s (at most --spin-time + 2 s)."
        ),
        epilog=_LIST_EXAMPLES,
        formatter_class=fmt,
    )
    p_list.add_argument("-t", "--show-types", action="store_true", help="also print types")
    p_list.add_argument(
        "--spin-time",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="minimum seconds to wait for discovery (default 2.0)",
    )
    p_list.set_defaults(_topic_run=_run_list)

    p_echo = sub.add_parser(
        "echo",
        help="print the messages of a topic as YAML",
        description=textwrap.fill(
            "Print each message of TOPIC as a YAML document, documents separated by '---' "
            "(like 'ros2 topic echo'). Waits for a publisher; the type is discovered unless "
            "given. The subscription QoS matches what the publishers offer unless --qos* "
            "say otherwise (so latched topics such as /scenario are received late)."
        ),
        epilog=_ECHO_EXAMPLES,
        formatter_class=fmt,
    )
    p_echo.add_argument("topic", metavar="TOPIC", help="topic name, e.g. /object/pose")
    p_echo.add_argument(
        "type", metavar="TYPE", nargs="?", help="message type (default: discovered)"
    )
    p_echo.add_argument("--once", action="store_true", help="exit after the first message")
    p_echo.add_argument(
        "--field", metavar="A.B", help="print only this field (dotted path; list index ok)"
    )
    p_echo.add_argument(
        "--timeout",
        type=positive_float,
        metavar="S",
        help="give up (exit 2) if no publisher, or no message, within S seconds",
    )
    add_qos_arguments(p_echo)
    p_echo.set_defaults(_topic_run=_run_echo)

    p_hz = sub.add_parser(
        "hz",
        help="print the receive rate of a topic",
        description=textwrap.fill(
            "Print, every second, the average receive rate of TOPIC over the last --window "
            "messages, with min/max/std of the gaps (like 'ros2 topic hz')."
        ),
        epilog=_HZ_EXAMPLES,
        formatter_class=fmt,
    )
    p_hz.add_argument("topic", metavar="TOPIC", help="topic name")
    p_hz.add_argument(
        "--window",
        type=int,
        default=10000,
        metavar="N",
        help="number of most recent gaps averaged (default 10000)",
    )
    p_hz.add_argument(
        "--timeout", type=positive_float, metavar="S", help="give up if no publisher in S s"
    )
    add_qos_arguments(p_hz)
    p_hz.set_defaults(_topic_run=_run_hz)


def _run(args: argparse.Namespace) -> int:
    if getattr(args, "window", 1) < 1:
        msg = f"--window {args.window}: expected >= 1"
        raise UsageError(msg)
    return int(args._topic_run(args))


COMMAND = Command(
    name="topic",
    help="inspect live topics (list, echo, hz)",
    description=(
        "Inspect live topics on the DDS domain: 'list' the topics, 'echo' a topic's "
        "messages as YAML, or measure its rate with 'hz'."
    ),
    examples="  dbcslam topic list -t\n  dbcslam topic echo /scenario --once\n"
    "  dbcslam topic hz /object/pose",
    configure=_configure,
    run=_run,
)
