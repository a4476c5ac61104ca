"""The ``dds`` backend: rclpy-shaped nodes directly on Cyclone DDS (PyPI ``cyclonedds``).

Wire conventions are those of rmw_cyclonedds_cpp, so a ROS 2 Jazzy machine on the same domain
sees the same topics: DDS topic ``rt/<topic>`` (``/object/pose`` -> ``rt/object/pose``), type
``pkg::msg::dds_::Type_``, plain CDR little endian (XCDR1, data representation QoS XCDR1 only),
``typehash=RIHS01_...;`` in the endpoint user data. One DDS participant per process (as in
rmw_cyclonedds), configured by :mod:`dbcslam_ros.runtime.dds_config` (loopback only by default).

Executor model: single-threaded. ``spin_once`` waits (at most 100 ms per wait so that SIGINT/
SIGTERM handlers run promptly) until data arrives, a timer is due or shutdown is requested,
then runs every ready subscription callback and every due timer.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from dbcslam_ros.errors import MessageTypeError, ParameterError, RuntimeBackendError, UsageError
from dbcslam_ros.runtime import dds_config, dds_messages
from dbcslam_ros.runtime.qos import QoSProfile
from dbcslam_ros.runtime.ros_args import RosArgs, params_for_node, parse_ros_args
from dbcslam_ros.runtime.typestore import get_typestore, normalize_type_name, ros_type_from_dds

__all__ = [
    "Clock",
    "Duration",
    "EndpointInfo",
    "ExternalShutdownException",
    "Logger",
    "Node",
    "Parameter",
    "ParameterDescriptor",
    "Publisher",
    "Subscription",
    "Time",
    "Timer",
    "get_logger",
    "init",
    "ok",
    "shutdown",
    "spin",
    "spin_once",
    "try_shutdown",
]

_MAX_WAIT_NS = 100_000_000  # cap of one DDS wait: keeps signal handling responsive
_TAKE_BATCH = 256
_ACK_TIMEOUT_NS = 300_000_000
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
UNKNOWN_NS = "_NODE_NAMESPACE_UNKNOWN_"


class ExternalShutdownException(Exception):
    """Raised by spin/spin_once when the context was shut down (SIGINT, SIGTERM, shutdown())."""


# --------------------------------------------------------------------------------- context


class _Context:
    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.initialized = False
        self.shutdown_requested = False
        self.args = RosArgs()
        self.domain: Any = None
        self.participant: Any = None
        self.nodes: list[Node] = []
        self.topics: dict[tuple[str, str], Any] = {}
        self.prev_handlers: dict[int, Any] = {}

    def get_participant(self) -> Any:
        with self.lock:
            if self.participant is None:
                from cyclonedds.domain import Domain, DomainParticipant

                dom = dds_config.domain_id_from_env()
                xml = dds_config.config_from_env().to_xml()
                try:
                    self.domain = Domain(dom, xml) if xml is not None else None
                    self.participant = DomainParticipant(dom)
                except Exception as err:
                    msg = f"cannot create a DDS participant on domain {dom}: {err}"
                    raise RuntimeBackendError(msg) from err
            return self.participant

    def topic(self, dds_name: str, type_name: str) -> Any:
        from cyclonedds.topic import Topic

        key = (dds_name, type_name)
        with self.lock:
            top = self.topics.get(key)
            if top is None:
                cls = dds_messages.message_class(type_name)
                try:
                    top = Topic(self.get_participant(), dds_name, cls)
                except Exception as err:
                    msg = f"cannot create DDS topic {dds_name!r} of type {type_name}: {err}"
                    raise RuntimeBackendError(msg) from err
                self.topics[key] = top
            return top

    def request_shutdown(self) -> None:
        self.shutdown_requested = True
        for node in list(self.nodes):
            node._wake()


_CTX = _Context()


def _on_signal(signum: int, _frame: Any) -> None:
    # First signal: orderly shutdown (spin raises ExternalShutdownException, finally runs).
    # A second SIGINT falls back to KeyboardInterrupt.
    _CTX.request_shutdown()
    if signum == signal.SIGINT:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def init(args: Sequence[str] | None = None) -> None:
    """Initialise the runtime: parse ``--ros-args`` of ``args`` (default ``sys.argv``) and
    install SIGINT/SIGTERM handlers (main thread only).

    Raises:
        UsageError: malformed ROS arguments.
        RuntimeBackendError: already initialised and not shut down.
    """
    with _CTX.lock:
        if _CTX.initialized and not _CTX.shutdown_requested:
            msg = "runtime.init() called twice without shutdown"
            raise RuntimeBackendError(msg)
        if _CTX.initialized:
            _teardown()
        _CTX.args = parse_ros_args(list(sys.argv if args is None else args))
        _CTX.shutdown_requested = False
        _CTX.initialized = True
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                _CTX.prev_handlers[sig] = signal.signal(sig, _on_signal)


def ok() -> bool:
    """True while initialised and not shut down."""
    return _CTX.initialized and not _CTX.shutdown_requested


def _teardown() -> None:
    for node in list(_CTX.nodes):
        node.destroy_node()
    _CTX.topics.clear()
    if _CTX.participant is not None:
        _delete(_CTX.participant)
        _CTX.participant = None
    if _CTX.domain is not None:
        _delete(_CTX.domain)
        _CTX.domain = None


def shutdown() -> None:
    """Shut the runtime down: destroy remaining nodes (flushing reliable publishers) and the
    DDS participant, restore signal handlers."""
    with _CTX.lock:
        _CTX.request_shutdown()
        _teardown()
        _CTX.initialized = False
        if threading.current_thread() is threading.main_thread():
            for sig, handler in _CTX.prev_handlers.items():
                with contextlib.suppress(TypeError, ValueError):
                    signal.signal(sig, handler)
        _CTX.prev_handlers.clear()


def try_shutdown() -> None:
    """Like :func:`shutdown`, but a no-op when already shut down."""
    if _CTX.initialized:
        shutdown()


def _delete(entity: Any) -> None:
    with contextlib.suppress(Exception):
        entity.__del__()


# --------------------------------------------------------------------------------- time


class Duration:
    """A time span in integer nanoseconds (like ``rclpy.duration.Duration``)."""

    def __init__(self, *, seconds: float = 0.0, nanoseconds: int = 0) -> None:
        self.nanoseconds = round(seconds * 1e9) + int(nanoseconds)

    def __repr__(self) -> str:
        return f"Duration(nanoseconds={self.nanoseconds})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Duration) and other.nanoseconds == self.nanoseconds

    def __lt__(self, other: Duration) -> bool:
        return self.nanoseconds < other.nanoseconds

    def __hash__(self) -> int:
        return hash(self.nanoseconds)


class Time:
    """A point in time in integer nanoseconds since the epoch (like ``rclpy.time.Time``)."""

    def __init__(self, *, seconds: float = 0.0, nanoseconds: int = 0) -> None:
        self.nanoseconds = round(seconds * 1e9) + int(nanoseconds)

    def seconds_nanoseconds(self) -> tuple[int, int]:
        """(seconds, nanoseconds) with 0 <= nanoseconds < 1e9."""
        return divmod(self.nanoseconds, 1_000_000_000)

    def to_msg(self) -> Any:
        """builtin_interfaces/msg/Time message."""
        sec, nsec = self.seconds_nanoseconds()
        return dds_messages.message_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nsec)

    @classmethod
    def from_msg(cls, msg: Any) -> Time:
        """From a builtin_interfaces/msg/Time message."""
        return cls(nanoseconds=int(msg.sec) * 1_000_000_000 + int(msg.nanosec))

    def __sub__(self, other: Any) -> Any:
        if isinstance(other, Time):
            return Duration(nanoseconds=self.nanoseconds - other.nanoseconds)
        return Time(nanoseconds=self.nanoseconds - other.nanoseconds)

    def __add__(self, other: Duration) -> Time:
        return Time(nanoseconds=self.nanoseconds + other.nanoseconds)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Time) and other.nanoseconds == self.nanoseconds

    def __lt__(self, other: Time) -> bool:
        return self.nanoseconds < other.nanoseconds

    def __le__(self, other: Time) -> bool:
        return self.nanoseconds <= other.nanoseconds

    def __hash__(self) -> int:
        return hash(self.nanoseconds)

    def __repr__(self) -> str:
        return f"Time(nanoseconds={self.nanoseconds})"


class Clock:
    """ROS time of a node: wall clock, or the last ``/clock`` value when ``use_sim_time``."""

    def __init__(self) -> None:
        self.sim_time_active = False
        self.sim_ns = 0

    def now(self) -> Time:
        """Current ROS time."""
        return Time(nanoseconds=self.now_ns())

    def now_ns(self) -> int:
        """Current ROS time in nanoseconds."""
        return self.sim_ns if self.sim_time_active else time.time_ns()


# --------------------------------------------------------------------------------- logging

_LEVELS = {"debug": 10, "info": 20, "warn": 30, "warning": 30, "error": 40, "fatal": 50}
_LEVEL_TAG = {10: "DEBUG", 20: "INFO", 30: "WARN", 40: "ERROR", 50: "FATAL"}


class Logger:
    """ROS-like logger writing ``[LEVEL] [epoch.ns] [name]: message`` to stderr."""

    def __init__(self, name: str, level: int = 20) -> None:
        self.name = name
        self.level = level
        self._last: dict[tuple[str, int], int] = {}
        self._seen: set[tuple[str, int]] = set()

    def set_level(self, level: str | int) -> None:
        """Set the threshold (``debug``/``info``/``warn``/``error``/``fatal`` or 10..50)."""
        self.level = _LEVELS[level.lower()] if isinstance(level, str) else int(level)

    def get_child(self, name: str) -> Logger:
        """A logger named ``<self>.<name>`` with the same level."""
        return Logger(f"{self.name}.{name}", self.level)

    def _log(
        self,
        level: int,
        message: Any,
        throttle_duration_sec: float | None = None,
        once: bool = False,
        skip_first: bool = False,
        **_kwargs: Any,
    ) -> bool:
        if level < self.level:
            return False
        caller = inspect.currentframe()
        site = ("", 0)
        if caller is not None and caller.f_back is not None and caller.f_back.f_back is not None:
            fr = caller.f_back.f_back
            site = (fr.f_code.co_filename, fr.f_lineno)
        if once or skip_first:
            first = site not in self._seen
            self._seen.add(site)
            if (once and not first) or (skip_first and first):
                return False
        now = time.time_ns()
        if throttle_duration_sec:
            last = self._last.get(site)
            if last is not None and now - last < throttle_duration_sec * 1e9:
                return False
            self._last[site] = now
        sec, nsec = divmod(now, 1_000_000_000)
        sys.stderr.write(f"[{_LEVEL_TAG[level]}] [{sec}.{nsec:09d}] [{self.name}]: {message}\n")
        sys.stderr.flush()
        return True

    def debug(self, message: Any, **kw: Any) -> bool:
        """Log at DEBUG level (kwargs: throttle_duration_sec, once, skip_first)."""
        return self._log(10, message, **kw)

    def info(self, message: Any, **kw: Any) -> bool:
        """Log at INFO level (kwargs: throttle_duration_sec, once, skip_first)."""
        return self._log(20, message, **kw)

    def warning(self, message: Any, **kw: Any) -> bool:
        """Log at WARN level (kwargs: throttle_duration_sec, once, skip_first)."""
        return self._log(30, message, **kw)

    warn = warning

    def error(self, message: Any, **kw: Any) -> bool:
        """Log at ERROR level (kwargs: throttle_duration_sec, once, skip_first)."""
        return self._log(40, message, **kw)

    def fatal(self, message: Any, **kw: Any) -> bool:
        """Log at FATAL level (kwargs: throttle_duration_sec, once, skip_first)."""
        return self._log(50, message, **kw)


def get_logger(name: str) -> Logger:
    """A logger not bound to a node (like ``rclpy.logging.get_logger``)."""
    lvl = _CTX.args.log_level
    return Logger(name, _LEVELS.get(lvl, 20) if lvl else 20)


# --------------------------------------------------------------------------------- parameters


class ParameterType(IntEnum):
    """Parameter types, numbered as rcl_interfaces/msg/ParameterType."""

    NOT_SET = 0
    BOOL = 1
    INTEGER = 2
    DOUBLE = 3
    STRING = 4
    BYTE_ARRAY = 5
    BOOL_ARRAY = 6
    INTEGER_ARRAY = 7
    DOUBLE_ARRAY = 8
    STRING_ARRAY = 9


def _type_of(value: Any) -> ParameterType:  # noqa: PLR0911
    if value is None:
        return ParameterType.NOT_SET
    if isinstance(value, bool):
        return ParameterType.BOOL
    if isinstance(value, int):
        return ParameterType.INTEGER
    if isinstance(value, float):
        return ParameterType.DOUBLE
    if isinstance(value, str):
        return ParameterType.STRING
    if isinstance(value, (bytes, bytearray)):
        return ParameterType.BYTE_ARRAY
    if isinstance(value, (list, tuple)):
        items = list(value)
        if items and all(isinstance(v, bool) for v in items):
            return ParameterType.BOOL_ARRAY
        if items and all(isinstance(v, int) and not isinstance(v, bool) for v in items):
            return ParameterType.INTEGER_ARRAY
        if items and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
            return ParameterType.DOUBLE_ARRAY
        if all(isinstance(v, str) for v in items):
            return ParameterType.STRING_ARRAY
    msg = f"unsupported parameter value {value!r} (bool, int, float, str or lists of them)"
    raise ParameterError(msg)


class Parameter:
    """A named, typed parameter value (like ``rclpy.parameter.Parameter``)."""

    Type = ParameterType

    def __init__(self, name: str, type_: ParameterType | None = None, value: Any = None) -> None:
        self.name = name
        self.value = value
        self.type_ = _type_of(value) if type_ is None else ParameterType(type_)

    def __repr__(self) -> str:
        return f"Parameter({self.name!r}, {self.type_.name}, {self.value!r})"


@dataclass
class ParameterDescriptor:
    """Parameter metadata (fields as rcl_interfaces/msg/ParameterDescriptor)."""

    name: str = ""
    type: int = 0
    description: str = ""
    additional_constraints: str = ""
    read_only: bool = False
    dynamic_typing: bool = False


@dataclass
class SetParametersResult:
    """Outcome of setting one parameter."""

    successful: bool
    reason: str = ""


def _coerce(name: str, declared: ParameterType, value: Any) -> Any:
    """Check ``value`` against the declared type; ints become floats for DOUBLE(_ARRAY)."""
    got = _type_of(value)
    if declared in (ParameterType.NOT_SET, got):
        return list(value) if isinstance(value, tuple) else value
    if declared == ParameterType.DOUBLE and got == ParameterType.INTEGER:
        return float(value)
    if declared == ParameterType.DOUBLE_ARRAY and got == ParameterType.INTEGER_ARRAY:
        return [float(v) for v in value]
    if isinstance(value, (list, tuple)) and not value and declared.name.endswith("ARRAY"):
        return []
    msg = f"parameter {name!r}: value {value!r} has type {got.name}, expected {declared.name}"
    raise ParameterError(msg)


# --------------------------------------------------------------------------------- endpoints


def _to_cyclone_qos(qos: QoSProfile, user_data: bytes) -> Any:
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration

    rel = (
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100))
        if qos.reliability == "reliable"
        else Policy.Reliability.BestEffort
    )
    dur = (
        Policy.Durability.TransientLocal
        if qos.durability == "transient_local"
        else Policy.Durability.Volatile
    )
    hist = (
        Policy.History.KeepAll
        if qos.history == "keep_all"
        else Policy.History.KeepLast(depth=int(qos.depth))
    )
    return Qos(
        rel,
        dur,
        hist,
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Userdata(data=user_data),
    )


def qos_from_cyclone(cqos: Any) -> QoSProfile:
    """Convert a discovered Cyclone ``Qos`` to a :class:`QoSProfile` (DDS defaults if absent:
    writers default to reliable/volatile/keep_last 1)."""
    reliability, durability, history, depth = "reliable", "volatile", "keep_last", 1
    for pol in cqos:
        scope = getattr(pol, "__scope__", "")
        text = repr(pol)
        if scope == "Reliability":
            reliability = "best_effort" if "BestEffort" in text else "reliable"
        elif scope == "Durability":
            durability = "volatile" if "Volatile" in text else "transient_local"
        elif scope == "History":
            if "KeepAll" in text:
                history, depth = "keep_all", 0
            else:
                history, depth = "keep_last", int(getattr(pol, "depth", 1))
    return QoSProfile(
        reliability, durability, history, max(depth, 1) if history == "keep_last" else 0
    )


def _type_hash(type_name: str) -> str:
    try:
        return str(get_typestore().hash_rihs01(type_name))
    except Exception:
        return ""


def _user_data(type_name: str, node: Node) -> bytes:
    th = _type_hash(type_name)
    text = f"typehash={th};" if th else ""
    text += f"dbcslam_node={node.get_namespace()}|{node.get_name()};"
    return text.encode()


def _strip_padding(data: bytes, type_name: str) -> bytes:
    """rosbag2-layout bytes of a DDS sample: trailing alignment padding removed and the
    header options (where Cyclone C records the padding count) zeroed."""
    try:
        end = dds_messages.cdr_length(data, type_name)
    except MessageTypeError:
        return bytes(data)  # not ours to judge: deliver unchanged
    return bytes(data[:2]) + b"\0\0" + bytes(data[4:end])


def _pad4(data: bytes) -> bytes:
    rem = len(data) % 4
    return data + b"\0" * (4 - rem) if rem else data


class Publisher:
    """A DDS writer for one ROS topic (like ``rclpy.publisher.Publisher``)."""

    def __init__(self, node: Node, type_name: str, topic_name: str, qos: QoSProfile) -> None:
        from cyclonedds.pub import DataWriter

        self.topic_name = topic_name
        self.type_name = type_name
        self.qos_profile = qos
        self.msg_type = dds_messages.message_class(type_name)
        top = _CTX.topic("rt" + topic_name, type_name)
        self._writer: Any = DataWriter(
            _CTX.get_participant(), top, _to_cyclone_qos(qos, _user_data(type_name, node))
        )

    def publish(self, msg: Any) -> None:
        """Publish a message object of this topic's type, or its CDR bytes (raw).

        Raises:
            MessageTypeError: wrong message type or unserializable field values.
            RuntimeBackendError: the write failed.
        """
        from cyclonedds._clayer import ddspy_write

        if isinstance(msg, (bytes, bytearray, memoryview)):
            data = bytes(msg)
            if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
                text = f"raw publish on {self.topic_name}: not plain CDR (header {data[:4].hex()})"
                raise MessageTypeError(text)
        else:
            if type(msg) is not self.msg_type:
                text = (
                    f"publish on {self.topic_name}: got {type(msg).__name__} object, "
                    f"expected {self.type_name}"
                )
                raise MessageTypeError(text)
            data = dds_messages.encode(msg)
        ret = ddspy_write(self._writer._ref, _pad4(data))
        if ret < 0:
            text = f"DDS write on {self.topic_name} failed with code {ret}"
            raise RuntimeBackendError(text)

    def get_subscription_count(self) -> int:
        """Number of matched subscriptions."""
        return len(self._writer.get_matched_subscriptions())

    def wait_for_acks(self, timeout_sec: float) -> bool:
        """Block until reliable readers acknowledged all samples; False on timeout."""
        try:
            return bool(self._writer.wait_for_acks(int(timeout_sec * 1e9)))
        except Exception:
            return False

    def wait_for_all_acked(self, timeout: Duration | None = None) -> bool:
        """rclpy spelling of :meth:`wait_for_acks` (``timeout`` None or negative: 1 day)."""
        ns = timeout.nanoseconds if timeout is not None else -1
        return self.wait_for_acks(ns / 1e9 if ns >= 0 else 86400.0)

    def destroy(self) -> None:
        """Flush (reliable: wait up to 0.3 s for acks) and delete the writer."""
        if self._writer is None:
            return
        if self.qos_profile.reliability == "reliable" and self.get_subscription_count():
            self.wait_for_acks(_ACK_TIMEOUT_NS / 1e9)
        _delete(self._writer)
        self._writer = None


class Subscription:
    """A DDS reader for one ROS topic (like ``rclpy.subscription.Subscription``).

    With ``raw=True`` the callback gets the CDR bytes (header + payload, the DDS alignment
    padding stripped): exactly ``typestore.serialize_cdr`` of the message.
    """

    def __init__(
        self,
        node: Node,
        type_name: str,
        topic_name: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        *,
        raw: bool,
    ) -> None:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
        from cyclonedds.sub import DataReader

        self.topic_name = topic_name
        self.type_name = type_name
        self.qos_profile = qos
        self.callback = callback
        self.raw = raw
        self.msg_type = dds_messages.message_class(type_name)
        top = _CTX.topic("rt" + topic_name, type_name)
        self._reader: Any = DataReader(
            _CTX.get_participant(), top, _to_cyclone_qos(qos, _user_data(type_name, node))
        )
        self._mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self._cond = ReadCondition(
            self._reader, SampleState.NotRead | ViewState.Any | InstanceState.Any
        )

    def get_publisher_count(self) -> int:
        """Number of matched publishers."""
        return len(self._reader.get_matched_publications())

    def _take(self) -> list[Any]:
        from cyclonedds._clayer import ddspy_take

        if self._reader is None:
            return []
        ret = ddspy_take(self._reader._ref, self._mask, _TAKE_BATCH)
        if isinstance(ret, int):
            text = f"DDS take on {self.topic_name} failed with code {ret}"
            raise RuntimeBackendError(text)
        out: list[Any] = []
        for data, info in ret:
            if not info.valid_data:
                continue
            if self.raw:
                out.append(_strip_padding(data, self.type_name))
            else:
                out.append(dds_messages.decode(data, self.msg_type))
        return out

    def destroy(self) -> None:
        """Delete the reader."""
        if self._reader is None:
            return
        _delete(self._cond)
        _delete(self._reader)
        self._reader = None


class Timer:
    """Periodic callback on the node's clock (like ``rclpy.timer.Timer``)."""

    def __init__(self, period_sec: float, callback: Callable[[], Any], clock: Clock) -> None:
        if not period_sec > 0 or not math.isfinite(period_sec):
            msg = f"timer period {period_sec!r} s: expected a finite value > 0"
            raise UsageError(msg)
        self.timer_period_ns = int(period_sec * 1e9)
        self.callback = callback
        self._clock = clock
        self._canceled = False
        self._next = clock.now_ns() + self.timer_period_ns

    def cancel(self) -> None:
        """Stop firing."""
        self._canceled = True

    def is_canceled(self) -> bool:
        """Whether :meth:`cancel` was called."""
        return self._canceled

    def reset(self) -> None:
        """Restart the period from now (and un-cancel)."""
        self._canceled = False
        self._next = self._clock.now_ns() + self.timer_period_ns

    def time_until_next_call(self) -> int | None:
        """Nanoseconds until the next call (None when canceled)."""
        if self._canceled:
            return None
        return max(0, self._next - self._clock.now_ns())

    def _due(self) -> bool:
        if self._canceled:
            return False
        now = self._clock.now_ns()
        if now < self._next - self.timer_period_ns:  # clock jumped back (e.g. bag loop)
            self._next = now + self.timer_period_ns
            return False
        if now < self._next:
            return False
        # skip missed periods rather than bursting (as rcl does)
        missed = (now - self._next) // self.timer_period_ns
        self._next += (missed + 1) * self.timer_period_ns
        return True

    def destroy(self) -> None:
        """Cancel the timer."""
        self._canceled = True


