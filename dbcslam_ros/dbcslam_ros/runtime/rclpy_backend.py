"""The ``rclpy`` backend: thin aliases of real rclpy (ROS 2 Jazzy) objects.

``Node``, ``spin``, QoS objects, parameters, clocks and message classes are rclpy's own; this
module only adds what rclpy spells differently: message classes by type name, named QoS
profiles from :mod:`dbcslam_ros.runtime.qos`, raw (CDR bytes) endpoints by type name, and a
backend-neutral view of discovered publishers.

Not importable without rclpy (the runtime selects it only when ``import rclpy`` works).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any

import rclpy
import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
from rclpy.qos import QoSProfile as RclpyQoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.time import Time

from dbcslam_ros.errors import MessageTypeError
from dbcslam_ros.network import apply_loopback_defaults
from dbcslam_ros.runtime.qos import QoSProfile
from dbcslam_ros.runtime.typestore import normalize_type_name

__all__ = [
    "Duration",
    "EndpointInfo",
    "ExternalShutdownException",
    "Node",
    "Parameter",
    "ParameterDescriptor",
    "Time",
    "decode",
    "encode",
    "get_logger",
    "init",
    "message_class",
    "native_qos",
    "neutral_qos",
    "ok",
    "shutdown",
    "spin",
    "spin_once",
    "try_shutdown",
    "type_name_of",
]


def init(args: Any = None) -> None:
    """rclpy.init after the loopback-only network defaults (:mod:`dbcslam_ros.network`)."""
    apply_loopback_defaults()
    rclpy.init(args=args)


ok = rclpy.ok
shutdown = rclpy.shutdown
try_shutdown = rclpy.try_shutdown
spin = rclpy.spin
spin_once = rclpy.spin_once
get_logger = rclpy.logging.get_logger


@dataclass
class EndpointInfo:
    """Backend-neutral view of a discovered endpoint (QoS as :class:`QoSProfile`)."""

    node_name: str
    node_namespace: str
    topic_type: str
    endpoint_type: str
    qos_profile: QoSProfile
    endpoint_gid: bytes = b""
    topic_name: str = ""
    user_data: dict[str, str] = field(default_factory=dict)


def message_class(name: str) -> Any:
    """The rclpy message class of ``pkg/msg/Type`` (imported from ``pkg.msg``)."""
    pkg, _, typ = normalize_type_name(name).split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), typ)
    except (ImportError, AttributeError) as err:
        msg = f"ROS message type {name!r} is not installed (import {pkg}.msg.{typ} failed)"
        raise MessageTypeError(msg) from err


def type_name_of(msg_or_cls: Any) -> str:
    """``pkg/msg/Type`` of an rclpy message object or class."""
    cls = msg_or_cls if isinstance(msg_or_cls, type) else type(msg_or_cls)
    pkg = cls.__module__.split(".")[0]
    return f"{pkg}/msg/{cls.__name__}"


def encode(msg: Any) -> bytes:
    """CDR bytes of an rclpy message (rmw serialization)."""
    return bytes(serialize_message(msg))


def decode(data: bytes, cls_or_name: Any) -> Any:
    """rclpy message from CDR bytes."""
    cls = message_class(cls_or_name) if isinstance(cls_or_name, str) else cls_or_name
    return deserialize_message(bytes(data), cls)


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
    """Neutral profile of an rclpy ``QoSProfile``."""
    keep_all = qos.history == HistoryPolicy.KEEP_ALL
    return QoSProfile(
        "best_effort" if qos.reliability == ReliabilityPolicy.BEST_EFFORT else "reliable",
        "transient_local" if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL else "volatile",
        "keep_all" if keep_all else "keep_last",
        0 if keep_all else max(int(qos.depth), 1),
    )
