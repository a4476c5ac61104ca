"""Feed a recorded run into a live filter node with rclpy, interleaved with hostile messages.

Run as a separate process by ``tests/ros/test_hostile_inputs.py`` (not a test module)::

    python tests/ros/hostile_feed.py BAG OUT.json --bad 10000 --seed 0

It publishes the bag's ``/scenario`` and inputs in stamp order (raw CDR, paced), and after
every valid sample a burst of malformed or hostile messages (non-finite fields, zero and
non-unit quaternions, stamps backwards, far back and far in the future, JointState with wrong
lengths / unknown names / huge arrays, a pusher wrench where there is no pusher, invalid,
hostile or enormous ``/scenario`` YAML). It listens to every filter output and writes what it
sent (per expected rejection reason), every non-finite number it received, the last
``/diagnostics`` values and the tracking error against the bag's truth to OUT.json.
"""

from __future__ import annotations

import argparse
import array
import json
import math
import random
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from dbcslam_ros.contract import DIAGNOSTICS, JOINT_STATES, OUTPUT_TOPICS, SCENARIO
from dbcslam_ros.contract import OBJECT_POSE as POSE
from dbcslam_ros.contract import OBJECT_WRENCH as WRENCH
from dbcslam_ros.contract import PUSHER_WRENCH as PUSHER
from dbcslam_ros.network import apply_loopback_defaults

JOINTS = JOINT_STATES
OUTPUTS = tuple(t for t in OUTPUT_TOPICS if t != DIAGNOSTICS)

HOSTILE_SCENARIOS = (
    "scenario: [unclosed",
    "a: &x [1, 2]\nb: *x\n",
    'l0: &a ["lol", "lol"]\nl1: &b [*a, *a, *a]\nl2: &c [*b, *b, *b]\nl3: [*c, *c, *c]\n',
    "x: " + "9" * (300 * 1024),
    "!!python/object/apply:os.system ['true']",
    "- just\n- a list\n",
    "scenario: edge\ndt: abc\n",
    "scenario: edge\ndt: -0.01\ncontacts: [edge]\n",
    "scenario: warp_drive\n",
    "\x00\x01\x02",
    "",
)


def read_bag(bag: Path) -> tuple[list[tuple[int, str, bytes]], str]:
    """(log_time, topic, cdr) of the bag's messages in log order, and its /scenario text."""
    from mcap.reader import make_reader

    rows: list[tuple[int, str, bytes]] = []
    for path in sorted(bag.glob("*.mcap")):
        with path.open("rb") as fh:
            for _schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                rows.append((message.log_time, channel.topic, bytes(message.data)))
    rows.sort(key=lambda r: r[0])
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    scen = next(r for r in rows if r[1] == SCENARIO)
    return rows, str(deserialize_message(scen[2], String).data)


def non_finite(msg: Any, where: str, out: list[str]) -> None:
    """Append the path of every non-finite float in a ROS message (recursively)."""
    if isinstance(msg, float):
        if not math.isfinite(msg):
            out.append(where)
        return
    if isinstance(msg, (list, tuple, array.array)) or type(msg).__name__ == "ndarray":
        for i, v in enumerate(msg):
            non_finite(v, f"{where}[{i}]", out)
        return
    fields = getattr(msg, "get_fields_and_field_types", None)
    if fields is None:
        return
    for name in fields():
        non_finite(getattr(msg, name), f"{where}.{name}", out)


