"""The simulator node (sim_publisher.node): tick sources, and the node as a process on loopback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from dbcslam_core.scenario import Scenario
from sim_publisher.errors import ParamError
from sim_publisher.node import make_source
from sim_publisher.simulate import make_simulation


def test_core_source_matches_the_synthetic_trajectory() -> None:
    from dbcslam_core.synthetic import edge_trajectory

    src = make_source("edge", engine="core", seed=2, duration=1.0)
    traj = edge_trajectory(2, duration=1.0)
    ticks = list(src.ticks)
    assert len(ticks) == src.n_ticks == traj.n_steps == 101
    assert src.period == pytest.approx(0.01)
    np.testing.assert_array_equal(np.stack([t.observed_pose[:2] for t in ticks]), traj.obs)
    np.testing.assert_array_equal(np.stack([t.wrench[:2] for t in ticks]), traj.u)
    assert all(t.observed_pose[2] == 0.0 for t in ticks)  # point mass: yaw 0
    modes = np.stack([t.modes for t in ticks])
    assert modes.shape == (101, 1, 4)
    np.testing.assert_array_equal(modes.sum(axis=2), 1.0)
    np.testing.assert_array_equal(np.argmax(modes, axis=2), traj.modes)
    assert Scenario.from_yaml(src.scenario_yaml) == traj.scenario


def test_core_gripper_source_has_joints() -> None:
    src = make_source("gripper", engine="core", duration=0.5)
    tick = next(src.ticks)
    assert src.joint_names == ("lower_jaw", "upper_jaw")
    assert tick.observed_joints.shape == (2,)
    assert tick.modes.shape == (len(src.contacts), 4)
    assert tick.friction.shape == (len(src.pairs),)


def test_pybullet_source_is_the_simulation() -> None:
    src = make_source("push", engine="pybullet", seed=4, duration=0.2)
    run = make_simulation("push", seed=4, duration=0.2).run()
    ticks = list(src.ticks)
    assert len(ticks) == len(run.records) == src.n_ticks
    for tick, rec in zip(ticks, run.records, strict=True):
        np.testing.assert_array_equal(tick.observed_pose, rec.observed_pose)
        np.testing.assert_array_equal(tick.pusher_wrench, rec.observed_pusher_wrench)
    assert src.scenario_yaml == run.scenario_yaml


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"scenario": "push", "engine": "core"}, ValueError),
        ({"scenario": "edge", "engine": "core", "rate": 50.0}, ValueError),
        ({"scenario": "edge", "engine": "ode"}, ValueError),
        ({"scenario": "edge", "engine": "core", "params_file": "x.yaml"}, ValueError),
        (
            {"scenario": "edge", "engine": "pybullet", "rate": -0.0, "params_file": "/no"},
            ParamError,
        ),
    ],
)
def test_bad_source_requests_fail_clearly(kwargs: dict[str, Any], error: type) -> None:
    scenario = kwargs.pop("scenario")
    with pytest.raises(error):
        make_source(scenario, **kwargs)


# ------------------------------------------------------------------------ node as a process


@pytest.fixture
def sim_process(tmp_path: Path) -> Iterator[Any]:
    """Starts ``python -m sim_publisher.node`` (real rclpy); stopped by PID at teardown."""
    procs: list[subprocess.Popen[bytes]] = []

    def start(*ros_args: str) -> subprocess.Popen[bytes]:
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        log = (tmp_path / f"sim{len(procs)}.log").open("wb")
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim_publisher.node", "--ros-args", *ros_args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGTERM)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(5)


@pytest.fixture
def listener() -> Iterator[Any]:
    from dbcslam_ros import runtime as rt

    rt.init(["test_node_sim"])
    node = rt.Node("test_node_sim_listener")
    yield node
    node.destroy_node()
    rt.try_shutdown()


TOPICS = {
    "/scenario": ("std_msgs/msg/String", "latched"),
    "/object/pose": ("geometry_msgs/msg/PoseStamped", "sensor"),
    "/object/wrench": ("geometry_msgs/msg/WrenchStamped", "sensor"),
    "/joint_states": ("sensor_msgs/msg/JointState", "sensor"),
    "/truth/object/pose": ("geometry_msgs/msg/PoseStamped", "reliable"),
    "/truth/contact_modes": ("std_msgs/msg/Float64MultiArray", "reliable"),
    "/truth/friction": ("std_msgs/msg/Float64MultiArray", "reliable"),
    "/clock": ("rosgraph_msgs/msg/Clock", "clock"),
}


def test_node_publishes_contract_qos_and_exits(sim_process: Any, listener: Any) -> None:
    from dbcslam_ros import runtime as rt

    got: dict[str, list[Any]] = defaultdict(list)
    for topic, (type_name, kind) in TOPICS.items():
        qos = {
            "latched": rt.qos_profile("latched"),
            "sensor": rt.qos_profile("sensor_data", depth=500),
            "reliable": rt.qos_profile("default", depth=500),
            "clock": rt.qos_profile("sensor_data", depth=500),
        }[kind]

        def cb(msg: Any, topic: str = topic) -> None:
            got[topic].append(msg)

        listener.create_subscription(rt.message_class(type_name), topic, cb, qos)
    proc = sim_process(
        "-p", "scenario:=gripper", "-p", "engine:=core", "-p", "duration:=0.5", "-p",
        "fast:=true", "-p", "wait_for_subscribers:=15.0",
    )  # fmt: skip
    offered: dict[str, Any] = {}
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and proc.poll() is None:
        rt.spin_once(listener, timeout_sec=0.02)
        for topic in TOPICS:
            if topic not in offered:
                infos = rt.get_publishers_info(listener, topic)
                if infos:
                    offered[topic] = infos[0].qos_profile
    assert proc.wait(10) == 0
    rt.spin_until(listener, lambda: len(got["/truth/friction"]) >= 51, 3.0)
    assert offered["/scenario"].durability == "transient_local"
    assert offered["/scenario"].reliability == "reliable"
    for topic in ("/object/pose", "/object/wrench", "/joint_states"):
        assert offered[topic].reliability == "best_effort", topic
    for topic in ("/truth/object/pose", "/truth/contact_modes", "/truth/friction"):
        assert offered[topic].reliability == "reliable", topic
    assert "/clock" in offered
    # reliable truth arrives completely: 0.5 s at 100 Hz = 51 samples
    assert len(got["/truth/friction"]) == 51
    assert len(got["/truth/object/pose"]) == 51
    scenario = yaml.safe_load(got["/scenario"][0].data)
    assert scenario["scenario"] == "gripper"
    assert list(got["/joint_states"][0].name) == ["lower_jaw", "upper_jaw"]
    # fast mode stamps with simulated time from 0 and /clock follows it
    stamps = [
        m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in got["/truth/object/pose"]
    ]
    np.testing.assert_allclose(stamps, np.arange(51) * 0.01, atol=1e-9)
    assert got["/clock"], "no /clock in fast mode"


def test_node_bad_parameter_exits_2(sim_process: Any) -> None:
    proc = sim_process("-p", "scenario:=push", "-p", "engine:=core")
    assert proc.wait(30) == 2


def test_node_stops_on_sigterm(sim_process: Any, tmp_path: Path) -> None:
    proc = sim_process(
        "-p", "scenario:=edge", "-p", "engine:=core", "-p", "duration:=30.0", "-p",
        "wait_for_subscribers:=0.0",
    )  # fmt: skip
    log = tmp_path / "sim0.log"
    deadline = time.monotonic() + 20.0
    while "publishing scenario" not in log.read_text() and time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(10) == 0
    assert "Traceback" not in log.read_text()
