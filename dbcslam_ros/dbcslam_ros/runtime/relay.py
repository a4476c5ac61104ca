"""Raw topic relay node: republish CDR bytes of input topics on output topics, unchanged.

``python -m dbcslam_ros.runtime.relay --ros-args -p routes:="['std_msgs/msg/String|/a|/b']"``

Parameter ``routes`` is a list of ``TYPE|INPUT|OUTPUT``; parameter ``qos`` (a profile name,
default ``default``) is used on both sides. The relay never decodes the payload, so it is also
a check that raw subscriptions and raw publishing round-trip bytes exactly.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any

from dbcslam_ros import runtime as rt
from dbcslam_ros.errors import UsageError

__all__ = ["main"]


def _forward(pub: Any) -> Callable[[bytes], None]:
    def cb(data: bytes) -> None:
        pub.publish(data)

    return cb


def main(args: Sequence[str] | None = None) -> int:
    """Run the relay until SIGINT/SIGTERM; returns the exit code."""
    rt.init(list(args) if args is not None else sys.argv)
    node = rt.Node("relay")
    try:
        routes = list(node.declare_parameter("routes", [""]).value)
        qos = rt.qos_profile(str(node.declare_parameter("qos", "default").value))
        for route in filter(None, routes):
            parts = str(route).split("|")
            if len(parts) != 3:
                msg = f"bad route {route!r}: expected TYPE|INPUT|OUTPUT"
                raise UsageError(msg)
            typ, src, dst = parts
            pub = rt.create_raw_publisher(node, typ, dst, qos)
            rt.create_raw_subscription(node, typ, src, _forward(pub), qos)
        node.get_logger().info(f"relaying {len(routes)} route(s)")
        rt.spin_node(node)
    finally:
        node.destroy_node()
        rt.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
