"""Bytes on the DDS wire equal rosbags' serialize_cdr for every message type of the stack.

A relay process (raw subscription -> raw publisher, payload never decoded) sits between this
process and itself: typed messages published here cross the loopback network twice, arrive
back through raw and typed subscriptions, and are compared with rosbags' serializer.
"""

from __future__ import annotations

import numpy as np
import pytest

from dbcslam_ros import runtime as rt
from dbcslam_ros.runtime.typestore import get_typestore

pytestmark = pytest.mark.skipif(rt.BACKEND != "dds", reason="needs the dds backend")


def _topic(name: str, direction: str) -> str:
    return f"/wire/{direction}/" + name.replace("/msg/", "_").replace("/", "_")


def test_wire_bytes_equal_rosbags_for_all_stack_types(rt_context, node_process, msgvals) -> None:
    STACK_TYPES = msgvals.types
    build_ours, build_rosbags, random_tree = (
        msgvals.build_ours,
        msgvals.build_rosbags,
        msgvals.random_tree,
    )
    routes = [f"{n}|{_topic(n, 'in')}|{_topic(n, 'out')}" for n in STACK_TYPES]
    relay = node_process(
        "dbcslam_ros.runtime.relay", "--ros-args", "-p", "routes:=" + repr(routes)
    )
    node = rt_context("wire_test")
    qos = rt.qos_profile("default", depth=50)
    raw: dict[str, list[bytes]] = {n: [] for n in STACK_TYPES}
    typed: dict[str, list[object]] = {n: [] for n in STACK_TYPES}
    pubs = {}
    for name in STACK_TYPES:
        pubs[name] = node.create_publisher(rt.message_class(name), _topic(name, "in"), qos)
        rt.create_raw_subscription(node, name, _topic(name, "out"), raw[name].append, qos)
        node.create_subscription(
            rt.message_class(name), _topic(name, "out"), typed[name].append, qos
        )
    assert rt.spin_until(
        node, lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), 15.0
    ), relay.log()
    # the relay's publishers must be matched by our subscriptions too
    assert rt.spin_until(
        node,
        lambda: all(len(rt.get_publishers_info(node, _topic(n, "out"))) >= 1 for n in STACK_TYPES),
        10.0,
    ), relay.log()

    rng = np.random.default_rng(20241121)
    store = get_typestore()
    sent: dict[str, list[tuple[object, bytes]]] = {n: [] for n in STACK_TYPES}
    for name in STACK_TYPES:
        for _ in range(3):
            tree = random_tree(name, rng)
            msg = build_ours(name, tree)
            expected = store.serialize_cdr(build_rosbags(name, tree), name)
            sent[name].append((msg, expected))
            pubs[name].publish(msg)

    assert rt.spin_until(
        node, lambda: all(len(raw[n]) >= 3 and len(typed[n]) >= 3 for n in STACK_TYPES), 15.0
    ), {n: (len(raw[n]), len(typed[n])) for n in STACK_TYPES}
    for name in STACK_TYPES:
        assert raw[name] == [exp for _, exp in sent[name]], name
        assert typed[name] == [msg for msg, _ in sent[name]], name
        for data in raw[name]:
            assert data[:4] == b"\x00\x01\x00\x00"  # plain CDR, little endian (XCDR1)


def test_raw_publish_of_rosbags_bytes_decodes_to_equal_message(rt_context, msgvals) -> None:
    build_ours, build_rosbags, random_tree = (
        msgvals.build_ours,
        msgvals.build_rosbags,
        msgvals.random_tree,
    )
    node = rt_context("wire_raw")
    name = "nav_msgs/msg/Odometry"
    tree = random_tree(name, np.random.default_rng(5))
    data = get_typestore().serialize_cdr(build_rosbags(name, tree), name)
    got: list[object] = []
    pub = rt.create_raw_publisher(node, name, "/wire/raw_odom", rt.qos_profile("default"))
    node.create_subscription(
        rt.message_class(name), "/wire/raw_odom", got.append, rt.qos_profile("default")
    )
    assert rt.spin_until(node, lambda: pub.get_subscription_count() >= 1, 5.0)
    pub.publish(data)
    assert rt.spin_until(node, lambda: bool(got), 5.0)
    assert got == [build_ours(name, tree)]


def test_raw_subscription_normalizes_cyclone_c_padding_header(rt_context) -> None:
    # Cyclone's C serializer pads samples to 4 bytes and records the pad count in the
    # encapsulation options; raw subscribers must still get exactly serialize_cdr's bytes.
    node = rt_context("wire_pad")
    name = "std_msgs/msg/String"
    expected = bytes(
        get_typestore().serialize_cdr(get_typestore().types[name](data="abcde"), name)
    )
    pad = -len(expected) % 4
    assert pad  # the case under test
    c_style = expected[:3] + bytes([pad]) + expected[4:] + b"\0" * pad
    got: list[bytes] = []
    qos = rt.qos_profile("default")
    pub = rt.create_raw_publisher(node, name, "/wire/pad", qos)
    rt.create_raw_subscription(node, name, "/wire/pad", got.append, qos)
    assert rt.spin_until(node, lambda: pub.get_subscription_count() >= 1, 5.0)
    pub.publish(c_style)
    assert rt.spin_until(node, lambda: bool(got), 5.0)
    assert got == [expected]
