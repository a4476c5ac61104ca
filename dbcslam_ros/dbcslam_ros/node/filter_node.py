"""The DBC-SLAM filter node: subscribes to the contract's inputs, publishes its outputs.

Run: ``dbcslam filter [--params FILE]`` or ``ros2 run dbcslam_ros filter_node``.

The node configures itself from the latched ``/scenario`` (or parameter ``scenario_file``;
a changed ``/scenario`` reconfigures it), feeds decoded inputs to a
:class:`~dbcslam_ros.node.session.FilterSession` (synchronisation rules there) and publishes, for
every processed pose, ``/dbcslam/pose`` first, then odometry, contact modes, friction, the
friction map, markers (at most one per ``marker_period`` of stamp time); ``/diagnostics``
every ``diagnostics_period`` s. ``/pusher/wrench`` (push) is a force observation when
``use_pusher_wrench`` is true. ``particles`` -1 (default) takes :data:`LIVE_PARTICLES` of the
scenario kind.

Robustness: a bad message (NaN, zero quaternion, stamp going backwards, unknown joint, ...) is
logged (throttled), counted per reason in ``/diagnostics`` and dropped; the node keeps running.
A jump back in time (bag played with --loop) resets the filter. A non-finite estimate or a
failing filter step is never published: it is counted and the filter is reset.

Backlog: poses are queued with depth one. When a new pose arrives before the previous one was
processed, the older one is dropped (reason ``backlog``) and the next step catches up with at
most ``catch_up_steps`` model steps (the state is held over the rest of the gap, counted as
``skipped_steps``), so a filter slower than the input rate lags by a bounded amount.
"""

from __future__ import annotations

import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.utilities import ok, try_shutdown

from dbcslam_core.errors import DbcSlamError
from dbcslam_core.rbpf import warm_up_kernels
from dbcslam_core.scenario import Scenario
from dbcslam_ros import contract
from dbcslam_ros import runtime as rt
from dbcslam_ros.contract import (
    DIAGNOSTICS,
    JOINT_STATES,
    OBJECT_POSE,
    OBJECT_WRENCH,
    OUTPUT_TOPICS,
    POSE,
    PUSHER_WRENCH,
    SCENARIO,
    message_type,
)
from dbcslam_ros.errors import ParameterError
from dbcslam_ros.node.inputs import feed_input
from dbcslam_ros.node.outputs import EstimateOutputs, diagnostics_message
from dbcslam_ros.node.params import (
    LIVE_PARTICLES,
    PARAMETERS,
    build_config,
    check_params,
    coerce_params,
    live_particles,
    load_extensions,
    make_session,
)
from dbcslam_ros.node.session import WINDOW, FilterSession, StampedEstimate
from dbcslam_ros.ros_context import init_ros

# The node's parameters live in dbcslam_ros.node.params (no rclpy there); the names below are
# re-exported here as the node's own: LIVE_PARTICLES, PARAMETERS, build_config, coerce_params,
# live_particles, load_extensions.
__all__ = [
    "INPUT_TOPICS",
    "LIVE_PARTICLES",
    "OUTPUT_TYPES",
    "PARAMETERS",
    "FilterCore",
    "FilterNode",
    "build_config",
    "coerce_params",
    "live_particles",
    "load_extensions",
    "main",
]

#: Output topics and their types (contract table), in publication order.
OUTPUT_TYPES: dict[str, str] = {topic: message_type(topic) for topic in OUTPUT_TOPICS}

#: A filter step slower than this (s) is logged as a warning.
SLOW_STEP_S = 0.5


#: Input topics (type, FilterCore method), in subscription order: inputs before the pose, so
#: an executor serving subscriptions in creation order hands over a step's inputs first.
INPUT_TOPICS: dict[str, tuple[str, str]] = {
    topic: (message_type(topic), method)
    for topic, method in zip(
        contract.INPUT_TOPICS,
        ("on_scenario", "on_wrench", "on_joints", "on_pusher_wrench", "on_pose"),
        strict=True,
    )
}


