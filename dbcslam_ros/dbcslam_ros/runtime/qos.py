"""Plain-data QoS description, named profiles and the plain-dict form used in bags.

:func:`dbcslam_ros.runtime.qos_profile` turns a named profile into a real
``rclpy.qos.QoSProfile``; :func:`dbcslam_ros.runtime.neutral_qos` goes the other way.

Named profiles (ROS 2 conventions):

- ``sensor_data``: best effort, volatile, keep last 5
- ``default``: reliable, volatile, keep last 10
- ``latched``: reliable, transient local, keep last 1 (late joiners get the last sample)
- ``clock``: best effort, volatile, keep last 1 (what rclpy's time source subscribes with)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from dbcslam_ros.errors import UsageError

__all__ = [
    "DURABILITIES",
    "HISTORIES",
    "PROFILES",
    "RELIABILITIES",
    "QoSProfile",
    "named_profile",
]

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
