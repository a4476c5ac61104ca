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
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.rbpf import FilterConfig
from dbcslam_core.scenario import Scenario
from dbcslam_ros import contract
from dbcslam_ros import runtime as rt
from dbcslam_ros.contract import (
    DIAGNOSTICS,
    MARKERS,
    OUTPUT_TOPICS,
    POSE,
    SCENARIO,
    message_type,
)
from dbcslam_ros.convert import (
    InputRejected,
    PoseReading,
    estimate_messages,
    joints_from_msg,
    ns_to_stamp,
    pose_from_msg,
    wrench_from_msg,
)
from dbcslam_ros.errors import ParameterError
from dbcslam_ros.markers import markers_message
from dbcslam_ros.node.session import WINDOW, FilterSession, StampedEstimate
from dbcslam_ros.ros_context import init_ros

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

# name: (default, description). Declared with these types and descriptions.
PARAMETERS: dict[str, tuple[Any, str]] = {
    "particles": (
        -1,
        "number of particles of the Rao-Blackwellized filter (-1: live default per scenario "
        "kind, LIVE_PARTICLES)",
    ),
    "ess_threshold": (0.5, "resample when ESS < ess_threshold * particles (0..1)"),
    "prune_threshold": (-1.0, "prune mode hypotheses below this probability (<0: preset)"),
    "parameter_model": ("", "eq. (7) form: reuse | mixture | geometric ('' = preset)"),
    "contact_weight": (-1.0, "eq. (7) weight w on the posterior while in contact (<0: preset)"),
    "gating_threshold": (
        8.0,
        "reject a pose whose Mahalanobis distance to the prediction exceeds this (0: off)",
    ),
    "seed": (0, "seed of the filter's random generator"),
    "scenario_file": ("", "YAML scenario file used instead of the /scenario topic"),
    "model_file": ("", "model-extension YAML (from `dbcslam discrepancy`) to load"),
    "frame_id": ("world", "frame of the published estimates"),
    "marker_particles": (100, "particles drawn in /dbcslam/markers (0: no markers)"),
    "marker_period": (
        0.1,
        "s of stamp time between /dbcslam/markers messages (0: one per estimate)",
    ),
    "diagnostics_period": (1.0, "seconds between /diagnostics messages"),
    "catch_up_steps": (
        2,
        "max model steps run for one pose after poses were dropped for backlog (>= 1)",
    ),
    "use_pusher_wrench": (
        True,
        "use /pusher/wrench (F/T force on the pusher) as a force observation (push scenarios)",
    ),
    "force_noise": (-1.0, "N; std per axis of the pusher force observation (<0: preset)"),
    "max_gap": (1.0, "s; a longer gap between poses re-initialises the filter"),
    "reset_after": (0.5, "s; a jump back in time larger than this resets the filter"),
}

#: Default particle count per scenario kind (parameter ``particles`` = -1): chosen so that on
#: an idle 2-core machine the filter keeps up with the simulator at 100 Hz (one core each)
#: with margin; measured with ``python -m dbcslam_research.bench_live --offline`` (README).
LIVE_PARTICLES: dict[str, int] = {"edge": 1000, "gripper": 80, "push": 100}
#: Live default for a kind not in LIVE_PARTICLES.
LIVE_PARTICLES_OTHER = 100


def live_particles(kind: str) -> int:
    """The filter node's default particle count for a scenario kind (LIVE_PARTICLES)."""
    return LIVE_PARTICLES.get(kind, LIVE_PARTICLES_OTHER)


#: A filter step slower than this (s) is logged as a warning.
SLOW_STEP_S = 0.5


def load_extensions(path: str) -> tuple[ModelExtension, ...]:
    """Model extensions from a YAML model file (``extensions: [{effect, params}, ...]`` or a
    single ``{effect, params}`` mapping); empty path -> nominal model."""
    if not path:
        return ()
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
        items = data.get("extensions", [data]) if isinstance(data, dict) else data
        return tuple(
            ModelExtension.from_dict(item) for item in items if item.get("effect") != "none"
        )
    except (OSError, yaml.YAMLError, DbcSlamError, ValueError, TypeError, AttributeError) as err:
        msg = (
            f"model_file {path!r} is not a model-extension YAML "
            f"({{effect, params}} or extensions: [...]): {err}"
        )
        raise ParameterError(msg) from err


