"""The simulator node and the filter node as two processes over DDS on loopback.

Two shared runs (module scope), each recorded by an in-process listener node:

* ``core_edge``: the filter starts first and waits for the latched /scenario; the simulator
  publishes the core's synthetic edge trajectory (engine core) in real time.
* ``bullet_push``: the simulator (pybullet, push) starts first and publishes the latched
  /scenario before the filter exists; the filter joins late and still configures from it.

Thresholds are deliberately loose (this is a plumbing test; accuracy lives in tests/core).
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
import yaml
from rclpy.executors import SingleThreadedExecutor

from dbcslam_ros import runtime as rt
from dbcslam_ros.convert import array_from_msg, stamp_to_ns

INPUT_TYPES = {
    "/object/pose": "geometry_msgs/msg/PoseStamped",
    "/object/wrench": "geometry_msgs/msg/WrenchStamped",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/scenario": "std_msgs/msg/String",
    "/truth/object/pose": "geometry_msgs/msg/PoseStamped",
    "/truth/contact_modes": "std_msgs/msg/Float64MultiArray",
    "/truth/friction": "std_msgs/msg/Float64MultiArray",
}
OUTPUT_TYPES = {
    "/dbcslam/pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/dbcslam/odometry": "nav_msgs/msg/Odometry",
    "/dbcslam/contact_modes": "std_msgs/msg/Float64MultiArray",
    "/dbcslam/friction": "std_msgs/msg/Float64MultiArray",
    "/dbcslam/friction_map": "nav_msgs/msg/OccupancyGrid",
    "/dbcslam/markers": "visualization_msgs/msg/MarkerArray",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}
SENSOR = {"/object/pose", "/object/wrench", "/joint_states", "/pusher/wrench"}


@dataclass
class Recording:
    """Messages per topic (in arrival order), the graph seen mid-run and process results."""

    msgs: dict[str, list[Any]] = field(default_factory=lambda: defaultdict(list))
    graph: dict[str, list[str]] = field(default_factory=dict)
    sim_code: int | None = None
    filter_alive: bool = False
    sim_log: str = ""
    filter_log: str = ""

    def diagnostics(self) -> dict[str, str]:
        """Key/values of the last /diagnostics message."""
        last = self.msgs["/diagnostics"][-1]
        return {kv.key: kv.value for kv in last.status[0].values}


def _subscribe_all(node: Any, rec: Recording, extra: dict[str, str]) -> list[Any]:
    subs = []
    topics = {**INPUT_TYPES, **OUTPUT_TYPES, **extra}
    for topic, type_name in topics.items():
        if topic == "/scenario":
            qos = rt.qos_profile("latched")
        elif topic in SENSOR:
            qos = rt.qos_profile("sensor_data", depth=1000)
        else:
            qos = rt.qos_profile("default", depth=1000)

        def cb(msg: Any, topic: str = topic) -> None:
            rec.msgs[topic].append(msg)

        subs.append(node.create_subscription(rt.message_class(type_name), topic, cb, qos))
    return subs


def _record(
    node: Any,
    rec: Recording,
    subs: list[Any],
    procs: tuple[Any, Any],
    until_s: float,
    graph_after: int,
) -> None:
    """Spin until the sim exited and nothing arrived for 1.5 s (the filter published its last
    outputs and this listener, one callback per spin, caught up with its queues)."""
    sim, filt = procs
    deadline = time.monotonic() + until_s
    sim_done = False
    total, quiet_since = -1, time.monotonic()
    # one executor for the whole run: rclpy.spin_once(node) adds and removes the node (and
    # rebuilds its wait set) on every call, too slow to keep up with a fast run
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        if not rec.graph and len(rec.msgs["/dbcslam/pose"]) >= graph_after:
            rec.graph = {t: list(ts) for t, ts in rt.get_topic_names_and_types(node)}
        now_total = sum(len(v) for v in rec.msgs.values())
        if now_total != total:
            total, quiet_since = now_total, time.monotonic()
        sim_done = sim_done or sim.proc.poll() is not None
        if sim_done and time.monotonic() - quiet_since > 1.5:
            break
    executor.remove_node(node)
    executor.shutdown()
    rec.sim_code = sim.proc.poll()
    rec.filter_alive = filt.proc.poll() is None
    rec.sim_log = sim.log()
    rec.filter_log = filt.log()
    for sub in subs:
        node.destroy_subscription(sub)


@pytest.fixture(scope="module")
def listener_node() -> Any:
    rt.init(["test_nodes_live"])
    node = rt.Node("test_nodes_live_listener")
    yield node
    node.destroy_node()
    rt.try_shutdown()


FILTER_ARGS = ("-p", "diagnostics_period:=0.25", "-p", "marker_particles:=20")


@pytest.fixture(scope="module")
def core_edge(listener_node: Any, module_processes: Any) -> Recording:
    rec = Recording()
    subs = _subscribe_all(listener_node, rec, {})
    filt = module_processes.start(
        "dbcslam_ros.node.filter_node", "--ros-args", "-p", "particles:=100", *FILTER_ARGS
    )
    sim = module_processes.start(
        "sim_publisher.node",
        "--ros-args",
        "-p",
        "scenario:=edge",
        "-p",
        "engine:=core",
        "-p",
        "duration:=2.5",
        "-p",
        "wait_for_subscribers:=15.0",
    )
    _record(listener_node, rec, subs, (sim, filt), until_s=40.0, graph_after=20)
    filt.terminate()
    return rec


@pytest.fixture(scope="module")
def bullet_push(listener_node: Any, module_processes: Any, core_edge: Recording) -> Recording:
    del core_edge  # run after it (one run at a time on 2 cores)
    rec = Recording()
    subs = _subscribe_all(
        listener_node, rec, {"/pusher/wrench": "geometry_msgs/msg/WrenchStamped"}
    )
    sim = module_processes.start(
        "sim_publisher.node",
        "--ros-args",
        "-p",
        "scenario:=push",
        "-p",
        "engine:=pybullet",
        "-p",
        "duration:=2.0",
        "-p",
        "rate:=50.0",  # model step 0.02 s: half the filter load on a shared 2-core machine
        "-p",
        "wait_for_subscribers:=30.0",
        "-p",
        "min_subscribers:=2",  # this listener and the filter
    )
    # the sim publishes the latched /scenario before the filter exists
    deadline = time.monotonic() + 20.0
    while not rec.msgs["/scenario"] and time.monotonic() < deadline:
        rt.spin_once(listener_node, timeout_sec=0.05)
    assert rec.msgs["/scenario"], sim.log()
    filt = module_processes.start(
        "dbcslam_ros.node.filter_node", "--ros-args", "-p", "particles:=60", *FILTER_ARGS
    )
    _record(listener_node, rec, subs, (sim, filt), until_s=40.0, graph_after=20)
    filt.terminate()
    return rec


def _estimate_errors(rec: Recording) -> np.ndarray:
    truth = {stamp_to_ns(m.header.stamp): m.pose.position for m in rec.msgs["/truth/object/pose"]}
    errs = []
    for m in rec.msgs["/dbcslam/pose"]:
        p = m.pose.pose.position
        t = truth.get(stamp_to_ns(m.header.stamp))
        if t is not None:
            errs.append(np.hypot(p.x - t.x, p.y - t.y))
    return np.asarray(errs)


RUNS = ["core_edge", "bullet_push"]


@pytest.mark.parametrize("run", RUNS)
def test_run_completes_and_filter_survives(run: str, request: pytest.FixtureRequest) -> None:
    rec: Recording = request.getfixturevalue(run)
    assert rec.sim_code == 0, rec.sim_log
    assert rec.filter_alive, rec.filter_log
    assert "Traceback" not in rec.filter_log + rec.sim_log
    n_obs = len(rec.msgs["/object/pose"])
    n_est = len(rec.msgs["/dbcslam/pose"])
    assert n_obs > 90
    assert n_est > 0.2 * n_obs, (n_est, n_obs, rec.diagnostics())


@pytest.mark.parametrize("run", RUNS)
def test_position_error_against_truth(run: str, request: pytest.FixtureRequest) -> None:
    rec: Recording = request.getfixturevalue(run)
    scenario = yaml.safe_load(rec.msgs["/scenario"][-1].data)
    noise = float(scenario["noise"]["position"])
    errs = _estimate_errors(rec)
    assert errs.size > 20
    assert float(np.mean(errs)) < 3.0 * noise, (np.mean(errs), noise)


@pytest.mark.parametrize("run", RUNS)
def test_outputs_are_distributions_without_nan(run: str, request: pytest.FixtureRequest) -> None:
    rec: Recording = request.getfixturevalue(run)
    scenario = yaml.safe_load(rec.msgs["/scenario"][-1].data)
    n_contacts = len(scenario["contacts"])
    n_pairs = len(scenario["friction"]["pairs"])
    for m in rec.msgs["/dbcslam/contact_modes"]:
        modes = array_from_msg(m)
        assert [d.label for d in m.layout.dim] == ["contacts", "modes"]
        assert modes.shape == (n_contacts, 4)
        np.testing.assert_allclose(modes.sum(axis=1), 1.0, atol=1e-6)
    for m in rec.msgs["/dbcslam/friction"]:
        fric = array_from_msg(m)
        assert [d.label for d in m.layout.dim] == ["pairs", "candidates"]
        assert fric.shape[0] == n_pairs
        np.testing.assert_allclose(fric.sum(axis=1), 1.0, atol=1e-6)
    for m in rec.msgs["/dbcslam/pose"]:
        values = [m.pose.pose.position.x, m.pose.pose.position.y, *m.pose.covariance]
        assert np.all(np.isfinite(values))
    # outputs of a step arrive together, pose first: every odometry stamp has a pose
    pose_stamps = {stamp_to_ns(m.header.stamp) for m in rec.msgs["/dbcslam/pose"]}
    odom_stamps = {stamp_to_ns(m.header.stamp) for m in rec.msgs["/dbcslam/odometry"]}
    assert odom_stamps <= pose_stamps


@pytest.mark.parametrize("run", RUNS)
def test_truth_topics_layout(run: str, request: pytest.FixtureRequest) -> None:
    rec: Recording = request.getfixturevalue(run)
    scenario = yaml.safe_load(rec.msgs["/scenario"][-1].data)
    for m in rec.msgs["/truth/contact_modes"]:
        modes = array_from_msg(m)
        assert [d.label for d in m.layout.dim] == ["contacts", "modes"]
        assert modes.shape == (len(scenario["contacts"]), 4)
        assert set(np.unique(modes)) <= {0.0, 1.0}
        np.testing.assert_array_equal(modes.sum(axis=1), 1.0)
    for m in rec.msgs["/truth/friction"]:
        assert [d.label for d in m.layout.dim] == ["pairs"]
        assert array_from_msg(m).shape == (len(scenario["friction"]["pairs"]),)
    # observations arrive in stamp order (one sample per tick)
    pose_stamps = [stamp_to_ns(m.header.stamp) for m in rec.msgs["/object/pose"]]
    assert pose_stamps == sorted(pose_stamps)


def test_every_contract_topic_present_with_its_type(bullet_push: Recording) -> None:
    graph = bullet_push.graph
    assert graph, "graph was never sampled"
    expected = {**INPUT_TYPES, **OUTPUT_TYPES, "/pusher/wrench": "geometry_msgs/msg/WrenchStamped"}
    for topic, type_name in expected.items():
        assert topic in graph, f"{topic} missing from {sorted(graph)}"
        assert type_name in graph[topic], (topic, graph[topic])


def _numbers(tree: Any) -> list[float]:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in _numbers(v)]
    if isinstance(tree, list):
        return [x for v in tree for x in _numbers(v)]
    if isinstance(tree, (int, float)) and not isinstance(tree, bool):
        return [float(tree)]
    return []


def _keys(tree: Any) -> set[str]:
    if isinstance(tree, dict):
        return set(tree) | {k for v in tree.values() for k in _keys(v)}
    if isinstance(tree, list):
        return {k for v in tree for k in _keys(v)}
    return set()


def test_scenario_carries_no_truth(core_edge: Recording, bullet_push: Recording) -> None:
    from dbcslam_core.synthetic import EDGE_ROUGH
    from sim_publisher.params import PushParams

    edge = yaml.safe_load(core_edge.msgs["/scenario"][-1].data)
    assert edge["scenario"] == "edge"
    # the rough region [0.45, 0.85] of the true friction layout appears nowhere
    for value in EDGE_ROUGH:
        assert all(abs(x - value) > 1e-9 for x in _numbers(edge)), (value, edge)
    push = yaml.safe_load(bullet_push.msgs["/scenario"][-1].data)
    true_params = PushParams()
    assert push["friction"]["pairs"] == ["pusher", true_params.support_pair]
    # each pair's true coefficient is one candidate of a prior that does not single it out
    prior = push["friction"]["prior"]
    flat_prior = _numbers(prior)
    assert max(flat_prior) - min(flat_prior) < 1e-9, prior
    for forbidden in ("mu", "mu_pusher", "mu_surface", "segments", "jaw_mu", "truth", "true"):
        assert forbidden not in _keys(edge) | _keys(push)


def test_diagnostics_report_health(core_edge: Recording) -> None:
    diag = core_edge.diagnostics()
    for key in (
        "ess",
        "live_hypotheses",
        "step_time_ms_mean",
        "latency_ms_mean",
        "input_rate_hz",
        "rejected_total",
        "resets",
    ):
        assert key in diag, sorted(diag)
    assert float(diag["ess"]) > 0.0
    assert float(diag["latency_ms_mean"]) > 0.0
    assert int(diag["estimates_published"]) == len(core_edge.msgs["/dbcslam/pose"])
    # poses were either processed, dropped for backlog, or arrived before the scenario
    assert int(diag["poses_received"]) >= int(diag["estimates_published"])
