"""Helpers shared by the live-DDS subcommands: node lifecycle, stop signals, QoS mapping.

The commands run on rclpy (started through :func:`dbcslam_ros.ros_context.init_ros`, so on
this machine only unless the user chose otherwise) with the helpers of
:mod:`dbcslam_ros.runtime`.
"""

from __future__ import annotations

import argparse
import os
import signal
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import replace
from types import FrameType
from typing import Any

from dbcslam_ros.bag.qos import Qos
from dbcslam_ros.errors import UsageError
from dbcslam_ros.qos import PROFILES, QoSProfile, adapt_to_offers, from_bag_qos

__all__ = [
    "StopSignal",
    "add_qos_arguments",
    "bag_qos_to_runtime",
    "native_qos",
    "node_session",
    "positive_float",
    "qos_from_arguments",
    "subscription_qos_for",
    "unique_node_name",
]


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError as err:
        msg = f"{text!r} is not a number"
        raise argparse.ArgumentTypeError(msg) from err
    if not value > 0 or value == float("inf"):
        msg = f"{text!r} must be a finite number > 0"
        raise argparse.ArgumentTypeError(msg)
    return value


class StopSignal:
    """SIGINT/SIGTERM set an event instead of raising, so a command can finish cleanly.

    Installed over the runtime's handlers (which would make ``spin_once`` raise), so the
    command can still drain pending messages after the signal. A second SIGINT raises
    ``KeyboardInterrupt`` as usual.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signal_name: str | None = None
        self._previous: dict[int, Any] = {}

    def install(self) -> StopSignal:
        """Take over SIGINT and SIGTERM (main thread only; a no-op elsewhere)."""
        if threading.current_thread() is not threading.main_thread():
            return self
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if self.event.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signal_name = signal.Signals(signum).name
        self.event.set()

    def restore(self) -> None:
        """Give the signals back to their previous handlers."""
        for sig, handler in self._previous.items():
            with suppress(TypeError, ValueError):
                signal.signal(sig, handler)
        self._previous.clear()

    @property
    def stopped(self) -> bool:
        """True once a stop was requested."""
        return self.event.is_set()

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds`` (returns early with True on a stop request)."""
        return self.event.wait(max(0.0, seconds))


@contextmanager
def node_session(name: str) -> Iterator[tuple[Any, Any, StopSignal]]:
    """Initialise the runtime, create node ``name``, take over SIGINT/SIGTERM.

    Yields ``(runtime module, node, stop signal)``; on exit the node is destroyed (reliable
    publishers flushed) and the runtime shut down.
    """
    from dbcslam_ros import runtime as rt

    rt.init(["dbcslam"], handle_signals=False)
    stop = StopSignal()
    node = None
    try:
        node = rt.Node(name)
        stop.install()
        try:
            yield rt, node, stop
        except rt.ExternalShutdownException:
            # A signal that arrived before our handlers took over: a normal stop.
            stop.event.set()
    finally:
        try:
            if node is not None:
                node.destroy_node()
        finally:
            rt.try_shutdown()
            stop.restore()


def native_qos(rt: Any, qos: QoSProfile) -> Any:
    """The rclpy ``QoSProfile`` of a neutral profile."""
    return rt.make_qos(qos.reliability, qos.durability, qos.history, qos.depth)


def unique_node_name(base: str) -> str:
    """``base`` with the process id appended (several tools may run at once)."""
    return f"{base}_{os.getpid()}"


# ------------------------------------------------------------------------------------ QoS


def bag_qos_to_runtime(profiles: Sequence[Qos], *, min_depth: int = 1) -> QoSProfile:
    """The publisher QoS for playing a topic back from the profiles recorded for it.

    Reliability and durability by :func:`dbcslam_ros.qos.adapt_to_offers` (as ``ros2 bag
    play`` adapts; no profile: reliable, volatile); depth the largest recorded depth, at least
    ``min_depth`` for volatile topics (so a fast playback does not overrun reliable readers)
    and as recorded for transient-local ones (late joiners get what they would have got).
    """
    plain = [from_bag_qos(q) for q in profiles]
    adapted = adapt_to_offers(plain)
    depth = max([int(q.depth) for q in profiles] + [1 if plain else PROFILES["default"].depth])
    if adapted.durability != "transient_local":
        depth = max(depth, min_depth)
    keep_all = any(q.history == "keep_all" for q in plain)
    return replace(adapted, history="keep_all" if keep_all else "keep_last", depth=depth)


def subscription_qos_for(offered: Sequence[QoSProfile], depth: int = 10) -> QoSProfile:
    """A subscription QoS compatible with every offered publisher QoS and as strong as they
    allow (:func:`dbcslam_ros.qos.adapt_to_offers`)."""
    return adapt_to_offers(offered, depth)


def add_qos_arguments(parser: argparse.ArgumentParser) -> None:
    """``--qos PROFILE`` and per-policy overrides (like ``ros2 topic echo``)."""
    group = parser.add_argument_group("QoS of the subscription")
    group.add_argument(
        "--qos",
        default="auto",
        choices=["auto", *sorted(PROFILES)],
        help="'auto' (default) matches what the publishers offer; or a named profile",
    )
    group.add_argument("--qos-reliability", choices=["reliable", "best_effort"])
    group.add_argument("--qos-durability", choices=["volatile", "transient_local"])
    group.add_argument("--qos-depth", type=int, metavar="N", help="history depth (>= 1)")


def qos_from_arguments(args: argparse.Namespace, offered: Sequence[QoSProfile]) -> QoSProfile:
    """The subscription QoS that ``--qos*`` arguments ask for, given the offered profiles.

    Raises:
        UsageError: a depth < 1.
    """
    base = subscription_qos_for(offered) if args.qos == "auto" else PROFILES[args.qos]
    depth = base.depth if args.qos_depth is None else args.qos_depth
    if depth < 1:
        msg = f"--qos-depth {depth}: expected >= 1"
        raise UsageError(msg)
    return QoSProfile(
        args.qos_reliability or base.reliability,
        args.qos_durability or base.durability,
        "keep_last",
        depth,
    )
