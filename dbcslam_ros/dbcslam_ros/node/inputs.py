"""Decoded input messages into a :class:`~dbcslam_ros.node.session.FilterSession`: the one
path from a contract input topic to the session, for the live node and offline replay.

Each message is validated and converted (:mod:`dbcslam_ros.convert`) and handed to the
session's call for its topic: ``/object/wrench`` -> ``add_wrench``, ``/joint_states`` ->
``add_joints`` (scenario joint order), ``/pusher/wrench`` -> ``add_pusher_wrench`` (only when
the pusher force is used), ``/object/pose`` -> ``offer_pose`` (the depth-one queue; the caller
decides when :meth:`~dbcslam_ros.node.session.FilterSession.process_pending` runs). A message
that cannot be used is counted by the session under its reason and its warning text returned;
it never raises.
"""

from __future__ import annotations

from typing import Any

from dbcslam_ros.contract import JOINT_STATES, OBJECT_POSE, OBJECT_WRENCH, PUSHER_WRENCH
from dbcslam_ros.convert import InputRejected, joints_from_msg, pose_from_msg, wrench_from_msg
from dbcslam_ros.node.session import FilterSession

__all__ = ["SESSION_INPUTS", "feed_input"]

#: The input topics :func:`feed_input` takes (``/scenario`` configures the session instead).
SESSION_INPUTS: tuple[str, ...] = (OBJECT_WRENCH, JOINT_STATES, PUSHER_WRENCH, OBJECT_POSE)


def feed_input(
    session: FilterSession,
    topic: str,
    msg: Any,
    *,
    use_pusher_wrench: bool = True,
    received: float = 0.0,
) -> str | None:
    """Hand one input message to the session (module docstring).

    Args:
        topic: one of :data:`SESSION_INPUTS`.
        received: arrival time of a pose (s, any monotonic clock), kept for its latency.

    Returns:
        None when the message was taken (or deliberately unused: a pusher wrench with
        ``use_pusher_wrench`` false), else the warning text of the rejected message.

    Raises:
        ValueError: ``topic`` is not an input the session takes (a programming error).
    """
    if topic not in SESSION_INPUTS:
        text = f"feed_input: {topic!r} is not a session input; expected one of {SESSION_INPUTS}"
        raise ValueError(text)
    if topic == PUSHER_WRENCH and not use_pusher_wrench:
        return None
    try:
        reading = _convert(session, topic, msg)
    except InputRejected as err:  # bad message: counted here
        session.reject(err.reason)
        return f"rejected {topic}: {err}"
    try:
        _deliver(session, topic, reading, received)
    except InputRejected as err:  # refused by the session, which counted it
        return f"rejected {topic}: {err}"
    return None


def _convert(session: FilterSession, topic: str, msg: Any) -> Any:
    """The validated reading of a message (raises InputRejected)."""
    if topic == OBJECT_POSE:
        return pose_from_msg(msg)
    if topic == JOINT_STATES:
        return joints_from_msg(msg, session.scenario.joints)
    return wrench_from_msg(msg)


def _deliver(session: FilterSession, topic: str, reading: Any, received: float) -> None:
    if topic == OBJECT_POSE:
        session.offer_pose(reading, received)
    elif topic == OBJECT_WRENCH:
        session.add_wrench(reading)
    elif topic == JOINT_STATES:
        session.add_joints(reading)
    else:
        session.add_pusher_wrench(reading)
