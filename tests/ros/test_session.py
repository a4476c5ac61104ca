"""Input synchronisation of dbcslam_ros.node.session.FilterSession.

Most tests replace the core filter by a recorder of the calls it gets, so the hold,
interpolation, gap and reset rules are checked exactly; one test runs the real filter.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import pytest

from dbcslam_core.rbpf import FilterConfig, FilterInput
from dbcslam_core.scenario import Scenario, edge_scenario, gripper_scenario, push_scenario
from dbcslam_ros.convert import InputRejected, JointReading, PoseReading, WrenchReading
from dbcslam_ros.node import session as session_mod
from dbcslam_ros.node.session import FilterSession

MS = 1_000_000  # ns
T0 = 5_000_000_000  # an arbitrary start stamp (ns)


class RecordingFilter:
    """Stands in for DbcSlamFilter: records initialize/step calls, returns a dummy estimate."""

    instances: ClassVar[list[RecordingFilter]] = []

    def __init__(self, scenario: Scenario, config: Any, rng: Any, extensions: Any = ()) -> None:
        self.scenario = scenario
        self.q = np.zeros((2, scenario.nq))
        self.v = np.ones((2, scenario.nq))
        self.inits: list[dict[str, Any]] = []
        self.steps: list[tuple[Any, FilterInput]] = []
        RecordingFilter.instances.append(self)

    def initialize(self, q_mean: Any, q_std: Any, joints: Any = None) -> None:
        self.inits.append({"q": list(q_mean), "std": list(q_std), "joints": joints})

    def warm_up(self) -> float:
        return 0.0

    def step(self, observation: Any, inputs: FilterInput) -> Any:
        self.steps.append((observation, inputs))
        return f"estimate{len(self.steps)}"


@pytest.fixture
def fake_filter(monkeypatch: pytest.MonkeyPatch) -> type[RecordingFilter]:
    RecordingFilter.instances = []
    monkeypatch.setattr(session_mod, "DbcSlamFilter", RecordingFilter)
    return RecordingFilter


def _session(scenario: Scenario | None = None, **kw: Any) -> FilterSession:
    sc = scenario or edge_scenario()
    return FilterSession(sc, FilterConfig.preset(sc.kind, particles=10), **kw)


def pose(t_ms: float, x: float = 0.0, y: float = 0.01, yaw: float = 0.0) -> PoseReading:
    return PoseReading(T0 + round(t_ms * MS), x, y, yaw)


def wrench(t_ms: float, fx: float) -> WrenchReading:
    return WrenchReading(T0 + round(t_ms * MS), fx, 0.0, 0.0)


def joints(t_ms: float, *pos: float) -> JointReading:
    return JointReading(T0 + round(t_ms * MS), tuple(pos))


def test_first_pose_initialises_then_one_estimate_per_pose(fake_filter: Any) -> None:
    s = _session()
    assert s.add_pose(pose(0.0, x=0.3, y=0.02)) == []
    flt = fake_filter.instances[-1]
    assert flt.inits[0]["q"] == [0.3, 0.02]  # point mass: (x, y)
    out = s.add_pose(pose(10.0))
    assert len(out) == 1 and out[0].stamp_ns == T0 + 10 * MS
    assert out[0].estimate == "estimate1" and out[0].model_steps == 1
    obs, _ = flt.steps[0]
    assert obs.yaw is None  # a point mass has no observed yaw


def test_polygon_gets_the_observed_yaw(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    s.add_joints(joints(0.0, -0.05, 0.05))
    s.add_pose(pose(0.0, yaw=0.3))
    assert fake_filter.instances[-1].inits[0]["q"] == [0.0, 0.01, 0.3]
    s.add_pose(pose(10.0, yaw=0.4))
    obs, _ = fake_filter.instances[-1].steps[0]
    assert obs.yaw == pytest.approx(0.4)


def test_wrench_is_held_from_the_step_start(fake_filter: Any) -> None:
    s = _session()
    s.add_pose(pose(0.0))
    s.add_wrench(wrench(0.0, 1.0))
    s.add_wrench(wrench(5.0, 2.0))  # arrives during the step: not this step's input
    s.add_wrench(wrench(10.0, 3.0))
    s.add_pose(pose(10.0))
    s.add_pose(pose(20.0))
    steps = fake_filter.instances[-1].steps
    assert steps[0][1].wrench == (1.0, 0.0, 0.0)
    assert steps[1][1].wrench == (3.0, 0.0, 0.0)


def test_no_wrench_yet_means_zero_input(fake_filter: Any) -> None:
    s = _session()
    s.add_pose(pose(0.0))
    s.add_wrench(wrench(10.0, 5.0))  # stamped at the step's end: too late for it
    s.add_pose(pose(10.0))
    assert fake_filter.instances[-1].steps[0][1].wrench == (0.0, 0.0, 0.0)


def test_joints_interpolated_to_the_pose_stamp_and_held_after(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    s.add_joints(joints(0.0, 0.0, 0.4))
    s.add_joints(joints(20.0, 0.2, 0.0))
    s.add_pose(pose(0.0))
    assert fake_filter.instances[-1].inits[0]["joints"] == (0.0, 0.4)
    s.add_pose(pose(10.0))
    s.add_pose(pose(30.0 - 0.0))  # after the last reading: held
    steps = fake_filter.instances[-1].steps
    np.testing.assert_allclose(steps[0][1].joints, (0.1, 0.2))
    np.testing.assert_allclose(steps[-1][1].joints, (0.2, 0.0))


def test_late_joint_message_is_sorted_in(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    s.add_joints(joints(0.0, 0.0, 0.0))
    s.add_joints(joints(20.0, 0.2, 0.2))
    s.add_joints(joints(10.0, 1.0, 1.0))  # arrives late, belongs in the middle
    s.add_pose(pose(0.0))
    s.add_pose(pose(10.0))
    np.testing.assert_allclose(fake_filter.instances[-1].steps[0][1].joints, (1.0, 1.0))


def test_no_joints_is_rejected_for_a_jawed_scenario(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    with pytest.raises(InputRejected) as info:
        s.add_pose(pose(0.0))
    assert info.value.reason == "no_joints"
    assert s.rejected["no_joints"] == 1
    s.add_joints(joints(0.0, 0.0, 0.0))
    assert s.add_pose(pose(0.0)) == []  # usable afterwards


@pytest.mark.parametrize("dt_ms", [0.0, 4.0, -10.0, -400.0])
def test_stamp_not_later_is_rejected_and_counted(fake_filter: Any, dt_ms: float) -> None:
    s = _session()
    s.add_pose(pose(0.0))
    s.add_pose(pose(10.0))
    with pytest.raises(InputRejected) as info:
        s.add_pose(pose(10.0 + dt_ms))
    assert info.value.reason == "stamp_order"
    assert s.rejected["stamp_order"] == 1
    assert s.resets == 0
    assert len(s.add_pose(pose(20.0))) == 1  # still usable


def test_jump_back_in_time_resets_cleanly(fake_filter: Any) -> None:
    s = _session(gripper_scenario(), reset_after_s=0.5)
    for k in range(100):  # one second of data
        s.add_joints(joints(10.0 * k, 0.001 * k, 0.0))
        s.add_pose(pose(10.0 * k))
    old = fake_filter.instances[-1]
    # the bag loops: the first inputs of the new time line arrive before its first pose
    s.add_joints(joints(0.0, -0.5, 0.5))
    for t in (0.0, 10.0):  # poses alone do not prove a new time line: held
        with pytest.raises(InputRejected) as info:
            s.add_pose(pose(t))
        assert info.value.reason == "stamp_jump" and s.resets == 0
    s.add_joints(joints(20.0, -0.5, 0.5))
    assert s.add_pose(pose(20.0)) == []  # the third pose in a row confirms it
    assert s.resets == 1
    new = fake_filter.instances[-1]
    assert new is not old
    assert new.inits[0]["joints"] == (-0.5, 0.5)  # the new line's joints, not the old ones
    assert len(s.add_pose(pose(30.0))) == 1
    assert s.rejected["stamp_order"] == 0 and s.rejected["stamp_jump"] == 2


@pytest.mark.parametrize("jump_ms", [-5000.0, 3000.0, 1e9])
def test_single_jumped_stamp_is_rejected_and_tracking_goes_on(
    fake_filter: Any, jump_ms: float
) -> None:
    s = _session(reset_after_s=0.5, max_gap_s=1.0)
    for k in range(10):
        s.add_pose(pose(1000.0 + 10.0 * k))
    with pytest.raises(InputRejected) as info:
        s.add_pose(pose(1090.0 + jump_ms))
    assert info.value.reason == "stamp_jump"
    assert len(s.add_pose(pose(1100.0))) == 1  # the old time line goes on, no reset
    assert s.resets == 0 and len(fake_filter.instances) == 1
    assert s.rejected["stamp_jump"] == 1


def test_multi_step_gap_predicts_then_updates(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    for k in range(5):
        s.add_joints(joints(10.0 * k, 0.01 * k, 0.0))
        s.add_wrench(wrench(10.0 * k, float(k)))
    s.add_pose(pose(0.0))
    out = s.add_pose(pose(30.0))  # two observations missing
    assert out[0].model_steps == 3
    steps = fake_filter.instances[-1].steps
    assert [obs is None for obs, _ in steps] == [True, True, False]
    assert [inp.wrench[0] for _, inp in steps] == [0.0, 1.0, 2.0]
    np.testing.assert_allclose([inp.joints[0] for _, inp in steps], [0.01, 0.02, 0.03])
    assert s.gap_steps == 2 and s.skipped_steps == 0 and s.steps == 3


def test_catch_up_runs_the_last_steps_of_the_gap(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    for k in range(7):
        s.add_joints(joints(10.0 * k, 0.01 * k, 0.0))
        s.add_wrench(wrench(10.0 * k, float(k)))
    s.add_pose(pose(0.0))
    out = s.add_pose(pose(50.0), max_steps=2)
    assert out[0].model_steps == 2
    steps = fake_filter.instances[-1].steps
    assert [inp.wrench[0] for _, inp in steps] == [3.0, 4.0]  # steps (30, 40], (40, 50]
    np.testing.assert_allclose([inp.joints[0] for _, inp in steps], [0.04, 0.05])
    np.testing.assert_allclose(steps[0][1].joints_start, (0.03, 0.0))  # no jaw jump
    assert steps[1][1].joints_start is None
    assert s.skipped_steps == 3
    # before the run steps the particles coasted over the 3 skipped steps at their velocity
    np.testing.assert_allclose(fake_filter.instances[-1].q[:, :2], 0.03)
    assert -np.pi < fake_filter.instances[-1].q[0, 2] <= np.pi


def test_long_gap_reinitialises(fake_filter: Any) -> None:
    s = _session(max_gap_s=0.2)
    s.add_pose(pose(0.0))
    s.add_pose(pose(10.0))
    for t in (500.0, 510.0):  # held: late poses may carry corrupted stamps
        with pytest.raises(InputRejected):
            s.add_pose(pose(t))
    assert s.add_pose(pose(520.0)) == []
    assert s.resets == 1
    assert len(fake_filter.instances) == 2


def test_long_gap_in_catch_up_holds_instead_of_resetting(fake_filter: Any) -> None:
    s = _session(max_gap_s=0.2)
    s.add_pose(pose(0.0))
    out = s.add_pose(pose(500.0), max_steps=2)
    assert out[0].model_steps == 2 and s.resets == 0
    assert s.skipped_steps == 48


def test_counters_survive_reset(fake_filter: Any) -> None:
    s = _session()
    s.reject("nan")
    s.reset()
    assert s.rejected["nan"] == 1 and s.resets == 1


def test_real_filter_tracks_synthetic_edge() -> None:
    from dbcslam_core.synthetic import edge_trajectory

    traj = edge_trajectory(0, duration=0.5)
    sc = traj.scenario
    s = FilterSession(sc, FilterConfig.preset("edge", particles=50), seed=1)
    errs = []
    for k in range(traj.n_steps):
        stamp = T0 + k * 10 * MS
        if k > 0:
            s.add_wrench(WrenchReading(stamp - 10 * MS, *traj.u[k - 1], 0.0))
        out = s.add_pose(PoseReading(stamp, float(traj.obs[k, 0]), float(traj.obs[k, 1]), 0.0))
        for res in out:
            assert np.all(np.isfinite(res.estimate.pose))
            errs.append(np.hypot(*(res.estimate.pose[:2] - traj.q[k])))
    assert len(errs) == traj.n_steps - 1
    assert float(np.mean(errs)) < 2.0 * sc.noise.position
    px, w = s.particles()
    assert px.shape == (50, 2) and w.sum() == pytest.approx(1.0)


# -- pusher force (/pusher/wrench) -------------------------------------------------------------


class ForceRecordingFilter(RecordingFilter):
    """RecordingFilter that also takes the force observation."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.forces: list[Any] = []

    def step(self, observation: Any, inputs: FilterInput, force: Any = None) -> Any:
        self.forces.append(force)
        return super().step(observation, inputs)


