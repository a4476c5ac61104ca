"""QoS behaviour on real rclpy: matching rules, latched topics for late joiners."""

from __future__ import annotations

import time

import pytest

from dbcslam_ros import runtime as rt
from dbcslam_ros.errors import UsageError


def _n(q):
    return rt.neutral_qos(q)


def test_named_profiles() -> None:
    assert _n(rt.qos_profile("sensor_data")) == rt.QoSProfile(
        "best_effort", "volatile", "keep_last", 5
    )
    assert _n(rt.qos_profile("default")) == rt.QoSProfile("reliable", "volatile", "keep_last", 10)
    assert _n(rt.qos_profile("latched")) == rt.QoSProfile(
        "reliable", "transient_local", "keep_last", 1
    )
    assert rt.qos_profile("default", depth=3).depth == 3
    prof = _n(rt.make_qos("best_effort", "transient_local", "keep_all", 1))
    assert rt.QoSProfile.from_dict(prof.to_dict()) == prof
    with pytest.raises(UsageError, match="unknown QoS profile"):
        rt.qos_profile("fast")
    with pytest.raises(UsageError, match="reliability"):
        rt.make_qos("sometimes")


def test_best_effort_sub_matches_reliable_pub_but_not_vice_versa(rt_context) -> None:
    node = rt_context("qos_match")
    string_cls = rt.message_class("std_msgs/msg/String")
    rel_pub = node.create_publisher(string_cls, "/qos/rel", rt.qos_profile("default"))
    be_pub = node.create_publisher(string_cls, "/qos/be", rt.qos_profile("sensor_data"))
    got_be: list[str] = []
    got_rel: list[str] = []
    be_sub = node.create_subscription(
        string_cls, "/qos/rel", lambda m: got_be.append(m.data), rt.qos_profile("sensor_data")
    )
    rel_sub = node.create_subscription(
        string_cls, "/qos/be", lambda m: got_rel.append(m.data), rt.qos_profile("default")
    )
    # control: a best-effort subscription on the best-effort topic does match
    control: list[str] = []
    node.create_subscription(
        string_cls, "/qos/be", lambda m: control.append(m.data), rt.qos_profile("sensor_data")
    )
    assert rt.spin_until(node, lambda: be_sub.get_publisher_count() == 1, 5.0)
    assert rt.spin_until(node, lambda: be_pub.get_subscription_count() == 1, 5.0)
    for i in range(3):
        rel_pub.publish(string_cls(data=f"r{i}"))
        be_pub.publish(string_cls(data=f"b{i}"))
    assert rt.spin_until(node, lambda: len(got_be) == 3 and len(control) == 3, 5.0)
    rt.spin_until(node, lambda: bool(got_rel), 0.3)
    assert got_be == ["r0", "r1", "r2"]
    assert got_rel == []
    assert rel_sub.get_publisher_count() == 0
    assert be_pub.get_subscription_count() == 1  # only the control subscription


def test_latched_message_reaches_late_subscriber_in_other_process(
    rt_context, node_process
) -> None:
    talker = node_process(
        "dbcslam_ros.node.demo_nodes",
        "talker",
        "--ros-args",
        "-p",
        "scenario_topic:=/scenario",
        "-p",
        "scenario:=push_demo",
        "-p",
        "rate_hz:=50.0",
    )
    node = rt_context("late_joiner")
    # wait until the talker is up and has published for a while, then join late
    assert rt.spin_until(
        node, lambda: len(rt.get_publishers_info(node, "/scenario")) == 1, 10.0
    ), talker.log()
    assert talker.wait_for_log("sent 'hello", 10.0), talker.log()
    info = rt.get_publishers_info(node, "/scenario")[0]
    offered = info.qos_profile  # discovery carries reliability and durability, not depth
    assert (offered.reliability, offered.durability) == ("reliable", "transient_local")
    assert info.topic_type == "std_msgs/msg/String"
    # node names travel separately from endpoints (ros_discovery_info): may lag a little
    assert rt.spin_until(
        node,
        lambda: rt.get_publishers_info(node, "/scenario")[0].node_name == "talker",
        10.0,
    )
    time.sleep(0.2)
    string_cls = rt.message_class("std_msgs/msg/String")
    got: list[str] = []
    node.create_subscription(
        string_cls, "/scenario", lambda m: got.append(m.data), rt.qos_profile("latched")
    )
    assert rt.spin_until(node, lambda: bool(got), 5.0), talker.log()
    assert got == ["push_demo"]


def test_adapted_subscription_qos_follows_publishers() -> None:
    def info(q: rt.QoSProfile) -> rt.EndpointInfo:
        return rt.EndpointInfo("n", "/", "std_msgs/msg/String", "PUBLISHER", q)

    latched, sensor = rt.PROFILES["latched"], rt.PROFILES["sensor_data"]
    adapted = rt.adapted_subscription_qos([info(latched)], depth=7)
    assert _n(adapted) == rt.QoSProfile("reliable", "transient_local", "keep_last", 7)
    mixed = _n(rt.adapted_subscription_qos([info(latched), info(sensor)]))
    assert (mixed.reliability, mixed.durability) == ("best_effort", "volatile")
    assert _n(rt.adapted_subscription_qos([])).reliability == "reliable"
