"""The filter node process under bad input: it rejects, counts, keeps running, resets on loops.

The test process plays the simulator: it publishes the latched /scenario and the core's
synthetic edge trajectory, with bad messages mixed in, then reads /diagnostics.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest

from dbcslam_ros import runtime as rt
from dbcslam_ros.convert import ns_to_stamp, pose_stamped, wrench_stamped

NS = 1_000_000_000
T0 = 100 * NS


class FakeSim:
    """Publishes the contract inputs like sim_publisher (sensor-data QoS, latched scenario)."""

    def __init__(self, node: Any, scenario_yaml: str) -> None:
        self.node = node
        sensor = rt.qos_profile("sensor_data", depth=10)
        cls = rt.message_class
        self.scenario = node.create_publisher(
            cls("std_msgs/msg/String"), "/scenario", rt.qos_profile("latched")
        )
        self.pose = node.create_publisher(
            cls("geometry_msgs/msg/PoseStamped"), "/object/pose", sensor
        )
        self.wrench = node.create_publisher(
            cls("geometry_msgs/msg/WrenchStamped"), "/object/wrench", sensor
        )
        self.joints = node.create_publisher(
            cls("sensor_msgs/msg/JointState"), "/joint_states", sensor
        )
        self.scenario.publish(cls("std_msgs/msg/String")(data=scenario_yaml))
        self.diags: list[Any] = []
        self.poses_out: list[Any] = []
        node.create_subscription(
            cls("diagnostic_msgs/msg/DiagnosticArray"),
            "/diagnostics",
            self.diags.append,
            rt.qos_profile("default", depth=100),
        )
        node.create_subscription(
            cls("geometry_msgs/msg/PoseWithCovarianceStamped"),
            "/dbcslam/pose",
            self.poses_out.append,
            rt.qos_profile("default", depth=1000),
        )

    def joint_state(self, stamp_ns: int, names: list[str], pos: list[float]) -> None:
        cls = rt.message_class("sensor_msgs/msg/JointState")
        header = rt.message_class("std_msgs/msg/Header")(stamp=ns_to_stamp(stamp_ns))
        self.joints.publish(cls(header=header, name=names, position=pos, velocity=[], effort=[]))

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rt.spin_once(self.node, timeout_sec=0.01)

    def values(self) -> dict[str, str]:
        return {kv.key: kv.value for kv in self.diags[-1].status[0].values}

    def wait_for(self, pred: Any, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rt.spin_once(self.node, timeout_sec=0.02)
            if self.diags and pred(self.values()):
                return True
        return False


@pytest.fixture
def fake_sim(rt_context: Any) -> FakeSim:
    from dbcslam_core.synthetic import edge_trajectory

    node = rt_context("fake_sim")
    return FakeSim(node, edge_trajectory(0, duration=0.1).scenario.to_yaml())


def _play(sim: FakeSim, traj: Any, ks: range, t0: int, bad: dict[int, Any]) -> None:
    for k in ks:
        stamp = t0 + k * NS // 100
        sim.joint_state(stamp, [], [])
        fx, fy = (float(v) for v in traj.u[k])
        sim.wrench.publish(wrench_stamped(stamp, fx, fy, 0.0))
        if k in bad:
            bad[k](stamp)
        x, y = (float(v) for v in traj.obs[k])
        sim.pose.publish(pose_stamped(stamp, x, y, 0.0))
        sim.spin(0.01)


def test_bad_messages_are_counted_and_the_node_survives(
    node_process: Any, fake_sim: FakeSim
) -> None:
    from dbcslam_core.synthetic import edge_trajectory

    filt = node_process(
        "dbcslam_ros.node.filter_node",
        "--ros-args",
        "-p",
        "particles:=50",
        "-p",
        "diagnostics_period:=0.2",
        "-p",
        "marker_particles:=0",
    )
    assert fake_sim.wait_for(lambda v: v.get("scenario") == "edge", 20.0), filt.log()
    traj = edge_trajectory(0, duration=1.5)
    sim = fake_sim

    def nan_pose(stamp: int) -> None:
        msg = pose_stamped(stamp, 0.0, 0.0, 0.0)
        msg.pose.position.y = math.nan
        sim.pose.publish(msg)

    def zero_quaternion(stamp: int) -> None:
        msg = pose_stamped(stamp, 0.0, 0.0, 0.0)
        msg.pose.orientation.w = 0.0
        sim.pose.publish(msg)

    def backwards(stamp: int) -> None:
        x, y = (float(v) for v in traj.obs[10])
        sim.pose.publish(pose_stamped(stamp - 200_000_000, x, y, 0.0))

    def unknown_joint(stamp: int) -> None:
        sim.joint_state(stamp, ["elbow"], [0.3])

    def nan_wrench(stamp: int) -> None:
        sim.wrench.publish(wrench_stamped(stamp, math.nan, 0.0, 0.0))

    bad = {30: nan_pose, 50: zero_quaternion, 70: backwards, 90: unknown_joint, 110: nan_wrench}
    _play(sim, traj, range(traj.n_steps), T0, bad)
    ok = sim.wait_for(
        lambda v: all(
            int(v.get(f"rejected_{r}", "0")) >= 1
            for r in ("nan", "zero_quaternion", "stamp_order", "unknown_joint")
        ),
        10.0,
    )
    values = sim.values()
    assert ok, (sorted(values.items()), filt.log())
    assert int(values["rejected_nan"]) >= 2  # the pose and the wrench
    assert filt.proc.poll() is None, filt.log()
    assert values["resets"] == "0"
    # estimates kept coming after the bad messages and none is NaN
    stamps = [m.header.stamp.sec * NS + m.header.stamp.nanosec for m in sim.poses_out]
    assert max(stamps) >= T0 + 140 * NS // 100
    for m in sim.poses_out:
        assert np.all(np.isfinite([m.pose.pose.position.x, m.pose.pose.position.y]))
    assert "Traceback" not in filt.log()

    # a bag played with --loop: time jumps back to the start -> clean reset, estimates resume
    n_before = len(sim.poses_out)
    _play(sim, traj, range(40), T0, {})
    assert sim.wait_for(lambda v: int(v["resets"]) >= 1, 5.0), (sim.values(), filt.log())
    sim.spin(0.3)
    after = [m for m in sim.poses_out[n_before:]]
    assert after, "no estimates after the reset"
    last = after[-1]
    k = round((last.header.stamp.sec * NS + last.header.stamp.nanosec - T0) / (NS // 100))
    assert k < 40
    err = math.hypot(
        last.pose.pose.position.x - traj.q[k, 0], last.pose.pose.position.y - traj.q[k, 1]
    )
    assert err < 3 * traj.scenario.noise.position
    assert filt.proc.poll() is None
    assert filt.terminate() == 0


@pytest.mark.parametrize(
    ("param", "needle"),
    [("catch_up_steps:=0", "catch_up_steps"), ("model_file:=/no/such.yaml", "/no/such.yaml")],
)
def test_filter_rejects_bad_parameters(node_process: Any, param: str, needle: str) -> None:
    filt = node_process("dbcslam_ros.node.filter_node", "--ros-args", "-p", param)
    assert filt.proc.wait(20) == 2
    assert needle in filt.log()
    assert "Traceback" not in filt.log()


def test_lost_filter_is_reinitialised(node_process: Any, fake_sim: FakeSim) -> None:
    """The object 'teleports' 0.5 m (e.g. the tracker re-acquired another marker): after a
    few gated poses the filter is declared lost, reset, and tracks the new position."""
    from dbcslam_core.synthetic import edge_trajectory

    filt = node_process(
        "dbcslam_ros.node.filter_node", "--ros-args", "-p", "particles:=50",
        "-p", "diagnostics_period:=0.2", "-p", "marker_particles:=0",
    )  # fmt: skip
    sim = fake_sim
    assert sim.wait_for(lambda v: v.get("scenario") == "edge", 20.0), filt.log()
    traj = edge_trajectory(0, duration=1.2)
    shifted = np.array(traj.obs, copy=True)
    shifted[60:, 0] += 0.5

    class Shifted:
        u = traj.u
        obs = shifted

    _play(sim, Shifted, range(traj.n_steps), T0, {})
    assert sim.wait_for(lambda v: int(v.get("rejected_diverged", "0")) >= 1, 5.0), (
        sorted(sim.values().items()),
        filt.log(),
    )
    sim.spin(0.3)
    last = sim.poses_out[-1]
    k = round((last.header.stamp.sec * NS + last.header.stamp.nanosec - T0) / (NS // 100))
    assert k > 80
    assert abs(last.pose.pose.position.x - (traj.q[k, 0] + 0.5)) < 0.05
    assert filt.proc.poll() is None