@pytest.fixture
def force_filter(monkeypatch: pytest.MonkeyPatch) -> type[ForceRecordingFilter]:
    RecordingFilter.instances = []
    monkeypatch.setattr(session_mod, "DbcSlamFilter", ForceRecordingFilter)
    return ForceRecordingFilter


@pytest.fixture
def push_session() -> FilterSession:
    from dbcslam_core.synthetic import PUSH_RECT, PUSH_RECT_MASS

    sc = push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS)
    return FilterSession(sc, FilterConfig.preset(sc.kind, particles=10))


def _push_tick(s: FilterSession, t_ms: float, force: tuple[float, float] | None) -> None:
    s.add_joints(joints(t_ms, 0.0, -0.1))
    if force is not None:
        s.add_pusher_wrench(WrenchReading(T0 + round(t_ms * MS), force[0], force[1], 0.0))


def test_pusher_force_at_the_pose_stamp_is_observed(
    force_filter: Any, push_session: FilterSession
) -> None:
    s = push_session
    _push_tick(s, 0.0, (9.0, 9.0))
    s.add_pose(pose(0.0))
    _push_tick(s, 10.0, (0.5, -1.5))
    s.add_pose(pose(10.0))
    flt = force_filter.instances[-1]
    (f,) = flt.forces
    assert (f.fx, f.fy) == (0.5, -1.5) and f.obstacle is None and f.std is None
    assert s.force_steps == 1


