"""rclpy as the nodes use it: timers, sim time from /clock, logging, graph, acks."""

from __future__ import annotations

import itertools
import time

from dbcslam_ros import runtime as rt


def test_timer_fires_at_its_period(rt_context) -> None:
    node = rt_context("timed")
    stamps: list[float] = []
    timer = node.create_timer(0.02, lambda: stamps.append(time.monotonic()))
    assert rt.spin_until(node, lambda: len(stamps) >= 6, 5.0)
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert min(gaps) > 0.01  # never bursts
    timer.cancel()
    n = len(stamps)
    rt.spin_until(node, lambda: len(stamps) > n, 0.1)
    assert len(stamps) == n


def test_spin_once_times_out_without_work(rt_context) -> None:
    node = rt_context("idle")
    t0 = time.monotonic()
    rt.spin_once(node, timeout_sec=0.05)
    assert 0.04 <= time.monotonic() - t0 < 1.0


def test_shutdown_ends_spin_node(rt_context) -> None:
    node = rt_context("stopper")
    node.create_timer(0.01, rt.shutdown)
    rt.spin_node(node)  # returns (no exception) once the context is shut down
    assert not rt.ok()


def test_sim_time_follows_clock_topic(rt_context) -> None:
    node = rt_context("sim", ("--ros-args", "-p", "use_sim_time:=true"))
    clock_cls = rt.message_class("rosgraph_msgs/msg/Clock")
    time_cls = rt.message_class("builtin_interfaces/msg/Time")
    pub = node.create_publisher(clock_cls, "/clock", rt.qos_profile("clock"))
    assert node.get_clock().now().nanoseconds == 0
    assert rt.spin_until(node, lambda: pub.get_subscription_count() >= 1, 5.0)
    pub.publish(clock_cls(clock=time_cls(sec=12, nanosec=500)))
    assert rt.spin_until(node, lambda: node.get_clock().now().nanoseconds > 0, 5.0)
    now = node.get_clock().now()
    assert now.nanoseconds == 12_000_000_500
    assert (now.to_msg().sec, now.to_msg().nanosec) == (12, 500)


def test_wall_clock_by_default(rt_context) -> None:
    node = rt_context("wall")
    assert abs(node.get_clock().now().nanoseconds - time.time_ns()) < 1e9


def test_logging_format_and_throttle(rt_context, capfd) -> None:
    node = rt_context("talky", namespace="/ns")
    logged = [node.get_logger().info("tick", throttle_duration_sec=10.0) for _ in range(3)]
    node.get_logger().warning("careful")
    node.get_logger().debug("hidden")
    err = capfd.readouterr().err  # rcutils writes to fd 2
    assert logged == [True, False, False]
    assert err.count("[INFO]") == 1 and "[ns.talky]: tick" in err
    assert "[WARN]" in err and "careful" in err
    assert "hidden" not in err


def test_graph_discovers_topics_that_appear_later(rt_context, node_process) -> None:
    node = rt_context("observer")
    assert "/chatter" not in dict(rt.get_topic_names_and_types(node))
    talker = node_process("dbcslam_ros.node.demo_nodes", "talker")
    assert rt.spin_until(
        node, lambda: "/chatter" in dict(rt.get_topic_names_and_types(node)), 10.0
    ), talker.log()
    topics = dict(rt.get_topic_names_and_types(node))
    assert topics["/chatter"] == ["std_msgs/msg/String"]
    (info,) = rt.get_publishers_info(node, "/chatter")
    assert (info.qos_profile.reliability, info.qos_profile.durability) == ("reliable", "volatile")
    # node names travel separately from endpoints (ros_discovery_info): may lag a little
    assert rt.spin_until(
        node, lambda: rt.get_publishers_info(node, "/chatter")[0].node_name == "talker", 10.0
    )
    talker.terminate()
    assert rt.spin_until(node, lambda: not rt.get_publishers_info(node, "/chatter"), 10.0)


def test_sim_time_timer_follows_clock_not_wall_time(rt_context) -> None:
    node = rt_context("simtimer", ("--ros-args", "-p", "use_sim_time:=true"))
    clock_cls = rt.message_class("rosgraph_msgs/msg/Clock")
    time_cls = rt.message_class("builtin_interfaces/msg/Time")
    pub = node.create_publisher(clock_cls, "/clock", rt.qos_profile("clock"))
    fired: list[int] = []
    node.create_timer(1.0, lambda: fired.append(node.get_clock().now().nanoseconds))
    assert rt.spin_until(node, lambda: pub.get_subscription_count() >= 1, 5.0)
    rt.spin_until(node, lambda: bool(fired), 0.3)
    assert fired == []  # 0.3 s of wall time is not 1 s of sim time
    for sec in (1, 2, 3):
        pub.publish(clock_cls(clock=time_cls(sec=sec)))
        assert rt.spin_until(node, lambda s=sec: len(fired) >= s, 5.0)
    assert fired == [1_000_000_000, 2_000_000_000, 3_000_000_000]


def test_reliable_publisher_waits_for_acks(rt_context) -> None:
    node = rt_context("acks")
    string_cls = rt.message_class("std_msgs/msg/String")
    pub = node.create_publisher(string_cls, "/acks", rt.qos_profile("default"))
    node.create_subscription(string_cls, "/acks", lambda _m: None, rt.qos_profile("default"))
    assert rt.spin_until(node, lambda: pub.get_subscription_count() == 1, 5.0)
    pub.publish(string_cls(data="x"))
    assert pub.wait_for_all_acked(rt.Duration(seconds=2.0))
