"""ROS 2 adapters of DBC-SLAM on rclpy, one concern per folder:

- ``node/``: the filter node, its session (per-run filter state) and demo nodes;
- ``bag/``: rosbag2 bags (MCAP + metadata.yaml) read and written without ROS;
- ``cli/``: the ``dbcslam`` command line, one module per subcommand;
- ``offline/``: replay, evaluate, report, plotting, demo, discrepancy report;
- ``importers/``: outside data into bags of the contract (MIT push);
- ``runtime/``: the small rclpy layer (QoS, message classes, raw CDR, typestore);
- modules: ``contract`` (topic names, types, QoS), ``qos`` (the one QoS form), ``convert``
  (messages <-> core values), ``network`` / ``ros_context`` (loopback DDS set-up), ``errors``.

Heavy submodules are imported on use, so `import dbcslam_ros` stays cheap and does not start
any middleware. The research scripts are a separate package (``dbcslam_research``).
"""

from __future__ import annotations

from dbcslam_ros.errors import (
    BagError,
    DbcSlamRosError,
    MessageTypeError,
    ParameterError,
    UsageError,
)

__all__ = [
    "BagError",
    "DbcSlamRosError",
    "MessageTypeError",
    "ParameterError",
    "UsageError",
]
