"""Talker/listener demo nodes over the node runtime (the ``make demo`` placeholder).

- ``talker``: publishes std_msgs/String ``"hello N"`` on ``chatter`` (reliable, depth 10) at
  parameter ``rate_hz`` (default 10 Hz) and, once at start, a latched (reliable,
  transient-local, depth 1) std_msgs/String on ``scenario_topic`` (default ``/demo/scenario``)
  holding parameter ``scenario`` (YAML text). Stops after ``count`` messages if ``count`` > 0.
- ``listener``: logs every message of both topics; exits once it has ``count`` chatter messages
  and the scenario, if ``count`` > 0.

Run: ``python -m dbcslam_ros.node.demo_nodes talker --ros-args -p rate_hz:=20`` (or the ``talker``
/ ``listener`` entry points). Both exit with 0 on SIGINT/SIGTERM.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy._rclpy_pybind11 import RCLError
from rclpy.node import Node

from dbcslam_ros import runtime as rt

__all__ = ["Listener", "Talker", "listener_main", "main", "talker_main"]

DEFAULT_SCENARIO = "scenario: edge\ndt: 0.01\n"


class Talker(Node):
    """Publishes a counter string at a rate plus one latched scenario string."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("talker", **kwargs)
        node = self
        desc = ParameterDescriptor
        self.rate_hz = float(
            node.declare_parameter(
                "rate_hz", 10.0, desc(description="publish rate of chatter, Hz")
            ).value
        )
        self.count = int(
            node.declare_parameter(
                "count", 0, desc(description="stop after this many messages (0: never)")
            ).value
        )
        scen_topic = str(
            node.declare_parameter(
                "scenario_topic", "/demo/scenario", desc(description="latched topic name")
            ).value
        )
        text = str(
            node.declare_parameter(
                "scenario", DEFAULT_SCENARIO, desc(description="latched YAML text")
            ).value
        )
        self.string_cls = rt.message_class("std_msgs/msg/String")
        self.pub = node.create_publisher(self.string_cls, "chatter", rt.qos_profile("default"))
        self.latched = node.create_publisher(
            self.string_cls, scen_topic, rt.qos_profile("latched")
        )
        self.latched.publish(self.string_cls(data=text))
        self.sent = 0
        self.timer = node.create_timer(1.0 / self.rate_hz, self.tick)

    def tick(self) -> None:
        """Publish the next counter message."""
        if self.count and self.sent >= self.count:
            return
        self.sent += 1
        self.pub.publish(self.string_cls(data=f"hello {self.sent}"))
        self.get_logger().info(f"sent 'hello {self.sent}'", throttle_duration_sec=1.0)  # type: ignore[no-untyped-call]

    @property
    def done(self) -> bool:
        """Whether ``count`` messages were sent (never when ``count`` is 0)."""
        return bool(self.count) and self.sent >= self.count


class Listener(Node):
    """Logs the chatter and latched scenario strings it receives."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("listener", **kwargs)
        node = self
        self.count = int(
            node.declare_parameter(
                "count",
                0,
                ParameterDescriptor(description="exit after this many messages (0: never)"),
            ).value
        )
        scen_topic = str(node.declare_parameter("scenario_topic", "/demo/scenario").value)
        cls = rt.message_class("std_msgs/msg/String")
        self.received: list[str] = []
        self.scenario: str | None = None
        node.create_subscription(cls, "chatter", self.on_chatter, rt.qos_profile("default"))
        node.create_subscription(cls, scen_topic, self.on_scenario, rt.qos_profile("latched"))
        self.get_logger().info(f"listening on chatter and {scen_topic}")  # type: ignore[no-untyped-call]

    def on_chatter(self, msg: Any) -> None:
        """Record and log one chatter message."""
        self.received.append(str(msg.data))
        self.get_logger().info(f"I heard: '{msg.data}'")  # type: ignore[no-untyped-call]

    def on_scenario(self, msg: Any) -> None:
        """Record and log the latched scenario."""
        self.scenario = str(msg.data)
        self.get_logger().info(f"scenario: {msg.data!r}")  # type: ignore[no-untyped-call]

    @property
    def done(self) -> bool:
        """Whether ``count`` messages and the scenario arrived (never when ``count`` is 0)."""
        return bool(self.count) and len(self.received) >= self.count and self.scenario is not None


def _run(kind: str, args: Sequence[str] | None) -> int:
    rt.init(list(args) if args is not None else sys.argv)
    node: Talker | Listener = Talker() if kind == "talker" else Listener()
    app = node
    try:
        while not app.done:
            rt.spin_once(node, timeout_sec=0.1)
        node.get_logger().info("done")  # type: ignore[no-untyped-call]
    except (KeyboardInterrupt, rt.ExternalShutdownException):
        pass
    except RCLError:
        if rt.ok():  # not the signal-vs-wait-set race of a shutdown
            raise
    finally:
        node.destroy_node()  # type: ignore[no-untyped-call]
        rt.try_shutdown()
    return 0


def talker_main(args: Sequence[str] | None = None) -> int:
    """Entry point ``talker``."""
    return _run("talker", args)


def listener_main(args: Sequence[str] | None = None) -> int:
    """Entry point ``listener``."""
    return _run("listener", args)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m dbcslam_ros.node.demo_nodes {talker|listener} [--ros-args ...]``."""
    argv = list(sys.argv if argv is None else argv)
    plain = rt.remove_ros_args(argv)
    if len(plain) < 2 or plain[1] not in ("talker", "listener"):
        sys.stderr.write(
            "usage: python -m dbcslam_ros.node.demo_nodes {talker|listener} [--ros-args ...]\n"
        )
        return 2
    return talker_main(argv) if plain[1] == "talker" else listener_main(argv)


if __name__ == "__main__":
    sys.exit(main())