class FilterCore:
    """The filter node's behaviour without ROS: decoded input messages in (the ``on_*``
    methods, :meth:`process_pending`), output messages out through ``publish(topic, msg)``.

    It converts and reports; the decisions are the session's: inputs go to the
    :class:`FilterSession` through :func:`~dbcslam_ros.node.inputs.feed_input`, a queued pose
    is processed by :meth:`FilterSession.process_pending`, the messages of an estimate are built
    by :class:`~dbcslam_ros.node.outputs.EstimateOutputs`. :class:`FilterNode` wires it to
    rclpy; offline replay drives a session with the same pieces.
    """

    def __init__(
        self, params: Mapping[str, Any], publish: Callable[[str, Any], None], logger: Any
    ) -> None:
        self.log = logger
        self._publish_msg = publish
        self.params: dict[str, Any] = dict(params)
        check_params(self.params)
        # the compiled kernels of every scenario kind, before the node subscribes: a fresh
        # install compiles them here (~30 s), not while the first scenario's poses arrive
        self.warm_up_s = warm_up_kernels()
        if self.warm_up_s > 1.0:
            self.log.info(f"compiled the filter kernels in {self.warm_up_s:.1f} s (cached now)")
        self.frame = str(self.params["frame_id"])
        self.session: FilterSession | None = None
        self.scenario: Scenario | None = None
        self.extensions = load_extensions(str(self.params["model_file"]))
        self.outputs = EstimateOutputs(
            self.frame,
            int(self.params["marker_particles"]),
            float(self.params["marker_period"]),
            logger,
        )
        self.rejected_before_scenario = 0
        self.received = 0
        self.published = 0
        # latency from pose receipt to publication over the last WINDOW estimates (the
        # session keeps the filter's own statistics)
        self.latencies: deque[float] = deque(maxlen=WINDOW)
        self._rate_window: deque[float] = deque()
        path = str(self.params["scenario_file"])
        if path:
            try:
                self.configure(Scenario.from_yaml(Path(path).read_text()))
            except (OSError, DbcSlamError) as err:
                msg = f"cannot load scenario_file {path!r}: {err}"
                raise ParameterError(msg) from err

    @property
    def last_estimate(self) -> StampedEstimate | None:
        """The last estimate the session produced (None before one / after a reset)."""
        return None if self.session is None else self.session.last_estimate

    @property
    def backlog_dropped(self) -> int:
        """Poses dropped unprocessed from the depth-one queue (the filter was busy)."""
        return 0 if self.session is None else self.session.backlog_dropped

    @property
    def not_published(self) -> Counter[str]:
        """Estimates (or their markers) not published, by reason."""
        return self.outputs.not_published

    def callbacks(self) -> dict[str, Callable[[Any], None]]:
        """``{input topic: method}`` in :data:`INPUT_TOPICS` order."""
        return {topic: getattr(self, method) for topic, (_t, method) in INPUT_TOPICS.items()}

    # -- configuration -----------------------------------------------------------------------
    def configure(self, scenario: Scenario) -> None:
        """(Re)build the session for a scenario."""
        self.session = make_session(scenario, self.params, self.extensions)
        self.scenario = scenario
        self.log.info(
            f"configured for scenario '{scenario.kind}': contacts {list(scenario.contacts)}, "
            f"friction pairs {list(scenario.friction.pairs)}, "
            f"{self.session.config.particles} particles"
        )

    def on_scenario(self, msg: Any) -> None:
        if str(self.params["scenario_file"]):
            return
        try:
            scenario = Scenario.from_yaml(str(msg.data))
        except (DbcSlamError, ValueError, TypeError, KeyError) as err:
            self._reject("bad_scenario", f"ignoring /scenario: {err}")
            return
        if self.scenario is not None and scenario == self.scenario:
            return
        try:
            self.configure(scenario)
        except ParameterError as err:
            self._reject("bad_scenario", f"cannot configure for /scenario: {err}")

    # -- inputs ------------------------------------------------------------------------------
    def _reject(self, reason: str, text: str) -> None:
        if self.session is not None:
            self.session.reject(reason)
        else:
            self.rejected_before_scenario += 1
        self.log.warning(text, throttle_duration_sec=2.0)

    def _feed(self, topic: str, msg: Any, received: float = 0.0) -> None:
        if self.session is None:
            return
        use_force = bool(self.params["use_pusher_wrench"])
        text = feed_input(self.session, topic, msg, use_pusher_wrench=use_force, received=received)
        if text is not None:
            self.log.warning(text, throttle_duration_sec=2.0)

    def on_wrench(self, msg: Any) -> None:
        self._feed(OBJECT_WRENCH, msg)

    def on_pusher_wrench(self, msg: Any) -> None:
        """Pusher F/T reading: a force observation (session rules), when enabled."""
        self._feed(PUSHER_WRENCH, msg)

    def on_joints(self, msg: Any) -> None:
        self._feed(JOINT_STATES, msg)

    def on_pose(self, msg: Any) -> None:
        """Queue a pose (depth one: a newer pose drops an unprocessed one)."""
        received = time.monotonic()
        self.received += 1
        self._rate_window.append(received)
        if self.session is None:
            self.rejected_before_scenario += 1
            self.log.warning("no /scenario yet: dropping pose", throttle_duration_sec=5.0)
            return
        self._feed(OBJECT_POSE, msg, received)

    def process_pending(self) -> None:
        """Run the filter on the queued pose (timer callback, after the inputs were taken):
        the session decides (`FilterSession.process_pose`), the node logs and publishes."""
        if self.session is None:
            return
        taken = self.session.process_pending()
        if taken is None:
            return
        outcome, received = taken
        if outcome.rejected == "nan_estimate":
            self.not_published["nan_estimate"] += 1
        if outcome.message:
            if outcome.level == "info":
                self.log.info(outcome.message, throttle_duration_sec=1.0)
            else:
                self.log.warning(outcome.message, throttle_duration_sec=2.0)
        for res in outcome.estimates:
            self._publish(res, received)

    # -- outputs -----------------------------------------------------------------------------
    def _publish(self, res: StampedEstimate, received: float) -> None:
        assert self.scenario is not None and self.session is not None
        msgs = self.outputs.messages(res, self.scenario, self.session.last_joints())
        if not msgs:
            return
        for topic, m in msgs:  # pose first
            self._publish_msg(topic, m)
            if topic == POSE:
                self.latencies.append(time.monotonic() - received)
        if res.step_time_s > SLOW_STEP_S:
            self.log.warning(
                f"slow filter step: {res.step_time_s:.3f} s for {res.model_steps} model "
                f"step(s) at stamp {res.stamp_ns * 1e-9:.3f} s",
                throttle_duration_sec=5.0,
            )
        self.published += 1

    def diagnostics_values(self) -> dict[str, str]:
        """Key/values published in /diagnostics (also used by tests and `dbcslam demo`).

        Times in ms; rates in Hz over the last diagnostics period; counters since start.
        ``rejected_<reason>``: inputs dropped per reason (``nan``, ``zero_quaternion``,
        ``stamp_order``, ``unknown_joint``, ``missing_joint``, ``malformed``, ``no_joints``,
        ``outlier``, ``backlog``, ``diverged``, ``filter_error``, ``nan_estimate``,
        ``bad_scenario``, ``no_pusher``). ``force_steps``: model steps that used a pusher
        force reading. The filter's counters and step times come from
        :meth:`FilterSession.statistics`.
        """
        now = time.monotonic()
        period = float(self.params["diagnostics_period"])
        while self._rate_window and self._rate_window[0] < now - period:
            self._rate_window.popleft()
        values: dict[str, str] = {
            "scenario": self.scenario.kind if self.scenario is not None else "",
            "poses_received": str(self.received),
            "estimates_published": str(self.published),
            "input_rate_hz": f"{len(self._rate_window) / period:.1f}",
            "rejected_before_scenario": str(self.rejected_before_scenario),
            "backlog_dropped": str(self.backlog_dropped),
        }
        if self.session is not None:
            values.update(self.session.statistics())
        if self.latencies:
            lat = np.asarray(self.latencies) * 1e3
            values["latency_ms_mean"] = f"{lat.mean():.3f}"
            values["latency_ms_p95"] = f"{np.percentile(lat, 95):.3f}"
            values["latency_ms_max"] = f"{lat.max():.3f}"
        return values

    def publish_diagnostics(self) -> None:
        stamp_ns = self.last_estimate.stamp_ns if self.last_estimate else 0
        values = self.diagnostics_values()
        msg = diagnostics_message(values, stamp_ns, configured=self.session is not None)
        self._publish_msg(DIAGNOSTICS, msg)