@dataclass
class EndpointInfo:
    """A discovered publisher or subscription (like ``rclpy.topic_endpoint_info``)."""

    node_name: str
    node_namespace: str
    topic_type: str
    endpoint_type: str
    qos_profile: QoSProfile
    endpoint_gid: bytes = b""
    topic_name: str = ""
    user_data: dict[str, str] = field(default_factory=dict)


# --------------------------------------------------------------------------------- node


def _check_name(kind: str, name: str, allow_slash: bool) -> None:
    allowed = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")
    if allow_slash:
        allowed |= set("/~")
    if not name or any(c not in allowed for c in name) or name[0].isdigit():
        msg = f"invalid {kind} {name!r}: use letters, digits and '_' (and '/' for topics)"
        raise UsageError(msg)


class Node:
    """A ROS node on the DDS backend (API subset of ``rclpy.node.Node``)."""

    def __init__(
        self,
        node_name: str,
        *,
        namespace: str | None = None,
        cli_args: Sequence[str] | None = None,
        parameter_overrides: Iterable[Parameter] | None = None,
        automatically_declare_parameters_from_overrides: bool = False,
        **_ignored: Any,
    ) -> None:
        if not _CTX.initialized:
            msg = "runtime.init() must be called before creating a Node"
            raise RuntimeBackendError(msg)
        args = _CTX.args
        # node-local arguments (rclpy's cli_args) win over the process-wide ones
        local = parse_ros_args(["node", *cli_args]) if cli_args else RosArgs()
        name = local.node_name or args.node_name or node_name
        ns_arg = local.namespace if local.namespace is not None else args.namespace
        ns = ns_arg if ns_arg is not None else (namespace or "")
        ns = "/" + ns.strip("/") if ns.strip("/") else "/"
        _check_name("node name", name, allow_slash=False)
        self._name = name
        self._ns = ns
        self._remaps = {**args.remaps, **local.remaps}
        lvl = local.log_level or args.log_level
        self._logger = Logger(
            self.get_fully_qualified_name().lstrip("/").replace("/", "."),
            _LEVELS.get(lvl, 20) if lvl else 20,
        )
        self._clock = Clock()
        self._overrides = params_for_node(args, name, ns)
        self._overrides.update(params_for_node(local, name, ns))
        for p in parameter_overrides or ():
            self._overrides[p.name] = p.value
        self._params: dict[str, Parameter] = {}
        self._descriptors: dict[str, ParameterDescriptor] = {}
        self.publishers: list[Publisher] = []
        self.subscriptions: list[Subscription] = []
        self.timers: list[Timer] = []
        self._destroyed = False

        from cyclonedds.builtin import (
            BuiltinDataReader,
            BuiltinTopicDcpsPublication,
            BuiltinTopicDcpsSubscription,
        )
        from cyclonedds.core import GuardCondition, WaitSet

        part = _CTX.get_participant()
        self._guard = GuardCondition(part)
        self._waitset = WaitSet(part)
        self._waitset.attach(self._guard)
        self._pub_reader = BuiltinDataReader(part, BuiltinTopicDcpsPublication)
        self._sub_reader = BuiltinDataReader(part, BuiltinTopicDcpsSubscription)
        _CTX.nodes.append(self)

        sim = self.declare_parameter("use_sim_time", False).value
        if automatically_declare_parameters_from_overrides:
            for key, value in self._overrides.items():
                if key not in self._params:
                    self.declare_parameter(key, value)
        if sim:
            self._clock.sim_time_active = True
            self.create_subscription(
                "rosgraph_msgs/msg/Clock",
                "/clock",
                self._on_clock,
                QoSProfile("best_effort", "volatile", "keep_last", 1),
            )

    # names -----------------------------------------------------------------------------
    def get_name(self) -> str:
        """Node name."""
        return self._name

    def get_namespace(self) -> str:
        """Node namespace (``/`` for none)."""
        return self._ns

    def get_fully_qualified_name(self) -> str:
        """``/ns/name``."""
        return (self._ns.rstrip("/") + "/" + self._name) if self._ns != "/" else f"/{self._name}"

    def resolve_topic_name(self, topic: str) -> str:
        """Fully qualified topic name after namespace, ``~`` and remapping."""
        full = self._expand(topic)
        for src, dst in self._remaps.items():
            if self._expand(src) == full:
                return self._expand(dst)
        return full

    def _expand(self, topic: str) -> str:
        _check_name("topic name", topic, allow_slash=True)
        if topic.startswith("~"):
            full = self.get_fully_qualified_name() + topic[1:]
        elif topic.startswith("/"):
            full = topic
        else:
            full = self._ns.rstrip("/") + "/" + topic
        if "//" in full or full.endswith("/"):
            msg = f"invalid topic name {topic!r} (resolved {full!r})"
            raise UsageError(msg)
        return full

    # logging / clock ---------------------------------------------------------------------
    def get_logger(self) -> Logger:
        """The node's logger."""
        return self._logger

    def get_clock(self) -> Clock:
        """The node's ROS clock (sim time when ``use_sim_time``)."""
        return self._clock

    def _on_clock(self, msg: Any) -> None:
        self._clock.sim_ns = int(msg.clock.sec) * 1_000_000_000 + int(msg.clock.nanosec)

    # endpoints ---------------------------------------------------------------------------
    @staticmethod
    def _type_name(msg_type: Any) -> str:
        if isinstance(msg_type, str):
            return normalize_type_name(msg_type)
        return dds_messages.type_name_of(msg_type)

    @staticmethod
    def _qos(qos: QoSProfile | int) -> QoSProfile:
        if isinstance(qos, QoSProfile):
            return qos
        if isinstance(qos, int) and not isinstance(qos, bool):
            return QoSProfile(depth=qos)
        msg = f"bad QoS {qos!r}: expected a QoSProfile or a history depth"
        raise UsageError(msg)

    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **_ignored: Any
    ) -> Publisher:
        """Create a publisher; ``msg_type`` is a message class or a type name (raw use)."""
        pub = Publisher(
            self, self._type_name(msg_type), self.resolve_topic_name(topic), self._qos(qos_profile)
        )
        self.publishers.append(pub)
        return pub

    def create_subscription(
        self,
        msg_type: Any,
        topic: str,
        callback: Callable[[Any], None],
        qos_profile: QoSProfile | int,
        *,
        raw: bool = False,
        **_ignored: Any,
    ) -> Subscription:
        """Create a subscription; ``raw=True`` delivers CDR bytes to ``callback``."""
        sub = Subscription(
            self,
            self._type_name(msg_type),
            self.resolve_topic_name(topic),
            callback,
            self._qos(qos_profile),
            raw=raw,
        )
        self._waitset.attach(sub._cond)
        self.subscriptions.append(sub)
        return sub

    def create_timer(
        self, timer_period_sec: float, callback: Callable[[], Any], **_ignored: Any
    ) -> Timer:
        """Call ``callback`` every ``timer_period_sec`` seconds of the node clock."""
        tmr = Timer(float(timer_period_sec), callback, self._clock)
        self.timers.append(tmr)
        self._wake()
        return tmr

    def destroy_publisher(self, pub: Publisher) -> None:
        """Flush and delete a publisher."""
        pub.destroy()
        if pub in self.publishers:
            self.publishers.remove(pub)

    def destroy_subscription(self, sub: Subscription) -> None:
        """Delete a subscription."""
        if sub in self.subscriptions:
            with contextlib.suppress(Exception):
                self._waitset.detach(sub._cond)
            self.subscriptions.remove(sub)
        sub.destroy()

    def destroy_timer(self, tmr: Timer) -> None:
        """Cancel and drop a timer."""
        tmr.destroy()
        if tmr in self.timers:
            self.timers.remove(tmr)

    # parameters --------------------------------------------------------------------------
    def declare_parameter(
        self,
        name: str,
        value: Any = None,
        descriptor: ParameterDescriptor | None = None,
        ignore_override: bool = False,
    ) -> Parameter:
        """Declare a parameter with a default; a ``-p``/params-file override replaces it.

        The declared type is the default's type (ints are accepted for floats).

        Raises:
            ParameterError: declared twice, or the override has another type.
        """
        if name in self._params:
            msg = f"parameter {name!r} of node {self.get_fully_qualified_name()} declared twice"
            raise ParameterError(msg)
        desc = descriptor or ParameterDescriptor()
        declared = _type_of(value)
        if desc.dynamic_typing:
            declared = ParameterType.NOT_SET
        final = value
        if not ignore_override and name in self._overrides:
            final = _coerce(name, declared, self._overrides[name])
        param = Parameter(name, value=final)
        self._params[name] = param
        self._descriptors[name] = desc
        return param

    def declare_parameters(
        self, namespace: str, parameters: Sequence[tuple[Any, ...]]
    ) -> list[Parameter]:
        """Declare several ``(name, value[, descriptor])`` under ``namespace.`` prefix."""
        prefix = f"{namespace}." if namespace else ""
        return [self.declare_parameter(prefix + p[0], *p[1:]) for p in parameters]

    def has_parameter(self, name: str) -> bool:
        """Whether ``name`` is declared."""
        return name in self._params

    def get_parameter(self, name: str) -> Parameter:
        """The declared parameter ``name``.

        Raises:
            ParameterError: not declared.
        """
        try:
            return self._params[name]
        except KeyError as err:
            msg = (
                f"parameter {name!r} is not declared on {self.get_fully_qualified_name()} "
                f"(declared: {sorted(self._params)})"
            )
            raise ParameterError(msg) from err

    def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter:
        """The parameter, or ``alternative_value`` when undeclared."""
        return self._params.get(name, alternative_value or Parameter(name))

    def get_parameters(self, names: Sequence[str]) -> list[Parameter]:
        """Several declared parameters."""
        return [self.get_parameter(n) for n in names]

    def describe_parameter(self, name: str) -> ParameterDescriptor:
        """The descriptor given at declaration."""
        self.get_parameter(name)
        return self._descriptors[name]

    def set_parameters(self, parameters: Sequence[Parameter]) -> list[SetParametersResult]:
        """Set declared parameters (type-checked, read-only refused)."""
        results = []
        for p in parameters:
            if p.name not in self._params:
                results.append(SetParametersResult(False, f"parameter {p.name!r} not declared"))
                continue
            if self._descriptors[p.name].read_only:
                results.append(SetParametersResult(False, f"parameter {p.name!r} is read-only"))
                continue
            cur = self._params[p.name]
            declared = (
                ParameterType.NOT_SET if self._descriptors[p.name].dynamic_typing else cur.type_
            )
            try:
                value = _coerce(p.name, declared, p.value)
            except ParameterError as err:
                results.append(SetParametersResult(False, str(err)))
                continue
            self._params[p.name] = Parameter(p.name, value=value)
            results.append(SetParametersResult(True))
        return results

    # graph -------------------------------------------------------------------------------
    def _endpoints(self, which: str) -> list[Any]:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState

        reader = self._pub_reader if which == "pub" else self._sub_reader
        cond = ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Alive)
        try:
            return list(reader.read(N=100_000, condition=cond))
        finally:
            _delete(cond)

    def get_topic_names_and_types(self, no_demangle: bool = False) -> list[tuple[str, list[str]]]:
        """ROS topics seen on the domain (publishers or subscriptions) with their type names."""
        found: dict[str, set[str]] = {}
        for ep in self._endpoints("pub") + self._endpoints("sub"):
            name = ep.topic_name
            if not name.startswith("rt/"):
                continue
            typ = ros_type_from_dds(ep.type_name) or ep.type_name
            found.setdefault(name[2:], set()).add(typ)
        return sorted((k, sorted(v)) for k, v in found.items())

    def _info(self, topic: str, which: str) -> list[EndpointInfo]:
        full = self.resolve_topic_name(topic)
        out = []
        for ep in self._endpoints(which):
            if ep.topic_name != "rt" + full:
                continue
            ud = _parse_user_data(ep.qos)
            node_ns, _, node = ud.get("dbcslam_node", "").partition("|")
            out.append(
                EndpointInfo(
                    node_name=node or UNKNOWN_NODE,
                    node_namespace=node_ns or UNKNOWN_NS,
                    topic_type=ros_type_from_dds(ep.type_name) or ep.type_name,
                    endpoint_type="PUBLISHER" if which == "pub" else "SUBSCRIPTION",
                    qos_profile=qos_from_cyclone(ep.qos),
                    endpoint_gid=ep.key.bytes,
                    topic_name=full,
                    user_data=ud,
                )
            )
        return out

    def get_publishers_info_by_topic(
        self, topic_name: str, no_mangle: bool = False
    ) -> list[EndpointInfo]:
        """Discovered publishers of ``topic_name`` with their offered QoS."""
        return self._info(topic_name, "pub")

    def get_subscriptions_info_by_topic(
        self, topic_name: str, no_mangle: bool = False
    ) -> list[EndpointInfo]:
        """Discovered subscriptions of ``topic_name`` with their requested QoS."""
        return self._info(topic_name, "sub")

    def count_publishers(self, topic_name: str) -> int:
        """Number of discovered publishers of ``topic_name``."""
        return len(self._info(topic_name, "pub"))

    def count_subscribers(self, topic_name: str) -> int:
        """Number of discovered subscriptions of ``topic_name``."""
        return len(self._info(topic_name, "sub"))

    # execution ---------------------------------------------------------------------------
    def _wake(self) -> None:
        with contextlib.suppress(Exception):
            if not self._destroyed:
                self._guard.set(True)

    def _spin_once(self, timeout_sec: float | None) -> None:
        if _CTX.shutdown_requested:
            raise ExternalShutdownException
        if self._destroyed:
            msg = f"node {self.get_fully_qualified_name()} was destroyed"
            raise RuntimeBackendError(msg)
        deadline = None if timeout_sec is None else time.monotonic() + max(0.0, timeout_sec)
        while True:
            if self._run_ready():
                return
            wait_ns = _MAX_WAIT_NS
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                wait_ns = min(wait_ns, int(left * 1e9))
            for tmr in self.timers:
                nxt = tmr.time_until_next_call()
                if nxt is not None and not self._clock.sim_time_active:
                    wait_ns = min(wait_ns, nxt)
            if wait_ns > 0:
                self._waitset.wait(wait_ns)
            if _CTX.shutdown_requested:
                raise ExternalShutdownException
            self._guard.set(False)

    def _run_ready(self) -> bool:
        """Run ready subscription callbacks and due timers; True if anything ran."""
        ran = False
        for sub in list(self.subscriptions):
            for item in sub._take():
                sub.callback(item)
                ran = True
        for tmr in list(self.timers):
            if tmr._due():
                tmr.callback()
                ran = True
        return ran

    def destroy_node(self) -> None:
        """Flush publishers (reliable: wait for acks, bounded) and delete all entities."""
        if self._destroyed:
            return
        self._destroyed = True
        for pub in list(self.publishers):
            self.destroy_publisher(pub)
        for sub in list(self.subscriptions):
            self.destroy_subscription(sub)
        self.timers.clear()
        for ent in (self._waitset, self._guard, self._pub_reader, self._sub_reader):
            _delete(ent)
        if self in _CTX.nodes:
            _CTX.nodes.remove(self)


def _parse_user_data(cqos: Any) -> dict[str, str]:
    out: dict[str, str] = {}
    for pol in cqos:
        if getattr(pol, "__scope__", "") == "Userdata":
            text = bytes(pol.data).decode("utf-8", "replace")
            for item in text.split(";"):
                key, sep, value = item.partition("=")
                if sep:
                    out[key.strip()] = value
    return out


def spin_once(node: Node, *, timeout_sec: float | None = None) -> None:
    """Wait up to ``timeout_sec`` (None: until something happens) and run ready callbacks.

    Raises:
        ExternalShutdownException: the runtime was shut down (signal or shutdown()).
    """
    node._spin_once(timeout_sec)


def spin(node: Node) -> None:
    """Run the node's callbacks until shutdown.

    Raises:
        ExternalShutdownException: on SIGINT/SIGTERM or shutdown() (always, spin never returns
            normally).
    """
    while True:
        node._spin_once(None)
