"""Bags written by dbcslam_ros.bag open in rosbags' AnyReader, mcap + mcap_ros2 and our reader."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from dbcslam_ros.bag import (
    LATCHED_QOS,
    SENSOR_DATA_QOS,
    BagWriter,
    TopicSpec,
    jazzy_typestore,
    make_qos,
    open_bag,
    qos_from_yaml,
    read_bag,
    serialize,
    write_bag,
)
from dbcslam_ros.bag.metadata import load_metadata
from dbcslam_ros.bag.salvage import scan_mcap
from dbcslam_ros.errors import BagError

T0 = 1_700_000_000_000_000_000  # ns


def _types() -> Any:
    return jazzy_typestore().types


def _pose(i: int) -> Any:
    t = _types()
    return t["geometry_msgs/msg/PoseStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](
                sec=1 + i // 100, nanosec=(i % 100) * 10_000_000
            ),
            frame_id="world",
        ),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=0.01 * i, y=-0.5 * i, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(i), w=np.cos(i)),
        ),
    )


def _modes(i: int) -> Any:
    t = _types()
    layout = t["std_msgs/msg/MultiArrayLayout"](
        dim=[
            t["std_msgs/msg/MultiArrayDimension"](label="contacts", size=1, stride=4),
            t["std_msgs/msg/MultiArrayDimension"](label="modes", size=4, stride=4),
        ],
        data_offset=0,
    )
    p = np.array([0.1, 0.2, 0.3, 0.4]) * (i + 1)
    return t["std_msgs/msg/Float64MultiArray"](layout=layout, data=p / p.sum())


def _joints(i: int) -> Any:
    t = _types()
    return t["sensor_msgs/msg/JointState"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=i, nanosec=0), frame_id=""
        ),
        name=["lower_jaw", "upper_jaw"],
        position=np.array([0.01 * i, -0.01 * i]),
        velocity=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
    )


@pytest.fixture
def sample() -> list[tuple[str, Any, int]]:
    """A small contract-shaped recording: latched scenario, 20 poses, modes, joint states."""
    t = _types()
    msgs: list[tuple[str, Any, int]] = [
        ("/scenario", t["std_msgs/msg/String"](data="scenario: edge\ndt: 0.01\n"), T0)
    ]
    for i in range(20):
        stamp = T0 + (i + 1) * 10_000_000
        msgs.append(("/object/pose", _pose(i), stamp))
        msgs.append(("/joint_states", _joints(i), stamp + 1))
        if i % 2 == 0:
            msgs.append(("/dbcslam/contact_modes", _modes(i), stamp + 2))
    return msgs


@pytest.fixture
def bag(tmp_path: Path, sample: list[tuple[str, Any, int]]) -> Path:
    path = tmp_path / "run"
    write_bag(path, sample)
    return path


def _expected(sample: list[tuple[str, Any, int]]) -> list[tuple[str, int, bytes]]:
    return [(topic, ts, serialize(msg)[1]) for topic, msg, ts in sample]


def test_our_reader_returns_every_message_in_log_time_order(
    bag: Path, sample: list[tuple[str, Any, int]]
) -> None:
    got = [(m.topic, m.log_time_ns, m.data) for m in read_bag(bag)]
    assert got == _expected(sample)
    with open_bag(bag) as reader:
        assert reader.counts() == {
            "/scenario": 1,
            "/object/pose": 20,
            "/joint_states": 20,
            "/dbcslam/contact_modes": 10,
        }
        assert reader.start_ns == T0
        assert reader.end_ns == max(ts for _, _, ts in sample)
        first_pose = next(iter(reader.decoded(["/object/pose"])))[1]
        assert first_pose.header.frame_id == "world"
        assert first_pose.pose.orientation.w == pytest.approx(1.0)


def test_rosbags_anyreader_reads_payloads_and_counts(
    bag: Path, sample: list[tuple[str, Any, int]]
) -> None:
    with AnyReader([bag], default_typestore=jazzy_typestore()) as reader:
        got = [(c.topic, ts, bytes(raw)) for c, ts, raw in reader.messages()]
        counts = {c.topic: c.msgcount for c in reader.connections}
        decoded = [
            reader.deserialize(raw, c.msgtype)
            for c, _, raw in reader.messages()
            if c.topic == "/dbcslam/contact_modes"
        ]
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert got == _expected(sample)
    assert counts["/object/pose"] == 20
    assert counts["/scenario"] == 1
    np.testing.assert_allclose(decoded[3].data, _modes(6).data)
    assert qos["/scenario"] == [LATCHED_QOS]
    assert qos["/object/pose"] == [SENSOR_DATA_QOS]


def test_mcap_reader_with_ros2_decoder_decodes_every_message(
    bag: Path, sample: list[tuple[str, Any, int]]
) -> None:
    mcap_file = next(bag.glob("*.mcap"))
    with mcap_file.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        out = list(reader.iter_decoded_messages(log_time_order=True))
        summary = reader.get_summary()
    assert summary is not None
    assert [(c.topic, m.log_time, bytes(m.data)) for _, c, m, _ in out] == _expected(sample)
    by_topic: dict[str, list[Any]] = {}
    for _schema, channel, _msg, obj in out:
        by_topic.setdefault(channel.topic, []).append(obj)
    assert by_topic["/scenario"][0].data == "scenario: edge\ndt: 0.01\n"
    assert [p.pose.position.x for p in by_topic["/object/pose"]] == pytest.approx(
        [0.01 * i for i in range(20)]
    )
    assert list(by_topic["/joint_states"][5].name) == ["lower_jaw", "upper_jaw"]
    assert list(by_topic["/dbcslam/contact_modes"][1].data) == pytest.approx(list(_modes(2).data))
    for schema in summary.schemas.values():
        assert schema.encoding == "ros2msg"
    pose_schema = next(s for s in summary.schemas.values() if s.name.endswith("PoseStamped"))
    assert b"MSG: geometry_msgs/Quaternion" in pose_schema.data  # full concatenated definition


def test_metadata_is_version_9_with_qos_and_counts(bag: Path) -> None:
    doc = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = doc["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["run_0.mcap"]
    assert info["message_count"] == 51
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert topics["/object/pose"]["message_count"] == 20
    scen = topics["/scenario"]["topic_metadata"]
    assert scen["offered_qos_profiles"][0]["durability"] == "transient_local"
    assert scen["offered_qos_profiles"][0]["reliability"] == "reliable"
    assert scen["type_description_hash"].startswith("RIHS01_")
    meta = load_metadata(bag / "metadata.yaml")
    assert sum(t.message_count for t in meta.topics) == meta.message_count
    # MCAP channel metadata carries the same QoS as a YAML string, and the type hash.
    with next(bag.glob("*.mcap")).open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    channels = {c.topic: c for c in summary.channels.values()}
    assert qos_from_yaml(channels["/scenario"].metadata["offered_qos_profiles"]) == (LATCHED_QOS,)
    assert channels["/scenario"].metadata["topic_type_hash"] == scen["type_description_hash"]


def test_reader_sorts_out_of_order_writes_by_log_time(tmp_path: Path) -> None:
    string = _types()["std_msgs/msg/String"]
    times = [50, 10, 40, 20, 30]
    write_bag(tmp_path / "b", [("/t", string(data=str(ts)), ts) for ts in times])
    assert [m.log_time_ns for m in read_bag(tmp_path / "b")] == sorted(times)
    assert [m.data for m in read_bag(tmp_path / "b")] == [
        serialize(string(data=str(ts)))[1] for ts in sorted(times)
    ]


def test_bare_mcap_file_opens_and_topic_filter_works(bag: Path) -> None:
    mcap_file = next(bag.glob("*.mcap"))
    poses = read_bag(mcap_file, ["/object/pose"])
    assert len(poses) == 20
    assert {m.msgtype for m in poses} == {"geometry_msgs/msg/PoseStamped"}


def test_raw_bytes_with_declared_topic_and_explicit_qos(tmp_path: Path) -> None:
    qos = make_qos(reliable=False, depth=7)
    string = _types()["std_msgs/msg/String"]
    data = serialize(string(data="raw"))[1]
    write_bag(
        tmp_path / "raw",
        [("/x", data, 5)],
        topics=[TopicSpec("/x", "std_msgs/msg/String", (qos,))],
    )
    with open_bag(tmp_path / "raw") as reader:
        (msg,) = list(reader.messages())
        assert msg.data == data
        assert msg.qos == (qos,)
        assert reader.decode(msg).data == "raw"


def test_existing_bag_is_not_overwritten_unless_asked(bag: Path) -> None:
    before = (bag / "metadata.yaml").read_bytes()
    string = _types()["std_msgs/msg/String"]
    with pytest.raises(BagError, match=r"already exists.*--overwrite"):
        write_bag(bag, [("/t", string(data="new"), 1)])
    assert (bag / "metadata.yaml").read_bytes() == before
    write_bag(bag, [("/t", string(data="new"), 1)], overwrite=True)
    assert [m.topic for m in read_bag(bag)] == ["/t"]


def test_overwrite_refuses_to_delete_a_directory_that_is_not_a_bag(tmp_path: Path) -> None:
    target = tmp_path / "notabag"
    target.mkdir()
    (target / "precious.txt").write_text("keep me")
    with pytest.raises(BagError, match="not a bag directory"):
        BagWriter(target, overwrite=True).open()
    assert (target / "precious.txt").read_text() == "keep me"


def test_writer_rejects_unknown_types_and_unregistered_topics(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "w") as writer:
        with pytest.raises(BagError, match="unknown message type"):
            writer.add_topic("/a", "nope_msgs/msg/Nothing")
        with pytest.raises(BagError, match="was not added"):
            writer.write("/b", b"\x00\x01\x00\x00", 1)
        writer.add_topic("/a", "std_msgs/msg/String")
        with pytest.raises(BagError, match="cannot add it again"):
            writer.add_topic("/a", "std_msgs/msg/Bool")
    assert load_metadata(tmp_path / "w" / "metadata.yaml").message_count == 0


def test_exception_inside_with_block_still_closes_the_bag(tmp_path: Path) -> None:
    string = _types()["std_msgs/msg/String"]
    with pytest.raises(RuntimeError), BagWriter(tmp_path / "x") as writer:
        writer.write_message("/t", string(data="kept"), 3)
        raise RuntimeError("boom")
    assert [m.data for m in read_bag(tmp_path / "x")] == [serialize(string(data="kept"))[1]]


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    payloads=st.lists(st.text(max_size=40), min_size=1, max_size=30),
    cut_fraction=st.floats(0.0, 1.0),
    chunk_size=st.sampled_from([64, 512, 1 << 20]),
)
def test_salvage_of_any_truncation_yields_a_prefix_of_the_written_messages(
    tmp_path_factory: pytest.TempPathFactory,
    payloads: list[str],
    cut_fraction: float,
    chunk_size: int,
) -> None:
    string = _types()["std_msgs/msg/String"]
    path = tmp_path_factory.mktemp("salv") / "b"
    with BagWriter(path, chunk_size=chunk_size) as writer:
        for i, text in enumerate(payloads):
            writer.write_message("/s", string(data=text), 100 + i)
    data = next(path.glob("*.mcap")).read_bytes()
    full = scan_mcap(data)
    assert full.damage is None
    assert [m.data for m in full.messages] == [serialize(string(data=p))[1] for p in payloads]
    cut = int(cut_fraction * len(data))
    part = scan_mcap(data[:cut])
    # Every message whose whole record lies before the cut must come back, in order.
    complete = 0
    for i, msg in enumerate(full.messages):
        record = (
            b"\x05"
            + struct.pack("<Q", 2 + 4 + 8 + 8 + len(msg.data))
            + struct.pack("<HIQQ", msg.channel_id, i, 100 + i, 100 + i)
            + msg.data
        )
        offset = data.find(record)
        assert offset > 0
        if offset + len(record) <= cut:
            complete += 1
    assert [m.data for m in part.messages] == [m.data for m in full.messages[:complete]]
    if cut < len(data):
        assert part.damage is not None


def test_bag_written_by_rosbags_writer_reads_back(tmp_path: Path) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    string = _types()["std_msgs/msg/String"]
    with Writer(tmp_path / "rb", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(
            "/scenario",
            "std_msgs/msg/String",
            typestore=jazzy_typestore(),
            offered_qos_profiles=[LATCHED_QOS],
        )
        for i in range(5):
            writer.write(conn, 10 + i, serialize(string(data=f"s{i}"))[1])
    with open_bag(tmp_path / "rb") as bag:
        assert [bag.decode(m).data for m in bag.messages()] == [f"s{i}" for i in range(5)]
        assert bag.topics()["/scenario"].offered_qos == (LATCHED_QOS,)


def test_zstd_compressed_chunks_read_and_salvage_whole_chunks(tmp_path: Path) -> None:
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    string = _types()["std_msgs/msg/String"]
    path = tmp_path / "z.mcap"
    payloads = [serialize(string(data=f"zstd {i:04d}" + "q" * 40))[1] for i in range(200)]
    with path.open("wb") as fh:
        writer = McapWriter(fh, chunk_size=1024, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data\n")
        channel = writer.register_channel("/z", "cdr", schema, {"offered_qos_profiles": ""})
        for i, data in enumerate(payloads):
            writer.add_message(channel, log_time=i, data=data, publish_time=i)
        writer.finish()
    assert [m.data for m in read_bag(path)] == payloads
    data = path.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    got = [m.data for m in read_bag(tmp_path / "cut.mcap", salvage=True)]
    assert 0 < len(got) < len(payloads)
    assert got == payloads[: len(got)]


def test_runtime_message_objects_can_be_written(tmp_path: Path) -> None:
    from dbcslam_ros import runtime as rt

    string_cls = rt.message_class("std_msgs/msg/String")
    write_bag(tmp_path / "rt", [("/scenario", string_cls(data="from runtime"), 7)])
    (msg,) = read_bag(tmp_path / "rt")
    assert msg.msgtype == "std_msgs/msg/String"
    assert msg.data == serialize(_types()["std_msgs/msg/String"](data="from runtime"))[1]
    with pytest.raises(BagError, match="not a ROS message"):
        serialize(object())


def _runtime_messages() -> list[tuple[str, Any]]:
    """(topic, runtime message object) for every topic of the contract, with content."""
    from dbcslam_ros import runtime as rt
    from dbcslam_ros.convert import float64_multiarray, pose_stamped, wrench_stamped
    from dbcslam_ros.node.filter_node import OUTPUT_TYPES

    cls = rt.message_class
    header = cls("std_msgs/msg/Header")
    stamp = pose_stamped(T0, 0.1, 0.2, 0.3).header.stamp
    joints = cls("sensor_msgs/msg/JointState")(
        header=header(stamp=stamp, frame_id="world"),
        name=["a", "b"],
        position=[0.1, -0.2],
        velocity=[],
        effort=[],
    )
    out: list[tuple[str, Any]] = [
        ("/object/pose", pose_stamped(T0, 0.1, 0.2, 0.3)),
        ("/truth/object/pose", pose_stamped(T0, 0.1, 0.2, 0.3)),
        ("/object/wrench", wrench_stamped(T0, 1.0, -2.0, 0.5)),
        ("/pusher/wrench", wrench_stamped(T0, 0.3, 0.4, 0.0)),
        ("/joint_states", joints),
        ("/scenario", cls("std_msgs/msg/String")(data="kind: push")),
        ("/truth/contact_modes", float64_multiarray([[0.0, 1.0, 0.0, 0.0]], ("c", "m"))),
        ("/truth/friction", float64_multiarray([0.3], ("pairs",))),
        ("/pusher/contact", float64_multiarray([[0.0, 1.0]], ("contacts", "state"))),
    ]
    out += [(topic, cls(name)()) for topic, name in OUTPUT_TYPES.items()]
    return out


def test_runtime_message_objects_of_every_stack_type_write_and_read_back(
    tmp_path: Path,
) -> None:
    """write_bag accepts the node runtime's message objects (which carry __msgtype__ like
    rosbags dataclasses) and stores their CDR bytes unchanged."""
    from dbcslam_ros import runtime as rt

    msgs = _runtime_messages()
    path = tmp_path / "runtime"
    write_bag(path, [(topic, m, T0 + k) for k, (topic, m) in enumerate(msgs)])
    with open_bag(path) as reader:
        got = [(raw.topic, bytes(raw.data)) for raw in reader.messages()]
        types = {name: t.msgtype for name, t in reader.topics().items()}
    assert got == [(topic, rt.encode(m)) for topic, m in msgs]
    for topic, m in msgs:
        assert types[topic] == rt.type_name_of(m)
    name, data = serialize(msgs[-1][1])
    assert data == rt.encode(msgs[-1][1]) and name == rt.type_name_of(msgs[-1][1])
