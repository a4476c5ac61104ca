"""Node runtime of dbcslam_ros: node code is written once against this rclpy-shaped API.

Backends
--------
- ``rclpy``: chosen when ``import rclpy`` works (a ROS 2 Jazzy install). ``Node``, ``spin``,
  QoS, parameters, clock and message classes are rclpy's own objects.
- ``dds``: otherwise. Nodes run directly on Cyclone DDS (PyPI ``cyclonedds``) with the wire
  conventions of rmw_cyclonedds_cpp (``rt/<topic>``, ``pkg::msg::dds_::Type_``, XCDR1), so
  they talk to real ROS 2 nodes on the same domain. Message classes are generated at runtime
  from the ROS 2 Jazzy definitions in rosbags' typestore.

``DBCSLAM_RUNTIME=rclpy|dds`` forces a backend (``rclpy`` forced but missing is an error).

Network (``dds`` backend): loopback only by default (interface ``lo``, no multicast, peer
127.0.0.1, domain ``ROS_DOMAIN_ID``). To leave loopback set ``DBCSLAM_DDS_INTERFACE=<iface>``
(multicast discovery on that interface, optional ``DBCSLAM_DDS_PEERS=a,b``) or
``DBCSLAM_DDS_RESPECT_URI=1`` to use your own ``CYCLONEDDS_URI``. See
:mod:`dbcslam_ros.runtime.dds_config`.

Typical node::

    from dbcslam_ros import runtime as rt

    def main(args=None):
        rt.init(args)
        node = rt.Node("talker")
        String = rt.message_class("std_msgs/msg/String")
        pub = node.create_publisher(String, "/chatter", rt.qos_profile("default"))
        node.create_timer(0.1, lambda: pub.publish(String(data="hi")))
        try:
            rt.spin(node)
        except (KeyboardInterrupt, rt.ExternalShutdownException):
            pass
        finally:
            node.destroy_node()
            rt.try_shutdown()

Raw access (bag recorder/player): :func:`create_raw_subscription` delivers CDR bytes
(4-byte encapsulation header + payload, as ``typestore.serialize_cdr`` produces), and
:func:`create_raw_publisher` returns a publisher whose ``publish`` takes such bytes. Graph:
:func:`get_topic_names_and_types`, :func:`get_publishers_info` (offered QoS as
:class:`QoSProfile`). Codec: :func:`encode`, :func:`decode`, :func:`to_rosbags`,
:func:`from_rosbags`.
"""

from __future__ import annotations

import importlib
import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from dbcslam_ros.errors import RuntimeBackendError
from dbcslam_ros.runtime.qos import PROFILES, QoSProfile, named_profile
from dbcslam_ros.runtime.ros_args import remove_ros_args
from dbcslam_ros.runtime.typestore import get_typestore, normalize_type_name, register_msgdefs

__all__ = [
    "BACKEND",
    "PROFILES",
    "Duration",
    "EndpointInfo",
    "ExternalShutdownException",
    "Node",
    "Parameter",
    "ParameterDescriptor",
    "QoSProfile",
    "Time",
    "adapted_subscription_qos",
    "create_raw_publisher",
    "create_raw_subscription",
    "decode",
    "encode",
    "from_rosbags",
    "get_logger",
    "get_publishers_info",
    "get_topic_names_and_types",
    "init",
    "make_qos",
    "message_class",
    "neutral_qos",
    "normalize_type_name",
    "ok",
    "qos_profile",
    "register_msgdefs",
    "remove_ros_args",
    "select_backend",
    "shutdown",
    "spin",
    "spin_once",
    "spin_until",
    "to_rosbags",
    "try_shutdown",
    "type_name_of",
]