def test_pusher_force_interpolated_or_nearest_or_absent(
    force_filter: Any, push_session: FilterSession
) -> None:
    s = push_session
    dt_ms = s.scenario.dt * 1e3
    _push_tick(s, 0.0, None)
    s.add_pose(pose(0.0))
    # readings at 0.5 dt and 1.4 dt bracket the pose at 1 dt: interpolated
    s.add_pusher_wrench(WrenchReading(T0 + round(0.5 * dt_ms * MS), 1.0, 0.0, 0.0))
    s.add_pusher_wrench(WrenchReading(T0 + round(1.4 * dt_ms * MS), 2.0, 4.0, 0.0))
    _push_tick(s, dt_ms, None)
    s.add_pose(pose(dt_ms))
    # next pose at 2 dt: no later reading; the 1.4 dt one is within 1.5 dt: nearest
    _push_tick(s, 2 * dt_ms, None)
    s.add_pose(pose(2 * dt_ms))
    # pose at 5 dt: the gap steps end at 3, 4, 5 dt, all > 1.5 dt after the last reading
    _push_tick(s, 5 * dt_ms, None)
    s.add_pose(pose(5 * dt_ms))
    forces = force_filter.instances[-1].forces
    a = 0.5 / 0.9
    assert forces[0].fx == pytest.approx(1.0 + a) and forces[0].fy == pytest.approx(4.0 * a)
    assert (forces[1].fx, forces[1].fy) == (2.0, 4.0)
    assert forces[2:] == [None, None, None]
    assert s.force_steps == 2


