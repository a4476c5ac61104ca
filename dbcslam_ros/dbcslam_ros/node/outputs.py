"""What the filter publishes, as messages: the outputs of one estimate in the contract's order
(:class:`EstimateOutputs`) and the ``/diagnostics`` message of a set of key/values
(:func:`diagnostics_message`). Shared by the live node and offline replay, so that a replayed
bag holds the messages the live node would have published."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any

from dbcslam_core.errors import DbcSlamError
from dbcslam_core.scenario import Scenario
from dbcslam_core.surprise import SURPRISE_WARNING
from dbcslam_ros import runtime as rt
from dbcslam_ros.contract import MARKERS
from dbcslam_ros.convert import estimate_messages, ns_to_stamp
from dbcslam_ros.markers import markers_message
from dbcslam_ros.node.session import StampedEstimate

__all__ = ["EstimateOutputs", "diagnostics_message"]


class EstimateOutputs:
    """The messages of each estimate: ``/dbcslam/pose`` first, then odometry, contact modes,
    friction, the friction map (:func:`~dbcslam_ros.convert.estimate_messages`), and
    ``/dbcslam/markers`` at most once per ``marker_period_s`` of stamp time (bag time in
    replay, so replays are deterministic; a jump back in time restarts the clock;
    ``marker_particles`` 0: no markers).

    A message that cannot be built is not published: it is counted in ``not_published`` by
    kind (``conversion``, ``markers``) and logged (throttled) through ``log``.
    """

    def __init__(
        self, frame: str, marker_particles: int, marker_period_s: float, log: Any
    ) -> None:
        self.frame = frame
        self.marker_particles = int(marker_particles)
        self.marker_period_ns = int(float(marker_period_s) * 1e9)
        self.log = log
        self.not_published: Counter[str] = Counter()
        self._last_marker_ns: int | None = None

    def messages(
        self, res: StampedEstimate, scenario: Scenario, joints: tuple[float, ...]
    ) -> list[tuple[str, Any]]:
        """(topic, message) pairs of one estimate, in publication order (pose first)."""
        try:  # the session screened the estimate; a failure here is a conversion bug
            msgs = list(
                estimate_messages(res.estimate, scenario, res.stamp_ns, self.frame).items()
            )
        except ValueError as err:
            self.not_published["conversion"] += 1
            self.log.error(f"not publishing: {err}", throttle_duration_sec=5.0)
            return []
        if self.marker_particles > 0 and self._marker_due(res.stamp_ns):
            try:
                msgs.append((MARKERS, self._markers(res, scenario, joints)))
            except (ValueError, DbcSlamError) as err:
                self.not_published["markers"] += 1
                self.log.warning(f"markers not published: {err}", throttle_duration_sec=5.0)
        return msgs

    def _marker_due(self, stamp_ns: int) -> bool:
        last = self._last_marker_ns
        if last is not None and 0 <= stamp_ns - last < self.marker_period_ns:
            return False
        self._last_marker_ns = stamp_ns
        return True

    def _markers(self, res: StampedEstimate, scenario: Scenario, joints: tuple[float, ...]) -> Any:
        header = rt.message_class("std_msgs/msg/Header")(
            stamp=ns_to_stamp(res.stamp_ns), frame_id=self.frame
        )
        return markers_message(
            res.estimate, scenario, header, n_particles=self.marker_particles, joints=joints
        )


def diagnostics_message(values: Mapping[str, str], stamp_ns: int, *, configured: bool) -> Any:
    """The ``/diagnostics`` DiagnosticArray of the filter (status ``dbcslam_filter``): level
    WARN while not configured (no scenario yet), when inputs were rejected or when a recent
    estimate's surprise (``surprise_nats_max``) is above `SURPRISE_WARNING` (the
    observations are badly explained: the filter may have lost the track), else OK."""
    cls = rt.message_class
    level = 0
    if not configured:
        level, text = 1, "waiting for /scenario"
    else:
        notes = []
        if values.get("rejected_total", "0") != "0":
            notes.append(f"{values['rejected_total']} input(s) rejected")
        if float(values.get("surprise_nats_max", "0")) > SURPRISE_WARNING:
            notes.append(
                f"observations badly explained (surprise {values['surprise_nats_max']} nats "
                f"> {SURPRISE_WARNING:g}): estimates unreliable, more particles may help"
            )
        level = 1 if notes else 0
        text = "; ".join(["running", *notes])
    status = cls("diagnostic_msgs/msg/DiagnosticStatus")(
        level=bytes([level]),
        name="dbcslam_filter",
        message=text,
        hardware_id="dbcslam",
        values=[cls("diagnostic_msgs/msg/KeyValue")(key=k, value=v) for k, v in values.items()],
    )
    header = cls("std_msgs/msg/Header")(stamp=ns_to_stamp(stamp_ns), frame_id="")
    return cls("diagnostic_msgs/msg/DiagnosticArray")(header=header, status=[status])