def select_backend() -> str:
    """Backend name from ``DBCSLAM_RUNTIME`` or, when unset, ``rclpy`` if importable else
    ``dds``.

    Raises:
        RuntimeBackendError: unknown value, or ``rclpy`` forced but not importable.
    """
    choice = os.environ.get("DBCSLAM_RUNTIME", "").strip().lower()
    if choice not in ("", "rclpy", "dds"):
        msg = f"bad DBCSLAM_RUNTIME={choice!r}: expected 'rclpy' or 'dds' (or unset for auto)"
        raise RuntimeBackendError(msg)
    if choice == "dds":
        return "dds"
    try:
        importlib.import_module("rclpy")
    except ImportError as err:
        if choice == "rclpy":
            msg = (
                "DBCSLAM_RUNTIME=rclpy but rclpy cannot be imported "
                f"({err}); source a ROS 2 Jazzy setup or use DBCSLAM_RUNTIME=dds"
            )
            raise RuntimeBackendError(msg) from err
        return "dds"
    return "rclpy"


BACKEND: str = select_backend()

if TYPE_CHECKING:
    from dbcslam_ros.runtime.dds_backend import (
        Duration,
        EndpointInfo,
        ExternalShutdownException,
        Node,
        Parameter,
        ParameterDescriptor,
        Time,
        get_logger,
        init,
        ok,
        shutdown,
        spin,
        spin_once,
        try_shutdown,
    )
else:
    _b = importlib.import_module(
        "dbcslam_ros.runtime.dds_backend"
        if BACKEND == "dds"
        else "dbcslam_ros.runtime.rclpy_backend"
    )
    Duration = _b.Duration
    EndpointInfo = _b.EndpointInfo
    ExternalShutdownException = _b.ExternalShutdownException
    Node = _b.Node
    Parameter = _b.Parameter
    ParameterDescriptor = _b.ParameterDescriptor
    Time = _b.Time
    get_logger = _b.get_logger
    init = _b.init
    ok = _b.ok
    shutdown = _b.shutdown
    spin = _b.spin
    spin_once = _b.spin_once
    try_shutdown = _b.try_shutdown


def _backend_module() -> Any:
    if BACKEND == "dds":
        from dbcslam_ros.runtime import dds_messages

        return dds_messages
    from dbcslam_ros.runtime import rclpy_backend

    return rclpy_backend


# ------------------------------------------------------------------------------------- QoS


def qos_profile(name: str, depth: int | None = None) -> Any:
    """Backend QoS object of a named profile: ``sensor_data`` (best effort, keep last 5),
    ``default`` (reliable, keep last 10), ``latched`` (reliable, transient local, depth 1),
    ``clock``; ``depth`` overrides the history depth.

    Raises:
        UsageError: unknown name.
    """
    return _native(named_profile(name, depth))


def make_qos(
    reliability: str = "reliable",
    durability: str = "volatile",
    history: str = "keep_last",
    depth: int = 10,
) -> Any:
    """Backend QoS object from explicit policies (see :class:`QoSProfile`)."""
    return _native(QoSProfile(reliability, durability, history, depth))


def _native(qos: QoSProfile) -> Any:
    if BACKEND == "dds":
        return qos
    from dbcslam_ros.runtime import rclpy_backend

    return rclpy_backend.native_qos(qos)


def neutral_qos(qos: Any) -> QoSProfile:
    """:class:`QoSProfile` of a backend QoS object (identity on the ``dds`` backend)."""
    if isinstance(qos, QoSProfile):
        return qos
    from dbcslam_ros.runtime import rclpy_backend

    return rclpy_backend.neutral_qos(qos)


# ---------------------------------------------------------------------------------- messages


def message_class(type_name: str) -> Any:
    """Message class of ``pkg/msg/Type`` (generated on ``dds``, imported on ``rclpy``).

    Raises:
        MessageTypeError: unknown type.
    """
    return _backend_module().message_class(type_name)


def type_name_of(msg_or_cls: Any) -> str:
    """``pkg/msg/Type`` of a message object or class."""
    return str(_backend_module().type_name_of(msg_or_cls))


def encode(msg: Any) -> bytes:
    """CDR bytes (4-byte header + payload, little endian) of a message object."""
    return bytes(_backend_module().encode(msg))