class FilterNode(Node):
    """The ``dbcslam_filter`` rclpy node: declares the parameters, subscribes to the contract
    inputs and publishes the outputs of a :class:`FilterCore`.

    Raises:
        ParameterError: a parameter value is invalid (``main`` exits 2).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("dbcslam_filter", **kwargs)
        params = {
            name: self.declare_parameter(
                name, default, ParameterDescriptor(description=text)
            ).value
            for name, (default, text) in PARAMETERS.items()
        }
        reliable = rt.qos_profile("default", depth=100)
        self.pubs = {
            topic: self.create_publisher(rt.message_class(type_name), topic, reliable)
            for topic, type_name in OUTPUT_TYPES.items()
        }
        logger = self.get_logger()  # type: ignore[no-untyped-call]
        self.core = FilterCore(params, self._publish, logger)
        sensor = rt.qos_profile("sensor_data", depth=50)
        callbacks = self.core.callbacks()
        self.subs = [
            self.create_subscription(
                rt.message_class(type_name),
                topic,
                callbacks[topic],
                rt.qos_profile("latched") if topic == SCENARIO else sensor,
            )
            for topic, (type_name, _m) in INPUT_TOPICS.items()
        ]
        self.process_timer = self.create_timer(0.001, self.core.process_pending)
        self.diagnostics_timer = self.create_timer(
            float(params["diagnostics_period"]), self.core.publish_diagnostics
        )

    def _publish(self, topic: str, msg: Any) -> None:
        self.pubs[topic].publish(msg)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the filter node (Jazzy node shape); exit 2 on bad parameters."""
    init_ros(list(args) if args is not None else sys.argv)
    node: Node | None = None
    code = 0
    try:
        node = FilterNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        if ok():  # not the signal-vs-wait-set race of a shutdown
            raise
    except (ParameterError, ParameterException) as err:
        # ours (bad value) or rclpy's (e.g. -p particles:=many: wrong type for the declaration)
        log = rclpy.logging.get_logger("dbcslam_filter")
        log.error(f"dbcslam_filter: {err}")
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
