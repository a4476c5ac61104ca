"""Small helpers on top of real rclpy (ROS 2 Jazzy) shared by the nodes and the CLI tools.

Nodes are plain ``rclpy.node.Node`` subclasses; this module only adds what rclpy spells
differently or leaves out:

- message classes by type name (:func:`message_class`, :func:`type_name_of`);
- named QoS profiles (:func:`qos_profile`, see :mod:`dbcslam_ros.qos`) and a neutral,
  plain-data view of rclpy QoS (:func:`neutral_qos`) for bag metadata;
- exact CDR (:func:`encode`): ``rclpy.serialization.serialize_message`` returns a buffer of the
  *estimated* size whose padding is uninitialised; :func:`encode` and :func:`canonical_cdr`
  re-serialise through the rosbags typestore, so bytes are what rosbags / rosbag2 write
  (zeroed padding, exact length) and bags are reproducible;
- raw (CDR bytes) endpoints by type name and graph queries for ``record / play / topic``;
- :func:`spin_until` for tools that spin until a condition holds.

Start ROS with :func:`init` (= :func:`dbcslam_ros.ros_context.init_ros`, network defaults).
"""

from __future__ import annotations

import functools
import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import rclpy
import rclpy.logging
import rclpy.utilities
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
from rclpy.qos import QoSProfile as RclpyQoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.time import Time
from rclpy.utilities import remove_ros_args

from dbcslam_ros.errors import MessageTypeError
from dbcslam_ros.qos import (
    PROFILES,
    QoSProfile,
    adapt_to_offers,
    named_profile,
    profile_from_policies,
)
from dbcslam_ros.ros_context import init_ros, spin_node
from dbcslam_ros.runtime.typestore import get_typestore, normalize_type_name, register_msgdefs

__all__ = [
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
    "canonical_cdr",
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
    "native_qos",
    "neutral_qos",
    "normalize_type_name",
    "ok",
    "qos_profile",
    "register_msgdefs",
    "remove_ros_args",
    "shutdown",
    "spin",
    "spin_node",
    "spin_once",
    "spin_until",
    "to_rosbags",
    "try_shutdown",
    "type_name_of",
]

init = init_ros
ok = rclpy.utilities.ok
shutdown = rclpy.shutdown
try_shutdown = rclpy.utilities.try_shutdown
spin = rclpy.spin
spin_once = rclpy.spin_once
get_logger = rclpy.logging.get_logger


@dataclass
class EndpointInfo:
    """Plain view of a discovered endpoint (QoS as the neutral :class:`QoSProfile`)."""

    node_name: str
    node_namespace: str
    topic_type: str
    endpoint_type: str
    qos_profile: QoSProfile
    endpoint_gid: bytes = b""
    topic_name: str = ""
    user_data: dict[str, str] = field(default_factory=dict)


# ------------------------------------------------------------------------------------- QoS


def qos_profile(name: str, depth: int | None = None) -> RclpyQoSProfile:
    """rclpy QoS of a named profile: ``sensor_data`` (best effort, keep last 5), ``default``
    (reliable, keep last 10), ``latched`` (reliable, transient local, depth 1), ``clock``;
    ``depth`` overrides the history depth.

    Raises:
        UsageError: unknown name.
    """
    return native_qos(named_profile(name, depth))


def make_qos(
    reliability: str = "reliable",
    durability: str = "volatile",
    history: str = "keep_last",
    depth: int = 10,
) -> RclpyQoSProfile:
    """rclpy QoS from explicit policies (see :class:`QoSProfile`)."""
    return native_qos(QoSProfile(reliability, durability, history, depth))


def native_qos(qos: QoSProfile) -> RclpyQoSProfile:
    """rclpy ``QoSProfile`` of a neutral profile."""
    return RclpyQoSProfile(
        reliability=ReliabilityPolicy.RELIABLE
        if qos.reliability == "reliable"
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
        history=HistoryPolicy.KEEP_ALL if qos.history == "keep_all" else HistoryPolicy.KEEP_LAST,
        depth=max(int(qos.depth), 1),
    )


def neutral_qos(qos: Any) -> QoSProfile:
    """Neutral profile of an rclpy ``QoSProfile`` (identity on a :class:`QoSProfile`)."""
    if isinstance(qos, QoSProfile):
        return qos
    return profile_from_policies(
        best_effort=qos.reliability == ReliabilityPolicy.BEST_EFFORT,
        transient_local=qos.durability == DurabilityPolicy.TRANSIENT_LOCAL,
        keep_all=qos.history == HistoryPolicy.KEEP_ALL,
        depth=int(qos.depth),
    )


# ---------------------------------------------------------------------------------- messages