def decode(data: bytes | bytearray | memoryview, cls_or_name: Any) -> Any:
    """Message object from CDR bytes; ``cls_or_name`` is a class or ``pkg/msg/Type``."""
    return _backend_module().decode(bytes(data), cls_or_name)


def to_rosbags(msg: Any) -> Any:
    """The rosbags (typestore) message object equal to ``msg``."""
    name = type_name_of(msg)
    return get_typestore().deserialize_cdr(encode(msg), name)


def from_rosbags(obj: Any, type_name: str | None = None) -> Any:
    """Runtime message object equal to a rosbags message object (type from ``__msgtype__``)."""
    name = normalize_type_name(type_name or obj.__msgtype__)
    return decode(get_typestore().serialize_cdr(obj, name), name)


# --------------------------------------------------------------------------- raw and graph


def create_raw_subscription(
    node: Any, type_name: str, topic: str, callback: Callable[[bytes], None], qos: Any
) -> Any:
    """Subscribe to ``topic`` of type ``pkg/msg/Type``; ``callback`` gets CDR bytes."""
    if BACKEND == "dds":
        return node.create_subscription(
            type_name, topic, callback, _native(neutral_qos(qos)), raw=True
        )
    return node.create_subscription(message_class(type_name), topic, callback, qos, raw=True)


def create_raw_publisher(node: Any, type_name: str, topic: str, qos: Any) -> Any:
    """Publisher of ``topic`` (type ``pkg/msg/Type``) whose ``publish`` accepts CDR bytes."""
    if BACKEND == "dds":
        return node.create_publisher(type_name, topic, _native(neutral_qos(qos)))
    return node.create_publisher(message_class(type_name), topic, qos)


def get_topic_names_and_types(node: Any) -> list[tuple[str, list[str]]]:
    """``[(topic, [pkg/msg/Type, ...]), ...]`` of all topics seen on the domain."""
    return [(str(n), list(t)) for n, t in node.get_topic_names_and_types()]


def get_publishers_info(node: Any, topic: str) -> list[Any]:
    """Discovered publishers of ``topic`` as :class:`EndpointInfo` with neutral QoS."""
    infos = node.get_publishers_info_by_topic(topic)
    if BACKEND == "dds":
        return list(infos)
    return [
        EndpointInfo(
            node_name=i.node_name,
            node_namespace=i.node_namespace,
            topic_type=i.topic_type,
            endpoint_type=str(getattr(i.endpoint_type, "name", i.endpoint_type)),
            qos_profile=neutral_qos(i.qos_profile),
            endpoint_gid=bytes(i.endpoint_gid),
            topic_name=topic,
        )
        for i in infos
    ]


def adapted_subscription_qos(infos: list[Any], depth: int = 100) -> Any:
    """Subscription QoS that matches every given publisher and keeps what they offer (the
    rosbag2 recorder rule): reliable only if all offer reliable, transient local only if all
    offer transient local; keep last ``depth``. ``infos`` as from :func:`get_publishers_info`;
    with none, reliable + volatile."""
    profiles = [neutral_qos(i.qos_profile) for i in infos]
    reliable = all(p.reliability == "reliable" for p in profiles)
    latched = bool(profiles) and all(p.durability == "transient_local" for p in profiles)
    return make_qos(
        "reliable" if reliable else "best_effort",
        "transient_local" if latched else "volatile",
        "keep_last",
        depth,
    )


def spin_until(
    node: Any, predicate: Callable[[], bool], timeout_sec: float, step_sec: float = 0.05
) -> bool:
    """Spin ``node`` until ``predicate()`` is true or ``timeout_sec`` passed; returns the
    predicate's last value."""
    deadline = time.monotonic() + timeout_sec
    while not predicate():
        left = deadline - time.monotonic()
        if left <= 0:
            return bool(predicate())
        spin_once(node, timeout_sec=min(step_sec, left))
    return True
