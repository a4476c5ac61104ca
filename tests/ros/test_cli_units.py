"""Pure helpers of the CLI: echo YAML, field selection, QoS mapping, /clock messages."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_ros.bag import LATCHED_QOS, RELIABLE_QOS, SENSOR_DATA_QOS, jazzy_typestore, make_qos
from dbcslam_ros.bag.qos import qos_from_yaml, qos_to_dicts, qos_to_yaml_string
from dbcslam_ros.cli._common import bag_qos_to_runtime, subscription_qos_for
from dbcslam_ros.cli._format import message_to_yaml, select_field
from dbcslam_ros.cli.commands.play import _publish_clock
from dbcslam_ros.errors import BagError, UsageError
from dbcslam_ros.qos import PROFILES, QoSProfile, to_bag_qos


def _t(name: str) -> Any:
    return jazzy_typestore().types[name]


def _wrench() -> Any:
    vec = _t("geometry_msgs/msg/Vector3")
    return _t("geometry_msgs/msg/WrenchStamped")(
        header=_t("std_msgs/msg/Header")(
            stamp=_t("builtin_interfaces/msg/Time")(sec=3, nanosec=500), frame_id="world"
        ),
        wrench=_t("geometry_msgs/msg/Wrench")(
            force=vec(x=1.0, y=-2.5, z=0.0), torque=vec(x=0.0, y=0.0, z=0.125)
        ),
    )


def test_echo_yaml_nests_fields_in_definition_order() -> None:
    text = message_to_yaml(_wrench())
    assert text.startswith("header:\n  stamp:\n    sec: 3\n    nanosec: 500\n")
    assert yaml.safe_load(text) == {
        "header": {"stamp": {"sec": 3, "nanosec": 500}, "frame_id": "world"},
        "wrench": {
            "force": {"x": 1.0, "y": -2.5, "z": 0.0},
            "torque": {"x": 0.0, "y": 0.0, "z": 0.125},
        },
    }


def test_echo_yaml_of_arrays_and_special_floats() -> None:
    msg = _t("std_msgs/msg/Float64MultiArray")(
        layout=_t("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0),
        data=np.array([0.25, math.inf, math.nan]),
    )
    data = yaml.safe_load(message_to_yaml(msg))
    assert data["data"][:2] == [0.25, math.inf]
    assert math.isnan(data["data"][2])
    assert data["layout"] == {"dim": [], "data_offset": 0}


@given(st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=60))
def test_echo_yaml_round_trips_any_string(text: str) -> None:
    msg = _t("std_msgs/msg/String")(data=text)
    assert yaml.safe_load(message_to_yaml(msg)) == {"data": text}
    assert yaml.safe_load(message_to_yaml(msg, "data")) == text


def test_field_selection_with_list_index_and_errors() -> None:
    joint = _t("sensor_msgs/msg/JointState")(
        header=_t("std_msgs/msg/Header")(
            stamp=_t("builtin_interfaces/msg/Time")(sec=0, nanosec=0), frame_id=""
        ),
        name=["pusher_x", "pusher_y"],
        position=np.array([0.5, 0.75]),
        velocity=np.array([]),
        effort=np.array([]),
    )
    assert yaml.safe_load(message_to_yaml(joint, "position.1")) == 0.75
    assert yaml.safe_load(message_to_yaml(joint, "name")) == ["pusher_x", "pusher_y"]
    with pytest.raises(UsageError, match="'positions'"):
        message_to_yaml(joint, "positions")
    with pytest.raises(UsageError, match="'7'"):
        select_field({"a": [1, 2]}, "a.7")


@pytest.mark.parametrize("qos", [LATCHED_QOS, RELIABLE_QOS, SENSOR_DATA_QOS, make_qos(depth=3)])
def test_qos_yaml_string_and_dicts_round_trip(qos: Any) -> None:
    assert qos_from_yaml(qos_to_yaml_string([qos])) == (qos,)
    assert qos_from_yaml(qos_to_dicts([qos, qos])) == (qos, qos)
    assert qos_to_yaml_string([]) == ""
    assert qos_from_yaml("") == ()


def test_qos_parser_accepts_rosbag2_v8_integers_and_rejects_garbage() -> None:
    v8 = (
        "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
        "  deadline: {sec: 0, nsec: 0}\n  lifespan: {sec: 0, nsec: 0}\n  liveliness: 1\n"
        "  liveliness_lease_duration: {sec: 0, nsec: 0}\n"
        "  avoid_ros_namespace_conventions: false\n"
    )
    (qos,) = qos_from_yaml(v8)
    assert qos.durability == LATCHED_QOS.durability
    assert qos.reliability == LATCHED_QOS.reliability
    with pytest.raises(BagError, match="reliability"):
        qos_from_yaml([{"reliability": "sometimes"}])
    with pytest.raises(BagError, match="YAML"):
        qos_from_yaml("- [unclosed")


def test_playback_qos_keeps_latching_and_reliability_of_the_recording() -> None:
    latched = bag_qos_to_runtime([LATCHED_QOS], min_depth=1000)
    assert latched == QoSProfile("reliable", "transient_local", "keep_last", 1)
    sensor = bag_qos_to_runtime([SENSOR_DATA_QOS], min_depth=1000)
    assert (sensor.reliability, sensor.durability, sensor.depth) == (
        "best_effort",
        "volatile",
        1000,
    )
    mixed = bag_qos_to_runtime([RELIABLE_QOS, SENSOR_DATA_QOS])
    assert mixed.reliability == "best_effort"
    assert bag_qos_to_runtime([]) == PROFILES["default"]


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_runtime_and_bag_qos_convert_both_ways(name: str) -> None:
    prof = PROFILES[name]
    assert bag_qos_to_runtime([to_bag_qos(prof)]) == prof


def test_subscription_qos_is_compatible_with_every_publisher() -> None:
    rel, be, tl = PROFILES["default"], PROFILES["sensor_data"], PROFILES["latched"]
    assert subscription_qos_for([rel]).reliability == "reliable"
    assert subscription_qos_for([rel, be]).reliability == "best_effort"
    assert subscription_qos_for([tl]).durability == "transient_local"
    assert subscription_qos_for([tl, rel]).durability == "volatile"
    # no publisher yet: the rosbag2 default (reliable), the one rule of dbcslam_ros.qos
    assert subscription_qos_for([]).reliability == "reliable"


def test_clock_message_carries_the_bag_time() -> None:
    sent: list[bytes] = []

    class Pub:
        def publish(self, data: bytes) -> None:
            sent.append(data)

    _publish_clock(Pub(), 12_345_678_901)
    msg = jazzy_typestore().deserialize_cdr(sent[0], "rosgraph_msgs/msg/Clock")
    assert (msg.clock.sec, msg.clock.nanosec) == (12, 345_678_901)


@pytest.mark.parametrize(
    ("topics", "internal", "asked"),
    [
        ([], False, ["/chatter"]),
        ([], True, ["/chatter", "/parameter_events", "/rosout"]),
        (["/rosout"], False, ["/rosout"]),
    ],
)
def test_record_leaves_out_ros_internal_topics_unless_asked(
    topics: list[str], internal: bool, asked: list[str]
) -> None:
    from dbcslam_ros.cli.commands.record import _Recorder

    seen: list[str] = []

    class GraphOnly:
        def get_topic_names_and_types(self, _node: object) -> list[tuple[str, list[str]]]:
            return [
                ("/chatter", ["std_msgs/msg/String"]),
                ("/parameter_events", ["rcl_interfaces/msg/ParameterEvent"]),
                ("/rosout", ["rcl_interfaces/msg/Log"]),
            ]

        def get_publishers_info(self, _node: object, topic: str) -> list[object]:
            seen.append(topic)
            return []  # no publisher yet: nothing is subscribed

    _Recorder(GraphOnly(), None, None, topics, internal=internal).discover()
    assert sorted(seen) == asked
