"""The interface contract in one table: topic names, message types and QoS.

Mirrors the topic tables of the contract (``../shared/CONTRACT.md`` beside the repository,
documented in the README): every module that names a contract topic imports it from here, so
a name, a type or a QoS is written once. QoS is the name of a profile of
:data:`dbcslam_ros.qos.PROFILES`:

- ``sensor_data`` (best effort, volatile, keep last 5): the sensor inputs,
- ``latched`` (reliable, transient local, keep last 1): ``/scenario``,
- ``default`` (reliable, volatile, keep last 10): truth, estimates, diagnostics and any topic
  the contract does not name.

Topic names are absolute (REP-135 style, no namespace), as recorded bags carry them.
"""

from __future__ import annotations

from dataclasses import dataclass

from dbcslam_ros.qos import QoSProfile, named_profile

__all__ = [
    "CONTACT_MODES",
    "CONTRACT_TOPICS",
    "DIAGNOSTICS",
    "ESTIMATE_TOPICS",
    "FRICTION",
    "FRICTION_MAP",
    "INPUT_TOPICS",
    "JOINT_STATES",
    "MARKERS",
    "OBJECT_POSE",
    "OBJECT_WRENCH",
    "ODOMETRY",
    "OUTPUT_TOPICS",
    "POSE",
    "PUSHER_CONTACT",
    "PUSHER_WRENCH",
    "SCENARIO",
    "SENSOR_TOPICS",
    "TOPICS",
    "TRUTH_CONTACT_MODES",
    "TRUTH_FRICTION",
    "TRUTH_POSE",
    "TRUTH_TOPICS",
    "Topic",
    "contract_qos_profile",
    "message_type",
]

# Inputs (simulator, recorded or imported bags, a robot)
OBJECT_POSE = "/object/pose"
OBJECT_WRENCH = "/object/wrench"
JOINT_STATES = "/joint_states"
PUSHER_WRENCH = "/pusher/wrench"
SCENARIO = "/scenario"
TRUTH_POSE = "/truth/object/pose"
TRUTH_CONTACT_MODES = "/truth/contact_modes"
TRUTH_FRICTION = "/truth/friction"
# Outputs of the filter node, in publication order (``/dbcslam/pose`` first)
POSE = "/dbcslam/pose"
ODOMETRY = "/dbcslam/odometry"
CONTACT_MODES = "/dbcslam/contact_modes"
FRICTION = "/dbcslam/friction"
FRICTION_MAP = "/dbcslam/friction_map"
MARKERS = "/dbcslam/markers"
DIAGNOSTICS = "/diagnostics"
#: Added to the contract by the MIT push importer: the measured contact flag
#: (std_msgs/Float64MultiArray), not published by the simulator.
PUSHER_CONTACT = "/pusher/contact"


@dataclass(frozen=True)
class Topic:
    """One contract topic: absolute name, ROS 2 message type (``pkg/msg/Name``) and the name
    of its QoS profile (see the module docstring)."""

    name: str
    type: str
    qos: str


#: Every contract topic: inputs (subscription order of the filter node: the inputs of a step
#: before the pose that triggers it), truth, then the outputs in publication order.
TOPICS: dict[str, Topic] = {
    t.name: t
    for t in (
        Topic(SCENARIO, "std_msgs/msg/String", "latched"),
        Topic(OBJECT_WRENCH, "geometry_msgs/msg/WrenchStamped", "sensor_data"),
        Topic(JOINT_STATES, "sensor_msgs/msg/JointState", "sensor_data"),
        Topic(PUSHER_WRENCH, "geometry_msgs/msg/WrenchStamped", "sensor_data"),
        Topic(OBJECT_POSE, "geometry_msgs/msg/PoseStamped", "sensor_data"),
        Topic(TRUTH_POSE, "geometry_msgs/msg/PoseStamped", "default"),
        Topic(TRUTH_CONTACT_MODES, "std_msgs/msg/Float64MultiArray", "default"),
        Topic(TRUTH_FRICTION, "std_msgs/msg/Float64MultiArray", "default"),
        Topic(POSE, "geometry_msgs/msg/PoseWithCovarianceStamped", "default"),
        Topic(ODOMETRY, "nav_msgs/msg/Odometry", "default"),
        Topic(CONTACT_MODES, "std_msgs/msg/Float64MultiArray", "default"),
        Topic(FRICTION, "std_msgs/msg/Float64MultiArray", "default"),
        Topic(FRICTION_MAP, "nav_msgs/msg/OccupancyGrid", "default"),
        Topic(MARKERS, "visualization_msgs/msg/MarkerArray", "default"),
        Topic(DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", "default"),
    )
}
#: Name -> message type of every contract topic (``dbcslam record --contract``).
CONTRACT_TOPICS: dict[str, str] = {name: t.type for name, t in TOPICS.items()}
#: What the filter node subscribes to, in subscription order.
INPUT_TOPICS: tuple[str, ...] = (SCENARIO, OBJECT_WRENCH, JOINT_STATES, PUSHER_WRENCH, OBJECT_POSE)
#: Sensor inputs (QoS ``sensor_data``).
SENSOR_TOPICS: frozenset[str] = frozenset(n for n, t in TOPICS.items() if t.qos == "sensor_data")
#: Ground truth (simulation only).
TRUTH_TOPICS: tuple[str, ...] = (TRUTH_POSE, TRUTH_CONTACT_MODES, TRUTH_FRICTION)
#: Everything the filter node publishes, in publication order.
OUTPUT_TOPICS: tuple[str, ...] = (
    POSE,
    ODOMETRY,
    CONTACT_MODES,
    FRICTION,
    FRICTION_MAP,
    MARKERS,
    DIAGNOSTICS,
)
#: The estimate arrays scored against the truth.
ESTIMATE_TOPICS: tuple[str, ...] = (POSE, CONTACT_MODES, FRICTION, FRICTION_MAP)


def message_type(topic: str) -> str:
    """Message type of a contract topic (``pkg/msg/Name``).

    Raises:
        KeyError: `topic` is not a contract topic (the message names the known ones).
    """
    try:
        return TOPICS[topic].type
    except KeyError as err:
        msg = f"{topic!r} is not a contract topic: expected one of {sorted(TOPICS)}"
        raise KeyError(msg) from err


def contract_qos_profile(topic: str) -> QoSProfile:
    """QoS of `topic` as the contract fixes it; ``default`` for topics it does not name."""
    known = TOPICS.get(topic)
    return named_profile(known.qos if known else "default")
