"""Message <-> core value conversions of dbcslam_ros.convert."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.parameters import FrictionMapView
from dbcslam_core.rbpf import Estimate
from dbcslam_core.scenario import edge_scenario, gripper_scenario
from dbcslam_ros import runtime as rt
from dbcslam_ros.convert import (
    InputRejected,
    array_from_msg,
    estimate_messages,
    float64_multiarray,
    friction_map_grid,
    joints_from_msg,
    ns_to_stamp,
    planar_cov6,
    pose_from_msg,
    pose_stamped,
    quaternion_to_yaw,
    stamp_to_ns,
    wrench_from_msg,
    wrench_stamped,
    yaw_to_quaternion,
)

angles = st.floats(-math.pi + 1e-9, math.pi, allow_nan=False)


@settings(deadline=None)
@given(angles)
def test_yaw_quaternion_round_trip(yaw: float) -> None:
    q = yaw_to_quaternion(yaw)
    assert math.isclose(sum(v * v for v in q), 1.0, rel_tol=1e-12)
    back = quaternion_to_yaw(*q)
    assert abs(math.remainder(back - yaw, 2 * math.pi)) < 1e-9


@settings(deadline=None)
@given(angles, st.floats(1e-3, 1e3))
def test_quaternion_to_yaw_normalises(yaw: float, scale: float) -> None:
    q = [scale * v for v in yaw_to_quaternion(yaw)]
    assert abs(math.remainder(quaternion_to_yaw(*q) - yaw, 2 * math.pi)) < 1e-9


@pytest.mark.parametrize("big", [1e154, 1e200, 1e308])
def test_huge_quaternions_do_not_overflow(big: float) -> None:
    q = [big * v for v in yaw_to_quaternion(1.0)]
    assert abs(quaternion_to_yaw(*q) - 1.0) < 1e-9


@pytest.mark.parametrize(
    ("quat", "reason"),
    [
        ((0.0, 0.0, 0.0, 0.0), "zero_quaternion"),
        ((0.0, 0.0, math.nan, 1.0), "nan"),
        ((0.0, 0.0, 0.0, math.inf), "nan"),
    ],
)
def test_bad_quaternions_are_rejected(quat: tuple[float, ...], reason: str) -> None:
    with pytest.raises(InputRejected) as info:
        quaternion_to_yaw(*quat)
    assert info.value.reason == reason


@settings(deadline=None)
@given(st.integers(0, 2**62))
def test_stamp_round_trip(ns: int) -> None:
    assert stamp_to_ns(ns_to_stamp(ns)) == ns


def test_negative_stamp_is_refused() -> None:
    with pytest.raises(ValueError, match="negative"):
        ns_to_stamp(-1)


def test_planar_cov6_layout() -> None:
    cov3 = np.array([[1.0, 0.2, 0.3], [0.2, 2.0, 0.4], [0.3, 0.4, 3.0]])
    c6 = np.asarray(planar_cov6(cov3)).reshape(6, 6)
    idx = (0, 1, 5)  # x, y, yaw rows of REP-103 (x, y, z, roll, pitch, yaw)
    np.testing.assert_array_equal(c6[np.ix_(idx, idx)], cov3)
    mask = np.ones((6, 6), dtype=bool)
    mask[np.ix_(idx, idx)] = False
    assert np.all(c6[mask] == 0.0)
    np.testing.assert_array_equal(c6, c6.T)


def test_pose_and_wrench_messages_round_trip() -> None:
    msg = pose_stamped(1_500_000_000, 0.25, -0.5, 1.0)
    reading = pose_from_msg(msg)
    assert reading.stamp_ns == 1_500_000_000
    assert (reading.x, reading.y) == (0.25, -0.5)
    assert math.isclose(reading.yaw, 1.0, abs_tol=1e-12)
    assert msg.pose.position.z == 0.0
    w = wrench_from_msg(wrench_stamped(7, 1.0, -2.0, 0.5))
    assert (w.stamp_ns, w.fx, w.fy, w.tau) == (7, 1.0, -2.0, 0.5)
    # the pose survives the wire codec
    decoded = rt.decode(rt.encode(msg), "geometry_msgs/msg/PoseStamped")
    assert pose_from_msg(decoded) == reading


def test_nan_position_and_wrench_are_rejected() -> None:
    msg = pose_stamped(1, 0.0, 0.0, 0.0)
    msg.pose.position.x = math.nan
    with pytest.raises(InputRejected) as info:
        pose_from_msg(msg)
    assert info.value.reason == "nan"
    w = wrench_stamped(1, 0.0, 0.0, 0.0)
    w.wrench.torque.z = math.inf
    with pytest.raises(InputRejected) as info:
        wrench_from_msg(w)
    assert info.value.reason == "nan"


def _joint_state(names: list[str], pos: list[float]) -> Any:
    cls = rt.message_class("sensor_msgs/msg/JointState")
    header = rt.message_class("std_msgs/msg/Header")(stamp=ns_to_stamp(5), frame_id="")
    return cls(header=header, name=names, position=pos, velocity=[], effort=[])


def test_joints_are_reordered_to_the_scenario_order() -> None:
    reading = joints_from_msg(
        _joint_state(["upper_jaw", "lower_jaw"], [0.2, -0.1]), ("lower_jaw", "upper_jaw")
    )
    assert reading.positions == (-0.1, 0.2)
    assert reading.stamp_ns == 5


@pytest.mark.parametrize(
    ("names", "pos", "reason"),
    [
        (["lower_jaw", "upper_jaw", "elbow"], [0.0, 0.0, 0.0], "unknown_joint"),
        (["lower_jaw"], [0.0], "missing_joint"),
        (["lower_jaw", "upper_jaw"], [0.0], "malformed"),
        (["lower_jaw", "upper_jaw"], [0.0, math.nan], "nan"),
    ],
)
def test_bad_joint_states_are_rejected(names: list[str], pos: list[float], reason: str) -> None:
    with pytest.raises(InputRejected) as info:
        joints_from_msg(_joint_state(names, pos), ("lower_jaw", "upper_jaw"))
    assert info.value.reason == reason


def test_empty_joint_state_is_fine_without_joints() -> None:
    assert joints_from_msg(_joint_state([], []), ()).positions == ()


@pytest.mark.parametrize("shape", [(3,), (2, 4), (2, 3, 2)])
def test_multiarray_round_trip(shape: tuple[int, ...]) -> None:
    arr = np.arange(math.prod(shape), dtype=np.float64).reshape(shape) * 0.5
    labels = [f"d{i}" for i in range(len(shape))]
    msg = float64_multiarray(arr, labels)
    assert [d.label for d in msg.layout.dim] == labels
    assert [d.size for d in msg.layout.dim] == list(shape)
    assert msg.layout.dim[0].stride == arr.size
    np.testing.assert_array_equal(array_from_msg(msg), arr)


def test_multiarray_needs_one_label_per_axis() -> None:
    with pytest.raises(ValueError, match="labels"):
        float64_multiarray(np.zeros((2, 2)), ["only_one"])


def _view(n_cells: int = 5) -> FrictionMapView:
    probs = np.tile([0.3, 0.7], (n_cells, 1))
    weight = np.zeros(n_cells)
    weight[1:3] = 1.0
    return FrictionMapView(0.0, 0.1, n_cells, (probs,), (weight,))


def _estimate(**changes: Any) -> Estimate:
    values: dict[str, Any] = {
        "step": 3,
        "pose": np.array([0.1, 0.2, 0.0]),
        "pose_cov": np.diag([1e-4, 2e-4, 0.0]),
        "twist": np.array([0.5, 0.0, 0.0]),
        "twist_cov": np.diag([1e-2, 1e-2, 0.0]),
        "modes": np.array([[0.1, 0.6, 0.2, 0.1]]),
        "friction": np.array([[0.25, 0.75]]),
        "friction_map": _view(),
        "ess": 100.0,
        "live_hypotheses": 2.0,
        "log_likelihood": -1.0,
        "resampled": False,
    }
    values.update(changes)
    return Estimate(**values)


def test_friction_map_grid_marks_untouched_cells() -> None:
    grid = friction_map_grid(_view(), edge_scenario(), 10)
    assert (grid.info.width, grid.info.height) == (5, 1)
    assert list(grid.data) == [-1, 70, 70, -1, -1]  # P(higher candidate 0.9) = 0.7
    assert math.isclose(grid.info.resolution, 0.1)


def test_estimate_messages_pose_first_and_consistent() -> None:
    msgs = estimate_messages(_estimate(), edge_scenario(), 2_000_000_000)
    assert next(iter(msgs)) == "/dbcslam/pose"
    assert set(msgs) == {
        "/dbcslam/pose",
        "/dbcslam/odometry",
        "/dbcslam/contact_modes",
        "/dbcslam/friction",
        "/dbcslam/friction_map",
    }
    pose = msgs["/dbcslam/pose"]
    assert stamp_to_ns(pose.header.stamp) == 2_000_000_000
    assert pose.pose.covariance[0] == pytest.approx(1e-4)
    assert pose.pose.covariance[7] == pytest.approx(2e-4)
    assert msgs["/dbcslam/odometry"].twist.twist.linear.x == 0.5
    np.testing.assert_allclose(
        array_from_msg(msgs["/dbcslam/contact_modes"]), [[0.1, 0.6, 0.2, 0.1]]
    )
    for topic, msg in msgs.items():  # every output survives the wire codec
        type_name = rt.type_name_of(msg)
        assert rt.encode(rt.decode(rt.encode(msg), type_name)) == rt.encode(msg), topic


@pytest.mark.parametrize("field", ["pose", "pose_cov", "twist", "modes", "friction"])
def test_estimate_with_nan_is_never_converted(field: str) -> None:
    good = _estimate()
    bad = np.array(getattr(good, field), dtype=np.float64)
    bad.flat[0] = math.nan
    with pytest.raises(ValueError, match=field):
        estimate_messages(_estimate(**{field: bad}), edge_scenario(), 1)


def test_estimate_with_nan_friction_map_is_never_converted() -> None:
    view = _view()
    probs = view.probs[0].copy()
    probs[2, 0] = math.nan
    bad = FrictionMapView(view.s_min, view.cell_size, view.n_cells, (probs,), view.weight)
    with pytest.raises(ValueError, match="friction map"):
        estimate_messages(_estimate(friction_map=bad), edge_scenario(), 1)


def test_gripper_estimate_has_polygon_yaw() -> None:
    sc = gripper_scenario()
    est = _estimate(
        pose=np.array([0.0, 0.0, 0.5]),
        modes=np.full((sc.n_contacts, 4), 0.25),
        friction=np.full((1, 3), 1.0 / 3.0),
        friction_map=FrictionMapView(
            -0.1, 0.01, 20, (np.full((20, 3), 1.0 / 3.0),), (np.zeros(20),)
        ),
    )
    msgs = estimate_messages(est, sc, 1)
    o = msgs["/dbcslam/pose"].pose.pose.orientation
    assert quaternion_to_yaw(o.x, o.y, o.z, o.w) == pytest.approx(0.5)
    assert array_from_msg(msgs["/dbcslam/contact_modes"]).shape == (sc.n_contacts, 4)
    assert all(v == -1 for v in msgs["/dbcslam/friction_map"].data)


def test_input_rejected_carries_reason() -> None:
    err = InputRejected("nan", "text")
    assert err.reason == "nan" and str(err) == "text"
