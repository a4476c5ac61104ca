"""`/dbcslam/markers` (visualization_msgs/MarkerArray) of one estimate, for RViz: the body at
the estimated pose (yellow outline or sphere), the most probable particles (grey points), and
the potential contact points coloured by their most probable mode (alpha = P(in contact)).
World frame (REP-103), metres."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dbcslam_core.angles import yaw_to_quaternion
from dbcslam_core.geometry import contact_kinematics
from dbcslam_core.rbpf import Estimate
from dbcslam_core.scenario import Scenario
from dbcslam_ros import runtime as rt

__all__ = ["MODE_COLOURS", "markers_message"]

#: RGB of each contact mode (order of `contact_modes.Mode`).
MODE_COLOURS = (
    (0.6, 0.6, 0.6),  # separated: grey
    (0.1, 0.8, 0.1),  # sticking: green
    (0.95, 0.3, 0.1),  # sliding_pos: red-orange
    (0.2, 0.3, 0.95),  # sliding_neg: blue
)

_LINE_STRIP, _SPHERE, _SPHERE_LIST, _POINTS = 4, 2, 7, 8


def markers_message(
    est: Estimate,
    scenario: Scenario,
    header: Any,
    *,
    n_particles: int,
    joints: Sequence[float],
) -> Any:
    """The MarkerArray of `est`: body, the n_particles heaviest particles, contacts (at the
    joint positions `joints`, scenario.joints order; () = none known)."""
    cls = rt.message_class
    markers = [
        _body_marker(est, scenario, header),
        _particle_marker(est, header, n_particles),
        _contact_marker(est, scenario, header, joints),
    ]
    return cls("visualization_msgs/msg/MarkerArray")(markers=markers)


def _point(x: float, y: float) -> Any:
    return rt.message_class("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=0.0)


def _colour(r: float, g: float, b: float, a: float) -> Any:
    return rt.message_class("std_msgs/msg/ColorRGBA")(r=r, g=g, b=b, a=a)


def _pose(x: float, y: float, yaw: float) -> Any:
    qx, qy, qz, qw = yaw_to_quaternion(yaw)
    return rt.message_class("geometry_msgs/msg/Pose")(
        position=_point(x, y),
        orientation=rt.message_class("geometry_msgs/msg/Quaternion")(x=qx, y=qy, z=qz, w=qw),
    )


def _marker(header: Any, ns: str, ident: int, kind: int, scale: float, **fields: Any) -> Any:
    vec = rt.message_class("geometry_msgs/msg/Vector3")
    y = scale if kind != _LINE_STRIP else 0.0  # a line strip's width is x only
    z = scale if kind in (_SPHERE, _SPHERE_LIST) else 0.0  # points are flat
    size = (scale, y, z)
    return rt.message_class("visualization_msgs/msg/Marker")(
        header=header,
        ns=ns,
        id=ident,
        type=kind,
        action=0,
        scale=vec(x=size[0], y=size[1], z=size[2]),
        **fields,
    )


def _body_marker(est: Estimate, scenario: Scenario, header: Any) -> Any:
    x, y, yaw = (float(v) for v in est.pose)
    yellow = _colour(1.0, 1.0, 0.0, 1.0)
    body = scenario.body
    if body.shape == "polygon":
        verts = [*body.vertices, body.vertices[0]]
        points = [_point(vx, vy) for vx, vy in verts]
        pose = _pose(x, y, yaw)
        return _marker(
            header, "body", 0, _LINE_STRIP, 0.002, pose=pose, color=yellow, points=points
        )
    return _marker(header, "body", 0, _SPHERE, 0.02, pose=_pose(x, y, yaw), color=yellow)


def _particle_marker(est: Estimate, header: Any, n_particles: int) -> Any:
    q, w = est.particle_poses, est.particle_weights
    idx = np.argsort(-w)[: min(n_particles, len(q))]
    points = [_point(q[i, 0], q[i, 1]) for i in idx]
    grey = _colour(0.8, 0.8, 0.8, 0.6)
    return _marker(
        header, "particles", 1, _POINTS, 0.003, pose=_pose(0.0, 0.0, 0.0), color=grey,
        points=points,
    )  # fmt: skip


def _contact_marker(
    est: Estimate, scenario: Scenario, header: Any, joints: Sequence[float]
) -> Any:
    env = np.asarray(joints, dtype=np.float64) if joints else None
    kin = contact_kinematics(scenario, est.pose[: scenario.nq], env, None)
    points, colours = [], []
    for c in range(len(scenario.contacts)):
        probs = est.modes[c]
        r, g, b = MODE_COLOURS[int(np.argmax(probs))]
        points.append(_point(kin.point[c, 0], kin.point[c, 1]))
        colours.append(_colour(r, g, b, float(max(0.2, 1.0 - probs[0]))))
    white = _colour(1.0, 1.0, 1.0, 1.0)
    return _marker(
        header, "contacts", 2, _SPHERE_LIST, 0.008, pose=_pose(0.0, 0.0, 0.0), color=white,
        points=points, colors=colours,
    )  # fmt: skip