@functools.lru_cache(maxsize=256)
def message_class(type_name: str) -> Any:
    """The rclpy message class of ``pkg/msg/Type`` (imported from ``pkg.msg``; cached: the
    converters ask for a class per message built).

    Raises:
        MessageTypeError: bad name or type not installed (not cached).
    """
    pkg, _, typ = normalize_type_name(type_name).split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), typ)
    except (ImportError, AttributeError) as err:
        msg = f"ROS message type {type_name!r} is not installed (import {pkg}.msg.{typ} failed)"
        raise MessageTypeError(msg) from err


def type_name_of(msg_or_cls: Any) -> str:
    """``pkg/msg/Type`` of an rclpy message object or class."""
    cls = msg_or_cls if isinstance(msg_or_cls, type) else type(msg_or_cls)
    pkg = cls.__module__.split(".")[0]
    return f"{pkg}/msg/{cls.__name__}"


def canonical_cdr(data: bytes | bytearray | memoryview, type_name: str) -> bytes:
    """The exact CDR bytes of a serialized message: parsed and re-serialised by the rosbags
    typestore (exact length, zeroed padding, little endian), whatever trailing bytes or
    padding garbage ``data`` carries.

    Raises:
        MessageTypeError: the bytes do not parse as ``type_name``.
    """
    import struct

    name = normalize_type_name(type_name)
    store = get_typestore()
    raw = memoryview(bytes(data))
    try:
        if len(raw) < 4 or bytes(raw[:2]) not in (b"\x00\x00", b"\x00\x01"):
            msg = f"not a CDR buffer (header {bytes(raw[:4])!r})"
            raise ValueError(msg)
        msgdef = store.get_msgdef(name)
        func = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
        obj, _pos = func(raw[4:], 0, msgdef.cls, store)
        return bytes(store.serialize_cdr(obj, name))
    except (KeyError, ValueError, struct.error, UnicodeDecodeError, IndexError) as err:
        msg = f"cannot read {len(raw)} CDR bytes as {name}: {err}"
        raise MessageTypeError(msg) from err


def encode(msg: Any) -> bytes:
    """Exact CDR bytes (4-byte header + payload, little endian) of an rclpy message."""
    return canonical_cdr(serialize_message(msg), type_name_of(msg))


def decode(data: bytes | bytearray | memoryview, cls_or_name: Any) -> Any:
    """rclpy message from CDR bytes; ``cls_or_name`` is a class or ``pkg/msg/Type``."""
    cls = message_class(cls_or_name) if isinstance(cls_or_name, str) else cls_or_name
    return deserialize_message(bytes(data), cls)


def to_rosbags(msg: Any) -> Any:
    """The rosbags (typestore) message object equal to ``msg``."""
    return get_typestore().deserialize_cdr(encode(msg), type_name_of(msg))


def from_rosbags(obj: Any, type_name: str | None = None) -> Any:
    """rclpy message object equal to a rosbags message object (type from ``__msgtype__``)."""
    name = normalize_type_name(type_name or obj.__msgtype__)
    return decode(bytes(get_typestore().serialize_cdr(obj, name)), name)


# --------------------------------------------------------------------------- raw and graph


def create_raw_subscription(
    node: Node, type_name: str, topic: str, callback: Callable[[bytes], None], qos: Any
) -> Any:
    """Subscribe to ``topic`` of type ``pkg/msg/Type``; ``callback`` gets the CDR bytes as
    received (use :func:`canonical_cdr` for bag-exact bytes)."""
    return node.create_subscription(message_class(type_name), topic, callback, qos, raw=True)


def create_raw_publisher(node: Node, type_name: str, topic: str, qos: Any) -> Any:
    """Publisher of ``topic`` (type ``pkg/msg/Type``) whose ``publish`` accepts CDR bytes."""
    return node.create_publisher(message_class(type_name), topic, qos)


def get_topic_names_and_types(node: Node) -> list[tuple[str, list[str]]]:
    """``[(topic, [pkg/msg/Type, ...]), ...]`` of all topics seen on the domain."""
    return [(str(n), list(t)) for n, t in node.get_topic_names_and_types()]


def get_publishers_info(node: Node, topic: str) -> list[EndpointInfo]:
    """Discovered publishers of ``topic`` with neutral QoS."""
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
        for i in node.get_publishers_info_by_topic(topic)
    ]


def adapted_subscription_qos(infos: list[Any], depth: int = 100) -> RclpyQoSProfile:
    """Subscription QoS that matches every given publisher and keeps what they offer (the
    rosbag2 recorder rule): reliable only if all offer reliable, transient local only if all
    offer transient local; keep last ``depth``. ``infos`` as from :func:`get_publishers_info`;
    with none, reliable + volatile."""
    return native_qos(adapt_to_offers([neutral_qos(i.qos_profile) for i in infos], depth))


def spin_until(
    node: Node, predicate: Callable[[], bool], timeout_sec: float, step_sec: float = 0.05
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