class Feed:
    """The publishing and listening node (rclpy is imported after the network defaults)."""

    def __init__(self, seed: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray, String
        from visualization_msgs.msg import MarkerArray

        self.rclpy = rclpy
        self.rng = random.Random(seed)
        self.node = rclpy.create_node("hostile_feed")
        rel = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.types = {
            POSE: PoseStamped,
            WRENCH: WrenchStamped,
            JOINTS: JointState,
            PUSHER: WrenchStamped,
            SCENARIO: String,
        }
        self.pubs = {
            t: self.node.create_publisher(c, t, latched if t == SCENARIO else rel)
            for t, c in self.types.items()
        }
        out_types = {
            "/dbcslam/pose": PoseWithCovarianceStamped,
            "/dbcslam/odometry": Odometry,
            "/dbcslam/contact_modes": Float64MultiArray,
            "/dbcslam/friction": Float64MultiArray,
            "/dbcslam/friction_map": OccupancyGrid,
            "/dbcslam/markers": MarkerArray,
        }
        self.received: Counter[str] = Counter()
        self.bad_numbers: list[str] = []
        self.estimates: dict[int, tuple[float, float]] = {}
        self.diagnostics: dict[str, str] = {}
        for topic, cls in out_types.items():
            self.node.create_subscription(
                cls, topic, lambda m, t=topic: self._on_output(t, m), 1000
            )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        self.sent: Counter[str] = Counter()

    def _on_output(self, topic: str, msg: Any) -> None:
        self.received[topic] += 1
        found: list[str] = []
        non_finite(msg, topic, found)
        self.bad_numbers.extend(found[:5])
        if topic == "/dbcslam/pose":
            st = msg.header.stamp
            p = msg.pose.pose.position
            self.estimates[st.sec * 1_000_000_000 + st.nanosec] = (p.x, p.y)

    def _on_diag(self, msg: Any) -> None:
        self.received["/diagnostics"] += 1
        for status in msg.status:
            if status.name.endswith("dbcslam_filter") or "filter" in status.name:
                values = {kv.key: kv.value for kv in status.values}
                for k, v in values.items():
                    try:
                        if not math.isfinite(float(v)):
                            self.bad_numbers.append(f"/diagnostics.{k}={v}")
                    except ValueError:
                        pass
                self.diagnostics = values

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while True:
            self.rclpy.spin_once(self.node, timeout_sec=0.0)
            if time.monotonic() >= end:
                return
            time.sleep(0.0005)

    # -- hostile messages --------------------------------------------------------------
    def _stamped(self, cls: Any, stamp_ns: int) -> Any:
        msg = cls()
        msg.header.frame_id = "world"
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        msg.header.stamp.sec = max(-(2**31), min(2**31 - 1, sec))
        msg.header.stamp.nanosec = nsec
        return msg

    def _pose(self, stamp_ns: int, x: float, y: float, q: tuple[float, ...]) -> Any:
        msg = self._stamped(self.types[POSE], stamp_ns)
        msg.pose.position.x, msg.pose.position.y = x, y
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = q
        return msg

    def send_bad(self, kind: int, last_ns: int, last_xy: tuple[float, float]) -> None:
        """Publish one hostile message of kind ``kind`` (round robin); count its reason."""
        x, y = last_xy
        unit = (0.0, 0.0, 0.0, 1.0)
        nan, inf = math.nan, math.inf
        bad = self.rng.choice((nan, inf, -inf))
        k = kind % 14
        if k == 0:
            self._send(POSE, self._pose(last_ns + 1, bad, y, unit), "nan")
        elif k == 1:
            self._send(POSE, self._pose(last_ns + 1, x, y, (0.0, 0.0, bad, 1.0)), "nan")
        elif k == 2:
            self._send(
                POSE, self._pose(last_ns + 1, x, y, (0.0, 0.0, 0.0, 0.0)), "zero_quaternion"
            )
        elif k == 3:  # non-unit quaternion, repeated stamp
            scale = self.rng.choice((1e-6, 1e6, 1e300))
            self._send(POSE, self._pose(last_ns, x, y, (0.0, 0.0, 0.0, scale)), "stamp_order")
        elif k == 4:  # slightly backwards
            self._send(POSE, self._pose(last_ns - 200_000_000, x, y, unit), "stamp_order")
        elif k == 5:  # far back
            self._send(POSE, self._pose(last_ns - 10**11, x, y, unit), "stamp_time")
        elif k == 6:  # far in the future, plausible position
            self._send(POSE, self._pose(last_ns + 10**15, x, y, unit), "stamp_time")
        elif k == 7:  # far in the future, absurd position
            self._send(POSE, self._pose(last_ns + 10**9 * 3600, 1e9, -1e9, unit), "stamp_time")
        elif k == 8:
            w = self._stamped(self.types[WRENCH], last_ns)
            w.wrench.force.x = bad
            self._send(WRENCH, w, "nan")
        elif k == 9:
            j = self._stamped(self.types[JOINTS], last_ns)
            j.name = ["a", "b"]
            j.position = [0.0]
            self._send(JOINTS, j, "malformed")
        elif k == 10:
            j = self._stamped(self.types[JOINTS], last_ns)
            j.name = ["warp_coil"]
            j.position = [bad]
            self._send(JOINTS, j, "unknown_joint")
        elif k == 11:
            j = self._stamped(self.types[JOINTS], last_ns)
            n = self.rng.choice((1000, 20000))
            j.name = [f"j{i}" for i in range(n)]
            j.position = [0.0] * n
            self._send(JOINTS, j, "unknown_joint")
        elif k == 12:
            p = self._stamped(self.types[PUSHER], last_ns)
            p.wrench.force.x = 1.0
            self._send(PUSHER, p, self.pusher_reason)
        else:
            text = HOSTILE_SCENARIOS[(kind // 14) % len(HOSTILE_SCENARIOS)]
            self._send(SCENARIO, self.types[SCENARIO](data=text), "bad_scenario")

    pusher_reason = "no_pusher"

    def _send(self, topic: str, msg: Any, reason: str) -> None:
        self.pubs[topic].publish(msg)
        self.sent[reason] += 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("bag", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--bad", type=int, default=10000, help="hostile messages in total")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--period", type=float, default=0.02, help="s between valid samples")
    args = ap.parse_args(argv)

    apply_loopback_defaults()
    import rclpy
    import yaml
    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import deserialize_message

    rclpy.init()
    feed = Feed(args.seed)
    rows, scenario_text = read_bag(args.bag)
    noise = float(yaml.safe_load(scenario_text)["noise"]["position"])
    truth = {}
    for _t, topic, data in rows:
        if topic == "/truth/object/pose":
            m = deserialize_message(data, PoseStamped)
            truth[m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec] = (
                m.pose.position.x,
                m.pose.position.y,
            )
    feed.pubs[SCENARIO].publish(feed.types[SCENARIO](data=scenario_text))
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and "scenario" not in feed.diagnostics:
        feed.spin_for(0.1)
    configured_after = round(20.0 - (deadline - time.monotonic()), 2)
    inputs = [r for r in rows if r[1] in (POSE, WRENCH, JOINTS)]
    n_poses = sum(1 for r in inputs if r[1] == POSE)
    per_pose = math.ceil(args.bad / max(1, n_poses))
    kind = 0
    last_ns, last_xy = 0, (0.0, 0.0)
    t_next = time.monotonic()
    for _t, topic, data in inputs:
        feed.pubs[topic].publish(data)  # raw CDR
        if topic != POSE:
            continue
        m = deserialize_message(data, PoseStamped)
        last_ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        last_xy = (m.pose.position.x, m.pose.position.y)
        feed.spin_for(0.004)  # let the node take the valid pose first
        for _ in range(per_pose):
            if sum(feed.sent.values()) >= args.bad:
                break
            feed.send_bad(kind, last_ns, last_xy)
            kind += 1
            if kind % 8 == 0:
                feed.spin_for(0.0005)
        t_next += args.period
        feed.spin_for(max(0.0, t_next - time.monotonic()))
    feed.spin_for(3.0)  # the last estimates and two diagnostics periods
    errors = [
        (ex - truth[s][0]) ** 2 + (ey - truth[s][1]) ** 2
        for s, (ex, ey) in feed.estimates.items()
        if s in truth
    ]
    rmse = math.sqrt(sum(errors) / (2 * len(errors))) if errors else math.inf
    result = {
        "configured_after_s": configured_after,
        "valid_poses": n_poses,
        "sent": dict(feed.sent),
        "sent_total": sum(feed.sent.values()),
        "received": dict(feed.received),
        "non_finite": feed.bad_numbers[:50],
        "diagnostics": feed.diagnostics,
        "matched_estimates": len(errors),
        "position_rmse_per_axis": rmse,
        "noise_position": noise,
    }
    args.out.write_text(json.dumps(result, indent=1))
    feed.node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
