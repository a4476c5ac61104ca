"""QoS profiles as rosbag2 records them (metadata version 9 and MCAP channel metadata).

A bag stores, for every topic, the list of QoS profiles the publishers *offered* while it was
recorded. Playback uses them to publish again with the same reliability and durability (so a
transient-local topic such as ``/scenario`` is latched again after playback).

The profile type is :class:`rosbags.interfaces.Qos` (history, depth, reliability, durability,
deadline, lifespan, liveliness, lease duration, namespace flag), so rosbags readers and writers
can use the profiles directly. Durations are ``QosTime(sec, nsec)``; "infinite" is the rmw value
``(9223372036, 854775807)``, as rosbag2 writes it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from dbcslam_ros.contract import contract_qos_profile
from dbcslam_ros.errors import BagError
from dbcslam_ros.qos import INFINITE, PROFILES, QoSProfile, to_bag_qos

__all__ = [
    "INFINITE",
    "LATCHED_QOS",
    "RELIABLE_QOS",
    "SENSOR_DATA_QOS",
    "Qos",
    "QosDurability",
    "QosHistory",
    "QosLiveliness",
    "QosReliability",
    "QosTime",
    "contract_qos",
    "make_qos",
    "qos_from_yaml",
    "qos_to_dicts",
    "qos_to_yaml_string",
]

#: rmw's "default" (zero) duration.
_ZERO = QosTime(0, 0)


def make_qos(
    *,
    reliable: bool = True,
    transient_local: bool = False,
    depth: int = 10,
    keep_all: bool = False,
) -> Qos:
    """Build a QoS profile with the defaults of rclpy for everything not given.

    Args:
        reliable: RELIABLE if True, else BEST_EFFORT.
        transient_local: TRANSIENT_LOCAL (late joiners get the last ``depth`` samples) if True,
            else VOLATILE.
        depth: history depth (samples kept), >= 1 for KEEP_LAST.
        keep_all: KEEP_ALL history instead of KEEP_LAST.
    """
    return to_bag_qos(
        QoSProfile(
            "reliable" if reliable else "best_effort",
            "transient_local" if transient_local else "volatile",
            "keep_all" if keep_all else "keep_last",
            depth,
        )
    )


#: rclpy ``qos_profile_sensor_data``: best effort, volatile, keep last 5.
SENSOR_DATA_QOS = to_bag_qos(PROFILES["sensor_data"])
#: rclpy default publisher profile: reliable, volatile, keep last 10.
RELIABLE_QOS = to_bag_qos(PROFILES["default"])
#: Latched topic (``/scenario``): reliable, transient local, keep last 1.
LATCHED_QOS = to_bag_qos(PROFILES["latched"])


def contract_qos(topic: str) -> Qos:
    """QoS of a topic as the interface contract fixes it (:mod:`dbcslam_ros.contract`):
    sensor inputs :data:`SENSOR_DATA_QOS`, ``/scenario`` :data:`LATCHED_QOS`, every other
    topic (truth, estimates, diagnostics, unknown ones) :data:`RELIABLE_QOS`."""
    return to_bag_qos(contract_qos_profile(topic))


def _time_dict(value: QosTime) -> dict[str, int]:
    return {"sec": int(value.sec), "nsec": int(value.nsec)}


def qos_to_dicts(profiles: Sequence[Qos]) -> list[dict[str, Any]]:
    """Profiles as the list of mappings rosbag2 metadata version 9 stores (enum names lower)."""
    return [
        {
            "history": q.history.name.lower(),
            "depth": int(q.depth),
            "reliability": q.reliability.name.lower(),
            "durability": q.durability.name.lower(),
            "deadline": _time_dict(q.deadline),
            "lifespan": _time_dict(q.lifespan),
            "liveliness": q.liveliness.name.lower(),
            "liveliness_lease_duration": _time_dict(q.liveliness_lease_duration),
            "avoid_ros_namespace_conventions": bool(q.avoid_ros_namespace_conventions),
        }
        for q in profiles
    ]


def qos_to_yaml_string(profiles: Sequence[Qos]) -> str:
    """Profiles as the YAML string of MCAP channel metadata ``offered_qos_profiles``.

    An empty list gives ``""`` (what rosbag2 stores when nothing was offered).
    """
    if not profiles:
        return ""
    return yaml.safe_dump(
        qos_to_dicts(profiles), default_flow_style=False, sort_keys=False
    ).strip()


def _enum_value(enum: Any, value: object, field: str) -> Any:
    if isinstance(value, bool):
        msg = f"QoS field {field!r} must be a name or an integer, got {value!r}"
        raise BagError(msg)
    if isinstance(value, int):
        try:
            return enum(value)
        except ValueError as err:
            msg = f"QoS field {field!r}: {value} is not one of {[e.value for e in enum]}"
            raise BagError(msg) from err
    if isinstance(value, str):
        try:
            return enum.__members__[value.upper()]
        except KeyError as err:
            names = [name.lower() for name in enum.__members__]
            msg = f"QoS field {field!r}: {value!r} is not one of {names}"
            raise BagError(msg) from err
    msg = f"QoS field {field!r} must be a name or an integer, got {value!r}"
    raise BagError(msg)


def _time_value(value: object, field: str) -> QosTime:
    if value is None:
        return _ZERO
    if isinstance(value, Mapping):
        try:
            return QosTime(int(value["sec"]), int(value["nsec"]))
        except (KeyError, TypeError, ValueError) as err:
            msg = f"QoS field {field!r} needs integer 'sec' and 'nsec', got {dict(value)!r}"
            raise BagError(msg) from err
    msg = f"QoS field {field!r} needs a mapping with 'sec' and 'nsec', got {value!r}"
    raise BagError(msg)


def qos_from_yaml(value: str | Sequence[Mapping[str, Any]] | None) -> tuple[Qos, ...]:
    """Parse offered QoS profiles from a metadata.yaml list or a YAML string (v8 or v9).

    Accepts enum names (``reliable``) and the integers of older rosbag2 versions.

    Raises:
        BagError: the YAML is malformed or a field has an invalid value.
    """
    if value is None or value in ("", []):
        return ()
    items: object
    if isinstance(value, str):
        try:
            items = yaml.safe_load(value)
        except yaml.YAMLError as err:
            msg = f"offered_qos_profiles is not valid YAML: {err}".splitlines()[0]
            raise BagError(msg) from err
    else:
        items = value
    if items is None:
        return ()
    if not isinstance(items, list):
        msg = f"offered_qos_profiles must be a list of profiles, got {type(items).__name__}"
        raise BagError(msg)
    out: list[Qos] = []
    for item in items:
        if not isinstance(item, Mapping):
            msg = f"offered_qos_profiles entries must be mappings, got {item!r}"
            raise BagError(msg)
        out.append(
            Qos(
                history=_enum_value(QosHistory, item.get("history", 1), "history"),
                depth=int(item.get("depth", 0)),
                reliability=_enum_value(QosReliability, item.get("reliability", 1), "reliability"),
                durability=_enum_value(QosDurability, item.get("durability", 2), "durability"),
                deadline=_time_value(item.get("deadline"), "deadline"),
                lifespan=_time_value(item.get("lifespan"), "lifespan"),
                liveliness=_enum_value(QosLiveliness, item.get("liveliness", 1), "liveliness"),
                liveliness_lease_duration=_time_value(
                    item.get("liveliness_lease_duration"), "liveliness_lease_duration"
                ),
                avoid_ros_namespace_conventions=bool(
                    item.get("avoid_ros_namespace_conventions", False)
                ),
            )
        )
    return tuple(out)