def build_config(kind: str, params: dict[str, Any]) -> FilterConfig:
    """FilterConfig for a scenario kind from the preset plus explicit parameter overrides
    (``particles`` < 1: :func:`live_particles` of the kind)."""
    particles = int(params["particles"])
    overrides: dict[str, Any] = {
        "particles": particles if particles >= 1 else live_particles(kind),
        "ess_threshold": float(params["ess_threshold"]),
    }
    if float(params["prune_threshold"]) >= 0.0:
        overrides["prune_threshold"] = float(params["prune_threshold"])
    if str(params["parameter_model"]):
        overrides["parameter_model"] = str(params["parameter_model"])
    if float(params["contact_weight"]) >= 0.0:
        overrides["contact_weight"] = float(params["contact_weight"])
    if float(params.get("force_noise", -1.0)) > 0.0:
        overrides["force_noise"] = float(params["force_noise"])
    return FilterConfig.preset(kind, **overrides)


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


def coerce_params(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """All filter parameters: :data:`PARAMETERS` defaults with ``overrides`` converted to the
    declared types (``"true"``/``"false"`` for booleans), as offline tools pass them.

    Raises:
        ParameterError: unknown name, or a value that does not convert.
    """
    unknown = sorted(set(overrides) - set(PARAMETERS))
    if unknown:
        msg = f"unknown filter parameter(s) {unknown}: expected some of {sorted(PARAMETERS)}"
        raise ParameterError(msg)
    params = {name: default for name, (default, _text) in PARAMETERS.items()}
    for name, value in overrides.items():
        default = PARAMETERS[name][0]
        try:
            if isinstance(default, bool):
                params[name] = value if isinstance(value, bool) else str(value).lower() == "true"
            elif isinstance(default, int):
                params[name] = int(value)
            elif isinstance(default, float):
                params[name] = float(value)
            else:
                params[name] = str(value)
        except (TypeError, ValueError) as err:
            msg = f"filter parameter {name} = {value!r}: expected a {type(default).__name__}"
            raise ParameterError(msg) from err
    return params


class FilterCore:
    """The filter node's behaviour without ROS: decoded input messages in (the ``on_*``
    methods, :meth:`process_pending`), output messages out through ``publish(topic, msg)``.

    :class:`FilterNode` wires it to rclpy; offline replay (:mod:`dbcslam_ros.offline.replay`) calls
    the same methods in bag order, so live and offline run the same code.
    """

    def __init__(
        self, params: Mapping[str, Any], publish: Callable[[str, Any], None], logger: Any
    ) -> None:
        self.log = logger
        self._publish_msg = publish
        self.params: dict[str, Any] = dict(params)
        self._check_params()
        self.frame = str(self.params["frame_id"])
        self.session: FilterSession | None = None
        self.scenario: Scenario | None = None
        self.extensions = load_extensions(str(self.params["model_file"]))
        self.rejected_before_scenario = 0
        self.received = 0
        self.published = 0
        self.not_published: Counter[str] = Counter()
        # latency from pose receipt to publication over the last WINDOW estimates (the
        # session keeps the filter's own statistics)
        self.latencies: deque[float] = deque(maxlen=WINDOW)
        self._pending: tuple[PoseReading, float] | None = None
        self._rate_window: deque[float] = deque()
        self._last_marker_ns: int | None = None
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

    def callbacks(self) -> dict[str, Callable[[Any], None]]:
        """``{input topic: method}`` in :data:`INPUT_TOPICS` order."""
        return {topic: getattr(self, method) for topic, (_t, method) in INPUT_TOPICS.items()}

    def _check_params(self) -> None:
        p = self.params
        checks = (
            ("particles", int(p["particles"]) >= 1 or int(p["particles"]) == -1, ">= 1 or -1"),
            ("marker_period", float(p["marker_period"]) >= 0.0, ">= 0"),
            ("catch_up_steps", int(p["catch_up_steps"]) >= 1, ">= 1"),
            ("diagnostics_period", float(p["diagnostics_period"]) > 0.0, "> 0"),
            ("max_gap", float(p["max_gap"]) > 0.0, "> 0"),
            ("reset_after", float(p["reset_after"]) >= 0.0, ">= 0"),
            ("gating_threshold", float(p["gating_threshold"]) >= 0.0, ">= 0"),
        )
        for name, good, valid in checks:
            if not good:
                msg = f"parameter {name} = {p[name]!r} is invalid; expected {valid}"
                raise ParameterError(msg)

    # -- configuration -----------------------------------------------------------------------
    def configure(self, scenario: Scenario) -> None:
        """(Re)build the session for a scenario."""
        try:
            config = build_config(scenario.kind, self.params)
        except DbcSlamError as err:
            msg = f"bad filter parameters for scenario '{scenario.kind}': {err}"
            raise ParameterError(msg) from err
        self.scenario = scenario
        self.session = FilterSession(
            scenario,
            config,
            seed=int(self.params["seed"]),
            extensions=self.extensions,
            reset_after_s=float(self.params["reset_after"]),
            max_gap_s=float(self.params["max_gap"]),
            gating_threshold=float(self.params["gating_threshold"]),
            catch_up_steps=int(self.params["catch_up_steps"]),
        )
        self._pending = None
        self.log.info(
            f"configured for scenario '{scenario.kind}': contacts {list(scenario.contacts)}, "
            f"friction pairs {list(scenario.friction.pairs)}, {config.particles} particles"
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

    def on_wrench(self, msg: Any) -> None:
        if self.session is None:
            return
        try:
            self.session.add_wrench(wrench_from_msg(msg))
        except InputRejected as err:
            self._reject(err.reason, f"rejected /object/wrench: {err}")

    def on_pusher_wrench(self, msg: Any) -> None:
        """Pusher F/T reading: a force observation (session rules), when enabled."""
        if self.session is None or not bool(self.params["use_pusher_wrench"]):
            return
        try:
            reading = wrench_from_msg(msg)
        except InputRejected as err:
            self._reject(err.reason, f"rejected /pusher/wrench: {err}")
            return
        try:
            self.session.add_pusher_wrench(reading)
        except InputRejected as err:  # counted by the session
            self.log.warning(f"rejected /pusher/wrench: {err}", throttle_duration_sec=5.0)

    def on_joints(self, msg: Any) -> None:
        if self.session is None or self.scenario is None:
            return
        try:
            self.session.add_joints(joints_from_msg(msg, self.scenario.joints))
        except InputRejected as err:
            self._reject(err.reason, f"rejected /joint_states: {err}")

    def on_pose(self, msg: Any) -> None:
        """Validate and queue a pose (depth one: a newer pose drops an unprocessed one)."""
        received = time.monotonic()
        self.received += 1
        self._rate_window.append(received)
        if self.session is None or self.scenario is None:
            self.rejected_before_scenario += 1
            self.log.warning("no /scenario yet: dropping pose", throttle_duration_sec=5.0)
            return
        try:
            reading = pose_from_msg(msg)
        except InputRejected as err:
            self._reject(err.reason, f"rejected /object/pose: {err}")
            return
        stamps = [self.session.last_pose_ns]
        if self._pending is not None:
            stamps.append(self.session.correct(self._pending[0]).stamp_ns)
        newest = max((s for s in stamps if s is not None), default=None)
        try:  # repeated, backwards or jumping stamps never displace a good pose
            self.session.screen_pose(reading, newest)
        except InputRejected as err:
            self.log.warning(f"rejected /object/pose: {err}", throttle_duration_sec=2.0)
            return
        if self._pending is not None:
            self.session.note_backlog_drop()
        self._pending = (reading, received)

    def process_pending(self) -> None:
        """Run the filter on the queued pose (timer callback, after the inputs were taken):
        the session decides (`FilterSession.process_pose`), the node logs and publishes."""
        if self._pending is None or self.session is None:
            return
        reading, received = self._pending
        self._pending = None
        outcome = self.session.process_pose(reading)
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
        try:  # the session screened the estimate; a failure here is a conversion bug
            msgs = estimate_messages(res.estimate, self.scenario, res.stamp_ns, self.frame)
        except ValueError as err:
            self.not_published["conversion"] += 1
            self.log.error(f"not publishing: {err}", throttle_duration_sec=5.0)
            return
        for topic, m in msgs.items():  # pose first (dict order)
            self._publish_msg(topic, m)
            if topic == POSE:
                self.latencies.append(time.monotonic() - received)
        if int(self.params["marker_particles"]) > 0 and self._marker_due(res.stamp_ns):
            try:
                self._publish_msg(MARKERS, self._markers(res))
            except (ValueError, DbcSlamError) as err:
                self.not_published["markers"] += 1
                self.log.warning(f"markers not published: {err}", throttle_duration_sec=5.0)
        if res.step_time_s > SLOW_STEP_S:
            self.log.warning(
                f"slow filter step: {res.step_time_s:.3f} s for {res.model_steps} model "
                f"step(s) at stamp {res.stamp_ns * 1e-9:.3f} s",
                throttle_duration_sec=5.0,
            )
        self.published += 1

    def _marker_due(self, stamp_ns: int) -> bool:
        """At most one marker message per ``marker_period`` of stamp time (bag time in
        replay), so that replays are deterministic; a jump back in time restarts the clock."""
        period_ns = int(float(self.params["marker_period"]) * 1e9)
        last = self._last_marker_ns
        if last is not None and 0 <= stamp_ns - last < period_ns:
            return False
        self._last_marker_ns = stamp_ns
        return True

    def _markers(self, res: StampedEstimate) -> Any:
        assert self.scenario is not None and self.session is not None
        header = rt.message_class("std_msgs/msg/Header")(
            stamp=ns_to_stamp(res.stamp_ns), frame_id=self.frame
        )
        return markers_message(
            res.estimate,
            self.scenario,
            header,
            n_particles=int(self.params["marker_particles"]),
            joints=self.session.last_joints(),
        )

    def diagnostics_values(self) -> dict[str, str]:
        """Key/values published in /diagnostics (also used by tests and `dbcslam demo`).

        Times in ms; rates in Hz over the last diagnostics period; counters since start.
        ``rejected_<reason>``: inputs dropped per reason (``nan``, ``zero_quaternion``,
        ``stamp_order``, ``unknown_joint``, ``missing_joint``, ``malformed``, ``no_joints``,
        ``outlier``, ``backlog``, ``diverged``, ``filter_error``, ``nan_estimate``,
        ``bad_scenario``, ``no_pusher``). ``force_steps``: model steps that used a pusher
        force reading.
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
            values["particles"] = str(self.session.config.particles)
            values["rejected_total"] = str(sum(self.session.rejected.values()))
            for reason, count in sorted(self.session.rejected.items()):
                values[f"rejected_{reason}"] = str(count)
            values["resets"] = str(self.session.resets)
            values["filter_steps"] = str(self.session.steps)
            values["skipped_steps"] = str(self.session.skipped_steps)
            values["gap_steps"] = str(self.session.gap_steps)
            values["force_steps"] = str(self.session.force_steps)
        if self.last_estimate is not None:
            est = self.last_estimate.estimate
            values["ess"] = f"{est.ess:.1f}"
            values["live_hypotheses"] = f"{est.live_hypotheses:.2f}"
        if self.session is not None and self.session.step_times:
            times = np.asarray(self.session.step_times) * 1e3
            steps = np.asarray(self.session.model_steps, dtype=np.float64)
            values["step_time_ms_mean"] = f"{times.mean():.3f}"
            values["step_time_ms_p95"] = f"{np.percentile(times, 95):.3f}"
            values["step_time_ms_max"] = f"{times.max():.3f}"
            per_step = times / steps
            values["model_step_time_ms_mean"] = f"{per_step.mean():.3f}"
            values["model_step_time_ms_p95"] = f"{np.percentile(per_step, 95):.3f}"
        if self.latencies:
            lat = np.asarray(self.latencies) * 1e3
            values["latency_ms_mean"] = f"{lat.mean():.3f}"
            values["latency_ms_p95"] = f"{np.percentile(lat, 95):.3f}"
            values["latency_ms_max"] = f"{lat.max():.3f}"
        return values

    def publish_diagnostics(self) -> None:
        cls = rt.message_class
        values = self.diagnostics_values()
        level = 0
        if self.session is None:
            level, text = 1, "waiting for /scenario"
        elif values.get("rejected_total", "0") != "0":
            level, text = 1, f"running; {values['rejected_total']} input(s) rejected"
        else:
            text = "running"
        stamp_ns = self.last_estimate.stamp_ns if self.last_estimate else 0
        status = cls("diagnostic_msgs/msg/DiagnosticStatus")(
            level=bytes([level]),
            name="dbcslam_filter",
            message=text,
            hardware_id="dbcslam",
            values=[
                cls("diagnostic_msgs/msg/KeyValue")(key=k, value=v) for k, v in values.items()
            ],
        )
        header = cls("std_msgs/msg/Header")(stamp=ns_to_stamp(stamp_ns), frame_id="")
        self._publish_msg(
            DIAGNOSTICS,
            cls("diagnostic_msgs/msg/DiagnosticArray")(header=header, status=[status]),
        )


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