def test_pusher_force_forgotten_on_reset(force_filter: Any, push_session: FilterSession) -> None:
    s = push_session
    _push_tick(s, 0.0, (1.0, 1.0))
    s.add_pose(pose(0.0))
    s.reset()
    _push_tick(s, 10.0, None)
    s.add_pose(pose(10.0))  # initialises the new filter
    _push_tick(s, 20.0, None)
    s.add_pose(pose(20.0))
    assert force_filter.instances[-1].forces == [None]


def test_pusher_force_without_a_pusher_is_rejected(fake_filter: Any) -> None:
    s = _session(gripper_scenario())
    with pytest.raises(InputRejected) as info:
        s.add_pusher_wrench(WrenchReading(T0, 1.0, 0.0, 0.0))
    assert info.value.reason == "no_pusher" and s.rejected["no_pusher"] == 1


def test_pusher_force_reaches_the_real_filter(push_session: FilterSession) -> None:
    """With the real core filter a force reading is accepted and changes the estimate."""
    from dbcslam_core.synthetic import push_trajectory

    tr = push_trajectory(0)
    results = {}
    for use in (False, True):
        s = FilterSession(tr.scenario, FilterConfig.preset("push", particles=20), seed=1)
        out = None
        for k in range(40):
            t = T0 + k * round(tr.scenario.dt * 1e9)
            s.add_joints(JointReading(t, tuple(float(v) for v in tr.env_obs[k])))
            if use:
                s.add_pusher_wrench(WrenchReading(t, 0.3, 0.0, 0.0))
            x, y, yaw = (float(v) for v in tr.obs[k])
            out = s.add_pose(PoseReading(t, x, y, yaw)) or out
        assert out is not None
        assert s.force_steps == (39 if use else 0)
        results[use] = out[0].estimate
    assert not np.array_equal(results[False].pose, results[True].pose)


