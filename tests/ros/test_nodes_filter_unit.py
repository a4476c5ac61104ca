"""The filter node's core (FilterCore) in-process, without ROS: configuration, backlog
policy, failure handling.

No DDS: the fake node records publications; callbacks are called directly, so the queueing
and catch-up rules are checked deterministically.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from typing import Any

import numpy as np
import pytest

from dbcslam_core.synthetic import edge_trajectory
from dbcslam_ros import runtime as rt
from dbcslam_ros.convert import array_from_msg, pose_stamped, wrench_stamped
from dbcslam_ros.node import filter_node as fn

NS = 1_000_000_000
T0 = 10 * NS


class FakeLogger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, text: str, **_: Any) -> None:
        self.lines.append(("info", text))

    def warning(self, text: str, **_: Any) -> None:
        self.lines.append(("warning", text))

    def error(self, text: str, **_: Any) -> None:
        self.lines.append(("error", text))


class FakeNode:
    """Collects what a :class:`FilterCore` publishes; ``subs`` are its input callbacks."""

    def __init__(self, overrides: dict[str, Any] | None = None) -> None:
        self.overrides = overrides or {}
        self.logger = FakeLogger()
        self.published: list[tuple[str, Any]] = []
        self.subs: dict[str, Any] = {}

    def build(self) -> fn.FilterCore:
        core = fn.FilterCore(
            fn.coerce_params(self.overrides),
            lambda topic, msg: self.published.append((topic, msg)),
            self.logger,
        )
        self.subs = core.callbacks()
        return core

    def topics(self) -> list[str]:
        return [t for t, _ in self.published]

    def last(self, topic: str) -> Any:
        return [m for t, m in self.published if t == topic][-1]


def _string(text: str) -> Any:
    return rt.message_class("std_msgs/msg/String")(data=text)


@pytest.fixture
def traj() -> Any:
    return edge_trajectory(0, duration=0.6)


@pytest.fixture
def node(traj: Any) -> tuple[FakeNode, fn.FilterCore]:
    fake = FakeNode({"particles": 30, "marker_particles": 5})
    filt = fake.build()
    fake.subs["/scenario"](_string(traj.scenario.to_yaml()))
    return fake, filt


def _tick(node: tuple[FakeNode, fn.FilterCore], traj: Any, k: int, process: bool = True) -> None:
    fake, filt = node
    stamp = T0 + k * NS // 100
    fx, fy = (float(v) for v in traj.u[k])
    fake.subs["/object/wrench"](wrench_stamped(stamp, fx, fy))
    x, y = (float(v) for v in traj.obs[k])
    fake.subs["/object/pose"](pose_stamped(stamp, x, y))
    if process:
        filt.process_pending()


def test_poses_before_the_scenario_are_counted() -> None:
    fake = FakeNode()
    filt = fake.build()
    fake.subs["/object/pose"](pose_stamped(T0, 0.0, 0.0))
    assert filt.rejected_before_scenario == 1
    filt.publish_diagnostics()
    status = fake.last("/diagnostics").status[0]
    assert "waiting for /scenario" in status.message


@pytest.mark.parametrize(
    ("values", "level", "says"),
    [
        ({"rejected_total": "0", "surprise_nats_max": "6.1"}, 0, ["running"]),
        ({"rejected_total": "0", "surprise_nats_max": "10.0"}, 0, ["running"]),
        ({"rejected_total": "0", "surprise_nats_max": "23.4"}, 1, ["badly explained", "23.4"]),
        ({"rejected_total": "2", "surprise_nats_max": "3.0"}, 1, ["2 input(s) rejected"]),
        ({"rejected_total": "2", "surprise_nats_max": "inf"}, 1, ["rejected", "inf nats"]),
        ({}, 0, ["running"]),
    ],
)
def test_diagnostics_warn_on_rejections_and_badly_explained_observations(
    values: dict[str, str], level: int, says: list[str]
) -> None:
    from dbcslam_ros.node.outputs import diagnostics_message

    status = diagnostics_message(values, 0, configured=True).status[0]
    assert status.level == bytes([level])
    assert all(text in status.message for text in says)
    assert ("badly explained" in status.message) == (
        float(values.get("surprise_nats_max", 0)) > 10
    )


def test_outputs_pose_first_and_well_formed(node: Any, traj: Any) -> None:
    fake, filt = node
    for k in range(20):
        _tick(node, traj, k)
    assert filt.published == 19  # the first pose initialises
    step_topics = fake.topics()[:7]
    assert step_topics[0] == "/dbcslam/pose"
    assert set(step_topics) == set(fn.OUTPUT_TYPES) - {"/diagnostics"}
    modes = array_from_msg(fake.last("/dbcslam/contact_modes"))
    np.testing.assert_allclose(modes.sum(axis=1), 1.0)
    filt.publish_diagnostics()
    values = {kv.key: kv.value for kv in fake.last("/diagnostics").status[0].values}
    assert values["estimates_published"] == "19"
    assert float(values["ess"]) > 0 and float(values["latency_ms_mean"]) >= 0
    assert float(values["surprise_nats_peak"]) >= float(values["surprise_nats_max"])
    assert int(values["surprised_steps"]) >= 0


def test_backlog_keeps_the_newest_pose_and_catches_up(node: Any, traj: Any) -> None:
    _fake, filt = node
    _tick(node, traj, 0)
    _tick(node, traj, 1)
    for k in range(2, 8):  # six poses arrive while the filter is busy
        _tick(node, traj, k, process=False)
    filt.process_pending()
    assert filt.backlog_dropped == 5
    assert filt.session is not None
    assert filt.session.rejected["backlog"] == 5
    last = filt.last_estimate
    assert last is not None and last.stamp_ns == T0 + 7 * NS // 100
    assert last.model_steps == 2  # catch_up_steps
    assert filt.session.skipped_steps == 4
    # back in step: the next pose runs its single step exactly
    _tick(node, traj, 8)
    assert filt.last_estimate is not None and filt.last_estimate.model_steps == 1


def test_same_scenario_keeps_the_session_new_one_reconfigures(node: Any, traj: Any) -> None:
    fake, filt = node
    session = filt.session
    fake.subs["/scenario"](_string(traj.scenario.to_yaml()))
    assert filt.session is session
    from dbcslam_core.scenario import gripper_scenario

    fake.subs["/scenario"](_string(gripper_scenario().to_yaml()))
    assert filt.session is not session
    assert filt.scenario is not None and filt.scenario.kind == "gripper"
    fake.subs["/scenario"](_string("scenario: [not, a, mapping"))
    assert filt.scenario.kind == "gripper"  # bad YAML ignored, counted
    assert filt.session is not None and filt.session.rejected["bad_scenario"] == 1


def test_filter_failure_is_counted_and_resets(
    node: Any, traj: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    _fake, filt = node
    for k in range(5):
        _tick(node, traj, k)
    assert filt.session is not None

    def boom(*_: Any, **__: Any) -> Any:
        raise FloatingPointError("synthetic failure")

    monkeypatch.setattr(filt.session, "add_pose", boom)
    _tick(node, traj, 5)
    assert filt.session.rejected["filter_error"] == 1
    assert filt.session.resets == 1
    monkeypatch.undo()
    _tick(node, traj, 6)  # re-initialises
    _tick(node, traj, 7)
    assert filt.last_estimate is not None and filt.last_estimate.stamp_ns == T0 + 7 * NS // 100


def test_non_finite_estimate_is_never_published(
    node: Any, traj: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake, filt = node
    for k in range(5):
        _tick(node, traj, k)
    n_pose = fake.topics().count("/dbcslam/pose")

    assert filt.session is not None
    flt = filt.session._filter
    assert flt is not None
    real_step = flt.step

    def nan_step(*args: Any, **kwargs: Any) -> Any:  # a filter that blows up
        est = real_step(*args, **kwargs)
        return dataclasses.replace(est, pose=np.full(3, np.nan))

    monkeypatch.setattr(flt, "step", nan_step)
    _tick(node, traj, 5)
    assert fake.topics().count("/dbcslam/pose") == n_pose
    assert filt.session is not None and filt.session.rejected["nan_estimate"] == 1
    assert filt.session.resets == 1


def test_nan_inputs_do_not_reach_the_filter(node: Any, traj: Any) -> None:
    fake, filt = node
    _tick(node, traj, 0)
    bad = pose_stamped(T0 + NS // 100, 0.0, 0.0)
    bad.pose.position.x = math.nan
    fake.subs["/object/pose"](bad)
    bad_w = wrench_stamped(T0 + NS // 100, 0.0, 0.0)
    bad_w.wrench.force.x = math.inf
    fake.subs["/object/wrench"](bad_w)
    filt.process_pending()
    assert filt.session is not None and filt.session.rejected["nan"] == 2
    for k in range(1, 5):
        _tick(node, traj, k)
    assert filt.published == 4
    counts: dict[str, int] = defaultdict(int)
    for topic, _ in fake.published:
        counts[topic] += 1
    assert counts["/dbcslam/pose"] == 4


def test_particles_default_is_the_live_default_per_kind(traj: Any) -> None:
    fake = FakeNode()
    filt = fake.build()
    fake.subs["/scenario"](_string(traj.scenario.to_yaml()))
    assert filt.session is not None
    assert filt.session.config.particles == fn.live_particles("edge")
    assert fn.build_config("gripper", {**_defaults(), "particles": 7}).particles == 7
    assert fn.build_config("push", _defaults()).particles == fn.LIVE_PARTICLES["push"]


def _defaults() -> dict[str, Any]:
    return {name: default for name, (default, _) in fn.PARAMETERS.items()}


@pytest.mark.parametrize("bad", [0, -2])
def test_bad_particle_count_is_a_parameter_error(bad: int) -> None:
    with pytest.raises(fn.ParameterError, match="particles"):
        FakeNode({"particles": bad}).build()


def test_threads_parameter_reaches_the_filter() -> None:
    """0 = automatic (FilterConfig.threads None), n >= 1 as given, negative refused."""
    assert fn.build_config("gripper", _defaults()).threads is None
    assert fn.build_config("gripper", {**_defaults(), "threads": 1}).threads == 1
    with pytest.raises(fn.ParameterError, match="threads"):
        FakeNode({"threads": -1}).build()


@pytest.mark.parametrize(("period", "expected"), [(0.0, 19), (0.05, 4)])
def test_markers_at_most_one_per_marker_period(traj: Any, period: float, expected: int) -> None:
    fake = FakeNode({"particles": 20, "marker_particles": 3, "marker_period": period})
    filt = fake.build()
    fake.subs["/scenario"](_string(traj.scenario.to_yaml()))
    for k in range(20):  # estimates at 10 .. 190 ms
        _tick((fake, filt), traj, k)
    assert filt.published == 19
    # period 0.05 s: markers at 10, 60, 110, 160 ms
    assert fake.topics().count("/dbcslam/markers") == expected


def _push_node(use: bool) -> tuple[FakeNode, fn.FilterCore, Any]:
    from dbcslam_core.synthetic import push_trajectory

    tr = push_trajectory(0)
    fake = FakeNode({"particles": 20, "use_pusher_wrench": use})
    filt = fake.build()
    fake.subs["/scenario"](_string(tr.scenario.to_yaml()))
    return fake, filt, tr


@pytest.mark.parametrize("use", [True, False])
def test_pusher_wrench_subscription_feeds_the_session(use: bool) -> None:
    fake, filt, tr = _push_node(use)
    joint_cls = rt.message_class("sensor_msgs/msg/JointState")
    assert "/pusher/wrench" in fake.subs
    order = list(fake.subs)
    assert order.index("/pusher/wrench") < order.index("/object/pose")
    for k in range(6):
        stamp = T0 + k * NS // 100
        fake.subs["/joint_states"](
            joint_cls(
                header=pose_stamped(stamp, 0.0, 0.0).header,
                name=list(tr.scenario.joints),
                position=[float(v) for v in tr.env_obs[k]],
                velocity=[],
                effort=[],
            )
        )
        fake.subs["/pusher/wrench"](wrench_stamped(stamp, 0.2, -0.1))
        x, y, yaw = (float(v) for v in tr.obs[k])
        fake.subs["/object/pose"](pose_stamped(stamp, x, y, yaw))
        filt.process_pending()
    assert filt.published == 5
    filt.publish_diagnostics()
    values = {kv.key: kv.value for kv in fake.last("/diagnostics").status[0].values}
    assert values["force_steps"] == ("5" if use else "0")


def test_pusher_wrench_for_a_scenario_without_pusher_is_rejected(node: Any) -> None:
    fake, filt = node
    fake.subs["/pusher/wrench"](wrench_stamped(T0, 1.0, 0.0))
    assert filt.session is not None and filt.session.rejected["no_pusher"] == 1


def test_the_core_warms_every_scenario_kind_before_a_scenario(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The node's core loads the compiled kernels of every kind when it is built (before it
    subscribes), so the first /scenario never waits for numba while poses arrive."""
    from dbcslam_core import kernels, rbpf

    monkeypatch.setattr(rbpf, "_WARM", set())
    FakeNode().build()
    expected = {"edge", "gripper", "push"} if kernels.AVAILABLE else set()
    warmed = set(rbpf._WARM)
    assert warmed == expected
