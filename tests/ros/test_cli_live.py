"""record / play / topic echo / topic list against live DDS, as real processes (loopback).

Helper publishers and subscribers run the node runtime in their own processes (written to
tmp_path as a module); every process is started through the ``node_process`` fixture of
tests/ros/conftest.py and stopped by PID at teardown, even when a test fails.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from dbcslam_ros.bag import jazzy_typestore, open_bag
from dbcslam_ros.bag.metadata import load_metadata
from dbcslam_ros.errors import BagError

HELPER = '''
"""Test helper processes for test_cli_live.py (publisher, subscriber)."""
import sys
import time

from dbcslam_ros import runtime as rt

SCENARIO = "scenario: edge\\ndt: 0.01\\n"


def publish(count, out, stream=False):
    rt.init(["helper"])
    node = rt.Node("h2_test_pub")
    string = rt.message_class("std_msgs/msg/String")
    latched = node.create_publisher(string, "/scenario", rt.qos_profile("latched"))
    latched.publish(string(data=SCENARIO))
    pub = node.create_publisher(
        string, "/chatter", rt.make_qos("reliable", "volatile", "keep_last", 1000)
    )
    if not rt.spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0):
        print("no subscriber", flush=True)
        return 3
    print("matched", flush=True)
    with open(out, "w") as fh:
        i = 0
        while stream or i < count:
            msg = string(data=f"chatter {i:05d} " + "z" * (i % 37))
            pub.publish(msg)
            fh.write(rt.encode(msg).hex() + "\\n")
            fh.flush()
            i += 1
            rt.spin_once(node, timeout_sec=0.005)
    pub.wait_for_all_acked(rt.Duration(seconds=5.0))
    print("done", flush=True)
    node.destroy_node()
    rt.try_shutdown()
    return 0


def subscribe(count, out):
    rt.init(["helper"])
    node = rt.Node("h2_test_sub")
    got = []
    scenario = []
    def keep(into):
        # exact CDR of what arrived (the middleware may add trailing alignment bytes)
        def cb(data):
            into.append(rt.canonical_cdr(data, "std_msgs/msg/String"))
        return cb

    rt.create_raw_subscription(
        node, "std_msgs/msg/String", "/chatter", keep(got),
        rt.make_qos("reliable", "volatile", "keep_last", 1000),
    )
    rt.create_raw_subscription(
        node, "std_msgs/msg/String", "/scenario", keep(scenario), rt.qos_profile("latched")
    )
    print("ready", flush=True)
    rt.spin_until(node, lambda: len(got) >= count and scenario, 40.0)
    time.sleep(0.3)
    rt.spin_once(node, timeout_sec=0.1)
    with open(out, "w") as fh:
        fh.write("".join(bytes(b).hex() + "\\n" for b in got))
    with open(out + ".scenario", "w") as fh:
        fh.write("".join(bytes(b).hex() + "\\n" for b in scenario))
    print("received", len(got), flush=True)
    node.destroy_node()
    rt.try_shutdown()
    return 0


def pose():
    rt.init(["helper"])
    node = rt.Node("h2_test_pose")
    string = rt.message_class("std_msgs/msg/String")
    pose_t = rt.message_class("geometry_msgs/msg/PoseStamped")
    latched = node.create_publisher(string, "/scenario", rt.qos_profile("latched"))
    latched.publish(string(data=SCENARIO))
    pub = node.create_publisher(pose_t, "/object/pose", rt.qos_profile("sensor_data"))
    msg = pose_t()
    msg.header.frame_id = "world"
    msg.pose.position.x = 1.5
    msg.pose.position.y = -0.25
    msg.pose.orientation.w = 1.0
    print("publishing", flush=True)
    try:
        while True:
            pub.publish(msg)
            rt.spin_once(node, timeout_sec=0.05)
    except rt.ExternalShutdownException:
        pass
    node.destroy_node()
    rt.try_shutdown()
    return 0


if __name__ == "__main__":
    mode = sys.argv[1]
    if mode == "pub":
        sys.exit(publish(int(sys.argv[2]), sys.argv[3]))
    if mode == "stream":
        sys.exit(publish(0, sys.argv[2], stream=True))
    if mode == "sub":
        sys.exit(subscribe(int(sys.argv[2]), sys.argv[3]))
    if mode == "pose":
        sys.exit(pose())
'''

COUNT = 60


@pytest.fixture
def helper_env(tmp_path: Path) -> dict[str, str]:
    """Environment that makes the helper module importable in child processes."""
    mod_dir = tmp_path / "helpers"
    mod_dir.mkdir()
    (mod_dir / "h2_cli_helper.py").write_text(HELPER)
    path = os.pathsep.join([str(mod_dir), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {"PYTHONPATH": path}


def _wait(proc: Any, timeout: float) -> int:
    try:
        return int(proc.proc.wait(timeout))
    except subprocess.TimeoutExpired:
        pytest.fail(f"process {proc.pid} did not exit within {timeout} s:\n{proc.log()}")


def _hex_lines(path: Path) -> list[bytes]:
    return [bytes.fromhex(line) for line in path.read_text().split()]


def test_record_then_play_delivers_every_message_in_order_with_same_bytes(
    tmp_path: Path, node_process: Callable[..., Any], helper_env: dict[str, str]
) -> None:
    bag = tmp_path / "rec"
    published = tmp_path / "published.txt"
    received = tmp_path / "received.txt"

    # 1. Recorder first; the publisher appears later and waits until the recorder matched.
    rec = node_process("dbcslam_ros.cli", "record", "-o", str(bag), "/chatter", "/scenario")
    pub = node_process("h2_cli_helper", "pub", str(COUNT), str(published), env=helper_env)
    assert _wait(pub, 60) == 0, pub.log()
    assert rec.wait_for_log("recording /scenario", 10), rec.log()
    time.sleep(0.5)
    os.kill(rec.pid, signal.SIGINT)
    assert _wait(rec, 30) == 0, rec.log()

    sent = _hex_lines(published)
    assert len(sent) == COUNT
    meta = load_metadata(bag / "metadata.yaml")
    counts = {t.name: t.message_count for t in meta.topics}
    assert counts == {"/chatter": COUNT, "/scenario": 1}
    assert meta.message_count == COUNT + 1
    with open_bag(bag) as reader:
        recorded = [m.data for m in reader.messages(["/chatter"])]
        qos = reader.topics()["/scenario"].offered_qos
    assert recorded == sent
    assert qos[0].durability.name == "TRANSIENT_LOCAL"

    # 2. Play it to a fresh subscriber: same bytes, same order, /scenario latched again.
    sub = node_process("h2_cli_helper", "sub", str(COUNT), str(received), env=helper_env)
    assert sub.wait_for_log("ready", 30), sub.log()
    play = node_process(
        "dbcslam_ros.cli",
        "play",
        str(bag),
        "--rate",
        "4",
        "--delay",
        "5.0",  # Fast DDS: a missed first announcement is repeated after 3 s
        "--topics",
        "/scenario",
        "/chatter",
    )
    assert _wait(play, 60) == 0, play.log()
    # the helper writes its files before it prints "received"; its own rclpy teardown is not
    # under test (once in ~20 CI runs it outlived 60 s after printing; the fixture stops it)
    assert sub.wait_for_log("received", 60), sub.log()
    assert _hex_lines(received) == sent
    scenario = _hex_lines(Path(f"{received}.scenario"))
    assert len(scenario) == 1
    assert b"scenario: edge" in scenario[0]


def test_sigterm_closes_the_bag_with_every_received_message(
    tmp_path: Path, node_process: Callable[..., Any], helper_env: dict[str, str]
) -> None:
    bag = tmp_path / "stream"
    published = tmp_path / "published.txt"
    rec = node_process("dbcslam_ros.cli", "record", "-o", str(bag))  # all topics
    pub = node_process("h2_cli_helper", "stream", str(published), env=helper_env)
    assert pub.wait_for_log("matched", 30), pub.log()
    time.sleep(1.5)
    os.kill(rec.pid, signal.SIGTERM)  # while messages are still flowing
    assert _wait(rec, 30) == 0, rec.log()
    assert "wrote" in rec.log()

    meta = load_metadata(bag / "metadata.yaml")
    with open_bag(bag) as reader:  # counts of metadata.yaml are checked against the file
        recorded = [m.data for m in reader.messages(["/chatter"])]
        assert reader.counts()["/chatter"] == len(recorded)
    assert {t.name: t.message_count for t in meta.topics}["/chatter"] == len(recorded)
    assert len(recorded) > 10
    sent = _hex_lines(published)
    # What was recorded is a gap-free run of what was published, from the first message.
    assert recorded == sent[: len(recorded)]
    # The recorder's bag opens in the independent readers too.
    with AnyReader([bag], default_typestore=jazzy_typestore()) as reader:
        assert [bytes(raw) for c, _, raw in reader.messages() if c.topic == "/chatter"] == (
            recorded
        )
    with next(bag.glob("*.mcap")).open("rb") as fh:
        decoded = [
            obj.data
            for _, channel, _, obj in make_reader(
                fh, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages()
            if channel.topic == "/chatter"
        ]
    assert decoded[:3] == ["chatter 00000 ", "chatter 00001 z", "chatter 00002 zz"]
    assert len(decoded) == len(recorded)


def test_topic_echo_prints_yaml_documents_list_shows_types_hz_measures(
    node_process: Callable[..., Any], helper_env: dict[str, str]
) -> None:
    talker = node_process("h2_cli_helper", "pose", env=helper_env)
    assert talker.wait_for_log("publishing", 30), talker.log()
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

    def run(*argv: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "dbcslam_ros.cli", *argv],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
        )

    echo = run("topic", "echo", "/scenario", "--once", "--timeout", "20")
    assert echo.returncode == 0, echo.stderr
    assert echo.stdout.endswith("---\n")
    docs = [d for d in yaml.safe_load_all(echo.stdout) if d is not None]
    assert docs == [{"data": "scenario: edge\ndt: 0.01\n"}]

    field = run("topic", "echo", "/object/pose", "--once", "--field", "pose.position")
    assert field.returncode == 0, field.stderr
    docs = [d for d in yaml.safe_load_all(field.stdout) if d is not None]
    assert docs == [{"x": 1.5, "y": -0.25, "z": 0.0}]

    listing = run("topic", "list", "-t", "--spin-time", "4")  # generous: loaded machines
    assert listing.returncode == 0, listing.stderr
    lines = listing.stdout.splitlines()
    assert "/scenario [std_msgs/msg/String]" in lines
    assert "/object/pose [geometry_msgs/msg/PoseStamped]" in lines

    hz = node_process("dbcslam_ros.cli", "topic", "hz", "/object/pose", "--window", "20")
    assert hz.wait_for_log("average rate:", 30), hz.log()
    os.kill(hz.pid, signal.SIGINT)
    assert _wait(hz, 30) == 0, hz.log()
    rate = float(hz.log().split("average rate:")[1].split()[0])
    assert 2.0 < rate < 40.0  # the helper publishes every 50 ms (loosely: loaded machines)

    missing = run("topic", "echo", "/does_not_exist", "--timeout", "1")
    assert missing.returncode == 2
    assert "/does_not_exist" in missing.stderr


def test_killed_recorder_leaves_a_salvageable_bag(
    tmp_path: Path, node_process: Callable[..., Any], helper_env: dict[str, str]
) -> None:
    bag = tmp_path / "killed"
    published = tmp_path / "published.txt"
    rec = node_process("dbcslam_ros.cli", "record", "-o", str(bag), "/chatter", "-q")
    pub = node_process("h2_cli_helper", "stream", str(published), env=helper_env)
    assert pub.wait_for_log("matched", 30), pub.log()
    time.sleep(2.5)  # the recorder flushes a chunk to disk every second
    os.kill(rec.pid, signal.SIGKILL)
    rec.proc.wait(10)
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(BagError, match="truncated"):
        open_bag(bag)
    with open_bag(bag, salvage=True) as reader:
        assert reader.damage is not None
        recorded = [m.data for m in reader.messages(["/chatter"])]
    assert len(recorded) > 5
    assert recorded == _hex_lines(published)[: len(recorded)]
