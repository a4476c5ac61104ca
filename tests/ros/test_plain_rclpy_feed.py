"""A plain rclpy node that is not part of the project feeds a recorded run into the filter.

The feeder below imports only rclpy, the message packages and rosbags (to read the bag): it
publishes the bag's ``/scenario`` (latched) and input topics at the recorded pace (held back
while the filter has not answered the previous pose, so machine load cannot drop poses) and counts
the ``/dbcslam/pose`` estimates that come back from ``dbcslam_ros.node.filter_node`` running as a
separate process. Nearly every pose must be answered.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]

FEEDER = r"""
import sys, time
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, DurabilityPolicy, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from std_msgs.msg import String
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from sensor_msgs.msg import JointState

TYPES = {"/scenario": String, "/object/pose": PoseStamped, "/object/wrench": WrenchStamped,
         "/joint_states": JointState}

def main():
    rclpy.init()
    node = Node("plain_feeder")
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pubs = {t: node.create_publisher(c, t, latched if t == "/scenario" else 100)
            for t, c in TYPES.items()}
    got = []
    def on_estimate(msg):
        got.append(msg)
    node.create_subscription(PoseWithCovarianceStamped, "/dbcslam/pose", on_estimate, 1000)
    with AnyReader([__import__("pathlib").Path(sys.argv[1])]) as reader:
        conns = [c for c in reader.connections if c.topic in TYPES]
        msgs = [(t, c.topic, raw) for c, t, raw in reader.messages(connections=conns)]
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and (
        pubs["/object/pose"].get_subscription_count() == 0
        or node.count_publishers("/dbcslam/pose") == 0
    ):
        rclpy.spin_once(node, timeout_sec=0.05)
    end = time.monotonic() + 1.5  # let the reader side of discovery finish
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    t0_bag, t0 = msgs[0][0], time.monotonic()
    poses = 0
    for t, topic, raw in msgs:
        t0 += max(0.0, time.monotonic() - (t0 + (t - t0_bag) / 1e9))  # held back: shift
        while time.monotonic() < t0 + (t - t0_bag) / 1e9:
            rclpy.spin_once(node, timeout_sec=0.002)
        answered = len(got)
        pubs[topic].publish(rclpy.serialization.deserialize_message(raw, TYPES[topic]))
        if topic == "/object/pose":
            poses += 1
            # the recorded pace, but never ahead of the filter: wait for this pose's answer
            # (or 2 s, if it was rejected), so a loaded machine slows the run down instead of
            # making the filter drop poses as backlog
            answer_by = time.monotonic() + 2.0
            while time.monotonic() < answer_by and len(got) == answered:
                rclpy.spin_once(node, timeout_sec=0.002)
    end = time.monotonic() + 5.0
    while time.monotonic() < end and len(got) < poses:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(f"poses {poses} estimates {len(got)}", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()

import rclpy.serialization
main()
"""


def test_plain_rclpy_node_feeds_the_filter(tmp_path: Path, node_process: Any) -> None:
    script = tmp_path / "plain_feeder.py"
    script.write_text(FEEDER)
    filt = node_process("dbcslam_ros.node.filter_node", "--ros-args", "-p", "particles:=50")
    import subprocess

    out = subprocess.run(
        [sys.executable, str(script), str(REPO / "bags" / "edge")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    words = out.stdout.split()
    poses, estimates = int(words[1]), int(words[3])
    assert poses == 301
    # nearly every pose answered (a few are rejected by the filter's outlier gate)
    assert estimates >= 0.95 * poses, (out.stdout, filt.log()[-3000:])
    print(out.stdout)
    assert filt.proc.poll() is None, filt.log()
