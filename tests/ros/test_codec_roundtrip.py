"""Codec of the generated message classes against rosbags' independent CDR serializer."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dbcslam_ros import runtime as rt
from dbcslam_ros.errors import MessageTypeError
from dbcslam_ros.runtime import dds_messages
from dbcslam_ros.runtime.typestore import get_typestore

pytestmark = pytest.mark.skipif(rt.BACKEND != "dds", reason="generated classes: dds backend")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_random_values_roundtrip_and_match_rosbags(
    stack_type: str, msgvals: Any, data: st.DataObject
) -> None:
    name = stack_type
    build_ours, build_rosbags = msgvals.build_ours, msgvals.build_rosbags
    tree = data.draw(msgvals.value_strategy(name))
    ours = build_ours(name, tree)
    store = get_typestore()
    expected = store.serialize_cdr(build_rosbags(name, tree), name)
    wire = rt.encode(ours)
    assert wire == expected
    assert rt.decode(wire, name) == ours
    assert dds_messages.cdr_length(wire + b"\0\0\0", name) == len(wire)
    assert rt.from_rosbags(build_rosbags(name, tree)) == ours
    assert store.serialize_cdr(rt.to_rosbags(ours), name) == expected


def test_default_constructed_matches_rosbags_defaults(stack_type: str) -> None:
    name = stack_type
    store = get_typestore()
    ours = rt.message_class(name)()
    theirs = store.deserialize_cdr(rt.encode(ours), name)
    assert store.serialize_cdr(theirs, name) == rt.encode(ours)
    assert rt.encode(ours)[:4] == b"\x00\x01\x00\x00"  # XCDR1, little endian


def test_classes_have_ros_shape_and_constants() -> None:
    marker_cls = rt.message_class("visualization_msgs/msg/Marker")
    assert (marker_cls.ADD, marker_cls.DELETEALL, marker_cls.SPHERE) == (0, 3, 2)
    pose = rt.message_class("geometry_msgs/msg/PoseWithCovarianceStamped")()
    assert len(pose.pose.covariance) == 36
    assert pose.pose.pose.orientation.w == 0.0  # ROS default (not identity)
    assert rt.type_name_of(pose) == "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert rt.message_class("geometry_msgs/PoseStamped") is rt.message_class(
        "geometry_msgs.msg.PoseStamped"
    )


def test_scalar_byte_accepts_rclpy_and_rosbags_spelling() -> None:
    status_cls = rt.message_class("diagnostic_msgs/msg/DiagnosticStatus")
    assert status_cls(level=b"\x02").level == status_cls.ERROR == 2
    assert rt.encode(status_cls(level=b"\x01")) == rt.encode(status_cls(level=status_cls.WARN))
    assert status_cls(level=-1).level == 255  # rosbags' signed spelling, same bits
    store = get_typestore()
    theirs = store.types["diagnostic_msgs/msg/DiagnosticStatus"](-1, "n", "m", "h", [])
    assert rt.from_rosbags(theirs) == status_cls(level=255, name="n", message="m", hardware_id="h")


def test_numpy_arrays_are_accepted_for_array_fields() -> None:
    pose = rt.message_class("geometry_msgs/msg/PoseWithCovarianceStamped")()
    pose.pose.covariance = np.eye(6).ravel()
    grid = rt.message_class("nav_msgs/msg/OccupancyGrid")(data=np.array([-1, 0, 100], np.int8))
    assert pose.pose.covariance[7] == 1.0 and isinstance(pose.pose.covariance, list)
    store = get_typestore()
    back = store.deserialize_cdr(rt.encode(grid), "nav_msgs/msg/OccupancyGrid")
    assert back.data.tolist() == [-1, 0, 100]


def test_cdr_length_strips_dds_padding(msgvals: Any) -> None:
    rng = np.random.default_rng(3)
    for name in msgvals.types:
        data = rt.encode(msgvals.build_ours(name, msgvals.random_tree(name, rng)))
        assert dds_messages.cdr_length(data + b"\0" * 3, name) == len(data)
        with pytest.raises(MessageTypeError, match="too short"):
            dds_messages.cdr_length(data[:-1], name)


def test_bad_inputs_raise_message_type_error() -> None:
    with pytest.raises(MessageTypeError, match="unknown ROS message type"):
        rt.message_class("nope_msgs/msg/Nothing")
    with pytest.raises(MessageTypeError, match="bad ROS message type name"):
        rt.message_class("justaname")
    with pytest.raises(MessageTypeError, match="header"):
        rt.decode(b"\x01\x02", "std_msgs/msg/String")
    with pytest.raises(MessageTypeError, match="cannot serialize"):
        rt.encode(rt.message_class("std_msgs/msg/String")(data=5))
