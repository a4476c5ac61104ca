"""Conversions between ROS 2 messages and dbcslam_core values (no math beyond unit plumbing).

Message classes are rclpy's (the real message packages), looked up by type name with
:func:`dbcslam_ros.runtime.message_class`.

Frames and conventions (REP-103, see the README): planar poses travel as geometry_msgs poses
with z = 0 and a yaw-only quaternion; covariances are 6x6 row-major over (x, y, z, roll,
pitch, yaw). Variances of the unobserved planar dimensions (z, roll, pitch) are reported as
0 and the point-mass yaw (undefined) likewise; consumers should read only x, y, yaw.

Validation: every ``*_from_msg`` function raises :class:`InputRejected` with a short
``reason`` key (``nan``, ``zero_quaternion``, ``unknown_joint``, ``missing_joint``, ...) so a
node can log it, count it in ``/diagnostics`` and keep running.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core.angles import quaternion_to_yaw as core_quaternion_to_yaw
from dbcslam_core.angles import yaw_to_quaternion
from dbcslam_core.contact_modes import MODE_NAMES
from dbcslam_core.parameters import FrictionMapView
from dbcslam_core.rbpf import Estimate
from dbcslam_core.scenario import Scenario
from dbcslam_ros import runtime as rt
from dbcslam_ros.contract import CONTACT_MODES, FRICTION, FRICTION_MAP, ODOMETRY, POSE
from dbcslam_ros.errors import DbcSlamRosError

__all__ = [
    "InputRejected",
    "JointReading",
    "PoseReading",
    "WrenchReading",
    "array_from_msg",
    "estimate_messages",
    "float64_multiarray",
    "friction_map_grid",
    "header_ns",
    "joints_from_msg",
    "ns_to_stamp",
    "planar_cov6",
    "planar_pose",
    "pose_from_msg",
    "pose_stamped",
    "quaternion_to_yaw",
    "stamp_to_ns",
    "wrench_from_msg",
    "wrench_stamped",
    "yaw_to_quaternion",
]

FloatArray = npt.NDArray[np.float64]
NS = 1_000_000_000
# The planar dims (x, y, yaw) sit at these rows/cols of a REP-103 6x6 covariance.
_PLANAR_IDX = (0, 1, 5)


class InputRejected(DbcSlamRosError):
    """One input message cannot be used; `reason` is a short key for diagnostics counters."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class PoseReading:
    """A planar pose observation: stamp (ns), x, y (m), yaw (rad)."""

    stamp_ns: int
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class WrenchReading:
    """A planar wrench: stamp (ns), fx, fy (N), tau_z (N m), world frame."""

    stamp_ns: int
    fx: float
    fy: float
    tau: float


@dataclass(frozen=True)
class JointReading:
    """Joint positions (m) in the order the scenario expects, with their stamp (ns)."""

    stamp_ns: int
    positions: tuple[float, ...]


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def header_ns(msg: Any) -> int:
    """The ``header.stamp`` of a stamped message, in integer nanoseconds."""
    return stamp_to_ns(msg.header.stamp)