def test_jump_confirmed_on_arrival_is_taken_when_processed(fake_filter: Any) -> None:
    """The live node screens each pose on arrival, then processes it: a jump confirmed by
    `screen_pose` must not be rejected again by `add_pose` (a looped bag resumes)."""
    s = _session(reset_after_s=0.5)
    for k in range(100):
        s.add_pose(pose(10.0 * k))
    for t in (0.0, 10.0):
        with pytest.raises(InputRejected):
            s.screen_pose(pose(t), s.last_pose_ns)
    s.screen_pose(pose(20.0), s.last_pose_ns)  # the third pose confirms: queued
    assert s.add_pose(pose(20.0)) == [] and s.resets == 1
    s.screen_pose(pose(30.0), s.last_pose_ns)
    assert len(s.add_pose(pose(30.0))) == 1


def test_tracking_health_statistics(fake_filter: Any) -> None:
    """The surprise of each estimate against the recent ones (`dbcslam_core.surprise`): the
    recent largest, the peak and the count above the warning survive a reset; the reference
    does not (a new track)."""
    from types import SimpleNamespace

    s = _session()
    assert "surprise_nats_max" not in s.statistics()  # nothing estimated yet
    for ll in [10.0] * 6 + [-5.0]:
        s._note_surprise(SimpleNamespace(log_likelihood=ll))  # type: ignore[arg-type]
    stats = s.statistics()
    assert (stats["surprise_nats_max"], stats["surprise_nats_peak"]) == ("15.0", "15.0")
    assert stats["surprised_steps"] == "1"
    s.reset()
    s._note_surprise(SimpleNamespace(log_likelihood=-50.0))  # type: ignore[arg-type]
    assert s.statistics()["surprised_steps"] == "1"  # no reference yet: not surprising
    for _ in range(session_mod.SURPRISE_RECENT):
        s._note_surprise(SimpleNamespace(log_likelihood=-50.0))  # type: ignore[arg-type]
    stats = s.statistics()
    assert stats["surprise_nats_max"] == "0.0"  # the surprising step left the recent window
    assert stats["surprise_nats_peak"] == "15.0"
