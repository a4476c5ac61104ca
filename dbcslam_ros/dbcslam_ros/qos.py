"""QoS in one form: the plain-data :class:`QoSProfile`, the named profiles, the one rule that
adapts to what publishers offer, and the one conversion to and from the form rosbag2 records.

:func:`dbcslam_ros.runtime.native_qos` turns a profile into a real ``rclpy.qos.QoSProfile``;
:func:`dbcslam_ros.runtime.neutral_qos` goes the other way. :func:`to_bag_qos` /
:func:`from_bag_qos` convert to and from :class:`rosbags.interfaces.Qos` (bag metadata). Which
topic has which profile is in :mod:`dbcslam_ros.contract`.

Named profiles (ROS 2 conventions):

- ``sensor_data``: best effort, volatile, keep last 5
- ``default``: reliable, volatile, keep last 10
- ``latched``: reliable, transient local, keep last 1 (late joiners get the last sample)
- ``clock``: best effort, volatile, keep last 1 (what rclpy's time source subscribes with)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from dbcslam_ros.errors import UsageError

__all__ = [
    "DURABILITIES",
    "HISTORIES",
    "INFINITE",
    "PROFILES",
    "RELIABILITIES",
    "QoSProfile",
    "adapt_to_offers",
    "from_bag_qos",
    "named_profile",
    "profile_from_policies",
    "to_bag_qos",
]

#: rmw's "infinite" duration as rosbag2 stores it (seconds and nanoseconds of INT64_MAX ns).
INFINITE = QosTime(9223372036, 854775807)

RELIABILITIES = ("reliable", "best_effort")
DURABILITIES = ("volatile", "transient_local")
HISTORIES = ("keep_last", "keep_all")


@dataclass(frozen=True)
class QoSProfile:
    """Quality of service of one publisher or subscription.

    Attributes:
        reliability: ``reliable`` or ``best_effort``.
        durability: ``volatile`` or ``transient_local``.
        history: ``keep_last`` or ``keep_all``.
        depth: queue depth for ``keep_last`` (>= 1; ignored for ``keep_all``).
    """

    reliability: str = "reliable"
    durability: str = "volatile"
    history: str = "keep_last"
    depth: int = 10

    def __post_init__(self) -> None:
        for field, value, allowed in (
            ("reliability", self.reliability, RELIABILITIES),
            ("durability", self.durability, DURABILITIES),
            ("history", self.history, HISTORIES),
        ):
            if value not in allowed:
                msg = f"bad QoS {field} {value!r}: expected one of {allowed}"
                raise UsageError(msg)
        if self.history == "keep_last" and int(self.depth) < 1:
            msg = f"bad QoS depth {self.depth!r} for keep_last: expected >= 1"
            raise UsageError(msg)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict ``{reliability, durability, history, depth}`` (e.g. for bag metadata)."""
        return {
            "reliability": self.reliability,
            "durability": self.durability,
            "history": self.history,
            "depth": int(self.depth),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> QoSProfile:
        """Inverse of :meth:`to_dict`; missing keys take the ``default`` profile's values."""
        unknown = set(data) - {"reliability", "durability", "history", "depth"}
        if unknown:
            msg = (
                f"unknown QoS keys {sorted(unknown)}: "
                "expected reliability/durability/history/depth"
            )
            raise UsageError(msg)
        base = PROFILES["default"]
        return cls(
            str(data.get("reliability", base.reliability)),
            str(data.get("durability", base.durability)),
            str(data.get("history", base.history)),
            int(data.get("depth", base.depth)),
        )


PROFILES: dict[str, QoSProfile] = {
    "sensor_data": QoSProfile("best_effort", "volatile", "keep_last", 5),
    "default": QoSProfile("reliable", "volatile", "keep_last", 10),
    "latched": QoSProfile("reliable", "transient_local", "keep_last", 1),
    "clock": QoSProfile("best_effort", "volatile", "keep_last", 1),
}


def named_profile(name: str, depth: int | None = None) -> QoSProfile:
    """Return the named profile, optionally with another ``depth``.

    Raises:
        UsageError: unknown profile name.
    """
    try:
        prof = PROFILES[name]
    except KeyError as err:
        msg = f"unknown QoS profile {name!r}: expected one of {sorted(PROFILES)}"
        raise UsageError(msg) from err
    return prof if depth is None else replace(prof, depth=int(depth))


def adapt_to_offers(offered: Sequence[QoSProfile], depth: int = 10) -> QoSProfile:
    """A subscription QoS compatible with every offered publisher QoS and as strong as they
    allow (the rule of the rosbag2 recorder and player): reliable if every publisher is
    reliable, transient local if every one is, keep last ``depth`` (at least 1).

    No offer at all gives the rosbag2 default: reliable, volatile (what rosbag2 uses when a bag
    records no ``offered_qos_profiles``, and what its recorder requests before a publisher
    is known).
    """
    reliable = all(q.reliability == "reliable" for q in offered)
    latched = bool(offered) and all(q.durability == "transient_local" for q in offered)
    return QoSProfile(
        "reliable" if reliable else "best_effort",
        "transient_local" if latched else "volatile",
        "keep_last",
        max(1, int(depth)),
    )


def to_bag_qos(qos: QoSProfile) -> Qos:
    """`qos` in the form rosbag2 records (deadline, lifespan, liveliness at rmw defaults)."""
    return Qos(
        history=QosHistory.KEEP_ALL if qos.history == "keep_all" else QosHistory.KEEP_LAST,
        depth=int(qos.depth),
        reliability=QosReliability.RELIABLE
        if qos.reliability == "reliable"
        else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else QosDurability.VOLATILE,
        deadline=INFINITE,
        lifespan=INFINITE,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=INFINITE,
        avoid_ros_namespace_conventions=False,
    )


def from_bag_qos(qos: Qos) -> QoSProfile:
    """The plain profile of a recorded rosbag2 QoS (inverse of :func:`to_bag_qos`); anything
    but BEST_EFFORT counts as reliable, anything but TRANSIENT_LOCAL as volatile."""
    return profile_from_policies(
        best_effort=qos.reliability == QosReliability.BEST_EFFORT,
        transient_local=qos.durability == QosDurability.TRANSIENT_LOCAL,
        keep_all=qos.history == QosHistory.KEEP_ALL,
        depth=int(qos.depth),
    )


def profile_from_policies(
    *, best_effort: bool, transient_local: bool, keep_all: bool, depth: int
) -> QoSProfile:
    """The plain profile of a foreign QoS read as four policies (rosbags or rclpy enums
    compared by the caller); depth 0 for keep-all, at least 1 for keep-last."""
    return QoSProfile(
        "best_effort" if best_effort else "reliable",
        "transient_local" if transient_local else "volatile",
        "keep_all" if keep_all else "keep_last",
        0 if keep_all else max(int(depth), 1),
    )