def ns_to_stamp(ns: int) -> Any:
    """Integer nanoseconds -> builtin_interfaces/Time (negative stamps are rejected)."""
    if ns < 0:
        msg = f"cannot represent a negative time stamp ({ns} ns) as builtin_interfaces/Time"
        raise ValueError(msg)
    time_cls = rt.message_class("builtin_interfaces/msg/Time")
    return time_cls(sec=int(ns // NS), nanosec=int(ns % NS))


def planar_pose(pose: Any) -> tuple[float, float, float]:
    """geometry_msgs/Pose -> (x, y, yaw) (m, m, rad), as recorded: nothing validated (for
    reading bags; inputs go through `pose_from_msg`)."""
    o = pose.orientation
    yaw = core_quaternion_to_yaw(o.x, o.y, o.z, o.w)
    return (float(pose.position.x), float(pose.position.y), yaw)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Quaternion -> yaw about +z (rad, in (-pi, pi]); rejects zero or non-finite quaternions."""
    values = (x, y, z, w)
    if not all(math.isfinite(v) for v in values):
        raise InputRejected("nan", f"quaternion has non-finite components {values}")
    scale = max(abs(v) for v in values)  # scaled first: no overflow for huge components
    if scale == 0.0:
        raise InputRejected("zero_quaternion", f"quaternion {values} has zero norm")
    norm = scale * math.sqrt(sum((v / scale) ** 2 for v in values))
    if norm < 1e-9:
        raise InputRejected("zero_quaternion", f"quaternion {values} has zero norm")
    x, y, z, w = (v / norm for v in values)
    return core_quaternion_to_yaw(x, y, z, w)


def _finite(reason_where: str, values: Sequence[float]) -> None:
    if not all(math.isfinite(float(v)) for v in values):
        raise InputRejected("nan", f"{reason_where} has non-finite values {tuple(values)}")


def pose_from_msg(msg: Any) -> PoseReading:
    """geometry_msgs/PoseStamped -> PoseReading (validated)."""
    p = msg.pose.position
    o = msg.pose.orientation
    _finite("pose position", (p.x, p.y, p.z))
    yaw = quaternion_to_yaw(o.x, o.y, o.z, o.w)
    return PoseReading(stamp_to_ns(msg.header.stamp), float(p.x), float(p.y), yaw)


def wrench_from_msg(msg: Any) -> WrenchReading:
    """geometry_msgs/WrenchStamped -> WrenchReading (planar part, validated)."""
    f = msg.wrench.force
    t = msg.wrench.torque
    _finite("wrench", (f.x, f.y, f.z, t.x, t.y, t.z))
    return WrenchReading(stamp_to_ns(msg.header.stamp), float(f.x), float(f.y), float(t.z))


def joints_from_msg(msg: Any, names: Sequence[str]) -> JointReading:
    """sensor_msgs/JointState -> positions in the order of `names` (validated).

    Every name in `names` must be present; names the scenario does not know are rejected, so a
    mis-wired robot is noticed instead of silently ignored.
    """
    got = list(msg.name)
    pos = list(msg.position)
    if len(got) != len(pos):
        raise InputRejected(
            "malformed", f"JointState has {len(got)} names but {len(pos)} positions"
        )
    unknown = sorted(set(got) - set(names))
    if unknown:
        shown = f"{unknown[:5]} and {len(unknown) - 5} more" if len(unknown) > 5 else unknown
        raise InputRejected(
            "unknown_joint", f"unknown joint name(s) {shown}; expected {list(names)}"
        )
    missing = [n for n in names if n not in got]
    if missing:
        raise InputRejected("missing_joint", f"JointState lacks joint(s) {missing}")
    values = tuple(float(pos[got.index(n)]) for n in names)
    _finite("joint positions", values)
    return JointReading(stamp_to_ns(msg.header.stamp), values)


def array_from_msg(msg: Any) -> FloatArray:
    """std_msgs/Float64MultiArray -> numpy array shaped by its layout dims (row-major)."""
    dims = [int(d.size) for d in msg.layout.dim]
    data = np.asarray(list(msg.data), dtype=np.float64)
    if dims and int(np.prod(dims)) == data.size:
        return data.reshape(dims)
    return data


def float64_multiarray(values: npt.ArrayLike, labels: Sequence[str]) -> Any:
    """numpy array -> std_msgs/Float64MultiArray with labelled row-major layout dims."""
    arr = np.ascontiguousarray(np.asarray(values, dtype=np.float64))
    if arr.ndim != len(labels):
        msg = f"array of shape {arr.shape} needs {arr.ndim} labels, got {list(labels)}"
        raise ValueError(msg)
    multi = rt.message_class("std_msgs/msg/Float64MultiArray")
    layout_cls = rt.message_class("std_msgs/msg/MultiArrayLayout")
    dim_cls = rt.message_class("std_msgs/msg/MultiArrayDimension")
    dims = []
    for axis, label in enumerate(labels):
        stride = int(np.prod(arr.shape[axis:])) if arr.ndim else 1
        dims.append(dim_cls(label=str(label), size=int(arr.shape[axis]), stride=stride))
    return multi(layout=layout_cls(dim=dims, data_offset=0), data=[float(v) for v in arr.ravel()])


def _header(stamp_ns: int, frame_id: str) -> Any:
    header_cls = rt.message_class("std_msgs/msg/Header")
    return header_cls(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


def _pose(x: float, y: float, yaw: float) -> Any:
    pose_cls = rt.message_class("geometry_msgs/msg/Pose")
    point_cls = rt.message_class("geometry_msgs/msg/Point")
    quat_cls = rt.message_class("geometry_msgs/msg/Quaternion")
    qx, qy, qz, qw = yaw_to_quaternion(yaw)
    return pose_cls(
        position=point_cls(x=float(x), y=float(y), z=0.0),
        orientation=quat_cls(x=qx, y=qy, z=qz, w=qw),
    )


def pose_stamped(
    stamp_ns: int, x: float, y: float, yaw: float = 0.0, *, frame_id: str = "world"
) -> Any:
    """Planar pose (m, m, rad; yaw 0 for a point mass) -> geometry_msgs/PoseStamped."""
    cls = rt.message_class("geometry_msgs/msg/PoseStamped")
    return cls(header=_header(stamp_ns, frame_id), pose=_pose(x, y, yaw))


def wrench_stamped(
    stamp_ns: int, fx: float, fy: float, tau: float = 0.0, *, frame_id: str = "world"
) -> Any:
    """Planar wrench (N, N, N m; tau 0 for a point mass) -> geometry_msgs/WrenchStamped."""
    cls = rt.message_class("geometry_msgs/msg/WrenchStamped")
    wrench_cls = rt.message_class("geometry_msgs/msg/Wrench")
    vec = rt.message_class("geometry_msgs/msg/Vector3")
    return cls(
        header=_header(stamp_ns, frame_id),
        wrench=wrench_cls(
            force=vec(x=float(fx), y=float(fy), z=0.0), torque=vec(x=0.0, y=0.0, z=float(tau))
        ),
    )


def planar_cov6(cov3: npt.ArrayLike) -> list[float]:
    """3x3 covariance over (x, y, yaw) -> REP-103 6x6 row-major list (other dims 0)."""
    c3 = np.asarray(cov3, dtype=np.float64)
    c6 = np.zeros((6, 6))
    for i, a in enumerate(_PLANAR_IDX):
        for j, b in enumerate(_PLANAR_IDX):
            c6[a, b] = c3[i, j]
    c6 = 0.5 * (c6 + c6.T)
    return [float(v) for v in c6.ravel()]


def friction_map_grid(
    view: FrictionMapView, scenario: Scenario, stamp_ns: int, frame_id: str = "world"
) -> Any:
    """Friction map -> nav_msgs/OccupancyGrid.

    One row per friction pair (row p = pair p, in `/scenario` order), one column per cell of
    the contact coordinate s (m along the obstacle tangent; for the edge scenario s = x, so the
    grid lies on the edge in `world`). Cell value: probability (0-100) that the pair's
    coefficient there is its highest candidate; -1 where contact never happened.
    """
    grid_cls = rt.message_class("nav_msgs/msg/OccupancyGrid")
    info_cls = rt.message_class("nav_msgs/msg/MapMetaData")
    n_pairs = len(scenario.friction.pairs)
    data = np.full((n_pairs, view.n_cells), -1, dtype=np.int64)
    for p in range(n_pairs):
        cands = np.asarray(scenario.friction.candidates[p], dtype=np.float64)
        hi = int(np.argmax(cands))
        probs = np.asarray(view.probs[p], dtype=np.float64)
        touched = view.touched(p)
        pct = np.clip(np.rint(100.0 * probs[:, hi]), 0, 100).astype(np.int64)
        data[p, touched] = pct[touched]
    origin_y = scenario.edge_y - 0.5 * view.cell_size if scenario.kind == "edge" else 0.0
    info = info_cls(
        map_load_time=ns_to_stamp(stamp_ns),
        resolution=float(view.cell_size),
        width=int(view.n_cells),
        height=int(n_pairs),
        origin=_pose(view.s_min, origin_y, 0.0),
    )
    return grid_cls(
        header=_header(stamp_ns, frame_id), info=info, data=[int(v) for v in data.ravel()]
    )


def estimate_messages(
    est: Estimate, scenario: Scenario, stamp_ns: int, frame_id: str = "world"
) -> dict[str, Any]:
    """One filter step's outputs as messages keyed by contract topic (pose first).

    Never emits NaN: a non-finite estimate raises ValueError (the node then skips publishing
    and counts it), because a silently wrong estimate is worse than a missing one.
    """
    bad = est.non_finite_field()
    if bad is not None:
        msg = f"estimate field {bad} has non-finite values at step {est.step}"
        raise ValueError(msg)
    x, y, yaw = (float(v) for v in est.pose)
    pwc_cls = rt.message_class("geometry_msgs/msg/PoseWithCovarianceStamped")
    pwc = rt.message_class("geometry_msgs/msg/PoseWithCovariance")
    odom_cls = rt.message_class("nav_msgs/msg/Odometry")
    twc = rt.message_class("geometry_msgs/msg/TwistWithCovariance")
    twist_cls = rt.message_class("geometry_msgs/msg/Twist")
    vec = rt.message_class("geometry_msgs/msg/Vector3")
    header = _header(stamp_ns, frame_id)
    pose_cov = planar_cov6(est.pose_cov)
    pose = pwc_cls(header=header, pose=pwc(pose=_pose(x, y, yaw), covariance=pose_cov))
    vx, vy, om = (float(v) for v in est.twist)
    odom = odom_cls(
        header=_header(stamp_ns, frame_id),
        child_frame_id="object",
        pose=pwc(pose=_pose(x, y, yaw), covariance=pose_cov),
        twist=twc(
            twist=twist_cls(linear=vec(x=vx, y=vy, z=0.0), angular=vec(x=0.0, y=0.0, z=om)),
            covariance=planar_cov6(est.twist_cov),
        ),
    )
    assert len(MODE_NAMES) == est.modes.shape[1]
    return {
        POSE: pose,
        ODOMETRY: odom,
        CONTACT_MODES: float64_multiarray(est.modes, ("contacts", "modes")),
        FRICTION: float64_multiarray(est.friction, ("pairs", "candidates")),
        FRICTION_MAP: friction_map_grid(est.friction_map, scenario, stamp_ns, frame_id),
    }
