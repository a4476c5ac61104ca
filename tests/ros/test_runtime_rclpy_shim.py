"""The rclpy backend module against a minimal stand-in of rclpy's API (rclpy is not
installable here): checks that it imports what Jazzy's rclpy provides and converts QoS and
type names correctly. Real rclpy runs are out of reach of this test suite."""

from __future__ import annotations

import enum
import importlib
import sys
import types
from typing import Any

import pytest

from dbcslam_ros.runtime.qos import PROFILES


def _fake_rclpy(monkeypatch: pytest.MonkeyPatch) -> None:
    def mod(name: str, **attrs: Any) -> None:
        m = types.ModuleType(name)
        for k, v in attrs.items():
            setattr(m, k, v)
        monkeypatch.setitem(sys.modules, name, m)
        parent, _, child = name.rpartition(".")
        if parent:
            setattr(sys.modules[parent], child, m)  # as the import system binds submodules

    reliability = enum.IntEnum("ReliabilityPolicy", "SYSTEM_DEFAULT RELIABLE BEST_EFFORT")
    durability = enum.IntEnum("DurabilityPolicy", "SYSTEM_DEFAULT TRANSIENT_LOCAL VOLATILE")
    history = enum.IntEnum("HistoryPolicy", "SYSTEM_DEFAULT KEEP_LAST KEEP_ALL")

    class QoSProfile:
        def __init__(self, **kw: Any) -> None:
            self.__dict__.update(kw)

    def noop(*_a: Any, **_k: Any) -> None:
        return None

    mod(
        "rclpy",
        init=noop,
        ok=noop,
        shutdown=noop,
        try_shutdown=noop,
        spin=noop,
        spin_once=noop,
    )
    mod("rclpy.logging", get_logger=noop)
    mod("rclpy.duration", Duration=object)
    mod(
        "rclpy.executors",
        ExternalShutdownException=type("ExternalShutdownException", (Exception,), {}),
    )
    mod("rclpy.node", Node=object)
    mod("rclpy.parameter", Parameter=object)
    mod(
        "rclpy.qos",
        QoSProfile=QoSProfile,
        ReliabilityPolicy=reliability,
        DurabilityPolicy=durability,
        HistoryPolicy=history,
    )
    mod("rclpy.serialization", serialize_message=noop, deserialize_message=noop)
    mod("rclpy.time", Time=object)
    mod("rcl_interfaces")
    mod("rcl_interfaces.msg", ParameterDescriptor=object)
    std = type("String", (), {"__module__": "std_msgs.msg._string"})
    mod("std_msgs")
    mod("std_msgs.msg", String=std)
    monkeypatch.delitem(sys.modules, "dbcslam_ros.runtime.rclpy_backend", raising=False)


def test_rclpy_backend_converts_qos_and_types(monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_rclpy(monkeypatch)
    try:
        rb = importlib.import_module("dbcslam_ros.runtime.rclpy_backend")
        for prof in PROFILES.values():
            native = rb.native_qos(prof)
            assert rb.neutral_qos(native) == prof
        string_cls = rb.message_class("std_msgs/String")
        assert string_cls is sys.modules["std_msgs.msg"].String
        assert rb.type_name_of(string_cls) == "std_msgs/msg/String"
        with pytest.raises(Exception, match="not installed"):
            rb.message_class("nope_msgs/msg/X")
    finally:
        sys.modules.pop("dbcslam_ros.runtime.rclpy_backend", None)
