"""ROS 2 adapters of DBC-SLAM on rclpy: filter node, bags, CLI, rclpy helpers.

Heavy submodules (runtime, bag, cli, filter_node) are imported on use, so `import dbcslam_ros`
stays cheap and does not start any middleware.
"""

from __future__ import annotations

from dbcslam_ros.errors import (
    BagError,
    DbcSlamRosError,
    MessageTypeError,
    ParameterError,
    RuntimeBackendError,
    UsageError,
)

__all__ = [
    "BagError",
    "DbcSlamRosError",
    "MessageTypeError",
    "ParameterError",
    "RuntimeBackendError",
    "UsageError",
]
